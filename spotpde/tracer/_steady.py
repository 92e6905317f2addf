"""The geometrical propagator by one steady solve (``tracer.t_end = inf``).

``G(r) = int_0^inf P(r, t) dt`` (the expected time spent per unit volume, area in 2D;
units time / d**dims) solves the steady tracer equation

    -L G = P0,     L P = -div(u_p P) + sum_ij d_i d_j (D_p^ij P)

with the boundary conditions of :func:`spotpde.tracer.solve` (outflow through the
orifice, open sides and the top; walls elsewhere; no diffusive flux through any
boundary). Its vertical face fluxes are ``P_height`` (the time integral of the downward
probability flux), its boundary fluxes the exit probabilities, and ``sum(G) h**dims``
the mean exit time (for a normalised ``P0``). Derivations and measurements:
docs/steady.md.

Discretisation: the finite volumes of the tracer with the same diffusion operator
(the positive 9-point splitting of the tensor, :mod:`spotpde.tracer._diffusion`) and the same
boundary faces; the interior advective face value is the hybrid (Spalding 1972) blend

    P*_f = P_up + (theta_f / 2) (P_down - P_up),   theta_f = min(1, 2 A_down / (|u_f| h))

with ``A_down`` the axial exchange coefficient (``D_ii - sum_j |D_ij|``) of the
downstream cell: central differences (second order) wherever the cell Peclet number
``|u| h / A`` is at most 2 (the whole void model: ``D_p ~ b |u_p|`` with ``b >> h``),
first-order upwind where advection dominates. ``theta_f`` is the largest value that
keeps the off-diagonal entries of ``-A`` non-positive, so ``-A`` has positive diagonal,
non-positive off-diagonals and column sums equal to the boundary outflow rates: an
M-matrix (on the cells the tracer can reach), ``G = (-A)^{-1} P0 >= 0``, and the exit
probabilities sum to the initial mass. The scheme is linear, so one sparse solve gives
``G``: SuperLU (``scipy.sparse.linalg.splu``) in 2D; in 3D GMRES preconditioned by an
incomplete LU (``spilu``), falling back to SuperLU if it does not reach a residual of
1e-11. The time-stepped solver run with the same face values converges to ``G``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import _advection, _diffusion
from ..errors import NumericalError

_AXES = {2: ("z", "x"), 3: ("z", "y", "x")}


@dataclass
class SteadyResult:
    """Output of :func:`spotpde.tracer.solve_steady`.

    Attributes:
        residence: grid-shaped ``G = int_0^inf P dt`` (time per d**dims): the expected
            time the tracer spends per unit volume (area in 2D) around each point.
        P_height: grid-shaped geometrical propagator at the cell-centre heights (mean of
            the two faces), 1/d**(dims-1), as :attr:`TracerResult.P_height` for
            ``t_end -> inf``.
        P_height_faces: ``(nz+1, ...)`` downward flux of ``G`` through the faces
            ``z0 + k h`` (row 0 the orifice plane).
        exit: probabilities of leaving through ``floor`` (orifice), ``sides`` (open
            walls) and ``top``, and ``trapped``: what flows into cells with no way out
            (no velocity, no diffusion; left out of the solve); the four sum to
            ``mass0``.
        mean_exit_time: ``sum(G) h**dims / mass0`` (time units).
        mass0: ``sum(P0) h**dims``.
        residual: relative max-norm residual ``|A G + P0| / max P0`` on the cells solved.
        seconds: wall time of the solve (assembly and factorisation).
        options: numerical options used.
    """

    residence: np.ndarray
    P_height: np.ndarray
    P_height_faces: np.ndarray
    exit: dict
    mean_exit_time: float
    mass0: float
    residual: float = 0.0
    seconds: float = 0.0
    options: dict = field(default_factory=dict)


class _Assembly:
    """The advective matrix for one grid, face velocities and axial diffusion."""

    def __init__(self, grid, faces, axial, scheme):
        self.grid = grid
        self.h = h = grid.spacing
        self.shape = grid.shape
        self.n = int(np.prod(self.shape))
        idx = np.arange(self.n).reshape(self.shape)
        self.axes = []
        for axis, name in enumerate(_AXES[grid.dims]):
            uf = faces[name]
            nax = self.shape[axis]
            sl = lambda a, b, axis=axis: tuple(slice(a, b) if d == axis else slice(None)
                                               for d in range(grid.dims))
            ui = uf[sl(1, nax)]
            A = axial[name]
            # the downstream cell's axial exchange coefficient (D_ii - sum |D_ij|)
            A_down = np.where(ui > 0.0, A[sl(1, nax)], A[sl(0, nax - 1)])
            au = np.abs(ui)
            if scheme == "hybrid":
                theta = np.where(au > 0.0, np.clip(2.0 * A_down / np.where(au > 0, au, 1.0)
                                                   / h, 0.0, 1.0), 1.0)
            else:
                theta = np.zeros_like(ui)
            w_up = 1.0 - 0.5 * theta
            w_L = np.where(ui > 0.0, w_up, 1.0 - w_up)
            self.axes.append(dict(
                name=name, uf=uf, sl=sl, nax=nax, lower=idx[sl(0, nax - 1)].ravel(),
                upper=idx[sl(1, nax)].ravel(), ui=ui.ravel(), wL=w_L.ravel(),
                wR=(1.0 - w_L).ravel(), theta=theta,
                first=idx[sl(0, 1)].ravel(), last=idx[sl(nax - 1, nax)].ravel()))

    def matrix(self):
        """Sparse advective operator ``A_adv`` (``dG/dt = A_adv G``)."""
        ih = 1.0 / self.h
        rows, cols, vals = [], [], []
        diag = np.zeros(self.n)
        for a in self.axes:
            lo, hi = a["lower"], a["upper"]
            cL = a["ui"] * a["wL"] * ih
            cR = a["ui"] * a["wR"] * ih
            # F = u (w_L G_lo + w_R G_hi) leaves `lo`, enters `hi`
            np.add.at(diag, lo, -cL)
            np.add.at(diag, hi, cR)
            rows += [lo, hi]
            cols += [hi, lo]
            vals += [-cR, cL]
            uf = a["uf"]
            # boundary faces: outflow with the boundary cell's value
            np.add.at(diag, a["first"], uf[a["sl"](0, 1)].ravel() * ih)
            np.add.at(diag, a["last"], -uf[a["sl"](a["nax"], a["nax"] + 1)].ravel() * ih)
        rows.append(np.arange(self.n))
        cols.append(np.arange(self.n))
        vals.append(diag)
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                     np.concatenate(cols))),
                             shape=(self.n, self.n))

    def z_fluxes(self, G):
        """Upward advective flux through every z face, ``(nz+1, ...)``."""
        a = self.axes[0]
        g = G.ravel()
        uf = a["uf"]
        F = np.zeros(uf.shape)
        F[1:-1] = (a["ui"] * (a["wL"] * g[a["lower"]] + a["wR"] * g[a["upper"]])
                   ).reshape(F[1:-1].shape)
        F[0] = uf[0] * G[0]
        F[-1] = uf[-1] * G[-1]
        return F

    def exits(self, G):
        """Outflow probabilities through the floor, the sides and the top."""
        hm = self.h ** (self.grid.dims - 1)
        out = {"floor": 0.0, "sides": 0.0, "top": 0.0}
        for axis, a in enumerate(self.axes):
            uf = a["uf"]
            nax = a["nax"]
            lo = float(-(uf[a["sl"](0, 1)] * G[a["sl"](0, 1)]).sum()) * hm
            hi = float((uf[a["sl"](nax, nax + 1)] * G[a["sl"](nax - 1, nax)]).sum()) * hm
            if axis == 0:
                out["floor"] += lo
                out["top"] += hi
            else:
                out["sides"] += lo + hi
        return out


def _reachable(M, seeds):
    """Boolean mask of the nodes reachable from ``seeds`` along ``j -> i`` where
    ``M_ij != 0`` (breadth-first search, :mod:`scipy.sparse.csgraph`)."""
    from scipy.sparse import csgraph
    n = M.shape[0]
    adj = (M != 0).T.tocsr().astype(np.int8)
    # a super node n linked to every seed
    link = sp.csr_matrix((np.ones(len(seeds), dtype=np.int8),
                          (np.full(len(seeds), 0), seeds)), shape=(1, n))
    big = sp.bmat([[adj, None], [link, None]], format="csr")
    big = sp.csr_matrix((big.data, big.indices, big.indptr), shape=(n + 1, n + 1))
    order = csgraph.breadth_first_order(big, n, directed=True, return_predecessors=False)
    keep = np.zeros(n + 1, dtype=bool)
    keep[order] = True
    return keep[:n]


def _krylov(M, b, rtol=1e-12):
    """GMRES preconditioned by an incomplete LU (``spilu``, drop 1e-4, fill 10); returns
    ``(None, reason)`` when it fails, so that the caller falls back to a direct solve."""
    try:
        ilu = spla.spilu(M, drop_tol=1e-4, fill_factor=10)
    except RuntimeError:
        return None, "spilu failed"
    pre = spla.LinearOperator(M.shape, ilu.solve)
    g, info = spla.gmres(M, b, M=pre, rtol=rtol, atol=0.0, restart=100, maxiter=50)
    res = float(np.abs(M @ g - b).sum()) / max(float(np.abs(b).sum()), 1e-300)
    if info != 0 or not np.all(np.isfinite(g)) or res > 1e-11:
        return None, "gmres failed"
    return g, "gmres+spilu"


def solve_steady(grid, f, P0, outlet, *, scheme="hybrid", permc_spec="MMD_AT_PLUS_A",
                 pieces=None):
    """Core of :func:`spotpde.tracer.solve_steady` (inputs already checked).

    ``pieces(f, outlet) -> (faces, axial, L, Bz, n_bad)`` replaces the Cartesian face
    velocities, axial coefficients, diffusion operator and its vertical flux map
    (axisymmetric metric and hopper walls, :mod:`._geometry`).
    """
    t0 = time.perf_counter()
    h = grid.spacing
    hv = grid.cell_volume
    if pieces is None:
        faces = _advection.face_velocities(f, grid.walls, outlet)
        terms, n_bad = _diffusion.split_tensor(f, grid.dims)
        axial = {}
        for name in _AXES[grid.dims]:
            off = tuple(1 if a == name else 0 for a in _AXES[grid.dims])
            axial[name] = next((A for o, A in terms if o == off), np.zeros(grid.shape))
        L = _diffusion.operator(terms, grid.shape, h)
        Bz = _diffusion.vertical_flux_operator(terms, grid.shape, h) if terms else None
    else:
        faces, axial, L, Bz, n_bad = pieces(f, outlet)
    asm = _Assembly(grid, faces, axial, scheme)
    A = asm.matrix() + L
    M_full = (-A).tocsr()
    b_full = np.ascontiguousarray(P0, dtype=float).ravel()
    mass0 = float(b_full.sum()) * hv
    # cells the tracer can reach from the support of P0 (edges j -> i where A_ij != 0);
    # the rest keep G = 0 (and would make the matrix singular where nothing moves)
    keep = _reachable(M_full, np.flatnonzero(b_full > 0))
    # cells with no way out at all (no outward velocity, no diffusion: where the spot
    # density underflows to 0 far beside a point orifice) that the drift points into:
    # a tracer reaching one would stay forever. They are left out and the probability
    # that flows into them is reported as `trapped` (below 1e-10 in the cases measured)
    traps = keep & (M_full.diagonal() <= 0.0)
    keep &= ~traps
    M = M_full[keep][:, keep].tocsc()
    t1 = time.perf_counter()
    b = b_full[keep]
    g, solver = None, f"splu({permc_spec})"
    if grid.dims == 3:
        # 3D: LU fill grows like n**(4/3) (96,000 cells: 36 s with MMD_AT_PLUS_A, 196 s
        # with COLAMD); incomplete LU + GMRES took 6.2 s to a residual of 2e-12
        g, solver = _krylov(M, b)
    if g is None:
        try:
            lu = spla.splu(M, permc_spec=permc_spec)
        except RuntimeError:
            raise NumericalError("tracer (steady): singular steady problem: part of the "
                                 "region the tracer reaches has no way out (closed walls "
                                 "and no outlet?)") from None
        g = lu.solve(b)
        # one step of iterative refinement (the exit probabilities are checked to 1e-10)
        g += lu.solve(b - M @ g)
        solver = f"splu({permc_spec})"
    t2 = time.perf_counter()
    if not np.all(np.isfinite(g)):
        raise NumericalError("tracer (steady): the propagator G is not finite")
    # an M-matrix has a non-negative inverse: negative values are solver round-off
    g_min = float(g.min()) if g.size else 0.0
    g = np.maximum(g, 0.0)
    g_full = np.zeros(asm.n)
    g_full[keep] = g
    G = g_full.reshape(grid.shape)
    residual = float(np.abs((M_full @ g_full - b_full)[keep]).max()) / max(
        float(b_full.max()), 1e-300)
    trapped = float(-(M_full[traps] @ g_full).sum()) * hv if traps.any() else 0.0
    Fz = asm.z_fluxes(G)
    if Bz is not None:
        Fz = Fz + (Bz @ g_full).reshape(Fz.shape)
    down = -Fz
    ex = asm.exits(G)
    ex["trapped"] = trapped
    return SteadyResult(
        residence=G, P_height=0.5 * (down[:-1] + down[1:]), P_height_faces=down, exit=ex,
        mean_exit_time=float(g_full.sum()) * hv / max(mass0, 1e-300), mass0=mass0,
        residual=residual, seconds=time.perf_counter() - t0,
        options={"scheme": scheme, "linear_solver": solver,
                 "cells_solved": int(keep.sum()), "cells_trapped": int(traps.sum()),
                 "n_bad": n_bad, "central_fraction": {a["name"]: float(np.mean(a["theta"] >= 1.0))
                                      for a in asm.axes},
                 "min_before_clip": g_min, "seconds_assembly": t1 - t0,
                 "seconds_solve": t2 - t1})


STEADY_SCHEMES = ("hybrid", "upwind")


def solve_steady_public(grid, fields, P0, *, scheme: str = "hybrid",
                        outlet: np.ndarray | None = None) -> SteadyResult:
    """The geometrical propagator ``G = int_0^inf P dt`` by one sparse solve.

    Solves ``-L G = P0`` (``L`` the tracer's Fokker-Planck operator, the boundaries of
    :func:`spotpde.tracer.solve`) with an M-matrix discretisation (module docstring):
    ``G >= 0``, exit probabilities summing to the initial mass.

    Args:
        grid: the grid (array order ``(z, x)`` / ``(z, y, x)``; axisymmetric ``(z, r)``
            and hoppers as for :func:`spotpde.tracer.solve`: ``residence`` per unit
            volume, ``P_height`` per unit horizontal area, ``mean_exit_time`` with
            ``grid.cell_volumes``).
        fields: dict of steady cell-centred arrays (or scalars) ``u_x``, [``u_y``,]
            ``u_z`` (d per unit time), ``D_xx``, ``D_xz``, ``D_zz`` (3D also ``D_yy``,
            ``D_xy``, ``D_yz``; d**2 per unit time; axisymmetric ``u_r``, ``u_z``,
            ``D_rr``, ``D_rz``, ``D_zz``), as for :func:`spotpde.tracer.solve`.
        P0: grid-shaped initial density, 1/d**dims, >= 0 (not normalised here).
        scheme: advective face value: ``"hybrid"`` (central where the cell Peclet
            number is <= 2, upwind elsewhere; default) or ``"upwind"``.
        outlet: optional boolean floor mask, as for :func:`spotpde.tracer.solve`.

    Returns:
        :class:`SteadyResult`.

    Raises:
        TypeError: ``fields`` is not a dict (time-dependent fields have no steady state).
        ValueError: bad ``P0``, ``scheme``, ``outlet`` or fields (the message names it).
        NumericalError: the region the tracer reaches has no way out.
    """
    from ._operator import _check_fields
    if callable(fields) or not hasattr(fields, "keys"):
        raise TypeError("solve_steady: fields must be a dict of steady arrays (time-"
                        f"dependent fields have no steady propagator), got "
                        f"{type(fields).__name__}")
    if scheme not in STEADY_SCHEMES:
        raise ValueError(f"solve_steady: scheme must be one of {', '.join(STEADY_SCHEMES)}, "
                         f"got {scheme!r}")
    P = np.array(P0, dtype=float)
    if P.shape != grid.shape:
        raise ValueError(f"solve_steady: P0 has shape {P.shape}, the grid {grid.shape}")
    if not np.all(np.isfinite(P)) or np.any(P < 0) or not np.any(P > 0):
        raise ValueError("solve_steady: P0 must be finite, >= 0 and not all zero")
    if outlet is None:
        outlet = np.ones(grid.shape[1:], dtype=bool)
    else:
        outlet = np.asarray(outlet, dtype=bool)
        if outlet.shape != grid.shape[1:]:
            raise ValueError(f"solve_steady: outlet has shape {outlet.shape}, the floor "
                             f"{grid.shape[1:]}")
    if grid.axisymmetric or grid.hopper is not None:   # Q = 2 pi r P on the Cartesian twin
        from . import _geometry
        return _geometry.solve_steady(solve_steady, grid, fields, P, outlet, scheme)
    f = _check_fields(grid, fields, "fields")
    return solve_steady(grid, f, P, outlet, scheme=scheme)
