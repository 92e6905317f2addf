"""Implicit and IMEX time stepping of the tracer equation for long runs (private).

For steady coefficient fields the explicit solver's step is capped by the fastest cell
(next to a point orifice: ``dt ~ 0.05`` for the void propagator at ``h = d/4``) while the
slow flow far up sets ``t_end`` (``4e5``: 7.3e6 steps). Two ways out, both on the
linear hybrid central/upwind finite-volume operator ``A`` of :mod:`._steady` (same
boundaries, the positive diffusion splitting; ``-A`` has a positive diagonal,
non-positive off-diagonals and column sums equal to the boundary outflow rates, so
``I - tau A`` is an M-matrix and ``(I - tau A)^-1 >= 0`` for every ``tau > 0``):

* ``stepping="imex"`` (:class:`IMEXStrang`, :func:`imex_result`): the few cells whose
  explicit positivity rate exceeds ``max(a) / split`` (next to the orifice) are
  stepped implicitly with ``A`` restricted to their faces, together with all of the
  diffusion; everything else keeps the explicit limited high-order advection
  (WENO5, SSP-RK3) at ``split`` times today's step. Same accuracy as the explicit run
  where the tracer spends its time (docs/tracer.md).
* ``stepping="implicit"`` (:class:`TRBDF2`, :func:`result`): ``dP/dt = A P`` everywhere
  by adaptive TR-BDF2, step sizes ``interval / 2**k`` chosen by an embedded error
  estimate, one SuperLU factorisation per step size. First order along the flow where
  the cell Peclet number exceeds 2 (the hybrid scheme is upwind there).

Both are exactly conservative (every stage is a difference of face fluxes; the running
integral ``S = int P dt`` of the implicit parts gives their outflow and ``P_height``, so
``mass + outflow = mass0`` to round-off) and positive (the M-matrix; the second-order
corrections are limited, or the step redone by backward Euler).

On axisymmetric and hopper grids (:mod:`._geometry`) the same code steps ``Q = 2 pi r P``
on the Cartesian twin: the face velocities and the diffusion (exchange matrix, flux map,
axial coefficients) are taken from the explicit scheme's operator of the geometry
(``op.implicit_parts()``), never assembled for a box.
"""

from __future__ import annotations

import math
import time

import numpy as np
import scipy.sparse as sp

from . import _advection, _diffusion
from ._extrapolation import Extrapolation
from ._linsolve import factorize
from ._steady import _AXES, _Assembly
from ._multirate import FastBox
from ._stepping import _FixedStepper, _rk_step
from ..errors import NumericalError


class TRBDF2:
    """TR-BDF2, an L-stable, stiffly accurate ESDIRK method of order 2 with an embedded
    order-3 companion for the local error estimate.

    With ``gamma = 2 - sqrt 2``, ``d = gamma / 2``, ``w = sqrt 2 / 4``, the stages of
    ``dP/dt = A P`` are ``Y1 = P_n``,

        (I - d dt A) Y2 = Y1 + d dt A Y1                  (trapezoidal rule to t + gamma dt)
        (I - d dt A) Y3 = Y1 + w dt A (Y1 + Y2),          P_{n+1} = Y3   (BDF2 to t + dt)

    i.e. Butcher weights ``b = (w, w, d)``, ``c = (0, gamma, 1)``; the companion weights
    ``b_hat = ((1 - w)/3, (3 w + 1)/3, d/3)`` give the error estimate
    ``e = (I - d dt A)^-1 dt A sum_i (b_i - b_hat_i) Y_i`` (filtered as Shampine's, so it
    stays bounded on stiff components). Local error ``O(dt**3)``.
    """

    name = "trbdf2"
    order = 2
    stages = 3
    gamma = 2.0 - math.sqrt(2.0)
    d = 1.0 - 1.0 / math.sqrt(2.0)
    w = math.sqrt(2.0) / 4.0
    b = (w, w, d)
    c = (0.0, gamma, 1.0)
    b_hat = ((1.0 - w) / 3.0, (3.0 * w + 1.0) / 3.0, d / 3.0)
    l_stable = True
    unconditionally_positive = False    # safeguarded by a backward-Euler redo
    reference = ("Bank et al. 1985, IEEE Trans. CAD 4, 436; Hosea & Shampine 1996, "
                 "Appl. Numer. Math. 20, 21")


