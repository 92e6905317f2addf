"""Lagrangian diffusivity of the discrete spot model in uniform flow ("passage" tensor).

The mean-field ``D_p = w^2 * (rho_s D_s)`` treats the steps of one spot passing a particle
as independent. They are not: the particle sits inside the spot while it passes, so the
whole passage is one correlated kick. In uniform flow the exact continuum limit of the
discrete model (steps ``-> 0``) is, per unit time (derivation in docs/coefficients.md,
section "Beyond mean field")::

    D_ij = (rho_s / 2) int d^dk/(2 pi)^d |w^(k)|^2 W(k) M_ij(k)
    M_ij = 2 D_ij^s + Re( N_ij / Gamma )
    Gamma = k.D_s.k + i k_z v_s
    N_ij = 2 v_s^2 e_z,i e_z,j - 8 lam (1 - lam) (D_s k)_i (D_s k)_j
           - 2 i v_s [ (D_s k)_i e_z,j + (D_s k)_j e_z,i ]

with ``w^`` the kernel's Fourier transform, ``W = 1`` for one particle and
``W = 2 (1 - cos k.Delta)`` for the separation ``Delta`` of two particles. The first term of
``M`` is the mean field (Parseval: ``int |w^|^2 = V2``); the rest comes from converting the
lam-rule stochastic integral ``Y = -int w(r_p - r_s) o_lam dr_s`` to Ito form and
integrating the Ito/drift cross-correlations along the Brownian path of the spot
(``1 / Gamma`` is the time integral of ``E exp(i k . (r_s(t) - r_s(0)))``).

All results here are *diffusion lengths per unit particle fall*: ``b_p_ij = D_ij / (V1 f)``
with ``f = rho_s v_s``, which depend only on the kernel, ``b = D_perp / v_s``,
``b_par = D_par / v_s`` and ``lam`` (set ``v_s = 1``).

Numerics (docs/coefficients.md): a product quadrature on a uniform ``k`` grid. Along
``k_z`` the factor ``1 / Gamma`` has a pole at ``k_z = i kappa`` with
``kappa ~ b k_perp^2``, arbitrarily close to the real axis at small ``k_perp`` (a nascent
delta function); its pole part is integrated exactly over each ``k_z`` column and the
difference to its discrete sum is put on the ``k_z = 0`` node (singularity subtraction),
so the grid only has to resolve the smooth factors. The part of ``int |w^|^2`` beyond
the grid is known exactly (``V2`` minus the grid sum, Parseval); it is added with the
tensor's mean weight on the outermost grid shell (analytic tail), which matters only
for the sharp uniform kernel (``|w^|^2 ~ k^-(d+1)``).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft
import scipy.ndimage
from scipy.interpolate import BarycentricInterpolator

from ._common import (_COMPONENTS, _as_point, _Convolutions, _is_zero, divergence,
                      spot_diffusivity)

from ._passage_grids import _quadrature_grid, _shape
from . import _passage_grids as _grids
from ..parameters import check_diffusivity, check_rule

__all__ = ["length_tensor", "effective_spot_length", "source_tensor", "keep_flux_velocity",
           "add_pair_correction", "proportional", "keys"]

#: One-particle tensors already computed (the fields of transient runs ask again and again).
_CACHE: dict = {}


def keys(dims: int) -> tuple[str, ...]:
    """Tensor keys in result order: ``xx, xz, zz`` (2D), plus ``yy, xy, yz`` (3D)."""
    return ("xx", "xz", "zz") if dims == 2 else ("xx", "xz", "zz", "yy", "xy", "yz")


def _check(kernel, b, b_par, rule, diffusivity):
    dims = getattr(kernel, "dims", None)
    if dims not in (2, 3) or not hasattr(kernel, "fourier"):
        raise TypeError(f"kernel: need a spotpde.kernels kernel (Uniform, Gaussian, "
                        f"Exponential), got {kernel!r}")
    v1, v2 = float(kernel.V1), float(kernel.V2)
    if not (0.0 < v1 < math.inf and 0.0 < v2 < math.inf):   # 1e-320 underflows in w**2
        raise ValueError(f"kernel: its volumes V1 = {v1:.3g} and V2 = {v2:.3g} must be "
                         "finite and > 0 (the amplitude is too small or too large)")
    try:
        b, b_par, lam = float(b), float(b_par), float(rule)
    except (TypeError, ValueError):
        raise TypeError(f"b, b_par, rule: must be numbers, got {b!r}, {b_par!r}, {rule!r}")
    if not (np.isfinite(b) and b > 0):
        raise ValueError(f"b: must be a finite number > 0, got {b!r}")
    if not (np.isfinite(b_par) and b_par >= 0):
        raise ValueError(f"b_par: must be a finite number >= 0, got {b_par!r}")
    lam = check_rule(lam)
    check_diffusivity(diffusivity)
    return dims, b, b_par, lam


# -- the integrand ---------------------------------------------------------------------------

def _components(dims):
    return {"xx": (0, 0), "xz": (0, dims - 1), "zz": (dims - 1, dims - 1),
            "yy": (1, 1), "xy": (0, 1), "yz": (1, dims - 1)}


def _N(i, j, Dk, dims, lam):
    """``N_ij`` of the module docstring (``v_s = 1``), broadcasting over the grid."""
    z = dims - 1
    out = -8.0 * lam * (1.0 - lam) * Dk[i] * Dk[j]
    if i == z:
        out = out - 2j * Dk[j]
    if j == z:
        out = out - 2j * Dk[i]
    if i == z and j == z:
        out = out + 2.0
    return out


def _weights(kh, kz, dims, b, b_par, lam, comps, dkz):
    """``M_ij`` on the grid, with the pole part of every ``k_z`` column made exact.

    Args:
        kh: horizontal wavenumbers, a list of ``d - 1`` arrays broadcasting with ``kz``
            (the ``k_z`` axis is axis 0 of the broadcast shape).
        kz: ``k_z`` nodes, shape ``(n_z, 1[, 1])``, uniform spacing ``dkz``.
        comps: tensor keys to compute.

    Returns:
        ``{key: M array}`` (the singularity subtraction added on the ``k_z = 0`` node
        as a weight per unit ``dkz``).
    """
    z = dims - 1
    kperp2 = sum(k * k for k in kh)
    G = b * kperp2
    gamma = G + b_par * kz * kz + 1j * kz
    # pole nearest the real axis, k_z = i kappa, and Gamma'(i kappa) = i Q
    Q = np.sqrt(1.0 + 4.0 * b_par * G)
    kappa = 2.0 * G / (Q + 1.0)
    kappa = np.maximum(kappa, 1e-300)
    p1 = 1j * kappa
    lo = kz.min() - 0.5 * dkz
    hi = kz.max() + 0.5 * dkz
    i0 = int(np.argmin(np.abs(kz.ravel())))
    shape = np.broadcast(*kh, kz).shape
    singular = np.broadcast_to(gamma == 0.0, shape)
    gamma = np.where(gamma == 0.0, 1.0, gamma)
    out = {}
    for key in comps:
        i, j = _components(dims)[key]
        Dk = [b * k for k in kh] + [b_par * kz]
        # pole part r / (k_z - i kappa), r = N(i kappa) / (i Q)
        Dk1 = [b * k for k in kh] + [b_par * p1]
        r = _N(i, j, Dk1, dims, lam) / (1j * Q)
        pole = np.broadcast_to(np.real(r / (kz - p1)), shape)
        M = np.array(np.broadcast_to(np.real(_N(i, j, Dk, dims, lam) / gamma), shape)) - pole
        if np.any(singular):  # the regular part at k = 0: mean of the k_z neighbours
            M[singular] = 0.5 * (M[i0 - 1][singular[i0]] + M[i0 + 1][singular[i0]])
        if i == j:
            M += 2.0 * (b_par if i == z else b)
        # the pole part: sampled off k_z = 0, the exact column integral's rest on k_z = 0
        exact = np.real(r * (np.log(hi - p1) - np.log(lo - p1)))
        others = np.delete(pole, i0, axis=0).sum(axis=0) * dkz
        row = M[i0] + (np.broadcast_to(exact, (1,) + shape[1:])[0] - others) / dkz
        M += pole
        M[i0] = row
        out[key] = M
    return out


def _tail(w2, M, shell, missing):
    """Weight of ``int |w^|^2 M`` beyond the grid: the shell's mean ``M`` times the mass."""
    if missing <= 0.0:
        return 0.0
    m = float(np.sum(w2[shell]))
    return float(np.sum((w2 * M)[shell]) / m) * missing if m > 0 else 0.0


