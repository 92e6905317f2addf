"""Ring-integrated kernel weights and the banded ring convolution (axisymmetric grids; private).

On an axisymmetric grid a field ``f(r, z)`` stands for the 3D field ``f(x)`` that does not
depend on the azimuth. The 3D convolution with a horizontally isotropic kernel ``w``
becomes, for a source piecewise constant on the grid's ring cells (cell ``j`` is the ring
``r' in [j h, (j + 1) h]``, ``z' in [z_k - h/2, z_k + h/2]``)::

    (w * f)(r_i, z_k) = sum_{j, l} W_m[l, i, j] f[k + l, j]

    W_m[l, i, j] = int_{z-cell l} dz' int_{r-cell j} r' dr' int_0^{2 pi} w(s, z') cos(m t) dt,
    s = sqrt(r_i^2 + r'^2 - 2 r_i r' cos t),

with ``m = 0`` for scalars and the vertical component of vectors and ``m = 1`` for radial
components (the source's radial unit vector projected on the target's: ``cos t``). This
is the cylindrical analogue of ``kernel.sample`` (cell-averaged ``w``): the kernel is
integrated exactly over every source cell, so in uniform flow the sums reproduce ``V1``
and ``V2``; every ``m = 0`` row is rescaled to sum to ``V_power`` over all rings (as
``kernel.sample`` rescales its stencil; the factor differs from 1 by the quadrature
error: 3e-11 for the sphere, 2e-15 for the Gaussian, 5e-10 for the exponential). "Face" weights
``rf int dt w cos(m t)`` on the ring of radius ``rf = (j + 1) h`` are the wall layer's.

The integrals (docs/walls.md, "Axisymmetric silos"):

* uniform kernel (sphere / ellipsoid): the azimuthal integral is exact (the arc of the
  source circle inside the spot: ``2 t_max`` or ``2 sin t_max``); over a cell, for
  ``m = 0`` the annulus-disk overlap area is closed form (lens areas) and for ``m = 1``
  Green's theorem turns ``int cos t dA`` into the two annulus arcs (closed form) plus one
  smooth integral along the spot's circle (8-point Gauss-Legendre); the height integral
  is split where the spot's cross-section radius meets a cell edge (the integrand has
  ``(z - z*)^(3/2)`` points there) and each piece uses 12-point Gauss-Legendre after
  ``z = a + (b - a)(1 - cos(pi u))/2`` (relative to 24 / 24 points: 3e-10 for ``m = 0``,
  2.5e-7 of the largest weight for ``m = 1``). Numba.
* Gaussian: separable; the height average is the exact ``erf`` form of ``kernel.sample``
  and the azimuthal integral is ``2 pi exp(-p (r - r')^2 / 2 sigma^2) I_m(p r r'/sigma^2)
  exp(-p r r'/sigma^2)`` (scaled Bessel functions), then Gauss-Legendre in ``r'``.
* any other kernel (exponential): tensor Gauss-Legendre in ``(r', z')`` and in the azimuth
  over the kernel's reach, sub-divided in the cells next to the target (the cusp).

Convolution: FFT along ``z`` (zero-padded to at least ``nz + mz``: linear, never wraps), a
banded product along ``r`` at every vertical wavenumber: ``O(nz nx (2 mb + 1))`` per field
after the transforms, ``mb`` the kernel's reach in cells.
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
from collections import OrderedDict

import numpy as np
import scipy.fft
from numba import njit
from scipy import special

from .._cache import user_cache_dir

__all__ = ["ring_weights", "ring_convolve", "halfwidths"]

_GL16_U, _GL16_W = np.polynomial.legendre.leggauss(16)
_GL16_U = 0.5 * (_GL16_U + 1.0)
_GL16_W = 0.5 * _GL16_W
_GL12_U, _GL12_W = np.polynomial.legendre.leggauss(12)
_GL12_U = 0.5 * (_GL12_U + 1.0)
_GL12_W = 0.5 * _GL12_W
_GL8_U, _GL8_W = np.polynomial.legendre.leggauss(8)
_GL8_U = 0.5 * (_GL8_U + 1.0)
_GL8_W = 0.5 * _GL8_W
_CACHE: OrderedDict = OrderedDict()
#: unit-height ellipsoid weights (the uniform kernel's w**power is height**power times them)
_UNIT: OrderedDict = OrderedDict()
_FACTORS: OrderedDict = OrderedDict()
_CACHE_SIZE = 12


def halfwidths(kernel, h: float) -> tuple[int, int]:
    """``(mz, mb)``: the kernel's reach in cells vertically and radially (as ``kernel.sample``)."""
    rh, rz = kernel.reach
    mb = max(0, math.ceil(rh / h - 0.5 - 1e-12))
    mz = max(0, math.ceil(rz / h - 0.5 - 1e-12))
    return mz, mb


