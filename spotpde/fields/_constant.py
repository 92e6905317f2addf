"""Particle fields for constant coefficients from one transform of ``rho_s`` per stencil.

With constant ``v_s`` and ``D_s`` every drift source of ``coefficients.particle_fields`` is
a constant times ``rho_s`` or one of its grid derivatives, and the discrete convolution
commutes with the central difference on the zero-extended field, so the whole grid is
transformed once per kernel stencil; what the one-sided differences at the boundaries
change is a few planes, convolved directly. Private: ``coefficients.particle_fields``
(truncated walls) and ``_walls.renormalised_constant_fields`` (renormalised walls of a
rectangular silo) call :func:`constant_fields`.

2D grids take :func:`fields_2d`: every field from one numba pass over the transform
(read in place), the passage drift included, the boundary terms (and the renormalised
walls' strips) as batched box convolutions (``_strips``). Measured cost and the
comparison with the plain computations: docs/coefficients.md section 6.1.
"""

from __future__ import annotations

from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import numba
import scipy.signal
from numba import njit

from . import _strips
from ._common import _COMPONENTS, _axis, _box_derivative, _is_zero, _pair
from ._fft import threads
from .convolution import convolve, convolve_padded
from ..grid import Grid
from ..parameters import drift_weight

__all__ = ["constant_fields", "fields_2d", "add_requests", "SpotFluxTensor"]


class SpotFluxTensor(Mapping):
    """``{"D_xx": rho_s D_s^xx or None, ...}`` for a constant ``D_s``, computed on access.

    The wall layer reads only its wall values, and only for rules other than 1/2, so the
    whole-grid products are formed when (and each time) a component is looked up.
    """

    def __init__(self, rho_s: np.ndarray, D_s: Mapping):
        self.rho_s, self.D_s = rho_s, D_s

    def __getitem__(self, key):
        d = self.D_s[key]
        return None if _is_zero(d) else self.rho_s * d

    def __iter__(self):
        return iter(self.D_s)

    def __len__(self):
        return len(self.D_s)


def _boundary_planes(grid: Grid, rho_p: np.ndarray, comp: str) -> list[tuple[int, np.ndarray]]:
    """Planes where the zero-extended central difference differs from ``np.gradient``.

    On the grid padded by one cell, ``delta f = (f[i+1] - f[i-1]) / 2h`` of the zero-extended
    ``rho_s`` equals the second-order ``np.gradient`` inside; they differ on the two
    boundary cells (one-sided formula ``(-3 f0 + 4 f1 - f2) / 2h``) and on the two ghost
    cells (where ``np.gradient``'s field is zero). Returns
    ``[(padded index, delta - gradient on that plane), ...]``; only those planes are read.
    """
    axis = _axis(grid, comp)
    h = grid.spacing
    n = rho_p.shape[axis] - 2

    def plane(i):
        return np.take(rho_p, i, axis=axis)

    r0, r1, r2 = plane(1), plane(2), plane(3)                 # rho_s[0], [1], [2]
    e0, e1, e2 = plane(n), plane(n - 1), plane(n - 2)         # rho_s[n-1], [n-2], [n-3]
    g_lo = (-1.5 * r0 + 2.0 * r1 - 0.5 * r2) / h              # np.gradient, edge_order=2
    g_hi = (1.5 * e0 - 2.0 * e1 + 0.5 * e2) / h
    return [(0, r0 / (2.0 * h)),
            (1, r1 / (2.0 * h) - g_lo),
            (n, -e1 / (2.0 * h) - g_hi),
            (n + 1, -e0 / (2.0 * h))]


