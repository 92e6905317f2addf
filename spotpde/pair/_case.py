"""The ``[pair]`` table of a case: cage breaking at a point of the flow (docs/pair.md).

Public through :mod:`spotpde.pair` (``add_to_result``, ``local_lengths``).
"""

from __future__ import annotations

import math

import numpy as np

from ._solver import cage_breaking
from ..errors import NumericalError
from ..fields.kernels import Uniform


def local_lengths(ds, x, z) -> dict:
    """Single-particle diffusion lengths per unit fall ``D_p^ab / |u_z|`` at ``(x, z)``.

    Bilinear interpolation of a result's ``D_xx``, ``D_xz``, ``D_zz`` and ``u_z`` (an
    axisymmetric result's ``D_rr``, ``D_rz``, ``D_zz`` at ``(r, z) = (x, z)``, returned
    under the same keys ``xx``, ``xz``, ``zz``).

    Raises:
        spotpde.NumericalError: the particles do not fall there (``u_z >= 0``).
    """

    h = "r" if "r" in ds.dims else "x"
    names = {"xx": f"D_{h}{h}", "xz": f"D_{h}z", "zz": "D_zz"}
    at = ds[[*names.values(), "u_z"]].interp({h: _radius(ds, x), "z": float(z)})
    speed = -float(at["u_z"])
    if not speed > 0 or not math.isfinite(speed):
        raise NumericalError(f"pair: the particles do not fall at ({h}, z) = ({x}, {z}) "
                             f"(u_z = {-speed:g}); move pair.x, pair.z into the flow")
    return {k: float(at[name]) / speed for k, name in names.items()}


def _radius(ds, x) -> float:
    """``x`` itself, or in a cylinder the radius held within the ring centres (the fields
    are even across the axis and flat to the wall within half a cell)."""
    if "r" not in ds.dims:
        return float(x)
    r = ds["r"].values
    return float(np.clip(float(x), r[0], r[-1]))


def add_to_result(case, ds):
    """The ``[pair]`` table of a case: cage breaking at ``(pair.x, pair.z)``, added to ``ds``.

    Local uniform-flow approximation: the pair sees the flow at the point as uniform, with
    the single-particle lengths ``b_p = D_p / |u_z|`` of the case's fields there (so
    ``B = 2 b_p (1 - C)`` in mean field, a full tensor where ``D_xz != 0``; the passage
    tensor is rescaled by the ratios of the local ``b_p`` to its uniform-flow value,
    ``relative_tensor``). Variables get the prefix ``pair_`` (dims ``pair_fall``,
    ``pair_frame``, ``pair_Z``, ``pair_X``), attributes too (``pair_mean_fall``, ...).
    In a cylinder (``(pair.x, pair.z)`` is ``(r, z)``) the pair is 3D: :func:`_cylinder_pair`.
    """

    p = case.pair
    b_p = local_lengths(ds, p.x, p.z)
    dims = case.grid.geometry.kernel_dims
    if case.model == "void":                         # one particle per void: C = 0 beyond d
        kernel = Uniform(radius=0.5, height=1.0, dims=dims)
    else:
        kernel = case.kernel
    diffusivity, dropped = case.diffusivity, 0.0
    if dims == 3:    # a cylinder: the 3D pair, reduced about the vertical (_cylinder_pair)
        diffusivity, b_p, dropped = _cylinder_pair(b_p)

    def at_point(v):
        a = np.asarray(v, dtype=float)
        if a.ndim == 0:
            return float(a)
        return float(ds["rho_s"].copy(data=a.reshape(ds["rho_s"].shape))
                     .interp({"r" if "r" in ds.dims else "x": _radius(ds, p.x),
                              "z": p.z}))

    b = at_point(case.spots.b)
    b_par = at_point(case.spots.b_par)

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
    if dims == 3:
        out.attrs.update({"pair_b_p_xz": dropped, "pair_relative_tensor": "mean-field"})
    return out


def _cylinder_pair(b_p: dict) -> tuple[str, dict, float]:
    """``(diffusivity, b_p, b_p_rz)`` of the pair in a cylinder (docs/pair.md section 4).

    The pair solver reduces a 3D pair about the vertical, which needs a relative tensor
    isotropic horizontally and without a mixed term: ``B = 2 b_p (1 - C(r))`` with the
    local ``b_p^rr`` (``= b_p^theta theta``) and ``b_p^zz`` (the mean-field form; the
    discrete model's passage pair tensor exists in 2D only). The local ``b_p^rz``, zero on
    the axis by symmetry, is left out and returned (recorded as ``pair_b_p_xz``).
    """
    return "mean-field", {"xx": b_p["xx"], "xz": 0.0, "zz": b_p["zz"]}, b_p["xz"]
