"""Checks on output paths, made before any computing, and signals that stop a run.

Every command that writes a file (``run``, ``plot``, ``sweep``, ``compare``) and
``spotpde.run(case, path=...)`` check their output paths here first, so that a run never
computes for minutes and then fails to write, and never destroys data:

* the directory exists, and a file can be created in it under the name of the hidden
  temporary sibling that the atomic write uses (``.NAME.XXXXXXXX.tmp``): this catches a
  read-only directory, a full inode table, and a name too long for that sibling;
* an existing target is a regular file (a directory, device node, FIFO or socket is
  never replaced);
* the target is not one of the command's inputs (``run c.toml -o c.toml``) nor another
  of its outputs (``run ... -o r.png --plot``), compared by
  :func:`os.path.samefile` when both exist and by :func:`os.path.realpath` otherwise;
* a figure has an extension matplotlib can write (:data:`FIGURE_FORMATS`).

:func:`output_problem` returns the problem as text (no key); callers prefix the key
(``output.path``, ``--plot``) or the Python argument (``path``).

:func:`handle_termination` makes SIGTERM and SIGHUP behave like Ctrl-C: they raise
:class:`Terminated` (a :class:`KeyboardInterrupt`), so the same clean-up runs (the
temporary file of an atomic write is removed) and the command exits with status
128 + the signal number; :func:`check_signals` raises a stop signal again whose exception
C code dropped (a handler that ran inside a ctypes callback). :class:`held_signals` holds these signals back for a block that
must not be cut halfway (a netCDF write inside xarray's file lock, the clean-up of a
temporary file) and acts on them when the block is done.
"""

from __future__ import annotations

import errno
import os
import signal
import stat
import sys
import tempfile
import threading
from collections.abc import Iterable
from pathlib import Path

from .._figures import FIGURE_FORMATS  # noqa: F401 - the figure writer's extensions


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP received; ``signum`` is the signal number."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = int(signum)


#: Stop signals whose handler has run. A handler runs between two bytecodes wherever the
#: main thread is, also inside a Python function that C code calls back through ctypes
#: (numba's cache notifier, called by llvmlite while a kernel compiles). ctypes prints
#: and drops an exception raised there, so the run would go on as if nothing happened;
#: :func:`check_signals` raises it again at the command's next checkpoint.
_PENDING: list[int] = []


def _stop(signum, frame):  # noqa: ARG001 - signal handler signature
    _PENDING.append(int(signum))
    raise _exception(signum)


def _exception(signum) -> KeyboardInterrupt:
    return KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signum)


def _quiet_unraisable(previous):
    """``sys.unraisablehook`` that stays silent about a stop signal's exception dropped
    by C code (it is recorded and raised again) and passes everything else on."""
    def hook(unraisable):
        if isinstance(unraisable.exc_value, KeyboardInterrupt) and _PENDING:
            return
        previous(unraisable)

    hook.__wrapped__ = previous
    return hook


def check_signals() -> None:
    """Raise again the first stop signal whose exception was dropped on its way (see
    :data:`_PENDING`): ``KeyboardInterrupt`` for SIGINT, :class:`Terminated` otherwise.
    The command line calls it at every progress report and once the result is written."""
    if _PENDING:
        signum = _PENDING[0]
        _PENDING.clear()
        raise _exception(signum)


def handle_termination() -> None:
    """Make SIGTERM and SIGHUP raise :class:`Terminated`, and SIGINT ``KeyboardInterrupt``
    as before, each recorded for :func:`check_signals` (main thread only; signals another
    program ignores stay ignored, and a SIGINT handler other than Python's default is
    kept). Forgets signals recorded by an earlier command of the same process. The
    exception C code drops is not printed (:func:`_quiet_unraisable`): the signal is acted
    upon at the next checkpoint, with the command's one line."""
    _PENDING.clear()
    if getattr(sys.unraisablehook, "__wrapped__", None) is None:
        sys.unraisablehook = _quiet_unraisable(sys.unraisablehook)
    for name in ("SIGINT", "SIGTERM", "SIGHUP"):
        sig = getattr(signal, name, None)
        if sig is None:
            continue
        try:
            current = signal.getsignal(sig)
            if current == signal.SIG_IGN:   # e.g. under nohup
                continue
            if sig == signal.SIGINT and current is not signal.default_int_handler:
                continue
            signal.signal(sig, _stop)
        except ValueError:   # not the main thread
            return


#: The signals that stop a command (SIGINT, SIGTERM, SIGHUP where they exist).
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP")
                     if hasattr(signal, name))


