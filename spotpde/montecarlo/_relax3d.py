"""Packing constraints for spheres in 3D (private; see ``_relax`` and docs/packing.md).

The soft-core relaxation of ``_relax`` for spheres in a box ``[x0, x1] x [y0, y1] x
[z0, z1]``, typically a thin slab between front and back walls: the same Jacobi sweep
of overlap springs,

    r_i += alpha (f_i - <f>_m) + alpha g_i,     <f>_m = sum m_i f_i / sum m_i, m_i = d_i^3,

with ``f_i`` the grain-grain overlaps (pairs through a cell list) and ``g_i`` the
overlaps with the repelling side walls ``x0, x1`` and front and back walls ``y0, y1``
(``rp.walls = 1``), with the floor outside the opening ``open_lo < x < open_hi`` (a slot
across the whole depth) and with the lid (``rp.lid = 1``). Lengths in d.

Here: :func:`relax_block3` (one block, called from ``_mc3d.advance3``),
:func:`relax_all3` (a whole packing; ``_relax.relax_packing`` with ``(N, 3)`` positions).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

_P_IN = 0  # particle status "inside"


@njit(cache=True, inline="always")
def _seg_dist2_3(x, y, z, ax, ay, az, bx, by, bz):
    """Squared distance from ``(x, y, z)`` to the segment ``a b``."""
    ux = bx - ax
    uy = by - ay
    uz = bz - az
    L2 = ux * ux + uy * uy + uz * uz
    t = 0.0
    if L2 > 0.0:
        t = min(max(((x - ax) * ux + (y - ay) * uy + (z - az) * uz) / L2, 0.0), 1.0)
    dx = x - ax - t * ux
    dy = y - ay - t * uy
    dz = z - az - t * uz
    return dx * dx + dy * dy + dz * dz


@njit(cache=True)
def _sweeps3(lx, ly, lz, ld, mobile, pa, pb, n_pairs, box, rp, iterations, hold_com, tol):
    """``iterations`` Jacobi sweeps (module docstring) in place; ``box = (x0, x1, y0, y1,
    z0, z1)``. Stops before a sweep when the largest overlap (pair or wall) is at most
    ``tol``. Returns (largest overlap of the last sweep, sweeps that moved grains)."""
    m = lx.size
    fx = np.zeros(m); fy = np.zeros(m); fz = np.zeros(m)
    gx = np.zeros(m); gy = np.zeros(m); gz = np.zeros(m)
    x0 = box[0]; x1 = box[1]; y0 = box[2]; y1 = box[3]; z0 = box[4]; z1 = box[5]
    alpha = rp.alpha
    worst = 0.0
    moved = 0
    for it in range(iterations):
        worst = 0.0
        for i in range(m):
            fx[i] = 0.0; fy[i] = 0.0; fz[i] = 0.0
            gx[i] = 0.0; gy[i] = 0.0; gz[i] = 0.0
        for k in range(n_pairs):
            a = pa[k]
            b = pb[k]
            dx = lx[a] - lx[b]
            dy = ly[a] - ly[b]
            dz = lz[a] - lz[b]
            r2 = dx * dx + dy * dy + dz * dz
            sig = 0.5 * (ld[a] + ld[b])
            if r2 >= sig * sig or r2 == 0.0:
                continue
            r = math.sqrt(r2)
            ov = sig - r
            if ov > worst:
                worst = ov
            s = ov / r
            fx[a] += s * dx; fy[a] += s * dy; fz[a] += s * dz
            fx[b] -= s * dx; fy[b] -= s * dy; fz[b] -= s * dz
        for i in range(m):
            if mobile[i] == 0:
                continue
            h = 0.5 * ld[i]
            if rp.walls == 1:
                if lx[i] - x0 < h:
                    gx[i] += h - (lx[i] - x0)
                if x1 - lx[i] < h:
                    gx[i] -= h - (x1 - lx[i])
                if ly[i] - y0 < h:
                    gy[i] += h - (ly[i] - y0)
                if y1 - ly[i] < h:
                    gy[i] -= h - (y1 - ly[i])
            if lz[i] - z0 < h and not (rp.open_lo < lx[i] < rp.open_hi):
                gz[i] += h - (lz[i] - z0)
            if rp.lid == 1 and z1 - lz[i] < h:
                gz[i] -= h - (z1 - lz[i])
            ow = max(abs(gx[i]), abs(gy[i]), abs(gz[i]))
            if ow > worst:
                worst = ow
        if worst <= tol:
            break
        mx = 0.0; my = 0.0; mz = 0.0
        if hold_com:
            msum = 0.0
            for i in range(m):
                if mobile[i] == 1:
                    w = ld[i] * ld[i] * ld[i]
                    mx += w * fx[i]; my += w * fy[i]; mz += w * fz[i]
                    msum += w
            if msum > 0.0:
                mx /= msum; my /= msum; mz /= msum
        for i in range(m):
            if mobile[i] == 1:
                lx[i] += alpha * (fx[i] - mx + gx[i])
                ly[i] += alpha * (fy[i] - my + gy[i])
                lz[i] += alpha * (fz[i] - mz + gz[i])
        moved += 1
    return worst, moved


@njit(cache=True)
def _grid_pairs3(lx, ly, lz, ld, mobile, cell, margin):
    """Pairs (at least one mobile) closer than ``(d_a + d_b)/2 + margin``, through a cell
    list of side ``cell >= dmax + margin`` over the points' bounding box: O(N)."""
    x0 = lx.min(); y0 = ly.min(); z0 = lz.min()
    ncx = int((lx.max() - x0) / cell) + 1
    ncy = int((ly.max() - y0) / cell) + 1
    ncz = int((lz.max() - z0) / cell) + 1
    n = lx.size
    cs = np.zeros(ncx * ncy * ncz + 1, np.int64)
    cid = np.empty(n, np.int64)
    for i in range(n):
        cx = min(max(int(math.floor((lx[i] - x0) / cell)), 0), ncx - 1)
        cy = min(max(int(math.floor((ly[i] - y0) / cell)), 0), ncy - 1)
        cz = min(max(int(math.floor((lz[i] - z0) / cell)), 0), ncz - 1)
        cid[i] = (cz * ncy + cy) * ncx + cx
        cs[cid[i] + 1] += 1
    for c in range(ncx * ncy * ncz):
        cs[c + 1] += cs[c]
    fill = cs[:-1].copy()
    idx = np.empty(n, np.int64)
    for i in range(n):
        idx[fill[cid[i]]] = i
        fill[cid[i]] += 1
    cap = 16 * n + 16
    while True:
        pa = np.empty(cap, np.int64)
        pb = np.empty(cap, np.int64)
        cnt = 0
        for a in range(n):
            cx = cid[a] % ncx
            cy = (cid[a] // ncx) % ncy
            cz = cid[a] // (ncx * ncy)
            for jz in range(max(cz - 1, 0), min(cz + 2, ncz)):
                for jy in range(max(cy - 1, 0), min(cy + 2, ncy)):
                    for jx in range(max(cx - 1, 0), min(cx + 2, ncx)):
                        c = (jz * ncy + jy) * ncx + jx
                        for q in range(cs[c], cs[c + 1]):
                            b = idx[q]
                            if b <= a or (mobile[a] == 0 and mobile[b] == 0):
                                continue
                            dx = lx[a] - lx[b]
                            dy = ly[a] - ly[b]
                            dz = lz[a] - lz[b]
                            lim = 0.5 * (ld[a] + ld[b]) + margin
                            if dx * dx + dy * dy + dz * dz < lim * lim:
                                if cnt < cap:
                                    pa[cnt] = a
                                    pb[cnt] = b
                                cnt += 1
        if cnt <= cap:
            break
        cap = cnt
    return pa, pb, cnt


@njit(cache=True)
def relax_block3(x0, x1, y0, y1, z0, z1, rp, ax, ay, az, bx, by, bz, px, py, pz, diam,
                 status, cell_start, cell_idx, cell, ncx, ncy, ncz, skin, blk, old):
    """Relax the grains within ``rp.radius`` of the segment ``a b`` with their centre of
    mass held (``_relax.relax_block`` in 3D): grains within ``radius + dmax + margin``
    are gathered through the Monte Carlo's 3D cell list, those beyond ``radius`` are fixed
    obstacles. ``px, py, pz`` are updated in place; ``blk[:n]`` receives the relaxed
    grains and ``old[:n]`` their positions before. Returns n."""
    R = rp.radius
    Rc = R + rp.dmax + rp.margin
    ext = Rc + skin
    ix_lo = min(max(int(math.floor((min(ax, bx) - ext - x0) / cell)), 0), ncx - 1)
    ix_hi = min(max(int(math.floor((max(ax, bx) + ext - x0) / cell)), 0), ncx - 1)
    iy_lo = min(max(int(math.floor((min(ay, by) - ext - y0) / cell)), 0), ncy - 1)
    iy_hi = min(max(int(math.floor((max(ay, by) + ext - y0) / cell)), 0), ncy - 1)
    iz_lo = min(max(int(math.floor((min(az, bz) - ext - z0) / cell)), 0), ncz - 1)
    iz_hi = min(max(int(math.floor((max(az, bz) + ext - z0) / cell)), 0), ncz - 1)
    cap = 0
    for icz in range(iz_lo, iz_hi + 1):
        for icy in range(iy_lo, iy_hi + 1):
            row = (icz * ncy + icy) * ncx
            cap += cell_start[row + ix_hi + 1] - cell_start[row + ix_lo]
    gidx = np.empty(cap, np.int64)
    mobile = np.empty(cap, np.int64)
    m = 0
    for icz in range(iz_lo, iz_hi + 1):
        for icy in range(iy_lo, iy_hi + 1):
            row = (icz * ncy + icy) * ncx
            for q in range(cell_start[row + ix_lo], cell_start[row + ix_hi + 1]):
                i = cell_idx[q]
                if status[i] != _P_IN:
                    continue
                d2 = _seg_dist2_3(px[i], py[i], pz[i], ax, ay, az, bx, by, bz)
                if d2 < Rc * Rc:
                    gidx[m] = i
                    mobile[m] = 1 if d2 < R * R else 0
                    m += 1
    n_mob = 0
    for k in range(m):
        n_mob += mobile[k]
    if n_mob == 0:
        return 0
    gidx = gidx[:m]
    mobile = mobile[:m]
    lx = np.empty(m); ly = np.empty(m); lz = np.empty(m); ld = np.empty(m)
    for k in range(m):
        lx[k] = px[gidx[k]]; ly[k] = py[gidx[k]]; lz[k] = pz[gidx[k]]
        ld[k] = diam[gidx[k]]
    pa, pb, n_pairs = _grid_pairs3(lx, ly, lz, ld, mobile, rp.dmax + rp.margin, rp.margin)
    box = np.array([x0, x1, y0, y1, z0, z1])
    _sweeps3(lx, ly, lz, ld, mobile, pa, pb, n_pairs, box, rp, rp.iterations, True, -1.0)
    n = 0
    for k in range(m):
        if mobile[k] == 1:
            i = gidx[k]
            blk[n] = i
            old[n, 0] = px[i]; old[n, 1] = py[i]; old[n, 2] = pz[i]
            px[i] = lx[k]; py[i] = ly[k]; pz[i] = lz[k]
            n += 1
    return n


@njit(cache=True)
def relax_all3(lx, ly, lz, ld, mobile, box, rp, max_iterations, tol, hold_com):
    """Relax a whole packing of spheres in place until the largest overlap is at most
    ``tol`` or ``max_iterations`` sweeps (pair list rebuilt every 10 sweeps; convergence
    accepted on a fresh list). Returns (sweeps, largest overlap)."""
    cell = rp.dmax + rp.margin
    done = 0
    worst = math.inf
    while done < max_iterations:
        pa, pb, n_pairs = _grid_pairs3(lx, ly, lz, ld, mobile, cell, rp.margin)
        k = min(10, max_iterations - done)
        worst, moved = _sweeps3(lx, ly, lz, ld, mobile, pa, pb, n_pairs, box, rp, k,
                                hold_com, tol)
        done += moved
        if moved == 0:
            break
    return done, worst
