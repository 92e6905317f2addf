"""The single-sweep 3D tracer kernel (issue 29: a step near the memory-bandwidth limit).

``tracer/_fp_kernels_3d.py`` computes each chunk's vertical face planes and finishes the
planes between them in one sweep (two plane buffers); the previous layout, kept in
``_fp_kernels_3d_two_pass.py``, first computed all of a chunk's vertical faces and then
went over the chunk again. The operator also passes ``D_xx = D_yy`` (the spot model's
horizontally isotropic tensor) as one array. None of this may change the scheme: the
kernels must agree to round-off on random data for every reconstruction, sharing an
array must not change a bit, and a step at the positivity limit must stay positive and
conservative. (``test_tracer_kernel.py`` checks the kernel against a plain Python
implementation of the discretisation.)
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

from spotpde.grid import Grid
from spotpde.tracer import _solve
from spotpde.tracer._advection import LIMITERS
from spotpde.tracer._fp_kernels_3d import rhs_3d_kernel
from spotpde.tracer._fp_kernels_3d_two_pass import rhs_3d_two_pass_kernel
from spotpde.tracer._timestepping import SSPRK3

#: unit round-off of float64
EPS = np.finfo(float).eps


def rough_problem(dims, shape, seed, walls="open", isotropic=False):
    """Random face velocities of both signs, random diagonal tensors (``isotropic``:
    ``D_xx = D_yy``) and a rough positive density with empty cells."""
    nz, nx = shape[0], shape[-1]
    ny = shape[1] if dims == 3 else None
    grid = Grid(dims, (0.0, nx * 0.25), (0.0, nz * 0.25), 0.25, walls=walls,
                y_range=None if ny is None else (0.0, ny * 0.25))
    rng = np.random.default_rng(seed)
    axes = "xz" if dims == 2 else "xyz"
    f = {f"u_{a}": rng.normal(-0.2 if a == "z" else 0.0, 1.0, grid.shape) for a in axes}
    for i, a in enumerate(axes):
        f[f"D_{a}{a}"] = rng.uniform(0.0, 0.05, grid.shape)
        for b in axes[i + 1:]:
            f[f"D_{a}{b}"] = np.zeros(grid.shape)
    if isotropic:
        f["D_yy"] = f["D_xx"].copy()
    P = rng.uniform(0, 1, grid.shape) * (rng.uniform(0, 1, grid.shape) < 0.4)
    return grid, _solve._check_fields(grid, f, "fields"), np.ascontiguousarray(P)


def call(kernel, op, P, P0, ca, cb, cc):
    """One stage of ``kernel`` on ``op``'s arrays: (out, Fz_edge, Fz_acc increment)."""
    f = op.faces
    out = np.empty_like(P)
    edge = np.empty((2,) + P.shape[1:])
    acc = np.ones((P.shape[0] + 1,) + P.shape[1:])
    kernel(op.limiter)(P, f["x"], f["y"], f["z"], *op.axial, op.eps, op.h, out, edge, acc,
                       0.3, P0, ca, cb, cc, 0.0)
    return out, edge, acc - 1.0


@pytest.mark.parametrize("name", list(LIMITERS))
@pytest.mark.parametrize("shape", [(4, 3, 2), (9, 7, 8), (37, 11, 9)])
@pytest.mark.parametrize("threads", [1, 2])
def test_single_sweep_kernel_equals_two_pass_kernel(name, shape, threads):
    """Same stage, fluxes and accumulator as the two-pass kernel (several chunks, the
    boundary fallbacks along every axis, both flow directions)."""
    grid, f, P = rough_problem(3, shape, seed=sum(shape))
    op = _solve._Operator(grid, f, LIMITERS[name].code, np.ones(grid.shape[1:], bool),
                          implicit=False, p_scale=P.max())
    P0 = np.random.default_rng(1).uniform(0, 1, P.shape)
    ca, cb, cc = 0.75, 0.25, 0.25 * 0.9 / op.rate
    saved = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        new = call(rhs_3d_kernel, op, P, P0, ca, cb, cc)
        old = call(rhs_3d_two_pass_kernel, op, P, P0, ca, cb, cc)
    finally:
        numba.set_num_threads(saved)
    # a face flux is at most |u| 2 max(P) (the face value lies in [0, 2 P_upwind]) plus
    # 2 max(A) max(P) / h; the stage sums eight terms (ca P0, cb P, six fluxes times
    # cc / h) whose order fast-math may choose differently in the two loops, and either
    # order rounds each of its seven partial sums by at most EPS of the sum of the
    # terms' magnitudes: the two differ by at most 14 EPS times that sum
    fmax = (max(np.abs(u).max() for u in op.faces.values()) * 2 * P.max()
            + 2 * max(a.max() for a in op.axial) * P.max() / op.h)
    terms = ca * P0.max() + cb * P.max() + 6 * cc * fmax / op.h
    np.testing.assert_allclose(new[0], old[0], rtol=0, atol=14 * EPS * terms)
    # the face fluxes come from the same row functions on the same values
    np.testing.assert_allclose(new[1], old[1], rtol=0, atol=2 * EPS * fmax)
    np.testing.assert_allclose(new[2], old[2], rtol=0, atol=2 * EPS * 0.3 * fmax)


