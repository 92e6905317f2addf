"""The wavenumber grids of the passage quadratures (:mod:`._passage`), and their size.

Shared by the quadratures themselves and by the memory estimate of a case
(:mod:`spotpde.app._resources`), which sizes them before anything is computed: the
one-particle grid grows like ``b / kernel size`` without bound, the grid of pair
separations is capped at :data:`PAIR_MAX_NODES`. Lengths in d, wavenumbers in 1/d.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft

#: Real-space extent of the kernel in units of its scale length (support / cut-off).
_EXTENT = {"uniform": 1.0, "gaussian": 7.0, "exponential": 14.0}
#: Grid spacing in units of the kernel scale length (k_max = pi / h).
_H = {"uniform": 1.0 / 24.0, "gaussian": 1.0 / 6.0, "exponential": 1.0 / 8.0}
#: Peak bytes a node of the one-particle grid costs (``|w^|^2``, the weights ``M`` of two
#: components, complex ``Gamma`` and the pole terms: 98 measured with tracemalloc, every
#: shape, 2D and 3D).
BYTES_PER_NODE = 100
#: Nodes of the pair-separation grid at most (coarser spacing beyond), and its peak bytes
#: per node (78 measured at the cap).
PAIR_MAX_NODES = 4.2e6
PAIR_BYTES_PER_NODE = 80


def _shape(kernel) -> str:
    name = getattr(kernel, "shape_name", "") or type(kernel).__name__.lower()
    return name if name in _EXTENT else "exponential"


def _spread(kernel, b, b_par) -> float:
    """How far a spot strays from its path while it passes a particle, in d."""
    ext, az = _EXTENT[_shape(kernel)], kernel.a_h / kernel.aspect
    return math.sqrt(4.0 * b * ext * az) + math.sqrt(2.0 * b_par * ext * az)


def _quadrature_grid(kernel, dims, b, b_par, scale=1.0, kscale=1.0):
    """The ``k`` grid of the one-particle quadrature: ``(nz, dkz, kmax_z, nh, dkh,
    kmax_h)``, the ``2 nz + 1`` nodes ``k_z = j dkz`` and ``nh + 1`` nodes ``k_perp = i dkh``."""
    shape = _shape(kernel)
    ah, az = kernel.a_h, kernel.a_h / kernel.aspect
    h = _H[shape] / kscale
    ext = _EXTENT[shape]
    # k_perp: half line (2D: even integrand, 3D: radial), trapezoid; k_z: symmetric nodes
    kmax_h, kmax_z = math.pi / (h * ah), math.pi / (h * az)
    spread = _spread(kernel, b, b_par)
    Lz = 8.0 * (2.0 * ext * az + spread + 2.0 * b_par) * scale
    dkz = 2.0 * math.pi / Lz
    nz = math.ceil(kmax_z / dkz)
    dkh = 2.0 * math.pi / (4.0 * (2.0 * ext * ah + spread)) / scale
    if dims == 3:  # the radial trapezoid is second order at k_perp = 0
        dkh = min(dkh, 0.05 / ah / scale)
    nh = math.ceil(kmax_h / dkh)
    return nz, dkz, kmax_z, nh, dkh, kmax_h


def pair_grid(kernel, dims, b, b_par, far):
    """Nodes per axis and spacings ``(n, hs)`` (axis order x, [y,] z) of the periodic grid
    of the pair quadrature, for separations up to ``far`` (per axis, d)."""
    shape = _shape(kernel)
    ah, az = kernel.a_h, kernel.a_h / kernel.aspect
    ext = _EXTENT[shape]
    spread = _spread(kernel, b, b_par)
    h = _H[shape] if dims == 2 else 2.0 * _H[shape]
    hs = [h * ah] * (dims - 1) + [h * az]
    L = [max(4.0 * (2.0 * ext * a + spread) + 2.0 * f, 16.0 * a)
         for a, f in zip([ah] * (dims - 1) + [az], far)]
    if dims == 3:  # bound the 3D grid (128^3 nodes): coarser spacing, same box
        hs = [max(hi, Li / 128.0) for Li, hi in zip(L, hs)]
    while math.prod(Li / hi for Li, hi in zip(L, hs)) > PAIR_MAX_NODES:  # anisotropic kernels
        a = int(np.argmax([Li / hi for Li, hi in zip(L, hs)]))
        hs[a] *= 1.25
    n = [scipy.fft.next_fast_len(int(math.ceil(Li / hi))) for Li, hi in zip(L, hs)]
    return n, hs


def pair_bytes(kernel, b, b_par, far) -> float:
    """Peak bytes of the pair quadrature for separations up to ``far`` (d, every axis)."""
    n, _ = pair_grid(kernel, kernel.dims, b, b_par, [far] * kernel.dims)
    return float(PAIR_BYTES_PER_NODE) * math.prod(n)
