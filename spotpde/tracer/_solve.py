"""Tracer propagator: the Fokker-Planck equation of one particle (docs/conventions.md section 3).

Solves, in Ito form with the full diffusion tensor,

    dP/dt + div(u_p P) = sum_ij d_i d_j (D_p^ij P)

on a :class:`spotpde.grid.Grid` (array order ``(z, x)`` / ``(z, y, x)``, cell centred)
with cell-centred coefficient fields, steady or time dependent. The scheme (details in
``docs/tracer.md`` and in :mod:`spotpde.tracer._advection`, :mod:`spotpde.tracer._diffusion`,
:mod:`spotpde.tracer._timestepping`):

* finite volumes, conservative: ``P`` changes only through face fluxes; boundary
  fluxes (floor over the orifice, open sides, top) are summed into ``outflow`` with
  the Runge-Kutta weights, so ``mass + outflow`` is constant to round-off;
* advection: upwind face values from a fifth-order WENO-Z reconstruction clipped to
  ``[0, 2 P_c]`` by default (numerical diffusion about 1 % of the physical one at cell
  Peclet 100), or a limited MUSCL reconstruction (Koren's third-order limiter, van Leer,
  MC, minmod) or first-order upwind on request; face velocities the mean of the two
  cells;
* diffusion: a positive conservative splitting of the tensor into axial and diagonal
  exchanges (9-point stencil), explicit in the Runge-Kutta stages, or implicit
  (backward Euler half steps, Strang splitting, sparse LU reused while ``dt`` and the
  fields are unchanged) when the explicit diffusive limit would dominate the step count;
* time: SSP Runge-Kutta (SSP-RK3 by default), adaptive ``dt`` from the per-cell
  positivity bound (CFL and diffusion limits) times ``cfl``.

Boundary conditions: reflecting side walls (zero total flux) or open sides (advective
outflow with the boundary cell's velocity and value, no inflow, zero diffusive flux);
the floor ``z = z0`` lets probability out by advection where the bottom cells' ``u_z``
is negative (optionally restricted by an ``outlet`` mask) and is a wall elsewhere; the
top lets probability out only where ``u_z > 0`` (there is no inflow of a single tracer).
Diffusive flux through every boundary is zero.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Callable, Mapping, Union

import numba
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import _advection, _diffusion, _timestepping
from . import _fp_kernels as K
from ..errors import CaseError, NumericalError
from ..grid import DIFFUSIVITY_KEYS, DRIFT_KEYS, Grid

Fields = Union[Mapping[str, np.ndarray], Callable[[float], Mapping[str, np.ndarray]]]

DIFFUSION_MODES = ("auto", "explicit", "implicit")


def required_fields(dims: int) -> tuple[str, ...]:
    """Names of the coefficient arrays ``solve`` needs in ``dims`` dimensions."""
    return DRIFT_KEYS[dims] + DIFFUSIVITY_KEYS[dims]


@dataclass
class TracerResult:
    """Output of :func:`solve`.

    Attributes:
        times: (frames,) output times.
        P: (frames, *grid.shape) probability density in 1/d**dims; ``None`` when the
            frames were handed to ``on_frame`` instead of being kept.
        mass: (frames,) probability inside the domain, ``sum(P) h**dims``.
        outflow: (frames,) cumulative probability that left through the floor
            (orifice), the open sides and the top up to each frame.
        P_height: grid.shape: the geometrical propagator at the cell-centre heights
            ``grid.z``: time-integrated (0 to t_end) net downward probability flux
            through height ``z_k``, per unit horizontal length (1/d**(dims-1)); the
            mean of the fluxes through the cell's bottom and top faces.
        P_height_faces: (nz+1, ...) the same at the cell faces ``z0 + k h``
            (row 0 is the orifice plane, its integral is the floor outflow).
        steps: time steps taken.
        max_cfl: largest ``dt * a`` over the run, ``a`` the per-cell positivity rate
            (advection + explicit diffusion); P >= 0 is guaranteed while <= 1.
        max_courant: largest ``max|u| dt / h`` (per axis) over the run.
        mass_error: largest ``|mass + outflow - mass0| / mass0`` over the frames.
        outflow_by_boundary: cumulative probability through ``floor``, ``sides``,
            ``top`` at t_end.
        options: the numerical options used (limiter, time scheme, diffusion mode...).
    """

    times: np.ndarray
    P: np.ndarray | None
    mass: np.ndarray
    outflow: np.ndarray
    P_height: np.ndarray
    P_height_faces: np.ndarray
    steps: int = 0
    max_cfl: float = 0.0
    max_courant: float = 0.0
    mass_error: float = 0.0
    outflow_by_boundary: dict = field(default_factory=dict)
    options: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------------
# validation


def _check_fields(grid: Grid, fields: Mapping[str, np.ndarray], where: str) -> dict:
    if not isinstance(fields, Mapping):
        raise CaseError(f"{where}: expected a dict of arrays, got {type(fields).__name__}")
    names = required_fields(grid.dims)
    missing = [n for n in names if n not in fields]
    if missing:
        raise CaseError(f"{where}: missing {', '.join(missing)} (needs {', '.join(names)})")
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
        diag = [f"D_{c}{c}" for c in (("x", "z") if grid.dims == 2 else ("x", "y", "z"))]
        for n in diag:
            if np.any(out[n] < 0):
                problems.append(f"{where}.{n}: must be >= 0, min {out[n].min():.3g}")
        if not problems:
            pairs = [("D_xx", "D_zz", "D_xz")] if grid.dims == 2 else [
                ("D_xx", "D_yy", "D_xy"), ("D_xx", "D_zz", "D_xz"), ("D_yy", "D_zz", "D_yz")]
            for a, b, c in pairs:
                bad = out[c] ** 2 > out[a] * out[b] * (1 + 1e-9) + 1e-300
                if np.any(bad):
                    problems.append(f"{where}.{c}: tensor not positive semidefinite "
                                    f"({c}**2 > {a}*{b}) in {int(bad.sum())} cells")
    if problems:
        raise CaseError(problems)
    return out


# ---------------------------------------------------------------------------------------
# the discrete operator at one time


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

    def backward_euler(self, P: np.ndarray, tau: float):
        """Solve ``(I - tau L) P_new = P``; returns ``P_new`` and its upward face flux."""
        lu = self._lu.get(tau)
        if lu is None:
            n = P.size
            M = (sp.identity(n, format="csc") - tau * self.L).tocsc()
            lu = spla.splu(M)
            self._lu = {tau: lu}
        Pn = lu.solve(P.ravel()).reshape(P.shape)
        Fz = (self.Bz @ Pn.ravel()).reshape((P.shape[0] + 1,) + P.shape[1:])
        return Pn, Fz


class _Workspace:
    def __init__(self, grid: Grid, p_scale: float = 1.0):
        shape = grid.shape
        self.tiny = 1e-100 * p_scale
        self.R = np.empty(shape)
        fshape = (shape[0] + 1,) + shape[1:]
        self.Fz_acc = np.zeros(fshape)
        if grid.dims == 2:
            self.Fz_edge = np.empty((2,) + shape[1:])     # floor and top face fluxes
        else:
            self.Fz = np.empty(fshape)
        self.stage = [np.empty(shape), np.empty(shape)]


def _rhs(op: _Operator, P: np.ndarray, ws: _Workspace, w_acc: float,
         stage: tuple | None = None) -> tuple[float, float, float]:
    """Fill ``ws.R = dP/dt``, accumulate ``w_acc * Fz``.

    With ``stage = (a, P0, dt, out)`` write the Runge-Kutta stage
    ``out = a P0 + (1 - a) (P + dt R)`` instead (values below ``ws.tiny`` set to 0); in 2D
    the kernel does this in the same pass and ``ws.R`` is not written.

    Returns:
        Outflow rates (probability per unit time) through the floor, the sides, the top.
    """
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
        K.advect_3d_kernel(op.limiter)(P, f["x"], f["y"], f["z"], op.eps, h, ws.R, ws.Fz,
                                       ws.Fz_acc, w_acc)
        if not op.implicit and len(op.terms):
            ws.R += (op.L @ P.ravel()).reshape(P.shape)
            ws.Fz_acc += w_acc * (op.Bz @ P.ravel()).reshape(ws.Fz.shape)
        side = (np.vdot(f["x"][:, :, -1], P[:, :, -1]) - np.vdot(f["x"][:, :, 0], P[:, :, 0])
                + np.vdot(f["y"][:, -1, :], P[:, -1, :]) - np.vdot(f["y"][:, 0, :], P[:, 0, :]))
        floor = -ws.Fz[0].sum()
        top = ws.Fz[-1].sum()
        hm = h * h
        if stage is not None:
            a, P0, dt, out = stage
            K.combine(a, P0.ravel(), 1.0 - a, P.ravel(), (1.0 - a) * dt, ws.R.ravel(),
                      out.ravel(), ws.tiny)
    return hm * floor, hm * side, hm * top


def _rk_step(ops, P, dt, scheme, ws, budget):
    """One SSP-RK step of ``dP/dt = L(P)``; ``ops[s]`` is the operator at stage ``s``.

    Stage ``s`` writes ``a_s P0 + (1 - a_s) (P_{s-1} + dt L(P_{s-1}))`` into a work array
    (the last stage into ``P0`` itself: elementwise, so safe in place).
    """
    P0 = P
    prev = P0
    for s in range(scheme.stages):
        out = ws.stage[s % 2] if s < scheme.stages - 1 else P0
        rates = _rhs(ops[s], prev, ws, scheme.b[s] * dt, (scheme.alpha[s], P0, dt, out))
        for j, r in enumerate(rates):
            budget[j] += scheme.b[s] * dt * r
        prev = out
    return prev


def solve(grid: Grid, fields: Fields, P0: np.ndarray, t_end: float, frames: int,
          progress: Callable[[float], None] | None = None, *, limiter: str = "weno5",
          time_scheme: str = "ssprk3", diffusion: str = "auto", cfl: float = 0.9,
          outlet: np.ndarray | None = None, check_mass: float = 1e-9,
          threads: int | None = None,
          on_frame: Callable[[int, float, np.ndarray], None] | None = None) -> TracerResult:
    """Evolve the tracer density ``P`` from ``P0`` over ``[0, t_end]``.

    Args:
        grid: the grid (array order ``(z, x)`` / ``(z, y, x)``).
        fields: dict of grid-shaped cell-centred arrays ``u_x``, [``u_y``,] ``u_z``
            (d per unit time) and ``D_xx``, ``D_xz``, ``D_zz`` (3D also ``D_yy``,
            ``D_xy``, ``D_yz``; d**2 per unit time); scalars are broadcast. Or a
            callable ``t -> dict`` for time-dependent coefficients (evaluated at the
            Runge-Kutta stage times).
        P0: grid-shaped initial density in 1/d**dims (not normalised here).
        t_end: final time (> 0).
        frames: number of equally spaced output frames including 0 and t_end (>= 2).
        progress: optional ``progress(fraction)`` callback (a few hundred calls at most).
        limiter: face reconstruction: ``"weno5"`` (default; fifth-order WENO-Z,
            positivity clip), ``"koren"`` (third order where smooth and monotone, about
            4 times cheaper), ``"vanleer"``, ``"mc"``, ``"minmod"`` or ``"upwind"``
            (first order; for demonstrations of numerical diffusion only).
        time_scheme: ``"ssprk3"`` (default) or ``"ssprk2"``.
        diffusion: ``"explicit"``, ``"implicit"`` (Strang splitting with backward-Euler
            half steps: first order in time for the diffusive part, unconditionally
            positive) or ``"auto"``: implicit when the explicit diffusive limit would
            more than double the number of steps (time-dependent fields: at ``t = 0``
            or at ``t_end``).
        cfl: fraction (0, 1] of the positivity limit ``dt <= 1 / max(a)`` used.
        outlet: optional boolean mask over the floor (shape ``grid.shape[1:]``) where
            probability may leave; default: wherever the bottom cells have ``u_z < 0``.
        check_mass: relative tolerance of the mass budget checked at every frame.
        threads: numba threads for the kernels; default 1 below 65536 cells (thread
            start-up costs more than it saves there) and numba's default above.
        on_frame: optional ``on_frame(index, time, P)`` called with every frame (index 0
            is ``P0``) after its checks passed; the frames are then *not* kept
            (``TracerResult.P`` is ``None``), so memory does not grow with ``frames``.
            ``P`` is the solver's working array: copy or write it out, do not keep it.

    Returns:
        :class:`TracerResult`.

    Raises:
        ValueError: invalid ``P0``, ``t_end``, ``frames`` or options (naming the
            argument); invalid fields (a ``CaseError``, which the pipeline reports as a
            numerical failure of derived data).
        NumericalError: NaN, ``P < 0`` or a broken mass budget (message names the time).
    """
    problems = []
    if not (isinstance(frames, (int, np.integer)) and frames >= 2):
        problems.append(f"frames: must be an integer >= 2, got {frames!r}")
    if not (np.isfinite(t_end) and t_end > 0):
        problems.append(f"t_end: must be a finite number > 0, got {t_end!r}")
    if not (0 < cfl <= 1):
        problems.append(f"cfl: must be in (0, 1], got {cfl!r}")
    if diffusion not in DIFFUSION_MODES:
        problems.append(f"diffusion: unknown mode {diffusion!r}; valid choices: "
                        f"{', '.join(DIFFUSION_MODES)}")
    try:
        lim = _advection.limiter_from_name(limiter)
    except ValueError as e:
        problems.append(str(e))
    try:
        scheme = _timestepping.scheme_from_name(time_scheme)
    except ValueError as e:
        problems.append(str(e))
    P = np.array(P0, dtype=float)
    if P.shape != grid.shape:
        problems.append(f"P0: shape {P.shape} does not match the grid {grid.shape}")
    elif not np.all(np.isfinite(P)) or np.any(P < 0):
        problems.append("P0: must be finite and >= 0")
    if outlet is None:
        outlet = np.ones(grid.shape[1:], dtype=bool)
    else:
        outlet = np.asarray(outlet, dtype=bool)
        if outlet.shape != grid.shape[1:]:
            problems.append(f"outlet: shape {outlet.shape} does not match the floor "
                            f"{grid.shape[1:]}")
    if problems:
        raise ValueError("; ".join(problems))
    P = np.ascontiguousarray(P)
    if threads is None:
        threads = 1 if grid.size < 65536 else numba.config.NUMBA_NUM_THREADS
    saved = numba.get_num_threads()
    numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))
    try:
        return _solve(grid, fields, P, t_end, frames, progress, lim, scheme, diffusion, cfl,
                      outlet, check_mass, on_frame)
    finally:
        numba.set_num_threads(saved)


def _solve(grid, fields, P, t_end, frames, progress, lim, scheme, diffusion, cfl, outlet,
           check_mass, on_frame=None):
    steady = not callable(fields)
    get = (lambda t: fields) if steady else fields
    f0 = _check_fields(grid, get(0.0), "fields")
    p_scale = float(P.max()) if P.size else 1.0
    op0 = _Operator(grid, f0, lim.code, outlet, implicit=False, p_scale=p_scale)
    if diffusion == "auto":
        # time-dependent fields: judge by the start and the end (a flow that starts
        # from rest has no coefficients at t = 0)
        probes = [op0] if steady else [
            op0, _Operator(grid, _check_fields(grid, get(float(t_end)), f"fields(t={t_end:g})"),
                           lim.code, outlet, implicit=False, p_scale=p_scale)]
        implicit = any(o.rate_explicit > 2.0 * o.rate_adv and o.rate_diff > 0 for o in probes)
    else:
        implicit = diffusion == "implicit"
    if implicit:
        op0 = _Operator(grid, f0, lim.code, outlet, implicit=True, p_scale=p_scale)
    if op0.n_bad:
        warnings.warn(f"tracer: D_p is not diagonally dominant in {op0.n_bad} cells "
                      "(|D_xz| > min(D_xx, D_zz)); the 9-point diffusion stencil is then "
                      "not guaranteed to keep P >= 0", stacklevel=2)

    cache = {0.0: op0}

    def op_at(t):
        if steady:
            return op0
        o = cache.get(t)
        if o is None:
            o = _Operator(grid, _check_fields(grid, get(t), f"fields(t={t:g})"), lim.code,
                          outlet, implicit, p_scale)
            if len(cache) > 4:        # a step's stages and the next step's start
                cache.pop(min(cache))
            cache[t] = o
        return o

    hv = grid.cell_volume
    times = np.linspace(0.0, float(t_end), frames)
    if on_frame is None:
        out_P = np.empty((frames,) + grid.shape)
        out_P[0] = P
    else:
        out_P = None
        on_frame(0, 0.0, P)
    mass = np.empty(frames)
    outflow = np.zeros(frames)
    mass[0] = P.sum() * hv
    mass0 = mass[0]
    budget = [0.0, 0.0, 0.0]       # floor, sides, top
    ws = _Workspace(grid, p_scale)
    steps = 0
    max_cfl = 0.0
    max_courant = 0.0
    mass_err = 0.0
    interval = t_end / (frames - 1)
    ptiny = 1e-12 * max(float(P.max()), 1e-300)
    est_steps = max(1, math.ceil(interval * op0.rate / cfl)) * (frames - 1)
    every = max(1, est_steps // 200)
    t = 0.0

    def advance(P, ops, dt, t):
        if implicit:
            P = _implicit_step(op0 if steady else op_at(t), P, 0.5 * dt, ws)
            P = _rk_step(ops, P, dt, scheme, ws, budget)
            return _implicit_step(op0 if steady else op_at(t + dt), P, 0.5 * dt, ws)
        return _rk_step(ops, P, dt, scheme, ws, budget)

    n_sub = max(1, math.ceil(interval * op0.rate / cfl - 1e-9))
    for j in range(1, frames):
        t_target = times[j]
        if steady:
            dt = interval / n_sub
            ops = [op0] * scheme.stages
            for m in range(n_sub):
                P = advance(P, ops, dt, t)
                t = t_target if m == n_sub - 1 else t + dt
                steps += 1
                if progress is not None and steps % every == 0:
                    progress(min(1.0, t / t_end))
            max_cfl = max(max_cfl, dt * op0.rate)
            max_courant = max(max_courant, dt * op0.umax / grid.spacing)
        else:
            while t_target - t > 1e-13 * t_end:
                remaining = t_target - t
                rate = op_at(t).rate
                for _ in range(30):
                    dt = remaining / max(1, math.ceil(remaining * rate / cfl - 1e-9))
                    stage_times = [t + c * dt for c in scheme.c] + ([t + dt] if implicit else [])
                    ops = [op_at(s) for s in stage_times]
                    rate_step = max(o.rate for o in ops)
                    if dt * rate_step <= 1.0:
                        break
                    rate = rate_step
                else:
                    raise NumericalError(f"tracer: no stable time step found at t = {t:g}")
                P = advance(P, ops[:scheme.stages], dt, t)
                t = t_target if dt >= remaining else t + dt
                steps += 1
                max_cfl = max(max_cfl, dt * rate_step)
                max_courant = max(max_courant, dt * max(o.umax for o in ops) / grid.spacing)
                if progress is not None and steps % every == 0:
                    progress(min(1.0, t / t_end))
        mass[j] = P.sum() * hv
        outflow[j] = sum(budget)
        pmin = float(P.min()) if P.size else 0.0
        if not np.isfinite(pmin) or not np.isfinite(mass[j]):
            raise NumericalError(f"tracer: P became NaN or infinite by t = {t:g}")
        if pmin < -ptiny:
            raise NumericalError(f"tracer: negative probability P = {pmin:.3g} at t = {t:g} "
                                 f"(positivity limit exceeded: max dt*a = {max_cfl:.3g})")
        err = abs(mass[j] + outflow[j] - mass0) / max(mass0, 1e-300)
        mass_err = max(mass_err, err)
        if err > check_mass:
            raise NumericalError(f"tracer: mass budget broken at t = {t:g}: mass + outflow "
                                 f"differs from the initial mass by {err:.3g} (relative)")
        if out_P is None:
            on_frame(j, float(times[j]), P)
        else:
            out_P[j] = P
        if progress is not None:
            progress(j / (frames - 1))

    faces = -ws.Fz_acc
    return TracerResult(
        times=times, P=out_P, mass=mass, outflow=outflow,
        P_height=0.5 * (faces[:-1] + faces[1:]), P_height_faces=faces,
        steps=steps, max_cfl=max_cfl, max_courant=max_courant, mass_error=mass_err,
        outflow_by_boundary={"floor": budget[0], "sides": budget[1], "top": budget[2]},
        options={"limiter": lim.name, "time_scheme": scheme.name,
                 "diffusion": "implicit" if implicit else "explicit", "cfl": cfl},
    )


def _implicit_step(op: _Operator, P: np.ndarray, tau: float, ws: _Workspace) -> np.ndarray:
    if not op.terms or op.rate_diff == 0.0:
        return P
    Pn, Fz = op.backward_euler(P, tau)
    ws.Fz_acc += tau * Fz
    return np.ascontiguousarray(Pn)


# ---------------------------------------------------------------------------------------
# diagnostics


def numerical_diffusion(speed: float, D: float, spacing: float, *, sigma: float = 1.0,
                        t_end: float | None = None, **options) -> dict:
    """Measure the scheme's effective numerical diffusion along the flow.

    Runs :func:`solve` on a uniform downward flow ``u_z = -speed`` with isotropic
    physical diffusivity ``D`` (a quasi-1D grid of 4 columns, reflecting walls, the
    whole floor an orifice) from a Gaussian layer of standard deviation ``sigma`` in z,
    and returns the apparent diffusivity from the growth of the z variance,
    ``D_eff = (var(t_end) - var(0)) / (2 t_end)``, and ``D_num = D_eff - D``.

    Args:
        speed: flow speed ``|u_p|`` in d per unit time (> 0).
        D: physical diffusivity along the flow in d**2 per unit time (>= 0).
        spacing: grid spacing ``h`` in d.
        sigma: initial width in d (the limiter's clipping, hence ``D_num``, grows as the
            profile sharpens: use the smallest width your pictures resolve).
        t_end: duration; default: the time to travel ``40 sigma``.
        **options: passed to :func:`solve` (``limiter``, ``time_scheme``, ``cfl``).

    Returns:
        dict with ``D_eff``, ``D_num``, ``D_phys``, ``ratio = D_num / D_phys`` (inf if
        ``D = 0``), ``cell_peclet = speed h / D``, ``travel`` (d), ``drift_error``
        (relative error of the mean displacement).
    """
    if not (speed > 0 and D >= 0 and spacing > 0 and sigma > 0):
        raise ValueError(f"speed, D, spacing, sigma: need speed > 0, D >= 0, spacing > 0, sigma > 0; "
                        f"got speed={speed!r}, D={D!r}, spacing={spacing!r}, sigma={sigma!r}")
    if t_end is None:
        t_end = 40.0 * sigma / speed
    travel = speed * t_end
    spread = 8.0 * math.sqrt(sigma**2 + 2 * D * t_end) + 4 * spacing
    z0 = travel + spread
    top = z0 + spread
    n = math.ceil(top / spacing)
    grid = Grid(2, (0.0, 4 * spacing), (0.0, n * spacing), spacing)
    Z, X = grid.mesh()
    P0 = np.exp(-0.5 * ((Z - z0) / sigma) ** 2) * np.ones(grid.shape)
    P0 /= P0.sum() * grid.cell_volume
    fields = {"u_x": 0.0, "u_z": -float(speed), "D_xx": float(D), "D_xz": 0.0,
              "D_zz": float(D)}
    res = solve(grid, fields, P0, t_end, 2, **options)
    z = grid.z

    def moments(P):
        pz = P.sum(axis=1)
        m = pz.sum()
        mean = (pz * z).sum() / m
        return mean, (pz * (z - mean) ** 2).sum() / m

    m0, v0 = moments(res.P[0])
    m1, v1 = moments(res.P[-1])
    D_eff = (v1 - v0) / (2 * t_end)
    return {"D_eff": D_eff, "D_num": D_eff - D, "D_phys": float(D),
            "ratio": (D_eff - D) / D if D > 0 else math.inf,
            "cell_peclet": speed * spacing / D if D > 0 else math.inf,
            "travel": travel, "drift_error": abs((m0 - m1) - travel) / travel}


# ---------------------------------------------------------------------------------------
# grid-free reference: Euler-Maruyama


def _interp_factory(grid: Grid):
    """Multilinear interpolation on the cell centres, clamped at the outer centres."""
    coords = [grid.coords()[a] for a in grid.axes]
    h = grid.spacing

    def interp(arrays, pos):
        # pos: (n, dims) in array order
        idx, wts = [], []
        for d, c in enumerate(coords):
            s = np.clip((pos[:, d] - c[0]) / h, 0.0, len(c) - 1.0)
            i0 = np.minimum(np.floor(s).astype(np.int64), len(c) - 2) if len(c) > 1 else \
                np.zeros(len(s), dtype=np.int64)
            idx.append(i0)
            wts.append(s - i0 if len(c) > 1 else np.zeros(len(s)))
        out = [np.zeros(len(pos)) for _ in arrays]
        for corner in range(2 ** grid.dims):
            bits = [(corner >> d) & 1 for d in range(grid.dims)]
            w = np.ones(len(pos))
            ii = []
            for d, bit in enumerate(bits):
                w = w * (wts[d] if bit else 1.0 - wts[d])
                ii.append(np.minimum(idx[d] + bit, len(coords[d]) - 1))
            ii = tuple(ii)
            for o, a in zip(out, arrays):
                o += w * a[ii]
        return out

    return interp


def sde_ensemble(grid: Grid, fields: Fields, starts, t_end: float, n: int, dt: float,
                 seed: int | None = None) -> np.ndarray:
    """Grid-free reference solution: Euler-Maruyama particles of the same equation.

    Integrates ``dX = u_p(X) dt + sqrt(2 D_p(X)) dW`` (Ito form, so the drift is exactly
    ``u_p`` and the density obeys the tracer equation) with the fields interpolated
    multilinearly between cell centres (constant beyond the outer centres). Boundaries
    mirror those of :func:`solve`: side walls reflect (``"open"`` walls absorb), the top
    reflects, and a particle crossing the floor ``z = z0`` is absorbed where the
    interpolated ``u_z`` there is negative (the orifice) and reflected elsewhere.

    Args:
        grid: the grid the fields live on.
        fields: the same dict (or callable ``t -> dict``) as for :func:`solve`.
        starts: start positions, shape ``(dims,)`` (all particles) or ``(m, dims)``
            (particle ``p`` starts at ``starts[p % m]``), columns in array order
            ``(z, x)`` / ``(z, y, x)``, in d.
        t_end: duration.
        n: number of particles.
        dt: time step (the weak error is first order in ``dt``).
        seed: seed of ``numpy.random.default_rng``.

    Returns:
        ``(n, dims)`` final positions in array order; rows of absorbed particles are NaN.
    """
    dims = grid.dims
    starts = np.atleast_2d(np.asarray(starts, dtype=float))
    if starts.shape[1] != dims:
        raise ValueError(f"starts: need {dims} columns (array order "
                        f"{grid.axes}), got shape {starts.shape}")
    if not (n >= 1 and dt > 0 and t_end >= 0):
        raise ValueError(f"n, dt, t_end: need n >= 1, dt > 0, t_end >= 0; got n={n!r}, "
                        f"dt={dt!r}, t_end={t_end!r}")
    rng = np.random.default_rng(seed)
    pos = starts[np.arange(n) % len(starts)].copy()
    alive = np.ones(n, dtype=bool)
    interp = _interp_factory(grid)
    axes = grid.axes
    lo = [grid.z_range[0]] + [grid.x_range[0]] * (dims - 1)
    hi = [grid.z_range[1]] + [grid.x_range[1]] * (dims - 1)
    steady = not callable(fields)
    f = _check_fields(grid, fields if steady else fields(0.0), "fields")
    nsteps = max(1, int(math.ceil(t_end / dt - 1e-9)))
    dt = t_end / nsteps
    ucomp = [f"u_{a}" for a in axes]
    dcomp = [["D_" + "".join(sorted((a, b), key="xyz".index)) for b in axes] for a in axes]
    for step in range(nsteps):
        if not steady:
            f = _check_fields(grid, fields(step * dt), "fields")
        idx = np.flatnonzero(alive)
        if idx.size == 0:
            break
        X = pos[idx]
        names = ucomp + [dcomp[i][j] for i in range(dims) for j in range(i, dims)]
        vals = interp([f[nm] for nm in names], X)
        u = np.stack(vals[:dims], axis=1)
        Dm = np.empty((len(idx), dims, dims))
        m = dims
        for i in range(dims):
            for j in range(i, dims):
                Dm[:, i, j] = Dm[:, j, i] = vals[m]
                m += 1
        S = _sqrt_psd(2.0 * Dm)
        dW = rng.standard_normal((len(idx), dims)) * math.sqrt(dt)
        X = X + u * dt + np.einsum("nij,nj->ni", S, dW)
        # floor: absorbed over the orifice (u_z < 0 at the floor), reflected elsewhere
        below = X[:, 0] < lo[0]
        if np.any(below):
            at_floor = X[below].copy()
            at_floor[:, 0] = grid.z[0]
            uz_floor = interp([f["u_z"]], at_floor)[0]
            absorb = np.zeros(len(idx), dtype=bool)
            absorb[np.flatnonzero(below)[uz_floor < 0]] = True
            X[below, 0] = 2 * lo[0] - X[below, 0]
        else:
            absorb = np.zeros(len(idx), dtype=bool)
        X[:, 0] = np.where(X[:, 0] > hi[0], 2 * hi[0] - X[:, 0], X[:, 0])
        for d in range(1, dims):
            out_lo, out_hi = X[:, d] < lo[d], X[:, d] > hi[d]
            if grid.walls == "open":
                absorb |= out_lo | out_hi
            X[:, d] = np.where(out_lo, 2 * lo[d] - X[:, d], X[:, d])
            X[:, d] = np.where(out_hi, 2 * hi[d] - X[:, d], X[:, d])
        pos[idx] = X
        alive[idx[absorb]] = False
    pos[~alive] = np.nan
    return pos


def _sqrt_psd(M: np.ndarray) -> np.ndarray:
    """A factor ``S`` with ``S S^T = M`` for a stack ``(n, d, d)`` of PSD matrices.

    Cholesky factorisation written out for d <= 3 and made safe for semi-definite
    matrices (a vanishing pivot gives a zero column), vectorised over the stack.
    """
    n, d, _ = M.shape
    Lf = np.zeros_like(M)
    for j in range(d):
        diag = M[:, j, j] - np.sum(Lf[:, j, :j] ** 2, axis=1)
        piv = np.sqrt(np.clip(diag, 0.0, None))
        Lf[:, j, j] = piv
        inv = np.divide(1.0, piv, out=np.zeros_like(piv), where=piv > 1e-300)
        for i in range(j + 1, d):
            Lf[:, i, j] = (M[:, i, j] - np.sum(Lf[:, i, :j] * Lf[:, j, :j], axis=1)) * inv
    return Lf
