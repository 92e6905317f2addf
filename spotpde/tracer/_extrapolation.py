"""The limited Richardson extrapolation of backward Euler in the IMEX and multirate
steps (private; user: :class:`spotpde.tracer._implicit.ImexSplit`).

``I(tau)`` advances ``dP/dt = A P`` (``A`` an M-matrix operator: the diffusion, plus
the hybrid advection of the fast faces for IMEX) by ``tau`` from ``p``:

    Pa = (I - tau A)^-1 p,   P1 = (I - tau/2 A)^-1 p,   Pb = (I - tau/2 A)^-1 P1,
    S_b = tau/2 (P1 + Pb),   delta = S_b - tau Pa         (so that Pb - Pa = A delta),
    P_new = Pb + A (theta delta),   S += S_b + theta delta.

``theta = 1`` is the extrapolation ``2 Pb - Pa`` (local error ``O(tau**3)``), ``theta =
0`` two backward-Euler half steps. The weights ``theta in [0, 1]`` are chosen cell by
cell to keep ``P_new >= -eps`` (docs/long_runs.md): cell ``i`` can lose at most
``(1 - LIMIT_MARGIN) max(Pb_i + eps, 0)`` through the negative terms ``A_ij theta_j
delta_j`` (``delta_j < 0``, ``A_ij >= 0``) and ``A_ii theta_i delta_i`` (``delta_i >
0``); these are scaled by ``R_i = min(1, (1 - LIMIT_MARGIN) max(Pb_i + eps, 0) /
-N_i)``, ``N_i`` their sum at ``theta = 1``, and ``theta_j`` is the smallest ``R`` of
the cells ``delta_j`` takes from (itself if ``delta_j > 0``, the rows of column ``j``
if ``< 0``). ``S`` (the running ``int P dt``) gives the fluxes, so ``P_new - p = A
(S_new - S)`` to round-off: conservative. An operator with negative off-diagonals (a
diffusion tensor that is not diagonally dominant, which the solver warns of) is applied
as it is, so conservation holds; the limiter then counts only the non-negative entries
and positivity is not guaranteed.

**Positivity in floating point.** In exact arithmetic the limited loss ``Pb_i + eps``
gives ``P_new_i >= -eps``; computed, the sum ``Pb_i + (terms)`` carries a rounding
error of up to about ``(m + 1) u (Pb_i + |terms|)`` (``u = 2**-53``, ``m`` the entries
of row ``i``), enough to end a few ulps of ``Pb_i`` below ``-eps`` (``-1.0000000019731e-15``
against ``eps = 1e-15`` with ``Pb_i = 8.5e-9``). :data:`LIMIT_MARGIN` holds back a
relative ``256 u`` of the allowed loss, more than the ``(4 m + 9) u`` the rounding of
the limiter (``N_i``, ``R_i``, the products ``theta delta`` and ``A c``) and of that sum
can take for rows of up to 61 entries (a 3D 27-point stencil has 27). So wherever
``Pb_i >= 0`` (always: the solves are of M-matrices, sums of non-negative terms)
``P_new_i >= -eps`` holds exactly as computed, not only to round-off; the held-back
fraction changes ``P_new`` by at most ``LIMIT_MARGIN (Pb_i + eps)``.

Two kernels compute the same numbers to round-off:

* :func:`_extrapolate`: any stencil, the off-diagonals in diagonal storage, after the
  three solves;
* :func:`_extrapolate_rows`: ``A`` tridiagonal without coupling between grid rows (the
  void model in 2D: horizontal diffusion only), factors by the Thomas algorithm
  (:mod:`._linsolve`). It does the three solves and the extrapolation row by row, rows
  in parallel, each row's work in the first-level cache: ``I(tau)`` in about 2 ms
  instead of 4.4 ms for the 89,600 cells of the void propagator (two threads). Values of
  its solves below ``tiny`` are set to 0 (:func:`._linsolve.thomas_rows`), which
  changes ``P`` and ``S`` by at most that much.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp

from ._linsolve import _Tridiagonal, thomas_rows, thomas_rows_pair

#: The fraction of a cell's allowed loss ``Pb_i + eps`` the limiter holds back, so that
#: ``P_new >= -eps`` survives the rounding of the step (module docstring): ``256 u``.
LIMIT_MARGIN = 256 * 2.0**-53


class Extrapolation:
    """``I(tau)`` for one operator ``A`` (CSC; ``nx`` cells per grid row)."""

    def __init__(self, A, nx):
        self.diag = np.ascontiguousarray(A.diagonal())
        off = (A - sp.diags(self.diag)).tocsc()
        off.eliminate_zeros()
        dia = off.todia()
        n = A.shape[0]
        self.offsets = np.ascontiguousarray(dia.offsets, dtype=np.int64)
        # diagonal storage as wide as the matrix (scipy's ends at the last non-empty column)
        self.data = np.zeros((self.offsets.size, n))
        self.data[:, :dia.data.shape[1]] = dia.data
        self.nx = None
        if set(self.offsets.tolist()) <= {-1, 1}:
            # A[i, i-1] and A[i, i+1] by row; zero across the ends of grid rows
            band = {int(o): self.data[k] for k, o in enumerate(self.offsets)}
            lower, upper = np.zeros(n), np.zeros(n)
            if -1 in band:
                lower[1:] = band[-1][:-1]       # data[k, j] = A[j + 1, j]
            if 1 in band:
                upper[:-1] = band[1][1:]        # data[k, j] = A[j - 1, j]
            if not (lower[::nx].any() or upper[nx - 1::nx].any()):
                self.nx, self.lower, self.upper = nx, lower, upper

    def __call__(self, lu, lu_half, p, tau, eps, S, tiny=0.0, margin=LIMIT_MARGIN):
        """``(P_new, min theta)`` from ``p`` over ``tau``; ``lu`` / ``lu_half`` the factors
        of ``I - tau A`` / ``I - tau/2 A``; ``S`` is updated in place; ``tiny``: values of
        the row solves below it are 0 (tridiagonal path); ``margin``: the fraction of
        the allowed loss held back (:data:`LIMIT_MARGIN`)."""
        p = np.ascontiguousarray(p, dtype=float)
        keep = 1.0 - margin
        if self.nx is not None and isinstance(lu, _Tridiagonal) and \
                isinstance(lu_half, _Tridiagonal):
            return _extrapolate_rows(self.nx, lu.m, lu.inv, lu.du, lu_half.m, lu_half.inv,
                                     lu_half.du, self.lower, self.upper, self.diag, p, tau,
                                     eps, tiny, S, keep)
        Pa = lu.solve(p)
        P1 = lu_half.solve(p)
        Pb = lu_half.solve(P1)
        return _extrapolate(self.offsets, self.data, self.diag, Pa, P1, Pb, tau, eps, S,
                            keep)


@numba.njit(cache=True)
def _extrapolate(offsets, data, diag, Pa, P1, Pb, tau, eps, S, keep):
    """The extrapolation from the three solves (module docstring), any stencil.

    The off-diagonal part of ``A`` (entries ``>= 0``) comes in diagonal storage:
    ``data[k, j] = A[j - offsets[k], j]`` (a finite-volume stencil has a few diagonals),
    so every loop runs over contiguous slices; ``diag`` is the diagonal. ``S`` is
    updated in place; ``keep = 1 - LIMIT_MARGIN``. Returns ``(P_new, min(theta))``.
    """
    n = Pb.size
    delta = np.empty(n)
    neg = np.empty(n)
    N = np.empty(n)
    for j in range(n):
        Sb = 0.5 * tau * (P1[j] + Pb[j])
        d = Sb - tau * Pa[j]
        delta[j] = d
        neg[j] = min(d, 0.0)
        N[j] = diag[j] * max(d, 0.0)
        S[j] += Sb
    # slices with loop indices from 0: no negative-index wraparound, so the loops vectorise
    for k in range(offsets.size):
        o = offsets[k]
        lo, hi = max(0, -o), min(n, n - o)
        Nk, ak, gk = N[lo:hi], data[k, lo + o:hi + o], neg[lo + o:hi + o]
        for t in range(hi - lo):           # row lo + t, column lo + t + o
            Nk[t] += max(ak[t], 0.0) * gk[t]
    R = np.empty(n)
    for i in range(n):
        r = max(Pb[i] + eps, 0.0) * keep / max(-N[i], 1e-300)
        R[i] = min(1.0, r) if N[i] < 0.0 else 1.0
    theta = np.ones(n)
    for k in range(offsets.size):
        o = offsets[k]
        lo, hi = max(0, o), min(n, n + o)
        th, ak, dk, rk = theta[lo:hi], data[k, lo:hi], delta[lo:hi], R[lo - o:hi - o]
        for t in range(hi - lo):           # column lo + t, row lo + t - o
            v = rk[t] if (ak[t] > 0.0) & (dk[t] < 0.0) else 1.0
            th[t] = min(th[t], v)
    c = np.empty(n)
    tmin = 1.0
    for j in range(n):
        t = R[j] if delta[j] > 0.0 else theta[j]
        tmin = min(tmin, t)
        c[j] = t * delta[j]
        S[j] += c[j]
    out = np.empty(n)
    for j in range(n):
        out[j] = Pb[j] + diag[j] * c[j]
    for k in range(offsets.size):
        o = offsets[k]
        lo, hi = max(0, -o), min(n, n - o)
        ok, ak, ck = out[lo:hi], data[k, lo + o:hi + o], c[lo + o:hi + o]
        for t in range(hi - lo):
            ok[t] += ak[t] * ck[t]
    return out, tmin


@numba.njit(cache=True, parallel=True)
def _extrapolate_rows(nx, m1, inv1, du1, m2, inv2, du2, lower, upper, diag, p, tau, eps,
                      tiny, S, keep):
    """The three solves and the extrapolation (module docstring) for a tridiagonal
    ``A`` without coupling between rows of ``nx`` cells, one row at a time (rows in
    parallel).

    ``m1, inv1, du1`` / ``m2, inv2, du2``: Thomas factors of ``I - tau A`` / ``I - tau/2
    A``; ``lower[i] = A[i, i-1]``, ``upper[i] = A[i, i+1]`` (``>= 0``, zero at the ends
    of the rows); ``diag`` the diagonal; ``tiny``: solution values below it are 0
    (:func:`._linsolve.thomas_rows`); ``keep = 1 - LIMIT_MARGIN``. ``S`` is updated in
    place. Returns ``(P_new, min(theta))``.
    """
    n = p.size
    rows = n // nx
    out = np.empty(n)
    row_min = np.ones(rows)
    for r in numba.prange(rows):
        s = r * nx
        Pa = np.empty(nx)
        P1 = np.empty(nx)
        Pb = np.empty(nx)
        delta = np.empty(nx)
        R = np.empty(nx)
        c = np.empty(nx)
        thomas_rows_pair(m1, inv1, du1, m2, inv2, du2, s, p, Pa, P1, tiny)
        thomas_rows(m2, inv2, du2, s, P1, 0, Pb, tiny)
        for t in range(nx):
            i = s + t
            Sb = 0.5 * tau * (P1[t] + Pb[t])
            delta[t] = Sb - tau * Pa[t]
            S[i] += Sb
        for t in range(nx):
            i = s + t
            N = 0.0
            if t > 0:
                N += max(lower[i], 0.0) * min(delta[t - 1], 0.0)
            if t < nx - 1:
                N += max(upper[i], 0.0) * min(delta[t + 1], 0.0)
            N += diag[i] * max(delta[t], 0.0)
            R[t] = min(1.0, max(Pb[t] + eps, 0.0) * keep / -N) if N < 0.0 else 1.0
        tmin = 1.0
        for t in range(nx):
            i = s + t
            d = delta[t]
            th = 1.0
            if d > 0.0:
                th = R[t]
            elif d < 0.0:
                # column i's rows: i - 1 (entry upper[i-1]) and i + 1 (entry lower[i+1])
                if t > 0 and upper[i - 1] > 0.0:
                    th = min(th, R[t - 1])
                if t < nx - 1 and lower[i + 1] > 0.0:
                    th = min(th, R[t + 1])
            tmin = min(tmin, th)
            c[t] = th * d
            S[i] += c[t]
        row_min[r] = tmin
        for t in range(nx):
            i = s + t
            v = Pb[t] + diag[i] * c[t]
            if t > 0:
                v += lower[i] * c[t - 1]
            if t < nx - 1:
                v += upper[i] * c[t + 1]
            out[i] = v
    return out, row_min.min()
