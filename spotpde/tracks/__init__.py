"""Measured particle trajectories in: experiments (trackpy), DEM (LAMMPS, LIGGGHTS) and
the project's own Monte Carlo, all in one layout (docs/calibration.md, section 1).

::

    import spotpde
    tracks = spotpde.tracks.read("tracks.csv", scale=12.5, fps=1000, origin=(400, 610),
                                 y_down=True)          # trackpy layout, pixels, image rows
    tracks = spotpde.tracks.read("silo.dump.gz", fps=1 / 1e-4)   # LAMMPS dump custom
    tracks.x, tracks.z             # (particle, t), in d, z up, orifice at the origin

The layout: an :class:`xarray.Dataset` with dims ``("particle", "t")``, variables ``x``,
``z`` (3D ``y``) in particle diameters, NaN where a particle is not tracked, ``id`` (the
source's particle id), optional ``diameter``; attributes ``source``, ``format``,
``scale``, ``fps``, ``origin``, ``y_down``. :func:`to_trackpy` writes tracks back out in
trackpy's layout (any scale, origin and image orientation).

Private modules: ``_read`` (the readers and the one transformation), ``_lammps`` (the
dump parser), ``_layout`` (building and checking the layout).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import xarray as xr

from ._layout import LAYOUT, check, make
from ._read import FORMATS, read

__all__ = ["read", "make", "check", "to_trackpy", "FORMATS", "LAYOUT"]


def to_trackpy(tracks: xr.Dataset, scale: float = 1.0, fps: float = 1.0,
               origin=(0.0, 0.0), y_down: bool = False) -> pd.DataFrame:
    """Tracks as a table in trackpy's layout: the inverse of :func:`read`'s transformation.

    Args:
        tracks: a tracks Dataset (2D or 3D).
        scale, fps, origin, y_down: as in :func:`read`; the frame numbers are
            ``round(t * fps)``, so ``t * fps`` must be (close to) integers.

    Returns:
        DataFrame with columns ``frame``, ``particle``, ``x``, ``y`` (3D ``z`` = depth),
        one row per tracked particle and frame, sorted by frame.

    Raises:
        ValueError: times that are not whole frames at ``fps``.
    """
    tracks = check(tracks)
    frames = np.asarray(tracks["t"].values, float) * fps
    if not np.allclose(frames, np.round(frames), rtol=0, atol=1e-6 * max(1.0, np.abs(frames).max())):
        raise ValueError(f"fps: t * fps must be whole frame numbers, got t * fps = {frames[:3]}...")
    frames = np.round(frames).astype(np.int64)
    x = tracks["x"].values * scale + origin[0]
    v = tracks["z"].values * scale
    v = (origin[1] - v) if y_down else (origin[1] + v)
    ok = np.isfinite(x) & np.isfinite(v)
    p_index, t_index = np.nonzero(ok)
    out = {"frame": frames[t_index], "particle": tracks["particle"].values[p_index],
           "x": x[ok], "y": v[ok]}
    if "y" in tracks:
        out["z"] = tracks["y"].values[ok] * scale + (origin[2] if len(origin) == 3 else 0.0)
    if "diameter" in tracks:
        out["diameter"] = tracks["diameter"].values[p_index] * scale
    return pd.DataFrame(out).sort_values(["frame", "particle"], kind="stable").reset_index(drop=True)
