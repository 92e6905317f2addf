"""Cost of an axisymmetric tracer run against the 3D Cartesian run of the same problem (issue 14).

The problem: a blob released on the axis of a cylindrical silo of radius ``a`` in a
converging flow (``u_r = -alpha r``, uniform fall ``u_z = -w``, isotropic ``D``), stepped
with the default options to ``t_end``. The axisymmetric run (``(z, r)`` grid,
``a / h`` columns) and the 3D Cartesian run of the same fields in the box
``[-a, a]**2`` (``2a / h`` cells a side) use the same spacing ``h``; both are timed in the
same process (best of ``--repeat``, calls interleaved so that both see the same load) and
the script prints the times, the ratio (target <= 1/20) and the agreement of the two runs
(mass(t) and the relative L1 difference of the final ``P``, the axisymmetric one
interpolated at the 3D cell centres inside the cylinder). The steady solve
(``t_end = inf``) of both grids is timed with ``--steady``.

``--hopper N``: instead, the cost per step of a 2D wedge hopper (30 degrees, ``N x N``
cells; the staircase walls and the sparse diffusion) against the box of the same grid
(the fused 2D kernel), same fields, same run.

Run: ``python benchmarks/axisymmetric.py [--repeat N] [--h H] [--radius A] [--steady]
[--hopper N]``.
"""

from __future__ import annotations

import argparse

import numpy as np
from _timing import best_times
from scipy.interpolate import RegularGridInterpolator

from spotpde import tracer
from spotpde.grid import Grid, Hopper

D, ALPHA, W, Z0, S0 = 0.2, 0.05, 0.5, 8.0, 2.0


