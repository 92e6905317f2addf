"""Numba kernels of the discrete spot-model Monte Carlo (private; see ``montecarlo``).

Everything here is 2D ``(x, z)``, lengths in particle diameters d, times in the case's
unit. State lives in plain arrays owned by :func:`spotpde.montecarlo.simulate`;
:func:`advance` moves it forward by whole ticks so that the Python driver can report
progress and stop between chunks. The run's constants come in one :class:`Params`
(a typed named tuple: numba compiles it as a heterogeneous tuple, read by field name).
"""

from __future__ import annotations

import math
from typing import NamedTuple, get_type_hints

import numpy as np
from numba import njit

from ._relax import relax_block


class Params(NamedTuple):
    """The constants of one run, as :func:`advance` reads them.

    Build it with :func:`make_params` (which converts every field to ``float`` or
    ``int``, so that numba compiles one signature only).

    Attributes:
        x0, x1, z0, z1: the box in d.
        xc, width: orifice centre and width in d. rate: ``Q0 dt``, mean spots per tick.
        step: vertical step Delta in d. sigx: ``sqrt(2 b0 Delta)``, sigz:
            ``sqrt(2 b_par Delta)`` (d), the horizontal and vertical step scales.
        gamma: correlation of successive horizontal steps. lam: the rule.
        ksize, ksize_v, kamp: kernel horizontal and vertical size (d), centre value.
        reach_h, reach_v: kernel support half-widths (x, z) in d.
        cell, skin: particle cell size and skin in d.
        probe_x0, probe_z0, probe_h: probe grid first centre and spacing in d.
        dt: time per tick (``Delta / v_s``).
        tab_x0, tab_dx: first node and spacing (d) of the wall coverage table.
        shape: ``SHAPE_*``. profile: ``PROFILE_*``. walls: ``WALLS_*``. steps: ``STEPS_*``.
        ncx, ncz: particle cells in x and z. pnx, pnz: probe grid points in x and z.
        n_batch: time batches. ticks_total: ticks of the whole run.
        probes: 1 to accumulate the probe fields, 0 not.
    """

    x0: float
    x1: float
    z0: float
    z1: float
    xc: float
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
    probe_x0: float
    probe_z0: float
    probe_h: float
    dt: float
    tab_x0: float
    tab_dx: float
    shape: int
    profile: int
    walls: int
    steps: int
    ncx: int
    ncz: int
    pnx: int
    pnz: int
    n_batch: int
    ticks_total: int
    probes: int


def typed(cls, name: str, values: dict):
    """A NamedTuple ``cls`` from keyword ``values``, each converted to its field's annotated
    type (``float`` or ``int``, so that numba compiles one signature only).

    Raises:
        TypeError: a field is missing or unknown (the message names ``name`` and it).
    """
    missing = [k for k in cls._fields if k not in values]
    unknown = [k for k in values if k not in cls._fields]
    if missing or unknown:
        raise TypeError(f"{name}: missing {missing}, unknown {unknown}")
    types = get_type_hints(cls)
    return cls(**{k: types[k](values[k]) for k in cls._fields})


def make_params(**values) -> Params:
    """A :class:`Params` from keyword values, each converted to its field's type.

    Raises:
        TypeError: a field is missing or unknown (the message names it).
    """
    return typed(Params, "make_params", values)


# -- kernel shapes, orifice profiles, walls, step kinds -------------------------------------
SHAPE_UNIFORM, SHAPE_GAUSSIAN, SHAPE_EXPONENTIAL = 0, 1, 2
PROFILE_POINT, PROFILE_UNIFORM, PROFILE_GAUSSIAN = 0, 1, 2
WALLS_REFLECTING, WALLS_OPEN = 0, 1
STEPS_GAUSSIAN, STEPS_BINARY = 0, 1
# -- counters (int64 array ``cnt``) ---------------------------------------------------------
C_TICK, C_INJECTED, C_STEPS, C_UPDATES, C_NACTIVE, C_PENDING, C_REBUILDS, C_REMOVED = range(8)
C_RELAXATIONS, C_RELAXED = 8, 9  # relaxations done, grains relaxed (summed)
NC = 10
# -- particle status ------------------------------------------------------------------------
P_IN, P_ORIFICE, P_SIDE = 0, 1, 2


