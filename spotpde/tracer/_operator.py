"""The discrete tracer operator at one time (private; used by :mod:`._solve`, :mod:`._stepping`).

For one snapshot of the coefficient fields (``u_p`` in d per unit time, ``D_p`` in d**2
per unit time, cell centred, array order ``(z, x)`` / ``(z, y, x)``) this module builds
the finite-volume right-hand side of

    dP/dt = -div(u_p P) + sum_ij d_i d_j (D_p^ij P)

* :func:`_check_fields`: the coefficient dict checked (shapes, finite, ``D_p`` positive
  semidefinite);
* :class:`_Operator`: face velocities (:mod:`._advection`), the positive splitting of the
  diffusion tensor (:mod:`._diffusion`) and the per-cell positivity rate ``a`` (1 / unit
  time) that bounds the step, ``dt a <= 1``;
* :class:`_Workspace`: the work arrays of one solve, including ``Fz_acc``, the
  time-integrated upward flux through every horizontal face (1/d**(dims-1));
* :func:`_rhs`: ``dP/dt`` (or one Runge-Kutta stage) and the outflow rates (probability
  per unit time) through the floor, the sides and the top.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import scipy.sparse as sp

from . import _advection, _diffusion
from ._linsolve import factorize
from . import _fp_kernels as K
from ._fp_kernels_3d import rhs_3d_kernel, side_outflow
from ..grid import DIFFUSIVITY_KEYS, DRIFT_KEYS, Grid


def required_fields(dims: int) -> tuple[str, ...]:
    """Names of the coefficient arrays ``solve`` needs in ``dims`` dimensions."""
    return DRIFT_KEYS[dims] + DIFFUSIVITY_KEYS[dims]


# ---------------------------------------------------------------------------------------
# validation


def _check_fields(grid: Grid, fields: Mapping[str, np.ndarray], where: str) -> dict:
    """The coefficient arrays ``grid.drift_keys + grid.diffusivity_keys`` (those of
    :func:`required_fields` on Cartesian grids) as contiguous float64 grid arrays.

    Scalars are broadcast. Raises ``ValueError`` listing every problem, each named
    ``{where}.{key}``: a wrong shape, NaN or infinite values, a negative diagonal ``D_ii``
    or a tensor that is not positive semidefinite (``D_ij**2 > D_ii D_jj``).
    """
    if not isinstance(fields, Mapping):
        raise ValueError(f"{where}: expected a dict of arrays, got {type(fields).__name__}")
    names = grid.drift_keys + grid.diffusivity_keys    # required_fields(dims) if Cartesian
    missing = [n for n in names if n not in fields]
    if missing:
        raise ValueError(f"{where}: missing {', '.join(missing)} (needs {', '.join(names)})")
    out = {}
    problems = []
    for n in names:
        a = np.asarray(fields[n], dtype=float)
        if a.ndim == 0:
            a = np.full(grid.shape, float(a))
        if a.shape != grid.shape:
            problems.append(f"{where}.{n}: shape {a.shape} does not match the grid {grid.shape}")
            continue
        if not np.all(np.isfinite(a)):
            problems.append(f"{where}.{n}: contains NaN or infinite values")
            continue
        out[n] = np.ascontiguousarray(a)
    if not problems:
        diag = [k for k in grid.diffusivity_keys if k[2] == k[3]]
        for n in diag:
            if np.any(out[n] < 0):
                problems.append(f"{where}.{n}: must be >= 0, min {out[n].min():.3g}")
        if not problems:
            pairs = [(f"D_{k[2]}{k[2]}", f"D_{k[3]}{k[3]}", k)
                     for k in grid.diffusivity_keys if k[2] != k[3]]
            for a, b, c in pairs:
                bad = out[c] ** 2 > out[a] * out[b] * (1 + 1e-9) + 1e-300
                if np.any(bad):
                    problems.append(f"{where}.{c}: tensor not positive semidefinite "
                                    f"({c}**2 > {a}*{b}) in {int(bad.sum())} cells")
    if problems:
        raise ValueError("\n".join(problems))
    return out


# ---------------------------------------------------------------------------------------
# the discrete operator at one time


def _shared(arrays: list) -> tuple:
    """``arrays`` with each one equal to an earlier one replaced by that earlier array.

    The 3D kernel reads its coefficient arrays plane by plane; one array passed twice is
    read from memory once (the second read finds the plane in cache). An isotropic
    horizontal tensor (``D_xx = D_yy``, the spot model's) thus saves 8 of the stage's
    88 bytes a cell; the values, hence the results, are the same to the bit.
    """
    out = []
    for a in arrays:
        out.append(next((b for b in out if np.array_equal(a, b)), a))
    return tuple(out)


class _Operator:
    """Face velocities, diffusion splitting and rates for one coefficient snapshot."""

    def __init__(self, grid: Grid, fields: dict, limiter: int, outlet: np.ndarray,
                 implicit: bool, p_scale: float = 1.0):
        self.grid = grid
        # WENO smoothness indicators are O(P**2): scale them by the initial peak
        self.eps = 1.0 / max(p_scale, 1e-150) ** 2
        self.h = grid.spacing
        self.dims = grid.dims
        self.limiter = limiter
        self.implicit = implicit
        self.faces = _advection.face_velocities(fields, grid.walls, outlet)
        self.terms, self.n_bad = _diffusion.split_tensor(fields, grid.dims)
        a_adv = _advection.advective_rate(self.faces, self.h)
        a_diff = _diffusion.self_rate(self.terms, grid.shape, self.h)
        self.rate_adv = float(a_adv.max())
        self.rate_diff = float(a_diff.max())
        self.rate_explicit = float((a_adv + a_diff).max())
        self.rate = self.rate_adv if implicit else self.rate_explicit
        self.umax = max(float(np.abs(fields[f"u_{c}"]).max()) for c in
                        (("x", "z") if grid.dims == 2 else ("x", "y", "z")))
        self.has_cross = len(self.terms) > grid.dims
        shape = grid.shape
        if grid.dims == 2:
            zero = np.zeros(shape)
            coef = {off: A for off, A in self.terms}
            if implicit:
                self.Axx = self.Azz = self.C = zero
                self.k_cross = False
            else:
                self.Axx = np.ascontiguousarray(coef[(0, 1)])
                self.Azz = np.ascontiguousarray(coef[(1, 0)])
                # signed D_xz: the kernel forms the exchange coefficients max(+-D_xz, 0)
                self.C = np.ascontiguousarray(coef.get((1, 1), zero) - coef.get((1, -1), zero))
                self.k_cross = self.has_cross
        else:
            # the fused kernel's axial coefficients (None when diffusion is implicit: the
            # kernel then reads the workspace's zeros); diagonal exchanges, if any, as a
            # sparse matrix of those only
            coef = {off: A for off, A in self.terms if sum(map(abs, off)) == 1}
            self.axial = None if implicit else _shared(
                [np.ascontiguousarray(coef[off]) for off in ((0, 0, 1), (0, 1, 0), (1, 0, 0))])
            cross = [(off, A) for off, A in self.terms if sum(map(abs, off)) > 1]
            self.cross = None
            if cross and not implicit:
                self.cross = (_diffusion.operator(cross, shape, self.h),
                              _diffusion.vertical_flux_operator(cross, shape, self.h))
        self._L = None
        self._Bz = None
        self._lu = {}

    # sparse pieces, built on demand
    @property
    def L(self):
        if self._L is None:
            self._L = _diffusion.operator(self.terms, self.grid.shape, self.h)
        return self._L

    @property
    def Bz(self):
        if self._Bz is None:
            self._Bz = _diffusion.vertical_flux_operator(self.terms, self.grid.shape, self.h)
        return self._Bz

    def implicit_parts(self):
        """``(axial, L, Bz, n_bad)`` of the long-run steppers' implicit operator
        (:func:`._implicit.build_operator`): the axial exchange coefficient of each axis
        (d**2 per unit time, keyed ``"z"``, [``"y"``,] ``"x"``: the hybrid weights), the
        diffusion matrix :attr:`L`, its vertical flux map :attr:`Bz` (``None`` without
        diffusion) and the count of cells whose tensor is not diagonally dominant. The
        geometry operator (:class:`._geometry._GeometryOperator`) gives its own."""
        names = ("z", "x") if self.dims == 2 else ("z", "y", "x")
        axial = {}
        for name in names:
            off = tuple(1 if a == name else 0 for a in names)
            axial[name] = next((A for o, A in self.terms if o == off),
                               np.zeros(self.grid.shape))
        return axial, self.L, (self.Bz if self.terms else None), self.n_bad

    def backward_euler(self, P: np.ndarray, tau: float):
        """Solve ``(I - tau L) P_new = P``; returns ``P_new`` and its upward face flux."""
        lu = self._lu.get(tau)
        if lu is None:
            n = P.size
            M = (sp.identity(n, format="csc") - tau * self.L).tocsc()
            lu = factorize(M)
            self._lu = {tau: lu}
        Pn = lu.solve(P.ravel()).reshape(P.shape)
        Fz = (self.Bz @ Pn.ravel()).reshape((P.shape[0] + 1,) + P.shape[1:])
        return Pn, Fz


class _Workspace:
    """Work arrays of one solve: ``R`` (dP/dt, 1/(d**dims time)), the Runge-Kutta stages,
    the face fluxes and their time integral ``Fz_acc`` (``nz + 1`` horizontal faces)."""

    def __init__(self, grid: Grid, p_scale: float = 1.0):
        shape = grid.shape
        self.tiny = 1e-100 * p_scale
        self.R = np.empty(shape)
        fshape = (shape[0] + 1,) + shape[1:]
        self.Fz_acc = np.zeros(fshape)
        self.Fz_edge = np.empty((2,) + shape[1:])     # floor and top face fluxes
        self.stage = [np.empty(shape), np.empty(shape)]
        self._zero = None

    def zeros(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Zero axial coefficients of this shape for the 3D kernel (advection only),
        one array made on first use."""
        if self._zero is None:
            self._zero = np.zeros(self.R.shape)
        return self._zero, self._zero, self._zero


def _rhs(op: _Operator, P: np.ndarray, ws: _Workspace, w_acc: float,
         stage: tuple | None = None) -> tuple[float, float, float]:
    """Fill ``ws.R = dP/dt``, accumulate ``w_acc * Fz`` (an operator with its own ``rhs``,
    :class:`._geometry._GeometryOperator`, does it itself).

    With ``stage = (a, P0, dt, out)`` write the Runge-Kutta stage
    ``out = a P0 + (1 - a) (P + dt R)`` instead (values below ``ws.tiny`` set to 0); in 2D
    the kernel does this in the same pass and ``ws.R`` is not written.

    Returns:
        Outflow rates (probability per unit time) through the floor, the sides, the top.
    """
    if hasattr(op, "rhs"):
        return op.rhs(P, ws, w_acc, stage)
    h = op.h
    f = op.faces
    if op.dims == 2:
        if stage is None:
            out, P0, ca, cb, cc, tiny = ws.R, P, 0.0, 0.0, 1.0, 0.0
        else:
            a, P0, dt, out = stage
            ca, cb, cc, tiny = a, 1.0 - a, (1.0 - a) * dt, ws.tiny
        K.rhs_2d_kernel(op.limiter)(P, f["x"], f["z"], op.Axx, op.Azz, op.C, op.k_cross,
                                    op.eps, h, out, ws.Fz_edge, ws.Fz_acc, w_acc,
                                    P0, ca, cb, cc, tiny)
        side = np.dot(f["x"][:, -1], P[:, -1]) - np.dot(f["x"][:, 0], P[:, 0])
        floor = -ws.Fz_edge[0].sum()
        top = ws.Fz_edge[1].sum()
        hm = h
    else:
        cross = op.cross if op.terms else None
        fused = stage is not None and cross is None
        if fused:       # the kernel writes the stage itself
            a, P0, dt, out = stage
            ca, cb, cc, tiny = a, 1.0 - a, (1.0 - a) * dt, ws.tiny
        else:
            out, P0, ca, cb, cc, tiny = ws.R, P, 0.0, 0.0, 1.0, 0.0
        # no diffusion (implicit, or an operator restricted to advection: op.terms empty)
        Axx, Ayy, Azz = op.axial if op.axial is not None and op.terms else ws.zeros()
        rhs_3d_kernel(op.limiter)(P, f["x"], f["y"], f["z"], Axx, Ayy, Azz, op.eps, h, out,
                                  ws.Fz_edge, ws.Fz_acc, w_acc, P0, ca, cb, cc, tiny)
        if cross is not None:
            L, Bz = cross
            ws.R += (L @ P.ravel()).reshape(P.shape)
            ws.Fz_acc += w_acc * (Bz @ P.ravel()).reshape(ws.Fz_acc.shape)
        side = side_outflow(f["x"], f["y"], P)
        floor = -ws.Fz_edge[0].sum()
        top = ws.Fz_edge[1].sum()
        hm = h * h
        if stage is not None and not fused:
            a, P0, dt, out = stage
            K.combine(a, P0.ravel(), 1.0 - a, P.ravel(), (1.0 - a) * dt, ws.R.ravel(),
                      out.ravel(), ws.tiny)
    return hm * floor, hm * side, hm * top
