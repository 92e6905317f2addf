"""Mean-flow observables (private; see :mod:`spotpde.observables`): the coarse-grained
velocity field, downward-speed profiles and the Kinematic-Model width ``b(z)``.

Data: velocities of the increments between frames ``k`` and ``k + lag`` of every track,
``(r_{k+lag} - r_k) / (t_{k+lag} - t_k)``, placed at the increment's midpoint and
coarse-grained with a Gaussian of standard deviation ``width`` (``_common.coarse_grain``):
``u(r) = sum_i phi(r - r_i) v_i / sum_i phi(r - r_i)`` (mass-weighted, as Weinhart et al.
coarse-grain momentum over density). Model: the mean particle velocity
(``_common.model_velocity``) coarse-grained with the same kernel and the data's sample
counts as weights, so that both are the same average of the same field.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from ..density.kinematic import fit_profile
from ._common import (BLOCKS, block_of, case_for, check_positive, coarse_grain, grid_of,
                      is_tracks, jackknife, model_velocity, positions, smooth_like, units,
                      with_errors)

__all__ = ["velocity_field", "velocity_profiles", "kinematic_width", "profiles_of", "width_of"]

#: Cells whose coarse-graining weight ``sum phi`` is below this (samples) are left NaN.
MIN_WEIGHT = 5.0


def velocity_field(source, case=None, *, width: float = 1.0, blocks: int = BLOCKS, lag: int = 1,
                   like: xr.Dataset | None = None) -> xr.Dataset:
    """Coarse-grained mean particle velocity ``u_x``, ``u_z`` on the case's grid.

    Args:
        source: tracks (``spotpde.tracks.read``) or a model result (``spotpde.run``).
        case: the case (its grid; for a model result default its own ``case`` attribute).
        width: standard deviation of the Gaussian coarse-graining kernel, d.
        blocks: time blocks of the jackknife errors (tracks).
        lag: frames between the two ends of an increment (tracks).
        like: for a model result, the tracks measurement to mirror (its coarse-graining
            width and sample counts).

    Returns:
        Dataset on ``("z", "x")``: ``u_x``, ``u_z`` (d per time unit); for tracks also
        ``*_se``, ``*_jk`` (dim ``block``), ``weight`` (``sum phi``) and ``histogram``.
    """
    case = case_for(source, case)
    grid = grid_of(case)
    if like is not None:
        width = float(like.attrs.get("cg_width", width))
    width = check_positive("width", width)
    coords = {"z": ("z", grid.z, units("d", "height above the orifice")),
              "x": ("x", grid.x, units("d", "horizontal position"))}
    attrs = {"cg_width": width, "cg_kernel": "Gaussian, cut at 3 standard deviations"}
    if not is_tracks(source):
        u = model_velocity(source, case)
        weights = like["histogram"].values if like is not None and "histogram" in like else None
        ds = xr.Dataset(coords=coords, attrs=attrs)
        for k in ("u_x", "u_z"):
            ds[k] = (("z", "x"), smooth_like(grid, u[k], weights, width),
                     units("d t-1", f"mean particle velocity, {k[2]} component"))
        return ds
    lag = check_positive("lag", lag, integer=True)
    x, z, t = positions(source)
    if t.size <= lag:
        raise ValueError(f"lag: the tracks have {t.size} frames, fewer than lag + 1 = {lag + 1}")
    dt = (t[lag:] - t[:-lag])[None, :]
    vx = (x[:, lag:] - x[:, :-lag]) / dt
    vz = (z[:, lag:] - z[:, :-lag]) / dt
    mx, mz = 0.5 * (x[:, lag:] + x[:, :-lag]), 0.5 * (z[:, lag:] + z[:, :-lag])
    tm = np.broadcast_to(0.5 * (t[lag:] + t[:-lag]), vx.shape)
    ok = np.isfinite(vx) & np.isfinite(vz)
    blk = block_of(tm[ok], t, blocks)
    sums = coarse_grain(grid, mx[ok], mz[ok], {"vx": vx[ok], "vz": vz[ok]}, blk, blocks, width)
    histogram = sums.pop("histogram")
    weight = sums["count"].sum(axis=0)
    mask = (weight >= MIN_WEIGHT) & grid_active(grid)
    ds = xr.Dataset(coords=coords, attrs={**attrs, "blocks": blocks, "lag": lag})
    for name, q in (("u_x", "vx"), ("u_z", "vz")):
        value, se, reps = jackknife({"n": sums["count"], "q": sums[q]},
                                    lambda s, q=q: s["q"] / s["n"])
        value, se = np.where(mask, value, np.nan), np.where(mask, se, np.nan)
        reps = np.where(mask, reps, np.nan)
        with_errors(ds, name, ("z", "x"), value, se, reps,
                    units("d t-1", f"mean particle velocity, {name[2]} component"))
    ds["weight"] = (("z", "x"), weight, units("1", "coarse-graining weight sum phi (samples)"))
    ds["histogram"] = (("z", "x"), histogram, units("1", "velocity samples per cell"))
    return ds


def grid_active(grid) -> np.ndarray:
    """Cells inside the material (all cells without a hopper)."""
    return np.array(grid.active, bool)


def default_heights(grid) -> np.ndarray:
    """Six heights from 10 % to 85 % of the silo."""
    z0, z1 = grid.z_range
    return np.round(z0 + np.linspace(0.1, 0.85, 6) * (z1 - z0), 1)


def _rows(grid, heights) -> np.ndarray:
    heights = np.atleast_1d(np.asarray(heights, float))
    if heights.ndim != 1 or not np.all(np.isfinite(heights)):
        raise ValueError(f"heights: must be finite heights in d, got {heights!r}")
    z0, z1 = grid.z_range
    if np.any((heights <= z0) | (heights >= z1)):
        raise ValueError(f"heights: must lie inside the silo ({z0:g}, {z1:g}) d, got {heights}")
    return np.unique(np.clip(np.round((heights - grid.z[0]) / grid.spacing).astype(int), 0, grid.nz - 1))


def profiles_of(vel: xr.Dataset, grid, heights=None) -> xr.Dataset:
    """Downward speed ``v_z = -u_z`` at the grid rows nearest ``heights`` (dim ``height``)."""
    rows = _rows(grid, default_heights(grid) if heights is None else heights)
    out = xr.Dataset(coords={"height": ("height", grid.z[rows], units("d", "height of the profile")),
                             "x": vel["x"]})
    for suffix in ("", "_se", "_jk"):
        if "u_z" + suffix in vel:
            a = vel["u_z" + suffix].isel(z=rows).rename(z="height").drop_vars("height")
            out["v_z" + suffix] = (-a if suffix != "_se" else a)
            out["v_z" + suffix].attrs = units("d t-1", "downward particle speed" + (
                " (standard error)" if suffix == "_se" else ""))
    return out


def velocity_profiles(source, case=None, heights=None, **kwargs) -> xr.Dataset:
    """Downward-speed profiles ``v_z(height, x)`` (d per time unit) at the grid rows nearest
    ``heights`` (default six heights from 10 % to 85 % of the silo); ``kwargs`` as
    :func:`velocity_field`."""
    case = case_for(source, case)
    return profiles_of(velocity_field(source, case, **kwargs), grid_of(case), heights)


# -- the Kinematic-Model width -----------------------------------------------------------------

def width_of(vel: xr.Dataset, case, heights=None, weights: xr.Dataset | None = None) -> xr.Dataset:
    """Kinematic-Model width ``b(z) = s(z) / z`` and flux at each height of the profiles.

    At each height the downward-speed profile is fitted by ``A K(x; s + width^2/2)``, ``K``
    the closed-form Kinematic-Model profile with the case's orifice and walls
    (``spotpde.kinematic.slot_profile``; ``width^2/2`` undoes the coarse-graining's
    broadening), weighted by the profile's standard errors (``weights``' for a model
    profile). ``b = s / z`` is the constant ``b`` that would give the profile at that
    height (the running mean of a height-dependent ``b``); ``A`` is the particle flux
    through the height (d**2 per time unit).
    """
    grid = grid_of(case)
    prof = profiles_of(vel, grid, heights)
    ref = prof if weights is None else profiles_of(weights, grid, heights)
    se_all = ref["v_z_se"].values if "v_z_se" in ref else None
    s_cg = 0.5 * float(vel.attrs.get("cg_width", 0.0)) ** 2
    s_range = (1e-3, 1e3 * (grid.x_range[1] - grid.x_range[0]) ** 2)
    x = prof["x"].values
    out_b, out_a = [], []
    reps = prof["v_z_jk"].values if "v_z_jk" in prof else None
    for j, z in enumerate(prof["height"].values):
        se = None if se_all is None else se_all[j]
        rows = [prof["v_z"].values[j]] + ([] if reps is None else list(reps[:, j]))
        fits = [fit_profile(x, v, case.orifice, grid.x_range, grid.walls, se=se,
                            broadening=s_cg, s_range=s_range) for v in rows]
        out_b.append([f[0] / z for f in fits])
        out_a.append([f[1] for f in fits])
    out_b, out_a = np.asarray(out_b), np.asarray(out_a)
    ds = xr.Dataset(coords={"height": prof["height"]})
    attrs_b = units("d", "Kinematic-Model width b = s/z fitted to the downward-speed profile")
    attrs_a = units("d2 t-1", "particle flux through the height (fitted profile amplitude)")
    if reps is None:
        ds["b_kin"] = ("height", out_b[:, 0], attrs_b)
        ds["flux"] = ("height", out_a[:, 0], attrs_a)
        return ds
    B = reps.shape[0]
    for name, arr, attrs in (("b_kin", out_b, attrs_b), ("flux", out_a, attrs_a)):
        jk = arr[:, 1:].T
        se = np.sqrt((B - 1) / B * np.nansum((jk - np.nanmean(jk, axis=0)) ** 2, axis=0))
        with_errors(ds, name, ("height",), arr[:, 0], np.where(np.isfinite(arr[:, 0]), se, np.nan),
                    jk, attrs)
    return ds


def kinematic_width(source, case=None, heights=None, *, like: xr.Dataset | None = None,
                    **kwargs) -> xr.Dataset:
    """Fitted Kinematic-Model width ``b_kin(height)`` (d) and ``flux(height)`` (d**2 per
    time unit) from the coarse-grained downward-speed profiles (:func:`width_of`);
    ``kwargs`` as :func:`velocity_field`. For a model result, ``like`` (the tracks'
    velocity measurement) supplies the coarse-graining and the fit's weights."""
    case = case_for(source, case)
    vel = velocity_field(source, case, like=like, **kwargs)
    return width_of(vel, case, heights, weights=like)
