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
the orifice, up to 0.063 per unit flux at ``h = 1/4``, 30 degrees). The second-order backward
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
def _solve_row(b, w, m, s, rhs, out, cp, dp):
    """Thomas solve of ``(I - s L B) out = rhs`` on one row (``s = dz / h**2``).

    ``(L B x)_i = [w_{i+1} (b_{i+1} x_{i+1} - b_i x_i) - w_i (b_i x_i - b_{i-1} x_{i-1})] / m_i``,
    ``w`` the ``n + 1`` face weights (``w_0 = w_n = 0``).
    """
    n = rhs.size
    di = 1.0 + s * (w[0] + w[1]) * b[0] / m[0]
    up = -s * w[1] * b[1] / m[0] if n > 1 else 0.0
    cp[0] = up / di
    dp[0] = rhs[0] / di
    for i in range(1, n):
        lo = -s * w[i] * b[i - 1] / m[i]
        di = 1.0 + s * (w[i] + w[i + 1]) * b[i] / m[i]
        up = -s * w[i + 1] * b[i + 1] / m[i] if i < n - 1 else 0.0
        den = di - lo * cp[i - 1]
        cp[i] = up / den
        dp[i] = (rhs[i] - lo * dp[i - 1]) / den
    out[n - 1] = dp[n - 1]
    for i in range(n - 2, -1, -1):
        out[i] = dp[i] - cp[i] * out[i + 1]


@njit(cache=True)
def _march_rows(b, w, m, act, h, bdf2, euler_rows, k0, k1, phi, prev, out):
    """Rows ``k0 + 1 .. k1`` of the march; ``phi`` (row ``k0``) and ``prev`` (row
    ``k0 - 1``, BDF2) are updated in place."""
    n = phi.size
    c_half = 0.5 / h
    rhs = np.empty(n)
    tmp = np.empty(n)
    bm = np.empty(n)
    cp = np.empty(n)
    dp = np.empty(n)
    for k in range(k0, k1):
        if k == 0 or (not bdf2 and k < euler_rows):
            # Rannacher: two backward-Euler half steps (the first with the mean b)
            for i in range(n):
                bm[i] = 0.5 * (b[k, i] + b[k + 1, i])
                rhs[i] = phi[i] * (act[k + 1, i] if k > 0 else 1.0)
            _solve_row(bm, w[k + 1] if k > 0 else w[0], m, c_half, rhs, tmp, cp, dp)
            for i in range(n):
                rhs[i] = tmp[i] * act[k + 1, i]
            _solve_row(b[k + 1], w[k + 1], m, c_half, rhs, tmp, cp, dp)
        elif bdf2:
            for i in range(n):
                rhs[i] = (4.0 * phi[i] - prev[i]) / 3.0 * act[k + 1, i]
            _solve_row(b[k + 1], w[k + 1], m, 2.0 / (3.0 * h), rhs, tmp, cp, dp)
        else:       # Crank-Nicolson: rhs = (I + c L_k B_k) phi
            for i in range(n):
                psi = b[k, i] * phi[i]
                lap = 0.0
                if i < n - 1:
                    lap += w[k, i + 1] * (b[k, i + 1] * phi[i + 1] - psi)
                if i > 0:
                    lap -= w[k, i] * (psi - b[k, i - 1] * phi[i - 1])
                rhs[i] = (phi[i] + c_half * lap / m[i]) * act[k + 1, i]
            _solve_row(b[k + 1], w[k + 1], m, c_half, rhs, tmp, cp, dp)
        for i in range(n):
            prev[i] = phi[i]
            phi[i] = tmp[i]
            out[k + 1, i] = tmp[i]


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
        scheme: ``"cn"`` (Crank-Nicolson) or ``"bdf2"`` (hoppers), see the module doc.

    Returns:
        ``phi`` ``(nz, nx)``, 0 on inactive cells.
    """
    b = np.ascontiguousarray(b, dtype=float)
    w = np.ascontiguousarray(w, dtype=float)
    m = np.ascontiguousarray(m, dtype=float)
    nz, n = b.shape
    act = np.ascontiguousarray(active, dtype=float)
    out = np.zeros(b.shape)
    cp, dp, tmp = np.empty(n), np.empty(n), np.empty(n)
    phi = np.ascontiguousarray(phi_floor, dtype=float) * act[0]
    for _ in range(2):          # floor -> first cell centre: two backward-Euler steps of h/4
        _solve_row(b[0], w[0], m, 0.25 / h, phi, tmp, cp, dp)
        phi = tmp.copy()
    out[0] = phi
    prev = phi.copy()
    chunk = max(1, nz // 20)
    for k0 in range(0, nz - 1, chunk):
        k1 = min(nz - 1, k0 + chunk)
        _march_rows(b, w, m, act, h, scheme == "bdf2", EULER_ROWS, k0, k1, phi, prev, out)
        if progress is not None:
            progress(k1 / nz)
    if progress is not None:
        progress(1.0)
    return out
