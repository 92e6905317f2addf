"""How near the memory-bandwidth limit the explicit 3D tracer step runs (issue 29).

One run measures, interleaved (each repetition times every item once, so all see the
same machine load; best of ``--repeat``), with 1 and 2 numba threads:

* **copy**: ``numpy.copyto`` of an array of the grid's size, counted as 16 bytes a cell
  (one read, one write; numpy copies on one thread);
* **triad**: a numba ``a = b + s c`` over the grid (24 bytes a cell);
* **11-array stream**: a numba loop that touches the arrays a Runge-Kutta stage touches
  (reads eight cell arrays, reads and writes the ``P_height`` accumulator, writes the
  output: 88 bytes a cell) with one addition per array: the bandwidth this access
  pattern can get;
* **old** and **new**: one SSP-RK3 step (three stages) of the slab's own fields
  (``cases/slab3d.toml``, WENO5 and Koren) through the solver's ``_rk_step``: old is the
  two-pass kernel (``tracer/_fp_kernels_3d_two_pass.py``) with three coefficient arrays
  and the side outflow summed by ``numpy.vdot`` (BLAS), new the single-sweep kernel
  (``tracer/_fp_kernels_3d.py``) with ``D_xx = D_yy`` stored once and the side outflow
  summed by a numba loop;

on the slab at d/4 (400 x 32 x 200, 2.56 M cells, 20 MB an array: every array streams
from memory) and d/2 (200 x 16 x 100), and on a cache-resident block of the d/4 grid
(16 planes, 102 400 cells: all arrays together, 9 MB, fit the 32 MB L3 cache), whose rate is
the step's compute roof on this machine.

Bytes a stage moves (reads + writes, the copy's convention): ``P`` 8, ``P0`` 8 (0 in
the first stage, where ``P0`` is ``P``), three face-velocity arrays 24, the axial
coefficients 24 (old) or 16 (new, ``D_xx = D_yy`` read once), the accumulator 16, the
output 8: old 80 / 88 / 88, new 72 / 80 / 80 bytes a cell in the three stages.

Floating-point operations a cell (counted in the source; add, subtract, multiply,
divide, min, max, abs one each, a fused multiply-add two): a WENO5-Z face value 84
(``weno5z``), a Koren face value 13 (``face_value``), a face flux 6 more (upwind and
diffusive parts); three faces a cell, plus 1/8 of a z face recomputed at the chunk
boundaries, plus 14 for the divergence, the stage combination and the accumulator:
WENO5 295, Koren 73. Their ratio to the bytes is the arithmetic intensity.

Usage: ``python benchmarks/tracer_bandwidth.py [--repeat N] [--threads 1 2]
[--limiters weno5 koren]`` (about 2 minutes on 2 cores).
"""

from __future__ import annotations

import argparse
import os
import time

import numba
import numpy as np
from numba import njit, prange

from slab3d import slab_fields
from spotpde.app.pipeline import initial_density
from spotpde.grid import Grid
from spotpde.tracer import _operator
from spotpde.tracer._advection import limiter_from_name
from spotpde.tracer._fp_kernels_3d import rhs_3d_kernel, side_outflow
from spotpde.tracer._fp_kernels_3d_two_pass import rhs_3d_two_pass_kernel
from spotpde.tracer._operator import _check_fields, _Operator, _Workspace
from spotpde.tracer._stepping import _rk_step
from spotpde.tracer._timestepping import SSPRK3

#: bytes a cell of the three stages (module docstring)
STAGE_BYTES = {"old": (80, 88, 88), "new": (72, 80, 80)}
#: floating-point operations a cell of one stage (module docstring)
STAGE_FLOPS = {"weno5": 3 * 90 + 90 / 8 + 14, "koren": 3 * 19 + 19 / 8 + 14}


@njit(parallel=True, cache=True)
def triad(a, b, c, s):
    """``a = b + s c`` (24 bytes a cell)."""
    for i in prange(a.size):
        a[i] = b[i] + s * c[i]


@njit(parallel=True, cache=True)
def stream11(out, acc, a, b, c, d, e, f, g, k):
    """The memory traffic of a stage without its arithmetic (88 bytes a cell)."""
    for i in prange(out.size):
        acc[i] += a[i]
        out[i] = b[i] + c[i] + d[i] + e[i] + f[i] + g[i] + k[i]


def sub_block(case_grid, fields, P0, planes):
    """The first ``planes`` z planes of the grid above the floor region (cache-resident)."""
    k0 = case_grid.shape[0] // 4
    h = case_grid.spacing
    z0 = case_grid.z[k0] - h / 2
    grid = Grid(3, (case_grid.x[0] - h / 2, case_grid.x[-1] + h / 2), (z0, z0 + planes * h), h,
                walls="reflecting", y_range=(case_grid.y[0] - h / 2, case_grid.y[-1] + h / 2))
    sl = slice(k0, k0 + planes)
    f = {k: np.ascontiguousarray(v[sl]) for k, v in fields.items()}
    return grid, _check_fields(grid, f, "fields"), np.ascontiguousarray(P0[sl])


