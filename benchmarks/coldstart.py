"""Cold and warm start of the flagship run (``spotpde run cases/quasi2d_layers.toml --plot``).

*Cold* is the first run after installation: a fresh, empty cache directory
(``SPOTPDE_CACHE_DIR`` and ``NUMBA_CACHE_DIR`` pointed at a new temporary directory), so
every numba kernel is compiled and every FFTW plan measured. *Warm* is the next run with
the same cache. Each run is a separate process (``python -m spotpde run ... --plot``; the
progress lines are read from its standard error): the script prints

* ``start``: seconds from process start to the first progress line (imports, case
  validation: the time before the process computes anything);
* ``total``: wall time of the whole process;
* ``cpu``: its CPU time (user + system, all threads): what the run costs on an idle
  machine, far less noisy than wall time on a shared one;
* the load average at the end of each run.

Baseline, in the same run: ``python -c "import numpy, scipy, xarray"``, the bare
interpreter with the libraries every run needs, so the start-up figures can be read
against what the machine gives a process that does nothing of its own.

``--kernel`` also times, in this process, the two compiled variants of the WENO5 2D
tracer kernel on one thread (the serial one a one-thread run compiles, and the
``parallel=True`` one, which was the only variant before) on the flagship's grid size,
as a ratio measured in the same run: the serial variant must not be slower.

Usage: ``python benchmarks/coldstart.py [--cold N] [--warm N] [--kernel]`` (about a
minute per cold run here).
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
CASE = ROOT / "cases" / "quasi2d_layers.toml"


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def timed_run(cache: Path, out: Path) -> tuple[float, float, float, float]:
    """One flagship run in a new process: (seconds to the first progress line, total,
    CPU seconds, 1-minute load average at its end)."""
    env = dict(os.environ, SPOTPDE_CACHE_DIR=str(cache), NUMBA_CACHE_DIR=str(cache / "numba"),
               PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    cpu0 = _children_cpu()
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "spotpde", "run", str(CASE), "-o",
                             str(out), "--plot"], stderr=subprocess.PIPE,
                            stdout=subprocess.DEVNULL, env=env, text=True)
    start = None
    lines = []
    for line in proc.stderr:
        lines.append(line)
        if start is None and line.startswith("spotpde:") and "%" in line:
            start = time.perf_counter() - t0
    proc.wait()
    total = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.stderr.write("".join(lines[-20:]))
        raise SystemExit(f"flagship run failed with exit status {proc.returncode}")
    return (start if start is not None else total, total, _children_cpu() - cpu0,
            os.getloadavg()[0])


def kernel_ratio(repeat: int = 200) -> None:
    """Serial against parallel variant of the WENO5 2D kernel, one thread, flagship grid."""
    sys.path.insert(0, str(ROOT))
    import numba
    import numpy as np

    from spotpde.tracer import _fp_kernels as K

    nz, nx = 240, 160
    rng = np.random.default_rng(1)
    P = 1e-3 * rng.random((nz, nx)) ** 4
    ux = 0.3 * rng.standard_normal((nz, nx + 1))
    uz = -np.abs(rng.standard_normal((nz + 1, nx)))
    A = 0.01 * rng.random((nz, nx))
    C = 0.002 * rng.standard_normal((nz, nx))
    out = np.empty_like(P)
    Fe = np.empty((2, nx))
    Fa = np.zeros((nz + 1, nx))
    saved = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        kernel = K.rhs_2d_kernel(K.WENO5)
        args = (P, ux, uz, A, A, C, True, 1e6, 0.25, out, Fe, Fa, 0.1, P, 0.0, 1.0, 1e-3, 0.0)
        variants = {"serial": kernel.variant(False), "parallel": kernel.variant(True),
                    "dispatch": kernel}
        best = {k: float("inf") for k in variants}
        for k, f in variants.items():
            f(*args)                                 # compile / load
        for _ in range(repeat):                      # interleaved: same machine state
            for k, f in variants.items():
                t = time.thread_time()
                f(*args)
                best[k] = min(best[k], time.thread_time() - t)
    finally:
        numba.set_num_threads(saved)
    cells = nz * nx / 1e6
    print(f"WENO5 2D kernel, {nz}x{nx}, 1 thread, best of {repeat} (CPU time): " + ", ".join(
        f"{k} {cells / t:.0f} Mcell/s" for k, t in best.items()))
    print(f"serial / parallel time = {best['serial'] / best['parallel']:.3f}; "
          f"dispatch (what the solver calls) / serial = {best['dispatch'] / best['serial']:.3f}"
          f"; load average {os.getloadavg()[0]:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cold", type=int, default=1, help="cold runs (each in a new cache)")
    parser.add_argument("--warm", type=int, default=2, help="warm runs (best is printed)")
    parser.add_argument("--kernel", action="store_true",
                        help="also time the serial and parallel kernel variants")
    parser.add_argument("--keep", type=Path, help="write the cold run's output here")
    args = parser.parse_args()
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import numpy, scipy, xarray"], check=True)
    base = time.perf_counter() - t0
    colds, warms = [], []
    with tempfile.TemporaryDirectory(prefix="spotpde-coldstart-") as tmp:
        tmp = Path(tmp)
        for i in range(args.cold):
            colds.append(timed_run(tmp / f"cache{i}", args.keep or tmp / "cold.nc"))
        warms = [timed_run(tmp / "cache0", tmp / "warm.nc") for _ in range(args.warm)]
    print(f"{'':8s} {'start (s)':>10s} {'total (s)':>10s} {'cpu (s)':>8s} {'load':>6s}")
    for name, runs in (("cold", colds), ("warm", warms)):
        for r in runs:
            print(f"{name:8s} {r[0]:10.2f} {r[1]:10.2f} {r[2]:8.2f} {r[3]:6.2f}")
    cold = min(colds, key=lambda r: r[2])
    warm = min(warms, key=lambda r: r[1]) if warms else None
    print(f"baseline (import numpy, scipy, xarray): {base:.2f} s")
    if warm is not None:
        print(f"warm start / baseline = {warm[0] / base:.2f}x; cold cpu - warm cpu "
              f"(compilation and FFTW planning) = {cold[2] - min(r[2] for r in warms):.2f} s")
    if args.kernel:
        kernel_ratio()


if __name__ == "__main__":
    main()
