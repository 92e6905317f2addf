"""The Kinematic Model of silo drainage (docs/conventions.md section 4; paper eqs. law, kin).

Downward speed ``v`` and horizontal velocity ``u_perp`` of the particles obey

    u_perp = b grad_perp v,        d v / dz = b lap_perp v,

the second being incompressibility ``div_perp u_perp - dv/dz = 0`` (the vertical
velocity is ``u_z = -v``). The sign follows the void-model flux balance of the paper
(eq. voidflux): ``rho_p (u, -v) = -v0 (-b grad_perp rho_v, rho_v)``, so ``u`` points
up the gradient of ``v``, toward the faster-flowing centre: particles converge on the
orifice as they fall. ``v`` obeys the same equation as the steady spot flux
``v_s rho_s`` with ``D_par = 0``, so :func:`speed` reuses :mod:`spotpde.spot_density`
(unit source rate, unit spot drift). Axisymmetric grids solve
``dv/dz = (b/r) d/dr (r dv/dr)`` with ``u_r = b dv/dr``; hoppers solve in the staircase
(docs/spot_density.md section 9). Closed forms: :func:`slot_profile` (2D, cosine series),
:func:`cylinder_profile` (a cylinder, Fourier-Bessel series; ``_bessel``).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit
from scipy.integrate import solve_ivp
from scipy.optimize import minimize_scalar
from scipy.special import erf

from ..grid import Grid
from ..parameters import Orifice, Spots
from . import _geometry, spot_density
from ._bessel import cylinder_profile

__all__ = ["point_source", "slot_profile", "cylinder_profile", "fit_profile",
           "fit_radial_profile", "speed", "velocity", "streamlines"]


def point_source(x, z, b, dims: int = 2):
    """Analytic downward speed below a point orifice (unit flux through every height).

    2D: ``v = exp(-x**2 / (4 b z)) / sqrt(4 pi b z)``; 3D: ``v = exp(-r**2 / (4 b z)) /
    (4 pi b z)`` with ``r`` the horizontal distance from the orifice (pass ``x = r``).
    Each integrates to 1 over a horizontal line (plane) for every ``z > 0``.
    At ``z < 0`` (below the floor) ``v = 0``; at ``z = 0``, the limit: 0 off the
    orifice and ``inf`` at ``x = 0``.

    Args:
        x: horizontal offset (3D: horizontal distance ``r``) in d; array or float.
        z: height above the orifice in d; broadcast with ``x``.
        b: kinematic diffusion length in d (> 0).
        dims: 2 or 3.

    Returns:
        ``v`` in 1/d**(dims-1) (times the flow rate for a speed), broadcast shape
        (a float for scalar input).

    Raises:
        ValueError: naming the argument (``x``, ``z``, ``b``, ``dims``) that is not a
            number, not finite (``x``, ``b``), out of range or of a shape that does not
            broadcast.
    """
    if isinstance(dims, bool) or dims not in (2, 3):
        raise ValueError(f"dims: must be 2 or 3, got {dims!r}")
    x, z, b = (_real(name, value) for name, value in (("x", x), ("z", z), ("b", b)))
    if not np.all(np.isfinite(x)):
        raise ValueError("x: must be finite")
    if not np.all((b > 0) & np.isfinite(b)):
        raise ValueError("b: must be > 0 and finite")
    if np.isnan(z).any():
        raise ValueError("z: must not be NaN")
    try:
        x, z = np.broadcast_arrays(x, z)
        if np.ndim(b):
            np.broadcast_to(b, x.shape)
    except ValueError:
        raise ValueError(f"x, z, b: shapes {np.shape(x)}, {np.shape(z)} and {np.shape(b)} "
                         "do not broadcast together") from None
    b = float(b) if np.ndim(b) == 0 else b
    out = np.zeros(x.shape)
    pos = z > 0
    zz = z[pos]
    four_bz = 4.0 * b * zz if np.ndim(b) == 0 else 4.0 * np.broadcast_to(b, x.shape)[pos] * zz
    g = np.exp(-x[pos] ** 2 / four_bz)
    out[pos] = g / np.sqrt(np.pi * four_bz) if dims == 2 else g / (np.pi * four_bz)
    out[(z == 0) & (x == 0)] = np.inf
    return float(out) if out.ndim == 0 else out


def _real(name: str, value) -> np.ndarray:
    """``value`` as a float array, or a ValueError naming ``name``."""
    try:
        out = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: must be a number or an array of numbers, "
                         f"got {value!r:.60}") from None
    if isinstance(value, (bool, np.bool_)) or np.asarray(value).dtype == bool:
        raise ValueError(f"{name}: must be a number or an array of numbers, got {value!r}")
    return out


def slot_profile(x, s, orifice: Orifice, x_range: tuple[float, float] | None = None,
                 walls: str = "reflecting"):
    """Closed-form downward speed of the 2D Kinematic Model with the orifice's profile.

    With constant ``b`` the solution depends on height only through ``s = b z`` (d**2):
    ``v(x, s)`` solves ``dv/ds = d2v/dx2`` from the orifice profile ``p(x)`` (unit
    integral). Between reflecting walls ``x_range = (x0, x1)``, ``L = x1 - x0``, it is the
    cosine series (exact; terms kept while ``exp(-k_n^2 s) > 1e-13``)::

        v = 1/L + (2/L) sum_n p^_n cos(k_n (x - x0)) exp(-k_n^2 s),   k_n = n pi / L

    with ``p^_n = int p(x') cos(k_n (x' - x0)) dx'`` (a uniform slot
    ``[a, c]``: ``(sin k_n (c - x0) - sin k_n (a - x0)) / (k_n (c - a))``; a point:
    ``cos k_n (x_c - x0)``; a Gaussian of standard deviation ``W/2``: its free-space
    transform ``cos k_n (x_c - x0) exp(-k_n^2 W^2 / 8)``, exact while it stays inside the
    walls). Open walls (or ``x_range = None``): the free-space convolution of ``p`` with
    the heat kernel of variance ``2 s`` (erf differences for a slot).

    Args:
        x: horizontal positions in d (array).
        s: ``b z`` in d**2, > 0 (float, or an array broadcasting with ``x``).
        orifice: the orifice (``x``, ``width``, ``profile``; the rate is ignored).
        x_range: the silo's side walls in d.
        walls: ``"reflecting"`` or ``"open"``.

    Returns:
        ``v`` in 1/d (unit flux through every height), the broadcast shape of ``x`` and ``s``.
    """
    x = np.asarray(x, dtype=float)
    s = np.asarray(s, dtype=float)
    if not np.all(s > 0):
        raise ValueError(f"s: must be > 0 (b z in d**2), got {s.min() if s.size else s!r}")
    if walls not in ("reflecting", "open"):
        raise ValueError(f'walls: must be "reflecting" or "open", got {walls!r}')
    xc, width = float(orifice.x), float(orifice.width)
    slot = width > 0 and orifice.profile == "uniform"
    sig2 = (0.5 * width) ** 2 if (width > 0 and not slot) else 0.0
    open_ = walls == "open" or x_range is None
    if not open_:
        # The cosine series equals the free-space solution plus its images in the walls;
        # the nearest image is exp(-D**2 / (2 var)) of the peak, D the distance from the
        # orifice's support to the nearer wall. Below e**-40 (4e-18) it is below round-off
        # and the free-space form is used: exact to round-off, and it needs no series of
        # thousands of terms when s is small.
        half = 0.5 * width if slot else 0.0
        gap = min(xc - half - float(x_range[0]), float(x_range[1]) - xc - half)
        var_max = 2.0 * float(np.max(s)) + sig2
        open_ = gap > 0 and gap * gap > 80.0 * var_max
    if open_:
        var = 2.0 * s + sig2
        if slot:
            a, c = xc - 0.5 * width, xc + 0.5 * width
            root = np.sqrt(2.0 * var)
            return 0.5 * (erf((x - a) / root) - erf((x - c) / root)) / width
        return np.exp(-(x - xc) ** 2 / (2.0 * var)) / np.sqrt(2.0 * np.pi * var)
    x0, x1 = (float(v) for v in x_range)
    L = x1 - x0
    s_min = float(np.min(s)) + 0.5 * sig2
    n_max = int(np.ceil(L / np.pi * np.sqrt(30.0 / max(s_min, 1e-12)))) + 1
    k = np.arange(1, n_max + 1) * (np.pi / L)
    if slot:
        a, c = xc - 0.5 * width, xc + 0.5 * width
        coef = (np.sin(k * (c - x0)) - np.sin(k * (a - x0))) / (k * width)
    else:
        coef = np.cos(k * (xc - x0)) * np.exp(-0.5 * k**2 * sig2)
    xs, ss = np.broadcast_arrays(x, s)
    terms = coef * np.cos(np.multiply.outer(xs - x0, k)) * np.exp(-np.multiply.outer(ss, k**2))
    return 1.0 / L + (2.0 / L) * terms.sum(axis=-1)


def fit_profile(x, v, orifice: Orifice, x_range: tuple[float, float] | None = None,
                walls: str = "reflecting", *, se=None, broadening: float = 0.0,
                s_range: tuple[float, float] = (1e-3, 1e6), model=None
                ) -> tuple[float, float]:
    """Fit a downward-speed profile by the Kinematic Model: ``v ~ A K(x; s + broadening)``.

    ``K`` is :func:`slot_profile` with the orifice's profile and the walls; the amplitude
    ``A`` (the flux through the height) is linear and solved exactly for each ``s``; ``s``
    (``b z`` for a constant ``b``, d**2) by a grid search on a log scale refined with
    Brent's bounded method. ``broadening`` (d**2) is added to ``s`` in the model, e.g.
    ``width**2 / 2`` for a profile coarse-grained with a Gaussian of that width.

    Args:
        x, v: positions (d) and speeds; NaN entries are ignored.
        orifice, x_range, walls: as :func:`slot_profile`.
        se: standard errors of ``v`` (weights ``1/se**2``), or None for equal weights.
        model: ``K(x, s, orifice, x_range, walls)``; default :func:`slot_profile`
            (:func:`cylinder_profile` for a cylinder's radial profile).

    Returns:
        ``(s, A)``; NaN if fewer than 4 finite points.
    """
    x, v = np.asarray(x, float), np.asarray(v, float)
    ok = np.isfinite(v) & (np.isfinite(se) if se is not None else True)
    if ok.sum() < 4:
        return math.nan, math.nan
    w = np.ones(ok.sum()) if se is None else 1.0 / np.maximum(np.asarray(se, float)[ok], 1e-300) ** 2
    xv, vv = x[ok], v[ok]

    def chi2(s):
        K = (model or slot_profile)(xv, s + broadening, orifice, x_range, walls)
        A = np.sum(w * vv * K) / np.sum(w * K * K)
        return float(np.sum(w * (vv - A * K) ** 2)), float(A)

    grid_s = np.geomspace(s_range[0], s_range[1], 80)
    j = int(np.argmin([chi2(s)[0] for s in grid_s]))
    lo, hi = grid_s[max(j - 1, 0)], grid_s[min(j + 1, grid_s.size - 1)]
    res = minimize_scalar(lambda ls: chi2(math.exp(ls))[0], bounds=(math.log(lo), math.log(hi)),
                          method="bounded", options={"xatol": 1e-7})
    s = math.exp(res.x)
    return s, chi2(s)[1]


def fit_radial_profile(r, v, orifice: Orifice, r_range: tuple[float, float] | None = None,
                       walls: str = "reflecting", **kwargs) -> tuple[float, float]:
    """:func:`fit_profile` of a cylinder's radial profile by :func:`cylinder_profile`
    (``r_range = (0, a)``; same keywords). Returns ``(s, A)``: ``b z`` in d**2, the flux."""
    return fit_profile(r, v, orifice, r_range, walls, model=cylinder_profile, **kwargs)


def speed(grid: Grid, orifice: Orifice, b, progress=None) -> np.ndarray:
    """Downward speed ``v`` for the case's orifice and walls, unit flux through every height.

    Solves ``dv/dz = b lap_perp v`` (Ito form ``lap_perp(b v)`` when ``b`` varies, the
    form the spot flux obeys) from ``v = s(x)`` on the floor (the orifice profile,
    integrating to 1): ``sum(v) h**(dims-1) = 1`` at every height between reflecting
    walls (axisymmetric: ``sum(v * grid.horizontal_measures) = 2 pi integral r v dr = 1``;
    a hopper's inactive cells carry 0). The pipeline multiplies by ``V1 Q0`` to obtain ``v_kin``.

    Args:
        grid: the grid.
        orifice: the orifice (its rate is ignored).
        b: diffusion length in d, float or grid-shaped array.
        progress: called with the fraction done.

    Returns:
        ``v`` in 1/d**(dims-1), grid shape: horizontal cell averages at the cell-centre
        heights (within ``O(h**2)`` of the point values, e.g. of :func:`point_source`).
    """
    unit = dataclasses.replace(orifice, rate=1.0)
    return spot_density.steady(grid, unit, Spots(drift=1.0, b=b, b_par=0.0), progress)


def velocity(grid: Grid, orifice: Orifice, b, progress=None) -> dict[str, np.ndarray]:
    """Kinematic velocity field: ``u_perp = b grad_perp v``, ``u_z = -v``.

    The horizontal gradient is taken by second-order central differences
    (``numpy.gradient``, one-sided second order at the walls). Axisymmetric grids:
    ``u_r = b dv/dr``, at the first cell ``(v_1 - v_0) / 2h`` (the even extension
    ``v(-r) = v(r)``, so ``u_r(0) = 0``). Hopper walls: in a cell next to a staircase
    wall the gradient is the mean of its two face gradients, the wall face's being 0
    (no flow through the wall); 0 on inactive cells.

    Args:
        grid, orifice, b: as :func:`speed`.

    Returns:
        dict ``u_x``, [``u_y``,] ``u_z`` (grid shape), for unit flow rate; ``u_r``,
        ``u_z`` on axisymmetric grids (:attr:`Grid.drift_keys`).
    """
    v = speed(grid, orifice, b, progress)
    h = grid.spacing
    bb = np.asarray(b, dtype=float)
    if not grid.geometry.uniform_cells:
        return {grid.drift_keys[0]: np.where(grid.active, bb * _horizontal_gradient(grid, v), 0.0),
                "u_z": -v}
    out = {"u_x": bb * np.gradient(v, h, axis=-1, edge_order=2)}
    if grid.dims == 3:
        out["u_y"] = bb * np.gradient(v, h, axis=1, edge_order=2)
    out["u_z"] = -v
    return out


def _horizontal_gradient(grid: Grid, v: np.ndarray) -> np.ndarray:
    """``dv/dx`` (``dv/dr``) on a metric / staircase grid, second order inside (see :func:`velocity`)."""
    h = grid.spacing
    grad = np.gradient(v, h, axis=-1, edge_order=2) if grid.nx >= 3 else np.zeros_like(v)
    _, fr, _, _ = _geometry.metric(grid)
    face = np.zeros(fr.shape)
    face[:, 1:-1] = np.diff(v, axis=-1) / h
    face *= fr > 0
    closed = np.zeros(fr.shape, bool)
    closed[:, 1:-1] = fr[:, 1:-1] == 0          # staircase walls inside the box
    if grid.geometry.has_axis:
        closed[:, 0] = True                      # the axis: v even in r
    near = closed[:, :-1] | closed[:, 1:]
    return np.where(near, 0.5 * (face[:, :-1] + face[:, 1:]), grad)


@njit(cache=True)
def _cell(lo, h, n, p):
    """Lower cell-centre index and fraction along one axis (linear extrapolation outside)."""
    s = (p - lo) / h
    i = min(max(int(np.floor(s)), 0), max(n - 2, 0))
    return i, (s - i if n > 1 else 0.0)


@njit(cache=True)
def _linear2(fields, lo, h, p, out):
    """Bilinear interpolation of every component of ``fields`` ``(ncomp, nz, nx)`` at ``p = (z, x)``."""
    k, fz = _cell(lo[0], h, fields.shape[1], p[0])
    i, fx = _cell(lo[1], h, fields.shape[2], p[1])
    k1 = min(k + 1, fields.shape[1] - 1)
    i1 = min(i + 1, fields.shape[2] - 1)
    for c in range(fields.shape[0]):
        f = fields[c]
        out[c] = ((1 - fz) * ((1 - fx) * f[k, i] + fx * f[k, i1])
                  + fz * ((1 - fx) * f[k1, i] + fx * f[k1, i1]))


@njit(cache=True)
def _linear3(fields, lo, h, p, out):
    """Trilinear interpolation of ``fields`` ``(ncomp, nz, ny, nx)`` at ``p = (z, y, x)``."""
    k, fz = _cell(lo[0], h, fields.shape[1], p[0])
    j, fy = _cell(lo[1], h, fields.shape[2], p[1])
    i, fx = _cell(lo[2], h, fields.shape[3], p[2])
    k1 = min(k + 1, fields.shape[1] - 1)
    j1 = min(j + 1, fields.shape[2] - 1)
    i1 = min(i + 1, fields.shape[3] - 1)
    for c in range(fields.shape[0]):
        f = fields[c]
        lo_z = ((1 - fy) * ((1 - fx) * f[k, j, i] + fx * f[k, j, i1])
                + fy * ((1 - fx) * f[k, j1, i] + fx * f[k, j1, i1]))
        hi_z = ((1 - fy) * ((1 - fx) * f[k1, j, i] + fx * f[k1, j, i1])
                + fy * ((1 - fx) * f[k1, j1, i] + fx * f[k1, j1, i1]))
        out[c] = (1 - fz) * lo_z + fz * hi_z


def streamlines(fields: dict[str, np.ndarray], grid: Grid, starts, max_length: float | None = None,
                rtol: float = 1e-6) -> list[np.ndarray]:
    """Trace particle paths of a velocity field from start points down to the floor.

    Integrates ``dX/ds = u(X) / |u(X)|`` (arc length ``s``, so slow stagnant regions
    cost nothing extra) with ``scipy.integrate.solve_ivp`` (RK45) on the (bi/tri)linearly
    interpolated field (a numba kernel), until the path reaches the first cell-centre level
    ``z0 + h/2`` (then one straight segment to the floor ``z0`` along the last
    direction), leaves the domain, or the length exceeds ``max_length``.

    Args:
        fields: dict with ``u_x``, [``u_y``,] ``u_z`` (grid shape), e.g. from :func:`velocity`
            (axisymmetric grids: ``u_r``, ``u_z``).
        grid: the grid the fields live on (with a hopper, a path ends half a cell
            beyond the hopper wall).
        starts: start points, shape ``(m, dims)``, columns ``(x, [y,] z)`` in d
            (axisymmetric: ``(r, z)``; a path that reaches the axis ends there).
        max_length: longest path in d (default: 4 x (height + width)).
        rtol: relative tolerance of the integrator.

    Returns:
        One ``(n, dims)`` array per start, columns ``(x, [y,] z)`` in d.
    """
    starts = np.atleast_2d(np.asarray(starts, dtype=float))
    dims = grid.dims
    if starts.shape[1] != dims:
        raise ValueError(f"starts: must have {dims} columns (x, [y,] z), got shape {starts.shape}")
    names = list(grid.drift_keys)
    missing = [n for n in names if n not in fields]
    if missing:
        raise ValueError(f"fields: lack {missing}; need {names}")
    stack = np.stack([np.asarray(fields[n], dtype=float) for n in names])
    if stack.shape[1:] != grid.shape:
        raise ValueError(f"fields: must have the grid shape {grid.shape}, got {stack.shape[1:]}")
    lo = np.array([grid.z[0]] + ([grid.y[0]] if dims == 3 else []) + [grid.x[0]])
    u = np.empty(dims)
    interp = _linear2 if dims == 2 else _linear3
    z0, z1 = grid.z_range
    x0, x1 = grid.x_range
    # horizontal bounds in the column order (x, [y])
    low = np.array([x0] + ([grid.y_range[0]] if dims == 3 else []))
    high = np.array([x1] + ([grid.y_range[1]] if dims == 3 else []))
    h = grid.spacing
    floor_level = z0 + 0.5 * h
    if max_length is None:
        max_length = 4.0 * ((z1 - z0) + (x1 - x0))

    def rhs(_s, X):
        p = np.ascontiguousarray(X[::-1])             # (x, [y,] z) -> array order (z, [y,] x)
        interp(stack, lo, h, p, u)
        norm = np.linalg.norm(u)
        return u / norm if norm > 0 else np.zeros(dims)

    def reach_floor(_s, X):
        return X[-1] - floor_level
    reach_floor.terminal = True
    reach_floor.direction = -1

    clearance = grid.geometry.clearance

    def leave(_s, X):
        inside = min((X[:-1] - low).min(), (high - X[:-1]).min(), z1 - X[-1])
        # beyond a hopper's staircase: half a cell outside its wall (inf without one)
        inside = min(inside, clearance(X[0], X[-1], 0.5 * h))
        return inside + 1e-9
    leave.terminal = True
    leave.direction = -1

    paths = []
    for X0 in starts:
        sol = solve_ivp(rhs, (0.0, max_length), X0, events=(reach_floor, leave), rtol=rtol,
                        atol=1e-8, max_step=h, dense_output=False)
        path = sol.y.T
        if sol.status == 1 and len(sol.t_events[0]) and path[-1, -1] > z0:
            d = rhs(0.0, path[-1])
            if d[-1] < 0:
                step = (path[-1, -1] - z0) / -d[-1]
                path = np.vstack([path, path[-1] + step * d])
        paths.append(path)
    return paths
