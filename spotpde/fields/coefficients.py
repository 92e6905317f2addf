"""Nonlocal drift and diffusivity of particles in the spot model (docs/conventions.md section 2).

A spot at ``r_s`` stepping by ``dR_s`` moves a particle at ``r`` by
``-w(r - r_s - lam dR_s) dR_s``. Expanding to second order in ``dR_s`` and averaging over
independent (Poisson) spots gives the Fokker-Planck coefficients of a tracer particle::

    u_p^a(r) = - sum_s w(r - r_s) rho_s u_s^a  +  2 lam sum_s (d_b w)(r - r_s) rho_s D_s^ab
    D_p^ab(r) =   sum_s w(r - r_s)^2 rho_s D_s^ab

(``sum_s`` is the integral over spot positions inside the silo). Integrating the second
drift term by parts turns it into the convolution form of the issue,

    u_p = - w * (rho_s u_s - 2 lam div(D_s rho_s))  +  wall layer,
    D_p =   w^2 * (rho_s D_s),

where ``div`` is the ordinary derivative inside the silo and the *wall layer* collects the
boundary terms. With reflecting side walls a reflected spot also has a mean push away
from the wall (its local time), ``rho_s u_s^a -= (D_s rho_s)^ab n_b delta_wall``, which gives
a boundary term of the same shape. Both together give (derivation and checks in
``docs/coefficients.md``)::

    wall layer^a(r) = (1 - 2 lam) * integral_walls (D_s rho_s)^ab n_b (r_w) w(r - r_w) dA_w

It vanishes for the midpoint rule ``lam = 1/2``, for which ``u_p = -w * J_s`` with
``J_s = rho_s u_s - div(D_s rho_s)`` the spot flux. With ``lam = 1`` (the paper's printed
eq. up) it pushes particles away from the walls. With ``walls = "open"`` (a window on a
wider silo) there is no wall and no wall layer.

Array conventions follow ``docs/architecture.md``: float64 arrays in array order ``(z, x)``
or ``(z, y, x)``; vector and tensor fields are dicts keyed ``u_x, [u_y,] u_z`` and
``D_xx, D_xz, D_zz, [D_yy, D_xy, D_yz]``. Units: lengths in d, times in the case's unit,
``u_p`` in d per unit time, ``D_p`` in d**2 per unit time.

The wall layer is computed in ``_wall_layer``; the two-point statistics
:func:`velocity_correlation` and :func:`pair_diffusivity` (cross integrals
``X^ab(r1, r2) = integral rho_s D_s^ab w(r1 - s) w(r2 - s) ds``) in ``_pairs``, both
re-exported here.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from . import _axisymmetric, _hopper, _passage, _strips, _walls, convolution
# the shared helpers live in _common (the bottom of the package); the two-point
# statistics and the wall layer beside this module
from ._common import (_COMPONENTS, ROUNDOFF, _assemble, _check_coefficient, _check_inputs,
                      _check_rule, _Convolutions, _is_zero, divergence, spot_diffusivity)
from ._constant import SpotFluxTensor, constant_fields
from ._pairs import pair_diffusivity, velocity_correlation
from ._wall_layer import add_wall_layer
from .._roundoff import clip_roundoff
from ..grid import DIFFUSIVITY_KEYS, DRIFT_KEYS, Grid
from ..parameters import Spots, check_diffusivity, drift_weight

__all__ = [
    "particle_fields",
    "spot_diffusivity",
    "divergence",
    "flux_velocity",
    "incompressibility_defect",
    "velocity_correlation",
    "pair_diffusivity",
    "release_caches",
    "DRIFT_KEYS",
    "DIFFUSIVITY_KEYS",
]

def _general_fields(grid: Grid, rho_s: np.ndarray, v_s, D_s: Mapping, lam: float,
                    conv: _Convolutions, D_source: Mapping | None = None) -> dict[str, np.ndarray]:
    """``u_p`` and ``D_p`` for coefficients that vary in space: one transform per source.

    Sources ``rho_s D_s^ab`` (for ``D_p``), ``div(D_s rho_s)`` (second-order grid
    differences) and ``rho_s v_s`` are convolved with ``w**2`` or ``w``; constant factors
    are pulled out of the convolutions. Also returns ``"_G"``: the ``rho_s D_s^ab`` arrays.
    ``D_source`` (default ``D_s``): the tensor ``T`` of ``D_p = w^2 * (rho_s T)``.
    """
    comps = _COMPONENTS[grid.dims]
    G = {}  # rho_s D_s^ab as arrays (None when identically zero)
    D_terms = {}
    for key, d in D_s.items():
        if _is_zero(d):
            G[key] = None
            continue
        G[key] = rho_s * d
        if D_source is not None:
            continue
        if np.ndim(d) == 0:
            D_terms[key] = (float(d), conv.request("rho", rho_s, 2))
        else:
            D_terms[key] = (1.0, conv.request(key, G[key], 2))
    diff_terms = {}  # passage drift: w^2 * (rho_s (T - D_s)) where not a multiple of D_p
    if D_source is not None:  # D_p from another tensor than the drift's D_s
        names = {}
        for key, d in D_source.items():
            if _is_zero(d):
                continue
            if np.ndim(d) == 0:
                D_terms[key] = (float(d), conv.request("rho", rho_s, 2))
            else:  # identical arrays (D_yy = D_xx) share one transform
                name = names.setdefault(id(d), "src_" + key)
                D_terms[key] = (1.0, conv.request(name, rho_s * d, 2))
            ds = D_s.get(key, 0.0)
            if _is_zero(ds) or _passage.proportional(d, ds) is not None:
                continue
            name = names.setdefault((id(d), id(ds)), "diff_" + key)
            diff_terms[key] = conv.request(name, rho_s * (d - ds), 2)

    # u_p = -w * (rho_s u_s) + 2 lam w * div(D_s rho_s), div on the grid; a constant v_s
    # multiplies the convolution w * rho_s
    div = divergence(grid, G)
    u_terms = {a: [] for a in comps}
    for a in comps:
        if lam != 0.0 and np.any(div[a]):
            u_terms[a].append((drift_weight(lam), conv.request(f"div_{a}", div[a], 1)))
    if np.ndim(v_s) == 0:
        if float(v_s) != 0.0:
            u_terms["z"].append((-float(v_s), conv.request("rho", rho_s, 1)))
    else:
        u_terms["z"].append((-1.0, conv.request("rho_v", rho_s * v_s, 1)))

    res = conv.run()
    fields = _assemble(grid, comps, u_terms, D_terms, D_s, res)
    fields["_G"] = G
    if diff_terms:
        fields["_diff"] = {key: res[k] for key, k in diff_terms.items()}
    return fields


# -- the fields ------------------------------------------------------------------------------

def particle_fields(grid: Grid, rho_s: np.ndarray, spots: Spots, kernel, rule: float = 0.5,
                    spot_diffusivity_tensor: Mapping | None = None, *,
                    diffusivity: str = "passage", walls: str = "renormalise",
                    mask: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Particle drift ``u_p`` and diffusivity ``D_p`` of the spot model.

    Implements (docs/conventions.md section 2, derivation in docs/coefficients.md)::

        u_p = - w * (rho_s u_s - 2 lam div(D_s rho_s)) + (1 - 2 lam) wall layer
        D_p =   w^2 * (rho_s D_s)                  (diffusivity="mean-field")
        D_p =   w^2 * (rho_s v_s b_eff(b, b_par))   (diffusivity="passage", default;
                                                     u_p += div(D_p - D_p_mf))

    with ``u_s = v_s z_hat``, ``*`` the linear (zero-padded) convolution over the silo
    (no spots outside it), ``div`` second-order differences on the grid (one-sided at the
    boundaries), and the wall layer of the reflecting side walls (module docstring).
    Convolutions sharing a kernel are done in one ``convolution.convolve`` call.

    Args:
        grid: the grid.
        rho_s: mean spot density in spots per d**dims, grid-shaped.
        spots: ``v_s`` (drift), ``b``, ``b_par``: floats or grid arrays.
        kernel: influence kernel from :mod:`spotpde.kernels` (``sample``, ``evaluate``,
            ``reach``).
        rule: ``lam`` in [0, 1]: where along a spot step the influence is evaluated;
            0.5 midpoint (default, the spot simulations' choice), 1 end point (the paper's
            printed eq. up).
        spot_diffusivity_tensor: optional full spot diffusivity tensor (keys ``D_xx``,
            ``D_xz``, ...; floats or grid arrays) replacing ``diag(D_perp, D_par)``.
        diffusivity: ``"passage"`` (default): the discrete model's own diffusivity, exact
            in uniform flow (passage correlations and shot noise, ``spotpde.fields._passage``;
            ``b_eff`` the diagonal tensor of ``_passage.effective_spot_length``
            at the source point's ``b``, ``b_par``; docs/coefficients.md, "Beyond mean
            field"); ``"mean-field"``: the paper's eq. Dp. The drift differs by
            ``div(D_p - D_p_mf)``, so that the probability-flux velocity ``u_p - div D_p``
            (the mean particle flow, exact in the mean field) is the same for both.
        walls: ``"renormalise"`` (default): a spot's influence is divided by the fraction
            ``phi`` of its kernel inside the material, so every spot step displaces the
            particle volume ``V1 dR`` and the particle flux through every height is
            ``V1 Q0`` (``spotpde.fields._walls``, docs/walls.md); ``"truncate"``: the part of the
            kernel beyond a reflecting wall displaces nothing. Identical with open walls.
        mask: optional material indicator for ``phi`` (see ``_walls.coverage``).

    Axisymmetric grids (3D kernel, ``rho_s`` per d**3; ``spotpde.fields._axisymmetric``)
    and hoppers (the staircase ``grid.active``; ``_hopper``): docs/walls.md sections 8-9.

    Returns:
        ``{"u_x", ["u_y",] "u_z", "D_xx", "D_xz", "D_zz", ["D_yy", "D_xy", "D_yz"]}``
        (``grid.drift_keys + grid.diffusivity_keys``: ``u_r, u_z, D_rr, D_rz, D_zz`` when
        axisymmetric, ``D_theta_theta = D_rr``; zero on inactive cells): grid-shaped
        float64 arrays, ``u`` in d per unit time, ``D`` in d**2 per unit time.
    """
    lam = _check_rule(rule)
    check_diffusivity(diffusivity)
    build = _FIELDS_OF[grid.geometry.kind]
    return build(grid, rho_s, spots, kernel, lam, spot_diffusivity_tensor, diffusivity, walls,
                 mask)


