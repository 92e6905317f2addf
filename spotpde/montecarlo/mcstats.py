"""Honest statistics for comparing the discrete spot model with the continuum.

A Monte Carlo estimate is only as good as its standard error. Particles closer than the
kernel's diameter ``2R`` share spots, so their displacements are correlated (for the
paper's disk ``integral C_p**2 dA ~ 9 d**2``): counting them as independent samples
(``sqrt(n)/N``) underestimates the error several-fold. Time batches shorter than the
time a spot takes to pass (``2R / v_s``, or the transit time for whole-silo quantities)
do the same. The safe errors come from **independent replicas** (different seeds, the
same set-up): the scatter of a quantity over ``R`` replicas, divided by ``sqrt(R)``.

This module collects what the comparisons need (docs/montecarlo.md, section 9):

* :func:`replicas` runs a function over seeds (sequentially, or as Dask tasks);
  :func:`replica_mean` gives the mean and its standard error over replicas.
  :func:`t_limit` is the Student-t multiple of the standard error for a check with
  ``R`` replicas.
* :func:`se_calibration` compares a run's own standard errors with the scatter between
  replicas, and :func:`zscore_spread` checks that z-scores ``(estimate - exact) / SE``
  have unit spread (chi-square tests): this is how the standard errors are tested.
* :func:`discard` drops a run's first probe batches (the warm-up while the spots fill
  the silo); :func:`positions_at` returns tracked positions at a snapshot time.
* :func:`particle_density` turns particle positions into a tracer density ``P0`` on the
  grid, so that the continuum starts from the particles' actual distribution;
  :func:`drained_fraction` counts the particles that left through the orifice.
* :func:`continuum_drainage` evolves such a ``P0`` with the continuum's fields and
  returns the fraction drained, the continuum's counterpart of
  :func:`drained_fraction`.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Callable, Iterable, Mapping

import numpy as np
from scipy import stats

from .. import tracer
from ..grid import Grid

__all__ = ["replicas", "replica_mean", "t_limit", "zscore_spread", "se_calibration", "discard",
           "positions_at", "particle_density", "drained_fraction", "continuum_drainage"]


def replicas(run: Callable[[int], object], seeds: Iterable[int], *,
             scheduler: str | None = None) -> list:
    """``[run(seed) for seed in seeds]``: independent replicas of one Monte Carlo set-up.

    Args:
        run: a function of the seed returning anything (typically a number, a dict of
            numbers or an :class:`~spotpde.montecarlo.MCResult`).
        seeds: distinct integer seeds (numba's generator is seeded from them, so the
            replicas are independent).
        scheduler: ``None`` runs them in this process one after the other; otherwise a
            Dask scheduler name (``"threads"``, ``"processes"``, ``"synchronous"``) and
            the replicas run as ``dask.delayed`` tasks.

    Returns:
        list of the results, in the order of ``seeds``.

    Raises:
        ValueError: ``seeds`` is empty or has repeated values.
    """
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds: need at least one seed")
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds: replicas need distinct seeds, got {seeds}")
    if scheduler is None:
        return [run(s) for s in seeds]
    import dask

    tasks = [dask.delayed(run)(s) for s in seeds]
    return list(dask.compute(*tasks, scheduler=scheduler))


def replica_mean(values, axis: int = 0) -> tuple[np.ndarray | float, np.ndarray | float]:
    """Mean over independent replicas and its standard error ``sd / sqrt(R)``.

    Args:
        values: array with the replicas along ``axis`` (``R >= 2``).

    Returns:
        ``(mean, se)``, floats for 1-D input.

    Raises:
        ValueError: fewer than two replicas.
    """
    v = np.asarray(values, dtype=float)
    n = v.shape[axis] if v.ndim else 0
    if n < 2:
        raise ValueError(f"values: need at least 2 replicas along axis {axis}, got {n}")
    mean = v.mean(axis=axis)
    se = v.std(axis=axis, ddof=1) / math.sqrt(n)
    if np.ndim(mean) == 0:
        return float(mean), float(se)
    return mean, se


def zscore_spread(z, level: float = 1e-3) -> dict:
    """Is a set of z-scores ``(estimate - exact) / SE`` consistent with unit spread?

    If the standard errors are right and the ``n`` z-scores independent, ``sum z**2``
    follows a chi-square law with ``n`` degrees of freedom (exactly for Gaussian
    estimates, approximately otherwise). Standard errors three times too large give
    ``rms ~ 1/3``, three times too small ``rms ~ 3``.

    Args:
        z: z-scores (any shape; NaN entries are dropped).
        level: two-sided significance of the test (default 1e-3: a calibrated estimator
            fails it once in a thousand runs).

    Returns:
        dict with ``n``, ``rms = sqrt(mean z**2)``, ``mean``, the acceptance interval of
        ``rms`` (``rms_low``, ``rms_high``, the chi-square quantiles ``level/2`` and
        ``1 - level/2`` over ``n``, square-rooted), ``p`` (two-sided p-value) and
        ``calibrated`` (``rms_low <= rms <= rms_high``).

    Raises:
        ValueError: fewer than two finite z-scores.
    """
    z = np.asarray(z, dtype=float).ravel()
    z = z[np.isfinite(z)]
    n = z.size
    if n < 2:
        raise ValueError(f"z: need at least 2 finite z-scores, got {n}")
    if not 0 < level < 1:
        raise ValueError(f"level: must be in (0, 1), got {level}")
    q = float(np.sum(z * z))
    lo = math.sqrt(stats.chi2.ppf(0.5 * level, n) / n)
    hi = math.sqrt(stats.chi2.ppf(1 - 0.5 * level, n) / n)
    cdf = float(stats.chi2.cdf(q, n))
    rms = math.sqrt(q / n)
    return {"n": n, "rms": rms, "mean": float(z.mean()), "rms_low": lo, "rms_high": hi,
            "p": 2 * min(cdf, 1 - cdf), "calibrated": lo <= rms <= hi}


def se_calibration(estimates, standard_errors, level: float = 1e-3) -> dict:
    """Do a run's own standard errors match the scatter between independent replicas?

    For ``m`` independent quantities (columns) estimated in ``R`` replicas (rows), each
    with the run's own standard error, the ratio of the scatter over replicas to the
    quoted error is, pooled over the quantities,

        ratio = sqrt( mean_j [ var_R(estimate_j) / mean_R(SE_j**2) ] ).

    With correct errors (and Gaussian estimates) ``ratio**2`` follows
    ``chi2(m (R - 1)) / (m (R - 1))``; tripled errors give ``ratio ~ 1/3``. Unlike the
    z-scores of :func:`zscore_spread`, the ratio needs no exact value and is not
    inflated by the noise of each run's own error estimate (which makes single z-scores
    Student-t rather than Gaussian when the error rests on few batches).

    Args:
        estimates, standard_errors: arrays ``(R, m)`` (or ``(R,)`` for one quantity),
            ``R >= 2`` independent replicas (different seeds).
        level: two-sided significance of the acceptance interval.

    Returns:
        dict with ``ratio``, ``low``, ``high`` (acceptance interval of ``ratio``),
        ``dof`` and ``calibrated``.
    """
    e = np.asarray(estimates, dtype=float)
    s = np.asarray(standard_errors, dtype=float)
    if e.shape != s.shape:
        raise ValueError(f"standard_errors: shape {s.shape} differs from estimates' {e.shape}")
    if e.ndim == 1:
        e, s = e[:, None], s[:, None]
    R, m = e.shape
    if R < 2:
        raise ValueError(f"estimates: need at least 2 replicas (rows), got {R}")
    if not (np.all(np.isfinite(e)) and np.all(s > 0)):
        raise ValueError("estimates, standard_errors: need finite estimates and positive errors")
    f = np.mean(e.var(axis=0, ddof=1) / np.mean(s * s, axis=0))
    dof = m * (R - 1)
    lo = math.sqrt(stats.chi2.ppf(0.5 * level, dof) / dof)
    hi = math.sqrt(stats.chi2.ppf(1 - 0.5 * level, dof) / dof)
    ratio = math.sqrt(f)
    return {"ratio": ratio, "low": lo, "high": hi, "dof": dof, "calibrated": lo <= ratio <= hi}


def discard(result, t: float):
    """The run without the probe batches that start before time ``t``.

    Probe averages (``montecarlo.measure``) then cover only ``[t_b, t_end]`` with
    ``t_b >= t`` the first batch start at or after ``t`` (whole batches are dropped; the
    warm-up while the spots fill the silo, ``(z1 - z0) / v_s``, is the usual ``t``).
    Tracked trajectories are left as they are.

    Args:
        result: :class:`~spotpde.montecarlo.MCResult` with probes.
        t: time to discard (>= 0).

    Returns:
        a new :class:`~spotpde.montecarlo.MCResult` (arrays shared, not copied).

    Raises:
        ValueError: no probes, ``t < 0``, or fewer than two batches would be left.
    """
    if result.probe is None:
        raise ValueError("result: the run has no probes (simulate(..., probes=True))")
    if not t >= 0:
        raise ValueError(f"t: must be >= 0, got {t}")
    starts = np.concatenate([[0], np.cumsum(result.batch_ticks)[:-1]]) * result.dt
    skip = int(np.searchsorted(starts, t - 1e-9 * max(result.dt, 1.0)))
    bt = result.batch_ticks[skip:]
    if bt.size < 2:
        raise ValueError(f"t: discarding {t} leaves {bt.size} probe batches; need at least 2")
    return dataclasses.replace(result, probe=result.probe[:, skip:],
                               rho_hist=result.rho_hist[skip:], batch_ticks=bt,
                               n_ticks=int(bt.sum()), t_end=float(bt.sum() * result.dt))


def positions_at(result, t: float, tol: float | None = None) -> np.ndarray:
    """Tracked particle positions ``(n_tracked, 2)`` (3D: ``(n_tracked, 3)``, columns
    ``(x, z, y)``) at snapshot time ``t`` (NaN: gone).

    ``t = 0`` is the initial state. Raises ValueError if no snapshot lies within ``tol``
    (default half a tick) of ``t``.
    """
    times = np.concatenate([[0.0], result.times])
    k = int(np.argmin(np.abs(times - t)))
    tol = 0.5 * result.dt if tol is None else tol
    if abs(times[k] - t) > tol:
        raise ValueError(f"t: no snapshot at {t} (nearest {times[k]}); choose `records` so "
                         "that the snapshot times include it")
    if k == 0:
        return result.initial[result.tracked].copy()
    return result.positions[k - 1].copy()


def particle_density(grid: Grid, points, weights=None) -> np.ndarray:
    """Particle positions as a tracer density on the grid, normalised to 1.

    ``P0[k, i] = (number of points in cell (k, i)) / (N h**2)`` (3D: cells ``(k, j, i)``
    of ``(z, y, x)``, ``/ (N h**3)``): the empirical
    distribution of the particles, cell-averaged. The continuum tracer is linear, so
    started from this ``P0`` it predicts the mean over these particles of any
    single-particle probability (such as having drained by time ``t``), up to the
    position of each particle inside its cell (an ``O(h)`` smoothing). Averaging the
    ``P0`` of several replicas gives the prediction for the replica average.

    Args:
        grid: 2D or 3D rectangular grid, or an axisymmetric grid.
        points: ``(N, 2)`` positions ``(x, z)``, 3D ``(N, 3)`` in columns ``(x, z, y)``
            (the Monte Carlo's order); rows with NaN (gone) are ignored.
            Axisymmetric grid: ``(N, 2)`` as ``(r, z)`` or the Monte Carlo's ``(N, 3)``
            ``(x, z, y)``, binned in ``(r, z)`` and divided by the ring volumes
            ``2 pi r h**2`` (the continuum tracer's ``P``, per d**3).
        weights: optional per-point weights (default 1).

    Raises:
        ValueError: wrong shape, or no point inside the grid.
    """
    p = np.asarray(points, dtype=float)
    if grid.geometry.curved and p.ndim == 2 and p.shape[1] == 3:   # (x, z, y) -> (r, z)
        p = np.column_stack([np.hypot(p[:, 0], p[:, 2]), p[:, 1]])
    if p.ndim != 2 or p.shape[1] != grid.dims:
        raise ValueError(f"points: need an (N, {grid.dims}) array of "
                         f"{'(x, z)' if grid.dims == 2 else '(x, z, y)'}, got shape {p.shape}")
    w = np.ones(len(p)) if weights is None else np.asarray(weights, dtype=float)
    ok = np.isfinite(p).all(axis=1)
    h = grid.spacing
    ex = np.concatenate([grid.x - 0.5 * h, [grid.x[-1] + 0.5 * h]])
    ez = np.concatenate([grid.z - 0.5 * h, [grid.z[-1] + 0.5 * h]])
    if grid.dims == 3:
        ey = np.concatenate([grid.y - 0.5 * h, [grid.y[-1] + 0.5 * h]])
        H, _ = np.histogramdd(p[ok][:, [1, 2, 0]], bins=[ez, ey, ex], weights=w[ok])
    else:
        H, _, _ = np.histogram2d(p[ok, 1], p[ok, 0], bins=[ez, ex], weights=w[ok])
    total = H.sum()
    if not total > 0:
        raise ValueError("points: no particle inside the grid")
    if grid.geometry.curved:   # rings: per unit volume, sum(P * ring volumes) = 1
        return H / (total * grid.geometry.cell_volumes)
    return H / (total * grid.cell_volume)


def drained_fraction(result, select, t0: float, t1: float) -> float:
    """Fraction of the selected tracked particles present at ``t0`` that are gone at ``t1``.

    Args:
        result: run with tracked particles (snapshots at ``t0`` and ``t1``).
        select: boolean mask over the tracked particles (e.g. coloured at ``t0``).
        t0, t1: snapshot times, ``t0 < t1``.
    """
    if not t1 > t0:
        raise ValueError(f"t1: must be > t0 = {t0}, got {t1}")
    a, b = positions_at(result, t0), positions_at(result, t1)
    sel = np.asarray(select, dtype=bool) & np.isfinite(a).all(axis=1)
    if not sel.any():
        raise ValueError("select: no selected particle is present at t0")
    gone = ~np.isfinite(b).all(axis=1)
    return float(np.sum(gone & sel) / np.sum(sel))


def continuum_drainage(grid: Grid, fields: Mapping[str, np.ndarray], P0: np.ndarray,
                       t: float, **tracer_options) -> float:
    """Probability that has left through the orifice by time ``t``, starting from ``P0``.

    ``tracer.solve`` with the given fields (``u_x``, ``u_z``, ``D_xx``, ``D_xz``,
    ``D_zz``) from ``P0`` (:func:`particle_density`, or ``pipeline.initial_density``);
    returns ``outflow(t) / integral(P0)``.
    """

    P0 = np.asarray(P0, dtype=float)
    mass = float(P0.sum() * grid.cell_volume)
    if not mass > 0:
        raise ValueError("P0: carries no probability")
    res = tracer.solve(grid, dict(fields), P0, float(t), 2, **tracer_options)
    return float(res.outflow[-1]) / mass


def t_limit(replicas: int, level: float = 0.01) -> float:
    """Two-sided ``1 - level`` quantile of Student's t with ``replicas - 1`` degrees of freedom.

    With ``R`` replicas the standard error is itself estimated from ``R - 1`` degrees of
    freedom, so ``(mean - exact) / se`` follows Student's t, not a Gaussian: a check
    ``|mean - exact| < t_limit(R) * se`` fails a correct estimate with probability
    ``level`` (for ``R = 6``: 4.03 standard errors at 1 %; ``R = 10``: 3.25).
    """
    if replicas < 2:
        raise ValueError(f"replicas: need at least 2, got {replicas}")
    return float(stats.t.ppf(1 - 0.5 * level, replicas - 1))
