"""Result Datasets and netCDF files.

:func:`make_dataset` turns grid arrays into an :class:`xarray.Dataset` with the
public variable names (docs/interface.md), dims ``("z", "x")`` / ``("z", "y", "x")``, or ``("z", "r")``
for an axisymmetric silo (tracer frames add a leading ``"t"``) and CF-style ``units`` / ``long_name`` on every variable and
coordinate. :func:`write_netcdf` writes netCDF4 with zlib compression atomically (a
temporary file in the same directory, then :func:`os.replace`), so an interrupted or
failed write never leaves a half-written result. :class:`FrameWriter` does the same for a
run whose tracer frames are streamed to the file as the solver produces them, so memory
does not grow with the number of frames. :func:`read_netcdf` reads a result back.

Signals and threads: a write holds SIGINT, SIGTERM and SIGHUP back
(:class:`~spotpde.app._outputs.held_signals`) while it is inside netCDF4 and xarray and
while it removes its temporary file; a signal received meanwhile is acted upon once the
write is complete, before the rename (the temporary file is removed, ``path`` is left as
it was) or, when it came during the rename, after it (``path`` is complete). The HDF5
library under netCDF4 is not thread-safe, and xarray opens a file without its own lock:
every write and read here takes one lock (:data:`NETCDF_LOCK`) for its whole length, and
the netCDF4 calls of :class:`FrameWriter` also take xarray's netCDF lock, so that
``spotpde.run(case, path=...)`` in several threads writes one file at a time.

Units (CF-1.10): every length is in particle diameters d and every time in the case's
time unit (``spots.drift`` is the spot speed in d per time unit), so every quantity is a
pure number and carries ``units = "1"``; its ``long_name`` says the scale ("in particle
diameters", "in d**2 per time unit"), the attribute ``spotpde_units`` gives it in
symbols (``"d-2"``, ``"d t-1"``), and the global attributes ``length_scale`` and
``time_scale`` define d and the time unit. Unit strings such as ``"d"`` or ``"t"`` are
not used: UDUNITS (cf_xarray, pint-xarray, Panoply) reads them as day and tonne.
Coordinates carry ``axis`` (``X``, ``Y``, ``Z``, ``T``) and ``z`` ``positive = "up"``.
:func:`cf_attrs` gives the global attributes ``Conventions``, ``history``, ``source``,
``references``, ``length_scale`` and ``time_scale``.
"""

from __future__ import annotations

import contextlib
import datetime
import os
import tempfile
import threading
from pathlib import Path
from typing import Mapping

import numpy as np
import xarray as xr

from .._version import __version__
from ..errors import WriteError
from ._outputs import held_signals

#: One netCDF write or read of spotpde at a time in this process (HDF5 is not
#: thread-safe): held by :func:`write_netcdf`, :func:`read_netcdf`, each step of a
#: :class:`FrameWriter`, and while ``spotpde.run`` opens the file it wrote.
NETCDF_LOCK = threading.RLock()

UNITS_NOTE = ("every quantity is dimensionless (units '1'): lengths in particle diameters d, "
              "times in the case's time unit (spots.drift is in d per time unit); "
              "the variable attribute spotpde_units gives the scale in these symbols")
#: Global attributes defining the scales (CF has no unit for them).
LENGTH_SCALE = "d, the particle diameter: every length is in particle diameters"
TIME_SCALE = ("the case's time unit: spots.drift is the spot speed v_s in d per time unit "
              "(with spots.drift = 1 the time unit is d / v_s)")
CONVENTIONS = "CF-1.10"
REFERENCES = ("M. Z. Bazant, The Spot Model for random-packing dynamics, Mechanics of "
              "Materials 38, 717-731 (2006), arXiv:cond-mat/0411040 (2004)")