def _grid_boundary_planes(grid: Grid, rho_s: np.ndarray, comp: str) -> list:
    """:func:`_boundary_planes` of ``np.pad(rho_s, 1)`` without padding the whole grid:
    each plane is one layer of ``rho_s`` padded by one cell along the other axes."""
    axis = _axis(grid, comp)
    h, n = grid.spacing, rho_s.shape[axis]

    def plane(i):
        return np.pad(np.take(rho_s, i, axis=axis), 1)

    r0, r1, r2 = plane(0), plane(1), plane(2)
    e0, e1, e2 = plane(n - 1), plane(n - 2), plane(n - 3)
    g_lo = (-1.5 * r0 + 2.0 * r1 - 0.5 * r2) / h
    g_hi = (1.5 * e0 - 2.0 * e1 + 0.5 * e2) / h
    return [(0, r0 / (2.0 * h)),
            (1, r1 / (2.0 * h) - g_lo),
            (n, -e1 / (2.0 * h) - g_hi),
            (n + 1, -e0 / (2.0 * h))]


def _inner_all(ndim: int) -> list[slice]:
    return [slice(1, -1)] * ndim


def _subtract_planes(target: np.ndarray, stencil: np.ndarray, planes, axis: int,
                     scale: float) -> None:
    """``target -= scale * (stencil * c)`` on the grid, ``c`` supported on a few padded planes.

    ``c`` lives on planes normal to ``axis`` of the grid padded by one cell; ``target`` is
    grid-shaped (the padded grid's interior). Each plane ``q`` at padded index ``p`` is one
    full convolution of ``q`` (a layer one cell thick) with the stencil, which lands on
    padded indices ``p - m ... p + m`` along ``axis``.

    Args:
        target: grid-shaped array, modified in place.
        stencil: centred stencil (array order), half-width ``m`` along ``axis``.
        planes: ``[(padded index p, plane array over the other padded axes), ...]``.
        axis: the planes' normal axis.
        scale: factor of the convolution (``h**dims`` for the integral).
    """
    m = stencil.shape[axis] // 2
    n = target.shape[axis]
    for p, q in planes:
        if not np.any(q):
            continue
        full = scipy.signal.convolve(np.expand_dims(q, axis), stencil, mode="full")
        # other axes: 'same' on the padded grid, then its interior (padded index 1..n)
        crop = [slice((k - 1) // 2 + 1, (k - 1) // 2 + 1 + t)
                for k, t in zip(stencil.shape, target.shape)]
        lo, hi = max(1, p - m), min(n + 1, p + m + 1)          # padded indices hit
        if hi <= lo:
            continue
        crop[axis] = slice(lo - (p - m), hi - (p - m))
        idx = [slice(None)] * target.ndim
        idx[axis] = slice(lo - 1, hi - 1)
        target[tuple(idx)] -= scale * full[tuple(crop)]


def constant_fields(grid: Grid, rho_s: np.ndarray, v_s: float, D_s: Mapping, lam: float,
                     conv, D_source: Mapping | None = None, passage_drift: bool = False,
                     strips=None) -> dict[str, np.ndarray]:
    """``u_p`` and ``D_p`` for constant ``v_s`` and ``D_s`` from one convolution per stencil.

    With constant coefficients ``w * div(D_s rho_s) = D_s^ab w * d_b rho_s``, and the
    discrete convolution commutes with the central difference on the zero-extended field:
    ``w * grad(rho_s) = delta(w * rho_s~) - w * c``, where ``c`` lives on the boundary and
    ghost planes only (:func:`_boundary_planes`). So ``w * rho_s~`` on the grid padded by
    one cell gives ``u_z``, every ``w * d_b rho_s`` and (``w**2`` proportional to ``w``, or one
    more transform) ``D_p``; the plane terms are cheap 1D/2D convolutions. Identical to
    the general path to round-off. ``D_source`` (default ``D_s``): the constant tensor
    ``T`` of ``D_p = w^2 * (rho_s T)`` (the passage diffusivity's ``v_s b_eff``). 2D grids
    take :func:`fields_2d` (one pass over the transform), which with ``passage_drift``
    also adds the passage drift ``div(D_p - D_p_mf)`` and with ``strips`` renormalises the
    walls; both need a 2D grid.
    """
    if grid.dims == 2:
        return fields_2d(grid, rho_s, v_s, D_s, lam, conv, D_source, passage_drift, strips)
    if passage_drift:
        raise ValueError("passage_drift: the fused passage drift needs a 2D grid")
    if strips is not None:
        raise ValueError("strips: the wall strips of the one-pass fields need a 2D grid")

    comps = _COMPONENTS[grid.dims]
    h = grid.spacing
    hd = h**grid.dims
    rho_p = np.pad(rho_s, 1)
    inner = tuple(_inner_all(grid.dims))
    D_src = D_s if D_source is None else D_source
    need_D = any(not _is_zero(d) for d in D_src.values())
    # the transforms themselves (unscaled: h**dims and the constants are applied once, on
    # the grid's interior); w**2 = c w (uniform kernel) reuses the one transform
    # float64 arrays whatever the transforms' precision (single for large 3D grids)
    c1 = np.asarray(convolve(rho_p, conv.stencils[1], mode="linear",
                             precision=conv.precision), dtype=float)
    p2, c2 = conv.use[2]
    c2_array = None
    if need_D:
        c2_array = c1 if p2 == 1 else np.asarray(
            convolve(rho_p, conv.stencils[2], mode="linear", precision=conv.precision),
            dtype=float)
    fields = {f"u_{a}": None for a in comps}      # None: zero so far

    def accumulate(key, value):
        fields[key] = value if fields[key] is None else fields[key] + value

    if v_s != 0.0:
        fields["u_z"] = (-v_s * hd) * c1[inner]
    if lam != 0.0:
        stencil = conv.stencils[1]
        for b in comps:
            coeffs = {a: D_s[_pair(a, b)] for a in comps if not _is_zero(D_s[_pair(a, b)])}
            if not coeffs:
                continue
            axis = _axis(grid, b)
            up, down = list(inner), list(inner)
            up[axis], down[axis] = slice(2, None), slice(0, -2)
            w_grad = c1[tuple(up)] - c1[tuple(down)]          # central difference, interior
            w_grad *= 0.5 * hd / h
            _subtract_planes(w_grad, stencil, _boundary_planes(grid, rho_p, b), axis, hd)
            for a, d in coeffs.items():
                if len(coeffs) == 1 and fields[f"u_{a}"] is None:   # the usual case: in place
                    w_grad *= drift_weight(lam) * float(d)
                    fields[f"u_{a}"] = w_grad
                else:
                    accumulate(f"u_{a}", (drift_weight(lam) * float(d)) * w_grad)
    for key in fields:
        if fields[key] is None:
            fields[key] = np.zeros(grid.shape)
    for key, d in D_src.items():
        fields[key] = ((float(d) * c2 * hd) * c2_array[inner] if not _is_zero(d)
                       else np.zeros(grid.shape))
    return fields




# -- 2D: every field in one pass over the transform --------------------------------------

@njit(cache=True, error_model="numpy", nogil=True)
def _fields_2d_cell(c, cD, i, j, h, a0, gxx, gxz, gzx, gzz, px, pz, axx, azz,
                    ux, uz, dxx, dzz):
    """One cell of :func:`_fields_2d_kernel`, any position (one-sided differences of
    ``cD`` on the boundary cells)."""
    nz, nx = ux.shape
    h2 = 2.0 * h
    ea, eb, ec = -1.5 / h, 2.0 / h, -0.5 / h
    k, q = i + 1, j + 1
    dx = c[k, q + 1] - c[k, q - 1]
    dz = c[k + 1, q] - c[k - 1, q]
    f = cD[k, q]
    if j == 0:
        fx = ea * f + eb * cD[k, 2] + ec * cD[k, 3]
    elif j == nx - 1:
        fx = -ec * cD[k, nx - 2] - eb * cD[k, nx - 1] - ea * f
    else:
        fx = (cD[k, q + 1] - cD[k, q - 1]) / h2
    if i == 0:
        fz = ea * f + eb * cD[2, q] + ec * cD[3, q]
    elif i == nz - 1:
        fz = -ec * cD[nz - 2, q] - eb * cD[nz - 1, q] - ea * f
    else:
        fz = (cD[k + 1, q] - cD[k - 1, q]) / h2
    ux[i, j] = gxx * dx + gxz * dz + px * fx
    uz[i, j] = a0 * c[k, q] + gzx * dx + gzz * dz + pz * fz
    if dxx.shape[0] == nz:
        dxx[i, j] = axx * f
    if dzz.shape[0] == nz:
        dzz[i, j] = azz * f


@njit(cache=True, error_model="numpy")
def _fields_2d_kernel(c, cD, h, a0, gxx, gxz, gzx, gzz, px, pz, axx, azz, ux, uz, dxx, dzz,
                      same=False):
    """One pass over the padded convolutions ``c = w * psi~`` (drift) and ``cD`` (``D_p``).

    For every grid cell ``(i, j)`` (padded index ``(i + 1, j + 1)``), with the central
    differences ``dx = c[., j+2] - c[., j]``, ``dz = c[i+2, .] - c[i, .]`` of the padded
    transform and ``Dx, Dz`` the second-order grid derivatives of ``cD`` on the grid
    (``grid.derivative``'s formulas: one-sided on the boundary cells)::

        u_x  = gxx dx + gxz dz + px Dx
        u_z  = a0 c + gzx dx + gzz dz + pz Dz
        D_xx = axx cD,   D_zz = azz cD

    ``D_xx`` (``D_zz``) is written only if ``dxx`` (``dzz``) is grid-shaped (an empty
    array: the caller's zeros). ``same``: ``cD`` is ``c`` (the uniform kernel: ``w**2``
    a multiple of ``w``), whose differences the drift already has: inner cells then take
    ``u_x = (gxx + px / 2h) dx + gxz dz`` (and ``u_z`` alike), the same sums to round-off.
    Inner cells run loops without branches; the boundary cells go through
    :func:`_fields_2d_cell`. Serial; :func:`_fields_2d_kernel_parallel` splits the rows.
    """
    _fields_2d_rows(c, cD, h, a0, gxx, gxz, gzx, gzz, px, pz, axx, azz, ux, uz, dxx, dzz,
                    same, 0, ux.shape[0])


def _fields_2d_kernel_parallel(c, cD, h, a0, gxx, gxz, gzx, gzz, px, pz, axx, azz, ux, uz,
                               dxx, dzz, same, chunks):
    """:func:`_fields_2d_kernel` with its rows split into ``chunks`` blocks run on as many
    Python threads (:func:`_fields_2d_rows` releases the GIL): the same operations cell by
    cell, the same values. Threads rather than ``numba.prange``: a parallel numba kernel
    took 4-5 s to compile, paid by the first run after installation (issue 16: under
    15 s in all)."""
    nz = ux.shape[0]
    args = (c, cD, h, a0, gxx, gxz, gzx, gzz, px, pz, axx, azz, ux, uz, dxx, dzz, same)
    bounds = [(t * nz // chunks, (t + 1) * nz // chunks) for t in range(chunks)]
    with ThreadPoolExecutor(chunks) as pool:
        for f in [pool.submit(_fields_2d_rows, *args, i0, i1) for i0, i1 in bounds]:
            f.result()


@njit(cache=True, error_model="numpy", nogil=True)
def _fields_2d_rows(c, cD, h, a0, gxx, gxz, gzx, gzz, px, pz, axx, azz, ux, uz, dxx, dzz,
                    same, i0, i1):
    """Rows ``i0 <= i < i1`` of :func:`_fields_2d_kernel`."""
    nz, nx = ux.shape
    h2 = 2.0 * h
    cxx, czz = gxx + px / h2, gzz + pz / h2
    wxx, wzz = dxx.shape[0] == nz, dzz.shape[0] == nz
    for i in range(i0, i1):
        if i == 0 or i == nz - 1:
            for j in range(nx):
                _fields_2d_cell(c, cD, i, j, h, a0, gxx, gxz, gzx, gzz, px, pz, axx, azz,
                                ux, uz, dxx, dzz)
            continue
        k = i + 1
        cm, c0, cp = c[k - 1], c[k], c[k + 1]
        dm, d0, dp = cD[k - 1], cD[k], cD[k + 1]
        uxr, uzr = ux[i], uz[i]
        if same:                        # cD is c: its differences are dx, dz, so the
            for q in range(2, nx):      # factors add up (fewer rows to read and flops)
                dx = c0[q + 1] - c0[q - 1]
                dz = cp[q] - cm[q]
                uxr[q - 1] = cxx * dx + gxz * dz
                uzr[q - 1] = a0 * c0[q] + gzx * dx + czz * dz
        else:
            for q in range(2, nx):      # padded column q: grid column j = q - 1
                dx = c0[q + 1] - c0[q - 1]
                dz = cp[q] - cm[q]
                fx = (d0[q + 1] - d0[q - 1]) / h2
                fz = (dp[q] - dm[q]) / h2
                uxr[q - 1] = gxx * dx + gxz * dz + px * fx
                uzr[q - 1] = a0 * c0[q] + gzx * dx + gzz * dz + pz * fz
        if wxx:
            dxr = dxx[i]
            for q in range(2, nx):
                dxr[q - 1] = axx * d0[q]
        if wzz:
            dzr = dzz[i]
            for q in range(2, nx):
                dzr[q - 1] = azz * d0[q]
        for j in (0, nx - 1):
            _fields_2d_cell(c, cD, i, j, h, a0, gxx, gxz, gzx, gzz, px, pz, axx, azz,
                            ux, uz, dxx, dzz)


def fields_2d(grid: Grid, rho_s: np.ndarray, v_s: float, D_s: Mapping, lam: float, conv,
              D_source: Mapping | None = None, passage_drift: bool = False, strips=None
              ) -> dict[str, np.ndarray]:
    """:func:`constant_fields` of a 2D grid, every field from one pass over the transform.

    The same sums, reordered to round-off: ``u_a = 2 lam sum_b D_s^ab (delta_b(w * psi~)
    h^2 / 2h - w * B_b)`` and ``D^ab = T^ab c2 h^2 (w * psi~)`` are formed cell by cell
    from the transform of ``psi = rho_s`` (:func:`_fields_2d_kernel`, numba, one pass
    writing each field once) instead of one whole-grid numpy pass per operation; ``B_b``,
    what the central difference of the zero-extended ``psi`` gets wrong near the
    boundaries, are box convolutions (``_strips``, batched; :func:`_boundary_sources`).
    ``passage_drift``: also add ``div(D_p - D_p_mf)`` (``_passage.keep_flux_velocity``;
    ``D_p - D_p_mf = (T - D_s) c2 h^2 (w * psi~ + strips)`` for constant tensors), the
    transform's part as second-order grid derivatives in the same pass.

    ``strips`` (the renormalised walls of a rectangular silo, ``_walls``): ``[(column
    slice, r), ...]`` with ``r = 1/phi`` on those columns (``phi = 1`` elsewhere). Then
    ``psi = rho_s r``, so ``u_z = -v_s h^2 w * psi~`` needs no correction,
    ``B_x = delta_x psi~ - (r grad_x rho_s)~`` lives on the strips widened by one cell (and
    the ghost columns), ``B_z`` on the planes of ``psi`` at the floor and top (``r``
    depends on ``x`` only), and ``D_p`` adds ``w^2 * (psi (r - 1))`` on the strips: the
    sources of :func:`spotpde.fields._walls.renormalised_fields` (``rho_s / phi``,
    ``div(D_s rho_s) / phi``, ``rho_s / phi^2``) to round-off, with two strip transforms
    per wall instead of three and the planes'.

    The transform is read in place (``convolution.convolve_padded``; ``r`` applied to the
    strip columns of its input buffer): no padded copy of ``rho_s``, no copy of the result.
    """
    h = grid.spacing
    hd = h * h
    D_src = D_s if D_source is None else D_source

    def val(m, key):
        return 0.0 if _is_zero(m.get(key, 0.0)) else float(m[key])

    d = {k: val(D_s, k) for k in ("D_xx", "D_xz", "D_zz")}
    t = {k: val(D_src, k) for k in ("D_xx", "D_xz", "D_zz")}
    p2, c2 = conv.use[2]
    g = lam * hd / h            # 2 lam D^ab (h^2 / 2h) per unit D^ab
    kD = c2 * hd
    px = (t["D_xx"] - d["D_xx"]) * kD if passage_drift else 0.0
    pz = (t["D_zz"] - d["D_zz"]) * kD if passage_drift else 0.0
    shape = grid.shape
    strips = [(sl, r) for sl, r in (strips or ()) if sl.stop > sl.start]

    def prepare(psi):           # rho_s -> psi = rho_s r, on the strip columns only
        for sl, r in strips:
            psi[:, sl] *= r

    ux, uz = np.empty(shape), np.empty(shape)
    # a D component that vanishes is the zero array (untouched pages: no writing pass)
    dxx, dzz = (np.empty(shape) if t[k] != 0.0 else np.zeros(shape) for k in ("D_xx", "D_zz"))
    need_D = any(v != 0.0 for v in t.values()) or px != 0.0 or pz != 0.0
    cD_own = None
    if need_D and p2 != 1:      # w**2 not a multiple of w: its own transform (a copy)
        psi = np.pad(rho_s, 1)
        prepare(psi[1:-1, 1:-1])
        cD_own = convolve(psi, conv.stencils[2], mode="linear")
    with convolve_padded(rho_s, conv.stencils[1], 1, prepare=prepare) as c:
        cD = c if cD_own is None else cD_own
        none = np.empty((0, 0))
        args = (c, cD, h, -float(v_s) * hd, g * d["D_xx"], g * d["D_xz"], g * d["D_xz"],
                g * d["D_zz"], px, pz, t["D_xx"] * kD, t["D_zz"] * kD, ux, uz,
                dxx if t["D_xx"] != 0.0 else none, dzz if t["D_zz"] != 0.0 else none, cD is c)
        chunks = _kernel_threads()
        if chunks > 1:          # cores free: the rows (and the outputs' first-touch page
            _fields_2d_kernel_parallel(*args, chunks)     # faults) split between them
        else:
            _fields_2d_kernel(*args)
        dxz = ((t["D_xz"] * kD) * cD[1:-1, 1:-1] if t["D_xz"] != 0.0 else np.zeros(shape))
    fields = {"u_x": ux, "u_z": uz, "D_xx": dxx, "D_xz": dxz, "D_zz": dzz}
    requests = []
    if lam != 0.0:              # - 2 lam D_s^ab h^2 w * B_b
        requests += _boundary_sources(grid, rho_s, d, lam * 2.0 * hd, strips)
    if need_D:                  # D_p: w^2 * (psi (r - 1)) on the strips
        requests += [("D", (slice(0, shape[0]), sl), rho_s[:, sl] * r * (r - 1.0), p2)
                     for sl, r in strips]
    add_requests(grid, fields, requests, conv, D_s, D_src, passage_drift)
    return fields


def _kernel_threads() -> int:
    """Threads for the one-pass kernel: the transforms' (``_fft.threads``: the cores not
    busy with other tasks), at most numba's."""
    return max(1, min(threads(), numba.get_num_threads()))


def _boundary_sources(grid: Grid, rho_s: np.ndarray, d: Mapping, scale: float,
                      strips) -> list:
    """``B_b`` of :func:`fields_2d` as box requests ``(("u_a", -scale D_s^ab), box, B_b, 1)``.

    Without strips ``B_b`` is the boundary-plane source ``c_b`` of
    :func:`_grid_boundary_planes` (two planes at each end of axis ``b``: the ghost plane
    at index -1 or ``n`` and the boundary cells). With strips (``psi = rho_s r``):
    ``B_z`` is ``c_z`` of ``psi``; ``B_x = delta_x psi~ - (r grad_x rho_s)~``, computed on the
    strips widened by one cell (merged where they meet), is ``c_x`` where ``r = 1``.
    """
    nz, nx = grid.shape
    h = grid.spacing
    r_row = np.ones(nx)
    for sl, r in strips:
        r_row[sl] = r
    out = []
    for b, axis in (("x", 1), ("z", 0)):
        coeffs = {a: d[_key(a, b)] for a in ("x", "z") if d[_key(a, b)] != 0.0}
        if not coeffs:
            continue
        boxes = []
        if b == "z" or not strips:
            n = grid.shape[axis]
            src = rho_s
            if b == "z":        # the three rows at each end (of psi: r depends on x only)
                src = np.concatenate([rho_s[:3], rho_s[-3:]]) * r_row[None, :]
            ns = src.shape[axis]
            planes = dict(_grid_boundary_planes(grid, src, b))
            for lo, (p, q) in ((-1, (0, 1)), (n - 1, (ns, ns + 1))):
                box = [slice(0, nz), slice(0, nx)]
                box[axis] = slice(lo, lo + 2)
                boxes.append((tuple(box),
                              np.stack([planes[p][1:-1], planes[q][1:-1]], axis=axis)))
        else:
            spans = []          # the strips widened by one cell, merged where they meet
            for sl, _ in sorted(strips, key=lambda s: s[0].start):
                lo, hi = max(-1, sl.start - 1), min(nx + 1, sl.stop + 1)
                if spans and lo <= spans[-1][1]:
                    spans[-1][1] = max(spans[-1][1], hi)
                else:
                    spans.append([lo, hi])
            for lo, hi in spans:
                psi = np.zeros((nz, hi - lo + 2))               # psi~ on lo - 1 ... hi
                a0, a1 = max(0, lo - 1), min(nx, hi + 1)
                psi[:, a0 - (lo - 1):a1 - (lo - 1)] = rho_s[:, a0:a1] * r_row[a0:a1]
                B = (psi[:, 2:] - psi[:, :-2]) / (2.0 * h)      # delta_x psi~ on lo ... hi - 1
                g0, g1 = max(0, lo), min(nx, hi)                # minus (r grad_x rho_s)~
                B[:, g0 - lo:g1 - lo] -= (_box_derivative(rho_s, h, (slice(0, nz),
                                                                      slice(g0, g1)), 1)
                                          * r_row[g0:g1])
                boxes.append(((slice(0, nz), slice(lo, hi)), B))
        for box, values in boxes:
            out += [((f"u_{a}", -scale * dab), box, values, 1) for a, dab in coeffs.items()]
    return out


def add_requests(grid: Grid, fields: dict, requests, conv, D_s: Mapping, T: Mapping,
                 passage_drift: bool = False) -> None:
    """Add the box convolutions of ``requests`` (``_strips.box_convolutions``) to ``fields``.

    Requests named ``("u_a", factor)`` are added to ``u_a`` times ``factor``; those named
    ``"D"`` (one source for every ``D_p`` component) to every ``D^ab`` times
    ``T^ab c2 h^dims``, and with ``passage_drift`` (2D) their derivatives times
    ``(T - D_s)^aa c2 h^2`` to ``u_a`` (the passage drift ``div(D_p - D_p_mf)``).
    """
    if not requests:
        return
    hd = grid.spacing**grid.dims
    c2 = conv.use[2][1]
    requests = list(requests)
    for name, dst, values in _strips.box_convolutions(requests, conv.stencils, grid.shape):
        part = [(dst, values)]
        if name != "D":
            _strips.add(fields[name[0]], part, name[1])
            continue
        for key, t in T.items():
            if not _is_zero(t):
                _strips.add(fields[key], part, float(t) * c2 * hd)
        for key, comp in (("D_xx", "x"), ("D_zz", "z")) if passage_drift else ():
            t, d = (0.0 if _is_zero(m[key]) else float(m[key]) for m in (T, D_s))
            if t != d:
                _strips.add_derivative(fields[f"u_{comp}"], part, grid.spacing,
                                       grid.axes.index(comp), (t - d) * c2 * hd)


def _key(a: str, b: str) -> str:
    return "D_xz" if a != b else f"D_{a}{a}"
