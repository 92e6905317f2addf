"""Benchmark: the nonlinear (interacting-spot) transient solver beside the linear one.

Both solve the spot density of the same 2D case (slot orifice 4 d, b = 1.3 d,
b_par = 0.5 d, v_s = 1, reflecting walls) from an empty silo to ``t = --t`` in the same
process, and each prints cell updates per second (cells x time steps / wall time, best
of ``--repeat`` after a warm-up):

* linear: ``spot_density.transient`` (BDF2, implicit, two SuperLU factorisations reused,
  default step ``h / v_s``: Courant number 1);
* nonlinear: ``traffic.transient`` with ``rho_max`` (MUSCL + demand-supply flux, SSP-RK2,
  explicit: its step is bounded by ``1 / (2 v/h + 2 sum D / h**2)``, several times
  smaller than the linear solver's at these diffusivities), once with ``rho_max`` large
  enough that the flux is linear in practice and once with interactions (rho_max = 0.5).

The ratio printed last is (nonlinear time to ``t``) / (linear time to ``t``): what a run
pays for interacting spots.

Usage::

    python benchmarks/traffic.py [--n 128] [--t 20] [--repeat 3]
"""

from __future__ import annotations

import argparse

import numpy as np
from _timing import best_times

from spotpde.density import spot_density, traffic
from spotpde.grid import Grid
from spotpde.parameters import Orifice, Spots


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=128, help="cells per side (spacing d/4)")
    ap.add_argument("--t", type=float, default=20.0, help="final time")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    h = 0.25
    L = args.n * h
    grid = Grid(2, (-L / 2, L / 2), (0.0, L), h, "reflecting")
    orifice = Orifice(x=0.0, width=4.0, rate=0.4)
    linear = Spots(drift=1.0, b=1.3, b_par=0.5, mode="transient", t_end=args.t)
    weak = Spots(drift=1.0, b=1.3, b_par=0.5, rho_max=1e6)
    strong = Spots(drift=1.0, b=1.3, b_par=0.5, rho_max=0.5)
    out = {}

    def run_linear():
        out["lin"] = spot_density.transient(grid, orifice, linear, args.t, full_output=True)

    def run_weak():
        out["weak"] = traffic.transient(grid, orifice, weak, args.t, full_output=True)

    def run_strong():
        out["strong"] = traffic.transient(grid, orifice, strong, args.t, full_output=True)

    times = best_times([run_linear, run_weak, run_strong], args.repeat)
    cells = grid.size
    print(f"2D {args.n}x{args.n} (h = d/4), to t = {args.t:g}, best of {args.repeat}")
    print(f"{'solver':42s} {'steps':>7s} {'time s':>8s} {'Mcell-updates/s':>16s}")
    for (label, key), t in zip((("linear BDF2 (spot_density.transient)", "lin"),
                                ("nonlinear, rho_max = 1e6", "weak"),
                                ("nonlinear, rho_max = 0.5", "strong")), times):
        steps = out[key]["steps"]
        print(f"{label:42s} {steps:7d} {t:8.3f} {cells * steps / t / 1e6:16.2f}")
    diff = np.abs(out["weak"]["frames"][-1] - out["lin"]["frames"][-1]).max()
    print(f"per-update cost, nonlinear / linear: "
          f"{(times[1] / out['weak']['steps']) / (times[0] / out['lin']['steps']):.2f}")
    print(f"time to t, nonlinear / linear: {times[1] / times[0]:.2f}")
    print(f"max |rho(rho_max = 1e6) - rho(linear)| / max rho: "
          f"{diff / out['lin']['frames'][-1].max():.2e}")


if __name__ == "__main__":
    main()
