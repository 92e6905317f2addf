"""The run pipeline: a validated case in, the result Dataset out.

Stages (each reports its progress)::

    spot density     spot_density.solve(grid, orifice, spots)          -> rho_s
                     (transient with a tracer: spot_density.transient(..., times=))
    particle fields  coefficients.particle_fields(grid, rho_s, spots, kernel, rule)
                     (tracer.model = "void": void.void_fields(grid, rho_s, spots, V1))
    kinematic model  kinematic.speed(grid, orifice, b) * V1 * Q0       -> v_kin
    tracer           tracer.solve(grid, fields, P0, t_end, frames, limiter=, cfl=,
                     diffusion=, on_frame=)                             (optional)

With ``spots.mode = "transient"`` and a tracer, the spot density is also kept at the
times ``case.snapshot_times()`` (over ``[0, tracer.t_end]``), and the tracer gets
time-dependent coefficients: the particle fields of the two snapshots around ``t``,
interpolated linearly (:class:`SnapshotFields`). The reported ``rho_s`` and fields are
those at ``spots.t_end`` (the same solve when ``spots.t_end = tracer.t_end``).

With ``run(case, path=...)`` the tracer's ``on_frame`` is an :class:`spotpde.io.FrameWriter`
that streams every frame to the result file, so ``P`` is never held in memory whole.

The Dataset has the public variables (docs/interface.md) and global attributes ``V1``, ``V2``, ``rule``,
``model``, ``spotpde_version`` and ``case`` (the validated case as TOML).
"""

from __future__ import annotations

import contextlib
import importlib
import math
import os
from typing import Callable, NamedTuple

import numpy as np
import xarray as xr

from .._version import __version__
from .cases import Case, check_arguments, load_case
from ..errors import CaseError, NumericalError
from .._roundoff import clip_roundoff
from .io import cf_attrs, FrameWriter, make_dataset, NETCDF_LOCK, write_netcdf
from ._outputs import held_signals, output_problem
from ..parameters import TracerStart, in_bands

#: The pipeline's stages, in order, as reported to ``progress``.
STAGES = ("spot density", "particle fields", "kinematic model", "tracer")

Progress = Callable[[str, float], None]


def run(case: Case | str, progress: Progress | None = None, *,
        path: str | os.PathLike | None = None,
        on_fields: Callable[[dict], None] | None = None) -> xr.Dataset:
    """Run a case.

    Args:
        case: a :class:`spotpde.cases.Case` (or a path / mapping for :func:`load_case`).
        progress: optional ``progress(stage, fraction)`` callback, ``stage`` one of
            :data:`STAGES`, ``fraction`` in 0..1 (a few hundred calls per stage at most).
        path: also write the result there as netCDF, atomically. The tracer frames are
            then streamed to the file as they are computed instead of being held in
            memory, and the returned Dataset reads ``P`` lazily from the file (one
            frame per chunk), so memory does not grow with ``tracer.frames``. Runs in
            several threads write their files one at a time (``spotpde.app.io``); a
            signal is acted upon between the steps of a write, never inside one.
        on_fields: optional ``on_fields(fields)``, called once with the steady
            coefficient fields (dict of grid arrays, as returned by :func:`case_fields`)
            right after the particle-fields stage, before the tracer stage and before
            ``path`` or its temporary file is created; an exception it raises propagates
            unchanged (``spotpde run`` prints its run-time estimate there and refuses a
            run of more than a day with a ``CaseError``).

    Returns:
        The result :class:`xarray.Dataset` (lengths in d, times in the case unit).

    Raises:
        TypeError: ``case``, ``path``, ``progress`` or ``on_fields`` of the wrong type
            (named).
        spotpde.CaseError: invalid case (only when ``case`` is a path or mapping).
        ValueError: ``path`` cannot be written (missing or read-only directory, an
            existing directory or device, the case file itself), checked before computing.
        spotpde.errors.WriteError: writing ``path`` failed (disk full); nothing is left.
        spotpde.NumericalError: a solver blew up, refused the derived fields (a
            ``CaseError`` raised inside a stage, re-raised with its lines), or a result
            holds NaN or infinity.
    """
    _check_arguments(case, path, progress, on_fields)
    if not isinstance(case, Case):
        case = load_case(case)
    if path is not None:   # before computing: a missing or read-only directory, ...

        problem = output_problem(path, inputs=[case.source] if case.source else ())
        if problem:
            raise ValueError(f"path: {problem}")
    raised = []        # what on_fields raised: not a solver refusing derived data

    def fields_hook(fields):
        try:
            on_fields(fields)
        except BaseException as exc:
            raised.append(exc)
            raise

    hook = fields_hook if on_fields is not None else None
    try:
        if path is None:
            return _run(case, progress, on_fields=hook)
        if case.tracer is None or math.isinf(case.tracer.t_end):   # no P frames to stream
            ds = _run(case, progress, on_fields=hook)
            write_netcdf(ds, path)
            return ds
        with contextlib.ExitStack() as files:
            writers = []

            def open_writer():   # when the tracer starts: after on_fields, so a refused
                writers.append(files.enter_context(     # run leaves no file
                    FrameWriter(path, case.grid, case.tracer.frames)))
                return writers[0]

            ds = _run(case, progress, open_frames=open_writer, on_fields=hook)
            written = writers[0].finish(ds)
        with NETCDF_LOCK, held_signals():   # another thread's write; a signal in xarray's lock
            return xr.open_dataset(written, engine="netcdf4", chunks={})  # P: a frame a chunk
    except ValueError as err:
        if raised and err is raised[0]:
            raise
        # The case passed validation, so a solver refusing its inputs here (ValueError
        # naming its argument) is refusing derived data (fields, densities): a numerical
        # failure, not an invalid case.
        lines = err.problems if isinstance(err, CaseError) else str(err).splitlines()
        raise NumericalError("; ".join(lines)) from None


