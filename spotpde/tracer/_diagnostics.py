"""Diagnostics of the tracer solver (private; re-exported by :mod:`spotpde.tracer`).

* :func:`numerical_diffusion`: the scheme's numerical diffusivity (d**2 per unit time)
  along a uniform flow, ``D_num = (var(t_end) - var(0)) / (2 t_end) - D``;
* :func:`sde_ensemble`: the grid-free reference, Euler-Maruyama particles of
  ``dX = u_p(X) dt + sqrt(2 D_p(X)) dW`` (Ito form), whose density obeys the same
  Fokker-Planck equation as :func:`spotpde.tracer.solve`'s ``P``.
"""

from __future__ import annotations

import math

import numpy as np

from ._operator import _check_fields
from ._solve import Fields, solve
from ..grid import Grid


# ---------------------------------------------------------------------------------------
# diagnostics


def numerical_diffusion(speed: float, D: float, spacing: float, *, sigma: float = 1.0,
                        t_end: float | None = None, **options) -> dict:
    """Measure the scheme's effective numerical diffusion along the flow.

    Runs :func:`solve` on a uniform downward flow ``u_z = -speed`` with isotropic
    physical diffusivity ``D`` (a quasi-1D grid of 4 columns, reflecting walls, the
    whole floor an orifice) from a Gaussian layer of standard deviation ``sigma`` in z,
    and returns the apparent diffusivity from the growth of the z variance,
    ``D_eff = (var(t_end) - var(0)) / (2 t_end)``, and ``D_num = D_eff - D``.

    Args:
        speed: flow speed ``|u_p|`` in d per unit time (> 0).
        D: physical diffusivity along the flow in d**2 per unit time (>= 0).
        spacing: grid spacing ``h`` in d.
        sigma: initial width in d (the limiter's clipping, hence ``D_num``, grows as the
            profile sharpens: use the smallest width your pictures resolve).
        t_end: duration; default: the time to travel ``40 sigma``.
        **options: passed to :func:`solve` (``limiter``, ``time_scheme``, ``cfl``).

    Returns:
        dict with ``D_eff``, ``D_num``, ``D_phys``, ``ratio = D_num / D_phys`` (inf if
        ``D = 0``), ``cell_peclet = speed h / D``, ``travel`` (d), ``drift_error``
        (relative error of the mean displacement).
    """
    if not (speed > 0 and D >= 0 and spacing > 0 and sigma > 0):
        raise ValueError(f"speed, D, spacing, sigma: need speed > 0, D >= 0, spacing > 0, sigma > 0; "
                        f"got speed={speed!r}, D={D!r}, spacing={spacing!r}, sigma={sigma!r}")
    if t_end is None:
        t_end = 40.0 * sigma / speed
    travel = speed * t_end
    spread = 8.0 * math.sqrt(sigma**2 + 2 * D * t_end) + 4 * spacing
    z0 = travel + spread
    top = z0 + spread
    n = math.ceil(top / spacing)
    grid = Grid(2, (0.0, 4 * spacing), (0.0, n * spacing), spacing)
    Z, X = grid.mesh()
    P0 = np.exp(-0.5 * ((Z - z0) / sigma) ** 2) * np.ones(grid.shape)
    P0 /= P0.sum() * grid.cell_volume
    fields = {"u_x": 0.0, "u_z": -float(speed), "D_xx": float(D), "D_xz": 0.0,
              "D_zz": float(D)}
    res = solve(grid, fields, P0, t_end, 2, **options)
    z = grid.z

    def moments(P):
        pz = P.sum(axis=1)
        m = pz.sum()
        mean = (pz * z).sum() / m
        return mean, (pz * (z - mean) ** 2).sum() / m

    m0, v0 = moments(res.P[0])
    m1, v1 = moments(res.P[-1])
    D_eff = (v1 - v0) / (2 * t_end)
    return {"D_eff": D_eff, "D_num": D_eff - D, "D_phys": float(D),
            "ratio": (D_eff - D) / D if D > 0 else math.inf,
            "cell_peclet": speed * spacing / D if D > 0 else math.inf,
            "travel": travel, "drift_error": abs((m0 - m1) - travel) / travel}


# ---------------------------------------------------------------------------------------
# grid-free reference: Euler-Maruyama


def _interp_factory(grid: Grid):
    """Multilinear interpolation on the cell centres, clamped at the outer centres."""
    coords = [grid.coords()[a] for a in grid.axes]
    h = grid.spacing

    def interp(arrays, pos):
        # pos: (n, dims) in array order
        idx, wts = [], []
        for d, c in enumerate(coords):
            s = np.clip((pos[:, d] - c[0]) / h, 0.0, len(c) - 1.0)
            i0 = np.minimum(np.floor(s).astype(np.int64), len(c) - 2) if len(c) > 1 else \
                np.zeros(len(s), dtype=np.int64)
            idx.append(i0)
            wts.append(s - i0 if len(c) > 1 else np.zeros(len(s)))
        out = [np.zeros(len(pos)) for _ in arrays]
        for corner in range(2 ** grid.dims):
            bits = [(corner >> d) & 1 for d in range(grid.dims)]
            w = np.ones(len(pos))
            ii = []
            for d, bit in enumerate(bits):
                w = w * (wts[d] if bit else 1.0 - wts[d])
                ii.append(np.minimum(idx[d] + bit, len(coords[d]) - 1))
            ii = tuple(ii)
            for o, a in zip(out, arrays):
                o += w * a[ii]
        return out

    return interp


