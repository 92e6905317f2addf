"""Case validation of the silo geometry keys: domain.coordinates and domain.hopper_angle.

Bad input exits 2 with one line naming the key (and the allowed values), before any work
and without an output file; good input builds the matching Grid (axisymmetric radius,
hopper walls from the orifice's edges, a 3D kernel for a cylinder).
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import spotpde
from spotpde.grid import Grid, Hopper

CYLINDER = {"domain": {"coordinates": "axisymmetric", "x": [0.0, 8.0], "z": [0.0, 16.0],
                       "spacing": 0.5},
            "orifice": {"x": 0.0, "width": 2.0}}


def _merge(base, **tables):
    out = {k: dict(v) for k, v in base.items()}
    for name, table in tables.items():
        out.setdefault(name, {}).update(table)
    return out


def _problems(raw) -> list[str]:
    with pytest.raises(spotpde.CaseError) as info:
        spotpde.load_case(raw)
    return info.value.problems


def test_axisymmetric_case_builds_a_cylinder_grid_and_a_3d_kernel():
    case = spotpde.load_case(_merge(CYLINDER, kernel={"shape": "uniform", "size": 2.5,
                                                      "height": 0.0024}))
    g = case.grid
    assert g.axisymmetric and g.axes == ("z", "r") and g.drift_keys == ("u_r", "u_z")
    assert case.kernel.dims == 3
    # kernel.height for a sphere: V1 = w * 4/3 pi R^3
    assert case.kernel.V1 == pytest.approx(0.0024 * 4.0 / 3.0 * math.pi * 2.5**3, rel=1e-12)
    # ring volumes add up to the cylinder
    assert float((g.cell_volumes * np.ones(g.shape)).sum()) == pytest.approx(
        math.pi * 8.0**2 * 16.0, rel=1e-12)


@pytest.mark.parametrize("raw, key, words", [
    (_merge(CYLINDER, domain={"coordinates": "polar"}), "domain.coordinates",
     '"cartesian", "axisymmetric"'),
    (_merge(CYLINDER, orifice={"x": 1.0}), "orifice.x", "centred on the axis"),
    (_merge(CYLINDER, domain={"x": [-8.0, 8.0]}), "domain.x", "[0, a]"),
    (_merge(CYLINDER, domain={"dims": 3}), "domain.dims", "must be 2"),
    (_merge(CYLINDER, orifice={"width": 20.0}), "orifice.x", "must lie on the floor"),
    (_merge(CYLINDER, domain={"hopper_angle": 90.0}), "domain.hopper_angle", "< 90"),
    (_merge(CYLINDER, domain={"hopper_angle": -1.0}), "domain.hopper_angle", ">= 0"),
    (_merge(CYLINDER, domain={"hopper_angle": "steep"}), "domain.hopper_angle", "a number"),
    (_merge(CYLINDER, domain={"hopper_angle": 0.0}, orifice={"width": 0.0}),
     "domain.hopper_angle", "closes the domain"),
    (_merge(CYLINDER, domain={"hopper_angle": 30.0}, orifice={"width": 0.5}),
     "orifice.width", "2 * domain.spacing"),
    ({"domain": {"dims": 3, "hopper_angle": 30.0}, "orifice": {"width": 2.0}},
     "domain.hopper_angle", "domain.dims = 2"),
    ({"domain": {"hopper_angle": 30.0}, "orifice": {"width": 2.0, "profile": "gaussian"}},
     "domain.hopper_angle", "uniform"),
])
def test_bad_geometry_names_the_key(raw, key, words):
    problems = _problems(raw)
    assert any(p.startswith(key + ":") and words in p for p in problems), problems


def test_bad_geometry_exits_2_with_one_line_and_no_file(tmp_path):
    case = tmp_path / "c.toml"
    case.write_text('[domain]\ncoordinates = "cylindrical"\nx = [0.0, 8.0]\n'
                    '[output]\npath = "out.nc"\n')
    r = subprocess.run([sys.executable, "-m", "spotpde", "run", str(case)], cwd=tmp_path,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        'domain.coordinates: must be one of "cartesian", "axisymmetric", got "cylindrical"']
    assert "Traceback" not in r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]


@settings(max_examples=60, deadline=None)
@given(angle=st.floats(-200.0, 200.0, allow_nan=False),
       width=st.sampled_from([0.0, 0.5, 1.0, 2.0, 4.0]),
       axisymmetric=st.booleans())
def test_hopper_angle_is_accepted_exactly_in_its_range(angle, width, axisymmetric):
    """Valid iff 0 <= angle < 90, the orifice leaves the floor open (width >= 2 h), and
    the angle-0 channel is not closed; otherwise a CaseError naming a dotted key."""
    raw = {"domain": {"x": [0.0, 8.0] if axisymmetric else [-8.0, 8.0], "z": [0.0, 8.0],
                      "spacing": 0.5, "hopper_angle": angle,
                      "coordinates": "axisymmetric" if axisymmetric else "cartesian"},
           "orifice": {"x": 0.0, "width": width}}
    valid = 0.0 <= angle < 90.0 and width >= 1.0
    if valid:
        g = spotpde.load_case(raw).grid
        assert g.hopper == Hopper(angle, 0.0, width / 2)
        # the walls leave the orifice's edges: the floor row is open over the orifice
        assert g.active[0].any()
    else:
        problems = _problems(raw)
        assert problems and all(p.split(":")[0] in ("domain.hopper_angle", "orifice.width")
                                for p in problems), problems


# -- the geometry itself -----------------------------------------------------------------

@pytest.mark.parametrize("angle", [0.0, 10.0, 30.0, 45.0, 60.0])
def test_wedge_material_fractions_are_exact_areas(angle):
    """sum(material) h^2 is the wedge's area inside the box (closed form)."""
    hw, h, X, H = 1.0, 0.25, 6.0, 10.0
    g = Grid(2, (-X, X), (0.0, H), h, hopper=Hopper(angle, 0.0, hw))
    s = math.tan(math.radians(angle))
    # half-width min(hw + s z, X): linear up to z* then flat
    zs = H if s == 0 else min(H, (X - hw) / s)
    area = 2 * (hw * zs + 0.5 * s * zs**2 + X * (H - zs))
    assert float(g.material.sum()) * h**2 == pytest.approx(area, rel=1e-12)
    assert np.all((g.material >= 0) & (g.material <= 1))
    # the staircase keeps the cells whose centre is inside
    Z, Xc = g.mesh()
    assert np.array_equal(g.active, np.broadcast_to(np.abs(Xc) <= hw + s * Z, g.shape))


