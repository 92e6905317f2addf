"""FFT backends for :mod:`spotpde.convolution`: planned pyFFTW transforms, scipy.fft fallback.

pyFFTW plans (a real-to-complex forward and a complex-to-real inverse transform sharing
one spectrum buffer) are built once per transform shape and kept in a small LRU cache.
FFTW wisdom is loaded from and saved to ``<cache>/fftw_wisdom`` where ``<cache>`` is
``$SPOTPDE_CACHE_DIR``, else ``$XDG_CACHE_HOME/spotpde``, else ``~/.cache/spotpde``.
The file is written atomically (temporary file + ``os.replace``); any failure to read or
write it is ignored (wisdom only makes planning faster). The planner effort is
``FFTW_ESTIMATE`` (a plan in milliseconds, chosen by FFTW's cost model) unless
``$SPOTPDE_FFTW_PLANNER`` names a measuring one (``FFTW_MEASURE``, ``FFTW_PATIENT``,
``FFTW_EXHAUSTIVE``); planning of one transform is then limited to
``PLANNING_TIMELIMIT`` seconds, and only then is wisdom read and written. Measured plans
are only as good as the machine was quiet while they were timed: a plan measured on a
loaded 2-core machine and kept as wisdom ran a 1080 x 1080 transform pair in 0.34 s,
against 0.02 s for the estimated plan; so the default measures nothing and keeps no
wisdom. Transforms of at least ``THREAD_MIN_SIZE`` points use the cores available to the
process that other tasks are not running on (:func:`threads`; or
``$SPOTPDE_FFT_THREADS``); smaller ones run on one thread, which is faster.
"""

from __future__ import annotations

import os
import struct
import tempfile
import threading
from collections import OrderedDict
from pathlib import Path

import numpy as np
import scipy.fft

from .._cache import user_cache_dir

try:  # pragma: no cover - exercised when pyfftw is installed
    import pyfftw

    HAVE_PYFFTW = True
except ImportError:  # pragma: no cover
    pyfftw = None
    HAVE_PYFFTW = False

BACKENDS = ("pyfftw", "scipy")
_MAGIC = b"SPOTPDE-FFTW-WISDOM-1\n"
_PLANNERS = ("FFTW_ESTIMATE", "FFTW_MEASURE", "FFTW_PATIENT", "FFTW_EXHAUSTIVE")
#: the planner effort without ``$SPOTPDE_FFTW_PLANNER``
DEFAULT_PLANNER = "FFTW_ESTIMATE"


def planner() -> str:
    """The FFTW planner flag: ``$SPOTPDE_FFTW_PLANNER`` if it names one, else the default."""
    flag = os.environ.get("SPOTPDE_FFTW_PLANNER", DEFAULT_PLANNER)
    return flag if flag in _PLANNERS else DEFAULT_PLANNER


def measures() -> bool:
    """True if plans are timed on this machine (and FFTW wisdom is worth keeping)."""
    return planner() != "FFTW_ESTIMATE"
_MAX_PLANS = 4
#: transforms with fewer points run single-threaded (thread start-up costs more than it saves)
THREAD_MIN_SIZE = 1 << 16
#: upper bound on FFTW planning time per transform, seconds
PLANNING_TIMELIMIT = 2.0

_lock = threading.Lock()
_plans: OrderedDict = OrderedDict()
_wisdom_loaded = False


def threads() -> int:
    """Number of threads for the transforms: the cores available to this process, less
    those other runnable tasks occupy right now (never below 1).

    A transform split over a core that another process is using waits for its slowest
    part: on the shared 2-core machine, with another process computing, a 1080 x 1080
    transform pair took 28 ms on two threads against 21 ms on one (and 13 ms on two when
    the machine was idle). So the cores in use are subtracted: the running count of
    ``/proc/loadavg`` (runnable tasks at this instant) less this process's own running
    threads (:func:`_other_runnable`, about 0.1 ms), read only when this process sees the
    whole machine (``os.cpu_count()`` cores in its affinity; in a container restricted to
    some cores the count would be the host's).
    ``$SPOTPDE_FFT_THREADS`` (a positive integer) overrides it, e.g. to avoid
    oversubscription when several worker processes share the cores.
    """
    env = os.environ.get("SPOTPDE_FFT_THREADS", "")
    if env.strip().isdigit() and int(env) > 0:
        return int(env)
    try:
        cores = max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # pragma: no cover - non-Linux
        return max(1, os.cpu_count() or 1)
    if cores > 1 and cores == os.cpu_count():
        cores = max(1, cores - _other_runnable())
    return cores


def _other_runnable() -> int:
    """Runnable tasks of other processes: ``/proc/loadavg``'s running count less this
    process's own running threads (the caller, and FFTW's workers, which keep spinning a
    while after a transform); 0 if it cannot be read."""
    try:
        with open("/proc/loadavg") as fh:
            running = int(fh.read().split()[3].split("/")[0])
    except (OSError, ValueError, IndexError):
        return 0
    own = 0
    try:
        for task in os.listdir("/proc/self/task"):
            try:
                with open(f"/proc/self/task/{task}/stat") as fh:
                    stat = fh.read()
            except OSError:         # the thread ended meanwhile
                continue
            own += stat[stat.rindex(")") + 2] == "R"
    except (OSError, ValueError):
        own = 1
    return max(0, running - max(own, 1))


def cache_dir() -> Path:
    """The spotpde user cache directory (not created here): see :mod:`spotpde._cache`."""
    return user_cache_dir()


