"""Advection operator of the tracer equation: limited upwind finite volumes (private).

The advective part of ``dP/dt + div(u_p P) = d_i d_j (D_p^ij P)`` is discretised as

    dP_c/dt = -(1/h) sum_axes [ F_{c+1/2} - F_{c-1/2} ],    F_{c+1/2} = u_{c+1/2} P*_{c+1/2}

with face velocity ``u_{c+1/2} = (u_c + u_{c+1}) / 2`` (second order) and the upwind,
limited face value (MUSCL, van Leer 1979; kappa-schemes, Koren 1993)

    P*_{c+1/2} = P_c + s_c / 2   if u_{c+1/2} > 0  (mirror image otherwise),
    s_c = sign(dR) * phi(|dL|, |dR|)   if dL * dR > 0, else 0,
    dL = P_c - P_{c-1},  dR = P_{c+1} - P_c .

Every limiter below satisfies ``0 <= phi <= min(2|dL|, 2|dR|)``, so the face value lies
between ``P_c`` and ``P_{c+1}`` and in ``[0, 2 P_c]``.

``weno5`` (the default of :func:`spotpde.tracer.solve`) replaces the limited value by the
fifth-order WENO-Z value from cells ``c-2 .. c+2`` (Jiang & Shu 1996; Borges et al. 2008),
then clips it to ``[0, 2 P_c]``; within two cells of a boundary it falls back to Koren.
The clip is all the positivity proof needs (below) and is inactive on resolved data.

Positivity (our proof, docs/tracer.md): with face values in ``[0, 2 P_c]``, inflow
terms are non-negative and each outward face removes at most ``2 |u_f| P_c dt / h``, so
forward Euler keeps ``P >= 0`` whenever ``dt * a_c <= 1`` with the per-cell rate
``a_c = (2/h) sum_{faces of c} max(outward face velocity, 0)`` (+ the diffusion part,
see :mod:`spotpde.tracer._diffusion`). SSP Runge-Kutta schemes (coefficient 1) keep this bound.

Numerical diffusion (measured with :func:`spotpde.tracer.numerical_diffusion`, cell
Peclet 100, Gaussian of standard deviation 4 cells travelling 160 cells): Koren adds
39 % of the physical diffusivity, WENO5 1.4 %, first-order upwind ``|u| h / 2`` (50 times
the physical one). The linear parts of the kappa = 1/3 and WENO5 schemes leave the
second moment exact; all of the measured excess comes from limiting/clipping.

Boundary faces: a reflecting wall has face velocity 0 (no advective flux); an open
side, the floor over the orifice and the top carry outflow only, with the boundary
cell's velocity (zero-gradient extrapolation) and the first-order upwind value
``P_c`` of the boundary cell. Cells next to a boundary use a zero slope towards it
(Koren/MUSCL) and WENO5 needs two cells on the upwind and one on the downwind side.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import _fp_kernels as K


@dataclass(frozen=True)
class Limiter:
    """A face reconstruction (slope limiter or WENO) of the advective flux.

    Attributes:
        name: option value.
        code: kernel code.
        order: formal spatial order of the face value in smooth monotone regions
            (the flux difference keeps this order; at extrema every limiter clips to
            first order locally, so the global L1 order of a smooth solution with
            extrema is about 2).
        phi: the limited slope magnitude as a function of ``|dL|, |dR|``.
        reference: where the scheme is published.
    """

    name: str
    code: int
    order: int
    phi: str
    reference: str


LIMITERS = {
    "upwind": Limiter("upwind", K.UPWIND, 1, "0 (first-order donor cell: numerical diffusion |u| h / 2)",
                      "Courant, Isaacson & Rees 1952"),
    "minmod": Limiter("minmod", K.MINMOD, 2, "min(|dL|, |dR|)", "Roe 1986; LeVeque 2002, sec. 6.9"),
    "vanleer": Limiter("vanleer", K.VANLEER, 2, "2 |dL| |dR| / (|dL| + |dR|)",
                       "van Leer 1974, J. Comput. Phys. 14, 361"),
    "mc": Limiter("mc", K.MC, 2, "min(2|dL|, 2|dR|, (|dL| + |dR|)/2)",
                  "van Leer 1977 (monotonized central), J. Comput. Phys. 23, 276"),
    "koren": Limiter("koren", K.KOREN, 3, "min(2|dR|, (|dL| + 2|dR|)/3, 2|dL|)",
                     "Koren 1993 (kappa = 1/3 limiter), in Numerical Methods for "
                     "Advection-Diffusion Problems, Vieweg, pp. 117-138"),
    "weno5": Limiter("weno5", K.WENO5, 5,
                     "fifth-order WENO-Z face value from the 5 cells c-2..c+2 (upwind-biased), "
                     "clipped to [0, 2 P_c]; Koren's limiter within two cells of a boundary",
                     "Jiang & Shu 1996, J. Comput. Phys. 126, 202; Borges, Carmona, Costa & "
                     "Don 2008, J. Comput. Phys. 227, 3191 (WENO-Z); positivity by the "
                     "[0, 2 P_c] clip (cf. Zhang & Shu 2010, J. Comput. Phys. 229, 3091)"),
}


def limiter_from_name(name: str) -> Limiter:
    """The :class:`Limiter` called ``name``; raises ValueError listing the choices."""
    try:
        return LIMITERS[name]
    except (KeyError, TypeError):
        raise ValueError(
            f"tracer.limiter: unknown limiter {name!r}; valid choices: {', '.join(LIMITERS)}"
        ) from None


def face_velocities(u: dict[str, np.ndarray], walls: str, outlet: np.ndarray):
    """Face-normal velocities with the boundary conditions built in.

    Args:
        u: cell-centred velocity components ``u_x``, [``u_y``,] ``u_z`` in d per unit time,
            array order ``(z, [y,] x)``.
        walls: ``"reflecting"`` (zero side flux) or ``"open"`` (outflow only).
        outlet: boolean mask over the floor (shape ``grid.shape[1:]``): where
            probability may leave through ``z = z0`` (where also ``u_z < 0``).

    Returns:
        dict ``x``, [``y``,] ``z`` of face arrays: one more entry along their own axis.
        Floor faces: ``min(u_z, 0)`` of the bottom cells over the outlet, 0 elsewhere;
        top faces: ``max(u_z, 0)`` of the top cells (no inflow through the top).
    """
    out = {}
    names = ["z", "y", "x"] if u["u_z"].ndim == 3 else ["z", "x"]
    for axis, name in enumerate(names):
        c = u[f"u_{name}"]
        n = c.shape[axis]
        shape = list(c.shape)
        shape[axis] = n + 1
        f = np.empty(shape)
        sl = lambda a, b: tuple(slice(a, b) if d == axis else slice(None) for d in range(c.ndim))
        f[sl(1, n)] = 0.5 * (c[sl(0, n - 1)] + c[sl(1, n)])
        first, last = c[sl(0, 1)], c[sl(n - 1, n)]
        if name == "z":
            f[sl(0, 1)] = np.where(outlet[None], np.minimum(first, 0.0), 0.0)
            f[sl(n, n + 1)] = np.maximum(last, 0.0)
        elif walls == "open":
            f[sl(0, 1)] = np.minimum(first, 0.0)
            f[sl(n, n + 1)] = np.maximum(last, 0.0)
        else:
            f[sl(0, 1)] = 0.0
            f[sl(n, n + 1)] = 0.0
        out[name] = f
    return out


def advective_rate(faces: dict[str, np.ndarray], h: float) -> np.ndarray:
    """Per-cell positivity rate ``(2/h) * sum of outward face velocities`` (1/time).

    Args:
        faces: output of :func:`face_velocities`.
        h: spacing in d.

    Returns:
        Cell array ``a_adv``; forward Euler of the advective part keeps ``P >= 0`` when
        ``dt * a_adv <= 1`` (see the module docstring).
    """
    a = 0.0
    for axis, f in enumerate(faces[n] for n in (["z", "y", "x"] if len(faces) == 3 else ["z", "x"])):
        n = f.shape[axis] - 1
        sl = lambda s, e: tuple(slice(s, e) if d == axis else slice(None) for d in range(f.ndim))
        a = a + np.maximum(f[sl(1, n + 1)], 0.0) + np.maximum(-f[sl(0, n)], 0.0)
    return (2.0 / h) * a