# -- the uniform kernel: exact azimuth, closed-form cell areas ----------------------------

@njit(cache=True)
def _lens(s, rho, d):
    """Area of the disk of radius ``s`` about 0 inside the disk of radius ``rho`` about ``d``."""
    if s <= 0.0 or rho <= 0.0:
        return 0.0
    if d >= s + rho:
        return 0.0
    if d <= abs(s - rho):
        m = min(s, rho)
        return math.pi * m * m
    a1 = min(1.0, max(-1.0, (d * d + s * s - rho * rho) / (2.0 * d * s)))
    a2 = min(1.0, max(-1.0, (d * d + rho * rho - s * s) / (2.0 * d * rho)))
    q = (-d + s + rho) * (d + s - rho) * (d - s + rho) * (d + s + rho)
    return s * s * math.acos(a1) + rho * rho * math.acos(a2) - 0.5 * math.sqrt(max(q, 0.0))


@njit(cache=True)
def _tmax(r, s, rho):
    """Half-angle of the circle of radius ``s`` (about 0) inside the disk ``(r, rho)``."""
    if s <= 0.0 or r <= 0.0:
        return math.pi if s < rho else 0.0
    c = (r * r + s * s - rho * rho) / (2.0 * r * s)
    return math.acos(min(1.0, max(-1.0, c)))


@njit(cache=True)
def _slice(r, r0, r1, rho, m, faces, pu, pw):
    """Integral over one height ``z'`` (the spot's cross-section a disk of radius ``rho``):
    ``int_annulus cos(m t) dA`` (cells, ``r' in [r0, r1]``) or ``r1 int cos(m t) dt``
    on the circle of radius ``r1`` (faces)."""
    if rho <= 0.0:
        return 0.0
    if faces:
        t = _tmax(r, r1, rho)
        return r1 * (2.0 * t if m == 0 else 2.0 * math.sin(t))
    if m == 0:
        return _lens(r1, rho, r) - _lens(r0, rho, r)
    # Green: int_D cos t dA = int_dD |x| n_x ds, D = annulus inside the disk
    out = 2.0 * r1 * r1 * math.sin(_tmax(r, r1, rho))
    if r0 > 0.0:
        out -= 2.0 * r0 * r0 * math.sin(_tmax(r, r0, rho))
    if r <= 0.0:
        return out
    c1 = min(1.0, max(-1.0, (r1 * r1 - r * r - rho * rho) / (2.0 * r * rho)))
    c0 = min(1.0, max(-1.0, (r0 * r0 - r * r - rho * rho) / (2.0 * r * rho)))
    p1 = math.acos(c1)
    p0 = math.acos(c0)
    if p0 > p1:
        acc = 0.0
        for q in range(pu.size):   # smooth along the arc: plain Gauss-Legendre
            phi = p1 + (p0 - p1) * pu[q]
            acc += pw[q] * (p0 - p1) * math.sqrt(max(r * r + rho * rho + 2.0 * r * rho * math.cos(phi), 0.0)) \
                * math.cos(phi)
        out += 2.0 * rho * acc
    return out


