"""Particle fields in a 2D wedge hopper: the staircase ``grid.active`` as the silo (private).

:func:`spotpde.fields.coefficients.particle_fields` calls :func:`particle_fields` for a
wedge geometry (``grid.geometry.kind == "wedge"``, a Cartesian grid with a hopper;
axisymmetric cones go to ``_axisymmetric``, which treats the staircase the same way).
The material is the staircase of active cells; the formulas are those of the
rectangular silo (docs/coefficients.md, docs/walls.md)::

    u_p = - w * ([rho_s u_s - 2 lam div(D_s rho_s)] / phi)
          + (1 - 2 lam) sum_faces w(r - s_f) (D_s rho_s).n / phi(s_f) h
    D_p =   w^2 * (rho_s T / phi^2)

with every source zero on inactive cells, ``div`` by second-order differences that never
cross a wall face (``grid.geometry.divergence``: one-sided next to an inactive
cell), ``phi`` the coverage of the material indicator ``chi = grid.active``
(``_walls.coverage`` with that mask: free volume is conserved at the inclined walls as at
flat ones) and the wall layer summed over the vertical wall faces of the staircase and
the reflecting box walls, and over the horizontal steps of the staircase: each face
carries ``(D_s rho_s).n / phi`` extrapolated to it from the active cells inward (third
order; ``phi`` cubic) and spreads it with ``w`` evaluated at the target's offset from the
face, averaged along the face (6 sub-samples, as ``_wall_layer`` does): one FFT
convolution of the face values per face orientation and component. Fields are
zero on inactive cells.
"""

from __future__ import annotations

import numpy as np

from . import _passage, _walls, convolution
from ._common import _SUBSAMPLE, _check_coefficient, _check_inputs, _Convolutions, spot_diffusivity
from ._common import _is_zero as _zero
from ._staircase import face_sources, passage_excess
from .._roundoff import clip_roundoff
from ..grid import DIFFUSIVITY_KEYS, DRIFT_KEYS, Grid
from ..parameters import drift_weight, wall_weight


def _face_stencil(grid: Grid, kernel, axis: int = 1) -> np.ndarray:
    """The push of one face on the cells around it, averaged along the face (6
    sub-samples; the normal offset exact). Vertical faces (``axis = 1``):
    ``S[dk, di] = h <w((di + 1/2) h, dk h - t)>_t`` on the cell ``di`` columns right of
    the face's right-hand cell; horizontal faces (``axis = 0``):
    ``S[dk, di] = h <w(di h - t, (dk + 1/2) h)>_t``."""
    h = grid.spacing
    rh, rz = kernel.reach
    M = int(np.ceil(rh / h)) + 1
    K = int(np.ceil(rz / h)) + 1
    di = np.arange(-M, M + 1)
    dk = np.arange(-K, K + 1)
    sub = (np.arange(_SUBSAMPLE) + 0.5) / _SUBSAMPLE - 0.5
    if axis == 1:
        z = dk[:, None] * h + sub[None, :] * h                        # (nk, sub)
        x = (di + 0.5) * h
        w = kernel.evaluate(x[None, None, :], z[:, :, None])          # (nk, sub, ni)
        return h * w.mean(axis=1)
    x = di[:, None] * h + sub[None, :] * h                            # (ni, sub)
    z = (dk + 0.5) * h
    w = kernel.evaluate(x[None, :, :], z[:, None, None])              # (nk, ni, sub)
    return h * w.mean(axis=2)


def add_wall_layer(grid: Grid, kernel, lam: float, G, phi, fields: dict) -> None:
    """``u += (1 - 2 lam) sum_faces w (D_s rho_s).n / phi h`` over the wall faces: the
    vertical ones (``G_xx``, ``G_xz``) and the staircase's horizontal steps (``G_xz``,
    ``G_zz``)."""
    if lam == 0.5:
        return
    nz, nx = grid.shape
    c = wall_weight(lam)
    geometry = grid.geometry
    for axis, faces in ((1, geometry.wall_faces()), (0, geometry.horizontal_faces())):
        if not faces:
            continue
        pushes = (("D_xx", "u_x"), ("D_xz", "u_z")) if axis == 1 else (("D_xz", "u_x"), ("D_zz", "u_z"))
        stencil = None
        for key, comp in pushes:
            g = G.get(key)
            if _zero(g):
                continue
            src = face_sources(grid, np.broadcast_to(np.asarray(g, dtype=float), grid.shape),
                               phi, faces, axis)
            if not np.any(src):
                continue
            if stencil is None:
                stencil = _face_stencil(grid, kernel, axis)
            out = convolution.convolve(src, stencil, mode="linear")
            fields[comp] = fields[comp] + c * (out[:, :nx] if axis == 1 else out[:nz])


def particle_fields(grid: Grid, rho_s, spots, kernel, lam, tensor, diffusivity, walls, mask):
    """The wedge-hopper fields (module docstring); arguments as ``particle_fields``."""
    rho_s = _check_inputs(grid, rho_s, kernel)
    _check_coefficient(grid, "spots.drift", spots.drift)
    act = grid.active
    rho = np.where(act, rho_s, 0.0)
    D_s = spot_diffusivity(grid, spots, tensor)
    v_s = spots.drift
    T = D_s
    if diffusivity == "passage":
        T = _passage.source_tensor(grid, spots, D_s, kernel, lam)
    renorm = _walls.check_walls(walls) == "renormalise"
    phi = _walls.coverage(grid, kernel, act.astype(float) if mask is None else mask) if renorm else None
    # sources vanish on inactive cells, where phi may be ~0
    inv = 1.0 if phi is None else np.where(act, 1.0 / np.where(act, phi, 1.0), 0.0)
    G = {k: None if _zero(d) else rho * d for k, d in D_s.items()}
    div = grid.geometry.divergence(G)
    conv = _Convolutions(grid, kernel)
    keys = {}
    keys["u_z"] = conv.request("u_z", -rho * v_s * inv + drift_weight(lam) * div["z"] * inv, 1)
    if lam != 0.0 and np.any(div["x"]):
        keys["u_x"] = conv.request("u_x", drift_weight(lam) * div["x"] * inv, 1)
    inv2 = inv * inv
    for key in DIFFUSIVITY_KEYS[2]:
        if not _zero(T[key]):
            keys[key] = conv.request(key, rho * T[key] * inv2, 2)
    if diffusivity == "passage":
        for key in ("D_xx", "D_zz"):
            t, d = T[key], D_s[key]
            if not (_zero(t) or _zero(d) or (np.ndim(t) == 0 and np.ndim(d) == 0)):
                keys["diff_" + key] = conv.request("diff_" + key, rho * (t - d) * inv2, 2)
    res = conv.run()
    fields = {k: res[keys[k]] if k in keys else np.zeros(grid.shape)
              for k in DRIFT_KEYS[2] + DIFFUSIVITY_KEYS[2]}
    if diffusivity == "passage":
        diff = passage_excess(T, D_s, fields, lambda key: res[keys["diff_" + key]],
                              ("D_xx", "D_zz"))
        dv = grid.geometry.divergence(diff)
        fields["u_x"] = fields["u_x"] + dv["x"]
        fields["u_z"] = fields["u_z"] + dv["z"]
    add_wall_layer(grid, kernel, lam, G, phi, fields)
    for k in ("D_xx", "D_zz"):
        fields[k] = clip_roundoff(fields[k])
    return {k: np.where(act, fields[k], 0.0) for k in DRIFT_KEYS[2] + DIFFUSIVITY_KEYS[2]}
