"""Where spotpde keeps its caches: never inside the installed package.

numba writes the machine code of ``@njit(cache=True)`` kernels next to their source
(``spotpde/__pycache__``) unless ``NUMBA_CACHE_DIR`` says otherwise. Inside an
installed package that is wrong three ways: a read-only install (a system package, a
container image) cannot be written, so numba raises on first use; a non-editable install
that is later replaced by an editable one (``pip install . && pip install -e .``) leaves
``site-packages/spotpde/__pycache__`` behind, which then shadows the package as an empty
namespace package (``module 'spotpde' has no attribute 'load_case'``); and the cache is
shared by every user of the install.

:func:`configure` (called by ``import spotpde`` before anything imports numba) therefore
points numba at a per-user directory, chosen in this order:

1. ``$NUMBA_CACHE_DIR`` when the user has set it (respected as it is);
2. ``$SPOTPDE_CACHE_DIR/numba``;
3. ``$XDG_CACHE_HOME/spotpde/numba``, else ``~/.cache/spotpde/numba``;
4. ``<tmp>/spotpde-<uid>/numba`` (``tempfile.gettempdir()``) when the directories above
   cannot be created or written (no writable ``HOME``, a read-only file system).

The first directory that can be created and written is used. numba keeps a separate
subtree per source directory under it, so several installs share it safely. FFTW wisdom
(:mod:`spotpde.fields._fft`) lives beside it, in the parent ``spotpde`` cache directory.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

#: The directory chosen by the last :func:`configure` call (``None`` before).
NUMBA_DIR: Path | None = None


def user_cache_dir() -> Path:
    """The spotpde user cache directory (not created here).

    ``$SPOTPDE_CACHE_DIR``, else ``$XDG_CACHE_HOME/spotpde``, else ``~/.cache/spotpde``
    (``HOME`` unset or unusable gives the temporary fallback of :func:`fallback_dir`).
    """
    env = os.environ.get("SPOTPDE_CACHE_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    if xdg and os.path.isabs(xdg):
        return Path(xdg) / "spotpde"
    try:
        home = Path.home()
    except (RuntimeError, KeyError):   # no HOME and no passwd entry
        return fallback_dir()
    return home / ".cache" / "spotpde"


def fallback_dir() -> Path:
    """``<tmp>/spotpde-<uid>``: a per-user cache directory in the temporary directory."""
    uid = os.getuid() if hasattr(os, "getuid") else "user"
    return Path(tempfile.gettempdir()) / f"spotpde-{uid}"


def writable(directory: Path) -> bool:
    """Create ``directory`` (mode 0700 for new parents) and check that a file can be
    written in it; False on any failure."""
    try:
        directory.mkdir(mode=0o700, parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".probe.", dir=directory)
        os.close(fd)
        os.unlink(probe)
        return True
    except OSError:
        return False


def configure() -> Path | None:
    """Point numba's cache at a writable per-user directory (see the module docstring).

    Sets ``os.environ["NUMBA_CACHE_DIR"]`` (read when numba is imported) and, if numba
    is already imported, ``numba.config.CACHE_DIR`` (read on every cache lookup). A
    ``NUMBA_CACHE_DIR`` set by the user is kept.

    Returns:
        The numba cache directory, or ``None`` when no candidate is writable (numba then
        compiles without caching and warns once).
    """
    global NUMBA_DIR
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user:
        NUMBA_DIR = Path(user)
        return NUMBA_DIR
    chosen = None
    for candidate in (user_cache_dir() / "numba", fallback_dir() / "numba"):
        if writable(candidate):
            chosen = candidate
            break
    if chosen is None:
        return None
    os.environ["NUMBA_CACHE_DIR"] = str(chosen)
    numba = sys.modules.get("numba")
    if numba is not None:   # imported before spotpde: its config was read already
        numba.config.CACHE_DIR = str(chosen)
    NUMBA_DIR = chosen
    return chosen
