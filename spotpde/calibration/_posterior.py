"""Posterior sampling of a fit with emcee (private; see :mod:`spotpde.calibration`).

The log-likelihood is ``-chi2 / (2 kappa)`` inside the bounds (flat priors), with
``kappa = tr(C_naive^-1 C) / p``: the residuals are correlated, so the plain ``chi2``
would give a posterior as narrow as the naive errors; ``kappa`` rescales it to the width
of the jackknife covariance ``C`` on average over the parameters (an approximation: one
scalar cannot carry a matrix; compare the posterior's spread with ``stderr``).
emcee (Foreman-Mackey et al., PASP 125, 306, 2013) is the optional extra ``posterior``.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

__all__ = ["sample_posterior"]


class _DaskPool:
    """emcee's ``pool``: ``map`` on a Dask client (walkers in parallel)."""

    def __init__(self, client):
        self.client = client

    def map(self, f, items):
        return self.client.gather(self.client.map(f, list(items), pure=False))


def sample_posterior(residual, params, keys, lo, hi, cov, cov_naive, *, client=None,
                     walkers: int = 16, steps: int = 300, seed: int = 0, burn: float = 0.3):
    """Sample the posterior around the fit; returns a Dataset of chains and summaries."""
    try:
        import emcee
    except ImportError:
        raise ValueError("sample: posterior sampling needs emcee (pip install "
                         "'spotpde[posterior]')") from None
    p = len(keys)
    names = list(params)
    best = np.array([params[n].value for n in names])
    kappa = float(np.trace(np.linalg.solve(cov_naive, cov)) / p)
    kappa = max(kappa, 1e-12)
    local = params.copy()

    def log_prob(theta):
        if np.any(theta < lo) or np.any(theta > hi):
            return -np.inf
        for n, v in zip(names, theta):
            local[n].value = float(v)
        try:
            r = residual(local)
        except Exception:   # noqa: BLE001 - a failed model evaluation has zero likelihood
            return -np.inf
        return -0.5 * float(r @ r) / kappa

    walkers = max(int(walkers), 2 * p + 2)
    rng = np.random.default_rng(seed)
    spread = np.sqrt(np.maximum(np.diag(cov), 1e-30))
    start = best + 0.1 * spread * rng.standard_normal((walkers, p))
    start = np.clip(start, lo + 1e-12 * (hi - lo), hi - 1e-12 * (hi - lo))
    sampler = emcee.EnsembleSampler(walkers, p, log_prob,
                                    pool=None if client is None else _DaskPool(client))
    sampler.random_state = np.random.RandomState(seed).get_state()
    sampler.run_mcmc(start, int(steps), progress=False)
    chain = sampler.get_chain()                  # (steps, walkers, p)
    kept = chain[int(burn * chain.shape[0]):].reshape(-1, p)
    ds = xr.Dataset({
        "chain": (("step", "walker", "parameter"), chain,
                  {"units": "1", "long_name": "emcee chains (case key units)"}),
        "posterior_mean": ("parameter", kept.mean(axis=0), {"units": "1", "long_name": "posterior mean"}),
        "posterior_std": ("parameter", kept.std(axis=0, ddof=1), {"units": "1", "long_name": "posterior standard deviation"}),
    }, coords={"parameter": np.asarray(keys, dtype=object)})
    ds.attrs.update({"posterior_kappa": kappa, "posterior_burn": burn,
                     "posterior_acceptance": float(np.mean(sampler.acceptance_fraction))})
    return ds
