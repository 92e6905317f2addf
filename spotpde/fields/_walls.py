"""Free-volume-conserving walls: the kernel coverage ``phi`` and the renormalised fields.

A spot at ``s`` whose kernel reaches through a reflecting wall displaces only the
particles inside the material. The paper's definition ``w = V_s / (N_p V_p)`` says that
each of the fewer particles then moves further; we implement it by renormalising the
influence of the spot::

    K(r, s) = w(r - s) / phi(s),      phi(s) = (1/V1) integral chi(r) w(r - s) dr

with ``chi`` the material indicator (1 in the granular material, 0 beyond a wall). A spot
step ``dR`` then displaces exactly the particle volume ``V1 dR`` wherever the spot is, so
the particle flux through every height is ``V1 Q0`` (docs/walls.md). Averaging the
discrete rule ``dr_p = -K(r_p, s + lam dR) dR`` over independent spots gives (Itô,
``u_s = v_s z``, ``D_s`` the spot diffusivity, ``n`` the outward wall normal)::

    u_p = - w * ([rho_s u_s - 2 lam div(D_s rho_s)] / phi)
          + (1 - 2 lam) integral_walls w(r - s_w) (D_s rho_s)·n / phi dA_w
    D_p =   w^2 * (rho_s D_s / phi^2)

i.e. the truncated fields of :mod:`spotpde.coefficients` with every source divided by
``phi`` (drift, wall layer) or ``phi^2`` (diffusivity): the ``lam``-rule term
``2 lam rho_s D_s grad(phi) / phi^2`` from differentiating ``1/phi`` combines with
``w * div(D_s rho_s / phi)`` into ``w * (div(D_s rho_s) / phi)`` exactly.

Where ``chi`` is taken beyond the grid: beyond a reflecting side wall ``chi = 0``; beyond
the floor, the open top and open side walls (``domain.walls = "open"``) the boundary
values of ``chi`` are continued (edge padding): the top is a cut through a packing that
continues upward, the orifice plane is where particles leave (not a wall), and an open
side is a window on a wider silo. So for a rectangular silo ``phi`` depends only on the
horizontal coordinates, and with open walls ``phi = 1`` (nothing changes).

This module is private; :func:`spotpde.coefficients.particle_fields` calls it through
``walls="renormalise"`` (the default) and ``spotpde.montecarlo`` tabulates the same ``phi``
for its spots between vertical walls (:func:`coverage_table`).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import scipy.integrate
import scipy.signal

from ._common import (_COMPONENTS, _assemble, _box_derivative, _is_zero, _pair,
                      divergence)
from ._constant import SpotFluxTensor, add_requests, constant_fields
from ..grid import Grid
from ..parameters import drift_weight

__all__ = ["WALL_TREATMENTS", "check_walls", "renormalises", "coverage", "face_value",
           "renormalised_fields", "renormalised_constant_fields", "cutoff_marginal",
           "coverage_table"]

#: ``"renormalise"`` (default): a spot's influence is divided by the fraction ``phi`` of its
#: kernel inside the material, so every step displaces ``V1 dR``; ``"truncate"``: the part
#: of the kernel beyond a wall displaces nothing (free volume is lost at walls).
WALL_TREATMENTS = ("renormalise", "truncate")


def check_walls(walls) -> str:
    """Validate the wall treatment name; raises ValueError naming the argument ``walls``."""
    if not isinstance(walls, str) or walls not in WALL_TREATMENTS:
        allowed = ", ".join(f'"{w}"' for w in WALL_TREATMENTS)
        raise ValueError(f"walls: must be one of {allowed}, got {walls!r}")
    return walls


def renormalises(grid: Grid, walls: str) -> bool:
    """True if ``walls`` changes anything on this grid (renormalise + reflecting walls)."""
    return check_walls(walls) == "renormalise" and grid.walls == "reflecting"


def _pad(chi: np.ndarray, widths, reflecting_axes) -> np.ndarray:
    """Pad ``chi`` by ``widths`` per axis: zeros beyond reflecting walls, edge values else."""
    out = chi
    for axis, m in enumerate(widths):
        pad = [(0, 0)] * out.ndim
        pad[axis] = (m, m)
        if axis in reflecting_axes:
            out = np.pad(out, pad, mode="constant")
        else:
            out = np.pad(out, pad, mode="edge")
    return out


def coverage(grid: Grid, kernel, mask: np.ndarray | None = None) -> np.ndarray:
    """Fraction ``phi(s) = (1/V1) integral chi(r) w(r - s) dr`` of a spot's kernel in the material.

    Discretised with the kernel's cell-averaged stencil (the same one the fields use):
    ``phi_i = sum_j h^dims stencil_j chi_(i+j) / (h^dims sum stencil)``, so ``phi = 1``
    to round-off wherever the kernel is entirely inside the material, and the discrete
    particle flux identity of docs/walls.md holds exactly. ``chi`` is continued beyond
    the grid as in the module docstring (zero beyond reflecting side walls).

    Args:
        grid: the grid (its ``walls`` decides the side boundaries).
        kernel: influence kernel (``sample``).
        mask: material indicator on the grid (array order; 1 material, 0 solid; values in
            between are volume fractions of cut cells). ``None``: the rectangular silo, all
            material (``phi`` then depends on the horizontal coordinates only).

    Returns:
        grid-shaped array, dimensionless, in ``(0, 1]`` (without ``mask`` a read-only
        broadcast of one horizontal layer).

    Raises:
        ValueError: ``mask`` of the wrong shape, with values outside [0, 1], or leaving a
            material cell without any material within the kernel's reach.
    """
    h = grid.spacing
    stencil = np.asarray(kernel.sample(h, power=1), dtype=float)
    total = float(stencil.sum())
    if mask is None:
        chi = np.ones((1,) + grid.shape[1:])
    else:
        chi = np.asarray(mask, dtype=float)
        if chi.shape != grid.shape:
            raise ValueError(f"mask: array shape {chi.shape} does not match the grid shape "
                             f"{grid.shape} (array order {grid.axes})")
        if not np.all((chi >= 0.0) & (chi <= 1.0)):
            raise ValueError("mask: values must lie in [0, 1] (material fraction of a cell)")
    widths = [(n - 1) // 2 for n in stencil.shape]
    reflecting = set(range(1, grid.dims)) if grid.walls == "reflecting" else set()
    if mask is None and grid.dims == 2:
        # chi is one row continued up and down (edge padding): the 'valid' sum over the
        # stencil's rows is the 1D convolution of that row with the stencil's column sums
        row = _pad(chi, [0, widths[1]], reflecting)[0]
        phi = np.convolve(row, stencil.sum(axis=0), mode="valid")[None, :] / total
    else:
        padded = _pad(chi, widths, reflecting)
        # w even: sum_j s_j chi_(i+j) = sum_j s_j chi_(i-j), a 'valid' correlation = convolution
        phi = scipy.signal.fftconvolve(padded, stencil, mode="valid") / total
    inside = chi > 0 if mask is not None else np.ones(phi.shape, bool)
    if np.any(phi[np.broadcast_to(inside, phi.shape)] <= 1e-12):
        raise ValueError("mask: a material cell has no material within the kernel's reach")
    phi = np.clip(phi, 1e-300, 1.0)
    # without a mask phi is one horizontal layer: a read-only view repeats it up the grid
    return phi if mask is not None else np.broadcast_to(phi, grid.shape)


def face_value(phi: np.ndarray, axis: int, side: int) -> np.ndarray:
    """``phi`` on a boundary face from the four nearest cell centres (cubic, error O(h^4)).

    ``(35 f0 - 35 f1 + 21 f2 - 5 f3) / 16`` (Lagrange extrapolation to ``-h/2``); ``phi``
    is smooth at a wall (its first kink lies a kernel radius inside), so this is ~10x
    more accurate than the third-order formula at ``h = R/10`` (the wall layer's
    ``1/phi`` at the face then errs by 1e-4 instead of 4e-3 for a Gaussian, h = 0.25).
    """
    n = phi.shape[axis]
    if n < 4:
        return np.take(phi, 0 if side < 0 else n - 1, axis=axis)
    idx = (0, 1, 2, 3) if side < 0 else (-1, -2, -3, -4)
    f0, f1, f2, f3 = (np.take(phi, i, axis=axis) for i in idx)
    return np.clip((35.0 * f0 - 35.0 * f1 + 21.0 * f2 - 5.0 * f3) / 16.0, 1e-300, 1.0)


def renormalised_fields(grid: Grid, rho_s: np.ndarray, v_s, D_s: Mapping, lam: float, conv,
                        phi: np.ndarray, D_source: Mapping | None = None
                        ) -> dict[str, np.ndarray]:
    """``u_p`` (without the wall layer) and ``D_p`` with every source divided by ``phi``.

    ``u_p = -w * (rho_s u_s / phi) + 2 lam w * (div(D_s rho_s) / phi)`` and
    ``D_p = w^2 * (rho_s D_s / phi^2)``; ``div`` by second-order grid differences of the
    un-renormalised ``D_s rho_s`` (as in the truncated fields). ``conv`` is the
    ``_common._Convolutions`` collector (one transform per source and stencil).
    With ``D_source`` (the passage tensor ``T`` of ``_passage.source_tensor``) the
    diffusivity sources are ``rho_s T / phi^2`` instead (``D_p = w^2 * (rho_s T / phi^2)``);
    the drift's ``div(D_s rho_s)`` keeps the spot diffusivity.
    Also returns ``"_G"``: ``rho_s D_s^ab`` and ``"_phi"``: ``phi`` (the wall layer takes
    the face values of both, each extrapolated to third order: ``phi`` is smooth at a
    wall, ``1/phi`` much less so).
    """
    comps = _COMPONENTS[grid.dims]
    inv = 1.0 / phi
    G, D_terms = {}, {}
    for key, d in D_s.items():
        G[key] = None if _is_zero(d) else rho_s * d
        t = D_source.get(key, d) if D_source is not None else d
        if _is_zero(t):
            continue
        if np.ndim(t) == 0:
            D_terms[key] = (float(t), conv.request("rho_phi2", rho_s * inv * inv, 2))
        else:
            D_terms[key] = (1.0, conv.request(f"{key}_phi2", rho_s * t * inv * inv, 2))
    div = divergence(grid, G)
    u_terms = {a: [] for a in comps}
    for a in comps:
        if lam != 0.0 and np.any(div[a]):
            u_terms[a].append((drift_weight(lam), conv.request(f"div_{a}_phi", div[a] * inv, 1)))
    if np.ndim(v_s) == 0:
        if float(v_s) != 0.0:
            u_terms["z"].append((-float(v_s), conv.request("rho_phi", rho_s * inv, 1)))
    else:
        u_terms["z"].append((-1.0, conv.request("rho_v_phi", rho_s * v_s * inv, 1)))
    res = conv.run()
    fields = _assemble(grid, comps, u_terms, D_terms, D_s, res)
    fields["_G"] = G
    fields["_phi"] = phi
    return fields


# -- the Monte Carlo's table ---------------------------------------------------------------

def cutoff_marginal(shape: str, size: float, size_v: float, amp: float,
                    reach: tuple[float, float], u) -> np.ndarray:
    """Marginal ``m(u) = integral w(u, z) dz`` of the Monte Carlo's 2D kernel (with its cut-off).

    ``shape``: ``"uniform"`` (``amp`` inside the ellipse of half-axes ``size, size_v``:
    ``m = 2 amp size_v sqrt(1 - (u/size)^2)``), ``"gaussian"`` or ``"exponential"``
    (``amp exp(-rho^2/2)`` or ``amp exp(-rho)``, zero outside the ellipse of half-axes
    ``reach``; 64-point Gauss-Legendre in ``z`` over ``[0, z_c(u)]``, doubled). In d.
    """
    u = np.asarray(u, dtype=float)
    rh, rv = reach
    if shape == "uniform":
        t = np.clip(u / size, -1.0, 1.0)
        return 2.0 * amp * size_v * np.sqrt(1.0 - t * t)
    zc = rv * np.sqrt(np.clip(1.0 - (u / rh) ** 2, 0.0, 1.0))
    g, wq = np.polynomial.legendre.leggauss(64)
    z = 0.5 * zc[..., None] * (g + 1.0)
    q2 = (u[..., None] / size) ** 2 + (z / size_v) ** 2
    f = np.exp(-0.5 * q2) if shape == "gaussian" else np.exp(-np.sqrt(q2))
    return 2.0 * amp * 0.5 * zc * np.sum(wq * f, axis=-1)


def coverage_table(shape: str, size: float, size_v: float, amp: float,
                   reach: tuple[float, float], x0: float, x1: float,
                   spacing: float = 2.5e-3) -> tuple[float, float, np.ndarray]:
    """``phi`` of the Monte Carlo's kernel between vertical walls at ``x0, x1``, tabulated.

    ``phi(s) = (M(min(x1 - s, r)) - M(max(x0 - s, -r))) / M(r)`` with ``M`` the cumulative
    integral of :func:`cutoff_marginal` from ``-r`` (``r`` the horizontal reach): closed
    form for the uniform kernel (``M`` = ellipse segment area), cumulative Simpson on
    ``4001`` nodes otherwise. Nodes every ``spacing`` (or fewer, at most 20001) on
    ``[x0, x1]``; linear interpolation between them errs by ``< spacing^2 max|phi''| / 8``.

    Returns:
        ``(first node, node spacing, phi at the nodes)``.
    """
    rh = reach[0] if shape != "uniform" else size
    n = int(min(20001, max(2, np.ceil((x1 - x0) / spacing) + 1)))
    xs = np.linspace(x0, x1, n)
    if shape == "uniform":
        def M(u):
            t = np.clip(u / size, -1.0, 1.0)
            return amp * size_v * size * (t * np.sqrt(1.0 - t * t) + np.arcsin(t) + 0.5 * np.pi)
    else:
        uu = np.linspace(-rh, rh, 4001)
        cum = scipy.integrate.cumulative_simpson(cutoff_marginal(shape, size, size_v, amp,
                                                                 reach, uu), x=uu, initial=0.0)

        def M(u):
            return np.interp(u, uu, cum)
    hi = np.minimum(x1 - xs, rh)
    lo = np.maximum(x0 - xs, -rh)
    phi = np.where(hi > lo, (M(hi) - M(lo)) / M(rh), 0.0)
    return float(xs[0]), float(xs[1] - xs[0]), np.clip(phi, 1e-300, 1.0)


# -- rectangular silos with constant coefficients: bulk transform + wall strips --------------

def _wall_boxes(grid: Grid, half_widths) -> list[tuple[slice, ...]]:
    """Disjoint boxes covering the cells within a stencil half-width of a reflecting side
    wall (where ``phi < 1``; ``phi = 1`` elsewhere, the kernel being whole in the material)."""
    boxes, shape = [], grid.shape
    done = [slice(0, n) for n in shape]          # along axes already boxed: their interior
    for axis in range(grid.dims - 1, 0, -1):     # x, then (3D) y
        n, m = shape[axis], half_widths[axis]
        lo, hi = min(m, n), max(min(m, n), n - m)
        for sl in (slice(0, lo), slice(hi, n)):
            box = list(done)
            box[axis] = sl
            if all(b.stop > b.start for b in box):
                boxes.append(tuple(box))
        done[axis] = slice(lo, hi)
    return boxes


def renormalised_constant_fields(grid: Grid, rho_s: np.ndarray, v_s: float, D_s: Mapping,
                                 lam: float, conv, phi: np.ndarray,
                                 D_source: Mapping | None = None,
                                 passage_drift: bool = False) -> dict[str, np.ndarray]:
    """:func:`renormalised_fields` of a rectangular silo with constant ``v_s``, ``D_s``, ``T``.

    ``S / phi = S + S (1/phi - 1)`` for every source ``S``, and ``1/phi - 1`` (``1/phi^2 - 1``)
    vanishes except within a stencil half-width of the reflecting side walls. So the fields
    are the truncated ones of ``_constant.constant_fields`` (one transform of ``rho_s``
    per stencil) plus the convolutions of the sources times ``1/phi - 1`` over those wall
    strips (``_strips.box_convolutions``)::

        u_z   += -v_s  w   * (rho_s (1/phi - 1))
        u_a   += 2 lam w   * (div_a(D_s rho_s) (1/phi - 1))
        D^ab  += T^ab  w^2 * (rho_s (1/phi^2 - 1))

    with ``div`` the same second-order differences as the general path (one-sided at the
    walls). Equal to :func:`renormalised_fields` to round-off (``phi`` is 1 to round-off
    away from the walls); whole-grid transforms drop from one per source to one per
    stencil. 2D grids take ``_constant.fields_2d`` with the strips' ``1/phi``: it
    transforms ``rho_s / phi`` itself (``1/phi`` applied to the strip columns of the
    transform's input), so ``u_z`` needs no strip and the drift's strips absorb the
    boundary planes (two strip transforms per wall instead of three); with
    ``passage_drift`` it also adds the passage drift ``div(D_p - D_p_mf)``
    (``_passage.keep_flux_velocity``). Also returns ``"_G"`` and ``"_phi"``.
    """
    boxes = _wall_boxes(grid, [(k - 1) // 2 for k in conv.stencils[1].shape])
    if grid.dims == 2:      # 1/phi on the strip columns multiplies the one transform's input
        strips = [(box[1], 1.0 / phi[0, box[1]]) for box in boxes]
        fields = constant_fields(grid, rho_s, v_s, D_s, lam, conv, D_source, passage_drift,
                                 strips)
        fields["_G"] = SpotFluxTensor(rho_s, D_s)
        fields["_phi"] = phi
        return fields
    comps = _COMPONENTS[grid.dims]
    h, hd = grid.spacing, grid.spacing**grid.dims
    eps1 = [1.0 / phi[box] - 1.0 for box in boxes]
    # requests are named by (drift component, factor): each is added to that component
    requests = []
    if v_s != 0.0:
        requests += [(("u_z", -v_s * hd), box, rho_s[box] * e, 1) for box, e in zip(boxes, eps1)]
    for a in comps if lam != 0.0 else ():
        coeffs = {b: float(D_s[_pair(a, b)]) for b in comps if not _is_zero(D_s[_pair(a, b)])}
        if coeffs:
            requests += [((f"u_{a}", drift_weight(lam) * hd), box, e * sum(
                d * _box_derivative(rho_s, h, box, grid.axes.index(b)) for b, d in coeffs.items()),
                1) for box, e in zip(boxes, eps1)]
    T = D_s if D_source is None else D_source
    p2 = conv.use[2][0]
    if any(not _is_zero(t) for t in T.values()):    # one source for every D component
        requests += [("D", box, rho_s[box] * (1.0 / phi[box]**2 - 1.0), p2) for box in boxes]
    fields = constant_fields(grid, rho_s, v_s, D_s, lam, conv, D_source)
    add_requests(grid, fields, requests, conv, D_s, T)
    fields["_G"] = SpotFluxTensor(rho_s, D_s)
    fields["_phi"] = phi
    return fields