# -- one particle ------------------------------------------------------------------------------

def quadrature_bytes(kernel, b, b_par=0.0) -> float:
    """Peak memory in bytes (a float) of :func:`length_tensor` for one particle, before
    computing it: its ``k`` grid grows like ``b / size`` (the range resolves the kernel,
    the spacing the spread ``sqrt(b size)``), twice as fine each way for a 2D uniform
    kernel. ``b``, ``b_par`` in d; raises as :func:`length_tensor`."""
    dims, b, b_par, _ = _check(kernel, b, b_par, 0.5, "passage")
    kscale = 2.0 if _shape(kernel) == "uniform" and dims == 2 else 1.0
    nz, _, _, nh, _, _ = _quadrature_grid(kernel, dims, b, b_par, kscale=kscale)
    return float(_grids.BYTES_PER_NODE) * (2.0 * nz + 1.0) * (nh + 1.0)


def _single(kernel, dims, b, b_par, lam, scale=1.0, kscale=1.0):
    """``b_p_ij`` for one particle: ``(1/2V1) int |w^|^2 M_ij`` (dict of floats)."""
    nz, dkz, kmax_z, nh, dkh, kmax_h = _quadrature_grid(kernel, dims, b, b_par, scale, kscale)
    kz = (np.arange(-nz, nz + 1) * dkz)[:, None]
    kp = (np.arange(nh + 1) * dkh)[None, :]
    trap = np.ones(nh + 1)
    trap[0] = 0.5
    if dims == 2:
        measure = 2.0 * trap * dkh * dkz / (2.0 * math.pi) ** 2
        w2 = kernel.fourier(kp, kz) ** 2
        kh = [kp]
        comps = ("xx", "zz")
    else:
        measure = 2.0 * math.pi * kp.ravel() * trap * dkh * dkz / (2.0 * math.pi) ** 3
        w2 = kernel.fourier(kp, 0.0 * kp, kz) ** 2
        # angle average over the horizontal direction: k_x^2 -> k_perp^2 / 2
        kh = [kp / math.sqrt(2.0), kp / math.sqrt(2.0)]
        comps = ("xx", "zz")
    w2m = w2 * measure
    mass = float(np.sum(w2m))
    if dims == 3:  # Euler-Maclaurin end correction of the radial trapezoid (below)
        mass += dkh * dkh / 12.0 * float(np.sum(w2[:, 0])) * dkz / (2.0 * math.pi) ** 2
    missing = kernel.V2 - mass
    rad = np.maximum(np.abs(kz) / kmax_z, kp / kmax_h)
    # the shell excludes the k_z = 0 row, which carries the columns' pole integrals
    shell = np.broadcast_to((rad > 0.8) & (kz != 0.0), w2.shape)
    M = _weights(kh, kz, dims, b, b_par, lam, comps, dkz)
    out = {}
    for key in comps:
        total = float(np.sum(w2m * M[key])) + _tail(w2m, M[key], shell, missing)
        if dims == 3:  # Euler-Maclaurin end correction of the radial trapezoid: g = k F(k)
            F0 = float(np.sum(w2[:, 0] * M[key][:, 0])) * dkz * 2.0 * math.pi / (2.0 * math.pi) ** 3
            total += dkh * dkh / 12.0 * F0
        out[key] = total / (2.0 * kernel.V1)
    res = {k: 0.0 for k in keys(dims)}
    res.update(out)
    if dims == 3:
        res["yy"] = res["xx"]
    return res


