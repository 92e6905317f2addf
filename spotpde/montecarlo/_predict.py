"""Closed-form predictions the discrete spot-model Monte Carlo is checked against
(private; see ``montecarlo``).

:func:`spot_walks`: free spot walks with the step rule of ``simulate`` (lengths in d);
:func:`uniform_flow_prediction`: the discrete model's Lagrangian drift and diffusivities
in uniform flow, beyond mean field (docs/montecarlo.md, section 4).
"""

from __future__ import annotations

import math

import numpy as np

from ..fields import _passage
from . import _mc_kernels as K
from ._simulate import CUTOFF, STEPS

__all__ = ["spot_walks", "uniform_flow_prediction"]


def spot_walks(b: float, step: float, n_walks: int, n_steps: int, gamma: float = 0.0,
               steps: str = "gaussian", seed: int = 0) -> np.ndarray:
    """Horizontal positions of free spot walks (no walls), the step rule of :func:`simulate`.

    Args:
        b: long-distance diffusion length in d; the single-step one is
            ``b0 = b (1 - gamma) / (1 + gamma)``.
        step: vertical step Delta in d.
        n_walks, n_steps: number of walks and steps.
        gamma: step autocorrelation. steps: ``"gaussian"`` or ``"binary"``.
        seed: random seed.

    Returns:
        ``(n_walks, n_steps)``: x after each step (height ``(n + 1) * step``).
    """
    b0 = b * (1.0 - gamma) / (1.0 + gamma)
    return K.spot_walks(int(n_walks), int(n_steps), math.sqrt(2.0 * b0 * step), float(gamma),
                        STEPS.index(steps), int(seed))


# ---------------------------------------------------------------------------------------
# What the discrete model predicts in uniform flow (docs/montecarlo.md, section 4)
# ---------------------------------------------------------------------------------------
def uniform_flow_prediction(kernel, b: float, flux: float, rule: float = 0.5,
                            resolution: int = 16, cutoff: float = CUTOFF,
                            b_par: float = 0.0, diffusivity: str = "passage") -> dict:
    """Lagrangian drift and diffusivities of the discrete model in uniform flow.

    Uniform flow: spots cross each height at ``flux = rho_s v_s`` per unit length (area in
    3D) and unit time (``Q0 / W``), straight up on average. For small steps
    (``Delta -> 0``) the displacement of a particle by one passing spot is the stochastic
    integral ``Y = -int w(r - s) o_lam ds`` along the spot path; passages are independent,
    so ``D = flux/2 <Y Y>`` (averaged over the spot's horizontal offset). Derivation in
    docs/montecarlo.md section 4 and docs/coefficients.md ("Beyond mean field"); the
    numbers come from the one quadrature of ``spotpde.fields._passage.length_tensor``:

    * ``u_z = -V1 flux`` (the continuum's ``-V1 rho_s v_s``);
    * ``D_xx = flux b V2 - lam (1 - lam) flux/2 E[Y^2]``: the mean field, exact for
      ``lam`` = 0 and 1, minus the passage correlation (``E[Y^2]`` finite for every kernel,
      the sharp disk and sphere included);
    * ``D_zz``: with ``b_par = 0`` the shot noise of the Poisson passages,
      ``flux/2 E[Z^2]``, absent from the mean-field ``D_p``.

    Args:
        kernel: a ``spotpde.kernels`` kernel (2D or 3D).
        b: spot diffusion length in d. flux: ``rho_s v_s`` in spots / (d^(dims-1) time).
        rule: lam. b_par: vertical spot diffusion length in d.
        resolution, cutoff: not used (the quadrature sets its own resolution,
            docs/coefficients.md); accepted so that existing calls keep working.
        diffusivity: ``"passage"`` (the discrete model, default) or ``"mean-field"``
            (the paper's eq. Dp: ``b V2/V1``, no shot noise). For every uniform-flow
            observable at once (Peclet numbers, the cage-breaking fall, the spot's size)
            use :func:`spotpde.pair.uniform_flow`.

    Returns:
        dict with ``u_z``, ``D_xx``, ``D_xx_meanfield``, ``D_zz``, ``b_p``,
        ``b_p_meanfield`` (``= b V2 / V1``), ``b_p_par``, ``EY2``, ``EZ2``
        (``E[Y^2]`` and ``E[Z^2]`` integrated over the offset, in d**(dims+1)).
    """
    lam = float(rule)
    V1, V2 = float(kernel.V1), float(kernel.V2)
    bp = _passage.length_tensor(kernel, b, b_par, lam, diffusivity=diffusivity)
    mid = bp if lam == 0.5 else _passage.length_tensor(kernel, b, b_par, 0.5,
                                                       diffusivity=diffusivity)
    b_mf = b * V2 / V1
    EY2 = 8.0 * V1 * (b_mf - mid["xx"])
    u_z = -V1 * flux
    D_xx = V1 * flux * bp["xx"]
    D_zz = V1 * flux * bp["zz"]
    EZ2 = 2.0 * V1 * (bp["zz"] - b_par * V2 / V1)
    return {"u_z": u_z, "D_xx": D_xx, "D_xx_meanfield": flux * b * V2, "D_zz": D_zz,
            "b_p": bp["xx"], "b_p_meanfield": b_mf, "b_p_par": bp["zz"], "EY2": EY2,
            "EZ2": EZ2}