def wisdom_path() -> Path:
    return cache_dir() / "fftw_wisdom"


def resolve_backend(backend: str | None) -> str:
    """``None`` -> ``"pyfftw"`` when importable, else ``"scipy"``; validate explicit names."""
    if backend is None:
        return "pyfftw" if HAVE_PYFFTW else "scipy"
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS} or None, got {backend!r}")
    if backend == "pyfftw" and not HAVE_PYFFTW:
        raise ValueError("backend 'pyfftw' requested but pyfftw is not importable; use 'scipy'")
    return backend


def next_fast_shape(target: tuple[int, ...], backend: str) -> tuple[int, ...]:
    """Smallest 5-smooth (2^a 3^b 5^c) length >= target along each axis.

    The same lengths for both backends, so they compute the same sums; FFTW also runs
    fastest on 5-smooth sizes (its 7-, 11- and 13-smooth sizes measured slower here).
    """
    return tuple(int(scipy.fft.next_fast_len(int(t), real=True)) for t in target)


# -- wisdom ---------------------------------------------------------------------------------


def _read_wisdom(path: Path):
    data = path.read_bytes()
    if not data.startswith(_MAGIC):
        return None
    pos = len(_MAGIC)
    parts = []
    for _ in range(3):
        (n,) = struct.unpack_from("<Q", data, pos)
        pos += 8
        parts.append(data[pos:pos + n])
        pos += n
    return tuple(parts)


def load_wisdom() -> bool:
    """Import the wisdom file once per process; True if some wisdom was imported."""
    global _wisdom_loaded
    if _wisdom_loaded or not HAVE_PYFFTW:
        return False
    _wisdom_loaded = True
    try:
        parts = _read_wisdom(wisdom_path())
        if parts is None:
            return False
        return any(pyfftw.import_wisdom(parts))
    except Exception:  # noqa: BLE001 - a missing or corrupt wisdom file is harmless
        return False


def save_wisdom() -> bool:
    """Write the current FFTW wisdom atomically; True on success, False (silently) otherwise."""
    if not HAVE_PYFFTW:
        return False
    tmp = None
    try:
        parts = pyfftw.export_wisdom()
        directory = cache_dir()
        directory.mkdir(parents=True, exist_ok=True)
        blob = _MAGIC + b"".join(struct.pack("<Q", len(p)) + p for p in parts)
        fd, tmp = tempfile.mkstemp(prefix=".fftw_wisdom.", dir=directory)
        with os.fdopen(fd, "wb") as fh:
            fh.write(blob)
        os.replace(tmp, wisdom_path())
        return True
    except Exception:  # noqa: BLE001 - failure to cache wisdom is harmless
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass
        return False


# -- pyFFTW plans -----------------------------------------------------------------------------


class RealPlan:
    """Planned r2c forward and c2r inverse transforms of one shape, sharing buffers.

    ``real_in`` -> forward -> ``spectrum`` -> (multiply in place) -> inverse -> ``real_out``.
    The inverse is unnormalised (FFTW convention): callers fold ``1/prod(shape)`` into the
    kernel spectrum. ``lock`` serialises use of the shared buffers across threads.
    ``filled`` records which field shape was last written into ``real_in`` (the r2c
    transform preserves its input, so the zero padding survives between calls).
    """

    def __init__(self, shape: tuple[int, ...], n_threads: int | None = None):
        self.shape = tuple(shape)
        cshape = self.shape[:-1] + (self.shape[-1] // 2 + 1,)
        axes = tuple(range(len(self.shape)))
        flag = planner()
        n = plan_threads(self.shape) if n_threads is None else int(n_threads)
        self.threads = n
        self.real_in = pyfftw.empty_aligned(self.shape, dtype="float64")
        self.spectrum = pyfftw.empty_aligned(cshape, dtype="complex128")
        self.real_out = pyfftw.empty_aligned(self.shape, dtype="float64")
        self.forward = pyfftw.FFTW(self.real_in, self.spectrum, axes=axes, direction="FFTW_FORWARD",
                                   flags=(flag,), threads=n,
                                   planning_timelimit=PLANNING_TIMELIMIT)
        self.inverse = pyfftw.FFTW(self.spectrum, self.real_out, axes=axes, direction="FFTW_BACKWARD",
                                   flags=(flag, "FFTW_DESTROY_INPUT"), threads=n,
                                   planning_timelimit=PLANNING_TIMELIMIT)
        self.real_in[...] = 0.0
        self.filled: tuple[int, ...] | None = None
        self.lock = threading.Lock()


def plan_threads(shape) -> int:
    """Threads of a transform of ``shape``: :func:`threads`, one below ``THREAD_MIN_SIZE``."""
    return threads() if int(np.prod(shape)) >= THREAD_MIN_SIZE else 1


def get_plan(shape: tuple[int, ...]) -> RealPlan:
    """The cached :class:`RealPlan` for ``shape`` and the threads it gets now
    (:func:`plan_threads`; built, and wisdom saved, on first use)."""
    shape = tuple(int(s) for s in shape)
    n = plan_threads(shape)
    key = (shape, n)
    with _lock:
        plan = _plans.get(key)
        if plan is not None:
            _plans.move_to_end(key)
            return plan
        if measures():
            load_wisdom()
        plan = RealPlan(shape, n)
        _plans[key] = plan
        while len(_plans) > _MAX_PLANS:
            _plans.popitem(last=False)
    if measures():
        save_wisdom()
    return plan


def clear_plans() -> None:
    """Drop every cached plan (frees their buffers)."""
    with _lock:
        _plans.clear()