#: Variables every result has (with a tracer also P, P_height, mass, outflow); an
#: axisymmetric result has ``u_r``, ``D_rr``, ``D_rz`` for the ``x`` names.
REQUIRED = ("rho_s", "v_kin", "u_x", "u_z", "D_xx", "D_xz", "D_zz")
REQUIRED_AXISYMMETRIC = ("rho_s", "v_kin", "u_r", "u_z", "D_rr", "D_rz", "D_zz")

COORDS = {
    "x": ("d", "horizontal position (cell centre), in particle diameters"),
    "y": ("d", "second horizontal position (cell centre), in particle diameters"),
    "z": ("d", "height above the orifice (cell centre), in particle diameters"),
    "r": ("d", "distance from the silo axis (cell centre), in particle diameters"),
    "t": ("t", "time since the tracer was released, in the case's time unit"),
}
#: CF axis attributes of the coordinates.
AXES = {"x": {"axis": "X"}, "y": {"axis": "Y"}, "z": {"axis": "Z", "positive": "up"},
        "r": {}, "t": {"axis": "T"}}
#: How ``spotpde_units`` symbols are spelled in long names.
_SPOKEN = {"d": "particle diameters", "d-1": "per particle diameter",
           "d-2": "per d**2", "d-3": "per d**3", "d2": "d**2", "d3": "d**3",
           "d t-1": "d per time unit", "d2 t-1": "d**2 per time unit",
           "t": "the case's time unit", "t-1": "per time unit"}


def cf_units(symbols: str, long_name: str) -> dict[str, str]:
    """CF attributes of a quantity whose scale is ``symbols`` in d and the time unit.

    Args:
        symbols: e.g. ``"d"``, ``"d-2"``, ``"d t-1"``, or ``"1"`` for a pure number.
        long_name: the description without units.

    Returns:
        ``{"units": "1", "long_name": "<long_name>, in <scale>", "spotpde_units": symbols}``
        (a pure number keeps its long name).
    """
    if symbols == "1":
        return {"units": "1", "long_name": long_name}
    spoken = _SPOKEN.get(symbols, symbols)
    return {"units": "1", "long_name": f"{long_name}, in {spoken}", "spotpde_units": symbols}


def cf_attrs(case=None, *, history: bool = True) -> dict[str, str]:
    """The CF global attributes of a result: ``Conventions``, ``source``, ``references``,
    ``history`` (a line naming the time and the case file), the scales.

    Args:
        case: the :class:`spotpde.cases.Case` (its source file goes into ``history``).
        history: include ``history`` (it holds the time, so two runs differ in it).
    """
    now = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    origin = getattr(case, "source", None)
    out = {
        "Conventions": CONVENTIONS,
        "source": f"spotpde {__version__}: continuum equations of the spot model",
        "references": REFERENCES,
        "history": f"{now} spotpde {__version__}: run "
                   + (f"of {origin}" if origin else "of a case given as a mapping"),
        "length_scale": LENGTH_SCALE,
        "time_scale": TIME_SCALE,
    }
    if not history:
        del out["history"]
    return out


