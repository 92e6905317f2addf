"""Benchmark: the spot-density solves against plain SciPy versions of the same solves.

Each line times spotpde and a straightforward SciPy implementation of the same
equation on the same grid, in the same process (best of ``--repeat`` after a warm-up
run that also compiles the numba kernels), and prints their ratio and the largest
difference of the two results relative to the field's maximum (over heights at least
``4 d`` above the floor, where the reference's Crank-Nicolson has left the singular
start behind).

1. 2D steady, ``D_par = 0``, constant ``b`` (``--n2`` cells per side, default 1024;
   spacing d/8, slot 4 d, b = 1.3 d): spotpde's exact cosine modes
   (``spot_density.steady``) vs Crank-Nicolson in height with
   ``scipy.linalg.solve_banded`` per step.
2. 2D steady, ``b`` varying in x and z (same grid): spotpde's numba Thomas marching vs
   the same SciPy Crank-Nicolson with the varying coefficients.
3. 3D steady, ``D_par = 0``, constant ``b`` (``--n3`` per side, default 128, spacing d/4):
   exact cosine modes vs Crank-Nicolson in height with the 2D horizontal operator
   factorised once by ``scipy.sparse.linalg.splu``.
4. 2D steady, ``D_par > 0`` (``--np`` per side, default 256, spacing d/4, b_par = 2.8 d):
   spotpde's exact modes vs the finite-volume system solved by ``scipy.sparse.linalg.spsolve``
   (the difference is the FV discretisation error).
5. 2D transient, ``D_par > 0`` (``--nt`` per side, default 128, spacing d/4, to
   ``t = 20``): spotpde's BDF2 (two factorisations reused) vs the same BDF2 steps solved
   by ``scipy.sparse.linalg.spsolve`` each step.

Usage::

    .venv/bin/python benchmarks/spot_density.py [--n2 1024] [--n3 128] [--np 256] [--nt 128] [--repeat 3]
"""

from __future__ import annotations

import argparse

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from _timing import best_time
from scipy.linalg import solve_banded

from spotpde.density import _elliptic, spot_density
from spotpde.grid import Grid
from spotpde.density.orifice import source_profile
from spotpde.parameters import Orifice, Spots


def scipy_cn_2d(grid, orifice, b):
    """CN in height of d phi/dz = (b phi)_xx, no-flux walls, solve_banded per step."""
    h, n, nz = grid.spacing, grid.nx, grid.nz
    b = np.broadcast_to(np.asarray(b, float), grid.shape)
    phi = source_profile(grid, orifice).copy()

    def banded(bk, c):
        ab = np.zeros((3, n))
        ab[0, 1:] = -c * bk[1:]
        ab[2, :-1] = -c * bk[:-1]
        ab[1] = 1 + 2 * c * bk
        ab[1, 0] = ab[1, -1] = 0
        ab[1, 0] = 1 + c * bk[0]
        ab[1, -1] = 1 + c * bk[-1]
        return ab

    def lap(psi):
        out = np.empty_like(psi)
        out[1:-1] = psi[2:] - 2 * psi[1:-1] + psi[:-2]
        out[0] = psi[1] - psi[0]
        out[-1] = psi[-2] - psi[-1]
        return out

    out = np.empty(grid.shape)
    for _ in range(2):                      # the same Rannacher start as spotpde
        phi = solve_banded((1, 1), banded(b[0], 0.25 / h), phi)
    out[0] = phi
    for k in range(nz - 1):
        c = 0.5 / h
        if k == 0:
            phi = solve_banded((1, 1), banded(0.5 * (b[0] + b[1]), c), phi)
            phi = solve_banded((1, 1), banded(b[1], c), phi)
        else:
            rhs = phi + c * lap(b[k] * phi)
            phi = solve_banded((1, 1), banded(b[k + 1], c), rhs)
        out[k + 1] = phi
    return out


def scipy_cn_3d(grid, orifice, b):
    """CN in height with the 2D horizontal Laplacian (no-flux walls) factorised by splu."""
    h, n, nz = grid.spacing, grid.nx, grid.nz
    e = np.ones(n)
    L1 = sp.diags([e[:-1], -2 * e, e[:-1]], [-1, 0, 1], format="lil")
    L1[0, 0] = L1[-1, -1] = -1
    L1 = sp.csr_matrix(L1) / h**2
    I1 = sp.identity(n)
    L = (sp.kron(I1, L1) + sp.kron(L1, I1)).tocsc()
    I = sp.identity(n * n, format="csc")
    be = spla.splu(I - 0.25 * h * b * L)
    be2 = spla.splu(I - 0.5 * h * b * L)
    cn = spla.splu(I - 0.5 * h * b * L)
    expl = (I + 0.5 * h * b * L).tocsr()
    phi = source_profile(grid, orifice).ravel()
    out = np.empty((nz, n * n))
    for _ in range(2):
        phi = be.solve(phi)
    out[0] = phi
    for k in range(nz - 1):
        if k == 0:
            phi = be2.solve(be2.solve(phi))
        else:
            phi = cn.solve(expl @ phi)
        out[k + 1] = phi
    return out.reshape(grid.shape)