@njit(cache=True)
def seed(s):
    """Seed numba's generator (legacy ``np.random`` inside nopython code)."""
    np.random.seed(s)


@njit(cache=True, inline="always")
def kernel_w(shape, dx, dz, size, size_v, amp, reach_h, reach_v):
    """Influence ``w`` at offset ``(dx, dz)`` (d) from the spot centre.

    Uniform: ``amp`` inside the ellipse ``(dx/size)^2 + (dz/size_v)^2 < 1``.
    Gaussian: ``amp exp(-(dx/size)^2/2 - (dz/size_v)^2/2)``.
    Exponential: ``amp exp(-sqrt((dx/size)^2 + (dz/size_v)^2))``.
    Gaussian and exponential are cut off outside the ellipse of half-axes ``reach``.
    """
    if abs(dx) > reach_h or abs(dz) > reach_v:
        return 0.0
    if shape == SHAPE_UNIFORM:
        q = (dx / size) ** 2 + (dz / size_v) ** 2
        return amp if q < 1.0 else 0.0
    if (dx / reach_h) ** 2 + (dz / reach_v) ** 2 > 1.0:
        return 0.0
    if shape == SHAPE_GAUSSIAN:
        return amp * math.exp(-0.5 * ((dx / size) ** 2 + (dz / size_v) ** 2))
    return amp * math.exp(-math.sqrt((dx / size) ** 2 + (dz / size_v) ** 2))


@njit(cache=True)
def kernel_eval(shape, x, z, size, size_v, amp, reach_h, reach_v):
    """Vectorised :func:`kernel_w` over arrays ``x``, ``z`` (for tests)."""
    out = np.empty(x.size)
    xf = x.ravel()
    zf = z.ravel()
    for i in range(xf.size):
        out[i] = kernel_w(shape, xf[i], zf[i], size, size_v, amp, reach_h, reach_v)
    return out


@njit(cache=True)
def build_cells(px, pz, status, x0, z0, cell, ncx, ncz, cell_start, cell_idx):
    """Counting sort of the particles still in the box into cells of size ``cell``.

    Particles outside the cell range are clamped into the edge cells (queries clamp the
    same way, so nobody within reach is missed).
    """
    n = px.size
    cid = np.empty(n, np.int64)
    for i in range(n):
        if status[i] != P_IN:
            cid[i] = -1
            continue
        cx = int(math.floor((px[i] - x0) / cell))
        cz = int(math.floor((pz[i] - z0) / cell))
        cx = min(max(cx, 0), ncx - 1)
        cz = min(max(cz, 0), ncz - 1)
        cid[i] = cz * ncx + cx
    sort_into_cells(cid, ncx * ncz, cell_start, cell_idx)


@njit(cache=True)
def sort_into_cells(cid, ncell, cell_start, cell_idx):
    """Counting sort by cell: particle ``i`` in cell ``cid[i]`` (``-1``: not in the box)
    goes to ``cell_idx[cell_start[c]:cell_start[c + 1]]``, in particle order. Shared by
    the 2D, 3D and hopper/cylinder cell lists, which differ only in how they number cells."""
    for c in range(ncell + 1):
        cell_start[c] = 0
    for i in range(cid.size):
        if cid[i] >= 0:
            cell_start[cid[i] + 1] += 1
    for c in range(ncell):
        cell_start[c + 1] += cell_start[c]
    fill = cell_start[:ncell].copy()
    for i in range(cid.size):
        c = cid[i]
        if c >= 0:
            cell_idx[fill[c]] = i
            fill[c] += 1


@njit(cache=True, inline="always")
def persistence(gamma):
    """``(fresh, keep)`` of the horizontal step rule with step correlation ``gamma``.

    ``fresh = sqrt(1 - gamma^2)``: the weight of the new normal in the AR(1) (Gaussian)
    rule; ``keep = (1 + gamma)/2``: the binary walk's probability of keeping its sign (its
    successive steps then correlate by ``2 keep - 1 = gamma``). Either way the long-distance
    diffusion length is ``b = b0 (1 + gamma)/(1 - gamma)`` (docs/montecarlo.md section 2).
    """
    return math.sqrt(1.0 - gamma * gamma), 0.5 * (1.0 + gamma)


