"""Particle drift and diffusivity on axisymmetric grids (cylindrical silos, cones; private).

:func:`spotpde.fields.coefficients.particle_fields` calls :func:`particle_fields` for the
ring geometries (``grid.geometry.kind`` ``"axisymmetric"`` or ``"cone"``). The fields
are those of the 3D spot model (docs/coefficients.md,
docs/walls.md) for an axisymmetric spot density ``rho_s(r, z)`` (spots per d**3) and a 3D
horizontally isotropic kernel, in cylindrical components::

    u_p = - w * ([rho_s u_s - 2 lam div(D_s rho_s)] / phi)
          + (1 - 2 lam) int_walls w(r - s_w) (D_s rho_s).n / phi dA
    D_p =   w^2 * (rho_s T / phi^2)        (T = D_s mean field, v_s b_eff passage)

``*`` is the 3D convolution over the silo, done with ring-integrated weights
(:mod:`spotpde.fields._rings`): ``m = 0`` weights for ``u_z``, ``D_rr``, ``D_zz`` (the
horizontal part of a horizontally isotropic tensor is a scalar times ``I_h``, so
``D_theta_theta = D_rr``) and ``m = 1`` weights for ``u_r`` and ``D_rz``. The divergence of
an axisymmetric tensor with ``T_tt = T_rr`` is
``(div T)_r = (1/r) d_r(r T_rr) + d_z T_rz - T_tt/r = d_r T_rr + d_z T_rz`` and
``(div T)_z = (1/r) d_r(r T_rz) + d_z T_zz`` (``grid.geometry.divergence``); derivatives
are second-order differences with the even continuation across the axis (``T_rr``,
``r T_rz``, ``T_zz`` are even in ``r``), one-sided at the outer wall, the floor, the top and next to inactive (hopper)
cells. Regular axis: ``u_r`` is an ``m = 1`` convolution, which vanishes like ``r``.

Walls: the cylinder wall ``r = a`` (reflecting) and, with a hopper, the faces between
active and inactive cells of ``grid.active`` (the staircase). ``phi`` is the ring
convolution of the material indicator ``chi`` (``grid.active``; zero beyond a reflecting
wall; continued beyond the floor and the top), summed over the target cells (so every
spot step displaces exactly ``V1 dR``). The wall layer sums over the vertical wall faces
(rings of radius ``r_f``) and the staircase's horizontal faces (annuli) with the
``m = 1`` (radial push) and ``m = 0`` (vertical push) face weights of ``_rings``.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from . import _passage, _rings, _walls
from ._common import _check_coefficient, _is_zero as _zero, spot_diffusivity
from ._staircase import face_sources, passage_excess
from .._roundoff import clip_roundoff
from ..grid import Grid
from ..parameters import drift_weight, wall_weight

KEYS = ("u_r", "u_z", "D_rr", "D_rz", "D_zz")


# -- coverage -------------------------------------------------------------------------------

def _transpose(W: np.ndarray) -> np.ndarray:
    """``WT[l, j, b] = W[l, j + b - mb, 2 mb - b]``: the weights of source ``j`` on target
    ``j + b - mb`` (zero where that target lies outside ``0 .. nx - 1``)."""
    nl, nx, nb = W.shape
    mb = (nb - 1) // 2
    i = np.arange(nx)[:, None] + np.arange(nb)[None, :] - mb
    ok = (i >= 0) & (i < nx)
    out = W[:, np.clip(i, 0, nx - 1), (nb - 1 - np.arange(nb))[None, :]]
    return np.where(ok[None], out, 0.0)


def coverage(grid: Grid, kernel, mask: np.ndarray | None = None) -> np.ndarray:
    """``phi_j``: the fraction of the particle volume a spot in cell ``j`` displaces that
    lies in the material, ``phi_j = sum_i V_i chi_i W0[i, j] / (V1 V_j)``.

    ``chi`` = ``mask`` (default ``grid.active``: 1 in the material), zero beyond a
    reflecting cylinder wall, continued beyond the floor and the top (edge values). The
    sum runs over the target cells ``i`` (volumes ``V_i``, the quadrature the particle
    flux uses) with the same ``m = 0`` ring weights as the fields, so that in the discrete
    sums every spot step displaces exactly ``V1 dR`` (docs/walls.md); ``phi`` differs
    from 1 by ~1e-8 where the kernel lies inside the material (the ring weights are
    reciprocal to second order only). With an open cylinder wall ``chi`` is continued
    outward and ``phi`` is the direct ring convolution of ``chi`` (no targets exist
    beyond ``r = a``).
    """
    h = grid.spacing
    nz, nx = grid.shape
    W = _rings.ring_weights(kernel, h, nx, 1, 0)
    mz, mb = (W.shape[0] - 1) // 2, (W.shape[2] - 1) // 2
    chi = np.asarray(grid.active if mask is None else mask, dtype=float)
    if chi.shape != grid.shape:
        raise ValueError(f"mask: array shape {chi.shape} does not match the grid shape "
                         f"{grid.shape} (array order {grid.axes})")
    if not np.all((chi >= 0.0) & (chi <= 1.0)):
        raise ValueError("mask: values must lie in [0, 1] (material fraction of a cell)")
    vol = grid.cell_volumes[0]
    padded = np.pad(chi, ((mz, mz), (0, 0)), mode="edge")
    if grid.walls == "reflecting":
        WT = _transpose(W)
        if not grid.geometry.masked and mask is None:
            phi_r = (WT.sum(axis=0) * np.pad(vol, mb)[np.arange(nx)[:, None] + np.arange(2 * mb + 1)]
                     ).sum(axis=1) / (kernel.V1 * vol)
            phi = np.broadcast_to(phi_r[None, :], grid.shape).copy()
        else:
            phi = _rings.ring_convolve([padded * vol[None, :]], WT)[0][mz:mz + nz] / (kernel.V1 * vol)
    else:
        extra = np.repeat(padded[:, -1:], max(mb, 1), axis=1)
        phi = _rings.ring_convolve([padded], W, beyond=extra)[0][mz:mz + nz] / kernel.V1
    inside = chi > 0
    if np.any(phi[inside] <= 1e-12):
        raise ValueError("mask: a material cell has no material within the kernel's reach")
    # no clip at 1: next to the axis the target sums exceed V1 by up to ~1e-3 h^2
    return np.maximum(phi, 1e-300)


# -- the wall layer --------------------------------------------------------------------------

def add_wall_layer(grid: Grid, kernel, lam: float, G: Mapping, phi, fields: dict) -> None:
    """``u += (1 - 2 lam) int_walls w (D_s rho_s).n / phi dA`` over the wall faces.

    A vertical face of cell ``j`` at radius ``r_f`` with outward normal ``+-e_r`` pushes
    with ``(G_rr e_r + G_rz e_z) (+-1) / phi``, a horizontal face (normal ``+-e_z``, the
    staircase's steps) with ``(G_rz e_r + G_zz e_z) (+-1) / phi`` (values at the face
    extrapolated from the cells inward, third order; ``phi`` cubic), spread by the
    face-ring and annulus weights of ``_rings`` (``m = 1`` for ``u_r``, ``m = 0`` for
    ``u_z``).
    """
    if lam == 0.5:
        return
    h = grid.spacing
    nz, nx = grid.shape
    c = wall_weight(lam)
    geometry = grid.geometry
    for axis, faces in ((1, geometry.wall_faces()), (0, geometry.horizontal_faces())):
        if not faces:
            continue
        pushes = (("D_rr", "u_r", 1), ("D_rz", "u_z", 0)) if axis == 1 else \
            (("D_rz", "u_r", 1), ("D_zz", "u_z", 0))
        for key, comp, m in pushes:
            g = G.get(key)
            if _zero(g):
                continue
            src = face_sources(grid, np.broadcast_to(np.asarray(g, dtype=float), grid.shape),
                               phi, faces, axis)
            if not np.any(src):
                continue
            if axis == 1:   # face ring j at radius (j + 1) h: columns 1 .. nx of src
                W = _rings.ring_weights(kernel, h, nx, 1, m, faces=True)
                fields[comp] = fields[comp] + c * _rings.ring_convolve([src[:, 1:]], W)[0]
            else:           # annuli at heights k h: rows 0 .. nz of src
                W = _rings.ring_weights(kernel, h, nx, 1, m, annuli=True)
                fields[comp] = fields[comp] + c * _rings.ring_convolve([src], W)[0][:nz]


# -- the fields -------------------------------------------------------------------------------

def particle_fields(grid: Grid, rho_s: np.ndarray, spots, kernel, lam: float,
                    tensor: Mapping | None, diffusivity: str, walls: str,
                    mask: np.ndarray | None) -> dict:
    """The axisymmetric particle fields (module docstring); arguments as
    :func:`spotpde.fields.coefficients.particle_fields` (already checked there)."""
    if getattr(kernel, "dims", None) != 3:
        raise ValueError(f"kernel: an axisymmetric grid needs a 3D kernel (dims=3), got "
                         f"dims={getattr(kernel, 'dims', None)!r}")
    _walls.check_walls(walls)
    _check_coefficient(grid, "spots.drift", spots.drift)
    act = grid.active
    rho = np.where(act, np.asarray(rho_s, dtype=float), 0.0)
    D_s = spot_diffusivity(grid, spots, tensor)
    v_s = spots.drift
    h = grid.spacing
    nz, nx = grid.shape

    T = D_s
    if diffusivity == "passage":
        cart = {"D_xx": D_s["D_rr"], "D_xz": D_s["D_rz"], "D_zz": D_s["D_zz"]}
        src = _passage.source_tensor(grid, spots, cart, kernel, lam)
        T = {"D_rr": src["D_xx"], "D_rz": 0.0, "D_zz": src["D_zz"]}

    renorm = _walls.check_walls(walls) == "renormalise" and (
        grid.walls == "reflecting" or grid.geometry.masked)
    phi = coverage(grid, kernel, mask) if renorm else None
    # sources vanish on inactive cells, where phi may be ~0
    inv = 1.0 if phi is None else np.where(act, 1.0 / np.where(act, phi, 1.0), 0.0)

    G = {k: None if _zero(d) else rho * d for k, d in D_s.items()}
    div = grid.geometry.divergence(G)

    W = {}

    def weights(power, m):
        if (power, m) not in W:
            W[(power, m)] = _rings.ring_weights(kernel, h, nx, power, m)
        return W[(power, m)]

    # batch the sources by weight set
    jobs: dict = {}

    def request(name, source, power, m):
        jobs.setdefault((power, m), []).append((name, source))

    drift_z = -rho * v_s * inv
    if lam != 0.0:
        drift_z = drift_z + drift_weight(lam) * div["z"] * inv
        if np.any(div["r"]):
            request("u_r", drift_weight(lam) * div["r"] * inv, 1, 1)
    request("u_z", drift_z, 1, 0)
    inv2 = inv * inv
    for key, m in (("D_rr", 0), ("D_zz", 0), ("D_rz", 1)):
        t = T[key]
        if not _zero(t):
            request(key, rho * t * inv2, 2, m)
    if diffusivity == "passage":
        for key in ("D_rr", "D_zz"):
            t, d = T[key], D_s[key]
            if _zero(t) or _zero(d) or (np.ndim(t) == 0 and np.ndim(d) == 0):
                continue
            request("diff_" + key, rho * (np.asarray(t) - np.asarray(d)) * inv2, 2, 0)
    res = {}
    for (power, m), items in jobs.items():
        out = _rings.ring_convolve([s for _, s in items], weights(power, m))
        res.update({name: o for (name, _), o in zip(items, out)})
    fields = {k: res.get(k, np.zeros(grid.shape)) for k in KEYS}

    if diffusivity == "passage":
        diff = passage_excess(T, D_s, fields, lambda key: res["diff_" + key], ("D_rr", "D_zz"))
        dv = grid.geometry.divergence(diff)
        fields["u_r"] = fields["u_r"] + dv["r"]
        fields["u_z"] = fields["u_z"] + dv["z"]

    add_wall_layer(grid, kernel, lam, G, phi, fields)
    for k in ("D_rr", "D_zz"):
        fields[k] = clip_roundoff(fields[k])
    return {k: np.where(act, fields[k], 0.0) for k in KEYS}
