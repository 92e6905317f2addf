"""Exact and high-order cell averages of the kernel shapes (private helpers of kernels).

All functions work in *scaled* coordinates, where the kernel is isotropic with unit
size: ``X = x / a_h`` (and ``Y``), ``Z = z / a_z``. A cell of the physical grid is a box
of sides ``h / a_h`` and ``h / a_z`` there. Three shapes:

* sharp unit disk / ball (``Uniform``): the covered area of a rectangle is exact in
  closed form (:func:`rect_disk_area`); the covered volume of a box is the integral over
  ``Z`` of exact slice areas, computed with Gauss-Legendre between the breakpoints where
  the slice radius meets an edge or a corner, after the substitution
  ``Z = a + (b - a)(1 - cos(pi u))/2`` that removes the square-root endpoint behaviour
  (so the quadrature converges exponentially): :func:`box_ball_volume`;
* Gaussian: separable, exact through ``erf`` / ``erfc`` (in :mod:`spotpde.kernels`);
* exponential ``exp(-p rho)``: numba kernels. Cells near the cusp at the origin use the
  divergence identity ``int_box f = sum_faces (x . n) int_face phi_d(p rho(x)) dS`` with
  ``phi_d(s) = int_0^1 t^(d-1) exp(-s t) dt`` (``div(x phi) = f`` for any ``f``; proof in
  docs/kernels.md), which turns the non-smooth cell integral into smooth face integrals;
  every other cell uses tensor Gauss-Legendre whose order is chosen from the distance to
  the cusp and from ``p * h / a`` so that the relative error is below ~1e-13.
"""

from __future__ import annotations

import numpy as np
from numba import njit

# ----------------------------------------------------------------------------------------
# Uniform: rectangle and box intersected with the unit disk / ball
# ----------------------------------------------------------------------------------------


def _G(s):
    """Antiderivative of sqrt(1 - s^2): (s sqrt(1 - s^2) + asin s) / 2, s clipped to [-1, 1]."""
    s = np.clip(s, -1.0, 1.0)
    return 0.5 * (s * np.sqrt(1.0 - s * s) + np.arcsin(s))


def rect_disk_area(x0, x1, z0, z1):
    """Exact area of ``[x0, x1] x [z0, z1]`` intersected with the unit disk.

    The area is ``int_{x0}^{x1} max(0, min(z1, c) - max(z0, -c)) ds`` with
    ``c = sqrt(1 - s^2)``; between the breakpoints ``s = +-1``, ``s = +-sqrt(1 - z0^2)``,
    ``s = +-sqrt(1 - z1^2)`` the integrand is one of ``z1 - z0``, ``c - z0``, ``z1 + c``,
    ``2c`` or 0, each integrated in closed form with ``int c ds = G(s)``.

    Args:
        x0, x1, z0, z1: rectangle bounds (broadcasting arrays), ``x0 <= x1``, ``z0 <= z1``.

    Returns:
        The covered area (array).
    """
    x0, x1, z0, z1 = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (x0, x1, z0, z1)))
    c0 = np.sqrt(np.clip(1.0 - z0 * z0, 0.0, None))
    c1 = np.sqrt(np.clip(1.0 - z1 * z1, 0.0, None))
    one = np.ones_like(x0)
    pts = np.stack([x0, x1, -one, one, -c0, c0, -c1, c1])
    pts = np.clip(pts, x0, x1)
    pts.sort(axis=0)
    total = np.zeros_like(x0)
    for k in range(pts.shape[0] - 1):
        a, b = pts[k], pts[k + 1]
        m = 0.5 * (a + b)
        cm = np.sqrt(np.clip(1.0 - m * m, 0.0, None))
        upper_is_c = cm < z1
        lower_is_c = -cm > z0
        up = np.where(upper_is_c, cm, z1)
        lo = np.where(lower_is_c, -cm, z0)
        valid = (np.abs(m) < 1.0) & (up > lo) & (b > a)
        ic = _G(b) - _G(a)
        i_up = np.where(upper_is_c, ic, z1 * (b - a))
        i_lo = np.where(lower_is_c, -ic, z0 * (b - a))
        total += np.where(valid, i_up - i_lo, 0.0)
    return total


