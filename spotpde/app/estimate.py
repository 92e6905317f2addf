"""Run-time estimate of a tracer run, before it starts (issue 16, docs/steady.md).

The time-stepped tracer (:func:`spotpde.tracer.solve`) takes equal steps
``dt = cfl / max_c a_c`` per frame interval, ``a_c`` the per-cell positivity rate
(advection, plus explicit diffusion unless the diffusion is implicit), so the number of
steps is known from the coefficient fields before the first step:

    steps = (frames - 1) * ceil((t_end / (frames - 1)) * max a / cfl)

and the wall time is ``steps * cells / R`` with ``R`` the measured cell-update rate of
one SSP-RK3 step (three right-hand sides) on this machine, plus, with implicit
diffusion, two sparse backward-Euler solves per step. The rates below are conservative
(one thread; measured on the 2-core development machine, benchmarks/tracer.py and
benchmarks/steady.py):

* ``weno5``: 2.0e7 cell-steps per second; the other reconstructions 3.0e7; a 3D cell
  costs :data:`STEP_COST_3D` times a 2D one (a third axis of fluxes and short rows:
  47-63 against 87-109 Mcell/s a stage on one thread, docs/tracer.md);
* implicit diffusion: 8e6 cell-steps per second for the two LU solves and flux products
  (void-model propagator, 8.96e4 cells: 16 ms a step in all with one thread at a load
  average of 3, of which about 5 ms are the SSP-RK3 advection).

``tracer.stepping = "multirate"`` (and ``"auto"`` where the solver picks it,
:func:`spotpde.tracer._solve.choose_stepping`) steps the grid at the limit of the cells
outside the fast box, ``dt = cfl / max_slow a``, so its steps are known the same way;
a step costs the SSP-RK3 step of the grid, its implicit diffusion (three solves and the
limiter, measured as costly as the explicit scheme's two solves: the same rate) and the
box's sub-steps, on every grid (axisymmetric and hopper grids too).

Transient spots (``spots.mode = "transient"``, :func:`transient_estimate`) are
time-stepped before anything else: the spot density by BDF2 in ``max(20, ceil(T max v_s
/ h))`` steps of two sparse triangular solves (:data:`SPOT_DENSITY_RATE`), or, for
interacting spots, by SSP-RK2 at its explicit limit (:data:`TRAFFIC_RATE`), to
``tracer.t_end`` (the snapshots) and to ``spots.t_end``. Their tracer steps in fields
that change: its steps are those of the steady fields at the mean orifice rate (the
flow fills the silo towards them; 1037 steps against 1020 estimated), each rebuilding
the operator from interpolated fields at every stage (:data:`TRANSIENT_STEP_RATE`), and
the fields of every snapshot are computed once (:data:`FIELDS_RATE`). ``spotpde run``
makes this estimate before the spot density stage.

A run estimated at more than :data:`MAX_SECONDS` (a day) is refused unless asked for
(``spotpde run --allow-long``); ``tracer.t_end = inf`` needs no estimate (one solve).
"""

from __future__ import annotations

import math

import numpy as np

from .._roundoff import clip_roundoff
from ..errors import CaseError

#: Cell updates per second of one SSP-RK3 step, by reconstruction (one thread).
STEP_RATE = {"weno5": 2.0e7}
STEP_RATE_DEFAULT = 3.0e7
#: Cost of a 3D cell update in 2D cell updates (the fused 3D kernel, WENO5).
STEP_COST_3D = 2.0
#: Cell updates per second of the two backward-Euler solves of a step (implicit diffusion).
IMPLICIT_RATE = 8.0e6
#: Longest run started without ``--allow-long``: one day.
MAX_SECONDS = 86400.0
#: Cell updates per second of the transient spot density: a BDF2 step (two triangular
#: solves; 5.7e5-1.0e6 measured on 1.6e4 cells), an SSP-RK2 step of interacting spots
#: (1.5e6 measured).
SPOT_DENSITY_RATE = 5.0e5
TRAFFIC_RATE = 1.0e6
#: Cell updates per second of a tracer step in time-dependent fields: the operator is
#: rebuilt from interpolated fields at every stage (6.8e5 measured on 4096 cells).
TRANSIENT_STEP_RATE = 5.0e5
#: Cells per second of the particle fields of one spot-density snapshot (2.9e5 measured).
FIELDS_RATE = 2.0e5


