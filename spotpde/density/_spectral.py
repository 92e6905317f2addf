"""Exact-in-height steady spot flux for constant ``b`` between reflecting walls.

Solves ``d phi / dz = b lap_perp phi`` (``phi = v_s rho_s``, the upward spot flux
density, docs/conventions.md section 1 with ``D_par = 0``) for ``z > z0`` with no flux through the
side walls and ``phi(x, z0) = Q0 s(x)``. Each cosine mode of the floor profile decays
independently:

    phi(x, z) = Q0 sum_n a_n exp(-b k_n**2 (z - z0)) cos(k_n (x - xa)),   k_n = n pi / L

(3D: a product of cosines and ``k**2 = k_n**2 + k_m**2``). The coefficients ``a_n`` are
the exact ones of the free profile (:func:`spotpde.orifice.cosine_coefficients`).

The returned values are the exact **cell averages** over each cell's horizontal extent
at the cell-centre height ``z_k`` (the quantity the finite-volume solvers and the
floor profile also carry): the average of ``cos(k x)`` over a cell is
``sinc(k h / 2) cos(k x_i)``. They are evaluated by a DCT-III
(``scipy.fft.dct(type=3)``: ``y_i = c_0 + 2 sum_{n>0} c_n cos(pi n (2i+1) / 2N)``, so
``c_0 = a_0`` and ``c_n = a_n sinc(k_n h/2) / 2``). The midpoint sum over the cells of
every mode ``0 < n < N`` vanishes exactly, so ``sum(phi) h**(dims-1) = Q0 a_0 L**(dims-1)
= Q0`` to round-off at every height, however narrow the plume.

Modes beyond the grid's (``p >= N``) are not dropped where they matter: at the cell
centres mode ``p = 2Nq +- n`` equals ``(-1)**q`` times mode ``n``, and modes
``p = N(2q+1)`` vanish; modes ``p = 2Nq`` (``q > 0``) have zero cell average
(``sinc(q pi) = 0``) and so never touch the flux. Rows where
``exp(-b (pi/h)**2 (z - z0)) > e**-40`` (a point source's first rows) carry ``M N``
modes per axis (``M <= 8``, enough for ``exp(-b (M N pi / L)**2 z) < e**-40``) folded onto
the ``N`` grid modes; every row is then the exact image-sum solution's cell average.
"""

from __future__ import annotations

import os

import numpy as np
import scipy.fft

from ..grid import Grid
from .orifice import cosine_coefficients
from ..parameters import Orifice

WORKERS = os.cpu_count() or 1
ALIAS_EXPONENT = 40.0
MAX_ALIAS_BLOCKS = 8


def decay_rate(k2, b: float, b_par: float):
    """``-lambda_-(k)``: the rate at which cosine mode ``k`` decays with height.

    ``D_par = 0``: ``b k**2``. ``D_par > 0``: the decaying root of
    ``b_par lambda**2 - lambda - b k**2 = 0``, written without cancellation as
    ``2 b k**2 / (1 + sqrt(1 + 4 b b_par k**2))``.
    """
    if b_par == 0:
        return b * k2
    return 2.0 * b * k2 / (1.0 + np.sqrt(1.0 + 4.0 * b * b_par * k2))


