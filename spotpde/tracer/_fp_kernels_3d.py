"""The fused 3D right-hand-side kernel of the tracer equation (private; used by ``_operator``).

One pass over the grid evaluates, for every cell of ``P[k, j, i]`` (array order
``(z, y, x)``),

    R = -(1/h) sum_axes (F_{+1/2} - F_{-1/2}),
    F = u_f P*_f - (A_b P_b - A_a P_a) / h      (a the cell below / behind the face, b above)

with the limited or WENO5 upwind face value ``P*_f`` of :mod:`._fp_kernels` (the same row
functions as the 2D kernel: ``zface_row`` along z and y lines, ``xface_row`` along x)
and the axial diffusion exchanges of :mod:`._diffusion` (``A = D_ii - sum |D_ij|`` per
axis, the 3-point second difference of ``A P``: second order), and writes the
Runge-Kutta stage ``out = ca P0 + cb P + cc R`` in the same pass (values below ``tiny``
flushed to 0, as :func:`._fp_kernels.combine`). The diagonal (cross-term) exchanges of
a non-diagonal tensor are not evaluated here (``_operator`` adds them with a sparse
matrix of those terms only; the spot model's tensor is diagonal).

Memory traffic: the planes are processed in chunks of :data:`PLANES_PER_CHUNK`; the
vertical face fluxes of a chunk live in a chunk-local buffer (cache resident), the y
faces in one plane buffer and the x faces in one row, so the pass reads ``P``, ``P0``,
the three face-velocity and the three coefficient arrays once, reads and writes the
flux accumulator ``Fz_acc`` of ``P_height``, and writes ``out``: 11 grid arrays, 88
bytes a cell (a copy moves 16). Each chunk recomputes the face plane it shares with
the chunk above (bit for bit the same value: conservation is exact), and only the
chunk below a face plane accumulates it.

Sign convention as in :mod:`._fp_kernels`: ``Fz[k]`` is the flux per unit horizontal
area through the bottom face of plane ``k``, positive upwards.
"""

from __future__ import annotations

import functools

import numpy as np
from numba import njit, prange

from ._fp_kernels import FASTMATH, _reach, xface_row, zface_row, zface_row_edge

#: z planes of cells per parallel work item (the chunk's vertical faces stay in cache:
#: (8 + 1) planes of 32 x 200 cells are 460 kB).
PLANES_PER_CHUNK = 8


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _stage_row_3d(Fx, Fys, Fyn, Fzb, Fzt, P0k, Pk, ca, cb, cc, tiny, out, ih):
    """``out = ca P0 + cb P + cc R`` for one x row, ``R = -(flux differences) / h``;
    values below ``tiny`` in magnitude become 0 (NaN passes through)."""
    for i in range(out.shape[0]):
        r = -((Fx[i + 1] - Fx[i]) + (Fyn[i] - Fys[i]) + (Fzt[i] - Fzb[i])) * ih
        v = ca * P0k[i] + cb * Pk[i] + cc * r
        out[i] = 0.0 if abs(v) < tiny else v


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _accumulate_plane(Fk, acc, w):
    """``acc += w Fk`` over one face plane (the vertical flux accumulator of ``P_height``)."""
    ny, nx = Fk.shape
    for j in range(ny):
        for i in range(nx):
            acc[j, i] += w * Fk[j, i]


@functools.lru_cache(maxsize=None)
def rhs_3d_kernel(limiter: int):
    """The fused 3D kernel specialised (and disk cached) for one reconstruction code
    (:data:`._fp_kernels.WENO5` ...; a closure constant, so the other reconstructions'
    branches are compiled out). Signature in :func:`rhs_3d` below."""
    r = _reach(limiter)

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
        """
        nz, ny, nx = P.shape
        ih = 1.0 / h
        nchunk = (nz + PLANES_PER_CHUNK - 1) // PLANES_PER_CHUNK
        for c in prange(nchunk):
            k0 = c * nz // nchunk
            m = (c + 1) * nz // nchunk - k0
            Fz = np.empty((m + 1, ny, nx))      # face planes k0 .. k0 + m
            Fy = np.empty((ny + 1, nx))
            Fx = np.empty(nx + 1)
            for kk in range(m + 1):
                k = k0 + kk
                for j in range(ny):
                    if k >= r and k <= nz - r:
                        zface_row(P[k - 3, j], P[k - 2, j], P[k - 1, j], P[k, j],
                                  P[k + 1, j], P[min(k + 2, nz - 1), j], uzf[k, j],
                                  Azz[k - 1, j], Azz[k, j], Fz[kk, j], ih, eps, limiter)
                    else:
                        zface_row_edge(P[:, j, :], uzf[:, j, :], Azz[:, j, :], k,
                                       Fz[kk, j], ih, eps, limiter)
                if kk < m or k == nz:      # this chunk owns face plane k
                    _accumulate_plane(Fz[kk], Fz_acc[k], w_acc)
                    if k == 0:
                        Fz_edge[0] = Fz[kk]
                    elif k == nz:
                        Fz_edge[1] = Fz[kk]
            for kk in range(m):
                k = k0 + kk
                Pk = P[k]
                for j in range(ny + 1):
                    if j >= r and j <= ny - r:
                        zface_row(Pk[j - 3], Pk[j - 2], Pk[j - 1], Pk[j], Pk[j + 1],
                                  Pk[min(j + 2, ny - 1)], uyf[k, j], Ayy[k, j - 1],
                                  Ayy[k, j], Fy[j], ih, eps, limiter)
                    else:
                        zface_row_edge(Pk, uyf[k], Ayy[k], j, Fy[j], ih, eps, limiter)
                for j in range(ny):
                    xface_row(Pk[j], uxf[k, j], Axx[k, j], Fx, ih, eps, limiter)
                    _stage_row_3d(Fx, Fy[j], Fy[j + 1], Fz[kk, j], Fz[kk + 1, j], P0[k, j],
                                  Pk[j], ca, cb, cc, tiny, out[k, j], ih)

    return rhs_3d

