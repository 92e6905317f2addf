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
   cannot be created or written (no writable ``HOME``, a read-only file system), if
   ``<tmp>/spotpde-<uid>`` is this user's own and writable by nobody else (another user
   could otherwise plant machine code there).

The first directory that can be created and written is used. numba keeps a separate
subtree per source directory under it, so several installs share it safely. FFTW wisdom
(:mod:`spotpde.fields._fft`) lives beside it, in the parent ``spotpde`` cache directory.

A cache never fails a run. When no directory can be used (including a
``NUMBA_CACHE_DIR`` that cannot be written), spotpde's kernels compile without a cache;
when reading or writing the cache fails later (a full disk), that kernel compiles without
it and no more cache files are written. Each case warns once (a ``RuntimeWarning`` naming
the directory; ``spotpde: warning: ...`` on the command line). numba itself would raise
(``cannot cache function``) or fall back to the package's ``__pycache__``; so when numba
is imported, :func:`_patch_numba` wraps its ``Dispatcher.enable_caching`` and
``Cache.load_overload`` / ``save_overload`` for functions of spotpde (other functions
keep numba's behaviour).
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import os
import stat
import sys
import tempfile
import threading
import warnings
from pathlib import Path

#: The directory chosen by the last :func:`configure` call (``None`` before, and when no
#: directory can be used).
NUMBA_DIR: Path | None = None
#: Why no directory can be used (the warning's text), or ``None``.
PROBLEM: str | None = None


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


def writable(directory: Path, private: Path | None = None) -> bool:
    """Create ``directory`` (mode 0700 for new parents) and check that a file can be
    written in it; False on any failure.

    Args:
        private: a parent of ``directory`` that must belong to this user and be writable
            by nobody else (the fallback in the shared temporary directory).
    """
    try:
        if private is not None and hasattr(os, "getuid"):
            private.mkdir(mode=0o700, parents=True, exist_ok=True)
            st = os.lstat(private)     # not a link, ours, writable by us alone
            if (st.st_uid != os.getuid() or not stat.S_ISDIR(st.st_mode)
                    or st.st_mode & 0o022):
                return False
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
        The numba cache directory, or ``None`` when no candidate is writable (spotpde's
        kernels then compile without a cache, with one warning: :data:`PROBLEM`).
    """
    global NUMBA_DIR, PROBLEM
    _install_hook()
    NUMBA_DIR, PROBLEM = None, None
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user:
        if not writable(Path(user)):
            PROBLEM = (f"NUMBA_CACHE_DIR={user} cannot be written: spotpde's kernels "
                       "compile without a cache (every run compiles them again)")
            return None
        NUMBA_DIR = Path(user)
        return NUMBA_DIR
    chosen = None
    tried = (user_cache_dir() / "numba", fallback_dir() / "numba")
    for candidate in tried:
        private = fallback_dir() if candidate.parent == fallback_dir() else None
        if writable(candidate, private=private):
            chosen = candidate
            break
    if chosen is None:
        PROBLEM = ("no writable cache directory (tried " + ", ".join(map(str, tried))
                   + "): spotpde's kernels compile without a cache (every run compiles "
                   "them again); set SPOTPDE_CACHE_DIR to a writable directory")
        return None
    os.environ["NUMBA_CACHE_DIR"] = str(chosen)
    numba = sys.modules.get("numba")
    if numba is not None:   # imported before spotpde: its config was read already
        numba.config.CACHE_DIR = str(chosen)
    NUMBA_DIR = chosen
    return chosen


_warned = threading.Lock()
_state = {"warned": False, "writes": True}


def _warn_once(message: str) -> None:
    """One ``RuntimeWarning`` per process about the cache."""
    with _warned:
        if _state["warned"]:
            return
        _state["warned"] = True
    warnings.warn(message, RuntimeWarning, stacklevel=3)


def _ours(func) -> bool:
    return (getattr(func, "__module__", None) or "").partition(".")[0] == "spotpde"


def _failure(what: str, exc: BaseException) -> str:
    where = NUMBA_DIR or os.environ.get("NUMBA_CACHE_DIR") or "numba's cache directory"
    why = (exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)) or \
        type(exc).__name__
    return (f"cannot {what} numba's cache in {where} ({why}): compiling without it")


def _patch_numba() -> None:
    """Make numba's caching of spotpde's kernels unable to fail a run (module docstring)."""
    try:
        from numba.core import caching, dispatcher
    except ImportError:     # pragma: no cover - numba without these modules
        return
    dispatch, cache = dispatcher.Dispatcher, caching.Cache
    if getattr(dispatch.enable_caching, "_spotpde", False):
        return
    enable, load, save = dispatch.enable_caching, cache.load_overload, cache.save_overload

    def enable_caching(self):
        if not _ours(self.py_func):
            return enable(self)
        if NUMBA_DIR is None:            # no usable directory: never the package's
            _warn_once(PROBLEM or "numba's cache is not configured: compiling without it")
            return None
        try:
            return enable(self)
        except (RuntimeError, OSError) as exc:   # "cannot cache function": no locator
            _warn_once(_failure("use", exc))
            return None

    def load_overload(self, sig, target_context):
        if not _ours(self._py_func):
            return load(self, sig, target_context)
        try:
            return load(self, sig, target_context)
        except Exception as exc:  # noqa: BLE001 - unreadable or damaged cache: compile
            _warn_once(_failure("read", exc))
            return None

    def save_overload(self, sig, data):
        if not _ours(self._py_func):
            return save(self, sig, data)
        if not _state["writes"]:
            return None
        try:
            return save(self, sig, data)
        except OSError as exc:           # a full disk, a quota, a read-only directory
            _state["writes"] = False
            _warn_once(_failure("write", exc) + " from here on")
            return None

    enable_caching._spotpde = True
    dispatch.enable_caching = enable_caching
    cache.load_overload = load_overload
    cache.save_overload = save_overload


class _NumbaHook(importlib.abc.MetaPathFinder):
    """Runs :func:`_patch_numba` right after ``import numba`` (without importing numba
    before it is needed)."""

    def find_spec(self, fullname, path=None, target=None):
        if fullname != "numba":
            return None
        _remove_hook()
        spec = importlib.util.find_spec(fullname)
        loader = getattr(spec, "loader", None)
        run = getattr(loader, "exec_module", None)
        if run is None:
            return spec

        def exec_module(module):
            run(module)
            _patch_numba()

        loader.exec_module = exec_module
        return spec


def _install_hook() -> None:
    if "numba" in sys.modules:
        _patch_numba()
    elif not any(isinstance(f, _NumbaHook) for f in sys.meta_path):
        sys.meta_path.insert(0, _NumbaHook())


def _remove_hook() -> None:
    sys.meta_path[:] = [f for f in sys.meta_path if not isinstance(f, _NumbaHook)]