def mode_profile(k2, zeta, b: float, b_par: float, H: float):
    """Height profile ``G_k(z)`` of cosine mode ``k`` per unit injected flux: ``v_s rho_k = a_k G_k``.

    ``D_par = 0``: ``G = exp(-b k**2 z)``. ``D_par > 0``, with the mode ODE
    ``b_par G'' - G' - b k**2 G = 0`` (the steady equation divided by ``v_s``), the floor
    condition ``G - b_par G' = 1`` (injected flux; zero flux is ``a_k = 0``) and the
    Danckwerts top ``G'(H) = 0``:

        G = [exp(lm z) - (lm / lp) exp(lm H) exp(lp (z - H))] / den,
        den = (1 - b_par lm) - (lm / lp) exp((lm - lp) H) (1 - b_par lp),

    ``lm < 0 < lp`` the roots, every exponential ``<= 1`` (no overflow). Mode 0 gives
    ``G = 1``: the flux ``v_s integral(rho)`` is ``Q0`` at every height.
    """
    lm = -decay_rate(k2, b, b_par)
    if b_par == 0:
        return np.exp(lm * zeta)
    lp = (1.0 + np.sqrt(1.0 + 4.0 * b * b_par * k2)) / (2.0 * b_par)
    ratio = lm / lp
    den = (1.0 - b_par * lm) - ratio * np.exp((lm - lp) * H) * (1.0 - b_par * lp)
    return (np.exp(lm * zeta) - ratio * np.exp(lm * H) * np.exp(lp * (zeta - H))) / den


def steady_flux(grid: Grid, orifice: Orifice, b: float, Q0: float = 1.0,
                b_par: float = 0.0) -> np.ndarray:
    """``v_s rho_s`` for uniform ``v_s``, ``b``, ``b_par`` between reflecting walls.

    Args:
        grid: the grid; its walls are treated as reflecting.
        orifice: the source.
        b: horizontal diffusion length ``D_perp / v_s`` in d (> 0).
        Q0: spots per unit time.
        b_par: vertical diffusion length ``D_par / v_s`` in d (>= 0).

    Returns:
        ``v_s rho_s`` in spots per unit time per d**(dims-1), grid shape (horizontal cell
        averages at the cell-centre heights); divide by ``v_s`` for ``rho_s``.
    """
    n, L, h = grid.nx, grid.x_range[1] - grid.x_range[0], grid.spacing
    ny, Ly = (grid.ny, grid.y_range[1] - grid.y_range[0]) if grid.dims == 3 else (1, L)
    zeta = grid.z - grid.z_range[0]
    H = grid.z_range[1] - grid.z_range[0]
    # rows where modes beyond the grid's still matter, and how many blocks of n to keep
    alias_rows = int(np.sum(decay_rate((np.pi / h) ** 2, b, b_par) * zeta < ALIAS_EXPONENT))
    blocks = 1
    if alias_rows:
        R = ALIAS_EXPONENT / zeta[0]
        kmax = np.sqrt((b_par * R**2 + R) / b)
        blocks = int(min(MAX_ALIAS_BLOCKS, np.ceil(kmax * h / np.pi) + 1))
    # cell averages: the mean of cos(k x) over a cell is sinc(k h / 2) cos(k x_i)
    avg = np.sinc(np.arange(n * blocks) * h / (2.0 * L))
    k1 = (np.pi * np.arange(n * blocks) / L) ** 2
    half = np.where(np.arange(n) == 0, 1.0, 0.5)
    if grid.dims == 2:
        a_full = cosine_coefficients(grid, orifice, n * blocks) * Q0 * avg
        a, k2, sizes = a_full[:n], k1, (n,)
    else:
        a_full = cosine_coefficients(grid, orifice, (ny * blocks, n * blocks)) * Q0
        avg_y = np.sinc(np.arange(ny * blocks) * h / (2.0 * Ly))
        a_full *= avg_y[:, None] * avg[None, :]
        a = a_full[:ny, :n]
        k1y = (np.pi * np.arange(ny * blocks) / Ly) ** 2
        k2 = k1y[:, None] + k1[None, :]
        sizes = (ny, n)
        half_y = np.where(np.arange(ny) == 0, 1.0, 0.5)
    if grid.dims == 2:      # (profile * a) * half, block by block (no whole-grid passes)
        c = _live_modes(k1[:n], zeta, b, b_par, H, factors=(a, half))
    elif b_par == 0:            # separable: exp(-b (kx^2 + ky^2) z) = product
        decay_x = np.exp(-b * zeta[:, None] * k1[None, :n])
        decay_y = np.exp(-b * zeta[:, None] * k1y[None, :ny])
        c = a[None, :, :] * decay_y[:, :, None] * decay_x[:, None, :]
    else:
        c = a[None, :, :] * mode_profile(k2[None, :ny, :n], zeta[:, None, None], b, b_par, H)
    for k in range(alias_rows if blocks > 1 else 0):
        R = ALIAS_EXPONENT / zeta[k]                    # fewer blocks needed higher up
        q = int(min(blocks, np.ceil(np.sqrt((b_par * R**2 + R) / b) * h / np.pi) + 1))
        sl = tuple(slice(0, q * m) for m in sizes)
        full = a_full[sl] * mode_profile(k2[sl], zeta[k], b, b_par, H)
        c[k] = _fold_modes(full, sizes)
        if grid.dims == 2:
            c[k] *= half
    if grid.dims == 3:
        c *= half_y[:, None] * half[None, :]
    if grid.dims == 2:
        return scipy.fft.dct(c, type=3, axis=-1, workers=WORKERS, overwrite_x=True)
    return scipy.fft.dctn(c, type=3, axes=(1, 2), workers=WORKERS, overwrite_x=True)


