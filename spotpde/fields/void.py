"""The Void Model: one particle per spot, and its geometrical particle propagator.

The Void Model (Litwiniszyn, Mullins, Hong & Caram) moves particles by exchanges with
particle-sized voids that rise from the orifice by directed random walks. It is the spot
model with one particle per spot: local kernel, ``V2 = V1`` (``w = 1`` inside one particle
volume) and the influence evaluated where the void *ends* its step (``rule = lam = 1``).
The derivation of everything here, with the checks, is in ``docs/void_model.md``.

Conventions: lengths in particle diameters d, ``z`` up, orifice at ``(x, z) = (0, 0)``;
``b`` is per horizontal component (each horizontal coordinate of a void step of height
``dz`` has variance ``2 b dz``).

Main results (point orifice, unbounded silo):

* Void density ``rho_v(x, z) = exp(-x**2 / 4bz) / sqrt(4 pi b z)`` (per unit ``Q0 / v_s``).
* Correct continuum equation for the geometrical propagator (``-z`` acts as time)::

      -dP/dz = b div_perp( grad_perp P - 2 P grad_perp log rho_v )

  i.e. a horizontal drift per unit fall ``+2 b grad_perp log rho_v`` (up the void
  gradient). The printed eq. Pcp has ``+ P grad_perp log rho_v`` inside the bracket: a
  drift ``-b grad_perp log rho_v``, of the wrong sign and half the size.
* Closed form: the horizontal position is a Brownian bridge in the fall variable ending
  at the orifice, ``x | z ~ N(x0 z / z0, 2 b z (z0 - z) / z0)`` per horizontal component.
  The printed equation instead gives ``N(x0 sqrt(z0 / z), b (z0**2 - z**2) / z)``.

Here: the void-model particle coefficient fields on a grid (:func:`void_fields`). In
the private ``_void_forms`` (re-exported here): the closed forms above, a 1D reference
marcher for either form of the propagator equation
(:func:`march_propagator`), and the lattice void model itself, solved exactly by a
transfer matrix (:func:`lattice_propagator`) and by a Monte Carlo of particles displaced
by simulated voids (:func:`lattice_void_montecarlo`).
"""

from __future__ import annotations

import numpy as np

from ..geometry import derivative, masked_derivative
from ..grid import Grid
from ..parameters import Spots, drift_weight
from ._void_forms import (  # noqa: F401 - the closed forms, re-exported
                          STAGGERED, FORMS, point_void_density, bridge_moments, printed_moments,
                          geometric_propagator, printed_propagator, pcp_rhs, printed_eq_pcp_rhs,
                          march_propagator, lattice_b, lattice_void_density, lattice_propagator,
                          lattice_void_montecarlo)


