"""The grid tracer solver in void-model fields reproduces the Brownian-bridge propagator.

A Gaussian blob released at (x0, z0) in the void-model coefficient fields of a point
orifice (docs/void_model.md, section 6). The geometrical propagator ``P_height`` of
``spotpde.tracer.solve`` must match the closed form averaged over the blob, and be far
from the printed eq. Pcp's prediction.

To keep the run short the floor of the grid is put at ``z = 3`` (the fields are those of
the orifice at ``z = 0``; the floor is an outflow): the vertical motion is pure
advection, so the flux through the heights above is not affected by where it leaves.
"""

from __future__ import annotations

import numpy as np
import pytest

from spotpde import tracer
from spotpde.fields import void
from spotpde.grid import Grid
from spotpde.parameters import Spots

B, X0, Z0, SIGMA = 1.3, 4.0, 20.0, 0.75


@pytest.fixture(scope="module")
def run():
    h = 0.5
    grid = Grid(2, (-16.0, 16.0), (3.0, 23.0), h, walls="open")
    Z, X = grid.mesh()
    rho = void.point_void_density(X, Z, B) + 0 * X  # Q0 = v_s = 1
    fields = void.void_fields(grid, rho, Spots(drift=1.0, b=B), V1=1.0)
    P0 = np.exp(-((X - X0) ** 2 + (Z - Z0) ** 2) / (2 * SIGMA**2)) + 0 * X
    P0 /= P0.sum() * h * h
    result = tracer.solve(grid, fields, P0, 1500.0, 2)
    return grid, X, Z, P0, result


def _blob_average(z, X, Z, w, moments):
    """Mean and variance at height z of the closed form averaged over the released cells."""
    above = np.where(Z > z, w, 0.0)
    m, v = moments(z, X, Z, B)
    mean = (above * m).sum() / above.sum()
    return mean, (above * (v + m * m)).sum() / above.sum() - mean**2


def test_tracer_P_height_is_brownian_bridge(run):
    grid, X, Z, P0, r = run
    h = grid.spacing
    w = P0 * h * h
    for z_target in (10.0, 12.5, 15.0, 17.5):
        k = int(np.argmin(np.abs(grid.z - z_target)))
        z = grid.z[k]
        ph = r.P_height[k]
        crossed = ph.sum() * h
        assert crossed == pytest.approx(1.0, abs=1e-3)  # (almost) everything has passed z
        m = (ph * grid.x).sum() * h / crossed
        v = (ph * grid.x**2).sum() * h / crossed - m * m
        mb, vb = _blob_average(z, X, Z, w, void.bridge_moments)
        mp, vp = _blob_average(z, X, Z, w, void.printed_moments)
        assert abs(m - mb) < 0.02 * np.sqrt(vb)  # h = 0.5 is ~1/7 of the bridge's width
        assert abs(v / vb - 1) < 0.02
        # and far from the printed eq. Pcp
        assert abs(m - mp) > 20 * abs(m - mb) and abs(m - mp) > 0.3 * np.sqrt(vb)
        assert abs(v / vp - 1) > 0.2
    assert r.outflow_by_boundary["sides"] < 1e-6
