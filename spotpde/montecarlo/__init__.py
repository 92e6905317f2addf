"""The discrete spot model (eq. discrete of Bazant 2004), simulated spot by spot.

It checks the continuum: :func:`simulate` (or :func:`from_case`) moves particles by
every step of every spot; :func:`measure`, :func:`propagator`, :func:`particle_frames`,
:func:`displacement_statistics` and :func:`velocity_correlation` turn the result into
fields comparable with the continuum's; :func:`uniform_flow_prediction` and
:func:`spot_walks` are the closed-form predictions it is checked against.
See docs/montecarlo.md.

Private modules: ``_simulate`` (run, result, kernel reduction), ``_mc_kernels`` (the
numba loop and its :class:`~spotpde.montecarlo._mc_kernels.Params`), ``_particles``
(particle sets), ``_relax`` (packing constraints: soft-core relaxation, docs/packing.md),
``_simulate3d``, ``_mc3d``, ``_relax3d`` (the 3D model: spheres in a box or thin slab,
docs/packing.md section 6),
``_measure`` (fields and statistics of a run), ``_predict`` (closed
forms), ``_settings`` (the ``[montecarlo]`` case table, :class:`MonteCarloSettings`),
``_geometry`` and ``_geom_kernels`` (wedge hoppers, cylinders and cones).
"""

from ._measure import (displacement_statistics, measure, particle_frames, propagator,
                       velocity_correlation)
from ._geometry import geometry_particles
from ._particles import blob, dense_packing, lattice, layer_mask, random_packing
from ._predict import spot_walks, uniform_flow_prediction
from ._relax import DISTRIBUTIONS, Relax, draw_diameters, relax_packing
from ._replicas import replicas_from_case
from ._settings import MonteCarloSettings
from ._simulate import (CUTOFF, STEPS, KernelParams, MCResult, from_case, kernel_evaluate,
                        kernel_params, simulate)

__all__ = ["CUTOFF", "DISTRIBUTIONS", "STEPS", "KernelParams", "MCResult", "MonteCarloSettings",
           "Relax", "blob",
           "dense_packing", "displacement_statistics", "draw_diameters", "relax_packing",
           "from_case", "geometry_particles", "kernel_evaluate", "kernel_params", "lattice",
           "layer_mask", "measure", "particle_frames", "propagator", "random_packing",
           "replicas_from_case", "simulate", "spot_walks",
           "uniform_flow_prediction", "velocity_correlation"]
