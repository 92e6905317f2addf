"""Analysis of results: ``comparison`` (the spot model's mean flow against the
Kinematic Model, rule by rule), ``layers`` (measures of layered-silo results;
``spotpde.layers``, i.e. ``spotpde.app.layers``, adds the runs they need) and
``packing`` (packing fraction, g(r), overlaps and number variance of particle
positions; docs/packing.md)."""

from .packing import (frames_of, number_variance, overlap_distribution, packing_fraction,
                      radial_distribution)

__all__ = ["frames_of", "number_variance", "overlap_distribution", "packing_fraction",
           "radial_distribution"]