@pytest.mark.parametrize("angle", [15.0, 30.0, 60.0])
def test_cone_material_volume(angle):
    """sum(material * ring volume) is the cone's volume inside the cylinder (closed form),
    to the midpoint rule's accuracy in the few cells where the cone meets the wall."""
    hw, h, a, H = 1.0, 0.25, 6.0, 10.0
    g = Grid(2, (0.0, a), (0.0, H), h, coordinates="axisymmetric", hopper=Hopper(angle, 0.0, hw))
    s = math.tan(math.radians(angle))
    zs = min(H, (a - hw) / s)
    vol = math.pi * ((((hw + s * zs) ** 3 - hw**3) / (3 * s)) + a**2 * (H - zs))
    got = float((g.material * g.cell_volumes).sum())
    assert got == pytest.approx(vol, rel=1e-5)


def test_vertical_hopper_is_a_channel_of_the_orifice_width():
    g = Grid(2, (-4.0, 4.0), (0.0, 4.0), 0.5, hopper=Hopper(0.0, 0.0, 1.0))
    assert np.array_equal(g.active.sum(axis=1), np.full(g.nz, 4))
    assert np.array_equal(g.material, g.active.astype(float))


@pytest.mark.parametrize("kwargs, word", [
    ({"coordinates": "axisymmetric", "x_range": (-1.0, 4.0)}, "x range"),
    ({"coordinates": "axisymmetric", "dims": 3}, "dims"),
    ({"coordinates": "spherical"}, "coordinates"),
])
def test_grid_refuses_bad_coordinates(kwargs, word):
    base = {"dims": 2, "x_range": (0.0, 4.0), "z_range": (0.0, 4.0), "spacing": 0.5}
    with pytest.raises(ValueError, match=word):
        Grid(**{**base, **kwargs})


@pytest.mark.parametrize("kwargs, word", [
    ({"angle": 90.0}, "angle"), ({"angle": -5.0}, "angle"), ({"angle": float("nan")}, "angle"),
    ({"angle": 0.0, "half_width": 0.0}, "half_width"), ({"angle": 10.0, "half_width": -1.0},
                                                        "half_width"),
])
def test_hopper_refuses_bad_arguments(kwargs, word):
    with pytest.raises(ValueError, match=f"^{word}"):
        Hopper(**{"half_width": 1.0, **kwargs})
