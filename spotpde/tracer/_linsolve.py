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
  SuperLU's to round-off (``tests/test_linsolve.py``).
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
def _thomas_solve(m, inv, du, b):
    """``x`` with ``L U x = b``: forward then backward substitution."""
    n = b.size
    x = np.empty(n)
    x[0] = b[0]
    for i in range(1, n):
        x[i] = b[i] - m[i] * x[i - 1]
    x[n - 1] *= inv[n - 1]
    for i in range(n - 2, -1, -1):
        x[i] = (x[i] - du[i] * x[i + 1]) * inv[i]
    return x


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
        return _thomas_solve(self.m, self.inv, self.du,
                             np.ascontiguousarray(rhs, dtype=float))


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
