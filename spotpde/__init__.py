"""spotpde: the continuum equations of the spot model of granular drainage.

The public surface (docs/interface.md)::

    import spotpde
    case = spotpde.load_case("cases/quasi2d_layers.toml")
    ds = spotpde.run(case)                 # xarray.Dataset
    spotpde.kernels.Gaussian(sigma=1.0, volume=0.05, dims=2)
    spotpde.kinematic.point_source(x, z, b, dims=2)

The package is laid out by pipeline stage (docs/architecture.md)::

    density/    spot density from the orifice (orifice, spot_density, kinematic)
    fields/     influence kernels and the particle drift and diffusivity (kernels,
                convolution, coefficients, void)
    tracer/     the tracer propagator (Fokker-Planck solver)
    pair/       relative diffusion of two tracers, cage breaking
    montecarlo/ the discrete spot model
    app/        case files, pipeline, netCDF, plots, command line, sweeps
    analysis/   comparison with the Kinematic Model, layered-silo diagnostics

Each public module keeps its short name as well: ``spotpde.kernels`` is
``spotpde.fields.kernels``, ``spotpde.cases`` is ``spotpde.app.cases``, and so on
(``import spotpde.kernels`` works too). Submodules are imported on first use, so
``import spotpde`` stays fast.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys

from . import _cache
from ._version import __version__
from .errors import CaseError, NumericalError

_cache.configure()   # numba's cache in a per-user directory, never in the package

#: Short public names of modules that live in a stage subpackage.
_ALIASES = {
    "orifice": "density.orifice",
    "spot_density": "density.spot_density",
    "kinematic": "density.kinematic",
    "traffic": "density.traffic",
    "noise": "density.noise",
    "kernels": "fields.kernels",
    "convolution": "fields.convolution",
    "coefficients": "fields.coefficients",
    "void": "fields.void",
    "cases": "app.cases",
    "pipeline": "app.pipeline",
    "io": "app.io",
    "plotting": "app.plotting",
    "cli": "app.cli",
    "sweep": "app.sweep",
    "comparison": "analysis.comparison",
    "layers": "analysis.layers",
    "mcstats": "montecarlo.mcstats",
}
_SUBPACKAGES = ("grid", "geometry", "parameters", "errors", "density", "fields", "tracer", "pair",
                "montecarlo", "app", "analysis", "tracks", "observables", "calibration")
_FUNCTIONS = {"load_case": "app.cases", "run": "app.pipeline", "sweep_case": "app.sweep",
              "fit": "calibration"}

__all__ = ["__version__", "CaseError", "NumericalError", *_SUBPACKAGES, *_ALIASES,
           *_FUNCTIONS]


class _AliasLoader(importlib.abc.Loader):
    """Loads ``spotpde.<short>`` as the module it names (no second copy)."""

    def __init__(self, target: str):
        self.target = target

    def create_module(self, spec):
        return importlib.import_module(self.target)

    def exec_module(self, module):
        pass


class _AliasFinder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        head, _, short = fullname.rpartition(".")
        if head != __name__ or short not in _ALIASES:
            return None
        return importlib.util.spec_from_loader(
            fullname, _AliasLoader(f"{__name__}.{_ALIASES[short]}"))


sys.meta_path.insert(0, _AliasFinder())


def __getattr__(name: str):
    if name in _ALIASES or name in _SUBPACKAGES:
        return importlib.import_module(f".{name}", __name__)
    if name in _FUNCTIONS:
        return getattr(importlib.import_module(f".{_FUNCTIONS[name]}", __name__), name)
    raise AttributeError(f"module 'spotpde' has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