# -- pairs ----------------------------------------------------------------------------------------

def _pairs(kernel, dims, b, b_par, lam, separation):
    """Relative tensor ``B_ij(Delta) = D_rel / (V1 f)`` at the given separations."""
    seps = [np.asarray(s, dtype=float) for s in separation]
    if len(seps) != dims:
        names = "(dx, dz)" if dims == 2 else "(dx, dy, dz)"
        raise ValueError(f"separation: a {dims}D kernel needs {dims} arrays {names}, "
                         f"got {len(seps)}")
    try:
        seps = np.broadcast_arrays(*seps)
    except ValueError:
        raise ValueError("separation: the arrays do not broadcast to one shape")
    if not all(np.all(np.isfinite(s)) for s in seps):
        raise ValueError("separation: contains NaN or infinite values")
    far = [float(np.max(np.abs(s))) if s.size else 0.0 for s in seps]
    n, hs = _grids.pair_grid(kernel, dims, b, b_par, far)
    L = [m * hi for m, hi in zip(n, hs)]
    ks = [2.0 * math.pi * scipy.fft.fftfreq(m, hi) for m, hi in zip(n, hs)]
    # arrays in order (z, [y,] x): k_z first so that _weights' columns run along axis 0
    kz = ks[-1].reshape((-1,) + (1,) * (dims - 1))
    # k_x on the last axis, k_y (3D) on axis 1
    kh = [ks[0].reshape((1,) * (dims - 1) + (-1,))] + (
        [ks[1].reshape((1, -1, 1))] if dims == 3 else [])
    dkz = 2.0 * math.pi / L[-1]
    measure = math.prod(2.0 * math.pi / Li for Li in L) / (2.0 * math.pi) ** dims
    w2 = kernel.fourier(*kh, kz) ** 2
    comps = keys(dims)
    M = _weights(kh, kz, dims, b, b_par, lam, comps, dkz)
    missing = kernel.V2 - float(np.sum(w2)) * measure
    kmax = [math.pi / hi for hi in hs]
    rad = np.abs(kz) / kmax[-1]
    for a, k in enumerate(kh):
        rad = np.maximum(rad, np.abs(k) / kmax[a])
    shell = np.broadcast_to((rad > 0.8) & (kz != 0.0), w2.shape)
    # real-space grid of the cos part: S(Delta) = sum w2 M exp(i k Delta) measure
    grid_index = []
    order = [dims - 1] + ([1] if dims == 3 else []) + [0]  # array axes: z, [y,] x
    for ax_arr, comp in enumerate(order):
        grid_index.append(np.mod(seps[comp] / hs[comp], n[comp]))
    out = {}
    for key in comps:
        F = w2 * M[key]
        S0 = float(np.sum(F)) * measure
        tail = _tail(w2, M[key], shell, missing)
        S = np.real(scipy.fft.ifftn(F)) * (F.size * measure)
        cos_part = scipy.ndimage.map_coordinates(S, grid_index, order=3, mode="grid-wrap")
        out[key] = (2.0 * (S0 - cos_part) + 2.0 * tail) / (2.0 * kernel.V1)
    return out


