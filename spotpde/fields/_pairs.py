"""Two-point statistics of the spot model: velocity correlation and pair diffusivity (private).

Re-exported by :mod:`spotpde.coefficients`. Both rest on the cross integral

    X^ab(r1, r2) = integral rho_s D_s^ab w(r1 - s) w(r2 - s) ds      (d**2 per unit time)

over the silo, with ``X(r, r) = D_p(r)``: the velocity correlation
``C^ab = X^ab(r1, r2) / sqrt(X^aa(r1, r1) X^bb(r2, r2))`` (dimensionless, the paper's
eq. Cp) and the diffusivity of the separation of two tracers
``D^ab = D_p^ab(r1) + D_p^ab(r2) - 2 X^ab(r1, r2)`` (plus the passage correction).
Points are ``(x, z)`` or ``(x, y, z)`` in d. Hoppers and cylinders: the same quadrature
on the local box of :mod:`._pairs_local` (the spots in the material; a cylinder's points
``(x, y, z)`` or ``(r, z)`` and 3D Cartesian results).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from . import _pairs_local, _passage
from ._common import (_COMPONENTS, _SUBSAMPLE, _as_point, _check_inputs, _check_rule,
                      _is_zero, spot_diffusivity)
from ..grid import DIFFUSIVITY_KEYS, Grid
from ..parameters import Spots

#: Largest number of quadrature points of one cross integral (fewer sub-samples beyond).
_MAX_POINTS = 4_000_000


def _cross_integrals(grid: Grid, rho_s: np.ndarray, D_s: Mapping, kernel, r1: np.ndarray,
                     r2: np.ndarray) -> dict[str, float]:
    """``X^ab(r1, r2) = integral rho_s D_s^ab w(r1 - s) w(r2 - s) ds`` over the silo.

    Sub-samples every cell ``_SUBSAMPLE`` times per axis (rho_s, D_s constant per cell;
    fewer when the box would exceed ``_MAX_POINTS`` points), on the cells within the
    kernel's reach of both points, slab by slab in z.
    """
    comps = _COMPONENTS[grid.dims]
    h = grid.spacing
    reach_h, reach_v = kernel.reach
    coords = grid.coords()
    sl = []
    for c in grid.axes:  # array order
        reach = reach_v if c == "z" else reach_h
        i = comps.index(c)
        lo, hi = max(r1[i], r2[i]) - reach - h, min(r1[i], r2[i]) + reach + h
        idx = np.nonzero((coords[c] >= lo) & (coords[c] <= hi))[0]
        if idx.size == 0:
            return {k: 0.0 for k in DIFFUSIVITY_KEYS[grid.dims]}
        sl.append(slice(idx[0], idx[-1] + 1))
    sl = tuple(sl)
    n_cells = int(np.prod([x.stop - x.start for x in sl]))
    # sub-samples per cell and axis: _SUBSAMPLE, fewer if the box is large (bounded work)
    ns = int(max(1, min(_SUBSAMPLE, np.floor((_MAX_POINTS / n_cells) ** (1.0 / grid.dims)))))
    sub = ((np.arange(ns) + 0.5) / ns - 0.5) * h
    dv = (h / ns) ** grid.dims
    terms = {k: d for k, d in D_s.items() if not _is_zero(d)}
    out = {k: 0.0 for k in D_s}

    def refine(a, s_):
        if np.ndim(a) == 0:
            return a
        a = np.asarray(a, dtype=float)[s_]
        for ax in range(a.ndim):
            a = np.repeat(a, ns, axis=ax)
        return a

    z_slice = sl[0]
    per_row = max(1, n_cells // (z_slice.stop - z_slice.start))
    step = max(1, int(_MAX_POINTS // (per_row * ns**grid.dims)) or 1)
    for k0 in range(z_slice.start, z_slice.stop, step):  # slabs in z bound the memory
        s_ = (slice(k0, min(k0 + step, z_slice.stop)),) + sl[1:]
        pts = [np.add.outer(coords[c][x], sub).ravel() for c, x in zip(grid.axes, s_)]
        mesh = dict(zip(grid.axes, np.meshgrid(*pts, indexing="ij", sparse=True)))
        w1 = kernel.evaluate(*[r1[comps.index(c)] - mesh[c] for c in comps])
        w2 = kernel.evaluate(*[r2[comps.index(c)] - mesh[c] for c in comps])
        base = refine(rho_s, s_) * w1 * w2
        for k, d in terms.items():
            out[k] += float(np.sum(base * refine(d, s_)) * dv)
    return out


def _two_point_integrals(grid: Grid, rho_s, spots: Spots, kernel, r1, r2,
                         spot_diffusivity_tensor: Mapping | None):
    """Checked inputs, then ``(X(r1, r2), X(r1, r1), X(r2, r2))`` of :func:`_cross_integrals`
    (on the box of :func:`._pairs_local.localise`)."""
    rho_s = _check_inputs(grid, rho_s, kernel)
    p1, p2 = _as_point(grid, r1, "r1"), _as_point(grid, r2, "r2")
    D_s = spot_diffusivity(grid, spots, spot_diffusivity_tensor)
    return (_cross_integrals(grid, rho_s, D_s, kernel, p1, p2),
            _cross_integrals(grid, rho_s, D_s, kernel, p1, p1),
            _cross_integrals(grid, rho_s, D_s, kernel, p2, p2))


def velocity_correlation(grid: Grid, rho_s: np.ndarray, spots: Spots, kernel, r1, r2,
                         spot_diffusivity_tensor: Mapping | None = None) -> dict[str, float]:
    """Two-point particle velocity correlation tensor ``C_p(r1, r2)`` (the paper's eq. Cp).

    ``C^ab = X^ab(r1, r2) / sqrt(X^aa(r1, r1) X^bb(r2, r2))`` with
    ``X^ab(r1, r2) = integral rho_s D_s^ab w(r1 - s) w(r2 - s) ds``, so ``X(r, r) = D_p(r)``.
    The normalisation uses the diagonal components, as the definition eq. Cdef does
    (the printed eq. Cp writes ``D_p^ab`` under the root, which is only right for
    ``a = b``). In uniform flow ``C^aa`` is the kernel's ``correlation(r1 - r2)``.
    Integrals are sub-sampled quadratures over the silo (zero outside it).

    Args:
        grid: the grid.
        rho_s: spot density, grid-shaped.
        spots: spot parameters (``D_s``).
        kernel: influence kernel (``evaluate``, ``reach``).
        r1, r2: points ``(x, z)`` or ``(x, y, z)`` in d; on an axisymmetric grid
            ``(x, y, z)`` around the axis ``x = y = 0`` or ``(r, z)`` (read as
            ``(r, 0, z)``), with 3D Cartesian results in that frame. Both must lie in the
            material (ValueError naming ``r1`` / ``r2`` beyond a hopper's or a
            cylinder's wall).
        spot_diffusivity_tensor: optional full ``D_s`` (see :func:`particle_fields`).

    Returns:
        ``{"C_xx": ..., "C_xz": ..., ...}`` (dimensionless; 0 where a component of ``D_s``
        vanishes; the six 3D components on an axisymmetric grid).
    """
    grid, rho_s, spots, spot_diffusivity_tensor, r1, r2 = _pairs_local.localise(
        grid, rho_s, spots, kernel, r1, r2, spot_diffusivity_tensor)
    X, X1, X2 = _two_point_integrals(grid, rho_s, spots, kernel, r1, r2,
                                     spot_diffusivity_tensor)
    out = {}
    for key in DIFFUSIVITY_KEYS[grid.dims]:
        a, b = key[2], key[3]
        norm = np.sqrt(X1[f"D_{a}{a}"] * X2[f"D_{b}{b}"])
        out["C_" + key[2:]] = X[key] / norm if norm > 0 else 0.0
    return out


def pair_diffusivity(grid: Grid, rho_s: np.ndarray, spots: Spots, kernel, r1, r2,
                     spot_diffusivity_tensor: Mapping | None = None, *, rule: float = 0.5,
                     diffusivity: str = "passage") -> dict[str, float]:
    """Diffusivity tensor of the separation ``r1 - r2`` of two tracer particles.

    Mean field (``diffusivity="mean-field"``): ``D^ab(r1, r2) = D_p^ab(r1) + D_p^ab(r2) -
    2 X^ab(r1, r2)`` with ``X`` the cross integral of :func:`velocity_correlation` (the
    paper's section "Relative Diffusion of Two Tracers"); in uniform flow
    ``D^aa = 2 D_p^aa (1 - C_p^aa(r))``.

    Passage (default): each particle's own passage diffusivity, the local form of
    :func:`particle_fields` (``integral rho_s T w(r_i - s)^2 ds`` with ``T`` of
    ``_passage.source_tensor``), minus twice the passage cross term, taken in locally
    uniform flow at the cell of the midpoint: ``D = D_p(r1) + D_p(r2) - 2 X_mf(r1, r2)
    - V1 f [(2 b_p - B)_passage - (2 b_p - B)_mean-field](Delta)``, ``Delta = r1 - r2``,
    ``B`` the relative tensor of ``spotpde.fields._passage.length_tensor``, ``f = rho_s
    v_s``, ``b``, ``b_par`` at the midpoint. Exact in uniform flow, and the sum of the two
    particles' own passage diffusivities once they share no spot (docs/coefficients.md
    section 7).

    Args:
        grid, rho_s, spots, kernel, r1, r2, spot_diffusivity_tensor: as in
            :func:`velocity_correlation`.
        rule: ``lam`` (used by the passage correction only).
        diffusivity: ``"passage"`` (default) or ``"mean-field"``.

    Returns:
        ``{"D_xx": ..., "D_xz": ..., ...}`` in d**2 per unit time.
    """
    if diffusivity not in ("passage", "mean-field"):
        raise ValueError(f"diffusivity: must be 'passage' or 'mean-field', got {diffusivity!r}")
    lam = _check_rule(rule)
    grid, rho_s, spots, spot_diffusivity_tensor, r1, r2 = _pairs_local.localise(
        grid, rho_s, spots, kernel, r1, r2, spot_diffusivity_tensor)
    X, X1, X2 = _two_point_integrals(grid, rho_s, spots, kernel, r1, r2,
                                     spot_diffusivity_tensor)
    out = {k: X1[k] + X2[k] - 2.0 * X[k] for k in DIFFUSIVITY_KEYS[grid.dims]}
    if diffusivity == "passage":
        D_s = spot_diffusivity(grid, spots, spot_diffusivity_tensor)
        T = _passage.source_tensor(grid, spots, D_s, kernel, lam)
        p1, p2 = _as_point(grid, r1, "r1"), _as_point(grid, r2, "r2")
        rho = np.asarray(rho_s, dtype=float)
        for p, X_mf in ((p1, X1), (p2, X2)):   # each particle's own D_p: passage for mean field
            own = _cross_integrals(grid, rho, T, kernel, p, p)
            for k in out:
                out[k] += own.get(k, 0.0) - X_mf[k]
        _passage.add_pair_correction(grid, rho_s, spots, kernel, r1, r2,
                                     spot_diffusivity_tensor, lam, out)
    return out
