"""Packing constraints in the discrete spot model: soft-core relaxation (private; see
``montecarlo`` and docs/packing.md).

The multiscale algorithm of Rycroft, Bazant, Grest and Landry (Phys. Rev. E 73, 051306,
2006): after a spot has displaced its block of grains, the grains near the spot are
relaxed by a soft-core repulsion, with the centre of mass of the relaxed block held
fixed so that the block does not slip back. Grains are disks of diameter ``d_i`` (in the
mean diameter d); two grains overlap by ``delta_ij = (d_i + d_j)/2 - |r_i - r_j|`` when
positive. One relaxation iteration (a Jacobi sweep of overlap springs) is

    f_i   = sum_j delta_ij n_ij                  (n_ij the unit vector from j to i; j over
                                                  the block and the frozen grains around it)
    g_i   = overlaps with the reflecting walls and with the floor outside the opening
    r_i  += alpha (f_i - <f>_m) + alpha g_i      (<f>_m = sum m_i f_i / sum m_i, m_i = d_i^2)

so the grain-grain part moves the block's centre of mass by exactly zero (round-off
only) and only the walls and floor, which are external, can push it. ``alpha`` is the
displacement per unit overlap (stable for ``alpha`` below about 1/3 on a dense
packing; see docs/packing.md).

Here: :class:`Relax` (the parameters, the names of a future ``[montecarlo] relax``
table), :func:`draw_diameters`, :func:`relax_packing` (relax a whole packing, e.g. to
make an initial one; spheres too) and the numba kernels :func:`relax_block` (one block,
called from ``_mc_kernels.advance``) and :func:`relax_all`. Spheres in 3D (masses
``d_i^3``, front and back walls): ``_relax3d``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import NamedTuple

import numpy as np
from numba import njit

from ._relax3d import relax_all3

__all__ = ["Relax", "DISTRIBUTIONS", "draw_diameters", "relax_packing"]

#: diameter distributions of :func:`draw_diameters`
DISTRIBUTIONS = ("uniform", "gaussian")
_P_IN = 0  # particle status "inside" (``_mc_kernels.P_IN``)


@dataclass(frozen=True)
class Relax:
    """Parameters of the soft-core relaxation after spot steps (lengths in d).

    Attributes:
        alpha: displacement per unit overlap in one iteration (default 0.2; stable below
            about 1/3 for dense disks, docs/packing.md).
        iterations: Jacobi iterations per relaxation (default 4).
        every: relax after every ``every``-th step of each spot, over the grains within
            ``radius`` of the segment the spot's influence centre has covered since its
            last relaxation (default 1: after each step). Rycroft, Wong and Bazant
            (Powder Technol. 200, 1, 2010) relax much less often.
        radius: grains within this distance of the spot's influence centre (or segment)
            are relaxed, the displaced block; the grains beyond it are felt as fixed
            obstacles. Default (None): the distance at which the kernel falls to 1 % of
            its centre value (``R`` for the disk, ``3.03 sigma`` Gaussian, ``4.61 l``
            exponential, along the larger axis).
        polydispersity: relative spread of the diameters (default 0.1).
        distribution: ``"uniform"`` (uniform in ``[1 - s, 1 + s]`` d) or ``"gaussian"``
            (standard deviation ``s`` d, truncated at 3 standard deviations).
        opening: width (d) of the floor's opening, centred on the orifice; beside it the
            floor repels grains and keeps them. Default (None): no floor, grains leave
            wherever the spots push them below ``z0``, as without relaxation. A repelling
            floor beside a slot makes the packing above the slot compact (measured in
            docs/packing.md: the spots keep pushing grains into the floor).
        margin: a pair within ``(d_i + d_j)/2 + margin`` at the start of a relaxation is
            watched during it (default 0.2 d; grains move far less in a few iterations).
    """

    alpha: float = 0.2
    iterations: int = 4
    every: int = 1
    radius: float | None = None
    polydispersity: float = 0.1
    distribution: str = "uniform"
    opening: float | None = None
    margin: float = 0.2

    def __post_init__(self):
        problems = []
        if not 0.0 < self.alpha <= 0.5:
            problems.append(f"alpha: must be in (0, 0.5], got {self.alpha}")
        for name in ("iterations", "every"):
            v = getattr(self, name)
            if not (isinstance(v, (int, np.integer)) and v >= 1):
                problems.append(f"{name}: must be an integer >= 1, got {v!r}")
        if self.radius is not None and not self.radius > 0:
            problems.append(f"radius: must be > 0 or None, got {self.radius}")
        if not 0.0 <= self.polydispersity < 0.5:
            problems.append(f"polydispersity: must be in [0, 0.5), got {self.polydispersity}")
        if self.distribution not in DISTRIBUTIONS:
            problems.append(f"distribution: must be one of {DISTRIBUTIONS}, got {self.distribution!r}")
        if self.opening is not None and not self.opening >= 0:
            problems.append(f"opening: must be >= 0 or None, got {self.opening}")
        if not self.margin > 0:
            problems.append(f"margin: must be > 0, got {self.margin}")
        if problems:
            raise ValueError("; ".join(problems))

    @classmethod
    def of(cls, value) -> "Relax | None":
        """``None`` or ``False`` (no relaxation), ``True`` (the defaults), a
        :class:`Relax`, or a dict of its field names: the values the case table's
        ``[montecarlo] relax`` takes."""
        if value is None or value is False:
            return None
        if value is True:
            return cls()
        if isinstance(value, Relax):
            return value
        if isinstance(value, dict):
            names = {f.name for f in fields(cls)}
            unknown = sorted(set(value) - names)
            if unknown:
                raise ValueError(f"relax: unknown keys {unknown}; valid: {sorted(names)}")
            return cls(**value)
        raise TypeError("relax: must be None, True, False, a Relax or a dict, got "
                        f"{type(value).__name__}")

    def resolved(self, kernel_radius: float) -> "Relax":
        """A copy with ``radius`` filled in from the kernel's (d)."""
        radius = self.radius if self.radius is not None else kernel_radius
        return replace(self, radius=float(radius))


