"""Spot sources on the floor: the horizontal injection profile and the rate Q0(t).

Spots enter through the orifice, a part of the floor ``z = z0`` (docs/conventions.md section 1).
The injection flux density is ``Q0(t) * s(x)`` (spots per unit time per d**(dims-1)),
with ``s`` a density over the floor that integrates to 1.

Profiles (``spotpde.parameters.Orifice``):

* point (``width == 0``): regularised as *cloud in cell*: the unit mass goes to the
  two (2D) or four (3D) cell centres around the point with linear weights. This keeps
  the mass and the centroid exact; the second moment grows by ``f (1 - f) h**2`` per
  axis (``f`` the fractional offset), so any field a distance ``z >> h`` above the
  orifice differs from the point-source solution by ``O(h**2 / z)`` (docs/spot_density.md).
* ``"uniform"``: slot ``|x - xc| <= W/2`` (2D) or disk of diameter ``W`` (3D), density
  ``1/W`` (``4 / (pi W**2)``); cell values are exact cell averages (3D: edge cells
  supersampled 16 x 16).
* ``"gaussian"``: ``width = 2 sigma`` per horizontal axis; exact cell averages (erf).
* 3D ``shape = "slot"``: the 2D profile in x across the whole depth, uniform in y
  (density ``s_2D(x) / L_y``): a thin slab's slot orifice.
* ``width >= floor side`` (any profile; the longer side for a 3D disk): uniform flow
  over the whole floor.
* axisymmetric grids (the orifice on the axis, ``width`` its diameter): exact ring
  masses of the disk or the radial Gaussian; a point orifice fills the first ring
  ``r < h`` (:func:`_ring_profile`). Hoppers: the profile on the active floor cells.

Reflecting walls fold the profile by the method of images (a part of the orifice
beyond a wall is mirrored back inside), so the profile integrates to 1 and its cosine
coefficients are those of the free profile (used by the spectral solver). Open walls
clip the profile to the window and renormalise it (the solvers themselves work on a
padded window, where no clipping happens).
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
from scipy.special import erf, j1

from ..grid import Grid
from ..parameters import ORIFICE_SHAPES, PROFILES, Orifice

__all__ = [
    "source_profile",
    "rate_from_table",
    "check_orifice",
    "cosine_coefficients",
    "is_uniform_flow",
]


# -- validation and rates -------------------------------------------------------------
def check_orifice(grid: Grid, orifice: Orifice) -> None:
    """Raise :class:`ValueError` naming every invalid orifice key.

    Args:
        grid: the computational grid.
        orifice: the orifice parameters.
    """
    problems = []
    if orifice.profile not in PROFILES:
        problems.append(
            f"orifice.profile: must be one of {', '.join(map(repr, PROFILES))}, "
            f"got {orifice.profile!r}"
        )
    if not (np.isfinite(orifice.width) and orifice.width >= 0):
        problems.append(f"orifice.width: must be a finite number >= 0, got {orifice.width!r}")
    x0, x1 = grid.x_range
    if grid.geometry.has_axis and orifice.x != 0.0:
        problems.append(f"orifice.x: an axisymmetric orifice is centred on the axis (x = 0), "
                        f"got {orifice.x!r}")
    elif not (x0 <= orifice.x <= x1):
        problems.append(f"orifice.x: must lie on the floor [{x0}, {x1}], got {orifice.x!r}")
    if orifice.shape not in ORIFICE_SHAPES:
        problems.append(f"orifice.shape: must be one of {', '.join(map(repr, ORIFICE_SHAPES))}, "
                        f"got {orifice.shape!r}")
    elif orifice.shape == "slot" and grid.dims != 3:
        problems.append("orifice.shape: \"slot\" is for 3D grids (a 2D orifice is a slot), "
                        f"got dims = {grid.dims}")
    if grid.dims == 3 and orifice.y is not None:
        y0, y1 = grid.y_range
        if not (y0 <= orifice.y <= y1):
            problems.append(f"orifice.y: must lie on the floor [{y0}, {y1}], got {orifice.y!r}")
    if not callable(orifice.rate):
        q = float(orifice.rate)
        if not (np.isfinite(q) and q >= 0):
            problems.append(f"orifice.rate: must be a finite number >= 0, got {orifice.rate!r}")
    if problems:
        raise ValueError("\n".join(problems))


def rate_from_table(times: Sequence[float], values: Sequence[float]) -> Callable[[float], float]:
    """Turn a table ``(times, values)`` of Q0 into a callable ``Q0(t)``.

    Linear interpolation between entries; before the first (after the last) time the
    first (last) value is held.

    Args:
        times: strictly increasing times (case time unit), at least one entry.
        values: Q0 at those times, spots per unit time, each >= 0.

    Returns:
        A function of ``t`` returning a float (or an array for an array ``t``).
    """
    t = np.asarray(times, dtype=float)
    q = np.asarray(values, dtype=float)
    if t.ndim != 1 or q.shape != t.shape or t.size == 0:
        raise ValueError(
            f"times, values: a rate table needs equal-length 1D times and values, got shapes "
            f"{t.shape} and {q.shape}"
        )
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q))):
        raise ValueError("times, values: table entries must be finite numbers")
    if np.any(np.diff(t) <= 0):
        raise ValueError("times: must be strictly increasing")
    if np.any(q < 0):
        raise ValueError(f"values: must be >= 0, got min {q.min()}")

    def rate(time):
        out = np.interp(time, t, q)
        return float(out) if np.ndim(out) == 0 else out

    return rate


def is_uniform_flow(grid: Grid, orifice: Orifice) -> bool:
    """True when the orifice spans the whole floor (width >= the floor's side: x for a
    slot, the longer of x and y for a 3D disk; the diameter ``2 a`` on an axisymmetric
    grid)."""
    if grid.geometry.has_axis:
        return orifice.width >= 2.0 * grid.x_range[1]
    side = grid.x_range[1] - grid.x_range[0]
    if grid.dims == 3 and orifice.shape != "slot":
        side = max(side, grid.y_range[1] - grid.y_range[0])
    return orifice.width >= side


def _centre(grid: Grid, orifice: Orifice) -> tuple[float, float]:
    yc = grid.y_centre if orifice.y is None else float(orifice.y)
    return float(orifice.x), yc


# -- cell weights on one axis ------------------------------------------------------------
def _fold(weights_ext: np.ndarray, pad: int, n: int, walls: str, axis: int) -> np.ndarray:
    """Map weights on extended cells ``-pad .. n+pad-1`` into ``0 .. n-1``.

    Reflecting walls mirror cell ``-1-j`` onto ``j`` (method of images, period ``2n``);
    open walls drop the outside cells.
    """
    j = np.arange(-pad, n + pad)
    if walls == "reflecting":
        r = np.mod(j, 2 * n)
        target = np.where(r < n, r, 2 * n - 1 - r)
    else:
        keep = (j >= 0) & (j < n)
        return np.compress(keep, weights_ext, axis=axis)
    w = np.moveaxis(weights_ext, axis, 0)
    out = np.zeros((n,) + w.shape[1:])
    np.add.at(out, target, w)
    return np.moveaxis(out, 0, axis)


def _axis_weights(lo: float, h: float, n: int, centre: float, width: float,
                  profile: str, walls: str) -> np.ndarray:
    """Cell masses (summing to 1 before clipping) of a 1D profile on ``n`` cells.

    Point: cloud in cell. Uniform: exact overlap of ``[c - W/2, c + W/2]`` with each
    cell divided by ``W``. Gaussian: ``Phi`` differences with ``sigma = width / 2``.
    """
    if width == 0.0:
        s = (centre - lo) / h - 0.5          # position in units of cell centres
        i0 = int(np.floor(s))
        f = s - i0
        pad = 2
        w = np.zeros(n + 2 * pad)
        w[i0 + pad] += 1.0 - f
        w[i0 + 1 + pad] += f
        return _fold(w, pad, n, walls, 0)
    half = 0.5 * width if profile == "uniform" else 4.0 * width   # 8 sigma support
    pad = int(np.ceil(max(0.0, max(lo - (centre - half), centre + half - (lo + n * h))) / h)) + 1
    edges = lo + h * np.arange(-pad, n + pad + 1)
    if profile == "uniform":
        cdf = np.clip((edges - (centre - 0.5 * width)) / width, 0.0, 1.0)
    else:
        sigma = 0.5 * width
        cdf = 0.5 * (1.0 + erf((edges - centre) / (np.sqrt(2.0) * sigma)))
    return _fold(np.diff(cdf), pad, n, walls, 0)


def _disk_weights(grid: Grid, xc: float, yc: float, diameter: float) -> np.ndarray:
    """Cell masses of a uniform disk on the ``(ny, nx)`` floor (folded or clipped)."""
    h, R = grid.spacing, 0.5 * diameter
    pads, centres = [], []
    for lo, n, c in ((grid.x_range[0], grid.nx, xc), (grid.y_range[0], grid.ny, yc)):
        pads.append(int(np.ceil(max(0.0, lo - (c - R), c + R - (lo + n * h)) / h)) + 1)
        centres.append(lo + h * (np.arange(-pads[-1], n + pads[-1]) + 0.5))
    X, Y = np.meshgrid(*centres, indexing="xy")           # array order (y, x)
    dx, dy = np.abs(X - xc), np.abs(Y - yc)
    near = np.hypot(np.maximum(dx - h / 2, 0), np.maximum(dy - h / 2, 0))
    far = np.hypot(dx + h / 2, dy + h / 2)
    frac = np.where(far <= R, 1.0, 0.0)
    edge = (near < R) & (far > R)
    ns = 16
    sub = (np.arange(ns) + 0.5) / ns - 0.5
    for a, b in zip(*np.nonzero(edge)):
        px = X[a, b] + h * sub[None, :]
        py = Y[a, b] + h * sub[:, None]
        frac[a, b] = np.mean((px - xc) ** 2 + (py - yc) ** 2 <= R * R)
    w = frac / frac.sum()
    w = _fold(w, pads[1], grid.ny, grid.walls, 0)
    return _fold(w, pads[0], grid.nx, grid.walls, 1)


# -- public profile --------------------------------------------------------------------
def source_profile(grid: Grid, orifice: Orifice) -> np.ndarray:
    """Horizontal density ``s`` of injected spots on the floor cells.

    Args:
        grid: the grid (its ``walls`` decide folding or clipping, see module doc).
        orifice: centre, width, profile.

    Returns:
        ``s`` in d**-(dims-1), shape ``(nx,)`` (2D) or ``(ny, nx)`` (3D, array order),
        with ``s.sum() * h**(dims-1) == 1`` to round-off. The injection flux density
        through floor cell ``i`` is ``Q0(t) * s[i]``. Axisymmetric grids: ``(nr,)``
        per unit area (d**-2), ``sum(s * grid.horizontal_measures) == 1``, exact ring
        masses (:func:`_ring_profile`). With a hopper, the profile is restricted to
        the active floor cells (``grid.active[0]``) and renormalised.
    """
    check_orifice(grid, orifice)
    geometry = grid.geometry
    profile = (_ring_profile if geometry.curved else _cartesian_profile)(grid, orifice)
    return profile if geometry.uniform_cells else _staircase(grid, profile)


def _cartesian_profile(grid: Grid, orifice: Orifice) -> np.ndarray:
    h, n, lo = grid.spacing, grid.nx, grid.x_range[0]
    measure = grid.horizontal_cell_measure
    floor = grid.shape[1:]
    if is_uniform_flow(grid, orifice):
        return np.full(floor, 1.0 / (np.prod(floor) * measure))
    xc, yc = _centre(grid, orifice)
    wx = None if grid.dims == 3 and orifice.profile == "uniform" and orifice.width > 0 \
        and orifice.shape == "disk" else \
        _axis_weights(lo, h, n, xc, orifice.width, orifice.profile, grid.walls)
    if grid.dims == 2:
        w = wx
    elif orifice.shape == "slot":
        w = np.broadcast_to(wx / grid.ny, floor)
    elif wx is None:
        w = _disk_weights(grid, xc, yc, orifice.width)
    else:
        wy = _axis_weights(grid.y_range[0], h, grid.ny, yc, orifice.width, orifice.profile,
                           grid.walls)
        w = wy[:, None] * wx[None, :]
    total = w.sum()
    if not total > 0:
        raise ValueError(
            f"orifice.x: the orifice at x={orifice.x} (width {orifice.width}) injects nothing "
            f"inside the floor {grid.x_range}"
        )
    return w / (total * measure)


def _ring_profile(grid: Grid, orifice: Orifice) -> np.ndarray:
    """Axisymmetric floor density per unit area on the rings ``[i h, (i + 1) h]``.

    Ring masses are exact: a uniform disk of radius ``R = W/2`` puts
    ``(min(r_+, R)**2 - min(r_-, R)**2) / R**2`` in ring ``[r_-, r_+]``; a Gaussian
    (``sigma = W/2`` per horizontal axis) ``exp(-r_-**2 / 2 sigma**2) - exp(-r_+**2 / 2 sigma**2)``;
    a point orifice puts its unit mass in the first ring, the disk ``r < h`` (the same
    second moment ``<r**2> = h**2/2`` as the Cartesian cloud in cell of a point at a cell
    corner). Mass beyond a reflecting wall ``r = a`` is mirrored back about it (ring
    ``a + t`` onto ``a - t``); open walls clip and renormalise.
    """
    h, n, a = grid.spacing, grid.nx, grid.x_range[1]
    measure = np.broadcast_to(np.asarray(grid.horizontal_measures, float), (n,))
    if is_uniform_flow(grid, orifice):
        return np.full(n, 1.0 / (np.pi * a * a))
    if orifice.width == 0.0:
        mass = np.zeros(n)
        mass[0] = 1.0
        return mass / measure
    R = 0.5 * orifice.width
    reach = R if orifice.profile == "uniform" else 8.0 * R       # 8 sigma support
    ext = max(n, int(np.ceil(reach / h)) + 1)
    edges = h * np.arange(ext + 1)
    if orifice.profile == "uniform":
        ring = np.diff(np.minimum(edges, R) ** 2 / R**2)
    else:                      # exp(-r-^2/2s^2) - exp(-r+^2/2s^2), accurate in the tail
        e0, e1 = edges[:-1] ** 2 / (2.0 * R * R), edges[1:] ** 2 / (2.0 * R * R)
        ring = -np.exp(-e0) * np.expm1(e0 - e1)
    mass = ring[:n].copy()
    if grid.walls == "reflecting" and ext > n:
        j = np.arange(n, ext)
        r = np.mod(j, 2 * n)
        np.add.at(mass, np.where(r < n, r, 2 * n - 1 - r), ring[n:])
    return mass / (mass.sum() * measure)


def _staircase(grid: Grid, s: np.ndarray) -> np.ndarray:
    """Restrict a floor profile to the hopper's active floor cells and renormalise."""
    s = s * np.asarray(grid.active)[0]
    total = float(np.sum(s * grid.horizontal_measures))
    if not total > 0:
        raise ValueError("orifice.width: the orifice injects nothing into the hopper's "
                         "floor cells (grid.active)")
    return s / total


