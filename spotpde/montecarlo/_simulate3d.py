"""The 3D discrete spot model: spheres in a box, typically a thin slab a few grains deep
between front and back walls like the experiments' silos (private; see ``montecarlo``
and docs/packing.md).

:func:`run3d` is what :func:`spotpde.montecarlo.simulate` runs for a 3D grid (after
checking the arguments). The model is the 2D one with a ``y`` coordinate: spots are
injected on the floor (a slot across the whole depth, ``orifice.shape = "slot"``, or a
disk), walk up with independent persistent horizontal steps in ``x`` and ``y`` (each of
diffusion length ``b``, as the continuum's ``D_perp`` per horizontal component), and are
mirrored by reflecting side, front and back walls (removed by open ones); a particle
within reach moves by ``-w(r_p - r_s - lam dR) dR / phi`` with a 3D kernel ``w`` and
``phi(x, y)`` the fraction of the kernel inside the walls (:func:`coverage_table3`;
``walls = "truncate"``: ``phi = 1``). Relaxation (``relax``) works on spheres
(``_relax3d``). With ``probes`` the frozen probes and the spot-density histogram of 2D
are kept on the 3D grid (``_mc3d._probe_step``; off by default).
"""

from __future__ import annotations

import math
import time

import numpy as np
from scipy import special

from . import _mc_kernels as K
from ._mc3d import advance3, build_cells3, make_params3
from ._particles import dense_packing, tracking
from ._relax import particle_diameters, relax_params
from ._result import STEPS, MCResult

__all__ = ["run3d", "coverage_table3", "case_particles3d"]


