"""Benchmark: particle fields of a cylindrical silo, axisymmetric against 3D Cartesian.

The same problem at the same spacing, timed side by side in one run: a silo of radius
``a`` and height ``H`` (default 16 d x 32 d, spacing d/4), the paper's sphere kernel
(R = 2.5 d, height 0.0024), b = 1.3 d, rule 1/2, the passage diffusivity and
free-volume-conserving walls (the defaults), the spot density of a point source below
the floor in a reflecting cylinder (Bessel series):

* axisymmetric: ``coefficients.particle_fields`` on the ``(z, r)`` grid, ring-integrated
  weights (``spotpde.fields._rings``), nx = a/h columns;
* 3D Cartesian: ``coefficients.particle_fields`` on the circumscribing box
  ``[-a, a]^2 x [0, H]`` with reflecting walls (the cylinder cannot be represented; the
  density is the same function of ``r``, zero outside the cylinder).

Prints the best-of-N time of each (after a warm-up: FFTW plans, numba, the 3D stencil),
the time of the axisymmetric run's ring weights (computed, or read back from the disk
cache where every later run finds them), and the ratios 3D / axisymmetric with the
weights in memory (transient runs, sweeps), read from disk, and computed from scratch.

Usage::

    python benchmarks/axisymmetric_fields.py [--radius 16] [--height 32] [--h 0.25] [--repeat 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _timing import best_times
from scipy import special

from spotpde.fields import _rings, coefficients, kernels
from spotpde.grid import Grid
from spotpde.parameters import Spots


def bessel_density(R, Z, a, b=1.3, z0=3.0, n=60):
    out = np.ones(np.broadcast(R, Z).shape)
    for j in special.jn_zeros(1, n):
        out = out + special.j0(j * np.minimum(R, a) / a) / special.j0(j) ** 2 \
            * np.exp(-b * j * j * (Z + z0) / a**2)
    return np.where(R <= a, out / (np.pi * a * a), 0.0)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--radius", type=float, default=16.0)
    ap.add_argument("--height", type=float, default=32.0)
    ap.add_argument("--h", type=float, default=0.25)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    a, H, h = args.radius, args.height, args.h
    kernel = kernels.Uniform(radius=2.5, height=0.0024, dims=3)
    spots = Spots(b=1.3)
    ga = Grid(2, (0.0, a), (0.0, H), h, coordinates="axisymmetric")
    Z, R = ga.mesh()
    rho_a = bessel_density(R, Z, a)
    g3 = Grid(3, (-a, a), (0.0, H), h)
    Z3, Y3, X3 = g3.mesh()
    rho_3 = bessel_density(np.hypot(X3, Y3), Z3, a)

    t0 = time.perf_counter()
    coefficients.particle_fields(ga, rho_a, spots, kernel)      # builds the ring weights
    cold = time.perf_counter() - t0
    t_axi, t_3d = best_times([lambda: coefficients.particle_fields(ga, rho_a, spots, kernel),
                              lambda: coefficients.particle_fields(g3, rho_3, spots, kernel)],
                             args.repeat)
    def weights(disk):
        for cache in (_rings._CACHE, _rings._FACTORS, _rings._UNIT):
            cache.clear()
        _rings.USE_DISK = disk
        t0 = time.perf_counter()
        for power, m in ((1, 0), (1, 1), (2, 0)):
            _rings.ring_weights(kernel, h, ga.nx, power, m)
        _rings.USE_DISK = True
        return time.perf_counter() - t0

    computed = min(weights(False) for _ in range(args.repeat))
    stored = min(weights(True) for _ in range(args.repeat))

    def first_run(grid, rho):   # a new kernel object: the 3D stencil / ring weights anew
        fresh = kernels.Uniform(radius=2.5, height=0.0024, dims=3)
        for cache in (_rings._CACHE, _rings._FACTORS, _rings._UNIT):
            cache.clear()
        _rings.USE_DISK = False
        t0 = time.perf_counter()
        coefficients.particle_fields(grid, rho, spots, fresh)
        _rings.USE_DISK = True
        return time.perf_counter() - t0

    first_axi = min(first_run(ga, rho_a) for _ in range(args.repeat))
    first_3d = min(first_run(g3, rho_3) for _ in range(args.repeat))
    print(f"grid: axisymmetric {ga.shape} ({ga.size} cells), 3D {g3.shape} ({g3.size} cells)")
    print(f"axisymmetric fields (weights in memory): {t_axi:.3f} s")
    print(f"ring weights: computed {computed:.3f} s, read from the disk cache {stored:.4f} s "
          f"(first call of this run, incl. numba load: {cold:.3f} s)")
    print(f"3D Cartesian fields: {t_3d:.3f} s")
    print(f"ratio 3D / axisymmetric: {t_3d / t_axi:.1f} (weights in memory), "
          f"{t_3d / (t_axi + stored):.1f} (weights from the disk cache), "
          f"{t_3d / (t_axi + computed):.1f} (weights computed)")
    print(f"first call with a new kernel (3D: its stencil sampled; axisymmetric: the weights "
          f"computed): 3D {first_3d:.3f} s, axisymmetric {first_axi:.3f} s, ratio "
          f"{first_3d / first_axi:.1f}")

if __name__ == "__main__":
    main()
