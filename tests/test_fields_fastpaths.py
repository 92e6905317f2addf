"""Fast paths of the steady fields pipeline equal the plain computations they replace.

Each shortcut (issue 16, item 5) is exact algebra, so each is checked against the
computation it replaces at round-off: the renormalised walls of a rectangular silo as one
transform plus wall strips, the grid derivative against ``numpy.gradient``, the spectral
spot flux without its underflowed modes, the round-off clip and the finiteness check.
"""

from __future__ import annotations

import numpy as np
import pytest

from spotpde._roundoff import clip_roundoff
from spotpde.density import _spectral
from spotpde.fields import _walls
from spotpde.fields import coefficients as C
from spotpde.fields import kernels
from spotpde.grid import Grid, derivative
from spotpde.parameters import Spots


def _kernel(shape: str, dims: int):
    if shape == "uniform":      # w**2 = height * w: one transform for u_p and D_p
        return kernels.Uniform(radius=1.5, height=0.05, dims=dims, aspect=1.2)
    return kernels.Gaussian(sigma=0.6, volume=0.05, dims=dims, aspect=1.5)


@pytest.mark.parametrize("dims, half", [(2, 4.0), (2, 1.0), (3, 4.0)])
@pytest.mark.parametrize("shape", ["uniform", "gaussian"])
@pytest.mark.parametrize("rule", [0.0, 0.5, 1.0])
def test_renormalised_walls_by_strips_equal_the_general_path(dims, half, shape, rule):
    """Scalar coefficients take ``renormalised_constant_fields`` (S/phi = S + S (1/phi - 1),
    the second term on the wall strips only); the same coefficients as arrays take the
    general path (every source divided by phi, one transform each). Random rho_s: strong
    boundaries. ``half = 1`` is narrower than the kernel: the strips meet in the middle."""
    grid = Grid(dims, (-half, half), (0.0, 6.0), 0.25 if dims == 2 else 0.5,
                walls="reflecting")
    kernel = _kernel(shape, dims)
    rho = np.random.default_rng(11).random(grid.shape) + 1.0
    ones = np.ones(grid.shape)
    tensor = ({"D_xx": 1.3, "D_xz": 0.4, "D_zz": 0.7} if dims == 2 else
              {"D_xx": 1.3, "D_yy": 0.9, "D_xz": 0.4, "D_yz": -0.2, "D_zz": 0.7})
    def runs(arrays: bool):   # (spots, keyword arguments): scalars or the same as arrays
        c = ones if arrays else 1.0
        yield (Spots(drift=1.4 * c), dict(diffusivity="mean-field",
               spot_diffusivity_tensor={k: v * c for k, v in tensor.items()}))
        yield Spots(drift=1.4 * c, b=1.3, b_par=0.4), dict(diffusivity="passage")

    for (s1, kw1), (s2, kw2) in zip(runs(False), runs(True)):
        f1 = C.particle_fields(grid, rho, s1, kernel, rule=rule, **kw1)
        f2 = C.particle_fields(grid, rho, s2, kernel, rule=rule, **kw2)
        for k in f1:
            np.testing.assert_allclose(f1[k], f2[k], rtol=0, atol=1e-13 * np.abs(f2[k]).max(),
                                       err_msg=k)
        # and the renormalisation does something: the truncated fields differ at the walls
        trunc = C.particle_fields(grid, rho, s1, kernel, rule=rule, walls="truncate", **kw1)
        assert np.abs(trunc["u_z"] - f1["u_z"]).max() > 1e-3 * np.abs(f1["u_z"]).max()


def test_wall_boxes_cover_exactly_the_cells_where_the_kernel_leaves_the_silo():
    """phi < 1 (to more than round-off) exactly on the boxes; the boxes are disjoint."""
    grid = Grid(3, (-3.0, 3.0), (0.0, 2.0), 0.25, walls="reflecting")
    kernel = kernels.Uniform(radius=1.0, height=0.05, dims=3)
    half = [(k - 1) // 2 for k in kernel.sample(grid.spacing).shape]
    count = np.zeros(grid.shape, dtype=int)
    for box in _walls._wall_boxes(grid, half):
        count[box] += 1
    assert count.max() == 1
    phi = _walls.coverage(grid, kernel)
    np.testing.assert_array_equal(count == 1, phi < 1.0 - 1e-12)


@pytest.mark.parametrize("shape", [(7, 5), (64, 33), (5, 6, 7), (3, 4)])
def test_derivative_is_numpy_gradient_bit_for_bit(shape):
    f = np.random.default_rng(3).random(shape)
    for axis in range(len(shape)):
        np.testing.assert_array_equal(derivative(f, 0.13, axis),
                                      np.gradient(f, 0.13, axis=axis, edge_order=2))


@pytest.mark.parametrize("b, b_par", [(1.3, 0.0), (1.3, 0.4), (0.02, 0.0), (40.0, 2.0)])
def test_spectral_profile_without_underflowed_modes_is_the_full_one(b, b_par):
    """Modes decayed past exp(-746) are skipped row block by row block: the result is the
    full evaluation to the last bit (they underflow to 0 there too)."""
    L, n = 128.0, 1024
    k2 = (np.pi * np.arange(n) / L) ** 2
    zeta = (np.arange(n) + 0.5) / 8
    full = _spectral.mode_profile(k2[None, :], zeta[:, None], b, b_par, 160.0)
    live = _spectral._live_modes(k2, zeta, b, b_par, 160.0)
    np.testing.assert_array_equal(live, full)
    assert np.count_nonzero(full[-1]) < n           # the shortcut had work to skip


def test_clip_roundoff_zeroes_roundoff_negatives_only():
    a = np.array([1.0, -1e-17, 2.0, 0.0])
    np.testing.assert_array_equal(clip_roundoff(a), [1.0, 0.0, 2.0, 0.0])
    b = np.array([1.0, -1e-3, -1e-17])              # a real negative: left for checks
    np.testing.assert_array_equal(clip_roundoff(b), [1.0, -1e-3, 0.0])
    c = np.array([1.0, 2.0])
    assert clip_roundoff(c) is c                     # nothing to do: the same array
    d = np.array([np.nan, -1e-17])
    assert np.isnan(clip_roundoff(d)[0])


def test_finiteness_check_is_not_fooled_by_an_overflowing_sum():
    from spotpde.app.pipeline import _check_finite
    from spotpde.errors import NumericalError

    _check_finite("big", np.array([1e308, 1e308, -1e308]))        # sum overflows: finite
    _check_finite("empty", np.zeros(0))
    for bad in ([1.0, np.nan], [np.inf, -np.inf], [1e308, np.inf]):
        with pytest.raises(NumericalError, match="1 values|2 values"):
            _check_finite("f", np.array(bad))