def _check_arguments(case, path, progress, on_fields) -> None:
    """TypeError naming the argument of :func:`run` that has the wrong type."""
    check_arguments(case, path=path)
    for name, f in (("progress", progress), ("on_fields", on_fields)):
        if f is not None and not callable(f):
            raise TypeError(f"{name}: must be callable or None, got {type(f).__name__}")


def _run(case: Case, progress: Progress | None, open_frames=None,
         on_fields=None) -> xr.Dataset:
    """:func:`run` without the output file; ``open_frames()`` returns the tracer's
    ``on_frame`` (called when the tracer stage starts), ``on_fields`` as in :func:`run`.

    The stages in order: the spot density (:func:`_density_stage`), the coefficient
    fields, the Kinematic Model (:func:`_kinematic_stage`), the tracer
    (:func:`_tracer_stage`), then the Dataset with its attributes (:func:`_attrs`),
    interacting spots' frames and the pair's cage breaking."""
    grid, spots = case.grid, case.spots
    density = _density_stage(case, progress)
    rho_s = clip_roundoff(density.rho_raw)

    stage = _stage(progress, "particle fields") or _noop
    stage(0.0)
    # transient fronts with b_par = 0 leave dispersive undershoots of a few per cent in
    # rho_s (BDF2, second-order upwind); a spot density cannot be negative, so the
    # coefficient fields of a transient run use its positive part (rho_s is reported as
    # solved)
    transient = spots.mode == "transient"
    fields = case_fields(case, np.maximum(rho_s, 0.0) if transient else rho_s)
    if density.snap_times is None and case.model != "void":   # no more convolutions
        importlib.import_module("spotpde.fields.coefficients").release_caches()
    stage(1.0)
    if on_fields is not None:
        on_fields(fields)

    v_kin = _kinematic_stage(case, density, progress)
    out = {"rho_s": rho_s, "v_kin": v_kin, **fields}
    times, steady_attrs = None, {}
    if case.tracer is not None:
        coefficients = (fields if density.snapshots is None else
                        SnapshotFields(density.snap_times, density.snapshots,
                                       lambda r: case_fields(case, r)))
        tracer_out, times, steady_attrs = _tracer_stage(case, coefficients, progress,
                                                        open_frames)
        out.update(tracer_out)
    for name, arr in out.items():
        _check_finite(name, np.asarray(arr, dtype=float))
    if grid.geometry.masked:     # cells outside the material are NaN in results
        out = {name: _mask_outside(grid, np.asarray(arr, dtype=float))
               for name, arr in out.items()}

    ds = make_dataset(grid, out, times=times, attrs=_attrs(case, steady_attrs))
    if density.interacting is not None:
        ds = importlib.import_module("spotpde.density.traffic").add_outputs(
            ds, case, density.interacting)
    if case.pair is not None:     # cage breaking at a point (spotpde.pair)
        ds = importlib.import_module("spotpde.pair").add_to_result(case, ds)
    return ds


