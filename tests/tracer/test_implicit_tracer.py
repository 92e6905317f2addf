"""Implicit and IMEX stepping of the tracer (``tracer.solve(stepping=...)``, docs/tracer.md).

Checks: positivity and exact conservation; TR-BDF2 is second order in dt on the linear
operator (against the matrix exponential) and the IMEX step second order in dt; IMEX
agrees with today's explicit SSP-RK3 within the explicit run's own discretisation error;
the implicit run drained gives the steady solve's P_height and exits (same operator:
P_N = P_0 + A S exactly); ``stepping="auto"`` leaves short runs explicit, bit for bit;
argument errors name the argument.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from spotpde import tracer
from spotpde.grid import Grid
from spotpde.tracer import _implicit

from _problems import void_problem as _void

B = 1.3




def _l1(a, b, grid):
    return float(np.abs(a - b).sum()) * grid.cell_volume


@pytest.mark.parametrize("stepping", ["imex", "multirate", "implicit"])
def test_positive_and_conservative(stepping):
    grid, fields, P0 = _void(0.5)
    r = tracer.solve(grid, fields, P0, 200.0, 5, stepping=stepping, split=4.0)
    assert r.options["stepping"] == stepping
    assert r.outflow[-1] > 0.8                       # most has left
    # mass + outflow = mass0 to round-off, at every frame
    assert r.mass_error < 1e-12
    assert np.all(np.abs(r.mass + r.outflow - 1.0) < 1e-12)
    # P >= 0 up to round-off (IMEX: the extrapolation is limited at -1e-15 max P0)
    assert r.P.min() >= -1e-14 * P0.max()
    # the floor outflow is the P_height through the orifice plane
    assert r.P_height_faces[0].sum() * grid.spacing == pytest.approx(
        r.outflow_by_boundary["floor"], rel=1e-10)
    if stepping in ("imex", "multirate"):
        assert 0 < r.options["cells_implicit"] < 0.05 * grid.size
        assert r.max_cfl <= 0.9 + 1e-12              # the explicit part at its limit


def test_trbdf2_second_order_in_dt():
    """Fixed TR-BDF2 steps of dP/dt = A P against expm(T A) P0."""
    grid, fields, P0 = _void(0.5)
    from spotpde.tracer._operator import _check_fields
    f = _check_fields(grid, fields, "fields")
    from spotpde.tracer import _advection
    faces = _advection.face_velocities(f, grid.walls, np.ones(grid.shape[1:], bool))
    A, _, _, _ = _implicit.build_operator(grid, f, faces)
    T = 4.0
    exact = spla.expm_multiply(T * A, P0.ravel())
    errs = []
    for n in (8, 16, 32):
        st = _implicit.ImplicitStepper(A, T, 1.0, T, grid.cell_volume, 1.0, P0.max())
        p = P0.ravel().copy()
        for _ in range(n):
            p = st._step(p, A @ p, T / n)[0]
        errs.append(np.abs(p - exact).sum() * grid.cell_volume)
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(orders > 1.8), (errs, orders)
    assert np.all(orders < 2.5), (errs, orders)


def test_imex_second_order_in_dt():
    """IMEX with a fixed partition (split 4) at cfl 0.8, 0.4, 0.2 against cfl 0.05."""
    grid, fields, P0 = _void(0.5)
    T = 8.0
    run = lambda c: tracer.solve(grid, fields, P0, T, 2, stepping="imex", split=4.0,
                                 cfl=c).P[-1]
    ref = run(0.05)
    errs = [_l1(run(c), ref, grid) for c in (0.8, 0.4, 0.2)]
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(orders > 1.6), (errs, orders)


@pytest.mark.parametrize("stepping, split", [("imex", 4.0), ("multirate", 4.0)])
def test_agrees_with_explicit_within_its_error(stepping, split):
    """Before, during and after the passage through the orifice the L1 distance between
    IMEX / multirate and explicit SSP-RK3 on the same grid is below the explicit run's
    own discretisation error (its distance from the explicit run at h/2); multirate
    (WENO5 kept on the fast faces) also its outflow."""
    T = 150.0
    grid, fields, P0 = _void(0.5)
    fine, ffields, fP0 = _void(0.25)
    ex = tracer.solve(grid, fields, P0, T, 4)
    im = tracer.solve(grid, fields, P0, T, 4, stepping=stepping, split=split)
    rf = tracer.solve(fine, ffields, fP0, T, 4)
    assert im.steps * split / 2 < ex.steps
    assert rf.outflow[2] > 0.3 and rf.outflow[3] > 0.8
    coarse = lambda P: P.reshape(P.shape[0] // 2, 2, P.shape[1] // 2, 2).mean(axis=(1, 3))
    for k in range(1, 4):
        e_ex = _l1(ex.P[k], coarse(rf.P[k]), grid)
        assert _l1(im.P[k], ex.P[k], grid) < e_ex
        if stepping == "multirate":
            assert abs(im.outflow[k] - ex.outflow[k]) < abs(ex.outflow[k] - rf.outflow[k])


def test_implicit_is_the_steady_solve_minus_what_is_left():
    """S = int_0^T P dt solves A S = P_T - P0 (conservative stages, exactly), so the
    run's P_height and exits are the steady solve's from P0 minus those from P_T."""
    grid, fields, P0 = _void(0.5)
    r = tracer.solve(grid, fields, P0, 400.0, 3, stepping="implicit")
    PT = np.maximum(r.P[-1], 0.0)
    assert 1e-6 < r.mass[-1] < 0.05
    s0 = tracer.solve_steady(grid, fields, P0, scheme="hybrid")   # the implicit operator
    sT = tracer.solve_steady(grid, fields, PT, scheme="hybrid")
    assert s0.exit["trapped"] == 0.0 and sT.exit["trapped"] == 0.0
    ph = s0.P_height - sT.P_height
    assert np.abs(r.P_height - ph).max() < 1e-9 * np.abs(ph).max()
    for k in ("floor", "sides"):
        assert r.outflow_by_boundary[k] == pytest.approx(s0.exit[k] - sT.exit[k], abs=1e-11)


def test_implicit_drained_to_round_off_equals_steady_exactly():
    """A flow that drains completely: S = int P dt solves A S = P_N - P0, so the
    P_height of the implicit run equals the steady solve's to the remaining mass."""
    grid = Grid(2, (-4.0, 4.0), (0.0, 10.0), 0.5)
    Z, X = grid.mesh()
    zero = 0 * X + 0 * Z
    fields = {"u_x": -0.04 * X + zero, "u_z": -1.0 + zero, "D_xx": 0.3 + zero,
              "D_xz": zero, "D_zz": 0.3 + zero}
    P0 = np.exp(-((X - 1) ** 2 + (Z - 7) ** 2) / 1.0) + zero
    P0 /= P0.sum() * grid.cell_volume
    r = tracer.solve(grid, fields, P0, 400.0, 3, stepping="implicit")
    assert r.mass[-1] < 1e-12
    s = tracer.solve_steady(grid, fields, P0, scheme="hybrid")
    assert np.abs(r.P_height - s.P_height).max() < 1e-9 * np.abs(s.P_height).max()
    assert r.outflow_by_boundary["floor"] == pytest.approx(s.exit["floor"], abs=1e-12)


