"""The steady propagator of the time-stepped scheme itself (private; used by :mod:`._steady`).

:func:`spotpde.tracer.solve` discretises ``dP/dt = L P`` with limited high-order upwind
face values (WENO5-Z clipped to ``[0, 2 P_up]``, or a MUSCL limiter; :mod:`._advection`)
and the positive splitting of the diffusion tensor (:mod:`._diffusion`). Its steady
problem for ``G = int_0^inf P dt`` is the nonlinear system

    R(G) + P0 = 0,     R(G)_c = -(1/h) sum_faces (+-) u_f P*_f(G)  +  (L G)_c

with ``R`` the time-stepped right-hand side (the same kernel, :func:`._operator._rhs`).

**Frozen face ratios.** Every face value lies between 0 and twice the upwind cell's
value, so the advective flux can be written ``u_f r_f G_up`` with the ratio
``r_f = P*_f(G) / G_up`` in ``[0, 2]``. For fixed ratios the system is linear,
``-A(r) G = P0``, and ``-A(r)`` has a positive diagonal, non-positive off-diagonals and
column sums equal to the boundary outflow rates (the argument of docs/steady.md for the
hybrid scheme, with ``r`` for the hybrid weights): an M-matrix. The Picard iteration

    G_{k+1} = (-A(r(G_k)))^{-1} P0

therefore gives a ``G_{k+1} >= 0`` whose exit fluxes sum to the initial mass at *every*
iterate, and a fixed point is a steady state of the time-stepped scheme. Ratios below
``RATIO_FLOOR`` (a face value clipped to 0, which would leave a cell with inflow and no
outflow: a singular matrix) are raised to it, changing that face's flux by at most
``RATIO_FLOOR u_f G_up``.

The iteration starts from the hybrid solution. Its error contracts by a roughly constant
factor (0.5-0.7 measured: the ratios depend on the shape of ``G`` through the
reconstruction stencil, as in deferred correction, Hemker 1986; Koren 1988). Once the
change of the outputs grows instead of shrinking (a limiter switching back and forth in
the far tails) the ratios are under-relaxed, ``G_k <- (G_k + G_{k+1}) / 2``. It stops
when the largest change of ``P_height`` between two iterates, relative to its maximum,
plus the change of the exit probabilities is below ``tol``.

Each iterate is an exact solve (:class:`LinearSolver`): a stale factorisation as a
preconditioner needed 80 GMRES iterations a step in the measurements, and the ratios
change by a constant fraction per iteration, so a fresh factorisation is cheaper.
"""

from __future__ import annotations

import math
import time

import numpy as np
import scipy.sparse.linalg as spla

from ._face_values import face_values
from ._operator import _Operator, _rhs, _Workspace

#: smallest face ratio ``P*_f / P_up`` of the frozen matrices (see the module docstring)
RATIO_FLOOR = 1e-6
#: default tolerance on the change of ``P_height`` and the exits between iterates
TOL = 1e-5
#: default largest number of Picard iterations
MAX_ITER = 60


class LinearSolver:
    """Solves ``M x = b`` for a sequence of M-matrices ``M`` with one sparsity pattern.

    2D: SuperLU with one step of iterative refinement. The first matrix is ordered by
    ``permc_spec`` (minimum degree on ``M + M^T``); the later ones reuse that ordering,
    symmetrically and without pivoting (``diag_pivot_thresh = 0``), which is stable
    because ``M`` is column diagonally dominant (its column sums are the outflow rates,
    >= 0; Golub & Van Loan 2013, Theorem 3.4.3) and saves the ordering (about 40 % of a
    factorisation). 3D: GMRES preconditioned by an incomplete LU (``spilu``, drop
    tolerance 1e-4, fill factor 10), accepted when the L1 residual is below
    ``1e-11 |b|_1``, else SuperLU (docs/steady.md: the fill of a 3D LU grows like
    ``n**(4/3)``).
    """

    RTOL = 1e-11

    def __init__(self, dims: int, permc_spec: str = "MMD_AT_PLUS_A"):
        self.dims = dims
        self.permc_spec = permc_spec
        self.order = None
        self.factorisations = 0
        self.name = ""

    def _krylov(self, M, b, x0):
        try:
            ilu = spla.spilu(M, drop_tol=1e-4, fill_factor=10)
        except RuntimeError:
            return None
        pre = spla.LinearOperator(M.shape, ilu.solve)
        x, _ = spla.gmres(M, b, x0=x0, M=pre, rtol=0.1 * self.RTOL, atol=0.0, restart=100,
                          maxiter=50)
        bn = max(float(np.abs(b).sum()), 1e-300)
        if not np.all(np.isfinite(x)) or float(np.abs(M @ x - b).sum()) > self.RTOL * bn:
            return None
        return x

    def solve(self, M, b, x0=None):
        """``x`` with ``M x = b`` (``M`` CSC); RuntimeError when ``M`` is singular."""
        self.factorisations += 1
        if self.dims == 3:
            x = self._krylov(M, b, x0)
            if x is not None:
                self.name = "gmres+spilu"
                return x
        if self.order is None or self.dims == 3:
            lu = spla.splu(M, permc_spec=self.permc_spec)
            self.name = f"splu({self.permc_spec})"
            if self.dims == 2:
                self.order = np.argsort(lu.perm_c)
            x = lu.solve(b)
            return x + lu.solve(b - M @ x)
        p = self.order
        Mp = M[p][:, p].tocsc()
        lu = spla.splu(Mp, permc_spec="NATURAL", diag_pivot_thresh=0.0,
                       options={"SymmetricMode": True})
        x = np.empty_like(b)
        x[p] = lu.solve(b[p])
        r = b - M @ x
        x[p] += lu.solve(r[p])
        return x


