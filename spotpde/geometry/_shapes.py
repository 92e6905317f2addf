"""The four silo shapes: box, axisymmetric, wedge hopper, cone hopper (private).

Each :class:`Geometry` answers, for one :class:`spotpde.grid.Grid`, the questions the
stages used to answer by testing which grid they had (docs/architecture.md,
"Geometry"): coordinate and field names, cell and face measures, the active cells, the
divergence on the cell centres, the wall faces of the staircase, and which features it
supports. Lengths in d; measures in d**dims (cells of a box) or d**3 (rings).
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cached_property
from typing import NamedTuple

import numpy as np

from ._differences import derivative, is_zero, masked_derivative

#: Result-variable names of the drift and the independent diffusivity components.
DRIFT_KEYS = {2: ("u_x", "u_z"), 3: ("u_x", "u_y", "u_z")}
DIFFUSIVITY_KEYS = {
    2: ("D_xx", "D_xz", "D_zz"),
    3: ("D_xx", "D_yy", "D_zz", "D_xy", "D_xz", "D_yz"),
}
AXISYMMETRIC_DRIFT_KEYS = ("u_r", "u_z")
AXISYMMETRIC_DIFFUSIVITY_KEYS = ("D_rr", "D_rz", "D_zz")

#: Features that only a box supports, with the reason the other shapes give. The one
#: place these refusals are stated (callers prefix the argument's name).
BOX_ONLY = {
    "sde ensemble": "sde_ensemble walks particles in a Cartesian box; axisymmetric grids "
                    "and hoppers are not supported",
    "cosine series": "cosine coefficients exist for Cartesian boxes only, not for "
                     "axisymmetric or hopper grids",
}
#: Features measured on a plane of equal cells (2D boxes and wedges, not rings, not 3D);
#: ``{shape}`` is replaced by the grid's dims (and ", axisymmetric" for rings).
PLANE_ONLY = {
    "track observables": "observables are measured on 2D Cartesian silos (domain.dims = 2, "
                         "domain.coordinates = 'cartesian'), got {shape}; read a thin 3D "
                         "silo with spotpde.tracks.read(..., dims=2)",
}
FEATURES = tuple(BOX_ONLY) + tuple(PLANE_ONLY)

#: Coordinate systems of a grid: ``"cartesian"`` (2D ``(x, z)`` or 3D ``(x, y, z)``) or
#: ``"axisymmetric"`` (``(r, z)``, a cylindrical silo, dims = 2).
COORDINATES = ("cartesian", "axisymmetric")


def check_shape(dims, x_range, coordinates, hopper) -> None:
    """ValueError unless ``coordinates`` and ``hopper`` (a ``spotpde.grid.Hopper`` or
    None) make a shape on a grid of ``dims`` over ``x_range`` (d): the one statement of
    which combinations exist (called by :class:`spotpde.grid.Grid`)."""
    if coordinates not in COORDINATES:
        raise ValueError(f"coordinates must be one of {COORDINATES}, got {coordinates!r}")
    curved = coordinates == "axisymmetric"
    if curved:
        if dims != 2:
            raise ValueError(f"dims: axisymmetric coordinates have dims = 2 (r, z), got {dims!r}")
        if float(x_range[0]) != 0.0:
            raise ValueError(f"x range: axisymmetric coordinates need x = (0, a) (the axis "
                             f"at r = 0), got {tuple(x_range)!r}")
    if hopper is not None:
        if dims != 2:
            raise ValueError("hopper: hoppers exist on 2D and axisymmetric grids only")
        if curved and hopper.centre != 0.0:
            raise ValueError(f"hopper: an axisymmetric hopper is centred on the axis, "
                             f"got centre {hopper.centre!r}")


class Support(NamedTuple):
    """Whether a geometry supports a feature, and why not (empty when it does)."""

    ok: bool
    reason: str = ""


def _clipped_ramp_integral(alpha, beta, t0, t1):
    """``integral_{t0}^{t1} clip(alpha + beta t, 0, 1) dt`` exactly (arrays broadcast)."""
    def F(u):   # antiderivative of clip(u, 0, 1)
        return np.where(u <= 0.0, 0.0, np.where(u >= 1.0, u - 0.5, 0.5 * u * u))
    a0 = alpha + beta * t0
    a1 = alpha + beta * t1
    with np.errstate(divide="ignore", invalid="ignore"):
        slanted = (F(a1) - F(a0)) / beta
    flat = np.clip(a0, 0.0, 1.0) * (t1 - t0)
    return np.where(np.abs(beta) > 1e-14, slanted, flat)


def _read_only(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


class Geometry:
    """The shape of the silo on one grid (base class; use :func:`geometry_of`).

    Attributes:
        kind: ``"box"``, ``"axisymmetric"``, ``"wedge"`` or ``"cone"``.
        curved: cells are rings (a metric factor ``r``).
        masked: a hopper's staircase of inactive cells is part of the grid.
    """

    kind = ""
    curved = False
    masked = False

    def __init__(self, grid):
        self.grid = grid

    # -- names ---------------------------------------------------------------------------
    @property
    def uniform_cells(self) -> bool:
        """Every cell has the same measure and every interior face is open: the fast
        box solvers apply (FFT convolutions, spectral and constant-coefficient paths)."""
        return not (self.curved or self.masked)

    @property
    def components(self) -> tuple[str, ...]:
        """Vector components in result order: ``("x", "z")``, ``("x", "y", "z")`` or
        ``("r", "z")``."""
        return ("x", "z") if self.grid.dims == 2 else ("x", "y", "z")

    @property
    def axes(self) -> tuple[str, ...]:
        """Dimension names in array order: ``("z", "x")``, ``("z", "y", "x")`` or ``("z", "r")``."""
        return ("z", "x") if self.grid.dims == 2 else ("z", "y", "x")

    @property
    def drift_keys(self) -> tuple[str, ...]:
        """Names of the particle drift components in result order."""
        return DRIFT_KEYS[self.grid.dims]

    @property
    def diffusivity_keys(self) -> tuple[str, ...]:
        """Names of the independent diffusivity components in result order."""
        return DIFFUSIVITY_KEYS[self.grid.dims]

    @property
    def kernel_dims(self) -> int:
        """Dimension of the influence kernel the physics needs (3 for rings)."""
        return self.grid.dims

    @property
    def has_axis(self) -> bool:
        """The low end of the horizontal axis is a symmetry axis (never a wall, never
        padded), not a side wall."""
        return False

    def padding(self, p: int) -> tuple[int, int]:
        """Cells ``(low, high)`` a window on a wider silo gains along x for ``p`` cells
        of open wall: both sides of a box, only outward from a symmetry axis."""
        return (0, p) if self.has_axis else (p, p)

    @property
    def description(self) -> str:
        """A few words naming the shape for people: ``"2D"``, ``"3D"``, ``"axisymmetric
        (z, r)"``, followed by ``", hopper <angle> degrees"`` for a hopper."""
        return f"{self.grid.dims}D"

    @property
    def result_attrs(self) -> dict:
        """Shape metadata a result Dataset carries beyond its coordinate system:
        ``{"hopper_angle": degrees}`` for a hopper, else empty."""
        return {}

    def to_pde(self):
        """The matching py-pde grid: ``pde.CartesianGrid`` with axes x, [y,] z (boxes) or
        ``pde.CylindricalSymGrid`` with axes r, z (rings). Imports py-pde (optional)."""
        import pde   # lazy: py-pde is an optional, heavy dependency

        g = self.grid
        bounds = [g.x_range] + ([g.y_range] if g.dims == 3 else []) + [g.z_range]
        shape = [g.nx] + ([g.ny] if g.dims == 3 else []) + [g.nz]
        return pde.CartesianGrid(bounds, shape)

    def coords(self) -> dict[str, np.ndarray]:
        """1D coordinate arrays by axis name (cell centres in d)."""
        g = self.grid
        out = {"z": g.z, "x": g.x}
        if g.dims == 3:
            out["y"] = g.y
        return out

    # -- measures ------------------------------------------------------------------------
    @cached_property
    def cell_volumes(self) -> np.ndarray:
        """Volume of every cell, broadcastable to the grid shape: ``h**dims`` (d**dims)
        or the ring ``2 pi r_i h**2`` (d**3, exact). Cut by a hopper, a cell's material
        volume is ``cell_volumes * material``."""
        return np.full((1,) * self.grid.dims, self.grid.spacing**self.grid.dims)

    @cached_property
    def horizontal_measures(self) -> np.ndarray:
        """Horizontal cross-section of every cell column, broadcastable to a horizontal
        slice: ``h**(dims-1)`` or the annulus ``2 pi r_i h`` (d**2)."""
        return np.full((1,) * (self.grid.dims - 1), self.grid.spacing ** (self.grid.dims - 1))

    @cached_property
    def column_weights(self) -> tuple[np.ndarray, np.ndarray]:
        """``(m, faces)`` of a 2D grid: each column's horizontal measure relative to a
        box cell's (``r_i / h`` or 1, shape ``(nx,)``) and each ``x`` face's area relative
        to a box face's (``r_{i-1/2} / h`` or 1, shape ``(nx + 1,)``; 0 on the axis)."""
        n = self.grid.nx
        return np.ones(n), np.ones(n + 1)

    @cached_property
    def density_weight(self) -> np.ndarray:
        """``Q / P`` of the tracer's conservative variable, shape ``(1, nx)``: ``2 pi r``
        (d) on rings, 1 otherwise."""
        return np.ones((1, self.grid.nx))

    # -- the material --------------------------------------------------------------------
    @cached_property
    def active(self) -> np.ndarray:
        """Cells of the computation, grid-shaped bool, read-only (all True without a
        hopper)."""
        return _read_only(np.ones(self.grid.shape, dtype=bool))

    @cached_property
    def material(self) -> np.ndarray:
        """Fraction of each cell's volume inside the granular material, grid-shaped,
        read-only (all ones without a hopper)."""
        return _read_only(np.ones(self.grid.shape))

    def restrict(self, a: np.ndarray) -> np.ndarray:
        """``a`` on the active cells, 0 elsewhere (a box returns ``a`` itself)."""
        return a

    def blank(self, a: np.ndarray) -> np.ndarray:
        """``a`` with NaN on the inactive cells (results outside the material); ``a``
        itself when every cell is active."""
        return a

    def total(self, a: np.ndarray) -> float:
        """``sum_cells a * volume``: the integral of a cell-centred density, in a's units
        times d**dims (boxes: the sum times ``h**dims``) or d**3 (rings)."""
        return a.sum() * self.grid.spacing**self.grid.dims

    def open_faces(self) -> tuple[np.ndarray, np.ndarray]:
        """Interior faces of a 2D grid that join two active cells: ``x`` faces
        ``(nz, nx - 1)`` (between columns ``i`` and ``i + 1``) and ``z`` faces
        ``(nz - 1, nx)`` (between rows ``k`` and ``k + 1``), bool. The others are walls."""
        act = np.asarray(self.active, dtype=bool)
        return act[:, :-1] & act[:, 1:], act[:-1] & act[1:]

    def clearance(self, x: float, z: float, margin: float = 0.0) -> float:
        """Horizontal distance in d from the point ``(x, z)`` inward to a hopper wall
        moved ``margin`` d outward (negative beyond it; ``inf`` without a hopper)."""
        return np.inf

    def side_walls(self) -> tuple[float, float, float]:
        """``(centre, half_width, slope)`` of the slanted walls: the material is the
        grid's box cut to ``|x - centre| <= half_width + slope (z - z0)`` (``r`` in place
        of ``|x - centre|`` on rings); ``half_width = inf`` without a hopper. In d, d, 1."""
        return 0.5 * sum(self.grid.x_range), np.inf, 0.0

    def contains(self, x, z) -> np.ndarray:
        """Whether the points ``(x, z)`` (``(r, z)`` on rings; d, arrays broadcast) lie
        in the material: inside the box (closed) and the hopper's walls."""
        x, z = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(z, dtype=float))
        (x0, x1), (z0, z1) = self.grid.x_range, self.grid.z_range
        c, hw, s = self.side_walls()
        ok = (x >= x0) & (x <= x1) & (z >= z0) & (z <= z1)
        if np.isfinite(hw):
            ok &= np.abs(x - c) <= hw + s * (z - z0)
        return ok

    # -- differences ---------------------------------------------------------------------
    def gradient(self, f: np.ndarray, comp: str) -> np.ndarray:
        """Second-order derivative of a cell-centred field along ``comp`` (central
        inside, one-sided at the ends), in f's units per d."""
        axis = self.grid.dims - 1 if comp == "x" else {"z": 0, "y": 1}[comp]
        if f.shape[axis] < 3:
            raise ValueError(f"grid: need at least 3 cells along {comp} to differentiate")
        return derivative(f, self.grid.spacing, axis)

    def divergence(self, T: Mapping) -> dict:
        """Row divergence ``(div T)^a = sum_b d_b T^ab`` of a symmetric tensor field
        keyed by :attr:`diffusivity_keys` (missing or scalar components are skipped).
        Returns ``{component: array}`` in T's units per d."""
        comps = self.components
        out = {}
        for a in comps:
            acc = None
            for b in comps:
                t = T.get("D_" + "".join(sorted((a, b), key="xyz".index)))
                if is_zero(t) or np.ndim(t) == 0:
                    continue
                g = self.gradient(np.asarray(t, dtype=float), b)
                acc = g if acc is None else acc + g
            out[a] = np.zeros(self.grid.shape) if acc is None else acc
        return out

    def velocity_divergence(self, u: Mapping) -> np.ndarray:
        """``div u`` of a vector field keyed ``u_<component>``, in u's units per d."""
        return sum(self.gradient(u[f"u_{a}"], a) for a in self.components)

    # -- walls ---------------------------------------------------------------------------
    def wall_faces(self) -> list[tuple[int, int, int]]:
        """Vertical wall faces ``(k, j, direction)`` of a 2D grid: cell ``(k, j)`` is
        active and its neighbour at ``j + direction`` is inactive or lies beyond a
        reflecting side wall (never the symmetry axis)."""
        act = np.asarray(self.active, dtype=bool)
        wall = self.grid.walls == "reflecting"
        low_wall = wall and not self.has_axis
        nbr_hi = np.concatenate([act[:, 1:], np.full((act.shape[0], 1), not wall)], axis=1)
        nbr_lo = np.concatenate([np.full((act.shape[0], 1), not low_wall), act[:, :-1]], axis=1)
        if self.has_axis:
            nbr_lo[:, 0] = True
        hi = np.argwhere(act & ~nbr_hi)
        lo = np.argwhere(act & ~nbr_lo)
        return sorted([(int(k), int(j), 1) for k, j in hi] + [(int(k), int(j), -1) for k, j in lo])

    def horizontal_faces(self) -> list[tuple[int, int, int]]:
        """Horizontal wall faces ``(k, j, direction)`` of the staircase: cell ``(k, j)`` is
        active and its neighbour at ``k + direction`` is inactive (the floor and the top
        are not walls)."""
        act = np.asarray(self.active, dtype=bool)
        below = np.zeros_like(act)
        below[1:] = act[1:] & ~act[:-1]
        above = np.zeros_like(act)
        above[:-1] = act[:-1] & ~act[1:]
        return sorted([(int(k), int(j), -1) for k, j in np.argwhere(below)]
                      + [(int(k), int(j), 1) for k, j in np.argwhere(above)])

    # -- features ------------------------------------------------------------------------
    def supports(self, feature: str) -> Support:
        """Whether this geometry supports ``feature`` (one of :data:`FEATURES`), with the
        reason when it does not."""
        if feature in PLANE_ONLY:
            if self.grid.dims == 2 and not self.curved:
                return Support(True)
            shape = f"dims = {self.grid.dims}" + (", axisymmetric" if self.curved else "")
            return Support(False, PLANE_ONLY[feature].format(shape=shape))
        if feature not in BOX_ONLY:
            raise ValueError(f"feature: must be one of {', '.join(map(repr, FEATURES))}, "
                             f"got {feature!r}")
        return Support(True) if self.uniform_cells else Support(False, BOX_ONLY[feature])

    def require(self, feature: str, name: str) -> None:
        """ValueError ``"<name>: <reason>"`` unless this geometry supports ``feature``."""
        s = self.supports(feature)
        if not s.ok:
            raise ValueError(f"{name}: {s.reason}")

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.kind}, shape={self.grid.shape})"


