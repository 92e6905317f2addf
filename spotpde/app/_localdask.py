"""The embedded Dask cluster of a sweep, and how an interrupted sweep stops it quietly.

A terminal's Ctrl-C sends SIGINT to its whole foreground process group: the ``spotpde``
process and every Dask worker process it started. A worker that takes it prints a
KeyboardInterrupt traceback from inside distributed, and closing a cluster whose workers
are dying prints more (nanny warnings, restarts, ``Client.__del__`` at interpreter exit).
Which of these appear depends on where the signal lands, so this module removes each
cause instead of hiding a few lines (docs/sweeps.md):

* **The workers never see SIGINT.** :meth:`LocalDask.start` builds the ``LocalCluster``
  in a helper thread created with SIGINT blocked (``pthread_sigmask``). Every thread the
  cluster then starts inherits that mask, and so does every worker process spawned from
  those threads (a signal mask survives ``fork`` and ``exec``; Python never unblocks it).
  The main thread keeps SIGINT and only waits for the helper, so a Ctrl-C during the
  start-up (seconds on a loaded machine) is acted upon at once, not lost or deferred.
* **The parent alone decides.** On KeyboardInterrupt (or
  :class:`~spotpde.app._outputs.Terminated`, for SIGTERM and SIGHUP) the sweep calls
  :meth:`LocalDask.abort`, which ignores further signals, silences Dask's loggers and
  file descriptor 2, tells the nannies not to restart their workers, kills (SIGKILL)
  every process the cluster started and waits until they are dead, removes the hidden
  temporary files of member writes they left (a member file is written to a temporary
  sibling and renamed, so it is complete or absent), closes the client and cluster with
  short timeouts, and then restores standard error and the signal handlers.
* The command line then prints its one line, runs multiprocessing's exit finalisers
  (:func:`before_exit`: they unlink the cluster's named semaphores, which the resource
  tracker would otherwise report as leaked) and leaves with ``os._exit``, so no
  finaliser of distributed (``Client.__del__``, the cluster's atexit hooks) runs.
"""

from __future__ import annotations

import logging
import os
import signal
import sys
import threading
import time
from multiprocessing import resource_tracker, util
from pathlib import Path

import psutil

from ._outputs import Terminated

#: Loggers whose messages about a cluster being torn down say nothing a user needs.
QUIET_LOGGERS = ("distributed", "tornado", "asyncio")
#: Seconds allowed for killed workers to die, and for the client and cluster to close.
ABORT_TIMEOUT = 5.0
#: The signals that stop a command (docs/interface.md: exit status 128 + n).
STOP_SIGNALS = tuple(getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP")
                     if hasattr(signal, name))
#: Temporary files of member writes (``spotpde.app.io._temporary``).
MEMBER_TEMPORARIES = ".member-*.tmp"


def _children() -> dict[int, float]:
    """This process's descendants: pid -> creation time (a pid may be reused)."""
    out = {}
    for child in psutil.Process().children(recursive=True):
        try:
            out[child.pid] = child.create_time()
        except psutil.Error:
            pass
    return out


def _resource_tracker_pid() -> int | None:
    """multiprocessing's resource tracker: shared with other users, never killed (it
    removes the cluster's named semaphores when this process ends)."""
    try:
        return resource_tracker._resource_tracker._pid
    except (ImportError, AttributeError):
        return None


def _start_resource_tracker() -> None:
    """Start multiprocessing's resource tracker here, in the main thread, with its
    standard error on /dev/null.

    It must not be started by a thread of the cluster: it unblocks SIGINT in the thread
    that starts it, so the workers spawned from that thread would take a Ctrl-C again.
    Its only messages are the warnings it prints once this process is gone, about named
    semaphores that it then removes; a sweep that leaves with ``os._exit`` while a
    thread of distributed is closing a queue would otherwise end with two such lines.
    """
    tracker = resource_tracker._resource_tracker
    if getattr(tracker, "_fd", None) is not None:   # already running: keep it
        resource_tracker.ensure_running()
        return
    with _silent_stderr():
        resource_tracker.ensure_running()


