"""Numba kernels of the tracer Fokker-Planck right-hand side (private).

All kernels work in spotpde array order, ``P[k, i]`` (2D) / ``P[k, j, i]`` (3D) with
``k`` the z index. Face velocities are precomputed by :mod:`spotpde._advection`
(boundary faces already carry the boundary condition: zero for walls, outflow-only
for open boundaries), and the diffusion tensor is pre-split into non-negative
stencil coefficients by :mod:`spotpde._diffusion`. The discretised equations are
written out in ``docs/tracer.md`` and in the docstrings of those two modules; this
module only evaluates them.

Sign convention of face fluxes: ``Fz[k, i]`` is the probability flux per unit
horizontal length through the bottom face of cell ``(k, i)`` (``k = nz`` is the top
face of the domain), positive upwards; ``Fx`` likewise positive towards ``+x``.
"""

from __future__ import annotations

import functools

import numpy as np
from numba import njit, prange

# Floating-point licence of the flux kernels: contraction (FMA), reassociation,
# reciprocal; NaN and infinity semantics are kept (the solver checks for NaN).
# Conservation does not depend on it: every face flux is computed once and used
# with opposite signs by the two cells it joins.
FASTMATH = {"contract", "reassoc", "arcp", "nsz"}

# Limiter codes used by the kernels (names in spotpde._advection.LIMITERS).
UPWIND, MINMOD, VANLEER, MC, KOREN, WENO5 = 0, 1, 2, 3, 4, 6


@njit(cache=True, inline="always")
def face_value(p_uu, p_u, p_d, limiter):
    """Limited reconstruction at the face between the upwind cell and the downwind cell.

    ``p_uu`` is the cell upwind of the upwind cell ``p_u``; ``p_d`` the downwind cell.
    Returns ``p_u + s/2`` with the limited slope ``s`` (see _advection.LIMITERS), a
    value in ``[0, 2 p_u]`` for non-negative data.
    """
    dl = p_u - p_uu
    dr = p_d - p_u
    # sign test by comparisons: the product dl * dr of tiny tails would be denormal
    if limiter == 0 or not ((dl > 0.0 and dr > 0.0) or (dl < 0.0 and dr < 0.0)):
        return p_u
    al = abs(dl)
    ar = abs(dr)
    if limiter == 1:
        s = min(al, ar)
    elif limiter == 2:
        s = 2.0 * al * ar / (al + ar)
    elif limiter == 3:
        s = min(2.0 * al, 2.0 * ar, 0.5 * (al + ar))
    else:
        s = min(2.0 * ar, (al + 2.0 * ar) / 3.0, 2.0 * al)
    if dr > 0.0:
        return p_u + 0.5 * s
    return p_u - 0.5 * s


@njit(cache=True, inline="always")
def weno5z(v1, v2, v3, v4, v5, iscale2):
    """Fifth-order WENO-Z face value at the downwind face of ``v3`` (upwind order v1..v5).

    Jiang & Shu 1996 (J. Comput. Phys. 126, 202) candidate stencils ``q_k`` and smoothness
    indicators ``beta_k``, Borges et al. 2008 (J. Comput. Phys. 227, 3191) Z-weights
    ``alpha_k = d_k (1 + (tau5 / B_k)**2)``, ``tau5 = |B_0 - B_2|``, with linear weights
    ``d = (1, 6, 3)/10`` and ``B_k = beta_k / P_scale**2 + 1e-12`` (``iscale2`` is
    ``1 / P_scale**2``: the weights are scale invariant and stay linear where the data
    vary by less than ~1e-6 of the peak). Evaluated with one division by multiplying the
    weights by ``(B_0 B_1 B_2)**2``.
    """
    q0 = (2.0 * v1 - 7.0 * v2 + 11.0 * v3) * (1.0 / 6.0)
    q1 = (-v2 + 5.0 * v3 + 2.0 * v4) * (1.0 / 6.0)
    q2 = (2.0 * v3 + 5.0 * v4 - v5) * (1.0 / 6.0)
    a = v1 - 2.0 * v2 + v3
    b = v1 - 4.0 * v2 + 3.0 * v3
    B0 = (13.0 / 12.0 * a * a + 0.25 * b * b) * iscale2 + 1e-12
    a = v2 - 2.0 * v3 + v4
    b = v2 - v4
    B1 = (13.0 / 12.0 * a * a + 0.25 * b * b) * iscale2 + 1e-12
    a = v3 - 2.0 * v4 + v5
    b = 3.0 * v3 - 4.0 * v4 + v5
    B2 = (13.0 / 12.0 * a * a + 0.25 * b * b) * iscale2 + 1e-12
    t2 = (B0 - B2) * (B0 - B2)
    c0 = B0 * B0
    c1 = B1 * B1
    c2 = B2 * B2
    w0 = 0.1 * (c0 + t2) * c1 * c2
    w1 = 0.6 * (c1 + t2) * c0 * c2
    w2 = 0.3 * (c2 + t2) * c0 * c1
    return (w0 * q0 + w1 * q1 + w2 * q2) / (w0 + w1 + w2)


