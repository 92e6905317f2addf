"""Standard figures of a result Dataset (matplotlib, drawn off-screen).

:func:`plot_result` writes one multi-panel figure (PNG, PDF, SVG, ...: the format of the
file's extension, written atomically by :func:`spotpde._figures.save_figure`): spot
density; downward particle speed next to the kinematic model on the same colour scale;
speed profiles at a few heights; streamlines of the particle drift; the tracer (the
layered silo for a layered start, snapshots of the blob otherwise) and its mass budget.
Each panel has its own function taking a Dataset and an Axes, for notebooks. 3D results
are shown in the ``y`` mid-plane; axisymmetric results (dims ``(z, r)``) as the whole
vertical section through the axis, mirrored (:func:`mirror_section`). Cells outside a
hopper's walls are NaN and left blank. Axes are in particle diameters d, times in the
case's time unit t.
"""

from __future__ import annotations

import os
from pathlib import Path

from .._figures import figure_format, prepare_matplotlib, save_figure

prepare_matplotlib()    # before matplotlib is imported: a writable home for its font cache

import matplotlib  # noqa: E402
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

SPEED_CMAP = "viridis"
LAYER_CMAP = "YlOrBr"


def midplane(ds: xr.Dataset) -> xr.Dataset:
    """The ``y`` mid-plane of a 3D result, the mirrored section of an axisymmetric one
    (:func:`mirror_section`), a 2D result unchanged.

    Args:
        ds: result Dataset.

    Returns:
        Dataset with dims ``(z, x)`` (and ``t``).
    """
    if "r" in ds.dims:
        return mirror_section(ds)
    if "y" in ds.dims:
        return ds.isel(y=ds.sizes["y"] // 2)
    return ds


#: Components that change sign under the mirror x = -r (odd in x); the rest are even.
_ODD_IN_X = ("u_r", "D_rz")
_MIRROR_NAMES = {"u_r": "u_x", "D_rr": "D_xx", "D_rz": "D_xz"}


def mirror_section(ds: xr.Dataset) -> xr.Dataset:
    """The vertical section ``(z, x)`` through the axis of an axisymmetric result.

    ``x = -r`` on the left half, ``x = r`` on the right; scalars and ``D_rr`` are even,
    ``u_r`` and ``D_rz`` odd (``u_x(-r) = -u_r(r)``). Cylindrical components get the
    Cartesian names of the section (``u_x``, ``D_xx``, ``D_xz``), so every panel of
    :func:`plot_result` applies. A result without an ``r`` axis is returned unchanged.
    """
    if "r" not in ds.dims:
        return ds
    left = ds.isel(r=slice(None, None, -1))
    left = left.assign_coords(r=-left.r.values)
    for name in _ODD_IN_X:
        if name in left:
            left[name] = -left[name]
    parts = []
    for part in (left, ds):
        part = part.rename({"r": "x"})
        parts.append(part.rename({k: v for k, v in _MIRROR_NAMES.items() if k in part}))
    out = xr.concat(parts, dim="x", data_vars="minimal", coords="minimal",
                    compat="override", combine_attrs="override")
    out.x.attrs.update(long_name="horizontal position in the section through the axis, "
                                 "in particle diameters", units="1", axis="X")
    return out


def _extent(ds):
    h = float(ds.x[1] - ds.x[0]) if ds.sizes["x"] > 1 else 1.0
    hz = float(ds.z[1] - ds.z[0]) if ds.sizes["z"] > 1 else 1.0
    return [float(ds.x[0]) - h / 2, float(ds.x[-1]) + h / 2,
            float(ds.z[0]) - hz / 2, float(ds.z[-1]) + hz / 2]


def _robust_max(*arrays, q=99.0):
    vals = np.concatenate([np.ravel(np.asarray(a)) for a in arrays])
    vals = vals[np.isfinite(vals)]
    if vals.size == 0:
        return 1.0
    top = float(np.percentile(vals, q))
    return top if top > 0 else float(max(vals.max(), 1e-300))


def _image(ax, ds, values, *, vmin, vmax, cmap, label, title, extend="max"):
    im = ax.imshow(np.asarray(values), origin="lower", extent=_extent(ds), vmin=vmin,
                   vmax=vmax, cmap=cmap, aspect="equal", interpolation="nearest")
    ax.set_xlabel("x (d)")
    ax.set_ylabel("z (d)")
    ax.set_title(title, fontsize=10)
    cb = ax.figure.colorbar(im, ax=ax, shrink=0.85, extend=extend)
    cb.set_label(label)
    return im


def _is_3d(ds) -> bool:
    """A 3D silo: Cartesian 3D or axisymmetric (densities per unit volume)."""
    return "y" in ds.dims or "r" in ds.dims or ds.attrs.get("dims") == 3


def _density_unit(ds):
    return "spots/d³" if _is_3d(ds) else "spots/d²"


def plot_spot_density(ds: xr.Dataset, ax) -> None:
    """Mean spot density ``rho_s`` (colour scale clipped at its 99th percentile)."""
    unit = _density_unit(ds)
    m = midplane(ds)
    what = "void" if ds.attrs.get("model") == "void" else "spot"
    _image(ax, m, m.rho_s, vmin=0.0, vmax=_robust_max(m.rho_s), cmap="magma",
           label=f"ρ_s ({unit.replace('spots', what + 's')})", title=f"{what} density ρ_s")


def plot_speed(ds: xr.Dataset, ax_particles, ax_kinematic) -> None:
    """Downward particle speed ``-u_z`` next to the kinematic model ``v_kin``, one scale."""
    m = midplane(ds)
    vmax = _robust_max(-m.u_z, m.v_kin)
    model = ds.attrs.get("model", "spot")
    _image(ax_particles, m, -m.u_z, vmin=0.0, vmax=vmax, cmap=SPEED_CMAP,
           label="speed (d/t)", title=f"particle speed −u_z ({model} model)")
    _image(ax_kinematic, m, m.v_kin, vmin=0.0, vmax=vmax, cmap=SPEED_CMAP,
           label="speed (d/t)", title="kinematic model v_kin")


def plot_profiles(ds: xr.Dataset, ax, fractions=(0.1, 0.3, 0.6)) -> None:
    """Horizontal profiles of ``-u_z`` (solid) and ``v_kin`` (dashed) at a few heights."""
    m = midplane(ds)
    ztop = float(m.z[-1])
    colors = matplotlib.colormaps["plasma"](np.linspace(0.1, 0.8, len(fractions)))
    for f, c in zip(fractions, colors):
        row = m.sel(z=f * ztop, method="nearest")
        ax.plot(row.x, -row.u_z, color=c, lw=1.8, label=f"z = {float(row.z):.3g} d")
        ax.plot(row.x, row.v_kin, color=c, lw=1.2, ls="--")
    ax.plot([], [], "k-", lw=1.8, label=f"−u_z ({ds.attrs.get('model', 'spot')} model)")
    ax.plot([], [], "k--", lw=1.2, label="v_kin (kinematic)")
    ax.set_xlabel("x (d)")
    ax.set_ylabel("downward speed (d/t)")
    ax.set_title("speed profiles at three heights", fontsize=10)
    ax.legend(fontsize=8, frameon=False)
    ax.grid(alpha=0.3)


def plot_streamlines(ds: xr.Dataset, ax) -> None:
    """Streamlines of the particle drift, coloured by its magnitude."""
    m = midplane(ds)
    x, z = np.asarray(m.x), np.asarray(m.z)
    ux, uz = np.nan_to_num(np.asarray(m.u_x)), np.nan_to_num(np.asarray(m.u_z))
    speed = np.hypot(ux, uz)
    vmax = _robust_max(speed)
    if x.size > 1 and z.size > 1 and np.any(speed > 0):
        sp = ax.streamplot(x, z, ux, uz, color=np.minimum(speed, vmax), cmap=SPEED_CMAP,
                           density=1.1, linewidth=0.8, arrowsize=0.7,
                           norm=matplotlib.colors.Normalize(0.0, vmax))
        sp.lines.set_in_layout(False)          # keeps constrained layout fast
        sp.arrows.set_in_layout(False)
        for patch in ax.patches:
            patch.set_in_layout(False)
        cb = ax.figure.colorbar(sp.lines, ax=ax, shrink=0.85, extend="max")
        cb.set_label("|u_p| (d/t)")
    ax.set_xlim(_extent(m)[:2])
    ax.set_ylim(_extent(m)[2:])
    ax.set_aspect("equal")
    ax.set_xlabel("x (d)")
    ax.set_ylabel("z (d)")
    ax.set_title("streamlines of the particle drift u_p", fontsize=10)


def plot_diffusivity(ds: xr.Dataset, ax) -> None:
    """Horizontal particle diffusivity ``D_xx``."""
    m = midplane(ds)
    _image(ax, m, m.D_xx, vmin=0.0, vmax=_robust_max(m.D_xx), cmap="cividis",
           label="D_xx (d²/t)", title="particle diffusivity D_xx")


def is_layered(ds: xr.Dataset) -> bool:
    """True when the tracer started as horizontal layers (read from the ``case`` text)."""
    return "layers" in ds.attrs.get("case", "")


def plot_layers(ds: xr.Dataset, ax, frame: int) -> None:
    """The layered silo at one frame: P relative to the initial band density."""
    m = midplane(ds)
    p0 = float(m.P.isel(t=0).max())
    P = m.P.isel(t=frame) / (p0 if p0 > 0 else 1.0)
    t = float(m.t[frame])
    _image(ax, m, P, vmin=0.0, vmax=1.0, cmap=LAYER_CMAP, label="P / P(t=0) in a band",
           title=f"coloured layers at t = {t:.3g}", extend="neither")


def plot_snapshots(ds: xr.Dataset, ax, count: int = 5) -> None:
    """Tracer snapshots: P at a few frames, each scaled to its own maximum, on one map."""
    m = midplane(ds)
    nt = m.sizes["t"]
    frames = sorted(set(np.linspace(0, nt - 1, min(count, nt)).round().astype(int)))
    composite = np.zeros((m.sizes["z"], m.sizes["x"]))
    for i in frames:
        P = np.asarray(m.P.isel(t=i))
        top = P.max()
        if top > 0:
            composite = np.maximum(composite, P / top)
            k, j = np.unravel_index(np.argmax(P), P.shape)
            ax.annotate(f"t={float(m.t[i]):.3g}", (float(m.x[j]), float(m.z[k])),
                        xytext=(6, 6), textcoords="offset points", fontsize=7, color="w")
    _image(ax, m, composite, vmin=0.0, vmax=1.0, cmap="inferno",
           label="P / max P (each frame)", title=f"tracer snapshots ({len(frames)} frames)",
           extend="neither")


def plot_mass(ds: xr.Dataset, ax) -> None:
    """Tracer mass budget: inside, out through the orifice, and their sum."""
    t = np.asarray(ds.t)
    ax.plot(t, ds.mass, label="inside")
    ax.plot(t, ds.outflow, label="out through orifice")
    ax.plot(t, ds.mass + ds.outflow, "k--", lw=1, label="sum")
    err = float(np.max(np.abs(np.asarray(ds.mass + ds.outflow) - 1.0))) if t.size else 0.0
    ax.set_xlabel("time t (case time unit)")
    ax.set_ylabel("probability")
    ax.set_ylim(-0.05, 1.1)
    ax.set_title(f"tracer mass budget (max |sum − 1| = {err:.1e})", fontsize=10)
    ax.legend(fontsize=8, frameon=False)
    ax.grid(alpha=0.3)


#: Dimensions a result may have, each put in increasing order by :func:`plottable`.
_AXES = ("t", "z", "y", "x", "r")


def plottable(ds: xr.Dataset, source: str = "ds") -> xr.Dataset:
    """``ds`` with every coordinate (``t``, ``z``, ``y``, ``x``, ``r``) in increasing
    order, as :func:`plot_result` draws it (a result written with ``z`` decreasing is
    the same silo).

    Args:
        ds: a result Dataset.
        source: what ``ds`` is called in a message (the command line: its file).

    Returns:
        ``ds``, or a sorted copy.

    Raises:
        ValueError: ``<source>: coordinate z ...`` when a coordinate has values that are
            not finite or repeated, or a spatial one is not equally spaced (the panels
            are images and streamlines on a uniform grid).
    """
    unsorted = []
    for dim in _AXES:
        if dim not in ds.dims or dim not in ds.coords:
            continue
        values = np.asarray(ds[dim].values, dtype=float)
        if not np.all(np.isfinite(values)):
            raise ValueError(f"{source}: coordinate {dim} has values that are not finite")
        if np.any(np.diff(values) <= 0):
            unsorted.append(dim)
    if unsorted:
        ds = ds.sortby(unsorted)
    for dim in _AXES:
        if dim not in ds.dims or dim not in ds.coords:
            continue
        values = np.asarray(ds[dim].values, dtype=float)
        step = np.diff(values)
        if np.any(step <= 0):
            raise ValueError(f"{source}: coordinate {dim} has repeated values; cannot plot")
        if dim != "t" and step.size > 1 and not np.allclose(
                step, (values[-1] - values[0]) / step.size):
            raise ValueError(f"{source}: coordinate {dim} is not equally spaced "
                             f"(steps from {step.min():.6g} to {step.max():.6g} d); "
                             "cannot plot")
    return ds


#: Layout of :func:`plot_result` in inches: the height of a row's panels, the width of
#: the line-plot column, the band of the overall title, the room above each panel (its
#: title) and below it (ticks and label), and the left and right margins of an image
#: panel (its colour bar is inside the panel) and of a line plot. A fixed layout draws
#: the figure once; matplotlib's constrained layout drew it twice (a third of the time).
_PANEL_H, _LINE_W, _TOP, _TITLE, _BELOW = 4.4, 5.0, 0.35, 0.32, 0.55
_IMAGE_MARGINS, _LINE_MARGINS = (0.7, 0.6), (0.95, 0.2)


def _panels(fig, panel_w: float) -> np.ndarray:
    """The 2 x 4 panels of :func:`plot_result`: three image columns ``panel_w`` wide and
    one line-plot column, placed by the margins above."""
    width, height = fig.get_size_inches()
    row = (height - _TOP) / 2
    axes = np.empty((2, 4), dtype=object)
    for i in range(2):
        bottom = height - _TOP - (i + 1) * row + _BELOW
        left = 0.0
        for j, column in enumerate([panel_w] * 3 + [_LINE_W]):
            before, after = _IMAGE_MARGINS if j < 3 else _LINE_MARGINS
            axes[i, j] = fig.add_axes(((left + before) / width, bottom / height,
                                       (column - before - after) / width,
                                       (row - _BELOW - _TITLE) / height))
            left += column
    return axes


def plot_result(ds: xr.Dataset, path: str | os.PathLike, *, dpi: int = 100) -> Path:
    """Write the standard multi-panel figure of a result.

    The panels a result cannot fill are replaced: without ``P_height`` the tracer's
    second panel shows the speed difference, without ``mass`` and ``outflow`` the
    budget panel shows the flux through each height.

    Args:
        ds: a result Dataset (from :func:`spotpde.run` or a netCDF file).
        path: the figure file, written atomically in the format its extension names
            (``.png``, ``.pdf``, ``.svg``, ...: :func:`spotpde._figures.save_figure`).
        dpi: resolution of a raster format, in dots per inch.

    Returns:
        The path written.

    Raises:
        ValueError: an unsupported extension, or coordinates that cannot be drawn
            (:func:`plottable`).
        spotpde.errors.WriteError: the file could not be written (disk full, ...).
    """
    figure_format(path)              # an unsupported extension: refused before drawing
    ds = plottable(ds)
    m = midplane(ds)
    width = float(m.x[-1] - m.x[0]) if m.sizes["x"] > 1 else 1.0
    height = float(m.z[-1] - m.z[0]) if m.sizes["z"] > 1 else 1.0
    panel_w = float(np.clip(_PANEL_H * width / height + 1.2, 3.2, 7.0))
    # a bare Figure (no pyplot): drawn off-screen whatever backend the user has chosen
    fig = Figure(figsize=(3 * panel_w + _LINE_W, 2 * _PANEL_H + 0.9))
    axes = _panels(fig, panel_w)
    plot_spot_density(ds, axes[0, 0])
    plot_speed(ds, axes[0, 1], axes[0, 2])
    plot_profiles(ds, axes[0, 3])
    plot_streamlines(ds, axes[1, 0])
    if "P" in ds:
        if is_layered(ds):
            nt = ds.sizes["t"]
            plot_layers(ds, axes[1, 1], nt // 2)
            plot_layers(ds, axes[1, 2], nt - 1)
        else:
            plot_snapshots(ds, axes[1, 1])
            if "P_height" in ds:
                plot_height_propagator(ds, axes[1, 2])
            else:
                plot_speed_difference(ds, axes[1, 2])
    else:
        plot_diffusivity(ds, axes[1, 1])
        plot_speed_difference(ds, axes[1, 2])
    if "P" in ds and "mass" in ds and "outflow" in ds:
        plot_mass(ds, axes[1, 3])
    else:
        plot_flux(ds, axes[1, 3])
    model = ds.attrs.get("model", "spot")
    n = "³" if _is_3d(ds) else "²"
    where = (" (y mid-plane)" if "y" in ds.dims else
             " (axisymmetric: section through the axis)" if "r" in ds.dims else "")
    fig.suptitle(f"spotpde {ds.attrs.get('spotpde_version', '')}: {model} model, "
                 f"V1 = {ds.attrs.get('V1', float('nan')):.3g} d{n}, "
                 f"V2 = {ds.attrs.get('V2', float('nan')):.3g} d{n}, "
                 f"rule λ = {ds.attrs.get('rule', float('nan')):g}" + where, fontsize=12)
    return save_figure(fig, path, dpi=dpi)


def plot_height_propagator(ds: xr.Dataset, ax) -> None:
    """Geometrical propagator ``P_height``: where the tracer crosses each height."""
    m = midplane(ds)
    unit = "1/d²" if _is_3d(ds) else "1/d"
    _image(ax, m, m.P_height, vmin=0.0, vmax=_robust_max(m.P_height), cmap="inferno",
           label=f"P_height ({unit})", title="geometrical propagator P_height")


def plot_speed_difference(ds: xr.Dataset, ax) -> None:
    """``(-u_z - v_kin)`` relative to the largest kinematic speed at the same height."""
    m = midplane(ds)
    scale = m.v_kin.max("x")
    rel = (-m.u_z - m.v_kin) / scale.where(scale > 0)
    lim = max(_robust_max(np.abs(rel)), 1e-6)
    _image(ax, m, rel, vmin=-lim, vmax=lim, cmap="RdBu_r",
           label="(−u_z − v_kin) / max_x v_kin", title="spot model minus kinematic model",
           extend="both")


def plot_flux(ds: xr.Dataset, ax) -> None:
    """Downward particle flux through each height: drift vs kinematic model (``V1 Q0``)."""
    horizontal = [d for d in ("y", "x", "r") if d in ds.dims]
    h = float(ds[horizontal[-1]][1] - ds[horizontal[-1]][0]) if ds.sizes[horizontal[-1]] > 1 else 1.0
    if "r" in ds.dims:     # rings of area 2 pi r h
        area = 2.0 * np.pi * ds.r * h
    else:
        area = h ** (2 if "y" in ds.dims else 1)
    ax.plot(((-ds.u_z) * area).sum(horizontal), ds.z, label="−u_z (drift)")
    ax.plot((ds.v_kin * area).sum(horizontal), ds.z, "--", label="v_kin")
    unit = "d³/t" if _is_3d(ds) else "d²/t"
    ax.set_xlabel(f"downward particle flux through height z ({unit})")
    ax.set_ylabel("z (d)")
    ax.set_xlim(left=0)
    ax.set_title("flux through each height", fontsize=10)
    ax.legend(fontsize=8, frameon=False)
    ax.grid(alpha=0.3)
