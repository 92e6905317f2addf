"""Time to calibrate: one forward evaluation of the mean-flow and diffusion observables of
the flagship silo, and whole fits of 3 and 4 parameters, serial and with the Jacobian's
columns on a local Dask cluster, with the number of model evaluations.

The data: tracks of the discrete spot model in the flagship silo (``cases/quasi2d_layers.toml``
without its tracer: 40 d x 60 d at d/4, the paper's disk kernel, rule 1/2), measured below
30 d. Baseline, in the same run: ``spotpde.run`` of the same case without observables
(the fields alone), so the ratio says what the observables and the fit add.

    python benchmarks/calibration.py [--t-end 600] [--no-dask]
"""

from __future__ import annotations

import argparse
import copy
import os
import sys
import time
import tomllib

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
from _timing import best_time  # noqa: E402

import spotpde  # noqa: E402
from spotpde import montecarlo as mc, observables as O, tracks as T  # noqa: E402
from spotpde.calibration._forward import Forward, Targets, observables_for_fit  # noqa: E402

CASE = os.path.join(os.path.dirname(__file__), "..", "cases", "quasi2d_layers.toml")


def flagship():
    with open(CASE, "rb") as fh:
        raw = tomllib.load(fh)
    raw.pop("tracer")
    raw.pop("output")
    return raw


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--t-end", type=float, default=600.0)
    p.add_argument("--no-dask", action="store_true")
    args = p.parse_args(argv)
    print(f"load average {os.getloadavg()}")
    raw = flagship()
    case = spotpde.load_case(raw)
    t0 = time.perf_counter()
    r = mc.from_case(case, particles="lattice", spacing=1.0, tracked="all",
                     records=int(args.t_end), t_end=args.t_end, seed=1, probes=False)
    tracks = T.read(r).sel(t=slice(60, None))
    tracks = tracks.where(tracks["z"] < 30)
    print(f"Monte Carlo tracks: {tracks.sizes['particle']} grains x {tracks.sizes['t']} frames "
          f"({time.perf_counter() - t0:.1f} s)")
    t0 = time.perf_counter()
    data = O.measure(tracks, case, ["velocity", "diffusion"])
    print(f"measure velocity + diffusion from tracks: {time.perf_counter() - t0:.2f} s")

    targets = Targets(data, observables_for_fit(["velocity", "diffusion"]), stride=4)
    keys = ["spots.b", "kernel.height", "orifice.rate"]
    fwd = Forward(case, keys, targets)
    base = [1.3, 0.0024, 21.22]
    fields, _ = best_time(lambda: spotpde.run(case), 3)
    same, _ = best_time(lambda: fwd(base), 3)
    step = iter(np.linspace(1.0, 1.2, 40))
    new_b, _ = best_time(lambda: fwd([1.3 * next(step), 0.0024, 21.22]), 3)
    sizes = iter(np.linspace(2.4, 2.6, 40))
    fwd4 = Forward(case, ["spots.b", "kernel.height", "orifice.rate", "kernel.size"], targets)
    new_size, _ = best_time(lambda: fwd4([1.3, 0.0024, 21.22, next(sizes)]), 3)
    print("\nforward evaluation (warm, best of 3), flagship silo 160 x 240 cells:")
    print(f"  baseline spotpde.run, fields only: {fields:.3f} s")
    print(f"  observables at cached kernel shape: {same:.3f} s ({same / fields:.2f}x baseline)")
    print(f"  new spots.b (a new passage tensor): {new_b:.3f} s ({new_b / fields:.2f}x)")
    print(f"  new kernel.size (a new kernel shape): {new_size:.3f} s ({new_size / fields:.2f}x)")

    start = copy.deepcopy(raw)
    start["spots"]["b"] = 2.0
    start["kernel"]["height"] = 0.004
    start["orifice"]["rate"] = 15.0
    free3 = {"spots.b": (0.3, 5.0), "kernel.height": (2e-4, 0.05), "orifice.rate": (2.0, 200.0)}
    free4 = {**free3, "kernel.size": (1.0, 5.0)}
    rows = []
    clients = [None]
    cluster = None
    if not args.no_dask:
        from spotpde.app._localdask import LocalDask

        cluster = LocalDask(2)
        clients.append(cluster.start())
    try:
        for name, free in (("3 parameters", free3), ("4 parameters", free4)):
            for client in clients:
                t0 = time.perf_counter()
                fit = spotpde.fit(start, tracks, free, measurement=data, client=client)
                rows.append((name, "Dask, 2 workers" if client else "serial",
                             time.perf_counter() - t0, fit.attrs["nfev"], fit))
    finally:
        if cluster is not None:
            cluster.close()
    print("\nwhole fits (velocity + diffusion), from spots.b = 2, w = 0.004, rate = 15:")
    for name, how, dt, nfev, fit in rows:
        vals = ", ".join(f"{k} = {v:.4g} +- {s:.2g}" for k, v, s in
                         zip(fit["parameter"].values, fit["value"].values, fit["stderr"].values))
        print(f"  {name}, {how}: {dt:.1f} s, {nfev} model evaluations; {vals}")
        print(f"    not reproduced: {fit.attrs['not_reproduced'] or 'nothing'}")


if __name__ == "__main__":
    main()
