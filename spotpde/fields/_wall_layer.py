"""The wall layer of the particle drift at reflecting side walls (private).

Used by :func:`spotpde.coefficients.particle_fields`. Integrating the drift's
``2 lam w * div(D_s rho_s)`` by parts, and adding the mean push of spots reflected at the
wall, leaves the boundary term (docs/coefficients.md)

    wall layer^a(r) = (1 - 2 lam) * integral_walls (D_s rho_s)^ab n_b (r_w) w(r - r_w) dA_w

in d per unit time (``D_s rho_s`` in d**2 per unit time per d**dims, ``dA_w`` in
d**(dims-1)). It vanishes for the midpoint rule ``lam = 1/2`` and with open walls.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import scipy.signal

from . import _walls
from ._common import _COMPONENTS, _SUBSAMPLE, _axis, _is_zero, _pair
from ..grid import Grid
from ..parameters import wall_weight

# _COMPONENTS, _SUBSAMPLE, _axis, _is_zero, _pair live in coefficients, which imports
# this module: they are imported inside the functions (as in _walls and _passage).


def _face_value(f: np.ndarray, axis: int, side: int) -> np.ndarray:
    """Value on the boundary face from the three nearest cell centres (third order)."""
    idx = (0, 1, 2) if side < 0 else (-1, -2, -3)
    f0, f1, f2 = (np.take(f, i, axis=axis) for i in idx)
    return (15.0 * f0 - 10.0 * f1 + 3.0 * f2) / 8.0


def _wall_layer(grid: Grid, kernel, comp: str, g_face: Mapping[int, np.ndarray]) -> np.ndarray:
    """``sum_walls integral g(r_w) w(r - r_w) dA_w`` for the two walls normal to ``comp``.

    Args:
        grid: the grid.
        kernel: influence kernel (``evaluate``, ``reach``).
        comp: ``"x"`` or ``"y"``: the wall normal.
        g_face: ``{-1: g on the low wall, +1: g on the high wall}``, arrays over the wall
            (the grid shape with the normal axis removed), already multiplied by ``n``.

    Returns:
        grid-shaped array. The tangential integral is a discrete sum over wall cells with
        ``w`` averaged over each cell (sub-sampled); along the normal, ``w`` is evaluated
        at the particle's cell centre.
    """
    h = grid.spacing
    axis = _axis(grid, comp)
    reach_h, reach_v = kernel.reach
    comps = _COMPONENTS[grid.dims]
    tangential = [c for c in ("z", "y", "x") if c in comps and c != comp]
    lo, hi = grid.y_range if comp == "y" else grid.x_range
    n_normal = grid.shape[axis]
    out = np.zeros(grid.shape)
    # tangential stencil offsets (in cells), centred, covering the reach
    half = {c: int(np.ceil((reach_v if c == "z" else reach_h) / h)) + 1 for c in tangential}
    sub = (np.arange(_SUBSAMPLE) + 0.5) / _SUBSAMPLE - 0.5
    t_offsets = [np.add.outer(np.arange(-half[c], half[c] + 1) * h, sub * h).ravel()
                 for c in tangential]
    t_mesh = np.meshgrid(*t_offsets, indexing="ij")
    jmax = min(n_normal, int(np.ceil(reach_h / h)) + 1)
    for side, g in g_face.items():
        if _is_zero(g) or not np.any(g):
            continue
        wall = hi if side > 0 else lo
        for j in range(jmax):
            i = n_normal - 1 - j if side > 0 else j
            centre = lo + (i + 0.5) * h
            coords = {comp: np.full(t_mesh[0].shape, centre - wall)}
            coords.update({c: m for c, m in zip(tangential, t_mesh)})
            # kernel offsets r - r_w; evaluate takes (x, z) or (x, y, z)
            args = [coords[c] for c in comps]
            w = np.asarray(kernel.evaluate(*args), dtype=float)
            if not np.any(w):
                continue
            # average the sub-samples of each tangential cell
            shape = []
            for c in tangential:
                shape += [2 * half[c] + 1, _SUBSAMPLE]
            w = w.reshape(shape).mean(axis=tuple(range(1, 2 * len(tangential), 2)))
            layer = scipy.signal.convolve(g, w, mode="same", method="direct" if w.size < 400 else "auto")
            idx = [slice(None)] * grid.dims
            idx[axis] = i
            out[tuple(idx)] += layer * h ** (grid.dims - 1)
    return out


def add_wall_layer(grid: Grid, kernel, lam: float, G: Mapping, phi: np.ndarray | None,
                   fields: dict) -> None:
    """Add ``(1 - 2 lam) * wall layer`` to ``fields["u_a"]`` in place (reflecting walls).

    Args:
        grid: the grid (nothing is added unless ``grid.walls == "reflecting"`` and
            ``lam != 0.5``).
        kernel: influence kernel (``evaluate``, ``reach``).
        lam: the rule ``lam`` in [0, 1].
        G: ``{"D_xx": rho_s D_s^xx or None, ...}``: ``rho_s D_s`` by component, ``None``
            where identically zero.
        phi: the free-volume coverage of ``spotpde.fields._walls`` (renormalised walls: the
            wall value of ``(D_s rho_s) n`` is divided by ``phi`` on the wall) or ``None``.
        fields: the particle fields, ``u_x``, [``u_y``,] ``u_z`` updated.
    """
    if grid.walls != "reflecting" or lam == 0.5:
        return
    comps = _COMPONENTS[grid.dims]
    for n in comps:
        if n == "z":
            continue
        axis = _axis(grid, n)
        for a in comps:
            g = G[_pair(a, n)]
            if g is None:
                continue
            faces = {-1: -_face_value(g, axis, -1), +1: _face_value(g, axis, +1)}
            if phi is not None:  # renormalised: (D_s rho_s)·n / phi on the wall
                faces = {s: v / _walls.face_value(phi, axis, s) for s, v in faces.items()}
            fields[f"u_{a}"] += wall_weight(lam) * _wall_layer(grid, kernel, n, faces)
