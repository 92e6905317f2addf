"""Interacting spots on ring cells and staircases: cylinders, wedges, cones (private).

The conservation law of :mod:`spotpde.density._traffic`,

    d rho/dt + div(q(rho) e_z) = div(m(rho) grad(D rho)) + S,

on a 2D grid whose cells carry a measure and whose faces carry areas, the finite volumes
of :mod:`spotpde.density._geometry` (docs/spot_density.md section 9): per cell

    d rho_c/dt = -(1 / (m_c h)) sum_f (+-) w_f F_f,

``F_f`` the flux density through face ``f`` (spots per unit area per unit time) and
``w_f`` its area relative to a box face, from the grid's geometry
(:func:`spotpde.density._geometry.metric`): ``m_i = r_i / h`` and radial faces
``r_{i-1/2} / h`` on rings (0 on the axis: no flux and no boundary condition there),
1 in a wedge; a face between an active and an inactive cell of a hopper's staircase
has weight 0 (a closed wall). The face fluxes are those of the box solver: MUSCL in
``z`` (zero slope in a cell whose vertical neighbour is inactive, the floor or the
top) with the demand-supply flux, the capped floor inflow, the free top exit, and the
pairwise diffusive exchanges ``((D rho)_a - (D rho)_b) m_face / h`` times the face
weight. Every face flux is evaluated once, so ``sum rho_c V_c`` (``grid.cell_volumes``)
changes only by the floor inflow minus the top outflow (``grid.horizontal_measures``).

Bounds: a vertical face of a column has the weight ``m_c`` of the column, so the
advective update is the box's one column by column; on rings the radial weights of a
cell add up to ``2 m_c`` (``i + (i + 1) = 2 (i + 1/2)``), so a cell's diffusive loss is
``2 D rho / h**2`` as in a box and the box's step keeps ``0 <= rho <= rho_max`` (uniform
``D``). NumPy only (the grids that need the metric are 2D and small).
"""

from __future__ import annotations

import numpy as np

from ._geometry import horizontal_measures, metric
from ._traffic import Solver, _slopes


class MetricSolver(Solver):
    """:class:`~spotpde.density._traffic.Solver` on a grid with cell measures and walls.

    Args:
        grid: a 2D grid (reflecting; open walls are padded by the caller) whose
            ``geometry`` gives the measures, face weights and active cells.
        other arguments: as for :class:`~spotpde.density._traffic.Solver`.
    """

    def __init__(self, grid, v, D_perp, D_par, rho_max, flux, diffusion_scaling, limiter,
                 request):
        super().__init__(grid.shape, grid.spacing, v, D_perp, D_par, rho_max, flux,
                         diffusion_scaling, limiter, request)
        if len(self.shape) != 2:
            raise ValueError(f"grid: the metric solver needs a 2D grid, got shape {self.shape}")
        m, fr, fz, active = metric(grid)
        self.backend = "numpy"
        self.active = np.asarray(active, dtype=bool)
        self.m = m
        self.fr = fr[:, 1:-1]                        # interior faces i | i+1, (nz, nx - 1)
        nz, nx = self.shape
        wz = np.empty((nz + 1, nx))                  # horizontal faces, floor first
        wz[0] = m * self.active[0]
        wz[1:-1] = fz
        wz[-1] = m * self.active[-1]
        self.wz = wz
        self.inv = 1.0 / (m[None, :] * self.h)
        meas = horizontal_measures(grid)
        self.floor_area = meas * self.active[0]      # d**2 (rings) or d
        self.top_area = meas * self.active[-1]
        self.volumes = np.broadcast_to(np.asarray(grid.cell_volumes, float), self.shape)
        # MUSCL slopes only where both vertical neighbours are active
        inner = np.zeros(self.shape, dtype=bool)
        inner[1:-1] = self.active[:-2] & self.active[1:-1] & self.active[2:]
        self.inner = inner

    def mass(self, rho: np.ndarray) -> float:
        """Spots in the silo, ``sum(rho * cell_volumes)``."""
        return float((rho * self.volumes).sum())

    def initial(self, rho0):
        """``rho0`` (default 0) restricted to the active cells."""
        rho = np.zeros(self.shape) if rho0 is None else np.array(rho0, float).reshape(self.shape)
        return np.where(self.active, rho, 0.0)

    def vertical_flux(self, rho, t):
        """Flux densities through the ``nz + 1`` horizontal faces (floor first); the
        weights :attr:`wz` close the staircase's walls."""
        F = np.empty((self.shape[0] + 1,) + self.shape[1:])
        s = _slopes(rho, self.limiter) if self.shape[0] > 2 else np.zeros_like(rho)
        s = np.where(self.inner, s, 0.0)
        lo = rho[:-1] + 0.5 * s[:-1]
        hi = rho[1:] - 0.5 * s[1:]
        vf = self.vf[1:-1]
        F[1:-1] = np.minimum(self.demand(lo, vf), self.supply(hi, vf))
        F[0] = np.minimum(self.request(t), self.supply(rho[0], self.vf[0]))
        F[-1] = self.demand(rho[-1], self.vf[-1])
        return F

    def rhs(self, rho, t):
        F = self.vertical_flux(rho, t)
        G = F * self.wz
        out = -(G[1:] - G[:-1]) * self.inv
        if self.diffusive:
            h2 = self.h * self.h
            Dr = self.Dz * rho
            E = (Dr[:-1] - Dr[1:]) * self._mobility(rho[:-1], rho[1:]) / h2 * self.wz[1:-1]
            acc = np.zeros(self.shape)
            acc[:-1] -= E
            acc[1:] += E
            Dr = self.Dp * rho
            E = (Dr[:, :-1] - Dr[:, 1:]) * self._mobility(rho[:, :-1], rho[:, 1:]) / h2 * self.fr
            acc[:, :-1] -= E
            acc[:, 1:] += E
            out += acc / self.m[None, :]
        inj = float((F[0] * self.floor_area).sum())
        outflow = float((F[-1] * self.top_area).sum())
        return out, inj, outflow