#: ``exp(-UNDERFLOW_EXPONENT)`` is below the smallest double: a mode decayed that far is 0
UNDERFLOW_EXPONENT = 746.0


def _live_modes(k2: np.ndarray, zeta: np.ndarray, b: float, b_par: float, H: float,
                rows: int = 32, factors=()) -> np.ndarray:
    """``mode_profile(k2[None, :], zeta[:, None], ...)``, skipping modes that underflow.

    Mode ``k`` at height ``zeta`` is at most ``2 exp(-decay_rate(k) zeta)`` (both terms of
    :func:`mode_profile` are bounded by it), which is 0 in double precision once the
    exponent passes ``UNDERFLOW_EXPONENT``; higher up ever fewer modes survive (``k`` up to
    ``sqrt(746 / (b zeta))``), so blocks of ``rows`` rows evaluate only their first row's
    surviving modes. Equal to the full evaluation to within the smallest subnormal.
    ``factors``: per-mode arrays multiplied in turn into each block (the same products,
    bit for bit, as multiplying the whole result by each, without its passes).
    """
    rate = decay_rate(k2, b, b_par)
    out = np.zeros((zeta.size, k2.size))
    for start in range(0, zeta.size, rows):
        z = zeta[start:start + rows]
        live = int(np.count_nonzero(rate * z[0] < UNDERFLOW_EXPONENT))
        if live:
            block = mode_profile(k2[None, :live], z[:, None], b, b_par, H)
            for f in factors:
                block *= f[:live]
            out[start:start + rows, :live] = block
    return out


def _fold_modes(c: np.ndarray, sizes: tuple[int, ...]) -> np.ndarray:
    """Fold cosine coefficients of ``M n`` modes onto the ``n`` modes seen at cell centres
    (``n = sizes[axis]`` along each axis).

    Per axis: blocks of ``2n`` modes summed with signs ``(-1)**q`` give ``S_r``
    (``r = p mod 2n``); then ``out_j = S_j - S_{2n-j}`` for ``0 < j < n``, ``out_0 = S_0``
    (mode ``r = n`` vanishes at the centres).
    """
    for ax, n in enumerate(sizes):
        a = np.moveaxis(c, ax, 0)
        m = a.shape[0]
        blocks = -(-m // (2 * n))
        padded = np.zeros((blocks * 2 * n,) + a.shape[1:])
        padded[:m] = a
        padded = padded.reshape((blocks, 2 * n) + a.shape[1:])
        signs = (-1.0) ** np.arange(blocks)
        S = np.tensordot(signs, padded, axes=(0, 0))            # (2n, ...)
        out = S[:n].copy()
        out[1:] -= S[:n:-1]                                     # S[2n-1], ..., S[n+1]
        c = np.moveaxis(out, 0, ax)
    return c