def draw_diameters(n: int, polydispersity: float = 0.1, distribution: str = "uniform",
                   seed: int = 0) -> np.ndarray:
    """``n`` grain diameters (in d) of mean 1 and relative spread ``polydispersity``.

    ``"uniform"``: uniform in ``[1 - s, 1 + s]``; ``"gaussian"``: normal of standard
    deviation ``s``, redrawn beyond ``1 +- 3 s``.
    """
    Relax(polydispersity=polydispersity, distribution=distribution)  # validates
    rng = np.random.default_rng(seed)
    s = float(polydispersity)
    if distribution == "uniform":
        return 1.0 + s * (2.0 * rng.random(n) - 1.0)
    d = 1.0 + s * rng.standard_normal(n)
    bad = np.abs(d - 1.0) > 3.0 * s
    while bad.any():
        d[bad] = 1.0 + s * rng.standard_normal(int(bad.sum()))
        bad = np.abs(d - 1.0) > 3.0 * s
    return d


def particle_diameters(n: int, relax: "Relax | None", diameters, seed: int) -> np.ndarray:
    """The ``n`` grain diameters of a run (d): ``diameters`` as given (checked), else
    drawn from ``relax``'s distribution (:func:`draw_diameters`), else all 1.

    Raises:
        ValueError: ``diameters`` is not ``n`` positive values.
    """
    if diameters is None:
        return (np.ones(n) if relax is None else
                draw_diameters(n, relax.polydispersity, relax.distribution, seed))
    diam = np.asarray(diameters, dtype=float).reshape(-1).copy()
    if diam.shape != (n,) or not np.all(diam > 0):
        raise ValueError(f"diameters: need {n} positive values, one per particle, "
                         f"got shape {np.shape(diameters)}")
    return diam


class RelaxParams(NamedTuple):
    """The relaxation's constants as the numba loop reads them (see :class:`Relax`).

    ``on`` 0/1; ``open_lo``, ``open_hi``: the floor opening; ``walls``: 1 reflecting
    side walls repel, 0 open; ``lid``: 1 the top ``z1`` repels (initial packings only);
    ``dmax``: largest diameter.
    """

    on: int
    alpha: float
    iterations: int
    every: int
    radius: float
    margin: float
    open_lo: float
    open_hi: float
    dmax: float
    walls: int
    lid: int


def relax_params(relax: Relax | None, diameters: np.ndarray, xc: float, reflecting: bool,
                 lid: bool = False) -> RelaxParams:
    """The :class:`RelaxParams` of a resolved :class:`Relax` (``None``: off)."""
    if relax is None:
        return RelaxParams(0, 0.0, 0, 1, 0.0, 0.0, -math.inf, math.inf, 0.0, 0, 0)
    half = math.inf if relax.opening is None else 0.5 * float(relax.opening)
    dmax = float(np.max(diameters)) if len(diameters) else 1.0
    return RelaxParams(1, float(relax.alpha), int(relax.iterations), int(relax.every),
                       float(relax.radius), float(relax.margin), float(xc) - half,
                       float(xc) + half, dmax, int(bool(reflecting)), int(bool(lid)))


