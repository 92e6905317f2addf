"""Particle drift and diffusivity on axisymmetric grids (cylindrical silos, cones; private).

:func:`spotpde.fields.coefficients.particle_fields` calls :func:`particle_fields` when
``grid.axisymmetric``. The fields are those of the 3D spot model (docs/coefficients.md,
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
``(div T)_z = (1/r) d_r(r T_rz) + d_z T_zz``; derivatives are second-order differences
with the even continuation across the axis (``T_rr``, ``r T_rz``, ``T_zz`` are even in
``r``), one-sided at the outer wall, the floor, the top and next to inactive (hopper)
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

from . import _rings, _walls
from .._roundoff import clip_roundoff
from ..grid import Grid

KEYS = ("u_r", "u_z", "D_rr", "D_rz", "D_zz")


# -- derivatives with the regular axis and the staircase ------------------------------------

def masked_derivative(f: np.ndarray, h: float, axis: int, active: np.ndarray,
                      even_axis: bool = False) -> np.ndarray:
    """Second-order derivative along ``axis`` that never differences across a wall.

    Central where both neighbours are active cells, second-order one-sided
    ``(-3 f0 + 4 f1 - f2) / 2h`` where one side is a wall (the array end or an inactive
    cell) and two cells are available on the other, first order with one, zero with
    none (``numpy.gradient(edge_order=2)`` without inactive cells). ``even_axis``: the
    field is even about the low end of axis 1 (the symmetry axis ``r = 0``), whose ghost
    value at ``r = -h/2`` is ``f[..., 0]``.
    """
    f = np.asarray(f, dtype=float)
    act = np.broadcast_to(active, f.shape)
    fm = np.moveaxis(f, axis, 0)
    am = np.moveaxis(act, axis, 0)
    n = fm.shape[0]
    pad_f = np.concatenate([fm[:1] if even_axis else np.zeros_like(fm[:1]), fm, np.zeros_like(fm[:2])])
    pad_a = np.concatenate([am[:1] if even_axis else np.zeros_like(am[:1]), am,
                            np.zeros_like(am[:2])]).astype(bool)
    # index p in the padded array = original index p - 1; neighbours at p +- 1, p +- 2
    P = np.arange(1, n + 1)

    def at(k):
        idx = np.clip(k, 0, n + 2)
        return pad_f[idx], pad_a[idx]

    def far(k):  # second cells (may lie outside the padded array: inactive)
        ok = (k >= 0) & (k <= n + 2)
        idx = np.clip(k, 0, n + 2)
        return pad_f[idx], pad_a[idx] & ok.reshape((-1,) + (1,) * (fm.ndim - 1))

    fl, al = at(P - 1)
    fr, ar = at(P + 1)
    fll, all_ = far(P - 2)
    frr, arr = far(P + 2)
    f0 = fm
    out = np.zeros_like(fm)
    central = al & ar
    out = np.where(central, (fr - fl) / (2 * h), out)
    right2 = ~al & ar & arr
    out = np.where(right2, (-3 * f0 + 4 * fr - frr) / (2 * h), out)
    right1 = ~al & ar & ~arr
    out = np.where(right1, (fr - f0) / h, out)
    left2 = al & ~ar & all_
    out = np.where(left2, (3 * f0 - 4 * fl + fll) / (2 * h), out)
    left1 = al & ~ar & ~all_
    out = np.where(left1, (f0 - fl) / h, out)
    out = np.where(am, out, 0.0)
    return np.moveaxis(out, 0, axis)


def divergence(grid: Grid, T: Mapping, active=None) -> dict:
    """Cylindrical divergence of an axisymmetric symmetric tensor with ``T_tt = T_rr``.

    ``(div T)_r = d_r T_rr + d_z T_rz``, ``(div T)_z = (1/r) d_r(r T_rz) + d_z T_zz``
    (module docstring); ``T`` keyed ``D_rr, D_rz, D_zz`` (arrays, floats or None).
    Returns ``{"r": ..., "z": ...}`` in ``T``'s units per d.
    """
    h = grid.spacing
    act = grid.active if active is None else active
    r = grid.r[None, :]

    def arr(key):
        t = T.get(key)
        if t is None or (np.ndim(t) == 0 and float(t) == 0.0):
            return None
        return np.broadcast_to(np.asarray(t, dtype=float), grid.shape)

    rr, rz, zz = arr("D_rr"), arr("D_rz"), arr("D_zz")
    out = {"r": np.zeros(grid.shape), "z": np.zeros(grid.shape)}
    if rr is not None:
        out["r"] += masked_derivative(rr, h, 1, act, even_axis=True)
    if rz is not None:
        out["r"] += masked_derivative(rz, h, 0, act)
        out["z"] += masked_derivative(r * rz, h, 1, act, even_axis=True) / r
    if zz is not None:
        out["z"] += masked_derivative(zz, h, 0, act)
    return out


def flux_velocity(grid: Grid, fields: Mapping) -> dict:
    """``u_p - div D_p`` on an axisymmetric or hopper grid (cylindrical / staircase
    differences; zero on inactive cells)."""
    keys = grid.diffusivity_keys
    if grid.axisymmetric:
        div = divergence(grid, {k: fields[k] for k in keys})
    else:
        from ._hopper import divergence as cartesian_divergence
        div = cartesian_divergence(grid, {k: fields[k] for k in keys}, grid.active)
    return {f"u_{a}": np.where(grid.active, np.asarray(fields[f"u_{a}"], dtype=float) - div[a], 0.0)
            for a in (("r", "z") if grid.axisymmetric else ("x", "z"))}


def velocity_divergence(grid: Grid, u: Mapping) -> np.ndarray:
    """``div u``: ``(1/r) d_r(r u_r) + d_z u_z`` (axisymmetric) or ``d_x u_x + d_z u_z``,
    by the staircase differences of :func:`masked_derivative`."""
    h, act = grid.spacing, grid.active
    if grid.axisymmetric:
        r = grid.r[None, :]
        radial = masked_derivative(r * u["u_r"], h, 1, act, even_axis=True) / r
    else:
        radial = masked_derivative(u["u_x"], h, 1, act)
    return radial + masked_derivative(u["u_z"], h, 0, act)


# -- inputs ---------------------------------------------------------------------------------

def spot_tensor(grid: Grid, spots, tensor: Mapping | None = None) -> dict:
    """``D_s`` in cylindrical components ``D_rr`` (= ``D_theta_theta``), ``D_rz``, ``D_zz``."""
    from .coefficients import _check_coefficient

    keys = ("D_rr", "D_rz", "D_zz")
    if tensor is not None:
        unknown = sorted(set(tensor) - set(keys))
        if unknown:
            raise ValueError(f"spot_diffusivity_tensor: unknown components {unknown}; valid on "
                             f"an axisymmetric grid: {list(keys)} (D_theta_theta = D_rr)")
        out = {k: tensor.get(k, 0.0) for k in keys}
    else:
        out = {"D_rr": spots.D_perp, "D_rz": 0.0, "D_zz": spots.D_par}
    for k, v in out.items():
        _check_coefficient(grid, f"spot diffusivity {k}", v)
    return out


def _zero(v) -> bool:
    return v is None or (np.ndim(v) == 0 and float(v) == 0.0)


def passage_excess(T: Mapping, D_s: Mapping, fields: Mapping, convolved, keys) -> dict:
    """``D_p - D_mf`` by component (the passage drift's ``div(D_p - D_mf)``), d**2/time.

    ``D_p = w^2 * (rho_s T)`` is ``fields[key]``; the mean-field part is ``w^2 *
    (rho_s D_s)``: nothing where ``T`` is zero, all of ``D_p`` where ``D_s`` is, the
    factor ``1 - D_s/T`` when both are constants, else ``convolved(key)`` (the transform
    of ``rho_s (T - D_s)`` requested beside the fields).
    """
    diff = {}
    for key in keys:
        t, d = T[key], D_s[key]
        if _zero(t):
            continue
        if _zero(d):
            diff[key] = fields[key]
        elif np.ndim(t) == 0 and np.ndim(d) == 0:
            diff[key] = (1.0 - float(d) / float(t)) * fields[key]
        else:
            diff[key] = convolved(key)
    return diff


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
        if grid.hopper is None and mask is None:
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

def _face_extrapolate(f, active, j, k, direction, nmax, axis=1):
    """Value of ``f`` at the face of cell ``(k, j)`` on the side ``direction`` (+1: the
    high side) along ``axis`` (1: r or x, 0: z), from up to ``nmax`` active cells inward
    (orders: cubic with four cells, 3 with three, 2, 1)."""
    vals = []
    for q in range(nmax):
        kk, jj = (k, j - direction * q) if axis == 1 else (k - direction * q, j)
        if not (0 <= jj < f.shape[1] and 0 <= kk < f.shape[0]) or not active[kk, jj]:
            break
        vals.append(f[kk, jj])
    if len(vals) >= 4 and nmax >= 4:
        return (35 * vals[0] - 35 * vals[1] + 21 * vals[2] - 5 * vals[3]) / 16.0
    if len(vals) >= 3:
        return (15 * vals[0] - 10 * vals[1] + 3 * vals[2]) / 8.0
    if len(vals) == 2:
        return (3 * vals[0] - vals[1]) / 2.0
    return vals[0]


def horizontal_faces(grid: Grid) -> list[tuple[int, int, int]]:
    """Horizontal wall faces ``(k, j, direction)`` of the staircase: cell ``(k, j)`` is
    active and its neighbour at ``k + direction`` is an inactive cell (the floor and the
    top are not walls)."""
    act = np.asarray(grid.active, dtype=bool)
    below = np.zeros_like(act)
    below[1:] = act[1:] & ~act[:-1]
    above = np.zeros_like(act)
    above[:-1] = act[:-1] & ~act[1:]
    return sorted([(int(k), int(j), -1) for k, j in np.argwhere(below)]
                  + [(int(k), int(j), 1) for k, j in np.argwhere(above)])


def face_sources(grid, g, phi, faces, axis):
    """Face values ``(G.n) / phi`` on a face array: vertical faces (``axis = 1``) on
    ``(nz, nx + 1)``, index ``j + 1`` for the face on the high side of column ``j``;
    horizontal faces (``axis = 0``) on ``(nz + 1, nx)``, index ``k + 1`` likewise."""
    act = grid.active
    nz, nx = grid.shape
    src = np.zeros((nz, nx + 1) if axis == 1 else (nz + 1, nx))
    for k, j, d in faces:
        val = d * _face_extrapolate(g, act, j, k, d, 3, axis)
        if phi is not None:
            val /= max(1e-300, _face_extrapolate(phi, act, j, k, d, 4, axis))
        if axis == 1:
            src[k, j + 1 if d > 0 else j] += val
        else:
            src[k + 1 if d > 0 else k, j] += val
    return src


def wall_faces(grid: Grid, both_box_walls: bool = False) -> list[tuple[int, int, int]]:
    """Vertical wall faces ``(k, j, direction)``: cell ``(k, j)`` is active and its
    neighbour at ``j + direction`` is inactive, or lies beyond a reflecting wall (the
    cylinder wall ``r = a``; with ``both_box_walls`` also the low end, a Cartesian box)."""
    act = np.asarray(grid.active, dtype=bool)
    wall = grid.walls == "reflecting"
    nbr_hi = np.concatenate([act[:, 1:], np.full((act.shape[0], 1), not wall)], axis=1)
    nbr_lo = np.concatenate([np.full((act.shape[0], 1), not (wall and both_box_walls)), act[:, :-1]],
                            axis=1)
    if not both_box_walls:      # the axis is never a wall
        nbr_lo[:, 0] = True
    hi = np.argwhere(act & ~nbr_hi)
    lo = np.argwhere(act & ~nbr_lo)
    faces = [(int(k), int(j), 1) for k, j in hi] + [(int(k), int(j), -1) for k, j in lo]
    return sorted(faces)


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
    c = 1.0 - 2.0 * lam
    for axis, faces in ((1, wall_faces(grid)), (0, horizontal_faces(grid))):
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
    from .coefficients import _check_coefficient

    if getattr(kernel, "dims", None) != 3:
        raise ValueError(f"kernel: an axisymmetric grid needs a 3D kernel (dims=3), got "
                         f"dims={getattr(kernel, 'dims', None)!r}")
    _walls.check_walls(walls)
    _check_coefficient(grid, "spots.drift", spots.drift)
    act = grid.active
    rho = np.where(act, np.asarray(rho_s, dtype=float), 0.0)
    D_s = spot_tensor(grid, spots, tensor)
    v_s = spots.drift
    h = grid.spacing
    nz, nx = grid.shape

    T = D_s
    if diffusivity == "passage":
        from . import _passage

        cart = {"D_xx": D_s["D_rr"], "D_xz": D_s["D_rz"], "D_zz": D_s["D_zz"]}
        src = _passage.source_tensor(grid, spots, cart, kernel, lam)
        T = {"D_rr": src["D_xx"], "D_rz": 0.0, "D_zz": src["D_zz"]}

    renorm = _walls.check_walls(walls) == "renormalise" and (
        grid.walls == "reflecting" or grid.hopper is not None)
    phi = coverage(grid, kernel, mask) if renorm else None
    # sources vanish on inactive cells, where phi may be ~0
    inv = 1.0 if phi is None else np.where(act, 1.0 / np.where(act, phi, 1.0), 0.0)

    G = {k: None if _zero(d) else rho * d for k, d in D_s.items()}
    div = divergence(grid, G, act)

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
        drift_z = drift_z + 2.0 * lam * div["z"] * inv
        if np.any(div["r"]):
            request("u_r", 2.0 * lam * div["r"] * inv, 1, 1)
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
        dv = divergence(grid, diff, act)
        fields["u_r"] = fields["u_r"] + dv["r"]
        fields["u_z"] = fields["u_z"] + dv["z"]

    add_wall_layer(grid, kernel, lam, G, phi, fields)
    for k in ("D_rr", "D_zz"):
        fields[k] = clip_roundoff(fields[k])
    return {k: np.where(act, fields[k], 0.0) for k in KEYS}
