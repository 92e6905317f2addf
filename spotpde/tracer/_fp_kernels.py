"""Numba kernels of the tracer Fokker-Planck right-hand side (private).

All kernels work in spotpde array order, ``P[k, i]`` (2D) / ``P[k, j, i]`` (3D) with
``k`` the z index. Face velocities are precomputed by :mod:`spotpde.tracer._advection`
(boundary faces already carry the boundary condition: zero for walls, outflow-only
for open boundaries), and the diffusion tensor is pre-split into non-negative
stencil coefficients by :mod:`spotpde.tracer._diffusion`. The discretised equations are
written out in ``docs/tracer.md`` and in the docstrings of those two modules; this
module only evaluates them.

Sign convention of face fluxes: ``Fz[k, i]`` is the probability flux per unit
horizontal length through the bottom face of cell ``(k, i)`` (``k = nz`` is the top
face of the domain), positive upwards; ``Fx`` likewise positive towards ``+x``.

Layout of the 2D right-hand side (the hot loop of every tracer run). Each row of
cells is handled by small row functions whose inner loops LLVM vectorises (AVX2, four
cells per instruction): they contain no branches (the upwind choice and the limiters
are written as selects, ``face_value``), no Python division checks
(``error_model="numpy"``) and index only with ``i + constant`` for ``i`` counting from
0, so that numba's negative-index wraparound cannot turn the loads into gathers (that
alone made the x sweep 10 times slower). Rows are processed in chunks of
:data:`ROWS_PER_CHUNK`; a chunk keeps its vertical face fluxes and corner exchanges in
chunk-local buffers, which stay in cache, instead of whole-grid arrays (each chunk
recomputes the face row it shares with the chunk above and does not accumulate it),
and the divergence is combined into the Runge-Kutta stage in the same pass. Measured
in ``benchmarks/tracer.py`` against the earlier whole-grid two-pass kernel: 2.3-3.0
times the throughput with two threads, 1.4-2.5 times on one core (docs/tracer.md,
Performance).
"""

from __future__ import annotations

import functools

import numba
import numpy as np
from numba import njit, prange, types
from numba.np.ufunc import parallel as _parallel_backend
from numba.core.errors import TypingError
from numba.extending import intrinsic, overload

# Floating-point licence of the flux kernels: contraction (FMA), reassociation,
# reciprocal; NaN and infinity semantics are kept (the solver checks for NaN).
# Conservation does not depend on it: each face flux is used with opposite signs by the
# two cells it joins (a face row shared by two chunks of the 2D kernel is computed by
# both, by the same call on the same inputs, hence bit for bit the same value).
#
# NaN reaches the right-hand side of a cell with a NaN density through the products
# ``A * P`` of the diffusive fluxes (``0 * NaN`` is NaN), not through the
# reconstructions: ``min`` and the sign selects of ``face_value`` drop a NaN. Keep
# those products even where the coefficients are zero (tests/tracer/test_tracer_kernel.py
# checks that a NaN survives a step).
FASTMATH = {"contract", "reassoc", "arcp", "nsz"}

# The reconstruction helpers (face_value, weno5z, ...) are ordinary njit functions, not
# inline="always": numba-level inlining copies their typed IR into every call site and
# doubled the first-run compilation of a kernel (about 150 s against 80 s for the WENO5
# 2D kernel on the loaded 2-core machine), while LLVM inlines them anyway (the same
# cells per second, within the 5-10 % noise of the measurement, benchmarks/coldstart.py).
#
# Compilation options of the row functions (numba overloads, compiled into the kernels).
_ROW_JIT = {"fastmath": FASTMATH, "error_model": "numpy"}

