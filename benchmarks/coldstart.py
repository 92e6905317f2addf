"""Cold and warm start of the flagship run (``spotpde run cases/quasi2d_layers.toml --plot``).

*Cold* is the first run after installation: a fresh, empty cache directory
(``SPOTPDE_CACHE_DIR`` and ``NUMBA_CACHE_DIR`` pointed at a new temporary directory), so
every numba kernel is compiled and every FFTW plan measured. *Warm* is the next run with
the same cache. Each run is a separate process (``python -m spotpde run ... --plot``; the
progress lines are read from its standard error): the script prints

* ``start``: seconds from process start to the first progress line (imports, case
  validation: the time before the process computes anything);
* ``fields``: seconds to the line ``particle fields 100%``: the spot density and the
  coefficient fields computed, solver imports included (the run-time estimate is
  printed there);
* ``total``: wall time of the whole process;
* ``cpu``: its CPU time (user + system, all threads): what the run costs on an idle
  machine, far less noisy than wall time on a shared one;
* the load average at the end of each run.

Baseline, in the same run: ``python -c "import numpy, scipy, xarray"``, the bare
interpreter with the libraries every run needs, so the start-up figures can be read
against what the machine gives a process that does nothing of its own.

Imports, first (``--imports N`` fresh interpreters each, interleaved, best and median):
the baseline against ``import spotpde``, ``import spotpde`` with the flagship case
validated (``spotpde.load_case``: what ``spotpde check`` and ``run`` do before anything
else) and with ``spotpde.run`` resolved (the pipeline and its netCDF writer), each with
the heavy optional libraries it has imported (numba, pyfftw, dask, matplotlib, py-pde
must not be among them, nor lmfit, emcee or spotpde's tracks, observables and
calibration: they load when a stage or ``spotpde fit`` uses them).

``--compile`` then compiles the flagship's WENO5 2D tracer kernel (one thread) in this
process with an empty cache, and prints its CPU time split by numba compilation and by
LLVM module (optimisation and machine code): where a cold run's compile time goes.

Usage: ``python benchmarks/coldstart.py [--cold N] [--warm N] [--imports N] [--compile]``
(about a minute per cold run here).
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


#: Statements timed in fresh interpreters (``--imports``), the baseline first.
IMPORTS = {
    "import numpy, scipy, xarray": "import numpy, scipy, xarray",
    "import spotpde": "import spotpde",
    "import spotpde; spotpde.load_case(flagship)":
        f"import spotpde; spotpde.load_case({str(CASE)!r})",
    "import spotpde; spotpde.run": "import spotpde; spotpde.run",
}
#: Libraries a stage imports when it needs them, never ``import spotpde``.
HEAVY = ("numba", "pyfftw", "dask", "distributed", "matplotlib", "pde", "lmfit", "emcee",
         "spotpde.tracks", "spotpde.observables", "spotpde.calibration")


def import_times(repeat: int) -> None:
    """Each statement of :data:`IMPORTS` in ``repeat`` fresh interpreters (interleaved, so
    that all see the same load): best and median wall time of the process, and the heavy
    libraries it imported."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    times = {name: [] for name in IMPORTS}
    for _ in range(repeat):
        for name, code in IMPORTS.items():
            t0 = time.perf_counter()
            subprocess.run([sys.executable, "-c", code], check=True, env=env, cwd=ROOT)
            times[name].append(time.perf_counter() - t0)
    probe = ("import sys\n{}\nprint(','.join(sorted({{'.'.join(m.split('.')[:k]) for m in "
             "sys.modules for k in (1, 2)}} & set({!r}))))")
    base = min(times["import numpy, scipy, xarray"])
    print(f"imports in fresh interpreters ({repeat} each, interleaved; load average "
          f"{os.getloadavg()[0]:.1f}): best / median seconds, best against the baseline")
    for name, code in IMPORTS.items():
        heavy = subprocess.run([sys.executable, "-c", probe.format(code, HEAVY)], check=True,
                               env=env, cwd=ROOT, capture_output=True, text=True)
        got = heavy.stdout.strip() or "none"
        t = sorted(times[name])
        print(f"  {name:45s} {t[0]:6.2f} / {t[len(t) // 2]:6.2f}  {t[0] / base:5.2f}x  "
              f"heavy libraries: {got}")


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def timed_run(cache: Path, out: Path) -> tuple[float, float, float, float, float]:
    """One flagship run in a new process: (seconds to the first progress line, total,
    CPU seconds, 1-minute load average at its end, seconds to ``particle fields 100%``)."""
    env = dict(os.environ, SPOTPDE_CACHE_DIR=str(cache), NUMBA_CACHE_DIR=str(cache / "numba"),
               PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    cpu0 = _children_cpu()
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "spotpde", "run", str(CASE), "-o",
                             str(out), "--plot"], stderr=subprocess.PIPE,
                            stdout=subprocess.DEVNULL, env=env, text=True, cwd=ROOT)
    start = fields = None
    lines = []
    for line in proc.stderr:
        lines.append(line)
        if start is None and line.startswith("spotpde:") and "%" in line:
            start = time.perf_counter() - t0
        if fields is None and line.startswith("spotpde: particle fields 100%"):
            fields = time.perf_counter() - t0
    proc.wait()
    total = time.perf_counter() - t0
    if proc.returncode != 0:
        sys.stderr.write("".join(lines[-20:]))
        raise SystemExit(f"flagship run failed with exit status {proc.returncode}")
    return (start if start is not None else total, total, _children_cpu() - cpu0,
            os.getloadavg()[0], fields if fields is not None else total)