def paths(grid, fields, P0, limiter):
    """The old and the new step as closures over their operators and workspaces."""
    code = limiter_from_name(limiter).code
    outlet = np.ones(grid.shape[1:], bool)
    new = _Operator(grid, fields, code, outlet, implicit=False, p_scale=float(P0.max()))
    old = _Operator(grid, fields, code, outlet, implicit=False, p_scale=float(P0.max()))
    old.axial = tuple(a.copy() for a in old.axial)        # three arrays, as before
    dt = 0.9 / new.rate

    def make(op, kernel, side):
        ws = _Workspace(grid, float(P0.max()))
        P = P0.copy()

        def step():
            saved = _operator.rhs_3d_kernel, _operator.side_outflow
            _operator.rhs_3d_kernel, _operator.side_outflow = kernel, side
            try:
                _rk_step([op] * 3, P, dt, SSPRK3, ws, [0.0, 0.0, 0.0])
            finally:
                _operator.rhs_3d_kernel, _operator.side_outflow = saved
        return step

    shared = sum(a is b for a, b in ((new.axial[1], new.axial[0]), (new.axial[2], new.axial[0])))
    return (make(old, rhs_3d_two_pass_kernel, vdot_side_outflow),
            make(new, rhs_3d_kernel, side_outflow), shared)


def vdot_side_outflow(ux, uy, P):
    """The side outflow as ``_operator._rhs`` computed it before (``numpy.vdot``, BLAS)."""
    return (np.vdot(ux[:, :, -1], P[:, :, -1]) - np.vdot(ux[:, :, 0], P[:, :, 0])
            + np.vdot(uy[:, -1, :], P[:, -1, :]) - np.vdot(uy[:, 0, :], P[:, 0, :]))


def measure(fns, repeat):
    """Best wall and best process-CPU time of each function, calls interleaved (one
    warm-up call each)."""
    for fn in fns:
        fn()
    wall = [np.inf] * len(fns)
    cpu = [np.inf] * len(fns)
    for _ in range(repeat):
        for i, fn in enumerate(fns):
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            wall[i] = min(wall[i], time.perf_counter() - t0)
            cpu[i] = min(cpu[i], time.process_time() - c0)
    return wall, cpu


def run(label, grid, fields, P0, limiters, threads, repeat):
    n = grid.size
    rng = np.random.default_rng(0)
    arrs = [rng.random(n) for _ in range(9)]
    out = np.empty(n)
    steps = {lim: paths(grid, fields, P0, lim) for lim in limiters}
    print(f"\n{label}: {grid.shape} = {n:,d} cells; D_xx = D_yy stored once: "
          f"{'yes' if any(s[2] for s in steps.values()) else 'no'}")
    for thr in threads:
        numba.set_num_threads(min(thr, numba.config.NUMBA_NUM_THREADS))
        fns = [lambda: np.copyto(out, arrs[0]), lambda: triad(out, arrs[0], arrs[1], 2.0),
               lambda: stream11(out, *arrs)]
        for lim in limiters:
            fns += steps[lim][:2]
        wall, cpu = measure(fns, repeat)
        # cell updates a second of wall clock, and per CPU second of the process (all its
        # threads): with one thread, what an idle core gives; with two, per core busy
        rates = [[n / w / 1e6 for w in wall], [n / c / 1e6 for c in cpu]]
        print(f"  {thr} thread(s), load {os.getloadavg()[0]:.1f} (rates: wall clock | per "
              f"CPU second)")
        for name, i, nb in (("copy", 0, 16), ("triad", 1, 24), ("11-array stream", 2, 88)):
            print(f"    {name:15s} {rates[0][i]:6.0f} | {rates[1][i]:6.0f} Mcell/s, "
                  f"{nb * rates[0][i] / 1e3:5.1f} | {nb * rates[1][i] / 1e3:5.1f} GB/s")
        for a, lim in enumerate(limiters):
            for b, path in enumerate(("old", "new")):
                i = 3 + 2 * a + b
                nbytes = sum(STAGE_BYTES[path]) / 3
                w, c = (3 * r[i] for r in rates)                 # a stage: 3 per step
                copy_w, copy_c = rates[0][0], rates[1][0]
                s11_w, s11_c = (88 * r[2] / nbytes for r in rates)
                print(f"    {lim:5s} {path}: {w:6.1f} | {c:6.1f} Mcell/s a stage, {nbytes:.0f} "
                      f"B/cell, {nbytes * w / 1e3:5.2f} | {nbytes * c / 1e3:5.2f} GB/s; "
                      f"/copy {w / copy_w:.3f} | {c / copy_c:.3f} (bound {16 / nbytes:.3f}); "
                      f"/11-array bound {w / s11_w:.2f} | {c / s11_c:.2f}; "
                      f"{STAGE_FLOPS[lim] * c / 1e3:4.1f} GFLOP/s (CPU), "
                      f"{STAGE_FLOPS[lim] / nbytes:.2f} flop/B")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--limiters", nargs="+", default=["weno5", "koren"])
    ap.add_argument("--spacings", type=float, nargs="+", default=[0.25, 0.5])
    args = ap.parse_args()
    print(f"explicit tracer step against the memory bandwidth; {os.cpu_count()} CPUs; "
          f"uptime load {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    for h in args.spacings:
        case, _, fields = slab_fields(h)
        P0 = initial_density(case.grid, case.tracer.start)
        run(f"slab at d/{1 / h:g}", case.grid, fields, P0, args.limiters, args.threads,
            args.repeat)
        if h == min(args.spacings):
            grid, f, P = sub_block(case.grid, fields, P0, 16)
            run("cache-resident block of it (the compute roof)", grid, f, P, args.limiters,
                args.threads, 4 * args.repeat)


if __name__ == "__main__":
    main()
