"""Factorisations of the implicit tracer steps ``(I - tau A) x = b`` (private).

Every implicit part of the tracer solvers (backward-Euler diffusion of the explicit
scheme, the IMEX / multirate diffusion, TR-BDF2) solves with an M-matrix ``I - tau A``
many times for one ``tau``, so it is factorised once. Two cases:

* **tridiagonal** in the natural (x fastest) ordering: every exchange is between
  horizontal neighbours of one row, as for the void model in 2D (``D_xx`` only, no
  vertical diffusion) when no advection is implicit. Gaussian elimination without
  pivoting (the Thomas algorithm; Golub & Van Loan 2013, §4.3) then costs about ``5 n``
  operations per solve. It is stable without pivoting because ``I - tau A`` is
  column diagonally dominant (an M-matrix whose column sums are ``1`` plus ``tau``
  times the outflow rates): the multipliers are at most 1 in magnitude and every
  reduced matrix stays column diagonally dominant (Golub & Van Loan, Theorem 3.4.3).
  SuperLU pays per supernode on such a matrix: for the 89,600 cells of the void
  propagator a solve took 0.7 ms here against 3.1 ms (timed in one process;
  ``benchmarks/long_runs.py`` times the runs with and without it). The solution is
  SuperLU's to round-off (``tests/tracer/test_linsolve.py``).
* anything else: SuperLU (``scipy.sparse.linalg.splu``) with the given column ordering.
"""

from __future__ import annotations

import numba
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


@numba.njit(cache=True, error_model="numpy")
def _thomas_factor(dl, d, du):
    """``M = L U``, ``L`` unit lower bidiagonal with multipliers ``m``, ``U`` upper
    bidiagonal with diagonal ``1 / inv`` and superdiagonal ``du`` (a zero pivot gives an
    infinite ``inv``: numpy's error model)."""
    n = d.size
    m = np.zeros(n)
    inv = np.empty(n)
    piv = d[0]
    inv[0] = 1.0 / piv
    for i in range(1, n):
        m[i] = dl[i - 1] * inv[i - 1]
        piv = d[i] - m[i] * du[i - 1]
        inv[i] = 1.0 / piv
    return m, inv


@numba.njit(cache=True)
def _flush(v, tiny):
    """``v``, or 0 when ``|v| < tiny`` (NaN is kept)."""
    return 0.0 if abs(v) < tiny else v


@numba.njit(cache=True)
def thomas_rows(m, inv, du, s, b, bs, x, tiny):
    """``x[:nx]`` (``nx = x.size``) solves the rows ``s .. s+nx-1`` of ``L U x = b``
    (forward, then backward substitution with the factors of :func:`_thomas_factor`)
    for the right-hand side ``b[bs:bs+nx]``; these rows must not be coupled to the
    others (``m[s] = 0``, ``du[s+nx-1] = 0``), which the whole system (``s = bs = 0``,
    ``nx = n``) trivially is. Values below ``tiny`` in magnitude are set to 0 as they
    arise (``tiny = 0``: none): the sweeps carry a geometrically decaying tail across
    the empty part of a row, which would otherwise pass through the subnormal numbers
    (each about a hundred times slower)."""
    nx = x.size
    x[0] = _flush(b[bs], tiny)
    for t in range(1, nx):
        x[t] = _flush(b[bs + t] - m[s + t] * x[t - 1], tiny)
    x[nx - 1] *= inv[s + nx - 1]
    for t in range(nx - 2, -1, -1):
        x[t] = _flush((x[t] - du[s + t] * x[t + 1]) * inv[s + t], tiny)


@numba.njit(cache=True)
def thomas_rows_pair(m, inv, du, m2, inv2, du2, s, b, x, y, tiny):
    """:func:`thomas_rows` of the same right-hand side ``b[s:s+nx]`` for two systems
    (factors ``m, inv, du`` into ``x``, ``m2, inv2, du2`` into ``y``) in one sweep: the
    two recurrences interleave, each waiting on its own previous value only, which hides
    the latency of one behind the other (``I(tau)`` of the void propagator 2.0 against
    2.8 ms with two separate sweeps); the same values as two calls."""
    nx = x.size
    x[0] = y[0] = _flush(b[s], tiny)
    for t in range(1, nx):
        x[t] = _flush(b[s + t] - m[s + t] * x[t - 1], tiny)
        y[t] = _flush(b[s + t] - m2[s + t] * y[t - 1], tiny)
    x[nx - 1] *= inv[s + nx - 1]
    y[nx - 1] *= inv2[s + nx - 1]
    for t in range(nx - 2, -1, -1):
        x[t] = _flush((x[t] - du[s + t] * x[t + 1]) * inv[s + t], tiny)
        y[t] = _flush((y[t] - du2[s + t] * y[t + 1]) * inv2[s + t], tiny)


class _Tridiagonal:
    """LU factors of a tridiagonal matrix without pivoting; ``solve(rhs)``."""

    def __init__(self, M):
        dia = M.todia()
        n = M.shape[0]
        band = {int(o): dia.data[k] for k, o in enumerate(dia.offsets)}
        zero = np.zeros(n)
        # DIA storage: data[k, j] is the entry (j - offset, j)
        dl = np.ascontiguousarray(band.get(-1, zero)[:-1])
        d = np.ascontiguousarray(band.get(0, zero))
        self.du = np.ascontiguousarray(band.get(1, zero)[1:])
        self.m, self.inv = _thomas_factor(dl, d, self.du)
        if not np.all(np.isfinite(self.inv)):
            raise np.linalg.LinAlgError("M: the tridiagonal factorisation met a zero pivot "
                                        "(the matrix is singular or needs pivoting)")

    def solve(self, rhs):
        x = np.empty(self.m.size)
        thomas_rows(self.m, self.inv, self.du, 0, np.ascontiguousarray(rhs, dtype=float),
                    0, x, 0.0)
        return x


def _is_tridiagonal(M) -> bool:
    """Whether every entry of ``M`` lies on the three central diagonals."""
    coo = M.tocoo()
    return coo.nnz == 0 or int(np.abs(coo.row.astype(np.int64) - coo.col).max()) <= 1


#: use the tridiagonal solver where it applies (``benchmarks/long_runs.py`` turns it off
#: to time the solvers as they were before it)
TRIDIAGONAL = True


def factorize(M, permc_spec: str = "COLAMD"):
    """Factors of the square sparse matrix ``M``, an object with ``solve(rhs)``: the
    Thomas algorithm when ``M`` is tridiagonal, else SuperLU."""
    M = sp.csc_matrix(M)
    if TRIDIAGONAL and _is_tridiagonal(M):
        return _Tridiagonal(M)
    return spla.splu(M, permc_spec=permc_spec)
