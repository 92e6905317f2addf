"""Packing diagnostics (spotpde.analysis.packing) against closed forms: the shells of a
triangular lattice in g(r), the Voronoi packing fraction of a lattice, exact overlaps,
and the number variance of a Poisson set (``var = n L^2``) and of a square lattice in
randomly placed windows (exact; it grows like the perimeter). See docs/packing.md."""

from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr
from scipy.special import j1

import spotpde
from spotpde import montecarlo as mc
from spotpde.analysis import (frames_of, number_variance, overlap_distribution,
                              packing_fraction, radial_distribution)
from spotpde.fields import kernels
from spotpde.grid import Grid
from spotpde.parameters import Orifice, Spots

A = 1.03  # lattice spacing: the shells 1.03, 1.784, 2.06, 2.725 fall inside 0.05 d bins


def _tri(L=30.0, a=A):
    return mc.lattice(Grid(2, (0.0, L), (0.0, L), 1.0), a)


def test_radial_distribution_of_a_triangular_lattice_counts_its_shells():
    P = _tri()
    ds = radial_distribution(P, r_max=2.9, dr=0.05)
    shell = math.pi * (ds.r_hi.values**2 - ds.r_lo.values**2)
    per_shell = ds.g.values * float(ds.n) * shell  # neighbours per centre in each shell
    expected = np.zeros_like(per_shell)
    for r, k in ((A, 6), (math.sqrt(3) * A, 6), (2 * A, 6), (math.sqrt(7) * A, 12)):
        expected[int(r / 0.05)] += k
    np.testing.assert_allclose(per_shell, expected, rtol=1e-12, atol=1e-12)
    # the density of the lattice itself, 2 / (sqrt(3) a^2), up to the edge rows
    assert float(ds.n) == pytest.approx(2.0 / (math.sqrt(3) * A**2), rel=0.03)


def test_voronoi_packing_fraction_of_a_lattice_is_exact():
    P = _tri()
    ds = packing_fraction(P, np.arange(5.0, 26.0, 5.0), np.arange(5.0, 26.0, 5.0), diameters=np.full(len(P), 0.9))
    exact = math.pi / 4 * 0.9**2 / (math.sqrt(3) / 2 * A**2)
    np.testing.assert_allclose(ds.phi.values, exact, rtol=1e-10)
    assert float(ds.phi_all) == pytest.approx(exact, rel=1e-10)
    assert np.all(np.isnan(ds.phi_se.values))  # one frame: no error claimed


def test_overlaps_of_a_compressed_lattice():
    P = _tri(a=0.98)
    ds = overlap_distribution(P)  # unit diameters: every nearest pair overlaps by 0.02
    assert float(ds["max"]) == pytest.approx(0.02, abs=1e-12)
    assert float(ds["mean"]) == pytest.approx(0.02, abs=1e-12)
    # 3 pairs per grain in the bulk, fewer at the edges of a 30 d box
    assert 2.7 < float(ds.pairs_per_grain) < 3.0
    ok = overlap_distribution(_tri(a=1.0), diameters=np.full(len(_tri(a=1.0)), 0.99))
    assert float(ok.pairs_per_grain) == 0.0


def test_number_variance_of_poisson_sets_grows_with_the_area():
    rng = np.random.default_rng(3)
    L_box, n = 30.0, 1.0
    frames = [rng.uniform(0, L_box, (rng.poisson(n * L_box**2), 2)) for _ in range(30)]
    sizes = np.array([1.0, 3.0, 6.0])
    for window, area in (("disk", math.pi / 4 * sizes**2), ("square", sizes**2)):
        ds = number_variance(frames, sizes, box=(0, L_box, 0, L_box), windows=200, seed=1,
                             window=window)
        z_var = (ds["var"].values - n * area) / ds.var_se.values
        z_mean = (ds["mean"].values - n * area) / ds.mean_se.values
        assert np.all(np.abs(z_var) < 4), (window, z_var)
        assert np.all(np.abs(z_mean) < 4), (window, z_mean)
    # one frame: tiles of the strips (independent for Poisson)
    one = number_variance(rng.uniform(0, 60, (3600, 2)), [2.0], box=(0, 60, 0, 60), window="square")
    assert abs(float(one["var"][0]) - 4.0) < 4 * float(one.var_se[0])


def _lattice_disk_variance(R, a, nmax=200):
    """Var of the count of a square lattice (spacing a, random offset) in a disk of
    radius R: rho^2 sum_{G != 0} |W(G)|^2, W(k) = 2 pi R J1(kR) / k (Poisson summation),
    summed for |n|, |m| <= nmax plus the tail R / (pi a nmax) of the rest."""
    k = np.arange(-nmax, nmax + 1)
    G = 2 * np.pi * np.hypot(*np.meshgrid(k, k)) / a
    G = G[G > 0]
    return np.sum((2 * np.pi * R * j1(G * R) / G) ** 2) / a**4 + R / (np.pi * a * nmax)


