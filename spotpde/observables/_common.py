"""What every observable shares (private; see :mod:`spotpde.observables`): telling tracks
from a model result, the case and its grid, time blocks and the delete-one jackknife,
the coarse-graining kernel, and the model's mean particle velocity.

Error model (docs/calibration.md, section 3): samples of one run are correlated (grains
moved by the same spot, successive frames), so errors come from ``B`` contiguous time
blocks (or independent replicas), never from the number of samples. Every estimator is
written as a function ``f`` of block sums; the estimate is ``f(sum over all blocks)``,
the delete-one jackknife replicates are ``theta_(b) = f(sum without block b)`` and

    se^2 = (B - 1) / B * sum_b (theta_(b) - mean_b theta_(b))^2

(Efron & Stein 1981; for ratio estimators this is the standard error of the ratio,
first order in 1/B). The replicates are kept (``<name>_jk``, dim ``block``) so that a fit
can propagate the errors of correlated observables (``spotpde.calibration``).
"""

from __future__ import annotations

import math
import os
import tomllib
from collections.abc import Callable, Mapping

import numpy as np
import scipy.ndimage
import xarray as xr

from ..app.cases import Case, load_case
from ..app.io import cf_units
from ..fields import coefficients

__all__ = ["is_tracks", "case_for", "grid_of", "block_of", "jackknife", "coarse_grain",
           "model_velocity", "sample", "positions", "BLOCKS", "with_errors"]

#: Default number of time blocks of the jackknife.
BLOCKS = 10


def is_tracks(source) -> bool:
    """True for a tracks Dataset (dims ``particle`` and ``t``), False for a model result."""
    return isinstance(source, xr.Dataset) and "particle" in source.dims


def case_for(source, case) -> Case:
    """The case of an observable: ``case`` (a Case, path or mapping), or for a model result
    without one the case it was run from (its ``case`` attribute)."""
    if isinstance(case, Case):
        return case
    if case is not None:
        if not isinstance(case, (str, os.PathLike, Mapping)):
            raise TypeError(f"case: must be a Case, a case file or a mapping, got {type(case).__name__}")
        return load_case(case)
    if isinstance(source, xr.Dataset) and "case" in source.attrs and not is_tracks(source):
        return load_case(tomllib.loads(source.attrs["case"]))
    raise ValueError("case: give the case the tracks come from (its grid, orifice and walls "
                     "define the observables)")


def grid_of(case: Case):
    """The case's grid, which must be a 2D Cartesian silo (a hopper mask is fine)."""
    g = case.grid
    g.geometry.require("track observables", "case")
    return g


