"""Subsample a silo run's tracks into a dataset small enough to commit.

    python validation/dem/subsample.py RUNDIR -o DATADIR [--fraction 0.15] [--seed 0]

Keeps whole tracks (every frame of the measuring window) of a subset of the grains,
chosen in small clusters so that touching pairs and close neighbours stay available
(pair separation, velocity correlations), with the same inclusion probability for every
grain wherever it is and however many neighbours it has, so that the kept grains sample
the flow without bias (mean flow, diffusion). Each grain is decided once, at its
*decision frame*: the first frame for the grains present then; grains reinserted later
are decided in batches (all those first seen within ``--batch`` time units), ``--landed``
time units after the batch ends, when they rest on the free surface. At each decision
frame, cluster centres are drawn as a Poisson process in the plane (space, in 3D) at
density ``lambda``, and a grain being decided is kept if a centre lies within
``--reach`` d of it: probability ``1 - exp(-lambda pi reach^2)`` (2D), set to
``--fraction``.

Writes DATADIR/tracks.dump.gz (same ``dump custom`` layout), exits.txt and params.toml
(copies), and provenance.json: the run's provenance (its ``files`` are the run
directory's) plus a ``subsample`` entry with the exact command, the method, counts,
sizes, the files written and the SHA-256 of the tracks file.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import shlex
import shutil
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, os.fspath(Path(__file__).resolve().parent))
import _git  # noqa: E402
import lammps_dump as dump  # noqa: E402


def decision_frames(present: np.ndarray, batch: int, landed: int) -> np.ndarray:
    """Frame at which each particle (row of ``present``, (particle, frame) bool) is decided."""
    first = np.argmax(present, axis=1)
    last = present.shape[1] - 1 - np.argmax(present[:, ::-1], axis=1)
    later = np.minimum((first // batch + 1) * batch - 1 + landed, last)
    return np.where(first == 0, 0, np.maximum(later, first))


def select(pos, decide, fraction, reach, rng) -> np.ndarray:
    """Kept particles: those within ``reach`` of a Poisson cluster centre at their decision frame.

    ``pos`` (particle, frame, dims) holds the coordinates that count (x, vertical in 2D).
    Centres are drawn in the box of the decided grains widened by ``reach``, so every
    grain has the same probability ``fraction`` of being kept.
    """
    dims = pos.shape[2]
    keep = np.zeros(pos.shape[0], dtype=bool)
    if fraction >= 1.0:
        return ~keep
    ball = math.pi * reach**2 if dims == 2 else 4.0 / 3.0 * math.pi * reach**3
    density = -math.log(1.0 - fraction) / ball
    for k in np.unique(decide):
        idx = np.flatnonzero(decide == k)
        here = pos[idx, k]
        lo, hi = here.min(axis=0) - reach, here.max(axis=0) + reach
        centres = rng.uniform(lo, hi, size=(rng.poisson(density * np.prod(hi - lo)), dims))
        if len(centres):
            dist, _ = cKDTree(centres).query(here)
            keep[idx[dist < reach]] = True
    return keep


def subsample(run: Path, fraction: float, seed: int, batch: float, landed: float,
              reach: float):
    """The kept frames and a summary of the selection."""
    frames = dump.read(run / "tracks.dump.gz")
    prov = json.loads((run / "provenance.json").read_text())
    dt_out = prov["params"]["time"]["output"]
    coords = [0, 1] if prov["params"]["silo"]["dims"] == 2 else [0, 1, 2]
    ids, steps, pos, radius = dump.tracks(frames)
    present = ~np.isnan(pos[..., 0])
    decide = decision_frames(present, max(1, round(batch / dt_out)), round(landed / dt_out))
    keep = select(pos[..., coords], decide, fraction, reach, np.random.default_rng(seed))
    lines = present.sum(axis=1)
    kept_ids = ids[keep]
    out = []
    for fr in frames:
        m = np.isin(fr.ids, kept_ids)
        out.append(dump.Frame(fr.step, fr.box_header, fr.ids[m], fr.data[m]))
    summary = {
        "git": _git.state("subsample.py", "lammps_dump.py"),
        "method": ("Poisson clusters: each grain decided once (at the first frame, or in "
                   "batches of --batch time units of reinsertion, --landed after the batch); "
                   "kept if a cluster centre (Poisson, density set by --fraction) lies within "
                   "--reach of it at that frame; whole tracks kept"),
        "inclusion_probability": fraction,
        "fraction_of_lines": round(float(lines[keep].sum() / lines.sum()), 5),
        "particles_kept": int(keep.sum()), "particles_in_run": len(ids),
        "frames": len(frames), "lines_kept": int(lines[keep].sum()),
        "batch": batch, "landed": landed, "reach": reach, "seed": seed,
    }
    return out, prov, summary


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(prog="subsample.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="run directory written by silo.py")
    ap.add_argument("-o", "--out", required=True, help="dataset directory (new or empty)")
    ap.add_argument("--fraction", type=float, default=0.15,
                    help="probability that a grain is kept")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--batch", type=float, default=20.0,
                    help="reinserted grains are decided in batches of this duration")
    ap.add_argument("--landed", type=float, default=10.0,
                    help="time after a batch at which its grains are decided")
    ap.add_argument("--reach", type=float, default=1.5,
                    help="radius of a cluster around its centre, in d")
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
    frames, prov, summary = subsample(run, args.fraction, args.seed, args.batch,
                                         args.landed, args.reach)
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
