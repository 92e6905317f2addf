"""``spotpde.kernels``: the influence kernels' public short name.

The kernels live in :mod:`spotpde.fields.kernels` (stage 2, the coefficient fields); this
module re-exports its public names so that ``spotpde.kernels.Gaussian(...)`` and
``from spotpde.kernels import Uniform`` work (docs/interface.md).
"""

from .fields.kernels import *  # noqa: F401,F403  (the public names, listed in __all__)
from .fields.kernels import __all__  # noqa: F401
