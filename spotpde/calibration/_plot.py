"""Figures of a fit (private; see :mod:`spotpde.calibration`): data (points with standard
errors) against the best fit (lines), one panel per fitted observable, the velocity
residual map, and a corner plot of the posterior when it was sampled."""

from __future__ import annotations

import numpy as np
import xarray as xr

from .._figures import figure_format, prepare_matplotlib, save_figure

__all__ = ["plot_fit"]


def _errorbar(ax, x, ds, var, label_model="best fit"):
    d, s, m = ds[f"data_{var}"].values, ds[f"data_{var}_se"].values, ds[f"model_{var}"].values
    ok = np.isfinite(d)
    ax.errorbar(x[ok], d[ok], yerr=s[ok], fmt="o", ms=3, capsize=2, label="data")
    ax.plot(x, m, "-", label=label_model)


def _velocity(ax, ds):
    d = ds["data_u_z"]
    z = d["z"].values
    rows = [int(np.argmin(np.abs(z - q))) for q in np.quantile(z, [0.1, 0.3, 0.55, 0.8])]
    x = d["x"].values
    for j, row in enumerate(rows):
        dv, sv = -d.values[row], ds["data_u_z_se"].values[row]
        mv = -ds["model_u_z"].values[row]
        stride = max(1, x.size // 40)
        ok = np.isfinite(dv)
        ok[np.arange(x.size) % stride != 0] = False
        ax.errorbar(x[ok], dv[ok], yerr=sv[ok], fmt="o", ms=2, color=f"C{j}", capsize=1)
        ax.plot(x, mv, "-", color=f"C{j}", label=f"z = {z[row]:.1f} d")
    ax.set_xlabel("x (d)")
    ax.set_ylabel("downward speed -u_z (d / time)")
    ax.legend(fontsize=7)


def _residual_map(fig, ax, ds):
    r = ds["residual_u_z"]
    im = ax.pcolormesh(r["x"].values, r["z"].values, r.values, cmap="RdBu_r", vmin=-4, vmax=4,
                       shading="nearest")
    fig.colorbar(im, ax=ax, label="(model - data) / SE")
    ax.set_title("u_z residuals at the fitted points")
    ax.set_xlabel("x (d)")
    ax.set_ylabel("z (d)")


def _panels(ds) -> list[str]:
    present = {str(v)[len("data_"):] for v in ds.data_vars
               if str(v).startswith("data_") and not str(v).endswith("_se")}
    order = ["u_z", "residual", "v_z", "b_kin", "flux", "b_p", "b_p_par", "var_x", "var_z", "C",
             "survival"]
    out = [p for p in order if p in present or (p == "residual" and "u_z" in present)]
    return out


def plot_fit(ds: xr.Dataset, path=None, *, dpi: int = 100):
    """Draw a fit: data with standard errors against the best fit.

    Args:
        ds: the result of :func:`spotpde.fit` (or its netCDF file read back).
        path: if given, the figure is written there (the format of its extension,
            written atomically: :func:`spotpde._figures.save_figure`).
        dpi: resolution of a raster file.

    Returns:
        The matplotlib Figure.
    """
    if path is not None:
        figure_format(path)          # an unsupported extension: refused before drawing
    prepare_matplotlib()
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    panels = _panels(ds)
    corner = "chain" in ds
    n = len(panels) + (1 if corner else 0)
    cols = min(3, max(n, 1))
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4.6 * cols, 3.6 * rows), squeeze=False)
    axes = axes.ravel()
    for ax, p in zip(axes, panels):
        if p == "u_z":
            _velocity(ax, ds)
        elif p == "residual":
            _residual_map(fig, ax, ds)
        elif p == "v_z":
            for j, h in enumerate(ds["data_v_z"]["height"].values):
                row = ds.sel(height=h)
                ax.errorbar(row["x"].values, row["data_v_z"].values, yerr=row["data_v_z_se"].values,
                            fmt="o", ms=2, color=f"C{j}")
                ax.plot(row["x"].values, row["model_v_z"].values, color=f"C{j}", label=f"z = {h:g}")
            ax.set_xlabel("x (d)")
            ax.set_ylabel("v_z (d / time)")
            ax.legend(fontsize=7)
        elif p in ("b_kin", "flux"):
            _errorbar(ax, ds[f"data_{p}"]["height"].values, ds, p)
            ax.set_xlabel("height (d)")
            ax.set_ylabel("b_kin (d)" if p == "b_kin" else "flux (d^2 / time)")
        elif p in ("b_p", "b_p_par"):
            d = ds[f"data_{p}"]
            col = int(np.argmin(np.abs(d["x_bin"].values)))
            sub = ds.isel(x_bin=col)
            _errorbar(ax, d["z_bin"].values, sub, p)
            ax.set_xlabel("height of the bin (d)")
            ax.set_ylabel(f"{p} (d), x = {d['x_bin'].values[col]:g} d")
        elif p in ("var_x", "var_z"):
            fall = ds["lag_fall"].values if "lag_fall" in ds else np.arange(ds.sizes["lag"])
            _errorbar(ax, fall, ds, p)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("mean fall (d)")
            ax.set_ylabel(f"{p} (d^2)")
        elif p == "C":
            _errorbar(ax, ds["data_C"]["r"].values, ds, "C")
            ax.set_xlabel("separation r (d)")
            ax.set_ylabel("velocity correlation C")
        elif p == "survival":
            _errorbar(ax, ds["data_survival"]["fall"].values, ds, "survival")
            ax.set_xlabel("fall of the pair (d)")
            ax.set_ylabel("pairs still caged")
        ax.legend(fontsize=7) if p not in ("u_z", "residual", "v_z") else None
    if corner:
        _corner(axes[len(panels)], ds)
    for ax in axes[n:]:
        ax.set_visible(False)
    title = ", ".join(f"{k} = {v:.4g} +- {s:.2g}" for k, v, s in
                      zip(ds["parameter"].values, ds["value"].values, ds["stderr"].values))
    fig.suptitle(title, fontsize=9)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path, dpi=dpi)
    return fig


def _corner(ax, ds):
    """The posterior of the first two parameters (a full corner plot needs one panel per
    pair; this shows the pair with the strongest correlation)."""
    chain = ds["chain"].values
    kept = chain[int(0.3 * chain.shape[0]):].reshape(-1, chain.shape[-1])
    names = [str(n) for n in ds["parameter"].values]
    if kept.shape[1] == 1:
        ax.hist(kept[:, 0], bins=40)
        ax.set_xlabel(names[0])
        return
    c = np.abs(np.nan_to_num(ds["correlation"].values) - np.eye(len(names)))
    i, j = np.unravel_index(np.argmax(c), c.shape)
    ax.plot(kept[:, i], kept[:, j], ",", alpha=0.4)
    ax.set_xlabel(names[i])
    ax.set_ylabel(names[j])
    ax.set_title("posterior samples")
