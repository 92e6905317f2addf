"""The previous layout of the fused 3D kernel: two passes over each chunk of planes
(private; kept for ``benchmarks/stream.py`` and ``tests/tracer/test_tracer_stream.py``).

The solver uses :func:`._fp_kernels_3d.rhs_3d_kernel`. This one computes the same face
fluxes with the same row functions, but in two passes over a chunk of
:data:`PLANES_PER_CHUNK` planes: first all the chunk's vertical face planes into a
chunk-local buffer of ``PLANES_PER_CHUNK + 1`` planes, then the y and x faces and the
Runge-Kutta stage plane by plane (the x flux differences through a plane buffer). On the
slab's 400 x 32 x 200 grid a chunk's planes and vertical fluxes (about 1 MB) do not fit
the 512 kB L2 cache of this machine, so the second pass reads ``P`` again from L3.
"""

from __future__ import annotations

import functools

import numpy as np
from numba import njit, prange

from ._fp_kernels import FASTMATH, WENO5, _reach, xface_row, zface_row
from ._fp_kernels_3d import (_accumulate_flat, _boundary_row, _codes, _copy_flat, _plane,
                             edge_row)

#: z planes of cells per parallel work item.
PLANES_PER_CHUNK = 8


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _stage_flat(divx, Fys, Fyn, Fzb, Fzt, P0k, Pk, ca, cb, cc, tiny, out, ih):
    """``out = ca P0 + cb P + cc R`` over one plane of cells (flattened),
    ``R = -(divx + Fyn - Fys + Fzt - Fzb) / h`` with ``divx`` the x flux differences;
    values below ``tiny`` in magnitude become 0 (NaN passes through)."""
    for m in range(out.shape[0]):
        r = -(divx[m] + (Fyn[m] - Fys[m]) + (Fzt[m] - Fzb[m])) * ih
        v = ca * P0k[m] + cb * Pk[m] + cc * r
        out[m] = 0.0 if abs(v) < tiny else v


