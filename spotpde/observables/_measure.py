"""All observables at once (private; see :mod:`spotpde.observables`): :func:`measure` from
tracks, :func:`predict` from a model, with the same variable names, dims and units.

The combined Dataset holds each observable's variables (``u_z``, ``b_p``, ``C``, ...),
their standard errors ``*_se`` and jackknife replicates ``*_jk`` (tracks), and each
observable's options as attributes prefixed with its name (``diffusion.fall``), so that
:func:`predict` with ``like=`` mirrors every choice of the measurement.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import xarray as xr

from ..app.cases import Case
from ..app.pipeline import run
from ._common import BLOCKS, case_for, grid_of, is_tracks
from ._correlation import pair_separation, velocity_correlation
from ._diffusion import diffusion, displacement_growth
from ._layers import drained_fraction
from ._velocity import profiles_of, velocity_field, width_of

__all__ = ["OBSERVABLES", "TARGETS", "FIT_DEFAULT", "measure", "predict", "part"]

#: The observables, and the variables of each that a fit compares (value +- se).
TARGETS = {
    "velocity": ("u_x", "u_z"),
    "profiles": ("v_z",),
    "width": ("b_kin", "flux"),
    "diffusion": ("b_p", "b_p_par"),
    "growth": ("var_x", "var_z"),
    "correlation": ("C",),
    "pairs": ("survival",),
    "layers": ("drained",),
}
OBSERVABLES = tuple(TARGETS)
#: What :func:`spotpde.fit` fits by default: the mean flow and the diffusion.
FIT_DEFAULT = ("velocity", "diffusion")
#: Observables that need the velocity field of the same tracks.
_NEED_VELOCITY = ("profiles", "width", "diffusion", "growth", "correlation")


def _names(observables) -> tuple[str, ...]:
    if observables is None:
        return FIT_DEFAULT
    if isinstance(observables, str):
        observables = [observables]
    names = tuple(observables)
    bad = [n for n in names if n not in TARGETS]
    if bad or not names:
        raise ValueError(f"observables: unknown {', '.join(map(repr, bad)) or 'empty list'}; "
                         f"valid: {', '.join(OBSERVABLES)}")
    return names


def _options(options: Mapping | None, name: str) -> dict:
    opts = dict((options or {}).get(name, {}))
    return opts


def part(ds: xr.Dataset, name: str) -> xr.Dataset:
    """The variables and options (attributes without their ``name.`` prefix) of one
    observable of a combined Dataset."""
    keep = [v for v in ds.data_vars if ds[v].attrs.get("observable") == name]
    out = ds[keep]
    out.attrs = {k[len(name) + 1:]: v for k, v in ds.attrs.items() if k.startswith(name + ".")}
    return out


def _combine(parts: dict[str, xr.Dataset], attrs: dict) -> xr.Dataset:
    merged, options = [], {}
    for name, ds in parts.items():
        ds = ds.copy()
        for v in ds.data_vars:
            ds[v].attrs["observable"] = name
        options.update({f"{name}.{k}": v for k, v in ds.attrs.items()})
        ds.attrs = {}
        merged.append(ds)
    out = xr.merge(merged, combine_attrs="override", compat="override", join="outer")
    out.attrs = {**options, **attrs}
    return out


def measure(tracks: xr.Dataset, case, observables: Sequence[str] | str | None = None, *,
            blocks: int = BLOCKS, options: Mapping[str, Mapping] | None = None,
            heights=None) -> xr.Dataset:
    """Measure observables from tracks, with jackknife errors over time blocks.

    Args:
        tracks: a tracks Dataset (``spotpde.tracks.read``).
        case: the case the tracks come from (its grid, orifice, walls).
        observables: names from :data:`OBSERVABLES` (default :data:`FIT_DEFAULT`).
        blocks: number of contiguous time blocks of the jackknife.
        options: per observable, keyword options of its function, e.g.
            ``{"velocity": {"width": 1.5}, "diffusion": {"fall": 2.0, "bins": (5, 10)}}``.
        heights: heights of the profiles and widths (d).

    Returns:
        One Dataset with every observable's variables, ``*_se``, ``*_jk``.
    """
    if not is_tracks(tracks):
        raise TypeError("tracks: must be a tracks Dataset (spotpde.tracks.read), got "
                        f"{type(tracks).__name__}")
    case = case_for(tracks, case)
    grid = grid_of(case)
    names = _names(observables)
    parts = {}
    vel = None
    if "velocity" in names or any(n in names for n in _NEED_VELOCITY):
        vel = velocity_field(tracks, case, blocks=blocks, **_options(options, "velocity"))
        parts["velocity"] = vel     # kept for predict(like=...) even when not asked for
    if "profiles" in names:
        parts["profiles"] = profiles_of(vel, grid, heights)
    if "width" in names:
        parts["width"] = width_of(vel, case, heights)
    common = {"blocks": blocks}
    calls = {"diffusion": diffusion, "growth": displacement_growth,
             "correlation": velocity_correlation}
    for name, f in calls.items():
        if name in names:
            parts[name] = f(tracks, case, velocity=vel, **common, **_options(options, name))
    if "pairs" in names:
        parts["pairs"] = pair_separation(tracks, case, **common, **_options(options, "pairs"))
    if "layers" in names:
        parts["layers"] = drained_fraction(tracks, case, **common, **_options(options, "layers"))
    heights_attr = {} if heights is None else {"heights": list(map(float, heights))}
    return _combine(parts, {"observables": list(names), "blocks": blocks,
                            "source": str(tracks.attrs.get("source", "tracks")), **heights_attr})


def predict(model, case=None, observables: Sequence[str] | str | None = None, *,
            like: xr.Dataset | None = None, progress=None) -> xr.Dataset:
    """The same observables computed by the model.

    Args:
        model: a model result (``spotpde.run``), or a case (a Case, path or mapping) to
            run first (with its tracer when ``"layers"`` is asked for).
        case: the case (default: the result's own).
        observables: names (default: those of ``like``, else :data:`FIT_DEFAULT`).
        like: the tracks' measurement to mirror (coarse-graining, bins, falls, weights).
        progress: passed to ``spotpde.run`` when ``model`` is a case.

    Returns:
        Dataset with the same variable names, dims and units as :func:`measure`'s.
    """
    if observables is None and like is not None:
        observables = list(like.attrs.get("observables", FIT_DEFAULT))
    names = _names(observables)
    if not isinstance(model, xr.Dataset):
        case = model if isinstance(model, Case) else case_for(None, model)
        model = run(case, progress)
    case = case_for(model, case)
    grid = grid_of(case)

    def sub(name):
        return None if like is None else part(like, name)

    parts = {}
    vel_like = sub("velocity") if like is not None and "velocity.cg_width" in like.attrs else None
    vel = velocity_field(model, case, like=vel_like)
    heights = None if like is None else like.attrs.get("heights")
    if "velocity" in names:
        parts["velocity"] = vel
    if "profiles" in names:
        parts["profiles"] = profiles_of(vel, grid, _heights(like, "profiles", heights))
    if "width" in names:
        parts["width"] = width_of(vel, case, _heights(like, "width", heights),
                                  weights=vel_like)
    for name, f in {"diffusion": diffusion, "growth": displacement_growth}.items():
        if name in names:
            parts[name] = f(model, case, like=sub(name), velocity=vel)
    calls = {"correlation": velocity_correlation, "pairs": pair_separation,
             "layers": drained_fraction}
    for name, f in calls.items():
        if name in names:
            parts[name] = f(model, case, like=sub(name))
    return _combine(parts, {"observables": list(names), "source": "model"})


def _heights(like, name, heights):
    if like is not None and "height" in like.coords:
        return like["height"].values
    return heights
