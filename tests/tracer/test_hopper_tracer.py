"""The tracer in hoppers: the staircase of ``grid.active`` is a wall (docs/tracer.md, "Hoppers").

Checks: a tracer pushed against the walls of a closed wedge (and cone) keeps its mass
to round-off, with a full tensor (the diagonal D_xz exchanges must not reach across the
staircase) and fields that are nonsense on the inactive cells; P = 0 there at every
frame and in the steady solve; a draining wedge conserves mass + outflow and its drained
time-stepped P_height equals the steady one; the steady mean exit time converges under
refinement.
"""

from __future__ import annotations


import numpy as np
import pytest

from spotpde import tracer
from spotpde.grid import Grid, Hopper

from _grids import hopper


def _wedge(h, axisymmetric=False, angle=30.0, half_width=1.0):
    return hopper(angle, 8.0, 16.0, h, half_width, cone=axisymmetric)


def _keys(grid):
    return grid.drift_keys + grid.diffusivity_keys


def _blob(grid, x0, z0, s=1.0):
    Z, X = grid.mesh()
    P0 = np.where(grid.active, np.exp(-((X - x0) ** 2 + (Z - z0) ** 2) / (2 * s * s)), 0.0)
    return P0 / (P0 * grid.cell_volumes).sum()


def _towards_walls(grid):
    """Flow out towards the hopper walls and down, full tensor (diagonally dominant);
    NaN and wrong-signed values on the inactive cells (they must be ignored)."""
    Z, X = grid.mesh()
    ux, uz, dxx, dxz, dzz = _keys(grid)
    sign = np.sign(X) if not grid.axisymmetric else 1.0
    f = {ux: 0.4 * sign + 0 * Z, uz: -0.3 + 0 * X + 0 * Z, dxx: 0.3 + 0 * X + 0 * Z,
         dxz: 0.1 + 0 * X + 0 * Z, dzz: 0.2 + 0 * X + 0 * Z}
    for k in f:
        f[k] = np.where(grid.active, f[k], np.nan if k != dxx else -1.0)
    return f


@pytest.mark.parametrize("diffusion", ["explicit", "implicit"])
@pytest.mark.parametrize("axisymmetric", [False, True])
def test_closed_hopper_keeps_its_mass(axisymmetric, diffusion):
    grid = _wedge(0.5, axisymmetric)
    f = _towards_walls(grid)
    P0 = _blob(grid, 0.0 if axisymmetric else 2.0, 7.0)
    closed = np.zeros(grid.nx, dtype=bool)
    res = tracer.solve(grid, f, P0, 40.0, 5, outlet=closed, diffusion=diffusion)
    assert res.options["diffusion"] == diffusion
    assert res.outflow[-1] == 0.0
    assert np.abs(res.mass - 1.0).max() < 1e-12
    assert np.all(res.P[:, ~grid.active] == 0.0)
    assert res.P.min() >= 0.0
    # no flux of any kind through a horizontal face that touches an inactive cell (a
    # diagonal exchange past a wall corner would put half its flux on one)
    act = grid.active
    wall = np.ones((grid.nz + 1, grid.nx), dtype=bool)
    wall[1:-1] = ~(act[:-1] & act[1:])
    wall[0], wall[-1] = ~act[0], ~act[-1]
    assert np.all(res.P_height_faces[wall] == 0.0)
    assert np.abs(res.P_height_faces[~wall]).max() > 0.01
    # the tracer did reach the walls: most of it now sits in the cells along them
    wall_cells = grid.active & ~np.roll(grid.active, -1, axis=1) if axisymmetric else \
        grid.active & (~np.roll(grid.active, 1, axis=1) | ~np.roll(grid.active, -1, axis=1))
    assert (res.P[-1] * grid.cell_volumes)[wall_cells].sum() > 0.2
    st = tracer.solve_steady(grid, f, P0, outlet=np.ones(grid.nx, dtype=bool))
    assert sum(st.exit.values()) == pytest.approx(1.0, abs=1e-10)
    assert np.all(st.residence[~grid.active] == 0.0) and st.residence.min() >= 0.0
    assert np.all(st.P_height_faces[wall] == 0.0)


