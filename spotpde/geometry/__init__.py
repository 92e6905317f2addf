"""The silo's shape on a grid: one :class:`Geometry` per grid (``grid.geometry``).

Modelled on how finite-volume codes separate the mesh from the physics (FiPy's meshes
with their cell volumes and face areas, py-pde's grids): a geometry owns the coordinate
and field names, cell measures and face weights, the active cells of a hopper's
staircase, the divergence on cell centres, the wall faces, and a statement of which
features it supports (:meth:`Geometry.supports`). Stages ask the geometry instead of
testing which grid they have; :func:`geometry_of` is the one place that reads a grid's
``coordinates`` and ``hopper``.

Shapes: :class:`BoxGeometry` (Cartesian 2D / 3D), :class:`AxisymmetricGeometry`
(``(r, z)``, ring cells), :class:`WedgeGeometry` (a 2D box masked by a wedge hopper),
:class:`ConeGeometry` (an axisymmetric grid masked by a conical hopper). This package
imports nothing else from spotpde, so every module may import it.
"""

from ._differences import derivative, is_zero, masked_derivative
from ._shapes import (AXISYMMETRIC_DIFFUSIVITY_KEYS, AXISYMMETRIC_DRIFT_KEYS, BOX_ONLY,
                      COORDINATES, DIFFUSIVITY_KEYS, DRIFT_KEYS, FEATURES,
                      PLANE_ONLY, AxisymmetricGeometry,
                      BoxGeometry, ConeGeometry, Geometry, Support, WedgeGeometry,
                      check_shape, geometry_of)

__all__ = ["Geometry", "BoxGeometry", "AxisymmetricGeometry", "WedgeGeometry",
           "ConeGeometry", "Support", "FEATURES", "BOX_ONLY", "PLANE_ONLY", "COORDINATES",
           "check_shape", "geometry_of", "derivative",
           "masked_derivative", "is_zero", "DRIFT_KEYS", "DIFFUSIVITY_KEYS",
           "AXISYMMETRIC_DRIFT_KEYS", "AXISYMMETRIC_DIFFUSIVITY_KEYS"]