def problem(h, radius, top):
    ga = Grid(2, (0.0, radius), (0.0, top), h, coordinates="axisymmetric")
    Z, R = ga.mesh()
    zero = 0.0 * R + 0.0 * Z
    fa = {"u_r": -ALPHA * R + zero, "u_z": -W + zero, "D_rr": D + zero, "D_rz": zero,
          "D_zz": D + zero}
    Pa = np.exp(-(R**2 + (Z - Z0) ** 2) / (2 * S0**2)) + zero
    Pa /= (Pa * ga.cell_volumes).sum()
    g3 = Grid(3, (-radius, radius), (0.0, top), h)
    Z3, Y3, X3 = g3.mesh()
    z3 = 0.0 * X3 + 0.0 * Y3 + 0.0 * Z3
    f3 = {"u_x": -ALPHA * X3 + z3, "u_y": -ALPHA * Y3 + z3, "u_z": -W + z3, "D_xx": D + z3,
          "D_yy": D + z3, "D_zz": D + z3, "D_xy": z3, "D_xz": z3, "D_yz": z3}
    P3 = np.exp(-(X3**2 + Y3**2 + (Z3 - Z0) ** 2) / (2 * S0**2)) + z3
    P3 /= P3.sum() * h**3
    return ga, fa, Pa, g3, f3, P3


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--h", type=float, default=0.5)
    ap.add_argument("--radius", type=float, default=10.0)
    ap.add_argument("--top", type=float, default=14.0)
    ap.add_argument("--t-end", type=float, default=10.0)
    ap.add_argument("--diffusion", default="auto",
                    help="the solver's diffusion mode for both runs (auto: the 3D run at h = 0.25 "
                         "goes implicit, a sparse LU of the 3D grid: use explicit there)")
    ap.add_argument("--steady", action="store_true",
                    help="also time the steady solves (the 3D one takes about a minute)")
    ap.add_argument("--hopper", type=int, default=0,
                    help="time a 2D wedge hopper of N x N cells against the box instead")
    args = ap.parse_args()
    if args.hopper:
        return hopper(args.hopper, args.repeat)
    ga, fa, Pa, g3, f3, P3 = problem(args.h, args.radius, args.top)
    out = {}

    def run_axi():
        out["a"] = tracer.solve(ga, fa, Pa, args.t_end, 6, diffusion=args.diffusion)

    def run_3d():
        out["3"] = tracer.solve(g3, f3, P3, args.t_end, 6, diffusion=args.diffusion)

    def steady_axi():
        out["sa"] = tracer.solve_steady(ga, fa, Pa)

    def steady_3d():
        out["s3"] = tracer.solve_steady(g3, f3, P3)

    t_a, t_3 = best_times([run_axi, run_3d], args.repeat)
    if args.steady:
        s_a, s_3 = best_times([steady_axi, steady_3d], max(1, args.repeat // 2))
    ra, r3 = out["a"], out["3"]
    print(f"h = {args.h}, radius {args.radius}, height {args.top}, t_end {args.t_end}")
    print(f"cells: axisymmetric {ga.size} ({ga.shape}), 3D {g3.size} ({g3.shape}), "
          f"ratio {ga.size / g3.size:.4f}")
    print(f"time stepped: axisymmetric {t_a:.3f} s ({ra.steps} steps, {ra.options['diffusion']} "
          f"diffusion), 3D {t_3:.3f} s ({r3.steps} steps, {r3.options['diffusion']}); "
          f"ratio {t_a / t_3:.4f} (target <= 0.05)")
    if args.steady:
        print(f"steady solve: axisymmetric {s_a:.3f} s, 3D {s_3:.3f} s; ratio {s_a / s_3:.4f}; "
              f"mean exit time {out['sa'].mean_exit_time:.5f} vs {out['s3'].mean_exit_time:.5f}")
    Z, Y, X = g3.mesh()
    it = RegularGridInterpolator((ga.z, ga.r), ra.P[-1], method="cubic")
    rr = np.broadcast_to(np.sqrt(X**2 + Y**2), g3.shape)
    zz = np.broadcast_to(Z, g3.shape)
    inside = rr < args.radius - args.h
    Pi = it(np.stack([zz[inside], rr[inside]], axis=1))
    l1 = np.abs(Pi - r3.P[-1][inside]).sum() / r3.P[-1].sum()
    print(f"agreement: max |mass_axi - mass_3d| = {np.abs(ra.mass - r3.mass).max():.2e}; "
          f"final P relative L1 = {l1:.2e}")


def hopper(n, repeat):
    """Seconds per step: a 30 degree wedge against the box of the same grid."""
    h = 0.25
    half = n * h / 2
    times, steps = [], []
    for hop in (None, Hopper(30.0, 0.0, 2.0)):
        g = Grid(2, (-half, half), (0.0, n * h), h, hopper=hop)
        Z, X = g.mesh()
        f = {"u_x": -0.02 * X + 0 * Z, "u_z": -0.5 + 0 * X + 0 * Z, "D_xx": 0.05 + 0 * X * Z,
             "D_xz": 0.0 * X * Z, "D_zz": 0.05 + 0 * X * Z}
        P0 = np.where(g.active, np.exp(-(X**2 + (Z - 0.7 * n * h) ** 2) / 8.0), 0.0)
        P0 /= P0.sum() * h * h
        out = {}

        def run(g=g, f=f, P0=P0, out=out):
            out["r"] = tracer.solve(g, f, P0, 5.0, 2, diffusion="explicit")

        times.append(run)
        steps.append(out)
    t_box, t_hop = best_times(times, repeat)
    s_box, s_hop = steps[0]["r"].steps, steps[1]["r"].steps
    print(f"{n} x {n} cells, t_end 5: box {t_box:.3f} s ({s_box} steps, "
          f"{1e3 * t_box / s_box:.2f} ms a step), wedge {t_hop:.3f} s ({s_hop} steps, "
          f"{1e3 * t_hop / s_hop:.2f} ms a step); per step wedge / box = "
          f"{(t_hop / s_hop) / (t_box / s_box):.2f}")


if __name__ == "__main__":
    main()