# ---------------------------------------------------------------------------------------
# numba kernels
# ---------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _seg_dist2(x, z, ax, az, bx, bz):
    """Squared distance from ``(x, z)`` to the segment ``a b``."""
    ux = bx - ax
    uz = bz - az
    L2 = ux * ux + uz * uz
    t = 0.0
    if L2 > 0.0:
        t = min(max(((x - ax) * ux + (z - az) * uz) / L2, 0.0), 1.0)
    dx = x - ax - t * ux
    dz = z - az - t * uz
    return dx * dx + dz * dz


@njit(cache=True)
def _sweeps(lx, lz, ld, mobile, pa, pb, n_pairs, box, rp, iterations, hold_com, tol):
    """``iterations`` Jacobi sweeps (module docstring) on local arrays, in place.

    ``box = (x0, x1, z0, z1)``; ``mobile`` 1 for grains that move (the block), 0 for
    fixed obstacles. Stops early when the largest overlap (of a pair or with a wall) is
    at most ``tol``, before the sweep that would move it. Returns (the largest overlap
    seen by the last sweep, the number of sweeps that moved grains).
    """
    m = lx.size
    fx = np.zeros(m)
    fz = np.zeros(m)
    gx = np.zeros(m)
    gz = np.zeros(m)
    x0 = box[0]; x1 = box[1]; z0 = box[2]; z1 = box[3]
    alpha = rp.alpha
    worst = 0.0
    moved = 0
    for it in range(iterations):
        worst = 0.0
        for i in range(m):
            fx[i] = 0.0; fz[i] = 0.0; gx[i] = 0.0; gz[i] = 0.0
        for k in range(n_pairs):
            a = pa[k]
            b = pb[k]
            dx = lx[a] - lx[b]
            dz = lz[a] - lz[b]
            r2 = dx * dx + dz * dz
            sig = 0.5 * (ld[a] + ld[b])
            if r2 >= sig * sig or r2 == 0.0:
                continue
            r = math.sqrt(r2)
            ov = sig - r
            if ov > worst:
                worst = ov
            fx[a] += ov * dx / r; fz[a] += ov * dz / r
            fx[b] -= ov * dx / r; fz[b] -= ov * dz / r
        for i in range(m):
            if mobile[i] == 0:
                continue
            h = 0.5 * ld[i]
            if rp.walls == 1:
                if lx[i] - x0 < h:
                    gx[i] += h - (lx[i] - x0)
                if x1 - lx[i] < h:
                    gx[i] -= h - (x1 - lx[i])
            if lz[i] - z0 < h and not (rp.open_lo < lx[i] < rp.open_hi):
                gz[i] += h - (lz[i] - z0)
            if rp.lid == 1 and z1 - lz[i] < h:
                gz[i] -= h - (z1 - lz[i])
            ow = max(abs(gx[i]), abs(gz[i]))
            if ow > worst:
                worst = ow
        if worst <= tol:
            break
        mx = 0.0
        mz = 0.0
        msum = 0.0
        if hold_com:
            for i in range(m):
                if mobile[i] == 1:
                    w = ld[i] * ld[i]
                    mx += w * fx[i]
                    mz += w * fz[i]
                    msum += w
            if msum > 0.0:
                mx /= msum
                mz /= msum
        for i in range(m):
            if mobile[i] == 1:
                lx[i] += alpha * (fx[i] - mx + gx[i])
                lz[i] += alpha * (fz[i] - mz + gz[i])
        moved += 1
    return worst, moved


