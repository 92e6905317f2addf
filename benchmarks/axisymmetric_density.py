"""Benchmark: axisymmetric spot density against the 3D Cartesian solve of the same silo.

A cylinder of radius ``a`` and height ``H`` at spacing ``h`` is solved on the ``(z, r)``
half-plane (``nz x a/h`` cells) and, as the baseline, on the 3D Cartesian box
``[-a, a]**2 x [0, H]`` at the same spacing (``nz x (2a/h)**2`` cells), in the same
process (best of ``--repeat`` after a warm-up that compiles the numba kernels). Lines:

1. steady, ``D_par = 0``, ``b`` varying in height (both march in height: the
   axisymmetric Crank-Nicolson / Thomas, the 3D Peaceman-Rachford ADI);
2. steady, ``D_par = 0``, constant ``b`` (axisymmetric marching vs the 3D exact cosine
   modes, the fastest 3D path);
3. transient, ``D_par > 0`` (BDF2 on both; the 3D system is factorised by SuperLU);
4. a 30-degree cone (marching on the staircase) vs the cylinder of line 1.

Prints both times, their ratio and the largest difference between the axisymmetric
field and the Cartesian one along the row of cells at ``y = h/2`` (interpolated in
``r``), relative to the peak at ``z >= 4 d``.

Usage::

    python benchmarks/axisymmetric_density.py [--a 16] [--H 32] [--h 0.25] [--repeat 3]
"""

from __future__ import annotations

import argparse

import numpy as np
from _timing import best_times

from spotpde.density import spot_density
from spotpde.grid import Grid, Hopper
from spotpde.parameters import Orifice, Spots


def line_difference(rc, ra, cart, axi, zmin):
    h, j = cart.spacing, cart.nx // 2
    r = np.hypot(cart.x[j:], 0.5 * h)
    line = rc[:, j, j:]
    interp = np.array([np.interp(r, axi.r, row) for row in ra])
    return float(np.abs(line - interp)[cart.z >= zmin].max() / line.max())


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--a", type=float, default=16.0)
    ap.add_argument("--H", type=float, default=32.0)
    ap.add_argument("--h", type=float, default=0.25)
    ap.add_argument("--nt", type=float, default=0.5, help="spacing of the transient line")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    a, H, h = args.a, args.H, args.h
    o2 = Orifice(x=0.0, width=4.0)
    o3 = Orifice(x=0.0, y=0.0, width=4.0)
    print(f"cylinder a = {a} d, H = {H} d, h = {h} d; 3D box (2a)^2 x H")
    print(f"{'solve':58s} {'axisym':>9s} {'3D':>9s} {'3D/axi':>8s} {'diff':>8s}")

    def row(name, axi, cart, spots, transient=None):
        if transient is None:
            fa = lambda: spot_density.steady(axi, o2, spots)             # noqa: E731
            fc = lambda: spot_density.steady(cart, o3, spots3)           # noqa: E731
        else:
            fa = lambda: spot_density.transient(axi, o2, spots, transient)      # noqa: E731
            fc = lambda: spot_density.transient(cart, o3, spots3, transient)    # noqa: E731
        spots3 = spots if np.ndim(spots.b) == 0 else Spots(
            drift=spots.drift, b=np.broadcast_to(spots.b[:, :1, None], cart.shape).copy(),
            b_par=spots.b_par)
        ta, tc = best_times([fa, fc], args.repeat)
        diff = line_difference(fc(), fa(), cart, axi, 4.0)
        print(f"{name:58s} {ta:9.4f} {tc:9.4f} {tc / ta:8.1f} {diff:8.1e}")

    axi = Grid(2, (0, a), (0, H), h, coordinates="axisymmetric")
    cart = Grid(3, (-a, a), (0, H), h)
    Z, _ = axi.mesh()
    b_z = np.broadcast_to(1.0 + 0.3 * Z / H, axi.shape).copy()
    row(f"steady, b(z), marching ({axi.nz}x{axi.nx} vs {cart.nz}x{cart.nx}^2)", axi, cart,
        Spots(b=b_z))
    row("steady, constant b (axisym marching vs 3D exact modes)", axi, cart, Spots(b=1.3))
    ht = args.nt
    axt = Grid(2, (0, a / 2), (0, H / 4), ht, coordinates="axisymmetric")
    cat = Grid(3, (-a / 2, a / 2), (0, H / 4), ht)
    row(f"transient b_par = 1, t = {H / 4:g} (BDF2; {axt.nz}x{axt.nx} vs {cat.nz}x{cat.nx}^2)",
        axt, cat, Spots(b=1.3, b_par=1.0), transient=H / 4)
    cone = Grid(2, (0, a), (0, H), h, coordinates="axisymmetric", hopper=Hopper(30.0, 0.0, 2.0))
    tc, ta = best_times([lambda: spot_density.steady(cone, o2, Spots(b=b_z)),
                         lambda: spot_density.steady(axi, o2, Spots(b=b_z))], args.repeat)
    print(f"{'30-degree cone vs the cylinder, steady b(z) (time ratio)':58s} {tc:9.4f} "
          f"{ta:9.4f} {ta / tc:8.2f}")


if __name__ == "__main__":
    main()