class BoxGeometry(Geometry):
    """A rectangular (2D) or cuboid (3D) Cartesian silo."""

    kind = "box"


class AxisymmetricGeometry(Geometry):
    """The ``(r, z)`` half-plane of a cylindrical silo: cells are rings around the axis."""

    kind = "axisymmetric"
    curved = True

    @property
    def components(self):
        return ("r", "z")

    @property
    def axes(self):
        return ("z", "r")

    @property
    def drift_keys(self):
        return AXISYMMETRIC_DRIFT_KEYS

    @property
    def diffusivity_keys(self):
        return AXISYMMETRIC_DIFFUSIVITY_KEYS

    @property
    def kernel_dims(self):
        return 3

    @property
    def has_axis(self):
        return True

    @property
    def description(self):
        return "axisymmetric (z, r)"

    def to_pde(self):
        import pde   # lazy: py-pde is an optional, heavy dependency

        g = self.grid
        return pde.CylindricalSymGrid(g.x_range[1], g.z_range, (g.nx, g.nz))

    def coords(self):
        return {"z": self.grid.z, "r": self.grid.x}

    def side_walls(self):
        return 0.0, np.inf, 0.0

    @cached_property
    def cell_volumes(self):
        return (2.0 * np.pi * self.grid.spacing**2 * self.grid.x)[None, :]

    @cached_property
    def horizontal_measures(self):
        return 2.0 * np.pi * self.grid.spacing * self.grid.x

    @cached_property
    def column_weights(self):
        n = self.grid.nx
        return np.arange(n) + 0.5, np.arange(n + 1).astype(float)

    @cached_property
    def density_weight(self):
        return (2.0 * np.pi * self.grid.x)[None, :]

    def restrict(self, a):
        return np.where(self.active, a, 0.0)

    def total(self, a):
        return float((a * self.cell_volumes).sum())

    def divergence(self, T, active=None):
        """Cylindrical divergence of an axisymmetric symmetric tensor with ``T_tt = T_rr``:
        ``(div T)_r = d_r T_rr + d_z T_rz``, ``(div T)_z = (1/r) d_r(r T_rz) + d_z T_zz``
        (``T`` keyed ``D_rr, D_rz, D_zz``), differences of :func:`masked_derivative` with
        the even continuation across the axis. Returns ``{"r": ..., "z": ...}``."""
        grid = self.grid
        h = grid.spacing
        act = self.active if active is None else active
        r = grid.x[None, :]

        def arr(key):
            t = T.get(key)
            return None if is_zero(t) else np.broadcast_to(np.asarray(t, dtype=float), grid.shape)

        rr, rz, zz = arr("D_rr"), arr("D_rz"), arr("D_zz")
        out = {"r": np.zeros(grid.shape), "z": np.zeros(grid.shape)}
        if rr is not None:
            out["r"] += masked_derivative(rr, h, 1, act, even_axis=True)
        if rz is not None:
            out["r"] += masked_derivative(rz, h, 0, act)
            out["z"] += masked_derivative(r * rz, h, 1, act, even_axis=True) / r
        if zz is not None:
            out["z"] += masked_derivative(zz, h, 0, act)
        return out

    def velocity_divergence(self, u):
        """``(1/r) d_r(r u_r) + d_z u_z`` by the staircase differences."""
        h, act = self.grid.spacing, self.active
        r = self.grid.x[None, :]
        radial = masked_derivative(r * u["u_r"], h, 1, act, even_axis=True) / r
        return radial + masked_derivative(u["u_z"], h, 0, act)