def tracer_steps(grid, fields, t_end: float, frames: int, *, limiter: str = "weno5",
                 cfl: float = 0.9, diffusion: str = "auto", stepping: str = "explicit",
                 split: float | None = None) -> dict:
    """Steps and wall time of ``tracer.solve`` with steady ``fields``, before running it.

    Args:
        grid: the grid.
        fields: steady coefficient fields (dict), as for :func:`spotpde.tracer.solve`.
        t_end: duration (time units), finite and > 0.
        frames: output frames (>= 2).
        limiter, cfl, diffusion: the solver's options.
        stepping, split: ``"explicit"``, ``"multirate"`` or ``"auto"`` (which is decided
            as the solver decides it), and the multirate split (``None``: the default).

    Returns:
        dict: ``steps``, ``dt`` (time units), ``seconds`` (estimated wall time),
        ``implicit`` (bool), ``rate`` (1/time: ``max a`` over the cells, or over the
        cells outside the fast box for multirate), ``cells``, ``stepping``
        (``"explicit"`` or ``"multirate"``), ``split``.

    Raises:
        ValueError: ``t_end``, ``frames``, ``cfl`` or ``stepping`` out of range.
    """
    from ..tracer import _advection
    from ..tracer._geometry import operator
    from ..tracer._solve import _check_fields, choose_stepping
    if stepping not in ("explicit", "multirate", "auto"):
        raise ValueError(f'stepping: the estimate knows "explicit", "multirate" and "auto", '
                         f"got {stepping!r}")
    if not (math.isfinite(t_end) and t_end > 0):
        raise ValueError(f"t_end: must be finite and > 0, got {t_end!r}")
    if not (isinstance(frames, (int, np.integer)) and frames >= 2):
        raise ValueError(f"frames: must be an integer >= 2, got {frames!r}")
    if not (0 < cfl <= 1):
        raise ValueError(f"cfl: must be in (0, 1], got {cfl!r}")
    f = _check_fields(grid, fields, "fields")
    lim = _advection.limiter_from_name(limiter)
    # any grid: axisymmetric and hopper operators step Q = 2 pi r P on a Cartesian twin
    op = operator(grid, f, lim.code, np.ones(grid.shape[1:], dtype=bool), implicit=False)
    if diffusion == "auto":
        implicit = op.rate_explicit > 2.0 * op.rate_adv and op.rate_diff > 0
    else:
        implicit = diffusion == "implicit"
    rate = op.rate_adv if implicit else op.rate_explicit
    interval = t_end / (frames - 1)
    per = interval * rate / cfl
    n_sub = max(1, math.ceil(per - 1e-9)) if math.isfinite(per) else math.inf
    steps = n_sub * (frames - 1)
    cells = int(grid.size)
    step_rate = STEP_RATE.get(limiter, STEP_RATE_DEFAULT)
    if grid.dims == 3:
        step_rate /= STEP_COST_3D
    per_step = cells / step_rate
    if implicit:
        per_step += cells / IMPLICIT_RATE
    mode, split = choose_stepping(stepping, split, op.faces, grid.spacing, steps)
    if mode == "multirate" and math.isfinite(per):
        from ..tracer._implicit import partition
        from ..tracer._multirate import box_of
        fast, _, _, slow_rate = partition(op.faces, grid.spacing, split)
        if fast.any():
            fastest = op.rate_adv               # max of the advective rate, all cells
            rate = slow_rate
            n_sub = max(1, math.ceil(interval * rate / cfl - 1e-9))
            steps = n_sub * (frames - 1)
            box = math.prod(s.stop - s.start for s in box_of(fast))
            sub = 2 * math.ceil(0.5 * interval / n_sub * fastest / cfl)
            # the grid's step and its implicit diffusion (measured as costly as the
            # explicit step's: docs/long_runs.md), the box's sub-steps
            per_step = cells / step_rate + cells / IMPLICIT_RATE + sub * box / step_rate
            implicit = True
        else:
            mode = "explicit"
    return {"steps": steps, "dt": interval / n_sub if n_sub else math.inf,
            "seconds": steps * per_step, "implicit": bool(implicit), "rate": rate,
            "cells": cells, "stepping": mode, "split": split}


