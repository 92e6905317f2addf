"""Diagnostics of the layered silo: how sharp the coloured layers stay, and how much of
their blur is numerical.

A layered tracer run (``[tracer] layers = {spacing}``, e.g. ``cases/quasi2d_layers.toml``)
starts with ``P`` uniform on horizontal bands and zero between them. With ``p = P / P_band``
(``P_band`` the band value at t = 0) the picture is the concentration of coloured
particles: 1 in a band, 0 in a gap, in between where bands and gaps have mixed.
All functions take the result Dataset of :func:`spotpde.run` (``P`` on dims
``(t, z, x)``; a 3D result is read in its ``y`` mid-plane) and measure in a *region*
away from the orifice, the walls and the free top (default ``|x| < 8 d``,
``5 d < z < 40 d``, the same as ``notebooks/layered_silo.ipynb``). Lengths in d, times in
the case's time unit.

* :func:`layer_contrast`: per column ``max p - min p``, averaged over the columns
  (1: fully separated layers; it falls as bands blur into gaps).
* :func:`interface_width`: the mean width ``sigma`` of the band edges, measured normal
  to the edges whatever their tilt::

      sigma = sqrt(pi) * integral p (1 - p) dA / integral |grad p| dA

  For an error-function edge ``p = Phi(n / sigma)`` the numerator per unit edge length
  is ``sigma / sqrt(pi)`` exactly and the denominator (the total variation) is the edge
  length, so ``sigma`` is the edge's standard deviation (``sigma**2`` its variance,
  which diffusion grows by ``2 D_nn t``). Stretching an edge changes both integrals
  alike, so the advective lengthening of the edges does not count as blur. It is
  meaningful while the bands still reach 0 and 1 (contrast near 1); once bands merge
  the total variation drops and ``sigma`` overstates the blur.
* :func:`spotpde.layers.numerical_blur`: the measured numerical diffusion of a run. The same case is
  rerun with the physical diffusivity switched off (``D_p = 0``; same drift, grid,
  limiter, CFL number), so any broadening of its edges is the scheme's. The physical
  broadening is the difference ``var_phys = sigma_run**2 - sigma_num**2`` (edge
  variances add: the width equation ``d var/dt = 2 D_nn - 2 gamma var`` of an edge in a
  flow of normal strain rate ``gamma`` is linear in its sources), and
  ``var_pred = 2 integral <D_nn> dt`` is the physical prediction along the path without
  the strain (an upper estimate: the converging flow stretches and thins edges).

Two numbers come out, because a sharp edge on a grid is blurred in two ways:

* the *capture width*: a step advected by a fraction of a cell is at once spread over
  about one cell (WENO5: ``sigma ~ h``) and then stays that wide; it does not grow and
  it halves when ``h`` halves. ``ratio = var_num / var_phys`` at the last frame counts
  it in full (everything the grid adds, relative to the physical broadening).
* numerical *diffusion*: growth of the edge variance of the ``D_p = 0`` run in time.
  ``growth_ratio = D_num / D_phys`` compares the growth rates (least-squares slopes
  over the second half of the run) of ``var_num`` and ``var_phys``. First-order upwind
  gives ``D_num = |u| h / 2``, about 80 times the spot model's ``D_p = b_p |u|`` at
  ``h = 0.5 d``; a scheme fit for the spot model keeps this well below 1.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import xarray as xr

#: Default measuring region: |x| < X_MAX d, Z_RANGE[0] < z < Z_RANGE[1] d.
X_MAX = 8.0
Z_RANGE = (5.0, 40.0)


def _plane(ds: xr.Dataset) -> xr.Dataset:
    if "y" in ds.dims:
        return ds.isel(y=ds.sizes["y"] // 2)
    return ds


def concentration(ds: xr.Dataset, P: xr.DataArray | None = None) -> xr.DataArray:
    """``p = P / P_band``: the coloured-particle concentration (1 in an initial band).

    Args:
        ds: layered result Dataset.
        P: other frames on the same grid (e.g. the ``D_p = 0`` run); default ``ds.P``.

    Returns:
        DataArray on ``(t, z, x)``, dimensionless.
    """
    m = _plane(ds)
    band = float(m.P.isel(t=0).max())
    if not band > 0:
        raise ValueError("the first frame of P is zero everywhere: not a layered start")
    P = m.P if P is None else _plane(P.to_dataset(name="P")).P
    return P / band


def _region(p: xr.DataArray, x_max: float, z_range: tuple[float, float]) -> np.ndarray:
    """Boolean mask (z, x) of the region."""
    x = np.asarray(p.x)
    z = np.asarray(p.z)
    return (np.abs(x) < x_max)[None, :] & ((z > z_range[0]) & (z < z_range[1]))[:, None]


def layer_contrast(ds: xr.Dataset, *, x_max: float = X_MAX,
                   z_range: tuple[float, float] = Z_RANGE,
                   P: xr.DataArray | None = None) -> np.ndarray:
    """Layer contrast per frame: per column ``max p - min p`` in the region, averaged.

    Args:
        ds: layered result Dataset.
        x_max, z_range: the region (d).
        P: frames to measure instead of ``ds.P`` (same grid and band value).

    Returns:
        (frames,) array: 1 for fully separated bands, lower as they blur into each other.
    """
    p = concentration(ds, P)
    mask = _region(p, x_max, z_range)
    cols = mask.any(axis=0)
    rows = mask.any(axis=1)
    sub = np.asarray(p)[:, rows][:, :, cols]
    return sub.max(axis=1).mean(axis=-1) - sub.min(axis=1).mean(axis=-1)


def _gradient(p: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    gz, gx = np.gradient(p, h, h)
    return gz, gx


def _width_parts(p: np.ndarray, h: float, mask: np.ndarray):
    q = np.clip(p, 0.0, 1.0)
    gz, gx = _gradient(p, h)
    g = np.hypot(gx, gz)
    mixed = float((q * (1.0 - q))[mask].sum())
    tv = float(g[mask].sum())
    return mixed, tv, gx, gz, g


def interface_width(ds: xr.Dataset, *, x_max: float = X_MAX,
                    z_range: tuple[float, float] = Z_RANGE,
                    P: xr.DataArray | None = None) -> np.ndarray:
    """Mean width of the band edges per frame, normal to the edges, in d.

    ``sigma = sqrt(pi) * sum p (1 - p) / sum |grad p|`` over the region (``p`` clipped
    to [0, 1] in the numerator; central differences): the standard deviation of an
    error-function edge, whatever its tilt; 0 for a step lying on cell faces (the start).

    Args:
        ds: layered result Dataset.
        x_max, z_range: the region (d).
        P: frames to measure instead of ``ds.P``.

    Returns:
        (frames,) array of ``sigma`` in d (NaN where the region has no edge).
    """
    p = concentration(ds, P)
    h = float(p.x[1] - p.x[0])
    mask = _region(p, x_max, z_range)
    out = []
    for frame in np.asarray(p):
        mixed, tv, *_ = _width_parts(frame, h, mask)
        out.append(np.sqrt(np.pi) * mixed / tv if tv > 0 else np.nan)
    return np.array(out)


def predicted_variance(ds: xr.Dataset, *, x_max: float = X_MAX,
                       z_range: tuple[float, float] = Z_RANGE) -> np.ndarray:
    """Physical edge variance ``2 integral_0^t <D_nn> dt`` per frame (d**2), no strain.

    ``D_nn = n.D_p.n`` with ``n = grad p / |grad p|`` the edge normal of each frame,
    averaged over the region with weight ``|grad p|`` (per unit edge length), and
    integrated over the frames by the trapezoidal rule. The converging flow's strain
    thins edges, which this leaves out, so it is an upper estimate of what diffusion
    alone does to the edges.
    """
    p = concentration(ds)
    m = _plane(ds)
    h = float(p.x[1] - p.x[0])
    mask = _region(p, x_max, z_range)
    Dxx, Dzz = np.asarray(m.D_xx), np.asarray(m.D_zz)
    Dxz = np.asarray(m.D_xz)
    rate = []
    for frame in np.asarray(p):
        _, tv, gx, gz, g = _width_parts(frame, h, mask)
        if tv <= 0:
            rate.append(0.0)
            continue
        w = g[mask]
        safe = np.where(w > 0, w, 1.0)
        nx, nz = gx[mask] / safe, gz[mask] / safe
        dnn = Dxx[mask] * nx**2 + 2 * Dxz[mask] * nx * nz + Dzz[mask] * nz**2
        rate.append(float((w * dnn).sum() / w.sum()))
    rate = np.array(rate)
    t = np.asarray(ds.t, dtype=float)
    steps = 0.5 * (rate[1:] + rate[:-1]) * np.diff(t)
    return 2.0 * np.concatenate([[0.0], np.cumsum(steps)])


def _slope(t: np.ndarray, v: np.ndarray) -> float:
    if t.size < 2:
        return float("nan")
    return float(np.polyfit(t, v, 1)[0])


def measure_blur(case, ds: xr.Dataset, P_num: xr.DataArray, *, x_max: float = X_MAX,
                 z_range: tuple[float, float] = Z_RANGE) -> dict:
    """Measured numerical diffusion of a layered run from its two results (see the
    module docstring): the physical run ``ds`` and its ``D_p = 0`` frames ``P_num``.
    :func:`spotpde.layers.numerical_blur` runs what is missing and calls this.

    Args:
        case: the :class:`spotpde.cases.Case` both ran (its grid spacing, tracer limiter
            and model label the result).
        ds: the physical run's Dataset.
        P_num: the ``D_p = 0`` frames (DataArray on ``ds.P``'s dims).
        x_max, z_range: the measuring region (d).

    Returns:
        dict with

        * ``t`` (frames,): times;
        * ``var_run``, ``var_num`` (frames,): edge variances (d**2) of the physical and
          the ``D_p = 0`` run; ``var_phys = var_run - var_num``: the broadening the
          physical diffusion adds; ``var_pred``: ``2 integral <D_nn> dt`` (no strain);
        * ``ratio``: ``var_num / var_phys`` at the last frame (all the grid's blur,
          capture width included, relative to the physical broadening);
        * ``D_num``, ``D_phys``: half the least-squares slopes of ``var_num`` and
          ``var_phys`` over the frames with ``t >= t_end / 2`` (d**2 per unit time);
          ``growth_ratio = D_num / D_phys`` (numerical diffusion as a fraction of the
          physical; <= 0 when the ``D_p = 0`` edges do not widen);
        * ``capture_cells``: ``max sigma_num / h``, the capture width in cells;
        * ``contrast_run``, ``contrast_num`` (frames,): :func:`layer_contrast`;
        * ``spacing``, ``limiter``, ``model``; ``P_num`` (the ``D_p = 0`` frames) and
          ``ds`` (the physical result), for plotting.
    """
    region = {"x_max": x_max, "z_range": z_range}
    s_run = interface_width(ds, **region)
    s_num = interface_width(ds, P=P_num, **region)
    var_run, var_num = s_run**2, s_num**2
    var_phys = var_run - var_num
    t = np.asarray(ds.t, dtype=float)
    late = t >= 0.5 * t[-1]
    D_num = 0.5 * _slope(t[late], var_num[late])
    D_phys = 0.5 * _slope(t[late], var_phys[late])
    h = float(case.grid.spacing)
    return {
        "t": t,
        "var_run": var_run,
        "var_num": var_num,
        "var_phys": var_phys,
        "var_pred": predicted_variance(ds, **region),
        "ratio": float(var_num[-1] / var_phys[-1]) if var_phys[-1] > 0 else float("inf"),
        "D_num": D_num,
        "D_phys": D_phys,
        "growth_ratio": D_num / D_phys if D_phys > 0 else float("inf"),
        "capture_cells": float(np.nanmax(s_num) / h),
        "contrast_run": layer_contrast(ds, **region),
        "contrast_num": layer_contrast(ds, P=P_num, **region),
        "spacing": h,
        "limiter": case.tracer_options.get("limiter", "weno5"),
        "model": case.model,
        "P_num": P_num,
        "ds": ds,
    }


def summary(blur: Mapping) -> str:
    """One-line text of a :func:`spotpde.layers.numerical_blur` result (for logs and figure titles)."""
    return (f"{blur['model']} h={blur['spacing']:g} d {blur['limiter']}: "
            f"var_run={blur['var_run'][-1]:.4g}, var_num={blur['var_num'][-1]:.4g}, "
            f"var_phys={blur['var_phys'][-1]:.4g}, var_pred={blur['var_pred'][-1]:.4g} d^2; "
            f"ratio={blur['ratio']:.3g}, D_num={blur['D_num']:.3g}, "
            f"D_phys={blur['D_phys']:.3g}, growth_ratio={blur['growth_ratio']:.3g}, "
            f"capture={blur['capture_cells']:.2f} cells, "
            f"contrast run/num={blur['contrast_run'][-1]:.3f}/{blur['contrast_num'][-1]:.3f}")


# -- numerical diffusion under strain ---------------------------------------------------------
def _edge_average(ds: xr.Dataset, fn, *, x_max: float, z_range: tuple[float, float],
                  P: xr.DataArray | None = None) -> np.ndarray:
    """Per frame, the |grad p|-weighted mean over the region of ``fn(nx, nz, mask)``."""
    p = concentration(ds, P)
    h = float(p.x[1] - p.x[0])
    mask = _region(p, x_max, z_range)
    out = []
    for frame in np.asarray(p):
        _, tv, gx, gz, g = _width_parts(frame, h, mask)
        if tv <= 0:
            out.append(0.0)
            continue
        w = g[mask]
        safe = np.where(w > 0, w, 1.0)
        out.append(float((w * fn(gx[mask] / safe, gz[mask] / safe, mask)).sum() / w.sum()))
    return np.array(out)


def normal_strain(ds: xr.Dataset, *, x_max: float = X_MAX, z_range: tuple[float, float] = Z_RANGE,
                  P: xr.DataArray | None = None) -> np.ndarray:
    """Edge-normal stretching rate ``e = n . grad(u_p) . n`` per frame (1 / time).

    Averaged over the edges of the region with weight ``|grad p|`` (as
    :func:`predicted_variance` averages ``D_nn``); ``grad u`` by central differences of
    the drift ``u_x``, ``u_z``. ``e < 0``: the flow compresses the edges (thins them).
    """
    m = _plane(ds)
    h = float(m.x[1] - m.x[0])
    duz_dz, duz_dx = np.gradient(np.asarray(m.u_z, dtype=float), h, h)
    dux_dz, dux_dx = np.gradient(np.asarray(m.u_x, dtype=float), h, h)

    def fn(nx, nz, mask):
        return (dux_dx[mask] * nx * nx + (dux_dz[mask] + duz_dx[mask]) * nx * nz
                + duz_dz[mask] * nz * nz)

    return _edge_average(ds, fn, x_max=x_max, z_range=z_range, P=P)


def strained_numerical_diffusion(blur: Mapping, *, x_max: float = X_MAX,
                                 z_range: tuple[float, float] = Z_RANGE) -> dict:
    """Numerical and physical edge diffusivities with the strain of the flow taken out.

    An edge of variance ``s2`` in a flow that stretches it at the normal rate ``e``
    obeys ``d s2/dt = 2 D_nn + 2 e s2``. Strain alone makes the ``D_p = 0`` rerun's edges
    of a converging silo *thinner* in time, so the bare growth of ``var_num`` (the
    ``growth_ratio`` of :func:`spotpde.layers.numerical_blur`) comes out negative and says nothing
    about the scheme. Solving the width equation for the diffusivity instead,

        D_num(t) = (1/2) d var_num/dt - e(t) var_num(t),

    (central differences between frames, ``e`` from :func:`normal_strain` on the
    ``D_p = 0`` frames) gives the scheme's diffusivity normal to the edges, whatever the
    strain; the physical one is ``<D_nn>`` (the rate of :func:`predicted_variance`), and
    ``var_pred_strained`` integrates the width equation with it from 0 (midpoint rule,
    50 substeps per frame interval).

    For first-order upwinding (dimension by dimension) the numerical diffusivity is
    known: ``D_nn = (h/2) (|u_x| n_x**2 + |u_z| n_z**2)``, returned as ``D_upwind``.

    Args:
        blur: a :func:`spotpde.layers.numerical_blur` result (uses ``t``, ``ds``, ``P_num``,
            ``var_num``, ``var_pred``, ``spacing``).
        x_max, z_range: the region (as for ``blur``).

    Returns:
        dict of per-frame arrays ``strain``, ``D_num``, ``D_nn``, ``D_upwind``,
        ``var_pred_strained``, and the second-half averages ``D_num_late``,
        ``D_nn_late``, ``D_upwind_late`` and ``ratio = D_num_late / D_nn_late``.
    """
    region = {"x_max": x_max, "z_range": z_range}
    t = np.asarray(blur["t"], dtype=float)
    ds, P_num = blur["ds"], blur["P_num"]
    e_num = normal_strain(ds, P=P_num, **region)
    e_run = normal_strain(ds, **region)
    var_num = np.asarray(blur["var_num"], dtype=float)
    D_num = 0.5 * np.gradient(var_num, t) - e_num * var_num
    D_nn = 0.5 * np.gradient(np.asarray(blur["var_pred"], dtype=float), t)
    m = _plane(ds)
    ux, uz = np.abs(np.asarray(m.u_x, dtype=float)), np.abs(np.asarray(m.u_z, dtype=float))
    h = float(blur["spacing"])
    D_up = _edge_average(ds, lambda nx, nz, mask: 0.5 * h * (ux[mask] * nx * nx + uz[mask] * nz * nz),
                         P=P_num, **region)
    v = [0.0]
    n_sub = 50
    for i in range(t.size - 1):
        dt = (t[i + 1] - t[i]) / n_sub
        vv = v[-1]
        for k in range(n_sub):
            tt = t[i] + (k + 0.5) * dt
            vv += dt * (2 * np.interp(tt, t, D_nn) + 2 * np.interp(tt, t, e_run) * vv)
        v.append(vv)
    late = t >= 0.5 * t[-1]
    D_num_late, D_nn_late = float(D_num[late].mean()), float(D_nn[late].mean())
    return {"strain": e_num, "D_num": D_num, "D_nn": D_nn, "D_upwind": D_up,
            "var_pred_strained": np.array(v), "D_num_late": D_num_late, "D_nn_late": D_nn_late,
            "D_upwind_late": float(D_up[late].mean()),
            "ratio": D_num_late / D_nn_late if D_nn_late > 0 else float("inf")}