def test_equal_horizontal_coefficients_are_stored_once_and_change_no_bit():
    grid, f, P = rough_problem(3, (19, 8, 11), seed=5, isotropic=True)
    outlet = np.ones(grid.shape[1:], bool)
    op = _solve._Operator(grid, f, LIMITERS["weno5"].code, outlet, implicit=False,
                          p_scale=P.max())
    Axx, Ayy, Azz = op.axial
    assert Ayy is Axx and Azz is not Axx
    assert not np.array_equal(Azz, Axx)
    apart = _solve._Operator(grid, f, LIMITERS["weno5"].code, outlet, implicit=False,
                             p_scale=P.max())
    apart.axial = tuple(a.copy() for a in apart.axial)
    steps = []
    for o in (op, apart):
        ws = _solve._Workspace(grid, P.max())
        budget = [0.0, 0.0, 0.0]
        Q = P.copy()
        for _ in range(3):
            Q = _solve._rk_step([o] * 3, Q, 0.9 / o.rate, SSPRK3, ws, budget)
        steps.append((Q, ws.Fz_acc.copy(), budget))
    np.testing.assert_array_equal(steps[0][0], steps[1][0])
    np.testing.assert_array_equal(steps[0][1], steps[1][1])
    assert steps[0][2] == steps[1][2]


@pytest.mark.parametrize("dims,shape", [(2, (33, 17)), (3, (21, 9, 13))])
@pytest.mark.parametrize("limiter", ["weno5", "koren", "minmod"])
@pytest.mark.parametrize("walls", ["reflecting", "open"])
def test_steps_at_the_positivity_limit_stay_positive_and_conservative(dims, shape, limiter,
                                                                      walls):
    """SSP-RK3 steps at ``dt = 1 / rate`` (cfl 1, the forward-Euler positivity bound) on
    rough data: ``P >= 0`` up to round-off of its largest value, and ``mass + outflow``
    kept to the solver's own check (1e-12 of the mass, ``check_mass`` of the runs)."""
    grid, f, P = rough_problem(dims, shape, seed=dims * 7 + len(walls), walls=walls)
    op = _solve._Operator(grid, f, LIMITERS[limiter].code, np.ones(grid.shape[1:], bool),
                          implicit=False, p_scale=P.max())
    ws = _solve._Workspace(grid, P.max())
    hv = grid.spacing ** dims
    mass0 = P.sum() * hv
    budget = [0.0, 0.0, 0.0]
    Q = P.copy()
    for _ in range(20):
        Q = _solve._rk_step([op] * 3, Q, 1.0 / op.rate, SSPRK3, ws, budget)
        assert Q.min() >= -1e-14 * P.max()
    assert sum(budget) > 1e-3 * mass0      # the floor and the top let some out
    assert abs(Q.sum() * hv + sum(budget) - mass0) < 1e-12 * mass0


def test_side_outflow_is_the_flux_through_the_four_walls():
    """``side_outflow`` (a numba loop; it replaced ``numpy.vdot`` through BLAS) is
    ``sum u P`` over the outer x and y faces, positive outwards, and a 3D step's side
    rate is that sum times ``h**2``."""
    from spotpde.tracer._fp_kernels_3d import side_outflow

    grid, f, P = rough_problem(3, (9, 7, 8), seed=11, walls="open")
    op = _solve._Operator(grid, f, LIMITERS["koren"].code, np.ones(grid.shape[1:], bool),
                          implicit=False, p_scale=P.max())
    ux, uy = op.faces["x"], op.faces["y"]
    want = (np.sum(ux[:, :, -1] * P[:, :, -1]) - np.sum(ux[:, :, 0] * P[:, :, 0])
            + np.sum(uy[:, -1, :] * P[:, -1, :]) - np.sum(uy[:, 0, :] * P[:, 0, :]))
    nz, ny, nx = P.shape
    # the sum of the terms' magnitudes bounds the round-off of either summation order
    # by (number of terms) EPS times it: 2 (nz ny + nz nx) = 270 terms here
    scale = max(np.abs(u).max() for u in (ux, uy)) * P.max() * 2 * (nz * ny + nz * nx)
    assert want > 0                     # open sides: outflow only
    assert side_outflow(ux, uy, P) == pytest.approx(want, abs=2 * 270 * EPS * scale)
    ws = _solve._Workspace(grid, P.max())
    floor, side, top = _solve._rhs(op, P, ws, 0.0)
    assert side == pytest.approx(want * grid.spacing ** 2,
                                 abs=2 * 270 * EPS * scale * grid.spacing ** 2)