def case_estimate(case) -> dict | None:
    """:func:`fields_estimate` for a case, computing its steady spot density and fields
    (``spotpde check``; ``spotpde run`` estimates from the fields its run computes), or
    :func:`transient_estimate` for transient spots.

    Returns ``None`` where :func:`fields_estimate` does (before computing anything).
    """
    if case.spots.mode == "transient":
        return transient_estimate(case)
    if not _estimated(case):
        return None
    from ..density import spot_density
    from .pipeline import case_fields
    rho = clip_roundoff(np.asarray(spot_density.solve(case.grid, case.orifice, case.spots),
                                   dtype=float))
    return fields_estimate(case, case_fields(case, rho))


def fields_estimate(case, fields) -> dict | None:
    """:func:`tracer_steps` for a case whose steady coefficient ``fields`` are known.

    Returns ``None`` without a tracer, for ``tracer.t_end = inf`` (a steady solve),
    for transient spots (the fields change during the run), and for ``tracer.stepping``
    "imex" and "implicit" (their steps are not the CFL's). ``"auto"`` is estimated as the
    solver will run it (multirate for long runs dominated by a few fast cells).
    """
    if not _estimated(case):
        return None
    t = case.tracer
    opts = {k: case.tracer_options[k] for k in ("limiter", "cfl", "diffusion", "stepping",
                                                 "split")
            if k in case.tracer_options}
    return tracer_steps(case.grid, fields, t.t_end, t.frames, **opts)


def _estimated(case) -> bool:
    """Whether :func:`fields_estimate` estimates the case's tracer run (see there)."""
    t = case.tracer
    if t is None or math.isinf(t.t_end) or case.spots.mode == "transient":
        return False
    return case.tracer_options.get("stepping", "explicit") not in ("imex", "implicit")


def spot_density_runs(case) -> list[dict]:
    """The time-stepped spot-density solves of a case (none for steady spots), before
    computing anything: ``[{"key", "t_end", "steps", "seconds"}, ...]``, ``key`` the case
    key that sets ``t_end`` (``tracer.t_end`` for the snapshots behind a tracer,
    ``spots.t_end`` for the reported ``rho_s``)."""
    s = case.spots
    if s.mode != "transient":
        return []
    from ..density.spot_density import pad_cells

    t = case.tracer
    ends = [("tracer.t_end", t.t_end)] if t is not None else []
    if s.rho_max is not None or t is None or t.t_end != s.t_end:
        ends.append(("spots.t_end", s.t_end))
    grid = case.grid
    p = pad_cells(grid, s.b) if grid.geometry.uniform_cells else 0
    cells = grid.size * math.prod((n + 2 * p) / n for n in grid.shape[1:])
    v = float(np.max(s.drift))
    h = grid.spacing
    if s.rho_max is not None:      # the explicit bound-preserving step (density.traffic)
        d_sum = float(np.max(s.b_par)) * v + (grid.dims - 1) * float(np.max(s.b)) * v
        per, rate = 0.9 / (2.0 * v / h + 2.0 * d_sum / h**2), TRAFFIC_RATE
    else:
        per, rate = h / v, SPOT_DENSITY_RATE
    out = []
    for key, end in ends:
        steps = max(1 if s.rho_max is not None else 20, math.ceil(end / per - 1e-9))
        out.append({"key": key, "t_end": end, "steps": steps, "seconds": steps * cells / rate})
    return out


