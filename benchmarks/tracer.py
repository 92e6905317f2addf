"""Throughput of the tracer Fokker-Planck right-hand side (issue 5, item 8).

Prints, for 512^2 and 1024^2 cells, the cell-updates per second of

* one full second-order 2D right-hand side (limited advection + explicit diffusion
  tensor with cross terms, face fluxes and P_height accumulation): ``rhs``;
* one full SSP-RK3 step (3 right-hand sides + stage combinations): ``step``;

for the second-order (Koren) and fifth-order (WENO5-Z, the default) reconstructions,
with 1 and with all numba threads, and the baseline measured in the same run: a plain
single-threaded numba 5-point Laplacian pass on the same grid (``lap1``). Ratios are
``time(rhs) / time(lap1)``. Timings are the best of ``--repeat`` runs (the machine is
shared). Run: ``.venv/bin/python benchmarks/tracer.py [--repeat N] [--threads 1 2]``.
"""

from __future__ import annotations

import argparse
import time

import numba
import numpy as np
from _timing import best_time

from spotpde.tracer import _fp_kernels as K
from spotpde import tracer
from spotpde.tracer import _solve
from spotpde.tracer._timestepping import SSPRK3
from spotpde.grid import Grid


def fields_for(grid):
    """A converging (kinematic point-source-like) flow with a full diffusion tensor."""
    Z, X = grid.mesh()
    b, z_s = 1.3, 2.0
    zz = Z + z_s
    v = np.exp(-X**2 / (4 * b * zz)) / np.sqrt(4 * np.pi * b * zz) * np.ones(grid.shape)
    u_x = b * (-X / (2 * b * zz)) * v
    D = 0.003 * v
    return {"u_x": u_x, "u_z": -v, "D_xx": D, "D_zz": 0.8 * D, "D_xz": 0.2 * D}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=10)
    ap.add_argument("--sizes", type=int, nargs="*", default=[512, 1024])
    ap.add_argument("--threads", type=int, nargs="*", default=[1, numba.config.NUMBA_NUM_THREADS])
    ap.add_argument("--cpu-time", action="store_true",
                    help="time with this thread's CPU clock (only with --threads 1): the cost "
                         "on an idle core, unaffected by other processes")
    args = ap.parse_args()
    clock = time.thread_time if args.cpu_time else time.perf_counter
    if args.cpu_time and args.threads != [1]:
        ap.error("--cpu-time needs --threads 1")
    print(f"{'n':>5} {'thr':>3} {'scheme':>7} {'lap1 Mc/s':>10} {'rhs Mc/s':>9} {'step Mc/s':>10} "
          f"{'rhs/lap1':>9} {'step/lap1':>10}")
    for n in args.sizes:
        grid = Grid(2, (-n / 8, n / 8), (0.0, n / 4), 0.25)
        f = _solve._check_fields(grid, fields_for(grid), "fields")
        Z, X = grid.mesh()
        # structure in every cell (so no early exits of the limiters in flat zero regions)
        P = np.exp(-((Z - n / 8) ** 2 + X**2) / 50.0) + 0.1 * (1.2 + np.sin(0.7 * X) * np.sin(0.3 * Z))
        P = np.ascontiguousarray(P)
        out = np.zeros_like(P)
        N = P.size
        for threads in args.threads:
            numba.set_num_threads(threads)
            t_lap1 = best_time(lambda: K.laplacian_5pt_serial(P, out), args.repeat, clock)[0]
            for name, code in (("koren", K.KOREN), ("weno5", K.WENO5)):
                op = _solve._Operator(grid, f, code, np.ones(n, bool), implicit=False)
                ws = _solve._Workspace(grid)
                t_rhs = best_time(lambda: _solve._rhs(op, P, ws, 0.0), args.repeat, clock)[0]
                budget = [0.0, 0.0, 0.0]
                Pw = P.copy()
                t_step = best_time(lambda: _solve._rk_step([op] * 3, Pw, 1e-6, SSPRK3, ws, budget),
                                   args.repeat, clock)[0]
                print(f"{n:>5} {threads:>3} {name:>7} {N / t_lap1 / 1e6:10.0f} {N / t_rhs / 1e6:9.0f} "
                      f"{N / t_step / 1e6:10.0f} {t_rhs / t_lap1:9.1f} {t_step / t_lap1:10.1f}")


if __name__ == "__main__":
    main()
