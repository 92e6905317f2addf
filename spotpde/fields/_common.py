"""Helpers every particle-field module shares (private; the bottom of ``fields``).

Argument checks, the spot diffusivity tensor ``D_s`` in the grid's components, the
divergence (asked of ``grid.geometry``), and the batched convolutions ``w**power *
source`` of :class:`_Convolutions`. ``coefficients`` and its private modules
(``_walls``, ``_constant``, ``_passage``, ``_pairs``, ``_wall_layer``, ``_hopper``,
``_axisymmetric``) import from here; this module imports none of them, so the package's
imports run one way. Units as in ``coefficients``: lengths in d, ``D`` in d**2 per unit
time.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from . import convolution
from ..geometry import derivative
from ..grid import Grid
from ..parameters import Spots, check_rule

_COMPONENTS = {2: ("x", "z"), 3: ("x", "y", "z")}
#: The largest negatives of ``D_p``'s diagonal taken for round-off, relative to its
#: maximum, by transform precision (single: 40 times the measured error, 2.5e-7).
ROUNDOFF = {"double": 1e-9, "single": 1e-5}
#: Sub-samples per cell and axis for kernel quadratures at arbitrary points.
_SUBSAMPLE = 6


# -- small helpers -----------------------------------------------------------------------

def _axis(grid: Grid, comp: str) -> int:
    """Array axis of a coordinate: z is axis 0, x the last, y (3D) axis 1."""
    return {"z": 0, "y": 1, "x": grid.dims - 1}[comp]


def _pair(a: str, b: str) -> str:
    """Canonical tensor key of components ``a, b`` (``D_xz``, never ``D_zx``)."""
    order = "xyz"
    a, b = sorted((a, b), key=order.index)
    return f"D_{a}{b}"


def _is_zero(value) -> bool:
    return value is None or (np.ndim(value) == 0 and float(value) == 0.0)


def _check_coefficient(grid: Grid, name: str, value) -> None:
    if np.ndim(value) == 0:
        if not np.isfinite(float(value)):
            raise ValueError(f"{name}: must be finite, got {value!r}")
        return
    if np.shape(value) != grid.shape:
        raise ValueError(f"{name}: array shape {np.shape(value)} does not match the grid "
                         f"shape {grid.shape} (array order {grid.axes})")
    if not np.all(np.isfinite(value)):
        raise ValueError(f"{name}: contains NaN or infinite values")


_check_rule = check_rule   # the one statement of the rule's range (spotpde.parameters)


def _check_inputs(grid: Grid, rho_s: np.ndarray, kernel) -> np.ndarray:
    rho_s = np.asarray(rho_s, dtype=float)
    if rho_s.shape != grid.shape:
        raise ValueError(f"rho_s: array shape {rho_s.shape} does not match the grid shape "
                         f"{grid.shape} (array order {grid.axes})")
    # a finite sum means every value is finite (one pass); an overflowing sum of finite
    # values only sends the check to the element test
    if not (np.isfinite(np.sum(rho_s)) or np.all(np.isfinite(rho_s))):
        raise ValueError("rho_s: contains NaN or infinite values")
    if getattr(kernel, "dims", grid.dims) != grid.dims:
        raise ValueError(f"kernel: built for dims={kernel.dims} but the grid has dims={grid.dims}")
    return rho_s


def spot_diffusivity(grid: Grid, spots: Spots, tensor: Mapping | None = None) -> dict:
    """The spot diffusivity tensor ``D_s`` by component, in d**2 per unit time.

    Args:
        grid: the grid (its geometry's ``diffusivity_keys`` are the components).
        spots: spot parameters; ``D_s = diag(D_perp, [D_perp,] D_par)`` with
            ``D_perp = b v_s`` and ``D_par = b_par v_s`` (docs/conventions.md; eq. Ds of the paper).
        tensor: optional full tensor overriding ``spots``: a mapping from keys
            ``D_xx``, ``D_xz``, ... (any subset; missing components are zero) to floats or
            grid arrays.

    Returns:
        ``{"D_xx": ..., "D_xz": ..., ...}``: floats or grid arrays (``DIFFUSIVITY_KEYS``;
        axisymmetric grids: ``D_rr`` (= ``D_theta_theta``), ``D_rz``, ``D_zz``).
    """
    keys = grid.geometry.diffusivity_keys
    if tensor is not None:
        unknown = sorted(set(tensor) - set(keys))
        if unknown:
            raise ValueError(f"spot_diffusivity_tensor: unknown components {unknown}; valid on "
                             f"this {grid.geometry.kind} grid: {list(keys)}"
                             + (" (D_theta_theta = D_rr)" if "D_rr" in keys else ""))
        out = {k: tensor.get(k, 0.0) for k in keys}
    else:   # diagonal: D_perp horizontally, D_par vertically
        out = {k: (spots.D_par if k == "D_zz" else spots.D_perp) if k[2] == k[3] else 0.0
               for k in keys}
    for k, v in out.items():
        _check_coefficient(grid, f"spot diffusivity {k}", v)
    return out


def _gradient(grid: Grid, f: np.ndarray, comp: str) -> np.ndarray:
    """Second-order derivative along ``comp``: central inside, one-sided at the ends."""
    return grid.geometry.gradient(f, comp)


def divergence(grid: Grid, tensor: Mapping[str, np.ndarray]) -> dict:
    """Row divergence ``(div T)^a = sum_b d_b T^ab`` of a symmetric tensor field.

    The grid's geometry differentiates: second order (central inside, one-sided at the
    boundaries and, on a staircase, next to inactive cells; cylindrical components on an
    axisymmetric grid). Missing or scalar-zero components are skipped.

    Args:
        grid: the grid.
        tensor: ``{"D_xx": array, ...}`` (keys of ``grid.diffusivity_keys``).

    Returns:
        ``{"x": array, ..., "z": array}`` (``"r"``, ``"z"`` when axisymmetric) in the
        tensor's units per d.
    """
    return grid.geometry.divergence(tensor)


def _as_point(grid: Grid, r, name: str) -> np.ndarray:
    """``r`` as a point of ``grid.dims`` coordinates (in d); ValueError naming ``name``."""
    p = np.asarray(r, dtype=float).reshape(-1)
    if p.shape != (grid.dims,):
        raise ValueError(f"{name}: a point needs {grid.dims} coordinates "
                         f"({', '.join(_COMPONENTS[grid.dims])}), got {r!r}")
    return p


def _box_derivative(f: np.ndarray, h: float, box, axis: int) -> np.ndarray:
    """``geometry.derivative(f, h, axis)[box]`` from the box widened by one cell along ``axis``."""
    sl = box[axis]
    lo, hi = max(0, sl.start - 1), min(f.shape[axis], sl.stop + 1)
    wide = list(box)
    wide[axis] = slice(lo, hi)
    crop = [slice(None)] * f.ndim
    crop[axis] = slice(sl.start - lo, sl.stop - lo)
    if hi - lo < 3 <= f.shape[axis]:             # too thin for the same formulas: whole axis
        wide[axis] = slice(0, f.shape[axis])
        crop[axis] = sl
    return derivative(f[tuple(wide)], h, axis)[tuple(crop)]


# -- convolution ---------------------------------------------------------------------------

def _convolve(fields: Sequence[np.ndarray], stencil: np.ndarray,
              precision: str = "double") -> list[np.ndarray]:
    """Linear (zero-padded) discrete convolution of several fields with one stencil
    (float64 results whatever the transforms' ``precision``)."""
    if not fields:
        return []
    out = convolution.convolve(list(fields), stencil, mode="linear", precision=precision)
    if isinstance(out, np.ndarray) and out.ndim == np.ndim(fields[0]) and len(fields) == 1:
        out = [out]
    return [np.asarray(a, dtype=float) for a in out]


def _proportional(s1: np.ndarray, s2: np.ndarray) -> float | None:
    """``c`` if ``s2 == c * s1`` to round-off (e.g. the uniform kernel: w**2 = height w)."""
    if s1.shape != s2.shape:
        return None
    total = s1.sum()
    if total == 0.0:
        return None
    c = s2.sum() / total
    if np.allclose(s2, c * s1, rtol=1e-12, atol=1e-14 * np.abs(s2).max()):
        return float(c)
    return None


class _Convolutions:
    """Collects ``w**power * source`` requests and computes them in one call per stencil.

    Sources are named; a source requested with both powers is transformed once when the
    ``w**2`` stencil is a multiple of the ``w`` stencil (the uniform kernel, where
    ``w**2 = height * w``), so every distinct (source, stencil) pair costs one transform.
    Results are the continuum integrals, i.e. already multiplied by ``h**dims``.
    """

    def __init__(self, grid: Grid, kernel):
        self.h = grid.spacing
        self.dims = grid.dims
        #: of the whole-grid transforms: single for large 3D grids (convolution module)
        self.precision = convolution.precision_for(grid.shape)
        self.stencils = {p: np.asarray(kernel.sample(self.h, power=p), dtype=float) for p in (1, 2)}
        c = _proportional(self.stencils[1], self.stencils[2])
        # power -> (stencil used, factor)
        self.use = {1: (1, 1.0), 2: (1, c) if c is not None else (2, 1.0)}
        self.sources: dict[str, np.ndarray] = {}
        self.requests: set = set()

    def request(self, name: str, source: np.ndarray, power: int) -> tuple:
        """Register ``w**power * source``; returns the key to look the result up with."""
        self.sources[name] = source
        self.requests.add((name, power))
        return (name, power)

    def run(self) -> dict[tuple, np.ndarray]:
        hd = self.h**self.dims
        out = {}
        for p in (1, 2):
            names = sorted({n for n, q in self.requests if self.use[q][0] == p})
            if not names:
                continue
            results = _convolve([self.sources[n] for n in names], self.stencils[p],
                                self.precision)
            done = dict(zip(names, results))
            for n, q in self.requests:
                if self.use[q][0] == p:
                    out[(n, q)] = done[n] * (hd * self.use[q][1])
        return out


def _assemble(grid: Grid, comps, u_terms: Mapping, D_terms: Mapping, D_s: Mapping,
              res: Mapping) -> dict[str, np.ndarray]:
    """Sum the convolved sources into the fields: ``u_a = sum factor * res[key]`` over
    ``u_terms[a]``, ``D^ab = factor * res[key]`` of ``D_terms`` (zero where absent)."""
    fields = {}
    for a in comps:
        acc = np.zeros(grid.shape)
        for factor, key in u_terms[a]:
            acc += factor * res[key]
        fields[f"u_{a}"] = acc
    for key in D_s:
        if key in D_terms:
            factor, rkey = D_terms[key]
            fields[key] = factor * res[rkey]
        else:
            fields[key] = np.zeros(grid.shape)
    return fields
