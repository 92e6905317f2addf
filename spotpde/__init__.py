"""spotpde: the continuum equations of the spot model of granular drainage.

The public surface (docs/interface.md)::

    import spotpde
    case = spotpde.load_case("cases/quasi2d_layers.toml")
    ds = spotpde.run(case)                 # xarray.Dataset
    spotpde.kernels.Gaussian(sigma=1.0, volume=0.05, dims=2)
    spotpde.kinematic.point_source(x, z, b, dims=2)

Submodules are imported on first use, so ``import spotpde`` stays fast.
"""

from __future__ import annotations

import importlib

from . import _cache
from ._version import __version__
from .errors import CaseError, NumericalError

_cache.configure()   # numba's cache in a per-user directory, never in the package

_SUBMODULES = (
    "grid", "parameters", "kernels", "convolution", "orifice", "spot_density",
    "kinematic", "coefficients", "comparison", "tracer", "void", "layers", "cases", "io",
    "pipeline",
    "plotting", "montecarlo", "sweep", "cli",
)
_FUNCTIONS = {
    "load_case": "cases",
    "run": "pipeline",
    "sweep_case": "sweep",
}

__all__ = ["__version__", "CaseError", "NumericalError", *_SUBMODULES, *_FUNCTIONS]


def __getattr__(name: str):
    if name in _SUBMODULES:
        return importlib.import_module(f".{name}", __name__)
    if name in _FUNCTIONS:
        module = importlib.import_module(f".{_FUNCTIONS[name]}", __name__)
        return getattr(module, name)
    raise AttributeError(f"module 'spotpde' has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