def _mean_field(kernel, dims, b, b_par, separation):
    diag = {"xx": b, "yy": b, "zz": b_par}
    ratio = kernel.V2 / kernel.V1
    if separation is None:
        return {k: diag.get(k, 0.0) * ratio for k in keys(dims)}
    seps = np.broadcast_arrays(*[np.asarray(s, dtype=float) for s in separation])
    if len(seps) != dims:
        raise ValueError(f"separation: a {dims}D kernel needs {dims} arrays, got {len(seps)}")
    one_minus_c = 1.0 - kernel.correlation_vector(*seps)
    return {k: 2.0 * diag.get(k, 0.0) * ratio * one_minus_c for k in keys(dims)}


def length_tensor(kernel, b, b_par=0.0, rule=0.5, *, diffusivity="passage", separation=None):
    """Particle diffusion-length tensor per unit fall in uniform flow, in d.

    ``b_p_ij = D_ij / (V1 rho_s v_s)`` of one particle, or with ``separation`` the tensor
    ``B_ij(Delta) = D_rel,ij / (V1 rho_s v_s)`` of the separation ``Delta`` of two
    particles (the Fokker-Planck coefficient of ``dP/dzeta = d_i d_j (B_ij P)``, ``zeta``
    the fall distance). ``diffusivity="passage"`` is the discrete spot model's own
    continuum limit (module docstring; Lagrangian, exact in uniform flow),
    ``"mean-field"`` the paper's eq. Dp: ``b_ij V2 / V1`` and
    ``2 b_ij (V2 / V1) (1 - C(Delta))``, ``b_ij = diag(b, [b,] b_par)``.

    Accuracy of the passage quadrature: about 1e-4 relative for the smooth kernels and
    1e-3 for the sharp uniform kernel (tests/fields/test_passage.py). Cost: ~0.1-1 s (2D),
    a few s (3D pairs).

    Args:
        kernel: a :mod:`spotpde.kernels` kernel (any shape, aspect, 2D or 3D).
        b: horizontal spot diffusion length ``D_perp / v_s`` in d, > 0.
        b_par: vertical spot diffusion length ``D_par / v_s`` in d, >= 0.
        rule: ``lam`` in [0, 1] (0.5 midpoint, 1 end point).
        diffusivity: ``"passage"`` (default) or ``"mean-field"``.
        separation: ``None`` (one particle) or a tuple of broadcasting arrays
            ``(dx, dz)`` / ``(dx, dy, dz)`` in d.

    Returns:
        ``{"xx", "xz", "zz"[, "yy", "xy", "yz"]}``: floats (one particle) or arrays of the
        separations' broadcast shape, in d.
    """
    dims, b, b_par, lam = _check(kernel, b, b_par, rule, diffusivity)
    if diffusivity == "mean-field":
        return _mean_field(kernel, dims, b, b_par, separation)
    if separation is None:
        out = _single(kernel, dims, b, b_par, lam)
        if _shape(kernel) == "uniform" and dims == 2:
            # the sharp disk's truncation error falls like k_max^(-3/2) (the sector
            # |k_z| > b k_x^2 near the k_z axis): Richardson extrapolation in k_max. (3D:
            # k_max^-2, already below 1e-4 on the standard grid.)
            fine = _single(kernel, dims, b, b_par, lam, kscale=2.0)
            c = 1.0 / (2.0**1.5 - 1.0)
            out = {k: fine[k] + c * (fine[k] - out[k]) for k in out}
        return out
    return _pairs(kernel, dims, b, b_par, lam, separation)


