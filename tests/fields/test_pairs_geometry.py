"""Two-point statistics (velocity correlation, pair diffusivity) in cylinders and hoppers.

The cross integral is local (the spots within the kernel's reach of both points), so:
far from the axis and the walls of a cylinder in plug flow it is the 3D box's; near the
axis it has the cylinder's symmetry; in a hopper far from the walls it is the box's,
near a wall it loses the spots beyond it; a point outside the material is refused by
name (spotpde/fields/_pairs_local.py).
"""

from __future__ import annotations

import numpy as np
import pytest

from spotpde.fields import coefficients as C
from spotpde.fields import kernels
from spotpde.grid import Grid, Hopper
from spotpde.parameters import Spots

SPOTS = Spots(drift=1.0, b=1.3, b_par=0.4)
MF = {"diffusivity": "mean-field"}


def _uniform(grid, value=3.0):
    return np.full(grid.shape, value)


def _close(a, b, rel):
    assert a.keys() == b.keys()
    scale = max(abs(v) for v in b.values())
    for k in a:
        assert abs(a[k] - b[k]) <= rel * scale, (k, a[k], b[k])


def test_cylinder_far_from_axis_and_wall_is_the_3d_box_in_plug_flow():
    kernel = kernels.Uniform(radius=1.5, height=0.01, dims=3)
    cyl = Grid(2, (0.0, 20.0), (0.0, 16.0), 0.25, coordinates="axisymmetric")
    box = Grid(3, (4.0, 16.0), (0.0, 16.0), 0.25, y_range=(-6.0, 6.0))
    r1, r2 = (10.0, 0.3, 8.0), (10.7, -0.4, 8.9)
    for f in (C.velocity_correlation,
              lambda *a: C.pair_diffusivity(*a, **MF),
              lambda *a: C.pair_diffusivity(*a, rule=0.5)):      # passage
        on_cyl = f(cyl, _uniform(cyl), SPOTS, kernel, r1, r2)
        on_box = f(box, _uniform(box), SPOTS, kernel, r1, r2)
        assert len(on_cyl) == 6                     # the 3D Cartesian components
        _close(on_cyl, on_box, 1e-10)               # the same cells and sub-samples
    assert on_box["D_xx"] > 0


def test_cylinder_near_the_axis_has_its_symmetry_and_follows_the_3d_flow():
    """A converging flow rho(r, z): a point on the axis and its partner rotated by 90
    degrees about it give the rotated tensor; the (r, z) form is the point in y = 0; and
    the local 3D field reproduces the 3D box carrying rho(sqrt(x**2 + y**2), z)."""
    kernel = kernels.Gaussian(sigma=0.6, volume=0.05, dims=3)
    cyl = Grid(2, (0.0, 8.0), (0.0, 12.0), 0.25, coordinates="axisymmetric")
    Z, R = np.meshgrid(cyl.z, cyl.x, indexing="ij")

    def rho_of(r, z):
        return np.exp(-r**2 / (2.0 + 0.2 * z)) / (1.0 + 0.1 * z)      # width ~ the kernel's

    rho = rho_of(R, Z)
    on_axis, d = (0.0, 0.0, 6.0), 0.9
    a = C.pair_diffusivity(cyl, rho, SPOTS, kernel, on_axis, (d, 0.0, 6.4), **MF)
    b = C.pair_diffusivity(cyl, rho, SPOTS, kernel, on_axis, (0.0, d, 6.4), **MF)
    scale = a["D_xx"]
    for ka, kb in (("D_xx", "D_yy"), ("D_yy", "D_xx"), ("D_zz", "D_zz"), ("D_xz", "D_yz")):
        assert a[ka] == pytest.approx(b[kb], rel=1e-12, abs=1e-12 * scale), ka
    assert abs(a["D_xy"]) < 1e-12 * scale and abs(a["D_yz"]) < 1e-12 * scale
    assert C.pair_diffusivity(cyl, rho, SPOTS, kernel, (0.0, 6.0), (d, 6.4), **MF) == a
    # both on the axis: no preferred horizontal direction
    c = C.velocity_correlation(cyl, rho, SPOTS, kernel, on_axis, (0.0, 0.0, 6.8))
    assert c["C_xx"] == pytest.approx(c["C_yy"], rel=1e-12)
    assert abs(c["C_xz"]) < 1e-12 and 0.0 < c["C_zz"] < 1.0
    # the 3D box with the same flow (sampled exactly; the cylinder interpolates in r)
    box = Grid(3, (-6.0, 6.0), (0.0, 12.0), 0.25)
    Zb, Yb, Xb = box.mesh()
    rho3 = np.broadcast_to(rho_of(np.hypot(Xb, Yb), Zb), box.shape)
    ref = C.pair_diffusivity(box, rho3, SPOTS, kernel, on_axis, (d, 0.0, 6.4), **MF)
    _close(a, ref, 3e-3)                           # measured: 1.2e-3 (D_xx) at h = d/4
    flat = C.pair_diffusivity(box, np.full(box.shape, rho_of(0.0, 6.2)), SPOTS, kernel,
                              on_axis, (d, 0.0, 6.4), **MF)
    assert abs(flat["D_xx"] - ref["D_xx"]) > 0.05 * ref["D_xx"]   # the flow matters here


