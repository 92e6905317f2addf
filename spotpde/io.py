"""Result Datasets and netCDF files.

:func:`make_dataset` turns grid arrays into an :class:`xarray.Dataset` with the
CONTRACT.md variable names, dims ``("z", "x")`` / ``("z", "y", "x")`` (tracer frames add
a leading ``"t"``) and CF-style ``units`` / ``long_name`` on every variable and
coordinate. :func:`write_netcdf` writes netCDF4 with zlib compression atomically (a
temporary file in the same directory, then :func:`os.replace`), so an interrupted or
failed write never leaves a half-written result. :class:`FrameWriter` does the same for a
run whose tracer frames are streamed to the file as the solver produces them, so memory
does not grow with the number of frames. :func:`read_netcdf` reads a result back.

Unit strings: ``d`` is the particle diameter (the length unit), ``t`` the case's time
unit (the time in which a spot rises ``spots.drift`` diameters); they are *not* the
UDUNITS day and tonne, which the global attribute ``units_note`` says.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Mapping

import numpy as np
import xarray as xr

UNITS_NOTE = ("lengths in particle diameters (unit 'd'); times in the case's time unit "
              "(unit 't': a spot rises spots.drift d per t)")

#: Variables every result has (with a tracer also P, P_height, mass, outflow).
REQUIRED = ("rho_s", "v_kin", "u_x", "u_z", "D_xx", "D_xz", "D_zz")

COORDS = {
    "x": ("d", "horizontal position (cell centre)"),
    "y": ("d", "second horizontal position (cell centre)"),
    "z": ("d", "height above the orifice (cell centre)"),
    "t": ("t", "time since the tracer was released"),
}


def variable_attrs(name: str, dims: int) -> dict[str, str]:
    """``units`` and ``long_name`` of a result variable.

    Args:
        name: a CONTRACT.md variable name (``rho_s``, ``v_kin``, ``u_x``, ``D_xz``, ``P`` ...).
        dims: 2 or 3.

    Returns:
        ``{"units": ..., "long_name": ...}``.

    Raises:
        KeyError: for a name that is not a result variable.
    """
    axis = {"x": "x", "y": "y", "z": "z"}
    if name == "rho_s":
        return {"units": f"d-{dims}", "long_name": "mean spot density (spots per unit volume)"}
    if name == "v_kin":
        return {"units": "d t-1",
                "long_name": "kinematic-model downward particle speed (flux V1*Q0)"}
    if name.startswith("u_") and name[2:] in axis:
        return {"units": "d t-1", "long_name": f"particle drift u_p, {name[2:]} component"}
    if name.startswith("D_") and len(name) == 4 and set(name[2:]) <= set(axis):
        return {"units": "d2 t-1",
                "long_name": f"particle diffusivity D_p, {name[2:]} component"}
    if name == "P":
        return {"units": f"d-{dims}", "long_name": "tracer propagator (probability density)"}
    if name == "P_height":
        return {"units": f"d-{dims - 1}",
                "long_name": "geometrical propagator: density of where the tracer crosses "
                             "each height (time-integrated downward probability flux)"}
    if name == "residence":
        return {"units": f"t d-{dims}",
                "long_name": "residence density: expected time the tracer spends per unit "
                             "volume (time integral of P to infinity)"}
    if name == "mass":
        return {"units": "1", "long_name": "tracer probability inside the domain"}
    if name == "outflow":
        return {"units": "1",
                "long_name": "tracer probability that has left through the orifice "
                             "(and through open side walls, where the walls are open)"}
    raise KeyError(f"{name!r} is not a spotpde result variable; valid: rho_s, v_kin, "
                   "u_x, u_y, u_z, D_xx, D_yy, D_zz, D_xy, D_xz, D_yz, P, P_height, mass, "
                   "outflow")


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
                        {"units": units, "long_name": long_name})
    if times is not None:
        units, long_name = COORDS["t"]
        coords["t"] = ("t", np.asarray(times, dtype=float),
                       {"units": units, "long_name": long_name})
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
        data_vars[name] = (dims, arr, variable_attrs(name, grid.dims))
    ds = xr.Dataset(data_vars, coords=coords, attrs=dict(attrs or {}))
    ds.attrs.setdefault("units_note", UNITS_NOTE)
    return ds


def write_netcdf(ds: xr.Dataset, path: str | os.PathLike, *, complevel: int = 4) -> Path:
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
    tmp = _temporary(path)
    try:
        ds.to_netcdf(tmp, mode="w", format="NETCDF4", engine="netcdf4",
                     encoding=_encoding(ds, complevel))
        _publish(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return path


class FrameWriter:
    """Stream tracer frames into a result file, then add the rest of the result, atomically.

    Used as ``on_frame`` callback of :func:`spotpde.tracer.solve`. The file is a
    temporary one in the target's directory until :meth:`finish` renames it onto
    ``path``; leaving the ``with`` block with an exception (or Ctrl-C) removes it and
    leaves an existing ``path`` untouched. The finished file is the same as
    :func:`write_netcdf` writes for the whole Dataset: ``P`` is compressed the same way,
    chunked one frame at a time.

    Args:
        path: the result file to write (its directory must exist).
        grid: :class:`spotpde.grid.Grid` of the run.
        frames: number of tracer frames.
        complevel: zlib compression level 1..9.
    """

    def __init__(self, path: str | os.PathLike, grid, frames: int, *, complevel: int = 4):
        import netCDF4

        self.path = Path(os.path.abspath(path))
        self.complevel = complevel
        self.tmp = _temporary(self.path)
        try:
            nc = netCDF4.Dataset(self.tmp, "w", format="NETCDF4")
            axes = ("t", *grid.axes)
            for axis, n in zip(axes, (frames, *grid.shape)):
                nc.createDimension(axis, n)   # coordinates come with the Dataset in finish()
            P = nc.createVariable("P", "f8", axes, zlib=True, complevel=complevel,
                                  shuffle=True, chunksizes=(1, *grid.shape))
            P.setncatts(variable_attrs("P", grid.dims))
        except BaseException:
            self.abort()
            raise
        self._nc = nc

    def __call__(self, index: int, time: float, P: np.ndarray) -> None:
        """Write frame ``index`` (the tracer's ``on_frame`` callback)."""
        self._nc["P"][index] = P

    def finish(self, ds: xr.Dataset) -> Path:
        """Add every other variable and the global attributes, then rename onto ``path``.

        Args:
            ds: the result Dataset without ``P``, with the coordinates (``t`` the frame
                times) that :func:`make_dataset` gives it.

        Returns:
            The absolute path written.
        """
        self._nc.close()
        ds.to_netcdf(self.tmp, mode="a", format="NETCDF4", engine="netcdf4",
                     encoding=_encoding(ds, self.complevel))
        _publish(self.tmp, self.path)
        return self.path

    def abort(self) -> None:
        """Remove the temporary file (nothing is left behind)."""
        nc = getattr(self, "_nc", None)
        if nc is not None and nc.isopen():
            nc.close()
        try:
            os.unlink(self.tmp)
        except FileNotFoundError:
            pass

    def __enter__(self) -> "FrameWriter":
        return self

    def __exit__(self, kind, value, tb) -> None:
        if kind is not None:
            self.abort()


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
        with xr.open_dataset(path, engine="netcdf4") as ds:
            ds = ds.load()
    except Exception as exc:  # netCDF4/HDF5 raise assorted errors for bad files
        raise ValueError(f"{path}: not a readable netCDF file ({exc})") from None
    missing = [n for n in REQUIRED if n not in ds.data_vars]
    if missing:
        raise ValueError(f"{path}: not a spotpde result (missing {', '.join(missing)}; "
                         f"found {', '.join(map(str, ds.data_vars)) or 'no variables'})")
    return ds


def _encoding(ds: xr.Dataset, complevel: int) -> dict:
    """netCDF4 encoding of every data variable: zlib level ``complevel`` with shuffle."""
    return {name: {"zlib": True, "complevel": complevel, "shuffle": True}
            for name in ds.data_vars}


def _temporary(path: Path) -> str:
    """An empty temporary file next to ``path`` (hidden, ``.tmp``), for an atomic write."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    return tmp


def _publish(tmp: str, path: Path) -> None:
    """Give ``tmp`` the usual permissions (0666 minus the umask) and rename it onto ``path``."""
    os.chmod(tmp, 0o666 & ~_umask())
    os.replace(tmp, path)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