def effective_spot_length(kernel, b, b_par=0.0, rule=0.5) -> dict:
    """``b_eff_ij = V1 b_p_ij / V2``: the spot length tensor whose mean field is the passage one.

    ``D_p = w^2 * (rho_s v_s b_eff)`` reproduces the passage tensor in uniform flow
    exactly (``w^2 * f = V2 f``); :func:`spotpde.coefficients.particle_fields` uses it as the
    local form in non-uniform flow. Off-diagonal entries vanish (mirror symmetry).

    Returns:
        ``{"xx", "zz"[, "yy"]}`` in d.

    Raises:
        ValueError: ``kernel`` with ``V1`` or ``V2`` zero or not finite (an amplitude
            such as 1e-320 whose square underflows), or ``b``, ``b_par``, ``rule`` out of
            range; TypeError: not a kernel.
    """
    _check(kernel, b, b_par, rule, "passage")
    # b_eff depends on the kernel's shape only (b_p scales like V2/V1 at a fixed shape):
    # the key leaves out the amplitude, so a change of kernel.height or volume is free
    key = (type(kernel).__name__, kernel.dims, float(kernel.a_h), float(kernel.aspect),
           float(b), float(b_par), float(rule))
    if key not in _CACHE:
        if len(_CACHE) > 256:
            _CACHE.clear()
        bp = length_tensor(kernel, b, b_par, rule)
        ratio = kernel.V1 / kernel.V2
        _CACHE[key] = {k: v * ratio for k, v in bp.items() if k in ("xx", "yy", "zz")}
    return dict(_CACHE[key])