class IMEXStrang:
    """IMEX splitting for ``stepping="imex"``: explicit SSP-RK (the limited high-order
    advection of the slow cells) between implicit steps of ``A_I`` (hybrid advection
    through the faces of the fast cells plus all of the diffusion), Strang-ordered with
    the halves of neighbouring steps merged,

        P(t + n dt) = I(dt/2) [E(dt) I(dt)]^(n-1) E(dt) I(dt/2) P(t),

    ``I(tau)`` the extrapolated backward Euler ``2 BE(tau/2)^2 - BE(tau)`` whose
    correction is limited cell by cell to keep ``P >= 0`` (:mod:`._extrapolation`).
    Explicit part positive for ``dt max(a_explicit) <= 1``; implicit part for every dt.
    """

    name = "imex"
    order = 2                            # where the limiter is inactive
    positive = True
    conservative = True
    reference = ("Strang 1968, SIAM J. Numer. Anal. 5, 506 (splitting); Richardson "
                 "extrapolation of backward Euler (Hairer & Wanner 1996, IV.9); limiter: "
                 "ours, after Zalesak 1979, J. Comput. Phys. 31, 335")


def build_operator(grid, f, faces, scheme="hybrid", parts=None):
    """The linear operator ``A`` (CSC, 1/time) of the hybrid advection through ``faces``
    (face velocities, :func:`spotpde.tracer._advection.face_velocities`, possibly with
    some set to 0) plus the whole diffusion of the fields ``f`` (checked), its assembly
    (face fluxes, exits) and the diffusive z-face flux map ``Bz`` (or ``None``).

    ``parts``: ``(axial, L, Bz, n_bad)`` of the explicit scheme's operator
    (``op.implicit_parts()``: on axisymmetric and hopper grids the exchanges of ``Q`` with
    the metric and the walls, :mod:`._geometry`); ``f`` is then unused. Default: the
    Cartesian box's, from ``f``."""
    if parts is None:
        terms, n_bad = _diffusion.split_tensor(f, grid.dims)
        axial = {}
        for name in _AXES[grid.dims]:
            off = tuple(1 if a == name else 0 for a in _AXES[grid.dims])
            axial[name] = next((A for o, A in terms if o == off), np.zeros(grid.shape))
        L = _diffusion.operator(terms, grid.shape, grid.spacing)
        Bz = _diffusion.vertical_flux_operator(terms, grid.shape, grid.spacing) \
            if terms else None
    else:
        axial, L, Bz, n_bad = parts
    asm = _Assembly(grid, faces, axial, scheme)
    A = (asm.matrix() + L).tocsc()
    return A, asm, Bz, n_bad


class _Factors:
    """Factors of ``I - tau A`` (:func:`._linsolve.factorize`: Thomas when tridiagonal,
    else SuperLU), one per ``tau``; the last ``KEEP`` are kept (the step sizes move along
    a short ladder; a SuperLU factor of the void case is ~30 MB)."""

    KEEP = 4

    def __init__(self, A):
        self.A = A
        self.I = sp.identity(A.shape[0], format="csc")
        self.lu = {}
        self.count = 0
        self.seconds = 0.0

    def solve(self, tau, rhs):
        return self.factor(tau).solve(rhs)

    def factor(self, tau):
        """The factors of ``I - tau A`` (made on first use)."""
        lu = self.lu.get(tau)
        if lu is None:
            t0 = time.perf_counter()
            lu = factorize((self.I - tau * self.A).tocsc(), permc_spec="MMD_AT_PLUS_A")
            self.seconds += time.perf_counter() - t0
            self.count += 1
            if len(self.lu) >= self.KEEP:
                self.lu.pop(next(iter(self.lu)))
            self.lu[tau] = lu
        return lu


