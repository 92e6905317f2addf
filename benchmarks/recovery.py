"""Parameter recovery and coverage: tracks of the discrete spot model (Monte Carlo) at
parameters the fit is not told, written as trackpy would write them (pixels, image rows
pointing down), read back and fitted; over several seeds, how often is the truth within
one and two reported standard errors (about 68 % and 95 % if the errors are honest)?

Two set-ups, each where the continuum describes the discrete model to within the errors:

* ``mean flow``: a converging silo (16 d x 24 d, 3 d slot); ``spots.b`` and
  ``orifice.rate`` from the coarse-grained velocity below 12 d.
* ``diffusion``: uniform flow (the orifice spans the floor); ``orifice.rate`` and
  ``kernel.volume`` from the velocity and the diffusion lengths (``b`` known).

(In a converging silo the discrete model's Lagrangian ``b_p`` falls 15-20 % below the
continuum's ``D_xx/|u_z|``; a fit of the kernel volume there is biased, and the fit's
report says so: docs/calibration.md, section 6.)

    python benchmarks/recovery.py [--seeds 8] [--setup both|flow|diffusion]
"""

from __future__ import annotations

import argparse
import copy
import os
import time

import numpy as np

import spotpde
from spotpde import montecarlo as mc, tracks as T

SCALE, FPS, ORIGIN = 12.5, 2.0, (300.0, 640.0)
SETUPS = {
    "flow": {
        "truth": {"domain": {"dims": 2, "x": [-8.0, 8.0], "z": [0.0, 24.0], "spacing": 0.5},
                  "orifice": {"x": 0.0, "width": 3.0, "rate": 16.0}, "spots": {"b": 1.3},
                  "kernel": {"shape": "gaussian", "size": 1.0, "volume": 0.05, "rule": 1.0}},
        "free": {"spots.b": (0.3, 5.0), "orifice.rate": (4.0, 60.0)},
        "start": {"spots.b": 2.2, "orifice.rate": 11.0},
        "observables": ["velocity"], "below": 12.0, "t_end": 500.0, "options": None,
    },
    "diffusion": {
        "truth": {"domain": {"dims": 2, "x": [-8.0, 8.0], "z": [0.0, 16.0], "spacing": 0.5},
                  "orifice": {"x": 0.0, "width": 16.0, "rate": 64.0}, "spots": {"b": 1.3},
                  "kernel": {"shape": "gaussian", "size": 1.0, "volume": 0.01, "rule": 1.0}},
        "free": {"orifice.rate": (10.0, 400.0), "kernel.volume": (0.001, 0.1)},
        "start": {"orifice.rate": 40.0, "kernel.volume": 0.02},
        "observables": ["velocity", "diffusion"], "below": 8.0, "t_end": 300.0,
        "options": {"diffusion": {"bins": (7.5, 12.0)}},
    },
}


def _lookup(data, key):
    node = data
    for part in key.split("."):
        node = node[part]
    return node


def pixel_tracks(setup, seed, path):
    """Monte Carlo tracks of the truth, written in trackpy's layout (pixels, y down)."""
    case = spotpde.load_case(setup["truth"])
    r = mc.from_case(case, particles="lattice", spacing=1.0, tracked="all",
                     records=int(setup["t_end"] * FPS), t_end=setup["t_end"], seed=seed,
                     probes=False)
    tr = T.read(r)
    transit = case.grid.z_range[1] / float(case.spots.drift)
    tr = tr.sel(t=slice(1.25 * transit, None))
    tr = tr.assign_coords(t=np.round(tr["t"].values * FPS) / FPS)
    tr = tr.where(tr["z"] < setup["below"])
    T.to_trackpy(tr, scale=SCALE, fps=FPS, origin=ORIGIN, y_down=True).to_csv(path, index=False)


def recover(setup, seed, workdir):
    path = os.path.join(workdir, f"tracks_{seed}.csv")
    pixel_tracks(setup, seed, path)
    tracks = T.read(path, scale=SCALE, fps=FPS, origin=ORIGIN, y_down=True)
    start = copy.deepcopy(setup["truth"])
    for key, value in setup["start"].items():
        *tables, last = key.split(".")
        node = start
        for t in tables:
            node = node[t]
        node[last] = value
    return spotpde.fit(start, tracks, setup["free"], setup["observables"],
                       options=setup["options"])


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--seeds", type=int, default=8)
    p.add_argument("--setup", choices=("both", "flow", "diffusion"), default="both")
    p.add_argument("--workdir", default="/tmp")
    args = p.parse_args(argv)
    names = list(SETUPS) if args.setup == "both" else [args.setup]
    print(f"load average {os.getloadavg()}")
    for name in names:
        setup = SETUPS[name]
        print(f"\n== {name}: free {', '.join(setup['free'])}; observables {setup['observables']}")
        print("seed | " + " | ".join(f"{k}: value +- stderr (z)" for k in setup["free"])
              + " | evaluations | seconds | not reproduced")
        z_all = {k: [] for k in setup["free"]}
        for seed in range(args.seeds):
            t0 = time.perf_counter()
            fit = recover(setup, seed, args.workdir)
            cells = []
            for key, value, se in zip(fit["parameter"].values, fit["value"].values,
                                      fit["stderr"].values):
                truth = _lookup(setup["truth"], key)
                z = (value - truth) / se
                z_all[key].append(z)
                cells.append(f"{value:.4g} +- {se:.2g} ({z:+.2f})")
            print(f"{seed} | " + " | ".join(cells) + f" | {fit.attrs['nfev']} | "
                  f"{time.perf_counter() - t0:.0f} | {fit.attrs['not_reproduced'] or '-'}",
                  flush=True)
        for key, zs in z_all.items():
            zs = np.abs(np.asarray(zs))
            print(f"coverage of {key} (truth {_lookup(setup['truth'], key)}): "
                  f"{np.mean(zs <= 1):.0%} within 1 SE, {np.mean(zs <= 2):.0%} within 2 SE "
                  f"({zs.size} seeds)")


if __name__ == "__main__":
    main()
