"""Benchmark: throughput of the discrete spot-model Monte Carlo (spotpde.montecarlo).

Prints spot steps per second and particle updates per second (CPU time of the numba
loop, so the numbers do not depend on other load on the machine) for

* the paper's kernel (uniform disk R = 2.5 d, w = 0.0024, b = 1.3 d) and a Gaussian
  (sigma = 1 d), with particles on a triangular lattice of spacing 1 d (about 22 and
  35 particles within reach of a spot), probes off;
* probes only (frozen particles on a grid of spacing 0.25 d: ~314 probes per step for the
  disk);
* the bare spot walk (no particles, no probes);
* a scaling check: the same flux per unit width in silos 40 d and 160 d wide (4 times
  more particles): the cost per spot step must stay the same (cell lists: O(particles
  within reach), not O(all particles)).

Usage::

    .venv/bin/python benchmarks/montecarlo.py [--quick]
"""

from __future__ import annotations

import argparse

from spotpde.fields import kernels
from spotpde import montecarlo as mc
from spotpde.grid import Grid
from spotpde.parameters import Orifice, Spots


def run(kernel, width=40.0, height=60.0, spacing=0.25, particles=True, probes=False,
        t_end=200.0, rate_per_width=0.5):
    g = Grid(2, (-width / 2, width / 2), (0.0, height), spacing)
    P = mc.lattice(g, 1.0) if particles else None
    r = mc.simulate(g, Orifice(width=width, rate=rate_per_width * width), Spots(drift=1.0, b=1.3),
                    kernel, rule=0.5, particles=P, t_end=t_end, step=0.5, probes=probes, seed=0)
    return r, (0 if P is None else len(P))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="shorter runs")
    args = ap.parse_args()
    t_end = 60.0 if args.quick else 200.0
    disk = kernels.Uniform(radius=2.5, height=0.0024, dims=2)
    gauss = kernels.Gaussian(sigma=1.0, volume=0.0471, dims=2)
    run(disk, t_end=2.0)  # load numba's cache / compile
    rows = []
    for name, k in (("disk R=2.5", disk), ("gaussian s=1", gauss)):
        r, n = run(k, t_end=t_end)
        rows.append((f"{name}, particles", n, r))
        r, n = run(k, t_end=t_end / 4, particles=False, probes=True)
        rows.append((f"{name}, probes h=0.25", 0, r))
    r, n = run(disk, t_end=t_end, particles=False)
    rows.append(("bare spot walk", 0, r))
    for w in (40.0, 160.0):
        r, n = run(disk, width=w, t_end=t_end / 2)
        rows.append((f"disk, width {w:.0f} d", n, r))
    print(f"{'run':28s} {'particles':>9s} {'spot steps':>11s} {'updates':>12s} "
          f"{'steps/s':>10s} {'updates/s':>10s} {'us/step':>8s}")
    for name, n, r in rows:
        p = r.performance
        print(f"{name:28s} {n:9d} {r.counters['spot_steps']:11d} {r.counters['particle_updates']:12d} "
              f"{p['spot_steps_per_second']:10.3g} {p['particle_updates_per_second']:10.3g} "
              f"{1e6 / p['spot_steps_per_second']:8.3f}")


if __name__ == "__main__":
    main()
