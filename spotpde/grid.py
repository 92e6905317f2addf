"""The computational grid: cell-centred, uniform spacing, lengths in particle diameters d.

Array order follows the result Dataset: ``(z, x)`` in 2D and ``(z, y, x)`` in 3D, so
``field[k, i]`` is the cell centred at ``(x[i], z[k])``. Cell ``k`` spans
``[z0 + k h, z0 + (k + 1) h)``; the orifice lies on the bottom face ``z = z0``.
In 3D the ``y`` extent equals the ``x`` extent (docs/interface.md).

py-pde orders axes the other way (``x`` first); :meth:`Grid.to_pde` builds the matching
``pde.CartesianGrid`` and :meth:`Grid.to_pde_data` / :meth:`Grid.from_pde_data`
transpose between the two orders.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

WALLS = ("reflecting", "open")

#: Particle drift components by dimension, in the result-variable names of docs/interface.md.
DRIFT_KEYS = {2: ("u_x", "u_z"), 3: ("u_x", "u_y", "u_z")}
#: Independent components of a symmetric diffusivity tensor by dimension.
DIFFUSIVITY_KEYS = {
    2: ("D_xx", "D_xz", "D_zz"),
    3: ("D_xx", "D_yy", "D_zz", "D_xy", "D_xz", "D_yz"),
}


def derivative(f: np.ndarray, spacing: float, axis: int) -> np.ndarray:
    """Derivative of a cell-centred field along one array axis, in f's units per d.

    Second-order central differences inside and second-order one-sided differences at
    the two ends (``numpy.gradient``, ``edge_order=2``); an axis of two cells gets the
    first-order difference, an axis of one cell a zero derivative.

    Args:
        f: field on the grid (array order ``(z, x)`` / ``(z, y, x)``).
        spacing: cell size ``h`` in d.
        axis: the array axis to differentiate along.
    """
    n = f.shape[axis]
    if n >= 3:
        return np.gradient(f, spacing, axis=axis, edge_order=2)
    if n == 2:
        return np.gradient(f, spacing, axis=axis, edge_order=1)
    return np.zeros_like(f)


@dataclass(frozen=True)
class Grid:
    """A uniform cell-centred grid over the silo.

    Args:
        dims: 2 for ``(x, z)``, 3 for ``(x, y, z)``.
        x: horizontal extent ``(x0, x1)`` in d (3D: also the ``y`` extent).
        z: vertical extent ``(z0, z1)`` in d; the orifice is at ``z0``.
        spacing: cell size ``h`` in d; must divide both extents.
        walls: ``"reflecting"`` (no flux through the side walls) or ``"open"``.
    """

    dims: int
    x_range: tuple[float, float]
    z_range: tuple[float, float]
    spacing: float
    walls: str = "reflecting"

    def __post_init__(self):
        if self.dims not in (2, 3):
            raise ValueError(f"dims must be 2 or 3, got {self.dims!r}")
        if self.walls not in WALLS:
            raise ValueError(f"walls must be one of {WALLS}, got {self.walls!r}")
        h = float(self.spacing)
        if not (h > 0 and np.isfinite(h)):
            raise ValueError(f"spacing must be a finite number > 0, got {self.spacing!r}")
        for name, (a, b) in (("x", self.x_range), ("z", self.z_range)):
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
        """Number of cells along x (3D: also along y)."""
        return int(round((self.x_range[1] - self.x_range[0]) / self.spacing))

    @property
    def nz(self) -> int:
        """Number of cells along z."""
        return int(round((self.z_range[1] - self.z_range[0]) / self.spacing))

    @property
    def shape(self) -> tuple[int, ...]:
        """Array shape: ``(nz, nx)`` or ``(nz, ny, nx)`` with ``ny == nx``."""
        return (self.nz, self.nx) if self.dims == 2 else (self.nz, self.nx, self.nx)

    @property
    def axes(self) -> tuple[str, ...]:
        """Dimension names in array order."""
        return ("z", "x") if self.dims == 2 else ("z", "y", "x")

    @property
    def size(self) -> int:
        """Total number of cells."""
        return int(np.prod(self.shape))

    @property
    def cell_volume(self) -> float:
        """``h**dims`` in d**dims."""
        return self.spacing**self.dims

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
        """Cell-centre y coordinates in d (3D; the same extent as x)."""
        return self.x.copy()

    @cached_property
    def z(self) -> np.ndarray:
        """Cell-centre z coordinates in d (height above the orifice plane)."""
        return self.z_range[0] + (np.arange(self.nz) + 0.5) * self.spacing

    @property
    def y_centre(self) -> float:
        """Middle of the y extent in d (3D; the default y of the orifice and tracer)."""
        return 0.5 * (self.x_range[0] + self.x_range[1])

    def coords(self) -> dict[str, np.ndarray]:
        """1D coordinate arrays by axis name."""
        out = {"z": self.z, "x": self.x}
        if self.dims == 3:
            out["y"] = self.y
        return out

    def mesh(self) -> tuple[np.ndarray, ...]:
        """Broadcastable coordinate arrays in array order: ``(Z, X)`` or ``(Z, Y, X)``."""
        return tuple(np.meshgrid(*[self.coords()[a] for a in self.axes], indexing="ij", sparse=True))

    def nbytes(self, fields: int = 1) -> int:
        """Bytes taken by ``fields`` float64 arrays on this grid."""
        return 8 * self.size * fields

    # -- py-pde interoperability ---------------------------------------------------
    def to_pde(self):
        """The matching ``pde.CartesianGrid`` (axes ordered x, [y,] z as py-pde expects)."""
        import pde

        bounds = [self.x_range] + ([self.x_range] if self.dims == 3 else []) + [self.z_range]
        shape = [self.nx] + ([self.nx] if self.dims == 3 else []) + [self.nz]
        return pde.CartesianGrid(bounds, shape)

    def to_pde_data(self, a: np.ndarray) -> np.ndarray:
        """Reorder a spotpde array ``(z, [y,] x)`` into py-pde order ``(x, [y,] z)``."""
        return np.ascontiguousarray(np.transpose(a, tuple(reversed(range(a.ndim)))))

    def from_pde_data(self, a: np.ndarray) -> np.ndarray:
        """Transpose py-pde order (x first, z last) back to spotpde order (z first)."""
        return np.ascontiguousarray(np.transpose(a, tuple(reversed(range(a.ndim)))))