@njit(cache=True)
def _uniform_weights(nx, mb, mz, h, R, Rz, m, faces, gu, gw, pu, pw):
    """``W[l, i, b]`` of the unit-height ellipsoid (l >= mz half; mirrored by the caller)."""
    nb = 2 * mb + 1
    out = np.zeros((mz + 1, nx, nb))
    cand = np.empty(16)
    for i in range(nx):
        r = (i + 0.5) * h
        for b in range(nb):
            j = i + b - mb
            if j < 0:
                continue
            r0 = j * h
            r1 = (j + 1) * h
            if abs(r - (r0 if r < r0 else (r1 if r > r1 else r))) >= R:
                continue
            # heights where the cross-section radius meets a special radius
            nc = 0
            specials = (abs(r - r0), abs(r - r1), r + r0, r + r1, r)
            for sp in specials:
                if sp < R:
                    cand[nc] = Rz * math.sqrt(1.0 - (sp / R) ** 2)
                    nc += 1
            cand[nc] = Rz
            nc += 1
            dr = max(0.0, r0 - r, r - r1)
            for l in range(mz + 1):
                za = (l - 0.5) * h
                zb = (l + 0.5) * h
                lo = max(za, 0.0)       # even in z': integrate z' >= 0, double the l = 0 half
                hi = min(zb, Rz)
                if hi <= lo or (dr / R) ** 2 + (lo / Rz) ** 2 >= 1.0:
                    continue            # the cell lies outside the ellipsoid
                pts = np.empty(nc + 2)
                pts[0] = lo
                pts[1] = hi
                k = 2
                for c in range(nc):
                    pts[k] = min(max(cand[c], lo), hi)
                    k += 1
                pts.sort()
                total = 0.0
                for p in range(pts.size - 1):
                    a = pts[p]
                    length = pts[p + 1] - a
                    if length <= 0.0:
                        continue
                    for q in range(gu.size):
                        sub = 0.5 * (1.0 - math.cos(math.pi * gu[q]))
                        zz = a + length * sub
                        jac = length * 0.5 * math.pi * math.sin(math.pi * gu[q])
                        rho = R * math.sqrt(max(0.0, 1.0 - (zz / Rz) ** 2))
                        total += gw[q] * jac * _slice(r, r0, r1, rho, m, faces, pu, pw)
                out[l, i, b] = 2.0 * total if l == 0 else total
    return out


@njit(cache=True)
def _uniform_annuli(nx, mb, M, h, R, Rz, m, pu, pw):
    """Horizontal faces: ``int_annulus cos(m t) dA`` of the unit-height ellipsoid at the
    height offsets ``(l - M + 1/2) h``, ``l = 0 .. 2M``."""
    nb = 2 * mb + 1
    out = np.zeros((2 * M + 1, nx, nb))
    for i in range(nx):
        r = (i + 0.5) * h
        for b in range(nb):
            j = i + b - mb
            if j < 0:
                continue
            r0 = j * h
            r1 = (j + 1) * h
            for l in range(2 * M + 1):
                dz = abs((l - M + 0.5) * h)
                if dz >= Rz:
                    continue
                rho = R * math.sqrt(1.0 - (dz / Rz) ** 2)
                out[l, i, b] = _slice(r, r0, r1, rho, m, False, pu, pw)
    return out


# -- Gaussian: separable, Bessel in the azimuth ------------------------------------------

