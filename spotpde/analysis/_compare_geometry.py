"""What the kinematic comparison needs of a cylinder or a hopper (private; used by
:mod:`spotpde.analysis.comparison`).

* Cylinder: the radial derivative of a field even across the axis.
* Hopper (wedge, cone): the compared cells of each height are those whose kernel sees
  only material: farther than the kernel's horizontal reach plus a cell from the walls at
  the kernel's lowest height (the walls close in downwards), like the box's columns
  away from its side walls; heights
  with fewer than 5 such columns are left out, and the streamlines start inside the walls.

Lengths in d.
"""

from __future__ import annotations

import numpy as np


def radial_gradient(v: np.ndarray, h: float) -> np.ndarray:
    """``dv/dr`` (per d) of a field even across the axis: second order inside,
    ``(v_1 - v_0) / 2h`` at the first ring (as :func:`spotpde.density.kinematic.velocity`)."""
    g = np.gradient(v, h, axis=-1, edge_order=2)
    g[..., 0] = (v[..., 1] - v[..., 0]) / (2.0 * h)
    return g


def hopper_cells(grid, kernel, rows: np.ndarray, cols: np.ndarray):
    """``(rows, inside)`` of a hopper: the heights of ``rows`` with at least 5 of ``cols``
    farther than the kernel's horizontal reach inside the walls, and the bool mask
    ``(len(rows), len(cols))`` of those cells. Without a hopper: ``(rows, None)``."""
    if not grid.geometry.masked:
        return rows, None
    reach_h, reach_v = (float(r) for r in kernel.reach)
    Z, X = np.meshgrid(grid.z[rows], grid.x[cols], indexing="ij")
    # the walls close in downwards: the kernel's lowest height sets the clearance
    inside = grid.geometry.clearance(X, Z - reach_v) > reach_h + grid.spacing
    keep = inside.sum(axis=1) >= 5
    return rows[keep], inside[keep]


def streamline_starts(grid, xs: np.ndarray, height: float, centre: float) -> np.ndarray:
    """``xs`` (d) squeezed into the middle half of a hopper's material at ``height``, the
    hopper centred on ``centre`` (the same ``xs`` without a hopper)."""
    if not grid.geometry.masked:
        return xs
    half = 0.5 * float(grid.geometry.clearance(centre, height))
    lo = grid.spacing if grid.geometry.has_axis else centre - half
    return np.linspace(max(lo, xs.min()), min(centre + half, xs.max()), xs.size)