def positions(tracks: xr.Dataset) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(x, z, t)``: ``(particle, t)`` arrays in d and the frame times."""
    return (np.asarray(tracks["x"].values, float), np.asarray(tracks["z"].values, float),
            np.asarray(tracks["t"].values, float))


def block_of(t: np.ndarray, times: np.ndarray, blocks: int) -> np.ndarray:
    """Index of the contiguous time block (of ``blocks`` equal spans of ``times``) of ``t``."""
    if not (isinstance(blocks, (int, np.integer)) and blocks >= 2):
        raise ValueError(f"blocks: must be an integer >= 2, got {blocks!r}")
    t0, t1 = float(times[0]), float(times[-1])
    span = max(t1 - t0, 1e-300)
    return np.clip(((np.asarray(t) - t0) / span * blocks).astype(np.int64), 0, blocks - 1)


def jackknife(sums: Mapping[str, np.ndarray], f: Callable[[dict], np.ndarray]):
    """Estimate, standard error and delete-one replicates of ``f`` of block sums.

    Args:
        sums: name -> array of shape ``(B, ...)`` (the sums of each block).
        f: maps a dict of summed arrays (block axis removed) to the estimate.

    Returns:
        ``(value, se, replicates)`` with ``replicates`` of shape ``(B,) + value.shape``.
    """
    total = {k: np.asarray(v).sum(axis=0) for k, v in sums.items()}
    B = next(iter(sums.values())).shape[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        value = np.asarray(f(total), dtype=float)
        reps = np.stack([np.asarray(f({k: total[k] - np.asarray(v)[b] for k, v in sums.items()}),
                                    dtype=float) for b in range(B)])
        mean = reps.mean(axis=0)
        se = np.sqrt((B - 1) / B * ((reps - mean) ** 2).sum(axis=0))
    return value, se, reps


def with_errors(ds: xr.Dataset, name: str, dims: tuple, value, se, reps, attrs: dict) -> None:
    """Put ``name``, ``name_se`` and the replicates ``name_jk`` (dim ``block``) into ``ds``."""
    ds[name] = (dims, value, attrs)
    ds[name + "_se"] = (dims, se, {**attrs, "long_name": "standard error of " + attrs.get(
        "long_name", name)})
    ds[name + "_jk"] = (("block",) + tuple(dims), reps,
                        {"units": attrs.get("units", "1"), "long_name": f"delete-one-block "
                         f"jackknife replicates of {name}"})


def coarse_grain(grid, x, z, values: Mapping[str, np.ndarray], block: np.ndarray, blocks: int,
                 width: float) -> dict[str, np.ndarray]:
    """Block sums of a Gaussian coarse-graining on the grid's cell centres.

    ``S_b[q](r) = sum_{i in b} phi(r - r_i) q_i`` with ``phi`` a Gaussian of standard
    deviation ``width`` (cut at 3 widths; Weinhart et al., Granular Matter 14, 289 (2012)),
    approximated by binning the samples on the grid and filtering the bins (error of
    order ``h^2 / 12`` in the samples' positions). The sample count is ``"count"``; a field
    is ``S[q] / S[count]``. Samples outside the grid's box are dropped.

    Returns:
        name -> ``(B, nz, nx)`` (``"count"`` included), and ``"histogram"`` -> the
        unfiltered sample count per cell ``(nz, nx)`` (the weights a model field is
        coarse-grained with).
    """
    h = grid.spacing
    x0, z0 = grid.x_range[0], grid.z_range[0]
    ix = np.floor((x - x0) / h).astype(np.int64)
    iz = np.floor((z - z0) / h).astype(np.int64)
    ok = (ix >= 0) & (ix < grid.nx) & (iz >= 0) & (iz < grid.nz) & np.isfinite(x) & np.isfinite(z)
    flat = (block[ok] * grid.nz + iz[ok]) * grid.nx + ix[ok]
    size = blocks * grid.nz * grid.nx
    sigma = (0.0, width / h, width / h)
    out = {}
    raw = np.bincount(flat, minlength=size).reshape(blocks, grid.nz, grid.nx).astype(float)
    out["histogram"] = raw.sum(axis=0)
    for name, q in {"count": None, **values}.items():
        binned = raw if q is None else np.bincount(
            flat, weights=np.asarray(q, float)[ok], minlength=size).reshape(raw.shape)
        out[name] = scipy.ndimage.gaussian_filter(binned, sigma, mode="constant", truncate=3.0)
    return out


def smooth_like(grid, field: np.ndarray, weights: np.ndarray | None, width: float) -> np.ndarray:
    """A model field coarse-grained as the data were: ``(phi * (n q)) / (phi * n)`` with
    ``n`` the data's samples per cell (uniform inside the silo without data)."""
    sigma = (width / grid.spacing,) * 2
    active = np.isfinite(field)
    n = active.astype(float) if weights is None else np.where(active, weights, 0.0)
    q = np.where(active, field, 0.0)
    num = scipy.ndimage.gaussian_filter(n * q, sigma, mode="constant", truncate=3.0)
    den = scipy.ndimage.gaussian_filter(n, sigma, mode="constant", truncate=3.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den > 0, num / den, np.nan)


def flux_factor(case: Case) -> float:
    """``int w/(1+w) dr / int w dr``: grains inside a passing spot move at ``1 + w`` times
    the spot's relative speed, so their density there is ``1/(1 + w)`` and the particle
    flux per spot is ``int w/(1+w)`` rather than ``V1`` (docs/calibration.md, section 2;
    1 for the void model, whose exchanges carry one grain each)."""
    if case.model == "void":
        return 1.0
    k = case.kernel
    axes = [np.linspace(-r, r, 201 if k.dims == 2 else 61)
            for r in (k.reach[0],) * (k.dims - 1) + (k.reach[1],)]
    w = k.evaluate(*np.meshgrid(*axes, indexing="ij"))      # point values: exact for a disk
    return float(np.sum(w / (1.0 + w)) / np.sum(w))


def model_velocity(result: xr.Dataset, case: Case) -> dict[str, np.ndarray]:
    """The model's mean (Eulerian) particle velocity: the flux velocity ``u_p - div D_p``
    times :func:`flux_factor`, as ``{"u_x", "u_z"}`` grid arrays in d per time unit."""
    grid = grid_of(case)
    fields = {k: np.asarray(result[k].values, float) for k in ("u_x", "u_z", "D_xx", "D_xz", "D_zz")}
    u = coefficients.flux_velocity(grid, fields)
    f = flux_factor(case)
    return {k: f * u[k] for k in ("u_x", "u_z")}


def sample(grid, field: np.ndarray, x: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Bilinear interpolation of a cell-centred field at points (NaN outside the centres'
    hull or where a neighbour is NaN)."""
    fx = (np.asarray(x, float) - grid.x[0]) / grid.spacing
    fz = (np.asarray(z, float) - grid.z[0]) / grid.spacing
    inside = (fx >= 0) & (fx <= grid.nx - 1) & (fz >= 0) & (fz <= grid.nz - 1)
    fx = np.where(inside, fx, 0.0)
    fz = np.where(inside, fz, 0.0)
    out = scipy.ndimage.map_coordinates(np.nan_to_num(field, nan=np.nan), [fz.ravel(), fx.ravel()],
                                        order=1, mode="nearest", cval=np.nan).reshape(fx.shape)
    return np.where(inside, out, np.nan)


def units(symbols: str, long_name: str) -> dict[str, str]:
    """CF attributes (``spotpde.io.cf_units``)."""
    return cf_units(symbols, long_name)


def check_positive(name: str, value, integer: bool = False):
    """``value`` as a float (int) > 0, else ValueError naming ``name``."""
    ok = isinstance(value, (int, np.integer)) if integer else isinstance(value, (int, float, np.number))
    if isinstance(value, bool) or not ok or not (math.isfinite(value) and value > 0):
        kind = "an integer" if integer else "a finite number"
        raise ValueError(f"{name}: must be {kind} > 0, got {value!r}")
    return int(value) if integer else float(value)