@njit(cache=True, inline="always")
def first_direction(steps):
    """Stationary unit step variable of a new walk: ``N(0, 1)`` or ``+-1``."""
    if steps == STEPS_GAUSSIAN:
        return np.random.standard_normal()
    return 1.0 if np.random.random() < 0.5 else -1.0


@njit(cache=True, inline="always")
def next_direction(xi, steps, gamma, fresh, keep):
    """The next unit step variable: ``gamma xi + fresh eta`` (Gaussian, ``eta ~ N(0, 1)``)
    or ``xi`` kept with probability ``keep``, else ``-xi`` (binary); see :func:`persistence`.
    :func:`advance` and :func:`spot_walks` both step by this rule."""
    if steps == STEPS_GAUSSIAN:
        return gamma * xi + fresh * np.random.standard_normal()
    return xi if np.random.random() < keep else -xi


@njit(cache=True, inline="always")
def coverage_inverse(x, tab_x0, tab_dx, phi_tab):
    """``1 / phi(x)`` from the coverage table ``phi_tab`` at ``tab_x0 + k tab_dx`` (d).

    Linear interpolation of ``phi`` between the two nodes around ``x`` (clamped to the
    table's ends; error ``<= tab_dx^2 max|phi''| / 8``); 1 for a table of length 0 or 1
    (no renormalisation).
    """
    n = phi_tab.size
    if n <= 1:
        return 1.0
    tt = (x - tab_x0) / tab_dx
    kt = min(max(int(math.floor(tt)), 0), n - 2)
    ft = min(max(tt - kt, 0.0), 1.0)
    return 1.0 / ((1.0 - ft) * phi_tab[kt] + ft * phi_tab[kt + 1])


@njit(cache=True)
def coverage_inverse_eval(x, tab_x0, tab_dx, phi_tab):
    """Vectorised :func:`coverage_inverse` over the array ``x`` (for tests)."""
    out = np.empty(x.size)
    xf = x.ravel()
    for i in range(xf.size):
        out[i] = coverage_inverse(xf[i], tab_x0, tab_dx, phi_tab)
    return out


@njit(cache=True, inline="always")
def _place(i, oxp, ozp, npx, npz, x0, x1, z0, walls, open_lo, open_hi, t_mid,
           px, pz, status, moved, track_slot, levels, lev_next, cross_x, cross_t,
           exit_x, exit_t):
    """Move particle ``i`` from ``(oxp, ozp)`` to ``(npx, npz)``: mirror it at reflecting
    walls or let it leave through open ones, record its level crossings (tracked) and
    its exit through the floor's opening ``open_lo < x < open_hi`` (the whole floor
    without relaxation). Returns its distance moved since the last binning (0 if it left
    sideways)."""
    if npx < x0 or npx > x1:
        if walls == WALLS_OPEN:
            status[i] = P_SIDE
            px[i] = npx
            pz[i] = npz
            return 0.0
        if npx < x0:
            npx = 2.0 * x0 - npx
        if npx > x1:
            npx = 2.0 * x1 - npx
        npx = min(max(npx, x0), x1)
    m = moved[i] + abs(npx - oxp) + abs(npz - ozp)
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
        xe = npx  # a grain already below the floor (beside the opening) leaves where it is
        if ozp >= z0:
            xe = oxp + (ozp - z0) / (ozp - npz) * (npx - oxp)
        if open_lo < xe < open_hi:
            status[i] = P_ORIFICE
            exit_x[i] = xe
            exit_t[i] = t_mid
    px[i] = npx
    pz[i] = npz
    return m


@njit(cache=True)
def _inject_x(profile, xc, width):
    if profile == PROFILE_POINT:
        return xc
    if profile == PROFILE_UNIFORM:
        return xc + width * (np.random.random() - 0.5)
    return xc + 0.5 * width * np.random.standard_normal()