def _gaussian_weights(kernel, h, nx, mb, mz, power, m, faces, annuli=False):
    sig = kernel.a_h / math.sqrt(power)
    if annuli:   # point values at the height offsets (l - mz - 1/2) h, l = 0 .. 2 mz + 2
        dz = (np.arange(2 * mz + 3) - (mz + 1) + 0.5) * h
        zavg = np.exp(-power * dz**2 / (2.0 * kernel.a_z**2))
    else:
        half = kernel._axis_average(mz, h / kernel.a_z, power) * h       # int over z-cells
        zavg = np.concatenate([half[:0:-1], half])
    i = np.arange(nx)[:, None]
    b = np.arange(2 * mb + 1)[None, :]
    j = i + b - mb
    r = (i + 0.5) * h
    valid = j >= 0
    if faces and not annuli:
        rf = (j + 1.0) * h
        H = rf * 2.0 * math.pi * np.exp(-(r - rf) ** 2 / (2 * sig**2)) * special.ive(m, r * rf / sig**2)
    else:
        panels = max(1, math.ceil(h / sig))
        H = np.zeros(j.shape)
        for p in range(panels):
            a = j * h + p * h / panels
            for u, wq in zip(_GL16_U, _GL16_W):
                rp = a + u * h / panels
                H += (wq * h / panels) * rp * 2.0 * math.pi * np.exp(-(r - rp) ** 2 / (2 * sig**2)) \
                    * special.ive(m, r * rp / sig**2)
    H = np.where(valid, H, 0.0)
    return kernel.amplitude**power * zavg[:, None, None] * H[None, :, :]


# -- any other kernel: tensor quadrature ---------------------------------------------------

def _generic_weights(kernel, h, nx, mb, mz, power, m, faces, annuli=False):
    nq, nt = 6, 48
    gu, gw = np.polynomial.legendre.leggauss(nq)
    gu, gw = 0.5 * (gu + 1.0), 0.5 * gw
    tu, tw = np.polynomial.legendre.leggauss(nt)
    tu, tw = 0.5 * (tu + 1.0), 0.5 * tw
    reach = kernel.reach[0]
    out = np.zeros((2 * mz + 3 if annuli else mz + 1, nx, 2 * mb + 1))
    for i in range(nx):
        r = (i + 0.5) * h
        for b in range(2 * mb + 1):
            j = i + b - mb
            if j < 0:
                continue
            near = abs(b - mb) <= 1
            nsub = 4 if near else 1
            if faces and not annuli:
                rp = np.array([(j + 1.0) * h])
                rw = np.array([(j + 1.0) * h])
            else:
                edges = j * h + np.arange(nsub)[:, None] * h / nsub
                rp = (edges + gu[None, :] * h / nsub).ravel()
                rw = (np.broadcast_to(gw, (nsub, nq)) * h / nsub).ravel() * rp
            # azimuth range within the horizontal reach
            c = np.clip((r * r + rp * rp - reach * reach) / (2 * r * rp), -1.0, 1.0)
            tmax = np.arccos(c)                                   # (nr,)
            t = tmax[:, None] * tu[None, :]
            tws = tmax[:, None] * tw[None, :] * 2.0               # both signs of t
            s = np.sqrt(np.maximum(r * r + rp[:, None] ** 2 - 2 * r * rp[:, None] * np.cos(t), 0.0))
            ang = np.cos(m * t) * tws
            if annuli:   # point values at the height offsets (l - mz - 1/2) h
                zz = (np.arange(2 * mz + 3) - (mz + 1) + 0.5) * h
                wv = kernel.evaluate(s[None, :, :], 0.0 * s[None, :, :], zz[:, None, None]) ** power
                out[:, i, b] = np.einsum("zrt,r,rt->z", wv, rw, ang)
                continue
            # every height cell at once: nodes of cell l are zz[start[l]:start[l + 1]]
            zz, zw, start = [], [], [0]
            for l in range(mz + 1):
                ns = nsub if (near and l <= 1) else 1
                zedges = (l - 0.5) * h + np.arange(ns) * h / ns
                zz.append((zedges[:, None] + gu[None, :] * h / ns).ravel())
                zw.append((np.broadcast_to(gw, (ns, nq)) * h / ns).ravel())
                start.append(start[-1] + ns * nq)
            zz, zw = np.concatenate(zz), np.concatenate(zw)
            wv = kernel.evaluate(s[None, :, :], 0.0 * s[None, :, :], zz[:, None, None]) ** power
            per_node = np.einsum("zrt,r,rt->z", wv, rw, ang) * zw
            out[:, i, b] = np.add.reduceat(per_node, start[:-1])
    return out


