"""Numba loop of the Monte Carlo in hoppers and cylinders (private; see ``_geometry``).

One loop serves two geometries, both "material within a horizontal distance ``W(z)`` of
an axis": the 2D wedge hopper (``cyl = 0``: positions ``(x, z)``, distance
``|x - xc|``, the box's side walls too) and the 3D cylindrical silo, optionally with a
conical hopper (``cyl = 1``: positions ``(x, y, z)``, distance ``r = sqrt(x^2 + y^2)``).
``W(z) = min(hw + slope (z - z0), wmax)``. Lengths in d, times in the case's unit.

Walls (docs/montecarlo.md, "Hoppers and cylinders"): a spot or particle that a step
takes beyond ``W(z)`` at its new height is mirrored horizontally (``rho -> 2 W - rho``,
along the radius in 3D) and, for a spot, its persistent step variable is reflected (its
component along the wall's horizontal normal changes sign), exactly as at the box's
reflecting walls. Every particle below the floor has left through the orifice (the
hopper's floor is the orifice; the cylinder's whole floor is open as in the box).
Particles are kept in a cell list rebuilt every tick; the probes in a fixed one.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ._mc3d import kernel_w3
from ._mc_kernels import (C_INJECTED, C_NACTIVE, C_PENDING, C_REBUILDS, C_REMOVED, C_STEPS,
                          C_TICK, C_UPDATES, P_IN, P_ORIFICE, PROFILE_POINT, PROFILE_UNIFORM,
                          first_direction, kernel_w, next_direction, persistence,
                          sort_into_cells, typed)


class GeomParams(NamedTuple):
    """Constants of one run (see the module docstring; lengths in d).

    Attributes:
        cyl: 0 the 2D wedge (x, z), 1 the 3D cylinder (x, y, z).
        xc: axis (2D: the hopper's centre; 3D: 0). hw, slope, wmax: ``W(z)``.
        x0, x1: 2D box side walls (3D: ``-wmax, wmax``). z0, z1: floor and top.
        ow: orifice half-width (radius). rate: ``Q0 dt``. step, sigx, sigz, gamma, lam:
            as ``_mc_kernels.Params``. ksize, ksize_v, kamp, reach_h, reach_v: kernel.
        cell: cell-list cell size; ncx, ncy, ncz: cells (``ncy = 1`` in 2D).
        tab_x0, tab_z0, tab_h, tnx, tnz: the coverage table's first node and spacing
            (the grid's cell centres; ``tnx = 0``: no renormalisation).
        shape, profile, steps: codes of ``_mc_kernels``. nbin: probe bins (grid cells);
        n_batch, ticks_total: time batches and ticks of the run.
    """

    cyl: int
    xc: float
    hw: float
    slope: float
    wmax: float
    x0: float
    x1: float
    z0: float
    z1: float
    ow: float
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
    ncx: int
    ncy: int
    ncz: int
    tab_x0: float
    tab_z0: float
    tab_h: float
    tnx: int
    tnz: int
    shape: int
    profile: int
    steps: int
    nbin: int
    n_batch: int
    ticks_total: int


def make_geom_params(**values) -> GeomParams:
    """A :class:`GeomParams` from keyword values (each converted to its field's type)."""
    return typed(GeomParams, "make_geom_params", values)


@njit(cache=True, inline="always")
def wall_w(prm, z):
    """``W(z)``: the material's half-width (radius) at height ``z`` (d)."""
    return min(prm.hw + prm.slope * (z - prm.z0), prm.wmax)


@njit(cache=True)
def confine(prm, x, y, z):
    """Mirror ``(x, y)`` horizontally into the material at height ``z``.

    Returns ``(x, y, nx, ny, hit)``: the new position, the horizontal unit normal of the
    last wall hit (pointing inward) and whether any wall was hit."""
    hit = False
    nxw = 0.0
    nyw = 0.0
    for _ in range(8):
        W = wall_w(prm, z)
        if prm.cyl == 1:
            r = math.sqrt(x * x + y * y)
            if r <= W:
                break
            f = (2.0 * W - r) / r
            nxw = -x / r
            nyw = -y / r
            x *= f
            y *= f
            hit = True
        else:
            d = x - prm.xc
            moved = False
            if abs(d) > W:
                s = 1.0 if d > 0.0 else -1.0
                x = prm.xc + s * (2.0 * W - abs(d))
                nxw = -s
                moved = True
            if x < prm.x0:
                x = 2.0 * prm.x0 - x
                nxw = 1.0
                moved = True
            elif x > prm.x1:
                x = 2.0 * prm.x1 - x
                nxw = -1.0
                moved = True
            if not moved:
                break
            hit = True
    # pathological overshoots (many wall widths): clamp onto the wall
    W = wall_w(prm, z)
    if prm.cyl == 1:
        r = math.sqrt(x * x + y * y)
        if r > W:
            x *= W / r
            y *= W / r
    else:
        x = min(max(x, prm.xc - W, prm.x0), prm.xc + W, prm.x1)
    return x, y, nxw, nyw, hit


@njit(cache=True, inline="always")
def inv_coverage(prm, phi_tab, s, z):
    """``1 / phi`` at horizontal coordinate ``s`` (x, or r) and height ``z``: bilinear
    interpolation in ``phi_tab[k_z, k_x]`` on the grid's cell centres, clamped to its
    ends; 1 without a table."""
    if prm.tnx == 0:
        return 1.0
    tx = (s - prm.tab_x0) / prm.tab_h
    tz = (z - prm.tab_z0) / prm.tab_h
    kx = min(max(int(math.floor(tx)), 0), prm.tnx - 2)
    kz = min(max(int(math.floor(tz)), 0), prm.tnz - 2)
    fx = min(max(tx - kx, 0.0), 1.0)
    fz = min(max(tz - kz, 0.0), 1.0)
    p = ((1.0 - fz) * ((1.0 - fx) * phi_tab[kz, kx] + fx * phi_tab[kz, kx + 1])
         + fz * ((1.0 - fx) * phi_tab[kz + 1, kx] + fx * phi_tab[kz + 1, kx + 1]))
    return 1.0 / max(p, 1e-3)


@njit(cache=True)
def build_cells(prm, px, py, pz, status, cell_start, cell_idx):
    """Counting sort of the points with ``status == P_IN`` into the cell list."""
    n = px.size
    cid = np.empty(n, np.int64)
    for i in range(n):
        cid[i] = _cell_of(prm, px[i], py[i], pz[i]) if status[i] == P_IN else -1
    sort_into_cells(cid, prm.ncx * prm.ncy * prm.ncz, cell_start, cell_idx)


@njit(cache=True, inline="always")
def _cell_of(prm, x, y, z):
    ix = min(max(int(math.floor((x - prm.x0) / prm.cell)), 0), prm.ncx - 1)
    iy = 0
    if prm.cyl == 1:
        iy = min(max(int(math.floor((y - prm.x0) / prm.cell)), 0), prm.ncy - 1)
    iz = min(max(int(math.floor((z - prm.z0) / prm.cell)), 0), prm.ncz - 1)
    return (iz * prm.ncy + iy) * prm.ncx + ix


@njit(cache=True, inline="always")
def _w(prm, dx, dy, dz):
    if prm.cyl == 1:
        return kernel_w3(prm.shape, dx, dy, dz, prm.ksize, prm.ksize_v, prm.kamp,
                         prm.reach_h, prm.reach_v)
    return kernel_w(prm.shape, dx, dz, prm.ksize, prm.ksize_v, prm.kamp, prm.reach_h,
                    prm.reach_v)


@njit(cache=True)
def advance_geom(prm, cnt, n_ticks, sx, sy, sz, sxi, syi, px, py, pz, status, exit_s,
                 exit_t, cell_start, cell_idx, qx, qy, qz, qbin, qcell_start, qcell_idx,
                 track_slot, tpos, rec_ticks, probe, rho_hist, phi_tab):
    """Advance by at most ``n_ticks`` ticks (``_mc_kernels.advance`` in the walls of
    the module docstring; returns early with ``cnt[C_PENDING]`` set when the spot arrays
    are full).

    Args:
        sx, sy, sz, sxi, syi: spot positions and persistent unit step variables (``y``
            unused in 2D). px, py, pz, status, exit_s, exit_t: particles (``exit_s``: the
            horizontal distance from the axis where each left). cell_start, cell_idx:
            particle cell list (rebuilt every tick).
        qx, qy, qz, qbin, qcell_start, qcell_idx: probes (frozen points) with the bin
            (flat grid cell) each accumulates into, and their fixed cell list.
        track_slot, tpos, rec_ticks: snapshots of tracked particles (``tpos[r, slot]`` =
            ``(x, z)`` or ``(x, z, y)``).
        probe: ``(5, n_batch, nbin)`` sums over probes of ``-w ds``, ``-w dz``,
            ``w^2 ds ds``, ``w^2 ds (dz - Delta)``, ``w^2 (dz - Delta)^2``, ``ds`` the
            step's component along the probe's outward horizontal direction (x in 2D,
            the probe's radial direction in 3D).
        rho_hist: ``(n_batch, nbin)`` spot samples (one per spot per tick, at a random
            point of its step). phi_tab: coverage table (see :func:`inv_coverage`).

    Returns:
        Number of ticks done.
    """
    cyl = prm.cyl
    cap = sx.size
    fresh, keep_p = persistence(prm.gamma)
    rh = prm.reach_h
    rv = prm.reach_v
    cell = prm.cell
    h = prm.tab_h
    n_rec = rec_ticks.size
    npart = px.size
    nq = qx.size
    done = 0
    while done < n_ticks:
        tick = cnt[C_TICK]
        batch = min(tick * prm.n_batch // max(prm.ticks_total, 1), prm.n_batch - 1)
        if cnt[C_PENDING] >= 0:
            n_new = cnt[C_PENDING]
        else:
            n_new = np.random.poisson(prm.rate)
        if cnt[C_NACTIVE] + n_new > cap:
            cnt[C_PENDING] = n_new
            return done
        cnt[C_PENDING] = -1
        for k in range(n_new):
            j = cnt[C_NACTIVE]
            x = prm.xc
            y = 0.0
            if prm.profile != PROFILE_POINT:
                if cyl == 1:   # uniform over the disk (Gaussian: sd ow in x and y, as _mc3d)
                    if prm.profile == PROFILE_UNIFORM:
                        rr = prm.ow * math.sqrt(np.random.random())
                        th = 2.0 * math.pi * np.random.random()
                        x = rr * math.cos(th)
                        y = rr * math.sin(th)
                    else:
                        x = prm.ow * np.random.standard_normal()
                        y = prm.ow * np.random.standard_normal()
                elif prm.profile == PROFILE_UNIFORM:
                    x = prm.xc + 2.0 * prm.ow * (np.random.random() - 0.5)
                else:
                    x = prm.xc + prm.ow * np.random.standard_normal()
                x, y, _a, _b, _c = confine(prm, x, y, prm.z0)
            sx[j] = x
            sy[j] = y
            sz[j] = prm.z0
            sxi[j] = first_direction(prm.steps)
            syi[j] = first_direction(prm.steps) if cyl == 1 else 0.0
            cnt[C_NACTIVE] += 1
        cnt[C_INJECTED] += n_new
        if npart > 0:
            build_cells(prm, px, py, pz, status, cell_start, cell_idx)
            cnt[C_REBUILDS] += 1
        j = 0
        while j < cnt[C_NACTIVE]:
            xi = next_direction(sxi[j], prm.steps, prm.gamma, fresh, keep_p)
            yi = next_direction(syi[j], prm.steps, prm.gamma, fresh, keep_p) if cyl == 1 else 0.0
            ox = sx[j]
            oy = sy[j]
            oz = sz[j]
            nz_ = oz + prm.step
            if prm.sigz > 0.0:
                nz_ += prm.sigz * np.random.standard_normal()
            if nz_ < prm.z0:
                nz_ = 2.0 * prm.z0 - nz_
            nx_, ny_, wnx, wny, hit = confine(prm, ox + prm.sigx * xi, oy + prm.sigx * yi, nz_)
            if hit:  # the persistent direction turns around with the walk
                if cyl == 1:
                    dot = xi * wnx + yi * wny
                    if dot < 0.0:
                        xi -= 2.0 * dot * wnx
                        yi -= 2.0 * dot * wny
                else:
                    xi = -xi
            sxi[j] = xi
            syi[j] = yi
            dx = nx_ - ox
            dy = ny_ - oy
            dz = nz_ - oz
            cnt[C_STEPS] += 1
            cx_ = ox + prm.lam * dx
            cy_ = oy + prm.lam * dy
            cz_ = oz + prm.lam * dz
            s_c = math.sqrt(cx_ * cx_ + cy_ * cy_) if cyl == 1 else cx_
            inv_phi = inv_coverage(prm, phi_tab, s_c, cz_)
            # ---- particles and probes near the spot ---------------------------------
            ix_lo = min(max(int(math.floor((cx_ - rh - prm.x0) / cell)), 0), prm.ncx - 1)
            ix_hi = min(max(int(math.floor((cx_ + rh - prm.x0) / cell)), 0), prm.ncx - 1)
            iy_lo = 0
            iy_hi = 0
            if cyl == 1:
                iy_lo = min(max(int(math.floor((cy_ - rh - prm.x0) / cell)), 0), prm.ncy - 1)
                iy_hi = min(max(int(math.floor((cy_ + rh - prm.x0) / cell)), 0), prm.ncy - 1)
            iz_lo = min(max(int(math.floor((cz_ - rv - prm.z0) / cell)), 0), prm.ncz - 1)
            iz_hi = min(max(int(math.floor((cz_ + rv - prm.z0) / cell)), 0), prm.ncz - 1)
            ddz = dz - prm.step
            for icz in range(iz_lo, iz_hi + 1):
                for icy in range(iy_lo, iy_hi + 1):
                    for icx in range(ix_lo, ix_hi + 1):
                        c = (icz * prm.ncy + icy) * prm.ncx + icx
                        if npart > 0:
                            for q in range(cell_start[c], cell_start[c + 1]):
                                i = cell_idx[q]
                                if status[i] != P_IN:
                                    continue
                                w = _w(prm, px[i] - cx_, py[i] - cy_, pz[i] - cz_)
                                if w == 0.0:
                                    continue
                                w *= inv_phi
                                cnt[C_UPDATES] += 1
                                _move(prm, i, px, py, pz, status, exit_s, exit_t,
                                      px[i] - w * dx, py[i] - w * dy, pz[i] - w * dz, tick)
                        if nq > 0:
                            for q in range(qcell_start[c], qcell_start[c + 1]):
                                i = qcell_idx[q]
                                w = _w(prm, qx[i] - cx_, qy[i] - cy_, qz[i] - cz_)
                                if w == 0.0:
                                    continue
                                w *= inv_phi
                                ds = dx
                                if cyl == 1:
                                    rq = math.sqrt(qx[i] * qx[i] + qy[i] * qy[i])
                                    ds = (dx * qx[i] + dy * qy[i]) / rq
                                b = qbin[i]
                                probe[0, batch, b] -= w * ds
                                probe[1, batch, b] -= w * dz
                                w2 = w * w
                                probe[2, batch, b] += w2 * ds * ds
                                probe[3, batch, b] += w2 * ds * ddz
                                probe[4, batch, b] += w2 * ddz * ddz
            # spot density sample at a uniformly random point of the step
            u = np.random.random()
            hx_ = ox + u * dx
            hy_ = oy + u * dy
            s_h = math.sqrt(hx_ * hx_ + hy_ * hy_) if cyl == 1 else hx_
            jx = int(math.floor((s_h - prm.tab_x0) / h + 0.5))
            jz = int(math.floor((oz + u * dz - prm.tab_z0) / h + 0.5))
            nbx = prm.nbin // prm.tnz
            if 0 <= jx < nbx and 0 <= jz < prm.tnz:
                rho_hist[batch, jz * nbx + jx] += 1.0
            if nz_ >= prm.z1:
                last = cnt[C_NACTIVE] - 1
                sx[j] = sx[last]
                sy[j] = sy[last]
                sz[j] = sz[last]
                sxi[j] = sxi[last]
                syi[j] = syi[last]
                cnt[C_NACTIVE] = last
                cnt[C_REMOVED] += 1
                continue
            sx[j] = nx_
            sy[j] = ny_
            sz[j] = nz_
            j += 1
        r = np.searchsorted(rec_ticks, tick)
        if r < n_rec and rec_ticks[r] == tick:
            for i in range(npart):
                ts = track_slot[i]
                if ts >= 0:
                    ok = status[i] == P_IN
                    tpos[r, ts, 0] = px[i] if ok else np.nan
                    tpos[r, ts, 1] = pz[i] if ok else np.nan
                    if cyl == 1:
                        tpos[r, ts, 2] = py[i] if ok else np.nan
        cnt[C_TICK] += 1
        done += 1
    return done


@njit(cache=True, inline="always")
def _move(prm, i, px, py, pz, status, exit_s, exit_t, nx_, ny_, nz_, tick):
    """Move particle ``i``: below the floor it has left (``exit_s``: its horizontal
    distance from the axis, ``exit_t``: the tick), else it is mirrored into the material."""
    if nz_ < prm.z0:
        status[i] = P_ORIFICE
        exit_s[i] = math.sqrt(nx_ * nx_ + ny_ * ny_) if prm.cyl == 1 else nx_
        exit_t[i] = tick + 0.5
        px[i] = nx_
        py[i] = ny_
        pz[i] = nz_
        return
    x, y, _a, _b, _c = confine(prm, nx_, ny_, nz_)
    px[i] = x
    py[i] = y
    pz[i] = nz_