# -- the local form in non-uniform flow ----------------------------------------------------------

#: Chebyshev nodes per varying length of the b_eff table (b and/or b_par given as fields).
_TABLE_NODES = {1: 9, 2: 6}
#: At most this many distinct (b, b_par) values are computed one by one.
_DIRECT = 8


def _cheb(lo, hi, n):
    j = np.arange(n)
    return 0.5 * (lo + hi) + 0.5 * (hi - lo) * np.cos(np.pi * (2 * j + 1) / (2 * n))[::-1]


def _interp(nodes, values, x):
    """Polynomial (barycentric) interpolation on Chebyshev nodes along the first axis."""
    return BarycentricInterpolator(nodes, values, axis=0)(x)


def source_tensor(grid, spots, D_s, kernel, lam) -> dict:
    """The tensor ``T`` of the local passage form ``D_p = w^2 * (rho_s T)``: ``T = v_s b_eff``.

    ``b_eff(b, b_par)`` (:func:`effective_spot_length`) is taken at every source cell's own
    ``b = D_xx / v_s`` and ``b_par = D_zz / v_s``. Constant lengths: one quadrature. Fields:
    the distinct values (at most 8) one by one, otherwise a Chebyshev table over their range
    (9 nodes per varying length, 6 x 6 when both vary), interpolated (the tensor is a smooth
    function of both lengths; interpolation error below 1e-6 relative).

    Args:
        grid: the grid (``dims``).
        spots: spot parameters (``drift`` v_s, float or grid array).
        D_s: the spot diffusivity tensor (``coefficients.spot_diffusivity``).
        kernel: the influence kernel.
        lam: the rule.

    Returns:
        ``{"D_xx": ..., ["D_yy": ...,] "D_zz": ...}``: floats or grid arrays, d**2 per unit time.
    """
    dims = grid.dims
    off = [k for k in ("D_xz", "D_xy", "D_yz") if k in D_s and not (
        np.ndim(D_s[k]) == 0 and float(D_s[k]) == 0.0) and np.any(D_s[k])]
    if off or (dims == 3 and not np.array_equal(np.asarray(D_s["D_xx"]), np.asarray(D_s["D_yy"]))):
        raise ValueError("diffusivity: 'passage' needs a diagonal spot diffusivity with "
                         "D_xx = D_yy; pass diffusivity='mean-field' for a general tensor")
    v_s = spots.drift
    if np.any(np.asarray(v_s) <= 0):
        raise ValueError("spots.drift: the passage diffusivity needs v_s > 0 everywhere")
    b = np.asarray(D_s["D_xx"], dtype=float) / v_s
    b_par = np.asarray(D_s["D_zz"], dtype=float) / v_s
    if np.any(b <= 0):
        raise ValueError("spots.b: the passage diffusivity needs b > 0 everywhere")
    if np.ndim(b) == 0 and np.ndim(b_par) == 0:
        be = effective_spot_length(kernel, float(b), float(b_par), lam)
        xx, zz = be["xx"], be["zz"]
    else:
        shape = np.broadcast_shapes(np.shape(b), np.shape(b_par))

        def distinct(a):  # interpolate on distinct values only
            if np.ndim(a) == 0:
                return np.array([float(a)]), np.zeros(shape, dtype=np.intp)
            u, i = np.unique(a, return_inverse=True)
            return u, np.broadcast_to(i.reshape(np.shape(a)), shape)

        ub, ib = distinct(b)
        up, ip = distinct(b_par)
        if ub.size * up.size <= _DIRECT:
            table = np.empty((ub.size, up.size, 2))
            for i, bb in enumerate(ub):
                for j, bp in enumerate(up):
                    be = effective_spot_length(kernel, bb, bp, lam)
                    table[i, j] = be["xx"], be["zz"]
            vals = table[ib, ip]
        else:
            n = _TABLE_NODES[int(ub.size > 1) + int(up.size > 1)]
            nb = _cheb(ub[0], ub[-1], n) if ub.size > 1 else ub[:1]
            npar = _cheb(up[0], up[-1], n) if up.size > 1 else up[:1]
            table = np.empty((nb.size, npar.size, 2))
            for i, bb in enumerate(nb):
                for j, bp in enumerate(npar):
                    be = effective_spot_length(kernel, bb, max(bp, 0.0), lam)
                    table[i, j] = be["xx"], be["zz"]
            # Lagrange weights of the distinct b (b_par) on the b (b_par) nodes
            Wb = _interp(nb, np.eye(nb.size), ub) if nb.size > 1 else np.ones((1, 1))
            Wp = _interp(npar, np.eye(npar.size), up) if npar.size > 1 else np.ones((1, 1))
            inner = np.einsum("pm,nmk->pnk", Wp, table)       # (distinct b_par, b nodes, 2)
            if up.size == 1:
                vals = (Wb @ inner[0])[ib]                    # (cells..., 2)
            elif ub.size == 1:
                vals = inner[:, 0, :][ip]
            else:
                vals = np.einsum("...n,...nk->...k", Wb[ib], inner[ip])
        xx, zz = vals[..., 0], vals[..., 1]
    out = {k: 0.0 for k in D_s}
    out.update({"D_xx": v_s * xx, "D_zz": v_s * zz})
    if dims == 3:
        out["D_yy"] = out["D_xx"]
    return out


