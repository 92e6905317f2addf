"""Numba kernel of the tracer's exchange (diffusion) operator with face coefficients (private).

Used by :class:`spotpde.tracer._geometry._GeometryOperator` on axisymmetric grids and in
hoppers, where an exchange's coefficients depend on the face (the metric ``r_f / r``, the
walls of the staircase) and the fused 2D kernel's per-cell coefficients cannot carry them.
It evaluates the same operator as the sparse matrix ``L`` of
:meth:`spotpde.tracer._geometry._Geometry.diffusion` (and its vertical flux map ``Bz``):
each pairwise exchange ``E = alpha P_a - beta P_b`` (1 / (d**2 time) times ``P``) is
computed once into a face array and added to one cell and subtracted from the other, so
the total is conserved to round-off and the result equals ``L P`` to round-off.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True)
def exchange_2d(P, xa, xb, za, zb, pa, pb, ma, mb, has_diag, R, Fz_acc, w_acc, h):
    """``R += L P`` and ``Fz_acc += w_acc Bz P`` for the exchanges given by face arrays.

    Args:
        P: (nz, nx) density.
        xa, xb: (nz, nx-1) exchange between cells (k, i) and (k, i+1):
            ``E = xa P[k, i] - xb P[k, i+1]``.
        za, zb: (nz-1, nx) between (k, i) and (k+1, i).
        pa, pb: (nz-1, nx-1) diagonal between (k, i) and (k+1, i+1).
        ma, mb: (nz-1, nx-1) diagonal between (k, i+1) and (k+1, i).
        has_diag: evaluate the diagonal exchanges.
        R: (nz, nx) added to.
        Fz_acc: (nz+1, nx) upward flux accumulator: ``+= w_acc h E`` for vertical
            exchanges, half of each diagonal one to each of the two columns it joins.
        w_acc: weight (time step times Runge-Kutta weight).
        h: spacing.
    """
    nz, nx = P.shape
    Ex = np.zeros((nz, nx + 1))
    Ez = np.zeros((nz + 1, nx))
    Ep = np.zeros((nz + 1, nx + 1))     # corner (k, i+1): (k-1, i) -> (k, i+1)
    Em = np.zeros((nz + 1, nx + 1))     # corner (k, i+1): (k-1, i+1) -> (k, i)
    for k in prange(nz):
        for i in range(nx - 1):
            Ex[k, i + 1] = xa[k, i] * P[k, i] - xb[k, i] * P[k, i + 1]
    for k in prange(1, nz):
        for i in range(nx):
            Ez[k, i] = za[k - 1, i] * P[k - 1, i] - zb[k - 1, i] * P[k, i]
        if has_diag:
            for i in range(nx - 1):
                Ep[k, i + 1] = pa[k - 1, i] * P[k - 1, i] - pb[k - 1, i] * P[k, i + 1]
                Em[k, i + 1] = ma[k - 1, i] * P[k - 1, i + 1] - mb[k - 1, i] * P[k, i]
    hw = h * w_acc
    for k in prange(nz):
        for i in range(nx):
            r = Ex[k, i] - Ex[k, i + 1] + Ez[k, i] - Ez[k + 1, i]
            if has_diag:
                r += Ep[k, i] - Ep[k + 1, i + 1] + Em[k, i + 1] - Em[k + 1, i]
            R[k, i] += r
        if k >= 1:
            for i in range(nx):
                v = Ez[k, i]
                if has_diag:
                    v += 0.5 * (Ep[k, i + 1] + Ep[k, i] + Em[k, i + 1] + Em[k, i])
                Fz_acc[k, i] += hw * v
