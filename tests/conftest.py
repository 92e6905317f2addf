"""Suite-wide settings: tests check numbers, not speed; they leave nothing behind.

FFTW plans are made with ``FFTW_ESTIMATE`` (measuring plans costs seconds per new shape
and changes no result beyond round-off), wisdom goes to a per-session temporary cache,
and matplotlib draws off-screen.

Temporary files: each test process (the pytest process, and each xdist worker) makes
one directory ``spotpde-tests-*`` in the system temporary directory, :data:`SESSION_DIR`,
and removes it when the session ends (``pytest_unconfigure``, or at exit). The
per-session caches (:func:`session_dir`) live in it, and so does everything made with
:mod:`tempfile` in this process or in the processes it starts: ``TMPDIR`` and
``tempfile.tempdir`` point into it (pytest's own ``tmp_path`` stays where pytest keeps
it: ``PYTEST_DEBUG_TEMPROOT``). ``tests/app/test_faults_inputs.py`` runs pytest on two
workers with an empty ``TMPDIR`` and checks that it stays empty.
"""

import atexit
import os
import shutil
import tempfile
from pathlib import Path

import spotpde  # noqa: F401 - sets NUMBA_CACHE_DIR to the persistent user cache first, so
#                 the per-session SPOTPDE_CACHE_DIR below does not force recompilation

_SYSTEM_TMP = tempfile.gettempdir()
_SAVED = {k: os.environ.get(k) for k in ("TMPDIR", "PYTEST_DEBUG_TEMPROOT")}
_OWNER = os.getpid()
#: This process's scratch directory, removed when the session ends.
SESSION_DIR = Path(tempfile.mkdtemp(prefix="spotpde-tests-", dir=_SYSTEM_TMP))
_SCRATCH = SESSION_DIR / "tmp"
_SCRATCH.mkdir()

os.environ.setdefault("PYTEST_DEBUG_TEMPROOT", _SYSTEM_TMP)  # pytest's tmp_path: unchanged
os.environ["TMPDIR"] = str(_SCRATCH)      # processes started by the tests
tempfile.tempdir = str(_SCRATCH)          # this process


def session_dir(name: str) -> Path:
    """A directory ``name`` for this test process, removed at the end of the session
    (e.g. a cache shared by the command-line processes of a test module)."""
    d = SESSION_DIR / name
    d.mkdir(exist_ok=True)
    return d


#: A tiny case without a tracer (a run is a fraction of a second once imported), for
#: the tests of commands, outputs and faults.
FIELDS = """
[domain]
x = [-4.0, 4.0]
z = [0.0, 8.0]
spacing = 0.5

[orifice]
width = 2.0

[output]
path = "r.nc"
"""


os.environ.setdefault("SPOTPDE_FFTW_PLANNER", "FFTW_ESTIMATE")
if not os.environ.get("SPOTPDE_CACHE_DIR"):
    os.environ["SPOTPDE_CACHE_DIR"] = str(session_dir("cache"))
os.environ.setdefault("MPLBACKEND", "Agg")


def _remove_session_dir() -> None:
    """Remove :data:`SESSION_DIR` (only in the process that made it) and point the
    temporary directory back at the system's."""
    if os.getpid() != _OWNER or not SESSION_DIR.exists():
        return
    tempfile.tempdir = None
    for key, value in _SAVED.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value
    shutil.rmtree(SESSION_DIR, ignore_errors=True)


atexit.register(_remove_session_dir)


def pytest_unconfigure(config):
    _remove_session_dir()
