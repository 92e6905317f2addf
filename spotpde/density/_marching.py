"""Height marching of the steady spot flux for spatially varying ``b`` (``D_par = 0``).

Equation (docs/conventions.md section 1, steady, ``D_par = 0``, Ito form): with the upward spot
flux density ``phi = v_s rho_s`` and ``D_perp rho_s = b phi``,

    d phi / dz = lap_perp (b phi),        no flux through the side walls.

Space: conservative second-order finite volumes on the cell centres,
``(L psi)_i = (psi_{i+1} - 2 psi_i + psi_{i-1}) / h**2`` with ``psi = b phi`` and the
wall fluxes set to zero (``psi_{-1} = psi_0``). Every column of ``L B`` sums to zero,
so each step below keeps ``sum(phi) h**(dims-1)`` exactly (round-off).

Height ("time" ``z``), step ``dz = h`` from cell centre ``z_k`` to ``z_{k+1}``:

* 2D, Crank-Nicolson (second order):
  ``(I - dz/2 L B_{k+1}) phi_{k+1} = (I + dz/2 L B_k) phi_k``.
* 3D, Peaceman-Rachford ADI (second order), ``B_m = (B_k + B_{k+1}) / 2``:
  ``(I - dz/2 Lx B_m) phi* = (I + dz/2 Ly B_m) phi_k``,
  ``(I - dz/2 Ly B_m) phi_{k+1} = (I + dz/2 Lx B_m) phi*``.

Start (Rannacher smoothing, Rannacher 1984, Numer. Math. 43, 309): the floor values
``phi(z0) = Q0 s(x)`` are carried to the first cell centre ``z0 + h/2`` by two
backward-Euler steps of ``h/4`` (3D: locally one-dimensional splitting
``(I - s Lx B)(I - s Ly B)``), and the first whole step ``z_0 -> z_1`` is taken as two
backward-Euler steps of ``h/2`` (four implicit-Euler steps in all, as Rannacher
recommends): this damps the high modes of a point source, which Crank-Nicolson alone
would carry up the silo as a slowly decaying odd-even oscillation. The fixed number of
first-order steps keeps the global error ``O(h**2)``. Each tridiagonal system is solved by
the Thomas algorithm (column diagonally dominant, no pivoting needed) in a numba kernel
that handles a batch of lines.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from numba import njit


@njit(cache=True)
def _solve_lines(b, rhs, c, out):
    """Solve ``(I - c L B) x = rhs`` on each row of ``rhs`` (reflecting ends); ``c = dz/h**2``."""
    m, n = rhs.shape
    cp = np.empty(n)
    dp = np.empty(n)
    for line in range(m):
        if n == 1:
            out[line, 0] = rhs[line, 0]
            continue
        diag = 1.0 + c * b[line, 0]
        up = -c * b[line, 1]
        cp[0] = up / diag
        dp[0] = rhs[line, 0] / diag
        for i in range(1, n):
            lo = -c * b[line, i - 1]
            if i < n - 1:
                diag = 1.0 + 2.0 * c * b[line, i]
                up = -c * b[line, i + 1]
            else:
                diag = 1.0 + c * b[line, i]
                up = 0.0
            den = diag - lo * cp[i - 1]
            cp[i] = up / den
            dp[i] = (rhs[line, i] - lo * dp[i - 1]) / den
        out[line, n - 1] = dp[n - 1]
        for i in range(n - 2, -1, -1):
            out[line, i] = dp[i] - cp[i] * out[line, i + 1]


@njit(cache=True)
def _apply_lines(b, x, c, out):
    """``out = (I + c L B) x`` on each row (reflecting ends)."""
    m, n = x.shape
    for line in range(m):
        for i in range(n):
            psi = b[line, i] * x[line, i]
            lap = 0.0
            if i > 0:
                lap += b[line, i - 1] * x[line, i - 1] - psi
            if i < n - 1:
                lap += b[line, i + 1] * x[line, i + 1] - psi
            out[line, i] = x[line, i] + c * lap


def _solve(b, rhs, c):
    out = np.empty_like(rhs)
    _solve_lines(b, rhs, c, out)
    return out


def _apply(b, x, c):
    out = np.empty_like(x)
    _apply_lines(b, x, c, out)
    return out


def march(phi_floor: np.ndarray, b: np.ndarray, h: float,
          progress: Callable[[float], None] | None = None) -> np.ndarray:
    """March ``d phi/dz = lap_perp(b phi)`` up the grid from the floor values.

    Args:
        phi_floor: ``Q0 s`` on the floor cells, shape ``(nx,)`` or ``(ny, nx)``.
        b: diffusion length at the cell centres, grid shape ``(nz, [ny,] nx)``, in d.
        h: grid spacing in d (the height step).
        progress: called with the fraction done.

    Returns:
        ``phi`` at the cell centres, grid shape.
    """
    b = np.ascontiguousarray(b, dtype=float)
    nz = b.shape[0]
    three_d = b.ndim == 3
    out = np.empty(b.shape)
    c_half = 0.5 * h / h**2
    c_start = 0.25 * h / h**2
    every = max(1, nz // 100)
    if not three_d:
        phi = np.ascontiguousarray(phi_floor, dtype=float).reshape(1, -1)
        b0 = b[0].reshape(1, -1)
        for _ in range(2):
            phi = _solve(b0, phi, c_start)
        out[0] = phi[0]
        for k in range(nz - 1):
            if k == 0:      # Rannacher: the first step as two backward-Euler half steps
                phi = _solve((0.5 * (b[0] + b[1])).reshape(1, -1), phi, c_half)
                phi = _solve(b[1].reshape(1, -1), phi, c_half)
            else:
                rhs = _apply(b[k].reshape(1, -1), phi, c_half)
                phi = _solve(b[k + 1].reshape(1, -1), rhs, c_half)
            out[k + 1] = phi[0]
            if progress is not None and k % every == 0:
                progress((k + 1) / nz)
    else:
        phi = np.ascontiguousarray(phi_floor, dtype=float)
        def lod_euler(bb, x, c):
            x = _solve(bb, x, c)                                          # x lines
            bT = np.ascontiguousarray(bb.T)
            return np.ascontiguousarray(_solve(bT, np.ascontiguousarray(x.T), c).T)

        for _ in range(2):
            phi = lod_euler(b[0], phi, c_start)
        out[0] = phi
        for k in range(nz - 1):
            bm = 0.5 * (b[k] + b[k + 1])
            if k == 0:      # Rannacher: the first step as two backward-Euler half steps
                phi = lod_euler(np.ascontiguousarray(bm), phi, c_half)
                phi = lod_euler(b[1], phi, c_half)
                out[1] = phi
                continue
            bmT = np.ascontiguousarray(bm.T)
            r1 = _apply(bmT, np.ascontiguousarray(phi.T), c_half).T      # (I + c Ly B) phi
            star = _solve(bm, np.ascontiguousarray(r1), c_half)          # x lines
            r2 = _apply(bm, star, c_half)                                # (I + c Lx B) phi*
            phi = np.ascontiguousarray(_solve(bmT, np.ascontiguousarray(r2.T), c_half).T)
            out[k + 1] = phi
            if progress is not None and k % every == 0:
                progress((k + 1) / nz)
    if progress is not None:
        progress(1.0)
    return out