# -- public --------------------------------------------------------------------------------

#: bump when a quadrature changes: the weights stored on disk are then recomputed
_DISK_VERSION = 2
#: False: never read or write the disk cache (benchmarks time the computation)
USE_DISK = True


def _disk(key, compute):
    """``compute()`` stored in ``<user cache>/rings/<hash>.npy`` (read back on later runs;
    any failure to read or write the file only costs the computation)."""
    if not USE_DISK:
        return compute()
    name = hashlib.sha1(repr((_DISK_VERSION,) + key).encode()).hexdigest() + ".npy"
    path = user_cache_dir() / "rings" / name
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError):
        pass
    out = compute()
    tmp = None
    try:
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".rings.", suffix=".npy", dir=path.parent)
        with os.fdopen(fd, "wb") as fh:
            np.save(fh, out, allow_pickle=False)
        os.replace(tmp, path)
        tmp = None
    except OSError:        # a full or read-only cache only costs the computation next time
        pass
    finally:               # never leave a half-written file behind (disk full, Ctrl-C)
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass
    return out


def _raw_weights(kernel, h, nx, power, m, faces, annuli=False):
    mz, mb = halfwidths(kernel, h)
    shape = getattr(kernel, "shape_name", "")
    if shape == "uniform":   # w**power = height**power * indicator: one computation
        key = ("uniform", float(kernel.a_h), float(kernel.aspect), float(h), int(nx), int(m),
               bool(faces)) + (("annuli",) if annuli else ())
        if key not in _UNIT:
            def compute():
                if annuli:
                    return _uniform_annuli(int(nx), mb, mz + 1, float(h), float(kernel.a_h),
                                           float(kernel.a_z), int(m), _GL8_U, _GL8_W)
                half = _uniform_weights(int(nx), mb, mz, float(h), float(kernel.a_h), float(kernel.a_z),
                                        int(m), bool(faces), _GL12_U, _GL12_W, _GL8_U, _GL8_W)
                return np.concatenate([half[:0:-1], half], axis=0)
            _UNIT[key] = _disk(key, compute)
            while len(_UNIT) > _CACHE_SIZE:
                _UNIT.popitem(last=False)
        return _UNIT[key] * kernel.amplitude**power
    if shape == "gaussian":   # closed forms: faster than the disk
        return _gaussian_weights(kernel, h, nx, mb, mz, power, m, faces, annuli)

    def compute():
        out = _generic_weights(kernel, h, nx, mb, mz, power, m, faces, annuli)
        return out if annuli else np.concatenate([out[:0:-1], out], axis=0)
    key = (type(kernel).__name__, float(kernel.a_h), float(kernel.aspect), float(kernel.amplitude),
           float(h), int(nx), int(power), int(m), bool(faces)) + (("annuli",) if annuli else ())
    return _disk(key, compute)


