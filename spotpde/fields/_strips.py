"""Convolutions of sources that live on thin boxes (wall strips, boundary planes), batched.

The constant-coefficient fields (``_constant``, ``_walls``) are one whole-grid transform
plus corrections whose sources are supported within a few cells (boundary planes) or a
stencil half-width (the renormalised walls' strips) of the boundary. Each correction is a
full linear convolution of its box with the kernel stencil, by FFT on the box widened by
the stencil (``scipy.fft.rfftn``; the stencil's spectrum cached per transform shape), the
sources of one box shape stacked in one call: exact to round-off (the convolution
theorem with zero padding to the full length; e.g. Press et al., Numerical Recipes, 3rd
ed., sec. 13.1), cheap for boxes a few stencils thick. Private.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict

import numpy as np
import scipy.fft

from ..geometry import derivative

__all__ = ["box_convolutions", "add", "add_derivative", "clear_spectra"]

_SPECTRA: OrderedDict = OrderedDict()
_SPECTRA_SIZE = 8
_lock = threading.Lock()
#: Bytes of the complex spectra transformed in one batch: a group of sources larger than
#: this is transformed in several batches (the strips of a thin 3D slab are most of the
#: grid: its four sources of one box shape would otherwise hold about 4 grid arrays of
#: spectrum and 4 of output at once).
BATCH_BYTES = 64 * 1024**2


def _spectrum(stencil: np.ndarray, fshape: tuple[int, ...]) -> np.ndarray:
    """``rfftn(stencil, fshape)``, cached (key: shape and bytes of the stencil)."""
    key = (fshape, stencil.shape, stencil.tobytes())
    with _lock:
        spec = _SPECTRA.get(key)
        if spec is not None:
            _SPECTRA.move_to_end(key)
            return spec
    spec = scipy.fft.rfftn(stencil, fshape)
    with _lock:
        _SPECTRA[key] = spec
        while len(_SPECTRA) > _SPECTRA_SIZE:
            _SPECTRA.popitem(last=False)
    return spec


def clear_spectra() -> None:
    """Drop the cached stencil spectra."""
    with _lock:
        _SPECTRA.clear()


def box_convolutions(requests, stencils, shape):
    """Linear convolutions of sources supported on boxes, batched, yielded group by group.

    ``requests``: ``[(name, box, source on the box, stencil key), ...]``, ``box`` a tuple
    of slices in grid indices (they may reach beyond the grid, e.g. ghost planes at index
    -1 or ``n``); ``stencils``: the centred stencils by key; ``shape``: the grid's. Sources
    of one stencil and box shape are stacked and transformed together (full convolution,
    transform lengths ``scipy.fft.next_fast_len``; one thread: the transforms are small,
    a few stencils thick). Yields ``(name, target slices, values)`` for every request,
    its box widened by the stencil's half-widths and cut to the grid, to be added with
    :func:`add`: one group's results at a time, so that only one group's transforms are
    in memory (in a thin 3D slab the walls' strips span most of the grid), in batches of
    at most :data:`BATCH_BYTES` of spectrum.
    """
    groups: dict = {}
    for i, (_, _, sub, key) in enumerate(requests):
        groups.setdefault((key, sub.shape), []).append(i)
    batches = []
    for (key, sub_shape), members in groups.items():
        full_shape = tuple(a + b - 1 for a, b in zip(sub_shape, stencils[key].shape))
        fshape = tuple(scipy.fft.next_fast_len(n, real=True) for n in full_shape)
        size = 16 * math.prod(fshape[:-1]) * (fshape[-1] // 2 + 1)
        step = max(1, BATCH_BYTES // size)
        batches += [(key, full_shape, fshape, members[i:i + step])
                    for i in range(0, len(members), step)]
    for key, full_shape, fshape, members in batches:
        stencil = stencils[key]
        axes = tuple(range(1, stencil.ndim + 1))
        src = np.stack([requests[i][2] for i in members])
        spec = scipy.fft.rfftn(src, fshape, axes=axes, workers=1)
        del src
        spec *= _spectrum(stencil, fshape)
        full = scipy.fft.irfftn(spec, fshape, axes=axes, workers=1, overwrite_x=True)
        del spec
        for j, i in enumerate(members):
            name, box = requests[i][:2]
            dst, cut = [], []
            for sl, k_s, n, k in zip(box, stencil.shape, shape, full_shape):
                start = sl.start - (k_s - 1) // 2              # grid index of full[0]
                lo, hi = max(0, start), min(n, start + k)
                dst.append(slice(lo, hi))
                cut.append(slice(lo - start, hi - start))
            yield name, tuple(dst), full[j][tuple(cut)]
        del full


def add(target: np.ndarray, parts, factor: float) -> None:
    """``target[dst] += factor * values`` for every part of :func:`box_convolutions`."""
    for dst, values in parts:
        target[dst] += factor * values


def add_derivative(target: np.ndarray, parts, h: float, axis: int, factor: float) -> None:
    """``target += factor * grid.derivative(F, h, axis)``, ``F`` zero but on the parts.

    ``parts``: ``[(target slices, values), ...]`` (:func:`box_convolutions`), not
    overlapping. Each part is differentiated on its box widened by three cells along
    ``axis`` (cut to the grid): the derivative of ``F`` vanishes beyond, and on the widened
    cells the box's own formulas (one-sided where the widened box ends inside the grid)
    read only zeros, as the whole grid's do; so this is the whole-grid derivative, term by
    term (the derivative is linear).
    """
    n = target.shape[axis]
    for dst, values in parts:
        sl = dst[axis]
        lo, hi = max(0, sl.start - 3), min(n, sl.stop + 3)
        wide = list(dst)
        wide[axis] = slice(lo, hi)
        buf = np.zeros(tuple(s.stop - s.start for s in wide))
        inner = [slice(None)] * target.ndim
        inner[axis] = slice(sl.start - lo, sl.stop - lo)
        buf[tuple(inner)] = values
        target[tuple(wide)] += factor * derivative(buf, h, axis)
