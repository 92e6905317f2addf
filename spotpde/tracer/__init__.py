"""Stage 3: the tracer propagator, the Fokker-Planck equation of one particle.

    dP/dt + div(u_p P) = sum_ij d_i d_j (D_p^ij P)        (Ito form, full tensor)

:func:`solve` steps it in time (finite volumes, WENO5-Z / MUSCL advection, positive
tensor diffusion, SSP Runge-Kutta); :func:`numerical_diffusion` predicts the scheme's
numerical diffusion and :func:`sde_ensemble` is the grid-free Euler-Maruyama reference.
:func:`solve_steady` gives the time integral of ``P`` to infinity as the steady state of
the same scheme (the geometrical propagator for ``tracer.t_end = inf``, docs/steady.md).
Both work on axisymmetric grids (``Q = 2 pi r P`` stepped with the metric exchange) and
in hoppers (the staircase ``grid.active`` walled), :mod:`._geometry`.
``solve(..., stepping="imex" | "implicit")`` removes the global CFL bottleneck of long
runs with steady fields (docs/long_runs.md).
Schemes and their properties: docs/tracer.md.
"""

from ._diagnostics import numerical_diffusion, sde_ensemble
from ._solve import DIFFUSION_MODES, STEPPING_MODES, TracerResult, required_fields, solve
from ._steady import SteadyResult, solve_steady_public as solve_steady

__all__ = ["DIFFUSION_MODES", "STEPPING_MODES", "TracerResult", "numerical_diffusion", "required_fields",
           "sde_ensemble", "solve", "solve_steady", "SteadyResult"]
