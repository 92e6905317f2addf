"""Analysis of results: ``comparison`` (the spot model's mean flow against the
Kinematic Model, rule by rule), ``layers`` (diagnostics of layered-silo runs) and
``packing`` (packing fraction, g(r), overlaps and number variance of particle
positions; docs/packing.md)."""

from .packing import (frames_of, number_variance, overlap_distribution, packing_fraction,
                      radial_distribution)

__all__ = ["frames_of", "number_variance", "overlap_distribution", "packing_fraction",
           "radial_distribution"]