@njit(cache=True, inline="always")
def recon(v1, v2, v3, v4, v5, h1, h2, h5, limiter, eps):
    """Upwind face value at the face between ``v3`` (upwind cell) and ``v4``.

    ``v1, v2`` lie further upwind, ``v5`` further downwind; ``h1, h2, h5`` say whether
    those cells exist (near a boundary the scheme falls back: WENO5 -> Koren -> donor
    cell). WENO5 values are clipped to ``[0, 2 v3]`` (the positivity bound).
    """
    if limiter == 6 and h1 and h2 and h5:
        f = weno5z(v1, v2, v3, v4, v5, eps)
        if f < 0.0:
            return 0.0
        if f > 2.0 * v3:
            return 2.0 * v3
        return f
    if h2:
        return face_value(v2, v3, v4, limiter if limiter < 6 else 4)
    return v3


@functools.lru_cache(maxsize=None)
def rhs_2d_kernel(limiter: int):
    """The 2D right-hand-side kernel specialised (and disk cached) for one reconstruction.

    The limiter code is a closure constant, so the compiler removes the branches of the
    other reconstructions from the inner loops (about 1.3x faster than passing it).
    """

    @njit(parallel=True, cache=True, fastmath=FASTMATH)
    def rhs_2d(P, uxf, uzf, Axx, Azz, Cp, Cm, has_cross, eps, h,
               out, Fz, Fz_acc, w_acc, Gp, Gm):
        """dP/dt of the 2D Fokker-Planck equation, fused advection + explicit diffusion.

        Args:
            P: (nz, nx) density.
            uxf: (nz, nx+1) x-face velocities (boundary faces carry the BC).
            uzf: (nz+1, nx) z-face velocities (floor and top faces carry the BC).
            Axx, Azz: (nz, nx) axial diffusion coefficients (>= 0 when the tensor is
                diagonally dominant); zero arrays for advection only.
            Cp, Cm: (nz, nx) diagonal coefficients max(D_xz, 0), max(-D_xz, 0).
            has_cross: evaluate the diagonal exchanges.
            eps: WENO scale ``1 / P_scale**2`` (the reconstruction ``limiter`` is a
                compile-time constant of this specialisation).
            h: spacing.
            out: (nz, nx) result dP/dt.
            Fz: (nz+1, nx) vertical face fluxes (advective + axial diffusive), written.
            Fz_acc: (nz+1, nx) accumulator of the upward flux including the diagonal
                exchanges (each split half to the two columns it joins),
                ``Fz_acc += w_acc * (Fz + h/2 * corner exchanges)``.
            w_acc: weight (time-step times Runge-Kutta weight).
            Gp, Gm: (nz+1, nx+1) corner exchange rates (interior written; edges stay 0).
        """
        nz, nx = P.shape
        ih = 1.0 / h
        ih2 = ih * ih
        hh = 0.5 * h * w_acc
        for k in prange(nz + 1):
            cross_row = has_cross and k >= 1 and k <= nz - 1
            if cross_row:
                for i in range(nx - 1):
                    Gp[k, i + 1] = (Cp[k - 1, i] * P[k - 1, i] - Cp[k, i + 1] * P[k, i + 1]) * ih2
                    Gm[k, i + 1] = (Cm[k - 1, i + 1] * P[k - 1, i + 1] - Cm[k, i] * P[k, i]) * ih2
            k3 = max(k - 3, 0)
            k2 = max(k - 2, 0)
            kp1 = min(k + 1, nz - 1)
            kp2 = min(k + 2, nz - 1)
            for i in range(nx):
                u = uzf[k, i]
                if k == 0:
                    F = u * P[0, i]
                elif k == nz:
                    F = u * P[nz - 1, i]
                else:
                    if u > 0.0:
                        pf = recon(P[k3, i], P[k2, i], P[k - 1, i], P[k, i], P[kp1, i],
                                   k >= 3, k >= 2, k + 1 <= nz - 1, limiter, eps)
                    else:
                        pf = recon(P[kp2, i], P[kp1, i], P[k, i], P[k - 1, i], P[k2, i],
                                   k + 2 <= nz - 1, k + 1 <= nz - 1, k >= 2, limiter, eps)
                    F = u * pf - (Azz[k, i] * P[k, i] - Azz[k - 1, i] * P[k - 1, i]) * ih
                Fz[k, i] = F
                if cross_row:
                    Fz_acc[k, i] += w_acc * F + hh * (Gp[k, i] + Gp[k, i + 1] + Gm[k, i] + Gm[k, i + 1])
                else:
                    Fz_acc[k, i] += w_acc * F
        for k in prange(nz):
            Fl = uxf[k, 0] * P[k, 0]
            for i in range(nx):
                u = uxf[k, i + 1]
                if i == nx - 1:
                    Fr = u * P[k, i]
                else:
                    if u > 0.0:
                        pf = recon(P[k, max(i - 2, 0)], P[k, max(i - 1, 0)], P[k, i], P[k, i + 1],
                                   P[k, min(i + 2, nx - 1)], i >= 2, i >= 1, i + 2 <= nx - 1,
                                   limiter, eps)
                    else:
                        pf = recon(P[k, min(i + 3, nx - 1)], P[k, min(i + 2, nx - 1)], P[k, i + 1],
                                   P[k, i], P[k, max(i - 1, 0)], i + 3 <= nx - 1, i + 2 <= nx - 1,
                                   i >= 1, limiter, eps)
                    Fr = u * pf - (Axx[k, i + 1] * P[k, i + 1] - Axx[k, i] * P[k, i]) * ih
                r = -(Fr - Fl) * ih - (Fz[k + 1, i] - Fz[k, i]) * ih
                if has_cross:
                    r += Gp[k, i] - Gp[k + 1, i + 1] + Gm[k, i + 1] - Gm[k + 1, i]
                out[k, i] = r
                Fl = Fr

    return rhs_2d


