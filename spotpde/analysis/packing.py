"""Packing diagnostics of particle positions: local packing fraction, radial distribution,
overlaps, number variance (docs/packing.md). Lengths in grain diameters d.

Every function takes *frames*: one ``(N, 2|3)`` array of centres ``(x, z[, y])``; a
sequence of them or an ``(F, N, 2|3)`` array; or a tracks Dataset with dims
``("particle", "t")`` (either order) and variables ``x``, ``z`` [, ``y``] [, ``diameter``]
(each ``t`` is a frame). Rows with NaN (grains that have left) are dropped per frame.
Diameters default to 1 d (or the Dataset's ``diameter``).

Errors are honest only if the samples they come from are independent:

* with two or more frames, each statistic is computed per frame and the error is the
  standard error of the mean over frames, ``sd / sqrt(F)``: the frames must be
  independent (separate replicas, or snapshots farther apart than the packing's memory);
* with one frame, the region is cut into ``blocks`` vertical strips and the statistic is
  computed per strip (``sd / sqrt(B)`` over strips); strips much wider than the
  correlation length (a few d) are close to independent. The local packing fraction of
  a single frame has no error (NaN): a Voronoi cell's volume is anticorrelated with its
  neighbours', so the scatter within a grid cell says nothing.

Functions: :func:`packing_fraction` (Voronoi cells, on a grid), :func:`radial_distribution`
(``g(r)``), :func:`overlap_distribution`, :func:`number_variance` (windows of growing side:
``sigma^2 ~ L^dim`` for a Poisson set, ``~ L^(dim-1)`` for a hyperuniform one).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import xarray as xr
from scipy.spatial import ConvexHull, Voronoi, cKDTree

__all__ = ["frames_of", "packing_fraction", "radial_distribution", "overlap_distribution",
           "number_variance", "pair_overlaps", "voronoi_volumes", "WINDOWS"]


def _attrs(long_name, units="d"):
    return {"units": "1", "long_name": f"{long_name}, in {units}" if units != "1" else long_name,
            "spotpde_units": units}


def frames_of(data, diameters=None):
    """The frames of ``data`` (module docstring) as lists of positions and diameters.

    Returns:
        (positions: list of ``(N_f, dim)`` arrays, diameters: list of ``(N_f,)`` arrays).

    Raises:
        ValueError / TypeError: ``data`` or ``diameters`` of the wrong shape.
    """
    if isinstance(data, xr.Dataset):
        names = [v for v in ("x", "z", "y") if v in data]
        if "x" not in names or "z" not in names or "particle" not in data.dims or "t" not in data.dims:
            raise ValueError("data: a tracks Dataset needs dims ('particle', 't') and variables x, z [, y]")
        arr = np.stack([data[v].transpose("t", "particle").values for v in names], axis=-1)
        if diameters is None and "diameter" in data:
            diameters = data["diameter"].values
    elif isinstance(data, np.ndarray) and data.ndim in (2, 3):
        arr = data if data.ndim == 3 else data[None]
    elif isinstance(data, (list, tuple)):
        arr = [np.asarray(f, float) for f in data]
    else:
        raise TypeError(f"data: must be an (N, 2|3) or (F, N, 2|3) array, a list of frames or "
                        f"a tracks Dataset, got {type(data).__name__}")
    pos, dia = [], []
    for f in arr:
        f = np.asarray(f, float)
        if f.ndim != 2 or f.shape[1] not in (2, 3):
            raise ValueError(f"data: each frame must be (N, 2) or (N, 3), got {f.shape}")
        d = np.ones(len(f)) if diameters is None else np.asarray(diameters, float).reshape(-1)
        if d.shape[0] != f.shape[0]:
            raise ValueError(f"diameters: need one per particle ({f.shape[0]}), got {d.shape[0]}")
        keep = np.all(np.isfinite(f), axis=1)
        pos.append(f[keep])
        dia.append(d[keep])
    return pos, dia


def _box(P, box):
    if box is not None:
        return np.asarray(box, float)
    if len(P) == 0:
        return np.zeros(2 * P.shape[1])
    lo, hi = P.min(axis=0), P.max(axis=0)
    # (x0, x1, z0, z1[, y0, y1]) in the order of the coordinates
    return np.ravel(np.column_stack([lo, hi]))


def _grain_volume(d, dim):
    return math.pi / 4.0 * d**2 if dim == 2 else math.pi / 6.0 * d**3


def _mean_se(values, axis=0):
    v = np.asarray(values, float)
    n = np.sum(np.isfinite(v), axis=axis)
    with warnings.catch_warnings():  # all-NaN cells and single samples: NaN, said in the docs
        warnings.simplefilter("ignore", RuntimeWarning)
        m = np.nanmean(v, axis=axis)
        se = np.where(n >= 2, np.nanstd(v, axis=axis, ddof=1) / np.sqrt(np.maximum(n, 1)), np.nan)
    return m, se


def _groups(pos, dia, box, blocks):
    """Independent samples: per frame ``(P, d, region, None)``; for a single frame
    ``(P, d, region, (x_lo, x_hi))`` per vertical strip of the region."""
    if len(pos) >= 2:
        return [(p, d, _box(p, box), None) for p, d in zip(pos, dia)]
    P, d = pos[0], dia[0]
    b = _box(P, box)
    edges = np.linspace(b[0], b[1], int(blocks) + 1)
    return [(P, d, b, (edges[k], edges[k + 1])) for k in range(int(blocks))]


def _in_strip(x, strip):
    return np.ones(len(x), bool) if strip is None else (x >= strip[0]) & (x < strip[1])


# ---------------------------------------------------------------------------------------
# local packing fraction (Voronoi)
# ---------------------------------------------------------------------------------------
def voronoi_volumes(P, box, max_volume=None):
    """Voronoi cell volume (area in 2D) of each centre; NaN for cells that are unbounded,
    reach outside ``box`` or exceed ``max_volume`` (grains at a free surface)."""
    out = np.full(len(P), np.nan)
    if len(P) <= P.shape[1] + 1:
        return out
    vor = Voronoi(P)
    lo, hi = box[0::2], box[1::2]
    for i, reg in enumerate(vor.point_region):
        verts = vor.regions[reg]
        if not verts or -1 in verts:
            continue
        V = vor.vertices[verts]
        if np.any(V < lo) or np.any(V > hi):
            continue
        vol = ConvexHull(V).volume
        if max_volume is None or vol <= max_volume:
            out[i] = vol
    return out


def packing_fraction(data, x_edges, z_edges, diameters=None, box=None,
                     min_phi: float = 0.3) -> xr.Dataset:
    """Local packing fraction on a grid, from the grains' Voronoi cells.

    In each grid cell, ``phi = sum v_i / sum V_i`` over the grains whose centre is in it
    (``v_i`` the grain's area or volume, ``V_i`` its Voronoi cell's); cells reaching
    outside ``box`` (default: the frame's bounding box), unbounded ones and those with
    ``v_i / V_i < min_phi`` (a free surface) are left out. For a lattice this is the
    lattice's packing fraction exactly.

    Args:
        data, diameters: frames (module docstring).
        x_edges, z_edges: grid cell edges in d (e.g. ``grid.x - h/2`` plus the last edge).

    Returns:
        Dataset ``phi (z, x)``, ``phi_se`` (over frames; NaN with one frame), ``count``
        (grains used, summed over frames), and the global ``phi_all`` (all used grains of
        all cells) with ``phi_all_se``.
    """
    pos, dia = frames_of(data, diameters)
    xe, ze = np.asarray(x_edges, float), np.asarray(z_edges, float)
    per, counts, glob = [], np.zeros((ze.size - 1, xe.size - 1)), []
    for P, d in zip(pos, dia):
        b = _box(P, box)
        v = _grain_volume(d, P.shape[1])
        V = voronoi_volumes(P, b)
        ok = np.isfinite(V) & (v / np.where(np.isfinite(V), V, np.inf) >= min_phi)
        sv, _, _ = np.histogram2d(P[ok, 1], P[ok, 0], bins=(ze, xe), weights=v[ok])
        sV, _, _ = np.histogram2d(P[ok, 1], P[ok, 0], bins=(ze, xe), weights=V[ok])
        n, _, _ = np.histogram2d(P[ok, 1], P[ok, 0], bins=(ze, xe))
        with np.errstate(invalid="ignore", divide="ignore"):
            per.append(np.where(sV > 0, sv / sV, np.nan))
        counts += n
        inside = ok & (P[:, 0] >= xe[0]) & (P[:, 0] < xe[-1]) & (P[:, 1] >= ze[0]) & (P[:, 1] < ze[-1])
        glob.append(v[inside].sum() / V[inside].sum() if inside.any() else np.nan)
    phi, se = _mean_se(per)
    g, gse = _mean_se(glob)
    xc, zc = 0.5 * (xe[1:] + xe[:-1]), 0.5 * (ze[1:] + ze[:-1])
    return xr.Dataset(
        {"phi": (("z", "x"), phi, _attrs("local packing fraction (Voronoi)", "1")),
         "phi_se": (("z", "x"), se, _attrs("standard error of phi over frames", "1")),
         "count": (("z", "x"), counts, _attrs("grains used, all frames", "1")),
         "phi_all": ((), g, _attrs("packing fraction of all used grains", "1")),
         "phi_all_se": ((), gse, _attrs("standard error of phi_all", "1"))},
        coords={"z": ("z", zc, _attrs("height")), "x": ("x", xc, _attrs("horizontal position"))},
        attrs={"frames": len(pos)})


# ---------------------------------------------------------------------------------------
# radial distribution
# ---------------------------------------------------------------------------------------
def _shell_counts(P, ref_mask, edges):
    """Mean number of other centres per reference centre in each shell ``edges``."""
    tree = cKDTree(P)
    refs = np.flatnonzero(ref_mask)
    cum = np.array([np.sum(tree.query_ball_point(P[refs], r, return_length=True)) for r in edges[1:]],
                   float)
    lo = np.sum(tree.query_ball_point(P[refs], edges[0], return_length=True)) if edges[0] > 0 else len(refs)
    cum = np.concatenate([[lo], cum])
    return np.diff(cum) / max(len(refs), 1), len(refs)


def radial_distribution(data, r_max: float = 5.0, dr: float = 0.05, diameters=None,
                        box=None, blocks: int = 4) -> xr.Dataset:
    """The radial distribution function ``g(r)`` (r in d).

    ``g`` in shell ``[r_k, r_k+1)`` is the mean number of centres in the shell around a
    reference centre divided by ``n`` times the shell's area ``pi (r_k+1^2 - r_k^2)``
    (volume ``4/3 pi (r_k+1^3 - r_k^3)`` in 3D), ``n`` the number density of the
    region. Reference centres are those at least ``r_max`` inside the region (``box``;
    default the frame's bounding box), so no edge correction is needed; ``n`` counts
    the centres of the region shrunk by half a mean spacing at the walls. With one
    frame, the reference centres are split into strips by ``x``. For a lattice
    ``g * n * shell area`` is the number of lattice points in the shell.

    Returns:
        Dataset ``g (r)``, ``g_se`` and ``n`` (number density), errors over frames or
        strips (module docstring).
    """
    pos, dia = frames_of(data, diameters)
    edges = np.arange(0.0, r_max + 0.5 * dr, dr)
    gs, ns = [], []
    for P, d, b, strip in _groups(pos, dia, box, blocks):
        dim = P.shape[1]
        lo, hi = b[0::2], b[1::2]
        ref = np.all((P >= lo + r_max) & (P <= hi - r_max), axis=1) & _in_strip(P[:, 0], strip)
        if not ref.any():
            raise ValueError(f"r_max: no centre lies {r_max} d inside the region (and its "
                             "strips); reduce r_max or blocks")
        half = 0.5 * (np.prod(hi - lo) / len(P)) ** (1.0 / dim)
        core = np.all((P >= lo + half) & (P <= hi - half), axis=1)
        n = core.sum() / np.prod(hi - lo - 2 * half)
        counts, _ = _shell_counts(P, ref, edges)
        shell = (math.pi * np.diff(edges**2) if dim == 2 else 4.0 / 3.0 * math.pi * np.diff(edges**3))
        gs.append(counts / (n * shell))
        ns.append(n)
    g, se = _mean_se(gs)
    n, nse = _mean_se(ns)
    rc = 0.5 * (edges[1:] + edges[:-1])
    return xr.Dataset({"g": ("r", g, _attrs("radial distribution function", "1")),
                       "g_se": ("r", se, _attrs("standard error of g", "1")),
                       "n": ((), n, _attrs("number density", "d^-dim")),
                       "n_se": ((), nse, _attrs("standard error of n", "d^-dim"))},
                      coords={"r": ("r", rc, _attrs("distance between centres (shell middle)")),
                              "r_lo": ("r", edges[:-1], _attrs("shell inner radius")),
                              "r_hi": ("r", edges[1:], _attrs("shell outer radius"))},
                      attrs={"samples": len(gs)})


# ---------------------------------------------------------------------------------------
# overlaps
# ---------------------------------------------------------------------------------------
def pair_overlaps(P, d):
    """Overlaps ``(d_i + d_j)/2 - r_ij > 0`` (in d) of all overlapping pairs of a frame,
    and the x of each pair's midpoint."""
    if len(P) < 2:
        return np.zeros(0), np.zeros(0)
    pairs = cKDTree(P).query_pairs(float(d.max()), output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros(0), np.zeros(0)
    a, b = pairs[:, 0], pairs[:, 1]
    ov = 0.5 * (d[a] + d[b]) - np.linalg.norm(P[a] - P[b], axis=1)
    keep = ov > 0
    return ov[keep], 0.5 * (P[a[keep], 0] + P[b[keep], 0])


def overlap_distribution(data, diameters=None, bins=None, blocks: int = 4) -> xr.Dataset:
    """Distribution of pair overlaps ``delta = (d_i + d_j)/2 - r_ij > 0`` (in d).

    Returns:
        Dataset with the histogram ``density (delta)`` (overlapping pairs per grain per
        unit overlap) and the summaries ``pairs_per_grain`` (overlapping pairs per
        grain), ``mean``, ``max`` (largest overlap), each with ``*_se`` over frames or
        strips (module docstring).
    """
    pos, dia = frames_of(data, diameters)
    bins = np.linspace(0.0, 0.1, 41) if bins is None else np.asarray(bins, float)
    hists, ppg, means, maxs = [], [], [], []
    for P, d, b, strip in _groups(pos, dia, None, blocks):
        ov, mid_x = pair_overlaps(P, d)
        ov = ov[_in_strip(mid_x, strip)]  # a pair belongs to the strip of its midpoint
        n = max(int(np.sum(_in_strip(P[:, 0], strip))), 1)
        hists.append(np.histogram(ov, bins)[0] / (n * np.diff(bins)))
        ppg.append(len(ov) / n)
        means.append(ov.mean() if len(ov) else 0.0)
        maxs.append(ov.max() if len(ov) else 0.0)
    out = {}
    for name, vals, long in (("pairs_per_grain", ppg, "overlapping pairs per grain"),
                             ("mean", means, "mean overlap of overlapping pairs"),
                             ("max", maxs, "largest overlap")):
        m, se = _mean_se(vals)
        units = "1" if name == "pairs_per_grain" else "d"
        out[name] = ((), m, _attrs(long, units))
        out[name + "_se"] = ((), se, _attrs(f"standard error of {name}", units))
    h, hse = _mean_se(hists)
    out["density"] = ("delta", h, _attrs("overlapping pairs per grain per unit overlap", "1/d"))
    out["density_se"] = ("delta", hse, _attrs("standard error of density", "1/d"))
    return xr.Dataset(out, coords={"delta": ("delta", 0.5 * (bins[1:] + bins[:-1]), _attrs("overlap"))},
                      attrs={"samples": len(ppg)})


# ---------------------------------------------------------------------------------------
# number variance
# ---------------------------------------------------------------------------------------
def _counts(P, centres, side, window):
    """Centres of ``P`` in the disks (spheres) of diameter ``side`` or the squares
    (cubes) of side ``side`` around ``centres``."""
    tree = cKDTree(P)
    p = 2.0 if window == "disk" else np.inf
    return tree.query_ball_point(centres, 0.5 * side, p=p, return_length=True).astype(float)


def _jackknife(stat, k):
    """Statistic of the frames ``k`` (F, W) and its delete-one-frame jackknife error."""
    F = k.shape[0]
    full = stat(k)
    loo = np.array([stat(np.delete(k, f, axis=0)) for f in range(F)])
    return full, math.sqrt((F - 1) / F * np.sum((loo - loo.mean()) ** 2))


WINDOWS = ("disk", "square")


def number_variance(data, sizes, box=None, windows: int = 400, seed: int = 0,
                    blocks: int = 4, window: str = "disk") -> xr.Dataset:
    """Variance of the number of centres in windows of size ``L``: disks (spheres) of
    diameter ``L`` (``window="disk"``, the default) or squares (cubes) of side ``L``.

    For a Poisson set ``var = mean = n |W|`` (the window's area or volume); for a
    hyperuniform set (a lattice, and the paper's expectation for dense packings) it
    grows like the perimeter of disks, ``~ L^(dim-1)``. (Squares aligned with a square
    lattice are the classic exception: a whole row enters at once, ``var ~ L^2``.)

    * Two or more frames (independent replicas): ``windows`` windows are placed at
      random inside the region (``box``, default the first frame's bounding box), the
      same in every frame; the variance of each window's count over the frames
      (unbiased, ``ddof = 1``) is averaged over the windows, and its error is the
      delete-one-frame jackknife. This needs nothing but independent frames.
    * One frame: the region is cut into ``blocks`` strips, each strip tiled by
      non-overlapping windows; the variance over the tiles of a strip, error over the
      strips. Unbiased when the counts of neighbouring tiles are uncorrelated (Poisson);
      for a hyperuniform packing neighbouring tiles are anticorrelated and this
      underestimates the variance: use replicas.

    Returns:
        Dataset over ``L``: ``mean``, ``var``, their ``*_se``, and ``ratio = var / mean``
        (1 for Poisson).
    """
    if window not in WINDOWS:
        raise ValueError(f"window: must be one of {WINDOWS}, got {window!r}")
    pos, _ = frames_of(data, None)
    L = np.asarray(sizes, float).reshape(-1)
    rng = np.random.default_rng(seed)
    b = _box(pos[0], box)
    lo, hi = b[0::2], b[1::2]
    dim = pos[0].shape[1]
    rows = {"mean": [], "mean_se": [], "var": [], "var_se": []}
    for side in L:
        if np.any(hi - lo < side):
            for v in rows.values():
                v.append(np.nan)
            continue
        if len(pos) >= 2:
            c = lo + 0.5 * side + rng.random((int(windows), dim)) * (hi - lo - side)
            k = np.array([_counts(P, c, side, window) for P in pos])
            m, mse = _jackknife(np.mean, k)
            v, vse = _jackknife(lambda a: np.mean(np.var(a, axis=0, ddof=1)), k)
        else:
            ms, vs = [], []
            edges = np.linspace(lo[0], hi[0], int(blocks) + 1)
            for k0 in range(int(blocks)):
                slo, shi = lo.copy(), hi.copy()
                slo[0], shi[0] = edges[k0], edges[k0 + 1]
                nt = np.floor((shi - slo) / side).astype(int)
                if np.prod(nt) < 2:
                    continue
                axes = [slo[a] + side * (np.arange(nt[a]) + 0.5) for a in range(dim)]
                c = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, dim)
                k = _counts(pos[0], c, side, window)
                ms.append(k.mean())
                vs.append(k.var(ddof=1))
            (m, mse), (v, vse) = _mean_se(ms), _mean_se(vs)
        for name, val in (("mean", m), ("mean_se", mse), ("var", v), ("var_se", vse)):
            rows[name].append(val)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.asarray(rows["var"]) / np.asarray(rows["mean"])
    longs = {"mean": "mean number in a window", "var": "number variance"}
    data_vars = {}
    for name, vals in rows.items():
        base = name.replace("_se", "")
        long = longs[base] if name == base else f"standard error of {base}"
        data_vars[name] = ("L", np.asarray(vals, float), _attrs(long, "1"))
    data_vars["ratio"] = ("L", ratio, _attrs("var / mean (1: Poisson)", "1"))
    return xr.Dataset(data_vars, coords={"L": ("L", L, _attrs("window side"))},
                      attrs={"frames": len(pos), "windows": int(windows), "window": window})
