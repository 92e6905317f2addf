"""Time stepping of the tracer equation: step drivers and the frame tracker (private).

:func:`spotpde.tracer.solve` advances ``P`` from one output frame to the next with a
*driver* and hands every frame to a *tracker* (the split of py-pde's solvers and
trackers):

* :class:`_FixedStepper` (steady coefficients): ``n_sub = ceil(interval a / cfl)`` equal
  steps ``dt = interval / n_sub`` per frame interval, ``a`` the per-cell positivity rate
  of the one operator (1 / unit time), so ``dt a <= cfl``;
* :class:`_AdaptiveStepper` (time-dependent coefficients): each step takes
  ``dt = remaining / ceil(remaining a / cfl)`` to the next frame and re-chooses it with
  ``a`` the largest rate of the operators at the Runge-Kutta stage times until
  ``dt a <= 1`` (at most 30 tries, else ``NumericalError``);
* :class:`_FrameTracker`: the output times, the kept (or handed-out) frames, mass
  ``sum(P) h**dims`` and cumulative outflow per frame, the checks (finite, ``P >= 0``,
  ``|mass + outflow - mass0| / mass0 <= check_mass``) and the progress calls.

One step (:meth:`_Stepper._advance`) is the SSP Runge-Kutta step :func:`_rk_step` of
``dP/dt = L(P)``; with implicit diffusion it is Strang split,
``P <- (I - dt/2 L_D(t + dt))^-1 RK_dt (I - dt/2 L_D(t))^-1 P`` (:func:`_implicit_step`).
The drivers accumulate the outflow ``budget`` (floor, sides, top; probability) with the
Runge-Kutta weights and the statistics ``steps``, ``max_cfl = max dt a`` and
``max_courant = max |u| dt / h``.
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from ._operator import _Operator, _rhs, _Workspace
from ..errors import NumericalError
from ..grid import Grid


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


def _implicit_step(op: _Operator, P: np.ndarray, tau: float, ws: _Workspace) -> np.ndarray:
    """Backward-Euler diffusion ``(I - tau L_D) P_new = P`` over ``tau``; its face flux
    times ``tau`` is added to ``ws.Fz_acc``."""
    if not op.terms or op.rate_diff == 0.0:
        return P
    Pn, Fz = op.backward_euler(P, tau)
    ws.Fz_acc += tau * Fz
    return np.ascontiguousarray(Pn)


class _Stepper:
    """One time step of the tracer equation and its statistics (base of the drivers).

    Args:
        op_at: ``t -> _Operator`` at time ``t``.
        scheme: SSP Runge-Kutta scheme (:mod:`._timestepping`).
        ws: the solve's :class:`_Workspace`.
        implicit: Strang-split backward-Euler diffusion around the Runge-Kutta step.
        spacing: grid spacing ``h`` in d (for the Courant number).
    """

    def __init__(self, op_at: Callable[[float], _Operator], scheme, ws: _Workspace,
                 implicit: bool, spacing: float):
        self.op_at = op_at
        self.scheme = scheme
        self.ws = ws
        self.implicit = implicit
        self.h = spacing
        self.budget = [0.0, 0.0, 0.0]       # floor, sides, top
        self.steps = 0
        self.max_cfl = 0.0
        self.max_courant = 0.0

    def _advance(self, P, ops, dt, t):
        if self.implicit:
            P = _implicit_step(self.op_at(t), P, 0.5 * dt, self.ws)
            P = _rk_step(ops, P, dt, self.scheme, self.ws, self.budget)
            return _implicit_step(self.op_at(t + dt), P, 0.5 * dt, self.ws)
        return _rk_step(ops, P, dt, self.scheme, self.ws, self.budget)


class _FixedStepper(_Stepper):
    """Steady coefficients: ``n_sub`` equal steps per frame interval (module docstring)."""

    def __init__(self, op: _Operator, scheme, ws: _Workspace, implicit: bool, spacing: float,
                 interval: float, cfl: float):
        super().__init__(lambda t: op, scheme, ws, implicit, spacing)
        self.op = op
        self.interval = interval
        self.n_sub = max(1, math.ceil(interval * op.rate / cfl - 1e-9))

    def advance_to(self, P, t, t_target, tick: Callable[[int, float], None]):
        """Advance ``P`` from ``t`` to ``t_target``; returns ``(P, t_target)``."""
        op, n_sub = self.op, self.n_sub
        dt = self.interval / n_sub
        ops = [op] * self.scheme.stages
        for m in range(n_sub):
            P = self._advance(P, ops, dt, t)
            t = t_target if m == n_sub - 1 else t + dt
            self.steps += 1
            tick(self.steps, t)
        self.max_cfl = max(self.max_cfl, dt * op.rate)
        self.max_courant = max(self.max_courant, dt * op.umax / self.h)
        return P, t


class _AdaptiveStepper(_Stepper):
    """Time-dependent coefficients: each ``dt`` checked at the stage times (module docstring)."""

    def __init__(self, op_at: Callable[[float], _Operator], scheme, ws: _Workspace,
                 implicit: bool, spacing: float, cfl: float, t_end: float):
        super().__init__(op_at, scheme, ws, implicit, spacing)
        self.cfl = cfl
        self.t_end = t_end

    def advance_to(self, P, t, t_target, tick: Callable[[int, float], None]):
        """Advance ``P`` from ``t`` to ``t_target``; returns ``(P, t)``."""
        scheme, cfl, op_at = self.scheme, self.cfl, self.op_at
        while t_target - t > 1e-13 * self.t_end:
            remaining = t_target - t
            rate = op_at(t).rate
            for _ in range(30):
                dt = remaining / max(1, math.ceil(remaining * rate / cfl - 1e-9))
                stage_times = [t + c * dt for c in scheme.c] + ([t + dt] if self.implicit else [])
                ops = [op_at(s) for s in stage_times]
                rate_step = max(o.rate for o in ops)
                if dt * rate_step <= 1.0:
                    break
                rate = rate_step
            else:
                raise NumericalError(f"tracer: no stable time step found at t = {t:g}")
            P = self._advance(P, ops[:scheme.stages], dt, t)
            t = t_target if dt >= remaining else t + dt
            self.steps += 1
            self.max_cfl = max(self.max_cfl, dt * rate_step)
            self.max_courant = max(self.max_courant, dt * max(o.umax for o in ops) / self.h)
            tick(self.steps, t)
        return P, t


class _FrameTracker:
    """Output frames, the mass budget and its checks, progress (module docstring).

    Args:
        grid: the grid.
        P0: initial density (1/d**dims); frame 0.
        t_end: final time; frames at ``linspace(0, t_end, frames)``.
        frames: number of frames (>= 2).
        on_frame: ``on_frame(index, time, P)`` or ``None`` (frames kept in ``P``).
        progress: ``progress(fraction)`` or ``None``.
        check_mass: relative tolerance of ``mass + outflow`` against the initial mass.
        every: call ``progress`` every this many steps (plus once per frame).
    """

    def __init__(self, grid: Grid, P0: np.ndarray, t_end: float, frames: int,
                 on_frame, progress, check_mass: float, every: int):
        self.hv = grid.cell_volume
        self.t_end = t_end
        self.frames = frames
        self.on_frame = on_frame
        self.progress = progress
        self.check_mass = check_mass
        self.every = every
        self.times = np.linspace(0.0, float(t_end), frames)
        if on_frame is None:
            self.P = np.empty((frames,) + grid.shape)
            self.P[0] = P0
        else:
            self.P = None
            on_frame(0, 0.0, P0)
        self.mass = np.empty(frames)
        self.outflow = np.zeros(frames)
        self.mass[0] = P0.sum() * self.hv
        self.mass0 = self.mass[0]
        self.mass_error = 0.0
        self.ptiny = 1e-12 * max(float(P0.max()), 1e-300)

    def tick(self, steps: int, t: float) -> None:
        """After a step: ``progress(t / t_end)`` every ``every`` steps."""
        if self.progress is not None and steps % self.every == 0:
            self.progress(min(1.0, t / self.t_end))

    def record(self, j: int, t: float, P: np.ndarray, budget, max_cfl: float) -> None:
        """Frame ``j`` reached at time ``t``: mass, outflow, checks, then keep or hand out.

        Raises:
            NumericalError: NaN or infinite ``P``, ``P < -1e-12 max(P0)`` or a mass budget
                broken by more than ``check_mass`` (the message names the time).
        """
        mass, outflow = self.mass, self.outflow
        mass[j] = P.sum() * self.hv
        outflow[j] = sum(budget)
        pmin = float(P.min()) if P.size else 0.0
        if not np.isfinite(pmin) or not np.isfinite(mass[j]):
            raise NumericalError(f"tracer: P became NaN or infinite by t = {t:g}")
        if pmin < -self.ptiny:
            raise NumericalError(f"tracer: negative probability P = {pmin:.3g} at t = {t:g} "
                                 f"(positivity limit exceeded: max dt*a = {max_cfl:.3g})")
        err = abs(mass[j] + outflow[j] - self.mass0) / max(self.mass0, 1e-300)
        self.mass_error = max(self.mass_error, err)
        if err > self.check_mass:
            raise NumericalError(f"tracer: mass budget broken at t = {t:g}: mass + outflow "
                                 f"differs from the initial mass by {err:.3g} (relative)")
        if self.P is None:
            self.on_frame(j, float(self.times[j]), P)
        else:
            self.P[j] = P
        if self.progress is not None:
            self.progress(j / (self.frames - 1))

    def result(self, result_cls, faces: np.ndarray, budget, *, steps: int, max_cfl: float,
               max_courant: float, options: dict):
        """The run packed as ``result_cls`` (:class:`spotpde.tracer.TracerResult`): the
        frames, mass budget and checks kept here, ``P_height`` from the accumulated
        downward face fluxes ``faces`` (cell value: the mean of its two faces), the exits
        ``budget`` (floor, sides, top) and the stepper's statistics."""
        return result_cls(
            times=self.times, P=self.P, mass=self.mass, outflow=self.outflow,
            P_height=0.5 * (faces[:-1] + faces[1:]), P_height_faces=faces,
            steps=steps, max_cfl=max_cfl, max_courant=max_courant,
            mass_error=self.mass_error,
            outflow_by_boundary={"floor": budget[0], "sides": budget[1], "top": budget[2]},
            options=options)
