"""Time to the geometrical propagator: one steady solve against time stepping (issue 16).

The case of the issue: the void-model propagator of a tracer released 60 d up a point
orifice, 280 x 320 cells at d/4 (x in [-35, 35], z in [0, 80]). Time stepped to
``t_end = 4e5`` it takes more than 30 minutes; ``tracer.t_end = inf`` solves
``-L G = P0`` once.

Prints, measured in the same run:

* ``steady``: ``tracer.solve_steady`` (its default, the steady state of the WENO5 scheme:
  assembly, the Picard iteration's SuperLU factorisations and solves), best of
  ``--repeat``, and the linear hybrid scheme (one solve) for comparison;
* ``stepped``: the time-stepped solver (default WENO5, SSP-RK3, implicit diffusion) on the
  same grid and fields cut off at ``--t-cut`` (default 100), its steps and wall time, and
  the time for ``t_end = 4e5`` extrapolated linearly (steady fields: a constant number of
  steps per unit time);
* the ratio. (Agreement of the two is in tests/tracer/test_steady.py, on cases that drain.)

Run: ``python benchmarks/steady.py [--repeat 3] [--t-cut 100] [--nx 280]``;
``--flagship`` prints instead the numerical diffusion of the steady schemes in the spot
model (variance of ``P_height`` against a drained time-stepped WENO5 run).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _timing import best_time

from spotpde.app import pipeline
from spotpde.density import spot_density
from spotpde import tracer
from spotpde._roundoff import clip_roundoff
from spotpde.app.cases import load_case


def void_case(nx: int, nz: int, h: float = 0.25):
    return load_case({
        "domain": {"dims": 2, "x": [-nx * h / 2, nx * h / 2], "z": [0.0, nz * h],
                   "spacing": h},
        "orifice": {"x": 0.0, "width": 0.0, "rate": 1.2732},
        "spots": {"b": 1.3},
        "kernel": {"shape": "uniform", "size": 0.5, "volume": 0.7854, "rule": 1.0},
        "tracer": {"model": "void", "start": {"x": 0.0, "z": 60.0, "width": 0.5},
                   "t_end": float("inf")}})


def flagship():
    """Numerical diffusion of the steady schemes in the spot model (cell Peclet ~100):
    variance of P_height over x against a drained time-stepped WENO5 run."""
    import pathlib
    import tomllib
    path = pathlib.Path(__file__).resolve().parent.parent / "cases" / "quasi2d_layers.toml"
    raw = tomllib.loads(path.read_text())
    raw["tracer"].pop("layers")
    raw["tracer"].update(start={"x": 1.0, "z": 20.0, "width": 1.0}, t_end=1500.0, frames=2)
    case = load_case(raw)
    grid = case.grid
    rho = clip_roundoff(spot_density.solve(grid, case.orifice, case.spots))
    f = pipeline.case_fields(case, rho)
    P0 = pipeline.initial_density(grid, case.tracer.start)
    t0 = time.perf_counter()
    tw = tracer.solve(grid, f, P0, 1500.0, 2)
    t_w = time.perf_counter() - t0
    runs = [tw] + [tracer.solve_steady(grid, f, P0, scheme=s)
                   for s in ("hybrid", "upwind", "weno5")]
    print(f"flagship, blob at (1, 20): stepped WENO5 {t_w:.1f} s ({tw.steps} steps, mass "
          f"left {tw.mass[-1]:.2g}); steady hybrid {runs[1].seconds:.2f} s, steady WENO5 "
          f"{runs[3].seconds:.2f} s ({runs[3].options['iterations']} iterations)")
    h, x = grid.spacing, grid.x
    for z in (2.0, 5.0, 10.0, 15.0):
        k = int(np.argmin(np.abs(grid.z - z)))
        mv = []
        for r in runs:
            ph = r.P_height[k]
            c = ph.sum() * h
            m = (ph * x).sum() * h / c
            mv.append((m, (ph * x * x).sum() * h / c - m * m))
        print(f"z = {grid.z[k]:5.2f}: var stepped WENO5 {mv[0][1]:.4f}, steady hybrid "
              f"{mv[1][1] / mv[0][1] - 1:+.3f}, upwind {mv[2][1] / mv[0][1] - 1:+.3f}, WENO5 "
              f"{mv[3][1] / mv[0][1] - 1:+.3f} (relative); means "
              + " ".join(f"{m[0]:.4f}" for m in mv))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--t-cut", type=float, default=100.0)
    ap.add_argument("--nx", type=int, default=280)
    ap.add_argument("--nz", type=int, default=320)
    ap.add_argument("--flagship", action="store_true",
                    help="instead: numerical diffusion of the steady schemes, spot model")
    args = ap.parse_args()
    if args.flagship:
        return flagship()
    case = void_case(args.nx, args.nz)
    grid = case.grid
    rho = clip_roundoff(spot_density.solve(grid, case.orifice, case.spots))
    fields = pipeline.case_fields(case, rho)
    P0 = pipeline.initial_density(grid, case.tracer.start)
    print(f"void model, point orifice, release at z = 60 d; grid {grid.shape[1]} x "
          f"{grid.shape[0]} cells, h = {grid.spacing} d")

    t_hybrid, _ = best_time(lambda: tracer.solve_steady(grid, fields, P0, scheme="hybrid"),
                            args.repeat)
    t_steady, res = best_time(lambda: tracer.solve_steady(grid, fields, P0), args.repeat)
    print(f"steady hybrid (one solve): {t_hybrid:.2f} s; steady WENO5: "
          f"{res.options['iterations']} iterations, converged {res.options['converged']}")
    ex = res.exit
    print(f"steady   : {t_steady:8.2f} s  (solve {res.options['seconds_solve']:.2f} s, "
          f"{res.options['cells_solved']} cells; exits floor {ex['floor']:.12f} "
          f"sides {ex['sides']:.3g} top {ex['top']:.3g} trapped {ex['trapped']:.3g}; "
          f"sum - 1 = {sum(ex.values()) - 1:.2e})")

    t0 = time.perf_counter()
    ts = tracer.solve(grid, fields, P0, args.t_cut, 2)
    t_cut = time.perf_counter() - t0       # includes numba compilation on a cold cache
    t0 = time.perf_counter()
    ts = tracer.solve(grid, fields, P0, args.t_cut, 2)
    t_cut = min(t_cut, time.perf_counter() - t0)
    per_t = t_cut / args.t_cut
    t_full = per_t * 4e5
    print(f"stepped  : {t_cut:8.2f} s for t = {args.t_cut:g} ({ts.steps} steps, "
          f"{ts.options['diffusion']} diffusion, {ts.options['limiter']}); mass still "
          f"inside {ts.mass[-1]:.3f}")
    print(f"stepped to t = 4e5 (extrapolated, {ts.steps / args.t_cut * 4e5:.3g} steps): "
          f"{t_full:8.0f} s = {t_full / 60:.0f} min")
    print(f"ratio stepped(4e5) / steady: {t_full / t_steady:.0f}x   target: steady < 10 s")


if __name__ == "__main__":
    main()