class ImplicitStepper:
    """Adaptive TR-BDF2 on the M-matrix operator (module docstring).

    Args:
        A: sparse operator (``dP/dt = A P``), CSC.
        interval: frame interval (time).
        tol: accepted local error per step: L1 norm of the estimate relative to the
            initial mass.
        dt0: first step tried (time), rounded down to ``interval / 2**k``.
        hv: cell volume (d**dims).
        mass0: initial probability.
        p_max: ``max(P0)`` (for the positivity threshold).
    """

    KMAX = 50

    def __init__(self, A, interval, tol, dt0, hv, mass0, p_max):
        self.A = A
        self.fac = _Factors(A)
        self.interval = interval
        self.tol = tol
        self.hv = hv
        self.mass0 = max(mass0, 1e-300)
        self.neg = 1e-13 * max(p_max, 1e-300)
        self.k = min(self.KMAX, max(0, math.ceil(math.log2(interval / dt0))))
        self.S = np.zeros(A.shape[0])       # int_0^t P dt
        self.steps = 0
        self.rejected = 0
        self.fallback = 0
        self.max_dt = 0.0
        self.min_dt = math.inf

    def _step(self, P, AP, dt):
        s = TRBDF2
        Y2 = self.fac.solve(s.d * dt, P + s.d * dt * AP)
        AY2 = self.A @ Y2
        Y3 = self.fac.solve(s.d * dt, P + s.w * dt * (AP + AY2))
        AY3 = self.A @ Y3
        db = [bi - bh for bi, bh in zip(s.b, s.b_hat)]
        e = self.fac.solve(s.d * dt, dt * (db[0] * AP + db[1] * AY2 + db[2] * AY3))
        err = float(np.abs(e).sum()) * self.hv / self.mass0
        return Y3, AY3, dt * (s.w * (P + Y2) + s.d * Y3), err

    def advance_to(self, P, tick):
        """Advance ``P`` (flat) by one frame interval; returns the new ``P``."""
        KMAX = self.KMAX
        unit = 2 ** KMAX                     # the interval in units of interval / 2**KMAX
        pos = 0
        AP = self.A @ P
        while pos < unit:
            k = self.k
            dt = self.interval / 2 ** k
            Pn, APn, dS, err = self._step(P, AP, dt)
            if err > self.tol and k < KMAX:
                self.rejected += 1
                shrink = max(1, math.ceil(math.log2((err / self.tol) ** (1.0 / 3.0) / 0.9)))
                self.k = min(KMAX, k + shrink)
                continue
            if Pn.min() < -self.neg:
                # TR-BDF2 is not unconditionally positive: backward Euler, same dt
                self.fallback += 1
                Pn = self.fac.solve(dt, P)
                APn = self.A @ Pn
                dS = dt * Pn
            if not np.all(np.isfinite(Pn)):
                raise NumericalError(f"tracer (implicit): P became NaN after {self.steps} steps")
            P, AP = Pn, APn
            self.S += dS
            pos += 2 ** (KMAX - k)
            self.steps += 1
            self.max_dt = max(self.max_dt, dt)
            self.min_dt = min(self.min_dt, dt)
            tick(self.steps)
            # next step: grow by powers of 2 the error allows, aligned with the position
            grow = (0.9 * (self.tol / max(err, 1e-300)) ** (1.0 / 3.0))
            up = int(math.floor(math.log2(grow))) if grow >= 2.0 else 0
            up = min(up, 2)
            knew = k - up
            while knew < k and (knew < 0 or pos % 2 ** (KMAX - knew)):
                knew += 1
            self.k = knew
        # start the next interval with the same dt
        return P


def run(grid, op, P, interval, frames, tracker, *, tol, dt0):
    """Step ``P`` through the frames with :class:`ImplicitStepper`; the frames go to
    ``tracker`` (:class:`spotpde.tracer._stepping._FrameTracker`). ``op``: the explicit
    scheme's operator (:class:`spotpde.tracer._operator._Operator` or the geometry's),
    whose face velocities and :meth:`implicit_parts` make ``A``.

    Returns:
        ``(stepper, P_height_faces, budget, info)``: the stepper (statistics), the
        time-integrated downward z-face flux ``(nz+1, ...)``, the outflow through floor,
        sides, top, and a dict of options for the result.
    """
    t0 = time.perf_counter()
    A, asm, Bz, n_bad = build_operator(grid, None, op.faces, parts=op.implicit_parts())
    hv = grid.cell_volume
    shape = grid.shape
    stepper = ImplicitStepper(A, interval, tol, dt0, hv, tracker.mass0, float(P.max()))
    p = P.ravel().copy()

    def exits():
        ex = asm.exits(stepper.S.reshape(shape))
        return [ex["floor"], ex["sides"], ex["top"]]

    for j in range(1, frames):
        p = stepper.advance_to(p, lambda n: tracker.tick(n, tracker.times[j - 1]))
        budget = exits()
        tracker.record(j, float(tracker.times[j]), p.reshape(shape), budget, 0.0)
    S = stepper.S.reshape(shape)
    Fz = asm.z_fluxes(S)
    if Bz is not None:
        Fz = Fz + (Bz @ stepper.S).reshape(Fz.shape)
    info = {"time_scheme": TRBDF2.name, "stepping": "implicit", "limiter": "hybrid",
            "diffusion": "implicit", "tol": tol, "rejected_steps": stepper.rejected,
            "fallback_steps": stepper.fallback, "factorisations": stepper.fac.count,
            "seconds_factorisation": stepper.fac.seconds, "dt_min": stepper.min_dt,
            "dt_max": stepper.max_dt, "n_bad": n_bad,
            "seconds": time.perf_counter() - t0}
    return stepper, -Fz, exits(), info


