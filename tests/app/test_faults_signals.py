"""Signals at the worst moments, two writing threads, and caches that cannot be used.

Each fault is reproduced in a ``python`` subprocess whose driver patches one function so
that the signal (or the failure) comes at the exact moment: inside xarray's netCDF lock
while the last write of a run goes on, right after the rename that completes a result,
during the clean-up of a first Ctrl-C; two threads meet at barriers before writing; numba
finds no usable cache directory or a full one. No sleeps: a hang is caught by the
subprocess timeout, a crash by the exit status.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from spotpde.app import io as sio
from spotpde.app._outputs import held_signals

from conftest import FIELDS

ROOT = Path(__file__).resolve().parents[2]

#: the same with a short tracer: frames streamed by a FrameWriter, finished by finish()
TRACER = FIELDS + """
[tracer]
start = { x = 0.0, z = 6.0, width = 1.0 }
limiter = "upwind"
t_end = 1.0
frames = 3
"""

#: runs ``spotpde ARGS`` as the command line does, after the test's hooks
DRIVER = """
import os, signal, sys
{hooks}
sys.argv = ["spotpde", *sys.argv[1:]]
from spotpde.cli import main
sys.exit(main())
"""


def driven(hooks: str, *args, cwd, env=None, timeout=240):
    """Run ``spotpde ARGS`` in a new process after ``hooks`` (Python code); returns the
    CompletedProcess. A hang fails the test through ``timeout``."""
    full = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg",
                SPOTPDE_CACHE_DIR=str(cwd / "cache"))
    full.update(env or {})
    return subprocess.run([sys.executable, "-c", DRIVER.format(hooks=hooks), *map(str, args)],
                          cwd=cwd, env={k: v for k, v in full.items() if v is not None},
                          capture_output=True, text=True, timeout=timeout)


def leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.endswith(".tmp"))


def one_line(proc) -> str:
    assert "Traceback" not in proc.stderr, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    return lines[0]


# -- held_signals ---------------------------------------------------------------------------

class Stop(Exception):
    pass


def _stop(signum, frame):
    raise Stop(signum)


def test_held_signals_act_after_the_block_nest_and_drop():
    previous = signal.signal(signal.SIGTERM, _stop)
    done = []
    try:
        with pytest.raises(Stop):
            with held_signals() as outer:
                with held_signals():
                    signal.raise_signal(signal.SIGTERM)
                    done.append("inner")            # not cut by the signal
                assert outer.received == [signal.SIGTERM]   # handed to the outer block
                done.append("outer")
        assert done == ["inner", "outer"]
        with held_signals(drop=True) as dropped:    # a clean-up while stopping anyway
            signal.raise_signal(signal.SIGTERM)
        assert dropped.received == [signal.SIGTERM]
        assert signal.getsignal(signal.SIGTERM) is _stop
    finally:
        signal.signal(signal.SIGTERM, previous)


# -- issue 30 item 4: a signal in the last write of a run -------------------------------------

#: SIGTERM while xarray acquires its netCDF lock to create a variable of the result (the
#: lock's first part taken, the rest not): the KeyboardInterrupt used to leave the lock
#: taken, and closing the file then waited for it forever.
IN_THE_LOCK = """
from xarray.backends import locks, netCDF4_
_prepare, _acquire = netCDF4_.NetCDF4DataStore.prepare_variable, locks.acquire
state = {"armed": False, "fired": False}
def prepare_variable(self, *args, **kwargs):
    state["armed"] = not state["fired"]
    return _prepare(self, *args, **kwargs)
def acquire(lock, blocking=True):
    if state["armed"] and (locks.HDF5_LOCK.locked() or locks.NETCDFC_LOCK.locked()):
        state["armed"], state["fired"] = False, True
        print("signal inside the lock", flush=True)
        signal.raise_signal(signal.SIGTERM)
    return _acquire(lock, blocking)