def _wedge():
    return Grid(2, (-20.0, 20.0), (0.0, 40.0), 0.5,
                hopper=Hopper(angle=30.0, centre=0.0, half_width=2.0))


def test_hopper_far_from_the_walls_is_the_box_and_loses_the_spots_beyond_a_wall():
    kernel = kernels.Gaussian(sigma=0.8, volume=0.05, dims=2)
    wedge = _wedge()
    box = Grid(2, (-20.0, 20.0), (0.0, 40.0), 0.5)
    rho_w = wedge.geometry.restrict(_uniform(wedge))
    r1, r2 = (0.3, 30.0), (1.4, 30.6)
    for f in (C.velocity_correlation, lambda *a: C.pair_diffusivity(*a, **MF),
              lambda *a: C.pair_diffusivity(*a, rule=0.5)):
        _close(f(wedge, _uniform(wedge), SPOTS, kernel, r1, r2),
               f(box, _uniform(box), SPOTS, kernel, r1, r2), 1e-12)
    # 1 d inside the wall: the spots beyond it are not there, the pair diffuses less
    x_wall = float(wedge.hopper.half_width_at(20.0))
    near = (x_wall - 1.0, 20.0), (x_wall - 1.8, 20.5)
    in_hopper = C.pair_diffusivity(wedge, rho_w, SPOTS, kernel, *near, **MF)
    in_box = C.pair_diffusivity(box, _uniform(box), SPOTS, kernel, *near, **MF)
    assert in_hopper["D_xx"] < 0.95 * in_box["D_xx"]     # measured: 0.905
    # a cone far from its walls is the cylinder
    k3 = kernels.Uniform(radius=1.5, height=0.01, dims=3)
    cone = Grid(2, (0.0, 20.0), (0.0, 20.0), 0.5, coordinates="axisymmetric",
                hopper=Hopper(angle=30.0, centre=0.0, half_width=2.0))
    cyl = Grid(2, (0.0, 20.0), (0.0, 20.0), 0.5, coordinates="axisymmetric")
    p1, p2 = (1.0, 0.5, 16.0), (1.6, 0.2, 16.5)
    _close(C.pair_diffusivity(cone, _uniform(cone), SPOTS, k3, p1, p2, **MF),
           C.pair_diffusivity(cyl, _uniform(cyl), SPOTS, k3, p1, p2, **MF), 1e-12)