def scipy_fv_steady(grid, orifice, spots):
    """The finite-volume steady system of ``_elliptic`` solved by ``spsolve``."""
    v, b, bp = spots.drift, spots.b, spots.b_par
    A, _ = _elliptic.assemble(grid.shape, grid.spacing, v, b * v, bp * v)
    q = _elliptic.floor_source(grid.shape, grid.spacing, orifice.rate_at(0.0) * source_profile(grid, orifice))
    return spla.spsolve(A.tocsc(), -q).reshape(grid.shape)


def scipy_bdf2(grid, orifice, spots, t_end):
    """The same BDF2 steps as spotpde's transient, each solved by spsolve."""
    h = grid.spacing
    v, b, bp = spots.drift, spots.b, spots.b_par
    A, _ = _elliptic.assemble(grid.shape, h, v, b * v, bp * v)
    q = _elliptic.floor_source(grid.shape, h, orifice.rate_at(0.0) * source_profile(grid, orifice))
    steps = max(20, int(np.ceil(t_end / (h / v) - 1e-9)))
    dt = t_end / steps
    I = sp.identity(A.shape[0], format="csc")
    rho, prev = np.zeros(A.shape[0]), None
    for _ in range(steps):
        if prev is None:
            new = spla.spsolve((I - dt * A).tocsc(), rho + dt * q)
        else:
            new = spla.spsolve((I - 2 / 3 * dt * A).tocsc(), (4 * rho - prev) / 3 + 2 / 3 * dt * q)
        prev, rho = rho, new
    return rho.reshape(grid.shape)


def report(name, t_spot, t_ref, a, b, grid):
    far = grid.z >= grid.z_range[0] + 4.0
    diff = np.abs(a - b)[far].max() / np.abs(b).max()
    print(f"{name:<44s} spotpde {t_spot:8.3f} s   scipy {t_ref:8.3f} s   "
          f"ratio {t_ref / t_spot:7.1f}x   max diff (z >= 4 d) {diff:.1e}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n2", type=int, default=1024, help="2D cells per side")
    parser.add_argument("--n3", type=int, default=128, help="3D cells per side")
    parser.add_argument("--np", type=int, default=256, help="D_par > 0 steady cells per side")
    parser.add_argument("--nt", type=int, default=128, help="transient cells per side")
    parser.add_argument("--repeat", type=int, default=3, help="timed repetitions (best kept)")
    args = parser.parse_args()
    r = args.repeat

    h = 0.125
    half = args.n2 * h / 2
    g2 = Grid(2, (-half, half), (0.0, args.n2 * h), h)
    slot = Orifice(x=0.0, width=4.0)
    t1, a = best_time(lambda: spot_density.steady(g2, slot, Spots(b=1.3)), r)
    t2, b = best_time(lambda: scipy_cn_2d(g2, slot, 1.3), r)
    report(f"2D steady const b, {args.n2}^2", t1, t2, a, b, g2)

    Z, X = g2.mesh()
    bvar = np.broadcast_to(1.3 * (1 + 0.3 * np.exp(-X**2 / 200.0)) * (1 + Z / 400.0), g2.shape).copy()
    t1, a = best_time(lambda: spot_density.steady(g2, slot, Spots(b=bvar)), r)
    t2, b = best_time(lambda: scipy_cn_2d(g2, slot, bvar), r)
    report(f"2D steady varying b, {args.n2}^2", t1, t2, a, b, g2)

    h3 = 0.25
    half = args.n3 * h3 / 2
    g3 = Grid(3, (-half, half), (0.0, args.n3 * h3), h3)
    disk = Orifice(x=0.0, y=0.0, width=4.0)
    t1, a = best_time(lambda: spot_density.steady(g3, disk, Spots(b=1.3)), r)
    t2, b = best_time(lambda: scipy_cn_3d(g3, disk, 1.3), min(r, 1))
    report(f"3D steady const b, {args.n3}^3", t1, t2, a, b, g3)

    half = args.np * h3 / 2
    gp = Grid(2, (-half, half), (0.0, args.np * h3), h3)
    sp_p = Spots(b=1.3, b_par=2.8)
    t1, a = best_time(lambda: spot_density.steady(gp, slot, sp_p), r)
    t2, b = best_time(lambda: scipy_fv_steady(gp, slot, sp_p), min(r, 1))
    report(f"2D steady D_par>0, {args.np}^2", t1, t2, a, b, gp)

    half = args.nt * h3 / 2
    gt = Grid(2, (-half, half), (0.0, args.nt * h3), h3)
    sp_t = Spots(b=1.3, b_par=1.0)
    t1, a = best_time(lambda: spot_density.transient(gt, slot, sp_t, 20.0), r)
    t2, b = best_time(lambda: scipy_bdf2(gt, slot, sp_t, 20.0), min(r, 1))
    report(f"2D transient D_par>0, {args.nt}^2, t=20", t1, t2, a, b, gt)


if __name__ == "__main__":
    main()
