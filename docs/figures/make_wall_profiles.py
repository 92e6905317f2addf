"""Wall velocity profiles before and after free-volume conservation at walls.

Left: the flagship case ``cases/quasi2d_layers.toml`` (40 d wide, 4 d slot, the paper's
disk R = 2.5 d, w = 0.0024, b = 1.3 d, rule 1/2): the downward particle speed
``-u_z`` next to the right wall at heights 18, 36 and 50 d, for ``kernel.walls =
"truncate"`` (the kernel beyond the wall displaces nothing), ``"renormalise"`` (the
default: a spot's influence divided by the fraction ``phi`` of its kernel inside the
silo) and the Kinematic Model ``v_kin`` (flux ``V1 Q0`` through every height). Right: a
silo 8 d wide (spacing d/8, same kernel and slot) at z = 30 d. Writes
``docs/figures/wall_profiles.png`` and prints the particle flux through the heights 6, 18,
36 and 50 d as a fraction of ``V1 Q0`` for both treatments (docs/walls.md).

    python docs/figures/make_wall_profiles.py        # ~10 s
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import spotpde  # noqa: E402
from spotpde.fields import coefficients
from spotpde.density import kinematic, spot_density  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
OUT = Path(__file__).resolve().parent / "wall_profiles.png"
HEIGHTS = (6.0, 18.0, 36.0, 50.0)


def fields(case):
    """rho_s, the particle fields for both treatments, and v_kin of a case."""
    g = case.grid
    rho = spot_density.solve(g, case.orifice, case.spots)
    out = {w: coefficients.particle_fields(g, rho, case.spots, case.kernel, rule=case.rule,
                                           walls=w) for w in ("truncate", "renormalise")}
    Q0 = float(case.orifice.rate)
    v_kin = kinematic.speed(g, case.orifice, float(case.spots.b)) * case.kernel.V1 * Q0
    return out, v_kin


def flux_table(name, case, out):
    g = case.grid
    norm = case.kernel.V1 * float(case.orifice.rate)
    print(f"{name}: particle flux -int u_z dx / (V1 Q0)")
    for w, f in out.items():
        flux = -f["u_z"].sum(axis=1) * g.spacing / norm
        cells = [flux[int(np.argmin(np.abs(g.z - z)))] for z in HEIGHTS]
        print(f"  {w:12s}" + "".join(f"  z={z:4.0f}: {c:.5f}" for z, c in zip(HEIGHTS, cells)))


def main():
    base = spotpde.load_case(ROOT / "cases" / "quasi2d_layers.toml")
    data = {k: (dict(v) if isinstance(v, dict) else v) for k, v in base.data.items()}
    data.pop("tracer", None)
    flag = spotpde.load_case(data)
    narrow = dict(data, domain=dict(data["domain"], x=[-4.0, 4.0], spacing=0.125))
    narrow = spotpde.load_case(narrow)

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), constrained_layout=True)
    styles = {"truncate": dict(ls="--"), "renormalise": dict(ls="-")}
    for ax, name, case, zs, xlim in (
            (axes[0], "flagship (40 d wide)", flag, (18.0, 36.0, 50.0), (8.0, 20.0)),
            (axes[1], "8 d wide silo", narrow, (30.0,), (-4.0, 4.0))):
        out, v_kin = fields(case)
        flux_table(name, case, out)
        g = case.grid
        for c, z in zip(("C0", "C1", "C2"), zs):
            k = int(np.argmin(np.abs(g.z - z)))
            for w, f in out.items():
                ax.plot(g.x, -f["u_z"][k], color=c, **styles[w],
                        label=f"z = {z:.0f} d, {w}")
            ax.plot(g.x, v_kin[k], color=c, ls=":", lw=2, label=f"z = {z:.0f} d, kinematic")
            near = np.argmin(np.abs(g.x - (g.x_range[1] - 0.5 * g.spacing)))
            print(f"  z = {z:.0f}: speed in the wall cell / v_kin: truncate "
                  f"{-out['truncate']['u_z'][k, near] / v_kin[k, near]:.3f}, renormalise "
                  f"{-out['renormalise']['u_z'][k, near] / v_kin[k, near]:.3f}")
        ax.set_xlim(*xlim)
        inside = (g.x >= xlim[0]) & (g.x <= xlim[1])
        rows = [int(np.argmin(np.abs(g.z - z))) for z in zs]
        top = max(max(float(np.max(-f["u_z"][k, inside])) for f in out.values())
                  for k in rows)
        ax.set_ylim(0.0, 1.15 * max(top, max(float(np.max(v_kin[k, inside])) for k in rows)))
        ax.axvline(g.x_range[1], color="k", lw=1)
        ax.set_xlabel("x (d)")
        ax.set_ylabel("downward particle speed (d per unit time)")
        ax.set_title(f"{name}: wall at x = {g.x_range[1]:.0f} d")
        ax.legend(fontsize=7, ncol=1)
    fig.savefig(OUT, dpi=90)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
