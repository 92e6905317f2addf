"""The implicit tracer steps' linear algebra: the tridiagonal fast path and the limited
extrapolation kernel of the IMEX / multirate diffusion (docs/long_runs.md).

Checks: the Thomas factors solve the void model's horizontal diffusion (a tridiagonal
M-matrix) to round-off and give SuperLU's solution, and they are chosen exactly when the
matrix is tridiagonal; the one-pass kernel ``_extrapolate`` equals the computation it
replaced (whole-array numpy with a sparse product and ``reduceat``), keeps ``P >= -eps``
exactly as computed with the limiter active (no tolerance: ``LIMIT_MARGIN``), and conserves ``sum P + (outflow of A S)`` exactly.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from spotpde.tracer import _advection, _diffusion, _implicit, _linsolve
from spotpde.tracer._extrapolation import LIMIT_MARGIN, Extrapolation
from _problems import diffusion_operator as _diffusion_operator, void_problem as _void


def _void_diffusion(h=0.25):
    grid, fields, P0 = _void(h)
    terms, _ = _diffusion.split_tensor(fields, grid.dims)
    return grid, fields, P0, _diffusion.operator(terms, grid.shape, grid.spacing).tocsc()


def test_void_diffusion_takes_the_tridiagonal_path_and_equals_superlu():
    grid, _, P0, L = _void_diffusion()
    rng = np.random.default_rng(3)
    b = rng.random(L.shape[0])
    for tau in (0.01, 1.0, 100.0):
        M = (sp.identity(L.shape[0], format="csc") - tau * L).tocsc()
        f = _linsolve.factorize(M)
        assert isinstance(f, _linsolve._Tridiagonal)
        x = f.solve(b)
        assert np.abs(M @ x - b).max() < 1e-13 * np.abs(b).max()
        ref = spla.splu(M).solve(b)
        np.testing.assert_allclose(x, ref, rtol=1e-12, atol=1e-14 * np.abs(ref).max())
        # an M-matrix: a non-negative right-hand side gives a non-negative solution
        assert f.solve(P0.ravel()).min() >= -1e-15 * P0.max()


def test_matrices_that_are_not_tridiagonal_use_superlu(monkeypatch):
    _, _, _, L = _void_diffusion(0.5)
    n = L.shape[0]
    nx = int(round(16.0 / 0.5))
    vertical = sp.diags([np.ones(n - nx), -2 * np.ones(n), np.ones(n - nx)], [-nx, 0, nx])
    M = (sp.identity(n) - 0.1 * (L + vertical)).tocsc()
    f = _linsolve.factorize(M)
    assert not isinstance(f, _linsolve._Tridiagonal)
    b = np.random.default_rng(0).random(n)
    assert np.abs(M @ f.solve(b) - b).max() < 1e-12
    # switched off, a tridiagonal matrix also goes to SuperLU
    monkeypatch.setattr(_linsolve, "TRIDIAGONAL", False)
    assert not isinstance(_linsolve.factorize(sp.identity(n) - L), _linsolve._Tridiagonal)


def _numpy_extrapolation(A, Pa, P1, Pb, tau, eps):
    """The limited extrapolation as it was written before the kernels (whole arrays):
    the limiter counts the non-negative off-diagonals, the update applies ``A``."""
    diag = A.diagonal()
    off = (A - sp.diags(diag)).tocsc()
    off.data[off.data < 0] = 0.0
    off.eliminate_zeros()
    off.sort_indices()
    Sb = 0.5 * tau * (P1 + Pb)
    delta = Sb - tau * Pa
    N = off @ np.minimum(delta, 0.0) + diag * np.maximum(delta, 0.0)
    R = np.ones_like(Pb)
    bad = N < 0
    R[bad] = np.minimum(1.0, np.maximum(Pb[bad] + eps, 0.0) * (1.0 - LIMIT_MARGIN) / -N[bad])
    theta = np.where(delta > 0, R, 1.0)
    col_min = np.ones(off.shape[1])
    nonempty = np.diff(off.indptr) > 0
    col_min[nonempty] = np.minimum.reduceat(R[off.indices], off.indptr[:-1][nonempty])
    take = delta < 0
    theta[take] = np.minimum(theta[take], col_min[take])
    corr = theta * delta
    return Pb + A @ corr, Sb + corr, theta.min()




@pytest.mark.parametrize("kind", ["void", "tensor", "not dominant"])
def test_both_kernels_equal_the_numpy_computation_and_conserve(kind):
    """Both kernels (rows for the tridiagonal operator, diagonal storage otherwise),
    including operators whose last rows exchange nothing and one with negative
    off-diagonals: the numbers of the whole-array computation, and ``P_new - p = A (S_new
    - S)`` to round-off (conservation holds even where positivity is not guaranteed)."""
    rng = np.random.default_rng(11)
    nz, nx = 12, 9
    A = _diffusion_operator(nz, nx, kind, rng)
    ex = Extrapolation(A, nx)
    assert (ex.nx is not None) == (kind == "void")
    I = sp.identity(nz * nx, format="csc")
    p = np.zeros(nz * nx)
    p[rng.integers(0, nz * nx, 6)] = rng.uniform(0.5, 1.0, 6)   # spikes: the limiter acts
    for tau in (0.05, 3.0):
        lu, lu_half = (_linsolve.factorize((I - t * A).tocsc()) for t in (tau, 0.5 * tau))
        S = np.zeros_like(p)
        P, theta = ex(lu, lu_half, p, tau, 1e-15, S)
        Pa, P1 = lu.solve(p), lu_half.solve(p)
        ref_P, ref_S, ref_theta = _numpy_extrapolation(A, Pa, P1, lu_half.solve(P1), tau,
                                                       1e-15)
        np.testing.assert_allclose(P, ref_P, rtol=0, atol=1e-13)
        np.testing.assert_allclose(S, ref_S, rtol=0, atol=1e-13 * tau)
        assert theta == pytest.approx(ref_theta, rel=1e-12)
        np.testing.assert_allclose(P - p, A @ S, rtol=0, atol=1e-13)
        if kind != "not dominant":      # exactly, as computed (LIMIT_MARGIN)
            assert lu_half.solve(P1).min() >= 0.0 and P.min() >= -1e-15
    assert theta < 1.0                                  # the limiter acted at tau = 3


def test_a_zero_pivot_is_an_error_naming_the_matrix():
    M = sp.csc_matrix(np.array([[0.0, 1.0], [1.0, 1.0]]))
    with pytest.raises(np.linalg.LinAlgError, match="^M: the tridiagonal"):
        _linsolve._Tridiagonal(M)


@pytest.mark.parametrize("advect", [False, True])
def test_extrapolation_kernel_equals_the_numpy_computation(advect):
    """On the void model's operator (diffusion alone, as in multirate; with the hybrid
    advection of the fast faces, as in IMEX) and a release that leaves most cells
    empty, at a step where the limiter acts."""
    grid, fields, P0 = _void(0.25)
    faces = _advection.face_velocities(fields, grid.walls, np.ones(grid.shape[1:], bool))
    if not advect:
        faces = {k: np.zeros_like(v) for k, v in faces.items()}
    imp = _implicit.ImexSplit(grid, fields, faces, True, 1e-15 * float(P0.max()))
    tau = 2.0
    p = P0.ravel()
    Pa = imp.fac.solve(tau, p)
    P1 = imp.fac.solve(0.5 * tau, p)
    Pb = imp.fac.solve(0.5 * tau, P1)
    ref_P, ref_S, ref_theta = _numpy_extrapolation(imp.A, Pa, P1, Pb, tau, imp.eps)
    S0 = imp.S.copy()
    P = imp.backward_euler(P0, tau).ravel()
    assert ref_theta < 0.5                       # the limiter acts
    assert imp.theta_min == pytest.approx(ref_theta, rel=1e-12)
    np.testing.assert_allclose(P, ref_P, rtol=0, atol=1e-13 * P0.max())
    np.testing.assert_allclose(imp.S - S0, ref_S, rtol=0, atol=1e-13 * tau * P0.max())
    assert Pb.min() >= 0.0 and P.min() >= -imp.eps
    # conservation: P_new - P0 = A S exactly, so the mass lost is the outflow of S
    hv = grid.cell_volume
    out = sum(imp.exits())
    assert abs((P.sum() - P0.sum()) * hv + out) < 1e-13 * P0.sum() * hv
