"""The long-run steppers (``stepping="imex"``, ``"multirate"``, ``"implicit"``, ``"auto"``)
in a cylinder, a wedge hopper and a cone hopper (docs/long_runs.md, "Other geometries").

They step the explicit scheme's own operator of the geometry (``Q = 2 pi r P`` on the
Cartesian twin, the staircase walls closed), so: mass + outflow is conserved to
round-off, ``P >= 0`` and ``P = 0`` off the hopper; IMEX and multirate stay within the
explicit run's own discretisation error (its distance from the explicit run at h/2, the
box tests' bound), multirate converges to the explicit solution as the step shrinks;
the implicit run is the geometry's steady solve minus what is left; ``"auto"`` chooses
by the box rule on the geometry's face velocities.
"""

from __future__ import annotations

import numpy as np
import pytest

from spotpde import tracer
from spotpde._roundoff import clip_roundoff
from spotpde.app import pipeline
from spotpde.app.cases import load_case
from spotpde.density import spot_density
from spotpde.grid import Grid, Hopper
from spotpde.tracer import _geometry, _implicit, _solve

KINDS = ("cylinder", "wedge", "cone")
#: orifice rates (void model) that drain most of the blob by t = 100 in each shape
RATE = {"cylinder": 6.0, "wedge": 1.0, "cone": 3.0}
T = 100.0


def _void(kind, h, stepping="explicit"):
    """Void-model fields in a silo of radius / half-width 4 d, 10 d tall, an orifice of
    width (diameter) 1 d; a blob released at (1, 6). The case carries ``stepping``: the
    case validation takes the long-run steppers in every geometry."""
    axi = kind != "wedge"
    dom = {"dims": 2, "z": [0.0, 10.0], "spacing": h, "walls": "reflecting",
           "x": [0.0, 4.0] if axi else [-4.0, 4.0]}
    if axi:
        dom["coordinates"] = "axisymmetric"
    if kind != "cylinder":
        dom["hopper_angle"] = 30.0
    case = load_case({
        "domain": dom, "orifice": {"x": 0.0, "width": 1.0, "rate": RATE[kind]},
        "spots": {"b": 1.3},
        "kernel": {"shape": "uniform", "size": 0.5, "volume": 0.5236 if axi else 0.7854,
                   "rule": 1.0},
        "tracer": {"model": "void", "start": {"x": 1.0, "z": 6.0, "width": 1.0},
                   "t_end": T, "stepping": stepping}})
    assert case.tracer_options["stepping"] == stepping
    grid = case.grid
    rho = clip_roundoff(spot_density.solve(grid, case.orifice, case.spots))
    return grid, pipeline.case_fields(case, rho), pipeline.initial_density(grid,
                                                                         case.tracer.start)


def _l1(grid, a, b):
    """L1 distance of two densities (probability)."""
    return float((np.abs(a - b) * grid.geometry.cell_volumes).sum())


