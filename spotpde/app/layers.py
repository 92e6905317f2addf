"""Layered-silo diagnostics, with the runs they need (``spotpde.layers``).

The measures on result Datasets live in :mod:`spotpde.analysis.layers` (re-exported
here: :func:`concentration`, :func:`layer_contrast`, :func:`interface_width`, ...); this
module adds what runs a case: :func:`numerical_blur` (the physical run and its
``D_p = 0`` rerun, then :func:`~spotpde.analysis.layers.measure_blur`),
:func:`run_without_diffusion`, and the variants :func:`refined` and
:func:`with_limiter`. Cases are a :class:`~spotpde.cases.Case`, a TOML path or a
mapping. Lengths in d, times in the case's time unit.
"""

from __future__ import annotations

import copy

import numpy as np
import xarray as xr

from .. import tracer
from ..analysis.layers import (X_MAX, Z_RANGE, concentration, interface_width,
                               layer_contrast, measure_blur, normal_strain,
                               predicted_variance, strained_numerical_diffusion, summary)
from . import pipeline
from .cases import Case, load_case

__all__ = ["X_MAX", "Z_RANGE", "concentration", "layer_contrast", "interface_width",
           "predicted_variance", "measure_blur", "numerical_blur", "run_without_diffusion",
           "refined", "with_limiter", "summary", "normal_strain",
           "strained_numerical_diffusion"]


def refined(case, factor: int = 2) -> Case:
    """The same case on a grid ``factor`` times finer (``domain.spacing / factor``)."""
    case = _as_case(case)
    data = copy.deepcopy(case.data)
    data["domain"]["spacing"] = case.data["domain"]["spacing"] / factor
    return load_case(data)


def with_limiter(case, limiter: str) -> Case:
    """The same case with another ``tracer.limiter``."""
    case = _as_case(case)
    data = copy.deepcopy(case.data)
    data["tracer"]["limiter"] = limiter
    return load_case(data)


def _as_case(case) -> Case:
    return case if isinstance(case, Case) else load_case(case)


def run_without_diffusion(case, ds: xr.Dataset | None = None) -> tuple[xr.Dataset, xr.DataArray]:
    """Run a layered case, and rerun its tracer with ``D_p = 0``.

    The ``D_p = 0`` run takes the drift ``u_x``, ``u_z`` of the physical run's Dataset
    (the very arrays, so the same flow), the same grid, initial density, frames and
    ``tracer.solve`` options (limiter, CFL number, diffusion mode) and sets ``D_xx``,
    ``D_xz``, ``D_zz`` to zero. (Without diffusion the time step is the advective limit;
    for the spot model that is the step of the physical run too.)

    Args:
        case: a :class:`spotpde.cases.Case`, a case path or mapping (2D, layered tracer).
        ds: the physical run's Dataset, if already computed (else it is run).

    Returns:
        ``(ds, P_num)``: the physical result and the ``D_p = 0`` frames (DataArray on
        ``(t, z, x)``, same coordinates as ``ds.P``).
    """
    case = _as_case(case)
    if case.tracer is None or case.tracer.start.kind != "layers":
        raise ValueError("numerical_blur needs a case with a layered tracer start")
    if case.grid.dims != 2:
        raise ValueError("numerical_blur is implemented for 2D cases")
    if ds is None:
        ds = pipeline.run(case)
    fields = {"u_x": np.asarray(ds.u_x, dtype=float), "u_z": np.asarray(ds.u_z, dtype=float),
              "D_xx": 0.0, "D_xz": 0.0, "D_zz": 0.0}
    P0 = pipeline.initial_density(case.grid, case.tracer.start)
    res = tracer.solve(case.grid, fields, P0, case.tracer.t_end, case.tracer.frames,
                       **case.tracer_options)
    P_num = xr.DataArray(res.P, dims=ds.P.dims, coords=ds.P.coords, name="P",
                         attrs=dict(ds.P.attrs))
    return ds, P_num


def numerical_blur(case, ds: xr.Dataset | None = None, *, x_max: float = X_MAX,
                   z_range: tuple[float, float] = Z_RANGE,
                   P_num: xr.DataArray | None = None) -> dict:
    """Measured numerical diffusion of a layered run (:mod:`spotpde.analysis.layers`).

    Runs the case (unless ``ds`` is given) and the same case with ``D_p = 0``
    (:func:`run_without_diffusion`, unless ``P_num`` is given), and measures the edge
    variance ``sigma**2`` (:func:`interface_width`) of both in the region per frame.

    Args:
        case: a :class:`spotpde.cases.Case`, path or mapping (2D, layered tracer).
        ds: the physical run's Dataset, if already computed.
        x_max, z_range: the measuring region (d).
        P_num: the ``D_p = 0`` frames, if already computed.

    Returns:
        the dict of :func:`~spotpde.analysis.layers.measure_blur` (edge variances in
        d**2, their growth rates in d**2 per unit time, ratios, contrasts, ``ds`` and
        ``P_num``).
    """
    case = _as_case(case)
    if P_num is None:
        ds, P_num = run_without_diffusion(case, ds)
    elif ds is None:
        raise ValueError("P_num given without ds")
    return measure_blur(case, ds, P_num, x_max=x_max, z_range=z_range)