def transient_estimate(case) -> dict | None:
    """Steps and wall time of a case with transient spots (module docstring): the
    spot-density solves (:func:`spot_density_runs`) and a finite tracer's steps in the
    fields that change, from the steady fields of the case at its mean orifice rate.

    Returns:
        dict: ``spot_density`` (:func:`spot_density_runs`), ``seconds`` (all of it), and
        with a tracer :func:`tracer_steps`'s keys for its steps (``tracer_seconds``: its
        share); ``None`` for steady spots.
    """
    if case.spots.mode != "transient":
        return None
    runs = spot_density_runs(case)
    est = {"spot_density": runs, "steps": None, "seconds": sum(r["seconds"] for r in runs)}
    t = case.tracer
    if t is None:
        return est
    try:
        steady = case_estimate(_steady_twin(case))
    except Exception:    # noqa: BLE001 - the run itself reports what is wrong
        steady = None
    if steady is not None:
        cells = steady["cells"]
        per = cells / TRANSIENT_STEP_RATE + (cells / IMPLICIT_RATE if steady["implicit"]
                                             else 0.0)
        snaps = len(case.snapshot_times())
        tracer = steady["steps"] * per + snaps * cells / FIELDS_RATE
        est.update({**steady, "tracer_seconds": tracer, "seconds": est["seconds"] + tracer})
    return est


def _steady_twin(case):
    """The case with steady spots at its mean orifice rate over ``[0, tracer.t_end]`` (no
    noise, no interaction): the fields a transient flow fills towards."""
    from .cases import load_case

    data = {name: dict(table) for name, table in case.data.items()}
    rate = data["orifice"]["rate"]
    if isinstance(rate, dict):
        times = np.linspace(0.0, data["tracer"]["t_end"], 1001)
        rate = float(np.mean(np.interp(times, rate["times"], rate["values"])))
    data["orifice"].update(rate=max(rate, 1e-300))
    data["orifice"].pop("noise", None)
    data["spots"].update(mode="steady", t_end=0.0)
    for key in ("rho_max", "flux", "diffusion_scaling", "frames"):
        data["spots"].pop(key, None)
    data["tracer"]["snapshots"] = "auto"
    data.pop("pair", None)
    return load_case(data)


def describe(est: dict) -> str:
    """One line: steps, time step and estimated wall time."""
    runs = est.get("spot_density") or []
    parts = [f"spot density to {r['key']} = {r['t_end']:.3g}: {r['steps']:.3g} steps"
             for r in runs]
    if est.get("steps") is not None:
        how = (f"multirate, split {est['split']:g}" if est.get("stepping") == "multirate"
               else f"{'implicit' if est['implicit'] else 'explicit'} diffusion")
        parts.append(f"tracer: {est['steps']:.3g} steps of dt = {est['dt']:.3g} ({how})")
    return f"{'; '.join(parts)}, about {_duration(est['seconds'])} on this machine"


def refuse_if_long(case, est: dict | None, allow_long: bool = False) -> None:
    """Raise :class:`CaseError` (one line naming ``tracer.t_end``, ``tracer.cfl`` or
    ``spots.t_end``) when the run is estimated at more than :data:`MAX_SECONDS` and
    ``allow_long`` is false."""
    if est is None or allow_long or est["seconds"] <= MAX_SECONDS:
        return
    runs = est.get("spot_density") or []
    if runs and (est.get("steps") is None or
                 max(r["seconds"] for r in runs) >= est.get("tracer_seconds", 0.0)):
        r = max(runs, key=lambda r: r["seconds"])
        raise CaseError(f"{r['key']}: the run would take about {_duration(est['seconds'])} "
                        f"(the transient spot density: {r['steps']:.3g} steps to "
                        f"{r['key']} = {r['t_end']:.3g}), more than a day; shorten "
                        f"{r['key']}, use a larger domain.spacing, or pass --allow-long, "
                        f"got {r['t_end']!r}")
    cfl = case.tracer_options.get("cfl", 0.9)
    # blame the cfl when the default would have made the run acceptable
    key, value = ("tracer.cfl", cfl) if est["seconds"] * cfl / 0.9 <= MAX_SECONDS else \
        ("tracer.t_end", case.tracer.t_end)
    faster = ("" if case.spots.mode == "transient" else
              "set tracer.t_end = inf for the geometrical propagator (one solve), "
              "tracer.stepping = \"multirate\" or \"implicit\" for long runs, ")
    raise CaseError(f"{key}: the run would take about {_duration(est['seconds'])} "
                    f"({est['steps']:.3g} steps of dt = {est['dt']:.3g}), more than a day; "
                    f"shorten tracer.t_end, {faster}or pass --allow-long, got {value!r}")


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "forever"
    for unit, s in (("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= 2 * s:
            return f"{seconds / s:.3g} {unit}"
    return f"{seconds:.3g} s"
