"""The 3D slab at grain resolution (``cases/slab3d.toml``): time and memory against grid size.

Three parts, each measured against a baseline in the same run:

1. **Scaling** (default): ``spotpde.run`` of the slab (50 x 8 x 100 d, slot across the
   depth, coloured layers, the flagship's tracer time) end to end, each spacing in a new
   process, from the smallest grid up (the smallest is run once first, unreported, to
   fill numba's cache). For each grid: wall and CPU seconds of the stages (spot density,
   particle fields, tracer with its file writes) and in all, and the peak resident
   memory of the process (``resource.getrusage(RUSAGE_SELF).ru_maxrss``); then the
   exponents ``p`` of fitted power laws ``time ~ N**p`` and ``memory - M0 ~ N**p`` (``N``
   cells, ``M0`` the peak of a process that imports everything and computes nothing,
   measured here). The tracer's time grows like ``N**(4/3)`` at a fixed physical
   time (its steps like ``1/h``), the rest like ``N`` (``N log N`` for the transforms).
2. **Tracer step** (``--step``): one SSP-RK3 step of the slab's own fields at the case's
   spacing (the fused 3D kernel, WENO5), best of ``--repeat``, with 1 and 2 numba
   threads, in cell updates per second per stage, against ``numpy.copyto`` of an array
   of the grid's size in the same process (the stream copy: 16 bytes a cell). A stage
   reads ``P``, ``P0``, three face-velocity and three coefficient arrays, reads and
   writes the ``P_height`` accumulator and writes its output: 88 bytes a cell (80 with
   ``D_xx = D_yy`` read once, the slab's case), so the memory-bandwidth limit is
   ``16/88`` (``16/80``) of the copy's cell rate; ``tracer_bandwidth.py`` compares the
   step with the bandwidth and its compute roof.
3. **Single precision** (``--precision``): the slab's particle fields at d/4 with the
   whole-grid transforms in float32 (the default for 3D grids of 1e6 cells or more,
   ``spotpde.fields.convolution.precision_for``) against float64, their time and their
   difference, beside the discretisation error of the fields (the d/2 fields against
   the d/4 fields averaged over 2 x 2 x 2 cells): the budget a cheaper transform may use.

Usage: ``python benchmarks/slab3d.py [--spacings 1 0.5 0.4 0.25] [--t-end T] [--step]
[--precision] [--repeat N]`` (the full scaling run takes several minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CASE = ROOT / "cases" / "slab3d.toml"

#: One run in a new process: stage times (wall, CPU) and the peak memory, as JSON.
CHILD = r"""
import json, resource, sys, time, tomllib
t_start = time.perf_counter()
import spotpde
from spotpde.app import pipeline
data = tomllib.loads(open(sys.argv[1]).read())
data["domain"]["spacing"] = float(sys.argv[2])
if sys.argv[3] != "-":
    data["tracer"]["t_end"] = float(sys.argv[3])
if sys.argv[5] == "imports":
    import spotpde.tracer, spotpde.fields.coefficients, spotpde.density.spot_density
    import spotpde.app.io, netCDF4, xarray
    print(json.dumps({"peak": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}))
    sys.exit(0)
case = spotpde.load_case(data, frames_in_memory=False)
marks = []
def progress(stage, fraction):
    if not marks or marks[-1][0] != stage:
        marks.append((stage, time.perf_counter(), time.process_time()))
t0, c0 = time.perf_counter(), time.process_time()
pipeline.run(case, progress=progress, path=sys.argv[4])
t1, c1 = time.perf_counter(), time.process_time()
marks.append(("end", t1, c1))
stages = {a[0]: (b[1] - a[1], b[2] - a[2]) for a, b in zip(marks, marks[1:])}
print(json.dumps({"cells": case.grid.size, "shape": case.grid.shape, "wall": t1 - t0,
                  "cpu": c1 - c0, "stages": stages,
                  "peak": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}))
"""


def child(spacing: float, t_end: float | None, out: Path, what: str = "run") -> dict:
    """One slab run (or, with ``what="imports"``, only the imports) in a new process."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    res = subprocess.run([sys.executable, "-c", CHILD, str(CASE), str(spacing),
                          "-" if t_end is None else str(t_end), str(out), what],
                         capture_output=True, text=True, env=env, cwd=ROOT)
    if res.returncode != 0:
        sys.stderr.write(res.stderr[-3000:])
        raise SystemExit(f"the slab run at spacing {spacing} failed ({res.returncode})")
    return json.loads(res.stdout.strip().splitlines()[-1])