# -- spectral coefficients (reflecting walls) ---------------------------------------------
def _axis_cosine(k: np.ndarray, X0: float, width: float, profile: str) -> np.ndarray:
    """``integral f(x) cos(k (x - xa)) dx`` of a unit-mass 1D profile centred at ``X0 = xc - xa``."""
    if width == 0.0:
        return np.cos(k * X0)
    if profile == "gaussian":
        sigma = 0.5 * width
        return np.cos(k * X0) * np.exp(-0.5 * (k * sigma) ** 2)
    half = 0.5 * width
    return np.cos(k * X0) * np.sinc(k * half / np.pi)      # sin(k W/2) / (k W/2)


def cosine_coefficients(grid: Grid, orifice: Orifice, n_modes: int | None = None) -> np.ndarray:
    """Cosine-series coefficients of the folded source between reflecting walls.

    With ``L`` the floor side, ``k_n = n pi / L`` and ``X = x - x0``, the folded unit-mass
    profile is ``s(x) = sum_n a_n cos(k_n X)`` (3D: ``sum a_nm cos(k_n X) cos(k_m Y)``),
    ``a_n = (c_n / L) integral f(x) cos(k_n X) dx`` with ``c_0 = 1``, ``c_n = 2`` and ``f``
    the free (unfolded) profile. Closed forms: point ``cos(k X_c)``; slot
    ``cos(k X_c) sinc(k W / 2)``; Gaussian ``cos(k X_c) exp(-k**2 sigma**2 / 2)``; 3D disk
    ``cos(k_n X_c) cos(k_m Y_c) 2 J1(kappa R) / (kappa R)``, ``kappa = |(k_n, k_m)|``.
    By default the ``nx`` modes a cell-centred grid resolves are returned (the rest
    decay as ``exp(-b (pi/h)**2 z)`` above the floor); ``n_modes`` asks for more.

    Args:
        grid: the grid (walls are assumed reflecting).
        orifice: the orifice.
        n_modes: number of modes per axis (default ``nx``, in 3D ``(ny, nx)``); in 3D
            an int gives that many along both axes, a pair ``(m_y, m_x)`` each.

    Returns:
        ``a`` of shape ``(m_x,)`` (2D) or ``(m_y, m_x)`` (3D, array order ``(y, x)``),
        in d**-(dims-1).
    """
    check_orifice(grid, orifice)
    grid.geometry.require("cosine series", "grid")
    if grid.dims == 2:
        my, mx = 1, (n_modes or grid.nx)
    elif n_modes is None:
        my, mx = grid.ny, grid.nx
    else:
        my, mx = (n_modes, n_modes) if np.ndim(n_modes) == 0 else n_modes
    Lx = grid.x_range[1] - grid.x_range[0]
    Ly = 1.0 if grid.dims == 2 else grid.y_range[1] - grid.y_range[0]

    def axis(m, L):      # wavenumbers and the series' normalisation c_n / L
        return np.pi * np.arange(m) / L, np.where(np.arange(m) == 0, 1.0, 2.0) / L

    (kx, cx), (ky, cy) = axis(mx, Lx), axis(my, Ly)
    if is_uniform_flow(grid, orifice):
        a = np.zeros((mx,) if grid.dims == 2 else (my, mx))
        a.flat[0] = 1.0 / (Lx * Ly)
        return a
    xc, yc = _centre(grid, orifice)
    X0 = xc - grid.x_range[0]
    if grid.dims == 2:
        return cx * _axis_cosine(kx, X0, orifice.width, orifice.profile)
    ax = cx * _axis_cosine(kx, X0, orifice.width, orifice.profile)
    if orifice.shape == "slot":          # uniform in y: mode 0 only
        ay = np.where(np.arange(my) == 0, 1.0 / Ly, 0.0)
        return ay[:, None] * ax[None, :]
    Y0 = yc - grid.y_range[0]
    if orifice.profile == "uniform" and orifice.width > 0:
        R = 0.5 * orifice.width
        kappa = np.hypot(ky[:, None], kx[None, :])
        with np.errstate(invalid="ignore", divide="ignore"):
            airy = np.where(kappa > 0, 2.0 * j1(kappa * R) / (kappa * R), 1.0)
        return (cy * np.cos(ky * Y0))[:, None] * (cx * np.cos(kx * X0))[None, :] * airy
    ay = cy * _axis_cosine(ky, Y0, orifice.width, orifice.profile)
    return ay[:, None] * ax[None, :]