def frozen_ratios(G, asm, limiter: int, eps: float):
    """Per axis of ``asm`` (:class:`._steady._Assembly`), the ratio ``P*_f / G_up`` of
    every interior face, clipped to ``[RATIO_FLOOR, 2]``; 1 (the upwind value) where the
    upwind cell is 0 (its flux is 0 whatever the ratio)."""
    ratios = []
    for axis, a in enumerate(asm.axes):
        pf = face_values(G, a["uf"], axis, limiter, eps)
        nax, sl = a["nax"], a["sl"]
        up = np.where(a["ui"].reshape(pf.shape) > 0.0, G[sl(0, nax - 1)], G[sl(1, nax)])
        pos = up > 0.0
        r = np.where(pos, pf / np.where(pos, up, 1.0), 1.0)
        ratios.append(np.clip(r, RATIO_FLOOR, 2.0))
    return ratios


def picard(grid, f, outlet, limiter: int, asm, L, keep, b_full, G0, solver, outputs, *,
           make_op=_Operator, tol: float = TOL, max_iter: int = MAX_ITER):
    """Picard iteration on the frozen face ratios (module docstring).

    Args:
        grid, f, outlet: the (Cartesian or twin) grid, checked fields, floor mask.
        limiter: kernel code of the reconstruction.
        asm: :class:`._steady._Assembly` of the faces; its weights are set to the ratios.
        L: sparse diffusion operator (``dG/dt = L G``).
        keep: boolean mask of the cells solved for (others keep ``G = 0``).
        b_full: ``P0`` flattened.
        G0: starting iterate (the hybrid solution), grid shaped.
        solver: :class:`LinearSolver` holding the starting matrix's factors.
        outputs: ``outputs(G) -> (P_height_faces, exits dict)`` of the current weights.
        make_op: the time-stepped operator's class (its ``_rhs`` gives the residual).
        tol: stopping tolerance (module docstring).
        max_iter: iterations at most.

    Returns:
        ``(G, info)``: the last iterate (an exact solve of its frozen matrix: ``>= 0``
        up to round-off, conservative) and a dict of statistics: ``iterations``,
        ``converged``, ``change`` (last change of the outputs), ``residual_l1`` and
        ``residual_max`` (the time-stepped scheme's ``|R(G) + P0|_1 h**dims / mass0``
        and ``max |R(G) + P0| / max P0``), ``relaxed`` (the iteration at which
        under-relaxation started, or -1), ``min_before_clip`` (the most negative value
        of the last solve, round-off, set to 0), ``weno_scale``.
    """
    t0 = time.perf_counter()
    shape = grid.shape
    b = b_full[keep]
    mass0 = float(b_full.sum()) * grid.cell_volume
    # the WENO smoothness scale: G where the tracer starts (as P0's peak for time stepping)
    start = b_full.reshape(shape) > 1e-3 * b_full.max()
    scale = max(float(G0[start].max()), 1e-300)
    eps = 1.0 / scale**2
    G = G0
    prev, prev_change = outputs(G0), math.inf
    omega, relaxed, change, it = 1.0, -1, math.inf, 0
    for it in range(1, max_iter + 1):
        asm.set_ratios(frozen_ratios(G, asm, limiter, eps))
        M = (-(asm.matrix() + L)).tocsr()[keep][:, keep].tocsc()
        g = solver.solve(M, b, G.ravel()[keep])
        if not np.all(np.isfinite(g)):
            raise RuntimeError("the propagator G is not finite")
        g_min = float(g.min()) if g.size else 0.0
        g = np.maximum(g, 0.0)
        G_new = np.zeros(G.size)
        G_new[keep] = g
        G_new = G_new.reshape(shape)
        out = outputs(G_new)
        peak = max(float(np.abs(out[0]).max()), 1e-300)
        change = (float(np.abs(out[0] - prev[0]).max()) / peak
                  + sum(abs(out[1][k] - prev[1][k]) for k in out[1]) / max(mass0, 1e-300))
        if change < tol:
            G = G_new
            break
        if change > prev_change and relaxed < 0:
            omega, relaxed = 0.5, it
        G = G_new if omega == 1.0 else (1.0 - omega) * G + omega * G_new
        prev, prev_change = out, change
    # the time-stepped scheme's residual of the result
    op = make_op(grid, f, limiter, outlet, False, scale)
    ws = _Workspace(grid, scale)
    _rhs(op, np.ascontiguousarray(G), ws, 0.0)
    res = np.abs(ws.R.ravel() + b_full)[keep]
    return G, {"iterations": it, "converged": change < tol, "change": change,
               "residual_l1": float(res.sum()) * grid.cell_volume / max(mass0, 1e-300),
               "residual_max": float(res.max(initial=0.0)) / max(float(b_full.max()), 1e-300),
               "min_before_clip": g_min,
               "relaxed": relaxed, "weno_scale": scale,
               "seconds_iteration": time.perf_counter() - t0}
