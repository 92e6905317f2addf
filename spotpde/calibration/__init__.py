"""Calibration: the spot model's parameters fitted to tracked grains, with honest errors
(docs/calibration.md, section 4).

::

    import spotpde
    fit = spotpde.fit("cases/quasi2d_layers.toml", tracks,
                      free={"spots.b": (0.5, 4.0), "kernel.height": (1e-4, 0.02)})
    print(fit.attrs["report"])          # values +- errors; what the fit cannot reproduce
    fit["value"], fit["stderr"], fit["correlation"]

The result's ``report`` names every fitted observable the best fit does not reproduce
(more than 5 % of its points beyond 3 standard errors): that is the answer to "does the
spot model describe my silo", not a failure. :func:`plot_fit` draws data against the
best fit.

Private modules: ``_forward`` (the data vector and the forward model, finite-difference
Jacobian on Dask), ``_fit`` (least squares and the jackknife covariance), ``_result``
(the Dataset and the report), ``_posterior`` (emcee), ``_plot`` (figures).
"""

from ._fit import RELATIVE_STEP, fit
from ._forward import DEFAULT_BOUNDS, FITTABLE
from ._plot import plot_fit
from ._result import BEYOND, FLAG_FRACTION

__all__ = ["fit", "plot_fit", "FITTABLE", "DEFAULT_BOUNDS", "RELATIVE_STEP", "BEYOND",
           "FLAG_FRACTION"]
