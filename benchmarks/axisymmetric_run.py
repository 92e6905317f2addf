"""The whole run of a cylindrical silo: axisymmetric against 3D Cartesian (issue 14).

One case, ``spotpde.run`` end to end (spot density, particle fields, Kinematic Model,
tracer, Dataset): a cylinder of radius ``a`` with a circular orifice of diameter 4 d on
its axis, the paper's spot (a sphere, R = 2.5 d, w = 0.0024), b = 1.3 d, rule 1/2, and a
tracer blob on the axis. The axisymmetric case (``domain.coordinates = "axisymmetric"``,
``x = [0, a]``) and the 3D Cartesian case of the same silo (the box ``[-a, a]**2``, whose
corners the cylinder does not have) run at the same spacing in the same process, calls
interleaved (best of ``--repeat`` after a warm-up). The first axisymmetric call of a new
(kernel, spacing, radius) also computes the ring-integrated kernel weights, which are then
kept in the user cache; ``--cold-weights`` times that first call too (the cache is pointed
at an empty directory for it). Prints the times and the ratio (target <= 1/20).

    python benchmarks/axisymmetric_run.py [--h 0.25] [--radius 8] [--repeat 2] [--cold-weights]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

from _timing import best_times

import spotpde


def case(coordinates: str, radius: float, height: float, h: float):
    axi = coordinates == "axisymmetric"
    return spotpde.load_case({
        "domain": {"dims": 2 if axi else 3, "coordinates": coordinates,
                   "x": [0.0, radius] if axi else [-radius, radius], "z": [0.0, height],
                   "spacing": h},
        "orifice": {"x": 0.0, "width": 4.0, "rate": 63.66},
        "kernel": {"shape": "uniform", "size": 2.5, "height": 0.0024, "rule": 0.5},
        "tracer": {"start": {"x": 0.0, "z": 0.6 * height, "width": 1.0},
                   "t_end": 60.0, "frames": 4},
    })


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--h", type=float, default=0.25)
    ap.add_argument("--radius", type=float, default=8.0)
    ap.add_argument("--height", type=float, default=16.0)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--cold-weights", action="store_true",
                    help="also time the first axisymmetric call with an empty weight cache")
    args = ap.parse_args()
    axi = case("axisymmetric", args.radius, args.height, args.h)
    box = case("cartesian", args.radius, args.height, args.h)
    print(f"cylinder radius {args.radius} d, height {args.height} d, spacing {args.h} d: "
          f"axisymmetric {axi.grid.shape}, 3D {box.grid.shape} cells")
    if args.cold_weights:
        os.environ["SPOTPDE_CACHE_DIR"] = tempfile.mkdtemp(prefix="spotpde-rings-")
        t0 = time.perf_counter()
        spotpde.run(axi)
        print(f"axisymmetric, first call (ring weights computed): {time.perf_counter() - t0:8.3f} s")
    t_axi, t_box = best_times([lambda: spotpde.run(axi), lambda: spotpde.run(box)],
                              args.repeat)
    print(f"axisymmetric run : {t_axi:8.3f} s")
    print(f"3D Cartesian run : {t_box:8.3f} s")
    print(f"ratio axisymmetric / 3D = {t_axi / t_box:.4f}  (target <= 0.05)")


if __name__ == "__main__":
    main()
