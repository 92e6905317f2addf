"""Monte Carlo of two particles in the discrete spot model: the cage-breaking fall.

Uniform flow (the local picture of ``spotpde.pair``): spots cross every height at a
uniform rate, straight up on average, with horizontal diffusion length ``b`` (Gaussian
steps of variance ``2 b Delta`` per vertical step ``Delta``, no persistence, ``b_par = 0``).
Per unit fall of the particles, ``1/V1`` spots cross each unit of horizontal length
(the mean particle speed is ``V1 rho_s v_s``), so a spot drawn uniformly in a window of
width ``W`` around the pair advances the fall clock by ``V1/W``.

Each spot is generated around the pair: its crossing of the pair's mid height is uniform
in the window (``W`` covers every path that can reach either particle: the kernel reach
plus 5 standard deviations of the path's horizontal wander from there), its step phase is uniform,
and the path is continued downward and upward from there (the Gaussian walk is
time-reversible). It then steps upward through the pair's neighbourhood and, at every
step ``dR``, moves both particles by ``-w(r_p - r_s - lam dR) dR`` (eq. discrete; ``lam``
the rule). Hard core: after each spot a separation below ``contact`` is reflected
radially, ``|r| -> 2 contact - |r|``, and the fall at which ``|r|`` first reaches
``separation`` is recorded, both checked after every spot step. Replicas are independent (one seed each).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy.interpolate import RegularGridInterpolator

from ..montecarlo import _mc_kernels as K, kernel_params



@njit(cache=True)
def _walk(xs, zs, nd, nu, sig, step):
    """Fill a spot path through the crossing point ``(xs[nd], zs[nd])``: ``nd`` steps of
    ``step`` down (walked backwards from the crossing) and ``nu`` up, each with a Gaussian
    horizontal step of standard deviation ``sig``."""
    for k in range(nd - 1, -1, -1):
        xs[k] = xs[k + 1] - sig * np.random.standard_normal()
        zs[k] = zs[k + 1] - step
    for k in range(nd + 1, nd + nu + 1):
        xs[k] = xs[k - 1] + sig * np.random.standard_normal()
        zs[k] = zs[k - 1] + step


@njit(cache=True)
def _push_apart(x1, z1, x2, z2, contact, conormal, angles, cxx, cxz, czz):
    """The pair reflected off the hard core ``|r| = contact`` (d), about its midpoint: along
    the separation (``conormal`` False) or along ``B n``, the relative diffusion tensor
    at contact (tabulated in the angle of ``n``) times the normal, the reflection that
    keeps an anisotropic diffusion's density flat at the wall; radial if that would
    still leave the pair overlapping. Returns the new ``(x1, z1, x2, z2)``."""
    rx, rz = x2 - x1, z2 - z1
    r = math.sqrt(rx * rx + rz * rz)
    cx, cz = 0.5 * (x1 + x2), 0.5 * (z1 + z2)
    if conormal:
        nx, nz = rx / r, rz / r
        a = math.atan2(abs(nz), abs(nx))
        bxx = np.interp(a, angles, cxx)
        bzz = np.interp(a, angles, czz)
        bxz = np.interp(a, angles, cxz) * (1.0 if nx * nz >= 0 else -1.0)
        vx, vz = bxx * nx + bxz * nz, bxz * nx + bzz * nz
        vn = vx * nx + vz * nz
        d = 2.0 * (contact - r) / vn
        rx, rz = rx + d * vx, rz + d * vz
        if rx * rx + rz * rz < contact * contact:   # safeguard: radial
            f = (2.0 * contact - r) / r
            rx, rz = f * (x2 - x1), f * (z2 - z1)
    else:
        f = (2.0 * contact - r) / r
        rx, rz = f * rx, f * rz
    return cx - 0.5 * rx, cz - 0.5 * rz, cx + 0.5 * rx, cz + 0.5 * rz


@njit(cache=True)
def _replicas(n, seed, x0, z0, contact, separation, shape, size, size_v, amp, reach_h,
              reach_v, V1, b, lam, step, max_fall, conormal, angles, cxx, cxz, czz):
    np.random.seed(seed)
    out = np.empty(n)
    sig = math.sqrt(2.0 * b * step)
    for rep in range(n):
        x1, z1, x2, z2 = 0.0, 0.0, x0, z0
        fall = 0.0
        while True:
            zlo = min(z1, z2) - reach_v - 0.5
            zhi = max(z1, z2) + reach_v + 0.5
            zm = 0.5 * (z1 + z2)
            nd = int(math.ceil((zm - zlo) / step))
            nu = int(math.ceil((zhi - zm) / step))
            wander = 5.0 * math.sqrt(2.0 * b * max(zm - zlo, zhi - zm))
            W = abs(x2 - x1) + 2.0 * (reach_h + wander)
            xm = 0.5 * (x1 + x2)
            xc = xm + (np.random.random() - 0.5) * W
            phase = np.random.random() * step
            # path below the crossing, walked backwards
            xs = np.empty(nd + nu + 1)
            zs = np.empty(nd + nu + 1)
            xs[nd] = xc
            zs[nd] = zm + phase
            _walk(xs, zs, nd, nu, sig, step)
            escaped = False
            lo, hi = xs[0], xs[0]
            for k in range(nd + nu + 1):
                lo = min(lo, xs[k])
                hi = max(hi, xs[k])
            if hi < min(x1, x2) - reach_h - 0.5 or lo > max(x1, x2) + reach_h + 0.5:
                nd = -1  # the path passes beside both particles: no step moves them
            for k in range(nd + nu if nd >= 0 else 0):
                dx = xs[k + 1] - xs[k]
                dz = step
                ex = xs[k] + lam * dx
                ez = zs[k] + lam * dz
                w1 = K.kernel_w(shape, x1 - ex, z1 - ez, size, size_v, amp, reach_h, reach_v)
                w2 = K.kernel_w(shape, x2 - ex, z2 - ez, size, size_v, amp, reach_h, reach_v)
                if w1 == 0.0 and w2 == 0.0:
                    continue
                x1 -= w1 * dx
                z1 -= w1 * dz
                x2 -= w2 * dx
                z2 -= w2 * dz
                rx, rz = x2 - x1, z2 - z1
                r = math.sqrt(rx * rx + rz * rz)
                if r < contact:
                    x1, z1, x2, z2 = _push_apart(x1, z1, x2, z2, contact, conormal,
                                                 angles, cxx, cxz, czz)
                elif r >= separation:
                    escaped = True
                    break
            # the clock: the spot's share of the fall (its influence is spread over the
            # passage; counting it whole at the exit step biases the fall by < V1/W)
            fall += V1 / W if not escaped else 0.5 * V1 / W
            if escaped:
                out[rep] = fall
                break
            if fall > max_fall:
                out[rep] = np.inf
                break
    return out


def cage_breaking_mc(kernel, b, rule=0.5, *, contact=1.0, separation=2.0, start=None,
                     replicas=200, seed=0, step=0.05, max_fall=np.inf, contact_tensor=None):
    """Falls (in d) at which pairs first separate to ``separation``, one per replica.

    Args:
        kernel: 2D ``spotpde.kernels`` kernel (cut off as in ``spotpde.montecarlo``).
        b: spot horizontal diffusion length in d (``b_par = 0``).
        rule: lam in [0, 1].
        contact, separation: hard-core and cage radii in d.
        start: initial separation ``(X0, Z0)`` (default ``(contact, 0)``).
        replicas: number of independent pairs.
        seed: seed of numba's generator.
        step: spot step ``Delta`` in d.
        max_fall: censoring fall (``inf`` in the result for pairs still caged).
        contact_tensor: ``None``: the hard core reflects the separation radially (a
            normal contact force). Or ``(angles, B)``: ``B`` a dict ``{"xx","xz","zz"}`` of
            values at ``|r| = contact`` for ``angles`` in ``[0, pi/2]`` (above the
            horizontal): the overshoot is pushed back along ``B n`` (conormal
            reflection), the reflection whose density obeys the zero-Ito-flux condition
            of ``spotpde.pair`` (docs/pair.md, section 3).

    Returns:
        ndarray of falls in d, shape ``(replicas,)``.
    """

    if not separation > contact > 0:
        raise ValueError(f"separation must be > contact > 0, got {separation}, {contact}")
    if b < 0:
        raise ValueError(f"b must be >= 0, got {b}")
    kp = kernel_params(kernel)
    x0, z0 = (contact, 0.0) if start is None else (float(start[0]), float(start[1]))
    if contact_tensor is None:
        angles, tab = np.array([0.0, 1.0]), {k: np.ones(2) for k in ("xx", "xz", "zz")}
    else:
        angles, tab = contact_tensor
    angles = np.ascontiguousarray(angles, dtype=float)
    cxx, cxz, czz = (np.ascontiguousarray(tab[k], dtype=float) for k in ("xx", "xz", "zz"))
    return _replicas(int(replicas), int(seed), x0, z0, float(contact), float(separation),
                     kp.shape, kp.size, kp.size_v, kp.amp, kp.reach[0], kp.reach[1],
                     kp.V1, float(b), float(rule), float(step), float(max_fall),
                     contact_tensor is not None, angles, cxx, cxz, czz)


@njit(cache=True)
def _probe(nspots, X, Z, shape, size, size_v, amp, reach_h, reach_v, V1, b, lam, step, seed):
    np.random.seed(seed)
    sig = math.sqrt(2.0 * b * step)
    zm = 0.5 * Z
    zlo = min(0.0, Z) - reach_v - 0.5
    zhi = max(0.0, Z) + reach_v + 0.5
    nd = int(math.ceil((zm - zlo) / step))
    nu = int(math.ceil((zhi - zm) / step))
    W = abs(X) + 2.0 * (reach_h + 5.0 * math.sqrt(2.0 * b * max(zm - zlo, zhi - zm)))
    sxx = 0.0
    sxz = 0.0
    szz = 0.0
    xs = np.empty(nd + nu + 1)
    zs = np.empty(nd + nu + 1)
    for _ in range(nspots):
        xs[nd] = 0.5 * X + (np.random.random() - 0.5) * W
        zs[nd] = zm + np.random.random() * step
        _walk(xs, zs, nd, nu, sig, step)
        x1, z1, x2, z2 = 0.0, 0.0, X, Z
        for k in range(nd + nu):
            dx = xs[k + 1] - xs[k]
            ex = xs[k] + lam * dx
            ez = zs[k] + lam * step
            w1 = K.kernel_w(shape, x1 - ex, z1 - ez, size, size_v, amp, reach_h, reach_v)
            w2 = K.kernel_w(shape, x2 - ex, z2 - ez, size, size_v, amp, reach_h, reach_v)
            x1 -= w1 * dx
            z1 -= w1 * step
            x2 -= w2 * dx
            z2 -= w2 * step
        ddx = (x2 - x1) - X
        ddz = (z2 - z1) - Z
        sxx += ddx * ddx
        sxz += ddx * ddz
        szz += ddz * ddz
    fall = nspots * V1 / W
    return sxx / (2.0 * fall), sxz / (2.0 * fall), szz / (2.0 * fall)


def probe_tensor(kernel, b, rule, X, Z, *, spots=100_000, seed=0, step=0.05,
                 blocks=8):
    """The discrete model's relative diffusion lengths ``B^ab`` at fixed separations.

    Frozen pairs (positions reset after every spot) at separation ``(X, Z)``: ``B^ab`` is
    ``<dr_a dr_b> / (2 fall)`` over independent spot passages, in d. ``blocks``
    independent seeds give the standard error.

    Returns:
        dict ``{"xx", "xz", "zz"}`` of arrays of shape ``(len(X),)`` and the same keys
        with suffix ``"_se"``.
    """

    kp = kernel_params(kernel)
    X = np.atleast_1d(np.asarray(X, float))
    Z = np.atleast_1d(np.asarray(Z, float))
    vals = np.empty((len(X), blocks, 3))
    for i, (x, z) in enumerate(zip(X, Z)):
        for j in range(blocks):
            vals[i, j] = _probe(int(spots // blocks), float(x), float(z), kp.shape, kp.size,
                                kp.size_v, kp.amp, kp.reach[0], kp.reach[1], kp.V1, float(b),
                                float(rule), float(step), int(seed) * 100_003 + 7919 * i + j)
    out = {}
    for c, key in enumerate(("xx", "xz", "zz")):
        out[key] = vals[:, :, c].mean(axis=1)
        out[key + "_se"] = vals[:, :, c].std(axis=1, ddof=1) / math.sqrt(blocks)
    return out


def tabulated_tensor(table, radii, angles):
    """A tensor field ``B(X, Z)`` interpolated from values on a polar table.

    ``table[key]`` has shape ``(len(radii), len(angles))`` with ``angles`` in
    ``[0, pi/2]`` the angle of ``(|X|, |Z|)`` above the horizontal; by the up-down and
    left-right mirror symmetry of uniform flow ``B^xx``, ``B^zz`` are even in ``X`` and
    in ``Z`` and ``B^xz`` has the sign of ``X Z``. Bilinear in ``(|r|, angle)``, ``|r|``
    clamped to the table.
    """

    interp = {k: RegularGridInterpolator((radii, angles), np.asarray(table[k], float))
              for k in ("xx", "xz", "zz")}

    def tensor(X, Z):
        X, Z = np.broadcast_arrays(np.asarray(X, float), np.asarray(Z, float))
        r = np.clip(np.hypot(X, Z), radii[0], radii[-1])
        a = np.arctan2(np.abs(Z), np.abs(X))
        pts = np.stack([r.ravel(), a.ravel()], axis=-1)
        out = {k: f(pts).reshape(X.shape) for k, f in interp.items()}
        out["xz"] = out["xz"] * np.sign(X * Z)
        out["xx"] = np.maximum(out["xx"], 0.0)
        out["zz"] = np.maximum(out["zz"], 0.0)
        return out

    return tensor
