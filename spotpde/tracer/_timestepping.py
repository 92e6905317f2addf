"""Strong-stability-preserving Runge-Kutta schemes for the tracer equation (private).

Each scheme is written in Shu-Osher form as convex combinations of forward-Euler
steps, so any property of forward Euler under ``dt <= dt_FE`` (here: ``P >= 0`` and
exact conservation) holds for the full step under ``dt <= C * dt_FE`` with ``C`` the
SSP coefficient (Shu & Osher 1988; Gottlieb, Shu & Tadmor 2001, SIAM Rev. 43, 89).

Stage ``s`` computes ``P_s = alpha_s P_0 + (1 - alpha_s) (P_{s-1} + dt L(P_{s-1}, t_s))``
with ``P_{-1} = P_0``; the step is ``P_{n+1} = P_0 + dt sum_s b_s L(P_{s-1}, t_s)``, so
time-integrated face fluxes (outflow, P_height) are accumulated with weights ``b_s``.
"""

from __future__ import annotations


class SSPRK2:
    """Heun's method, SSP(2,2): 2 stages, order 2, SSP coefficient 1.

    P1 = P + dt L(P, t);  P_{n+1} = P/2 + (P1 + dt L(P1, t + dt))/2.
    """

    name = "ssprk2"
    stages = 2
    order = 2
    ssp_coefficient = 1.0
    alpha = (0.0, 0.5)               # weight of P_0 in each stage
    c = (0.0, 1.0)                   # stage times as fractions of dt
    b = (0.5, 0.5)                   # flux weights
    reference = "Shu & Osher 1988, J. Comput. Phys. 77, 439"


class SSPRK3:
    """Shu-Osher SSP(3,3): 3 stages, order 3, SSP coefficient 1.

    P1 = P + dt L(P, t);  P2 = 3P/4 + (P1 + dt L(P1, t + dt))/4;
    P_{n+1} = P/3 + 2 (P2 + dt L(P2, t + dt/2))/3.
    """

    name = "ssprk3"
    stages = 3
    order = 3
    ssp_coefficient = 1.0
    alpha = (0.0, 0.75, 1.0 / 3.0)
    c = (0.0, 1.0, 0.5)
    b = (1.0 / 6.0, 1.0 / 6.0, 2.0 / 3.0)
    reference = "Shu & Osher 1988, J. Comput. Phys. 77, 439, eq. (2.18)"


SCHEMES = {s.name: s for s in (SSPRK2, SSPRK3)}


def scheme_from_name(name: str):
    """The scheme class called ``name``; ValueError listing the valid choices."""
    try:
        return SCHEMES[name]
    except (KeyError, TypeError):
        raise ValueError(
            f"tracer.time_scheme: unknown scheme {name!r}; valid choices: {', '.join(SCHEMES)}"
        ) from None
