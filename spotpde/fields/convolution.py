"""Discrete convolution of grid fields with a centred stencil, by FFT (2D and 3D).

The operation is the discrete sum

    out[i] = sum_j stencil[j] f[i - j],      j in [-m, m] per axis (stencil centred, odd sizes),

with ``out`` the same shape as ``f``. No hidden factors: the continuum convolution
``int w(r - s) f(s) ds`` is ``h**dims * convolve(f, kernel.sample(h))``.

Modes:

* ``"linear"``: ``f`` is zero outside the array (spots outside the silo do not exist);
  never wraps. Implemented as a circular convolution of length ``L >= n + m`` per axis
  (padding by the stencil half-width only): for output indices ``0 <= i < n`` the
  wrapped indices ``(i - j) mod L`` with ``i - j`` outside ``[0, n)`` land in the zero
  padding ``[n, L)`` exactly when ``L >= n + m``. Stencil offsets ``|j| >= n`` cannot
  reach any output and are cropped first, so a stencil wider than the domain costs
  nothing extra. ``L`` is the next fast FFT length.
* ``"periodic"``: ``f[i - j]`` is taken modulo ``n``; the stencil is folded onto the
  period (offsets ``j`` and ``j + n`` add up), transform length ``n``.

The kernel spectrum ``rfftn(stencil placed with its centre at index 0)`` is computed
once per (stencil, field shape, mode, backend, precision) and cached; one call may
convolve several fields with the same stencil.

Precision: double by default. ``precision="single"`` transforms in float32 (``scipy.fft``,
the spectrum rounded to complex64) and returns float32 arrays: half the bytes and about
2.5 times the speed, with errors of a few 1e-7 of the result's maximum (the 3D slab's
spot density at d/4: 2.5e-7, against a discretisation error of the fields of 4e-3 to
2e-2 of their maxima, ``benchmarks/slab3d.py --precision``). :func:`precision_for`
chooses it for 3D grids of at least :data:`SINGLE_PRECISION_CELLS` cells. Backends: planned pyFFTW real transforms (default when
importable, ``threads`` = cores available, wisdom cached on disk; see
:mod:`spotpde.fields._fft`) or ``scipy.fft`` with ``workers`` = cores. Both give the same
result to round-off. Reference for the scheme: the convolution theorem for the DFT,
e.g. Press et al., Numerical Recipes, 3rd ed., sec. 13.1 (zero padding against wrap).
"""

from __future__ import annotations

import contextlib
import math
import threading
from collections import OrderedDict
from typing import Sequence

import numpy as np
import scipy.fft

from . import _fft

__all__ = ["convolve", "convolve_padded", "Convolver", "MODES", "BACKENDS", "fft_shape",
           "clear_caches", "PRECISIONS", "precision_for", "SINGLE_PRECISION_CELLS"]

MODES = ("linear", "periodic")
BACKENDS = _fft.BACKENDS
PRECISIONS = ("double", "single")
#: 3D grids from this size on transform in single precision (:func:`precision_for`):
#: the transforms are then the fields' largest arrays, and their error (a few 1e-7 of
#: the maximum) is four orders below the fields' discretisation error at such spacings.
SINGLE_PRECISION_CELLS = 1_000_000


def precision_for(shape: Sequence[int]) -> str:
    """``"single"`` for 3D grids of at least :data:`SINGLE_PRECISION_CELLS` cells, else
    ``"double"``: the precision of the particle fields' whole-grid transforms."""
    return "single" if len(shape) == 3 and math.prod(shape) >= SINGLE_PRECISION_CELLS \
        else "double"

_CACHE_SIZE = 6
_cache: OrderedDict = OrderedDict()
_cache_lock = threading.Lock()


def _check_stencil(stencil) -> np.ndarray:
    s = np.asarray(stencil)
    if np.iscomplexobj(s):
        raise ValueError("stencil must be real, got a complex array")
    s = np.ascontiguousarray(s, dtype=np.float64)
    if s.ndim not in (1, 2, 3):
        raise ValueError(f"stencil must have 1, 2 or 3 dimensions, got {s.ndim}")
    if any(n % 2 == 0 for n in s.shape):
        raise ValueError(f"stencil sizes must all be odd (centred), got shape {s.shape}")
    if not np.all(np.isfinite(s)):
        raise ValueError("stencil contains NaN or infinite values")
    return s


