"""Cold and warm start of the flagship run (``spotpde run cases/quasi2d_layers.toml``).

*Cold* is the first run after installation: a fresh, empty cache directory
(``SPOTPDE_CACHE_DIR`` and ``NUMBA_CACHE_DIR`` pointed at a new temporary directory), so
every numba kernel is compiled and every FFTW plan measured. *Warm* is the next run with
the same cache. Each run is a separate process (``python -m spotpde.cli run ... -q``
would hide the start; the progress lines are read instead): the script prints

* ``start``: seconds from process start to the first progress line (imports, case
  validation: the time before the process computes anything);
* ``total``: wall time of the whole process.

Baseline, in the same run: ``python -c "import numpy, scipy, xarray"``, the bare
interpreter with the libraries every run needs, so the start-up figures can be read
against what the machine gives a process that does nothing of its own.

Usage: ``python benchmarks/coldstart.py [--warm N]`` (about a minute here).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CASE = ROOT / "cases" / "quasi2d_layers.toml"


def timed_run(cache: Path, out: Path) -> tuple[float, float]:
    """One flagship run in a new process; (seconds to the first progress line, total)."""
    env = dict(os.environ, SPOTPDE_CACHE_DIR=str(cache), NUMBA_CACHE_DIR=str(cache / "numba"),
               PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "spotpde.cli", "run", str(CASE), "-o",
                             str(out)], stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                            env=env, text=True)
    start = None
    for line in proc.stderr:
        if start is None and line.startswith("spotpde:") and "%" in line:
            start = time.perf_counter() - t0
    proc.wait()
    total = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"flagship run failed with exit status {proc.returncode}")
    return start if start is not None else total, total


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--warm", type=int, default=2, help="warm runs (best is printed)")
    args = parser.parse_args()
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import numpy, scipy, xarray"], check=True)
    base = time.perf_counter() - t0
    with tempfile.TemporaryDirectory(prefix="spotpde-coldstart-") as tmp:
        tmp = Path(tmp)
        cold = timed_run(tmp / "cache", tmp / "cold.nc")
        warm = min((timed_run(tmp / "cache", tmp / "warm.nc") for _ in range(args.warm)),
                   key=lambda r: r[1])
    print(f"{'':8s} {'start (s)':>10s} {'total (s)':>10s}")
    print(f"{'cold':8s} {cold[0]:10.2f} {cold[1]:10.2f}")
    print(f"{'warm':8s} {warm[0]:10.2f} {warm[1]:10.2f}")
    print(f"baseline (import numpy, scipy, xarray): {base:.2f} s; "
          f"warm start / baseline = {warm[0] / base:.2f}x; cold total / warm total = "
          f"{cold[1] / warm[1]:.2f}x")
    print(f"load average: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
