"""The geometrical propagator as a steady state (``tracer.t_end = inf``).

``G(r) = int_0^inf P(r, t) dt`` (the expected time spent per unit volume, area in 2D;
units time / d**dims) solves the steady tracer equation

    -L G = P0,     L P = -div(u_p P) + sum_ij d_i d_j (D_p^ij P)

with the boundary conditions of :func:`spotpde.tracer.solve` (outflow through the
orifice, open sides and the top; walls elsewhere; no diffusive flux through any
boundary). Its vertical face fluxes are ``P_height`` (the time integral of the downward
probability flux), its boundary fluxes the exit probabilities, and ``sum(G) h**dims``
the mean exit time (for a normalised ``P0``). Derivations and measurements:
docs/steady.md.

Default (``scheme`` a reconstruction of :func:`spotpde.tracer.solve`, WENO5): the
steady state of the time-stepped scheme itself, by Picard iteration on frozen face
ratios started from the hybrid solution (:mod:`._steady_limited`); this module sets up
the faces, the diffusion operator and the reachable cells and computes the outputs.

The linear schemes (``scheme="hybrid"``, ``"upwind"``, one solve): the finite volumes of
the tracer with the same diffusion operator (the positive 9-point splitting of the
tensor, :mod:`spotpde.tracer._diffusion`) and the same boundary faces; the interior
advective face value is the hybrid (Spalding 1972) blend

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

import functools
import time
import warnings
from dataclasses import dataclass, field

import numba
import numpy as np
import scipy.sparse as sp
from scipy.sparse import csgraph

from . import _advection, _diffusion, _geometry, _steady_limited
from ._operator import _check_fields, _Operator
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

    def set_ratios(self, ratios):
        """Make every interior face flux ``u_f r_f G_up`` (the frozen limited scheme of
        :mod:`._steady_limited`): ``ratios`` holds ``r_f`` per axis, shaped as the
        interior faces."""
        for a, r in zip(self.axes, ratios):
            lower = a["ui"] > 0.0
            r = np.ravel(r)
            a["wL"] = np.where(lower, r, 0.0)
            a["wR"] = np.where(lower, 0.0, r)

    def matrix(self):
        """Sparse advective operator ``A_adv`` (``dG/dt = A_adv G``)."""
        ih = 1.0 / self.h
        n = self.n
        rows, cols, vals = [], [], []
        diag = np.zeros(n)
        for a in self.axes:
            lo, hi = a["lower"], a["upper"]
            cL = a["ui"] * a["wL"] * ih
            cR = a["ui"] * a["wR"] * ih
            # F = u (w_L G_lo + w_R G_hi) leaves `lo`, enters `hi`
            diag += np.bincount(hi, cR, n) - np.bincount(lo, cL, n)
            rows += [lo, hi]
            cols += [hi, lo]
            vals += [-cR, cL]
            uf = a["uf"]
            # boundary faces: outflow with the boundary cell's value
            diag += (np.bincount(a["first"], uf[a["sl"](0, 1)].ravel() * ih, n)
                     - np.bincount(a["last"], uf[a["sl"](a["nax"], a["nax"] + 1)].ravel() * ih, n))
        rows.append(np.arange(n))
        cols.append(np.arange(n))
        vals.append(diag)
        return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows),
                                                     np.concatenate(cols))),
                             shape=(n, n))

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


def _cartesian_pieces(grid, f, outlet):
    """Face velocities, axial exchange coefficients, diffusion operator, its vertical flux
    map and the count of non-dominant cells of a Cartesian box."""
    h = grid.spacing
    faces = _advection.face_velocities(f, grid.walls, outlet)
    terms, n_bad = _diffusion.split_tensor(f, grid.dims)
    axial = {}
    for name in _AXES[grid.dims]:
        off = tuple(1 if a == name else 0 for a in _AXES[grid.dims])
        axial[name] = next((A for o, A in terms if o == off), np.zeros(grid.shape))
    L = _diffusion.operator(terms, grid.shape, h)
    Bz = _diffusion.vertical_flux_operator(terms, grid.shape, h) if terms else None
    return faces, axial, L, Bz, n_bad


def _singular():
    return NumericalError("tracer (steady): singular steady problem: part of the region "
                          "the tracer reaches has no way out (closed walls and no outlet?)")


def solve_steady(grid, f, P0, outlet, *, scheme="weno5", permc_spec="MMD_AT_PLUS_A",
                 pieces=None, make_op=_Operator, tol=_steady_limited.TOL,
                 max_iter=_steady_limited.MAX_ITER):
    """Core of :func:`spotpde.tracer.solve_steady` (inputs already checked).

    ``pieces(f, outlet) -> (faces, axial, L, Bz, n_bad)`` replaces the Cartesian face
    velocities, axial coefficients, diffusion operator and its vertical flux map
    (axisymmetric metric and hopper walls, :mod:`._geometry`), ``make_op`` the
    time-stepped operator whose right-hand side a limited scheme's steady state solves
    (the signature of :class:`._operator._Operator`).
    """
    t0 = time.perf_counter()
    hv = grid.cell_volume
    faces, axial, L, Bz, n_bad = (pieces or functools.partial(_cartesian_pieces, grid))(
        f, outlet)
    limited = scheme not in LINEAR_SCHEMES
    asm = _Assembly(grid, faces, axial, "hybrid" if limited else scheme)
    M_full = (-(asm.matrix() + L)).tocsr()
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
    solver = _steady_limited.LinearSolver(grid.dims, permc_spec)
    try:
        g = solver.solve(M, b_full[keep])
    except RuntimeError:
        raise _singular() from None
    if not np.all(np.isfinite(g)):
        raise NumericalError("tracer (steady): the propagator G is not finite")
    # an M-matrix has a non-negative inverse: negative values are solver round-off
    g_min = float(g.min()) if g.size else 0.0
    g_full = np.zeros(asm.n)
    g_full[keep] = np.maximum(g, 0.0)
    G = g_full.reshape(grid.shape)

    def outputs(G):
        Fz = asm.z_fluxes(G)
        if Bz is not None:
            Fz = Fz + (Bz @ G.ravel()).reshape(Fz.shape)
        return -Fz, asm.exits(G)

    info = {}
    if limited:
        try:
            G, info = _steady_limited.picard(
                grid, f, outlet, _advection.LIMITERS[scheme].code, asm, L, keep, b_full, G,
                solver, outputs, make_op=make_op, tol=tol, max_iter=max_iter)
        except RuntimeError:
            raise _singular() from None
        g_min = info.pop("min_before_clip")
        M_full = (-(asm.matrix() + L)).tocsr()     # the last iterate's frozen scheme
        residual = info.pop("residual_max")
    t2 = time.perf_counter()
    g_full = G.ravel()
    if not limited:
        residual = float(np.abs((M_full @ g_full - b_full)[keep]).max()) / max(
            float(b_full.max()), 1e-300)
    trapped = float(-(M_full[traps] @ g_full).sum()) * hv if traps.any() else 0.0
    down, ex = outputs(G)
    ex["trapped"] = trapped
    options = {"scheme": scheme, "linear_solver": solver.name,
               "factorisations": solver.factorisations,
               "cells_solved": int(keep.sum()), "cells_trapped": int(traps.sum()),
               "n_bad": n_bad, "min_before_clip": g_min, "seconds_assembly": t1 - t0,
               "seconds_solve": t2 - t1, **info}
    if not limited:
        options["central_fraction"] = {a["name"]: float(np.mean(a["theta"] >= 1.0))
                                       for a in asm.axes}
    return SteadyResult(
        residence=G, P_height=0.5 * (down[:-1] + down[1:]), P_height_faces=down, exit=ex,
        mean_exit_time=float(g_full.sum()) * hv / max(mass0, 1e-300), mass0=mass0,
        residual=residual, seconds=time.perf_counter() - t0, options=options)


#: the linear M-matrix schemes (one solve); every other name is a time-stepped
#: reconstruction (:data:`._advection.LIMITERS`) solved by :mod:`._steady_limited`
LINEAR_SCHEMES = ("hybrid", "upwind")
STEADY_SCHEMES = tuple(k for k in _advection.LIMITERS if k not in LINEAR_SCHEMES) + LINEAR_SCHEMES


def solve_steady_public(grid, fields, P0, *, scheme: str = "weno5",
                        outlet: np.ndarray | None = None, tol: float = _steady_limited.TOL,
                        max_iter: int = _steady_limited.MAX_ITER,
                        threads: int | None = None) -> SteadyResult:
    """The geometrical propagator ``G = int_0^inf P dt`` of the time-stepped scheme.

    Solves ``R(G) + P0 = 0``, ``R`` the right-hand side of :func:`spotpde.tracer.solve`
    with the same reconstruction, diffusion splitting and boundaries (docs/steady.md):
    by Picard iteration on the frozen face ratios for a limited reconstruction
    (:mod:`._steady_limited`), by one sparse solve for the linear schemes. Every result
    has ``G >= 0`` and exit probabilities summing to the initial mass.

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
        scheme: advective face value: a reconstruction of :func:`spotpde.tracer.solve`
            (``"weno5"``, the default and the time-stepped default, ``"koren"``,
            ``"vanleer"``, ``"mc"``, ``"minmod"``; ``"upwind"`` is linear), or
            ``"hybrid"`` (central where the cell Peclet number is <= 2, upwind
            elsewhere: one solve, first order along an advection-dominated flow).
        outlet: optional boolean floor mask, as for :func:`spotpde.tracer.solve`.
        tol: limited schemes: the iteration stops when ``P_height`` changes by less than
            ``tol`` of its maximum (plus the change of the exit probabilities); in (0, 1).
        max_iter: limited schemes: iterations at most (>= 1); a run that stops there
            warns (``RuntimeWarning``) and reports ``options["converged"] = False``.
        threads: numba threads of the residual kernel; default 1 below 65536 cells,
            numba's default above (as :func:`spotpde.tracer.solve`).

    Returns:
        :class:`SteadyResult`.

    Raises:
        TypeError: ``fields`` is not a dict (time-dependent fields have no steady state).
        ValueError: bad ``P0``, ``scheme``, ``outlet``, ``tol``, ``max_iter`` or fields
            (the message names it).
        NumericalError: the region the tracer reaches has no way out.
    """
    if callable(fields) or not hasattr(fields, "keys"):
        raise TypeError("fields: must be a dict of steady arrays (time-dependent fields "
                        f"have no steady propagator), got {type(fields).__name__}")
    if scheme not in STEADY_SCHEMES:
        raise ValueError(f"scheme: must be one of {', '.join(STEADY_SCHEMES)}, got {scheme!r}")
    if not (isinstance(tol, (int, float)) and 0 < tol < 1):
        raise ValueError(f"tol: must be a number in (0, 1), got {tol!r}")
    if not (isinstance(max_iter, (int, np.integer)) and max_iter >= 1):
        raise ValueError(f"max_iter: must be an integer >= 1, got {max_iter!r}")
    P = np.array(P0, dtype=float)
    if P.shape != grid.shape:
        raise ValueError(f"P0: shape {P.shape} does not match the grid {grid.shape}")
    if not np.all(np.isfinite(P)) or np.any(P < 0) or not np.any(P > 0):
        raise ValueError("P0: must be finite, >= 0 and not all zero")
    if outlet is None:
        outlet = np.ones(grid.shape[1:], dtype=bool)
    else:
        outlet = np.asarray(outlet, dtype=bool)
        if outlet.shape != grid.shape[1:]:
            raise ValueError(f"outlet: shape {outlet.shape} does not match the floor "
                             f"{grid.shape[1:]}")
    if threads is None:
        threads = 1 if grid.size < 65536 else numba.config.NUMBA_NUM_THREADS
    saved = numba.get_num_threads()
    numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
    try:
        if _geometry.special(grid):      # Q = 2 pi r P on the Cartesian twin
            res = _geometry.solve_steady(solve_steady, grid, fields, P, outlet, scheme,
                                         tol=tol, max_iter=max_iter)
        else:
            res = solve_steady(grid, _check_fields(grid, fields, "fields"), P, outlet,
                               scheme=scheme, tol=tol, max_iter=max_iter)
    finally:
        numba.set_num_threads(saved)
    if res.options.get("converged") is False:
        warnings.warn(f"tracer (steady): the {scheme} iteration stopped after {max_iter} "
                      f"iterations with P_height still changing by "
                      f"{res.options['change']:.2g} (tol {tol:g})", RuntimeWarning,
                      stacklevel=2)
    return res