@pytest.mark.parametrize("grid, kernel, inside, outside, why", [
    (_wedge(), kernels.Gaussian(sigma=0.8, volume=0.05, dims=2), (0.0, 10.0), (12.0, 10.0),
     "beyond the hopper's wall"),
    (Grid(2, (0.0, 8.0), (0.0, 8.0), 0.5, coordinates="axisymmetric"),
     kernels.Uniform(radius=1.5, height=0.01, dims=3), (1.0, 0.0, 4.0), (6.0, 6.0, 4.0),
     "beyond the cylinder's wall r = 8"),
    (Grid(2, (0.0, 8.0), (0.0, 8.0), 0.5, coordinates="axisymmetric"),
     kernels.Uniform(radius=1.5, height=0.01, dims=3), (1.0, 0.0, 4.0), (1.0, 0.0, 9.0),
     "outside the silo's height"),
])
def test_a_point_outside_the_material_is_refused_by_name(grid, kernel, inside, outside, why):
    rho = _uniform(grid)
    with pytest.raises(ValueError, match=r"^r2: the point .* lies outside the material \("
                       + why):
        C.pair_diffusivity(grid, rho, SPOTS, kernel, inside, outside, **MF)
    with pytest.raises(ValueError, match=r"^r1: .* outside the material"):
        C.velocity_correlation(grid, rho, SPOTS, kernel, outside, inside)
    with pytest.raises(ValueError, match=r"^kernel: the axisymmetric grid needs a 3D kernel"):
        cyl = Grid(2, (0.0, 8.0), (0.0, 8.0), 0.5, coordinates="axisymmetric")
        C.velocity_correlation(cyl, _uniform(cyl), SPOTS,
                               kernels.Uniform(radius=1.5, height=0.01, dims=2),
                               (1.0, 4.0), (1.5, 4.0))


def test_cylinder_spot_tensor_turns_with_the_azimuth():
    """A constant cylindrical ``D_rz`` is ``D_xz = D_rz x / r``, ``D_yz = D_rz y / r``:
    rotating the pair by 90 degrees about the axis moves it from xz to yz, and off the
    axis it is a little less than the box's constant ``D_xz`` (the kernel straddles
    azimuths). Spot fields given as grid arrays give the numbers of the constants."""
    kernel = kernels.Uniform(radius=1.5, height=0.01, dims=3)
    cyl = Grid(2, (0.0, 8.0), (0.0, 10.0), 0.5, coordinates="axisymmetric")
    rho = _uniform(cyl, 2.0)
    tensor = {"D_rr": 1.3, "D_rz": 0.2, "D_zz": 0.4}
    a = C.pair_diffusivity(cyl, rho, SPOTS, kernel, (2.0, 0.0, 5.0), (2.5, 0.0, 5.3),
                           spot_diffusivity_tensor=tensor, **MF)
    b = C.pair_diffusivity(cyl, rho, SPOTS, kernel, (0.0, 2.0, 5.0), (0.0, 2.5, 5.3),
                           spot_diffusivity_tensor=tensor, **MF)
    assert b["D_yz"] == pytest.approx(a["D_xz"], rel=1e-12)
    assert abs(a["D_yz"]) < 1e-12 * a["D_xz"] and abs(b["D_xz"]) < 1e-12 * a["D_xz"]
    box = Grid(3, (-8.0, 8.0), (0.0, 10.0), 0.5)
    ref = C.pair_diffusivity(box, _uniform(box, 2.0), SPOTS, kernel, (2.0, 0.0, 5.0),
                             (2.5, 0.0, 5.3), spot_diffusivity_tensor={
                                 "D_xx": 1.3, "D_yy": 1.3, "D_zz": 0.4, "D_xz": 0.2}, **MF)
    assert a["D_xx"] == pytest.approx(ref["D_xx"], rel=1e-12)
    assert 0.85 * ref["D_xz"] < a["D_xz"] < 0.97 * ref["D_xz"]      # measured: 0.927
    fields = Spots(drift=np.full(cyl.shape, 1.0), b=np.full(cyl.shape, 1.3),
                   b_par=np.full(cyl.shape, 0.4))
    for kw in (MF, {"rule": 0.5}):
        _close(C.pair_diffusivity(cyl, rho, fields, kernel, (2.0, 5.0), (2.5, 5.3), **kw),
               C.pair_diffusivity(cyl, rho, SPOTS, kernel, (2.0, 5.0), (2.5, 5.3), **kw), 1e-12)
