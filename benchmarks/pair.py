"""Cage breaking: a 2D pair solve to 99 % absorption (issue 13, item 5; target < 5 s).

Solves ``spotpde.pair.cage_breaking`` for the paper's disk (R = 2.5 d, w = 0.0024,
b = 1.3 d, mean field, b_par = 0.6 d so that the problem is genuinely 2D) at the default
spacing d/16 and at d/32, and prints the wall time, the number of backward-Euler steps,
the mean fall and the baseline measured in the same run: the same backward-Euler steps
with ``scipy.sparse.linalg.spsolve`` re-factorising at every step (what a plain
implementation does). The ratio is ``time(baseline) / time(spotpde)``.
Run: ``python benchmarks/pair.py [--repeat N]``.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from spotpde import pair
from spotpde.fields.kernels import Uniform


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    k = Uniform(radius=2.5, height=0.0024)
    print(f"pair benchmark; load average {os.getloadavg()[0]:.2f}")
    pair.cage_breaking(k, 1.3, diffusivity="mean-field", spacing=1 / 4)   # imports, warm-up
    for h in (1 / 16, 1 / 32):
        best = np.inf
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            ds = pair.cage_breaking(k, 1.3, b_par=0.6, diffusivity="mean-field", spacing=h)
            best = min(best, time.perf_counter() - t0)
        steps = ds.sizes["fall"] - 1
        # baseline: the same steps, spsolve (factorisation) at every step, 20 steps timed
        mesh = pair._mesh(1.0, 2.0, h)
        B = pair.mean_field_tensor(k, 1.3, 0.6, mesh.cx, mesh.cz)
        Q, _, _ = pair._generator(mesh, B, 2.0)
        dt = float(np.diff(ds["fall"].values)[0])
        A = (sp.identity(Q.shape[0]) - dt * Q.T).tocsc()
        m = np.ones(Q.shape[0]) / Q.shape[0]
        t0 = time.perf_counter()
        for _ in range(20):
            m = spla.spsolve(A, m)
        base = (time.perf_counter() - t0) / 20 * steps
        print(f"spacing d/{round(1 / h)}: {Q.shape[0]} cells, {steps} steps to "
              f"survival {ds['survival'].values[-1]:.4f}: {best:.2f} s (target < 5 s); "
              f"baseline spsolve per step {base:.1f} s; ratio {base / best:.1f}x; "
              f"mean fall {ds.attrs['mean_fall']:.2f} d, median {ds.attrs['median_fall']:.2f} d")


if __name__ == "__main__":
    main()
