"""Read and write LAMMPS ``dump custom`` text files (plain or gzip) of the silo runs.

A dump is a sequence of frames: ``ITEM: TIMESTEP``, ``ITEM: NUMBER OF ATOMS``, ``ITEM:
BOX BOUNDS``, ``ITEM: ATOMS id type x y z radius``. ``read`` returns the frames as
arrays (lengths in d, as written); ``tracks`` arranges them as ``(particle, frame)``
arrays with NaN where a particle is absent; ``write`` writes frames back in the same
layout.
"""

from __future__ import annotations

import contextlib
import gzip
import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

COLUMNS = ("id", "type", "x", "y", "z", "radius")


@dataclass
class Frame:
    step: int
    box_header: str          # the "ITEM: BOX BOUNDS ..." line and its three lines
    ids: np.ndarray          # (n,) int64
    data: np.ndarray         # (n, 5) float: type x y z radius


def _reader(path: Path):
    return gzip.open(path, "rt") if str(path).endswith(".gz") else open(path)


def read(path: str | Path) -> list[Frame]:
    """All frames of the dump at ``path``; raises ValueError naming a malformed frame."""
    with _reader(Path(path)) as f:
        text = f.read()
    frames = []
    for k, chunk in enumerate(text.split("ITEM: TIMESTEP\n")[1:]):
        lines = chunk.split("\n", 9)
        if len(lines) < 9 or lines[1] != "ITEM: NUMBER OF ATOMS":
            raise ValueError(f"path: frame {k} of {path} is not a LAMMPS dump frame")
        step, n = int(lines[0]), int(lines[2])
        header = "\n".join(lines[3:7])
        columns = tuple(lines[7].split()[2:])
        if columns != COLUMNS:
            raise ValueError(f"path: {path} has columns {columns}, expected {COLUMNS}")
        body = lines[8] + ("\n" + lines[9] if len(lines) > 9 else "")
        values = np.array(body.split(), dtype=float)
        if values.size != 6 * n:
            raise ValueError(f"path: frame {k} (step {step}) of {path} has {values.size} "
                             f"numbers, expected 6 x {n}")
        values = values.reshape(n, 6)
        frames.append(Frame(step, header, values[:, 0].astype(np.int64), values[:, 1:]))
    return frames


def tracks(frames: list[Frame]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(ids, steps, pos, radius)``: ``pos`` is (particle, frame, 3) with NaN where absent."""
    ids = np.unique(np.concatenate([f.ids for f in frames]))
    steps = np.array([f.step for f in frames])
    pos = np.full((len(ids), len(frames), 3), np.nan)
    radius = np.full(len(ids), np.nan)
    for k, f in enumerate(frames):
        rows = np.searchsorted(ids, f.ids)
        pos[rows, k] = f.data[:, 1:4]
        radius[rows] = f.data[:, 4]
    return ids, steps, pos, radius


def write(path: str | Path, frames: list[Frame], digits: int = 4) -> None:
    """Write ``frames`` as a ``dump custom`` file (gzip if the name ends in .gz), atomically."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    fmt = f"%d %d %.{digits}f %.{digits}f %.{digits}f %.4f"
    with contextlib.ExitStack() as stack:
        raw = stack.enter_context(open(tmp, "wb"))
        if path.name.endswith(".gz"):   # mtime 0, no name: the same frames give the same bytes
            raw = stack.enter_context(gzip.GzipFile(filename="", mode="wb", fileobj=raw,
                                                    mtime=0))
        f = stack.enter_context(io.TextIOWrapper(raw, encoding="ascii", newline="\n"))
        for fr in frames:
            f.write(f"ITEM: TIMESTEP\n{fr.step}\nITEM: NUMBER OF ATOMS\n{len(fr.ids)}\n"
                    f"{fr.box_header}\nITEM: ATOMS {' '.join(COLUMNS)}\n")
            if len(fr.ids):
                table = np.column_stack([fr.ids, fr.data])
                np.savetxt(f, table, fmt=fmt)
    os.replace(tmp, path)