class _Density(NamedTuple):
    """The spot density stage's results: ``rho_raw`` (d^-dims, as solved, before round-off
    clipping), the transient ``snapshots`` at ``snap_times`` (or None), and interacting
    spots' frames and rates (or None)."""

    rho_raw: np.ndarray
    snapshots: object
    snap_times: object
    interacting: object


def _density_stage(case: Case, progress: Progress | None) -> _Density:
    """The spot density ``rho_s``: steady, transient (with the snapshots the tracer
    needs), or interacting spots' last frame."""
    grid, orifice, spots = case.grid, case.orifice, case.spots
    if progress is not None:     # the stage starts with loading its solver
        progress("spot density", 0.0)
    spot_density = importlib.import_module("spotpde.density.spot_density")
    snap_times = case.snapshot_times()
    snapshots = None
    if snap_times is not None:
        snapshots = spot_density.transient(grid, orifice, spots, float(snap_times[-1]),
                                           times=snap_times,
                                           progress=_stage(progress, "spot density"))
    interacting = None        # spots.rho_max: space-time frames and rates (spotpde.traffic)
    if spots.rho_max is not None:
        interacting = importlib.import_module("spotpde.density.traffic").solve_case(
            case, progress=_stage(progress, "spot density"))
    if interacting is not None:          # the same solve as its frames rho_s_t
        rho_s = interacting.rho_s
    elif snapshots is not None and snap_times[-1] == spots.t_end:
        rho_s = snapshots[-1]
    else:
        rho_s = spot_density.solve(grid, orifice, spots,
                                   progress=_stage(progress, "spot density"))
    rho_s = _check_shape(np.asarray(rho_s, dtype=float), grid)
    _check_finite("rho_s", rho_s)
    return _Density(rho_s, snapshots, snap_times, interacting)


def _kinematic_stage(case: Case, density: _Density, progress: Progress | None) -> np.ndarray:
    """``v_kin`` (d per unit time, downward): the Kinematic Model for the mean ``b``,
    scaled so its flux through every height is ``V1 Q0``; zero outside a hopper."""
    grid, orifice, spots = case.grid, case.orifice, case.spots
    stage = _stage(progress, "kinematic model") or _noop
    stage(0.0)
    kinematic = importlib.import_module("spotpde.density.kinematic")
    V1 = float(case.kernel.V1)
    b = float(np.mean(spots.b))
    q0 = orifice.rate_at(spots.t_end if spots.mode == "transient" else 0.0)
    if (spots.mode == "steady" and density.snapshots is None and np.ndim(spots.b) == 0
            and np.ndim(spots.b_par) == 0 and float(spots.b_par) == 0.0):
        # uniform b, b_par = 0: the kinematic equation dv/dz = b lap_perp v is the spot
        # flux's (v_s rho_s), the same solve from the same floor profile: scale it
        v_kin = V1 * np.asarray(spots.drift, dtype=float) * density.rho_raw
    else:
        v_kin = np.asarray(kinematic.speed(grid, orifice, b), dtype=float) * V1 * q0
    stage(1.0)
    return grid.geometry.restrict(v_kin)     # nothing moves outside a hopper's walls


def _tracer_stage(case: Case, coefficients, progress: Progress | None, open_frames):
    """The tracer: one steady solve for ``t_end = inf`` (``P_height``, ``residence`` and
    the exit statistics as attributes, docs/steady.md), else time stepping (frames of
    ``P`` or streamed to ``open_frames()``, ``P_height``, ``mass``, ``outflow``).
    Returns ``(variables, times or None, attributes)``."""
    grid = case.grid
    tracer = importlib.import_module("spotpde.tracer")
    P0 = initial_density(grid, case.tracer.start)
    if math.isinf(case.tracer.t_end):
        stage = _stage(progress, "tracer") or _noop
        stage(0.0)
        res = tracer.solve_steady(grid, coefficients, P0,
                                  scheme=case.tracer_options.get("limiter", "weno5"))
        stage(1.0)
        attrs = {f"exit_{k}": float(v) for k, v in res.exit.items()}
        attrs.update(mean_exit_time=float(res.mean_exit_time),
                     steady_scheme=res.options["scheme"],
                     steady_residual=float(res.residual))
        return {"P_height": res.P_height, "residence": res.residence}, None, attrs
    on_frame = open_frames() if open_frames is not None else None
    res = tracer.solve(grid, coefficients, P0, case.tracer.t_end, case.tracer.frames,
                       progress=_stage(progress, "tracer"),
                       on_frame=_outside_as_nan(grid, on_frame), **case.tracer_options)
    out = {"P_height": res.P_height, "mass": res.mass, "outflow": res.outflow}
    if res.P is not None:      # None: the frames went to on_frame
        out["P"] = res.P
    return out, np.asarray(res.times, dtype=float), {}


