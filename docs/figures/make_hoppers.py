"""Layered silos with hoppers: a cylinder with a 30 degree cone (axisymmetric, the whole
section through the axis shown, mirrored) and a quasi-2D silo with a 30 degree wedge.

Runs ``cases/cylinder_hopper.toml`` and ``cases/wedge_hopper.toml`` as they are and
writes ``docs/figures/hoppers.png``: the coloured layers at three times for each, and the
downward speed across the hopper at two heights against radial flow toward the apex.

    python docs/figures/make_hoppers.py          # about a minute

Prints the numbers it puts on the figure.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import spotpde  # noqa: E402
from spotpde.app.plotting import midplane, plot_layers  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = Path(__file__).resolve().parent / "hoppers.png"


def radial_speed(ds, case, z):
    """Downward speed of radial flow toward the apex, with the run's flux, at height z
    on the section's x (2D wedge: Q / (2 theta rho); cone: Q / (2 pi (1 - cos theta) rho^2))."""
    m = midplane(ds)
    th = np.radians(case.grid.hopper.angle)
    za = -case.grid.hopper.half_width / np.tan(th)
    x = m.x.values
    rho = np.hypot(x, z - za)
    Q = ds.attrs["V1"] * case.orifice.rate_at(0.0)
    if case.grid.axisymmetric:
        speed = Q / (2 * np.pi * (1 - np.cos(th)) * rho**2)
    else:
        speed = Q / (2 * th * rho)
    inside = np.abs(x) <= case.grid.hopper.half_width_at(z)
    return x, np.where(inside, speed * (z - za) / rho, np.nan)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", default=str(OUT))
    args = ap.parse_args(argv)
    runs = []
    for name in ("cylinder_hopper", "wedge_hopper"):
        case = spotpde.load_case(ROOT / "cases" / f"{name}.toml")
        t0 = time.perf_counter()
        ds = spotpde.run(case)
        print(f"{name}: {time.perf_counter() - t0:.1f} s, mass + outflow - 1 = "
              f"{float(np.max(np.abs(ds.mass + ds.outflow - 1))):.1e}")
        runs.append((name, case, ds))
    fig, axes = plt.subplots(2, 4, figsize=(17, 9.5), layout="constrained",
                             gridspec_kw={"width_ratios": [1, 1, 1, 1.25]})
    for row, (name, case, ds) in zip(axes, runs):
        nt = ds.sizes["t"]
        for ax, frame in zip(row[:3], (0, nt // 2, nt - 1)):
            plot_layers(ds, ax, frame)
        kind = "cylinder, 30° cone (section through the axis)" if case.grid.axisymmetric \
            else "quasi-2D silo, 30° wedge"
        row[0].set_title(f"{kind}\nt = 0", fontsize=10)
        m = midplane(ds)
        for i, z in enumerate((6.0, 15.0)):
            line = m.sel(z=z, method="nearest")
            zz = float(line.z)
            x, rad = radial_speed(ds, case, zz)
            row[3].plot(line.x, -line.u_z, color=f"C{i}", label=f"spot model, z = {zz:.2f} d")
            row[3].plot(x, rad, "--", color=f"C{i}", lw=1, label=f"radial flow, z = {zz:.2f} d")
            dev = np.nanmax(np.abs(-line.u_z.values - rad)) / np.nanmax(rad)
            print(f"{name}: z = {zz:.2f} d, max |spot - radial| / max radial = {dev:.3f}")
        row[3].set(xlabel="x (d)", ylabel="downward speed (d per time unit)",
                   title="speed across the hopper")
        row[3].legend(fontsize=8)
        row[3].grid(alpha=0.3)
    fig.suptitle("spotpde: layered silos with hoppers (spot model, the paper's spot, "
                 "b = 1.3 d, rule 1/2)", fontsize=12)
    fig.savefig(args.output, dpi=80)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
