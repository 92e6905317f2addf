"""Shared pieces of the fields on a staircase or ring grid (private).

Used by ``_axisymmetric`` (cylinders, cones) and ``_hopper`` (2D wedges): the passage
drift's excess ``D_p - D_mf`` and the wall layer's face values ``(D_s rho_s).n / phi``
extrapolated from the active cells inward. The wall faces themselves are the grid's
(``grid.geometry.wall_faces()``, ``horizontal_faces()``).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ._common import _is_zero as _zero


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