def _check_mode(mode: str) -> str:
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    return mode


def fft_shape(field_shape: Sequence[int], stencil_shape: Sequence[int], mode: str = "linear",
              backend: str | None = None) -> tuple[int, ...]:
    """Transform shape used for a field/stencil pair.

    ``linear``: next fast length of ``n + min(m, n - 1)`` per axis; ``periodic``: ``n``.
    """
    mode = _check_mode(mode)
    backend = _fft.resolve_backend(backend)
    if mode == "periodic":
        return tuple(int(n) for n in field_shape)
    target = [n + min((k - 1) // 2, n - 1) for n, k in zip(field_shape, stencil_shape)]
    return _fft.next_fast_shape(tuple(target), backend)


def _wrap(stencil: np.ndarray, L: tuple[int, ...]) -> np.ndarray:
    """Place ``stencil[m + j]`` at index ``j mod L`` per axis, adding entries that coincide.

    Per axis: zero-pad the ``2m + 1`` entries to a multiple ``K L`` of the period, fold by
    summing the ``K`` blocks (entry ``p`` then holds the offsets ``p - m + k L``), and
    rotate by ``-m`` so that offset 0 sits at index 0.
    """
    out = stencil
    for axis, n in enumerate(L):
        k = out.shape[axis]
        m = (k - 1) // 2
        blocks = -(-k // n)
        pad = [(0, 0)] * out.ndim
        pad[axis] = (0, blocks * n - k)
        padded = np.pad(out, pad)
        shape = out.shape[:axis] + (blocks, n) + out.shape[axis + 1:]
        out = np.roll(padded.reshape(shape).sum(axis=axis), -m, axis=axis)
    return out


class Convolver:
    """A reusable convolution of fields of one shape with one stencil.

    Holds the kernel spectrum; the pyFFTW plans are shared through a cache in
    :mod:`spotpde.fields._fft`. Calling it is :func:`convolve` without the lookup.

    Args:
        stencil: real array, odd size on every axis, centred; same ndim as the fields.
        shape: the field shape (array order).
        mode: ``"linear"`` (zero padding) or ``"periodic"``.
        backend: ``"pyfftw"``, ``"scipy"`` or ``None`` (pyfftw when importable).
    """

    def __init__(self, stencil, shape: Sequence[int], mode: str = "linear",
                 backend: str | None = None, precision: str = "double"):
        s = _check_stencil(stencil)
        self.mode = _check_mode(mode)
        if precision not in PRECISIONS:
            raise ValueError(f"precision: must be one of {PRECISIONS}, got {precision!r}")
        self.precision = precision
        # single precision: scipy.fft (the planned pyFFTW buffers are float64)
        self.backend = "scipy" if precision == "single" else _fft.resolve_backend(backend)
        self.shape = tuple(int(n) for n in shape)
        if len(self.shape) != s.ndim:
            raise ValueError(f"field shape {self.shape} and stencil shape {s.shape} differ in dimensions")
        if any(n < 1 for n in self.shape):
            raise ValueError(f"field shape must be positive, got {self.shape}")
        if self.mode == "linear":
            # offsets |j| >= n never reach an output cell: crop them
            crop = tuple(slice(max(0, (k - 1) // 2 - (n - 1)), k - max(0, (k - 1) // 2 - (n - 1)))
                         for k, n in zip(s.shape, self.shape))
            s = s[crop]
        self.stencil_shape = s.shape
        self.fft_shape = fft_shape(self.shape, s.shape, self.mode, self.backend)
        spec = scipy.fft.rfftn(_wrap(s, self.fft_shape), workers=_fft.threads())
        if precision == "single":
            spec = spec.astype(np.complex64)
        if self.backend == "pyfftw":
            spec /= float(np.prod(self.fft_shape))  # FFTW's inverse is unnormalised
            self._spectrum = _aligned_copy(spec)
        else:
            self._spectrum = spec
        self._region = tuple(slice(0, n) for n in self.shape)

    @property
    def spectrum(self) -> np.ndarray:
        """The kernel spectrum on the transform grid (pyfftw: divided by ``prod(fft_shape)``)."""
        return self._spectrum

    def __call__(self, fields):
        """Convolve one array, a stacked array (one more leading axis), or a sequence.

        Returns:
            The same kind as the input: an array, a stacked array, a list or a tuple.
        """
        if isinstance(fields, np.ndarray) or not isinstance(fields, (list, tuple)):
            a = np.asarray(fields)
            if a.ndim == len(self.shape):
                return self._one(a)
            if a.ndim == len(self.shape) + 1:
                return np.stack([self._one(f) for f in a]) if len(a) else np.empty((0,) + self.shape)
            raise ValueError(f"field of shape {a.shape} does not match the convolver shape {self.shape}")
        out = [self._one(np.asarray(f)) for f in fields]
        return tuple(out) if isinstance(fields, tuple) else out

    def _one(self, f: np.ndarray) -> np.ndarray:
        if np.iscomplexobj(f):
            raise ValueError("fields must be real, got a complex array")
        if f.shape != self.shape:
            raise ValueError(f"field of shape {f.shape} does not match the convolver shape {self.shape}")
        if self.backend == "scipy":
            w = _fft.threads()
            if self.precision == "single":
                f = f.astype(np.float32)
            spec = scipy.fft.rfftn(f, s=self.fft_shape, workers=w)
            spec *= self._spectrum
            return scipy.fft.irfftn(spec, s=self.fft_shape, workers=w)[self._region].copy()
        plan = _fft.get_plan(self.fft_shape)
        with plan.lock:
            if plan.filled != self.shape:
                plan.real_in[...] = 0.0
            plan.real_in[self._region] = f
            plan.filled = self.shape
            plan.forward.execute()
            np.multiply(plan.spectrum, self._spectrum, out=plan.spectrum)
            plan.inverse.execute()
            return plan.real_out[self._region].copy()


    @contextlib.contextmanager
    def padded(self, f: np.ndarray, pad: int = 1, prepare=None):
        """The convolution of ``f`` zero-padded by ``pad`` cells per side, lent for a ``with`` block.

        The same sums as ``self(np.pad(f, pad))`` (the convolver's shape is the padded
        one), without forming the padded array or copying the result: pyfftw writes ``f``
        into the plan's input buffer at offset ``pad`` (its zero border survives between
        calls of this shape) and yields a view of the output buffer. The view is valid
        inside the block only, and the plan is locked meanwhile: do not convolve with a
        plan of the same transform shape inside it. ``prepare(view)``, if given, may
        change the copy of ``f`` in place before the transform (e.g. scale a few columns).
        """
        f = np.asarray(f)
        if np.iscomplexobj(f):
            raise ValueError("fields must be real, got a complex array")
        if tuple(n + 2 * pad for n in f.shape) != self.shape:
            raise ValueError(f"field of shape {f.shape} padded by {pad} does not match the "
                             f"convolver shape {self.shape}")
        inner = tuple(slice(pad, pad + n) for n in f.shape)
        if self.backend == "scipy":
            padded = np.pad(f, pad)
            if prepare is not None:
                prepare(padded[inner])
            yield self._one(padded)
            return
        plan = _fft.get_plan(self.fft_shape)
        with plan.lock:
            if plan.filled != ("padded", self.shape, pad):
                plan.real_in[...] = 0.0
            plan.real_in[inner] = f
            if prepare is not None:
                prepare(plan.real_in[inner])
            plan.filled = ("padded", self.shape, pad)
            plan.forward.execute()
            np.multiply(plan.spectrum, self._spectrum, out=plan.spectrum)
            plan.inverse.execute()
            yield plan.real_out[self._region]


def convolve_padded(f, stencil, pad: int = 1, backend: str | None = None, prepare=None):
    """``convolve(np.pad(f, pad), stencil, mode="linear")``, lent for a ``with`` block.

    See :meth:`Convolver.padded`: the result is a view of the transform's output buffer,
    valid (and the plan locked) inside the block only; ``prepare`` changes the copy of
    ``f`` in place before the transform.
    """
    s = np.asarray(stencil)
    if np.iscomplexobj(s) or s.dtype != np.float64 or not s.flags.c_contiguous:
        s = _check_stencil(s)
    backend = _fft.resolve_backend(backend)
    shape = tuple(int(n) + 2 * pad for n in np.shape(f))
    if len(shape) != s.ndim:
        raise ValueError(f"field of shape {np.shape(f)} and stencil of shape {s.shape} differ "
                         f"in dimensions")
    return _get_convolver(s, shape, "linear", backend).padded(f, pad, prepare)


def _aligned_copy(a: np.ndarray) -> np.ndarray:
    out = _fft.pyfftw.empty_aligned(a.shape, dtype=a.dtype)
    out[...] = a
    return out


def _summary(s: np.ndarray) -> tuple:
    flat = s.reshape(-1)
    return (s.shape, float(flat.sum()), float(flat[0]), float(flat[flat.size // 2]), float(flat[-1]))


def _get_convolver(stencil: np.ndarray, shape, mode: str, backend: str,
                   precision: str = "double") -> Convolver:
    """Cached :class:`Convolver`: key is a cheap summary, confirmed by ``array_equal``.

    A stencil with NaN never compares equal, so it always reaches the validating constructor.
    """
    if stencil.ndim not in (1, 2, 3) or stencil.size == 0:
        stencil = _check_stencil(stencil)
    key = (backend, mode, precision, tuple(shape), _summary(stencil))
    with _cache_lock:
        entry = _cache.get(key)
        if entry is not None and np.array_equal(entry[0], stencil):
            _cache.move_to_end(key)
            return entry[1]
    conv = Convolver(stencil, shape, mode=mode, backend=backend, precision=precision)
    with _cache_lock:
        _cache[key] = (stencil.copy(), conv)
        while len(_cache) > _CACHE_SIZE:
            _cache.popitem(last=False)
    return conv


def clear_caches() -> None:
    """Drop the cached convolvers (kernel spectra) and pyFFTW plans (their buffers): about
    three padded grid arrays for each shape used; the next call rebuilds what it needs."""
    with _cache_lock:
        _cache.clear()
    _fft.clear_plans()


def convolve(fields, stencil, mode: str = "linear", backend: str | None = None, *,
             precision: str = "double"):
    """Discrete convolution ``out[i] = sum_j stencil[j] f[i - j]`` of fields with a centred stencil.

    Args:
        fields: one real array (2D or 3D, array order), a stacked array with one more
            leading axis, or a list/tuple of arrays of one shape; all share one kernel
            spectrum (computed once and cached across calls).
        stencil: real array with odd sizes, centred, same ndim as each field (e.g.
            ``kernel.sample(h)``); multiply the result by ``h**dims`` for the integral.
        mode: ``"linear"`` (zero outside the domain, never wraps) or ``"periodic"``.
        backend: ``"pyfftw"`` (default when importable), ``"scipy"``, or ``None``.
        precision: ``"double"`` or ``"single"`` (float32 transforms with ``scipy.fft``,
            whatever ``backend`` says; float32 results).

    Returns:
        The same kind as ``fields``: an array (each the shape of a field), a stacked
        array, a list or a tuple.

    Raises:
        ValueError: for a bad mode or backend, an even-sized or non-finite stencil, or
            fields whose shapes differ from each other or from the stencil's ndim.
    """
    s = np.asarray(stencil)
    if np.iscomplexobj(s) or s.dtype != np.float64 or not s.flags.c_contiguous:
        s = _check_stencil(s)  # converts (or raises); full checks also run on a cache miss
    mode = _check_mode(mode)
    backend = _fft.resolve_backend(backend)
    if isinstance(fields, (list, tuple)):
        if len(fields) == 0:
            return type(fields)()
        shapes = {np.shape(f) for f in fields}
        if len(shapes) != 1:
            raise ValueError(f"all fields must share one shape, got {sorted(shapes)}")
        shape = shapes.pop()
    else:
        a = np.asarray(fields)
        shape = a.shape if a.ndim == s.ndim else a.shape[1:]
        fields = a
    if len(shape) != s.ndim:
        raise ValueError(f"fields of shape {shape} and stencil of shape {s.shape} differ in dimensions")
    return _get_convolver(s, shape, mode, backend, precision)(fields)