class _Hopper:
    """The staircase of a hopper: cells whose centre lies inside the walls are active."""

    masked = True

    @cached_property
    def active(self):
        g, hop = self.grid, self.grid.hopper
        Z, X = np.meshgrid(g.z, g.x, indexing="ij", sparse=True)
        return _read_only(np.broadcast_to(
            np.abs(X - hop.centre) <= hop.half_width_at(Z - g.z_range[0]), g.shape).copy())

    def restrict(self, a):
        return np.where(self.active, a, 0.0)

    def blank(self, a):
        return np.where(self.active, a, np.nan)

    @property
    def description(self):
        return f"{super().description}, hopper {self.grid.hopper.angle:g} degrees"

    @property
    def result_attrs(self):
        return {"hopper_angle": float(self.grid.hopper.angle)}

    def side_walls(self):
        hop = self.grid.hopper
        return hop.centre, hop.half_width, hop.slope

    def clearance(self, x, z, margin=0.0):
        hop = self.grid.hopper
        return hop.half_width_at(z - self.grid.z_range[0]) + margin - abs(x - hop.centre)


class WedgeGeometry(_Hopper, BoxGeometry):
    """A 2D box cut by a wedge hopper's straight walls (the staircase ``active``)."""

    kind = "wedge"

    @cached_property
    def material(self):
        """Exact area fractions of the wedge in each cell."""
        g, hop = self.grid, self.grid.hopper
        h = g.spacing
        zf = g.z_range[0] + np.arange(g.nz + 1) * h
        xl = g.x_range[0] + np.arange(g.nx) * h   # left faces
        s = hop.slope
        t0, t1 = (zf[:-1] - g.z_range[0])[:, None], (zf[1:] - g.z_range[0])[:, None]
        # fraction left of the right wall x = c + hw + s t, right of the left wall
        right = _clipped_ramp_integral((hop.centre + hop.half_width - xl) / h, s / h, t0, t1)
        left = _clipped_ramp_integral((xl + h - (hop.centre - hop.half_width)) / h, s / h, t0, t1)
        return _read_only(np.clip((right + left) / h - 1.0, 0.0, 1.0))

    def divergence(self, T, active=None):
        """Row divergence ``d_b T^ab`` (keys ``D_xx, D_xz, D_zz``) that never differences
        across a wall face; scalar components are skipped. Returns ``{"x", "z"}``."""
        h = self.grid.spacing
        act = self.active if active is None else active
        out = {"x": np.zeros(self.grid.shape), "z": np.zeros(self.grid.shape)}
        for key, a, axis in (("D_xx", "x", 1), ("D_xz", "x", 0), ("D_xz", "z", 1), ("D_zz", "z", 0)):
            t = T.get(key)
            if is_zero(t) or np.ndim(t) == 0:
                continue
            out[a] += masked_derivative(t, h, axis, act)
        return out

    def velocity_divergence(self, u):
        """``d_x u_x + d_z u_z`` by the staircase differences."""
        h, act = self.grid.spacing, self.active
        return masked_derivative(u["u_x"], h, 1, act) + masked_derivative(u["u_z"], h, 0, act)


