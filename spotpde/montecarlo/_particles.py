"""Particle sets for the discrete spot-model Monte Carlo (private; see ``montecarlo``).

Initial positions ``(N, 2)`` of ``(x, z)`` in particle diameters d: :func:`lattice`,
:func:`random_packing` (random sequential addition), :func:`blob` (a Gaussian tracer
blob), and :func:`layer_mask` (the layered silo's coloured bands).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ..grid import Grid
from ..parameters import in_bands
from ._relax import draw_diameters, relax_packing

__all__ = ["lattice", "random_packing", "dense_packing", "blob", "layer_mask"]


def _region(grid: Grid, region):
    if region is None:
        return grid.x_range[0], grid.x_range[1], grid.z_range[0], grid.z_range[1]
    return tuple(float(v) for v in region)


def lattice(grid: Grid, spacing: float = 1.0, kind: str = "triangular",
            region: Sequence[float] | None = None) -> np.ndarray:
    """Particles on a lattice filling the box (or ``region = (x0, x1, z0, z1)``).

    Args:
        grid: the silo (its box).
        spacing: nearest-neighbour distance in d.
        kind: ``"triangular"`` (rows ``spacing * sqrt(3)/2`` apart, alternate rows shifted
            by half a spacing) or ``"square"``.
        region: sub-box to fill.

    Returns:
        ``(N, 2)`` array of ``(x, z)`` in d.
    """
    if kind not in ("triangular", "square"):
        raise ValueError(f"lattice kind: must be one of 'triangular', 'square', got {kind!r}")
    x0, x1, z0, z1 = _region(grid, region)
    dz = spacing * (math.sqrt(3.0) / 2.0 if kind == "triangular" else 1.0)
    rows = np.arange(z0 + 0.5 * dz, z1, dz)
    pts = []
    for k, z in enumerate(rows):
        shift = 0.5 * spacing * (k % 2) if kind == "triangular" else 0.0
        xs = np.arange(x0 + 0.5 * spacing + shift, x1, spacing)
        pts.append(np.column_stack([xs, np.full_like(xs, z)]))
    return np.concatenate(pts) if pts else np.zeros((0, 2))


def random_packing(grid: Grid, phi: float = 0.5, seed: int = 0,
                   region: Sequence[float] | None = None, diameter: float = 1.0,
                   max_tries: int = 20000) -> np.ndarray:
    """Random sequential addition of non-overlapping disks of diameter ``diameter``.

    Disks are tried at uniformly random positions until the area fraction ``phi`` is
    reached (RSA jams near 0.547 in 2D: ask for less) or ``max_tries`` consecutive
    failures per disk occur.

    Returns:
        ``(N, 2)`` array of centres ``(x, z)`` in d.
    """
    x0, x1, z0, z1 = _region(grid, region)
    area = (x1 - x0) * (z1 - z0)
    n_target = int(phi * area / (math.pi * diameter**2 / 4.0))
    return _rsa(x0, x1, z0, z1, n_target, diameter, seed, max_tries)


def _rsa(x0, x1, z0, z1, n_target, d, seed, max_tries):
    rng = np.random.default_rng(seed)
    cell = d / math.sqrt(2.0)  # at most one centre per cell
    ncx = int(math.ceil((x1 - x0) / cell))
    ncz = int(math.ceil((z1 - z0) / cell))
    occ = -np.ones((ncz + 4, ncx + 4), np.int64)
    pts = np.empty((n_target, 2))
    n = 0
    fails = 0
    batch = 4096
    while n < n_target and fails < max_tries:
        cand = rng.random((batch, 2)) * [x1 - x0, z1 - z0] + [x0, z0]
        for x, z in cand:
            cx = int((x - x0) / cell) + 2
            cz = int((z - z0) / cell) + 2
            ok = occ[cz, cx] < 0
            if ok:
                block = occ[cz - 2:cz + 3, cx - 2:cx + 3]
                idx = block[block >= 0]
                if idx.size and np.any(np.sum((pts[idx] - (x, z)) ** 2, axis=1) < d * d):
                    ok = False
            if ok:
                occ[cz, cx] = n
                pts[n] = (x, z)
                n += 1
                fails = 0
                if n == n_target:
                    break
            else:
                fails += 1
                if fails >= max_tries:
                    break
    return pts[:n].copy()


def dense_packing(grid: Grid, phi: float | None = None, polydispersity: float = 0.1,
                  distribution: str = "uniform", seed: int = 0,
                  region: Sequence[float] | None = None, tolerance: float = 1e-3,
                  max_iterations: int | None = None):
    """A dense random packing of slightly polydisperse disks (2D) or spheres (3D grid,
    e.g. a thin slab), made by soft-core relaxation.

    Centres are drawn uniformly in the box (or ``region``) at the number that gives the
    area (volume) fraction ``phi`` with the drawn diameters, then relaxed by the soft-core
    sweeps of docs/packing.md (``alpha = 0.25``; side, front and back walls, floor and lid
    repel) until no overlap exceeds ``tolerance`` d. Below jamming (about 0.84 for 2D
    disks of 10 % spread; about 0.64 for spheres, less in a slab a few grains deep, whose
    walls loosen the packing) this ends with a disordered, overlap-free packing at exactly
    ``phi``; above it, overlaps remain (the returned largest overlap says so).

    Args:
        grid: the silo; ``dims`` 2 or 3.
        phi: area fraction (2D, default 0.8, in (0, 0.9)) or volume fraction (3D,
            default 0.55, in (0, 0.7); in a slab 4 d deep the sweeps reach 1e-3 d at
            0.55 after about 40000 sweeps, and stay jammed at 0.57).
        max_iterations: sweeps at most (default 20000 in 2D, 100000 in 3D).
        region: sub-box ``(x0, x1, z0, z1)`` (2D) or ``(x0, x1, z0, z1, y0, y1)`` (3D).

    Returns:
        (positions ``(N, 2)`` ``(x, z)`` or ``(N, 3)`` ``(x, z, y)`` in d (the depth
        last, as the 3D Monte Carlo takes them), diameters ``(N,)`` in d, largest
        remaining overlap).

    Raises:
        ValueError: ``phi`` out of range.
    """
    if grid.dims == 3:
        return _dense_packing3(grid, 0.55 if phi is None else phi, polydispersity,
                               distribution, seed, region, tolerance,
                               100000 if max_iterations is None else max_iterations)
    phi = 0.8 if phi is None else phi
    max_iterations = 20000 if max_iterations is None else max_iterations
    if not 0.0 < phi < 0.9:
        raise ValueError(f"phi: must be in (0, 0.9), got {phi}")
    x0, x1, z0, z1 = _region(grid, region)
    rng = np.random.default_rng(seed)
    mean_area = math.pi / 4.0 * (1.0 + polydispersity**2 / (3.0 if distribution == "uniform" else 1.0))
    n = int(round(phi * (x1 - x0) * (z1 - z0) / mean_area))
    d = draw_diameters(n, polydispersity, distribution, seed)
    # fix phi exactly with the drawn diameters
    d *= math.sqrt(phi * (x1 - x0) * (z1 - z0) / (math.pi / 4.0 * np.sum(d**2)))
    P = np.column_stack([rng.uniform(x0 + 0.5, x1 - 0.5, n), rng.uniform(z0 + 0.5, z1 - 0.5, n)])
    P, _, worst = relax_packing(P, d, (x0, x1, z0, z1), relax={"alpha": 0.25},
                                tolerance=tolerance, max_iterations=max_iterations)
    return P, d, worst


def _dense_packing3(grid, phi, polydispersity, distribution, seed, region, tolerance,
                    max_iterations):
    """:func:`dense_packing` of spheres in the 3D box (volume fraction ``phi``)."""
    if not 0.0 < phi < 0.7:
        raise ValueError(f"phi: must be in (0, 0.7) for spheres, got {phi}")
    if region is None:
        box = (*grid.x_range, *grid.z_range, *grid.y_range)
    else:
        box = tuple(float(v) for v in region)
        if len(box) != 6:
            raise ValueError(f"region: need (x0, x1, z0, z1, y0, y1) in 3D, got {region!r}")
    lo, hi = np.array(box[0::2]), np.array(box[1::2])
    volume = float(np.prod(hi - lo))
    rng = np.random.default_rng(seed)
    # E[d^3] = 1 + s^2 (uniform in [1 - s, 1 + s]), 1 + 3 s^2 (Gaussian)
    mean_vol = math.pi / 6.0 * (1.0 + polydispersity**2 * (1.0 if distribution == "uniform" else 3.0))
    n = int(round(phi * volume / mean_vol))
    d = draw_diameters(n, polydispersity, distribution, seed)
    d *= (phi * volume / (math.pi / 6.0 * np.sum(d**3))) ** (1.0 / 3.0)
    P = rng.uniform(lo + 0.5, hi - 0.5, (n, 3))
    P, _, worst = relax_packing(P, d, box, relax={"alpha": 0.25}, tolerance=tolerance,
                                max_iterations=max_iterations)
    return P, d, worst


def blob(x: float, z: float, width: float, n: int, seed: int = 0) -> np.ndarray:
    """``n`` tracer particles drawn from a Gaussian blob (standard deviation ``width``).

    The discrete counterpart of ``[tracer] start = {x, z, width}``.
    """
    rng = np.random.default_rng(seed)
    return np.column_stack([x + width * rng.standard_normal(n), z + width * rng.standard_normal(n)])


def layer_mask(z, spacing: float) -> np.ndarray:
    """True for heights in the coloured bands ``[k s, k s + s/2)`` (the layered silo)."""
    return in_bands(z, spacing)


def tracking(tracked, n: int, records: int, n_ticks: int, levels, z_tracked, ncoord: int):
    """The bookkeeping of tracked particles for a Monte Carlo run (2D and 3D alike).

    Args:
        tracked: ``"all"``, None or particle indices.
        n: number of particles. records: snapshots of the tracked particles.
        n_ticks: ticks of the run. levels: heights (d) whose crossings are recorded.
        z_tracked: a callable giving the heights of the tracked particles (indices -> d).
        ncoord: coordinates per position (2: ``(x, z)``, 3: ``(x, z, y)``).

    Returns:
        dict: ``tracked`` (indices), ``track_slot`` (particle -> row or -1),
        ``rec_ticks``, ``tpos`` (snapshot, particle, ncoord; NaN), ``levels`` (sorted),
        ``lev_next``, ``cross_x``, ``cross_t`` (tracked x level; NaN), ``exit_x``,
        ``exit_t`` (per particle; NaN).
    """
    if tracked is None:
        tracked = np.zeros(0, np.int64)
    elif isinstance(tracked, str):
        if tracked != "all":
            raise ValueError(f"tracked: must be 'all', None or indices, got {tracked!r}")
        tracked = np.arange(n)
    tracked = np.asarray(tracked, np.int64)
    track_slot = -np.ones(n, np.int64)
    track_slot[tracked] = np.arange(tracked.size)
    records = max(1, int(records)) if tracked.size else 0
    rec_ticks = (np.round(np.linspace(0, n_ticks, records + 1)[1:]).astype(np.int64) - 1
                 if records else np.zeros(0, np.int64))
    rec_ticks = np.unique(np.clip(rec_ticks, 0, n_ticks - 1))
    levels = np.sort(np.asarray(levels, float))
    return dict(
        tracked=tracked, track_slot=track_slot, rec_ticks=rec_ticks,
        tpos=np.full((rec_ticks.size, tracked.size, ncoord), np.nan), levels=levels,
        lev_next=np.searchsorted(levels, z_tracked(tracked), side="right").astype(np.int64) - 1,
        cross_x=np.full((tracked.size, levels.size), np.nan),
        cross_t=np.full((tracked.size, levels.size), np.nan),
        exit_x=np.full(n, np.nan), exit_t=np.full(n, np.nan))