# Limiter codes used by the kernels (names in spotpde.tracer._advection.LIMITERS).
UPWIND, MINMOD, VANLEER, MC, KOREN, WENO5 = 0, 1, 2, 3, 4, 6


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def face_value(p_uu, p_u, p_d, limiter):
    """Limited reconstruction at the face between the upwind cell and the downwind cell.

    ``p_uu`` is the cell upwind of the upwind cell ``p_u``; ``p_d`` the downwind cell.
    Returns ``p_u + s/2`` with the limited slope ``s`` (see _advection.LIMITERS), a
    value in ``[0, 2 p_u]`` for non-negative data. Written without branches (selects
    only; ``limiter`` is a compile-time constant) so that loops over it vectorise.
    """
    if limiter == 0:
        return p_u
    dl = p_u - p_uu
    dr = p_d - p_u
    al = abs(dl)
    ar = abs(dr)
    if limiter == 1:
        s = min(al, ar)
    elif limiter == 2:
        s = 2.0 * al * ar / max(al + ar, 1e-300)
    elif limiter == 3:
        s = min(2.0 * al, 2.0 * ar, 0.5 * (al + ar))
    else:
        s = min(2.0 * ar, (al + 2.0 * ar) * (1.0 / 3.0), 2.0 * al)
    # s = 0 unless dl, dr have the same sign (where either is 0, s is 0 already); the
    # sign test uses comparisons: the product dl * dr of tiny tails would be denormal
    s = s if (dl > 0.0) == (dr > 0.0) else 0.0
    return p_u + (0.5 * s if dr > 0.0 else -0.5 * s)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def weno5z(v1, v2, v3, v4, v5, iscale2):
    """Fifth-order WENO-Z face value at the downwind face of ``v3`` (upwind order v1..v5),
    clipped to ``[0, 2 v3]`` (the positivity bound; inactive on resolved data).

    Jiang & Shu 1996 (J. Comput. Phys. 126, 202) candidate stencils ``q_k`` and smoothness
    indicators ``beta_k``, Borges et al. 2008 (J. Comput. Phys. 227, 3191) Z-weights
    ``alpha_k = d_k (1 + (tau5 / B_k)**2)``, ``tau5 = |B_0 - B_2|``, with linear weights
    ``d = (1, 6, 3)/10`` and ``B_k = beta_k / P_scale**2 + 1e-12`` (``iscale2`` is
    ``1 / P_scale**2``: the weights are scale invariant and stay linear where the data
    vary by less than ~1e-6 of the peak). Evaluated with one division by multiplying the
    weights by ``(B_0 B_1 B_2)**2``; no branches.
    """
    q0 = (2.0 * v1 - 7.0 * v2 + 11.0 * v3) * (1.0 / 6.0)
    q1 = (-v2 + 5.0 * v3 + 2.0 * v4) * (1.0 / 6.0)
    q2 = (2.0 * v3 + 5.0 * v4 - v5) * (1.0 / 6.0)
    a = v1 - 2.0 * v2 + v3
    b = v1 - 4.0 * v2 + 3.0 * v3
    B0 = (13.0 / 12.0 * a * a + 0.25 * b * b) * iscale2 + 1e-12
    a = v2 - 2.0 * v3 + v4
    b = v2 - v4
    B1 = (13.0 / 12.0 * a * a + 0.25 * b * b) * iscale2 + 1e-12
    a = v3 - 2.0 * v4 + v5
    b = 3.0 * v3 - 4.0 * v4 + v5
    B2 = (13.0 / 12.0 * a * a + 0.25 * b * b) * iscale2 + 1e-12
    t2 = (B0 - B2) * (B0 - B2)
    c0 = B0 * B0
    c1 = B1 * B1
    c2 = B2 * B2
    w0 = 0.1 * (c0 + t2) * c1 * c2
    w1 = 0.6 * (c1 + t2) * c0 * c2
    w2 = 0.3 * (c2 + t2) * c0 * c1
    f = (w0 * q0 + w1 * q1 + w2 * q2) / (w0 + w1 + w2)
    return min(max(f, 0.0), 2.0 * v3)


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def recon(v1, v2, v3, v4, v5, h1, h2, h5, limiter, eps):
    """Upwind face value at the face between ``v3`` (upwind cell) and ``v4``.

    ``v1, v2`` lie further upwind, ``v5`` further downwind; ``h1, h2, h5`` say whether
    those cells exist (near a boundary the scheme falls back: WENO5 -> Koren -> donor
    cell). The general, branching form: used near boundaries.
    """
    if limiter == 6 and h1 and h2 and h5:
        return weno5z(v1, v2, v3, v4, v5, eps)
    if h2:
        return face_value(v2, v3, v4, limiter if limiter < 6 else 4)
    return v3