def proportional(t, d) -> float | None:
    """``c`` if ``t == c * d`` (floats or arrays, to round-off), else None."""
    if np.ndim(t) == 0 and np.ndim(d) == 0:
        return float(t) / float(d) if float(d) != 0.0 else None
    t, d = np.broadcast_arrays(np.asarray(t, dtype=float), np.asarray(d, dtype=float))
    flat_d = d.ravel()
    i = int(np.argmax(np.abs(flat_d)))
    if flat_d[i] == 0.0:
        return None
    c = float(t.ravel()[i] / flat_d[i])
    return c if np.allclose(t, c * d, rtol=1e-13, atol=0.0) else None


def keep_flux_velocity(grid, rho_s, D_s, D_source, kernel, fields: dict, phi=None) -> None:
    """Passage drift: ``u_p += div(D_p - D_p_mf)``, so ``u_p - div D_p`` stays the mean field's.

    The probability-flux velocity at uniform density is a first moment of the spot
    displacements, which the mean field gets exactly (each spot's effect is linear and
    spots are independent); only the second moments change with the passage correlations.
    ``D_p - D_p_mf = w^2 * (rho_s (T - D_s))``: ``D_p`` itself where ``D_s`` vanishes,
    ``(1 - 1/c) D_p`` where ``T = c D_s``, otherwise the convolutions that
    ``coefficients._general_fields`` batched with the others (``fields["_diff"]``) or,
    failing those, one more convolution per component. Zero in uniform flow (divergence
    free), so the uniform-flow drift is unchanged. With free-volume-conserving walls
    (``phi``, the kernel coverage of ``_walls``) every source is divided by ``phi^2``, as in
    ``D_p`` itself. Modifies ``fields`` in place.
    """
    diff = dict(fields.pop("_diff", {}))
    todo = {}
    for key, t in D_source.items():
        d = D_s.get(key, 0.0)
        if key in diff or (_is_zero(t) and _is_zero(d)):
            continue
        if _is_zero(d):  # no mean-field component: the difference is D_p itself
            diff[key] = fields[key]
            continue
        c = proportional(t, d)
        if c is not None and c != 0.0:  # T = c D_s: D_p - D_p_mf = (1 - 1/c) D_p
            diff[key] = (1.0 - 1.0 / c) * fields[key]
        else:
            todo[key] = rho_s * (np.asarray(t, dtype=float) - np.asarray(d, dtype=float))
            if phi is not None:
                todo[key] = todo[key] / phi**2
    if todo:
        conv = _Convolutions(grid, kernel)
        keys_ = {key: conv.request("diff_" + key, src, 2) for key, src in todo.items()}
        res = conv.run()
        diff.update({key: res[k] for key, k in keys_.items()})
    div = divergence(grid, diff)
    for a in _COMPONENTS[grid.dims]:
        u = fields[f"u_{a}"]
        fields[f"u_{a}"] = np.add(u, div[a], out=div[a])     # a new array, u untouched