def _box_fields(grid: Grid, rho_s: np.ndarray, spots: Spots, kernel, lam: float,
                spot_diffusivity_tensor: Mapping | None, diffusivity: str, walls: str,
                mask: np.ndarray | None) -> dict[str, np.ndarray]:
    """The fields of a rectangular (2D) or cuboid (3D) silo: FFT convolutions, the
    constant-coefficient fast paths, the renormalised walls of ``_walls`` and the wall
    layer of ``_wall_layer``; arguments as :func:`particle_fields` (``lam`` checked)."""
    rho_s = _check_inputs(grid, rho_s, kernel)
    _check_coefficient(grid, "spots.drift", spots.drift)
    D_s = spot_diffusivity(grid, spots, spot_diffusivity_tensor)
    comps = _COMPONENTS[grid.dims]
    v_s = spots.drift

    D_source = None
    if diffusivity == "passage":
        D_source = _passage.source_tensor(grid, spots, D_s, kernel, lam)

    conv = _Convolutions(grid, kernel)
    phi = None
    constant = np.ndim(v_s) == 0 and all(np.ndim(d) == 0 for d in D_s.values())
    if D_source is not None:
        constant = constant and all(np.ndim(d) == 0 for d in D_source.values())
    constant = constant and min(grid.shape) >= 3    # the one-transform paths need 3 cells
    # 2D constant coefficients: the passage drift comes with the fields (one pass)
    fused = constant and grid.dims == 2 and D_source is not None
    if _walls.renormalises(grid, walls):
        # free-volume-conserving walls: sources divided by phi (u_p) and phi^2 (D_p)
        phi = _walls.coverage(grid, kernel, mask)
        if constant and mask is None:   # phi < 1 by the walls only
            fields = _walls.renormalised_constant_fields(grid, rho_s, float(v_s), D_s, lam,
                                                         conv, phi, D_source, fused)
        else:
            fused = False
            fields = _walls.renormalised_fields(grid, rho_s, v_s, D_s, lam, conv, phi, D_source)
        G = fields.pop("_G")
        fields.pop("_phi")
    elif constant:
        fields = constant_fields(grid, rho_s, float(v_s), D_s, lam, conv, D_source, fused)
        G = SpotFluxTensor(rho_s, D_s)
    else:
        fields = _general_fields(grid, rho_s, v_s, D_s, lam, conv, D_source)
        G = fields.pop("_G")
    if D_source is not None and not fused:
        _passage.keep_flux_velocity(grid, rho_s, D_s, D_source, kernel, fields, phi)

    # wall layer of the reflecting side walls: (1 - 2 lam) int (D_s rho_s)^ab n_b w dA
    add_wall_layer(grid, kernel, lam, G, phi, fields)
    # D_p = w^2 * (rho_s D_s) has a non-negative diagonal; the FFT leaves round-off
    # negatives (~1e-17 of the peak, ~1e-7 in single precision) where it vanishes, which
    # the tracer would reject
    rel = ROUNDOFF[conv.precision]
    for a in comps:   # the arrays are this call's own: clipped in place
        fields[f"D_{a}{a}"] = clip_roundoff(fields[f"D_{a}{a}"], rel, inplace=True)
    order = DRIFT_KEYS[grid.dims] + DIFFUSIVITY_KEYS[grid.dims]
    return {k: fields[k] for k in order}


