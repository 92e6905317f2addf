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

Memory traffic: the planes are processed in chunks of :data:`PLANES_PER_CHUNK` (the
parallel work items), each in one sweep upwards: the vertical face fluxes of the plane
being finished live in two plane buffers (its bottom and top faces), the y faces in a
plane buffer and the x faces in a row buffer, so the pass reads ``P``, ``P0``, the three
face-velocity and the three coefficient arrays once, reads and writes the flux
accumulator ``Fz_acc`` of ``P_height`` and writes ``out``: 11 grid arrays, 88 bytes a
cell (a copy moves 16; 80 when ``_operator`` passes ``D_xx = D_yy`` as one array, 8
less again in the first Runge-Kutta stage, where ``P0`` is ``P``). The face plane two
chunks share is computed by both (bit for bit the same value: conservation is exact)
and accumulated by the chunk above it only. The
earlier two-pass layout is kept in :mod:`._fp_kernels_3d_two_pass`; docs/tracer.md
("How fast a step is") compares them with the memory bandwidth.

Sign convention as in :mod:`._fp_kernels`: ``Fz[k]`` is the flux per unit horizontal
area through the bottom face of plane ``k``, positive upwards.
"""

from __future__ import annotations

import functools

import numpy as np
from numba import njit, prange

from numba.extending import overload

from ._fp_kernels import (FASTMATH, KOREN, WENO5, _literal_limiter, _reach, _ROW_JIT,
                          face_value, weno5z, xface_row, zface_row)

#: z planes of cells per parallel work item (one face plane in this many is computed
#: twice; 50 work items for the slab's 400 planes).
PLANES_PER_CHUNK = 8


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _codes(k, n, weno):
    """Reconstructions of face row ``k`` (between rows ``k - 1`` and ``k`` of ``n``) for
    upward and downward flow: 2 WENO5, 1 the limited one (Koren for WENO5), 0 the donor
    cell; as :func:`._fp_kernels.recon` falls back where the stencil leaves the grid."""
    up = 2 if weno and k >= 3 and k + 1 <= n - 1 else (1 if k >= 2 else 0)
    down = 2 if weno and k + 2 <= n - 1 and k >= 2 else (1 if k + 1 <= n - 1 else 0)
    return up, down


def edge_row(Pm3, Pm2, Pm1, P0, Pp1, Pp2, u, Am1, A0, Fk, ih, eps, limiter, up, down):
    """:func:`._fp_kernels.zface_row` for a face row near a wall, the floor or the top
    (numba only): the reconstruction of each flow direction is chosen by ``up`` and
    ``down`` (:func:`_codes`; rows beyond the grid are passed clipped and not used).
    Every candidate is computed and selected, so the row still vectorises; the values
    are those of ``recon``, the scalar fallback of the 2D kernel."""
    raise NotImplementedError("edge_row is compiled into numba kernels only")


@overload(edge_row, prefer_literal=True, jit_options=_ROW_JIT)
def _edge_row(Pm3, Pm2, Pm1, P0, Pp1, Pp2, u, Am1, A0, Fk, ih, eps, limiter, up, down):
    lim = _literal_limiter(limiter)
    weno = lim == WENO5
    limited = KOREN if weno else lim

    def impl(Pm3, Pm2, Pm1, P0, Pp1, Pp2, u, Am1, A0, Fk, ih, eps, limiter, up, down):
        for i in range(Fk.shape[0]):
            a3 = Pm3[i]
            a = Pm2[i]
            b = Pm1[i]
            c = P0[i]
            d = Pp1[i]
            e = Pp2[i]
            fp = face_value(a, b, c, limited) if up == 1 else b
            fn = face_value(d, c, b, limited) if down == 1 else c
            if weno:
                wp = weno5z(a3, a, b, c, d, eps)
                wn = weno5z(e, d, c, b, a, eps)
                fp = wp if up == 2 else fp
                fn = wn if down == 2 else fn
            ui = u[i]
            Fk[i] = ui * (fp if ui > 0.0 else fn) - (A0[i] * c - Am1[i] * b) * ih

    return impl


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _boundary_row(Pe, u, Fk):
    """Fluxes through the floor or the top: ``u P`` of the boundary cells (first order;
    ``u`` carries the boundary condition)."""
    for i in range(Fk.shape[0]):
        Fk[i] = u[i] * Pe[i]


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _accumulate_flat(Fk, acc, w):
    """``acc += w Fk`` over one face plane (the vertical flux accumulator of ``P_height``)."""
    for m in range(Fk.shape[0]):
        acc[m] += w * Fk[m]


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _copy_flat(src, dst):
    """``dst[:] = src`` as an explicit loop: the slice assignment
    ``_plane(Fz_edge, 0)[:] = Fk`` in the parallel loop left ``Fz_edge`` unwritten
    (numba 0.68; tests/tracer/test_tracer_kernel.py caught it)."""
    for m in range(src.shape[0]):
        dst[m] = src[m]


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _plane(A, k):
    """Plane ``k`` of a C-contiguous 3D array as a flat view."""
    return A[k].reshape(A.shape[1] * A.shape[2])


@njit(cache=True, error_model="numpy")
def side_outflow(uxf, uyf, P):
    """Advective outflow rate through the four side walls per unit face area (d per unit
    time times 1/d**3), ``sum u P`` over the boundary faces (positive outwards).

    One serial loop over the wall cells: ``numpy.vdot`` of the strided wall slices went
    through BLAS, whose threads waited for cores on the shared machine; it took 7-14 ms
    a stage on the slab (as much as the kernel itself on one thread, measured).
    """
    nz, ny, nx = P.shape
    s = 0.0
    for k in range(nz):
        for j in range(ny):
            s += uxf[k, j, nx] * P[k, j, nx - 1] - uxf[k, j, 0] * P[k, j, 0]
        for i in range(nx):
            s += uyf[k, ny, i] * P[k, ny - 1, i] - uyf[k, 0, i] * P[k, 0, i]
    return s


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _stage_row(Fx, Fys, Fyn, Fzb, Fzt, P0k, Pk, ca, cb, cc, tiny, out, ih):
    """``out = ca P0 + cb P + cc R`` over one row of cells, ``R = -(Fx[i+1] - Fx[i] +
    Fyn - Fys + Fzt - Fzb) / h`` (the terms of
    :func:`._fp_kernels_3d_two_pass._stage_flat`, in its order);
    values below ``tiny`` in magnitude become 0 (NaN passes through)."""
    for i in range(out.shape[0]):
        r = -((Fx[i + 1] - Fx[i]) + (Fyn[i] - Fys[i]) + (Fzt[i] - Fzb[i])) * ih
        v = ca * P0k[i] + cb * Pk[i] + cc * r
        out[i] = 0.0 if abs(v) < tiny else v


@functools.lru_cache(maxsize=None)
def rhs_3d_kernel(limiter: int):
    """The fused 3D kernel specialised (and disk cached) for one reconstruction code
    (:data:`._fp_kernels.WENO5` ...; a closure constant, so the other reconstructions'
    branches are compiled out). Signature in :func:`rhs_3d` below."""
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
                time (zero arrays: advection only; the same array may be passed twice).
            eps: WENO scale ``1 / P_scale**2``; h: spacing in d.
            out: (nz, ny, nx) ``ca P0 + cb P + cc R`` (``ca = cb = tiny = 0``, ``cc = 1``
                give ``R``); may be ``P0`` itself, never ``P``.
            Fz_edge: (2, ny, nx) written: the vertical fluxes through the floor (0) and
                the top (1).
            Fz_acc: (nz+1, ny, nx) ``Fz_acc += w_acc Fz``.
            w_acc: weight of this stage's fluxes (time step times Runge-Kutta weight).
            P0, ca, cb, cc, tiny: the stage combination.

        All arrays C-contiguous. One sweep up each chunk of planes: step ``kk``
        computes face plane ``k0 + kk`` into one of two plane buffers and then finishes
        plane ``k0 + kk - 1`` (its y faces over the flattened plane, its x faces and
        its stage row by row), so every plane of every array is read once, while the
        planes the vertical stencil shares are still in cache.
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
            Fz = np.empty((2, n))               # the bottom and top faces of a plane
            Fy = np.empty((ny + 1) * nx)
            Fx = np.empty(nx + 1)
            for kk in range(m + 1):
                k = k0 + kk
                Fk = Fz[kk % 2]
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
                if kk == 0:
                    continue
                k = k - 1                    # the plane below face plane k: finish it
                Fb = Fz[(kk - 1) % 2]
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
                P0k, outk = P0[k], out[k]
                for j in range(ny):
                    xface_row(Pk[j], uxf[k, j], Axx[k, j], Fx, ih, eps, limiter)
                    s = j * nx
                    _stage_row(Fx, Fy[s:s + nx], Fy[s + nx:s + 2 * nx], Fb[s:s + nx],
                               Fk[s:s + nx], P0k[j], Pk[j], ca, cb, cc, tiny, outk[j], ih)

    return rhs_3d
