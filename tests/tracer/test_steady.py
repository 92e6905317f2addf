"""The geometrical propagator by one steady solve (tracer.t_end = inf, docs/steady.md).

G = int_0^inf P dt solves -L G = P0. Checks: it is the limit of the time-stepped solver
(same linear face values: to the undrained remainder; the hybrid scheme against
time-stepped WENO5: to the discretisation error; the default limited scheme:
tests/tracer/test_steady_limited.py), the void model's Brownian bridge, the
mean exit time against the time-stepped integral of the mass, exit probabilities
summing to the initial mass through every kind of boundary, positivity, 3D, and the
case/pipeline/CLI integration.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import spotpde
from spotpde import tracer
from spotpde.fields import void
from spotpde.app.cases import load_case
from spotpde.errors import CaseError
from spotpde.grid import Grid
from spotpde.parameters import Spots

B, X0, Z0, SIGMA = 1.3, 4.0, 20.0, 0.75


def _moments(ph, x, h):
    crossed = ph.sum() * h
    m = (ph * x).sum() * h / crossed
    return crossed, m, (ph * x**2).sum() * h / crossed - m * m


@pytest.fixture(scope="module")
def void_setup():
    """Void-model fields of a point orifice, floor at z = 3 (as tests/tracer/test_void_tracer.py)."""
    h = 0.5
    grid = Grid(2, (-16.0, 16.0), (3.0, 23.0), h, walls="open")
    Z, X = grid.mesh()
    rho = void.point_void_density(X, Z, B) + 0 * X
    fields = void.void_fields(grid, rho, Spots(drift=1.0, b=B), V1=1.0)
    P0 = np.exp(-((X - X0) ** 2 + (Z - Z0) ** 2) / (2 * SIGMA**2)) + 0 * X
    P0 /= P0.sum() * h * h
    return grid, X, Z, fields, P0


def _blob_average(z, X, Z, w):
    above = np.where(Z > z, w, 0.0)
    m, v = void.bridge_moments(z, X, Z, B)
    mean = (above * m).sum() / above.sum()
    return mean, (above * (v + m * m)).sum() / above.sum() - mean**2


@pytest.mark.parametrize("scheme", ["weno5", "hybrid"])
def test_void_point_orifice_gives_brownian_bridge(void_setup, scheme):
    grid, X, Z, fields, P0 = void_setup
    h = grid.spacing
    r = tracer.solve_steady(grid, fields, P0, scheme=scheme)
    # (within ~3 d below the release, z > 15, streamwise upwinding (D_zz = 0 here, so the
    # hybrid scheme is upwind along z) smears the release height: +5 % variance at
    # z = 17.25 with h = 0.5; docs/steady.md)
    for z_target in (6.0, 10.0, 12.5, 15.0):
        k = int(np.argmin(np.abs(grid.z - z_target)))
        crossed, m, v = _moments(r.P_height[k], grid.x, h)
        mb, vb = _blob_average(grid.z[k], X, Z, P0 * h * h)
        assert crossed == pytest.approx(1.0, abs=1e-3)
        assert abs(m - mb) < 0.02 * math.sqrt(vb)
        assert abs(v / vb - 1) < 0.02
    if scheme != "hybrid":
        return
    # central (second order) across the flow: horizontal cell Peclet h / b < 2; upwind
    # along z (b_par = 0: no vertical diffusion)
    assert r.options["central_fraction"]["x"] > 0.99
    assert r.options["central_fraction"]["z"] < 0.5
    # first-order upwind adds |u| h / 2 across the converging streamlines: visibly wider
    ru = tracer.solve_steady(grid, fields, P0, scheme="upwind")
    k = int(np.argmin(np.abs(grid.z - 10.0)))
    _, _, vu = _moments(ru.P_height[k], grid.x, h)
    _, _, vh = _moments(r.P_height[k], grid.x, h)
    _, vb = _blob_average(grid.z[k], X, Z, P0 * h * h)
    assert abs(vu / vb - 1) > 2 * abs(vh / vb - 1)


def _converging():
    """A draining converging flow with void-like diffusion (cell Peclet <= 1.7)."""
    grid = Grid(2, (-8.0, 8.0), (0.0, 20.0), 0.5)
    Z, X = grid.mesh()
    fields = {"u_x": -0.04 * X + 0 * Z, "u_z": -1.0 + 0 * X + 0 * Z, "D_xx": 0.3 + 0 * X + 0 * Z,
              "D_xz": 0.0 + 0 * X + 0 * Z, "D_zz": 0.3 + 0 * X + 0 * Z}
    P0 = np.exp(-((X - 2) ** 2 + (Z - 15) ** 2) / (2 * 0.75**2)) + 0 * X
    P0 /= P0.sum() * grid.cell_volume
    return grid, fields, P0


def test_steady_equals_time_stepped_limit_and_mean_exit_time():
    """Same (linear, first-order upwind) face values: the time-stepped P_height converges
    to the steady one; the mean exit time is int_0^inf mass dt."""
    grid, fields, P0 = _converging()
    h = grid.spacing
    t_end, frames = 80.0, 801
    ts = tracer.solve(grid, fields, P0, t_end, frames, limiter="upwind")
    assert ts.mass[-1] < 1e-10                      # drained
    st = tracer.solve_steady(grid, fields, P0, scheme="upwind")
    scale = np.abs(st.P_height).max()
    assert np.abs(ts.P_height - st.P_height).max() < 1e-8 * scale
    assert ts.outflow_by_boundary["floor"] == pytest.approx(st.exit["floor"], abs=1e-10)
    # mean exit time: trapezoid of the mass over the frames (error O(dt**2))
    mean_ts = float(np.sum(0.5 * (ts.mass[1:] + ts.mass[:-1]) * np.diff(ts.times)))
    assert st.mean_exit_time == pytest.approx(mean_ts, rel=1e-4)
    # the default schemes, steady hybrid (central everywhere here) and time-stepped
    # WENO5: different discretisations of the same equation, close at this resolution
    tw = tracer.solve(grid, fields, P0, t_end, frames)
    sh = tracer.solve_steady(grid, fields, P0, scheme="hybrid")
    assert min(sh.options["central_fraction"].values()) == 1.0
    mean_w = float(np.sum(0.5 * (tw.mass[1:] + tw.mass[:-1]) * np.diff(tw.times)))
    # closed form of the continuum problem (uniform u_z = -1, zero diffusive flux through
    # the floor): G = 1/|u| below the release, so the mean exit time is z0/|u| + D/u**2;
    # upwinding adds its numerical diffusion h/2 to D
    assert sh.mean_exit_time == pytest.approx(15.0 + 0.3, rel=1e-6)
    assert st.mean_exit_time == pytest.approx(15.0 + 0.3 + 0.25, rel=1e-3)
    assert sh.mean_exit_time == pytest.approx(mean_w, rel=2e-3)
    for z_target in (4.0, 10.0):
        k = int(np.argmin(np.abs(grid.z - z_target)))
        _, mw, vw = _moments(tw.P_height[k], grid.x, h)
        _, mh, vh = _moments(sh.P_height[k], grid.x, h)
        assert abs(mh - mw) < 0.01 * math.sqrt(vw)
        assert abs(vh / vw - 1) < 0.01


def _saddle_fields(grid):
    """Flow out through the floor, the top and the open sides, with diffusion."""
    Z, X = grid.mesh()
    zc = 0.5 * (grid.z_range[0] + grid.z_range[1])
    zero = 0 * X + 0 * Z
    return {"u_x": 0.15 + zero, "u_z": 0.2 * (Z - zc) + zero, "D_xx": 0.05 + zero,
            "D_xz": 0.01 + zero, "D_zz": 0.04 + zero}


@pytest.mark.parametrize("scheme", ["weno5", "koren", "hybrid", "upwind"])
def test_exit_probabilities_sum_to_one_and_positive(scheme):
    grid = Grid(2, (-4.0, 4.0), (0.0, 10.0), 0.25, walls="open")
    Z, X = grid.mesh()
    P0 = np.exp(-((X + 1) ** 2 + (Z - 5.2) ** 2) / 0.5)
    P0 /= P0.sum() * grid.cell_volume
    r = tracer.solve_steady(grid, _saddle_fields(grid), P0, scheme=scheme)
    ex = r.exit
    assert min(ex["floor"], ex["sides"], ex["top"]) > 0.02
    assert abs(sum(ex.values()) - 1.0) < 1e-10
    assert r.residence.min() >= 0.0
    assert r.options["min_before_clip"] >= -1e-12 * r.residence.max()
    # P_height faces: floor row is the floor exit, per unit length
    assert r.P_height_faces[0].sum() * grid.spacing == pytest.approx(ex["floor"], rel=1e-10)
    assert r.P_height_faces[-1].sum() * grid.spacing == pytest.approx(-ex["top"], rel=1e-10)


def test_advection_dominated_positive_and_matches_time_stepping():
    """Cell Peclet 100 (the spot model's regime): hybrid is upwind there; G >= 0 and the
    time-stepped upwind run converges to it."""
    grid = Grid(2, (-3.0, 3.0), (0.0, 8.0), 0.25)
    Z, X = grid.mesh()
    zero = 0 * X + 0 * Z
    fields = {"u_x": -0.05 * X + zero, "u_z": -1.0 + zero, "D_xx": 0.0025 + zero,
              "D_xz": zero, "D_zz": 0.0025 + zero}
    P0 = np.exp(-((X - 1) ** 2 + (Z - 6) ** 2) / 0.5)
    P0 /= P0.sum() * grid.cell_volume
    st = tracer.solve_steady(grid, fields, P0, scheme="hybrid")
    assert st.options["central_fraction"]["z"] < 0.01
    assert st.residence.min() >= 0 and st.options["min_before_clip"] >= -1e-12 * st.residence.max()
    ts = tracer.solve(grid, fields, P0, 20.0, 2, limiter="upwind", diffusion="explicit")
    assert ts.mass[-1] < 1e-10
    su = tracer.solve_steady(grid, fields, P0, scheme="upwind")
    assert np.abs(ts.P_height - su.P_height).max() < 1e-8 * np.abs(su.P_height).max()
    assert abs(sum(st.exit.values()) - 1) < 1e-10


def test_3d_matches_time_stepping():
    grid = Grid(3, (-2.0, 2.0), (0.0, 4.0), 0.5, walls="open")
    Z, Y, X = grid.mesh()
    zero = 0 * X + 0 * Y + 0 * Z
    fields = {"u_x": 0.1 + zero, "u_y": -0.05 + zero, "u_z": -0.5 + zero,
              "D_xx": 0.05 + zero, "D_yy": 0.04 + zero, "D_zz": 0.05 + zero,
              "D_xy": 0.01 + zero, "D_xz": zero, "D_yz": -0.01 + zero}
    P0 = np.exp(-(X**2 + Y**2 + (Z - 3) ** 2) / 0.5)
    P0 /= P0.sum() * grid.cell_volume
    ts = tracer.solve(grid, fields, P0, 200.0, 2, limiter="upwind", diffusion="explicit")
    assert ts.mass[-1] < 1e-10
    st = tracer.solve_steady(grid, fields, P0, scheme="upwind")
    assert np.abs(ts.P_height - st.P_height).max() < 1e-8 * np.abs(st.P_height).max()
    assert st.exit["sides"] == pytest.approx(ts.outflow_by_boundary["sides"], abs=1e-9)
    assert abs(sum(st.exit.values()) - 1) < 1e-10


def test_bad_arguments_name_the_argument():
    grid = Grid(2, (-1.0, 1.0), (0.0, 2.0), 0.5)
    f = {"u_x": 0.0, "u_z": -1.0, "D_xx": 0.1, "D_xz": 0.0, "D_zz": 0.1}
    P0 = np.ones(grid.shape)
    with pytest.raises(ValueError, match="^scheme: .*weno5.*hybrid"):
        tracer.solve_steady(grid, f, P0, scheme="weno7")
    with pytest.raises(ValueError, match="^P0"):
        tracer.solve_steady(grid, f, -P0)
    with pytest.raises(ValueError, match="^tol"):
        tracer.solve_steady(grid, f, P0, tol=0.0)
    with pytest.raises(ValueError, match="^max_iter"):
        tracer.solve_steady(grid, f, P0, max_iter=0)
    with pytest.raises(TypeError, match="^fields"):
        tracer.solve_steady(grid, lambda t: f, P0)


def _case(**tracer_keys):
    t = {"model": "void", "start": {"x": 2.0, "z": 12.0, "width": 0.5}, "t_end": math.inf}
    t.update(tracer_keys)
    return {"domain": {"x": [-8.0, 8.0], "z": [0.0, 16.0], "spacing": 0.5},
            "orifice": {"width": 2.0, "rate": 1.2732},
            "kernel": {"shape": "uniform", "size": 0.5, "volume": 0.7854, "rule": 1.0},
            "tracer": t}


def test_case_validation():
    load_case(_case())
    for bad in (-math.inf, math.nan):
        with pytest.raises(CaseError, match="tracer.t_end"):
            load_case(_case(t_end=bad))
    c = _case()
    c["spots"] = {"mode": "transient", "t_end": 10.0}
    with pytest.raises(CaseError) as err:
        load_case(c)
    assert any(p.startswith("tracer.t_end: inf") for p in err.value.problems)


@pytest.mark.slow   # ~30 s: the whole pipeline, netCDF and the plots
def test_pipeline_writes_steady_variables(tmp_path):
    path = tmp_path / "steady.nc"
    ds = spotpde.run(load_case(_case()), path=path)
    assert "P" not in ds and "mass" not in ds
    for name in ("residence", "P_height"):
        assert ds[name].attrs["units"] and ds[name].attrs["long_name"]
    total = sum(ds.attrs[f"exit_{k}"] for k in ("floor", "sides", "top", "trapped"))
    assert abs(total - 1) < 1e-10
    G = ds["residence"].values
    assert G.min() >= 0
    h = 0.5
    assert ds.attrs["mean_exit_time"] == pytest.approx(G.sum() * h * h, rel=1e-12)
    # the plots of a result without P frames
    from spotpde.cli import main
    assert main(["plot", str(path), "-o", str(tmp_path / "f.png")]) == 0
