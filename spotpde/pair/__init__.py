"""Relative diffusion of two tracers and the cage-breaking fall.

The separation ``r`` of two particles in locally uniform flow obeys, with the fall
distance ``zeta`` as time, the relative Fokker-Planck equation (Ito, no drift)

    dP/dzeta = d_a d_b (B^ab(r) P)

with zero Ito normal flux at ``|r| = contact`` (hard core) and absorption at
``|r| = separation`` (the cage breaks). :func:`cage_breaking` solves it and returns the
survival curve and the mean and median fall (:func:`mean_fall`: the mean alone,
one sparse solve); :func:`uniform_flow`: every uniform-flow observable of a kernel; :func:`relative_tensor` gives ``B``
(``"mean-field"`` ``2 b_p (1 - C)`` or ``"passage"``). ``_case`` evaluates a case's
``[pair]`` table at a point of its flow; ``_mc`` simulates two particles in the
discrete model. See docs/pair.md.
"""

from ._solver import (cage_breaking, mean_fall, mean_fall_1d, mean_field_tensor,
                      relative_tensor, solve)
from ._case import add_to_result, local_lengths
from ._uniform import kinematic_rule, uniform_flow

__all__ = ["add_to_result", "cage_breaking", "kinematic_rule", "local_lengths", "mean_fall",
           "mean_fall_1d", "mean_field_tensor", "relative_tensor", "solve", "uniform_flow"]