def _attrs(case: Case, steady_attrs: dict) -> dict:
    """The result's global attributes: ``V1``, ``V2`` (d^dims), the rule, the models,
    the geometry, the version, the case as TOML text and the CF attributes."""
    grid = case.grid
    V1 = float(case.kernel.V1)
    V2 = V1 if case.model == "void" else float(case.kernel.V2)   # void: one particle a spot
    attrs = {
        "title": "spotpde result: spot model of granular drainage (Bazant 2004)",
        "V1": V1,
        "V2": V2,
        "rule": float(case.rule),
        "kernel_walls": case.kernel_walls,
        "diffusivity": case.diffusivity,
        "model": case.model,
        "dims": int(grid.dims),
        "coordinate_system": grid.coordinates,   # ("coordinates" is reserved by CF)
        "spotpde_version": __version__,
        "case": case.to_toml(),
    }
    attrs.update(grid.geometry.result_attrs)   # a hopper's angle
    attrs.update(steady_attrs)
    if case.source is not None:
        attrs["case_file"] = str(case.source)
    attrs.update(cf_attrs(case))   # Conventions, history, source, references, scales
    return attrs


def case_fields(case: Case, rho_s: np.ndarray) -> dict[str, np.ndarray]:
    """The particle drift and diffusivity fields of a case for one spot density.

    ``coefficients.particle_fields`` with the case's kernel and rule, or
    ``void.void_fields`` for ``tracer.model = "void"``.
    """
    if case.model == "void":
        void = importlib.import_module("spotpde.fields.void")
        fields = void.void_fields(case.grid, rho_s, case.spots, float(case.kernel.V1))
    else:
        coefficients = importlib.import_module("spotpde.fields.coefficients")
        fields = coefficients.particle_fields(case.grid, rho_s, case.spots, case.kernel,
                                              rule=case.rule, diffusivity=case.diffusivity,
                                              walls=case.kernel_walls)
    return {name: np.asarray(a, dtype=float) for name, a in fields.items()}


class SnapshotFields:
    """Time-dependent coefficient fields from spot-density snapshots: ``fields(t)``.

    Between snapshot times ``t_j <= t <= t_{j+1}`` the fields are
    ``(1 - s) F(rho_j+) + s F(rho_{j+1}+)``, ``s = (t - t_j) / (t_{j+1} - t_j)`` (linear
    in time; ``F`` the particle fields of one spot density, ``rho+`` its positive part),
    constant beyond the last snapshot. The fields of a snapshot are computed when first
    needed and three are kept, dropping the one farthest in time from the one asked for
    (the tracer asks at its stage times, which go back by at most a step, and once at
    ``t_end``: so at most three snapshots are in use).

    Args:
        times: sorted snapshot times (case time unit).
        rho: snapshots, ``(len(times),) + grid shape``.
        fields_of: ``rho_s -> dict`` of particle fields.
    """

    def __init__(self, times: np.ndarray, rho: np.ndarray, fields_of):
        self.times = np.asarray(times, dtype=float)
        self.rho = rho
        self.fields_of = fields_of
        self._cache: dict[int, dict[str, np.ndarray]] = {}

    def _fields(self, j: int) -> dict[str, np.ndarray]:
        f = self._cache.get(j)
        if f is None:
            r = np.asarray(self.rho[j], dtype=float)
            _check_finite(f"rho_s(t={self.times[j]:g})", r)
            f = self.fields_of(np.maximum(r, 0.0))     # positive part: see _run
            if len(self._cache) >= 3:   # the farthest (not the earliest: the solver's
                self._cache.pop(max(self._cache, key=lambda k: abs(k - j)))   # t_end probe)
            self._cache[j] = f
        return f

    def __call__(self, t: float) -> dict[str, np.ndarray]:
        times = self.times
        j = int(np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 1))
        if j == len(times) - 1 or t <= times[j]:
            return self._fields(j)
        s = (t - times[j]) / (times[j + 1] - times[j])
        a, b = self._fields(j), self._fields(j + 1)
        return {k: (1.0 - s) * a[k] + s * b[k] for k in a}