def result(result_cls, grid, op, P, interval, frames, tracker, *, tol, dt0):
    """:func:`run` packed as a :class:`spotpde.tracer.TracerResult` (``result_cls``);
    the explicit positivity rate and the largest speed of ``op`` give
    ``max_cfl = max(dt) rate`` and ``max_courant``, here well above 1."""
    rate, umax = op.rate_explicit, op.umax
    stepper, faces, budget, info = run(grid, op, P, interval, frames, tracker,
                                       tol=tol, dt0=dt0)
    return tracker.result(result_cls, faces, budget, steps=stepper.steps,
                          max_cfl=stepper.max_dt * rate,
                          max_courant=stepper.max_dt * umax / grid.spacing, options=info)


# ---------------------------------------------------------------------------------------
# IMEX: explicit WENO5 / SSP-RK3 on the slow cells, implicit on the fast ones


def split_faces(faces, fast):
    """Split the face velocities into the explicit ones (faces of two slow cells) and the
    implicit ones (faces touching a cell of ``fast``, boundary faces of fast cells)."""
    explicit, implicit = {}, {}
    names = ["z", "y", "x"] if len(faces) == 3 else ["z", "x"]
    for axis, name in enumerate(names):
        f = faces[name]
        n = f.shape[axis] - 1
        pad = [(0, 0)] * f.ndim
        pad[axis] = (1, 1)
        fp = np.pad(fast, pad, constant_values=False)   # ghost cells are slow
        sl = lambda a, b: tuple(slice(a, b) if d == axis else slice(None) for d in range(f.ndim))
        touch = fp[sl(0, n + 1)] | fp[sl(1, n + 2)]
        explicit[name] = np.ascontiguousarray(np.where(touch, 0.0, f))
        implicit[name] = np.where(touch, f, 0.0)
    return explicit, implicit


class ImexSplit:
    """The implicit half of the IMEX step: ``A_I`` = hybrid advection through the faces
    of the fast cells plus the whole diffusion operator; backward Euler
    ``(I - tau A_I) P_new = P`` (an M-matrix: positive for every ``tau``), its time
    integral ``S`` kept for the fluxes (``P_height``, outflow)."""

    def __init__(self, grid, f, faces_implicit, extrapolate=True, eps=0.0, parts=None):
        self.extrapolate = extrapolate
        self.eps = eps
        self.tiny = 1e-85 * eps              # 1e-100 max(P0), as in the explicit kernels
        self.theta_min = 1.0
        self.A, self.asm, self.Bz, self.n_bad = build_operator(grid, f, faces_implicit,
                                                               parts=parts)
        self.fac = _Factors(self.A)
        self.S = np.zeros(self.A.shape[0])
        self.shape = grid.shape
        self.extrapolation = Extrapolation(self.A, grid.shape[-1])

    def backward_euler(self, P, tau):
        p = P.ravel()
        if not self.extrapolate:
            Pn = self.fac.solve(tau, p)
            self.S += tau * Pn
            return np.ascontiguousarray(Pn.reshape(self.shape))
        Pn, theta_min = self.extrapolation(self.fac.factor(tau), self.fac.factor(0.5 * tau),
                                           p, tau, self.eps, self.S, self.tiny)
        self.theta_min = min(self.theta_min, theta_min)
        return Pn.reshape(self.shape)

    def exits(self):
        ex = self.asm.exits(self.S.reshape(self.shape))
        return [ex["floor"], ex["sides"], ex["top"]]

    def z_fluxes(self):
        """Time-integrated upward flux through the z faces, ``(nz+1, ...)``."""
        S = self.S.reshape(self.shape)
        Fz = self.asm.z_fluxes(S)
        if self.Bz is not None:
            Fz = Fz + (self.Bz @ self.S).reshape(Fz.shape)
        return Fz


def partition(faces, h, split):
    """``(fast, explicit, implicit, rate)``: the fast cells (explicit positivity rate
    above ``max(a) / split``), the faces split between the slow and the fast ones
    (:func:`split_faces`), and the largest positivity rate of the slow faces (1/time),
    which sets the grid's step of ``stepping="imex"`` / ``"multirate"``."""
    a = _advection.advective_rate(faces, h)
    fast = a > a.max() / split
    explicit, implicit = split_faces(faces, fast)
    return fast, explicit, implicit, float(_advection.advective_rate(explicit, h).max())