#: Rows of cells per parallel work item of the 2D right-hand side.
ROWS_PER_CHUNK = 16


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _xface_edge(Pk, ux, Ak, f, nx, limiter, eps, ih):
    """Flux through the x face ``f`` (between cells ``f-1`` and ``f``) of one row,
    with the boundary fallbacks of :func:`recon` (faces within ``r`` of a side)."""
    i = f - 1
    u = ux[f]
    if u > 0.0:
        pf = recon(Pk[max(i - 2, 0)], Pk[max(i - 1, 0)], Pk[i], Pk[i + 1],
                   Pk[min(i + 2, nx - 1)], i >= 2, i >= 1, i + 2 <= nx - 1, limiter, eps)
    else:
        pf = recon(Pk[min(i + 3, nx - 1)], Pk[min(i + 2, nx - 1)], Pk[i + 1], Pk[i],
                   Pk[max(i - 1, 0)], i + 3 <= nx - 1, i + 2 <= nx - 1, i >= 1, limiter, eps)
    return u * pf - (Ak[i + 1] * Pk[i + 1] - Ak[i] * Pk[i]) * ih


def _literal_limiter(limiter) -> int:
    """The compile-time value of a ``limiter`` argument of a row function (typing)."""
    if not isinstance(limiter, types.IntegerLiteral):
        raise TypingError("the limiter code of a row function must be a compile-time constant")
    return limiter.literal_value


def _reach(limiter: int) -> int:
    """Stencil reach: cells a face needs on its upwind side (3 for WENO5, else 2)."""
    return 3 if limiter == WENO5 else 2


def zface_row(Pm3, Pm2, Pm1, P0, Pp1, Pp2, uz, Am1, A0, Fk, ih, eps, limiter):
    """Vertical fluxes through the faces between rows ``m1`` (below) and ``0`` (numba only).

    ``Pm3 .. Pp2`` are the rows ``k-3 .. k+2`` (``Pm3``/``Pp2`` unused unless WENO5),
    ``uz`` the face velocities, ``Am1``/``A0`` the axial coefficients ``D_zz - |D_xz|``
    of the two rows; ``limiter`` a compile-time constant. Writes
    ``Fk = u P* - (A0 P0 - Am1 Pm1) / h`` for every column (rows far from the floor
    and the top: :func:`zface_row_edge` does the others).
    """
    raise NotImplementedError("zface_row is compiled into numba kernels only")


