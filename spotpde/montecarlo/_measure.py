"""Measurements on a discrete spot-model Monte Carlo run (private; see ``montecarlo``).

:func:`measure`: probe fields (``rho_s``, ``u_p``, ``D_p``) and ``P_height`` as an
``xarray.Dataset`` with the continuum result's names; :func:`particle_frames`,
:func:`propagator`; Lagrangian statistics :func:`displacement_statistics` and
:func:`velocity_correlation`. Lengths in d, times in the case's unit.
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr

from .._version import __version__
from ._particles import layer_mask
from ._simulate import MCResult

__all__ = ["measure", "particle_frames", "propagator", "displacement_statistics",
           "velocity_correlation"]


def _da(data, grid, units, long_name, **attrs):
    # CF: lengths in d and times in the case unit are pure numbers (units "1"; "d" would
    # read as a day); the scale goes into the long name and spotpde_units
    return xr.DataArray(data, dims=("z", "x") if grid.dims == 2 else ("z", "y", "x"), attrs={
        "units": "1", "long_name": f"{long_name}, in {units.replace('time', 'time unit')}",
        "spotpde_units": units, **attrs})


def _geometry_names(g, names):
    """Cell measure (spot density's denominator) and field names of the grid's shape: a
    box's ``h**dims`` and names unchanged; rings (``u_r``, ``D_rr``, ..., ring volumes, d**3)
    and hoppers (the material's part of each cell, inactive cells NaN) otherwise."""
    geo = g.geometry
    if geo.uniform_cells:
        return g.spacing**g.dims, names
    vol = np.broadcast_to(geo.cell_volumes * geo.material, g.shape)
    keys = geo.drift_keys + geo.diffusivity_keys
    comp = {"x": geo.components[0]}
    renamed = [(key, u, ln.replace(", x component", f", {comp['x']} component")
                .replace(", xx", f", {comp['x']}{comp['x']}").replace(", xz", f", {comp['x']}z"))
               for key, (_, u, ln) in zip(keys, names)]
    return np.where(np.asarray(geo.active) & (vol > 0), vol, np.nan), renamed


def measure(result: MCResult, tracer: bool = True) -> xr.Dataset:
    """Fields of a run as an ``xarray.Dataset`` with the continuum result's names.

    Probe fields (frozen particles at the grid's cell centres, time averages over the
    run, each with a standard error ``*_se`` from the scatter of time batches):

    * ``rho_s``: spot density (spots per d**2);
    * ``u_x``, ``u_z``: mean particle drift ``u_p`` (d per unit time);
    * ``D_xx``, ``D_xz``, ``D_zz``: ``(1/2T) sum w**2 (dR - <dR>)(dR - <dR>)^T``, the
      mean-field particle diffusivity of the continuum (d**2 per unit time).
    * 3D runs (``simulate(..., probes=True)`` on a 3D grid): fields on ``(z, y, x)``, with
      ``u_y``, ``D_yy``, ``D_xy``, ``D_yz`` besides; ``rho_s`` in spots per d**3.

    With tracked particles, ``tracer=True`` and the default crossing levels (``grid.z``):
    ``P_height`` (density over x of where the tracked particles first cross each height,
    normalised by their number). For other levels call :func:`propagator`.

    Attributes: ``V1``, ``V2``, ``rule``, ``gamma``, ``step``, ``t_end``, ``seed``,
    counters and performance, ``spotpde_version``, ``source = "montecarlo"``.
    """
    g = result.grid
    coords = {"z": ("z", g.z, {"units": "1", "long_name": "height above the orifice, in particle diameters"}),
              "x": ("x", g.x, {"units": "1", "long_name": "horizontal position, in particle diameters"})}
    if g.dims == 3:
        coords["y"] = ("y", g.y, {"units": "1", "long_name": "depth, in particle diameters"})
    ds = xr.Dataset(coords=coords)
    if result.probe is not None:
        bt = result.batch_ticks.astype(float) * result.dt  # duration of each batch
        ok = bt > 0
        lead = (slice(None),) + (None,) * g.dims
        per = result.probe[:, ok] / bt[ok][(None,) + lead]
        nb = per.shape[1]
        mean = result.probe.sum(axis=1) / result.t_end
        se = per.std(axis=1, ddof=1) / math.sqrt(nb) if nb > 1 else np.full_like(mean, np.nan)
        drifts = ("x", "z") if g.dims == 2 else ("x", "y", "z")
        pairs = ("xx", "xz", "zz") if g.dims == 2 else ("xx", "yy", "zz", "xy", "xz", "yz")
        names = ([(f"u_{c}", "d / time", f"particle drift u_p, {c} component") for c in drifts]
                 + [(f"D_{c}", "d**2 / time", f"particle diffusivity D_p, {c}") for c in pairs])
        h2, names = _geometry_names(g, names)
        for k, (name, units, ln) in enumerate(names):
            f = 1.0 if k < len(drifts) else 0.5
            ds[name] = _da(f * mean[k], g, units, ln + " (Monte Carlo probes)")
            ds[name + "_se"] = _da(f * se[k], g, units, "standard error of " + name)
        rb = result.rho_hist[ok] / (result.batch_ticks[ok][lead] * h2)
        # rings: spots per unit volume (d**-3); boxes: per d**dims
        rho_units = "1 / d**3" if g.geometry.curved else f"1 / d**{g.dims}"
        ds["rho_s"] = _da(result.rho_hist.sum(axis=0) / (result.n_ticks * h2), g, rho_units,
                          "spot density (Monte Carlo)")
        ds["rho_s_se"] = _da(rb.std(axis=0, ddof=1) / math.sqrt(nb) if nb > 1
                             else np.full(g.shape, np.nan), g, rho_units,
                             "standard error of rho_s")
    same_levels = (result.levels.size == g.nz and np.allclose(result.levels, g.z))
    if tracer and result.tracked.size and same_levels:
        ds["P_height"] = propagator(result).assign_coords(z=g.z, x=g.x)
    kp = result.kernel
    ds.attrs.update({
        "V1": kp.V1, "V2": kp.V2, "rule": result.rule, "gamma": result.gamma,
        "step": result.step, "t_end": result.t_end, "seed": result.seed,
        "steps": result.steps, "source": "montecarlo", "spotpde_version": __version__,
        "kernel_walls": result.walls,
        **{k: v for k, v in result.counters.items()},
        **{k: v for k, v in result.performance.items()},
    })
    return ds


def particle_frames(result: MCResult, layer_spacing: float | None = None) -> xr.Dataset:
    """Tracked particle positions as a Dataset on dims ``("t", "particle")``.

    Frame 0 is the initial state (``t = 0``), then one frame per snapshot. With
    ``layer_spacing`` a boolean ``layer`` variable marks particles that started in the
    coloured bands ``[k s, k s + s/2)`` (the layered-silo picture, docs/interface.md, ``tracer.layers``),
    so the discrete layered silo is ``plt.scatter(f.x[k], f.z[k], c=f.layer)``. A 3D
    run also gets ``y``.
    """
    start = result.initial[result.tracked]
    pos = np.concatenate([start[None], result.positions], axis=0)
    t = np.concatenate([[0.0], result.times])
    ds = xr.Dataset(
        {"x": (("t", "particle"), pos[..., 0], {"units": "1", "long_name": "particle x (NaN: gone), in particle diameters"}),
         "z": (("t", "particle"), pos[..., 1], {"units": "1", "long_name": "particle z (NaN: gone), in particle diameters"})},
        coords={"t": ("t", t, {"units": "1", "long_name": "time, in the case's time unit"}),
                "particle": ("particle", result.tracked)})
    if pos.shape[-1] == 3:
        ds["y"] = (("t", "particle"), pos[..., 2],
                   {"units": "1", "long_name": "particle y (NaN: gone), in particle diameters"})
    if layer_spacing is not None:
        ds["layer"] = ("particle", layer_mask(start[:, 1], layer_spacing),
                       {"units": "1", "long_name": f"started in a coloured band (spacing {layer_spacing} d)"})
    return ds


def propagator(result: MCResult, select: np.ndarray | None = None) -> xr.DataArray:
    """Geometrical propagator ``P_height`` of the tracked particles.

    At each crossing level (``result.levels``; by default the grid's cell centres), the
    density over x of where the selected tracked particles first fell through it: a
    histogram over the grid's x cells divided by (number of particles * h). Its integral
    over x is the fraction that reached that height.

    Args:
        result: a run with tracked particles.
        select: boolean mask over the tracked particles (default all).
    """
    g = result.grid
    cx = result.cross_x if select is None else result.cross_x[np.asarray(select)]
    n = max(cx.shape[0], 1)
    edges = np.concatenate([g.x - 0.5 * g.spacing, [g.x[-1] + 0.5 * g.spacing]])
    out = np.zeros((result.levels.size, g.nx))
    for k in range(result.levels.size):
        v = cx[:, k]
        v = v[np.isfinite(v)]
        out[k] = np.histogram(v, bins=edges)[0] / (n * g.spacing)
    return xr.DataArray(out, dims=("z", "x"),
                        coords={"z": ("z", result.levels, {"units": "1", "long_name": "in particle diameters"}), "x": ("x", g.x, {"units": "1", "long_name": "in particle diameters"})},
                        attrs={"units": "1", "spotpde_units": "1 / d", "long_name":
                               "geometrical propagator: density over x of first crossings of height z "
                               "(Monte Carlo), per particle diameter", "n_particles": int(cx.shape[0])})


def _windows(result: MCResult, select=None):
    """Displacement increments of tracked particles between consecutive snapshots.

    Returns (dx, dz, tau, start) with dx, dz of shape (n_windows, n_tracked) (NaN where a
    particle was gone at either end), tau the window durations, start the positions at
    each window's start (n_windows, n_tracked, 2) (3D: ``(.., 3)``, columns ``(x, z, y)``).
    """
    pos = np.concatenate([result.initial[result.tracked][None], result.positions], axis=0)
    times = np.concatenate([[0.0], result.times])
    if select is not None:
        pos = pos[:, np.asarray(select)]
    d = pos[1:] - pos[:-1]
    return d[..., 0], d[..., 1], np.diff(times), pos[:-1]


def displacement_statistics(result: MCResult, select=None, skip: int = 0) -> dict:
    """Lagrangian drift, diffusivities and diffusion lengths of the tracked particles.

    Windows are the intervals between snapshots. In each window ``k`` the mean over
    particles of ``dx``, ``dz`` and of the centred squares gives ``U_k``, ``D_k``; the
    results are the window averages and their standard errors (windows are nearly
    independent when long compared with a spot's passage). Intended for uniform flow
    (spatially uniform statistics).

    Args:
        result: a run with tracked particles and several snapshots.
        select: boolean mask over tracked particles (e.g. away from walls).
        skip: number of initial windows to drop (transient).

    Returns:
        dict with ``u_x``, ``u_z`` (d/time), ``D_xx``, ``D_zz``, ``D_xz`` (d**2/time),
        ``b_p = D_xx / |u_z|`` and ``b_p_par = D_zz / |u_z|`` (d), each with ``*_se``,
        and ``n_windows``, ``n_particles``; a 3D run adds ``u_y`` and ``D_yy``.
    """
    dx, dz, tau, start = _windows(result, select)
    dx, dz, tau = dx[skip:], dz[skip:], tau[skip:]
    ok = np.isfinite(dx) & np.isfinite(dz)
    keep = ok.all(axis=0)
    dx, dz = dx[:, keep], dz[:, keep]
    extra = ()
    if start.shape[-1] == 3:  # 3D: the y component too
        pos = np.concatenate([result.initial[result.tracked][None], result.positions], axis=0)
        if select is not None:
            pos = pos[:, np.asarray(select)]
        dy = np.diff(pos[..., 2], axis=0)[skip:][:, keep]
        my = dy.mean()
        extra = (("u_y", dy.mean(axis=1) / tau), ("D_yy", ((dy - my) ** 2).mean(axis=1) / (2 * tau)))
    ux = dx.mean(axis=1) / tau
    uz = dz.mean(axis=1) / tau
    mx = dx.mean()  # the drift is common to all windows when tau is constant
    mz = dz.mean()
    Dxx = ((dx - mx) ** 2).mean(axis=1) / (2 * tau)
    Dzz = ((dz - mz) ** 2).mean(axis=1) / (2 * tau)
    Dxz = ((dx - mx) * (dz - mz)).mean(axis=1) / (2 * tau)
    n = ux.size
    out = {"n_windows": n, "n_particles": int(keep.sum())}
    for name, v in (("u_x", ux), ("u_z", uz), ("D_xx", Dxx), ("D_zz", Dzz), ("D_xz", Dxz),
                    *extra):
        out[name] = float(v.mean())
        out[name + "_se"] = float(v.std(ddof=1) / math.sqrt(n)) if n > 1 else math.nan
    # ratios with jackknife errors over windows
    for name, num in (("b_p", Dxx), ("b_p_par", Dzz)):
        est = num.mean() / abs(uz.mean())
        if n > 2:
            jk = np.array([np.delete(num, i).mean() / abs(np.delete(uz, i).mean()) for i in range(n)])
            se = math.sqrt((n - 1) / n * np.sum((jk - jk.mean()) ** 2))
        else:
            se = math.nan
        out[name] = float(est)
        out[name + "_se"] = float(se)
    return out


def velocity_correlation(result: MCResult, bins: np.ndarray, select=None, component: str = "x",
                         skip: int = 0, centre: str = "ensemble") -> xr.Dataset:
    """Spatial correlation of tracked particles' displacement fluctuations.

    ``C(r) = <dq_i dq_j> / <dq**2>`` over pairs whose separation at the window's start
    falls in each bin, the discrete counterpart of the continuum ``C_p(r)`` (eq. Cp).
    ``dq`` is the displacement component minus the mean drift of the whole run (mean
    rate over all windows and particles, times the window's duration). Standard errors
    from the scatter over windows (make windows longer than a spot's passage, ``2R/v_s``).

    ``centre="window"`` subtracts each window's own mean over its ``N`` particles instead;
    that removes the common displacement the particles share and biases ``C`` low by about
    ``2/N sum_k C(r_ik)`` (-0.02 to -0.04 for 150 particles on a 1.5 d lattice with a
    Gaussian kernel of sigma 1): kept only to show the bias.

    Args:
        bins: separation bin edges in d.
        select: boolean mask over tracked particles. component: ``"x"`` or ``"z"``, or
            ``"y"`` (the depth) for a 3D run.
        skip: number of initial windows to drop.
        centre: ``"ensemble"`` (default, unbiased) or ``"window"``.

    Returns:
        Dataset with ``C`` and ``C_se`` on dim ``r`` (the mean separation of the pairs in
        each bin, d) and ``pairs``; bins with pairs in fewer than two windows (no
        standard error) are left out.
    """
    if centre not in ("ensemble", "window"):
        raise ValueError(f"centre: must be 'ensemble' or 'window', got {centre!r}")
    dx, dz, tau, start = _windows(result, select)
    if component not in ("x", "z", "y") or (component == "y" and start.shape[-1] != 3):
        raise ValueError(f"component: must be 'x' or 'z' (or 'y' in 3D), got {component!r}")
    if component == "y":
        pos = np.concatenate([result.initial[result.tracked][None], result.positions], axis=0)
        d = np.diff(pos[..., 2] if select is None else pos[:, np.asarray(select), 2], axis=0)
    else:
        d = dx if component == "x" else dz
    d = d[skip:]
    tau = tau[skip:]
    start = start[skip:]
    with np.errstate(invalid="ignore"):
        rate = float(np.nanmean(d / tau[:, None]))
    bins = np.asarray(bins, float)
    nbin = bins.size - 1
    per = np.full((d.shape[0], nbin), np.nan)
    pairs = np.zeros(nbin, np.int64)
    rsum = np.zeros(nbin)
    for k in range(d.shape[0]):
        ok = np.isfinite(d[k])
        q = d[k, ok] - (d[k, ok].mean() if centre == "window" else rate * tau[k])
        p = start[k, ok]
        var = np.mean(q * q)
        iu, ju = np.triu_indices(q.size, 1)
        r = (np.hypot(*(p[iu] - p[ju]).T) if p.shape[1] == 2
             else np.sqrt(((p[iu] - p[ju]) ** 2).sum(axis=1)))
        which = np.digitize(r, bins) - 1
        good = (which >= 0) & (which < nbin)
        prod = q[iu][good] * q[ju][good] / var
        s = np.bincount(which[good], weights=prod, minlength=nbin)
        c = np.bincount(which[good], minlength=nbin)
        per[k] = np.where(c > 0, s / np.maximum(c, 1), np.nan)
        pairs += c
        rsum += np.bincount(which[good], weights=r[good], minlength=nbin)
    n = np.sum(np.isfinite(per), axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        C = np.array([np.mean(c[np.isfinite(c)]) if m else np.nan for c, m in zip(per.T, n)])
        se = np.array([np.std(c[np.isfinite(c)], ddof=1) / math.sqrt(m) if m > 1 else np.nan
                       for c, m in zip(per.T, n)])
        rc = np.where(pairs > 0, rsum / np.maximum(pairs, 1), np.nan)
    keep = n >= 2   # pairs in at least two windows: a mean and a standard error
    C, se, pairs, rc = C[keep], se[keep], pairs[keep], rc[keep]
    return xr.Dataset(
        {"C": ("r", C, {"units": "1", "long_name": f"velocity correlation C_p ({component}), Monte Carlo"}),
         "C_se": ("r", se, {"units": "1", "long_name": "standard error of C"}),
         "pairs": ("r", pairs, {"units": "1", "long_name": "pair samples per bin"})},
        coords={"r": ("r", rc, {"units": "1", "long_name": "separation, in particle diameters"})})