def _ring_fields(grid, rho_s, *args):
    """Cylinders and cones: ring convolutions with a 3D kernel (``_axisymmetric``)."""
    return _axisymmetric.particle_fields(grid, _check_inputs(grid, rho_s, None), *args)


#: The particle fields of each shape (``grid.geometry.kind``): the box's FFT paths, the
#: ring convolutions of an axisymmetric grid, the staircase of a 2D wedge.
_FIELDS_OF = {"box": _box_fields, "axisymmetric": _ring_fields, "cone": _ring_fields,
              "wedge": _hopper.particle_fields}


def release_caches() -> None:
    """Free what the convolutions of :func:`particle_fields` keep for the next call of the
    same shape: FFT plans and their buffers, kernel spectra, the wall strips' spectra.

    For a grid of millions of cells that is several hundred MB (a 3D slab of 2.6 M cells:
    about 8 grid arrays) held through the tracer stage, which needs none of it; the next
    call rebuilds them (milliseconds: the plans are estimated, not measured).
    """
    convolution.clear_caches()
    _strips.clear_spectra()


# -- diagnostics ------------------------------------------------------------------------------

def flux_velocity(grid: Grid, fields: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Probability-flux velocity ``u_p - div D_p`` of particles at uniform density.

    The Fokker-Planck flux is ``J = u_p P - div(D_p P)``; at uniform ``P`` it is
    ``P (u_p - div D_p)``, the mean (Eulerian) velocity a kinematic model describes
    (docs/conventions.md section 3). Derivatives are second-order grid differences.

    Args:
        grid: the grid.
        fields: output of :func:`particle_fields`.

    Returns:
        ``{"u_x", ["u_y",] "u_z"}`` in d per unit time.
    """
    geometry = grid.geometry
    div = geometry.divergence({k: fields[k] for k in geometry.diffusivity_keys})
    return {f"u_{a}": geometry.restrict(np.asarray(fields[f"u_{a}"], dtype=float) - div[a])
            for a in geometry.components}


def incompressibility_defect(grid: Grid, fields: Mapping[str, np.ndarray]) -> np.ndarray:
    """``div(u_p - div D_p)``: the rate at which uniform particle density would change.

    Zero for an incompressible mean particle flow (the kinematic model's assumption).

    Args:
        grid: the grid.
        fields: output of :func:`particle_fields`.

    Returns:
        grid-shaped array in 1 / unit time.
    """
    return grid.geometry.velocity_divergence(flux_velocity(grid, fields))
