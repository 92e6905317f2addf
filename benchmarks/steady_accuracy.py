"""Accuracy and time of the steady propagator's schemes in the spot model (issue 29, part 1).

The case of the issue: a spot-model tracer (paper's disk kernel, b = 1.3 d, slot of
4 d, silo 30 d wide and 30 d high between reflecting walls, h = d/4) released as a blob
of standard deviation 0.75 d at (4, 20) d. Cell Peclet number about 100.

Prints, from one run:

* each steady scheme's ``P_height`` against the drained time-stepped WENO5 run on the
  same grid (relative L2 over the grid: the issue's 26 % for the old default "hybrid"),
  and per height;
* per height, the relative L2 error of ``P_height`` (the faces ``z = k h``) against a
  converged reference, for the time-stepped WENO5 run at h (drained, t = 3000), the
  steady solves "hybrid" and "upwind" (the linear schemes, one solve; "hybrid" was the
  default before), and "weno5" (the steady state of the time-stepped scheme itself, the
  default now);
* the time of each, measured interleaved (best of ``--repeat``), and the load average.

Reference: the time-stepped WENO5 run on a grid ``--ref-factor`` times finer (default 2;
4 takes about 16 times longer) with the h = d/4 fields interpolated bilinearly (the
tracer's discretisation error alone, not the fields'); results on the finer grid are
averaged onto the h = d/4 faces. ``--also-fine`` adds the steady WENO5 solve on the
reference grid (its distance from the reference: the two schemes converge together).

Run: ``python benchmarks/steady_accuracy.py [--repeat 2] [--ref-factor 2]``.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import time
import tomllib

import numpy as np
from scipy.interpolate import RegularGridInterpolator

from spotpde import tracer
from spotpde._roundoff import clip_roundoff
from spotpde.app import pipeline
from spotpde.app.cases import load_case
from spotpde.density import spot_density
from spotpde.grid import Grid

T_END = 3000.0
START = (4.0, 20.0, 0.75)        # x, z, standard deviation (d)


def spot_case():
    """Grid, fields and P0 of the issue's case at h = d/4."""
    path = pathlib.Path(__file__).resolve().parent.parent / "cases" / "quasi2d_layers.toml"
    raw = tomllib.loads(path.read_text())
    raw["tracer"].pop("layers")
    raw["domain"].update(x=[-15.0, 15.0], z=[0.0, 30.0])
    raw["tracer"].update(start={"x": START[0], "z": START[1], "width": START[2]},
                         t_end=T_END, frames=2)
    case = load_case(raw)
    grid = case.grid
    rho = clip_roundoff(spot_density.solve(grid, case.orifice, case.spots))
    f = {k: np.asarray(v, dtype=float) for k, v in pipeline.case_fields(case, rho).items()}
    return grid, f, pipeline.initial_density(grid, case.tracer.start)


def refined(grid, f, fac):
    """The same silo at ``h / fac``, the fields interpolated bilinearly (clamped to the
    coarse cell centres), the blob sampled and normalised on the fine cells."""
    h = grid.spacing / fac
    g = Grid(2, grid.x_range, grid.z_range, h, walls=grid.walls)
    Z, X = np.broadcast_arrays(*g.mesh())
    pts = np.stack([np.clip(Z, grid.z[0], grid.z[-1]), np.clip(X, grid.x[0], grid.x[-1])], -1)
    ff = {k: np.ascontiguousarray(RegularGridInterpolator((grid.z, grid.x), v)(pts))
          for k, v in f.items()}
    P0 = np.exp(-0.5 * ((X - START[0]) ** 2 + (Z - START[1]) ** 2) / START[2] ** 2)
    return g, ff, P0 / (P0.sum() * h * h)


def on_coarse(faces, fac):
    """Fine ``P_height_faces`` at the coarse faces, averaged over the coarse cells."""
    a = faces[::fac]
    return a.reshape(a.shape[0], -1, fac).mean(-1)


