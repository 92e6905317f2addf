"""Benchmark: particle fields with free-volume-conserving walls against truncated walls.

Times ``coefficients.particle_fields`` on one 2D case (1024 x 1024 cells by default:
spacing d/8, the paper's disk R = 2.5 d, height 0.0024, b = 1.3 d, 4 d slot, reflecting
walls, rule 1/2) with ``walls="truncate"`` (one FFT convolution, the constant-coefficient
path) and ``walls="renormalise"`` (the default: sources divided by the coverage ``phi``,
one transform per source), calls interleaved so both see the same machine load. Prints
each time and the ratio renormalise / truncate for every repetition (docs/walls.md).

Usage::

    python benchmarks/walls.py [--n 1024] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time

from spotpde.fields import coefficients, kernels
from spotpde.density import spot_density
from spotpde.grid import Grid
from spotpde.parameters import Orifice, Spots


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1024, help="cells per side")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    h = 0.125
    half = args.n * h / 2
    grid = Grid(2, (-half, half), (0.0, args.n * h), h)
    kernel = kernels.Uniform(radius=2.5, height=0.0024, dims=2)
    spots = Spots(b=1.3)
    rho = spot_density.steady(grid, Orifice(x=0.0, width=4.0, rate=21.22), spots)
    run = {w: (lambda w=w: coefficients.particle_fields(grid, rho, spots, kernel, walls=w))
           for w in ("truncate", "renormalise")}
    for fn in run.values():  # warm-up: FFTW plans, kernel spectra
        fn()
    for rep in range(args.repeat):
        t = {}
        for name, fn in run.items():
            t0 = time.perf_counter()
            fn()
            t[name] = time.perf_counter() - t0
        print(f"run {rep + 1}: truncate {t['truncate']:.3f} s, renormalise "
              f"{t['renormalise']:.3f} s, ratio {t['renormalise'] / t['truncate']:.2f}")


if __name__ == "__main__":
    main()
