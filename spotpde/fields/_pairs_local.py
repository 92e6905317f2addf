"""Two-point statistics in cylinders and hoppers: the box quadrature on a local box (private).

The cross integral ``X^ab(r1, r2) = integral rho_s D_s^ab w(r1 - s) w(r2 - s) ds`` of
:mod:`._pairs` only sees the spots within the kernel's reach of the two points, so it is
local: it follows the flow around the chosen points.

* Hopper (wedge, cone): the spots live in the material only. The integrand is the
  box's with ``rho_s`` restricted to the staircase's active cells (the cells the solvers
  compute; 0 beyond the walls).
* Axisymmetric grid: the silo is a 3D cylinder and the kernel a 3D one. Around the points
  :func:`localise` builds a Cartesian box of cells of the grid's spacing ``h`` (faces at
  multiples of ``h`` in ``x`` and ``y``, at the grid's own face heights in ``z``), each
  cell carrying the axisymmetric field at its centre's radius ``R = sqrt(x**2 + y**2)``:
  linear in ``R`` between the ring centres (flat inside the first ring: the field is even
  across the axis; flat from the last active ring to the wall), 0 beyond the wall
  ``r = a``, below the floor, above the top, and in a cone's inactive cells. The
  cylindrical spot tensor (``D_theta_theta = D_rr``) turns into Cartesian components
  ``D_xx = D_yy = D_rr``, ``D_xy = 0``, ``D_xz = D_rz x/R``, ``D_yz = D_rz y/R``.
  The points are ``(x, y, z)`` with the axis at ``x = y = 0``, or ``(r, z)``, read as
  ``(r, 0, z)`` (the meridian plane ``y = 0``), and the results are the 3D Cartesian
  components in that frame (``x`` radial, ``y`` azimuthal in the plane ``y = 0``).

A point outside the material (beyond a hopper wall, beyond the cylinder's wall, below the
floor or above the top) is refused, naming the argument. Lengths in d.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping

import numpy as np

from ._common import _check_inputs, spot_diffusivity
from ..grid import Grid


def localise(grid: Grid, rho_s, spots, kernel, r1, r2, tensor: Mapping | None):
    """The box the two-point quadrature of ``_pairs`` runs on, and its fields.

    Args:
        grid: the silo's grid (any geometry).
        rho_s: spot density, grid-shaped.
        spots: spot parameters (``drift`` v_s, ``b``, ``b_par``).
        kernel: the influence kernel (3D on an axisymmetric grid).
        r1, r2: the points, in d (see the module docstring).
        tensor: the optional full spot diffusivity (keys of the grid's geometry).

    Returns:
        ``(box, rho_s, spots, tensor, r1, r2)``: the inputs themselves on a box; on a
        hopper the same cells as a box with ``rho_s`` restricted to the material; on an
        axisymmetric grid the local 3D box and its sampled fields (``tensor`` in
        Cartesian keys), the points as 3D arrays.

    Raises:
        ValueError: naming ``r1`` / ``r2`` for a point outside the material, ``kernel``
            for a kernel of the wrong dimension, ``rho_s`` for a wrong shape.
    """
    geometry = grid.geometry
    if geometry.uniform_cells:
        return grid, rho_s, spots, tensor, r1, r2
    if getattr(kernel, "dims", None) != geometry.kernel_dims:
        raise ValueError(f"kernel: the {geometry.kind} grid needs a "
                         f"{geometry.kernel_dims}D kernel, got dims="
                         f"{getattr(kernel, 'dims', None)!r}")
    if geometry.curved:
        rho = np.asarray(rho_s, dtype=float)
        if rho.shape != grid.shape:
            raise ValueError(f"rho_s: array shape {rho.shape} does not match the grid shape "
                             f"{grid.shape} (array order {grid.axes})")
    else:
        rho = _check_inputs(grid, rho_s, kernel)
    if not np.all(np.isfinite(rho)):
        raise ValueError("rho_s: contains NaN or infinite values")
    D_s = spot_diffusivity(grid, spots, tensor)
    if not geometry.curved:     # a wedge: the box's cells, spots in the material only
        p1, p2 = (_planar_point(grid, r, name) for r, name in ((r1, "r1"), (r2, "r2")))
        box = Grid(2, grid.x_range, grid.z_range, grid.spacing, walls=grid.walls)
        return box, geometry.restrict(rho), spots, D_s, p1, p2
    p1, p2 = (_space_point(grid, r, name) for r, name in ((r1, "r1"), (r2, "r2")))
    box = _box_around(grid, kernel, p1, p2)
    sample = _Sampler(grid, box)
    tensor_box = {"D_xx": sample(D_s["D_rr"]), "D_zz": sample(D_s["D_zz"]), "D_xy": 0.0}
    tensor_box["D_yy"] = tensor_box["D_xx"]
    rz = D_s["D_rz"]
    if np.ndim(rz) == 0 and float(rz) == 0.0:
        tensor_box["D_xz"] = tensor_box["D_yz"] = 0.0
    else:
        rz = sample(rz)
        tensor_box["D_xz"], tensor_box["D_yz"] = (np.broadcast_to(rz * t, box.shape).copy()
                                                  for t in (sample.cos, sample.sin))
    changes = {}
    for key in ("drift", "b", "b_par"):
        value = getattr(spots, key)
        if np.ndim(value):
            changes[key] = sample(value)
    spots_box = dataclasses.replace(spots, **changes) if changes else spots
    rho_box = sample(rho) * sample.inside
    return box, rho_box, spots_box, tensor_box, p1, p2


def _planar_point(grid: Grid, r, name: str) -> np.ndarray:
    p = np.asarray(r, dtype=float).reshape(-1)
    if p.shape != (2,):
        raise ValueError(f"{name}: a point needs 2 coordinates (x, z), got {r!r}")
    _refuse_outside(grid, p[0], p[1], name, f"(x, z) = ({p[0]:g}, {p[1]:g})")
    return p


def _space_point(grid: Grid, r, name: str) -> np.ndarray:
    p = np.asarray(r, dtype=float).reshape(-1)
    if p.shape == (2,):
        p = np.array([p[0], 0.0, p[1]])
    if p.shape != (3,):
        raise ValueError(f"{name}: a point in a cylinder needs (x, y, z) or (r, z), in d, "
                         f"got {r!r}")
    R = math.hypot(p[0], p[1])
    _refuse_outside(grid, R, p[2], name,
                    f"(x, y, z) = ({p[0]:g}, {p[1]:g}, {p[2]:g}) at r = {R:g}")
    return p


def _refuse_outside(grid: Grid, x: float, z: float, name: str, where: str) -> None:
    """ValueError naming ``name`` unless ``(x, z)`` (``x`` the radius in a cylinder) lies
    in the material: inside the walls, the hopper's walls and the height of the silo."""
    if not np.all(np.isfinite([x, z])):
        raise ValueError(f"{name}: must be finite, got {where}")
    z0, z1 = grid.z_range
    x0, x1 = grid.x_range
    if not z0 <= z <= z1:
        why = f"outside the silo's height [{z0:g}, {z1:g}]"
    elif not x0 <= x <= x1:
        why = ("beyond the cylinder's wall r = " + f"{x1:g}" if grid.geometry.has_axis
               else f"outside the silo's width [{x0:g}, {x1:g}]")
    elif grid.geometry.clearance(x, z) < 0:
        why = "beyond the hopper's wall"
    else:
        return
    raise ValueError(f"{name}: the point {where} lies outside the material ({why}); "
                     "two-point statistics need both points in the material")


def _box_around(grid: Grid, kernel, p1: np.ndarray, p2: np.ndarray) -> Grid:
    """The 3D box of cells of spacing ``h`` around both points and the kernel's reach."""
    h = grid.spacing
    reach_h, reach_v = (float(v) for v in kernel.reach)
    z0 = grid.z_range[0]
    ranges = []
    for i, (reach, origin) in enumerate(((reach_h, 0.0), (reach_h, 0.0), (reach_v, z0))):
        lo = min(p1[i], p2[i]) - reach - 2 * h
        hi = max(p1[i], p2[i]) + reach + 2 * h
        ranges.append((origin + math.floor((lo - origin) / h) * h,
                       origin + math.ceil((hi - origin) / h) * h))
    return Grid(3, ranges[0], ranges[2], h, walls="open", y_range=ranges[1])


class _Sampler:
    """Axisymmetric ``(z, r)`` fields at the cell centres of a 3D box (module docstring)."""

    def __init__(self, grid: Grid, box: Grid):
        h = grid.spacing
        self.grid = grid
        X, Y = np.meshgrid(box.x, box.y, indexing="xy")       # (ny, nx)
        R = np.hypot(X, Y)
        with np.errstate(invalid="ignore", divide="ignore"):
            self.cos = np.where(R > 0, X / np.where(R > 0, R, 1.0), 0.0)[None]
            self.sin = np.where(R > 0, Y / np.where(R > 0, R, 1.0), 0.0)[None]
        self.R = R
        # grid row of each box row (the z faces coincide), -1 outside the silo
        k = np.rint((box.z - grid.z[0]) / h).astype(int)
        self.rows = np.where((k >= 0) & (k < grid.nz), k, -1)
        act = np.asarray(grid.geometry.active, dtype=bool)
        self.n_active = act.sum(axis=1)                        # rings 0..n-1 (from the axis)
        ring = np.floor(R / h).astype(int)
        inside = np.zeros((box.nz,) + R.shape)
        for kb, kg in enumerate(self.rows):
            if kg >= 0:
                inside[kb] = (ring < self.n_active[kg]) & (R <= grid.x_range[1])
        self.inside = inside

    def __call__(self, field) -> np.ndarray | float:
        """``field`` (a float or a grid array) at the box's cell centres (0 outside the
        silo's height; clamped radially, so multiply by ``inside`` for the material)."""
        if np.ndim(field) == 0:
            return float(field)
        f = np.broadcast_to(np.asarray(field, dtype=float), self.grid.shape)
        r = self.grid.x
        out = np.zeros((self.rows.size,) + self.R.shape)
        for kb, kg in enumerate(self.rows):
            n = int(self.n_active[kg]) if kg >= 0 else 0
            if n:
                out[kb] = np.interp(self.R, r[:n], f[kg, :n])
        return out
