"""The ``[pair]`` table of a case: cage breaking at a point of the flow (docs/pair.md).

Public through :mod:`spotpde.pair` (``add_to_result``, ``local_lengths``).
"""

from __future__ import annotations

import math

import numpy as np


def local_lengths(ds, x, z) -> dict:
    """Single-particle diffusion lengths per unit fall ``D_p^ab / |u_z|`` at ``(x, z)``.

    Bilinear interpolation of a result's ``D_xx``, ``D_xz``, ``D_zz`` and ``u_z``.

    Raises:
        spotpde.NumericalError: the particles do not fall there (``u_z >= 0``).
    """
    from ..errors import NumericalError

    at = ds[["D_xx", "D_xz", "D_zz", "u_z"]].interp(x=float(x), z=float(z))
    speed = -float(at["u_z"])
    if not speed > 0 or not math.isfinite(speed):
        raise NumericalError(f"pair: the particles do not fall at (x, z) = ({x}, {z}) "
                             f"(u_z = {-speed:g}); move pair.x, pair.z into the flow")
    return {k: float(at[f"D_{k}"]) / speed for k in ("xx", "xz", "zz")}


def add_to_result(case, ds):
    """The ``[pair]`` table of a case: cage breaking at ``(pair.x, pair.z)``, added to ``ds``.

    Local uniform-flow approximation: the pair sees the flow at the point as uniform, with
    the single-particle lengths ``b_p = D_p / |u_z|`` of the case's fields there (so
    ``B = 2 b_p (1 - C)`` in mean field, a full tensor where ``D_xz != 0``; the passage
    tensor is rescaled by the ratios of the local ``b_p`` to its uniform-flow value,
    ``relative_tensor``). Variables get the prefix ``pair_`` (dims ``pair_fall``,
    ``pair_frame``, ``pair_Z``, ``pair_X``), attributes too (``pair_mean_fall``, ...).
    """
    from ..fields.kernels import Uniform

    p = case.pair
    b_p = local_lengths(ds, p.x, p.z)
    if case.model == "void":
        kernel = Uniform(radius=0.5, height=1.0)     # one particle per void: C = 0 beyond d
    else:
        kernel = case.kernel

    def at_point(v):
        a = np.asarray(v, dtype=float)
        if a.ndim == 0:
            return float(a)
        return float(ds["rho_s"].copy(data=a.reshape(ds["rho_s"].shape))
                     .interp(x=p.x, z=p.z))

    b = at_point(case.spots.b)
    b_par = at_point(case.spots.b_par)
    diffusivity = case.diffusivity
    from ..pair import cage_breaking

    res = cage_breaking(kernel, b, rule=case.rule, b_par=b_par, diffusivity=diffusivity,
                        contact=p.contact, separation=p.separation, start=p.start,
                        spacing=p.spacing, frames=p.frames, b_p=b_p)
    names = {n: f"pair_{n}" for n in list(res.data_vars) + list(res.coords)}
    res = res.rename(names)
    out = ds.merge(res)
    out.attrs = dict(ds.attrs)
    out.attrs.update({f"pair_{k}": v for k, v in res.attrs.items()})
    out.attrs.update({"pair_x": float(p.x), "pair_z": float(p.z),
                      **{f"pair_b_p_{k}": v for k, v in b_p.items()}})
    return out
