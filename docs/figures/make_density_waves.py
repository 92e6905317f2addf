"""Space-time diagrams of interacting spots: ``docs/figures/density_waves.png``.

Runs the two shipped cases as they are, ``cases/waves_wide.toml`` (4 d slot in a 40 d
box, rho below rho_c: waves rise, shocks on their backs) and ``cases/waves_narrow.toml``
(8 d box, capacity drop above z = 30 d: a compaction front runs down), and draws the
free-volume fraction ``w * rho_s`` on the axis against time and height
(:func:`spotpde.traffic.plot_space_time`).

    python docs/figures/make_density_waves.py          # ~1 min

Prints the rates and mass budgets of both runs.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import spotpde  # noqa: E402
from spotpde.density import traffic  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def main() -> None:
    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    for ax, name, title in zip(axes, ("waves_wide", "waves_narrow"),
                               ("wide channel: waves rise (rho < rho_c)",
                                "narrow channel, capacity drop at z = 30-35 d: "
                                "compaction front runs down")):
        ds = spotpde.run(spotpde.load_case(ROOT / "cases" / f"{name}.toml"))
        traffic.plot_space_time(ds, ax=ax)
        ax.set_title(title, fontsize=9)
        a = ds.attrs
        print(f"{name}: injected {a['injected_total']:.2f} of {a['requested_total']:.2f} asked "
              f"for, outflow {a['outflow_total']:.2f}, mass budget error "
              f"{a['mass_budget_error']:.1e}")
    out = ROOT / "docs" / "figures" / "density_waves.png"
    fig.savefig(out, dpi=80, bbox_inches="tight")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
