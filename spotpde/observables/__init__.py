"""Observables of a draining silo, measured from tracked grains and computed by the model
with the same names, dims and units, so that they can be subtracted and plotted
together (docs/calibration.md, sections 2-3).

::

    import spotpde
    from spotpde import observables as obs
    case = spotpde.load_case("cases/quasi2d_layers.toml")
    tracks = spotpde.tracks.read("tracks.csv", scale=12.5, fps=1000, y_down=True)
    data = obs.measure(tracks, case, ["velocity", "width", "diffusion", "correlation"])
    model = obs.predict(spotpde.run(case), case, like=data)
    ((data.u_z - model.u_z) / data.u_z_se).plot()          # residuals in standard errors

Each observable is also one function taking tracks or a model result:

=======================  =====================================================  ==========
function                 variables                                              dims
=======================  =====================================================  ==========
velocity_field           ``u_x``, ``u_z`` (coarse-grained mean velocity)        z, x
velocity_profiles        ``v_z`` (downward speed at chosen heights)             height, x
kinematic_width          ``b_kin`` (Kinematic-Model width), ``flux``            height
diffusion                ``b_p``, ``b_p_par``, ``Pe_x``, ``Pe_z``               z_bin, x_bin
displacement_growth      ``var_x``, ``var_z`` against ``lag_fall``;             lag
                         ``exponent_x``, ``exponent_z``
velocity_correlation     ``C`` (velocity correlation)                           r
pair_separation          ``survival``; ``mean_fall``, ``median_fall``           fall
drained_fraction         ``drained`` (coloured layers)                          t
=======================  =====================================================  ==========

From tracks every variable comes with ``*_se`` (delete-one-block jackknife over time
blocks: correlated samples are never counted as independent) and ``*_jk`` (the
replicates, which ``spotpde.fit`` uses to propagate correlated errors).
:func:`uniform_flow` gives the uniform-flow values of a kernel (``b_p``, ``Pe_x``,
``Pe_z``, the cage-breaking fall, the spot's size and grains per spot) in one call.

Private modules: ``_common`` (blocks, jackknife, coarse-graining, the model's mean
velocity), ``_velocity``, ``_diffusion``, ``_correlation``, ``_layers`` (one family of
observables each, data and model side by side), ``_measure`` (all at once).
"""

from ..pair import kinematic_rule, uniform_flow
from ._common import flux_factor
from ._correlation import pair_separation, velocity_correlation
from ._diffusion import diffusion, displacement_growth
from ._layers import drained_fraction
from ._measure import FIT_DEFAULT, OBSERVABLES, TARGETS, measure, part, predict
from ._velocity import kinematic_width, velocity_field, velocity_profiles

__all__ = ["FIT_DEFAULT", "OBSERVABLES", "TARGETS", "diffusion", "displacement_growth",
           "drained_fraction", "flux_factor", "kinematic_rule", "kinematic_width", "measure",
           "pair_separation", "part", "predict", "uniform_flow", "velocity_correlation",
           "velocity_field", "velocity_profiles"]