class held_signals:
    """Hold :data:`STOP_SIGNALS` back for a block that must not be interrupted halfway.

    Inside the block a signal is only recorded in ``received``. On leaving it the previous
    handlers come back and the first signal received is raised again
    (:func:`signal.raise_signal`), so that whatever handled it before acts on it now:
    ``KeyboardInterrupt`` for SIGINT, :class:`Terminated` under :func:`handle_termination`,
    the default action (the end of the process) where no handler is set. Blocks nest (an
    inner one hands its signal to the outer one). Ignored signals stay ignored; outside the
    main thread, which receives no signals in Python, it does nothing.

    Why: Python runs a signal's handler between any two bytecodes, also inside a library
    that holds a lock. A ``KeyboardInterrupt`` raised while xarray acquires its netCDF lock
    leaves the lock taken, and the next netCDF call (closing the file) waits for it forever;
    one raised during the removal of a temporary file leaves the file behind.

    Args:
        drop: forget the signals received instead of raising them again, for a clean-up
            that runs because the process is stopping anyway (a second Ctrl-C must not cut
            the clean-up of the first). A signal received while the block raises a
            ``KeyboardInterrupt`` of its own is dropped too.
    """

    def __init__(self, drop: bool = False):
        self.drop = drop
        self.received: list[int] = []
        self._previous: dict = {}

    def __enter__(self) -> "held_signals":
        self.received = []
        self._previous = {}
        if threading.current_thread() is not threading.main_thread():
            return self
        try:
            for sig in STOP_SIGNALS:
                if signal.getsignal(sig) in (signal.SIG_IGN, None):
                    continue
                self._previous[sig] = signal.signal(sig, self._record)
        except BaseException:   # a signal while swapping: put everything back first
            self._restore()
            raise
        return self

    def _record(self, signum, frame):  # noqa: ARG002 - signal handler signature
        self.received.append(signum)

    def _restore(self) -> None:
        pending, self._previous = list(self._previous.items()), {}
        try:
            while pending:
                signal.signal(*pending[0])
                del pending[0]
        finally:            # a signal whose handler came back first cut the loop: finish it
            for sig, handler in pending:
                signal.signal(sig, handler)

    def __exit__(self, kind, value, tb) -> bool:
        self._restore()
        interrupted = kind is not None and issubclass(kind, KeyboardInterrupt)
        if self.received and not self.drop and not interrupted:
            signal.raise_signal(self.received[0])
        return False


def file_identity(path: str | os.PathLike) -> tuple[int, int] | None:
    """``(device, inode)`` of ``path``, or ``None`` when there is no such file: an atomic
    write (a new file renamed onto ``path``) changes it."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino


def resolve(path: str | os.PathLike) -> Path:
    """``path`` made absolute (``~`` expanded), without resolving symbolic links."""
    return Path(os.path.abspath(os.path.expanduser(os.fspath(path))))


def same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """True when ``a`` and ``b`` name the same file (hard links and symbolic links
    included; by real path when one of them does not exist yet)."""
    a, b = resolve(a), resolve(b)
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def _full(directory: Path) -> bool:
    """True when the file system holding ``directory`` has no block or no inode left
    for this user (:func:`os.statvfs`; False when that cannot be told)."""
    try:
        st = os.statvfs(directory)
    except (OSError, AttributeError):
        return False
    return st.f_blocks > 0 and st.f_bavail == 0 or st.f_files > 0 and st.f_favail == 0


def _reason(exc: OSError, directory: Path) -> str:
    """Why a file could not be created in ``directory``. Some file systems refuse a new
    file on a full disk with "Permission denied": when the directory is writable and
    the file system full, the reason given is the full disk."""
    why = exc.strerror or str(exc)
    if exc.errno in (errno.EACCES, errno.EPERM) and _full(directory):
        if os.access(directory, os.W_OK | os.X_OK):
            return f"{os.strerror(errno.ENOSPC)}: the file system is full"
        return f"{why}; the file system is full too"
    return why


def output_problem(path: str | os.PathLike, *, inputs: Iterable = (), others: Iterable = (),
                   formats: Iterable[str] | None = None) -> str | None:
    """What stops ``path`` from being written as an output, or ``None``.

    Args:
        path: the output file.
        inputs: the command's input files (a path equal to one of them is refused).
        others: ``(what, path)`` pairs of the command's other outputs.
        formats: allowed extensions without the dot (``None``: any).

    Returns:
        A message such as ``"the directory /x does not exist, got 'r.nc'"``, or ``None``.
    """
    shown = os.fspath(path)
    target = resolve(path)
    for source in inputs:
        if source is not None and same_file(target, source):
            return (f"is the input file {os.fspath(source)} of this command; writing there "
                    f"would destroy it, got {shown!r}")
    for what, other in others:
        if other is not None and same_file(target, other):
            return f"is also the {what} of this command; give them different names, got {shown!r}"
    if formats is not None:
        formats = tuple(formats)
        ext = target.suffix.lower().lstrip(".")
        if ext not in formats:
            return (f"unsupported format {target.suffix or '(no extension)'!r}; use one of "
                    + ", ".join("." + f for f in formats) + f", got {shown!r}")
    try:
        st = os.stat(target)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        return f"cannot use {target}: {exc.strerror or exc}, got {shown!r}"
    if st is not None:
        if stat.S_ISDIR(st.st_mode):
            return f"is a directory; give a file name, got {shown!r}"
        if not stat.S_ISREG(st.st_mode):
            return (f"exists and is not a regular file (a device, FIFO or socket); refusing "
                    f"to replace it, got {shown!r}")
    parent = target.parent
    if not parent.is_dir():
        return f"the directory {parent} does not exist, got {shown!r}"
    try:
        fd, probe = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=parent)
    except OSError as exc:
        return f"cannot write in {parent} ({_reason(exc, parent)}), got {shown!r}"
    os.close(fd)
    try:
        os.unlink(probe)
    except OSError:
        pass
    return None