@njit(cache=True)
def advance(prm, cnt, n_ticks,
            sx, sz, sxi,
            px, pz, status, moved, cell_start, cell_idx,
            track_slot, tpos, rec_ticks, levels, lev_next, cross_x, cross_t, exit_x, exit_t,
            probe, rho_hist, phi_tab, rp, diam, srel, blk, old):
    """Advance the simulation by at most ``n_ticks`` ticks.

    Each tick (duration ``dt = Delta / v_s``): inject ``Poisson(Q0 dt)`` spots on the floor,
    then every active spot makes one step ``dR = (dx, dz)``; each particle within reach of
    ``r_s + lam dR`` moves by ``-w(r_p - r_s - lam dR) dR / phi(x_s + lam dx)`` (eq.
    discrete, general rule; ``phi`` the fraction of the kernel inside the walls, from
    ``phi_tab``, 1 without).
    Returns early (with ``cnt[C_PENDING]`` set) when the spot arrays are full.

    Args:
        prm: the run's constants (:class:`Params`). cnt: counters (updated in place).
        sx, sz, sxi: spot positions and persistent unit step variable.
        px, pz, status, moved: particle positions, status, displacement since binning.
        cell_start, cell_idx: particle cell list.
        track_slot: per particle, its tracked index or -1. tpos: (n_rec, n_tracked, 2)
            snapshots taken at the end of the ticks listed in ``rec_ticks`` (sorted).
        levels, lev_next, cross_x, cross_t: crossing heights (ascending), per tracked
            particle the index of the next level below, and the crossing x / time.
        exit_x, exit_t: where/when each particle left through the orifice.
        probe: (5, n_batch, pnz, pnx) sums of u_x dt, u_z dt, and the step covariance
            products w^2 (dR - <dR>)(dR - <dR>)^T for D_xx, D_xz, D_zz.
        rho_hist: (n_batch, pnz, pnx) spot-count histogram (one sample per spot per tick).
        phi_tab: kernel coverage ``phi`` at ``x = tab_x0 + k tab_dx`` (linear
            interpolation; ``walls = "renormalise"``), or a length-0/1 array: ``phi = 1``.
        rp: ``_relax.RelaxParams`` (``rp.on = 0``: no relaxation, the floor is open
            everywhere). diam: grain diameters. srel: per spot, the start ``(x, z)`` of
            the segment not yet relaxed and the steps since. blk, old: scratch of
            ``_relax.relax_block`` (size: all particles).
        After a spot's step (every ``rp.every``-th, and its last), the grains near it are
        relaxed (``_relax.relax_block``) and moved as by the step itself (``_place``).

    Returns:
        Number of ticks done.
    """
    x0 = prm.x0; x1 = prm.x1; z0 = prm.z0; z1 = prm.z1
    xc = prm.xc; width = prm.width; rate = prm.rate
    step = prm.step; sigx = prm.sigx; sigz = prm.sigz; gamma = prm.gamma
    lam = prm.lam
    ksize = prm.ksize; ksizev = prm.ksize_v; kamp = prm.kamp
    rh = prm.reach_h; rv = prm.reach_v
    cell = prm.cell; skin = prm.skin
    pxo = prm.probe_x0; pzo = prm.probe_z0; ph = prm.probe_h
    dt = prm.dt
    tx0 = prm.tab_x0; tdx = prm.tab_dx
    shape = prm.shape; profile = prm.profile; walls = prm.walls; steps = prm.steps
    ncx = prm.ncx; ncz = prm.ncz; pnx = prm.pnx; pnz = prm.pnz
    nbatch = prm.n_batch; ticks_total = prm.ticks_total; use_probes = prm.probes
    cap = sx.size
    fresh, keep_p = persistence(gamma)
    n_rec = rec_ticks.size
    n_levels = levels.size
    npart = px.size
    ex = np.empty(max(pnx, 1))
    ez = np.empty(max(pnz, 1))
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
            sx[j] = _inject_x(profile, xc, width)
            sz[j] = z0
            srel[j, 0] = sx[j]
            srel[j, 1] = z0
            srel[j, 2] = 0.0
            sxi[j] = first_direction(steps)
            cnt[C_NACTIVE] += 1
        cnt[C_INJECTED] += n_new
        # ---- rebuild the particle cell list if someone may have left its cell -----------
        if npart > 0 and maxmoved > 0.5 * skin:
            build_cells(px, pz, status, x0, z0, cell, ncx, ncz, cell_start, cell_idx)
            for i in range(npart):
                moved[i] = 0.0
            maxmoved = 0.0
            cnt[C_REBUILDS] += 1
        # ---- spot steps -----------------------------------------------------------------
        j = 0
        while j < cnt[C_NACTIVE]:
            # horizontal step: AR(1) (Gaussian) or persistent +-1 (binary), unit variance
            xi = next_direction(sxi[j], steps, gamma, fresh, keep_p)
            ox = sx[j]
            oz = sz[j]
            nx_ = ox + sigx * xi
            nz_ = oz + step
            if sigz > 0.0:
                nz_ += sigz * np.random.standard_normal()
            remove = False
            if nx_ < x0 or nx_ > x1:
                if walls == WALLS_OPEN:
                    remove = True
                else:
                    # reflect; the persistent direction turns around with the walk
                    if nx_ < x0:
                        nx_ = 2.0 * x0 - nx_
                    if nx_ > x1:
                        nx_ = 2.0 * x1 - nx_
                    nx_ = min(max(nx_, x0), x1)
                    xi = -xi
            if nz_ < z0:
                nz_ = 2.0 * z0 - nz_
            sxi[j] = xi
            dx = nx_ - ox
            dz = nz_ - oz
            cnt[C_STEPS] += 1
            # centre at which the influence is evaluated
            cx_ = ox + lam * dx
            cz_ = oz + lam * dz
            # free-volume-conserving walls: influence divided by the kernel's coverage
            inv_phi = coverage_inverse(cx_, tx0, tdx, phi_tab)
            # ---- particles --------------------------------------------------------------
            if npart > 0:
                ix_lo = int(math.floor((cx_ - rh - skin - x0) / cell))
                ix_hi = int(math.floor((cx_ + rh + skin - x0) / cell))
                iz_lo = int(math.floor((cz_ - rv - skin - z0) / cell))
                iz_hi = int(math.floor((cz_ + rv + skin - z0) / cell))
                ix_lo = min(max(ix_lo, 0), ncx - 1)
                ix_hi = min(max(ix_hi, 0), ncx - 1)
                iz_lo = min(max(iz_lo, 0), ncz - 1)
                iz_hi = min(max(iz_hi, 0), ncz - 1)
                for icz in range(iz_lo, iz_hi + 1):
                    for icx in range(ix_lo, ix_hi + 1):
                        c = icz * ncx + icx
                        for q in range(cell_start[c], cell_start[c + 1]):
                            i = cell_idx[q]
                            if status[i] != P_IN:
                                continue
                            w = kernel_w(shape, px[i] - cx_, pz[i] - cz_, ksize, ksizev, kamp, rh, rv)
                            if w == 0.0:
                                continue
                            w *= inv_phi
                            cnt[C_UPDATES] += 1
                            m = _place(i, px[i], pz[i], px[i] - w * dx, pz[i] - w * dz,
                                       x0, x1, z0, walls, rp.open_lo, rp.open_hi, t_mid,
                                       px, pz, status, moved, track_slot, levels, lev_next,
                                       cross_x, cross_t, exit_x, exit_t)
                            if m > maxmoved:
                                maxmoved = m
            # ---- relaxation of the grains around the spot (packing constraints) -------
            if rp.on == 1 and npart > 0:
                ns = srel[j, 2] + 1.0
                if ns >= rp.every or remove or nz_ >= z1:
                    nb = relax_block(x0, x1, z0, z1, rp, srel[j, 0], srel[j, 1], cx_, cz_,
                                     px, pz, diam, status, cell_start, cell_idx, cell, ncx,
                                     ncz, skin, blk, old)
                    for q in range(nb):
                        i = blk[q]
                        m = _place(i, old[q, 0], old[q, 1], px[i], pz[i], x0, x1, z0, walls,
                                   rp.open_lo, rp.open_hi, t_mid, px, pz, status, moved,
                                   track_slot, levels, lev_next, cross_x, cross_t, exit_x,
                                   exit_t)
                        if m > maxmoved:
                            maxmoved = m
                    cnt[C_RELAXATIONS] += 1
                    cnt[C_RELAXED] += nb
                    ns = 0.0
                    srel[j, 0] = nx_
                    srel[j, 1] = nz_
                srel[j, 2] = ns
            # ---- probes (frozen particles on the measurement grid) ------------------------
            if use_probes:
                jx_lo = max(int(math.ceil((cx_ - rh - pxo) / ph)), 0)
                jx_hi = min(int(math.floor((cx_ + rh - pxo) / ph)), pnx - 1)
                jz_lo = max(int(math.ceil((cz_ - rv - pzo) / ph)), 0)
                jz_hi = min(int(math.floor((cz_ + rv - pzo) / ph)), pnz - 1)
                ddz = dz - step
                if shape == SHAPE_GAUSSIAN:  # separable: 1D factors once per step
                    for jx in range(jx_lo, jx_hi + 1):
                        ex[jx] = math.exp(-0.5 * ((pxo + jx * ph - cx_) / ksize) ** 2)
                    for jz in range(jz_lo, jz_hi + 1):
                        ez[jz] = kamp * math.exp(-0.5 * ((pzo + jz * ph - cz_) / ksizev) ** 2)
                for jz in range(jz_lo, jz_hi + 1):
                    zz = pzo + jz * ph - cz_
                    for jx in range(jx_lo, jx_hi + 1):
                        if shape == SHAPE_GAUSSIAN:
                            xx = pxo + jx * ph - cx_
                            if (xx / rh) ** 2 + (zz / rv) ** 2 > 1.0:
                                continue
                            w = ex[jx] * ez[jz]
                        else:
                            w = kernel_w(shape, pxo + jx * ph - cx_, zz, ksize, ksizev, kamp, rh, rv)
                        if w == 0.0:
                            continue
                        w *= inv_phi
                        probe[0, batch, jz, jx] -= w * dx
                        probe[1, batch, jz, jx] -= w * dz
                        w2 = w * w
                        probe[2, batch, jz, jx] += w2 * dx * dx
                        probe[3, batch, jz, jx] += w2 * dx * ddz
                        probe[4, batch, jz, jx] += w2 * ddz * ddz
                # spot density sample at a uniformly random point of the step
                u = np.random.random()
                hx = int(math.floor((ox + u * dx - pxo) / ph + 0.5))
                hz = int(math.floor((oz + u * dz - pzo) / ph + 0.5))
                if 0 <= hx < pnx and 0 <= hz < pnz:
                    rho_hist[batch, hz, hx] += 1.0
            if remove or nz_ >= z1:
                # swap-remove spot j (the swapped-in spot is stepped next)
                last = cnt[C_NACTIVE] - 1
                sx[j] = sx[last]
                sz[j] = sz[last]
                sxi[j] = sxi[last]
                srel[j, 0] = srel[last, 0]
                srel[j, 1] = srel[last, 1]
                srel[j, 2] = srel[last, 2]
                cnt[C_NACTIVE] = last
                cnt[C_REMOVED] += 1
                continue
            sx[j] = nx_
            sz[j] = nz_
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
                        else:
                            tpos[r, ts, 0] = np.nan
                            tpos[r, ts, 1] = np.nan
        cnt[C_TICK] += 1
        done += 1
    return done


@njit(cache=True)
def spot_walks(n_walks, n_steps, sig, gamma, steps, seed_):
    """Horizontal positions of ``n_walks`` free spot walks after each of ``n_steps`` steps.

    The step rule of :func:`advance` (no walls; :func:`first_direction`,
    :func:`next_direction`): ``xi_{n+1} = gamma xi_n + sqrt(1 - gamma^2) eta`` (Gaussian)
    or keep the sign with probability ``(1+gamma)/2`` (binary); step ``sig * xi``;
    ``xi_0`` stationary.
    """
    np.random.seed(seed_)
    out = np.empty((n_walks, n_steps))
    fresh, keep_p = persistence(gamma)
    for k in range(n_walks):
        xi = first_direction(steps)
        x = 0.0
        for n in range(n_steps):
            xi = next_direction(xi, steps, gamma, fresh, keep_p)
            x += sig * xi
            out[k, n] = x
    return out
