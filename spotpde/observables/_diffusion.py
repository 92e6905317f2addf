"""Diffusion observables (private; see :mod:`spotpde.observables`): diffusion lengths and
Peclet numbers per region, and the growth of the displacement variance with the fall.

Displacements are taken *relative to the local mean flow* of the data themselves (the
coarse-grained velocity of :func:`~spotpde.observables.velocity_field`):

* :func:`diffusion` cuts every track where it first falls through the heights
  ``z_k = k * fall``. Over a segment from ``z_k`` to ``z_(k-1)``, with the mean velocity
  ``u`` at its midpoint, the horizontal residual is ``dx - fall * u_x / |u_z|`` and the
  vertical one ``(dt - fall / |u_z|) |u_z|``; their variances per unit fall are
  ``2 b_p`` and ``2 b_p_par`` (``b_p = D_xx / |u_z|``, ``b_p_par = D_zz / |u_z|``; the
  Peclet numbers are ``Pe_x = d / b_p``, ``Pe_z = d / b_p_par``, Bazant 2004 eq. Pe_est).
* :func:`displacement_growth` takes increments over time lags and subtracts the mean-flow
  displacement integrated along the particle's own path (trapezoid rule over frames):
  ``var(dx)`` against the mean fall, from sub-grain falls (the experiments' super-diffusive
  regime, ``var ~ fall^1.5``) to normal diffusion (``var = 2 b_p fall``).

The model's values are ``D_xx / |u_z|`` and ``D_zz / |u_z|`` of its fields (``u`` the mean
particle velocity), averaged with the data's sample counts.
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr

from ._common import (BLOCKS, block_of, case_for, check_positive, grid_of, is_tracks,
                      jackknife, model_velocity, positions, sample, units, with_errors)
from ._velocity import grid_active, velocity_field

__all__ = ["diffusion", "displacement_growth", "crossings", "path_residuals"]

#: Bins with fewer segments are left NaN.
MIN_SEGMENTS = 30


def crossings(x, z, t, fall: float, z_top: float):
    """First downward crossing of each height ``k * fall`` (``k >= 1``) by each track.

    Returns:
        ``(X, T)``: ``(n_tracks, n_levels + 1)`` arrays of the crossing's ``x`` and time
        (linear interpolation between frames; NaN where the track does not cross); column
        ``k`` is the height ``k * fall`` (column 0 unused).
    """
    n_lev = int(math.floor(z_top / fall))
    X = np.full((x.shape[0], n_lev + 1), np.nan)
    T = np.full_like(X, np.nan)
    za, zb = z[:, :-1], z[:, 1:]
    ok = np.isfinite(za) & np.isfinite(zb) & np.isfinite(x[:, :-1]) & np.isfinite(x[:, 1:]) & (zb < za)
    hi = np.where(ok, np.floor(za / fall), 0).astype(np.int64)
    lo = np.where(ok, np.floor(zb / fall) + 1, 1).astype(np.int64)
    hi, lo = np.minimum(hi, n_lev), np.maximum(lo, 1)
    count = np.where(ok, np.maximum(hi - lo + 1, 0), 0)
    p, j = np.nonzero(count)
    reps = count[p, j]
    p, j = np.repeat(p, reps), np.repeat(j, reps)
    first = np.repeat(np.cumsum(reps) - reps, reps)
    k = lo[p, j] + (np.arange(p.size) - first)
    level = k * fall
    a = (z[p, j] - level) / (z[p, j] - z[p, j + 1])
    xc = x[p, j] + a * (x[p, j + 1] - x[p, j])
    tc = t[j] + a * (t[j + 1] - t[j])
    order = np.lexsort((tc, k, p))                 # by track, level, time
    _, first_of = np.unique((p * (n_lev + 1) + k)[order], return_index=True)
    sel = order[first_of]                          # the first crossing of each level
    X[p[sel], k[sel]] = xc[sel]
    T[p[sel], k[sel]] = tc[sel]
    return X, T


def _bins(grid, size):
    try:
        bz, bx = (float(v) for v in size)
    except (TypeError, ValueError):
        raise ValueError(f"bins: must be (height, width) of a bin in d, got {size!r}") from None
    if not (bz > 0 and bx > 0):
        raise ValueError(f"bins: sizes must be > 0, got {size!r}")
    (x0, x1), (z0, z1) = grid.x_range, grid.z_range
    nz, nx = max(1, int(round((z1 - z0) / bz))), max(1, int(round((x1 - x0) / bx)))
    ez, ex = np.linspace(z0, z1, nz + 1), np.linspace(x0, x1, nx + 1)
    return ez, ex


def _bin_index(ez, ex, z, x):
    iz = np.clip(np.searchsorted(ez, z, side="right") - 1, 0, ez.size - 2)
    ix = np.clip(np.searchsorted(ex, x, side="right") - 1, 0, ex.size - 2)
    return iz * (ex.size - 1) + ix


def _bin_coords(ez, ex):
    return {"z_bin": ("z_bin", 0.5 * (ez[1:] + ez[:-1]), units("d", "height of the bin centre")),
            "x_bin": ("x_bin", 0.5 * (ex[1:] + ex[:-1]), units("d", "horizontal bin centre"))}


def _cell_histogram(grid, x, z):
    h = grid.spacing
    ix = np.clip(np.floor((x - grid.x_range[0]) / h).astype(int), 0, grid.nx - 1)
    iz = np.clip(np.floor((z - grid.z_range[0]) / h).astype(int), 0, grid.nz - 1)
    return np.bincount(iz * grid.nx + ix, minlength=grid.nz * grid.nx).reshape(grid.shape).astype(float)


def _bin_mean(index, nb, val, weights, good):
    num = np.bincount(index, weights=np.where(good, val * weights, 0).ravel(), minlength=nb)
    den = np.bincount(index, weights=np.where(good, weights, 0).ravel(), minlength=nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        return num / den


def _focusing(grid, u, speed, fall):
    """Factors by which a converging mean flow changes the variance of one segment.

    Neighbouring mean paths converge at the rate ``ds/dx`` per unit fall (``s = u_x/|u_z|``,
    negative where the flow converges), so a horizontal deviation shrinks while it grows
    and ``Var dx = 2 b_p fall (1 + fall ds/dx)`` to first order in ``fall ds/dx``;
    vertically the speed rises toward the orifice and ``Var = 2 b_p_par fall
    (1 - fall d|u_z|/dz / |u_z|)``. The model applies them so that it predicts what the
    segment estimator measures (both are first order: keep ``fall`` below the height).
    """
    h = grid.spacing
    slope = u["u_x"] / speed
    ds_dx = np.gradient(slope, h, axis=1)
    dv_dz = np.gradient(speed, h, axis=0)
    return {"b_p": 1.0 + fall * ds_dx, "b_p_par": 1.0 - fall * dv_dz / speed}


def _estimator_bias(u, speed, velocity, fall):
    """Per cell, the segment residual the data's estimator sees from the mean flow alone.

    The data subtract their *coarse-grained* mean flow, so where the true mean flow
    varies on the coarse-graining scale each segment keeps ``fall (s - s_cg)`` (``s`` the
    slope ``u_x / |u_z|``) horizontally and ``fall (|u_cg| / |u| - 1)`` vertically; its
    variance over a bin adds to the measured ``2 b_p fall``. The model predicts the
    measurement by adding the same (``velocity``: the model's field coarse-grained as
    the data's was); ``None`` without it.
    """
    if velocity is None:
        return None
    cg_speed = np.where(velocity["u_z"].values < 0, -velocity["u_z"].values, np.nan)
    return {"b_p": fall * (u["u_x"] / speed - velocity["u_x"].values / cg_speed),
            "b_p_par": fall * (cg_speed / speed - 1.0)}


def _variance(s):
    n = s["n"]
    return (s["q2"] - s["q1"] ** 2 / n) / (n - 1)


def diffusion(source, case=None, *, fall: float = 1.0, bins=(5.0, 5.0), region=None,
              blocks: int = BLOCKS, velocity: xr.Dataset | None = None,
              like: xr.Dataset | None = None, **kwargs) -> xr.Dataset:
    """Diffusion lengths ``b_p``, ``b_p_par`` (d) and Peclet numbers ``Pe_x``, ``Pe_z`` per bin.

    Args:
        source: tracks or a model result.
        case: the case (its grid).
        fall: fall between the heights that cut the tracks into segments, d.
        bins: ``(height, width)`` of the bins, d.
        region: ``(x0, x1, z0, z1)``: segments whose midpoint lies outside are left out
            (default: the silo less 2 d at each side wall, whose layers have a particle
            density and mean flow unlike the bulk's).
        blocks: time blocks of the jackknife (tracks).
        velocity: the tracks' :func:`velocity_field` (computed if not given).
        like: for a model result, the tracks' measurement (its bins and segment counts).
        kwargs: passed to :func:`velocity_field`.

    Returns:
        Dataset on ``("z_bin", "x_bin")``: ``b_p``, ``b_p_par``, ``Pe_x``, ``Pe_z`` (tracks:
        with ``*_se``, ``*_jk``, ``segments`` per bin and ``segment_histogram`` per cell).
    """
    case = case_for(source, case)
    grid = grid_of(case)
    if like is not None:
        fall, bins = float(like.attrs["fall"]), tuple(like.attrs["bins"])
        region = tuple(like.attrs["region"])
    fall = check_positive("fall", fall)
    if region is None:
        region = (grid.x_range[0] + 2.0, grid.x_range[1] - 2.0, *grid.z_range)
    x0, x1, z0, z1 = _region(grid, region)
    ez, ex = _bins(grid, bins)
    attrs = {"fall": fall, "bins": np.asarray(bins, float),
             "region": np.asarray([x0, x1, z0, z1])}
    names = {"b_p": units("d", "horizontal diffusion length per unit fall, D_xx/|u_z|"),
             "b_p_par": units("d", "vertical diffusion length per unit fall, D_zz/|u_z|"),
             "Pe_x": units("1", "horizontal Peclet number d/b_p"),
             "Pe_z": units("1", "vertical Peclet number d/b_p_par")}
    if not is_tracks(source):
        return _model_diffusion(source, case, grid, velocity, like, fall, ez, ex,
                                (x0, x1, z0, z1), attrs, names)
    return _tracks_diffusion(source, case, grid, velocity, blocks, fall, ez, ex,
                             (x0, x1, z0, z1), attrs, names, **kwargs)


def _model_diffusion(source, case, grid, velocity, like, fall, ez, ex, region, attrs, names):
    """:func:`diffusion` of a model result: ``D / |u_z|`` averaged over each bin (weights:
    the tracks' segment histogram ``like`` or the active cells), with the estimator's
    bias from the tracks' mean flow added."""
    x0, x1, z0, z1 = region
    u = model_velocity(source, case)
    speed = np.where(u["u_z"] < 0, -u["u_z"], np.nan)
    weights = (like["segment_histogram"].values if like is not None
               else grid_active(grid).astype(float))
    weights = weights * (((grid.x >= x0) & (grid.x <= x1))[None, :]
                         & ((grid.z >= z0) & (grid.z <= z1))[:, None])
    ds = xr.Dataset(coords=_bin_coords(ez, ex), attrs=attrs)
    Z, X = np.meshgrid(grid.z, grid.x, indexing="ij")
    index = _bin_index(ez, ex, Z.ravel(), X.ravel())
    nb = (ez.size - 1) * (ex.size - 1)
    bias = _estimator_bias(u, speed, velocity, fall)
    focus = _focusing(grid, u, speed, fall)
    for name, comp in (("b_p", "D_xx"), ("b_p_par", "D_zz")):
        val = np.asarray(source[comp].values, float) / speed * focus[name]
        good = np.isfinite(val) & (weights > 0)
        mean = _bin_mean(index, nb, val, weights, good)
        if bias is not None:   # what the data's own mean flow adds to the estimator
            e = bias[name]
            ok = good & np.isfinite(e)
            m1 = _bin_mean(index, nb, e, weights, ok)
            m2 = _bin_mean(index, nb, e * e, weights, ok)
            mean = mean + np.nan_to_num(m2 - m1 * m1) / (2.0 * fall)
        ds[name] = (("z_bin", "x_bin"), mean.reshape(ez.size - 1, ex.size - 1), names[name])
    with np.errstate(divide="ignore"):
        ds["Pe_x"] = (("z_bin", "x_bin"), 1.0 / ds["b_p"].values, names["Pe_x"])
        ds["Pe_z"] = (("z_bin", "x_bin"), 1.0 / ds["b_p_par"].values, names["Pe_z"])
    return ds


def _tracks_diffusion(source, case, grid, velocity, blocks, fall, ez, ex, region, attrs,
                      names, **kwargs):
    """:func:`diffusion` of tracks: the variances of the segments' residual displacements
    per bin, with jackknife errors over ``blocks`` time blocks."""
    x0, x1, z0, z1 = region
    x, z, t = positions(source)
    vel = velocity if velocity is not None else velocity_field(source, case, blocks=blocks, **kwargs)
    X, T = crossings(x, z, t, fall, grid.z_range[1])
    dx = X[:, :-1] - X[:, 1:]              # segment from level k (column k) down to k - 1
    dt = T[:, :-1] - T[:, 1:]
    xm = 0.5 * (X[:, :-1] + X[:, 1:])
    zm = np.broadcast_to((np.arange(X.shape[1] - 1) + 0.5) * fall, xm.shape)
    ts = T[:, 1:]
    ok = np.isfinite(dx) & np.isfinite(dt) & (dt > 0)
    ok[:, 0] = False                        # column 0 is no level (z = 0 is the floor)
    xm, zm, dx, dt, ts = xm[ok], zm[ok], dx[ok], dt[ok], ts[ok]
    ux = sample(grid, vel["u_x"].values, xm, zm)
    uz = sample(grid, vel["u_z"].values, xm, zm)
    good = (np.isfinite(ux) & np.isfinite(uz) & (uz < 0) & (xm >= x0) & (xm <= x1)
            & (zm >= z0) & (zm <= z1))
    xm, zm, dx, dt, ts, ux, uz = (a[good] for a in (xm, zm, dx, dt, ts, ux, uz))
    rx = dx - fall * ux / (-uz)
    rz = (dt - fall / (-uz)) * (-uz)
    blk = block_of(ts, t, blocks)
    nb = (ez.size - 1) * (ex.size - 1)
    flat = blk * nb + _bin_index(ez, ex, zm, xm)

    def sums(q):
        return {"n": np.bincount(flat, minlength=blocks * nb).reshape(blocks, nb).astype(float),
                "q1": np.bincount(flat, weights=q, minlength=blocks * nb).reshape(blocks, nb),
                "q2": np.bincount(flat, weights=q * q, minlength=blocks * nb).reshape(blocks, nb)}

    shape = (ez.size - 1, ex.size - 1)
    count = np.bincount(_bin_index(ez, ex, zm, xm), minlength=nb).reshape(shape)
    enough = count >= MIN_SEGMENTS
    ds = xr.Dataset(coords=_bin_coords(ez, ex), attrs={**attrs, "blocks": blocks})
    for name, pe, q in (("b_p", "Pe_x", rx), ("b_p_par", "Pe_z", rz)):
        s = sums(q)
        for out, f in ((name, lambda s: _variance(s) / (2.0 * fall)),
                       (pe, lambda s: 2.0 * fall / _variance(s))):
            value, se, reps = jackknife(s, f)
            value, se, reps = (np.where(enough.ravel(), a, np.nan).reshape(a.shape[:-1] + shape)
                               for a in (value, se, reps))
            with_errors(ds, out, ("z_bin", "x_bin"), value, se, reps, names[out])
    ds["segments"] = (("z_bin", "x_bin"), count, units("1", "segments per bin"))
    ds["segment_histogram"] = (("z", "x"), _cell_histogram(grid, xm, zm),
                               units("1", "segment midpoints per grid cell"))
    ds = ds.assign_coords(z=("z", grid.z, units("d", "height")), x=("x", grid.x, units("d", "x")))
    return ds


# -- growth of the displacement variance -------------------------------------------------------

def _lags(n_t: int, lags) -> np.ndarray:
    if lags is None:
        return np.unique(np.round(np.geomspace(1, max(1, n_t // 2), 16)).astype(int))
    lags = np.unique(np.asarray(lags, dtype=int))
    if lags.size == 0 or lags.min() < 1 or lags.max() >= n_t:
        raise ValueError(f"lags: frame lags must lie in [1, {n_t - 1}], got {lags}")
    return lags


def _region(grid, region):
    if region is None:
        (x0, x1), (z0, z1) = grid.x_range, grid.z_range
        return x0 + 1.0, x1 - 1.0, z0 + 1.0, z1 - 1.0
    try:
        x0, x1, z0, z1 = (float(v) for v in region)
    except (TypeError, ValueError):
        raise ValueError(f"region: must be (x0, x1, z0, z1) in d, got {region!r}") from None
    if not (x0 < x1 and z0 < z1):
        raise ValueError(f"region: must have x0 < x1 and z0 < z1, got {region!r}")
    return x0, x1, z0, z1


def path_residuals(grid, vel: xr.Dataset, x, z, t):
    """Mean-flow displacement integrated along each particle's own path.

    ``U[p, k] = sum_{j < k} (u(r_j) + u(r_(j+1))) / 2 (t_(j+1) - t_j)`` (trapezoid rule,
    ``u`` the coarse-grained velocity interpolated at the positions), so that the
    displacement relative to the mean flow from frame ``k`` to ``k + L`` is
    ``x[k+L] - x[k] - (U_x[k+L] - U_x[k])``; ``bad[p, k]`` counts the steps before ``k``
    without a position or a velocity (a window is usable when ``bad`` does not change).

    Returns:
        ``(U_x, U_z, bad)``, each ``(particle, t)``.
    """
    ux = sample(grid, vel["u_x"].values, x, z)
    uz = sample(grid, vel["u_z"].values, x, z)
    dts = np.diff(t)[None, :]
    step_bad = ~(np.isfinite(ux[:, 1:]) & np.isfinite(ux[:, :-1]) & np.isfinite(uz[:, 1:])
                 & np.isfinite(uz[:, :-1]) & np.isfinite(x[:, 1:]) & np.isfinite(x[:, :-1]))
    zero = np.zeros((x.shape[0], 1))
    bad = np.concatenate([zero, np.cumsum(step_bad, axis=1)], axis=1)
    out = []
    for u in (ux, uz):
        inc = np.nan_to_num(0.5 * (u[:, 1:] + u[:, :-1]) * dts)
        out.append(np.concatenate([zero, np.cumsum(inc, axis=1)], axis=1))
    return out[0], out[1], bad


def displacement_growth(source, case=None, *, lags=None, region=None,
                        fit_range=(0.005, 0.5), blocks: int = BLOCKS,
                        velocity: xr.Dataset | None = None, like: xr.Dataset | None = None,
                        falls=None, **kwargs) -> xr.Dataset:
    """Variance of the displacement relative to the mean flow against the fall.

    Args:
        source: tracks or a model result.
        case: the case.
        lags: frame lags (default 16 from 1 frame to half the record).
        region: ``(x0, x1, z0, z1)`` where increments start (default the silo less 1 d).
        fit_range: falls (d) over which the exponent of ``var ~ fall^alpha`` is fitted.
        blocks: time blocks of the jackknife (tracks).
        velocity: the tracks' :func:`velocity_field` (computed if not given).
        like: for a model result, the tracks' measurement (its falls and starts).
        falls: for a model result without ``like``, the falls (d) to evaluate.

    Returns:
        Dataset on ``lag``: ``lag_fall`` (mean fall, d), ``var_x``, ``var_z`` (d**2); scalars
        ``exponent_x``, ``exponent_z`` (tracks: with errors; the continuum: 1).
    """
    case = case_for(source, case)
    grid = grid_of(case)
    if like is not None:
        region, fit_range = tuple(like.attrs["region"]), tuple(like.attrs["fit_range"])
    x0, x1, z0, z1 = _region(grid, region)
    attrs = {"region": np.asarray([x0, x1, z0, z1]), "fit_range": np.asarray(fit_range, float)}
    var_attrs = {"var_x": units("d2", "variance of the horizontal displacement relative to the mean flow"),
                 "var_z": units("d2", "variance of the vertical displacement relative to the mean flow")}
    if not is_tracks(source):
        u = model_velocity(source, case)
        speed = np.where(u["u_z"] < 0, -u["u_z"], np.nan)
        Z, X = np.meshgrid(grid.z, grid.x, indexing="ij")
        inside = (X >= x0) & (X <= x1) & (Z >= z0) & (Z <= z1)
        w = (like["start_histogram"].values if like is not None else np.ones(grid.shape)) * inside
        fall = like["lag_fall"].values if like is not None else np.asarray(
            np.geomspace(0.01, 10.0, 12) if falls is None else falls, float)
        ds = xr.Dataset(coords={"lag": np.arange(fall.size)}, attrs=attrs)
        ds["lag_fall"] = ("lag", fall, units("d", "mean fall over the lag"))
        tau = like["lag"].values if like is not None else fall / np.nanmedian(speed)
        for name, comp in (("var_x", "D_xx"), ("var_z", "D_zz")):
            val = np.asarray(source[comp].values, float) / speed
            good = np.isfinite(val) & (w > 0)
            bp = float(np.sum(np.where(good, val * w, 0)) / np.sum(np.where(good, w, 0)))
            var = 2.0 * bp * fall
            if velocity is not None:   # the data's coarse-grained mean flow (see diffusion)
                e = u["u_" + name[-1]] - velocity["u_" + name[-1]].values
                ok = good & np.isfinite(e)
                m1, m2 = (float(np.sum(np.where(ok, q * w, 0)) / np.sum(np.where(ok, w, 0)))
                          for q in (e, e * e))
                var = var + (m2 - m1 * m1) * tau**2
            ds[name] = ("lag", var, var_attrs[name])
        ds["exponent_x"] = ((), 1.0, units("1", "exponent of var_x ~ fall^alpha"))
        ds["exponent_z"] = ((), 1.0, units("1", "exponent of var_z ~ fall^alpha"))
        return ds
    x, z, t = positions(source)
    vel = velocity if velocity is not None else velocity_field(source, case, blocks=blocks, **kwargs)
    lags = _lags(t.size, lags)
    Ux, Uz, bad = path_residuals(grid, vel, x, z, t)
    keys = ("n", "fall", "x1", "x2", "z1", "z2")
    acc = {k: np.zeros((blocks, lags.size)) for k in keys}
    start_hist = np.zeros(grid.shape)
    for i, L in enumerate(lags):
        ok = (bad[:, L:] - bad[:, :-L] == 0) & (x[:, :-L] >= x0) & (x[:, :-L] <= x1) \
            & (z[:, :-L] >= z0) & (z[:, :-L] <= z1)
        rx = (x[:, L:] - x[:, :-L] - (Ux[:, L:] - Ux[:, :-L]))[ok]
        rz = (z[:, L:] - z[:, :-L] - (Uz[:, L:] - Uz[:, :-L]))[ok]
        fall_i = (z[:, :-L] - z[:, L:])[ok]
        blk = block_of(np.broadcast_to(t[:-L], ok.shape)[ok], t, blocks)
        for k, q in (("n", None), ("fall", fall_i), ("x1", rx), ("x2", rx * rx), ("z1", rz), ("z2", rz * rz)):
            acc[k][:, i] = np.bincount(blk, weights=q, minlength=blocks)
        if i == 0:
            start_hist = _cell_histogram(grid, x[:, :-L][ok], z[:, :-L][ok])
    ds = xr.Dataset(coords={"lag": ("lag", t[lags] - t[0], units("t", "time lag"))},
                    attrs={**attrs, "blocks": blocks})
    lo, hi = (float(v) for v in fit_range)

    def exponent(s, comp):
        f = s["fall"] / s["n"]
        v = (s[comp + "2"] - s[comp + "1"] ** 2 / s["n"]) / (s["n"] - 1)
        use = (f >= lo) & (f <= hi) & (v > 0) & np.isfinite(v)
        if use.sum() < 2:
            return np.nan
        return np.polyfit(np.log(f[use]), np.log(v[use]), 1)[0]

    for name, f in (("lag_fall", lambda s: s["fall"] / s["n"]),
                    ("var_x", lambda s: (s["x2"] - s["x1"] ** 2 / s["n"]) / (s["n"] - 1)),
                    ("var_z", lambda s: (s["z2"] - s["z1"] ** 2 / s["n"]) / (s["n"] - 1))):
        value, se, reps = jackknife(acc, f)
        with_errors(ds, name, ("lag",), value, se, reps,
                    var_attrs.get(name, units("d", "mean fall over the lag")))
    for comp in ("x", "z"):
        value, se, reps = jackknife(acc, lambda s, c=comp: exponent(s, c))
        with_errors(ds, f"exponent_{comp}", (), value, se, reps,
                    units("1", f"exponent of var_{comp} ~ fall^alpha over falls {lo:g}-{hi:g} d"))
    ds["samples"] = ("lag", acc["n"].sum(axis=0), units("1", "increments per lag"))
    ds["start_histogram"] = (("z", "x"), start_hist, units("1", "increment starts per grid cell"))
    return ds.assign_coords(z=("z", grid.z, units("d", "height")), x=("x", grid.x, units("d", "x")))
