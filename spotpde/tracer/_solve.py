"""Tracer propagator: the Fokker-Planck equation of one particle (docs/conventions.md section 3).

Solves, in Ito form with the full diffusion tensor,

    dP/dt + div(u_p P) = sum_ij d_i d_j (D_p^ij P)

on a :class:`spotpde.grid.Grid` (array order ``(z, x)`` / ``(z, y, x)``, cell centred)
with cell-centred coefficient fields, steady or time dependent. The scheme (details in
``docs/tracer.md`` and in :mod:`spotpde.tracer._advection`, :mod:`spotpde.tracer._diffusion`,
:mod:`spotpde.tracer._timestepping`; the operator of one coefficient snapshot in
``_operator``, the fixed- and adaptive-step drivers and the frame bookkeeping in
``_stepping``):

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

import warnings
from dataclasses import dataclass, field
import math
from typing import Callable, Mapping, Union

import numba
import numpy as np

from . import _advection, _geometry, _implicit, _timestepping
from ._operator import _check_fields, _Operator, _rhs, _Workspace, required_fields
from ._stepping import (_AdaptiveStepper, _FixedStepper, _FrameTracker, _implicit_step,
                        _rk_step)
from ..grid import Grid

__all__ = ["DIFFUSION_MODES", "Fields", "TracerResult", "required_fields", "solve",
           # the discrete operator and one step, for tests and benchmarks
           "_check_fields", "_Operator", "_Workspace", "_rhs", "_rk_step", "_implicit_step"]

Fields = Union[Mapping[str, np.ndarray], Callable[[float], Mapping[str, np.ndarray]]]

DIFFUSION_MODES = ("auto", "explicit", "implicit")
#: ``stepping="auto"`` uses multirate beyond this many explicit steps (steady fields)
AUTO_IMEX_STEPS = 200_000
#: default ``split`` of each mode: the largest measured to keep the explicit accuracy
DEFAULT_SPLIT = {"imex": 5.0, "multirate": 10.0}
#: ``stepping="auto"`` takes multirate at most at this split: the largest at which every
#: total error stayed at most the explicit scheme's (docs/long_runs.md, the orifice row)
MAX_AUTO_SPLIT = 10.0
STEPPING_MODES = ("explicit", "imex", "multirate", "implicit", "auto")


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

def solve(grid: Grid, fields: Fields, P0: np.ndarray, t_end: float, frames: int,
          progress: Callable[[float], None] | None = None, *, limiter: str = "weno5",
          time_scheme: str = "ssprk3", diffusion: str = "auto", cfl: float = 0.9,
          outlet: np.ndarray | None = None, check_mass: float = 1e-9,
          threads: int | None = None,
          on_frame: Callable[[int, float, np.ndarray], None] | None = None,
          stepping: str = "explicit", tol: float = 1e-5,
          split: float | None = None) -> TracerResult:
    """Evolve the tracer density ``P`` from ``P0`` over ``[0, t_end]``.

    Args:
        grid: the grid (array order ``(z, x)`` / ``(z, y, x)``; axisymmetric ``(z, r)``:
            ``P``, ``P0`` per unit volume, ``mass = sum(P * grid.cell_volumes)``,
            ``P_height`` per unit horizontal area; with a hopper the staircase
            ``grid.active`` is walled and ``P0`` must vanish off it; docs/tracer.md).
        fields: dict of grid-shaped cell-centred arrays ``u_x``, [``u_y``,] ``u_z``
            (d per unit time) and ``D_xx``, ``D_xz``, ``D_zz`` (3D also ``D_yy``,
            ``D_xy``, ``D_yz``; d**2 per unit time; axisymmetric ``u_r``, ``u_z``,
            ``D_rr``, ``D_rz``, ``D_zz``); scalars are broadcast. Or a
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
        stepping: ``"explicit"`` (default: SSP Runge-Kutta at the positivity limit),
            ``"multirate"`` (steady fields only: the faces of the cells whose positivity
            rate exceeds ``max(rate) / split``, next to a point orifice, are sub-stepped
            explicitly on a small box, the rest stepped at about ``split`` times the
            explicit step; diffusion implicit everywhere, second order), ``"imex"``
            (the same, the fast faces implicit with the hybrid M-matrix operator of
            ``solve_steady(scheme="hybrid")``: cheaper, first order along the flow there),
            ``"implicit"`` (steady fields only: adaptive TR-BDF2 on the hybrid operator
            everywhere, step sizes set by ``tol``, not by the CFL limit; first order
            along the flow where the cell Peclet number exceeds 2; ``limiter``,
            ``time_scheme``, ``diffusion``, ``cfl`` and ``threads`` are unused) or
            ``"auto"``: ``"multirate"`` for steady fields when the explicit run would
            take more than ``AUTO_IMEX_STEPS`` steps and fewer than 1 % of the moving
            cells are 4 or more times faster than the rest (``split`` is then at most
            that ratio and at most ``MAX_AUTO_SPLIT``), else ``"explicit"``. All are
            positive and conservative, on every grid: axisymmetric and hopper grids
            step the explicit scheme's operator of their geometry (docs/long_runs.md).
        tol: ``"implicit"``: local error per step, L1 relative to the initial mass, in
            (0, 1).
        split: ``"multirate"`` / ``"imex"``: ratio (>= 1) of the step to the explicit
            CFL step; default ``DEFAULT_SPLIT`` (10 and 5: the largest that kept the
            explicit accuracy of frames, outflow and P_height in the measurements).

    Returns:
        :class:`TracerResult`.

    Raises:
        ValueError: invalid ``P0``, ``t_end``, ``frames`` or options (naming the
            argument); invalid fields (a ``ValueError`` naming ``fields.<key>``, which the pipeline reports as a
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
    if stepping not in STEPPING_MODES:
        problems.append(f"stepping: unknown mode {stepping!r}; valid choices: "
                        f"{', '.join(STEPPING_MODES)}")
    elif stepping in ("implicit", "imex", "multirate") and callable(fields):
        problems.append(f"stepping: {stepping!r} needs steady fields (a dict), got a callable")
    if split is None:
        split = DEFAULT_SPLIT.get(stepping, DEFAULT_SPLIT["multirate"])
    if not (isinstance(split, (int, float)) and split >= 1):
        problems.append(f"split: must be a number >= 1, got {split!r}")
    if not (isinstance(tol, (int, float)) and 0 < tol < 1):
        problems.append(f"tol: must be in (0, 1), got {tol!r}")
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
        if _geometry.special(grid):     # rings or a staircase: Q = 2 pi r P on the twin
            return _geometry.solve(_solve, grid, fields, P, t_end, frames, progress, lim,
                                   scheme, diffusion, cfl, outlet, check_mass, on_frame,
                                   stepping, tol, split)
        return _solve(grid, fields, P, t_end, frames, progress, lim, scheme, diffusion, cfl,
                      outlet, check_mass, on_frame, stepping, tol, split)
    finally:
        numba.set_num_threads(saved)


def choose_stepping(stepping, split, faces, h, explicit_steps, steady=True):
    """``(stepping, split)`` a run takes: ``split`` defaults to ``DEFAULT_SPLIT`` of the
    mode; ``"auto"`` becomes ``"multirate"`` when the explicit run (``explicit_steps``)
    needs more than ``AUTO_IMEX_STEPS`` steps with steady fields and the fastest 1 % of
    the moving cells are at least ``MIN_SPLIT`` times faster than the rest (``split``
    then at most that ratio, :func:`._implicit.auto_split`, and at most
    ``MAX_AUTO_SPLIT`` whatever ``split`` asks), else ``"explicit"``.
    ``faces``: the explicit operator's face velocities; ``h``: the spacing."""
    if split is None:
        split = DEFAULT_SPLIT.get(stepping, DEFAULT_SPLIT["multirate"])
    if stepping == "auto":
        # multirate where a few fast cells (next to a point orifice) set the explicit step;
        # its time error grows like the step (the orifice row of P_height,
        # docs/long_runs.md), so the automatic choice never goes past MAX_AUTO_SPLIT
        split = min(split, MAX_AUTO_SPLIT, _implicit.auto_split(faces, h)) if steady and \
            explicit_steps > AUTO_IMEX_STEPS else 1.0
        stepping = "multirate" if split >= _implicit.MIN_SPLIT else "explicit"
    return stepping, split


def _solve(grid, fields, P, t_end, frames, progress, lim, scheme, diffusion, cfl, outlet,
           check_mass, on_frame=None, stepping="explicit", tol=1e-5, split=None,
           make_op=_Operator):
    """Core of :func:`solve` (inputs checked): the operators (built by ``make_op``, the
    signature of :class:`._operator._Operator`), then the frames.

    Steady fields use the fixed-step driver, time-dependent ones the adaptive one
    (:mod:`._stepping`); the frame tracker keeps the frames and checks the mass budget.
    """
    steady = not callable(fields)
    get = (lambda t: fields) if steady else fields
    f0 = _check_fields(grid, get(0.0), "fields")
    p_scale = float(P.max()) if P.size else 1.0
    op0 = make_op(grid, f0, lim.code, outlet, implicit=False, p_scale=p_scale)
    if diffusion == "auto":
        # time-dependent fields: judge by the start and the end (a flow that starts
        # from rest has no coefficients at t = 0)
        probes = [op0] if steady else [
            op0, make_op(grid, _check_fields(grid, get(float(t_end)), f"fields(t={t_end:g})"),
                           lim.code, outlet, implicit=False, p_scale=p_scale)]
        implicit = any(o.rate_explicit > 2.0 * o.rate_adv and o.rate_diff > 0 for o in probes)
    else:
        implicit = diffusion == "implicit"
    if implicit:
        op0 = make_op(grid, f0, lim.code, outlet, implicit=True, p_scale=p_scale)
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
            o = make_op(grid, _check_fields(grid, get(t), f"fields(t={t:g})"), lim.code,
                          outlet, implicit, p_scale)
            if len(cache) > 4:        # a step's stages and the next step's start
                cache.pop(min(cache))
            cache[t] = o
        return o

    interval = t_end / (frames - 1)
    est_steps = max(1, math.ceil(interval * op0.rate / cfl)) * (frames - 1)
    stepping, split = choose_stepping(stepping, split, op0.faces, grid.spacing, est_steps,
                                      steady)
    if stepping == "implicit":
        tracker = _FrameTracker(grid, P, t_end, frames, on_frame, progress, check_mass,
                                every=1)
        return _implicit.result(TracerResult, grid, op0, P, interval, frames, tracker,
                                tol=tol, dt0=cfl / op0.rate_explicit)
    if stepping in ("imex", "multirate"):
        op = make_op(grid, f0, lim.code, outlet, implicit=True, p_scale=p_scale)
        ws = _Workspace(grid, p_scale)
        tracker = _FrameTracker(grid, P, t_end, frames, on_frame, progress, check_mass,
                                every=max(1, int(est_steps / split) // 200))
        return _implicit.imex_result(TracerResult, grid, f0, P, outlet, interval, frames,
                                     tracker, op=op, scheme=scheme, ws=ws, split=split,
                                     cfl=cfl, limiter=lim.name,
                                     multirate=stepping == "multirate")
    ws = _Workspace(grid, p_scale)
    tracker = _FrameTracker(grid, P, t_end, frames, on_frame, progress, check_mass,
                            every=max(1, est_steps // 200))
    if steady:
        stepper = _FixedStepper(op0, scheme, ws, implicit, grid.spacing, interval, cfl)
    else:
        stepper = _AdaptiveStepper(op_at, scheme, ws, implicit, grid.spacing, cfl, t_end)
    t = 0.0
    for j in range(1, frames):
        P, t = stepper.advance_to(P, t, tracker.times[j], tracker.tick)
        tracker.record(j, t, P, stepper.budget, stepper.max_cfl)

    faces = -ws.Fz_acc
    budget = stepper.budget
    return tracker.result(
        TracerResult, faces, budget, steps=stepper.steps, max_cfl=stepper.max_cfl,
        max_courant=stepper.max_courant,
        options={"limiter": lim.name, "time_scheme": scheme.name,
                 "diffusion": "implicit" if implicit else "explicit", "cfl": cfl,
                 "stepping": "explicit"})
