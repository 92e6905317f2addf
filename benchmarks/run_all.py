"""All of spotpde's performance figures in one table (issue 8).

Runs, each in a fresh subprocess so that one measurement does not warm another:

* ``convolution.py``: the engine against ``scipy.signal.fftconvolve`` at 1024^2, for a
  full-domain and a cut (support-sized) kernel (ratio = fftconvolve time / ours);
* ``fields.py``: all fields of a 1024^2 case against the plain SciPy implementation
  (ratio = ours / SciPy, target <= 0.5);
* ``tracer.py``: throughput of the tracer right-hand side at 1024^2 against a plain
  numba 5-point Laplacian pass on the same grid;
* peak memory (``resource.getrusage(RUSAGE_SELF).ru_maxrss`` of a fresh process) of a
  1024^2 case with a tracer and 20 frames, twice: ``spotpde.run(case)`` holding the frames
  in memory and then writing the file, and ``spotpde.run(case, path=...)``, which streams
  the frames to the file as ``spotpde run`` does;
* how the time of the fields (spot density, u_p, D_p, v_kin) grows with the grid from
  256^2 to 2048^2 cells: the fitted exponent of time against the number of cells N
  (N log N gives slightly above 1).

Usage::

    python benchmarks/run_all.py [--quick]

``--quick`` skips the largest sizes (for a smoke test). Every ratio is between two codes
measured in the same run on the same machine; absolute times depend on the machine's load.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

HERE = Path(__file__).resolve().parent


def run_script(name: str, *args: str) -> str:
    """Run a benchmark script with this interpreter; return its standard output."""
    out = subprocess.run([sys.executable, str(HERE / name), *args], check=True,
                         capture_output=True, text=True)
    return out.stdout


def run_snippet(code: str) -> dict:
    """Run Python code in a fresh process; it prints one JSON line, returned as a dict."""
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def convolution_figures() -> list[tuple[str, str, str]]:
    text = run_script("convolution.py")
    rows = []
    for line in text.splitlines():
        m = re.match(r"\s*(1024x1024)\s+(full-domain|cut \(support\))\s+\S+\s+([\d.]+)\s+([\d.]+)"
                     r"\s+([\d.]+)", line)
        if m:
            target = "3.5" if m.group(2) == "full-domain" else "2"
            rows.append((f"convolution 1024^2, {m.group(2)} kernel: fftconvolve / spotpde",
                         f"{float(m.group(5)):.2f}x", f">= {target}x"))
    return rows


def fields_figures() -> list[tuple[str, str, str]]:
    text = run_script("fields.py", "--n", "1024", "--repeat", "3")
    m = re.search(r"ratio spotpde / scipy = ([\d.]+)", text)
    return [("fields of a 1024^2 case: spotpde / SciPy reference", m.group(1) if m else "?",
             "<= 0.5")]


def tracer_figures() -> list[tuple[str, str, str]]:
    text = run_script("tracer.py", "--sizes", "512", "1024", "--repeat", "5")
    rows = []
    for line in text.splitlines():
        parts = line.split()
        if len(parts) == 8 and parts[0] in ("512", "1024") and parts[2] in ("koren", "weno5"):
            n, threads, scheme, lap, rhs, _, ratio, _ = parts
            rows.append((f"tracer rhs {n}^2, {scheme}, {threads} thread(s): Mcell/s "
                         f"(x slower than 5-point Laplacian at {lap} Mcell/s)",
                         f"{rhs} ({ratio}x)", ">= 100 Mcell/s" if scheme == "koren" else ""))
    return rows


MEMORY_CASE = """
    import json, resource, tempfile, os
    import spotpde
    from spotpde.app.io import write_netcdf
    case = spotpde.load_case({
        "domain": {"dims": 2, "x": [-64.0, 64.0], "z": [0.0, 128.0], "spacing": 0.125},
        "orifice": {"width": 4.0, "rate": 21.22},
        "spots": {"b": 1.3},
        "kernel": {"shape": "uniform", "size": 2.5, "height": 0.0024},
        "tracer": {"layers": {"spacing": 8.0}, "t_end": 20.0, "frames": 20},
    })
    path = os.path.join(tempfile.mkdtemp(), "memory.nc")
    if STREAM:
        ds = spotpde.run(case, path=path)
    else:
        ds = spotpde.run(case)
        write_netcdf(ds, path)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps({"peak": peak, "cells": int(ds.sizes["z"] * ds.sizes["x"]),
                      "frames": int(ds.sizes["t"]), "file": os.path.getsize(path)}))
"""

SCALING = """
    import json, time
    import numpy as np
    import spotpde
    def case(n):
        half = n * 0.125 / 2
        return spotpde.load_case({
            "domain": {"dims": 2, "x": [-half, half], "z": [0.0, 2 * half], "spacing": 0.125},
            "orifice": {"width": 4.0}, "spots": {"b": 1.3},
            "kernel": {"shape": "uniform", "size": 2.5, "height": 0.0024}})
    spotpde.run(case(128))                        # JIT compilation, imports
    times = {}
    for n in SIZES:
        c = case(n)
        spotpde.run(c)                            # FFTW plans for this shape
        best = np.inf
        for _ in range(2):
            t0 = time.perf_counter(); spotpde.run(c); best = min(best, time.perf_counter() - t0)
        times[n] = best
    print(json.dumps(times))
"""


def memory_figures() -> list[tuple[str, str, str]]:
    rows = []
    for stream, how in ((False, "frames in memory"), (True, "frames streamed, as spotpde run")):
        r = run_snippet(MEMORY_CASE.replace("STREAM", repr(stream)))
        rows.append((f"peak memory, {r['cells']} cells, tracer with {r['frames']} frames, {how}",
                     f"{r['peak'] / 2**20:.0f} MiB", "< 1024 MiB"))
    return rows


def scaling_figures(sizes) -> list[tuple[str, str, str]]:
    import numpy as np

    times = run_snippet(SCALING.replace("SIZES", repr(list(sizes))))
    n = np.array([int(k) for k in times]) ** 2
    t = np.array(list(times.values()))
    slope = np.polyfit(np.log(n), np.log(t), 1)[0]
    rows = [(f"fields of a {int(k)}^2 case", f"{v:.3f} s", "") for k, v in times.items()]
    rows.append(("fitted exponent of time against cells N", f"{slope:.2f}",
                 "~1 (N log N)"))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="skip the largest sizes")
    args = parser.parse_args()
    print(f"spotpde benchmarks; cores: {os.cpu_count()}, load average: {os.getloadavg()[0]:.2f}",
          flush=True)
    rows = []
    steps = [convolution_figures, fields_figures, tracer_figures, memory_figures,
             lambda: scaling_figures((256, 512) if args.quick else (256, 512, 1024, 2048))]
    for step in steps:
        for row in step():
            rows.append(row)
            print(f"  {row[0]}: {row[1]}", flush=True)
    width = max(len(r[0]) for r in rows)
    print()
    print(f"| {'figure':<{width}} | {'measured':>16} | {'target':>16} |")
    print(f"|{'-' * (width + 2)}|{'-' * 18}|{'-' * 18}|")
    for name, value, target in rows:
        print(f"| {name:<{width}} | {value:>16} | {target:>16} |")
    print(f"\nload average at the end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