@overload(zface_row, prefer_literal=True, jit_options=_ROW_JIT)
def _zface_row(Pm3, Pm2, Pm1, P0, Pp1, Pp2, uz, Am1, A0, Fk, ih, eps, limiter):
    lim = _literal_limiter(limiter)
    weno = lim == WENO5

    def impl(Pm3, Pm2, Pm1, P0, Pp1, Pp2, uz, Am1, A0, Fk, ih, eps, limiter):
        for i in range(Fk.shape[0]):
            u = uz[i]
            pos = u > 0.0
            a = Pm2[i]
            b = Pm1[i]
            c = P0[i]
            d = Pp1[i]
            if weno:
                a3 = Pm3[i]
                e = Pp2[i]
                pf = weno5z(a3 if pos else e, a if pos else d, b if pos else c,
                            c if pos else b, d if pos else a, eps)
            else:
                pf = face_value(a if pos else d, b if pos else c, c if pos else b, lim)
            Fk[i] = u * pf - (A0[i] * c - Am1[i] * b) * ih

    return impl


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def zface_row_edge(P, uzf, Azz, k, Fk, ih, eps, limiter):
    """:func:`zface_row` for face row ``k`` within the stencil reach of the floor or
    the top (boundary fallbacks of :func:`recon`; floor and top faces first order)."""
    nz, nx = P.shape
    uz = uzf[k]
    if k == 0 or k == nz:
        Pe = P[0] if k == 0 else P[nz - 1]
        for i in range(nx):
            Fk[i] = uz[i] * Pe[i]
        return
    k3 = max(k - 3, 0)
    k2 = max(k - 2, 0)
    kp1 = min(k + 1, nz - 1)
    kp2 = min(k + 2, nz - 1)
    for i in range(nx):
        u = uz[i]
        if u > 0.0:
            pf = recon(P[k3, i], P[k2, i], P[k - 1, i], P[k, i], P[kp1, i],
                       k >= 3, k >= 2, k + 1 <= nz - 1, limiter, eps)
        else:
            pf = recon(P[kp2, i], P[kp1, i], P[k, i], P[k - 1, i], P[k2, i],
                       k + 2 <= nz - 1, k + 1 <= nz - 1, k >= 2, limiter, eps)
        Fk[i] = u * pf - (Azz[k, i] * P[k, i] - Azz[k - 1, i] * P[k - 1, i]) * ih


def xface_row(Pk, ux, Ak, Fx, ih, eps, limiter):
    """Horizontal fluxes ``Fx`` (``nx + 1`` faces) of one row of cells ``Pk`` (numba only;
    ``limiter`` a compile-time constant)."""
    raise NotImplementedError("xface_row is compiled into numba kernels only")


@overload(xface_row, prefer_literal=True, jit_options=_ROW_JIT)
def _xface_row(Pk, ux, Ak, Fx, ih, eps, limiter):
    lim = _literal_limiter(limiter)
    weno = lim == WENO5
    r = _reach(lim)
    o = r - 2

    def impl(Pk, ux, Ak, Fx, ih, eps, limiter):
        nx = Pk.shape[0]
        Fx[0] = ux[0] * Pk[0]
        Fx[nx] = ux[nx] * Pk[nx - 1]
        if nx < 2 * r:
            for f in range(1, nx):
                Fx[f] = _xface_edge(Pk, ux, Ak, f, nx, lim, eps, ih)
            return
        for f in range(1, r):
            Fx[f] = _xface_edge(Pk, ux, Ak, f, nx, lim, eps, ih)
        # face f = j + r joins cells f - 1 and f; indices are written as j + constant
        # with j >= 0 provably, so no negative-index wraparound blocks vectorisation
        for j in range(nx - 2 * r + 1):
            u = ux[j + r]
            pos = u > 0.0
            a = Pk[j + o]
            b = Pk[j + o + 1]
            c = Pk[j + o + 2]
            d = Pk[j + o + 3]
            if weno:
                a3 = Pk[j]
                e = Pk[j + 5]
                pf = weno5z(a3 if pos else e, a if pos else d, b if pos else c,
                            c if pos else b, d if pos else a, eps)
            else:
                pf = face_value(a if pos else d, b if pos else c, c if pos else b, lim)
            Fx[j + r] = u * pf - (Ak[j + o + 2] * c - Ak[j + o + 1] * b) * ih
        for f in range(nx - r + 1, nx):
            Fx[f] = _xface_edge(Pk, ux, Ak, f, nx, lim, eps, ih)

    return impl


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _corner_row(Cb, Cc, Pb, Pc, gp, gm, ih2):
    """Diagonal exchange rates at the ``nx + 1`` corners between rows b (below) and c.

    ``gp[i+1] = (c+_b[i] P_b[i] - c+_c[i+1] P_c[i+1]) / h**2`` (offset (+1, +1)) and
    ``gm[i+1] = (c-_b[i+1] P_b[i+1] - c-_c[i] P_c[i]) / h**2`` (offset (+1, -1)), with
    ``c+- = max(+-D_xz, 0)`` formed here from the signed ``C = D_xz``; side corners 0.
    """
    nx = Pb.shape[0]
    gp[0] = 0.0
    gm[0] = 0.0
    gp[nx] = 0.0
    gm[nx] = 0.0
    for i in range(nx - 1):
        gp[i + 1] = (max(Cb[i], 0.0) * Pb[i] - max(Cc[i + 1], 0.0) * Pc[i + 1]) * ih2
        gm[i + 1] = (max(-Cb[i + 1], 0.0) * Pb[i + 1] - max(-Cc[i], 0.0) * Pc[i]) * ih2


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _accumulate_row(Fk, acc, w):
    """``acc += w Fk`` (the vertical flux accumulator of ``P_height``)."""
    for i in range(Fk.shape[0]):
        acc[i] += w * Fk[i]


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _accumulate_row_cross(Fk, gp, gm, acc, w, hh):
    """``acc += w Fk + hh (corner exchanges)``: each diagonal exchange crosses the face
    row once, split half to each of the two columns it joins (``hh = w h / 2``)."""
    for i in range(Fk.shape[0]):
        acc[i] += w * Fk[i] + hh * (gp[i] + gp[i + 1] + gm[i] + gm[i + 1])


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _stage_row(Fx, Fb, Ft, P0k, Pk, ca, cb, cc, tiny, out, ih):
    """``out = ca P0 + cb P + cc R`` with ``R = -(Fx[i+1] - Fx[i] + Ft - Fb) / h`` the
    divergence of the face fluxes; values below ``tiny`` in magnitude become 0 (see
    :func:`combine`; NaN passes through)."""
    for i in range(out.shape[0]):
        r = (-(Fx[i + 1] - Fx[i]) - (Ft[i] - Fb[i])) * ih
        v = ca * P0k[i] + cb * Pk[i] + cc * r
        out[i] = 0.0 if abs(v) < tiny else v