#: ``stepping="auto"``: smallest useful split (below it the run stays explicit)
MIN_SPLIT = 4.0


def auto_split(faces, h, fraction=0.01):
    """``max(a) / q``: ``a`` the advective positivity rate of the cells, ``q`` its
    ``1 - fraction`` quantile over the cells that move (``a > 0``): the step gain of
    making the fastest ``fraction`` of the moving cells implicit."""
    a = _advection.advective_rate(faces, h)
    moving = a[a > 0]
    if moving.size == 0:
        return 1.0
    return float(a.max() / max(np.quantile(moving, 1.0 - fraction), 1e-300))


def imex_result(result_cls, grid, f, P, outlet, interval, frames, tracker, *, op, scheme,
                ws, split, cfl, limiter, extrapolate=True, multirate=False):
    """IMEX run packed as a :class:`spotpde.tracer.TracerResult` (``result_cls``).

    ``op`` is the explicit :class:`spotpde.tracer._operator._Operator` (built with
    ``implicit=True``: no diffusion in the kernel); its faces are replaced by the
    explicit ones. Fast cells: explicit positivity rate above ``max(rate) / split``.
    ``multirate``: the fast faces are sub-stepped explicitly on their box
    (:mod:`._multirate`) instead of implicitly; the implicit part is the diffusion.
    """
    t0 = time.perf_counter()
    fast, fe, fi, op.rate = partition(op.faces, grid.spacing, split)
    op.faces = fe
    op.rate_adv = op.rate
    box = None
    if multirate and fast.any():
        box = FastBox(op, fi, fast, ws, scheme, cfl, float(P.max()))
        fi = {k: np.zeros_like(v) for k, v in fi.items()}
    imp = ImexSplit(grid, f, fi, extrapolate, 1e-15 * float(P.max()),
                    parts=op.implicit_parts())

    def explicit_step(P, ops, dt, budget):
        if box is None:
            return _rk_step(ops, P, dt, scheme, ws, budget)
        P = box.advance(P, 0.5 * dt, budget)
        P = _rk_step(ops, P, dt, scheme, ws, budget)
        return box.advance(P, 0.5 * dt, budget)

    class _Imex(_FixedStepper):
        """Strang splitting with the implicit halves of neighbouring steps merged:
        ``I(dt/2) [E(dt) I(dt)]^(n-1) E(dt) I(dt/2)`` over each frame interval."""

        def advance_to(self, P, t, t_target, tick):
            n = self.n_sub
            dt = self.interval / n
            ops = [self.op] * self.scheme.stages
            P = imp.backward_euler(P, 0.5 * dt)
            for m in range(n):
                P = explicit_step(P, ops, dt, self.budget)
                P = imp.backward_euler(P, dt if m < n - 1 else 0.5 * dt)
                t = t_target if m == n - 1 else t + dt
                self.steps += 1
                tick(self.steps, t)
            self.max_cfl = max(self.max_cfl, dt * self.op.rate)
            self.max_courant = max(self.max_courant, dt * self.op.umax / self.h)
            return P, t

    stepper = _Imex(op, scheme, ws, True, grid.spacing, interval, cfl)
    t = 0.0
    for j in range(1, frames):
        P, t = stepper.advance_to(P, t, tracker.times[j], tracker.tick)
        budget = [b + c for b, c in zip(stepper.budget, imp.exits())]
        tracker.record(j, t, P, budget, stepper.max_cfl)
    faces = -(ws.Fz_acc + imp.z_fluxes())
    info = {"time_scheme": scheme.name, "stepping": "multirate" if multirate else "imex",
            "limiter": limiter, "box_cells": box.cells if box else 0,
            "substeps": box.substeps if box else 0,
            "diffusion": "implicit", "cfl": cfl, "split": split,
            "cells_implicit": int(fast.sum()), "dt": interval / stepper.n_sub,
            "factorisations": imp.fac.count, "theta_min": imp.theta_min,
            "seconds_factorisation": imp.fac.seconds,
            "n_bad": imp.n_bad, "seconds": time.perf_counter() - t0}
    return tracker.result(result_cls, faces, budget, steps=stepper.steps,
                          max_cfl=stepper.max_cfl, max_courant=stepper.max_courant,
                          options=info)
