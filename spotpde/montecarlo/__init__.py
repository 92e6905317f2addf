"""The discrete spot model (eq. discrete of Bazant 2004), simulated spot by spot.

It checks the continuum: :func:`simulate` (or :func:`from_case`) moves particles by
every step of every spot; :func:`measure`, :func:`propagator`, :func:`particle_frames`,
:func:`displacement_statistics` and :func:`velocity_correlation` turn the result into
fields comparable with the continuum's; :func:`uniform_flow_prediction` and
:func:`spot_walks` are the closed-form predictions it is checked against.
See docs/montecarlo.md.
"""

from ._simulate import (CUTOFF, STEPS, KernelParams, MCResult, blob, displacement_statistics,
                        from_case, kernel_evaluate, kernel_params, lattice, layer_mask,
                        measure, particle_frames, propagator, random_packing, simulate,
                        spot_walks, uniform_flow_prediction, velocity_correlation)

__all__ = ["CUTOFF", "STEPS", "KernelParams", "MCResult", "blob", "displacement_statistics",
           "from_case", "kernel_evaluate", "kernel_params", "lattice", "layer_mask", "measure",
           "particle_frames", "propagator", "random_packing", "simulate", "spot_walks",
           "uniform_flow_prediction", "velocity_correlation"]