def initial_density(grid, start: TracerStart) -> np.ndarray:
    """Initial tracer density ``P0`` on the grid, normalised so ``sum(P0) h**dims = 1``.

    Args:
        grid: :class:`spotpde.grid.Grid`.
        start: ``kind="blob"``: a Gaussian of standard deviation ``width`` (d) centred at
            ``(x, [y,] z)`` (3D: ``y`` defaults to the middle); ``kind="layers"``: P
            uniform on the bands ``[k*spacing, k*spacing + spacing/2)`` in ``z`` (cell
            centres), zero between.

        On an axisymmetric grid the blob is centred at radius ``x`` (on the axis for
        ``x = 0``; elsewhere a ring); with a hopper ``P0`` is 0 outside the material.

    Returns:
        ``P0`` in d**-dims (d**-3 axisymmetric), array order ``(z, x)`` / ``(z, y, x)``
        / ``(z, r)``, normalised with the cell volumes (rings when axisymmetric).

    Raises:
        ValueError: the start puts no probability on the grid.
    """
    mesh = grid.mesh()
    Z, X = mesh[0], mesh[-1]
    if start.kind == "layers":
        bands = in_bands(Z - grid.z_range[0], start.spacing)
        P = np.broadcast_to(bands.astype(float), grid.shape).copy()
    elif start.kind == "blob":
        r2 = (X - start.x) ** 2 + (Z - start.z) ** 2
        if grid.dims == 3:
            y0 = start.y if start.y is not None else grid.y_centre
            r2 = r2 + (mesh[1] - y0) ** 2
        P = np.broadcast_to(np.exp(-0.5 * r2 / start.width**2), grid.shape).copy()
    else:
        raise ValueError(f"tracer start kind must be 'blob' or 'layers', got {start.kind!r}")
    P = grid.geometry.restrict(P)      # no tracer outside the material
    total = grid.geometry.total(P)     # rings: sum(P * 2 pi r h**2)
    if not total > 0:
        raise ValueError("tracer start puts no probability on the grid")
    return P / total


def _mask_outside(grid, arr: np.ndarray) -> np.ndarray:
    """``arr`` with NaN on the cells outside the material (``~grid.active``); arrays
    without the grid's trailing shape (``mass``, ``outflow``) are returned unchanged."""
    if arr.shape[-grid.dims:] != grid.shape:
        return arr
    return grid.geometry.blank(arr)


def _outside_as_nan(grid, on_frame):
    """``on_frame`` writing each frame with NaN outside the material (hoppers)."""
    if on_frame is None or not grid.geometry.masked:
        return on_frame
    return lambda index, time, P: on_frame(index, time, _mask_outside(grid, np.asarray(P)))


def _stage(progress: Progress | None, name: str):
    """A solver's ``progress(fraction)`` for one stage, or None without a callback."""
    if progress is None:
        return None
    return lambda fraction: progress(name, float(fraction))


def _noop(fraction: float) -> None:
    return None


def _check_shape(rho_s: np.ndarray, grid) -> np.ndarray:
    """``rho_s`` itself; a spot density that does not have the grid's shape is a failure."""
    if rho_s.shape != grid.shape:
        raise NumericalError(f"spot density has shape {rho_s.shape}, expected {grid.shape}")
    return rho_s


def _check_finite(name: str, arr: np.ndarray) -> None:
    # a finite sum means every value is finite (NaN and infinities propagate into it; an
    # overflowing sum of finite values only sends the check to the full test): one pass
    if arr.size == 0 or np.isfinite(np.sum(arr)) or np.all(np.isfinite(arr)):
        return
    bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
    raise NumericalError(f"{name}: {bad} values are NaN or infinite; the run is not "
                         f"trustworthy (try a smaller domain.spacing)")
