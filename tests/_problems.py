"""Small shared problems of the tests (not a test module): a void-model run near a point
orifice, and a random diffusion operator of the implicit tracer steps."""

from __future__ import annotations

import numpy as np

from spotpde._roundoff import clip_roundoff
from spotpde.app import pipeline
from spotpde.app.cases import load_case
from spotpde.density import spot_density
from spotpde.tracer import _diffusion

#: b of the void problem, in d
B = 1.3


def void_problem(h, half=8.0, top=16.0):
    """Void-model fields of a point orifice at the centre of the floor (open sides), a
    blob released at (1, 10): the cells next to the orifice are the fast ones."""
    case = load_case({
        "domain": {"dims": 2, "x": [-half, half], "z": [0.0, top], "spacing": h,
                   "walls": "open"},
        "orifice": {"x": 0.0, "width": 0.0, "rate": 1.2732}, "spots": {"b": B},
        "kernel": {"shape": "uniform", "size": 0.5, "volume": 0.7854, "rule": 1.0},
        "tracer": {"model": "void", "start": {"x": 1.0, "z": 10.0, "width": 1.0},
                   "t_end": 1.0}})
    grid = case.grid
    rho = clip_roundoff(spot_density.solve(grid, case.orifice, case.spots))
    return (grid, pipeline.case_fields(case, rho),
            pipeline.initial_density(grid, case.tracer.start))


def diffusion_operator(nz, nx, kind, rng):
    """A random diffusion operator on an ``nz x nx`` grid (h = 0.5): ``"void"`` D_xx only
    (tridiagonal), ``"tensor"`` D_xx, D_zz and D_xz (9-point), ``"not dominant"`` the
    same with |D_xz| > D_xx in some cells (negative off-diagonals); the top two rows have
    no diffusion (empty trailing columns of the matrix)."""
    Dxx = rng.uniform(0.2, 1.0, (nz, nx))
    Dzz = np.zeros((nz, nx)) if kind == "void" else rng.uniform(0.2, 1.0, (nz, nx))
    Dxz = np.zeros((nz, nx)) if kind == "void" else 0.15 * rng.uniform(-1, 1, (nz, nx))
    if kind == "not dominant":
        Dxz[2:5, 3:6] = 1.5
    for D in (Dxx, Dzz, Dxz):
        D[-2:] = 0.0
    terms, n_bad = _diffusion.split_tensor({"D_xx": Dxx, "D_zz": Dzz, "D_xz": Dxz}, 2)
    assert (n_bad > 0) == (kind == "not dominant")
    return _diffusion.operator(terms, (nz, nx), 0.5).tocsc()