@njit(cache=True)
def relax_block(x0, x1, z0, z1, rp, ax, az, bx, bz, px, pz, diam, status,
                cell_start, cell_idx, cell, ncx, ncz, skin, blk, old):
    """Relax the grains within ``rp.radius`` of the segment ``a b`` (the spot's influence
    centres since its last relaxation), holding their centre of mass (module docstring).

    Grains within ``radius + dmax + margin`` are gathered through the Monte Carlo's cell
    list (cells of side ``cell``, valid to within ``skin / 2``); those beyond ``radius``
    are fixed obstacles. ``px``, ``pz`` are updated in place; ``blk[:n]`` receives the
    indices of the relaxed grains and ``old[:n]`` their positions before (for the
    caller's bookkeeping). Cost: O(M) for the M gathered grains (a local cell list),
    then O(pairs) per iteration; independent of the total number of grains.

    Returns:
        n, the number of relaxed grains (``blk`` and ``old`` must hold the largest
        possible n; the caller sizes them to all grains).
    """
    R = rp.radius
    Rc = R + rp.dmax + rp.margin
    lo_x = min(ax, bx) - Rc - skin
    hi_x = max(ax, bx) + Rc + skin
    lo_z = min(az, bz) - Rc - skin
    hi_z = max(az, bz) + Rc + skin
    ix_lo = min(max(int(math.floor((lo_x - x0) / cell)), 0), ncx - 1)
    ix_hi = min(max(int(math.floor((hi_x - x0) / cell)), 0), ncx - 1)
    iz_lo = min(max(int(math.floor((lo_z - z0) / cell)), 0), ncz - 1)
    iz_hi = min(max(int(math.floor((hi_z - z0) / cell)), 0), ncz - 1)
    cap = 0
    for icz in range(iz_lo, iz_hi + 1):
        cap += cell_start[icz * ncx + ix_hi + 1] - cell_start[icz * ncx + ix_lo]
    gidx = np.empty(cap, np.int64)
    mobile = np.empty(cap, np.int64)
    m = 0
    for icz in range(iz_lo, iz_hi + 1):
        for q in range(cell_start[icz * ncx + ix_lo], cell_start[icz * ncx + ix_hi + 1]):
            i = cell_idx[q]
            if status[i] != _P_IN:
                continue
            d2 = _seg_dist2(px[i], pz[i], ax, az, bx, bz)
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
    lx = np.empty(m)
    lz = np.empty(m)
    ld = np.empty(m)
    for k in range(m):
        lx[k] = px[gidx[k]]
        lz[k] = pz[gidx[k]]
        ld[k] = diam[gidx[k]]
    pa, pb, n_pairs = _grid_pairs(lx, lz, ld, mobile, rp.dmax + rp.margin, rp.margin)
    box = np.array([x0, x1, z0, z1])
    _sweeps(lx, lz, ld, mobile, pa, pb, n_pairs, box, rp, rp.iterations, True, -1.0)
    n = 0
    for k in range(m):
        if mobile[k] == 1:
            i = gidx[k]
            blk[n] = i
            old[n, 0] = px[i]
            old[n, 1] = pz[i]
            px[i] = lx[k]
            pz[i] = lz[k]
            n += 1
    return n


@njit(cache=True)
def _grid_pairs(lx, lz, ld, mobile, cell, margin):
    """Pairs (at least one of them mobile) closer than ``(d_a + d_b)/2 + margin``, found
    through a cell list of side ``cell >= dmax + margin`` over the points' bounding box:
    O(N)."""
    x0 = lx.min()
    z0 = lz.min()
    ncx = int((lx.max() - x0) / cell) + 1
    ncz = int((lz.max() - z0) / cell) + 1
    n = lx.size
    cs = np.zeros(ncx * ncz + 1, np.int64)
    cid = np.empty(n, np.int64)
    for i in range(n):
        cx = min(max(int(math.floor((lx[i] - x0) / cell)), 0), ncx - 1)
        cz = min(max(int(math.floor((lz[i] - z0) / cell)), 0), ncz - 1)
        cid[i] = cz * ncx + cx
        cs[cid[i] + 1] += 1
    for c in range(ncx * ncz):
        cs[c + 1] += cs[c]
    fill = cs[:-1].copy()
    idx = np.empty(n, np.int64)
    for i in range(n):
        idx[fill[cid[i]]] = i
        fill[cid[i]] += 1
    cap = 8 * n + 16
    while True:
        pa = np.empty(cap, np.int64)
        pb = np.empty(cap, np.int64)
        cnt = 0
        for a in range(n):
            cx = cid[a] % ncx
            cz = cid[a] // ncx
            for jz in range(max(cz - 1, 0), min(cz + 2, ncz)):
                for jx in range(max(cx - 1, 0), min(cx + 2, ncx)):
                    c = jz * ncx + jx
                    for q in range(cs[c], cs[c + 1]):
                        b = idx[q]
                        if b <= a or (mobile[a] == 0 and mobile[b] == 0):
                            continue
                        dx = lx[a] - lx[b]
                        dz = lz[a] - lz[b]
                        lim = 0.5 * (ld[a] + ld[b]) + margin
                        if dx * dx + dz * dz < lim * lim:
                            if cnt < cap:
                                pa[cnt] = a
                                pb[cnt] = b
                            cnt += 1
        if cnt <= cap:
            break
        cap = cnt  # crowded (an unrelaxed packing): once more with room for all
    return pa, pb, cnt


