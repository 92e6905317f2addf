"""The computational grid: cell-centred, uniform spacing, lengths in particle diameters d.

Array order follows the result Dataset: ``(z, x)`` in 2D and ``(z, y, x)`` in 3D, so
``field[k, i]`` is the cell centred at ``(x[i], z[k])``. Cell ``k`` spans
``[z0 + k h, z0 + (k + 1) h)``; the orifice lies on the bottom face ``z = z0``.
In 3D the ``y`` extent is ``y_range``, by default the ``x`` extent (a square floor);
a thin slab has a short one (docs/cases.md, ``domain.y``).

Axisymmetric grids (``coordinates="axisymmetric"``, ``dims = 2``) are the ``(r, z)``
half-plane of a cylindrical silo: ``x_range = (0, a)`` is the radius, the axis is
``r = 0`` and array order is ``(z, r)``. A cell is a ring of volume ``2 pi r_i h**2``
(:attr:`Grid.cell_volumes`); fields are the axisymmetric 3D fields sampled on the
half-plane, and vector / tensor components are cylindrical (``u_r``, ``u_z``,
``D_rr``, ``D_rz``, ``D_zz``; :attr:`Grid.drift_keys`, :attr:`Grid.diffusivity_keys`).

A hopper (:class:`Hopper`) restricts the material to a wedge (2D) or cone
(axisymmetric) whose straight walls leave the orifice's edges at ``angle`` degrees from
the vertical; :attr:`Grid.material` is the fraction of each cell inside it and
:attr:`Grid.active` the staircase every solver uses (cells whose centre is inside).

py-pde orders axes the other way (``x`` first); :meth:`Grid.to_pde` builds the matching
``pde.CartesianGrid`` and :meth:`Grid.to_pde_data` / :meth:`Grid.from_pde_data`
transpose between the two orders.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .geometry import (AXISYMMETRIC_DIFFUSIVITY_KEYS, AXISYMMETRIC_DRIFT_KEYS, COORDINATES,
                       DIFFUSIVITY_KEYS, DRIFT_KEYS, Geometry, check_shape, derivative,
                       geometry_of)

WALLS = ("reflecting", "open")
#: Coordinate systems (owned by :mod:`spotpde.geometry`): ``"cartesian"`` (2D ``(x, z)``
#: or 3D ``(x, y, z)``) or ``"axisymmetric"`` (``(r, z)``, a cylindrical silo, dims = 2).

#: Field-name tables (docs/interface.md), owned by :mod:`spotpde.geometry`:
#: ``DRIFT_KEYS[dims]`` / ``DIFFUSIVITY_KEYS[dims]`` in result order, and the cylindrical
#: names of axisymmetric grids (``D_theta_theta`` equals ``D_rr`` for the spot model's
#: horizontally isotropic spots).
__all__ = ["Grid", "Hopper", "derivative", "WALLS", "COORDINATES", "DRIFT_KEYS",
           "DIFFUSIVITY_KEYS", "AXISYMMETRIC_DRIFT_KEYS", "AXISYMMETRIC_DIFFUSIVITY_KEYS"]


@dataclass(frozen=True)
class Hopper:
    """Straight hopper walls from the orifice's edges, widening upward.

    The material is ``|x - centre| <= half_width + (z - z0) tan(angle)`` (2D wedge), or
    ``r <= half_width + (z - z0) tan(angle)`` (axisymmetric cone, ``centre = 0``),
    intersected with the grid's box: above the height where the hopper walls meet the
    silo walls, the silo walls bound the material.

    Args:
        angle: wall angle from the vertical in degrees, ``0 <= angle < 90``.
        centre: the orifice centre ``x`` in d (0 on the axis).
        half_width: the orifice's half-width (radius when axisymmetric) in d, ``>= 0``.
    """

    angle: float
    centre: float = 0.0
    half_width: float = 0.0

    def __post_init__(self):
        a = float(self.angle)
        if not (np.isfinite(a) and 0.0 <= a < 90.0):
            raise ValueError(f"angle: must lie in [0, 90) degrees, got {self.angle!r}")
        if not (np.isfinite(self.half_width) and self.half_width >= 0.0):
            raise ValueError(f"half_width: must be finite and >= 0, got {self.half_width!r}")
        if not np.isfinite(self.centre):
            raise ValueError(f"centre: must be finite, got {self.centre!r}")
        if a == 0.0 and self.half_width == 0.0:
            raise ValueError("half_width: a vertical hopper (angle 0) needs an orifice "
                             "of width > 0, otherwise its walls close the domain")
        object.__setattr__(self, "angle", a)
        object.__setattr__(self, "centre", float(self.centre))
        object.__setattr__(self, "half_width", float(self.half_width))

    @property
    def slope(self) -> float:
        """``tan(angle)``: horizontal widening per unit height."""
        return float(np.tan(np.radians(self.angle)))

    def half_width_at(self, height):
        """Half-width of the material (radius for a cone) at ``height`` above the floor, in d."""
        return self.half_width + np.asarray(height, dtype=float) * self.slope


@dataclass(frozen=True)
class Grid:
    """A uniform cell-centred grid over the silo.

    Args:
        dims: 2 for ``(x, z)``, 3 for ``(x, y, z)``.
        x: horizontal extent ``(x0, x1)`` in d.
        z: vertical extent ``(z0, z1)`` in d; the orifice is at ``z0``.
        spacing: cell size ``h`` in d; must divide both extents.
        walls: ``"reflecting"`` (no flux through the side walls) or ``"open"``; on an
            axisymmetric grid the wall at ``r = a`` (the axis is never a wall).
        coordinates: ``"cartesian"`` or ``"axisymmetric"`` (``dims = 2``, ``x = (0, a)``
            the radius).
        hopper: optional :class:`Hopper`: the material is the wedge / cone it bounds.
        y_range: 3D only: the ``y`` extent ``(y0, y1)`` in d (the depth of a slab);
            ``None`` gives the ``x`` extent (a square floor). Stored as a tuple in 3D,
            ``None`` in 2D.
    """

    dims: int
    x_range: tuple[float, float]
    z_range: tuple[float, float]
    spacing: float
    walls: str = "reflecting"
    coordinates: str = "cartesian"
    hopper: Hopper | None = None
    y_range: tuple[float, float] | None = None

    def __post_init__(self):
        if self.dims not in (2, 3):
            raise ValueError(f"dims must be 2 or 3, got {self.dims!r}")
        if self.walls not in WALLS:
            raise ValueError(f"walls must be one of {WALLS}, got {self.walls!r}")
        if self.hopper is not None and not isinstance(self.hopper, Hopper):
            raise TypeError(f"hopper must be a Hopper or None, got {type(self.hopper).__name__}")
        check_shape(self.dims, self.x_range, self.coordinates, self.hopper)
        h = float(self.spacing)
        if not (h > 0 and np.isfinite(h)):
            raise ValueError(f"spacing must be a finite number > 0, got {self.spacing!r}")
        if self.y_range is not None and self.dims != 3:
            raise ValueError(f"y_range: only for dims = 3, got {tuple(self.y_range)!r} "
                             f"with dims = {self.dims}")
        if self.dims == 3:
            y = self.x_range if self.y_range is None else self.y_range
            object.__setattr__(self, "y_range", (float(y[0]), float(y[1])))
        extents = (("x", self.x_range), ("z", self.z_range)) + \
            ((("y", self.y_range),) if self.dims == 3 else ())
        for name, (a, b) in extents:
            if not (np.isfinite(a) and np.isfinite(b) and b > a):
                raise ValueError(f"{name} range must be increasing and finite, got {(a, b)!r}")
            n = (b - a) / h
            if abs(n - round(n)) > 1e-6 * max(1.0, n) or round(n) < 1:
                raise ValueError(
                    f"spacing {h} does not divide the {name} extent {b - a} into whole cells"
                )
        object.__setattr__(self, "x_range", (float(self.x_range[0]), float(self.x_range[1])))
        object.__setattr__(self, "z_range", (float(self.z_range[0]), float(self.z_range[1])))
        object.__setattr__(self, "spacing", h)

    # -- sizes -----------------------------------------------------------------
    @property
    def nx(self) -> int:
        """Number of cells along x."""
        return int(round((self.x_range[1] - self.x_range[0]) / self.spacing))

    @property
    def ny(self) -> int:
        """Number of cells along y (3D; 1 in 2D)."""
        if self.dims != 3:
            return 1
        return int(round((self.y_range[1] - self.y_range[0]) / self.spacing))

    @property
    def nz(self) -> int:
        """Number of cells along z."""
        return int(round((self.z_range[1] - self.z_range[0]) / self.spacing))

    @property
    def shape(self) -> tuple[int, ...]:
        """Array shape: ``(nz, nx)`` or ``(nz, ny, nx)``."""
        return (self.nz, self.nx) if self.dims == 2 else (self.nz, self.ny, self.nx)

    @property
    def axisymmetric(self) -> bool:
        """True for ``coordinates = "axisymmetric"`` (array order ``(z, r)``)."""
        return self.geometry.curved

    @cached_property
    def geometry(self) -> Geometry:
        """The silo's shape on this grid (:mod:`spotpde.geometry`): names, measures, the
        active cells, divergence, wall faces and the features it supports."""
        return geometry_of(self)

    @property
    def axes(self) -> tuple[str, ...]:
        """Dimension names in array order: ``("z", "x")``, ``("z", "y", "x")`` or ``("z", "r")``."""
        return self.geometry.axes

    @property
    def drift_keys(self) -> tuple[str, ...]:
        """Names of the particle drift components in result order."""
        return self.geometry.drift_keys

    @property
    def diffusivity_keys(self) -> tuple[str, ...]:
        """Names of the independent diffusivity components in result order."""
        return self.geometry.diffusivity_keys

    @property
    def size(self) -> int:
        """Total number of cells."""
        return int(np.prod(self.shape))

    @property
    def cell_volume(self) -> float:
        """``h**dims`` in d**dims (Cartesian; an axisymmetric cell's volume is
        :attr:`cell_volumes`)."""
        return self.spacing**self.dims

    @property
    def cell_volumes(self) -> np.ndarray:
        """Volume of every cell, broadcastable to :attr:`shape`, in d**3 (axisymmetric:
        the ring ``2 pi r_i h**2``, exact) or d**dims (Cartesian: ``h**dims``). Cut by
        a hopper, a cell's material volume is ``cell_volumes * material``."""
        return self.geometry.cell_volumes

    @property
    def horizontal_measures(self) -> np.ndarray:
        """Horizontal cross-section of every cell column, broadcastable to a horizontal
        slice (axisymmetric: the annulus ``2 pi r_i h`` in d**2; else ``h**(dims-1)``)."""
        return self.geometry.horizontal_measures

    @property
    def active(self) -> np.ndarray:
        """Cells of the computation, grid-shaped bool: those whose centre lies in the
        material (all True without a hopper). Every stage solves on this staircase:
        faces between an active and an inactive cell are walls (no flux of spots or
        tracer), and results are NaN on inactive cells. Read-only."""
        return self.geometry.active

    @property
    def material(self) -> np.ndarray:
        """Fraction of each cell's volume inside the granular material, grid-shaped.

        All ones without a hopper. With one: exact area fractions of the wedge in 2D;
        in axisymmetric coordinates the ring-volume fraction of the cone (``r dr``
        weights), by the midpoint rule with 64 sub-heights per cell (exact except in
        the few cells where the cone meets the outer wall or the axis). Read-only.
        """
        return self.geometry.material

    @property
    def horizontal_cell_measure(self) -> float:
        """Measure of one cell's horizontal cross-section, ``h**(dims-1)``."""
        return self.spacing ** (self.dims - 1)

    # -- coordinates -------------------------------------------------------------
    @cached_property
    def x(self) -> np.ndarray:
        """Cell-centre x coordinates in d."""
        return self.x_range[0] + (np.arange(self.nx) + 0.5) * self.spacing

    @cached_property
    def y(self) -> np.ndarray:
        """Cell-centre y coordinates in d (3D)."""
        return self.y_range[0] + (np.arange(self.ny) + 0.5) * self.spacing

    @cached_property
    def z(self) -> np.ndarray:
        """Cell-centre z coordinates in d (height above the orifice plane)."""
        return self.z_range[0] + (np.arange(self.nz) + 0.5) * self.spacing

    @property
    def y_centre(self) -> float:
        """Middle of the y extent in d (3D; the default y of the orifice and tracer)."""
        y = self.y_range if self.y_range is not None else self.x_range
        return 0.5 * (y[0] + y[1])

    @property
    def r(self) -> np.ndarray:
        """Cell-centre radii in d (axisymmetric grids; the same array as :attr:`x`)."""
        return self.x

    def coords(self) -> dict[str, np.ndarray]:
        """1D coordinate arrays by axis name (``z`` and ``r`` when axisymmetric)."""
        return self.geometry.coords()

    def mesh(self) -> tuple[np.ndarray, ...]:
        """Broadcastable coordinate arrays in array order: ``(Z, X)`` or ``(Z, Y, X)``."""
        return tuple(np.meshgrid(*[self.coords()[a] for a in self.axes], indexing="ij", sparse=True))

    def nbytes(self, fields: int = 1) -> int:
        """Bytes taken by ``fields`` float64 arrays on this grid."""
        return 8 * self.size * fields

    # -- py-pde interoperability ---------------------------------------------------
    def to_pde(self):
        """The matching ``pde.CartesianGrid`` (axes ordered x, [y,] z as py-pde expects;
        axisymmetric grids: ``pde.CylindricalSymGrid``, axes r, z)."""
        return self.geometry.to_pde()

    def to_pde_data(self, a: np.ndarray) -> np.ndarray:
        """Reorder a spotpde array ``(z, [y,] x)`` into py-pde order ``(x, [y,] z)``."""
        return np.ascontiguousarray(np.transpose(a, tuple(reversed(range(a.ndim)))))

    def from_pde_data(self, a: np.ndarray) -> np.ndarray:
        """Transpose py-pde order (x first, z last) back to spotpde order (z first)."""
        return np.ascontiguousarray(np.transpose(a, tuple(reversed(range(a.ndim)))))
