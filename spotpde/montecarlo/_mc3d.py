"""Numba kernels of the 3D discrete spot-model Monte Carlo (private; see ``montecarlo``).

The 3D counterpart of ``_mc_kernels`` for a box ``[x0, x1] x [y0, y1] x [z0, z1]``
(lengths in d, times in the case's unit), typically a thin slab a few grains deep in
``y`` between front and back walls. Spots walk in ``x`` and ``y`` with independent
persistent steps of the same rule as in 2D (``_mc_kernels.next_direction``) and drift
up in ``z``; reflecting walls mirror them in ``x`` and in ``y`` (their persistent
direction along that axis turns around), open walls remove them. The influence is a
3D kernel (:func:`kernel_w3`), renormalised by the fraction ``phi(x, y)`` of the
kernel inside the side, front and back walls (bilinear in a table). Particles are found
through a 3D cell list, so a spot step costs O(particles within reach). Frozen probes at
the grid's cell centres (``probes``) accumulate the mean-field drift and diffusivity as
in 2D, with all three components.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ._mc_kernels import (C_INJECTED, C_NACTIVE, C_PENDING, C_REBUILDS, C_RELAXATIONS,
                          C_RELAXED, C_REMOVED, C_STEPS, C_TICK, C_UPDATES, P_IN, P_ORIFICE,
                          P_SIDE, PROFILE_POINT, PROFILE_UNIFORM,
                          SHAPE_GAUSSIAN, SHAPE_UNIFORM, WALLS_OPEN, first_direction,
                          next_direction, persistence, sort_into_cells, typed)
from ._relax3d import relax_block3


class Params3(NamedTuple):
    """The constants of one 3D run, as :func:`advance3` reads them (see
    ``_mc_kernels.Params`` for the fields shared with 2D).

    Attributes (beyond the 2D ones): y0, y1: the front and back walls (d); yc: the
    orifice's centre in y; slot: 1 the orifice spans the whole depth (``y`` uniform), 0 a
    disk of diameter ``width`` (or a radial Gaussian) at ``(xc, yc)``; ty0, tdy: the
    coverage table's first node and spacing in y; ncy: particle cells in y;
    probe_x0, probe_y0, probe_z0, probe_h: the probe grid's first centre and spacing;
    pnx, pny, pnz: its points; n_batch: time batches; probes: 1 to accumulate them.
    """

    x0: float
    x1: float
    y0: float
    y1: float
    z0: float
    z1: float
    xc: float
    yc: float
    width: float
    rate: float
    step: float
    sigx: float
    sigz: float
    gamma: float
    lam: float
    ksize: float
    ksize_v: float
    kamp: float
    reach_h: float
    reach_v: float
    cell: float
    skin: float
    dt: float
    tab_x0: float
    tab_dx: float
    tab_y0: float
    tab_dy: float
    shape: int
    profile: int
    slot: int
    walls: int
    steps: int
    ncx: int
    ncy: int
    ncz: int
    ticks_total: int
    probe_x0: float = 0.0
    probe_y0: float = 0.0
    probe_z0: float = 0.0
    probe_h: float = 1.0
    pnx: int = 1
    pny: int = 1
    pnz: int = 1
    n_batch: int = 1
    probes: int = 0


def make_params3(**values) -> Params3:
    """A :class:`Params3` from keyword values, each converted to its field's type.

    Raises:
        TypeError: a field is missing or unknown (the message names it).
    """
    return typed(Params3, "make_params3", values)


@njit(cache=True, inline="always")
def kernel_w3(shape, dx, dy, dz, size, size_v, amp, reach_h, reach_v):
    """Influence ``w`` at offset ``(dx, dy, dz)`` (d) from the spot centre: the 3D form
    of ``_mc_kernels.kernel_w`` with ``(dx^2 + dy^2) / size^2`` in place of
    ``(dx / size)^2`` (horizontally isotropic; smooth kernels cut off outside the
    spheroid of half-axes ``reach``)."""
    if abs(dx) > reach_h or abs(dy) > reach_h or abs(dz) > reach_v:
        return 0.0
    h2 = dx * dx + dy * dy
    if shape == SHAPE_UNIFORM:
        q = h2 / (size * size) + (dz / size_v) ** 2
        return amp if q < 1.0 else 0.0
    if h2 / (reach_h * reach_h) + (dz / reach_v) ** 2 > 1.0:
        return 0.0
    q = h2 / (size * size) + (dz / size_v) ** 2
    if shape == SHAPE_GAUSSIAN:
        return amp * math.exp(-0.5 * q)
    return amp * math.exp(-math.sqrt(q))


@njit(cache=True)
def kernel_eval3(shape, x, y, z, size, size_v, amp, reach_h, reach_v):
    """Vectorised :func:`kernel_w3` over flat arrays (for tests)."""
    out = np.empty(x.size)
    for i in range(x.size):
        out[i] = kernel_w3(shape, x[i], y[i], z[i], size, size_v, amp, reach_h, reach_v)
    return out


@njit(cache=True)
def build_cells3(px, py, pz, status, x0, y0, z0, cell, ncx, ncy, ncz, cell_start, cell_idx):
    """Counting sort of the particles still in the box into cubic cells of side ``cell``
    (index ``(cz ncy + cy) ncx + cx``; outside particles clamped into the edge cells)."""
    n = px.size
    cid = np.empty(n, np.int64)
    for i in range(n):
        if status[i] != P_IN:
            cid[i] = -1
            continue
        cx = min(max(int(math.floor((px[i] - x0) / cell)), 0), ncx - 1)
        cy = min(max(int(math.floor((py[i] - y0) / cell)), 0), ncy - 1)
        cz = min(max(int(math.floor((pz[i] - z0) / cell)), 0), ncz - 1)
        cid[i] = (cz * ncy + cy) * ncx + cx
    sort_into_cells(cid, ncx * ncy * ncz, cell_start, cell_idx)


@njit(cache=True, inline="always")
def coverage_inverse2(x, y, tx0, tdx, ty0, tdy, tab):
    """``1 / phi(x, y)`` by bilinear interpolation in ``tab[k_y, k_x]`` (nodes at
    ``tx0 + k_x tdx``, ``ty0 + k_y tdy``, clamped to the table); 1 without a table."""
    ny = tab.shape[0]
    nx = tab.shape[1]
    if nx < 2 or ny < 2:
        return 1.0
    tx = (x - tx0) / tdx
    ty = (y - ty0) / tdy
    kx = min(max(int(math.floor(tx)), 0), nx - 2)
    ky = min(max(int(math.floor(ty)), 0), ny - 2)
    fx = min(max(tx - kx, 0.0), 1.0)
    fy = min(max(ty - ky, 0.0), 1.0)
    p = ((1.0 - fy) * ((1.0 - fx) * tab[ky, kx] + fx * tab[ky, kx + 1])
         + fy * ((1.0 - fx) * tab[ky + 1, kx] + fx * tab[ky + 1, kx + 1]))
    return 1.0 / p


@njit(cache=True, inline="always")
def _mirror(v, lo, hi):
    if v < lo:
        v = 2.0 * lo - v
    if v > hi:
        v = 2.0 * hi - v
    return min(max(v, lo), hi)


@njit(cache=True, inline="always")
def _place3(i, oxp, oyp, ozp, npx, npy, npz, x0, x1, y0, y1, z0, walls, open_lo, open_hi,
            t_mid, px, py, pz, status, moved, track_slot, levels, lev_next, cross_x, cross_t,
            exit_x, exit_t):
    """Move particle ``i`` to ``(npx, npy, npz)``: ``_mc_kernels._place`` in 3D (mirrored
    at reflecting side, front and back walls, gone through open ones; level crossings
    of tracked particles; exit through the floor's opening ``open_lo < x < open_hi``).
    Returns its distance moved since the last binning (0 if it left sideways)."""
    if npx < x0 or npx > x1 or npy < y0 or npy > y1:
        if walls == WALLS_OPEN:
            status[i] = P_SIDE
            px[i] = npx
            py[i] = npy
            pz[i] = npz
            return 0.0
        npx = _mirror(npx, x0, x1)
        npy = _mirror(npy, y0, y1)
    m = moved[i] + abs(npx - oxp) + abs(npy - oyp) + abs(npz - ozp)
    moved[i] = m
    ts = track_slot[i]
    if ts >= 0:
        k = lev_next[ts]
        while k >= 0 and npz < levels[k]:
            if ozp >= levels[k]:
                f = (ozp - levels[k]) / (ozp - npz)
                cross_x[ts, k] = oxp + f * (npx - oxp)
            else:
                cross_x[ts, k] = npx
            cross_t[ts, k] = t_mid
            k -= 1
        lev_next[ts] = k
    if npz < z0:
        xe = npx
        if ozp >= z0:
            xe = oxp + (ozp - z0) / (ozp - npz) * (npx - oxp)
        if open_lo < xe < open_hi:
            status[i] = P_ORIFICE
            exit_x[i] = xe
            exit_t[i] = t_mid
    px[i] = npx
    py[i] = npy
    pz[i] = npz
    return m


@njit(cache=True)
def _inject(prm, j, sx, sy):
    """Position ``(x, y)`` of a new spot on the floor (the orifice's profile)."""
    xc = prm.xc
    yc = prm.yc
    w = prm.width
    if prm.slot == 1:
        sy[j] = prm.y0 + (prm.y1 - prm.y0) * np.random.random()
        if prm.profile == PROFILE_POINT:
            sx[j] = xc
        elif prm.profile == PROFILE_UNIFORM:
            sx[j] = xc + w * (np.random.random() - 0.5)
        else:
            sx[j] = xc + 0.5 * w * np.random.standard_normal()
        return
    if prm.profile == PROFILE_POINT:
        sx[j] = xc
        sy[j] = yc
    elif prm.profile == PROFILE_UNIFORM:  # uniform in the disk of diameter w
        while True:
            u = 2.0 * np.random.random() - 1.0
            v = 2.0 * np.random.random() - 1.0
            if u * u + v * v < 1.0:
                break
        sx[j] = xc + 0.5 * w * u
        sy[j] = yc + 0.5 * w * v
    else:
        sx[j] = xc + 0.5 * w * np.random.standard_normal()
        sy[j] = yc + 0.5 * w * np.random.standard_normal()
    sx[j] = min(max(sx[j], prm.x0), prm.x1)
    sy[j] = min(max(sy[j], prm.y0), prm.y1)


@njit(cache=True)
def _probe_step(prm, probe, rho_hist, batch, ox, oy, oz, dx, dy, dz, cx_, cy_, cz_, inv_phi):
    """Add one spot step to the frozen probes and the spot-density histogram."""
    h = prm.probe_h
    rh = prm.reach_h; rv = prm.reach_v
    jx_lo = max(int(math.ceil((cx_ - rh - prm.probe_x0) / h)), 0)
    jx_hi = min(int(math.floor((cx_ + rh - prm.probe_x0) / h)), prm.pnx - 1)
    jy_lo = max(int(math.ceil((cy_ - rh - prm.probe_y0) / h)), 0)
    jy_hi = min(int(math.floor((cy_ + rh - prm.probe_y0) / h)), prm.pny - 1)
    jz_lo = max(int(math.ceil((cz_ - rv - prm.probe_z0) / h)), 0)
    jz_hi = min(int(math.floor((cz_ + rv - prm.probe_z0) / h)), prm.pnz - 1)
    ddz = dz - prm.step
    for jz in range(jz_lo, jz_hi + 1):
        zz = prm.probe_z0 + jz * h - cz_
        for jy in range(jy_lo, jy_hi + 1):
            yy = prm.probe_y0 + jy * h - cy_
            for jx in range(jx_lo, jx_hi + 1):
                w = kernel_w3(prm.shape, prm.probe_x0 + jx * h - cx_, yy, zz, prm.ksize,
                              prm.ksize_v, prm.kamp, rh, rv)
                if w == 0.0:
                    continue
                w *= inv_phi
                w2 = w * w
                probe[0, batch, jz, jy, jx] -= w * dx
                probe[1, batch, jz, jy, jx] -= w * dy
                probe[2, batch, jz, jy, jx] -= w * dz
                probe[3, batch, jz, jy, jx] += w2 * dx * dx
                probe[4, batch, jz, jy, jx] += w2 * dy * dy
                probe[5, batch, jz, jy, jx] += w2 * ddz * ddz
                probe[6, batch, jz, jy, jx] += w2 * dx * dy
                probe[7, batch, jz, jy, jx] += w2 * dx * ddz
                probe[8, batch, jz, jy, jx] += w2 * dy * ddz
    # spot density sample at a uniformly random point of the step
    u = np.random.random()
    hx = int(math.floor((ox + u * dx - prm.probe_x0) / h + 0.5))
    hy = int(math.floor((oy + u * dy - prm.probe_y0) / h + 0.5))
    hz = int(math.floor((oz + u * dz - prm.probe_z0) / h + 0.5))
    if 0 <= hx < prm.pnx and 0 <= hy < prm.pny and 0 <= hz < prm.pnz:
        rho_hist[batch, hz, hy, hx] += 1.0


@njit(cache=True)
def advance3(prm, cnt, n_ticks, sx, sy, sz, sxi, syi,
             px, py, pz, status, moved, cell_start, cell_idx,
             track_slot, tpos, rec_ticks, levels, lev_next, cross_x, cross_t, exit_x, exit_t,
             phi_tab, rp, diam, srel, blk, old, probe, rho_hist):
    """Advance the 3D simulation by at most ``n_ticks`` ticks (``_mc_kernels.advance`` in
    3D): inject ``Poisson(Q0 dt)`` spots, step each one by
    ``dR = (dx, dy, dz)``, move each particle within reach of ``r_s + lam dR`` by
    ``-w dR / phi(x_s + lam dx, y_s + lam dy)``, relax the grains near the spot (every
    ``rp.every``-th step and its last; ``_relax3d.relax_block3``).
    Returns early (``cnt[C_PENDING]`` set) when the spot arrays are full.

    Arrays: spots ``sx, sy, sz`` and persistent unit step variables ``sxi, syi``; ``srel``
    ``(cap, 4)``: the start ``(x, y, z)`` of the segment not yet relaxed and the steps
    since; ``tpos`` ``(n_rec, n_tracked, 3)`` in columns ``(x, z, y)``; ``phi_tab`` ``(ny_t, nx_t)`` (or 1 x 1:
    no renormalisation); ``old`` ``(N, 3)``; ``probe`` ``(9, n_batch, pnz, pny, pnx)``: sums
    of ``-w dx``, ``-w dy``, ``-w dz`` and of ``w**2`` times ``dx dx``, ``dy dy``, ``dz' dz'``,
    ``dx dy``, ``dx dz'``, ``dy dz'`` (``dz' = dz - Delta``); ``rho_hist``
    ``(n_batch, pnz, pny, pnx)`` spot samples. The others as in ``_mc_kernels.advance``.

    Returns:
        Number of ticks done.
    """
    x0 = prm.x0; x1 = prm.x1; y0 = prm.y0; y1 = prm.y1; z0 = prm.z0; z1 = prm.z1
    rate = prm.rate; step = prm.step; sigx = prm.sigx; sigz = prm.sigz
    gamma = prm.gamma; lam = prm.lam
    ksize = prm.ksize; ksizev = prm.ksize_v; kamp = prm.kamp
    rh = prm.reach_h; rv = prm.reach_v
    cell = prm.cell; skin = prm.skin; dt = prm.dt
    tx0 = prm.tab_x0; tdx = prm.tab_dx; ty0 = prm.tab_y0; tdy = prm.tab_dy
    shape = prm.shape; walls = prm.walls; steps = prm.steps
    ncx = prm.ncx; ncy = prm.ncy; ncz = prm.ncz
    use_probes = prm.probes; nbatch = prm.n_batch; ticks_total = prm.ticks_total
    cap = sx.size
    fresh, keep_p = persistence(gamma)
    n_rec = rec_ticks.size
    npart = px.size
    maxmoved = 0.0
    for i in range(npart):
        if moved[i] > maxmoved:
            maxmoved = moved[i]

    done = 0
    while done < n_ticks:
        tick = cnt[C_TICK]
        t_mid = (tick + 0.5) * dt
        batch = min(tick * nbatch // max(ticks_total, 1), nbatch - 1)
        # ---- injection ----------------------------------------------------------------
        if cnt[C_PENDING] >= 0:
            n_new = cnt[C_PENDING]
        else:
            n_new = np.random.poisson(rate)
        if cnt[C_NACTIVE] + n_new > cap:
            cnt[C_PENDING] = n_new
            return done
        cnt[C_PENDING] = -1
        for k in range(n_new):
            j = cnt[C_NACTIVE]
            _inject(prm, j, sx, sy)
            sz[j] = z0
            srel[j, 0] = sx[j]
            srel[j, 1] = sy[j]
            srel[j, 2] = z0
            srel[j, 3] = 0.0
            sxi[j] = first_direction(steps)
            syi[j] = first_direction(steps)
            cnt[C_NACTIVE] += 1
        cnt[C_INJECTED] += n_new
        # ---- rebuild the cell list if someone may have left its cell --------------------
        if npart > 0 and maxmoved > 0.5 * skin:
            build_cells3(px, py, pz, status, x0, y0, z0, cell, ncx, ncy, ncz, cell_start,
                         cell_idx)
            for i in range(npart):
                moved[i] = 0.0
            maxmoved = 0.0
            cnt[C_REBUILDS] += 1
        # ---- spot steps -----------------------------------------------------------------
        j = 0
        while j < cnt[C_NACTIVE]:
            xi = next_direction(sxi[j], steps, gamma, fresh, keep_p)
            eta = next_direction(syi[j], steps, gamma, fresh, keep_p)
            ox = sx[j]; oy = sy[j]; oz = sz[j]
            nx_ = ox + sigx * xi
            ny_ = oy + sigx * eta
            nz_ = oz + step
            if sigz > 0.0:
                nz_ += sigz * np.random.standard_normal()
            remove = False
            if nx_ < x0 or nx_ > x1:
                if walls == WALLS_OPEN:
                    remove = True
                else:
                    nx_ = _mirror(nx_, x0, x1)
                    xi = -xi
            if ny_ < y0 or ny_ > y1:
                if walls == WALLS_OPEN:
                    remove = True
                else:
                    ny_ = _mirror(ny_, y0, y1)
                    eta = -eta
            if nz_ < z0:
                nz_ = 2.0 * z0 - nz_
            sxi[j] = xi
            syi[j] = eta
            dx = nx_ - ox; dy = ny_ - oy; dz = nz_ - oz
            cnt[C_STEPS] += 1
            cx_ = ox + lam * dx; cy_ = oy + lam * dy; cz_ = oz + lam * dz
            inv_phi = coverage_inverse2(cx_, cy_, tx0, tdx, ty0, tdy, phi_tab)
            # ---- particles --------------------------------------------------------------
            if npart > 0:
                ix_lo = min(max(int(math.floor((cx_ - rh - skin - x0) / cell)), 0), ncx - 1)
                ix_hi = min(max(int(math.floor((cx_ + rh + skin - x0) / cell)), 0), ncx - 1)
                iy_lo = min(max(int(math.floor((cy_ - rh - skin - y0) / cell)), 0), ncy - 1)
                iy_hi = min(max(int(math.floor((cy_ + rh + skin - y0) / cell)), 0), ncy - 1)
                iz_lo = min(max(int(math.floor((cz_ - rv - skin - z0) / cell)), 0), ncz - 1)
                iz_hi = min(max(int(math.floor((cz_ + rv + skin - z0) / cell)), 0), ncz - 1)
                for icz in range(iz_lo, iz_hi + 1):
                    for icy in range(iy_lo, iy_hi + 1):
                        row = (icz * ncy + icy) * ncx
                        for q in range(cell_start[row + ix_lo], cell_start[row + ix_hi + 1]):
                            i = cell_idx[q]
                            if status[i] != P_IN:
                                continue
                            w = kernel_w3(shape, px[i] - cx_, py[i] - cy_, pz[i] - cz_,
                                          ksize, ksizev, kamp, rh, rv)
                            if w == 0.0:
                                continue
                            w *= inv_phi
                            cnt[C_UPDATES] += 1
                            m = _place3(i, px[i], py[i], pz[i], px[i] - w * dx, py[i] - w * dy,
                                        pz[i] - w * dz, x0, x1, y0, y1, z0, walls, rp.open_lo,
                                        rp.open_hi, t_mid, px, py, pz, status, moved,
                                        track_slot, levels, lev_next, cross_x, cross_t,
                                        exit_x, exit_t)
                            if m > maxmoved:
                                maxmoved = m
            # ---- relaxation of the grains around the spot ---------------------------------
            if rp.on == 1 and npart > 0:
                ns = srel[j, 3] + 1.0
                if ns >= rp.every or remove or nz_ >= z1:
                    nb = relax_block3(x0, x1, y0, y1, z0, z1, rp, srel[j, 0], srel[j, 1],
                                      srel[j, 2], cx_, cy_, cz_, px, py, pz, diam, status,
                                      cell_start, cell_idx, cell, ncx, ncy, ncz, skin, blk, old)
                    for q in range(nb):
                        i = blk[q]
                        m = _place3(i, old[q, 0], old[q, 1], old[q, 2], px[i], py[i], pz[i],
                                    x0, x1, y0, y1, z0, walls, rp.open_lo, rp.open_hi, t_mid,
                                    px, py, pz, status, moved, track_slot, levels, lev_next,
                                    cross_x, cross_t, exit_x, exit_t)
                        if m > maxmoved:
                            maxmoved = m
                    cnt[C_RELAXATIONS] += 1
                    cnt[C_RELAXED] += nb
                    ns = 0.0
                    srel[j, 0] = nx_
                    srel[j, 1] = ny_
                    srel[j, 2] = nz_
                srel[j, 3] = ns
            if use_probes == 1:
                _probe_step(prm, probe, rho_hist, batch, ox, oy, oz, dx, dy, dz, cx_, cy_, cz_,
                            inv_phi)
            if remove or nz_ >= z1:
                last = cnt[C_NACTIVE] - 1
                sx[j] = sx[last]; sy[j] = sy[last]; sz[j] = sz[last]
                sxi[j] = sxi[last]; syi[j] = syi[last]
                for c in range(4):
                    srel[j, c] = srel[last, c]
                cnt[C_NACTIVE] = last
                cnt[C_REMOVED] += 1
                continue
            sx[j] = nx_; sy[j] = ny_; sz[j] = nz_
            j += 1
        # ---- end of tick: snapshots ---------------------------------------------------
        r = np.searchsorted(rec_ticks, tick)
        if r < n_rec and rec_ticks[r] == tick:
            for i in range(npart):
                ts = track_slot[i]
                if ts >= 0:
                    if status[i] == P_IN:
                        tpos[r, ts, 0] = px[i]
                        tpos[r, ts, 1] = pz[i]
                        tpos[r, ts, 2] = py[i]
                    else:
                        tpos[r, ts, 0] = np.nan
                        tpos[r, ts, 1] = np.nan
                        tpos[r, ts, 2] = np.nan
        cnt[C_TICK] += 1
        done += 1
    return done
