"""Diffusion operator ``sum_ij d_i d_j (D^ij P)`` (Ito form, full tensor), private.

Positive, conservative splitting of the tensor (our derivation, docs/tracer.md):
with ``c = D_xz`` and ``c+ = max(c, 0)``, ``c- = max(-c, 0)``, the identity

    D_xx d_xx + 2 D_xz d_xz + D_zz d_zz
      = d_xx (D_xx - |c|) + d_zz (D_zz - |c|) + 2 d_ee c+ + 2 d_ff c-      (acting on P)

holds, where ``e = (x + z)/sqrt 2`` and ``f = (x - z)/sqrt 2`` are the grid diagonals
(``2 d_ee = d_xx + 2 d_xz + d_zz``). Each term is discretised as a pairwise exchange
between a cell ``a`` and its neighbour ``b = a + o`` (offset ``o`` an axis or a
diagonal), with coefficient field ``A >= 0``:

    E_ab = (A_a P_a - A_b P_b) / h**2 ,      dP_a/dt -= E_ab,   dP_b/dt += E_ab .

For an axis this is the 3-point second difference of ``A P`` (second order); for a
diagonal, ``(f_{++} - 2 f + f_{--}) / h**2 = 2 d_ee f + O(h**2)``. 3D uses the same
splitting in each coordinate plane (axial coefficient ``D_xx - |D_xy| - |D_xz|`` etc.).

Properties: exactly conservative (pairwise exchanges; none across the boundary, so the
diffusive flux through walls, the floor and the top is zero); the off-diagonal
coefficients are ``A / h**2 >= 0`` whenever the tensor is diagonally dominant
(``D_xx >= |D_xy| + |D_xz|`` etc.), which makes forward Euler positive for
``dt * 2 (sum_i D_ii - sum_{i<j} |D_ij|) / h**2 <= 1`` and backward Euler positive for
any ``dt`` (``I - dt L`` is then an M-matrix with unit column sums). Diagonal dominance
holds for every diagonal tensor (the spot model's ``D_p``) and for any anisotropy whose
principal axes lie along the grid axes or diagonals; for other tensors positivity is not
guaranteed by this 9-point stencil (none exists in general) and the solver warns.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

#: Offsets (array order) and the tensor components that feed them.
_PLANES_2D = (("x", "z"),)
_PLANES_3D = (("x", "y"), ("x", "z"), ("y", "z"))


def _axis_index(name: str, dims: int) -> int:
    return {"z": 0, "x": dims - 1, "y": 1}[name]


def _tensor(fields, a, b):
    key = "D_" + "".join(sorted((a, b), key="xyz".index))
    return fields[key]


def split_tensor(fields: dict[str, np.ndarray], dims: int):
    """Split ``D_p`` into non-negative exchange coefficients.

    Args:
        fields: cell-centred tensor components (``D_xx``, ``D_xz``, ``D_zz``; 3D also
            ``D_yy``, ``D_xy``, ``D_yz``) in d**2 per unit time.
        dims: 2 or 3.

    Returns:
        ``(terms, n_bad)``: ``terms`` a list of ``(offset, A)`` with ``offset`` a tuple
        in array order and ``A`` a cell array (axial coefficients may be negative where
        the tensor is not diagonally dominant); ``n_bad`` the number of such cells.
    """
    names = ("x", "z") if dims == 2 else ("x", "y", "z")
    planes = _PLANES_2D if dims == 2 else _PLANES_3D
    axial = {n: np.array(fields[f"D_{n}{n}"], dtype=float) for n in names}
    terms = []
    for a, b in planes:
        c = np.asarray(_tensor(fields, a, b), dtype=float)
        if not np.any(c):
            continue
        axial[a] = axial[a] - np.abs(c)
        axial[b] = axial[b] - np.abs(c)
        for sign, coef in ((+1, np.maximum(c, 0.0)), (-1, np.maximum(-c, 0.0))):
            if not np.any(coef):
                continue
            off = [0] * dims
            off[_axis_index(a, dims)] = 1
            off[_axis_index(b, dims)] = sign
            # canonical orientation: first non-zero component positive
            if next(o for o in off if o != 0) < 0:
                off = [-o for o in off]
            terms.append((tuple(off), coef))
    bad = np.zeros(np.shape(axial[names[0]]), dtype=bool)
    for n in names:
        off = [0] * dims
        off[_axis_index(n, dims)] = 1
        terms.insert(0, (tuple(off), axial[n]))
        bad |= axial[n] < -1e-12 * max(1.0, float(np.max(np.abs(fields[f"D_{n}{n}"]))))
    return terms, int(np.count_nonzero(bad))


def self_rate(terms, shape, h: float) -> np.ndarray:
    """Per-cell loss rate ``2 sum_o A_o / h**2`` (1/time) of the explicit operator.

    This equals ``2 (sum_i D_ii - sum_{i<j} |D_ij|) / h**2``; forward Euler of the
    diffusion part keeps ``P >= 0`` when ``dt`` times it is at most 1.
    """
    r = np.zeros(shape)
    for _, A in terms:
        r += A
    return 2.0 * r / h**2


def _pairs(shape, off):
    """Flat indices ``a, b = a + off`` of all in-domain pairs."""
    idx = np.arange(int(np.prod(shape))).reshape(shape)
    sa = tuple(slice(max(0, -o), n - max(0, o)) for o, n in zip(off, shape))
    sb = tuple(slice(max(0, o), n - max(0, -o)) for o, n in zip(off, shape))
    return idx[sa].ravel(), idx[sb].ravel(), sa


def operator(terms, shape, h: float) -> sp.csr_matrix:
    """Sparse matrix ``L`` with ``(L P)_a = sum_b E_ba - E_ab`` (the diffusion operator).

    Column sums are zero (conservation); off-diagonals are ``A_b / h**2``.
    """
    n = int(np.prod(shape))
    rows, cols, vals = [], [], []
    diag = np.zeros(n)
    for off, A in terms:
        a, b, _ = _pairs(shape, off)
        Af = A.ravel() / h**2
        # E_ab = Af[a] P_a - Af[b] P_b ; dP_a -= E_ab ; dP_b += E_ab
        np.subtract.at(diag, a, Af[a])
        np.subtract.at(diag, b, Af[b])
        rows += [a, b]
        cols += [b, a]
        vals += [Af[b], Af[a]]
    rows.append(np.arange(n))
    cols.append(np.arange(n))
    vals.append(diag)
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(n, n))


def vertical_flux_operator(terms, shape, h: float, cross_only: bool = False) -> sp.csr_matrix:
    """Sparse map from ``P`` to the upward diffusive flux through each horizontal face.

    Face ``k`` is the bottom face of cell row ``k`` (``k = 0`` the floor, ``k = nz`` the
    top); the flux is per unit horizontal length: an exchange ``E_ab`` between ``a`` in
    row ``k-1`` and ``b`` in row ``k`` carries ``E_ab h`` upward through face ``k``; a
    diagonal exchange is split half to the column of ``a`` and half to that of ``b``
    (the diagonal segment crosses the face at the columns' common edge). Floor and top
    rows are zero (no diffusive flux through them).

    Args:
        terms: output of :func:`split_tensor`.
        shape: grid shape.
        h: spacing.
        cross_only: only the diagonal (cross-term) exchanges.

    Returns:
        CSR matrix of shape ``((nz+1) * n_h, n)``, ``n_h`` cells per row.
    """
    nz = shape[0]
    nh = int(np.prod(shape[1:]))
    n = nz * nh
    rows, cols, vals = [], [], []
    for off, A in terms:
        if off[0] != 1 or (cross_only and not any(off[1:])):
            continue
        a, b, _ = _pairs(shape, off)
        Af = A.ravel() / h
        face_row = a // nh + 1
        diagonal = any(off[1:])
        for col_cell, w in (((a, 0.5), (b, 0.5)) if diagonal else ((a, 1.0),)):
            r = face_row * nh + col_cell % nh
            # upward flux w * E_ab * h = w * (Af[a] P_a - Af[b] P_b)
            rows += [r, r]
            cols += [a, b]
            vals += [w * Af[a], -w * Af[b]]
    if not rows:
        return sp.csr_matrix(((nz + 1) * nh, n))
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=((nz + 1) * nh, n))
