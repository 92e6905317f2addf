"""Cell averages of the exponential kernel ``exp(-p rho)`` (private helpers of kernels; numba).

Scaled coordinates as in :mod:`._cellavg` (the kernel isotropic with unit size). Cells
near the cusp at the origin use the divergence identity
``int_box f = sum_faces (x . n) int_face phi_d(p rho(x)) dS`` with
``phi_d(s) = int_0^1 t^(d-1) exp(-s t) dt`` (``div(x phi) = f`` for any ``f``; proof in
docs/kernels.md), which turns the non-smooth cell integral into smooth face integrals;
every other cell uses tensor Gauss-Legendre whose order is chosen from the distance to
the cusp and from ``p * h / a`` so that the relative error is below ~1e-13. A module of
its own so that only exponential kernels import numba (``spotpde.load_case`` builds
every case's kernel).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _phi(d, s):
    """phi_d(s) = int_0^1 t^(d-1) exp(-s t) dt = gamma(d, s) / s^d (series for s < 1)."""
    if s < 1.0:
        total = 0.0
        term = 1.0  # (-s)^k / k!
        for k in range(40):
            total += term / (k + d)
            term *= -s / (k + 1)
        return total
    e = np.exp(-s)
    if d == 2:
        return (1.0 - (1.0 + s) * e) / (s * s)
    return (2.0 - (2.0 + 2.0 * s + s * s) * e) / (s * s * s)


@njit(cache=True)
def _gl_points(n):
    # Golub-Welsch is overkill; Newton iteration on Legendre polynomials (numba friendly).
    x = np.empty(n)
    w = np.empty(n)
    for i in range(n):
        z = np.cos(np.pi * (i + 0.75) / (n + 0.5))
        for _ in range(100):
            p1 = 1.0
            p2 = 0.0
            for j in range(1, n + 1):
                p3 = p2
                p2 = p1
                p1 = ((2.0 * j - 1.0) * z * p2 - (j - 1.0) * p3) / j
            pp = n * (z * p1 - p2) / (z * z - 1.0)
            z1 = z
            z = z1 - p1 / pp
            if abs(z - z1) < 1e-15:
                break
        x[i] = z
        w[i] = 2.0 / ((1.0 - z * z) * pp * pp)
    return x, w


@njit(cache=True)
def _face_integral_2d(c, t0, t1, p, xn, xg, wg):
    """int_{t0}^{t1} phi_2(p sqrt(c^2 + t^2)) dt on panels no longer than |c|."""
    npan = max(1, int(np.ceil((t1 - t0) / abs(c))))
    dl = (t1 - t0) / npan
    total = 0.0
    for k in range(npan):
        a = t0 + k * dl
        for q in range(xg.size):
            t = a + 0.5 * dl * (xg[q] + 1.0)
            total += 0.5 * dl * wg[q] * _phi(2, p * np.sqrt(c * c + t * t))
    return xn * total


@njit(cache=True)
def _face_integral_3d(c, s0, s1, t0, t1, p, xn, xg, wg):
    """int over [s0,s1] x [t0,t1] of phi_3(p sqrt(c^2 + s^2 + t^2)), panels <= |c|."""
    ns = max(1, int(np.ceil((s1 - s0) / abs(c))))
    nt = max(1, int(np.ceil((t1 - t0) / abs(c))))
    ds = (s1 - s0) / ns
    dt = (t1 - t0) / nt
    total = 0.0
    for i in range(ns):
        a = s0 + i * ds
        for j in range(nt):
            b = t0 + j * dt
            for q in range(xg.size):
                s = a + 0.5 * ds * (xg[q] + 1.0)
                for r in range(xg.size):
                    t = b + 0.5 * dt * (xg[r] + 1.0)
                    total += 0.25 * ds * dt * wg[q] * wg[r] * _phi(
                        3, p * np.sqrt(c * c + s * s + t * t))
    return xn * total


@njit(cache=True)
def _far_order(p, hmax):
    """Smallest Gauss order n with (p hmax / 2)^(2n) / (2n)! < 1e-15.

    This bounds the Gauss-Legendre error for the analytic part of exp(-p rho) on a cell
    of size hmax far from the cusp (Taylor remainder of order 2n).
    """
    e = 0.5 * p * hmax
    for n in range(2, 30):
        val = 1.0
        for k in range(1, 2 * n + 1):
            val *= e / k
        if val < 1e-15:
            return n
    return 30


@njit(cache=True)
def _far_split(p, hmax, d):
    """Sub-cells per axis and Gauss order minimising (nsub * n)^d for exp(-p rho) on a cell."""
    best_cost = 1e300
    best = (1, 30)
    for nsub in range(1, 64):
        if 0.5 * p * hmax / nsub > 2.0:
            continue
        n = _far_order(p, hmax / nsub)
        cost = (nsub * n) ** d
        if cost < best_cost:
            best_cost = cost
            best = (nsub, n)
    return best


@njit(cache=True)
def _rules(p, hmax, d, n_face):
    """The quadrature rules of a cell average in ``d`` dimensions: sub-cells per axis, the
    far and middle Gauss-Legendre rules (nodes, weights) and the face rule of order
    ``n_face`` for cells next to the cusp."""
    nsub, nfar = _far_split(p, hmax, d)
    xf, wf = _gl_points(nfar)
    xm, wm = _gl_points(max(nfar, 12))
    xi, wi = _gl_points(n_face)
    return nsub, xf, wf, xm, wm, xi, wi


@njit(cache=True)
def exp_cell_avg_2d(mz, mx, hz, hx, p):
    """Cell averages of exp(-p sqrt(X^2 + Z^2)) on cells (k, i), 0 <= k <= mz, 0 <= i <= mx.

    Cell (k, i) spans ``[(i - 1/2) hx, (i + 1/2) hx] x [(k - 1/2) hz, (k + 1/2) hz]``
    (scaled coordinates). Returns the first quadrant; the rest follows by symmetry.
    """
    out = np.zeros((mz + 1, mx + 1))
    hmax = max(hx, hz)
    nsub, xf, wf, xm, wm, xi, wi = _rules(p, hmax, 2, 14)
    for k in range(mz + 1):
        z0 = (k - 0.5) * hz
        z1 = (k + 0.5) * hz
        for i in range(mx + 1):
            x0 = (i - 0.5) * hx
            x1 = (i + 0.5) * hx
            dz = max(z0, 0.0)
            dx = max(x0, 0.0)
            dist = np.sqrt(dx * dx + dz * dz)
            if dist < 1.5 * hmax:
                tot = 0.0
                for c, xn, s0, s1 in ((x1, x1, z0, z1), (x0, -x0, z0, z1),
                                      (z1, z1, x0, x1), (z0, -z0, x0, x1)):
                    if c != 0.0:
                        tot += _face_integral_2d(c, s0, s1, p, xn, xi, wi)
                out[k, i] = tot / (hx * hz)
                continue
            if dist < 6.0 * hmax:
                xg, wg = xm, wm
            else:
                xg, wg = xf, wf
            tot = 0.0
            sx = hx / nsub
            sz = hz / nsub
            for a in range(nsub):
                for b in range(nsub):
                    cz = z0 + (a + 0.5) * sz
                    cx = x0 + (b + 0.5) * sx
                    for q in range(xg.size):
                        zz = cz + 0.5 * sz * xg[q]
                        for r in range(xg.size):
                            xx = cx + 0.5 * sx * xg[r]
                            tot += wg[q] * wg[r] * np.exp(-p * np.sqrt(xx * xx + zz * zz))
            out[k, i] = 0.25 * tot / (nsub * nsub)
    return out


@njit(cache=True)
def exp_cell_avg_3d(mz, mx, hz, hx, p):
    """As :func:`exp_cell_avg_2d` for exp(-p sqrt(X^2 + Y^2 + Z^2)); returns (k, j, i) octant."""
    out = np.zeros((mz + 1, mx + 1, mx + 1))
    hmax = max(hx, hz)
    nsub, xf, wf, xm, wm, xi, wi = _rules(p, hmax, 3, 12)
    for k in range(mz + 1):
        z0 = (k - 0.5) * hz
        z1 = (k + 0.5) * hz
        for j in range(mx + 1):
            y0 = (j - 0.5) * hx
            y1 = (j + 0.5) * hx
            for i in range(j, mx + 1):  # symmetric in x <-> y: fill i >= j, mirror
                x0 = (i - 0.5) * hx
                x1 = (i + 0.5) * hx
                dz = max(z0, 0.0)
                dy = max(y0, 0.0)
                dx = max(x0, 0.0)
                dist = np.sqrt(dx * dx + dy * dy + dz * dz)
                if dist < 1.5 * hmax:
                    tot = 0.0
                    if x1 != 0.0:
                        tot += _face_integral_3d(x1, y0, y1, z0, z1, p, x1, xi, wi)
                    if x0 != 0.0:
                        tot += _face_integral_3d(x0, y0, y1, z0, z1, p, -x0, xi, wi)
                    if y1 != 0.0:
                        tot += _face_integral_3d(y1, x0, x1, z0, z1, p, y1, xi, wi)
                    if y0 != 0.0:
                        tot += _face_integral_3d(y0, x0, x1, z0, z1, p, -y0, xi, wi)
                    if z1 != 0.0:
                        tot += _face_integral_3d(z1, x0, x1, y0, y1, p, z1, xi, wi)
                    if z0 != 0.0:
                        tot += _face_integral_3d(z0, x0, x1, y0, y1, p, -z0, xi, wi)
                    val = tot / (hx * hx * hz)
                else:
                    if dist < 6.0 * hmax:
                        xg, wg = xm, wm
                    else:
                        xg, wg = xf, wf
                    tot = 0.0
                    sx = hx / nsub
                    sz = hz / nsub
                    for a in range(nsub):
                        cz = z0 + (a + 0.5) * sz
                        for b in range(nsub):
                            cy = y0 + (b + 0.5) * sx
                            for c in range(nsub):
                                cx = x0 + (c + 0.5) * sx
                                for q in range(xg.size):
                                    zz = cz + 0.5 * sz * xg[q]
                                    for r in range(xg.size):
                                        yy = cy + 0.5 * sx * xg[r]
                                        for s in range(xg.size):
                                            xx = cx + 0.5 * sx * xg[s]
                                            tot += wg[q] * wg[r] * wg[s] * np.exp(
                                                -p * np.sqrt(xx * xx + yy * yy + zz * zz))
                    val = 0.125 * tot / (nsub * nsub * nsub)
                out[k, j, i] = val
                out[k, i, j] = val
    return out
