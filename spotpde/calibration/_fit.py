"""The calibration itself (private; see :mod:`spotpde.calibration`).

Weighted least squares (lmfit's trust-region-reflective ``least_squares`` with bounds) of
the residuals ``r = (m(theta) - y) / sigma`` over the free case keys ``theta``.

Standard errors. The entries of ``y`` are not independent (neighbouring cells of a
coarse-grained field, grains moved by the same spot), so ``(J^T J)^-1`` of the weighted
Jacobian understates the errors. The fit is linearised at the optimum,
``delta theta = (J^T J)^-1 J^T (delta y / sigma)``, and applied to the delete-one-block
jackknife replicates of the data (``spotpde.observables``: every observable is measured
on the same time blocks, so their correlations are kept):

    Cov(theta) = (B - 1)/B sum_b dtheta_b dtheta_b^T,  dtheta_b = (J^T J)^-1 J^T (y_(b) - ybar) / sigma

(the jackknife estimate of a sandwich covariance; e.g. Shao & Tu, *The Jackknife and
Bootstrap*, 1995, ch. 2). ``stderr`` is its diagonal; ``stderr_naive`` the textbook
``(J^T J)^-1`` one, kept for comparison.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Mapping, Sequence

import lmfit
import numpy as np
import xarray as xr

from ..app.cases import Case, load_case
from ..errors import NumericalError
from ..observables import measure
from ..tracks import read
from ._posterior import sample_posterior
from ._forward import Forward, Targets, bounds_for, jacobian, observables_for_fit
from ._result import result_dataset

__all__ = ["fit", "RELATIVE_STEP"]

#: Relative step of the finite-difference Jacobian (the model's quadratures are accurate
#: to ~1e-4 relative, so much smaller steps would difference round-off).
RELATIVE_STEP = 2e-3


def _pname(index: int) -> str:
    """lmfit's name of the ``index``-th free key (dotted keys are not Python names)."""
    return f"p{index}"


def _steps(values, lo, hi) -> np.ndarray:
    values, lo, hi = (np.asarray(a, float) for a in (values, lo, hi))
    step = RELATIVE_STEP * np.maximum(np.abs(values), 1e-3 * (hi - lo))
    # step away from an upper bound
    return np.where(values + step > hi, -step, step)