def case_particles3d(grid, name: str, spacing: float = 1.0, seed: int = 0) -> np.ndarray:
    """Initial spheres of ``from_case`` in a 3D grid, ``(N, 3)`` in columns ``(x, z, y)``:
    ``"lattice"`` a simple cubic lattice of ``spacing`` d filling the box, ``"random"``
    a :func:`~spotpde.montecarlo.dense_packing` at volume fraction 0.5."""
    if name == "lattice":
        axes = [np.arange(lo + 0.5 * spacing, hi, spacing)
                for lo, hi in (grid.x_range, grid.z_range, grid.y_range)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    if name == "random":

        return dense_packing(grid, 0.5, seed=seed)[0]
    raise ValueError(f"particles: unknown {name!r} for a 3D case; valid: 'lattice', "
                     "'random', None or an (N, 3) array of positions (x, z, y)")


def _footprint(kp, u):
    """``int w dz`` of the kernel at horizontal distance ``u`` (d) from its axis, up to a
    constant factor (only ratios are used)."""
    r = u / kp.size
    if kp.shape == K.SHAPE_UNIFORM:
        return np.sqrt(np.clip(1.0 - r * r, 0.0, None))
    if kp.shape == K.SHAPE_GAUSSIAN:
        return np.exp(-0.5 * r * r)
    # int exp(-sqrt(r^2 + t^2)) dt = 2 r K_1(r), -> 2 at r = 0
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(r > 0, 2.0 * r * special.k1(np.maximum(r, 1e-300)), 2.0)
    return out


def coverage_table3(kp, x_range, y_range, spacing: float = 0.02, fine: int = 400):
    """``phi(x, y)``: the fraction of the 3D kernel ``kp`` centred at ``(x, y)`` that lies
    between the walls ``x_range`` and ``y_range`` (d), tabulated on a grid of nodes.

    The kernel's footprint ``int w dz`` is integrated over squares of side ``2 reach /
    fine`` (midpoint rule) into a cumulative table ``F(a, b)`` (the integral over
    ``u < a, v < b``), and ``phi`` is the rectangle sum of ``F`` at the walls, bilinear in
    ``F`` between its nodes; relative error of order ``(reach / fine)^2`` for smooth
    kernels, ``(reach / fine)^1.5`` at the sphere's rim. Nodes every ``spacing`` (or
    fewer, at most 1001 per axis) over the box.

    Returns:
        ``(x first node, x spacing, y first node, y spacing, phi[k_y, k_x])``.
    """
    rh = kp.size if kp.shape == K.SHAPE_UNIFORM else kp.reach[0]
    h = 2.0 * rh / fine
    c = -rh + h * (np.arange(fine) + 0.5)
    U, V = np.meshgrid(c, c, indexing="ij")
    f = _footprint(kp, np.hypot(U, V))
    if kp.shape != K.SHAPE_UNIFORM:
        f = np.where(np.hypot(U, V) <= rh, f, 0.0)
    F = np.zeros((fine + 1, fine + 1))
    F[1:, 1:] = f.cumsum(axis=0).cumsum(axis=1)
    F /= F[-1, -1]

    def Fat(a, b):
        ia = np.clip((a + rh) / h, 0.0, fine)
        ib = np.clip((b + rh) / h, 0.0, fine)
        ka = np.minimum(ia.astype(int), fine - 1)
        kb = np.minimum(ib.astype(int), fine - 1)
        ta, tb = ia - ka, ib - kb
        return ((1 - ta) * (1 - tb) * F[ka, kb] + ta * (1 - tb) * F[ka + 1, kb]
                + (1 - ta) * tb * F[ka, kb + 1] + ta * tb * F[ka + 1, kb + 1])

    (x0, x1), (y0, y1) = x_range, y_range
    nx = int(min(1001, max(2, math.ceil((x1 - x0) / spacing) + 1)))
    ny = int(min(1001, max(2, math.ceil((y1 - y0) / spacing) + 1)))
    xs, ys = np.linspace(x0, x1, nx), np.linspace(y0, y1, ny)
    X, Y = np.meshgrid(xs, ys)
    a0, a1, b0, b1 = x0 - X, x1 - X, y0 - Y, y1 - Y
    phi = Fat(a1, b1) - Fat(a0, b1) - Fat(a1, b0) + Fat(a0, b0)
    return (float(xs[0]), float(xs[1] - xs[0]), float(ys[0]), float(ys[1] - ys[0]),
            np.clip(phi, 1e-300, 1.0))


def run3d(grid, orifice, spots, kp, *, rule, gamma, step, steps, seed, t_end, dt, n_ticks,
          Q0, b0, b_par, profile, skin, cell, particles, tracked, records, levels, progress,
          walls, relax, diameters, relax_reach, probes=False, batches=20):
    """Run the 3D model with the arguments :func:`~spotpde.montecarlo.simulate` checked
    and derived (lengths in d). Returns an :class:`~spotpde.montecarlo.MCResult` with
    ``(N, 3)`` positions in columns ``(x, z, y)`` (the first two as in 2D, the depth
    last; the order of ``spotpde.analysis.packing``); with ``probes`` the probe sums
    ``(9, batches, nz, ny, nx)`` on the grid's cell centres (``_mc3d.advance3``)."""

    if kp.dims != 3:
        raise ValueError("kernel: the 3D Monte Carlo needs a 3D kernel")
    x0, x1 = grid.x_range
    y0, y1 = grid.y_range
    z0, z1 = grid.z_range
    slot = getattr(orifice, "shape", "disk") == "slot"
    yc = 0.5 * (y0 + y1) if orifice.y is None else float(orifice.y)
    ncx = max(1, int(math.ceil((x1 - x0) / cell)))
    ncy = max(1, int(math.ceil((y1 - y0) / cell)))
    ncz = max(1, int(math.ceil((z1 - z0) / cell)))
    tab = (0.0, 0.0, 0.0, 0.0, np.ones((1, 1)))
    if walls == "renormalise" and grid.walls == "reflecting":
        tab = coverage_table3(kp, (x0, x1), (y0, y1))
    prm = make_params3(
        x0=x0, x1=x1, y0=y0, y1=y1, z0=z0, z1=z1, xc=orifice.x, yc=yc, width=orifice.width,
        rate=Q0 * dt, step=step, sigx=math.sqrt(2.0 * b0 * step),
        sigz=math.sqrt(2.0 * b_par * step), gamma=gamma, lam=rule, ksize=kp.size,
        ksize_v=kp.size_v, kamp=kp.amp, reach_h=kp.reach[0], reach_v=kp.reach[1], cell=cell,
        skin=skin, dt=dt, tab_x0=tab[0], tab_dx=tab[1], tab_y0=tab[2], tab_dy=tab[3],
        shape=kp.shape, profile=profile, slot=int(slot),
        walls=K.WALLS_OPEN if grid.walls == "open" else K.WALLS_REFLECTING,
        steps=STEPS.index(steps), ncx=ncx, ncy=ncy, ncz=ncz, ticks_total=n_ticks,
        probe_x0=grid.x[0], probe_y0=grid.y[0], probe_z0=grid.z[0], probe_h=grid.spacing,
        pnx=grid.nx, pny=grid.ny, pnz=grid.nz, n_batch=batches, probes=int(bool(probes)))
    shape = (batches, grid.nz, grid.ny, grid.nx) if probes else (1, 1, 1, 1)
    probe, rho_hist = np.zeros((9,) + shape), np.zeros(shape)
    phi_tab = np.ascontiguousarray(tab[4])

    P = np.zeros((0, 3)) if particles is None else np.asarray(particles, dtype=float)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"particles: a 3D run needs (N, 3) positions (x, z, y), got shape {P.shape}")
    n = P.shape[0]
    px, pz, py = (np.ascontiguousarray(P[:, k]).copy() for k in range(3))
    status = np.zeros(n, np.int64)
    status[pz < z0] = K.P_ORIFICE
    moved = np.zeros(n)
    diam = particle_diameters(n, relax, diameters, seed)
    if relax is not None:
        relax = relax.resolved(relax_reach)
    rp = relax_params(relax, diam, orifice.x, grid.walls == "reflecting")
    blk = np.zeros(max(n, 1), np.int64)
    old = np.zeros((max(n, 1), 3))
    cell_start = np.zeros(ncx * ncy * ncz + 1, np.int64)
    cell_idx = np.zeros(max(n, 1), np.int64)
    if n:
        build_cells3(px, py, pz, status, x0, y0, z0, cell, ncx, ncy, ncz, cell_start, cell_idx)
    bk = tracking(tracked, n, records, n_ticks, grid.z if levels is None else levels,
                  lambda i: pz[i], 3)
    tracked, track_slot, rec_ticks, tpos, levels, lev_next, cross_x, cross_t, exit_x, exit_t = (
        bk[k] for k in ("tracked", "track_slot", "rec_ticks", "tpos", "levels", "lev_next",
                        "cross_x", "cross_t", "exit_x", "exit_t"))

    mean_active = Q0 * (z1 - z0) / spots.drift
    cap = int(mean_active * 1.2 + 10.0 * math.sqrt(mean_active) + 64)
    sx, sy, sz, sxi, syi = (np.zeros(cap) for _ in range(5))
    srel = np.zeros((cap, 4))
    cnt = np.zeros(K.NC, np.int64)
    cnt[K.C_PENDING] = -1
    K.seed(int(seed) % (2**32))
    chunk = max(1, n_ticks // 200)
    wall = cpu = 0.0
    while cnt[K.C_TICK] < n_ticks:
        todo = min(chunk, n_ticks - cnt[K.C_TICK])
        t0, c0 = time.perf_counter(), time.process_time()
        advance3(prm, cnt, todo, sx, sy, sz, sxi, syi, px, py, pz, status, moved, cell_start,
                 cell_idx, track_slot, tpos, rec_ticks, levels, lev_next, cross_x, cross_t,
                 exit_x, exit_t, phi_tab, rp, diam, srel, blk, old, probe, rho_hist)
        wall += time.perf_counter() - t0
        cpu += time.process_time() - c0
        if cnt[K.C_PENDING] >= 0:  # spot arrays full: grow and carry on
            cap *= 2
            sx, sy, sz, sxi, syi = (np.concatenate([a, np.zeros(a.size)])
                                    for a in (sx, sy, sz, sxi, syi))
            srel = np.concatenate([srel, np.zeros_like(srel)])
        if progress is not None:
            progress(cnt[K.C_TICK] / n_ticks)

    return MCResult(
        grid=grid, orifice=orifice, spots=spots, kernel=kp, rule=rule, gamma=gamma, step=step,
        steps=steps, seed=seed, t_end=t_end, dt=dt, n_ticks=n_ticks, initial=P.copy(),
        final=np.column_stack([px, pz, py]), status=status, exit_x=exit_x, exit_t=exit_t,
        tracked=tracked, times=(rec_ticks + 1) * dt, positions=tpos, levels=levels,
        cross_x=cross_x, cross_t=cross_t, probe=probe if probes else None,
        rho_hist=rho_hist if probes else None,
        batch_ticks=np.bincount(np.arange(n_ticks) * batches // n_ticks, minlength=batches)
        if probes else np.array([n_ticks]),
        counters={"spots_injected": int(cnt[K.C_INJECTED]), "spot_steps": int(cnt[K.C_STEPS]),
                  "particle_updates": int(cnt[K.C_UPDATES]),
                  "cell_rebuilds": int(cnt[K.C_REBUILDS]), "spots_removed": int(cnt[K.C_REMOVED]),
                  "relaxations": int(cnt[K.C_RELAXATIONS]), "grains_relaxed": int(cnt[K.C_RELAXED])},
        wall_time=wall, cpu_time=cpu, walls=walls, relax=relax, diameters=diam)
