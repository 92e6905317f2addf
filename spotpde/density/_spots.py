"""Spot parameters checked against a grid, and the padding of open walls (private).

Shared by :mod:`spotpde.density.spot_density` (which re-exports :func:`check_spots` and
:func:`pad_cells`) and :mod:`spotpde.density.traffic`, so neither imports the other for
them. Lengths in d.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..grid import Grid
from ..parameters import SPOT_MODES, Spots


# -- validation -------------------------------------------------------------------------
def check_spots(grid: Grid, spots: Spots) -> None:
    """Raise :class:`ValueError` naming every invalid ``spots`` key.

    Args:
        grid: the grid (array coefficients must have its shape).
        spots: drift, b, b_par (floats or grid-shaped arrays), mode, t_end.
    """
    problems = []
    for key, value, strict in (("drift", spots.drift, True), ("b", spots.b, True),
                               ("b_par", spots.b_par, False)):
        arr = np.asarray(value, dtype=float)
        if arr.ndim > 0 and arr.shape != grid.shape:
            problems.append(f"spots.{key}: an array must have the grid shape {grid.shape}, got {arr.shape}")
            continue
        if not np.all(np.isfinite(arr)):
            problems.append(f"spots.{key}: must be finite")
        elif strict and np.any(arr <= 0):
            problems.append(f"spots.{key}: must be > 0, got {arr.min()!r}")
        elif not strict and np.any(arr < 0):
            problems.append(f"spots.{key}: must be >= 0, got {arr.min()!r}")
    if spots.mode not in SPOT_MODES:
        problems.append(f"spots.mode: must be one of {', '.join(map(repr, SPOT_MODES))}, got {spots.mode!r}")
    if problems:
        raise ValueError("\n".join(problems))


# -- open walls: padding -------------------------------------------------------------------
def pad_cells(grid: Grid, b) -> int:
    """Cells added on each side for open walls: ``ceil(6 sqrt(b_max H) / h)`` (0 if reflecting)."""
    if grid.walls == "reflecting":
        return 0
    H = grid.z_range[1] - grid.z_range[0]
    return int(np.ceil(6.0 * np.sqrt(float(np.max(b)) * H) / grid.spacing))


def _pad(grid: Grid, spots: Spots):
    """Padded reflecting grid, padded coefficient arrays (or floats), crop function."""
    p = pad_cells(grid, spots.b)
    coeffs = [spots.drift, spots.b, spots.b_par]
    if p == 0:
        g = dataclasses.replace(grid, walls="reflecting")
        return g, coeffs, lambda a: a
    h = grid.spacing

    def wider(r):
        return (r[0] - p * h, r[1] + p * h)

    g = Grid(grid.dims, wider(grid.x_range), grid.z_range, h, "reflecting",
             y_range=wider(grid.y_range) if grid.dims == 3 else None)
    widths = [(0, 0)] + [(p, p)] * (grid.dims - 1)
    coeffs = [np.pad(c, widths, mode="edge") if np.ndim(c) > 0 else c for c in coeffs]
    n = grid.nx

    def crop(a):
        if grid.dims == 2:
            return np.ascontiguousarray(a[..., p:p + n])
        return np.ascontiguousarray(a[..., p:p + grid.ny, p:p + n])

    return g, coeffs, crop