@njit(cache=True, fastmath=FASTMATH, error_model="numpy")
def _stage_row_cross(Fx, Fb, Ft, gpb, gpt, gmb, gmt, P0k, Pk, ca, cb, cc, tiny, out, ih):
    """:func:`_stage_row` with the four diagonal exchanges of each cell added to ``R``."""
    for i in range(out.shape[0]):
        r = ((-(Fx[i + 1] - Fx[i]) - (Ft[i] - Fb[i])) * ih
             + gpb[i] - gpt[i + 1] + gmb[i + 1] - gmt[i])
        v = ca * P0k[i] + cb * Pk[i] + cc * r
        out[i] = 0.0 if abs(v) < tiny else v


_fast_num_threads = getattr(_parallel_backend, "_get_num_threads", None)


def _num_threads() -> int:
    """``numba.get_num_threads()`` without its locks (0.8 against 9 microseconds here)."""
    if _fast_num_threads is not None and getattr(_parallel_backend, "_is_initialized", False):
        return _fast_num_threads()
    return numba.get_num_threads()


class _ThreadDispatch:
    """The 2D kernel of one reconstruction, compiled on first use in the variant the
    caller's numba thread count needs: serial for one thread, ``parallel=True`` else.

    Both run the same chunks with the same operations (the same values to round-off:
    fast-math contraction may differ between the two builds, tests/tracer/test_tracer_coldstart.py);
    a one-thread run (the default below 65536 cells)
    compiles only the serial one, in about 2/3 of the CPU time: ``parallel=True`` has LLVM
    optimise and emit the kernel body four times (kernel, gufunc, two gufunc wrappers).
    """

    __slots__ = ("limiter", "_variants")

    def __init__(self, limiter: int):
        self.limiter = limiter
        self._variants = [None, None]

    def __call__(self, *args):
        parallel = _num_threads() > 1
        kernel = self._variants[parallel]
        if kernel is None:
            kernel = self._variants[parallel] = _rhs_2d_variant(self.limiter, parallel)
        return kernel(*args)

    def variant(self, parallel: bool):
        """The compiled dispatcher of one variant (``parallel`` True or False)."""
        return _rhs_2d_variant(self.limiter, bool(parallel))


