"""Suite-wide settings: tests check numbers, not speed.

FFTW plans are made with ``FFTW_ESTIMATE`` (measuring plans costs seconds per new shape
and changes no result beyond round-off), wisdom goes to a per-session temporary cache,
and matplotlib draws off-screen.
"""

import os
import tempfile

import spotpde  # noqa: F401 - sets NUMBA_CACHE_DIR to the persistent user cache first, so
#                 the per-session SPOTPDE_CACHE_DIR below does not force recompilation

os.environ.setdefault("SPOTPDE_FFTW_PLANNER", "FFTW_ESTIMATE")
os.environ.setdefault("SPOTPDE_CACHE_DIR", tempfile.mkdtemp(prefix="spotpde-test-cache-"))
os.environ.setdefault("MPLBACKEND", "Agg")
