"""The discrete spot model in a wedge hopper, a cylindrical silo and a cone (private).

:func:`simulate_geometry` runs ``_geom_kernels.advance_geom`` on a 2D grid with a wedge
hopper (spots and particles in ``(x, z)`` between the slanted walls and the box's side
walls) or on an axisymmetric grid (``domain.coordinates = "axisymmetric"``, with or
without a cone): spots, particles and the 3D kernel live in the cylinder ``r <= a``
(``r = sqrt(x^2 + y^2)``, the grid's ``x`` is the radius) and the probe fields are
binned on the grid's ``(r, z)`` cells, so they compare with the continuum result of the
same case. The walls come from ``grid.geometry`` (``side_walls``, ``contains``,
``active``). Lengths in d, times in the case's unit; docs/montecarlo.md, "Hoppers and
cylinders".
"""

from __future__ import annotations

import math
import time

import numpy as np

from . import _geom_kernels as G
from . import _mc_kernels as K
from ._particles import lattice, tracking
from ._result import MCResult
from ..fields import _axisymmetric, _walls
from ..grid import Grid

__all__ = ["simulate_geometry", "geometry_particles", "runs_in_geometry"]


def runs_in_geometry(grid) -> bool:
    """True for the grids :func:`simulate_geometry` handles (a hopper or rings)."""
    geo = grid.geometry
    return grid.dims == 2 and (geo.curved or geo.masked)


def geometry_particles(grid, spacing: float = 1.0) -> np.ndarray:
    """A lattice of particles filling the material of ``grid`` (none outside it).

    2D (wedge): the triangular :func:`lattice` of the box, kept where
    ``grid.geometry.contains``. Rings (cylinder, cone): a simple cubic lattice of
    ``spacing`` in the cylinder, kept where ``contains(r, z)``; columns ``(x, z, y)``.
    """
    geo = grid.geometry
    if not geo.curved:
        P = lattice(grid, spacing)
        return P[geo.contains(P[:, 0], P[:, 1])]
    a = grid.x_range[1]
    z0, z1 = grid.z_range
    xs = np.arange(-a + 0.5 * spacing, a, spacing)
    zs = np.arange(z0 + 0.5 * spacing, z1, spacing)
    X, Z, Y = np.meshgrid(xs, zs, xs, indexing="ij")
    P = np.column_stack([X.ravel(), Z.ravel(), Y.ravel()])
    return P[geo.contains(np.hypot(P[:, 0], P[:, 2]), P[:, 1])]


def _phi_table(grid, kernel, walls: str) -> np.ndarray:
    """The continuum's kernel coverage ``phi`` on the cell centres (rings: relative to
    a cylinder without a wall in reach), continued from the
    nearest active cell of each row into the inactive ones (so that interpolating at a
    spot inside the material never reads the ~0 of a cell outside); empty: no
    renormalisation."""
    geo = grid.geometry
    if walls != "renormalise" or not (geo.masked or grid.walls == "reflecting"):
        return np.zeros((0, 0))
    if geo.curved:
        phi = np.asarray(_axisymmetric.coverage(grid, kernel, None), dtype=float)
        # the ring quadrature's own error near the axis (phi up to 1.005 with no wall in
        # reach) belongs to the continuum's discrete kernel, not to the walls: divide it
        # out with the coverage of a cylinder wider by the kernel's reach
        h = grid.spacing
        wider = Grid(2, (0.0, grid.x_range[1] + h * math.ceil(kernel.reach[0] / h + 1)),
                     grid.z_range, h, walls=grid.walls, coordinates="axisymmetric")
        phi = phi / np.asarray(_axisymmetric.coverage(wider, kernel, None),
                               dtype=float)[:, :grid.nx]
    else:
        phi = np.asarray(_walls.coverage(grid, kernel, geo.active.astype(float)), dtype=float)
    act = np.asarray(geo.active, dtype=bool)
    out = phi.copy()
    cols = np.arange(grid.nx)
    for k in range(grid.nz):
        on = np.flatnonzero(act[k])
        if on.size:
            nearest = on[np.abs(cols[:, None] - on[None, :]).argmin(axis=1)]
            out[k] = phi[k, nearest]
    return np.ascontiguousarray(out)