@functools.lru_cache(maxsize=None)
def rhs_2d_kernel(limiter: int) -> _ThreadDispatch:
    """The 2D right-hand-side kernel specialised (and disk cached) for one reconstruction.

    The limiter code is a closure constant, so the compiler removes the branches of the
    other reconstructions from the inner loops. Returns a callable with the signature
    of ``rhs_2d`` below that compiles (lazily) only the serial or parallel variant in use.
    """
    return _ThreadDispatch(limiter)


@intrinsic
def _borrowed(typingctx, arr):
    """``arr`` without its reference count (NULL meminfo), for use while the caller holds it.

    Every row view (``P[k]``) of a counted array costs two atomic reference-count updates;
    the ``parallel=True`` kernel never pays them because numba's gufunc wrapper hands the
    loop body uncounted arrays. Without this, the serial 2D kernel ran 1.2 times slower
    than the parallel one on one thread (2 times on rows of 16 cells), with it 0.91-0.99.
    """
    def codegen(context, builder, sig, args):
        src = context.make_array(arr)(context, builder, value=args[0])
        dst = context.make_array(arr)(context, builder)
        context.populate_array(dst, data=src.data, shape=src.shape, strides=src.strides,
                               itemsize=src.itemsize, meminfo=None)
        return dst._getvalue()

    return arr(arr), codegen