@functools.lru_cache(maxsize=None)
def advect_3d_kernel(limiter: int):
    """The 3D advection kernel specialised for one reconstruction (see rhs_2d_kernel)."""

    @njit(parallel=True, cache=True, fastmath=FASTMATH)
    def advect_3d(P, uxf, uyf, uzf, eps, h, out, Fz, Fy, Fz_acc, w_acc):
        """-div(u P) in 3D with limited upwind face values (diffusion is added separately).

        Args:
            P: (nz, ny, nx) density.
            uxf: (nz, ny, nx+1), uyf: (nz, ny+1, nx), uzf: (nz+1, ny, nx) face velocities.
            eps: WENO scale ``1 / P_scale**2``; h: spacing (``limiter`` is a compile-time
                constant of this specialisation).
            out: (nz, ny, nx) result.
            Fz, Fy: work arrays of the face-velocity shapes (z fluxes written).
            Fz_acc: accumulator, ``Fz_acc += w_acc * Fz`` (advective part).
        """
        nz, ny, nx = P.shape
        ih = 1.0 / h
        for k in prange(nz + 1):
            k3 = max(k - 3, 0)
            k2 = max(k - 2, 0)
            kp1 = min(k + 1, nz - 1)
            kp2 = min(k + 2, nz - 1)
            for j in range(ny):
                for i in range(nx):
                    u = uzf[k, j, i]
                    if k == 0:
                        F = u * P[0, j, i]
                    elif k == nz:
                        F = u * P[nz - 1, j, i]
                    elif u > 0.0:
                        F = u * recon(P[k3, j, i], P[k2, j, i], P[k - 1, j, i], P[k, j, i],
                                      P[kp1, j, i], k >= 3, k >= 2, k + 1 <= nz - 1, limiter, eps)
                    else:
                        F = u * recon(P[kp2, j, i], P[kp1, j, i], P[k, j, i], P[k - 1, j, i],
                                      P[k2, j, i], k + 2 <= nz - 1, k + 1 <= nz - 1, k >= 2,
                                      limiter, eps)
                    Fz[k, j, i] = F
                    Fz_acc[k, j, i] += w_acc * F
        for k in prange(nz):
            for j in range(ny + 1):
                j3 = max(j - 3, 0)
                j2 = max(j - 2, 0)
                jp1 = min(j + 1, ny - 1)
                jp2 = min(j + 2, ny - 1)
                for i in range(nx):
                    u = uyf[k, j, i]
                    if j == 0:
                        F = u * P[k, 0, i]
                    elif j == ny:
                        F = u * P[k, ny - 1, i]
                    elif u > 0.0:
                        F = u * recon(P[k, j3, i], P[k, j2, i], P[k, j - 1, i], P[k, j, i],
                                      P[k, jp1, i], j >= 3, j >= 2, j + 1 <= ny - 1, limiter, eps)
                    else:
                        F = u * recon(P[k, jp2, i], P[k, jp1, i], P[k, j, i], P[k, j - 1, i],
                                      P[k, j2, i], j + 2 <= ny - 1, j + 1 <= ny - 1, j >= 2,
                                      limiter, eps)
                    Fy[k, j, i] = F
        for k in prange(nz):
            for j in range(ny):
                Fl = uxf[k, j, 0] * P[k, j, 0]
                for i in range(nx):
                    u = uxf[k, j, i + 1]
                    if i == nx - 1:
                        Fr = u * P[k, j, i]
                    elif u > 0.0:
                        Fr = u * recon(P[k, j, max(i - 2, 0)], P[k, j, max(i - 1, 0)], P[k, j, i],
                                       P[k, j, i + 1], P[k, j, min(i + 2, nx - 1)], i >= 2, i >= 1,
                                       i + 2 <= nx - 1, limiter, eps)
                    else:
                        Fr = u * recon(P[k, j, min(i + 3, nx - 1)], P[k, j, min(i + 2, nx - 1)],
                                       P[k, j, i + 1], P[k, j, i], P[k, j, max(i - 1, 0)],
                                       i + 3 <= nx - 1, i + 2 <= nx - 1, i >= 1, limiter, eps)
                    out[k, j, i] = -((Fr - Fl) + (Fy[k, j + 1, i] - Fy[k, j, i])
                                     + (Fz[k + 1, j, i] - Fz[k, j, i])) * ih
                    Fl = Fr

    return advect_3d


