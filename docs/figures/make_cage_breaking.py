"""Survival of a caged pair for the paper's disk (docs/pair.md): python make_cage_breaking.py"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from spotpde import pair  # noqa: E402
from spotpde.fields.kernels import Uniform  # noqa: E402

disk = Uniform(radius=2.5, height=0.0024)
fig, ax = plt.subplots(1, 2, figsize=(9, 3.4))
for b_par in (0.0, 0.6, 1.3):
    ds = pair.cage_breaking(disk, 1.3, b_par=b_par, diffusivity="mean-field")
    ax[0].plot(ds["fall"], ds["survival"],
               label=f"b_par = {b_par} d: mean {ds.attrs['mean_fall']:.0f} d")
ax[0].axvline(200, color="k", ls=":", lw=1, label="experiment ~ 200 d")
ax[0].set(xlabel="fall (d)", ylabel="still caged", title="paper's disk, mean field")
ax[0].legend(fontsize=8)
ds = pair.cage_breaking(disk, 1.3, b_par=0.6, diffusivity="mean-field", frames=4)
im = ax[1].pcolormesh(ds["X"], ds["Z"], ds["P"].isel(frame=1), shading="nearest")
ax[1].set(aspect="equal", xlabel="X (d)", ylabel="Z (d)",
          title=f"P at fall {float(ds['frame'][1]):.0f} d")
fig.colorbar(im, ax=ax[1])
fig.tight_layout()
fig.savefig(Path(__file__).with_name("cage_breaking.png"), dpi=90)