def compile_breakdown(cache: Path) -> None:
    """Compile the flagship's WENO5 2D tracer kernel in this process with an empty cache
    and print where the CPU time goes: each numba compilation (inclusive of the functions
    it compiles in turn) and the LLVM optimisation and machine-code passes per module."""
    os.environ["NUMBA_CACHE_DIR"] = str(cache)     # read when numba is imported
    sys.path.insert(0, str(ROOT))
    import collections

    from llvmlite.binding import executionengine, newpassmanagers

    compiles, open_ = [], {}

    llvm = collections.defaultdict(float)

    def timed(cls, name, label):
        original = getattr(cls, name)

        def wrapper(self, *args):
            t = time.thread_time()
            try:
                return original(self, *args)
            finally:
                module = args[0].name if args and hasattr(args[0], "name") else ""
                llvm[f"{label} {module[:48]}" if module else label] += time.thread_time() - t
        setattr(cls, name, wrapper)

    timed(newpassmanagers.ModulePassManager, "run", "optimise module")
    timed(newpassmanagers.FunctionPassManager, "run", "optimise functions")
    timed(executionengine.ExecutionEngine, "finalize_object", "machine code")
    # numba binds some of these methods when it is imported: patch first
    import numba
    import numpy as np
    from numba.core import event

    from spotpde.tracer import _fp_kernels as K

    class Compiles(event.Listener):
        def on_start(self, e):
            open_[id(e.data["dispatcher"]), str(e.data["args"])] = time.thread_time()

        def on_end(self, e):
            t = open_.pop((id(e.data["dispatcher"]), str(e.data["args"])), None)
            if t is not None:
                compiles.append((time.thread_time() - t, e.data["dispatcher"].py_func.__qualname__))

    event.register("numba:compile", Compiles())
    nz, nx = 40, 30
    P = np.random.default_rng(0).random((nz, nx))
    u = np.zeros((nz, nx + 1)), np.zeros((nz + 1, nx))
    numba.set_num_threads(1)
    t0, c0 = time.perf_counter(), time.thread_time()
    K.rhs_2d_kernel(K.WENO5)(P, u[0], u[1], P, P, 0.1 * P, True, 1.0, 0.25, np.empty_like(P),
                             np.empty((2, nx)), np.zeros((nz + 1, nx)), 0.1, P, 0.0, 1.0,
                             0.01, 0.0)
    wall, cpu = time.perf_counter() - t0, time.thread_time() - c0
    print(f"compiling the WENO5 2D kernel: {wall:.2f} s wall, {cpu:.2f} s CPU "
          f"(load {os.getloadavg()[0]:.2f}); numba compilations, CPU s inclusive:")
    for t, name in sorted(compiles, reverse=True)[:14]:
        print(f"  {t:6.2f}  {name}")
    machine = sum(v for k, v in llvm.items() if k.startswith("machine"))
    print(f"LLVM: {sum(llvm.values()):.2f} s CPU ({machine:.2f} s machine code); the "
          f"largest modules:")
    for k, v in sorted(llvm.items(), key=lambda kv: -kv[1])[:8]:
        print(f"  {v:6.2f}  {k}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cold", type=int, default=1, help="cold runs (each in a new cache)")
    parser.add_argument("--warm", type=int, default=2,
                        help="warm runs (with --cold 0 after an unreported run that fills "
                             "the cache)")
    parser.add_argument("--compile", action="store_true",
                        help="also break down the compilation of the tracer kernel")
    parser.add_argument("--keep", type=Path, help="write the cold run's output here")
    parser.add_argument("--imports", type=int, default=5,
                        help="fresh interpreters per import statement (0: skip)")
    args = parser.parse_args()
    if args.imports:
        import_times(args.imports)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import numpy, scipy, xarray"], check=True)
    base = time.perf_counter() - t0
    colds, warms = [], []
    with tempfile.TemporaryDirectory(prefix="spotpde-coldstart-") as tmp:
        tmp = Path(tmp)
        for i in range(args.cold):
            colds.append(timed_run(tmp / f"cache{i}", args.keep or tmp / "cold.nc"))
        if not colds and args.warm:    # fill the cache first (not reported)
            timed_run(tmp / "cache0", tmp / "warm.nc")
        warms = [timed_run(tmp / "cache0", tmp / "warm.nc") for _ in range(args.warm)]
    print(f"{'':8s} {'start (s)':>10s} {'fields (s)':>10s} {'total (s)':>10s} {'cpu (s)':>8s} "
          f"{'load':>6s}")
    for name, runs in (("cold", colds), ("warm", warms)):
        for r in runs:
            print(f"{name:8s} {r[0]:10.2f} {r[4]:10.2f} {r[1]:10.2f} {r[2]:8.2f} {r[3]:6.2f}")
    warm = min(warms, key=lambda r: r[1]) if warms else None
    print(f"baseline (import numpy, scipy, xarray): {base:.2f} s")
    if warm is not None:
        print(f"warm start / baseline = {warm[0] / base:.2f}x")
    if warm is not None and colds:
        cold = min(colds, key=lambda r: r[2])
        print(f"cold cpu - warm cpu (compilation and FFTW planning) = "
              f"{cold[2] - min(r[2] for r in warms):.2f} s")
    if args.compile:
        with tempfile.TemporaryDirectory(prefix="spotpde-compile-") as tmp:
            compile_breakdown(Path(tmp))


if __name__ == "__main__":
    main()
