"""The fit's result Dataset and its plain-language report (private; see
:mod:`spotpde.calibration`)."""

from __future__ import annotations

import math

import numpy as np
import xarray as xr

from .._version import __version__
from ..app.io import cf_attrs

__all__ = ["result_dataset", "verdicts", "BEYOND", "FLAG_FRACTION"]

#: A residual "beyond" this many standard errors is one the model does not reproduce.
BEYOND = 3.0
#: An observable is reported as not reproduced when more than this fraction of its points
#: lie beyond :data:`BEYOND` standard errors (0.27 % would for a correct model).
FLAG_FRACTION = 0.05


def verdicts(targets, residuals: np.ndarray) -> list[dict]:
    """Per fitted variable: points, rms residual, points beyond 3 standard errors."""
    out = []
    for (name, var), (sl, _, _) in targets.slices.items():
        r = residuals[sl]
        n = r.size
        beyond = int(np.sum(np.abs(r) > BEYOND))
        out.append({"observable": name, "variable": var, "points": n,
                    "rms": float(np.sqrt(np.mean(r * r))) if n else math.nan,
                    "beyond": beyond, "fraction": beyond / n if n else math.nan,
                    "reproduced": bool(n and beyond / n <= FLAG_FRACTION)})
    return out


def _report(keys, value, stderr, chi2r, rows, stats) -> str:
    lines = ["spotpde fit: " + ("converged" if stats["success"] else "NOT converged: "
                                 + stats["message"]),
             f"{stats['nfev']} model evaluations, {stats['wall_time']:.1f} s",
             "best fit (standard errors from the jackknife over time blocks):"]
    for k, v, s in zip(keys, value, stderr):
        lines.append(f"  {k} = {v:.6g} +- {s:.2g}")
    lines.append(f"reduced chi-square {chi2r:.3g} (neighbouring points are correlated: a "
                 "guide, not a test)")
    bad = [r for r in rows if not r["reproduced"]]
    for r in rows:
        lines.append(f"  {r['observable']}.{r['variable']}: {r['points']} points, rms residual "
                     f"{r['rms']:.2f} SE, {r['beyond']} beyond {BEYOND:g} SE "
                     f"({100 * r['fraction']:.1f} %)")
    if bad:
        lines.append("The best fit does NOT reproduce: " + "; ".join(
            f"{r['observable']}.{r['variable']} ({100 * r['fraction']:.0f} % of its points "
            f"beyond {BEYOND:g} SE)" for r in bad))
    else:
        lines.append(f"The best fit reproduces every fitted observable (at most "
                     f"{100 * FLAG_FRACTION:.0f} % of the points of each beyond {BEYOND:g} SE).")
    return "\n".join(lines)


def result_dataset(*, keys, initial, lower, upper, value, cov, cov_naive, residuals, targets,
                   model, measurement, best_case, stats, posterior=None) -> xr.Dataset:
    """Assemble the fit's Dataset (``spotpde.fit``'s documented variables)."""
    p = len(keys)
    stderr = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(stderr, stderr)
    ds = xr.Dataset(coords={"parameter": ("parameter", np.asarray(keys, dtype=object),
                                          {"long_name": "free case key (dotted name)"}),
                            "parameter_2": ("parameter_2", np.asarray(keys, dtype=object),
                                            {"long_name": "free case key (dotted name)"})})
    unit = {"units": "1", "long_name": "in the case key's own units (lengths in d, times in "
            "the case's time unit)"}
    ds["value"] = ("parameter", np.asarray(value, float), {**unit, "long_name": "best fit, " + unit["long_name"]})
    ds["stderr"] = ("parameter", stderr, {**unit, "long_name": "standard error (jackknife over "
                                          "time blocks, correlations kept)"})
    ds["stderr_naive"] = ("parameter", np.sqrt(np.maximum(np.diag(cov_naive), 0.0)),
                          {**unit, "long_name": "standard error if every data point were "
                           "independent ((J^T J)^-1)"})
    ds["initial"] = ("parameter", np.asarray(initial, float), {**unit, "long_name": "start (the case's value)"})
    ds["lower"] = ("parameter", np.asarray(lower, float), {**unit, "long_name": "lower bound"})
    ds["upper"] = ("parameter", np.asarray(upper, float), {**unit, "long_name": "upper bound"})
    ds["correlation"] = (("parameter", "parameter_2"), corr,
                         {"units": "1", "long_name": "correlation of the parameter estimates"})
    for (name, var) in targets.slices:
        dims = measurement[var].dims
        coords = {d: measurement[d] for d in dims if d in measurement.coords}
        arr = targets.unflatten(residuals, name, var)
        ds[f"residual_{var}"] = xr.DataArray(arr, dims=dims, coords=coords, attrs={
            "units": "1", "long_name": f"(model - data) / standard error of {var}, at the "
            "fitted points (NaN elsewhere)"})
        for out, src in ((f"data_{var}", measurement[var]), (f"data_{var}_se", measurement[var + "_se"]),
                         (f"model_{var}", model[var])):
            da = xr.DataArray(np.broadcast_to(src.values, measurement[var].shape).copy(),
                              dims=dims, coords=coords, attrs=dict(src.attrs))
            da.attrs.pop("observable", None)
            ds[out] = da
    if "growth" in targets.observables:        # the falls the variances are plotted against
        ds["lag_fall"] = measurement["lag_fall"].copy()
        ds["lag_fall"].attrs.pop("observable", None)
    n = targets.y.size
    chi2 = float(residuals @ residuals)
    chi2r = chi2 / max(n - p, 1)
    rows = verdicts(targets, residuals)
    ds.attrs.update(cf_attrs(best_case))
    ds.attrs.update({
        "title": "spotpde fit of spot-model parameters to tracked grains",
        "chi2": chi2, "chi2_reduced": chi2r, "n_data": n, "n_free": p,
        "blocks": int(targets.replicates.shape[0]),
        "observables": list(targets.observables), "tracks": str(measurement.attrs.get("source", "")),
        "nfev": stats["nfev"], "success": int(stats["success"]), "message": stats["message"],
        "wall_time": float(stats["wall_time"]),
        "not_reproduced": ", ".join(f"{r['observable']}.{r['variable']}" for r in rows
                                    if not r["reproduced"]),
        "report": _report(keys, value, stderr, chi2r, rows, stats),
        "case": best_case.to_toml(), "spotpde_version": __version__,
    })
    if posterior is not None:
        ds = xr.merge([ds, posterior], combine_attrs="override")
    return ds