def _table(title, cols, ref, ref_grid, h, k_rel):
    """Relative L2 error of each ``cols[name]`` (face values) against ``ref`` at the
    faces below the blob, then over all faces below it (and, with ``ref_grid``, of the
    grid-shaped ``P_height`` over the whole grid: the issue's measure)."""
    names = list(cols)
    print(f"\n{title}")
    print(f"{'z (d)':>6}        " + "".join(f"{n[:26]:>28}" for n in names))
    for k in sorted({0, 1, 2, 4, 8, 12, 20, 40, 60, k_rel}):
        nrm = np.linalg.norm(ref[k])
        print(f"{k * h:6.2f}        " + "".join(f"{np.linalg.norm(cols[n][k] - ref[k]) / nrm:28.4f}"
                                          for n in names))
    sel = slice(0, k_rel + 1)
    print(f"all z < {k_rel * h:<6.2f}" + "".join(
        f"{np.linalg.norm(cols[n][sel] - ref[sel]) / np.linalg.norm(ref[sel]):28.4f}"
        for n in names))
    if ref_grid is not None:
        grid_ref, grid_cols = ref_grid
        print("whole grid    " + "".join(
            f"{np.linalg.norm(grid_cols[n] - grid_ref) / np.linalg.norm(grid_ref):28.4f}"
            for n in names))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--ref-factor", type=int, default=2)
    ap.add_argument("--also-fine", action="store_true")
    args = ap.parse_args()
    grid, f, P0 = spot_case()
    print(f"spot model, slot 4 d, silo 30 x 30 d, blob sigma {START[2]} at ({START[0]}, "
          f"{START[1]}); {grid.shape[1]} x {grid.shape[0]} cells, h = {grid.spacing}")
    runs = {
        "time-stepped WENO5": lambda: tracer.solve(grid, f, P0, T_END, 2),
        "steady hybrid (old default)": lambda: tracer.solve_steady(grid, f, P0, scheme="hybrid"),
        "steady upwind": lambda: tracer.solve_steady(grid, f, P0, scheme="upwind"),
        "steady WENO5 (new default)": lambda: tracer.solve_steady(grid, f, P0),
    }
    best = {k: np.inf for k in runs}
    res = {}
    load = [os.getloadavg()[0]]
    for k, fn in runs.items():           # warm-up (numba compilation)
        res[k] = fn()
    for _ in range(args.repeat):
        for k, fn in runs.items():
            t0 = time.perf_counter()
            res[k] = fn()
            best[k] = min(best[k], time.perf_counter() - t0)
    load.append(os.getloadavg()[0])
    h = grid.spacing
    k_rel = int(round((START[1] - 3 * START[2]) / h))        # the last face below the blob
    ts = res["time-stepped WENO5"]
    steady = {k: r for k, r in res.items() if k.startswith("steady")}
    _table(f"against the drained time-stepped WENO5 run at h = {h} (mass left "
           f"{ts.mass[-1]:.1e}): relative L2 of P_height",
           {k: r.P_height_faces for k, r in steady.items()}, ts.P_height_faces,
           (ts.P_height, {k: r.P_height for k, r in steady.items()}), h, k_rel)
    fac = args.ref_factor
    g2, f2, P2 = refined(grid, f, fac)
    t0 = time.perf_counter()
    ref_run = tracer.solve(g2, f2, P2, T_END, 2)
    t_ref = time.perf_counter() - t0
    ref = on_coarse(ref_run.P_height_faces, fac)
    print(f"reference: time-stepped WENO5 at h = {g2.spacing} ({g2.size} cells, "
          f"{ref_run.steps} steps, {t_ref:.0f} s, mass left {ref_run.mass[-1]:.1e})")
    cols = {k: r.P_height_faces for k, r in res.items()}
    if args.also_fine:
        t0 = time.perf_counter()
        cols[f"steady WENO5 at h/{fac}"] = on_coarse(tracer.solve_steady(g2, f2, P2)
                                                     .P_height_faces, fac)
        print(f"steady WENO5 at h/{fac}: {time.perf_counter() - t0:.1f} s")
    _table("relative L2 error of P_height at the face z, against the reference", cols, ref,
           None, h, k_rel)
    print("\ntime (best of {}, interleaved; load average {:.1f} -> {:.1f}):".format(
        args.repeat, *load))
    for k in runs:
        extra = ""
        o = getattr(res[k], "options", {})
        if "iterations" in o:
            extra = (f"  ({o['iterations']} iterations, {o['factorisations']} factorisations, "
                     f"residual {o['residual_l1']:.1e})")
        elif k.startswith("time"):
            extra = f"  ({res[k].steps} steps)"
        print(f"  {k:30s} {best[k]:8.2f} s  {best[k] / best['time-stepped WENO5']:6.3f} x the "
              f"time-stepped run{extra}")
    ex = res["steady WENO5 (new default)"].exit
    print(f"  steady WENO5 exits: floor {ex['floor']:.15f}, sum - 1 = {sum(ex.values()) - 1:.1e}; "
          f"min G {res['steady WENO5 (new default)'].residence.min():.1e}")


if __name__ == "__main__":
    main()