def fit_exponent(n, y) -> float:
    """Slope of ``log y`` against ``log n`` (least squares)."""
    return float(np.polyfit(np.log(n), np.log(y), 1)[0])


def scaling(spacings, t_end) -> None:
    spacings = sorted(spacings, reverse=True)       # small grids first
    with tempfile.TemporaryDirectory(prefix="spotpde-slab-") as tmp:
        out = Path(tmp) / "slab.nc"
        base = child(spacings[0], t_end, out, "imports")["peak"]
        child(spacings[0], t_end, out)               # warm-up: numba cache, unreported
        rows = [(h, child(h, t_end, out)) for h in spacings]
    print(f"slab3d end to end (tracer to t = {t_end if t_end else 'the case t_end'}); "
          f"load average {os.getloadavg()[0]:.1f} at the end; peak of a process with the "
          f"imports only: {base / 2**20:.0f} MiB")
    print("seconds wall / CPU of each stage (the tracer's includes writing its frames and "
          "the result file), peak resident memory")
    print(f"{'h':>5s} {'cells':>10s} {'density':>11s} {'fields':>11s} {'tracer':>13s} "
          f"{'total':>13s} {'peak MiB':>9s} {'B/cell':>7s}")
    for h, r in rows:
        st = r["stages"]
        extra = (r["peak"] - base) / r["cells"]
        cols = [st["spot density"], st["particle fields"], st.get("tracer", (0.0, 0.0)),
                (r["wall"], r["cpu"])]
        print(f"{h:5.3g} {r['cells']:10,d} " + " ".join(
            f"{w:6.1f}/{c:<{w2}.1f}" for (w, c), w2 in zip(cols, (4, 4, 6, 6)))
            + f" {r['peak'] / 2**20:9.0f} {extra:7.0f}")
    n = np.array([r["cells"] for _, r in rows], float)
    series = (("total wall", [r["wall"] for _, r in rows]),
              ("total CPU", [r["cpu"] for _, r in rows]),
              ("fields CPU", [r["stages"]["particle fields"][1] for _, r in rows]),
              ("tracer CPU", [r["stages"].get("tracer", (0, 1e-9))[1] for _, r in rows]),
              ("peak memory above the imports", [r["peak"] - base for _, r in rows]))
    for label, y in series if len(rows) >= 2 else ():
        tail = (f"; largest three: {fit_exponent(n[-3:], y[-3:]):.2f}"
                if len(rows) > 3 else "")
        print(f"fitted exponent of {label} against N: {fit_exponent(n, y):.2f}{tail}")


def slab_fields(spacing: float):
    """The slab case at ``spacing``, its spot density and its particle fields."""
    import tomllib

    import spotpde
    from spotpde.app import pipeline
    from spotpde.density import spot_density

    data = tomllib.loads(CASE.read_text())
    data["domain"]["spacing"] = spacing
    case = spotpde.load_case(data, frames_in_memory=False)
    rho = spot_density.solve(case.grid, case.orifice, case.spots)
    return case, rho, pipeline.case_fields(case, rho)