@njit(parallel=True, cache=True)
def combine(a, P0, b, P1, c, R, out, tiny):
    """``out = a * P0 + b * P1 + c * R`` elementwise (flattened arrays), one pass.

    Values with ``|out| < tiny`` are set to 0: this keeps far tails, and the squares the
    WENO smoothness indicators form from them, out of denormal floating point (about 100
    times slower arithmetic); the solver uses ``tiny = 1e-100 max P0``, so the
    probability removed is below 1e-90 of the total.
    """
    n = out.size
    for m in prange(n):
        v = a * P0[m] + b * P1[m] + c * R[m]
        if abs(v) < tiny:
            v = 0.0
        out[m] = v


@njit(cache=True)
def laplacian_5pt_serial(f, out):
    """Single-threaded 5-point Laplacian (the ~1.8 Gcell/s one-core baseline)."""
    nz, nx = f.shape
    for k in range(1, nz - 1):
        for i in range(1, nx - 1):
            out[k, i] = f[k - 1, i] + f[k + 1, i] + f[k, i - 1] + f[k, i + 1] - 4.0 * f[k, i]


def empty_like_faces(shape):
    """Zero arrays for the 2D corner exchanges ``Gp, Gm`` of shape (nz+1, nx+1)."""
    return np.zeros((shape[0] + 1, shape[1] + 1)), np.zeros((shape[0] + 1, shape[1] + 1))
