"""The tracks layout: one :class:`xarray.Dataset` for particle trajectories (private;
see :mod:`spotpde.tracks`).

Dims ``("particle", "t")``; variables ``x``, ``z`` (3D also ``y``) in particle diameters d,
``z`` up with the orifice centre at the origin, NaN where a particle is not tracked;
optional ``diameter`` on ``("particle",)`` and ``id`` (the file's particle id). Every
reader ends in :func:`make`, which checks the arrays and attaches units and provenance.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from .._version import __version__
from ..app.io import cf_units

__all__ = ["LAYOUT", "make", "check", "split_jumps"]

#: Value of the ``layout`` attribute of a tracks Dataset.
LAYOUT = "spotpde-tracks-1"

_LONG = {"x": "horizontal position of the particle", "y": "second horizontal (depth) position "
         "of the particle", "z": "height of the particle above the orifice"}


def make(x, z, t, *, y=None, particle=None, ids=None, diameter=None,
         attrs: dict | None = None) -> xr.Dataset:
    """Build a tracks Dataset from dense arrays.

    Args:
        x, z (and ``y`` in 3D): positions in d, shape ``(n_particle, n_t)``, NaN where the
            particle is not tracked.
        t: frame times in the case's time unit, strictly increasing, shape ``(n_t,)``.
        particle: integer labels (default ``0 .. n-1``).
        ids: the source's particle ids (default ``particle``), ``(n_particle,)``.
        diameter: grain diameters in d, ``(n_particle,)`` (optional).
        attrs: provenance (``source``, ``format``, ``scale``, ``fps``, ``origin``, ...).

    Raises:
        ValueError: shapes that do not match, times not increasing, or infinite positions.
    """
    t = np.asarray(t, dtype=float)
    arrays = {"x": x, "z": z} if y is None else {"x": x, "y": y, "z": z}
    arrays = {k: np.asarray(v, dtype=float) for k, v in arrays.items()}
    shape = arrays["x"].shape
    for name, a in arrays.items():
        if a.ndim != 2 or a.shape != shape:
            raise ValueError(f"{name}: must be a (particle, t) array of shape {shape}, "
                             f"got shape {a.shape}")
        if np.isinf(a).any():
            raise ValueError(f"{name}: contains infinite positions")
    if t.shape != (shape[1],):
        raise ValueError(f"t: must have one time per frame ({shape[1]}), got shape {t.shape}")
    if t.size > 1 and not np.all(np.diff(t) > 0):
        raise ValueError("t: frame times must be strictly increasing")
    n = shape[0]
    particle = np.arange(n) if particle is None else np.asarray(particle, dtype=np.int64)
    ids = particle if ids is None else np.asarray(ids, dtype=np.int64)
    data = {k: (("particle", "t"), a, cf_units("d", _LONG[k] + " (NaN: not tracked)"))
            for k, a in arrays.items()}
    data["id"] = ("particle", ids, {"units": "1", "long_name": "particle id in the source"})
    if diameter is not None:
        data["diameter"] = ("particle", np.asarray(diameter, dtype=float),
                            cf_units("d", "grain diameter"))
    coords = {"particle": ("particle", particle, {"units": "1", "long_name": "track index"}),
              "t": ("t", t, {**cf_units("t", "time of the frame"), "axis": "T"})}
    ds = xr.Dataset(data, coords=coords)
    ds.attrs.update({"layout": LAYOUT, "dims": len(arrays), "spotpde_version": __version__,
                     "Conventions": "CF-1.10"})
    for key, value in (attrs or {}).items():
        ds.attrs[key] = _attr(value)
    return ds


def _attr(value):
    """A netCDF-writable attribute (tuples as arrays, None and bools as text)."""
    if value is None or isinstance(value, bool):
        return str(value)
    if isinstance(value, (tuple, list)):
        return np.asarray(value, dtype=float)
    return value


def check(ds: xr.Dataset, name: str = "tracks") -> xr.Dataset:
    """Check that ``ds`` is a tracks Dataset; return it with dims ordered ``(particle, t)``.

    Accepts the Monte Carlo's frames (``montecarlo.particle_frames``: dims ``("t",
    "particle")``) as well.

    Raises:
        ValueError: ``<name>: ...`` naming what is missing.
    """
    if not isinstance(ds, xr.Dataset):
        raise TypeError(f"{name}: must be an xarray.Dataset of tracks, got {type(ds).__name__}")
    missing = [v for v in ("x", "z") if v not in ds.data_vars]
    if missing or not {"particle", "t"} <= set(ds.dims):
        raise ValueError(f"{name}: not a tracks Dataset (needs variables x, z on dims "
                         f"(particle, t); has variables {', '.join(map(str, ds.data_vars)) or 'none'} "
                         f"and dims {', '.join(map(str, ds.dims)) or 'none'})")
    ds = ds.transpose("particle", "t", ...)
    if ds.sizes["t"] > 1 and not np.all(np.diff(ds["t"].values) > 0):
        raise ValueError(f"{name}: frame times t must be strictly increasing")
    return ds


def split_jumps(x: np.ndarray, z: np.ndarray, y: np.ndarray | None, max_jump: float):
    """Split each track where a particle moves more than ``max_jump`` d between two frames
    it is tracked in (a grain re-inserted at the top after leaving through the orifice).

    Returns:
        ``(owner, start, stop)``: for every piece the source row and its frame range
        ``[start, stop)``.
    """
    # a jump across untracked frames counts too: compare with the last tracked frame
    owner, start, stop = [], [], []
    n_t = x.shape[1]
    for i in range(x.shape[0]):
        seen = np.flatnonzero(np.isfinite(x[i]) & np.isfinite(z[i]))
        if seen.size == 0:
            continue
        dx = np.diff(x[i, seen]) ** 2 + np.diff(z[i, seen]) ** 2
        if y is not None:
            dx = dx + np.diff(y[i, seen]) ** 2
        cuts = seen[1:][dx > max_jump**2]
        bounds = [seen[0], *cuts.tolist(), n_t]
        for a, b in zip(bounds[:-1], bounds[1:]):
            owner.append(i)
            start.append(a)
            stop.append(b)
    return np.asarray(owner, int), np.asarray(start, int), np.asarray(stop, int)