def sde_ensemble(grid: Grid, fields: Fields, starts, t_end: float, n: int, dt: float,
                 seed: int | None = None) -> np.ndarray:
    """Grid-free reference solution: Euler-Maruyama particles of the same equation.

    Integrates ``dX = u_p(X) dt + sqrt(2 D_p(X)) dW`` (Ito form, so the drift is exactly
    ``u_p`` and the density obeys the tracer equation) with the fields interpolated
    multilinearly between cell centres (constant beyond the outer centres). Boundaries
    mirror those of :func:`solve`: side walls reflect (``"open"`` walls absorb), the top
    reflects, and a particle crossing the floor ``z = z0`` is absorbed where the
    interpolated ``u_z`` there is negative (the orifice) and reflected elsewhere.

    Args:
        grid: the grid the fields live on.
        fields: the same dict (or callable ``t -> dict``) as for :func:`solve`.
        starts: start positions, shape ``(dims,)`` (all particles) or ``(m, dims)``
            (particle ``p`` starts at ``starts[p % m]``), columns in array order
            ``(z, x)`` / ``(z, y, x)``, in d.
        t_end: duration.
        n: number of particles.
        dt: time step (the weak error is first order in ``dt``).
        seed: seed of ``numpy.random.default_rng``.

    Returns:
        ``(n, dims)`` final positions in array order; rows of absorbed particles are NaN.

    Raises:
        ValueError: ``grid`` is axisymmetric or has a hopper (box grids only).
    """
    grid.geometry.require("sde ensemble", "grid")
    dims = grid.dims
    starts = np.atleast_2d(np.asarray(starts, dtype=float))
    if starts.shape[1] != dims:
        raise ValueError(f"starts: need {dims} columns (array order "
                        f"{grid.axes}), got shape {starts.shape}")
    if not (n >= 1 and dt > 0 and t_end >= 0):
        raise ValueError(f"n, dt, t_end: need n >= 1, dt > 0, t_end >= 0; got n={n!r}, "
                        f"dt={dt!r}, t_end={t_end!r}")
    rng = np.random.default_rng(seed)
    pos = starts[np.arange(n) % len(starts)].copy()
    alive = np.ones(n, dtype=bool)
    interp = _interp_factory(grid)
    axes = grid.axes
    ranges = {"z": grid.z_range, "y": grid.y_range, "x": grid.x_range}
    lo = [ranges[a][0] for a in grid.axes]
    hi = [ranges[a][1] for a in grid.axes]
    steady = not callable(fields)
    f = _check_fields(grid, fields if steady else fields(0.0), "fields")
    nsteps = max(1, int(math.ceil(t_end / dt - 1e-9)))
    dt = t_end / nsteps
    ucomp = [f"u_{a}" for a in axes]
    dcomp = [["D_" + "".join(sorted((a, b), key="xyz".index)) for b in axes] for a in axes]
    for step in range(nsteps):
        if not steady:
            f = _check_fields(grid, fields(step * dt), "fields")
        idx = np.flatnonzero(alive)
        if idx.size == 0:
            break
        X = pos[idx]
        names = ucomp + [dcomp[i][j] for i in range(dims) for j in range(i, dims)]
        vals = interp([f[nm] for nm in names], X)
        u = np.stack(vals[:dims], axis=1)
        Dm = np.empty((len(idx), dims, dims))
        m = dims
        for i in range(dims):
            for j in range(i, dims):
                Dm[:, i, j] = Dm[:, j, i] = vals[m]
                m += 1
        S = _sqrt_psd(2.0 * Dm)
        dW = rng.standard_normal((len(idx), dims)) * math.sqrt(dt)
        X = X + u * dt + np.einsum("nij,nj->ni", S, dW)
        # floor: absorbed over the orifice (u_z < 0 at the floor), reflected elsewhere
        below = X[:, 0] < lo[0]
        if np.any(below):
            at_floor = X[below].copy()
            at_floor[:, 0] = grid.z[0]
            uz_floor = interp([f["u_z"]], at_floor)[0]
            absorb = np.zeros(len(idx), dtype=bool)
            absorb[np.flatnonzero(below)[uz_floor < 0]] = True
            X[below, 0] = 2 * lo[0] - X[below, 0]
        else:
            absorb = np.zeros(len(idx), dtype=bool)
        X[:, 0] = np.where(X[:, 0] > hi[0], 2 * hi[0] - X[:, 0], X[:, 0])
        for d in range(1, dims):
            out_lo, out_hi = X[:, d] < lo[d], X[:, d] > hi[d]
            if grid.walls == "open":
                absorb |= out_lo | out_hi
            X[:, d] = np.where(out_lo, 2 * lo[d] - X[:, d], X[:, d])
            X[:, d] = np.where(out_hi, 2 * hi[d] - X[:, d], X[:, d])
        pos[idx] = X
        alive[idx[absorb]] = False
    pos[~alive] = np.nan
    return pos


def _sqrt_psd(M: np.ndarray) -> np.ndarray:
    """A factor ``S`` with ``S S^T = M`` for a stack ``(n, d, d)`` of PSD matrices.

    Cholesky factorisation written out for d <= 3 and made safe for semi-definite
    matrices (a vanishing pivot gives a zero column), vectorised over the stack.
    """
    n, d, _ = M.shape
    Lf = np.zeros_like(M)
    for j in range(d):
        diag = M[:, j, j] - np.sum(Lf[:, j, :j] ** 2, axis=1)
        piv = np.sqrt(np.clip(diag, 0.0, None))
        Lf[:, j, j] = piv
        inv = np.divide(1.0, piv, out=np.zeros_like(piv), where=piv > 1e-300)
        for i in range(j + 1, d):
            Lf[:, i, j] = (M[:, i, j] - np.sum(Lf[:, i, :j] * Lf[:, j, :j], axis=1)) * inv
    return Lf