def fit(case, tracks, free: Mapping[str, tuple[float, float] | None],
        observables: Sequence[str] | str | None = None, *, blocks: int = 10,
        options: Mapping[str, Mapping] | None = None, heights=None,
        measurement: xr.Dataset | None = None, client=None, sample: Mapping | None = None,
        max_nfev: int | None = None,
        progress: Callable[[int, float], None] | None = None) -> xr.Dataset:
    """Fit free case keys to tracked grains (docs/calibration.md, section 4).

    Args:
        case: the case (a Case, a case file or a mapping); its own values start the fit.
        tracks: tracks (``spotpde.tracks.read``) or a file ``read`` accepts with defaults.
        free: ``{dotted key: (lower, upper)}`` (``None`` for default bounds), any numeric
            case keys: ``spots.b``, ``spots.b_par``, ``kernel.size``, ``kernel.height`` or
            ``kernel.volume``, ``kernel.aspect``, ``kernel.rule``, ``orifice.rate``, ...
        observables: names from ``spotpde.calibration.FITTABLE``, or one variable of one
            (``"diffusion.b_p"``: the horizontal diffusion alone); default the mean flow and
            the diffusion: ``("velocity", "diffusion")``.
        blocks: time blocks of the errors. options, heights: as
            ``spotpde.observables.measure``.
        measurement: a ready ``spotpde.observables.measure`` result (then ``tracks`` may
            be ``None`` and ``observables`` defaults to the measurement's).
        client: a ``dask.distributed.Client``: the Jacobian's columns (and posterior
            walkers) run on it in parallel.
        sample: ``{"walkers": 16, "steps": 300, "seed": 0}`` to sample the posterior with
            emcee after the fit (needs the ``posterior`` extra).
        max_nfev: most model evaluations of the least-squares search.
        progress: ``progress(evaluations, chi2)`` after every model evaluation.

    Returns:
        Dataset with dim ``parameter`` (the dotted keys): ``value``, ``stderr``,
        ``stderr_naive``, ``initial``, ``lower``, ``upper``; ``correlation``
        (``parameter``, ``parameter_2``); per fitted variable ``data_V``, ``data_V_se``,
        ``model_V`` and ``residual_V`` (in standard errors); attributes ``chi2``,
        ``chi2_reduced``, ``n_data``, ``nfev``, ``success``, ``report`` (which observables
        the best fit reproduces and which it does not), ``case`` (the best-fit case).

    Raises:
        ValueError: a bad argument (named). spotpde.NumericalError: the model failed.
    """
    began = time.perf_counter()
    if not isinstance(case, Case):
        case = load_case(case)
    if measurement is None:
        if isinstance(tracks, (str, os.PathLike)):
            tracks = read(tracks)
        names = observables_for_fit(observables)
        measurement = measure(tracks, case, list(names), blocks=blocks, options=options,
                              heights=heights)
    else:
        names = observables_for_fit(observables if observables is not None
                                    else measurement.attrs.get("observables"))
    start = bounds_for(case, free)
    keys = list(start)
    x0 = np.array([start[k][0] for k in keys])
    lo = np.array([start[k][1] for k in keys])
    hi = np.array([start[k][2] for k in keys])
    cg = float(measurement.attrs.get("velocity.cg_width", 1.0))
    targets = Targets(measurement, names, stride=max(1, int(round(cg / case.grid.spacing))))
    forward = Forward(case, keys, targets)
    memo = {}

    def model_vector(values):
        key = tuple(np.asarray(values, float))
        if key not in memo:
            if len(memo) > 64:
                memo.clear()
            memo[key] = forward(values)
            if progress is not None:
                r = (memo[key] - targets.y) / targets.sigma
                progress(forward.evaluations, float(r @ r))
        return memo[key]

    def values_of(params):
        return np.array([params[_pname(i)].value for i in range(len(keys))])

    def residual(params):
        return (model_vector(values_of(params)) - targets.y) / targets.sigma

    def jac(params, *args, **kwargs):
        v = values_of(params)
        J = jacobian(forward, v, _steps(v, lo, hi), base=model_vector(v), client=client)
        return J / targets.sigma[:, None]

    params = lmfit.Parameters()
    for i, (v, a, b) in enumerate(zip(x0, lo, hi)):
        params.add(_pname(i), value=v, min=a, max=b)
    minimizer = lmfit.Minimizer(residual, params)
    out = minimizer.minimize(method="least_squares", jac=jac, x_scale="jac",
                             max_nfev=max_nfev or 50 * (len(keys) + 1))
    best = values_of(out.params)
    r = residual(out.params)
    J = jac(out.params)
    cov_naive, cov = _covariances(J, targets)
    model_ds = forward.model(best)
    posterior = None
    if sample:
        posterior = sample_posterior(residual, out.params, keys, lo, hi, cov, cov_naive,
                                     client=client, **dict(sample))
    return result_dataset(
        keys=keys, initial=x0, lower=lo, upper=hi, value=best, cov=cov, cov_naive=cov_naive,
        residuals=r, targets=targets, model=model_ds, measurement=measurement,
        best_case=forward.case(best), stats={
            "nfev": int(forward.evaluations), "success": bool(out.success),
            "message": str(out.message), "wall_time": time.perf_counter() - began},
        posterior=posterior)


def _covariances(J: np.ndarray, targets: Targets) -> tuple[np.ndarray, np.ndarray]:
    """Naive ``(J^T J)^-1`` and the jackknife sandwich covariance of the parameters."""
    JTJ = J.T @ J
    try:
        inv = np.linalg.inv(JTJ)
    except np.linalg.LinAlgError:
        raise NumericalError("the fit's parameters are not determined by these observables "
                             "(singular Jacobian): fix a parameter or add an observable") from None
    reps = targets.replicates
    B = reps.shape[0]
    dev = (reps - np.nanmean(reps, axis=0)) / targets.sigma
    dev = np.nan_to_num(dev)
    dtheta = dev @ J @ inv.T                     # (B, p)
    cov = (B - 1) / B * dtheta.T @ dtheta
    return inv, cov


def relative_errors(ds: xr.Dataset) -> dict[str, float]:
    """``stderr / |value|`` per parameter (a convenience for reports)."""
    return {str(k): float(s / abs(v)) if v else math.inf
            for k, v, s in zip(ds["parameter"].values, ds["value"].values, ds["stderr"].values)}
