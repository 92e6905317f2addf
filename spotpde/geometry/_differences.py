"""Cell-centre differences on a box and on a staircase (private; lengths in d).

:func:`derivative` is the box's second-order difference (``numpy.gradient``,
``edge_order=2``); :func:`masked_derivative` is the same where a cell has active
neighbours on both sides and one-sided next to a wall (an array end or an inactive cell),
with the even continuation across the symmetry axis of an axisymmetric grid.
"""

from __future__ import annotations

import numpy as np


def derivative(f: np.ndarray, spacing: float, axis: int) -> np.ndarray:
    """Derivative of a cell-centred field along one array axis, in f's units per d.

    Second-order central differences inside and second-order one-sided differences at
    the two ends (``numpy.gradient``, ``edge_order=2``); an axis of two cells gets the
    first-order difference, an axis of one cell a zero derivative.

    Args:
        f: field on the grid (array order ``(z, x)`` / ``(z, y, x)``).
        spacing: cell size ``h`` in d.
        axis: the array axis to differentiate along.
    """
    n = f.shape[axis]
    if n >= 3:   # numpy.gradient's formulas, bit for bit, in fewer passes over the array
        f = np.asarray(f, dtype=float)
        out = np.empty_like(f)

        def at(index):
            i = [slice(None)] * f.ndim
            i[axis] = index
            return tuple(i)

        inner = out[at(slice(1, -1))]
        np.subtract(f[at(slice(2, None))], f[at(slice(0, -2))], out=inner)
        np.divide(inner, 2.0 * spacing, out=inner)
        a, b, c = -1.5 / spacing, 2.0 / spacing, -0.5 / spacing
        out[at(0)] = a * f[at(0)] + b * f[at(1)] + c * f[at(2)]
        out[at(-1)] = -c * f[at(-3)] - b * f[at(-2)] - a * f[at(-1)]
        return out
    if n == 2:
        return np.gradient(f, spacing, axis=axis, edge_order=1)
    return np.zeros_like(f)


def masked_derivative(f: np.ndarray, h: float, axis: int, active: np.ndarray,
                      even_axis: bool = False) -> np.ndarray:
    """Second-order derivative along ``axis`` that never differences across a wall.

    Central where both neighbours are active cells, second-order one-sided
    ``(-3 f0 + 4 f1 - f2) / 2h`` where one side is a wall (the array end or an inactive
    cell) and two cells are available on the other, first order with one, zero with
    none (``numpy.gradient(edge_order=2)`` without inactive cells). ``even_axis``: the
    field is even about the low end of axis 1 (the symmetry axis ``r = 0``), whose ghost
    value at ``r = -h/2`` is ``f[..., 0]``. Units: f's per d (``h`` in d); zero on
    inactive cells.
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


def is_zero(value) -> bool:
    """True for ``None`` or a scalar zero (an absent tensor component)."""
    return value is None or (np.ndim(value) == 0 and float(value) == 0.0)
