"""Subsample a silo run's tracks into a dataset small enough to commit.

    python validation/dem/subsample.py RUNDIR -o DATADIR [--fraction 0.1] [--seed 0]

Keeps whole tracks (every frame of the measuring window) of a subset of the grains,
chosen in small clusters so that touching pairs and close neighbours stay available
(pair separation, velocity correlations) while the clusters sample the silo uniformly
(mean flow, diffusion). Each grain id is decided once, at its *decision frame*: the
first frame for grains present then, otherwise ``--landed`` time units after the grain
first appears (reinserted grains have then landed on the free surface). With
probability ``q`` it is a cluster seed, and a seed brings in every grain touching it at
that frame (gap below ``--contact`` d). ``q`` is tuned so that the kept lines are
about ``--fraction`` of the run's.

Writes DATADIR/tracks.dump.gz (same ``dump custom`` layout), exits.txt and params.toml
(copies), and provenance.json: the run's provenance (its ``files`` are the run
directory's) plus a ``subsample`` entry with the exact command, the method, counts,
sizes, the files written and the SHA-256 of the tracks file.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shlex
import shutil
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, os.fspath(Path(__file__).resolve().parent))
import lammps_dump as dump  # noqa: E402


def decision_frames(present: np.ndarray, landed_frames: int) -> np.ndarray:
    """Frame at which each particle (row of ``present``, (particle, frame) bool) is decided."""
    first = np.argmax(present, axis=1)
    last = present.shape[1] - 1 - np.argmax(present[:, ::-1], axis=1)
    return np.where(first == 0, 0, np.minimum(first + landed_frames, last))


def select(pos, radius, present, decide, q, contact, rng) -> np.ndarray:
    """Boolean mask of kept particles: seeds (probability ``q``) and the grains touching them."""
    keep = np.zeros(len(radius), dtype=bool)
    seeds = rng.random(len(radius)) < q
    for k in np.unique(decide[seeds]):
        here = present[:, k]
        idx = np.flatnonzero(here)
        tree = cKDTree(pos[idx, k])
        for s in np.flatnonzero(seeds & (decide == k)):
            keep[s] = True
            near = idx[tree.query_ball_point(pos[s, k], radius[s] + radius.max() + contact)]
            gap = np.linalg.norm(pos[near, k] - pos[s, k], axis=1) - radius[near] - radius[s]
            keep[near[gap < contact]] = True
    return keep


def subsample(run: Path, fraction: float, seed: int, landed: float, contact: float):
    """The kept frames and a summary of the selection."""
    frames = dump.read(run / "tracks.dump.gz")
    prov = json.loads((run / "provenance.json").read_text())
    dt_out = prov["params"]["time"]["output"]
    ids, steps, pos, radius = dump.tracks(frames)
    present = ~np.isnan(pos[..., 0])
    decide = decision_frames(present, int(round(landed / dt_out)))
    lines = present.sum(axis=1)
    q = fraction / 4.0
    for _ in range(3):                                     # tune q to the wanted fraction
        keep = select(pos, radius, present, decide, q, contact, np.random.default_rng(seed))
        achieved, q_used = lines[keep].sum() / lines.sum(), q
        q = min(1.0, q * fraction / max(achieved, 1e-12))
    kept_ids = ids[keep]
    out = []
    for fr in frames:
        m = np.isin(fr.ids, kept_ids)
        out.append(dump.Frame(fr.step, fr.box_header, fr.ids[m], fr.data[m]))
    summary = {
        "method": ("clusters: each id decided once (first frame, or --landed after it first "
                   "appears); a seed with probability q keeps itself and every grain whose "
                   "gap to it is below --contact at that frame; whole tracks kept"),
        "seed_probability": round(q_used, 6),
        "fraction_of_lines": round(float(achieved), 5),
        "particles_kept": int(keep.sum()), "particles_in_run": len(ids),
        "frames": len(frames), "lines_kept": int(lines[keep].sum()),
        "landed": landed, "contact": contact, "seed": seed,
    }
    return out, prov, summary


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(prog="subsample.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="run directory written by silo.py")
    ap.add_argument("-o", "--out", required=True, help="dataset directory (new or empty)")
    ap.add_argument("--fraction", type=float, default=0.1, help="fraction of lines kept")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--landed", type=float, default=10.0,
                    help="time after a grain is reinserted at which it is decided")
    ap.add_argument("--contact", type=float, default=0.1, help="gap counted as touching, in d")
    args = ap.parse_args(argv)
    run, out = Path(args.run), Path(args.out)
    if not 0 < args.fraction <= 1:
        print(f"subsample.py: --fraction: must be in (0, 1], got {args.fraction}",
              file=sys.stderr)
        return 2
    if not (run / "tracks.dump.gz").exists() or not (run / "provenance.json").exists():
        print(f"subsample.py: run: {run} has no tracks.dump.gz and provenance.json "
              "(a directory written by silo.py)", file=sys.stderr)
        return 2
    if out.exists() and any(out.iterdir()):
        print(f"subsample.py: --out: {out} exists and is not empty", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    frames, prov, summary = subsample(run, args.fraction, args.seed, args.landed, args.contact)
    dump.write(out / "tracks.dump.gz", frames)
    for name in ("exits.txt", "params.toml"):
        shutil.copyfile(run / name, out / name)
    data = (out / "tracks.dump.gz").read_bytes()
    summary.update({"command": shlex.join(["python", os.path.relpath(sys.argv[0]), *argv]),
                    "bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()})
    prov["subsample"] = summary
    summary["files"] = sorted(f.name for f in out.iterdir()) + ["provenance.json"]
    tmp = out / "provenance.json.tmp"
    tmp.write_text(json.dumps(prov, indent=1) + "\n")
    os.replace(tmp, out / "provenance.json")
    print(f"subsample.py: kept {summary['particles_kept']} of {summary['particles_in_run']} "
          f"grains ({summary['fraction_of_lines']:.3f} of the lines, {len(data)} bytes) -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
