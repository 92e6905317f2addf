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
* exponential ``exp(-p rho)``: numba kernels in :mod:`._cellavg_exp` (imported only
  when an exponential kernel is sampled, so that validating a case does not import
  numba).
"""

from __future__ import annotations

import numpy as np

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
