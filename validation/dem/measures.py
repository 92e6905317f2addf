"""Simple measures of a silo run, with standard errors from blocks in time.

    python validation/dem/measures.py RUNDIR [RUNDIR ...] [--heights 10 40] [--json OUT]

For each run (a directory written by silo.py or subsample.py; 2D runs):
- the flow rate Q (grains per unit time through the orifice, from exits.txt);
- the mean downward speed profile v(x) at each height h: the speed -dy/dt of every
  grain between two successive frames whose midpoint lies within 1 d of h, averaged in
  2 d wide bins of x; its centreline value v0 (|x| < 1) and its width
  sigma = sqrt(sum v x^2 / sum v) over the grains in the band (the flux-weighted
  second moment), which for the Kinematic Model's profile v ~ exp(-x^2 / (4 b (z - z0)))
  far from the walls is sqrt(2 b (z - z0)), and W / sqrt(12) for a plug;
- the horizontal displacement variance on the centreline: grains at |x| < 1.5 between
  ``--band`` heights at a frame, their horizontal displacement dx over lags of
  1, 2, 4, ... frames, Var(dx) against the mean fall -dy over the same lag.

Errors: the window is cut into ``--blocks`` consecutive blocks of equal length; each
block gives one estimate and the standard error is their standard deviation over
sqrt(blocks). Blocks of 25 time units are much longer than the flow's correlation
times (a grain passes 1 d of the orifice region in well under one time unit), so they
are close to independent; a subsample of grains gives larger errors, not biased ones.
With several runs, the first is the baseline and every other measure is printed with
its difference from the baseline in combined standard errors.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, os.fspath(Path(__file__).resolve().parent))
import lammps_dump as dump  # noqa: E402

LAGS = (1, 2, 4, 8, 16, 32, 64)


def _block_stats(values: np.ndarray) -> tuple[float, float]:
    """Mean and standard error of per-block estimates (NaN blocks ignored)."""
    values = values[np.isfinite(values)]
    if values.size < 2:
        return float("nan"), float("nan")
    return float(values.mean()), float(values.std(ddof=1) / math.sqrt(values.size))


def flow_rate(run: Path, blocks: int, window: float | None = None) -> tuple[float, float]:
    """Grains per unit time through the orifice in the measuring window (or its first
    ``window`` time units), and its error."""
    t, n = np.loadtxt(run / "exits.txt", unpack=True, ndmin=2)
    m = (t > 0) & (t <= (window if window else np.inf) + 1e-9)
    t, n = t[m], n[m]
    edges = np.linspace(0.0, t.max(), blocks + 1)
    per = np.array([n[(t > a) & (t <= b)].sum() / (b - a) for a, b in zip(edges, edges[1:])])
    return _block_stats(per)


def speed_profile(pos, times, width, h, blocks, half_band=1.0, bin_width=2.0):
    """Mean downward speed in x bins at height h; centreline speed and width, with errors."""
    x0, y0, x1, y1 = pos[:, :-1, 0], pos[:, :-1, 1], pos[:, 1:, 0], pos[:, 1:, 1]
    v = -(y1 - y0) / np.diff(times)[None, :]
    xm, ym = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
    ok = np.isfinite(v) & (np.abs(ym - h) < half_band) & (y0 > 0) & (y1 > 0)
    edges = np.arange(-width / 2, width / 2 + 1e-9, bin_width)
    centres = 0.5 * (edges[1:] + edges[:-1])
    frame_block = np.minimum((np.arange(v.shape[1]) * blocks) // v.shape[1], blocks - 1)
    prof = np.full((blocks, len(centres)), np.nan)
    v0 = np.full(blocks, np.nan)
    sig = np.full(blocks, np.nan)
    for b in range(blocks):
        m = ok & (frame_block == b)[None, :]
        xs, vs = xm[m], v[m]
        k = np.digitize(xs, edges) - 1
        for j in range(len(centres)):
            if np.any(k == j):
                prof[b, j] = vs[k == j].mean()
        c = np.abs(xs) < 1.0
        v0[b] = vs[c].mean() if c.any() else np.nan
        sig[b] = math.sqrt((vs * xs**2).sum() / vs.sum()) if vs.sum() > 0 else np.nan
    counts = np.isfinite(prof).sum(axis=0)
    mean = np.array([np.nanmean(c) if n else np.nan for c, n in zip(prof.T, counts)])
    err = np.array([np.nanstd(c, ddof=1) / math.sqrt(n) if n > 1 else np.nan
                    for c, n in zip(prof.T, counts)])
    return {"x": centres.tolist(), "v": mean.tolist(), "v_err": err.tolist(),
            "v0": _block_stats(v0), "sigma": _block_stats(sig)}


def centreline_variance(pos, band, blocks, half_width=1.5):
    """Var(dx) and mean fall over lags for grains starting on the centreline in ``band``."""
    nframes = pos.shape[1]
    out = []
    for lag in LAGS:
        if lag >= nframes:
            break
        x0, y0 = pos[:, :-lag, 0], pos[:, :-lag, 1]
        dx, dy = pos[:, lag:, 0] - x0, pos[:, lag:, 1] - y0
        ok = (np.isfinite(dx) & (np.abs(x0) < half_width) & (y0 > band[0]) & (y0 < band[1])
              & (pos[:, lag:, 1] > 0))
        frame_block = np.minimum((np.arange(dx.shape[1]) * blocks) // dx.shape[1], blocks - 1)
        var = np.full(blocks, np.nan)
        fall = np.full(blocks, np.nan)
        for b in range(blocks):
            m = ok & (frame_block == b)[None, :]
            if m.sum() > 2:
                var[b], fall[b] = dx[m].var(), -dy[m].mean()
        out.append({"lag_frames": lag, "var_dx": _block_stats(var), "fall": _block_stats(fall),
                    "samples": int(ok.sum())})
    return out


def measure(run: Path, heights, band, blocks, window: float | None = None) -> dict:
    prov = json.loads((run / "provenance.json").read_text())
    p = prov["params"]
    if p["silo"]["dims"] != 2:
        raise ValueError(f"run: {run} is a 3D run; measures.py reads 2D runs")
    frames = dump.read(run / "tracks.dump.gz")
    if window:
        frames = [f for f in frames if f.step * p["time"]["step"] <= window + 1e-9]
    _, steps, pos, _ = dump.tracks(frames)
    times = steps * p["time"]["step"]
    res = {"run": str(run), "flow_rate": flow_rate(run, blocks, window),
           "profiles": {str(h): speed_profile(pos, times, p["silo"]["width"], h, blocks)
                        for h in heights},
           "centreline": centreline_variance(pos, band, blocks),
           "grains": prov["derived"]["grains"], "cpu_s": prov["timing"]["total_cpu_s"],
           "stiffness": p["contacts"]["stiffness"], "step": p["time"]["step"],
           "seed": p["run"]["seed"]}
    return res


def _fmt(v: tuple[float, float]) -> str:
    return f"{v[0]:.4g} +- {v[1]:.2g}"


def _dev(a, b) -> str:
    return f"{(b[0] - a[0]) / math.hypot(a[1], b[1]):+.1f}" if a[1] > 0 and b[1] > 0 else "nan"


def table(results: list[dict]) -> str:
    """Scalar measures of each run, and each run's deviation from the first in std errors."""
    rows = [("flow rate Q", lambda r: r["flow_rate"])]
    for h in results[0]["profiles"]:
        rows.append((f"v0 at h={h}", lambda r, h=h: r["profiles"][h]["v0"]))
        rows.append((f"sigma at h={h}", lambda r, h=h: r["profiles"][h]["sigma"]))
    for k, c in enumerate(results[0]["centreline"]):
        rows.append((f"Var dx, lag {c['lag_frames']}", lambda r, k=k: r["centreline"][k]["var_dx"]))
        rows.append((f"fall, lag {c['lag_frames']}", lambda r, k=k: r["centreline"][k]["fall"]))
    names = [Path(r["run"]).name for r in results]
    lines = ["| measure | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for label, get in rows:
        base = get(results[0])
        cells = [_fmt(base)] + [f"{_fmt(get(r))} ({_dev(base, get(r))})" for r in results[1:]]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="measures.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", help="run or dataset directories (2D)")
    ap.add_argument("--heights", type=float, nargs="+", default=[10.0, 40.0])
    ap.add_argument("--band", type=float, nargs=2, default=[20.0, 50.0],
                    help="heights between which centreline grains start")
    ap.add_argument("--blocks", type=int, default=10)
    ap.add_argument("--window", type=float,
                    help="use only the first WINDOW time units of each measuring window")
    ap.add_argument("--json", help="write all measures to this JSON file")
    args = ap.parse_args(argv)
    try:
        results = [measure(Path(r), args.heights, args.band, args.blocks, args.window)
                   for r in args.runs]
    except (OSError, ValueError) as exc:
        print(f"measures.py: {exc}", file=sys.stderr)
        return 2
    print(table(results))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