# ---------------------------------------------------------------------------------------
# Void-model coefficient fields on the grid (local spot-model limit)
# ---------------------------------------------------------------------------------------
def void_fields(grid: Grid, rho_s: np.ndarray, spots: Spots, V1: float,
                rule: float = 1.0) -> dict[str, np.ndarray]:
    """Particle drift and diffusivity of the void model (local kernel, ``V2 = V1``).

    Local limit of the spot-model coefficients (docs/conventions.md section 2)::

        u_p = -V1 (rho_s u_s - 2 lam div(D_s rho_s)),   D_p = V1 rho_s D_s

    with ``u_s = v_s e_z``, ``D_s = diag(D_perp, [D_perp,] D_par)``, ``D_perp = b v_s``,
    ``D_par = b_par v_s`` and ``lam = rule = 1`` (influence where the void ends its step,
    which is what the lattice void model does). For constant ``D_s``,
    ``div(D_s rho_s) = D_s grad rho_s``. Derivatives: second-order central differences,
    second-order one-sided at the boundaries (``numpy.gradient``, ``edge_order=2``).

    With ``lam = 1`` the horizontal drift per unit fall is ``2 b d_x log rho_s`` (twice
    the kinematic ``u / v``) while the probability-flux velocity ``u_p - div D_p`` equals
    the kinematic velocity ``(b d_x v, -v)``, ``v = V1 v_s rho_s`` (docs/void_model.md).

    Args:
        grid: the grid (array order ``(z, x)`` or ``(z, y, x)``).
        rho_s: void (spot) density, spots per d**dims, grid-shaped.
        spots: drift ``v_s`` (d per unit time), ``b``, ``b_par`` (d); floats or arrays.
        V1: particle volume carried per void (``V1 = V2``), d**dims.
        rule: ``lam``; the void model is ``1`` (kept as a parameter for comparisons).

    Axisymmetric grids (``rho_s`` per d**3, ``V1`` in d**3) and hoppers: the same
    fields in cylindrical components ``u_r, u_z, D_rr, D_rz, D_zz``, zero on inactive
    cells (:func:`_staircase_void_fields`).

    Returns:
        Dict with ``u_x``, [``u_y``,] ``u_z`` (d per unit time) and ``D_xx``, ``D_xz``,
        ``D_zz`` [, ``D_yy``, ``D_xy``, ``D_yz``] (d**2 per unit time), grid-shaped
        (``grid.drift_keys + grid.diffusivity_keys``).
    """
    rho = np.asarray(rho_s, dtype=float)
    if rho.shape != grid.shape:
        raise ValueError(f"rho_s has shape {rho.shape}, grid has {grid.shape}")
    if not grid.geometry.uniform_cells:   # rings or a staircase
        return _staircase_void_fields(grid, rho, spots, V1, float(rule))
    h = grid.spacing
    v_s = np.broadcast_to(np.asarray(spots.drift, float), grid.shape)
    D_perp = np.broadcast_to(np.asarray(spots.D_perp, float), grid.shape)
    D_par = np.broadcast_to(np.asarray(spots.D_par, float), grid.shape)
    lam = float(rule)
    Fh = rho * D_perp  # horizontal components of D_s rho_s
    Fz = rho * D_par
    ax = {a: i for i, a in enumerate(grid.axes)}
    out = {
        "u_x": drift_weight(lam) * V1 * derivative(Fh, h, ax["x"]),
        "u_z": -V1 * (rho * v_s - drift_weight(lam) * derivative(Fz, h, ax["z"])),
        "D_xx": V1 * Fh,
        "D_xz": np.zeros(grid.shape),
        "D_zz": V1 * Fz,
    }
    if grid.dims == 3:
        out["u_y"] = drift_weight(lam) * V1 * derivative(Fh, h, ax["y"])
        out["D_yy"] = V1 * Fh.copy()
        out["D_xy"] = np.zeros(grid.shape)
        out["D_yz"] = np.zeros(grid.shape)
    return {k: np.ascontiguousarray(v, dtype=float) for k, v in out.items()}


def _staircase_void_fields(grid: Grid, rho: np.ndarray, spots: Spots, V1: float,
                           lam: float) -> dict[str, np.ndarray]:
    """:func:`void_fields` on axisymmetric grids and in hoppers (``grid.active``).

    The same local fields in cylindrical components (``rho_s`` per d**3, ``V1`` in d**3)::

        u_r = 2 lam V1 d_r(rho_s D_perp),   u_z = -V1 (rho_s v_s - 2 lam d_z(rho_s D_par)),
        D_rr = V1 rho_s D_perp (= D_theta_theta),   D_rz = 0,   D_zz = V1 rho_s D_par

    (``(div(D_s rho_s))_r = d_r G_rr`` because ``G_theta_theta = G_rr``). Derivatives:
    second-order differences with the even continuation across the axis (so ``u_r -> 0``
    there) that never cross a wall face of the staircase (one-sided next to inactive
    cells). Zero on inactive cells. A 2D wedge hopper gives ``u_x, u_z, D_xx, D_xz, D_zz``.
    """
    h = grid.spacing
    act = grid.active
    rho = np.where(act, rho, 0.0)
    v_s = np.broadcast_to(np.asarray(spots.drift, float), grid.shape)
    Fh = rho * np.broadcast_to(np.asarray(spots.D_perp, float), grid.shape)
    Fz = rho * np.broadcast_to(np.asarray(spots.D_par, float), grid.shape)
    axi = grid.geometry.has_axis          # even across the axis r = 0
    h_key = grid.geometry.components[0]
    out = {
        f"u_{h_key}": drift_weight(lam) * V1 * masked_derivative(Fh, h, 1, act, even_axis=axi),
        "u_z": -V1 * (rho * v_s - drift_weight(lam) * masked_derivative(Fz, h, 0, act)),
        f"D_{h_key}{h_key}": V1 * Fh,
        f"D_{h_key}z": np.zeros(grid.shape),
        "D_zz": V1 * Fz,
    }
    keys = grid.drift_keys + grid.diffusivity_keys
    return {k: np.ascontiguousarray(np.where(act, out[k], 0.0), dtype=float) for k in keys}
