"""Finite-volume operator of the spot Fokker-Planck equation and its steady solve.

Equation (docs/conventions.md section 1, Ito form, drift ``v_s`` up):

    d rho/dt = -div J + S,   J_perp = -grad_perp (D_perp rho),
                             J_z    = v_s rho - d/dz (D_par rho).

Cells are the grid's; with ``rho`` the cell values the semi-discrete system is
``d rho/dt = A rho + q``, every flux evaluated once per face (conservative: the total
``sum(rho) h**dims`` changes only by inflow minus outflow). Face fluxes:

* horizontal face ``i | i+1``: ``-(D_perp[i+1] rho[i+1] - D_perp[i] rho[i]) / h``
  (second order); side walls: zero (reflecting; open walls are handled by the caller
  on a padded domain).
* vertical face ``k | k+1``: ``v_f rho_f - (D_par[k+1] rho[k+1] - D_par[k] rho[k]) / h``,
  ``v_f`` the mean of the two cells, ``rho_f = 3/2 rho[k] - 1/2 rho[k-1]`` (linear
  upwind, second order, stable for any cell Peclet number, also ``D_par = 0``); the
  first face ``0 | 1`` uses ``rho_f = rho[0]`` (one face, first order).
* top face (outflow, Danckwerts): ``v rho_top``, ``rho_top = 3/2 rho[-1] - 1/2 rho[-2]``,
  no diffusive flux.
* floor: the prescribed inflow ``Q0 s(x)`` on the orifice, zero elsewhere.

For ``D_par = 0`` the steady system is the second-order backward-difference (BDF2)
marching of ``d(v rho)/dz = lap_perp(D_perp rho)`` in height.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..errors import NumericalError

DIRECT_LIMIT = {2: 400_000, 3: 40_000}   # SuperLU fill-in grows fast in 3D


def _full(value, shape) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, dtype=float), shape)


def assemble(shape: tuple[int, ...], h: float, v, D_perp, D_par) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """Build ``A`` (``d rho/dt = A rho + q``) and the outflow row.

    Args:
        shape: grid shape in array order ``(nz, [ny,] nx)``.
        h: spacing in d.
        v, D_perp, D_par: drift (d per unit time, > 0) and diffusivities (d**2 per
            unit time), floats or grid-shaped arrays at the cell centres.

    Returns:
        ``(A, out)``: ``A`` sparse ``(N, N)`` in 1/time; ``out`` a ``(1, N)`` row with
        ``out @ rho`` the total outflow through the top (spots per unit time).
    """
    v, Dp, Dz = (_full(c, shape) for c in (v, D_perp, D_par))
    idx = np.arange(int(np.prod(shape))).reshape(shape)
    rows, cols, vals = [], [], []

    def flux(minus, plus, terms):
        """Face flux ``F = sum coef * rho[col]`` leaves cell ``minus`` and enters ``plus``."""
        for col, coef in terms:
            col = np.broadcast_to(col, minus.shape).ravel()
            coef = np.broadcast_to(coef, minus.shape).ravel() / h
            rows.append(minus.ravel()); cols.append(col); vals.append(-coef)
            if plus is not None:
                rows.append(plus.ravel()); cols.append(col); vals.append(coef)

    for ax in range(1, len(shape)):
        n = shape[ax]
        if n < 2:
            continue
        lo, hi = np.arange(n - 1), np.arange(1, n)
        L, R = idx.take(lo, axis=ax), idx.take(hi, axis=ax)
        flux(L, R, [(R, -Dp.take(hi, axis=ax) / h), (L, Dp.take(lo, axis=ax) / h)])

    nz = shape[0]
    if nz >= 2:
        vf = 0.5 * (v[:-1] + v[1:])
        below, above = idx[:-1], idx[1:]
        flux(below, above, [(above, -Dz[1:] / h), (below, Dz[:-1] / h)])
        flux(below[:1], above[:1], [(below[:1], vf[:1])])
        if nz >= 3:
            flux(below[1:], above[1:], [(below[1:], 1.5 * vf[1:]), (idx[:-2], -0.5 * vf[1:])])
        top = [(idx[-1:], 1.5 * v[-1:]), (idx[-2:-1], -0.5 * v[-1:])]
    else:
        top = [(idx[-1:], v[-1:])]
    flux(idx[-1:], None, top)
    N = idx.size
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(N, N))
    orow = np.zeros(N)
    hm = h ** (len(shape) - 1)
    for col, coef in top:
        np.add.at(orow, col.ravel(), coef.ravel() * hm)
    return A, sp.csr_matrix(orow[None, :])


def floor_source(shape: tuple[int, ...], h: float, flux_density: np.ndarray) -> np.ndarray:
    """Source vector ``q`` of the floor inflow: ``flux_density / h`` in the bottom cells.

    Args:
        shape: grid shape.
        h: spacing in d.
        flux_density: ``Q0 s`` on the floor, shape ``shape[1:]`` (spots / time / d**(dims-1)).

    Returns:
        ``q`` flattened, spots per d**dims per unit time.
    """
    q = np.zeros(shape)
    q[0] = flux_density / h
    return q.ravel()


def factorize(M: sp.spmatrix, dims: int):
    """A solver ``f(rhs) -> x`` for the sparse matrix ``M``.

    Direct (SuperLU, ``scipy.sparse.linalg.splu``) up to ``DIRECT_LIMIT[dims]``
    unknowns, else GMRES preconditioned by an incomplete LU (``spilu``). Measured on a
    37**3 system: COLAMD 50 s and 8.4e7 factor entries, ``MMD_AT_PLUS_A`` 13 s and 4.1e7.
    """
    M = sp.csc_matrix(M)
    if M.shape[0] <= DIRECT_LIMIT[dims]:
        # minimum degree on A^T + A fills 3D stencils about half as much as COLAMD
        lu = spla.splu(M, permc_spec="MMD_AT_PLUS_A" if dims == 3 else "COLAMD")
        return lu.solve
    ilu = spla.spilu(M, drop_tol=1e-3, fill_factor=10)
    prec = spla.LinearOperator(M.shape, ilu.solve)

    def solve(rhs, x0=None):
        x, info = spla.gmres(M, rhs, x0=x0, M=prec, rtol=1e-11, atol=0.0, restart=60, maxiter=400)
        if info != 0:
            raise NumericalError(f"spot density: GMRES did not converge (info={info})")
        return x

    return solve


def solve_steady(shape, h, v, D_perp, D_par, q: np.ndarray) -> np.ndarray:
    """Solve ``A rho = -q`` (steady state).

    Args:
        shape, h, v, D_perp, D_par: as :func:`assemble`.
        q: source vector (flattened), spots per d**dims per unit time.

    Returns:
        ``rho`` with grid shape, spots per d**dims.
    """
    A, _ = assemble(shape, h, v, D_perp, D_par)
    rho = factorize(A, len(shape))(-q)
    if not np.all(np.isfinite(rho)):
        raise NumericalError("spot density: the steady solve produced non-finite values")
    return rho.reshape(shape)