@njit(cache=True)
def relax_all(lx, lz, ld, mobile, box, rp, max_iterations, tol, hold_com):
    """Relax a whole packing in place until the largest overlap is at most ``tol`` or
    ``max_iterations`` sweeps are done. The pair list (cell list, O(N)) is rebuilt every
    10 sweeps, and convergence is only accepted on a freshly built list. Returns
    (sweeps, largest overlap)."""
    cell = rp.dmax + rp.margin
    done = 0
    worst = math.inf
    while done < max_iterations:
        pa, pb, n_pairs = _grid_pairs(lx, lz, ld, mobile, cell, rp.margin)
        k = min(10, max_iterations - done)
        worst, moved = _sweeps(lx, lz, ld, mobile, pa, pb, n_pairs, box, rp, k, hold_com, tol)
        done += moved
        if moved == 0:  # converged on a fresh pair list
            break
    return done, worst


# ---------------------------------------------------------------------------------------
# Python entry points
# ---------------------------------------------------------------------------------------
def relax_packing(positions, diameters, box, *, relax: Relax | dict | None = None,
                  walls: str = "reflecting", lid: bool = True, xc: float = 0.0,
                  tolerance: float = 1e-3, max_iterations: int = 20000,
                  hold_com: bool = False, mobile=None):
    """Relax a packing of disks (or spheres) by the soft-core sweeps until no overlap
    exceeds ``tolerance`` (in d), or ``max_iterations`` sweeps.

    Args:
        positions: ``(N, 2)`` centres ``(x, z)`` in d, or ``(N, 3)`` centres
            ``(x, z, y)`` of spheres (``_relax3d``; the depth ``y`` last, as in the 3D
            Monte Carlo and ``spotpde.analysis.packing``). diameters: ``(N,)`` in d.
        box: ``(x0, x1, z0, z1)`` (2D) or ``(x0, x1, z0, z1, y0, y1)`` (3D); side (and
            front and back) walls repel if ``walls == "reflecting"``, the floor outside
            ``relax.opening`` (default: none, a closed floor) and the lid ``z1`` if ``lid``.
        relax: the :class:`Relax` whose ``alpha`` and ``margin`` are used.
        hold_com: subtract the mean grain-grain displacement (as in the Monte Carlo).
        mobile: boolean mask of grains that move (default all).

    Returns:
        (positions, sweeps, largest remaining overlap).
    """
    P = np.array(positions, dtype=float)
    dims = 3 if P.ndim == 2 and P.shape[1] == 3 else 2
    P = P.reshape(-1, dims)
    d = np.asarray(diameters, dtype=float).reshape(-1)
    if np.size(box) != 2 * dims:
        raise ValueError(f"box: need {2 * dims} numbers for {dims}D positions, got {np.size(box)}")
    if d.shape[0] != P.shape[0]:
        raise ValueError(f"diameters: need one per position ({P.shape[0]}), got {d.shape[0]}")
    if walls not in ("reflecting", "open"):
        raise ValueError(f"walls: must be one of 'reflecting', 'open', got {walls!r}")
    rx = Relax.of(relax) or Relax()
    rx = replace(rx, radius=1.0, opening=0.0 if rx.opening is None else rx.opening)
    rp = relax_params(rx, d, xc, walls == "reflecting", lid)
    mob = np.ones(len(d), np.int64) if mobile is None else np.asarray(mobile, bool).astype(np.int64)
    if dims == 3:

        lx, lz, ly = (np.ascontiguousarray(P[:, k]) for k in range(3))
        b = np.asarray(box, float)[[0, 1, 4, 5, 2, 3]]  # (x0, x1, y0, y1, z0, z1)
        sweeps, worst = relax_all3(lx, ly, lz, d, mob, b, rp, int(max_iterations),
                                   float(tolerance), bool(hold_com))
        return np.column_stack([lx, lz, ly]), int(sweeps), float(worst)
    lx = np.ascontiguousarray(P[:, 0])
    lz = np.ascontiguousarray(P[:, 1])
    sweeps, worst = relax_all(lx, lz, d, mob, np.asarray(box, float), rp, int(max_iterations),
                              float(tolerance), bool(hold_com))
    return np.column_stack([lx, lz]), int(sweeps), float(worst)
