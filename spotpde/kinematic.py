"""``spotpde.kinematic``: the Kinematic Model's public short name.

The Kinematic Model lives in :mod:`spotpde.density.kinematic` (stage 1, beside the spot
density it is compared with); this module re-exports its public names so that
``spotpde.kinematic.point_source(...)`` and ``from spotpde.kinematic import
point_source`` work (docs/interface.md).
"""

from .density.kinematic import *  # noqa: F401,F403  (the public names, listed in __all__)
from .density.kinematic import __all__  # noqa: F401
