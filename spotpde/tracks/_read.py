"""Reading particle tracks into the tracks layout (private; see :mod:`spotpde.tracks`).

Every source becomes one table of rows ``(frame, particle, horizontal, vertical[, depth])``
in the file's own units; :func:`read` then applies one transformation to all of them::

    x = (h - origin[0]) / scale
    z = (v - origin[1]) / scale          (y_down: z = -(v - origin[1]) / scale)
    y = (depth - origin[2]) / scale      (3D; origin[2] = 0 when origin has two entries)
    t = frame / fps

so ``scale`` is file length units per grain diameter (pixels per d), ``fps`` frames per
unit time (for a LAMMPS dump the frame is the TIMESTEP, so ``fps = 1 / dt``), ``origin``
the orifice centre in the file's coordinates.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import numpy as np
import pandas as pd
import xarray as xr

from ..app.cases import available_memory
from . import _lammps
from ._layout import check, make, split_jumps

__all__ = ["read", "FORMATS"]

#: Formats :func:`read` knows (``format=None`` guesses from the source).
FORMATS = ("trackpy", "lammps", "tracks")
#: Refuse a dense (particle, t) layout above this fraction of the available memory.
_MEMORY_FRACTION = 0.5


def read(source, scale: float = 1.0, fps: float = 1.0, origin: Sequence[float] = (0.0, 0.0),
         y_down: bool = False, *, format: str | None = None, vertical: str | None = None,
         depth: str | None = None, dims: int | None = None,
         max_jump: float | None = 5.0) -> xr.Dataset:
    """Read particle tracks (docs/calibration.md, section 1).

    Args:
        source: a :class:`pandas.DataFrame` or a CSV / Parquet file in trackpy's layout
            (columns ``frame``, ``particle``, ``x``, ``y``; ``z`` in 3D; optional
            ``diameter``); a LAMMPS / LIGGGHTS ``dump custom`` text file (plain or gzip;
            columns ``id`` and ``x``/``xu``/``xs`` ...; optional ``radius`` or
            ``diameter``); a tracks Dataset or netCDF file written from one; or a
            :class:`spotpde.montecarlo.MCResult` with tracked particles.
        scale: file length units per grain diameter (pixels per d), > 0.
        fps: frames per unit time (LAMMPS: TIMESTEPs per unit time, ``1 / dt``), > 0.
        origin: the orifice centre in the file's coordinates: ``(horizontal, vertical)``,
            optionally a third entry for the depth coordinate.
        y_down: the vertical coordinate points down (image rows).
        format: one of :data:`FORMATS`, or ``None`` to guess.
        vertical: the source column that is vertical (default ``"y"`` for trackpy and 2D
            dumps, ``"z"`` for 3D dumps).
        depth: the source column of the second horizontal coordinate (3D; default the
            remaining one of ``y``/``z``).
        dims: 2 to drop the depth coordinate of a thin 3D silo (positions projected on
            its width), 3 to require it, ``None`` to keep what the source has.
        max_jump: split a track where the particle moves more than this (in d) between
            two frames it is tracked in (a grain re-inserted at the top after leaving);
            ``None`` never splits.

    Returns:
        Dataset with dims ``("particle", "t")``: ``x``, ``z`` (3D ``y``) in d, ``z`` up,
        orifice at the origin, NaN where a particle is not tracked; ``id`` (the
        source's particle id), ``diameter`` when the source has one; attributes
        ``source``, ``format``, ``scale``, ``fps``, ``origin``, ``y_down``.

    Raises:
        ValueError: ``source: ...`` for a malformed source (missing column, frames that
            do not increase, duplicate particle-frame rows, mixed units, non-numeric
            values), or naming the bad argument.
        TypeError: a source of an unknown type.
    """
    scale, fps, origin = _check_transform(scale, fps, origin, y_down)
    if dims not in (None, 2, 3):
        raise ValueError(f"dims: must be 2, 3 or None, got {dims!r}")
    if max_jump is not None and not (isinstance(max_jump, (int, float)) and max_jump > 0):
        raise ValueError(f"max_jump: must be > 0 (in d) or None, got {max_jump!r}")
    fmt, label, table, info = _load(source, format)
    cols = _axes(table, fmt, info, vertical, depth, dims, label)
    ds = _dense(table, info, cols, scale, fps, origin, y_down, max_jump, label)
    ds.attrs.update({"source": label, "format": fmt, "scale": float(scale), "fps": float(fps),
                     "origin": np.asarray(origin, dtype=float), "y_down": str(bool(y_down)),
                     "columns": " ".join(f"{k}<-{v}" for k, v in cols.items())})
    return ds


def _check_transform(scale, fps, origin, y_down):
    for name, value in (("scale", scale), ("fps", fps)):
        if isinstance(value, bool) or not isinstance(value, (int, float, np.number)) \
                or not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name}: must be a finite number > 0, got {value!r}")
    try:
        origin = tuple(float(v) for v in origin)
    except (TypeError, ValueError):
        raise ValueError(f"origin: must be 2 or 3 numbers (horizontal, vertical[, depth]), "
                         f"got {origin!r}") from None
    if len(origin) not in (2, 3) or not all(math.isfinite(v) for v in origin):
        raise ValueError(f"origin: must be 2 or 3 finite numbers, got {origin!r}")
    if not isinstance(y_down, (bool, np.bool_)):
        raise TypeError(f"y_down: must be True or False, got {y_down!r}")
    return float(scale), float(fps), origin


def _load(source, format):
    """``(format, label, table, info)``: the source as rows of the file's columns."""
    if format is not None and format not in FORMATS:
        raise ValueError(f"format: must be one of {', '.join(FORMATS)} or None, got {format!r}")
    if isinstance(source, pd.DataFrame):
        return "trackpy", "DataFrame", _trackpy_table(source, "DataFrame"), {}
    if isinstance(source, xr.Dataset):
        return "tracks", source.attrs.get("source", "Dataset"), *_tracks_table(source, "Dataset")
    if hasattr(source, "tracked") and hasattr(source, "positions") and hasattr(source, "initial"):
        return "tracks", "Monte Carlo result", *_montecarlo_table(source)
    if not isinstance(source, (str, os.PathLike)):
        raise TypeError(f"source: must be a DataFrame, a tracks Dataset, a Monte Carlo result "
                        f"or a file path, got {type(source).__name__}")
    path = os.fspath(source)
    label = path
    if not os.path.isfile(path):
        raise ValueError(f"source: {path}: no such file")
    lower = path.lower()
    if format is None:
        if lower.endswith((".nc", ".nc4", ".netcdf")):
            format = "tracks"
        elif lower.endswith((".parquet", ".pq", ".csv", ".csv.gz", ".tsv", ".txt")) \
                and not _lammps.is_dump(path):
            format = "trackpy"
        else:
            format = "lammps" if _lammps.is_dump(path) else "trackpy"
    if format == "lammps":
        table, info = _lammps.parse(path, label)
        return "lammps", label, table, info
    if format == "tracks":
        try:
            with xr.open_dataset(path, engine="netcdf4") as ds:
                ds = ds.load()
        except Exception as exc:  # noqa: BLE001 - netCDF4 raises assorted errors
            raise ValueError(f"source: {path}: not a readable netCDF file ({exc})") from None
        return "tracks", label, *_tracks_table(ds, path)
    return "trackpy", label, _trackpy_table(_read_frame(path, lower), label), {}


def _read_frame(path: str, lower: str) -> pd.DataFrame:
    try:
        if lower.endswith((".parquet", ".pq")):
            return pd.read_parquet(path)
        return pd.read_csv(path, sep=None if lower.endswith((".tsv", ".txt")) else ",",
                           engine="python" if lower.endswith((".tsv", ".txt")) else "c")
    except ImportError as exc:
        raise ValueError(f"source: {path}: reading Parquet needs pyarrow ({exc}); "
                         "pip install pyarrow") from None
    except (ValueError, OSError, pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise ValueError(f"source: {path}: not a readable table "
                         f"({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None


def _trackpy_table(df: pd.DataFrame, label: str) -> pd.DataFrame:
    names = {str(c).strip(): c for c in df.columns}
    missing = [c for c in ("frame", "particle", "x", "y") if c not in names]
    if missing:
        raise ValueError(f"source: {label}: missing column{'s' if len(missing) > 1 else ''} "
                         f"{', '.join(repr(m) for m in missing)} (columns: "
                         f"{', '.join(map(str, df.columns)) or 'none'}; trackpy's layout has "
                         "frame, particle, x, y)")
    keep = [c for c in ("frame", "particle", "x", "y", "z", "diameter") if c in names]
    out = pd.DataFrame({c: df[names[c]] for c in keep})
    for c in keep:
        values = pd.to_numeric(out[c], errors="coerce")
        bad = values.isna() & out[c].notna()
        if bad.any():
            raise ValueError(f"source: {label}: column {c!r} is not numeric "
                             f"(e.g. {out[c][bad].iloc[0]!r})")
        out[c] = values
    for c in ("frame", "particle"):
        v = out[c].to_numpy()
        if np.isnan(v).any() or np.any(v != np.round(v)):
            raise ValueError(f"source: {label}: column {c!r} must hold integers")
        out[c] = v.astype(np.int64)
    return out


def _tracks_table(ds: xr.Dataset, label: str):
    """A tracks Dataset (or the Monte Carlo's frames) as rows, in its own units (d)."""
    ds = check(ds, f"source: {label}")
    units = {k: ds[k].attrs.get("spotpde_units", ds[k].attrs.get("units"))
             for k in ("x", "y", "z") if k in ds}
    if len(set(units.values())) > 1:
        raise ValueError(f"source: {label}: mixed units ("
                         + ", ".join(f"{k} in {u!r}" for k, u in units.items()) + ")")
    n_p, n_t = ds.sizes["particle"], ds.sizes["t"]
    times = ds["t"].values.astype(float)
    table = {"frame": np.tile(np.arange(n_t), n_p),
             "particle": np.repeat(ds["id"].values if "id" in ds else ds["particle"].values, n_t)}
    for k in ("x", "y", "z"):
        if k in ds:
            table[k] = ds[k].values.ravel()
    if "diameter" in ds:
        table["diameter"] = np.repeat(ds["diameter"].values, n_t)
    table = pd.DataFrame(table)
    table = table[np.isfinite(table["x"].to_numpy()) & np.isfinite(table["z"].to_numpy())]
    return table, {"times": times, "dimension": 3 if "y" in ds else 2}


def _montecarlo_table(result):
    pos = np.concatenate([result.initial[result.tracked][None], result.positions], axis=0)
    times = np.concatenate([[0.0], np.asarray(result.times, float)])
    n_t, n_p = pos.shape[:2]
    table = pd.DataFrame({"frame": np.repeat(np.arange(n_t), n_p),
                          "particle": np.tile(np.asarray(result.tracked), n_t),
                          "x": pos[..., 0].ravel(), "z": pos[..., 1].ravel()})
    table = table[np.isfinite(table["x"].to_numpy())]
    return table, {"times": times, "dimension": 2}


def _axes(table, fmt, info, vertical, depth, dims, label) -> dict[str, str]:
    """Which source column becomes ``x``, ``z`` (and ``y``)."""
    present = [c for c in ("x", "y", "z") if c in table]
    if fmt == "tracks":
        default_v, default_d = "z", "y"
    elif fmt == "lammps" and info.get("dimension") == 3:
        default_v, default_d = "z", "y"
    else:
        default_v, default_d = "y", "z"
    vertical = default_v if vertical is None else vertical
    if vertical not in ("x", "y", "z") or vertical not in present:
        raise ValueError(f"vertical: must name a coordinate column of the source "
                         f"({', '.join(present)}), got {vertical!r}")
    horizontal = "x" if vertical != "x" else "y"
    rest = [c for c in present if c not in (vertical, horizontal)]
    if fmt == "lammps" and info.get("dimension") == 2:
        rest = []                      # a 2D dump carries a constant z
    if depth is None:
        depth = default_d if default_d in rest else (rest[0] if rest else None)
    elif depth not in rest:
        raise ValueError(f"depth: must name the remaining coordinate column "
                         f"({', '.join(rest) or 'none: the source is 2D'}), got {depth!r}")
    if dims == 3 and depth is None:
        raise ValueError(f"dims: 3 needs a depth coordinate, but {label} has only "
                         f"{horizontal} and {vertical}")
    cols = {"x": horizontal, "z": vertical}
    if depth is not None and dims != 2:
        cols["y"] = depth
    return cols


def _dense(table, info, cols, scale, fps, origin, y_down, max_jump, label) -> xr.Dataset:
    frames = table["frame"].to_numpy()
    ids = table["particle"].to_numpy()
    key = pd.MultiIndex.from_arrays([ids, frames])
    if key.has_duplicates:
        dup = key[key.duplicated()][0]
        raise ValueError(f"source: {label}: duplicate rows for particle {dup[0]} in frame {dup[1]}")
    uid, row = np.unique(ids, return_inverse=True)
    ufr, col = np.unique(frames, return_inverse=True)
    need = uid.size * ufr.size * 8 * (len(cols) + 1)
    if need > _MEMORY_FRACTION * available_memory():
        raise ValueError(f"source: {label}: {uid.size} particles x {ufr.size} frames need "
                         f"{need / 2**30:.1f} GiB as a dense (particle, t) table; read a "
                         "subset of particles or frames")
    shift = {"x": origin[0], "z": origin[1], "y": origin[2] if len(origin) == 3 else 0.0}
    dense = {}
    for out, src in cols.items():
        a = np.full((uid.size, ufr.size), np.nan)
        values = table[src].to_numpy(dtype=float)
        if not np.all(np.isfinite(values)):
            raise ValueError(f"source: {label}: column {src!r} holds NaN or infinite values")
        a[row, col] = (values - shift[out]) / scale
        dense[out] = -a if (out == "z" and y_down) else a
    times = (np.asarray(info["times"], float)[ufr] if "times" in info else ufr) / fps
    diameter = None
    if "diameter" in table:
        diameter = np.full(uid.size, np.nan)
        diameter[row] = table["diameter"].to_numpy(dtype=float) / scale
    if max_jump is None:
        return make(dense["x"], dense["z"], times, y=dense.get("y"), ids=uid, diameter=diameter)
    owner, start, stop = split_jumps(dense["x"], dense["z"], dense.get("y"), max_jump)
    pieces = {}
    for k, a in dense.items():
        b = np.full((owner.size, ufr.size), np.nan)
        for j, (i, s, e) in enumerate(zip(owner, start, stop)):
            b[j, s:e] = a[i, s:e]
        pieces[k] = b
    return make(pieces["x"], pieces["z"], times, y=pieces.get("y"), ids=uid[owner],
                diameter=None if diameter is None else diameter[owner])
