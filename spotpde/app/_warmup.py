"""Compile the tracer kernel in a second process while ``spotpde run`` computes the spot
density and fields (private; user: :mod:`spotpde.cli`).

The first run after installation compiles the 2D tracer kernel of its reconstruction
(numba, 5-7 s CPU here, mostly numba's Python front end, which holds the GIL: a thread
cannot overlap it). ``spotpde run`` therefore starts this module as a child process,
``python -m spotpde.app._warmup LIMITER THREADS``, as soon as the case is valid (at the
run's own priority: the run waits for it, so a lower one would only slow the run down
on a busy machine). The child steps a tracer on an 8 x 8 grid once with the run's
reconstruction and numba thread count, which compiles the kernel variant the run will
call with the same argument types, and numba writes it to its disk cache (an atomic
rename). The run waits for the child (:func:`Warmup.wait`) before its tracer stage and
then loads the kernel from the cache. On a machine with a free core the compilation
overlaps the imports, spot density and fields of the run (measured in docs/steady.md,
"The first run after installation"); with no free core it takes as long as compiling
in the run, plus the child's imports.
No child is started once numba's cache holds a fresh index of this install's tracer
kernel (:func:`needed`, a file test): the first run of another reconstruction then
compiles in the run, as without this module. If the child fails or is killed, the run compiles the
kernel itself: the child writes nothing but numba's cache.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from .. import _cache
from ..grid import Grid


class Warmup:
    """The child process (or ``None`` when it could not be started)."""

    def __init__(self, limiter: str, threads: int):
        try:
            self.proc = subprocess.Popen(
                [sys.executable, "-m", "spotpde.app._warmup", limiter, str(int(threads))],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL, close_fds=True)
        except OSError:
            self.proc = None

    def wait(self, timeout: float = 120.0) -> None:
        """Wait for the child to finish (at most ``timeout`` seconds, then stop it)."""
        if self.proc is None:
            return
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.stop()

    def stop(self) -> None:
        """Stop the child if it still runs (on an error or a signal in the run): SIGTERM,
        which lets numba finish or drop a cache file it is writing, then SIGKILL after
        2 s."""
        if self.proc is None or self.proc.poll() is not None:
            return
        self.proc.terminate()
        try:
            self.proc.wait(2.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


def needed() -> bool:
    """Whether this install's tracer kernel has no fresh numba cache yet: no index file of
    it in the cache subdirectory numba uses for this source directory (numba names it
    ``tracer_<sha1 of the directory>``), or only indexes older than the source file (an
    upgrade: numba would recompile). A file test, no import of numba."""
    root = _cache.NUMBA_DIR
    if root is None:                # no writable cache: a child's work would be lost
        return False
    # numba hashes os.path.abspath of the source directory (symbolic links kept)
    source = Path(os.path.abspath(__file__)).parent.parent / "tracer" / "_fp_kernels.py"
    sub = root / ("tracer_" + hashlib.sha1(str(source.parent).encode()).hexdigest())
    try:
        changed = source.stat().st_mtime
        return not any(index.stat().st_mtime >= changed for index in
                       sub.glob("_fp_kernels._rhs_2d_variant.*rhs_2d-*.nbi"))
    except OSError:
        return True


def _main(limiter: str, threads: int) -> None:
    from ..tracer import solve

    grid = Grid(2, (-1.0, 1.0), (0.0, 2.0), 0.25)
    Z, X = grid.mesh()
    zero = 0.0 * X + 0.0 * Z
    fields = {"u_x": zero + 0.1, "u_z": zero - 1.0, "D_xx": zero + 0.01,
              "D_xz": zero + 0.001, "D_zz": zero + 0.01}
    solve(grid, fields, np.exp(-X**2 - (Z - 1.0) ** 2), 0.1, 2, limiter=limiter,
          threads=threads, diffusion="explicit")


if __name__ == "__main__":
    _main(sys.argv[1], int(sys.argv[2]))
