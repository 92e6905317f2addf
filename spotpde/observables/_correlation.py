"""Velocity correlations and pair separation (private; see :mod:`spotpde.observables`).

* :func:`velocity_correlation`: ``C(r) = <dq_i dq_j> / <dq^2>`` of the displacement
  fluctuations ``dq`` (relative to the mean flow along each path, as in
  ``displacement_growth``) of particle pairs at separation ``r`` over a window of ``lag``
  frames (Bazant 2004 eq. Cp). The model's value in uniform flow: the pair's relative
  variance is ``2 B(r)`` per unit fall and each particle's ``2 b_p``, so
  ``C(r) = 1 - B(r) / (2 b_p)`` (``B`` the relative tensor of ``spotpde.pair``, averaged
  over the directions of the separation).
* :func:`pair_separation`: pairs of neighbours closer than ``contact`` at a start frame,
  followed until they are ``separation`` apart (the cage breaks) or leave the record
  (censored); the Kaplan-Meier survival against the running maximum of the pair's fall,
  its restricted mean and median. Model: ``spotpde.pair.cage_breaking`` from contact, in
  every direction.
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr
from scipy.spatial import cKDTree

from .. import pair
from ._common import (BLOCKS, block_of, case_for, check_positive, grid_of, is_tracks,
                      jackknife, positions, units, with_errors)
from ._diffusion import _region, path_residuals
from ._velocity import velocity_field

__all__ = ["velocity_correlation", "pair_separation"]


def _model_params(case):
    """``(kernel, b, b_par, rule, diffusivity)`` of a case, constant lengths (means)."""
    s = case.spots
    return (case.kernel, float(np.mean(s.b)), float(np.mean(s.b_par)), case.rule, case.diffusivity)


def velocity_correlation(source, case=None, *, bins=None, lag: int = 1, component: str = "x",
                         region=None, stride: int = 1, blocks: int = BLOCKS,
                         velocity: xr.Dataset | None = None,
                         like: xr.Dataset | None = None, **kwargs) -> xr.Dataset:
    """Spatial correlation ``C(r)`` of displacement fluctuations.

    Args:
        source: tracks or a model result.
        case: the case.
        bins: separation bin edges in d (default 0.5 d bins up to 8 d).
        lag: frames in a window. component: ``"x"`` or ``"z"``.
        region: ``(x0, x1, z0, z1)`` where windows start. stride: frames between windows.
        blocks: time blocks of the jackknife. velocity: the tracks' velocity field.
        like: for a model result, the tracks' measurement (its bins and separations).

    Returns:
        Dataset on ``r`` (bin centres, d): ``C`` (tracks: ``C_se``, ``C_jk``, ``pairs``).
    """
    case = case_for(source, case)
    grid = grid_of(case)
    if component not in ("x", "z"):
        raise ValueError(f"component: must be 'x' or 'z', got {component!r}")
    if like is not None:
        bins, component = like.attrs["bins"], like.attrs["component"]
    bins = np.arange(0.5, 8.01, 0.5) if bins is None else np.asarray(bins, float)
    if bins.ndim != 1 or bins.size < 2 or np.any(np.diff(bins) <= 0) or bins[0] < 0:
        raise ValueError(f"bins: must be increasing separations >= 0 in d, got {bins}")
    centres = 0.5 * (bins[1:] + bins[:-1])
    attrs = {"bins": bins, "component": component}
    c_attrs = units("1", f"velocity correlation of the {component} displacement fluctuations")
    coords = {"r": ("r", centres, units("d", "separation"))}
    if not is_tracks(source):
        kernel, b, b_par, lam, diff = _model_params(case)
        key = "xx" if component == "x" else "zz"
        single = pair.uniform_flow(kernel, b, b_par, lam, diff, cage=False)
        one = single["b_p"] if component == "x" else single["b_p_par"]
        angles = np.linspace(0.0, 0.5 * math.pi, 7)
        R, A = np.meshgrid(centres, angles, indexing="ij")
        B = pair.relative_tensor(kernel, b, lam, b_par, diff, R * np.cos(A), R * np.sin(A))[key]
        C = 1.0 - np.asarray(B).mean(axis=1) / (2.0 * one)
        return xr.Dataset({"C": ("r", C, c_attrs)}, coords=coords, attrs=attrs)
    lag = check_positive("lag", lag, integer=True)
    stride = check_positive("stride", stride, integer=True)
    x, z, t = positions(source)
    x0, x1, z0, z1 = _region(grid, region)
    vel = velocity if velocity is not None else velocity_field(source, case, blocks=blocks, **kwargs)
    Ux, Uz, bad = path_residuals(grid, vel, x, z, t)
    q_all = (x[:, lag:] - x[:, :-lag] - (Ux[:, lag:] - Ux[:, :-lag])) if component == "x" else \
        (z[:, lag:] - z[:, :-lag] - (Uz[:, lag:] - Uz[:, :-lag]))
    nbin = centres.size
    acc = {k: np.zeros((blocks, nbin)) for k in ("prod", "pairs")}
    acc.update({k: np.zeros((blocks, 1)) for k in ("n", "q1", "q2")})
    for k in range(0, t.size - lag, stride):
        ok = (bad[:, k + lag] - bad[:, k] == 0) & np.isfinite(q_all[:, k]) \
            & (x[:, k] >= x0) & (x[:, k] <= x1) & (z[:, k] >= z0) & (z[:, k] <= z1)
        if ok.sum() < 2:
            continue
        q = q_all[ok, k]
        pts = np.column_stack([x[ok, k], z[ok, k]])
        ij = cKDTree(pts).query_pairs(bins[-1], output_type="ndarray")
        r = np.hypot(*(pts[ij[:, 0]] - pts[ij[:, 1]]).T)
        which = np.digitize(r, bins) - 1
        good = (which >= 0) & (which < nbin)
        blk = int(block_of(np.asarray([t[k]]), t, blocks)[0])
        acc["prod"][blk] += np.bincount(which[good], weights=(q[ij[good, 0]] * q[ij[good, 1]]),
                                        minlength=nbin)
        acc["pairs"][blk] += np.bincount(which[good], minlength=nbin)
        acc["n"][blk] += q.size
        acc["q1"][blk] += q.sum()
        acc["q2"][blk] += (q * q).sum()

    def corr(s):
        m = s["q1"] / s["n"]
        return (s["prod"] / s["pairs"] - m * m) / (s["q2"] / s["n"] - m * m)

    value, se, reps = jackknife(acc, corr)
    ds = xr.Dataset(coords=coords, attrs={**attrs, "lag": lag, "blocks": blocks})
    with_errors(ds, "C", ("r",), value, se, reps, c_attrs)
    ds["pairs"] = ("r", acc["pairs"].sum(axis=0), units("1", "pair samples per bin"))
    return ds


# -- pair separation -------------------------------------------------------------------------------

def _kaplan_meier(fall, event, grid_f):
    """Kaplan-Meier survival on ``grid_f`` from event/censoring falls (NaN without pairs)."""
    if fall.size == 0:
        return np.full(np.shape(grid_f), np.nan)
    order = np.argsort(fall, kind="stable")
    fall, event = fall[order], event[order]
    at_risk = fall.size - np.arange(fall.size)
    factor = np.where(event, 1.0 - 1.0 / np.maximum(at_risk, 1), 1.0)
    S = np.cumprod(factor)
    idx = np.searchsorted(fall, grid_f, side="right") - 1
    return np.where(idx >= 0, S[np.clip(idx, 0, None)], 1.0)


def _summaries(grid_f, S):
    mean = float(np.trapezoid(S, grid_f))
    below = np.nonzero(S <= 0.5)[0]
    median = float(grid_f[below[0]]) if below.size else math.nan
    return mean, median


def pair_separation(source, case=None, *, contact: float = 1.1, separation: float = 2.0,
                    falls=None, region=None, starts: int = 20, blocks: int = BLOCKS,
                    like: xr.Dataset | None = None) -> xr.Dataset:
    """Survival of initially touching pairs against their fall, the cage-breaking fall.

    Args:
        source: tracks or a model result.
        case: the case (the model's kernel, ``b``, rule and diffusivity).
        contact: pairs closer than this (d) at a start frame are neighbours in contact.
        separation: the cage counts as broken when the pair is this far apart, d.
        falls: the fall grid of the survival curve (default 40 points up to the largest
            fall with at least 20 pairs at risk).
        region: ``(x0, x1, z0, z1)`` where pairs start. starts: number of start frames.
        blocks: the jackknife's blocks of start frames.
        like: for a model result, the tracks' measurement (its falls and separations).

    Returns:
        Dataset on ``fall`` (d): ``survival``; scalars ``mean_fall`` (the mean restricted
        to the grid: ``int S dfall``) and ``median_fall`` (d; NaN if S stays above 1/2).
    """
    case = case_for(source, case)
    grid = grid_of(case)
    if like is not None:
        contact, separation = float(like.attrs["contact"]), float(like.attrs["separation"])
        falls = like["fall"].values
    contact, separation = check_positive("contact", contact), check_positive("separation", separation)
    if separation <= contact:
        raise ValueError(f"separation: must be > contact ({contact}), got {separation}")
    attrs = {"contact": contact, "separation": separation}
    s_attrs = units("1", "fraction of initially touching pairs still closer than the separation")
    m_attrs = units("d", "mean cage-breaking fall restricted to the fall grid")
    d_attrs = units("d", "median cage-breaking fall")
    if not is_tracks(source):
        kernel, b, b_par, lam, diff = _model_params(case)
        f_end = None if falls is None else float(np.max(falls))
        # the grains' hard core is one diameter; ``contact`` only selects the data's pairs
        res = pair.cage_breaking(kernel, b, lam, b_par, diff, contact=1.0,
                                 separation=separation, start="contact", fall_end=f_end)
        grid_f = np.linspace(0.0, float(res["fall"].values[-1]), 40) \
            if falls is None else np.asarray(falls, float)
        S = np.interp(grid_f, res["fall"].values, res["survival"].values)
        mean, median = _summaries(grid_f, S)
        ds = xr.Dataset({"survival": ("fall", S, s_attrs), "mean_fall": ((), mean, m_attrs),
                         "median_fall": ((), median, d_attrs)},
                        coords={"fall": ("fall", grid_f, units("d", "fall of the pair"))}, attrs=attrs)
        return ds
    x, z, t = positions(source)
    x0, x1, z0, z1 = _region(grid, region)
    starts = check_positive("starts", starts, integer=True)
    first = np.unique(np.linspace(0, t.size - 2, min(starts, t.size - 1)).astype(int))
    rows = _cage_events(x, z, t, first, contact, separation, (x0, x1, z0, z1))
    if not rows:
        raise ValueError(f"contact: no pair of tracked particles closer than {contact} d "
                         "in the region at any start frame")
    data = np.concatenate(rows)
    f, ev, ts = data[:, 0], data[:, 1].astype(bool), data[:, 2]
    blk = block_of(ts, t, blocks)
    if falls is None:
        order = np.sort(f)
        f_max = order[-20] if order.size > 20 else order[-1]
        falls = np.linspace(0.0, max(f_max, 1e-9), 40)
    grid_f = np.asarray(falls, float)

    def stats(mask):
        S = _kaplan_meier(f[mask], ev[mask], grid_f)
        return S, *_summaries(grid_f, S)

    S, mean, median = stats(np.ones(f.size, bool))
    reps = [stats(blk != b) for b in range(blocks)]
    ds = xr.Dataset(coords={"fall": ("fall", grid_f, units("d", "fall of the pair"))},
                    attrs={**attrs, "blocks": blocks, "pairs": int(f.size), "broken": int(ev.sum())})
    for name, value, rep, a in (("survival", S, [r[0] for r in reps], s_attrs),
                                ("mean_fall", mean, [r[1] for r in reps], m_attrs),
                                ("median_fall", median, [r[2] for r in reps], d_attrs)):
        rep = np.asarray(rep, float)
        se = np.sqrt((blocks - 1) / blocks * np.nansum((rep - np.nanmean(rep, axis=0)) ** 2, axis=0))
        with_errors(ds, name, ("fall",) if name == "survival" else (), value, se, rep, a)
    return ds


def _cage_events(x, z, t, first, contact, separation, region) -> list[np.ndarray]:
    """For each start frame ``k`` in ``first``: the pairs closer than ``contact`` (d)
    whose midpoint lies in ``region`` ``(x0, x1, z0, z1)``, followed until they part
    beyond ``separation`` (an event) or one is lost (censored). Returns one array per
    start frame with pairs, rows ``(fall in d, event, start time)``."""
    x0, x1, z0, z1 = region
    rows = []
    for k in first:
        ok = np.isfinite(x[:, k]) & np.isfinite(z[:, k])
        idx = np.nonzero(ok)[0]
        pts = np.column_stack([x[idx, k], z[idx, k]])
        ij = cKDTree(pts).query_pairs(contact, output_type="ndarray")
        if ij.size == 0:
            continue
        a, b = idx[ij[:, 0]], idx[ij[:, 1]]
        zm0 = 0.5 * (z[a, k] + z[b, k])
        xm0 = 0.5 * (x[a, k] + x[b, k])
        keep = (xm0 >= x0) & (xm0 <= x1) & (zm0 >= z0) & (zm0 <= z1)
        a, b, zm0 = a[keep], b[keep], zm0[keep]
        sep = np.hypot(x[a, k:] - x[b, k:], z[a, k:] - z[b, k:])
        fall = np.fmax.accumulate(np.nan_to_num(zm0[:, None] - 0.5 * (z[a, k:] + z[b, k:]),
                                                nan=-np.inf), axis=1)
        broken = sep >= separation
        lost = ~np.isfinite(sep)
        end_b = np.where(broken.any(axis=1), broken.argmax(axis=1), sep.shape[1])
        end_l = np.where(lost.any(axis=1), lost.argmax(axis=1), sep.shape[1])
        event = end_b < end_l
        last = np.where(event, end_b, np.maximum(end_l - 1, 0))
        f_at = fall[np.arange(a.size), np.minimum(last, sep.shape[1] - 1)]
        rows.append(np.column_stack([np.maximum(f_at, 0.0), event, np.full(a.size, t[k])]))
    return rows