def add_pair_correction(grid, rho_s, spots, kernel, r1, r2, spot_diffusivity_tensor, lam,
                        out: dict) -> None:
    """Replace the mean-field cross term of a pair tensor by the passage one.

    Adds ``V1 f [(B_passage - B_mf)(r1 - r2) - 2 (b_p,passage - b_p,mf)]``: the change of
    ``-2 X`` (``B = 2 b_p - 2 X / (V1 f)`` in uniform flow), to a tensor whose one-particle
    terms are already the passage ones. ``f = rho_s v_s``, ``b``, ``b_par`` at the grid
    cell of the midpoint (locally uniform flow; exact in uniform flow; zero once the pair
    shares no spot). ``out``: ``{"D_xx": ..., ...}``, modified in place.
    """
    p1, p2 = _as_point(grid, r1, "r1"), _as_point(grid, r2, "r2")
    mid = 0.5 * (p1 + p2)
    comps = _COMPONENTS[grid.dims]
    coords = grid.coords()
    cell = tuple(int(np.argmin(np.abs(coords[c] - mid[comps.index(c)]))) for c in grid.axes)
    D_s = spot_diffusivity(grid, spots, spot_diffusivity_tensor)
    at = {k: float(np.asarray(v)[cell]) if np.ndim(v) else float(v) for k, v in D_s.items()}
    v_s = float(np.asarray(spots.drift)[cell]) if np.ndim(spots.drift) else float(spots.drift)
    if any(at[k] != 0.0 for k in at if k in ("D_xz", "D_xy", "D_yz")):
        raise ValueError("diffusivity: 'passage' needs a diagonal spot diffusivity; pass "
                         "diffusivity='mean-field' for a general tensor")
    flux = float(np.asarray(rho_s)[cell]) * v_s
    sep = tuple(np.array([d]) for d in (p1 - p2))
    b, b_par = at["D_xx"] / v_s, at["D_zz"] / v_s
    Bp = length_tensor(kernel, b, b_par, lam, separation=sep)
    Bm = length_tensor(kernel, b, b_par, lam, diffusivity="mean-field", separation=sep)
    bp = length_tensor(kernel, b, b_par, lam)
    bm = length_tensor(kernel, b, b_par, lam, diffusivity="mean-field")
    for key in out:
        t = key[2:]
        cross = float(Bp[t][0] - Bm[t][0]) - 2.0 * float(bp[t] - bm[t])
        out[key] += kernel.V1 * flux * cross