def variable_attrs(name: str, dims: int) -> dict[str, str]:
    """``units``, ``long_name`` and ``spotpde_units`` of a result variable (:func:`cf_units`).

    Args:
        name: a result variable name (``rho_s``, ``v_kin``, ``u_x``, ``D_xz``, ``P`` ...;
            docs/interface.md).
        dims: 2 or 3: the dimension of the silo (3 for an axisymmetric one, whose
            densities are per unit volume).

    Returns:
        ``{"units": "1", "long_name": ..., "spotpde_units": ...}``.

    Raises:
        KeyError: for a name that is not a result variable.
    """
    axis = {"x": "x", "y": "y", "z": "z", "r": "r"}
    if name == "rho_s":
        return cf_units(f"d-{dims}", "mean spot density (spots per unit volume)")
    if name == "v_kin":
        return cf_units("d t-1", "kinematic-model downward particle speed (flux V1*Q0)")
    if name.startswith("u_") and name[2:] in axis:
        return cf_units("d t-1", f"particle drift u_p, {name[2:]} component")
    if name.startswith("D_") and len(name) == 4 and set(name[2:]) <= set(axis):
        return cf_units("d2 t-1", f"particle diffusivity D_p, {name[2:]} component")
    if name == "P":
        return cf_units(f"d-{dims}", "tracer propagator (probability density)")
    if name == "P_height":
        return cf_units(f"d-{dims - 1}",
                        "geometrical propagator: density of where the tracer crosses "
                        "each height (time-integrated downward probability flux)")
    if name == "residence":
        return cf_units(f"t d-{dims}",
                        "residence density: expected time the tracer spends per unit "
                        "volume (time integral of P to infinity)")
    if name == "mass":
        return cf_units("1", "tracer probability inside the domain")
    if name == "outflow":
        return cf_units("1", "tracer probability that has left through the orifice "
                        "(and through open side walls, where the walls are open)")
    raise KeyError(f"{name!r} is not a spotpde result variable; valid: rho_s, v_kin, "
                   "u_x, u_y, u_z, D_xx, D_yy, D_zz, D_xy, D_xz, D_yz, u_r, D_rr, D_rz, "
                   "P, P_height, residence, mass, outflow")


def silo_dims(grid) -> int:
    """The silo's dimension: ``grid.dims``, or 3 for an axisymmetric grid (a cylinder)."""
    return 3 if getattr(grid, "axisymmetric", False) else grid.dims


def make_dataset(
    grid,
    fields: Mapping[str, np.ndarray],
    *,
    times: np.ndarray | None = None,
    attrs: Mapping | None = None,
) -> xr.Dataset:
    """Build the result Dataset of a run.

    Args:
        grid: :class:`spotpde.grid.Grid` the arrays live on.
        fields: arrays by variable name; grid-shaped arrays get dims ``grid.axes``,
            arrays with one more leading axis (``P``) get ``("t", *grid.axes)``, 1D
            arrays of ``len(times)`` (``mass``, ``outflow``) get ``("t",)``.
        times: tracer frame times in t (required when any field has a ``"t"`` axis).
        attrs: global attributes.

    Returns:
        The Dataset, every variable and coordinate carrying ``units`` and ``long_name``.

    Raises:
        ValueError: an array whose shape fits none of the above.
    """
    coords = {}
    for axis in grid.axes:
        units, long_name = COORDS[axis]
        coords[axis] = (axis, np.asarray(grid.coords()[axis], dtype=float),
                        {**cf_units(units, long_name), **AXES[axis]})
    if times is not None:
        units, long_name = COORDS["t"]
        coords["t"] = ("t", np.asarray(times, dtype=float),
                       {**cf_units(units, long_name), **AXES["t"]})
    data_vars = {}
    for name, arr in fields.items():
        arr = np.asarray(arr, dtype=float)
        if arr.shape == grid.shape:
            dims = grid.axes
        elif times is not None and arr.shape == (len(times), *grid.shape):
            dims = ("t", *grid.axes)
        elif times is not None and arr.shape == (len(times),):
            dims = ("t",)
        else:
            valid = [grid.shape] + ([(len(times), *grid.shape), (len(times),)]
                                    if times is not None else [])
            raise ValueError(f"{name}: array of shape {arr.shape} fits none of the result "
                             f"shapes {valid}")
        attrs_v = variable_attrs(name, silo_dims(grid))
        if attrs_v.get("units", "1") != "1":     # a scale in symbols: make it CF
            attrs_v = {**attrs_v, **cf_units(attrs_v["units"], attrs_v["long_name"])}
        data_vars[name] = (dims, arr, attrs_v)
    ds = xr.Dataset(data_vars, coords=coords, attrs=dict(attrs or {}))
    ds.attrs.setdefault("units_note", UNITS_NOTE)
    for key, value in cf_attrs(history=False).items():
        ds.attrs.setdefault(key, value)
    return ds