def _sink(grid, c=2.0, D=0.2):
    """Radial flow into the hopper's virtual apex below the orifice (tangent to the
    walls), isotropic diffusion."""
    hop = grid.hopper
    za = -hop.half_width / hop.slope
    Z, X = grid.mesh()
    rho2 = X**2 + (Z - za) ** 2
    keys = _keys(grid)
    return {keys[0]: -c * X / rho2, keys[1]: -c * (Z - za) / rho2, keys[2]: D + 0 * rho2,
            keys[3]: 0 * rho2, keys[4]: D + 0 * rho2}


@pytest.mark.parametrize("axisymmetric", [False, True])
def test_draining_hopper_budget_and_steady_limit(axisymmetric):
    # the hopper walls reach the silo walls at the top (z = 12.1): radial flow everywhere
    grid = Grid(2, (0.0 if axisymmetric else -8.0, 8.0), (0.0, 12.0), 0.5,
                coordinates="axisymmetric" if axisymmetric else "cartesian",
                hopper=Hopper(30.0, 0.0, 1.0))
    f = _sink(grid, c=4.0, D=0.05)
    P0 = _blob(grid, 0.0 if axisymmetric else 1.5, 8.0)
    ts = tracer.solve(grid, f, P0, 130.0, 651, limiter="upwind")
    assert ts.mass[-1] < 1e-10
    assert ts.mass_error < 1e-10
    assert ts.P.min() >= 0.0 and np.all(ts.P[:, ~grid.active] == 0.0)
    assert ts.outflow_by_boundary["floor"] == pytest.approx(1.0, abs=1e-9)
    st = tracer.solve_steady(grid, f, P0, scheme="upwind")
    assert np.abs(ts.P_height - st.P_height).max() < 1e-8 * np.abs(st.P_height).max()
    assert st.exit["floor"] == pytest.approx(1.0, abs=1e-10)
    mean_ts = float(np.sum(0.5 * (ts.mass[1:] + ts.mass[:-1]) * np.diff(ts.times)))
    assert st.mean_exit_time == pytest.approx(mean_ts, rel=1e-3)


def test_steady_hopper_converges_under_refinement():
    """Mean exit time and P_height from a release in a 30 degree wedge, h = 1/2, 1/4, 1/8:
    the differences between successive grids shrink (staircase walls: measured order
    about 1, docs/tracer.md)."""
    T, crossed = [], []
    for h in (0.5, 0.25, 0.125):
        grid = _wedge(h)
        st = tracer.solve_steady(grid, _sink(grid), _blob(grid, 1.5, 9.0))
        T.append(st.mean_exit_time)
        # fraction of P_height crossing z = 4 at |x| > 2 (near the walls)
        k = int(round(4.0 / h))
        ph = st.P_height_faces[k]
        crossed.append(float(ph[np.abs(grid.x) > 2.0].sum() * h))
    d1, d2 = abs(T[1] - T[0]), abs(T[2] - T[1])
    assert d2 < 0.7 * d1 and d2 < 0.02 * T[2]
    e1, e2 = abs(crossed[1] - crossed[0]), abs(crossed[2] - crossed[1])
    assert e2 < 0.7 * e1


def test_P0_on_inactive_cells_is_refused():
    grid = _wedge(0.5)
    f = _sink(grid)
    P0 = np.ones(grid.shape)
    with pytest.raises(ValueError, match="P0: must be 0 on the inactive cells"):
        tracer.solve(grid, f, P0, 1.0, 2)
    with pytest.raises(ValueError, match="P0: must be 0 on the inactive cells"):
        tracer.solve_steady(grid, f, P0)


