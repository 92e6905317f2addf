"""Shared reference quadratures of the tests (not a test module)."""

from __future__ import annotations

import numpy as np
from numpy.polynomial.legendre import leggauss


def discrete_rule_drift(x_p, lam, W, D, rho, L, phi=None, eps=1e-3):
    """Exact mean horizontal particle velocity near reflecting walls at +-L.

    Uniform spots of density rho in [-L, L] step by xi ~ N(0, 2 D dt) (reflected at the
    walls); each moves the particle by ``-W(x_p - x_c) dX / phi(x_c)``, ``x_c = x_s +
    lam dX``, with W the kernel integrated over z and ``phi`` the kernel's coverage of the
    free-volume-conserving walls (``None``: 1, the truncated kernel). Quadrature over x_s
    (Gauss-Legendre panels, refined at the walls) and the step (uniform nodes: the
    reflection has a kink) for 2 D dt = eps^2; the result's own error is O(eps) (5e-4
    relative without phi).
    """
    dt = eps**2 / (2 * D)
    xi = np.linspace(-9.0, 9.0, 2001)
    cq = np.exp(-xi**2 / 2)
    cq[[0, -1]] *= 0.5
    cq /= cq.sum()
    xi = xi * eps

    def reflect(y):
        y = np.where(y > L, 2 * L - y, y)
        return np.where(y < -L, -2 * L - y, y)

    edges = np.unique(np.concatenate([
        [-L], -L + eps * np.array([2, 5, 10, 20]), np.linspace(-L + 0.05, L - 0.05, 201),
        L - eps * np.array([20, 10, 5, 2]), [L]]))
    t, wt = leggauss(16)
    total = 0.0
    for a, c in zip(edges[:-1], edges[1:]):
        xs = 0.5 * (a + c) + 0.5 * (c - a) * t
        Xs, Q = np.meshgrid(xs, xi, indexing="ij")
        dX = reflect(Xs + Q) - Xs
        xc = Xs + lam * dX
        weight = W(x_p - xc) if phi is None else W(x_p - xc) / phi(xc)
        total += 0.5 * (c - a) * np.dot(wt, (weight * dX) @ cq)
    return -rho * total / dt