@functools.lru_cache(maxsize=None)
def _rhs_2d_variant(limiter: int, parallel: bool):
    """The numba dispatcher of the 2D kernel for one reconstruction and one variant
    (``serial`` is a closure value, so numba's disk cache keeps the two apart)."""
    r = _reach(limiter)
    serial = not parallel

    def rhs_2d(P, uxf, uzf, Axx, Azz, C, has_cross, eps, h, out, Fz_edge, Fz_acc, w_acc,
               P0, ca, cb, cc, tiny):
        """``R = dP/dt`` of the 2D Fokker-Planck equation (fused advection + explicit
        diffusion), combined into a Runge-Kutta stage ``out = ca P0 + cb P + cc R``.

        Args:
            P: (nz, nx) density.
            uxf: (nz, nx+1) x-face velocities (boundary faces carry the BC).
            uzf: (nz+1, nx) z-face velocities (floor and top faces carry the BC).
            Axx, Azz: (nz, nx) axial diffusion coefficients ``D_xx - |D_xz|``,
                ``D_zz - |D_xz|`` (>= 0 when the tensor is diagonally dominant); zero
                arrays for advection only.
            C: (nz, nx) the cross coefficient ``D_xz`` (signed; the diagonal exchange
                coefficients are ``max(+-C, 0)``).
            has_cross: evaluate the diagonal exchanges.
            eps: WENO scale ``1 / P_scale**2`` (the reconstruction ``limiter`` is a
                compile-time constant of this specialisation).
            h: spacing.
            out: (nz, nx) result ``ca P0 + cb P + cc R``, entries below ``tiny`` in
                magnitude set to 0 (``ca = cb = tiny = 0``, ``cc = 1`` give ``R``). May be
                ``P0`` itself (elementwise), never ``P``.
            Fz_edge: (2, nx) written: the vertical face fluxes through the floor (row 0)
                and the top (row 1), for the outflow budget.
            Fz_acc: (nz+1, nx) accumulator of the upward face fluxes including the
                diagonal exchanges (each split half to the two columns it joins),
                ``Fz_acc += w_acc * (Fz + h/2 * corner exchanges)``.
            w_acc: weight (time-step times Runge-Kutta weight).
            P0, ca, cb, cc, tiny: the stage combination (above).
        """
        nz, nx = P.shape
        ih = 1.0 / h
        ih2 = ih * ih
        hh = 0.5 * h * w_acc
        nchunk = (nz + ROWS_PER_CHUNK - 1) // ROWS_PER_CHUNK
        if serial:   # a closure constant: the parallel variant's compiler drops this branch
            P = _borrowed(P)
            uxf = _borrowed(uxf)
            uzf = _borrowed(uzf)
            Axx = _borrowed(Axx)
            Azz = _borrowed(Azz)
            C = _borrowed(C)
            out = _borrowed(out)
            Fz_edge = _borrowed(Fz_edge)
            Fz_acc = _borrowed(Fz_acc)
            P0 = _borrowed(P0)
        for c in prange(nchunk):
            k0 = c * nz // nchunk
            m = (c + 1) * nz // nchunk - k0
            # face rows k0 .. k0 + m of this chunk (chunk-local, cache resident)
            Fz = np.empty((m + 1, nx))
            gp = np.empty((m + 1, nx + 1))
            gm = np.empty((m + 1, nx + 1))
            Fx = np.empty(nx + 1)
            for kk in range(m + 1):
                k = k0 + kk
                Fk = Fz[kk]
                if k >= r and k <= nz - r:
                    zface_row(P[k - 3], P[k - 2], P[k - 1], P[k], P[k + 1],
                              P[min(k + 2, nz - 1)], uzf[k], Azz[k - 1], Azz[k], Fk, ih, eps,
                              limiter)
                else:
                    zface_row_edge(P, uzf, Azz, k, Fk, ih, eps, limiter)
                if has_cross:
                    if k >= 1 and k <= nz - 1:
                        _corner_row(C[k - 1], C[k], P[k - 1], P[k], gp[kk], gm[kk], ih2)
                    else:
                        for i in range(nx + 1):
                            gp[kk, i] = 0.0
                            gm[kk, i] = 0.0
                if kk < m or k == nz:
                    # this chunk owns face row k (the chunk above owns its top row)
                    if has_cross:
                        _accumulate_row_cross(Fk, gp[kk], gm[kk], Fz_acc[k], w_acc, hh)
                    else:
                        _accumulate_row(Fk, Fz_acc[k], w_acc)
                    if k == 0:
                        for i in range(nx):
                            Fz_edge[0, i] = Fk[i]
                    elif k == nz:
                        for i in range(nx):
                            Fz_edge[1, i] = Fk[i]
            for kk in range(m):
                k = k0 + kk
                xface_row(P[k], uxf[k], Axx[k], Fx, ih, eps, limiter)
                if has_cross:
                    _stage_row_cross(Fx, Fz[kk], Fz[kk + 1], gp[kk], gp[kk + 1], gm[kk],
                                     gm[kk + 1], P0[k], P[k], ca, cb, cc, tiny, out[k], ih)
                else:
                    _stage_row(Fx, Fz[kk], Fz[kk + 1], P0[k], P[k], ca, cb, cc, tiny, out[k],
                               ih)

    return njit(parallel=parallel, cache=True, fastmath=FASTMATH, error_model="numpy")(rhs_2d)


@njit(parallel=True, cache=True)
def combine(a, P0, b, P1, c, R, out, tiny):
    """``out = a * P0 + b * P1 + c * R`` elementwise (flattened arrays), one pass.

    Values with ``|out| < tiny`` are set to 0: this keeps far tails, and the squares the
    WENO smoothness indicators form from them, out of denormal floating point (about 100
    times slower arithmetic); the solver uses ``tiny = 1e-100 max P0``, so the
    probability removed is below 1e-90 of the total.
    """
    n = out.size
    for m in prange(n):
        v = a * P0[m] + b * P1[m] + c * R[m]
        if abs(v) < tiny:
            v = 0.0
        out[m] = v


@njit(cache=True)
def laplacian_5pt_serial(f, out):
    """Single-threaded 5-point Laplacian (the ~1.8 Gcell/s one-core baseline)."""
    nz, nx = f.shape
    for k in range(1, nz - 1):
        for i in range(1, nx - 1):
            out[k, i] = f[k - 1, i] + f[k + 1, i] + f[k, i - 1] + f[k, i + 1] - 4.0 * f[k, i]