netCDF4_.NetCDF4DataStore.prepare_variable = prepare_variable
locks.acquire = acquire
"""


@pytest.mark.parametrize("case", [TRACER, FIELDS], ids=["FrameWriter.finish", "write_netcdf"])
def test_signal_inside_xarrays_lock_neither_hangs_nor_leaves_a_file(tmp_path, case):
    (tmp_path / "c.toml").write_text(case)
    (tmp_path / "r.nc").write_bytes(b"the user's old result")
    proc = driven(IN_THE_LOCK, "run", "c.toml", "-q", cwd=tmp_path)
    assert "signal inside the lock" in proc.stdout        # the hook fired
    assert proc.returncode == 128 + signal.SIGTERM, proc.stderr
    assert one_line(proc) == "spotpde: terminated by signal 15, no result written"
    assert leftovers(tmp_path) == []
    assert (tmp_path / "r.nc").read_bytes() == b"the user's old result"


#: SIGTERM right after the rename that completes the result, and while the run reopens
#: the file it wrote (the result is complete either way)
AFTER_RENAME = """
from spotpde.app import io
_publish = io._publish
def publish(tmp, path):
    _publish(tmp, path)
    print("signal after the rename", flush=True)
    signal.raise_signal(signal.SIGTERM)
io._publish = publish
"""
REOPENING = """
import xarray
_open = xarray.open_dataset
def open_dataset(*args, **kwargs):
    print("signal while reopening", flush=True)
    signal.raise_signal(signal.SIGTERM)
    return _open(*args, **kwargs)
xarray.open_dataset = open_dataset
"""


@pytest.mark.parametrize("case, hooks", [(TRACER, AFTER_RENAME), (FIELDS, AFTER_RENAME),
                                         (TRACER, REOPENING)],
                         ids=["finish-rename", "write_netcdf-rename", "reopen"])
def test_signal_after_the_rename_says_the_result_is_complete(tmp_path, case, hooks):
    (tmp_path / "c.toml").write_text(case)
    proc = driven(hooks, "run", "c.toml", "-q", cwd=tmp_path)
    assert "signal " in proc.stdout
    assert proc.returncode == 128 + signal.SIGTERM, proc.stderr
    assert one_line(proc) == (f"spotpde: terminated by signal 15; {tmp_path / 'r.nc'} "
                              "is complete")
    ds = sio.read_netcdf(tmp_path / "r.nc")
    assert ("P" in ds) == (case == TRACER)
    assert leftovers(tmp_path) == []


# -- issue 30 item 5: a second Ctrl-C during the clean-up of the first ------------------------

#: the first SIGINT once the tracer has written frame 1
FIRST_CTRL_C = """
from spotpde.app import io
_frame = io.FrameWriter.__call__
def frame(self, index, time, P):
    _frame(self, index, time, P)
    if index == 1:
        signal.raise_signal(signal.SIGINT)
io.FrameWriter.__call__ = frame
"""
#: the second one as the temporary file is about to be removed, or as the clean-up starts
SECOND_WHILE_REMOVING = FIRST_CTRL_C + """
_unlink = io._unlink
def unlink(path):
    if not os.environ.get("SECOND"):
        os.environ["SECOND"] = "sent"
        print("second signal", flush=True)
        signal.raise_signal(signal.SIGINT)
    _unlink(path)
io._unlink = unlink
"""
SECOND_AS_CLEAN_UP_STARTS = FIRST_CTRL_C + """
_exit = io.FrameWriter.__exit__
def exit_(self, kind, value, tb):
    print("second signal", flush=True)
    signal.raise_signal(signal.SIGINT)
    return _exit(self, kind, value, tb)
io.FrameWriter.__exit__ = exit_
"""


@pytest.mark.parametrize("hooks", [SECOND_WHILE_REMOVING, SECOND_AS_CLEAN_UP_STARTS],
                         ids=["removing-the-file", "clean-up-starts"])
def test_second_ctrl_c_during_the_clean_up_leaves_no_temporary_file(tmp_path, hooks):
    (tmp_path / "c.toml").write_text(TRACER)
    proc = driven(hooks, "run", "c.toml", "-q", cwd=tmp_path)
    assert "second signal" in proc.stdout
    assert proc.returncode == 130, proc.stderr
    assert one_line(proc) == "spotpde: interrupted, no result written"
    assert leftovers(tmp_path) == [] and not (tmp_path / "r.nc").exists()


# -- issue 30 item 6: spotpde.run(case, path=...) in two threads --------------------------------

THREADS = """
import os, sys, threading
import spotpde
from spotpde.app import io
case = {"domain": {"x": [-8.0, 8.0], "z": [0.0, 16.0], "spacing": 0.25},
        "orifice": {"width": 2.0},
        "tracer": {"start": {"x": 0.0, "z": 12.0, "width": 1.0}, "limiter": "upwind",
                   "t_end": 5.0, "frames": 24}}
