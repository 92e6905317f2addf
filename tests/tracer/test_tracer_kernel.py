"""The 2D tracer right-hand-side kernel against a plain reference implementation.

The numba kernel (``spotpde.tracer._fp_kernels.rhs_2d_kernel``) is written for speed: chunks
of rows, branch-free selects, index offsets arranged for vectorisation, face fluxes in
chunk-local buffers. This test writes the same discretisation the slow, obvious way
(Python loops over faces, the limiter table of docs/tracer.md, the WENO-Z formula of
Jiang & Shu / Borges et al. in its textbook form, and the diffusion tensor from the
independent sparse assembly in ``spotpde.tracer._diffusion``) and requires agreement to
round-off, for every reconstruction, on grids that exercise the boundary fallbacks
(fewer cells than the stencil), several chunks, both flow directions, and 1 or 2
threads; in 2D and in 3D (where the same row functions run along z, y and x lines).
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

from spotpde.tracer import _solve
from spotpde.tracer._advection import LIMITERS
from spotpde.grid import Grid


def phi(name, al, ar):
    """Limited slope magnitude (docs/tracer.md table)."""
    return {
        "upwind": lambda: 0.0,
        "minmod": lambda: min(al, ar),
        "vanleer": lambda: 2 * al * ar / (al + ar),
        "mc": lambda: min(2 * al, 2 * ar, (al + ar) / 2),
        "koren": lambda: min(2 * ar, (al + 2 * ar) / 3, 2 * al),
    }[name]()


def limited(name, puu, pu, pd):
    dl, dr = pu - puu, pd - pu
    if dl * dr <= 0 or name == "upwind":
        return pu
    return pu + 0.5 * np.sign(dr) * phi(name, abs(dl), abs(dr))


def weno_z(v, iscale2):
    """WENO-Z (q = 2) upwind value at the downwind face of v[2], clipped to [0, 2 v[2]]."""
    v1, v2, v3, v4, v5 = v
    q = [(2 * v1 - 7 * v2 + 11 * v3) / 6, (-v2 + 5 * v3 + 2 * v4) / 6, (2 * v3 + 5 * v4 - v5) / 6]
    beta = [13 / 12 * (v1 - 2 * v2 + v3) ** 2 + 1 / 4 * (v1 - 4 * v2 + 3 * v3) ** 2,
            13 / 12 * (v2 - 2 * v3 + v4) ** 2 + 1 / 4 * (v2 - v4) ** 2,
            13 / 12 * (v3 - 2 * v4 + v5) ** 2 + 1 / 4 * (3 * v3 - 4 * v4 + v5) ** 2]
    B = [b * iscale2 + 1e-12 for b in beta]
    tau = abs(B[0] - B[2])
    alpha = [d * (1 + (tau / b) ** 2) for d, b in zip((0.1, 0.6, 0.3), B)]
    f = sum(a * qk for a, qk in zip(alpha, q)) / sum(alpha)
    return min(max(f, 0.0), 2 * v3)


def face_value(name, line, up, down, iscale2):
    """Upwind face value between cells ``up`` and ``down`` of a 1D line of cells."""
    s = 1 if down > up else -1
    n = len(line)
    cell = lambda j: line[j] if 0 <= j < n else None
    stencil = [cell(up - 2 * s), cell(up - s), line[up], line[down], cell(down + s)]
    if name == "weno5" and None not in stencil:
        return weno_z(stencil, iscale2)
    if stencil[1] is None:
        return line[up]
    return limited("koren" if name == "weno5" else name, stencil[1], line[up], line[down])


def reference(name, op, P, w):
    """(dP/dt, floor and top fluxes, increment of the flux accumulator) the slow way."""
    names = ("z", "x") if P.ndim == 2 else ("z", "y", "x")
    adv = np.zeros(P.shape)
    for axis, key in enumerate(names):
        u = np.moveaxis(op.faces[key], axis, -1)
        lines = np.moveaxis(P, axis, -1)
        F = np.zeros(u.shape)
        n = lines.shape[-1]
        for idx in np.ndindex(lines.shape[:-1]):
            line, ul = lines[idx], u[idx]
            F[idx + (0,)] = ul[0] * line[0]
            F[idx + (n,)] = ul[n] * line[n - 1]
            for f in range(1, n):
                up, down = (f - 1, f) if ul[f] > 0 else (f, f - 1)
                F[idx + (f,)] = ul[f] * face_value(name, line, up, down, op.eps)
        F = np.moveaxis(F, -1, axis)
        adv -= np.diff(F, axis=axis) / op.h
        if key == "z":
            Fz = F
    diff = (op.L @ P.ravel()).reshape(P.shape)
    Fz_diff = (op.Bz @ P.ravel()).reshape(Fz.shape)
    return adv + diff, Fz[[0, -1]], w * (Fz + Fz_diff)


def random_problem(dims, nz, nx, seed, cross, ny=None):
    """Random face velocities of both signs, a diagonally dominant tensor (with or without
    cross terms) and a density with monotone stretches, extrema and tiny values (3D: ``ny``
    cells along y, default ``nx``)."""
    grid = Grid(dims, (0.0, nx * 0.25), (0.0, nz * 0.25), 0.25, walls="open",
                y_range=None if ny is None else (-1.0, -1.0 + ny * 0.25))
    rng = np.random.default_rng(seed)
    axes = "xz" if dims == 2 else "xyz"
    fields = {f"u_{a}": rng.normal(-0.3 if a == "z" else 0.0, 1.0, grid.shape) for a in axes}
    for i, a in enumerate(axes):
        fields[f"D_{a}{a}"] = rng.uniform(0.5, 1.0, grid.shape)
        for b in axes[i + 1:]:
            # |cross| <= 0.2 per pair: diagonally dominant in 2D and 3D
            c = 0.2 * rng.uniform(-1, 1, grid.shape)
            fields[f"D_{a}{b}"] = c if cross else np.zeros(grid.shape)
    centre = np.array(grid.shape) * 0.25 * 0.4
    mesh = np.meshgrid(*[(np.arange(n) + 0.5) * 0.25 for n in grid.shape], indexing="ij")
    r2 = sum((m - c) ** 2 for m, c in zip(mesh, centre))
    # scaled far from 1, so that the WENO weights' scale 1 / max(P)**2 matters
    P = 1e-3 * (np.exp(-r2 / 2.0) + 0.3 * rng.random(grid.shape) ** 4)
    return grid, _solve._check_fields(grid, fields, "fields"), np.ascontiguousarray(P)


@pytest.mark.parametrize("name", list(LIMITERS))
@pytest.mark.parametrize("dims,nz,nx,ny", [(2, 1, 1, None), (2, 3, 2, None),
                                           (2, 5, 6, None), (2, 17, 2, None),
                                           (2, 37, 11, None), (2, 40, 33, None),
                                           (3, 4, 2, None), (3, 9, 7, None), (3, 19, 8, 11)])
@pytest.mark.parametrize("cross", [True, False])
def test_rhs_kernel_matches_reference(name, dims, nz, nx, ny, cross):
    grid, f, P = random_problem(dims, nz, nx, seed=dims * 10000 + nz * 100 + nx, cross=cross,
                                ny=ny)
    outlet = np.ones(grid.shape[1:], bool)
    op = _solve._Operator(grid, f, LIMITERS[name].code, outlet, implicit=False,
                          p_scale=P.max())
    assert op.has_cross == cross
    want_R, want_edge, want_acc = reference(name, op, P, w=0.7)
    scale = np.abs(want_R).max()
    for threads in (1, 2):
        saved = numba.get_num_threads()
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
        try:
            ws = _solve._Workspace(grid)
            ws.Fz_acc[:] = 1.0
            rates = _solve._rhs(op, P, ws, 0.7)
        finally:
            numba.set_num_threads(saved)
        np.testing.assert_allclose(ws.R, want_R, rtol=0, atol=1e-12 * scale)
        edge = ws.Fz_edge
        np.testing.assert_allclose(edge, want_edge, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(ws.Fz_acc - 1.0, want_acc, rtol=0, atol=1e-12 * scale)
        floor, side, top = rates
        area = grid.spacing ** (dims - 1)
        assert floor == pytest.approx(-want_edge[0].sum() * area, abs=1e-12 * scale)
        assert top == pytest.approx(want_edge[1].sum() * area, abs=1e-12 * scale)



@pytest.mark.parametrize("dims", [2, 3])
@pytest.mark.parametrize("scheme_name", ["ssprk3", "ssprk2"])
@pytest.mark.parametrize("cross", [True, False])
def test_fused_stages_equal_explicit_runge_kutta(dims, scheme_name, cross):
    """The kernels write each Runge-Kutta stage in the same pass as the right-hand side
    (3D: unless the tensor has cross terms, added by a sparse product); the step must
    equal the textbook composition of right-hand sides."""
    from spotpde.tracer._timestepping import scheme_from_name

    scheme = scheme_from_name(scheme_name)
    grid, f, P = random_problem(dims, 37 if dims == 2 else 9, 11 if dims == 2 else 7,
                                seed=7, cross=cross, ny=None if dims == 2 else 10)
    op = _solve._Operator(grid, f, LIMITERS["weno5"].code, np.ones(grid.shape[1:], bool),
                          implicit=False, p_scale=P.max())
    dt = 0.5 / op.rate
    ws = _solve._Workspace(grid, P.max())

    def R(Q):
        _solve._rhs(op, Q, ws, 0.0)
        return ws.R.copy()

    want = P.copy()
    prev = P.copy()
    for a in scheme.alpha:
        prev = a * P + (1 - a) * (prev + dt * R(prev))
    budget = [0.0, 0.0, 0.0]
    got = _solve._rk_step([op] * scheme.stages, P.copy(), dt, scheme, ws, budget)
    np.testing.assert_allclose(got, prev, rtol=0, atol=1e-13 * np.abs(want).max())
    assert (got >= 0).all()


@pytest.mark.parametrize("dims", [2, 3])
@pytest.mark.parametrize("cross", [True, False])
def test_nan_reaches_the_stage_output(dims, cross):
    """A NaN in P must survive the selects and fastmath of the kernels, so that the solver
    sees a blow-up instead of writing a silently wrong field."""
    from spotpde.tracer._timestepping import scheme_from_name

    grid, f, P = random_problem(dims, 37 if dims == 2 else 9, 11 if dims == 2 else 7,
                                seed=3, cross=cross)
    where = (20, 5) if dims == 2 else (4, 3, 3)
    P[where] = np.nan
    op = _solve._Operator(grid, f, LIMITERS["koren"].code, np.ones(grid.shape[1:], bool),
                          implicit=False)
    ws = _solve._Workspace(grid)
    out = _solve._rk_step([op] * 3, P, 1e-3, scheme_from_name("ssprk3"), ws, [0.0, 0.0, 0.0])
    assert np.isnan(out[where])