#: zlib level of the result files. Level 1 compresses the fields and tracer frames of a
#: result (float64 with the shuffle filter) within 1 % of level 4 at 2.2-2.5 times the
#: speed (a 3D slab at d/2: P 2.4 MiB -> 1.29 / 1.28 MiB, 59 / 25 MiB per CPU second);
#: writing was a tenth of a 3D slab's run at level 4.
COMPLEVEL = 1


def write_netcdf(ds: xr.Dataset, path: str | os.PathLike, *,
                 complevel: int = COMPLEVEL) -> Path:
    """Write a Dataset as compressed netCDF4, atomically.

    The data go to a temporary file in the target's directory, which is then renamed
    onto ``path``; on any error or interruption the temporary file is removed and an
    existing ``path`` is left untouched.

    Args:
        ds: the result Dataset.
        path: target file (its directory must exist).
        complevel: zlib compression level 1..9.

    Returns:
        The absolute path written.
    """
    path = Path(os.path.abspath(path))
    tmp = None
    with NETCDF_LOCK, held_signals() as held:
        try:
            tmp = _temporary(path)
            ds.to_netcdf(tmp, mode="w", format="NETCDF4", engine="netcdf4",
                         encoding=_encoding(ds, complevel))
            stopped = bool(held.received)     # a signal during the write: no result
            if stopped:
                _unlink(tmp)
            else:
                _publish(tmp, path)
        except BaseException as exc:
            if tmp is not None:
                _unlink(tmp)
            if isinstance(exc, Exception) and not isinstance(exc, WriteError):
                raise _write_error(path, exc) from None
            raise
    if stopped:       # its handler did not raise
        raise _stopped(path, held.received[0])
    return path


class FrameWriter:
    """Stream tracer frames into a result file, then add the rest of the result, atomically.

    Used as ``on_frame`` callback of :func:`spotpde.tracer.solve`. The file is a
    temporary one in the target's directory until :meth:`finish` renames it onto
    ``path``; leaving the ``with`` block with an exception (or Ctrl-C) removes it and
    leaves an existing ``path`` untouched. Signals and threads: see the module docstring
    (a signal is acted upon between two steps, never inside netCDF4 or the clean-up). The finished file is the same as
    :func:`write_netcdf` writes for the whole Dataset: ``P`` is compressed the same way,
    chunked one frame at a time.

    Args:
        path: the result file to write (its directory must exist).
        grid: :class:`spotpde.grid.Grid` of the run.
        frames: number of tracer frames.
        complevel: zlib compression level 1..9.
    """

    def __init__(self, path: str | os.PathLike, grid, frames: int, *,
                 complevel: int = COMPLEVEL):
        import netCDF4

        self.path = Path(os.path.abspath(path))
        self.complevel = complevel
        self.tmp = self._nc = None
        try:
            with NETCDF_LOCK, held_signals():
                self.tmp = _temporary(self.path)
                with _netcdf_lock():
                    self._nc = nc = netCDF4.Dataset(self.tmp, "w", format="NETCDF4")
                    axes = ("t", *grid.axes)
                    for axis, n in zip(axes, (frames, *grid.shape)):
                        nc.createDimension(axis, n)   # coordinates come in finish()
                    P = nc.createVariable("P", "f8", axes, zlib=True, complevel=complevel,
                                          shuffle=True, chunksizes=(1, *grid.shape))
                    P.setncatts(variable_attrs("P", silo_dims(grid)))
        except BaseException as exc:
            self._abort(drop=isinstance(exc, KeyboardInterrupt))
            raise

    def __call__(self, index: int, time: float, P: np.ndarray) -> None:
        """Write frame ``index`` (the tracer's ``on_frame`` callback).

        Raises:
            spotpde.errors.WriteError: the frame could not be written (disk full, file
                size limit); the temporary file has been removed.
        """
        try:
            with NETCDF_LOCK, held_signals(), _netcdf_lock():
                self._nc["P"][index] = P
        except Exception as exc:
            self.abort()
            raise _write_error(self.path, exc) from None

    def finish(self, ds: xr.Dataset) -> Path:
        """Add every other variable and the global attributes, then rename onto ``path``.

        Args:
            ds: the result Dataset without ``P``, with the coordinates (``t`` the frame
                times) that :func:`make_dataset` gives it.

        Returns:
            The absolute path written.

        A signal received during this call is acted upon when it returns: before the
        rename, the temporary file is removed and ``path`` left as it was.
        """
        with NETCDF_LOCK, held_signals() as held:
            try:
                nc, self._nc = self._nc, None     # closed once, here, even if closing fails
                with _netcdf_lock():
                    nc.close()
                ds.to_netcdf(self.tmp, mode="a", format="NETCDF4", engine="netcdf4",
                             encoding=_encoding(ds, self.complevel))
                stopped = bool(held.received)     # a signal during the write: no result
                if stopped:
                    self.abort()
                else:
                    _publish(self.tmp, self.path)
            except BaseException as exc:
                self.abort()
                if isinstance(exc, Exception) and not isinstance(exc, WriteError):
                    raise _write_error(self.path, exc) from None
                raise
        if stopped:       # its handler did not raise
            raise _stopped(self.path, held.received[0])
        return self.path

    def abort(self) -> None:
        """Close the file if it is still open and remove the temporary file (nothing is
        left behind; safe to call more than once, and after a failed close). Signals are
        held back until it is done."""
        self._abort(drop=False)

    def _abort(self, drop: bool) -> None:
        """:meth:`abort`; ``drop``: forget signals received meanwhile (the process is
        stopping already)."""
        with held_signals(drop=drop):
            nc, self._nc = getattr(self, "_nc", None), None
            if nc is not None:
                try:
                    with NETCDF_LOCK, _netcdf_lock():
                        if nc.isopen():
                            nc.close()
                except Exception:  # noqa: BLE001 - a failing close (disk full) must not stop the unlink
                    pass
            if getattr(self, "tmp", None) is not None:
                _unlink(self.tmp)

    def __enter__(self) -> "FrameWriter":
        return self

    def __exit__(self, kind, value, tb) -> None:
        if kind is not None:
            self._abort(drop=issubclass(kind, KeyboardInterrupt))