def _coarse(grid, fine, P):
    """Frames of the h/2 grid on the cells of ``grid`` (probability per cell kept)."""
    m = P * fine.geometry.cell_volumes
    nz, nx = m.shape[-2:]
    m = m.reshape(m.shape[:-2] + (nz // 2, 2, nx // 2, 2)).sum(axis=(-3, -1))
    return m / grid.geometry.cell_volumes


_RUNS = {}


def _runs(kind):
    """Explicit runs at h = 0.5 and h = 0.25 (the converged reference), once per shape."""
    if kind not in _RUNS:
        grid, fields, P0 = _void(kind, 0.5)
        fine, ffields, fP0 = _void(kind, 0.25)
        _RUNS[kind] = (grid, fields, P0, tracer.solve(grid, fields, P0, T, 4), fine,
                       tracer.solve(fine, ffields, fP0, T, 4))
    return _RUNS[kind]


@pytest.mark.parametrize("stepping", ["imex", "multirate", "implicit"])
@pytest.mark.parametrize("kind", KINDS)
def test_positive_and_conservative(kind, stepping):
    grid, fields, P0 = _void(kind, 0.5, stepping)
    r = tracer.solve(grid, fields, P0, T, 4, stepping=stepping, split=4.0)
    assert r.options["stepping"] == stepping
    assert r.options["coordinates"] == grid.coordinates
    assert r.outflow[-1] > 0.5                       # most has left
    mass0 = r.mass[0]
    assert mass0 == pytest.approx(1.0, rel=1e-12)
    assert r.mass_error < 1e-12
    assert np.all(np.abs(r.mass + r.outflow - mass0) < 1e-12)
    assert r.P.min() >= -1e-14 * P0.max()
    assert np.all(r.P[:, ~grid.active] == 0.0)       # nothing crosses a staircase wall
    # the floor outflow is P_height through the orifice plane (per unit area)
    floor = float((r.P_height_faces[0] * grid.geometry.horizontal_measures).sum())
    assert floor == pytest.approx(r.outflow_by_boundary["floor"], rel=1e-10)
    if stepping != "implicit":
        assert 0 < r.options["cells_implicit"] < 0.1 * grid.size     # a few cells
        assert r.max_cfl <= 0.9 + 1e-12


@pytest.mark.parametrize("stepping", ["imex", "multirate"])
@pytest.mark.parametrize("kind", KINDS)
def test_frames_within_the_explicit_error(kind, stepping):
    """Before, during and after the passage through the orifice the L1 distance of IMEX /
    multirate from the explicit run on the same grid is below the explicit run's own
    error, its distance from the explicit run at h/2 (the box tests' bound), with at
    least split / 2 times fewer steps."""
    grid, fields, P0, ex, fine, rf = _runs(kind)
    split = 4.0
    im = tracer.solve(grid, fields, P0, T, 4, stepping=stepping, split=split)
    assert im.steps * split / 2 < ex.steps
    ref = _coarse(grid, fine, rf.P)
    for k in range(1, 4):
        assert _l1(grid, im.P[k], ex.P[k]) < _l1(grid, ex.P[k], ref[k]), k


@pytest.mark.parametrize("kind", ["cylinder", "cone"])
def test_multirate_outflow_within_the_explicit_error(kind):
    """The cumulative outflow of multirate: its largest distance from the explicit run
    over the frames is below the explicit run's largest error (the wedge, where the
    whole blob passes a 2-cell orifice between t = 0 and 33, is not: 1.5e-2 against
    6.0e-3 at split 4, a time error, next test; docs/long_runs.md)."""
    grid, fields, P0, ex, fine, rf = _runs(kind)
    mr = tracer.solve(grid, fields, P0, T, 4, stepping="multirate", split=4.0)
    assert np.abs(mr.outflow - ex.outflow).max() < np.abs(ex.outflow - rf.outflow).max()


@pytest.mark.parametrize("kind", KINDS)
def test_multirate_converges_to_the_explicit_solution_in_dt(kind):
    """Multirate's distance from the time-converged explicit run (cfl 0.1) shrinks with
    its step: frames and outflow at cfl 0.9, 0.45, 0.225 (first order or better: each
    halving divides both by more than 1.4)."""
    grid, fields, P0 = _void(kind, 0.5)
    ref = tracer.solve(grid, fields, P0, T, 4, cfl=0.1)
    dp, do = [], []
    for cfl in (0.9, 0.45, 0.225):
        r = tracer.solve(grid, fields, P0, T, 4, stepping="multirate", split=4.0, cfl=cfl)
        dp.append(max(_l1(grid, r.P[k], ref.P[k]) for k in range(1, 4)))
        do.append(np.abs(r.outflow - ref.outflow).max())
    for d in (dp, do):
        assert d[0] / d[1] > 1.4 and d[1] / d[2] > 1.4, (dp, do)


@pytest.mark.parametrize("kind", KINDS)
def test_implicit_is_the_steady_solve_minus_what_is_left(kind):
    """The implicit run steps the geometry's hybrid operator, the steady solve's: its
    P_height and exits are the steady solve's from P0 minus those from P_T."""
    grid, fields, P0 = _void(kind, 0.5)
    r = tracer.solve(grid, fields, P0, 3 * T, 3, stepping="implicit")
    PT = np.maximum(r.P[-1], 0.0)
    assert 1e-9 < r.mass[-1] < 0.2
    s0 = tracer.solve_steady(grid, fields, P0, scheme="hybrid")
    sT = tracer.solve_steady(grid, fields, PT, scheme="hybrid")
    ph = s0.P_height - sT.P_height
    assert np.abs(r.P_height - ph).max() < 1e-9 * np.abs(ph).max()
    for k in ("floor", "sides"):
        assert r.outflow_by_boundary[k] == pytest.approx(s0.exit[k] - sT.exit[k], abs=1e-11)


def _sink(kind):
    """A point sink at the orifice (speed 1 / (0.005 + r**2)): 1 % of the moving cells
    many times faster than the rest; a blob at (2, 6)."""
    hop = None if kind == "cylinder" else Hopper(30.0, 0.0, 0.5)
    x = (-4.0, 4.0) if kind == "wedge" else (0.0, 4.0)
    coords = "cartesian" if kind == "wedge" else "axisymmetric"
    grid = Grid(2, x, (0.0, 8.0), 0.25, coordinates=coords, hopper=hop)
    Z, X = grid.mesh()
    zero = 0 * X + 0 * Z
    r = np.hypot(X, Z)
    speed = 1.0 / (0.005 + r**2)
    ux, uz = grid.drift_keys
    dxx, dxz, dzz = grid.diffusivity_keys
    fields = {ux: -speed * X / r + zero, uz: -speed * Z / r + zero, dxx: 0.01 + zero,
              dxz: zero, dzz: zero}
    P0 = np.where((np.abs(np.abs(X) - 2.0) < 0.6) & (np.abs(Z - 6.0) < 0.6) & grid.active,
                  1.0, 0.0)
    return grid, fields, P0


@pytest.mark.parametrize("kind", KINDS)
def test_auto_chooses_by_the_box_rule(kind, monkeypatch):
    """``"auto"``: a short run stays explicit, bit for bit; a long one (threshold
    lowered) runs multirate at ``min(MAX_AUTO_SPLIT, auto_split)`` of the geometry's
    face velocities, bit for bit the multirate run at that split."""
    grid, fields, P0 = _sink(kind)
    a = tracer.solve(grid, fields, P0, 2.0, 3, stepping="auto")
    e = tracer.solve(grid, fields, P0, 2.0, 3)
    assert a.options["stepping"] == "explicit"
    assert np.array_equal(a.P, e.P) and np.array_equal(a.P_height, e.P_height)
    op = _geometry.operator(grid, _solve._check_fields(grid, fields, "fields"), 6,
                            np.ones(grid.shape[1:], bool), implicit=False)
    ratio = _implicit.auto_split(op.faces, grid.spacing)
    assert ratio > _implicit.MIN_SPLIT
    monkeypatch.setattr(_solve, "AUTO_IMEX_STEPS", 10)
    a = tracer.solve(grid, fields, P0, 2.0, 3, stepping="auto")
    split = min(_solve.MAX_AUTO_SPLIT, ratio)
    assert a.options["stepping"] == "multirate" and a.options["split"] == split
    m = tracer.solve(grid, fields, P0, 2.0, 3, stepping="multirate", split=split)
    assert np.array_equal(a.P, m.P) and np.array_equal(a.P_height, m.P_height)
    # a flow without fast cells stays explicit however long
    even = {k: (np.where(grid.active, -0.5, 0.0) if k == grid.drift_keys[1] else 0.0 * v)
            + (0.01 if k == grid.diffusivity_keys[0] else 0.0) for k, v in fields.items()}
    assert tracer.solve(grid, even, P0, 2.0, 3, stepping="auto").options["stepping"] == \
        "explicit"