def kill_and_wait(pids, timeout: float = ABORT_TIMEOUT) -> None:
    """SIGKILL ``pids`` and wait until each is dead or a zombie (not reaped here: the
    thread of multiprocessing that watches the process reaps it)."""
    procs = []
    for pid in pids:
        try:
            proc = psutil.Process(pid)
            proc.kill()
            procs.append(proc)
        except psutil.Error:
            pass
    deadline = time.monotonic() + timeout
    while procs and time.monotonic() < deadline:
        alive = []
        for proc in procs:
            try:
                if proc.status() != psutil.STATUS_ZOMBIE:
                    alive.append(proc)
            except psutil.Error:
                pass
        procs = alive
        if procs:
            time.sleep(0.02)


class LocalDask:
    """An embedded ``LocalCluster`` (one single-threaded worker process per member slot)
    whose workers ignore a terminal's Ctrl-C, stopped by :meth:`close` or :meth:`abort`.

    Args:
        n_workers: worker processes.
    """

    def __init__(self, n_workers: int):
        self.n_workers = int(n_workers)
        self.cluster = None
        self.client = None
        self._lock = threading.Lock()
        self._aborted = False
        self._started = threading.Event()
        self._error: BaseException | None = None
        self._before: dict[int, float] = {}

    def start(self):
        """Start the cluster; returns its ``distributed.Client``.

        The main thread waits in short steps, so SIGINT, SIGTERM and SIGHUP interrupt the
        start-up at once (then call :meth:`abort`).
        """
        import distributed  # noqa: F401 - imported here, in the main thread

        _start_resource_tracker()
        self._before = _children()
        blocked = hasattr(signal, "pthread_sigmask") and hasattr(signal, "SIGINT")
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT}) if blocked else None
        try:
            helper = threading.Thread(target=self._build, name="spotpde: Dask start-up",
                                      daemon=True)
            helper.start()
        finally:
            if blocked:
                signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        while not self._started.wait(0.05):
            pass
        if self._error is not None:
            raise self._error
        return self.client

    def _build(self) -> None:
        """The helper thread: build the cluster and its client (SIGINT blocked here and
        in everything started from here)."""
        from distributed import Client, LocalCluster

        cluster = client = None
        try:
            cluster = LocalCluster(n_workers=self.n_workers, threads_per_worker=1,
                                   processes=True, dashboard_address=None,
                                   silence_logs=logging.ERROR, preload=[__name__])
            client = Client(cluster)
        except BaseException as exc:  # noqa: BLE001 - handed to the main thread
            self._error = exc
        with self._lock:
            self.cluster, self.client = cluster, client
            aborted = self._aborted
        self._started.set()
        if aborted:           # interrupted during the start-up: nobody else closes it
            _close(client, cluster)

    def close(self) -> None:
        """Close the client and the cluster (a sweep that ended normally)."""
        _close(self.client, self.cluster)

    def abort(self, directory: Path | None = None) -> None:
        """Stop everything the cluster started, at once and without a word.

        Args:
            directory: where member files are written; the temporary files of
                interrupted member writes are removed from it.
        """
        handlers = _ignore_signals()
        levels = {name: logging.getLogger(name).level for name in QUIET_LOGGERS}
        for name in QUIET_LOGGERS:
            logging.getLogger(name).setLevel(logging.CRITICAL + 1)
        try:
            with _silent_stderr():
                self._stop(directory)
        finally:
            for name, level in levels.items():
                logging.getLogger(name).setLevel(level)
            _restore_signals(handlers)

    def _stop(self, directory: Path | None) -> None:
        """:meth:`abort` once signals, loggers and standard error are quiet."""
        with self._lock:
            self._aborted = True
            cluster, client = self.cluster, self.client
        if cluster is not None:
            try:
                for nanny in list(cluster.workers.values()):
                    nanny.close_gracefully(reason="spotpde: interrupted")   # no restart
            except Exception:  # noqa: BLE001 - the cluster may be half built
                pass
        exempt = {_resource_tracker_pid()}
        kill_and_wait([pid for pid, t in _children().items()
                       if pid not in exempt and self._before.get(pid) != t])
        if directory is not None:
            for tmp in Path(directory).glob(MEMBER_TEMPORARIES):
                try:
                    tmp.unlink()
                except OSError:
                    pass
        if cluster is not None:
            closer = threading.Thread(target=_close, args=(client, cluster),
                                      name="spotpde: Dask close", daemon=True)
            closer.start()
            closer.join(ABORT_TIMEOUT)


