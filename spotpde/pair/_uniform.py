"""The uniform-flow observables of a spot kernel, in one call (see :mod:`spotpde.pair`).

In uniform flow every single-particle and pair statistic of the spot model is a
diffusion length per unit fall, and each is proportional to ``V2 / V1`` at a fixed kernel
*shape* (its profile, size and aspect; ``w`` only scales it): ``D_p ~ w^2`` while the
drift ``~ w``. So ``b_p``, ``b_p_par`` and the pair tensor ``B`` scale like the kernel's
height ``w`` (or volume), and the Peclet numbers and the cage-breaking fall like ``1/w``.
:func:`uniform_flow` computes the shape's values once (cached) and scales them, so a
change of ``kernel.height`` or ``kernel.volume`` costs nothing (docs/calibration.md).
"""

from __future__ import annotations

import math

from ..fields import _passage
from ._solver import _check_args, _check_kernel_2d, mean_fall, relative_tensor

__all__ = ["uniform_flow", "kinematic_rule", "PACKING"]

#: Default packing fraction of grains: random disks (2D) and spheres (3D).
PACKING = {2: 0.82, 3: 0.60}
#: Shape results per unit ``V2 / V1`` (amplitude-free), keyed by shape and spot lengths.
_CACHE: dict = {}


def kinematic_rule(kernel) -> float:
    """``lam* = 1/2 + V2 / (2 V1)``: the rule whose mean flow is exactly kinematic
    (docs/coefficients.md)."""
    return 0.5 + 0.5 * float(kernel.V2) / float(kernel.V1)


def _shape_key(kernel) -> tuple:
    return (type(kernel).__name__, int(kernel.dims), float(kernel.a_h), float(kernel.aspect))


def uniform_flow(kernel, b, b_par=0.0, rule=0.5, diffusivity="passage", *, cage=True,
                 contact=1.0, separation=2.0, packing=None) -> dict:
    """Single-particle and pair observables of the spot model in uniform flow.

    Args:
        kernel: a :mod:`spotpde.kernels` kernel (2D or 3D).
        b, b_par: spot diffusion lengths ``D_perp / v_s``, ``D_par / v_s`` in d.
        rule: ``lam`` in [0, 1], or ``"kinematic"`` for :func:`kinematic_rule`.
        diffusivity: ``"passage"`` (the discrete model's own) or ``"mean-field"``.
        cage: also compute the mean cage-breaking fall (one sparse solve of the pair
            equation, neighbours starting in contact in every direction).
        contact, separation: the pair's hard-core and cage-breaking separations, d.
        packing: grain packing fraction for ``grains_per_spot`` (default :data:`PACKING`).

    Returns:
        dict: ``b_p``, ``b_p_par`` (d; diffusion lengths per unit fall, horizontal and
        vertical), ``Pe_x = 1/b_p``, ``Pe_z = 1/b_p_par`` (with lengths in d),
        ``cage_fall`` (d; NaN without ``cage`` or for a 3D kernel with ``"passage"``),
        ``participation_area`` (``V1^2/V2``, d**dims: the area, volume in 3D, of a uniform
        spot with the same ``V1`` and ``V2``), ``spot_diameter`` (d; of the disk or sphere
        with that area), ``grains_per_spot`` (``packing * area / grain volume``),
        ``rule`` (the ``lam`` used), ``V1``, ``V2``.
    """
    if rule == "kinematic":
        rule = kinematic_rule(kernel)
    _check_args(b, b_par, rule, diffusivity, contact, separation, None)
    b, b_par, lam = float(b), float(b_par), float(rule)
    dims = int(kernel.dims)
    ratio = float(kernel.V2) / float(kernel.V1)
    key = (_shape_key(kernel), b, b_par, lam, diffusivity)
    if key not in _CACHE:
        t = _passage.length_tensor(kernel, b, b_par, lam, diffusivity=diffusivity)
        _CACHE[key] = {"xx": t["xx"] / ratio, "zz": t["zz"] / ratio}
    unit = _CACHE[key]
    b_p, b_p_par = unit["xx"] * ratio, unit["zz"] * ratio
    fall = math.nan
    if cage and not (dims == 3 and diffusivity == "passage"):
        _check_kernel_2d(kernel, allow_3d=True)
        ckey = key + ("cage", float(contact), float(separation))
        if ckey not in _CACHE:
            def tensor(X, Z):
                return relative_tensor(kernel, b, lam, b_par, diffusivity, X, Z)

            _CACHE[ckey] = mean_fall(tensor, contact, separation, "contact",
                                     axisym=dims == 3) * ratio
        fall = _CACHE[ckey] / ratio
    area = float(kernel.participation_area)
    diameter = 2.0 * math.sqrt(area / math.pi) if dims == 2 else (6.0 * area / math.pi) ** (1 / 3)
    grain = math.pi / 4.0 if dims == 2 else math.pi / 6.0
    phi = PACKING[dims] if packing is None else float(packing)
    return {"b_p": b_p, "b_p_par": b_p_par,
            "Pe_x": 1.0 / b_p if b_p > 0 else math.inf,
            "Pe_z": 1.0 / b_p_par if b_p_par > 0 else math.inf,
            "cage_fall": fall, "participation_area": area, "spot_diameter": diameter,
            "grains_per_spot": phi * area / grain, "rule": lam,
            "V1": float(kernel.V1), "V2": float(kernel.V2)}
