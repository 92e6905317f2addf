"""Finite volumes with a metric and a staircase: axisymmetric silos and hoppers.

The spot Fokker-Planck equation of :mod:`spotpde.density._elliptic`,
``d rho/dt = -div J + S`` with ``J_perp = -grad_perp(D_perp rho)`` and
``J_z = v_s rho - d/dz(D_par rho)``, on a 2D grid whose cells carry a horizontal
measure and whose faces carry areas (docs/spot_density.md section 9):

* Cartesian (a 2D wedge hopper): cell measure ``m_i = 1``, face weights 1;
* axisymmetric (``(z, r)``, a ring per cell): ``m_i = r_i / h = i + 1/2`` (ring volume
  ``2 pi r_i h**2 = 2 pi h**3 m_i``), radial face ``r_{i-1/2}`` has weight
  ``r_{i-1/2} / h = i`` (area ``2 pi r_{i-1/2} h``), a vertical face has weight ``m_i``
  (the annulus ``2 pi r_i h`` exactly). The axis face ``r_{-1/2} = 0`` has weight 0:
  no flux through the axis and no boundary condition there (a regular axis).

Per cell, ``d rho_c/dt = -(1 / (m_c h)) sum_f (+-) w_f F_f + q_c`` with ``F_f`` the flux
density through face ``f`` (the same face formulas as ``_elliptic``: centred diffusion
``-(D rho)' `` at second order, linear-upwind advection with first-order upwind next to
the floor or a wall below) and ``w_f`` its weight; every face flux is computed once, so
``sum_c m_c rho_c`` (the spots, times ``2 pi h**3`` when axisymmetric) changes only by
inflow minus outflow. On axisymmetric grids the radial operator is
``(1/r) d/dr (r d/dr psi)`` discretised as
``[r_{i+1/2} (psi_{i+1} - psi_i) - r_{i-1/2} (psi_i - psi_{i-1})] / (r_i h**2)``,
second order for smooth axisymmetric ``psi`` (``psi_r(0) = 0``), also in the first cell.

**Staircase.** With a hopper, only ``grid.active`` cells are solved; a face between an
active and an inactive cell is a wall (weight 0). Inactive cells are decoupled and held
at 0 (a diagonal ``-v_max / h``).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from ..grid import Grid

__all__ = ["metric", "assemble", "level_fluxes", "pad", "horizontal_measures"]


def metric(grid: Grid):
    """Cell measures and face weights of a 2D (Cartesian or axisymmetric) grid.

    Returns:
        ``(m, fr, fz, active)``: ``m`` ``(nx,)`` cell measures (``r_i / h`` or 1);
        ``fr`` ``(nz, nx + 1)`` weights of the horizontal-flux faces at
        ``x_{i-1/2}`` (0 at the axis, the outer walls and staircase walls);
        ``fz`` ``(nz - 1, nx)`` weights of the faces between rows ``k`` and ``k + 1``
        (``m_i``, 0 at staircase walls); ``active`` the grid's bool mask.
    """
    nz, n = grid.shape
    active = np.asarray(grid.active)
    m, faces = grid.geometry.column_weights
    open_x, open_z = grid.geometry.open_faces()
    fr = np.zeros((nz, n + 1))
    fr[:, 1:-1] = faces[1:-1] * open_x
    fz = m[None, :] * open_z
    return m, fr, fz, active


def horizontal_measures(grid: Grid) -> np.ndarray:
    """``grid.horizontal_measures`` as an ``(nx,)`` array (d**2 or d)."""
    return np.broadcast_to(np.asarray(grid.horizontal_measures, float), (grid.nx,)).copy()


def _full(value, shape) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, dtype=float), shape)


def assemble(grid: Grid, v, D_perp, D_par) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """``A`` (``d rho/dt = A rho + q``) and the outflow row on a metric / staircase grid.

    Args:
        grid: a 2D grid (reflecting outer walls; open walls are padded by the caller).
        v, D_perp, D_par: drift (d / time, > 0) and diffusivities (d**2 / time), floats
            or grid-shaped arrays.

    Returns:
        ``(A, out)``: ``A`` sparse ``(N, N)`` in 1/time; ``out @ rho`` the outflow
        through the top in spots per unit time (``grid.horizontal_measures`` weights).
    """
    shape = grid.shape
    nz, n = shape
    h = grid.spacing
    v, Dp, Dz = (_full(c, shape) for c in (v, D_perp, D_par))
    m, fr, fz, active = metric(grid)
    idx = np.arange(nz * n).reshape(shape)
    rows, cols, vals = [], [], []
    inv_vol = 1.0 / (m[None, :] * h)

    def flux(minus, plus, weight, terms):
        """Face flux density ``sum coef * rho[col]``, times ``weight``, leaves ``minus``."""
        for col, coef in terms:
            w = np.broadcast_to(weight * coef, minus.shape).ravel()
            col = np.broadcast_to(col, minus.shape).ravel()
            mi = minus.ravel()
            rows.append(mi); cols.append(col); vals.append(-w * inv_vol.ravel()[mi % n])
            if plus is not None:
                pl = plus.ravel()
                rows.append(pl); cols.append(col); vals.append(w * inv_vol.ravel()[pl % n])

    # horizontal faces i | i+1 (interior faces of fr)
    if n >= 2:
        L, R = idx[:, :-1], idx[:, 1:]
        flux(L, R, fr[:, 1:-1], [(R, -Dp[:, 1:] / h), (L, Dp[:, :-1] / h)])
    # vertical faces k | k+1
    if nz >= 2:
        vf = 0.5 * (v[:-1] + v[1:])
        below, above = idx[:-1], idx[1:]
        flux(below, above, fz, [(above, -Dz[1:] / h), (below, Dz[:-1] / h)])
        # linear upwind where the cell below the face's lower cell is active, else first order
        second = np.zeros((nz - 1, n), bool)
        second[1:] = active[:-2] & active[1:-1]
        first = ~second
        flux(below, above, fz * first, [(below, vf)])
        if nz >= 3:
            w2 = fz[1:] * second[1:]
            flux(below[1:], above[1:], w2, [(below[1:], 1.5 * vf[1:]), (idx[:-2], -0.5 * vf[1:])])
        top_second = active[-2] & active[-1]
        top = [(idx[-1], np.where(top_second, 1.5, 1.0) * v[-1]),
               (idx[-2], np.where(top_second, -0.5, 0.0) * v[-1])]
    else:
        top = [(idx[-1], v[-1])]
    top_w = m * active[-1]
    flux(idx[-1], None, top_w, top)
    # inactive cells: decoupled, held at zero
    dead = idx[~active]
    if dead.size:
        rows.append(dead); cols.append(dead)
        vals.append(np.full(dead.size, -max(float(np.max(v)), 1e-300) / h))
    N = nz * n
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(N, N))
    meas = horizontal_measures(grid)
    orow = np.zeros(N)
    for col, coef in top:
        np.add.at(orow, np.ravel(col), np.ravel(coef * active[-1] * meas))
    return A, sp.csr_matrix(orow[None, :])


def level_fluxes(grid: Grid, rho: np.ndarray, v, D_par) -> np.ndarray:
    """Spots per unit time through every horizontal face level of the operator.

    Args:
        grid: the grid of :func:`assemble`; rho: grid-shaped density.
        v, D_par: drift and vertical diffusivity as passed to :func:`assemble`.

    Returns:
        ``(nz,)``: the flux through the faces between rows ``k`` and ``k + 1``
        (``k < nz - 1``) and, last, the outflow through the top. In a steady state each
        equals the inflow ``Q0``.
    """
    shape = grid.shape
    nz, n = shape
    h = grid.spacing
    v, Dz = _full(v, shape), _full(D_par, shape)
    _, _, fz, active = metric(grid)
    meas = horizontal_measures(grid)
    rho = np.asarray(rho, float)
    out = np.empty(nz)
    vf = 0.5 * (v[:-1] + v[1:])
    for k in range(nz - 1):
        if k >= 1:
            up2 = np.where(active[k - 1] & active[k], 1.5 * rho[k] - 0.5 * rho[k - 1], rho[k])
        else:
            up2 = rho[0]
        F = vf[k] * up2 - (Dz[k + 1] * rho[k + 1] - Dz[k] * rho[k]) / h
        out[k] = np.sum(F * meas * (fz[k] > 0))
    if nz >= 2:
        rt = np.where(active[-2] & active[-1], 1.5 * rho[-1] - 0.5 * rho[-2], rho[-1])
    else:
        rt = rho[-1]
    out[-1] = np.sum(v[-1] * rt * meas * active[-1])
    return out


def pad(grid: Grid, p: int, coeffs):
    """A reflecting grid widened by ``p`` cells for open walls, padded coefficients, crop.

    Axisymmetric grids widen outward only (``r`` up to ``a + p h``); Cartesian ones on
    both sides. The hopper is kept (same centre and slope): the window sees a wider silo
    with the same hopper. Coefficient arrays are extended by their edge values.
    """
    if p == 0:
        return dataclasses.replace(grid, walls="reflecting"), list(coeffs), lambda a: a
    h = grid.spacing
    x0, x1 = grid.x_range
    lo, _ = grid.geometry.padding(p)
    g = dataclasses.replace(grid, x_range=(x0 - lo * h, x1 + p * h), walls="reflecting")
    widths = [(0, 0), (lo, p)]
    coeffs = [np.pad(c, widths, mode="edge") if np.ndim(c) > 0 else c for c in coeffs]
    n = grid.nx

    def crop(a):
        return np.ascontiguousarray(a[..., lo:lo + n])

    return g, coeffs, crop
