"""Orifice source profiles: unit mass, exact moments, images at walls, rate tables."""

import numpy as np
import pytest
from scipy.special import erf

from spotpde.grid import Grid
from spotpde.density.orifice import cosine_coefficients, rate_from_table, source_profile
from spotpde.parameters import Orifice


def grid(dims=2, walls="reflecting", h=0.25):
    return Grid(dims, (-5.0, 5.0), (0.0, 4.0), h, walls)


CASES = [
    Orifice(x=0.0, width=0.0),
    Orifice(x=1.13, width=0.0),
    Orifice(x=-4.9, width=0.0),                    # point near a wall
    Orifice(x=0.3, width=2.0),
    Orifice(x=4.2, width=3.0),                     # slot crossing a wall
    Orifice(x=0.1, width=1.5, profile="gaussian"),
    Orifice(x=-4.5, width=2.0, profile="gaussian"),
    Orifice(x=0.0, width=40.0),                    # uniform flow
]


@pytest.mark.parametrize("walls", ["reflecting", "open"])
@pytest.mark.parametrize("dims", [2, 3])
@pytest.mark.parametrize("orifice", CASES)
def test_unit_mass(orifice, dims, walls):
    g = grid(dims, walls)
    s = source_profile(g, orifice)
    assert s.shape == g.shape[1:]
    assert np.all(s >= 0)
    assert s.sum() * g.horizontal_cell_measure == pytest.approx(1.0, abs=1e-13)


@pytest.mark.parametrize("dims", [2, 3])
def test_point_source_keeps_centroid(dims):
    """Cloud in cell: the centroid of the regularised point source is the point itself."""
    g = grid(dims)
    o = Orifice(x=1.13, width=0.0, y=-0.61)
    s = source_profile(g, o)
    m = g.horizontal_cell_measure
    if dims == 2:
        assert np.sum(s * g.x) * m == pytest.approx(1.13, abs=1e-13)
    else:
        assert np.sum(s * g.x[None, :]) * m == pytest.approx(1.13, abs=1e-13)
        assert np.sum(s * g.y[:, None]) * m == pytest.approx(-0.61, abs=1e-13)


def test_slot_cell_averages_are_exact():
    """A slot [-0.95, 1.05] of width 2: 1/W inside, partial cells by overlap fraction."""
    g = grid(2)
    s = source_profile(g, Orifice(x=0.05, width=2.0))
    lo, hi = g.x - 0.125, g.x + 0.125
    overlap = np.clip(np.minimum(hi, 1.05) - np.maximum(lo, -0.95), 0, None) / 0.25
    np.testing.assert_allclose(s, overlap / 2.0, atol=1e-14)


def test_gaussian_folds_by_images_at_reflecting_wall():
    g = grid(2)
    x0, sigma = -4.5, 1.0
    s = source_profile(g, Orifice(x=x0, width=2 * sigma, profile="gaussian"))
    edges = -5.0 + 0.25 * np.arange(g.nx + 1)
    cdf = lambda x, c: 0.5 * (1 + erf((x - c) / (np.sqrt(2) * sigma)))
    # images of x0 in the walls at -5 and 5: -10 - x0, 10 - x0
    exact = sum(np.diff(cdf(edges, c)) for c in (x0, -10 - x0, 10 - x0, x0 + 20, x0 - 20))
    np.testing.assert_allclose(s * 0.25, exact, atol=1e-12)


def test_uniform_flow_when_wide():
    g = grid(3)
    s = source_profile(g, Orifice(x=2.0, width=10.0, profile="gaussian"))
    np.testing.assert_allclose(s, 1.0 / 100.0, rtol=1e-14)


def test_disk_area_and_symmetry():
    """A disk of diameter 3 centred on a cell corner: fourfold symmetric, second moment R^2/4."""
    g = grid(3, h=0.125)
    s = source_profile(g, Orifice(x=0.0, width=3.0, y=0.0))
    np.testing.assert_allclose(s, s[::-1, :], atol=1e-14)
    np.testing.assert_allclose(s, s.T, atol=1e-14)
    m2 = np.sum(s * g.x[None, :] ** 2) * g.horizontal_cell_measure
    assert m2 == pytest.approx(1.5**2 / 4, rel=2e-3)


@pytest.mark.parametrize("orifice", [Orifice(x=1.0, width=2.0),
                                     Orifice(x=-1.0, width=1.2, profile="gaussian")])
def test_cosine_coefficients_match_fine_profile(orifice):
    """Analytic cosine coefficients vs midpoint quadrature of the folded cell profile."""
    g = grid(2)
    fine = Grid(2, g.x_range, g.z_range, 1 / 512, "reflecting")
    s = source_profile(fine, orifice)
    k = np.pi * np.arange(12) / 10.0
    quad = np.array([np.sum(s * np.cos(kk * (fine.x + 5.0))) / 512 for kk in k])
    a = cosine_coefficients(g, orifice)[:12]
    quad *= np.where(np.arange(12) == 0, 1.0, 2.0) / 10.0
    # the cell-average of each cosine carries sinc(k h / 2), h = 1/512
    quad /= np.sinc(k / 1024 / np.pi)
    np.testing.assert_allclose(a, quad, atol=2e-7)


def test_rate_table_interpolates_linearly():
    q = rate_from_table([0.0, 10.0, 20.0], [1.0, 3.0, 0.0])
    assert q(5.0) == pytest.approx(2.0)
    assert q(15.0) == pytest.approx(1.5)
    assert q(-1.0) == 1.0 and q(30.0) == 0.0
    with pytest.raises(ValueError, match="strictly increasing"):
        rate_from_table([0.0, 0.0], [1.0, 2.0])
    with pytest.raises(ValueError, match=">= 0"):
        rate_from_table([0.0, 1.0], [1.0, -2.0])


def test_invalid_orifice_names_key_and_choices():
    with pytest.raises(ValueError, match=r"orifice.profile: must be one of 'uniform', 'gaussian'"):
        source_profile(grid(), Orifice(profile="box"))
    with pytest.raises(ValueError, match=r"orifice.x"):
        source_profile(grid(), Orifice(x=9.0))