def test_number_variance_of_a_square_lattice_is_exact_and_grows_like_the_perimeter():
    rng = np.random.default_rng(5)
    a, L_box = 1.0, 30.0
    g = Grid(2, (-2.0, L_box + 2.0), (-2.0, L_box + 2.0), 1.0)
    base = mc.lattice(g, a, kind="square")
    frames = [base + rng.random(2) * a for _ in range(40)]  # random offsets over the cell
    # aligned squares: a whole row enters at once, N = N_x N_y with N_x = m + Bernoulli(f)
    sizes = np.array([2.3, 4.5, 8.7])
    ds = number_variance(frames, sizes, box=(0, L_box, 0, L_box), windows=150, seed=2,
                         window="square")
    m, f = np.floor(sizes / a), sizes / a - np.floor(sizes / a)
    exact = (f * (1 - f) + (m + f) ** 2) ** 2 - (m + f) ** 4
    z = (ds["var"].values - exact) / ds.var_se.values
    assert np.all(np.abs(z) < 4), (ds["var"].values, exact, z)
    # disks: the Poisson-summation closed form, growing like the perimeter
    sizes = np.array([2.3, 4.5, 8.7, 16.0])
    ds = number_variance(frames, sizes, box=(0, L_box, 0, L_box), windows=150, seed=2)
    exact = np.array([_lattice_disk_variance(L / 2, a) for L in sizes])
    z = (ds["var"].values - exact) / ds.var_se.values
    assert np.all(np.abs(z) < 4), (ds["var"].values, exact, z)
    assert ds["var"].values[-1] < 0.05 * ds["mean"].values[-1]  # Poisson: var = mean


def test_frames_of_accepts_a_tracks_dataset():
    P = _tri(L=10.0)
    x = np.stack([P[:, 0], P[:, 0] + 0.1], axis=1)
    z = np.stack([P[:, 1], np.where(np.arange(len(P)) == 0, np.nan, P[:, 1])], axis=1)
    ds = xr.Dataset({"x": (("particle", "t"), x), "z": (("particle", "t"), z),
                     "diameter": ("particle", np.full(len(P), 0.9))})
    pos, dia = frames_of(ds)
    assert len(pos) == 2 and pos[0].shape == (len(P), 2) and pos[1].shape == (len(P) - 1, 2)
    assert np.all(dia[1] == 0.9)
    with pytest.raises(ValueError, match="^data"):
        frames_of(xr.Dataset({"x": ("particle", P[:, 0])}))


def test_three_dimensional_frames_simple_cubic_lattice():
    a = 1.03
    k = np.arange(12) * a
    P = np.stack(np.meshgrid(k, k, k, indexing="ij"), axis=-1).reshape(-1, 3)
    ds = radial_distribution(P, r_max=1.9, dr=0.05)
    shell = 4.0 / 3.0 * math.pi * (ds.r_hi.values**3 - ds.r_lo.values**3)
    per_shell = ds.g.values * float(ds.n) * shell
    expected = np.zeros_like(per_shell)
    for r, n in ((a, 6), (math.sqrt(2) * a, 12), (math.sqrt(3) * a, 8)):
        expected[int(r / 0.05)] += n
    np.testing.assert_allclose(per_shell, expected, rtol=1e-12, atol=1e-12)
    phi = packing_fraction(P, [3.0, 8.0], [3.0, 8.0], diameters=np.full(len(P), 0.9))
    assert float(phi.phi[0, 0]) == pytest.approx(math.pi / 6 * 0.9**3 / a**3, rel=1e-10)


def test_a_monte_carlo_run_read_as_tracks_gives_its_frames_and_diameters():
    g = Grid(2, (-5.0, 5.0), (0.0, 10.0), 1.0)
    P, d, _ = mc.dense_packing(g, 0.75, seed=2)
    r = mc.simulate(g, Orifice(width=10.0, rate=5.0), Spots(drift=1.0, b=1.3),
                    kernels.Uniform(radius=2.0, height=0.01, dims=2), particles=P, diameters=d,
                    relax={}, tracked="all", records=3, t_end=6.0, probes=False, seed=1)
    tracks = spotpde.tracks.read(r)
    pos, dia = frames_of(tracks, diameters=None)
    assert len(pos) == 4  # t = 0 and three snapshots
    last = r.positions[-1][np.isfinite(r.positions[-1, :, 0])]
    np.testing.assert_allclose(np.sort(pos[-1][:, 0]), np.sort(last[:, 0]))
    ov = overlap_distribution(tracks)
    assert ov.attrs["samples"] == 4