def _probes(grid, azimuths: int):
    """Probe points on the active cells' centres and the flat cell each belongs to:
    2D one per cell ``(x, 0, z)``; rings ``azimuths`` evenly spaced around each ring."""
    act = np.asarray(grid.geometry.active, dtype=bool)
    k, i = np.nonzero(act)
    bins = k * grid.nx + i
    z = grid.z[k]
    s = grid.x[i]
    if not grid.geometry.curved:
        return s, np.zeros_like(s), z, bins, np.bincount(bins, minlength=grid.nz * grid.nx)
    th = 2.0 * np.pi * (np.arange(azimuths) + 0.5) / azimuths
    x = (s[:, None] * np.cos(th)[None, :]).ravel()
    y = (s[:, None] * np.sin(th)[None, :]).ravel()
    zz = np.repeat(z, azimuths)
    bb = np.repeat(bins, azimuths)
    return x, y, zz, bb, np.bincount(bb, minlength=grid.nz * grid.nx)


def simulate_geometry(grid, orifice, spots, kp, *, rule, gamma, step, steps, seed, t_end,
                      dt, n_ticks, Q0, b0, b_par, profile, particles, tracked, records,
                      batches, walls, kernel, azimuths: int = 8, progress=None,
                      probes: bool = True):
    """Run the Monte Carlo in the hopper or cylinder of ``grid`` (arguments as resolved
    by ``_simulate.simulate``; ``kp`` the kernel's ``KernelParams``, 3D on rings).

    ``particles``: ``(N, 2)`` ``(x, z)`` (wedge) or ``(N, 3)`` ``(x, z, y)`` (rings), all
    inside the material (ValueError naming ``particles`` otherwise). ``probes``: False
    for particles only (``probe``, ``rho_hist`` None). ``azimuths``: probes
    per ring (the ``(r, z)`` fields average them, the drift's horizontal component
    projected on each probe's radial direction).

    Returns:
        ``MCResult`` whose ``probe`` (``(5, n_batch, nz, nx)``: per-probe averages) and
        ``rho_hist`` (spot samples per cell) are on the grid's cells (``(r, z)`` on
        rings), ``exit_x`` the exit's ``x`` (rings: its radius ``r``).
    """

    geo = grid.geometry
    cyl = 1 if geo.curved else 0
    ncoord = 3 if cyl else 2
    (x0, x1), (z0, z1) = grid.x_range, grid.z_range
    c, hw, slope = geo.side_walls()
    wmax = x1 if cyl else max(abs(x1 - c), abs(c - x0))
    hw = min(float(hw), wmax)
    if cyl:
        x0, x1, c = -x1, x1, 0.0
    if particles is None:
        particles = np.zeros((0, ncoord))
    P = np.asarray(particles, dtype=float)
    if P.ndim != 2 or P.shape[1] != ncoord:
        raise ValueError(f"particles: need an (N, {ncoord}) array for this grid, got shape {P.shape}")
    s_p = np.hypot(P[:, 0], P[:, 2]) if cyl else P[:, 0]
    if P.shape[0] and not np.all(geo.contains(s_p, P[:, 1])):
        raise ValueError("particles: every particle must start inside the material "
                         "(grid.geometry.contains); use geometry_particles(grid)")
    n = P.shape[0]
    px = np.ascontiguousarray(P[:, 0]).copy()
    pz = np.ascontiguousarray(P[:, 1]).copy()
    py = np.ascontiguousarray(P[:, 2]).copy() if cyl else np.zeros(n)
    status = np.zeros(n, np.int64)
    cell = max(kp.reach[0], kp.reach[1], 0.25)
    ncx = max(1, int(math.ceil((x1 - x0) / cell)))
    ncy = ncx if cyl else 1
    ncz = max(1, int(math.ceil((z1 - z0) / cell)))
    phi_tab = _phi_table(grid, kernel, walls)
    batches = max(1, min(int(batches), n_ticks))
    prm = G.make_geom_params(
        cyl=cyl, xc=c, hw=hw, slope=slope, wmax=wmax, x0=x0, x1=x1, z0=z0, z1=z1,
        ow=0.5 * orifice.width, rate=Q0 * dt, step=step, sigx=math.sqrt(2.0 * b0 * step),
        sigz=math.sqrt(2.0 * b_par * step), gamma=gamma, lam=rule, ksize=kp.size,
        ksize_v=kp.size_v, kamp=kp.amp, reach_h=kp.reach[0], reach_v=kp.reach[1],
        cell=cell, ncx=ncx, ncy=ncy, ncz=ncz, tab_x0=grid.x[0], tab_z0=grid.z[0],
        tab_h=grid.spacing, tnx=phi_tab.shape[1] if phi_tab.size else 0, tnz=grid.nz,
        shape=kp.shape, profile=profile, steps=K.STEPS_GAUSSIAN if steps == "gaussian"
        else K.STEPS_BINARY, nbin=grid.nz * grid.nx, n_batch=batches, ticks_total=n_ticks)
    if not phi_tab.size:
        phi_tab = np.ones((1, 1))
    ncell = ncx * ncy * ncz
    cell_start = np.zeros(ncell + 1, np.int64)
    cell_idx = np.zeros(max(n, 1), np.int64)
    qx, qy, qz, qbin, per_bin = _probes(grid, int(azimuths))
    if not probes:
        qx, qy, qz, qbin = (a[:0] for a in (qx, qy, qz, qbin))
    qcell_start = np.zeros(ncell + 1, np.int64)
    qcell_idx = np.zeros(max(qx.size, 1), np.int64)
    G.build_cells(prm, qx, qy, qz, np.zeros(qx.size, np.int64), qcell_start, qcell_idx)
    bk = tracking(tracked, n, records, n_ticks, np.zeros(0), lambda i: pz[i], ncoord)
    probe = np.zeros((5, batches, grid.nz * grid.nx))
    rho_hist = np.zeros((batches, grid.nz * grid.nx))
    mean_active = Q0 * (z1 - z0) / spots.drift
    cap = int(mean_active * 1.2 + 10.0 * math.sqrt(mean_active) + 64)
    sx, sy, sz, sxi, syi = (np.zeros(cap) for _ in range(5))
    exit_s = np.full(n, np.nan)
    exit_t = np.full(n, np.nan)
    cnt = np.zeros(K.NC, np.int64)
    cnt[K.C_PENDING] = -1
    K.seed(int(seed) % (2**32))
    chunk = max(1, n_ticks // 200)
    wall = cpu = 0.0
    while cnt[K.C_TICK] < n_ticks:
        todo = min(chunk, n_ticks - cnt[K.C_TICK])
        t0, c0 = time.perf_counter(), time.process_time()
        G.advance_geom(prm, cnt, todo, sx, sy, sz, sxi, syi, px, py, pz, status, exit_s,
                       exit_t, cell_start, cell_idx, qx, qy, qz, qbin, qcell_start,
                       qcell_idx, bk["track_slot"], bk["tpos"], bk["rec_ticks"], probe,
                       rho_hist, phi_tab)
        wall += time.perf_counter() - t0
        cpu += time.process_time() - c0
        if cnt[K.C_PENDING] >= 0:
            cap *= 2
            sx, sy, sz, sxi, syi = (np.concatenate([a, np.zeros(a.size)])
                                    for a in (sx, sy, sz, sxi, syi))
        if progress is not None:
            progress(cnt[K.C_TICK] / n_ticks)
    probe = probe / np.maximum(per_bin, 1)[None, None, :]
    shape = (grid.nz, grid.nx)
    batch_of_tick = np.arange(n_ticks) * batches // n_ticks
    final = np.column_stack([px, pz, py] if cyl else [px, pz])
    return MCResult(
        grid=grid, orifice=orifice, spots=spots, kernel=kp, rule=float(rule), gamma=float(gamma),
        step=step, steps=steps, seed=int(seed), t_end=t_end, dt=dt, n_ticks=n_ticks,
        initial=P.copy(), final=final, status=status, exit_x=exit_s, exit_t=exit_t * dt,
        tracked=bk["tracked"], times=(bk["rec_ticks"] + 1) * dt, positions=bk["tpos"],
        levels=bk["levels"], cross_x=bk["cross_x"], cross_t=bk["cross_t"],
        probe=probe.reshape(5, batches, *shape) if probes else None,
        rho_hist=rho_hist.reshape(batches, *shape) if probes else None,
        batch_ticks=np.bincount(batch_of_tick, minlength=batches),
        counters={"spots_injected": int(cnt[K.C_INJECTED]), "spot_steps": int(cnt[K.C_STEPS]),
                  "particle_updates": int(cnt[K.C_UPDATES]),
                  "cell_rebuilds": int(cnt[K.C_REBUILDS]), "spots_removed": int(cnt[K.C_REMOVED]),
                  "spots_active": int(cnt[K.C_NACTIVE]), "relaxations": 0,
                  "grains_relaxed": 0},
        wall_time=wall, cpu_time=cpu, walls=walls, relax=None, diameters=None)