def read_netcdf(path: str | os.PathLike) -> xr.Dataset:
    """Read a result file completely into memory.

    Args:
        path: a netCDF file written by :func:`write_netcdf`.

    Returns:
        The Dataset (the file is closed).

    Raises:
        ValueError: the file is missing, unreadable, or not a spotpde result
            (lacks one of :data:`REQUIRED`).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ValueError(f"{path}: no such result file")
    try:
        with NETCDF_LOCK, held_signals(), xr.open_dataset(path, engine="netcdf4") as ds:
            ds = ds.load()
    except Exception as exc:  # netCDF4/HDF5 raise assorted errors for bad files
        raise ValueError(f"{path}: not a readable netCDF file ({exc})") from None
    missing = [n for n in required_variables(ds) if n not in ds.data_vars]
    if missing:
        raise ValueError(f"{path}: not a spotpde result (missing {', '.join(missing)}; "
                         f"found {', '.join(map(str, ds.data_vars)) or 'no variables'})")
    return ds


def check_single_run(ds: xr.Dataset, path: str | os.PathLike = "result") -> None:
    """Check that a Dataset is the result of one run, as :func:`plot_result
    <spotpde.plotting.plot_result>` and the analysis functions expect.

    Every :data:`REQUIRED` variable must have dims ``("z", "x")``, ``("z", "y", "x")``
    or, axisymmetric, ``("z", "r")`` (``P`` a leading ``"t"``) with at least 2 points
    along each.

    Args:
        ds: a Dataset read by :func:`read_netcdf`.
        path: the file it came from (for the message).

    Raises:
        ValueError: naming the file and what is different (e.g. a sweep result, whose
            variables have the swept keys as leading dimensions).
    """
    allowed = (("z", "x"), ("z", "y", "x"), ("z", "r"))
    dims = tuple(ds["rho_s"].dims)
    if dims not in allowed:
        extra = [d for d in dims if d not in ("z", "y", "x", "r")]
        hint = (f"; it looks like a sweep result over {', '.join(map(str, extra))}: select "
                "one member first, e.g. ds.isel(" + ", ".join(f"{d}=0" for d in extra)
                + ")") if extra and "sweep_keys" in ds.attrs else ""
        raise ValueError(f"{os.fspath(path)}: not a single-run result (rho_s has dims "
                         f"{dims}, expected ('z', 'x'), ('z', 'y', 'x') or ('z', 'r')){hint}")
    for name in required_variables(ds):
        if tuple(ds[name].dims) != dims:
            raise ValueError(f"{os.fspath(path)}: not a single-run result ({name} has dims "
                             f"{tuple(ds[name].dims)}, expected {dims})")
    if "P" in ds.data_vars and tuple(ds["P"].dims) != ("t", *dims):
        raise ValueError(f"{os.fspath(path)}: not a single-run result (P has dims "
                         f"{tuple(ds['P'].dims)}, expected {('t', *dims)})")
    small = [d for d in dims if ds.sizes[d] < 2 or d not in ds.coords]
    if small:
        raise ValueError(f"{os.fspath(path)}: not a single-run result (dimension "
                         f"{small[0]} needs a coordinate and at least 2 points)")


def required_variables(ds: xr.Dataset) -> tuple[str, ...]:
    """:data:`REQUIRED`, or :data:`REQUIRED_AXISYMMETRIC` for a result with an ``r`` axis."""
    return REQUIRED_AXISYMMETRIC if "r" in ds.dims else REQUIRED


def _write_error(path: Path, exc: BaseException) -> WriteError:
    """A :class:`WriteError` naming ``path`` and the cause (its temporary file is gone)."""
    why = (exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)) or \
        type(exc).__name__
    return WriteError(f"could not write {path} ({why}); nothing was written")


def _stopped(path: Path, signum: int) -> WriteError:
    """The error of a write that a signal stopped (when the signal's handler returned)."""
    return WriteError(f"could not write {path} (stopped by signal {signum}); nothing was "
                      "written")


def _netcdf_lock():
    """xarray's lock around netCDF4 calls (every xarray read and write takes it): the
    :class:`FrameWriter`'s own netCDF4 calls take it too, so no other thread's xarray
    I/O runs inside HDF5 beside them."""
    try:
        from xarray.backends.netCDF4_ import NETCDF4_PYTHON_LOCK
    except ImportError:     # pragma: no cover - another xarray layout
        return contextlib.nullcontext()
    return NETCDF4_PYTHON_LOCK


#: Temporary files of writes under way in this process (:func:`remove_temporaries`).
_LIVE: set[str] = set()


def remove_temporaries() -> None:
    """Remove the temporary files of every write still under way in this process (for a
    command that stops on a signal: a second signal may have cut a write's own clean-up)."""
    with held_signals(drop=True):
        for tmp in list(_LIVE):
            _unlink(tmp)


def _unlink(path: str) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    _LIVE.discard(path)


def _encoding(ds: xr.Dataset, complevel: int) -> dict:
    """netCDF4 encoding of every data variable: zlib level ``complevel`` with shuffle."""
    return {name: {"zlib": True, "complevel": complevel, "shuffle": True}
            for name in ds.data_vars}


def _temporary(path: Path) -> str:
    """An empty temporary file next to ``path`` (hidden, ``.tmp``), for an atomic write."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    _LIVE.add(tmp)
    os.close(fd)
    return tmp


def _publish(tmp: str, path: Path) -> None:
    """Give ``tmp`` the usual permissions (0666 minus the umask) and rename it onto ``path``."""
    os.chmod(tmp, 0o666 & ~_umask())
    os.replace(tmp, path)
    _LIVE.discard(tmp)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
