"""Drained fraction of coloured layers (private; see :mod:`spotpde.observables`).

Coloured grains are those in the bands ``[k s, k s + s/2)`` (``s`` the layer spacing,
as ``tracer.layers``) at the first frame. A grain has drained once it is seen below the
floor (``z < 0``), or once its track ends within ``exit_height`` of the floor before
the record does. The model's drained fraction is the tracer's ``outflow(t)`` started
from the same bands (a case with ``tracer.layers``).

Errors: a single drainage is one realisation of a flow that fluctuates as a whole, so
no time blocks exist; the jackknife over groups of grains (dealt at random) only
measures the sampling of grains and is a lower bound. Give several independent runs
(``spotpde.observables.measure`` with a list of tracks) for honest errors.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from ..parameters import in_bands
from ._common import BLOCKS, case_for, check_positive, grid_of, is_tracks, jackknife, positions, units, with_errors

__all__ = ["drained_fraction"]


def _spacing(case, spacing):
    if spacing is not None:
        return check_positive("spacing", spacing)
    start = getattr(case.tracer, "start", None)
    if start is None or start.kind != "layers":
        raise ValueError("spacing: give the layer spacing (d), or a case with tracer.layers")
    return float(start.spacing)


def drained_fraction(source, case=None, *, spacing: float | None = None,
                     exit_height: float = 2.0, blocks: int = BLOCKS,
                     like: xr.Dataset | None = None) -> xr.Dataset:
    """Fraction of the coloured grains that have left through the orifice, against time.

    Args:
        source: tracks, or a model result with a layered tracer (``outflow``).
        case: the case (default layer spacing: ``tracer.layers.spacing``).
        spacing: layer spacing in d. exit_height: see the module docstring (d).
        blocks: groups of grains of the jackknife (tracks).
        like: for a model result, the tracks' measurement (its times).

    Returns:
        Dataset on ``t``: ``drained`` (tracks: with ``drained_se``, ``drained_jk``).
    """
    case = case_for(source, case)
    grid_of(case)
    attrs = units("1", "drained fraction of the coloured layers")
    if not is_tracks(source):
        if "outflow" not in source:
            raise ValueError("source: the model result has no tracer outflow; run the case "
                             "with [tracer] layers = { spacing = ... }")
        t = like["t"].values if like is not None else source["t"].values
        d = np.interp(t, source["t"].values, source["outflow"].values)
        return xr.Dataset({"drained": ("t", d, attrs)},
                          coords={"t": ("t", t, units("t", "time"))})
    spacing = _spacing(case, spacing)
    x, z, t = positions(source)
    z_first = z[:, 0]
    coloured = np.isfinite(z_first) & (z_first >= 0) & in_bands(z_first, spacing)
    x, z = x[coloured], z[coloured]
    if x.shape[0] == 0:
        raise ValueError("source: no tracked grain in a coloured band at the first frame")
    below = np.isfinite(z) & (z < 0)
    t_out = np.where(below.any(axis=1), t[np.argmax(below, axis=1)], np.inf)
    seen = np.isfinite(z)
    last = z.shape[1] - 1 - np.argmax(seen[:, ::-1], axis=1)
    ended = (last < z.shape[1] - 1) & (z[np.arange(z.shape[0]), last] < exit_height)
    t_end = np.where(ended, t[np.minimum(last + 1, t.size - 1)], np.inf)
    t_out = np.minimum(t_out, t_end)
    # grains dealt to the groups at random (a fixed deal): the jackknife then measures the
    # random sampling of grains. Groups by column overstate it (they count the columns'
    # difference as noise), groups interleaved in x understate it (stratified by x).
    group = np.random.default_rng(0).permutation(x.shape[0]) % blocks
    out = (t_out[None, :] <= t[:, None]).astype(float)        # (t, grain)
    sums = {"n": np.stack([np.full(t.size, float((group == g).sum())) for g in range(blocks)]),
            "d": np.stack([out[:, group == g].sum(axis=1) for g in range(blocks)])}
    value, se, reps = jackknife(sums, lambda s: s["d"] / s["n"])
    ds = xr.Dataset(coords={"t": ("t", t, units("t", "time"))},
                    attrs={"spacing": spacing, "grains": int(x.shape[0]), "blocks": blocks,
                           "errors": "jackknife over groups of grains: a lower bound"})
    with_errors(ds, "drained", ("t",), value, se, reps, attrs)
    return ds
