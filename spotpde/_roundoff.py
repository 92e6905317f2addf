"""Round-off negatives of quantities that are non-negative by construction."""

from __future__ import annotations

import numpy as np


def clip_roundoff(a: np.ndarray, rel: float = 1e-9, *, inplace: bool = False) -> np.ndarray:
    """Set round-off negatives (``-rel * max|a| <= a < 0``) of a non-negative field to zero.

    Densities and the diagonal of a diffusivity tensor are non-negative by construction,
    but solvers and FFT convolutions leave values like ``-1e-17 * max`` where they vanish,
    which positivity checks downstream (the tracer's) rightly reject. Larger negatives
    are a real defect and are left alone for those checks to catch.

    Args:
        a: the field.
        rel: the largest negative treated as round-off, relative to ``max|a|``.
        inplace: zero them in ``a`` itself (which the caller owns) instead of a copy: the
            same values without allocating another array.

    Returns:
        ``a`` with its round-off negatives zeroed (``a`` itself when it has none).
    """
    lowest = a.min() if a.size else 0.0
    if not lowest < 0:                   # nothing negative (or NaN: left alone)
        return a
    scale = max(float(a.max()), -float(lowest))
    if lowest >= -rel * scale:           # every negative is round-off: three passes in all
        return np.maximum(a, 0.0, out=a) if inplace else np.maximum(a, 0.0)
    tiny = (a < 0) & (a >= -rel * scale)
    if not np.any(tiny):
        return a
    if inplace:
        a[tiny] = 0.0
        return a
    return np.where(tiny, 0.0, a)
