"""LAMMPS / LIGGGHTS ``dump custom`` text files (private; see :mod:`spotpde.tracks`).

A dump is a sequence of snapshots::

    ITEM: TIMESTEP
    1000
    ITEM: NUMBER OF ATOMS
    3
    ITEM: BOX BOUNDS pp pp ff
    -25 25
    0 80
    -0.5 0.5
    ITEM: ATOMS id type x y z radius
    1 1 0.31 12.2 0 0.5
    ...

:func:`parse` returns the rows of every snapshot as columns (``frame`` = the TIMESTEP),
unscaling ``xs``/``ys``/``zs`` with the snapshot's box; plain (``x``), unwrapped (``xu``)
and scaled (``xs``) coordinates are accepted, but not a mixture of scaled and
unscaled ones. Gzip-compressed dumps (``.gz``) are read as well.
"""

from __future__ import annotations

import gzip
import io

import numpy as np
import pandas as pd

__all__ = ["is_dump", "parse"]

_MAGIC = "ITEM: TIMESTEP"


def _open_text(path):
    with open(path, "rb") as fh:
        head = fh.read(2)
    if head == b"\x1f\x8b":
        return io.TextIOWrapper(gzip.open(path, "rb"), encoding="utf-8", errors="replace")
    return open(path, encoding="utf-8", errors="replace")


def is_dump(path) -> bool:
    """True if the file (plain or gzip) starts with ``ITEM: TIMESTEP``."""
    try:
        with _open_text(path) as fh:
            return fh.readline().strip().startswith(_MAGIC)
    except (OSError, EOFError, UnicodeError):
        return False


def _coordinate_columns(names: list[str], label: str) -> dict[str, str]:
    """Map ``x``, ``y``, ``z`` to the dump's column for each (``x``, ``xu`` or ``xs``)."""
    out = {}
    for axis in "xyz":
        found = [c for c in (axis, axis + "u", axis + "s", axis + "su") if c in names]
        if found:
            out[axis] = found[0]
    scaled = sorted(a for a, c in out.items() if c.endswith(("s", "su")))
    plain = sorted(a for a, c in out.items() if not c.endswith(("s", "su")))
    if scaled and plain:
        raise ValueError(f"source: {label}: mixed units: {', '.join(out[a] for a in scaled)} "
                         f"scaled to the box but {', '.join(out[a] for a in plain)} not; "
                         "dump all coordinates one way")
    return out


def parse(path, label: str) -> tuple[pd.DataFrame, dict]:
    """Read a dump into one table.

    Returns:
        ``(table, info)``: columns ``frame`` (TIMESTEP), ``particle`` (id), ``x``, ``y``,
        ``z`` (those present, unscaled) and ``diameter`` (from ``radius`` or ``diameter``,
        when present); ``info`` with ``dimension`` (2 if every ``z`` is the same, else 3)
        and ``columns`` (the ATOMS header).

    Raises:
        ValueError: ``source: <label>: ...`` for a truncated snapshot, a missing ``id``
            or coordinate column, TIMESTEPs that do not increase, mixed units, or
            non-numeric values.
    """
    frames, counts, boxes, header = [], [], [], None
    body = []
    with _open_text(path) as fh:
        lines = iter(enumerate(fh, start=1))
        for number, line in lines:
            text = line.strip()
            if not text:
                continue
            if not text.startswith("ITEM:"):
                raise ValueError(f"source: {label}: line {number}: expected an ITEM: line, "
                                 f"got {text[:40]!r}")
            item = text[5:].strip()
            if item.startswith("TIMESTEP"):
                frames.append(_int(next(lines, (number, ""))[1], label, number + 1, "TIMESTEP"))
                if len(frames) > 1 and frames[-1] <= frames[-2]:
                    raise ValueError(f"source: {label}: line {number + 1}: frames are not "
                                     f"increasing (TIMESTEP {frames[-1]} after {frames[-2]})")
            elif item.startswith("NUMBER OF ATOMS"):
                counts.append(_int(next(lines, (number, ""))[1], label, number + 1, "NUMBER OF ATOMS"))
            elif item.startswith("BOX BOUNDS"):
                box = []
                for _ in range(3 if "xy" not in item else 3):
                    n, row = next(lines, (number, ""))
                    vals = row.split()
                    if len(vals) < 2:
                        raise ValueError(f"source: {label}: line {n}: truncated BOX BOUNDS")
                    box.append((float(vals[0]), float(vals[1])))
                boxes.append(box)
            elif item.startswith("ATOMS"):
                names = item.split()[1:]
                if header is None:
                    header = names
                elif names != header:
                    raise ValueError(f"source: {label}: line {number}: the ATOMS columns "
                                     f"change ({' '.join(names)} after {' '.join(header)})")
                if len(counts) != len(frames):
                    raise ValueError(f"source: {label}: line {number}: ATOMS without "
                                     "NUMBER OF ATOMS")
                for _ in range(counts[-1]):
                    n, row = next(lines, (None, None))
                    if row is None or row.startswith("ITEM:"):
                        raise ValueError(f"source: {label}: truncated snapshot at TIMESTEP "
                                         f"{frames[-1]}: expected {counts[-1]} atoms")
                    body.append(row)
            # other items (TIME, UNITS, ...) carry nothing the layout needs
    if header is None or not frames:
        raise ValueError(f"source: {label}: no snapshot (ITEM: ATOMS) in the dump")
    if "id" not in header:
        raise ValueError(f"source: {label}: missing column 'id' (columns: {' '.join(header)})")
    cols = _coordinate_columns(header, label)
    if "x" not in cols or ("y" not in cols and "z" not in cols):
        raise ValueError(f"source: {label}: missing coordinate columns (need x and y or z as "
                         f"x/xu/xs; columns: {' '.join(header)})")
    try:
        table = pd.read_csv(io.StringIO("".join(body)), sep=r"\s+", header=None, names=header,
                            usecols=sorted({"id", *cols.values(), *[c for c in ("radius", "diameter")
                                                                     if c in header]},
                                           key=header.index),
                            dtype=float, engine="c")
    except (ValueError, pd.errors.ParserError) as exc:
        raise ValueError(f"source: {label}: non-numeric atom data ({str(exc).splitlines()[0]})") from None
    out = pd.DataFrame({"frame": np.repeat(np.asarray(frames, dtype=np.int64), counts),
                        "particle": table["id"].to_numpy()})
    for axis, col in cols.items():
        values = table[col].to_numpy()
        if col.endswith(("s", "su")):
            k = "xyz".index(axis)
            lo = np.repeat([b[k][0] for b in boxes], counts)
            hi = np.repeat([b[k][1] for b in boxes], counts)
            values = lo + values * (hi - lo)
        out[axis] = values
    if "diameter" in table:
        out["diameter"] = table["diameter"].to_numpy()
    elif "radius" in table:
        out["diameter"] = 2.0 * table["radius"].to_numpy()
    dimension = 3 if "z" in out and np.ptp(out["z"].to_numpy()) > 0 else 2
    return out, {"dimension": dimension, "columns": " ".join(header)}


def _int(text: str, label: str, number: int, what: str) -> int:
    try:
        return int(text.split()[0])
    except (ValueError, IndexError):
        raise ValueError(f"source: {label}: line {number}: {what} must be an integer, "
                         f"got {text.strip()[:40]!r}") from None
