"""Checks of the numerical core where only special cases were tested before.

Each test here was written against a specific wrong implementation that the earlier
tests let through (docs/montecarlo.md, section 9, lists them and the mutation pass):

* ``coefficients.pair_diffusivity`` in non-uniform flow: ``D(r1, r2) = D_p(r1) + D_p(r2)
  - 2 X(r1, r2)`` is symmetric in the two particles and, for particles too far apart to
  share a spot, is the sum of the one-particle ``D_p`` of ``particle_fields``;
* the 3D ADI height marching with ``b`` varying in height (the mid-step value
  ``B_m = (B_k + B_k+1)/2`` is what makes it second order), against the exact Gaussian
  of variance ``2 integral b dz``;
* the 3D wall layer of the rule-1 drift: for a uniform spot density its value at the
  middle of a wall is the 2D one (the kernel integrated over the wall's tangential
  directions is the same), and the 2D one is checked against the exact discrete-step
  average in tests/fields/test_coefficients.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from spotpde.fields import coefficients as C
from spotpde.fields import kernels
from spotpde.density import spot_density as sd
from spotpde.grid import Grid
from spotpde.parameters import Orifice, Spots


# -- pair diffusivity in converging flow ----------------------------------------------------
def test_pair_diffusivity_is_symmetric_and_adds_one_particle_diffusivities():
    grid = Grid(2, (-8.0, 8.0), (0.0, 16.0), 0.25, walls="reflecting")
    spots = Spots(drift=1.0, b=1.3)
    rho = sd.steady(grid, Orifice(x=0.0, width=2.0), spots)
    kernel = kernels.Gaussian(sigma=0.8, volume=0.05, dims=2)
    # pair_diffusivity integrates the plain kernel (no wall renormalisation): compare
    # with the one-particle fields of the same kernel (r1 is 1.9 d from a wall)
    # mean field: pairs share a spot only where their kernels overlap (in the discrete
    # model a spot that passes one particle rises on and may pass the other: the passage
    # cross term reaches far vertically; tests/fields/test_passage.py)
    f = C.particle_fields(grid, rho, spots, kernel, rule=0.5, walls="truncate",
                          diffusivity="mean-field")
    MF = {"diffusivity": "mean-field"}
    i1, k1, i2, k2 = 7, 12, 32, 40                 # cell centres (x, z) = (-6.125, 3.125), (0.125, 10.125)
    r1 = (grid.x[i1], grid.z[k1])
    r2 = (grid.x[i2], grid.z[k2])
    assert f["D_xx"][k2, i2] > 3 * f["D_xx"][k1, i1] > 0   # the flow is far from uniform here
    far = C.pair_diffusivity(grid, rho, spots, kernel, r1, r2, **MF)
    swapped = C.pair_diffusivity(grid, rho, spots, kernel, r2, r1, **MF)
    for key in ("D_xx", "D_xz", "D_zz"):
        assert far[key] == pytest.approx(swapped[key], rel=1e-12, abs=1e-20)
    # 9.4 d apart: no shared spot (exp(-r^2 / 4 sigma^2) ~ 1e-14), so D = D_p(r1) + D_p(r2)
    for key in ("D_xx", "D_zz"):
        one = f[key][k1, i1] + f[key][k2, i2]
        assert far[key] == pytest.approx(one, rel=2e-3), key
    # close pairs: symmetric, and between 0 and the sum
    r3 = (grid.x[i1 + 4], grid.z[k1 + 2])
    a = C.pair_diffusivity(grid, rho, spots, kernel, r1, r3, **MF)
    b = C.pair_diffusivity(grid, rho, spots, kernel, r3, r1, **MF)
    assert a["D_xx"] == pytest.approx(b["D_xx"], rel=1e-12)
    assert 0 < a["D_xx"] < 0.5 * (f["D_xx"][k1, i1] + f["D_xx"][k1 + 2, i1 + 4])


# -- 3D ADI marching with b(z) ----------------------------------------------------------------
def _gauss(x, var):
    return np.exp(-x**2 / (2 * var)) / np.sqrt(2 * np.pi * var)


def _images(x, x0, var, lo, hi, m=3):
    L = hi - lo
    return sum(_gauss(x - (x0 + 2 * k * L), var) + _gauss(x - (2 * lo - x0 + 2 * k * L), var)
               for k in range(-m, m + 1))


def _adi_error(h):
    """b = b0 (1 + z / z1): each horizontal direction a Gaussian of variance 2 tau(z),
    tau = b0 (z + z^2 / 2 z1), reflected at the walls (images)."""
    lo, hi = -4.0, 4.0
    g = Grid(3, (lo, hi), (0.0, 6.0), h, walls="reflecting")
    b0, z1, x0, y0 = 0.8, 2.0, 1.0, -1.0        # (x0, y0) on cell faces for every h
    Z, Y, X = g.mesh()
    b = b0 * (1 + Z / z1) + 0 * X + 0 * Y
    rho = sd.steady(g, Orifice(x=x0, y=y0), Spots(b=b))
    var = 2 * b0 * (Z + Z**2 / (2 * z1))
    exact = _images(X, x0, var, lo, hi) * _images(Y, y0, var, lo, hi)
    far = np.broadcast_to(Z >= 2.0, g.shape)
    return np.max(np.abs(rho - exact)[far]) / exact[far].max()


def test_3d_marching_with_height_varying_b_is_second_order():
    e = [_adi_error(h) for h in (0.5, 0.25)]
    order = np.log2(e[0] / e[1])
    assert e[1] < 1e-2 and order > 1.6, (e, order)


# -- 3D wall layer ------------------------------------------------------------------------------
@pytest.mark.parametrize("rule", [1.0, 0.0])
def test_3d_wall_layer_equals_2d_at_the_middle_of_a_wall(rule):
    L, h, rho0 = 6.0, 0.5, 2.0
    spots = Spots(drift=1.0, b=1.3)
    g2 = Grid(2, (-L, L), (0.0, 2 * L), h, walls="reflecting")
    g3 = Grid(3, (-L, L), (0.0, 2 * L), h, walls="reflecting")
    f2 = C.particle_fields(g2, np.full(g2.shape, rho0), spots,
                           kernels.Gaussian(sigma=1.0, volume=0.05, dims=2), rule=rule)
    f3 = C.particle_fields(g3, np.full(g3.shape, rho0), spots,
                           kernels.Gaussian(sigma=1.0, volume=0.05, dims=3), rule=rule)
    k, j = g2.nz // 2, g3.shape[1] // 2
    u2, u3 = f2["u_x"][k], f3["u_x"][k, j]
    scale = np.abs(u2).max()
    assert scale > 0
    np.testing.assert_allclose(u3, u2, rtol=0, atol=2e-3 * scale)
    # and by symmetry the y walls give the same layer to u_y
    np.testing.assert_allclose(f3["u_y"][k, :, g3.nx // 2], u2, rtol=0, atol=2e-3 * scale)