def ring_weights(kernel, h: float, nx: int, power: int = 1, m: int = 0,
                 faces: bool = False, annuli: bool = False) -> np.ndarray:
    """``W[l, i, b]``: the ring-integrated ``w**power`` (module docstring), in d**3 (cells)
    or d**2 (``faces``: the vertical rings of radius ``(j + 1) h``; ``annuli``: the
    horizontal faces ``r' in [j h, (j + 1) h]`` at the height offsets ``(l - M + 1/2) h``,
    ``M = mz + 1``: ``int_annulus w cos(m t) dA``).

    ``l = 0 .. 2 mz`` is the source's height offset ``(l - mz) h``, ``i`` the target
    column, ``b = 0 .. 2 mb`` the source column ``j = i + b - mb`` (zero where ``j < 0``;
    columns ``j >= nx``, beyond the grid, are included so that the ``m = 0`` rows can be
    normalised to ``V_power``). Cached (the last few kernels, spacings and sizes).
    """
    if getattr(kernel, "dims", None) != 3:
        raise ValueError(f"kernel: an axisymmetric grid needs a 3D kernel (dims=3), got "
                         f"dims={getattr(kernel, 'dims', None)!r}")
    if annuli:
        faces = True
    key = (type(kernel).__name__, float(kernel.a_h), float(kernel.aspect), float(kernel.amplitude),
           float(h), int(nx), int(power), int(m), bool(faces), bool(annuli))
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    W = _raw_weights(kernel, h, nx, power, m, faces, annuli)
    if not faces:
        # every row normalised to V_power over all rings; the m = 1 rows by the same factor
        fkey = key[:-3]
        if fkey not in _FACTORS:
            W0 = W if m == 0 else _raw_weights(kernel, h, nx, power, 0, False)
            _FACTORS[fkey] = kernel.moment(power) / W0.sum(axis=(0, 2))
            while len(_FACTORS) > _CACHE_SIZE:
                _FACTORS.popitem(last=False)
        W = W * _FACTORS[fkey][None, :, None]
    W.setflags(write=False)
    _CACHE[key] = W
    while len(_CACHE) > _CACHE_SIZE:
        _CACHE.popitem(last=False)
    return W


def ring_convolve(sources, W: np.ndarray, beyond: np.ndarray | None = None) -> list[np.ndarray]:
    """``out[k, i] = sum_{l, b} W[l, i, b] f[k - (l - mz), i + b - mb]`` for every source ``f``
    (``mz = (len(W) - 1) / 2``; the cell weights are even in ``l - mz``).

    Sources are zero outside the grid (no spots below the floor, above the top or beyond
    ``r = a``) unless ``beyond`` gives the columns ``nx, nx + 1, ...`` (at most ``mb``) of
    every source (the material continued beyond an open wall). FFT along ``z`` (linear:
    length >= ``nz + mz``), banded product along ``r``.

    Args:
        sources: list of ``(nz, nx)`` arrays.
        W: weights of :func:`ring_weights` for this ``nx``.
        beyond: optional ``(nz, q)`` array, ``q <= mb``, shared by all sources.

    Returns:
        list of ``(nz, nx)`` arrays.
    """
    if not sources:
        return []
    nz, nx = np.shape(sources[0])
    nl, nxw, nb = W.shape
    if nxw != nx:
        raise ValueError(f"W: weights for {nxw} columns, sources have {nx}")
    mz, mb = (nl - 1) // 2, (nb - 1) // 2
    keep = min(mz, nz - 1)
    Wc = W[mz - keep: mz + keep + 1]
    L = scipy.fft.next_fast_len(nz + keep, real=True)
    Wz = np.zeros((L, nx, nb))
    Wz[:keep + 1] = Wc[keep:]
    if keep:
        Wz[L - keep:] = Wc[:keep]
    What = scipy.fft.rfft(Wz, axis=0)
    stack = np.stack([np.asarray(f, dtype=float) for f in sources])
    if beyond is not None and np.shape(beyond)[1]:
        q = min(mb, np.shape(beyond)[1])
        stack = np.concatenate([stack, np.broadcast_to(beyond[:, :q], (len(sources), nz, q))], axis=2)
    F = scipy.fft.rfft(stack, n=L, axis=1)
    Fp = np.zeros(F.shape[:2] + (nx + 2 * mb,), dtype=complex)
    Fp[:, :, mb:mb + F.shape[2]] = F
    out_hat = np.zeros(F.shape[:2] + (nx,), dtype=complex)
    for b in range(nb):   # the band: no (nq, nx, nb) temporaries per source
        out_hat += What[None, :, :, b] * Fp[:, :, b:b + nx]
    out = scipy.fft.irfft(out_hat, n=L, axis=1)[:, :nz]
    return [np.ascontiguousarray(o) for o in out]
