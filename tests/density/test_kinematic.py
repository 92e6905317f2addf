"""Kinematic Model: analytic point source, numerical speed and velocity, streamlines."""

import numpy as np
import pytest
from scipy.integrate import quad

from spotpde.density import kinematic
from spotpde.grid import Grid
from spotpde.parameters import Orifice


@pytest.mark.parametrize("z", [0.1, 3.0, 50.0])
def test_point_source_unit_flux_2d_and_3d(z):
    b = 1.3
    s = np.sqrt(2 * b * z)
    f2, _ = quad(lambda x: kinematic.point_source(x, z, b, 2), -12 * s, 12 * s, epsabs=1e-13)
    f3, _ = quad(lambda r: 2 * np.pi * r * kinematic.point_source(r, z, b, 3), 0, 12 * s, epsabs=1e-13)
    assert f2 == pytest.approx(1.0, abs=1e-10)
    assert f3 == pytest.approx(1.0, abs=1e-10)


@pytest.mark.parametrize("dims", [2, 3])
def test_point_source_solves_kinematic_equation(dims):
    """dv/dz = b lap_perp v, checked by centred differences (3D: radial Laplacian)."""
    b, e = 1.7, 1e-3
    x = np.array([0.0, 0.7, -2.0, 4.5])
    z = np.array([0.5, 2.0, 7.0, 30.0])
    v = lambda x, z: kinematic.point_source(x, z, b, dims)
    dvdz = (v(x, z + e) - v(x, z - e)) / (2 * e)
    vxx = (v(x + e, z) - 2 * v(x, z) + v(x - e, z)) / e**2
    if dims == 3:   # lap = v_rr + v_r / r, evaluate off the axis via (r, 0) -> use Cartesian
        vyy = (v(np.hypot(x, e), z) - v(x, z)) * 2 / e**2
        lap = vxx + vyy
    else:
        lap = vxx
    np.testing.assert_allclose(dvdz, b * lap, rtol=1e-5)


def test_point_source_below_and_at_the_floor():
    v = kinematic.point_source(np.array([0.0, 1.0, 0.0, 2.0]), np.array([0.0, 0.0, -1.0, -3.0]), 1.3)
    assert v[0] == np.inf and np.all(v[1:] == 0.0)
    assert isinstance(kinematic.point_source(0.5, 2.0, 1.3), float)
    with pytest.raises(ValueError, match="^b: must be > 0"):
        kinematic.point_source(0.5, 2.0, -1.0)


def test_speed_has_unit_flux_between_reflecting_walls():
    g = Grid(3, (-3, 3), (0, 5), 0.25)
    b = np.broadcast_to(1.0 + 0.1 * g.mesh()[0], g.shape)
    v = kinematic.speed(g, Orifice(x=1.0, width=2.0, rate=7.0), b)
    np.testing.assert_allclose(v.sum(axis=(1, 2)) * g.spacing**2, 1.0, rtol=1e-13)


def _u_x_error(h):
    g = Grid(2, (-8, 8), (0, 12), h, "open")
    u = kinematic.velocity(g, Orifice(x=0.0), 1.3)
    Z, X = g.mesh()
    exact = -X / (2 * Z) * kinematic.point_source(X, Z, 1.3)       # b dv/dx
    far = np.broadcast_to(Z > 3, g.shape)
    return u, g, np.abs(u["u_x"] - exact)[far].max() / np.abs(exact[far]).max()


def test_velocity_converges_and_points_toward_the_orifice():
    (u, g, e1), (_, _, e2) = _u_x_error(0.5), _u_x_error(0.25)
    assert e2 < 4e-3 and e1 / e2 > 3.5, (e1, e2)
    X = np.broadcast_to(g.mesh()[1], g.shape)
    rows = slice(2, None)
    assert np.all(u["u_x"][rows][X[rows] > 0.5] < 0) and np.all(u["u_x"][rows][X[rows] < -0.5] > 0)
    assert np.all(u["u_z"] <= 1e-15 * np.abs(u["u_z"]).max())      # round-off of the DCT


def test_velocity_is_divergence_free():
    """div u = b v_xx - dv/dz = 0: centred differences vanish to O(h^2)."""
    res = []
    for h in (0.5, 0.25):
        g = Grid(2, (-6, 6), (0, 10), h)
        u = kinematic.velocity(g, Orifice(x=0.5, width=1.0), 1.3)
        div = np.gradient(u["u_x"], h, axis=1) + np.gradient(u["u_z"], h, axis=0)
        scale = np.abs(np.gradient(u["u_z"], h, axis=0))[g.z > 3].max()
        res.append(np.abs(div[g.z > 3][:, 2:-2]).max() / scale)
    assert res[1] < 2e-2 and res[0] / res[1] > 3.5, res


def test_streamlines_are_parabolas_and_end_at_the_orifice():
    """Point source: the flux left of a streamline, Phi(x / sqrt(2 b z)), is constant: x ~ sqrt(z)."""
    g = Grid(2, (-12, 12), (0, 30), 0.25, "open")
    u = kinematic.velocity(g, Orifice(x=0.0), 1.3)
    paths = kinematic.streamlines(u, g, [[3.0, 25.0], [-2.0, 12.0]])
    for p, start in zip(paths, ([3.0, 25.0], [-2.0, 12.0])):
        assert p.shape[1] == 2
        np.testing.assert_allclose(p[0], start)
        assert p[-1, 1] == pytest.approx(0.0, abs=1e-9)
        assert abs(p[-1, 0]) < 0.3
        upper = p[:, 1] > 2.0
        c = p[upper, 0] / np.sqrt(p[upper, 1])
        np.testing.assert_allclose(c, c[0], rtol=3e-3)


def test_streamline_3d_stays_in_its_symmetry_plane():
    g = Grid(3, (-6, 6), (0, 10), 0.25, "open")
    u = kinematic.velocity(g, Orifice(x=0.0, y=0.0), 1.0)
    (p,) = kinematic.streamlines(u, g, [[2.0, 2.0, 8.0]])
    assert p.shape[1] == 3
    np.testing.assert_allclose(p[:, 0], p[:, 1], atol=1e-6)
    upper = p[:, 2] > 2.0
    r = np.hypot(p[upper, 0], p[upper, 1])
    c = r / np.sqrt(p[upper, 2])
    np.testing.assert_allclose(c, c[0], rtol=1e-2)