def _disk_area_radius(x0, x1, y0, y1, a):
    """Area of ``[x0,x1] x [y0,y1]`` inside the disk of radius ``a`` (``a >= 0``)."""
    safe = np.where(a > 0, a, 1.0)
    area = safe * safe * rect_disk_area(x0 / safe, x1 / safe, y0 / safe, y1 / safe)
    return np.where(a > 0, area, 0.0)


_GL_U, _GL_W = np.polynomial.legendre.leggauss(16)
_GL_U = 0.5 * (_GL_U + 1.0)
_GL_W = 0.5 * _GL_W


def box_ball_volume(x0, x1, y0, y1, z0, z1):
    """Volume of the box ``[x0,x1] x [y0,y1] x [z0,z1]`` inside the unit ball (1D arrays).

    ``V = int_{z0}^{z1} A(sqrt(1 - Z^2)) dZ`` with ``A(a)`` the exact area of the
    ``(x, y)`` rectangle inside the disk of radius ``a`` (:func:`rect_disk_area`).
    ``A`` is analytic in ``Z`` between the breakpoints ``Z = +-sqrt(1 - t^2)`` for
    ``t`` in ``{|x_i|, |y_j|, sqrt(x_i^2 + y_j^2)}`` and ``Z = +-1``; on each piece the
    substitution ``Z = a + (b - a)(1 - cos(pi u))/2`` makes the square-root behaviour at
    the ends smooth and 16-point Gauss-Legendre in ``u`` is exact to round-off.
    """
    x0, x1, y0, y1, z0, z1 = (np.asarray(v, dtype=float) for v in (x0, x1, y0, y1, z0, z1))
    ts = [np.abs(x0), np.abs(x1), np.abs(y0), np.abs(y1)]
    ts += [np.hypot(xi, yj) for xi in (x0, x1) for yj in (y0, y1)]
    cand = [z0, z1, -np.ones_like(z0), np.ones_like(z0)]
    for t in ts:
        zt = np.sqrt(np.clip(1.0 - t * t, 0.0, None))
        cand += [zt, -zt]
    pts = np.clip(np.stack(cand), z0, z1)
    pts.sort(axis=0)
    total = np.zeros_like(z0)
    for k in range(pts.shape[0] - 1):
        a, b = pts[k], pts[k + 1]
        length = b - a
        if not np.any(length > 0):
            continue
        for u, wgt in zip(_GL_U, _GL_W):
            s = 0.5 * (1.0 - np.cos(np.pi * u))
            zz = a + length * s
            jac = length * 0.5 * np.pi * np.sin(np.pi * u)
            rad = np.sqrt(np.clip(1.0 - zz * zz, 0.0, None))
            total += wgt * jac * _disk_area_radius(x0, x1, y0, y1, rad)
    return total


# ----------------------------------------------------------------------------------------
# Exponential: cell averages of exp(-p rho), numba
# ----------------------------------------------------------------------------------------


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
def exp_cell_avg_2d(mz, mx, hz, hx, p):
    """Cell averages of exp(-p sqrt(X^2 + Z^2)) on cells (k, i), 0 <= k <= mz, 0 <= i <= mx.

    Cell (k, i) spans ``[(i - 1/2) hx, (i + 1/2) hx] x [(k - 1/2) hz, (k + 1/2) hz]``
    (scaled coordinates). Returns the first quadrant; the rest follows by symmetry.
    """
    out = np.zeros((mz + 1, mx + 1))
    hmax = max(hx, hz)
    nsub, nfar = _far_split(p, hmax, 2)
    xf, wf = _gl_points(nfar)
    xm, wm = _gl_points(max(nfar, 12))
    xi, wi = _gl_points(14)
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
    nsub, nfar = _far_split(p, hmax, 3)
    xf, wf = _gl_points(nfar)
    xm, wm = _gl_points(max(nfar, 12))
    xi, wi = _gl_points(12)
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