def test_auto_keeps_short_runs_explicit_bit_for_bit():
    grid, fields, P0 = _void(0.5)
    a = tracer.solve(grid, fields, P0, 5.0, 3, stepping="auto")
    e = tracer.solve(grid, fields, P0, 5.0, 3)
    assert a.options["stepping"] == "explicit"
    assert np.array_equal(a.P, e.P) and np.array_equal(a.P_height, e.P_height)
    # a point orifice: 1 % of the moving cells are many times faster than the rest, the
    # more so the finer the grid (u ~ 1/r next to the orifice)
    from spotpde.tracer import _advection
    splits = []
    for h in (0.5, 0.25):
        g, f, _ = _void(h, half=16.0, top=32.0)
        faces = _advection.face_velocities(f, g.walls, np.ones(g.shape[1:], bool))
        splits.append(_implicit.auto_split(faces, g.spacing))
    assert splits[0] > _implicit.MIN_SPLIT and splits[1] > 1.8 * splits[0]
    # uniform flow: nothing to gain
    uni = {"u_x": 0.0, "u_z": -1.0, "D_xx": 0.1, "D_xz": 0.0, "D_zz": 0.1}
    from spotpde.tracer._operator import _check_fields
    faces = _advection.face_velocities(_check_fields(grid, uni, "f"), grid.walls,
                                       np.ones(grid.shape[1:], bool))
    assert _implicit.auto_split(faces, grid.spacing) == pytest.approx(1.0)


def test_bad_arguments_name_the_argument():
    grid, fields, P0 = _void(0.5)
    with pytest.raises(ValueError, match="stepping"):
        tracer.solve(grid, fields, P0, 1.0, 2, stepping="rk4")
    with pytest.raises(ValueError, match="stepping"):
        tracer.solve(grid, lambda t: fields, P0, 1.0, 2, stepping="implicit")
    with pytest.raises(ValueError, match="tol"):
        tracer.solve(grid, fields, P0, 1.0, 2, stepping="implicit", tol=0.0)
    with pytest.raises(ValueError, match="split"):
        tracer.solve(grid, fields, P0, 1.0, 2, stepping="imex", split=0.5)
