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

Each public module keeps its short name as an attribute: ``spotpde.coefficients`` is
``spotpde.fields.coefficients``, ``spotpde.cases`` is ``spotpde.app.cases``, and so on.
``spotpde.kernels`` and ``spotpde.kinematic`` are also small modules of their own
(``from spotpde.kernels import Gaussian``), re-exporting ``spotpde.fields.kernels`` and
``spotpde.density.kinematic``. Submodules are imported on first use, so
``import spotpde`` stays fast.
"""

from __future__ import annotations

import importlib

from . import _cache
from ._version import __version__
from .errors import CaseError, NumericalError

_cache.configure()   # numba's cache in a per-user directory, never in the package

#: Short public names (attributes of the package) of modules in a stage subpackage.
_ALIASES = {
    "orifice": "density.orifice",
    "spot_density": "density.spot_density",
    "traffic": "density.traffic",
    "noise": "density.noise",
    "convolution": "fields.convolution",
    "coefficients": "fields.coefficients",
    "void": "fields.void",
    "cases": "app.cases",
    "pipeline": "app.pipeline",
    "io": "app.io",
    "plotting": "app.plotting",
    "sweep": "app.sweep",
    "comparison": "analysis.comparison",
    "layers": "app.layers",
    "mcstats": "montecarlo.mcstats",
}
#: Subpackages and top-level modules, imported on first use.
_SUBPACKAGES = ("kernels", "kinematic", "grid", "geometry", "parameters", "errors",
                "density", "fields", "tracer", "pair", "montecarlo", "app", "analysis",
                "tracks", "observables", "calibration", "cli")
_FUNCTIONS = {"load_case": "app.cases", "run": "app.pipeline", "sweep_case": "app.sweep",
              "fit": "calibration"}

__all__ = ["__version__", "CaseError", "NumericalError", *_SUBPACKAGES, *_ALIASES,
           *_FUNCTIONS]


def __getattr__(name: str):
    if name in _ALIASES:
        return importlib.import_module(f".{_ALIASES[name]}", __name__)
    if name in _SUBPACKAGES:
        return importlib.import_module(f".{name}", __name__)
    if name in _FUNCTIONS:
        return getattr(importlib.import_module(f".{_FUNCTIONS[name]}", __name__), name)
    raise AttributeError(f"module 'spotpde' has no attribute {name!r}")


def __dir__():
    return sorted(__all__)
