"""Height marching of the steady spot flux with a metric and a staircase (``D_par = 0``).

The 2D counterpart of :mod:`spotpde.density._marching` for axisymmetric grids and
hoppers (docs/spot_density.md section 9). With ``phi = v_s rho_s`` and ``psi = b phi``,

    d phi / dz = (1 / m) d/dx (w d psi / dx),

``m = r, w = r`` in ``(r, z)`` (the horizontal Laplacian of an axisymmetric field) and
``m = w = 1`` in a Cartesian wedge, discretised on row ``k`` as

    (L_k psi)_i = [w_{k,i+1} (psi_{i+1} - psi_i) - w_{k,i} (psi_i - psi_{i-1})] / (m_i h**2),

with the face weights ``w`` of :func:`spotpde.density._geometry.metric` (0 on the axis,
the outer wall and the staircase walls of row ``k``). ``sum_i m_i (L_k psi)_i = 0``
(the sum telescopes), so every step keeps ``sum_i m_i phi_i`` (the flux
``v_s sum(rho_s * horizontal_measures)``, over ``2 pi h**2`` when axisymmetric) to
round-off, and cells that join the staircase higher up start empty (the face below
them is a wall).

Height stepping as in ``_marching`` (2D): Crank-Nicolson
``(I - h/2 L_{k+1} B_{k+1}) phi_{k+1} = (I + h/2 L_k B_k) phi_k`` (second order),
with a Rannacher start (Rannacher 1984, Numer. Math. 43, 309): two backward-Euler
steps of ``h/4`` to the first cell centre, then the first ``EULER_ROWS = 2`` rows by
two backward-Euler half steps each (``_marching`` takes one such row). A point orifice
on the axis is a delta in the first ring; with one Euler row its highest radial modes,
which Crank-Nicolson damps only by ``|1 - b/h| / (1 + b/h)`` per row, left an
``O(h**2)`` kink in the first two cells, hence a first-order ``u_r = b dv/dr`` there
(1.5e-2, 8.8e-3, 4.8e-3 of max ``|u_r|`` at ``z >= 3`` for ``h = 1/8, 1/16, 1/32``);
with two rows ``u_r`` converges at second order (2.0e-3, 5.0e-4, 1.2e-4) and ``v`` as
before (1.5e-3, 3.7e-4, 9.3e-5). A fixed number of first-order steps keeps the global
error ``O(h**2)``.

Hoppers (``scheme="bdf2"``): every few rows the staircase gains a cell, which joins
empty (the face below it is a wall), a sharp perturbation on which Crank-Nicolson
rings: ``v`` overshot its inner neighbour in the new cell (``u_x`` pointing away from
the orifice, up to 0.06 at ``h = 1/4``, 30 degrees). The second-order backward
difference, L-stable,
``(I - 2h/3 L_{k+1} B_{k+1}) phi_{k+1} = (4 phi_k - phi_{k-1}) / 3``, after the same
backward-Euler start, damps it (no outward ``u_x`` left) and keeps the flux:
``S_{k+1} = (4 S_k - S_{k-1}) / 3 = S_k``. Its error constant is larger (point source
on the axis: ``v`` 1.6e-3 against 1.5e-3, ``u_r`` 5.5e-3 against 2.0e-3 at ``h = 1/8``),
so plain cylinders keep Crank-Nicolson. Each tridiagonal
system is solved by the Thomas algorithm (numba): scaled by ``m``, the matrix is
symmetric-positive in its off-diagonal pattern and strictly column diagonally dominant
(``m_j + s b_j (w_j + w_{j+1})`` against ``s b_j w_j + s b_j w_{j+1}``), so no pivoting
is needed.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from numba import njit

#: rows reached by backward-Euler half steps before Crank-Nicolson takes over
EULER_ROWS = 2


@njit(cache=True)
def _thomas(lo, di, up, rhs, out):
    """Solve the tridiagonal system ``lo_i x_{i-1} + di_i x_i + up_i x_{i+1} = rhs_i``."""
    n = rhs.size
    cp = np.empty(n)
    dp = np.empty(n)
    cp[0] = up[0] / di[0]
    dp[0] = rhs[0] / di[0]
    for i in range(1, n):
        den = di[i] - lo[i] * cp[i - 1]
        cp[i] = up[i] / den
        dp[i] = (rhs[i] - lo[i] * dp[i - 1]) / den
    out[n - 1] = dp[n - 1]
    for i in range(n - 2, -1, -1):
        out[i] = dp[i] - cp[i] * out[i + 1]


def _solve(b, w, m, s, rhs):
    """``(I - s L B)^{-1} rhs`` on one row, ``s = dz / h**2``, ``w`` the ``n + 1`` face weights."""
    lo = -s * w[:-1] / m * np.roll(b, 1)
    up = -s * w[1:] / m * np.roll(b, -1)
    di = 1.0 + s * (w[:-1] + w[1:]) / m * b
    out = np.empty_like(rhs)
    _thomas(lo, di, up, np.ascontiguousarray(rhs), out)
    return out


def _apply(b, w, m, s, x):
    """``(I + s L B) x`` on one row."""
    psi = b * x
    d = np.diff(psi)                       # psi_{i+1} - psi_i at the n - 1 interior faces
    flux = np.zeros(psi.size + 1)
    flux[1:-1] = w[1:-1] * d
    return x + s * (flux[1:] - flux[:-1]) / m


def march(phi_floor: np.ndarray, b: np.ndarray, h: float, m: np.ndarray, w: np.ndarray,
          active: np.ndarray, progress: Callable[[float], None] | None = None,
          scheme: str = "cn") -> np.ndarray:
    """March the steady spot flux up a metric / staircase grid from the floor values.

    Args:
        phi_floor: ``Q0 s`` on the floor cells, ``(nx,)``, spots / time per unit area.
        b: diffusion length at the cell centres ``(nz, nx)``, d.
        h: spacing in d.
        m: cell measures ``(nx,)``; w: face weights ``(nz, nx + 1)``; active: mask
            ``(nz, nx)`` (:func:`spotpde.density._geometry.metric`).
        progress: called with the fraction done.

    Returns:
        ``phi`` ``(nz, nx)``, 0 on inactive cells.
    """
    b = np.ascontiguousarray(b, dtype=float)
    nz = b.shape[0]
    act = np.asarray(active, float)
    out = np.zeros(b.shape)
    c_half = 0.5 / h
    c_start = 0.25 / h
    phi = np.asarray(phi_floor, dtype=float) * act[0]
    for _ in range(2):
        phi = _solve(b[0], w[0], m, c_start, phi)
    out[0] = phi
    every = max(1, nz // 100)
    for k in range(nz - 1):
        if k == 0:      # Rannacher: the first step as two backward-Euler half steps
            prev = phi
            phi = _solve(0.5 * (b[0] + b[1]), w[0], m, c_half, phi)
            phi = _solve(b[1], w[1], m, c_half, phi * act[1])
        elif scheme == "bdf2":
            prev, phi = phi, _solve(b[k + 1], w[k + 1], m, 2.0 / (3.0 * h),
                                    (4.0 * phi - prev) / 3.0 * act[k + 1])
        elif k < EULER_ROWS:
            phi = _solve(0.5 * (b[k] + b[k + 1]), w[k + 1], m, c_half, phi * act[k + 1])
            phi = _solve(b[k + 1], w[k + 1], m, c_half, phi)
        else:
            rhs = _apply(b[k], w[k], m, c_half, phi) * act[k + 1]
            phi = _solve(b[k + 1], w[k + 1], m, c_half, rhs)
        out[k + 1] = phi
        if progress is not None and k % every == 0:
            progress((k + 1) / nz)
    if progress is not None:
        progress(1.0)
    return out
