"""spotpde.observables against closed forms: tracks whose statistics are known exactly
(uniform motion, Brownian particles in uniform flow, grains sharing common kicks,
pairs whose separation is a reflected Brownian motion), and the kinematic width of the
closed-form Kinematic Model."""

from __future__ import annotations


import numpy as np
import pytest

import spotpde
from spotpde import observables as O, tracks as T
from spotpde.density import kinematic
from spotpde.montecarlo import mcstats
from spotpde.parameters import Orifice

BOX = {"domain": {"dims": 2, "x": [-10.0, 10.0], "z": [0.0, 30.0], "spacing": 0.5},
       "orifice": {"x": 0.0, "width": 20.0}, "spots": {"b": 1.3},
       "kernel": {"shape": "gaussian", "size": 1.0, "volume": 0.05, "rule": 1.0}}


@pytest.fixture(scope="module")
def box():
    return spotpde.load_case(BOX)


def brownian(n, frames, dt, v, D, D_z=0.0, seed=0, x_range=(-9.0, 9.0), z0=(5.0, 28.0)):
    """Independent particles falling at speed v with diffusivities D (x) and D_z (z)."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(*x_range, n)[:, None] + np.cumsum(
        np.sqrt(2 * D * dt) * rng.standard_normal((n, frames)), axis=1)
    z = rng.uniform(*z0, n)[:, None] - v * dt * np.arange(frames)[None, :] + np.cumsum(
        np.sqrt(2 * D_z * dt) * rng.standard_normal((n, frames)), axis=1)
    x[:, 0] = x[:, 1] - (x[:, 2] - x[:, 1])    # keep the first frame on the path
    return T.make(x, z, dt * np.arange(frames))


def test_uniform_motion_is_coarse_grained_exactly(box):
    n, frames, dt = 400, 30, 0.5
    rng = np.random.default_rng(1)
    x0, z0 = rng.uniform(-9, 9, n), rng.uniform(8, 28, n)
    t = dt * np.arange(frames)
    tr = T.make(x0[:, None] + 0.01 * t, z0[:, None] - 0.2 * t, t)
    v = O.velocity_field(tr, box, width=1.0)
    ok = np.isfinite(v["u_z"].values)
    assert ok.sum() > 500
    np.testing.assert_allclose(v["u_x"].values[ok], 0.01, rtol=1e-9)
    np.testing.assert_allclose(v["u_z"].values[ok], -0.2, rtol=1e-9)
    assert np.nanmax(v["u_z_se"].values) < 1e-12


def test_diffusion_lengths_of_brownian_particles_are_D_over_v(box):
    v, D, Dz = 0.05, 2e-4, 5e-4          # b_p = 0.004 d, b_p_par = 0.01 d
    tr = brownian(3000, 500, 1.0, v, D, Dz, seed=2)
    d = O.diffusion(tr, box, fall=1.0, bins=(10.0, 20.0))
    for name, exact in (("b_p", D / v), ("b_p_par", Dz / v)):
        value, se = d[name].values.ravel(), d[name + "_se"].values.ravel()
        ok = np.isfinite(value)
        assert ok.sum() >= 2
        z = (value[ok] - exact) / se[ok]
        assert np.all(np.abs(z) < 4), (name, value, se)
        assert np.all(se[ok] < 0.1 * exact)            # a test that can fail
    np.testing.assert_allclose(d["Pe_x"].values, 1.0 / d["b_p"].values, rtol=1e-12)


def test_displacement_growth_is_normal_diffusion_for_brownian_particles(box):
    v, D = 0.05, 2e-4
    tr = brownian(2000, 400, 0.5, v, D, seed=3)
    g = O.displacement_growth(tr, box, fit_range=(0.1, 5.0))
    ok = np.isfinite(g["var_x"].values) & (g["samples"].values > 1000)
    exact = 2 * (D / v) * g["lag_fall"].values[ok]
    z = (g["var_x"].values[ok] - exact) / g["var_x_se"].values[ok]
    assert np.all(np.abs(z) < 4)
    assert abs(float(g["exponent_x"]) - 1.0) < 4 * float(g["exponent_x_se"]) + 1e-9
    assert float(g["exponent_x_se"]) < 0.05


def test_velocity_correlation_of_grains_sharing_kicks(box):
    """Pairs 0.75 d apart share a kick of variance A, each grain has its own of variance B:
    C = A / (A + B) within a pair and 0 between pairs 5 d apart."""
    rng = np.random.default_rng(4)
    frames, A, B = 200, 3e-3, 1e-3
    centres = np.array([(x, z) for x in np.arange(-7.5, 8, 5.0) for z in np.arange(4, 27, 5.0)])
    n = 2 * len(centres)
    x0 = np.repeat(centres[:, 0], 2) + np.tile([-0.375, 0.375], len(centres))
    z0 = np.repeat(centres[:, 1], 2)
    common = np.repeat(np.sqrt(A) * rng.standard_normal((len(centres), frames)), 2, axis=0)
    own = np.sqrt(B) * rng.standard_normal((n, frames))
    x = x0[:, None] + np.cumsum(common + own, axis=1)
    z = np.repeat(z0[:, None], frames, axis=1)
    tr = T.make(x, z, np.arange(frames, dtype=float))
    c = O.velocity_correlation(tr, box, bins=[0.5, 1.0, 4.5, 5.5], region=(-10, 10, 0, 30))
    near, far = c["C"].sel(r=0.75).item(), c["C"].sel(r=5.0).item()
    assert abs(near - A / (A + B)) < 4 * c["C_se"].sel(r=0.75).item()
    assert abs(far) < 4 * c["C_se"].sel(r=5.0).item()
    assert c["C_se"].sel(r=0.75).item() < 0.05


def test_pair_survival_is_that_of_a_reflected_absorbed_brownian_separation(box):
    """The separation X of two falling grains: reflecting at 1 d, absorbed at 2 d, variance
    2 B per unit fall; S(F) = sum 4 (-1)^n / ((2n+1) pi) exp(-(2n+1)^2 pi^2 B F / 4)."""
    rng = np.random.default_rng(5)
    pairs, frames, v, dt, B = 300, 600, 0.1, 0.5, 0.02
    X = np.ones((pairs, frames))
    step = np.sqrt(2 * B * v * dt)
    for k in range(1, frames):
        X[:, k] = 1.0 + np.abs(X[:, k - 1] - 1.0 + step * rng.standard_normal(pairs))
    xc = np.tile(np.arange(60) * 3.3 - 98.0, 5)                # pairs 3.3 d apart, in
    zc = np.repeat(29.0 - 4.0 * np.arange(5), 60)              # five rows 4 d apart
    x = np.concatenate([xc[:, None] - X / 2, xc[:, None] + X / 2])
    fall = v * dt * np.arange(frames)
    z = np.concatenate([zc[:, None] - fall[None, :]] * 2)
    tr = T.make(x, z, dt * np.arange(frames))
    wide = spotpde.load_case({**BOX, "domain": {"dims": 2, "x": [-100.0, 100.0],
                                                "z": [0.0, 30.0], "spacing": 1.0},
                              "orifice": {"x": 0.0, "width": 4.0}})
    p = O.pair_separation(tr, wide, contact=1.05, separation=2.0, starts=1,
                          falls=np.linspace(0, 25, 11), region=(-100, 100, 0, 30))
    assert p.attrs["pairs"] == pairs
    F = p["fall"].values
    n = np.arange(60)[:, None]
    exact = np.sum(4 * (-1.0) ** n / ((2 * n + 1) * np.pi)
                   * np.exp(-((2 * n + 1) ** 2) * np.pi**2 * B * F[None, :] / 4), axis=0)
    exact[0] = 1.0
    se = p["survival_se"].values
    # start frame only: one block holds every pair, so the jackknife has no spread; use
    # the binomial error of independent pairs instead (they are independent here)
    binom = np.sqrt(np.maximum(exact * (1 - exact), 1e-4) / pairs)
    assert np.all(np.abs(p["survival"].values - exact) < 4 * binom + 1e-12), (p["survival"].values, exact)
    assert se.shape == exact.shape


def test_drained_fraction_of_bands_falling_at_known_speeds(box):
    # grains at heights z0 fall at 0.1 d per unit time: a grain leaves at t = z0 / 0.1
    z0 = np.linspace(0.05, 29.95, 300)
    t = np.arange(0, 301, 10.0)
    z = z0[:, None] - 0.1 * t[None, :]
    z = np.where(z < -0.5, np.nan, z)
    tr = T.make(np.zeros_like(z), z, t)
    d = O.drained_fraction(tr, box, spacing=6.0)
    coloured = z0[np.mod(z0, 6.0) < 3.0]
    exact = np.array([np.mean(coloured / 0.1 <= tt) for tt in t])
    np.testing.assert_allclose(d["drained"].values, exact, atol=1.0 / coloured.size + 1e-12)


def test_drained_fraction_error_is_the_scatter_of_independent_samples(box):
    """Grains drawn at random, each leaving at a time set mostly by its column: the
    jackknife error of the drained fraction equals the scatter of the estimate over
    independent samples. (Groups by column overstate it 3-4x here, taking the columns'
    difference for noise; groups interleaved in x understate it by 30-45 %.)"""
    rng = np.random.default_rng(7)
    t = np.arange(0, 121, 20.0)
    est, se = [], []
    for _ in range(150):
        x0 = rng.uniform(-10, 10, 240)
        z0 = 6.0 * rng.integers(0, 5, 240) + rng.uniform(0, 3, 240)     # coloured bands
        t_exit = 8.0 * np.abs(x0) + 0.5 * z0 + rng.exponential(3.0, 240)
        z = z0[:, None] - (z0[:, None] + 0.5) * t[None, :] / t_exit[:, None]
        d = O.drained_fraction(T.make(np.repeat(x0[:, None], t.size, 1), z, t), box, spacing=6.0)
        est.append(d["drained"].values)
        se.append(d["drained_se"].values)
    est, se = np.array(est), np.array(se)
    mid = slice(1, -2)                 # times where the fraction is neither 0 nor 1
    scatter = est[:, mid].std(axis=0, ddof=1)
    ratio = np.sqrt((se[:, mid] ** 2).mean(axis=0)) / scatter
    # 150 samples: the scatter is known to about 6 %, the mean jackknife variance to less
    assert np.all(np.abs(ratio - 1) < 0.2), ratio


@pytest.mark.parametrize("walls", ["reflecting", "open"])
def test_slot_profile_is_the_kinematic_solution(walls):
    o = Orifice(x=1.0, width=4.0)
    x = np.linspace(-10, 10, 2001)
    for s in (0.3, 5.0, 40.0):
        v = kinematic.slot_profile(x, s, o, (-10.0, 10.0), walls)
        if walls == "reflecting":
            assert abs(np.trapezoid(v, x) - 1.0) < 1e-6
            vx = np.gradient(v, x, edge_order=2)       # zero flux through the walls
            assert max(abs(vx[0]), abs(vx[-1])) < 1e-3 * np.max(np.abs(vx))
        ds = 1e-4
        dv_ds = (kinematic.slot_profile(x, s + ds, o, (-10.0, 10.0), walls)
                 - kinematic.slot_profile(x, s - ds, o, (-10.0, 10.0), walls)) / (2 * ds)
        vxx = np.gradient(np.gradient(v, x), x)
        inner = slice(20, -20)
        assert np.max(np.abs(dv_ds[inner] - vxx[inner])) < 1e-3 * np.max(np.abs(vxx))
    point = kinematic.slot_profile(x, 2.6, Orifice(x=0.0, width=0.0), None, "open")
    np.testing.assert_allclose(point, kinematic.point_source(x, 2.0, 1.3), rtol=1e-12)


@pytest.mark.parametrize("orifice", [Orifice(x=1.0, width=4.0), Orifice(x=-2.0, width=0.0),
                                     Orifice(x=0.5, width=2.0, profile="gaussian")])
def test_slot_profile_between_walls_is_the_cosine_series_at_small_and_large_s(orifice):
    """Between walls, small ``s`` takes the free-space form (the images are below
    round-off) and large ``s`` the cosine series: both equal the series summed here
    independently with many terms, on either side of the switch."""
    x0, x1 = -30.0, 30.0
    L = x1 - x0
    x = np.linspace(x0, x1, 301)
    k = np.arange(1, 3001) * np.pi / L      # exp(-k**2 s) < 1e-40 beyond, at s = 0.05
    xc, W = orifice.x, orifice.width
    if orifice.profile == "uniform" and W > 0:
        coef = (np.sin(k * (xc + W / 2 - x0)) - np.sin(k * (xc - W / 2 - x0))) / (k * W)
    else:
        coef = np.cos(k * (xc - x0)) * np.exp(-k**2 * (W / 2) ** 2 / 2)
    for s in (0.05, 0.5, 2.0, 4.0, 8.0, 30.0):
        series = 1 / L + 2 / L * (coef * np.cos(np.outer(x - x0, k)) * np.exp(-k**2 * s)).sum(-1)
        v = kinematic.slot_profile(x, s, orifice, (x0, x1))
        np.testing.assert_allclose(v, series, rtol=0, atol=1e-9 * series.max())


def test_kinematic_width_recovers_b_from_a_kinematic_flow():
    case = spotpde.load_case({**BOX, "orifice": {"x": 0.0, "width": 4.0},
                              "spots": {"b": 1.7}})
    grid = case.grid
    Z, X = np.meshgrid(grid.z, grid.x, indexing="ij")
    w = 1.0                       # coarse-graining width: the fit removes its broadening
    v = kinematic.slot_profile(X, 1.7 * Z + 0.5 * w**2, case.orifice, grid.x_range)
    import xarray as xr

    vel = xr.Dataset({"u_x": (("z", "x"), 0 * v), "u_z": (("z", "x"), -2.0 * v)},
                     coords={"z": grid.z, "x": grid.x}, attrs={"cg_width": w})
    from spotpde.observables._velocity import width_of

    out = width_of(vel, case, [3.0, 10.0, 25.0])
    np.testing.assert_allclose(out["b_kin"].values, 1.7, rtol=1e-4)
    np.testing.assert_allclose(out["flux"].values, 2.0, rtol=1e-4)


def test_flux_factor_of_a_disk_is_one_over_one_plus_w():
    case = spotpde.load_case({**BOX, "kernel": {"shape": "uniform", "size": 2.5, "height": 0.015}})
    assert abs(O.flux_factor(case) - 1.0 / 1.015) < 1e-3 * 0.015


def test_uniform_flow_numbers_and_their_exact_scaling():
    k = spotpde.kernels.Uniform(radius=2.5, height=0.0024, dims=2)
    one = O.uniform_flow(k, 1.3, rule=1.0, cage=True)
    assert abs(one["Pe_x"] - 1 / (0.0024 * 1.3)) < 1e-3 * one["Pe_x"]   # rule 1: b_p = w b
    assert abs(one["spot_diameter"] - 5.0) < 1e-12
    k2 = spotpde.kernels.Uniform(radius=2.5, height=0.0048, dims=2)
    two = O.uniform_flow(k2, 1.3, rule=1.0, cage=True)
    for key in ("b_p", "b_p_par"):
        assert abs(two[key] / one[key] - 2.0) < 1e-9
    assert abs(one["cage_fall"] / two["cage_fall"] - 2.0) < 1e-9
    kin = O.uniform_flow(k, 1.3, rule="kinematic", cage=False)
    assert abs(kin["rule"] - (0.5 + 0.5 * 0.0024)) < 1e-12


@pytest.mark.slow
def test_standard_errors_match_the_scatter_of_independent_monte_carlo_runs():
    """Replicas of the discrete spot model (uniform flow): the jackknife errors of the
    velocity and the diffusion length agree with the scatter between seeds."""
    from spotpde import montecarlo as mc

    raw = {"domain": {"dims": 2, "x": [-6.0, 6.0], "z": [0.0, 16.0], "spacing": 0.5},
           "orifice": {"x": 0.0, "width": 12.0, "rate": 6.0}, "spots": {"b": 1.0},
           "kernel": {"shape": "gaussian", "size": 1.0, "volume": 0.08, "rule": 1.0}}
    case = spotpde.load_case(raw)
    est, err = [], []
    for seed in range(8):
        r = mc.from_case(case, particles="lattice", spacing=0.8, tracked="all", records=200,
                         t_end=400.0, seed=seed, probes=False)
        tr = T.read(r).sel(t=slice(20, None))
        tr = tr.where(tr.z < 9)
        m = O.measure(tr, case, ["velocity", "diffusion"],
                      options={"diffusion": {"bins": (4.0, 6.0)}})
        u = m["u_z"].sel(z=[2.25, 6.25], x=[-3.25, 3.25], method="nearest").values.ravel()
        use = m["u_z_se"].sel(z=[2.25, 6.25], x=[-3.25, 3.25], method="nearest").values.ravel()
        b, bse = m["b_p"].values.ravel(), m["b_p_se"].values.ravel()
        keep = np.isfinite(b)
        est.append(np.concatenate([u, b[keep][:2]]))
        err.append(np.concatenate([use, bse[keep][:2]]))
    res = mcstats.se_calibration(np.array(est), np.array(err), level=1e-3)
    assert res["calibrated"], res
    # and the diffusion length is the model's b V2 / V1 (rule 1 is exact in uniform flow)
    k = case.kernel
    exact = 1.0 * k.V2 / k.V1 / O.flux_factor(case) * 1.0
    b_mean = np.mean([e[-2:] for e in est])
    assert abs(b_mean - exact) < 4 * np.sqrt(np.mean(np.array(err)[:, -2:] ** 2) / 16) + 0.02 * exact
