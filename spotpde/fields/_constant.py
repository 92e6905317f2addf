"""Particle fields for constant coefficients from one transform of ``rho_s`` per stencil.

With constant ``v_s`` and ``D_s`` every drift source of ``coefficients.particle_fields`` is
a constant times ``rho_s`` or one of its grid derivatives, and the discrete convolution
commutes with the central difference on the zero-extended field, so the whole grid is
transformed once per kernel stencil; what the one-sided differences at the boundaries
change is a few planes, convolved directly. Private: ``coefficients.particle_fields``
(truncated walls) and ``_walls.renormalised_constant_fields`` (renormalised walls of a
rectangular silo) call :func:`constant_fields`.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import scipy.signal

from ..grid import Grid

__all__ = ["constant_fields", "SpotFluxTensor"]


class SpotFluxTensor(Mapping):
    """``{"D_xx": rho_s D_s^xx or None, ...}`` for a constant ``D_s``, computed on access.

    The wall layer reads only its wall values, and only for rules other than 1/2, so the
    whole-grid products are formed when (and each time) a component is looked up.
    """

    def __init__(self, rho_s: np.ndarray, D_s: Mapping):
        self.rho_s, self.D_s = rho_s, D_s

    def __getitem__(self, key):
        from .coefficients import _is_zero

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
    from .coefficients import _axis

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
                     conv, D_source: Mapping | None = None) -> dict[str, np.ndarray]:
    """``u_p`` and ``D_p`` for constant ``v_s`` and ``D_s`` from one convolution per stencil.

    With constant coefficients ``w * div(D_s rho_s) = D_s^ab w * d_b rho_s``, and the
    discrete convolution commutes with the central difference on the zero-extended field:
    ``w * grad(rho_s) = delta(w * rho_s~) - w * c``, where ``c`` lives on the boundary and
    ghost planes only (:func:`_boundary_planes`). So ``w * rho_s~`` on the grid padded by
    one cell gives ``u_z``, every ``w * d_b rho_s`` and (``w**2`` proportional to ``w``, or one
    more transform) ``D_p``; the plane terms are cheap 1D/2D convolutions. Identical to
    the general path to round-off. ``D_source`` (default ``D_s``): the constant tensor
    ``T`` of ``D_p = w^2 * (rho_s T)`` (the passage diffusivity's ``v_s b_eff``).
    """
    from .coefficients import _COMPONENTS, _axis, _is_zero, _pair

    comps = _COMPONENTS[grid.dims]
    h = grid.spacing
    hd = h**grid.dims
    rho_p = np.pad(rho_s, 1)
    inner = tuple(_inner_all(grid.dims))
    D_src = D_s if D_source is None else D_source
    need_D = any(not _is_zero(d) for d in D_src.values())
    # the transforms themselves (unscaled: h**dims and the constants are applied once, on
    # the grid's interior); w**2 = c w (uniform kernel) reuses the one transform
    from .convolution import convolve

    c1 = convolve(rho_p, conv.stencils[1], mode="linear")
    p2, c2 = conv.use[2]
    c2_array = None
    if need_D:
        c2_array = c1 if p2 == 1 else convolve(rho_p, conv.stencils[2], mode="linear")
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
                    w_grad *= 2.0 * lam * float(d)
                    fields[f"u_{a}"] = w_grad
                else:
                    accumulate(f"u_{a}", (2.0 * lam * float(d)) * w_grad)
    for key in fields:
        if fields[key] is None:
            fields[key] = np.zeros(grid.shape)
    for key, d in D_src.items():
        fields[key] = ((float(d) * c2 * hd) * c2_array[inner] if not _is_zero(d)
                       else np.zeros(grid.shape))
    return fields


