"""The 2D tracer right-hand-side kernel against a plain reference implementation.

The numba kernel (``spotpde._fp_kernels.rhs_2d_kernel``) is written for speed: chunks
of rows, branch-free selects, index offsets arranged for vectorisation, face fluxes in
chunk-local buffers. This test writes the same discretisation the slow, obvious way
(Python loops over faces, the limiter table of docs/tracer.md, the WENO-Z formula of
Jiang & Shu / Borges et al. in its textbook form, and the diffusion tensor from the
independent sparse assembly in ``spotpde._diffusion``) and requires agreement to
round-off, for every reconstruction, on grids that exercise the boundary fallbacks
(fewer cells than the stencil), several chunks, both flow directions, and 1 or 2
threads.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

from spotpde import tracer
from spotpde._advection import LIMITERS
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
    nz, nx = P.shape
    h = op.h
    ux, uz = op.faces["x"], op.faces["z"]
    Fz = np.zeros((nz + 1, nx))
    Fx = np.zeros((nz, nx + 1))
    for i in range(nx):
        col = P[:, i]
        Fz[0, i] = uz[0, i] * P[0, i]
        Fz[nz, i] = uz[nz, i] * P[nz - 1, i]
        for k in range(1, nz):
            up, down = (k - 1, k) if uz[k, i] > 0 else (k, k - 1)
            Fz[k, i] = uz[k, i] * face_value(name, col, up, down, op.eps)
    for k in range(nz):
        row = P[k]
        Fx[k, 0] = ux[k, 0] * P[k, 0]
        Fx[k, nx] = ux[k, nx] * P[k, nx - 1]
        for i in range(1, nx):
            up, down = (i - 1, i) if ux[k, i] > 0 else (i, i - 1)
            Fx[k, i] = ux[k, i] * face_value(name, row, up, down, op.eps)
    adv = -(np.diff(Fx, axis=1) + np.diff(Fz, axis=0)) / h
    diff = (op.L @ P.ravel()).reshape(P.shape)
    Fz_diff = (op.Bz @ P.ravel()).reshape(Fz.shape)
    return adv + diff, Fz[[0, nz]], w * (Fz + Fz_diff)


def random_problem(nz, nx, seed, cross):
    grid = Grid(2, (0.0, nx * 0.25), (0.0, nz * 0.25), 0.25, walls="open")
    rng = np.random.default_rng(seed)
    D = rng.uniform(0.5, 1.0, grid.shape)
    fields = {"u_x": rng.normal(0.0, 1.0, grid.shape), "u_z": rng.normal(-0.3, 1.0, grid.shape),
              "D_xx": D, "D_zz": rng.uniform(0.5, 1.0, grid.shape),
              "D_xz": (0.4 * rng.uniform(-1, 1, grid.shape) * D) if cross else np.zeros(grid.shape)}
    # smooth plus rough: monotone stretches, extrema and tiny values
    Z, X = grid.mesh()
    P = (np.exp(-((X - nx * 0.12) ** 2 + (Z - nz * 0.1) ** 2) / 2.0)
         + 0.3 * rng.random(grid.shape) ** 4)
    return grid, tracer._check_fields(grid, fields, "fields"), np.ascontiguousarray(P)


@pytest.mark.parametrize("name", list(LIMITERS))
@pytest.mark.parametrize("nz,nx", [(3, 2), (5, 6), (37, 11), (40, 33)])
@pytest.mark.parametrize("cross", [True, False])
def test_rhs_kernel_matches_reference(name, nz, nx, cross):
    grid, f, P = random_problem(nz, nx, seed=nz * 100 + nx, cross=cross)
    op = tracer._Operator(grid, f, LIMITERS[name].code, np.ones(nx, bool), implicit=False)
    assert op.k_cross == cross
    want_R, want_edge, want_acc = reference(name, op, P, w=0.7)
    scale = np.abs(want_R).max()
    for threads in (1, 2):
        saved = numba.get_num_threads()
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
        try:
            ws = tracer._Workspace(grid)
            ws.Fz_acc[:] = 1.0
            rates = tracer._rhs(op, P, ws, 0.7)
        finally:
            numba.set_num_threads(saved)
        np.testing.assert_allclose(ws.R, want_R, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(ws.Fz_edge, want_edge, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(ws.Fz_acc - 1.0, want_acc, rtol=0, atol=1e-12 * scale)
        floor, side, top = rates
        assert floor == pytest.approx(-want_edge[0].sum() * grid.spacing, abs=1e-12 * scale)
        assert top == pytest.approx(want_edge[1].sum() * grid.spacing, abs=1e-12 * scale)