meet = threading.Barrier(2, timeout=200)
_frame, _finish = io.FrameWriter.__call__, io.FrameWriter.finish
def frame(self, index, time, P):
    if index == 0:               # both write frame 0 many times over, at the same time
        meet.wait()
        for _ in range(100):
            _frame(self, index, time, P)
    return _frame(self, index, time, P)
def finish(self, ds):
    meet.wait()                  # and finish (xarray's writer) at the same time
    return _finish(self, ds)
io.FrameWriter.__call__, io.FrameWriter.finish = frame, finish
errors = []
def run(i):
    try:
        ds = spotpde.run(spotpde.load_case(case), path=f"r{i}.nc")
        meet.wait()              # and read their results back at the same time
        ds.load()
        ds.close()
    except BaseException as exc:
        errors.append(repr(exc))
        meet.abort()
threads = [threading.Thread(target=run, args=(i,)) for i in range(2)]
for t in threads:
    t.start()
for t in threads:
    t.join()
print(errors)
sys.exit(1 if errors else 0)
"""


def test_two_threads_write_two_complete_results(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT), SPOTPDE_CACHE_DIR=str(tmp_path / "cache"))
    proc = subprocess.run([sys.executable, "-X", "faulthandler", "-c", THREADS],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=400)
    assert proc.returncode == 0, proc.stderr[-3000:]      # was SIGSEGV / SIGBUS
    first, second = (sio.read_netcdf(tmp_path / f"r{i}.nc") for i in range(2))
    assert first["P"].shape[0] == 24 and np.isfinite(first["P"].values).all()
    np.testing.assert_array_equal(first["P"].values, second["P"].values)   # same case
    np.testing.assert_array_equal(first["rho_s"].values, second["rho_s"].values)
    assert leftovers(tmp_path) == []


# -- issue 30 items 13 and 17: numba's cache cannot be used ---------------------------------

def _package_cache_files() -> list[Path]:
    return sorted(ROOT.joinpath("spotpde").rglob("*.nb[ic]"))


@pytest.mark.parametrize("blocker", ["a file", "another user's directory"])
def test_no_writable_cache_directory_warns_once_and_runs(tmp_path, blocker):
    """No HOME to write in, and the temporary fallback taken: compile without a cache
    (numba raised "cannot cache function", or wrote into the package's __pycache__)."""
    (tmp_path / "c.toml").write_text(FIELDS)
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    fallback = tmp / f"spotpde-{os.getuid()}"
    if blocker == "a file":
        fallback.write_text("")
    else:
        if os.geteuid() != 0:
            pytest.skip("only root can give a directory to another user")
        fallback.mkdir()
        os.chown(fallback, 65534, 65534)
        fallback.chmod(0o777)                 # writable, but not ours: never used
    (tmp_path / "home").write_text("")        # HOME is a file: ~/.cache cannot be made
    before = _package_cache_files()
    env = {"HOME": str(tmp_path / "home"), "TMPDIR": str(tmp), "NUMBA_CACHE_DIR": None,
           "SPOTPDE_CACHE_DIR": None, "XDG_CACHE_HOME": None}
    proc = driven("", "run", "c.toml", "-q", cwd=tmp_path, env=env)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    warning, wrote = proc.stderr.strip().splitlines()
    assert warning.startswith("spotpde: warning: no writable cache directory")
    assert str(fallback / "numba") in warning and "without a cache" in warning
    assert wrote.startswith("spotpde: wrote")
    assert sio.read_netcdf(tmp_path / "r.nc")["rho_s"].shape == (16, 16)
    assert _package_cache_files() == before   # nothing cached inside the package
    assert not (fallback / "numba").exists()  # nor in another user's directory


FULL_CACHE = """
import errno
import spotpde
from numba.core import caching
def full(self, filepath):
    raise OSError(errno.ENOSPC, "No space left on device", filepath)
caching.IndexDataCacheFile._open_for_write = full
"""


def test_full_cache_directory_warns_once_naming_it_and_runs(tmp_path):
    """Every write into numba's cache fails with ENOSPC: the run goes on (it failed with
    "No space left on device" naming no cache)."""
    (tmp_path / "c.toml").write_text(FIELDS)
    cache = tmp_path / "numba-cache"
    proc = driven(FULL_CACHE, "run", "c.toml", "-q", cwd=tmp_path,
                  env={"NUMBA_CACHE_DIR": str(cache)})
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    warning, wrote = proc.stderr.strip().splitlines()    # one warning for all kernels
    assert warning == (f"spotpde: warning: cannot write numba's cache in {cache} (No space "
                       "left on device): compiling without it from here on")
    assert wrote.startswith("spotpde: wrote")
    assert sio.read_netcdf(tmp_path / "r.nc")["rho_s"].shape == (16, 16)
    assert not list(cache.rglob("*.nbi"))


# -- a signal whose exception C code dropped ------------------------------------------------

#: hooks: SIGTERM arrives while the spot density is solved, inside a Python function that
#: C code calls through ctypes, as numba's cache notifier is called by llvmlite while a
#: kernel compiles: ctypes drops the handler's exception (the fault CI met once)
SWALLOWED = """
import ctypes
import spotpde.density.spot_density as sd
_solve = sd.solve
def solve(*args, **kwargs):
    ctypes.CFUNCTYPE(None)(lambda: signal.raise_signal(signal.SIGTERM))()
    return _solve(*args, **kwargs)
sd.solve = solve
"""


def test_a_signal_dropped_inside_a_c_callback_still_stops_the_run(tmp_path):
    """The next progress report acts on it: exit 143, one line, no file."""
    (tmp_path / "c.toml").write_text(FIELDS)
    proc = driven(SWALLOWED, "run", "c.toml", "-o", "r.nc", cwd=tmp_path)
    assert proc.returncode == 128 + signal.SIGTERM, proc.stderr
    line = [ln for ln in proc.stderr.splitlines() if not ln.startswith("spotpde: spot")]
    assert "Traceback" not in proc.stderr and "Exception ignored" not in proc.stderr
    assert line == ["spotpde: terminated by signal 15, no result written"], proc.stderr
    assert not (tmp_path / "r.nc").exists() and leftovers(tmp_path) == []


def test_a_dropped_signal_without_progress_reports_is_acted_on_after_the_write(tmp_path):
    """``-q``: no progress reports; the run ends, its file is complete, and the command
    still stops with 143 and says so."""
    (tmp_path / "c.toml").write_text(FIELDS)
    proc = driven(SWALLOWED, "run", "c.toml", "-o", "r.nc", "-q", cwd=tmp_path)
    assert proc.returncode == 128 + signal.SIGTERM, proc.stderr
    assert one_line(proc) == f"spotpde: terminated by signal 15; {tmp_path / 'r.nc'} is complete"
    assert (tmp_path / "r.nc").stat().st_size > 0 and leftovers(tmp_path) == []


def test_check_signals_raises_what_a_c_callback_dropped():
    """In process: the handler's exception dies in the ctypes callback; check_signals
    raises it again (Terminated for SIGTERM, KeyboardInterrupt for SIGINT), once."""
    import ctypes

    from spotpde.app import _outputs

    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    hook = sys.unraisablehook
    try:
        _outputs.handle_termination()
        for sig, exc in ((signal.SIGTERM, _outputs.Terminated), (signal.SIGINT, KeyboardInterrupt)):
            ctypes.CFUNCTYPE(None)(lambda s=sig: signal.raise_signal(s))()
            with pytest.raises(exc):
                _outputs.check_signals()
            _outputs.check_signals()        # once only: nothing left to raise
    finally:
        for s, h in saved.items():
            signal.signal(s, h)
        sys.unraisablehook = hook
        _outputs._PENDING.clear()