def before_exit() -> None:
    """Run multiprocessing's exit finalisers, for a process about to leave with
    ``os._exit``: they unlink the cluster's named semaphores, which the resource tracker
    would otherwise report as leaked (a warning on standard error) once this process is
    gone. Not for a process that goes on: they also stop every ``multiprocessing.Pool``."""
    try:
        util._run_finalizers(0)
    except Exception:  # noqa: BLE001 - best effort on the way out
        pass


def dask_setup(worker) -> None:  # noqa: ARG001 - distributed's preload hook
    """In each worker process, once its event loop runs: ignore SIGINT for good (the
    blocked mask already kept it out during the start-up)."""
    if threading.current_thread() is threading.main_thread() and hasattr(signal, "SIGINT"):
        signal.signal(signal.SIGINT, signal.SIG_IGN)


class deferred_signals:
    """Hold STOP_SIGNALS back for the block, then act on the first one received.

    Inside the block a signal is only recorded; on leaving it, the previous handlers come
    back and a recorded SIGINT raises KeyboardInterrupt, SIGTERM or SIGHUP
    :class:`~spotpde.app._outputs.Terminated`. For the seconds in which a command imports
    its libraries: a KeyboardInterrupt raised inside an import can be swallowed by a bare
    ``except``, turned into an ImportError by a C extension (``numba._devicearray failed
    to import``), or make Python kill itself with SIGINT at exit instead of returning 130.
    Signals that are ignored (``nohup``, a background job) stay ignored. A no-op outside
    the main thread.
    """

    def __enter__(self):
        self.received: list[int] = []
        self.previous = {}
        if threading.current_thread() is not threading.main_thread():
            return self
        for sig in STOP_SIGNALS:
            if signal.getsignal(sig) in (signal.SIG_IGN, None):
                continue
            try:
                self.previous[sig] = signal.signal(sig, self._record)
            except (ValueError, OSError):
                pass
        return self

    def _record(self, signum, frame):  # noqa: ARG002 - signal handler signature
        self.received.append(signum)

    def __exit__(self, *exc):
        _restore_signals(self.previous)
        if self.received:
            first = self.received[0]
            raise KeyboardInterrupt() if first == signal.SIGINT else Terminated(first)
        return False


def import_libraries(dask: bool = True) -> None:
    """Import what a sweep will use (inside :class:`deferred_signals`): distributed and
    psutil for the cluster, netCDF4 and xarray's backends (found through entry points on
    first use) for the member files."""
    import netCDF4  # noqa: F401
    import xarray

    xarray.backends.list_engines()
    if dask:
        import distributed  # noqa: F401


def _close(client, cluster, timeout: float = ABORT_TIMEOUT) -> None:
    """Close ``client`` then ``cluster`` (either may be None), each within ``timeout``."""
    for thing in (client, cluster):
        if thing is None:
            continue
        try:
            thing.close(timeout=timeout)
        except Exception:  # noqa: BLE001 - closing what is already broken
            pass


def _ignore_signals() -> dict:
    """Ignore STOP_SIGNALS (a second Ctrl-C must not interrupt the clean-up); returns the
    previous handlers. A no-op outside the main thread."""
    handlers = {}
    if threading.current_thread() is not threading.main_thread():
        return handlers
    for sig in STOP_SIGNALS:
        try:
            handlers[sig] = signal.signal(sig, signal.SIG_IGN)
        except (ValueError, OSError):
            pass
    return handlers


def _restore_signals(handlers: dict) -> None:
    for sig, handler in handlers.items():
        if handler is not None:
            signal.signal(sig, handler)


class _silent_stderr:
    """File descriptor 2 onto /dev/null for the block (Python's ``sys.stderr``, C
    libraries and processes started meanwhile all write there)."""

    def __enter__(self):
        try:
            sys.stderr.flush()
        except (OSError, ValueError, AttributeError):
            pass
        self.saved = os.dup(2)
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 2)
        os.close(null)
        return self

    def __exit__(self, *exc):
        try:
            sys.stderr.flush()
        except (OSError, ValueError, AttributeError):
            pass
        os.dup2(self.saved, 2)
        os.close(self.saved)
        return False
