"""Relative diffusion of two tracers and the cage-breaking fall (paper, eq. fprel).

Two particles a distance ``r = r_2 - r_1 = (X, Z)`` apart fall through locally uniform
flow. With the fall distance ``zeta`` (in d) as time, the density ``P(r, zeta)`` of the
separation obeys the Ito Fokker-Planck equation without drift (the pair drift is zero for
every rule: both particles share the same mean velocity)::

    dP/dzeta = d_a d_b (B^ab(r) P),        a, b in {x, z},

with ``B`` the relative diffusion length tensor per unit fall (in d). In uniform flow of
spots of density ``rho_s`` and diffusivity ``D_s``, the relative diffusivity is
``D_rel = 2 [D_p - int w(r_1 - s) w(r_2 - s) rho_s D_s ds] = 2 D_p (1 - C(r))``
(mean field), divided by the particle speed ``V1 rho_s v_s``::

    B^ab(r) = 2 b_p^ab (1 - C(r)),   b_p = diag(b, b_par) V2/V1     ("mean-field"),

``C`` the kernel's normalised autocorrelation (``Kernel.correlation_vector``: anisotropic
kernels enter through the scaled separation; ``B`` stays diagonal in ``(x, z)``).
``"passage"`` takes ``B`` from :func:`spotpde.fields._passage.length_tensor` (the discrete
model's own pair diffusivity; imported on use).

Boundaries: the hard core is reflecting with zero Ito normal flux
``n . div(B P) = 0`` at ``|r| = contact``; the cage breaks at an absorbing circle
``|r| = separation``.

Scheme (derivation and checks in ``docs/pair.md``): cell-centred finite volumes on a
Cartesian grid of the square ``[-s, s]^2``, cut by the two circles. The Ito flux across a
face is ``A_f (B_i P_i - B_j P_j) / h`` (the coefficient taken in the cell it multiplies:
the Ito form, second order in the interior), the core's cut cells carry their exact fluid
area and face apertures, the absorbing circle enters by its distance along the grid line
(Shortley-Weller). A mixed ``B^xz`` (not present in mean field) adds diagonal moves
(Kushner's stencil, monotone while ``|B^xz| <= min(B^xx, B^zz)``). In mass variables the
scheme is the generator ``Q`` of a continuous-time Markov chain (non-negative rates, rows
summing to minus the absorption rate), so the forward update ``dm/dzeta = Q^T m`` conserves
probability up to what is absorbed, and backward Euler ``(I - dzeta Q^T)`` is an M-matrix:
positive for any step. The mean fall solves the backward equation ``-Q T = 1`` (one sparse
solve; ``B^ab d_a d_b T = -1``, reflecting at contact, ``T = 0`` at separation), and the
backward Euler survival integrates to exactly that mean.

Public: :func:`cage_breaking` (-> ``xarray.Dataset``), :func:`relative_tensor`,
:func:`mean_field_tensor`, :func:`mean_fall_1d`, :func:`passage_simulation`
(Monte Carlo of the discrete model in :mod:`spotpde.pair._mc`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import xarray as xr
from scipy import integrate

from ..errors import NumericalError
from ..fields import _passage
from ..parameters import DIFFUSIVITIES, check_diffusivity, check_rule

#: Subsamples per cell side used for the cut cells' areas, centroids and apertures.
_SUB = 32

__all__ = ["cage_breaking", "relative_tensor", "mean_field_tensor", "mean_fall_1d",
           "DIFFUSIVITIES", "solve"]


# --------------------------------------------------------------------------------------
# The relative diffusion length tensor
# --------------------------------------------------------------------------------------
def _check_kernel_2d(kernel, allow_3d=False):
    dims = getattr(kernel, "dims", None)
    if dims != 2 and not (allow_3d and dims == 3):
        need = "a 2D or 3D" if allow_3d else "a 2D"
        raise ValueError(f"kernel must be {need} spotpde.kernels kernel, got {kernel!r}")


def mean_field_tensor(kernel, b, b_par=0.0, X=0.0, Z=0.0, *, b_p=None) -> dict:
    """Mean-field relative diffusion lengths ``B^ab = 2 b_p^ab (1 - C(X, Z))`` in d.

    Args:
        kernel: a 2D or 3D kernel (``spotpde.kernels``); ``C`` is
            ``kernel.correlation_vector`` (3D: at ``(X, 0, Z)``, ``X`` the horizontal
            distance; the kernels are isotropic horizontally).
        b, b_par: spot diffusion lengths (horizontal, vertical) in d, ``>= 0``.
        X, Z: separation components in d (broadcasting arrays).
        b_p: optional single-particle tensor ``{"xx", "xz", "zz"}`` in d replacing
            ``diag(b, b_par) V2/V1`` (a case's local ``D_p / |u_z|``).

    Returns:
        dict ``{"xx", "xz", "zz"}`` of arrays (the broadcast shape of X and Z).
    """
    _check_kernel_2d(kernel, allow_3d=True)
    if b_p is None:
        ratio = kernel.V2 / kernel.V1
        b_p = {"xx": b * ratio, "xz": 0.0, "zz": b_par * ratio}
    X, Z = np.broadcast_arrays(np.asarray(X, float), np.asarray(Z, float))
    offsets = (X, Z) if kernel.dims == 2 else (X, np.zeros_like(X), Z)
    one_minus_c = 1.0 - kernel.correlation_vector(*offsets)
    return {k: 2.0 * b_p[k] * one_minus_c for k in ("xx", "xz", "zz")}


def relative_tensor(kernel, b, rule=0.5, b_par=0.0, diffusivity="passage", X=0.0, Z=0.0,
                    *, b_p=None) -> dict:
    """Relative diffusion length tensor ``B^ab(X, Z)`` per unit fall, in d.

    ``diffusivity="mean-field"``: :func:`mean_field_tensor`. ``"passage"``:
    ``spotpde.fields._passage.length_tensor(kernel, b, b_par, rule, diffusivity="passage",
    separation=(X, Z))``. With ``b_p`` (local single-particle lengths; the local
    uniform-flow approximation) the tensor is the congruence ``S B S``,
    ``S = diag(sqrt(b_p^xx / b_p,uniform^xx), sqrt(b_p^zz / b_p,uniform^zz))``: ``B^xx``
    and ``B^zz`` scale by their ratios, the passage cross term ``B^xz`` (not zero off the
    axes, although ``b_p,uniform^xz = 0``) by their geometric mean, so ``B`` stays positive
    semi-definite and ``b_p = s b_p,uniform`` gives ``s B``; the local ``b_p^xz`` adds its
    mean-field form ``2 b_p^xz (1 - C)``. A component whose uniform diagonal value
    vanishes takes the mean-field form ``2 b_p^ab (1 - C)``.
    """
    check_diffusivity(diffusivity)
    if diffusivity == "mean-field":
        return mean_field_tensor(kernel, b, b_par, X, Z, b_p=b_p)
    _check_kernel_2d(kernel)
    X, Z = np.broadcast_arrays(np.asarray(X, float), np.asarray(Z, float))
    B = _passage.length_tensor(kernel, b, b_par, rule, diffusivity="passage",
                               separation=(X, Z))
    B = {k: np.broadcast_to(np.asarray(B.get(k, 0.0), float), X.shape) for k in ("xx", "xz", "zz")}
    if b_p is None:
        return B
    far = _passage.length_tensor(kernel, b, b_par, rule, diffusivity="passage")
    mf = mean_field_tensor(kernel, b, b_par, X, Z, b_p=b_p)
    ratio = {k: b_p[k] / float(far[k]) if float(far[k]) > 0 else None for k in ("xx", "zz")}
    cross = mf["xz"]
    if ratio["xx"] is not None and ratio["zz"] is not None:
        cross = cross + B["xz"] * math.sqrt(max(ratio["xx"], 0.0) * max(ratio["zz"], 0.0))
    return {"xx": mf["xx"] if ratio["xx"] is None else B["xx"] * ratio["xx"], "xz": cross,
            "zz": mf["zz"] if ratio["zz"] is None else B["zz"] * ratio["zz"]}


def mean_fall_1d(B, contact=1.0, separation=2.0) -> float:
    """Mean fall ``int_c^s (s - y) / B(y) dy`` of the 1D Ito problem started at contact.

    Solves ``B T'' = -1``, ``T'(c) = 0`` (reflecting, Ito), ``T(s) = 0``, at ``y = c``.

    Args:
        B: callable ``B(y)`` in d, positive on ``(c, s]``.
        contact, separation: ``c < s`` in d.
    """
    if not separation > contact:
        raise ValueError(f"separation must be > contact, got {separation} <= {contact}")
    val, _ = integrate.quad(lambda y: (separation - y) / B(y), contact, separation,
                            limit=200)
    return float(val)


# --------------------------------------------------------------------------------------
# Geometry: the annulus contact <= |r| < separation on a Cartesian grid
# --------------------------------------------------------------------------------------
@dataclass
class _Mesh:
    h: float
    x: np.ndarray          # cell-centre coordinates (1D)
    z: np.ndarray
    active: np.ndarray     # bool (nz, nx)
    area: np.ndarray       # fluid area of each cell (d^2), 0 if inactive
    cx: np.ndarray         # fluid centroid
    cz: np.ndarray
    ax: np.ndarray         # aperture (fluid length) of the face between (j, i) and (j, i+1), (nz, nx-1)
    az: np.ndarray         # aperture of the face between (j, i) and (j+1, i), (nz-1, nx)
    axisym: bool = False   # 3D: x is the horizontal distance R >= 0, measures carry 2 pi R


def _mesh(contact, separation, h, axisym=False) -> _Mesh:
    """Cells of side ``h`` centred at ``x = (i + 1/2) h`` and ``z = j h``.

    The z = 0 row is a row of centres (a pair side by side stays on it when ``B^zz = 0``)
    and ``x = contact`` is a face when ``contact / h`` is an integer. ``axisym``: 3D
    separations reduced to ``(R, Z)``, ``R = sqrt(X^2 + Y^2) >= 0``; cell measures are
    volumes ``int 2 pi R dR dZ`` and face measures areas (``2 pi R`` times the length).
    """
    c, s = contact, separation
    nx = int(math.ceil(s / h - 1e-9))
    x = (np.arange(0 if axisym else -nx, nx) + 0.5) * h
    nzh = int(math.ceil(s / h - 0.5 - 1e-9))
    z = np.arange(-nzh, nzh + 1) * h
    Xc, Zc = np.meshgrid(x, z)
    inside = Xc**2 + Zc**2 < s * s
    # cells touched by the core: subsample area, centroid and apertures
    near = (np.abs(np.hypot(Xc, Zc) - c) < h)
    ring = 2 * np.pi * Xc if axisym else 1.0
    area = np.where(Xc**2 + Zc**2 >= c * c, h * h * ring, 0.0)
    cx, cz = Xc.copy(), Zc.copy()
    u = (np.arange(_SUB) + 0.5) / _SUB - 0.5
    for j, i in zip(*np.nonzero(near)):
        px = x[i] + u[None, :] * h
        pz = z[j] + u[:, None] * h
        fluid = (px**2 + pz**2) >= c * c
        wgt = fluid * (2 * np.pi * px if axisym else 1.0)
        area[j, i] = wgt.mean() * h * h
        if wgt.sum() > 0:
            cx[j, i] = (px * wgt).sum() / wgt.sum()
            cz[j, i] = (pz * wgt).sum() / wgt.sum()
    active = inside & (area > 0)
    area = np.where(active, area, 0.0)
    # apertures: fluid fraction of each face segment (exact, a segment against a circle)
    xf = 0.5 * (x[:-1] + x[1:])                                  # vertical faces at x = xf
    ax = h * _segment_outside(xf[None, :], z[:, None], h, c, vertical=True)
    zf = 0.5 * (z[:-1] + z[1:])
    az = h * _segment_outside(x[None, :], zf[:, None], h, c, vertical=False)
    if axisym:
        ax = ax * 2 * np.pi * xf[None, :]
        az = _ring_outside(x[None, :], zf[:, None], h, c)
    return _Mesh(h, x, z, active, area, cx, cz, ax, az, axisym)


def _ring_outside(xc, zf, h, c):
    """Area of the annular face ``R in [xc - h/2, xc + h/2]`` at height ``zf`` with ``|r| >= c``."""
    xc, zf = np.broadcast_arrays(xc, zf)
    lo, hi = xc - h / 2, xc + h / 2
    half = np.sqrt(np.maximum(c * c - zf**2, 0.0))
    blo, bhi = np.maximum(lo, 0.0), np.minimum(hi, half)
    blocked = np.where((half > 0) & (bhi > blo), np.pi * (bhi**2 - blo**2), 0.0)
    return np.pi * (hi**2 - lo**2) - blocked


def _segment_outside(xf, zf, h, c, vertical):
    """Fraction of the face segment (centre ``(xf, zf)``, length h) with ``|r| >= c``."""
    xf, zf = np.broadcast_arrays(xf, zf)
    along, across = (zf, xf) if vertical else (xf, zf)
    half2 = c * c - across**2
    half = np.sqrt(np.maximum(half2, 0.0))
    lo, hi = along - h / 2, along + h / 2
    blocked = np.clip(np.minimum(hi, half) - np.maximum(lo, -half), 0.0, None)
    blocked = np.where(half2 > 0, blocked, 0.0)
    return 1.0 - blocked / h


def _generator(mesh: _Mesh, B: dict, separation: float, absorbing: bool = True):
    """Rates ``Q`` (active cells, row = from) and the absorption rate of each cell.

    Returns ``(Q, kill, index)``: ``Q`` a CSR matrix with non-negative off-diagonals and
    ``Q 1 = -kill``; ``index[j, i]`` the unknown number of cell ``(j, i)`` or -1.
    """
    h, s = mesh.h, separation
    act = mesh.active
    nz, nx = act.shape
    index = -np.ones(act.shape, dtype=np.int64)
    index[act] = np.arange(act.sum())
    n = int(act.sum())
    Bxx, Bxz, Bzz = (np.where(act, B[k], 0.0) for k in ("xx", "xz", "zz"))
    if (np.min(Bxx[act], initial=0) < 0 or np.min(Bzz[act], initial=0) < 0):
        raise ValueError("B must be positive semi-definite (B^xx, B^zz >= 0)")
    # Kushner split of a mixed term: diagonal rate |B^xz|/h^2, axis rates reduced by it
    mixed = np.abs(Bxz)
    rows, cols, vals = [], [], []
    kill = np.zeros(n)
    area = np.where(act, mesh.area, 1.0)

    # axis moves --------------------------------------------------------------------
    J, I = np.nonzero(act)
    src = index[J, I]
    for dj, di, coef in ((0, 1, Bxx), (0, -1, Bxx), (1, 0, Bzz), (-1, 0, Bzz)):
        cf = np.maximum(coef[J, I] - mixed[J, I], 0.0)
        j2, i2 = J + dj, I + di
        if di:
            fi = np.minimum(I, i2)
            ok = (i2 >= 0) & (i2 < nx)
            full = (2 * np.pi * np.maximum(mesh.x[I] + di * h / 2, 0.0) * h if mesh.axisym
                    else np.full(I.shape, h))
            ap = np.where(ok, mesh.ax[J, np.clip(fi, 0, nx - 2)], full)
        else:
            fj = np.minimum(J, j2)
            ok = (j2 >= 0) & (j2 < nz)
            full = 2 * np.pi * mesh.x[I] * h if mesh.axisym else np.full(I.shape, h)
            ap = np.where(ok, mesh.az[np.clip(fj, 0, nz - 2), I], full)
        j2c, i2c = np.clip(j2, 0, nz - 1), np.clip(i2, 0, nx - 1)
        tgt = np.where(ok, index[j2c, i2c], -1)
        rate_in = cf * ap / (h * area[J, I])
        inner = tgt >= 0
        rows.append(src[inner]); cols.append(tgt[inner]); vals.append(rate_in[inner])
        # neighbour outside the cage (not the core): absorbed at the circle's distance
        X0, Z0 = mesh.x[I], mesh.z[J]
        out = ~inner
        xo = X0 + di * h
        zo = Z0 + dj * h
        beyond = out & (xo**2 + zo**2 >= s * s)
        if absorbing and beyond.any():
            # distance from the centre to |r| = s along the move
            along = X0 if di else Z0
            perp = Z0 if di else X0
            sign = di if di else dj
            root = np.sqrt(np.maximum(s * s - perp**2, 0.0))
            dist = np.where(sign > 0, root - along, along + root)
            dist = np.clip(dist, 1e-3 * h, h)
            np.add.at(kill, src[beyond], (cf * full / (dist * area[J, I]))[beyond])
    # diagonal moves for B^xz -----------------------------------------------------------
    if np.any(mixed[act] > 0):
        for dj, di in ((1, 1), (-1, -1), (1, -1), (-1, 1)):
            sgn = dj * di
            cf = np.where(sgn * Bxz[J, I] > 0, mixed[J, I], 0.0)
            rate = cf / area[J, I]
            j2, i2 = J + dj, I + di
            ok = (j2 >= 0) & (j2 < nz) & (i2 >= 0) & (i2 < nx)
            tgt = np.where(ok, index[np.clip(j2, 0, nz - 1), np.clip(i2, 0, nx - 1)], -1)
            inner = (tgt >= 0) & (rate > 0)
            rows.append(src[inner]); cols.append(tgt[inner]); vals.append(rate[inner])
            xo, zo = mesh.x[I] + di * h, mesh.z[J] + dj * h
            beyond = (tgt < 0) & (xo**2 + zo**2 >= s * s) & (rate > 0)
            if absorbing:
                np.add.at(kill, src[beyond], rate[beyond])
    rows, cols, vals = (np.concatenate(a) for a in (rows, cols, vals))
    off = sp.csr_matrix((vals, (rows, cols)), shape=(n, n))
    out_rate = np.asarray(off.sum(axis=1)).ravel() + kill
    Q = (off - sp.diags(out_rate)).tocsr()
    return Q, kill, index


# --------------------------------------------------------------------------------------
# Solver
# --------------------------------------------------------------------------------------
def _start_weights(mesh: _Mesh, index, start):
    """Bilinear weights of the start point on the surrounding active cells (>= 0, sum 1)."""
    X0, Z0 = start
    h = mesh.h
    fi = (X0 - mesh.x[0]) / h
    fj = (Z0 - mesh.z[0]) / h
    i0, j0 = int(math.floor(fi)), int(math.floor(fj))
    tx, tz = fi - i0, fj - j0
    w = {}
    for dj, wz in ((0, 1 - tz), (1, tz)):
        for di, wx in ((0, 1 - tx), (1, tx)):
            j, i = j0 + dj, i0 + di
            if 0 <= j < index.shape[0] and 0 <= i < index.shape[1] and index[j, i] >= 0:
                if wz * wx > 0:
                    w[int(index[j, i])] = w.get(int(index[j, i]), 0.0) + wz * wx
    if not w:  # the start cell itself is cut away: the nearest active cell
        act = index >= 0
        d2 = (mesh.cx - X0) ** 2 + (mesh.cz - Z0) ** 2
        d2 = np.where(act, d2, np.inf)
        j, i = np.unravel_index(np.argmin(d2), d2.shape)
        w[int(index[j, i])] = 1.0
    total = sum(w.values())
    p0 = np.zeros(int((index >= 0).sum()))
    for k, v in w.items():
        p0[k] = v / total
    return p0


def _setup(tensor, contact, separation, start, spacing, axisym):
    """Mesh, generator ``Q``, absorption rates, cell index, start weights ``p0``, the start
    point and the fraction of cells whose mixed term was clipped (see :func:`solve`)."""
    c, s = float(contact), float(separation)
    ring = isinstance(start, str)
    start = ((c, 0.0) if start is None or ring else (float(start[0]), float(start[1])))
    h = float(spacing) if spacing is not None else c / 16
    mesh = _mesh(c, s, h, axisym=axisym)
    act = mesh.active
    B = tensor(np.where(act, mesh.cx, 0.0), np.where(act, mesh.cz, 0.0))
    B = {k: np.broadcast_to(np.asarray(B[k], float), act.shape) for k in ("xx", "xz", "zz")}
    clipped = float(np.mean((np.abs(B["xz"]) > np.minimum(B["xx"], B["zz"]) + 1e-300)[act]))
    if axisym and np.any(B["xz"][act] != 0):
        raise ValueError("axisym needs B^xz = 0 (a horizontally isotropic, diagonal tensor)")
    Q, kill, index = _generator(mesh, B, s)
    if ring:
        # directions uniform on the circle (3D: on the sphere, weight R = c cos(angle))
        ang = (np.arange(256) + 0.5) / 256 * (np.pi if axisym else 2 * np.pi) - (np.pi / 2 if axisym else 0)
        wts = np.cos(ang) if axisym else np.ones_like(ang)
        r0 = c * (1 + 1e-9)
        p0 = sum(w * _start_weights(mesh, index, (r0 * np.cos(a), r0 * np.sin(a)))
                 for a, w in zip(ang, wts)) / wts.sum()
    else:
        p0 = _start_weights(mesh, index, start)
    return mesh, Q, kill, index, p0, start, clipped


def _mean_fall(Q, p0) -> float:
    """Mean fall before absorption: ``p0 . T`` with ``-Q T = 1`` (the backward equation),
    one sparse solve."""
    T = spla.splu((-Q).tocsc()).solve(np.ones(Q.shape[0]))
    mean = float(p0 @ T)
    if not np.isfinite(mean) or mean <= 0:
        raise NumericalError("the pair never leaves the cage: B vanishes on the way out")
    return mean


def mean_fall(tensor, contact=1.0, separation=2.0, start=None, *, spacing=None,
              axisym=False) -> float:
    """Mean cage-breaking fall (d) of :func:`solve`'s problem by one sparse solve, without
    the survival curve (same arguments)."""
    mesh, Q, kill, index, p0, start, clipped = _setup(tensor, contact, separation, start,
                                                      spacing, axisym)
    return _mean_fall(Q, p0)


def solve(tensor, contact=1.0, separation=2.0, start=None, *, spacing=None, frames=8,
          fall_end=None, steps_per_mean=200, absorbed=0.99, axisym=False):
    """Solve the relative Fokker-Planck equation for a given tensor field.

    Args:
        tensor: callable ``tensor(X, Z) -> {"xx", "xz", "zz"}`` (arrays in d).
        contact, separation: radii of the reflecting core and the absorbing cage, in d.
        start: initial separation ``(X0, Z0)`` in d (default ``(contact, 0)``), or
            ``"contact"``: uniform over the directions of the contact circle (3D: sphere),
            the neighbours of a grain in an isotropic packing.
        spacing: grid spacing in d (default ``contact / 16``).
        frames: number of stored frames of ``P``.
        fall_end: last fall in d (default: when ``absorbed`` of the probability is gone).
        steps_per_mean: backward Euler steps per mean fall.
        absorbed: stop when ``survival <= 1 - absorbed`` (if ``fall_end`` is None).
        axisym: 3D separations with a tensor that is isotropic horizontally and has no
            ``B^xz``: ``X`` is the horizontal distance ``R >= 0`` (cylindrical
            finite volumes; docs/pair.md).

    Returns:
        dict with ``fall``, ``survival``, ``msd``, ``mean_fall``, ``median_fall``,
        ``frames_fall``, ``P`` (frames, z, x; NaN outside the annulus), ``x``, ``z``,
        ``mass_error`` (max |survival + absorbed - 1|), ``min_P``, ``spacing``, ``mixed_clipped``.
    """
    mesh, Q, kill, index, p0, start, clipped = _setup(tensor, contact, separation, start,
                                                      spacing, axisym)
    h, act, n = mesh.h, mesh.active, Q.shape[0]
    mean = _mean_fall(Q, p0)
    dt = (mean if fall_end is None else min(mean, float(fall_end))) / steps_per_mean
    A = (sp.identity(n, format="csc") - dt * Q.T.tocsc()).tocsc()
    lu = spla.splu(A)
    r2 = (mesh.cx**2 + mesh.cz**2)[act]
    m = p0.copy()
    surv, msd, absorbed_mass, falls = [1.0], [float(p0 @ r2)], [0.0], [0.0]
    rate = [float(kill @ p0)]
    max_steps = (int(math.ceil(fall_end / dt)) if fall_end is not None
                 else 200 * steps_per_mean)
    snaps = [m.copy()]
    step = 0
    min_m = float(m.min())
    while step < max_steps:
        m_new = lu.solve(m)
        rate.append(float(kill @ m_new))
        absorbed_mass.append(absorbed_mass[-1] + dt * rate[-1])
        m = m_new
        step += 1
        S = float(m.sum())
        falls.append(step * dt)
        surv.append(S)
        msd.append(float(m @ r2) / S if S > 0 else np.nan)
        snaps.append(m.copy()) if step % max(1, steps_per_mean // 20) == 0 else None
        min_m = min(min_m, float(m.min()))
        if fall_end is None and S <= 1.0 - absorbed:
            break
    falls, surv, msd = np.array(falls), np.array(surv), np.array(msd)
    median = float(np.interp(0.5, surv[::-1], falls[::-1])) if surv[-1] <= 0.5 else np.nan
    # frames: evenly spaced in fall, from the stored snapshots
    stride = max(1, steps_per_mean // 20)
    snap_falls = np.arange(len(snaps)) * stride * dt
    want = np.linspace(0.0, falls[-1], max(int(frames), 1))
    pick = np.unique(np.searchsorted(snap_falls, want).clip(0, len(snaps) - 1))
    P = np.full((len(pick),) + act.shape, np.nan)
    for f, k in enumerate(pick):
        P[f][act] = snaps[k] / mesh.area[act]
    mass_error = float(np.max(np.abs(surv + np.array(absorbed_mass) - 1.0)))
    return {"fall": falls, "survival": surv, "msd": msd, "mean_fall": mean,
            "breaking": np.array(rate),
            "median_fall": median, "frames_fall": snap_falls[pick], "P": P,
            "x": mesh.x, "z": mesh.z, "mass_error": mass_error, "min_P": min_m,
            "spacing": h, "mixed_clipped": clipped, "start": start,
            "mean_from_survival": float(dt * surv[1:].sum() + 0.0)}


def _check_args(b, b_par, rule, diffusivity, contact, separation, start):
    for name, v in (("b", b), ("b_par", b_par), ("contact", contact),
                    ("separation", separation)):
        if not isinstance(v, (int, float, np.floating, np.integer)) or isinstance(v, bool) \
                or not math.isfinite(float(v)):
            raise TypeError(f"{name} must be a finite number, got {v!r}")
    if not b > 0:
        raise ValueError(f"b must be > 0 (without spot diffusion no cage breaks), got {b}")
    if b_par < 0:
        raise ValueError(f"b_par must be >= 0, got {b_par}")
    check_rule(rule)
    check_diffusivity(diffusivity)
    if not contact > 0:
        raise ValueError(f"contact must be > 0, got {contact}")
    if not separation > contact:
        raise ValueError(f"separation must be > contact, got separation={separation}, contact={contact}")
    if start is not None:
        if isinstance(start, str):
            if start != "contact":
                raise ValueError(f'start must be (X, Z) or "contact", got {start!r}')
            return
        if len(start) != 2:
            raise ValueError(f"start must be a separation (X, Z) in d, got {start!r}")
        r = math.hypot(float(start[0]), float(start[1]))
        if r < contact:
            raise ValueError(f"start is inside the core (|start| = {r:g} < contact = {contact})")
        if r >= separation:
            raise ValueError(f"start is outside the cage (|start| = {r:g} >= separation = {separation})")


def cage_breaking(kernel, b, rule=0.5, b_par=0.0, diffusivity="passage", contact=1.0,
                  separation=2.0, start=None, *, spacing=None, frames=8, fall_end=None,
                  steps_per_mean=200, b_p=None):
    """Cage breaking of two neighbours: survival, mean and median fall, ``P`` frames.

    Solves ``dP/dzeta = d_a d_b (B^ab P)`` in ``contact <= |r| < separation`` (module
    docstring) for a pair starting at separation ``start`` (default ``(contact, 0)``:
    neighbours side by side, touching).

    Args:
        kernel: 2D kernel (``spotpde.kernels``).
        b, b_par: spot diffusion lengths in d (horizontal ``> 0``, vertical ``>= 0``).
        rule: lam, in [0, 1] (used by ``"passage"``; mean field does not depend on it).
        diffusivity: ``"passage"`` (the discrete model's pair diffusivity) or ``"mean-field"``.
        contact: hard-core diameter in d (reflecting, zero Ito flux).
        separation: separation at which the cage counts as broken, in d (absorbing).
        start: initial separation ``(X0, Z0)`` in d, ``contact <= |start| < separation``
            (3D: ``X0`` the horizontal distance), or ``"contact"``: uniform over the
            directions at contact (the average over a grain's neighbours).
        spacing: grid spacing in d (default ``contact/16``).
        frames: number of ``P`` frames stored.
        fall_end: last fall in d (default: until 99 % of the pairs have separated).
        steps_per_mean: backward Euler steps per mean fall (time step = mean/steps).
        b_p: optional local single-particle lengths ``{"xx","xz","zz"}`` in d (a case's
            ``D_p/|u_z|`` at a point) replacing the uniform-flow ``diag(b, b_par) V2/V1``.

    Returns:
        ``xarray.Dataset``: ``survival(fall)``, ``breaking(fall)`` (density of the
        cage-breaking fall, ``-dS/dfall``), ``msd(fall)`` (mean squared separation of
        the pairs still caged), ``P(frame, Z, X)``, ``B_xx``, ``B_xz``, ``B_zz`` (Z, X);
        attributes ``mean_fall``, ``median_fall`` (d) and every input.
    """
    _check_args(b, b_par, rule, diffusivity, contact, separation, start)
    _check_kernel_2d(kernel, allow_3d=True)
    axisym = kernel.dims == 3
    if axisym and diffusivity != "mean-field":
        raise ValueError('diffusivity must be "mean-field" for a 3D kernel (the passage '
                         "tensor is 2D only), got " + repr(diffusivity))
    if axisym and start is not None and not isinstance(start, str) and start[0] < 0:
        raise ValueError("start[0] is the horizontal distance in 3D and must be >= 0, "
                         f"got {start[0]}")

    def tensor(X, Z):
        return relative_tensor(kernel, b, rule, b_par, diffusivity, X, Z, b_p=b_p)

    res = solve(tensor, contact, separation, start, spacing=spacing, frames=frames,
                fall_end=fall_end, steps_per_mean=steps_per_mean, axisym=axisym)
    Xg, Zg = np.meshgrid(res["x"], res["z"])
    Bg = tensor(Xg, Zg)
    outside = (Xg**2 + Zg**2 < contact**2) | (Xg**2 + Zg**2 >= separation**2)
    attrs = {
        "mean_fall": res["mean_fall"], "median_fall": res["median_fall"],
        "contact": float(contact), "separation": float(separation),
        "start_x": res["start"][0], "start_z": res["start"][1],
        "start": start if isinstance(start, str) else "point",
        "b": float(b), "b_par": float(b_par), "rule": float(rule),
        "diffusivity": diffusivity, "kernel": repr(kernel), "spacing": res["spacing"],
        "mass_error": res["mass_error"], "min_P": res["min_P"],
        "mixed_clipped_fraction": res["mixed_clipped"], "dims": int(kernel.dims),
        "equation": "dP/dzeta = d_a d_b (B^ab P) (Ito); zero Ito flux at contact, "
                    "absorbing at separation",
    }
    return _dataset(res, Bg, outside, attrs, dims=int(kernel.dims))


def _dataset(res, Bg, outside, attrs, prefix="", dims=2):

    L = "1"  # lengths are numbers of particle diameters (no UDUNITS 'd', a day)
    p = prefix
    fall, frame, X, Z = (f"{p}fall", f"{p}frame", f"{p}X", f"{p}Z")
    coords = {
        fall: (fall, res["fall"], {"units": L, "long_name": "fall distance of the pair (in d)"}),
        frame: (frame, res["frames_fall"], {"units": L, "long_name": "fall distance of the P frames (in d)"}),
        X: (X, res["x"], {"units": L, "long_name": "horizontal separation X (in d)" if dims == 2
                          else "horizontal distance sqrt(X^2 + Y^2) of the pair (in d)"}),
        Z: (Z, res["z"], {"units": L, "long_name": "vertical separation Z (in d)"}),
    }
    data = {
        f"{p}survival": ((fall,), res["survival"],
                         {"units": "1", "long_name": "probability the pair is still caged (|r| < separation)"}),
        f"{p}breaking": ((fall,), res["breaking"],
                         {"units": "1", "long_name": "probability density of the cage-breaking "
                                                     "fall, -dS/dfall (per d)"}),
        f"{p}msd": ((fall,), res["msd"],
                    {"units": "1", "long_name": "mean squared separation of caged pairs (in d^2)"}),
        f"{p}P": ((frame, Z, X), res["P"],
                  {"units": "1", "long_name": f"density of the separation (per d^{dims}); "
                                              "NaN outside the annulus"}),
    }
    for k in ("xx", "xz", "zz"):
        data[f"{p}B_{k}"] = ((Z, X), np.where(outside, np.nan, Bg[k]),
                             {"units": L, "long_name": f"relative diffusion length B^{k} per unit fall (in d)"})
    ds = xr.Dataset(data, coords=coords)
    ds.attrs.update({f"{p}{k}": v for k, v in attrs.items()} if p else attrs)
    return ds