@functools.lru_cache(maxsize=None)
def rhs_3d_two_pass_kernel(limiter: int):
    """The two-pass 3D kernel for one reconstruction code (signature and results those
    of :func:`._fp_kernels_3d.rhs_3d_kernel`)."""
    r = _reach(limiter)
    # rows upwind and downwind of a face the row functions read (WENO5: 3 and 2); the
    # others read 2 and 1 and get those rows again in the unused arguments
    weno = limiter == WENO5
    back, fwd = (3, 2) if weno else (2, 1)

    @njit(parallel=True, cache=True, fastmath=FASTMATH, error_model="numpy")
    def rhs_3d(P, uxf, uyf, uzf, Axx, Ayy, Azz, eps, h, out, Fz_edge, Fz_acc, w_acc,
               P0, ca, cb, cc, tiny):
        """Advection and axial diffusion of ``P``, combined into a Runge-Kutta stage.

        Args:
            P: (nz, ny, nx) density, 1/d**3.
            uxf: (nz, ny, nx+1), uyf: (nz, ny+1, nx), uzf: (nz+1, ny, nx) face
                velocities in d per unit time (boundary faces carry the boundary
                condition: 0 at walls, outflow only at open faces).
            Axx, Ayy, Azz: (nz, ny, nx) axial exchange coefficients in d**2 per unit
                time (zero arrays: advection only).
            eps: WENO scale ``1 / P_scale**2``; h: spacing in d.
            out: (nz, ny, nx) ``ca P0 + cb P + cc R`` (``ca = cb = tiny = 0``, ``cc = 1``
                give ``R``); may be ``P0`` itself, never ``P``.
            Fz_edge: (2, ny, nx) written: the vertical fluxes through the floor (0) and
                the top (1).
            Fz_acc: (nz+1, ny, nx) ``Fz_acc += w_acc Fz``.
            w_acc: weight of this stage's fluxes (time step times Runge-Kutta weight).
            P0, ca, cb, cc, tiny: the stage combination.

        All arrays C-contiguous. The z faces of a plane, the y faces away from the two
        y walls and the stage are computed over whole flattened planes (one call each:
        rows of a slab are short, 200 cells, and a call per row cost as much again);
        the x faces row by row (the walls at each row's ends).
        """
        nz, ny, nx = P.shape
        n = ny * nx
        ih = 1.0 / h
        lo, hi = r, ny - r              # y face rows away from the walls: whole planes
        L = max(hi - lo + 1, 0) * nx
        nchunk = (nz + PLANES_PER_CHUNK - 1) // PLANES_PER_CHUNK
        for c in prange(nchunk):
            k0 = c * nz // nchunk
            m = (c + 1) * nz // nchunk - k0
            Fz = np.empty((m + 1, n))           # face planes k0 .. k0 + m
            Fy = np.empty((ny + 1) * nx)
            divx = np.empty(n)
            Fx = np.empty(nx + 1)
            for kk in range(m + 1):
                k = k0 + kk
                Fk = Fz[kk]
                if k == 0 or k == nz:
                    _boundary_row(_plane(P, 0 if k == 0 else nz - 1), _plane(uzf, k), Fk)
                elif k >= r and k <= nz - r:
                    zface_row(_plane(P, k - 3), _plane(P, k - 2), _plane(P, k - 1),
                              _plane(P, k), _plane(P, k + 1), _plane(P, min(k + 2, nz - 1)),
                              _plane(uzf, k), _plane(Azz, k - 1), _plane(Azz, k), Fk, ih,
                              eps, limiter)
                else:
                    up, down = _codes(k, nz, weno)
                    edge_row(_plane(P, max(k - 3, 0)), _plane(P, max(k - 2, 0)),
                             _plane(P, k - 1), _plane(P, k), _plane(P, min(k + 1, nz - 1)),
                             _plane(P, min(k + 2, nz - 1)), _plane(uzf, k), _plane(Azz, k - 1),
                             _plane(Azz, k), Fk, ih, eps, limiter, up, down)
                if kk < m or k == nz:      # this chunk owns face plane k
                    _accumulate_flat(Fk, _plane(Fz_acc, k), w_acc)
                    if k == 0 or k == nz:
                        _copy_flat(Fk, _plane(Fz_edge, 0 if k == 0 else 1))
            for kk in range(m):
                k = k0 + kk
                Pk = P[k]
                Pf = _plane(P, k)
                if L > 0:
                    a = lo * nx
                    Af = _plane(Ayy, k)
                    zface_row(Pf[a - back * nx:a - back * nx + L], Pf[a - 2 * nx:a - 2 * nx + L],
                              Pf[a - nx:a - nx + L], Pf[a:a + L], Pf[a + nx:a + nx + L],
                              Pf[a + fwd * nx:a + fwd * nx + L],
                              uyf[k].reshape((ny + 1) * nx)[a:a + L], Af[a - nx:a - nx + L],
                              Af[a:a + L], Fy[a:a + L], ih, eps, limiter)
                uk, Ak = uyf[k], Ayy[k]
                for j in range(ny + 1):
                    Fj = Fy[j * nx:(j + 1) * nx]
                    if j == 0 or j == ny:
                        _boundary_row(Pk[0 if j == 0 else ny - 1], uk[j], Fj)
                    elif L == 0 or j < lo or j > hi:
                        up, down = _codes(j, ny, weno)
                        edge_row(Pk[max(j - 3, 0)], Pk[max(j - 2, 0)], Pk[j - 1], Pk[j],
                                 Pk[min(j + 1, ny - 1)], Pk[min(j + 2, ny - 1)], uk[j],
                                 Ak[j - 1], Ak[j], Fj, ih, eps, limiter, up, down)
                for j in range(ny):
                    xface_row(Pk[j], uxf[k, j], Axx[k, j], Fx, ih, eps, limiter)
                    for i in range(nx):
                        divx[j * nx + i] = Fx[i + 1] - Fx[i]
                _stage_flat(divx, Fy[0:n], Fy[nx:n + nx], Fz[kk], Fz[kk + 1], _plane(P0, k),
                            Pf, ca, cb, cc, tiny, _plane(out, k), ih)

    return rhs_3d