def step_rate(repeat: int) -> None:
    import numba

    from spotpde.app.pipeline import initial_density
    from spotpde.tracer._advection import limiter_from_name
    from spotpde.tracer._operator import _Operator, _Workspace
    from spotpde.tracer._stepping import _rk_step
    from spotpde.tracer._timestepping import scheme_from_name

    case, _, fields = slab_fields(0.25)
    grid = case.grid
    P0 = initial_density(grid, case.tracer.start)
    op = _Operator(grid, fields, limiter_from_name("weno5").code,
                   np.ones(grid.shape[1:], bool), implicit=False, p_scale=float(P0.max()))
    ws = _Workspace(grid, float(P0.max()))
    scheme = scheme_from_name("ssprk3")
    dt = 0.9 / op.rate
    nbytes = 80 if op.axial[1] is op.axial[0] else 88     # D_xx = D_yy read once
    src, dst = np.random.default_rng(0).random(grid.shape), np.empty(grid.shape)
    print(f"tracer step on the slab's fields, {grid.shape} = {grid.size:,d} cells, WENO5, "
          f"SSP-RK3 (3 stages), best of {repeat}; load average {os.getloadavg()[0]:.1f}")
    for threads in (1, 2):
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
        P = P0.copy()
        _rk_step([op] * 3, P, dt, scheme, ws, [0.0, 0.0, 0.0])      # warm-up
        best_step = best_copy = cpu_step = cpu_copy = float("inf")
        for _ in range(repeat):                   # interleaved: the same load for both
            t0, c0 = time.perf_counter(), time.process_time()
            _rk_step([op] * 3, P, dt, scheme, ws, [0.0, 0.0, 0.0])
            best_step = min(best_step, time.perf_counter() - t0)
            cpu_step = min(cpu_step, time.process_time() - c0)
            t0, c0 = time.perf_counter(), time.process_time()
            np.copyto(dst, src)
            best_copy = min(best_copy, time.perf_counter() - t0)
            cpu_copy = min(cpu_copy, time.process_time() - c0)
        stage = grid.size * 3 / best_step / 1e6
        copy = grid.size / best_copy / 1e6
        print(f"  {threads} thread(s): step {best_step * 1e3:.0f} ms, {stage:.0f} Mcell/s a "
              f"stage; numpy copy {copy:.0f} Mcell/s ({16 * copy / 1e3:.1f} GB/s); stage / "
              f"copy = {stage / copy:.3f} against the bandwidth bound 16/{nbytes} = "
              f"{16 / nbytes:.3f} (the stage at {nbytes * stage / 1e3:.1f} GB/s)")
        print(f"    per CPU second (the process's, all threads): stage "
              f"{grid.size * 3 / cpu_step / 1e6:.0f} Mcell, copy "
              f"{grid.size / max(cpu_copy, 1e-9) / 1e6:.0f} Mcell")


def precision() -> None:
    from spotpde.app import pipeline
    from spotpde.fields import convolution

    case, rho, _ = slab_fields(0.25)
    grid = case.grid
    print(f"the slab's fields at d/4, {grid.shape}: whole-grid transforms in "
          f"{convolution.precision_for(grid.shape)} precision by default; load average "
          f"{os.getloadavg()[0]:.1f}")
    default = convolution.SINGLE_PRECISION_CELLS
    times, fields = {}, {}
    for label, cells in (("double", 10**12), ("single", default)) * 2:   # interleaved
        convolution.SINGLE_PRECISION_CELLS = cells
        t0 = time.perf_counter()
        fields[label] = pipeline.case_fields(case, rho)
        times[label] = min(times.get(label, np.inf), time.perf_counter() - t0)
    convolution.SINGLE_PRECISION_CELLS = default
    print(f"  particle fields: {times['single']:.2f} s single, {times['double']:.2f} s double "
          f"(best of 2)")
    _, _, coarse = slab_fields(0.5)
    double, single = fields["double"], fields["single"]
    scales = {kind: max(np.abs(a).max() for n, a in double.items() if n[0] == kind)
              for kind in "uD"}
    print("  errors relative to the drift's or the tensor's largest component:")
    for name in ("u_x", "u_y", "u_z", "D_xx", "D_yy", "D_zz"):
        fine, scale = double[name], scales[name[0]]
        nz, ny, nx = fine.shape
        avg = fine.reshape(nz // 2, 2, ny // 2, 2, nx // 2, 2).mean(axis=(1, 3, 5))
        disc = np.abs(coarse[name] - avg).max() / scale
        err = np.abs(single[name] - fine).max() / scale
        print(f"  {name}: single against double {err:.1e}; discretisation (d/2 against d/4 "
              f"averaged over 2 x 2 x 2 cells) {disc:.1e}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spacings", type=float, nargs="+", default=[1.0, 0.5, 0.4, 0.25])
    parser.add_argument("--t-end", type=float, default=None,
                        help="tracer duration (default: the case's, 600)")
    parser.add_argument("--step", action="store_true", help="the tracer step rate only")
    parser.add_argument("--precision", action="store_true",
                        help="the single-precision transform's error only")
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    if args.step:
        step_rate(args.repeat)
    elif args.precision:
        precision()
    else:
        scaling(args.spacings, args.t_end)


if __name__ == "__main__":
    main()