class ConeGeometry(_Hopper, AxisymmetricGeometry):
    """A cylindrical silo cut by a conical hopper (axisymmetric staircase)."""

    kind = "cone"

    @cached_property
    def material(self):
        """Ring-volume fractions of the cone (``r dr`` weights) by the midpoint rule with
        64 sub-heights per cell (exact except where the cone meets the outer wall)."""
        g, hop = self.grid, self.grid.hopper
        h = g.spacing
        zf = g.z_range[0] + np.arange(g.nz + 1) * h
        xl = g.x_range[0] + np.arange(g.nx) * h
        m = 64
        sub = (np.arange(m) + 0.5) / m
        zs = (zf[:-1, None] - g.z_range[0]) + sub[None, :] * h   # (nz, m)
        R = hop.half_width_at(zs)[..., None]                      # (nz, m, 1)
        r0, r1 = xl, xl + h
        inside = (np.clip(R, r0, r1) ** 2 - r0**2) / (r1**2 - r0**2)
        return _read_only(inside.mean(axis=1))


_SHAPES = {(False, False): BoxGeometry, (True, False): AxisymmetricGeometry,
           (False, True): WedgeGeometry, (True, True): ConeGeometry}


def geometry_of(grid) -> Geometry:
    """The :class:`Geometry` of ``grid`` (``grid.geometry`` caches it): the one place
    that reads a grid's coordinates and hopper."""
    return _SHAPES[(grid.coordinates == "axisymmetric", grid.hopper is not None)](grid)