def test_vertical_hopper_on_cell_faces_equals_the_narrow_box():
    """A hopper of angle 0 whose walls lie on cell faces is a box: the staircase solve
    equals the solve on the box of the orifice's width (steady hybrid and time-stepped
    donor cell to round-off; WENO5, steady and stepped, to its boundary treatment, zero
    neighbours instead of the box's one-sided fallback)."""
    h = 0.5
    wide = Grid(2, (-6.0, 6.0), (0.0, 10.0), h, hopper=Hopper(0.0, 0.0, 2.0))
    box = Grid(2, (-2.0, 2.0), (0.0, 10.0), h)
    cols = np.flatnonzero(wide.active[0])
    assert np.all(wide.active == wide.active[0][None, :]) and len(cols) == box.nx

    def fields(g):
        Z, X = g.mesh()
        return {"u_x": 0.1 * np.sin(X) + 0 * Z, "u_z": -0.4 - 0.02 * X**2 + 0 * Z,
                "D_xx": 0.1 + 0 * X * Z, "D_xz": 0.02 + 0 * X * Z, "D_zz": 0.08 + 0 * X * Z}

    Pw = _blob(wide, 0.5, 7.0)
    Pb = _blob(box, 0.5, 7.0)
    np.testing.assert_allclose(Pw[:, cols], Pb, rtol=1e-13)
    sw = tracer.solve_steady(wide, fields(wide), Pw, scheme="hybrid")
    sb = tracer.solve_steady(box, fields(box), Pb, scheme="hybrid")
    scale = np.abs(sb.P_height).max()
    assert np.abs(sw.P_height[:, cols] - sb.P_height).max() < 1e-10 * scale
    assert sw.mean_exit_time == pytest.approx(sb.mean_exit_time, rel=1e-12)
    # the steady WENO5 solve: to the same boundary treatment (measured 3.4e-3)
    sw = tracer.solve_steady(wide, fields(wide), Pw)
    sb = tracer.solve_steady(box, fields(box), Pb)
    assert np.abs(sw.P_height[:, cols] - sb.P_height).max() < 5e-3 * scale
    for limiter, tol in (("upwind", 1e-12), ("weno5", 5e-3)):   # measured 2e-16, 2.5e-3
        tw = tracer.solve(wide, fields(wide), Pw, 10.0, 3, limiter=limiter, diffusion="explicit")
        tb = tracer.solve(box, fields(box), Pb, 10.0, 3, limiter=limiter, diffusion="explicit")
        assert tw.steps == tb.steps
        assert np.abs(tw.P[-1][:, cols] - tb.P[-1]).max() < tol * tb.P[-1].max()
        assert tw.mass[-1] == pytest.approx(tb.mass[-1], abs=tol)


@pytest.mark.parametrize("axisymmetric", [False, True])
def test_exchange_kernel_equals_the_sparse_operator(axisymmetric):
    """The numba exchange kernel of the time-stepped solver and the sparse matrix of the
    steady solve and of implicit diffusion are the same operator (staircase, metric and
    diagonal exchanges included): R and the vertical fluxes agree to round-off."""
    from spotpde.tracer import _geometry, _geometry_kernels
    grid = _wedge(0.5, axisymmetric)
    geo = _geometry._Geometry(grid)
    f = geo.cartesian_fields(_towards_walls(grid), "fields")
    op = _geometry._GeometryOperator(geo, geo.twin, f, 6, np.ones(grid.nx, dtype=bool),
                                     implicit=False)
    assert op.has_diag
    P = np.where(grid.active, np.random.default_rng(1).random(grid.shape), 0.0)
    R = np.zeros(grid.shape)
    Fz = np.zeros((grid.nz + 1, grid.nx))
    _geometry_kernels.exchange_2d(P, *op.coef, True, R, Fz, 0.7, grid.spacing)
    scale = np.abs(R).max()
    assert np.abs(R - (op.L @ P.ravel()).reshape(grid.shape)).max() < 1e-13 * scale
    assert np.abs(Fz - 0.7 * (op.Bz @ P.ravel()).reshape(Fz.shape)).max() < 1e-13 * scale
    assert abs(R.sum()) < 1e-13 * np.abs(R).sum()
