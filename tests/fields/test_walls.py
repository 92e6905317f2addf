"""Free volume is conserved at walls: the renormalised kernel ``w(r - s) / phi(s)``.

Closed forms used (derivations in docs/walls.md):
* a spot step ``dR`` displaces exactly ``V1 dR`` of particles, so the particle flux
  ``-int u_z dx`` through every height (farther than the kernel's reach from the floor and
  the top) is ``V1 Q0``; with ``kernel.walls = "truncate"`` it falls short;
* uniform flow between walls at ``x0, x1`` (orifice across the floor), Gaussian kernel:
  ``u_z(x) = -v_s rho_s int m(x - s) / phi(s) ds`` with ``m = V1 N(0, sigma^2)`` the
  kernel's horizontal marginal and ``phi(s) = Phi((x1 - s)/sigma) - Phi((x0 - s)/sigma)``;
  ``D_xx = D_perp rho_s int m2(x - s) / phi(s)^2 ds``; the wall layer of rule ``lam``
  ``u_x = (1 - 2 lam) D_perp rho_s [m(x - x1) / phi(x1) - m(x - x0) / phi(x0)]``;
* the discrete spot model (Monte Carlo) with the same treatment gives the continuum's
  velocity profile near the walls (independent seeds as replicas).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, stats
from scipy.special import ndtr

import spotpde
from spotpde.fields import _walls, coefficients as C, kernels
from spotpde.density import spot_density
from spotpde.grid import Grid
from spotpde.parameters import Orifice, Spots
from _quadrature import discrete_rule_drift

DISK = dict(radius=2.5, height=0.0024)  # the paper's spot: R = 2.5 d, w = 0.0024


def _flux_fraction(grid, orifice, spots, kernel, walls, rule=0.5):
    rho = spot_density.steady(grid, orifice, spots)
    f = C.particle_fields(grid, rho, spots, kernel, rule=rule, walls=walls)
    axes = tuple(range(1, grid.dims))
    flux = -f["u_z"].sum(axis=axes) * grid.spacing ** (grid.dims - 1)
    return flux / (kernel.V1 * float(orifice.rate))


def _away_from_floor_and_top(grid, kernel):
    """Heights >= 2 kernel reaches above the floor and >= 1 reach below the top.

    Within one reach of the floor and the top spots below/above do not exist (no spots
    there, in the continuum as in the Monte Carlo); between one and two reaches above a
    narrow orifice the spot flux near the walls still changes fast with height, and the
    flux through a plane deviates by ``(1/2) int d_zz J_z Delta M2 dx`` (docs/walls.md:
    2.7e-3 at z = R in the 8 d silo, 4e-4 at z = 2R).
    """
    rz = kernel.reach[1]
    return (grid.z > grid.z_range[0] + 2.0 * rz) & (grid.z < grid.z_range[1] - rz - grid.spacing)


# -- 1. the particle flux through every height is V1 Q0 ------------------------------------

@pytest.mark.parametrize("width", [5.0, 8.0, 16.0])   # down to 2R
def test_particle_flux_is_V1_Q0_at_every_height_2d(width):
    kernel = kernels.Uniform(dims=2, **DISK)
    grid = Grid(2, (-width / 2, width / 2), (0.0, 40.0), 0.125)
    orifice = Orifice(x=0.0, width=2.0, rate=21.22)
    spots = Spots(b=1.3)
    rows = _away_from_floor_and_top(grid, kernel)
    ren = _flux_fraction(grid, orifice, spots, kernel, "renormalise")[rows]
    assert np.abs(ren - 1.0).max() < 1e-3
    # the check can fail: truncation loses the free volume beyond the walls
    cut = _flux_fraction(grid, orifice, spots, kernel, "truncate")[rows]
    assert cut.max() < 1.0 - 0.03 * 8.0 / width


@pytest.mark.parametrize("width, kernel", [
    (5.0, kernels.Uniform(dims=3, radius=2.5, height=0.0024)),
    (9.0, kernels.Uniform(dims=3, radius=2.5, height=0.0024)),
    (6.0, kernels.Gaussian(sigma=1.0, volume=0.05, dims=3, aspect=2.0)),
])
def test_particle_flux_is_V1_Q0_at_every_height_3d(width, kernel):
    grid = Grid(3, (-width / 2, width / 2), (0.0, 16.0), 0.25)
    orifice = Orifice(x=0.0, y=0.0, width=2.0, rate=5.0)
    spots = Spots(b=1.3)
    rows = _away_from_floor_and_top(grid, kernel)
    ren = _flux_fraction(grid, orifice, spots, kernel, "renormalise")[rows]
    assert np.abs(ren - 1.0).max() < 1e-3
    cut = _flux_fraction(grid, orifice, spots, kernel, "truncate")[rows]
    assert cut.max() < 0.9


# -- 2. uniform flow between walls: closed forms -------------------------------------------

SIG, V1, HALF, Q0, B = 1.0, 0.05, 3.0, 2.0, 1.3


def _normal(u, var):
    return math.exp(-u * u / (2.0 * var)) / math.sqrt(2.0 * math.pi * var)


def _closed_form(x, lam):
    """u_z, u_x, D_xx of uniform flow between walls at -HALF, HALF (Gaussian, 2D)."""
    m = lambda u: V1 * _normal(u, SIG**2)
    # w^2 = V1^2 / (2 pi sigma^2)^2 exp(-r^2/sigma^2): marginal V2 N(0, sigma^2/2)
    V2 = V1**2 / (4.0 * np.pi * SIG**2)
    m2 = lambda u: V2 * _normal(u, SIG**2 / 2.0)
    phi = lambda s: float(ndtr((HALF - s) / SIG) - ndtr((-HALF - s) / SIG))
    rho = Q0 / (2.0 * HALF)          # v_s = 1
    uz = np.array([-rho * integrate.quad(lambda s: m(xx - s) / phi(s), -HALF, HALF,
                                         epsabs=1e-14)[0] for xx in x])
    dxx = np.array([B * rho * integrate.quad(lambda s: m2(xx - s) / phi(s) ** 2, -HALF, HALF,
                                             epsabs=1e-14)[0] for xx in x])
    ux = (1.0 - 2.0 * lam) * B * rho * np.array([m(xx - HALF) / phi(HALF) - m(xx + HALF) / phi(-HALF)
                                                 for xx in x])
    return uz, ux, dxx


def _uniform_fields(h, lam, walls="renormalise", path="fast"):
    """``path``: "fast" (constant coefficients: bulk transform plus wall strips),
    "array" (the drift as a grid array: the general path, every source divided by phi
    and phi^2, one transform each) or "mask" (a material mask: the general path too)."""
    grid = Grid(2, (-HALF, HALF), (0.0, 16.0), h)
    orifice = Orifice(x=0.0, width=2.0 * HALF, rate=Q0)
    spots = Spots(b=B)
    rho = spot_density.steady(grid, orifice, spots)
    if path == "array":
        spots = Spots(drift=np.ones(grid.shape), b=B)
    mask = np.ones(grid.shape) if path == "mask" else None
    # the closed form is the mean-field one (the passage drift adds div(D_p - D_p_mf),
    # which is not zero where phi varies)
    f = C.particle_fields(grid, rho, spots, kernels.Gaussian(sigma=SIG, volume=V1, dims=2),
                          rule=lam, walls=walls, diffusivity="mean-field", mask=mask)
    k = int(np.argmin(np.abs(grid.z - 8.0)))
    return grid, {key: a[k] for key, a in f.items()}


@pytest.mark.parametrize("lam", [0.5, 1.0])
def test_uniform_flow_between_walls_matches_closed_form_at_second_order(lam):
    bulk = V1 * Q0 / (2.0 * HALF)
    errs = {}
    for h in (0.25, 0.125):
        grid, f = _uniform_fields(h, lam)
        uz, ux, dxx = _closed_form(grid.x, lam)
        errs[h] = (np.abs(f["u_z"] - uz).max() / bulk, np.abs(f["D_xx"] - dxx).max() / dxx.max())
        # the speed profile integrates to V1 Q0 (exactly, discretely)
        assert -f["u_z"].sum() * h == pytest.approx(V1 * Q0, rel=1e-12)
        if lam == 0.5:
            np.testing.assert_allclose(f["u_x"], 0.0, atol=1e-15)  # the wall layer cancels
        else:
            assert np.abs(f["u_x"] - ux).max() < 0.01 * np.abs(ux).max()
    # u_z: 4.9e-4; D_xx: 1.8e-3, in the wall cell, where 1/phi^2 is steepest
    assert errs[0.125][0] < 1e-3 and errs[0.125][1] < 2.5e-3
    # second order in h: the error falls by about 4 when h halves
    assert errs[0.25][0] / errs[0.125][0] > 3.5
    assert errs[0.25][1] / errs[0.125][1] > 3.5
    # at the wall: slower than the bulk (only half a kernel of spots reaches it) but
    # faster than the truncated kernel; the lost volume reappears in an overshoot
    # about one kernel width from the wall (the closed form's shape, docs/walls.md)
    grid, f = _uniform_fields(0.125, lam)
    _, t = _uniform_fields(0.125, lam, walls="truncate")
    assert -t["u_z"][0] < 0.6 * bulk < 0.7 * bulk < -f["u_z"][0] < 0.8 * bulk
    assert -f["u_z"].min() > 1.05 * bulk and -t["u_z"].min() < 1.0001 * bulk


@pytest.mark.parametrize("path", ["array", "mask"])
@pytest.mark.parametrize("lam", [0.5, 1.0])
def test_general_renormalised_path_matches_the_closed_form(path, lam):
    """The path of space-dependent coefficients (and of a material mask) meets the same
    closed forms as the constant-coefficient one: ``u_z`` (sources over phi), ``D_xx``
    (sources over phi^2) and the wall layer of rule 1, to the same second-order error."""
    bulk = V1 * Q0 / (2.0 * HALF)
    grid, f = _uniform_fields(0.125, lam, path=path)
    uz, ux, dxx = _closed_form(grid.x, lam)
    assert np.abs(f["u_z"] - uz).max() < 1e-3 * bulk
    assert np.abs(f["D_xx"] - dxx).max() < 2.5e-3 * dxx.max()
    assert -f["u_z"].sum() * grid.spacing == pytest.approx(V1 * Q0, rel=1e-12)
    if lam == 1.0:
        assert np.abs(f["u_x"] - ux).max() < 0.01 * np.abs(ux).max()
    # the same numbers as the fast path (which the closed-form test above checks)
    _, fast = _uniform_fields(0.125, lam)
    for key in ("u_z", "u_x", "D_xx"):
        scale = max(np.abs(fast[key]).max(), bulk)    # u_x of lam = 1/2 is round-off
        np.testing.assert_allclose(f[key], fast[key], rtol=0, atol=1e-12 * scale, err_msg=key)


def test_wall_layer_of_rule_one_is_divided_by_the_coverage_at_the_wall():
    """lam = 1: the push away from the walls is the truncated one divided by phi_w = 1/2."""
    grid, f = _uniform_fields(0.125, 1.0)
    _, t = _uniform_fields(0.125, 1.0, walls="truncate")
    near = np.abs(grid.x) > HALF - 2.0 * SIG
    np.testing.assert_allclose(f["u_x"][near], 2.0 * t["u_x"][near], rtol=2e-3)


# -- 3. coverage phi ---------------------------------------------------------------------

def test_coverage_is_the_kernel_fraction_inside_the_walls_2d_and_3d():
    for dims, h in ((2, 0.125), (3, 0.25)):
        k = kernels.Gaussian(sigma=SIG, volume=V1, dims=dims)
        grid = Grid(dims, (-HALF, HALF), (0.0, 4.0), h)
        phi = _walls.coverage(grid, k)
        one = stats.norm.cdf((HALF - grid.x) / SIG) - stats.norm.cdf((-HALF - grid.x) / SIG)
        expect = one if dims == 2 else one[None, :] * one[:, None]   # corners: a product
        err = np.abs(phi - expect).max()
        assert err < 2e-3 * h / 0.125   # cell averages of w against point values: O(h^2)
        # open walls: no wall, phi = 1 everywhere
        g_open = Grid(dims, (-HALF, HALF), (0.0, 4.0), h, walls="open")
        np.testing.assert_allclose(_walls.coverage(g_open, k), 1.0, atol=1e-13)


def test_monte_carlo_table_matches_the_disk_closed_form():
    """The Monte Carlo's phi of the disk: the circle segment area fraction."""
    R, a = 2.5, 0.0024
    x0, dx, tab = _walls.coverage_table("uniform", R, R, a, (R, R), -4.0, 4.0)
    xs = x0 + dx * np.arange(tab.size)
    d = np.clip((4.0 - np.abs(xs)) / R, -1, 1)         # distance to the nearer wall / R
    seg = (np.arccos(d) - d * np.sqrt(1 - d * d)) / np.pi   # area fraction beyond it
    np.testing.assert_allclose(tab, 1.0 - seg, atol=1e-12)


def test_monte_carlo_table_of_smooth_kernels():
    """Gaussian: phi = Phi((x1 - s)/sigma) - Phi((x0 - s)/sigma) up to the cut-off (1e-6 of V1).

    Exponential (no closed form): 1/2 on a wall and symmetric, as for every even kernel.
    """
    from spotpde import montecarlo as mc

    kp = mc.kernel_params(kernels.Gaussian(sigma=1.0, volume=V1, dims=2, aspect=2.0))
    x0, dx, tab = _walls.coverage_table("gaussian", kp.size, kp.size_v, kp.amp, kp.reach,
                                        -3.0, 3.0)
    xs = x0 + dx * np.arange(tab.size)
    np.testing.assert_allclose(tab, ndtr(3.0 - xs) - ndtr(-3.0 - xs), atol=2e-5)
    kp = mc.kernel_params(kernels.Exponential(length=0.5, volume=V1, dims=2))
    x0, dx, tab = _walls.coverage_table("exponential", kp.size, kp.size_v, kp.amp, kp.reach,
                                        -8.0, 8.0)   # wider than 2 reaches (6.9 d each)
    assert tab[0] == pytest.approx(0.5, abs=1e-6) and tab[-1] == pytest.approx(0.5, abs=1e-6)
    np.testing.assert_allclose(tab, tab[::-1], atol=1e-9)
    assert tab[tab.size // 2] == pytest.approx(1.0, abs=1e-9)


# -- 4. options, bit-for-bit truncation, validation ------------------------------------------

def test_renormalise_changes_nothing_far_from_walls_and_with_open_walls():
    k = kernels.Uniform(dims=2, **DISK)
    spots = Spots(b=1.3)
    orifice = Orifice(x=0.0, width=2.0, rate=1.0)
    g = Grid(2, (-12.0, 12.0), (0.0, 20.0), 0.25)
    rho = spot_density.steady(g, orifice, spots)
    for lam in (0.5, 1.0):
        a = C.particle_fields(g, rho, spots, k, rule=lam)
        b = C.particle_fields(g, rho, spots, k, rule=lam, walls="truncate")
        far = np.abs(g.x) < 12.0 - 2.0 * 2.5 - 0.25   # spots with phi < 1 lie within R of a wall
        for key in a:
            scale = np.abs(b[key]).max() or 1.0
            np.testing.assert_allclose(a[key][:, far], b[key][:, far], atol=1e-12 * scale)
    g_open = Grid(2, (-12.0, 12.0), (0.0, 20.0), 0.25, walls="open")
    a = C.particle_fields(g_open, rho, spots, k)
    b = C.particle_fields(g_open, rho, spots, k, walls="truncate")
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])


def test_bad_walls_argument_and_case_key():
    k = kernels.Uniform(dims=2, **DISK)
    g = Grid(2, (-4.0, 4.0), (0.0, 8.0), 0.5)
    with pytest.raises(ValueError, match="^walls: must be one of"):
        C.particle_fields(g, np.ones(g.shape), Spots(), k, walls="reflect")
    with pytest.raises(spotpde.CaseError) as e:
        spotpde.load_case({"kernel": {"walls": "renormalize"}})
    assert str(e.value).startswith("kernel.walls: must be one of")
    assert len(str(e.value).splitlines()) == 1
    assert spotpde.load_case({}).kernel_walls == "renormalise"


def test_cli_check_rejects_a_bad_wall_treatment(tmp_path, capsys):
    from spotpde import cli

    bad = tmp_path / "bad.toml"
    bad.write_text('[kernel]\nwalls = "reflect"\n')
    assert cli.main(["check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.strip().splitlines() == [
        'kernel.walls: must be one of "renormalise", "truncate", got "reflect"']


def test_pipeline_records_the_wall_treatment():
    case = {"domain": {"x": [-4.0, 4.0], "z": [0.0, 10.0], "spacing": 0.5},
            "kernel": {"shape": "uniform", "size": 2.5, "height": 0.0024},
            "orifice": {"width": 2.0, "rate": 21.22}}
    fluxes = {}
    for walls in ("renormalise", "truncate"):
        c = dict(case, kernel=dict(case["kernel"], walls=walls))
        ds = spotpde.run(spotpde.load_case(c))
        assert ds.attrs["kernel_walls"] == walls
        fluxes[walls] = float(-ds["u_z"].sel(z=5.0, method="nearest").sum() * 0.5)
    V1 = 0.0024 * np.pi * 2.5**2
    assert fluxes["renormalise"] == pytest.approx(V1 * 21.22, rel=1e-3)
    assert fluxes["truncate"] < 0.9 * V1 * 21.22


# -- 5. the discrete spot model with the same treatment -------------------------------------

@pytest.mark.slow
def test_monte_carlo_wall_profile_matches_the_renormalised_continuum():
    """Uniform flow in an 8 d silo (paper's disk), probes of the discrete model vs the grid.

    Six independent seeds are the replicas (their scatter gives the standard error); the
    first tenth of each run (the spots filling the silo) is dropped. ``b = 0.1`` keeps
    the horizontal spot step (0.24 d) small against R, so that the discrete model is in
    its continuum limit at the wall (with b = 1.3, step 0.6 d, the reflected steps lower
    the speed in the wall cell by 5 %); the continuum profile does not depend on b.
    """
    from spotpde import montecarlo as mc

    half = 4.0
    g = Grid(2, (-half, half), (0.0, 12.0), 0.25)
    k = kernels.Uniform(dims=2, **DISK)
    orifice = Orifice(x=0.0, width=2 * half, rate=20.0)
    spots = Spots(drift=1.0, b=0.1)
    rows = (g.z > 4.0) & (g.z < 8.0)          # > R above the floor and below the top
    sym = lambda p: 0.5 * (p + p[::-1])       # the two walls are mirror images
    bulk = k.V1 * 20.0 / (2 * half)
    rho = spot_density.steady(g, orifice, spots)
    cont = {w: sym(C.particle_fields(g, rho, spots, k, walls=w)["u_z"][rows].mean(0)) / bulk
            for w in ("renormalise", "truncate")}
    prof = []
    for seed in range(1, 7):
        r = mc.simulate(g, orifice, spots, k, rule=0.5, t_end=300.0, seed=seed, step=0.3,
                        batches=10, walls="renormalise")
        dur = r.batch_ticks[1:].sum() * r.dt
        prof.append(sym(r.probe[1, 1:].sum(0)[rows].mean(0) / dur) / bulk)
    prof = np.array(prof)
    mean, se = prof.mean(0), prof.std(0, ddof=1) / np.sqrt(len(prof))
    near = np.abs(g.x) > half - 2.5          # within R of a wall
    z_ren = np.abs(mean - cont["renormalise"])[near] / se[near]
    z_cut = np.abs(mean - cont["truncate"])[near] / se[near]
    assert z_ren.max() < 4.0                  # 16 correlated cells: 4 SE
    assert z_cut.min() > 10.0                 # the truncated profile is rejected


# -- 6. the lam-rule terms and the wall layer against the exact discrete-step average --------

@pytest.mark.slow
@pytest.mark.parametrize("rule", [0.0, 0.5, 1.0])
def test_renormalised_wall_layer_matches_the_discrete_rule(rule):
    """Signs and sizes of the lam terms: 2 lam rho D grad(phi)/phi^2 and the wall layer / phi."""
    sigma, b, rho0, L = 1.0, 1.3, 2.0, 6.0
    kernel = kernels.Gaussian(sigma=sigma, volume=V1, dims=2)
    grid = Grid(2, (-L, L), (0.0, 24.0), 0.25, walls="reflecting")
    f = C.particle_fields(grid, np.full(grid.shape, rho0), Spots(drift=1.0, b=b), kernel,
                          rule=rule)
    k = grid.nz // 2
    W = lambda x: V1 * stats.norm.pdf(x, scale=sigma)
    phi = lambda s: stats.norm.cdf((L - s) / sigma) - stats.norm.cdf((-L - s) / sigma)
    scale = b * rho0 * W(0.0)
    for i in (grid.nx - 1, grid.nx - 4, 2):
        exact = discrete_rule_drift(grid.x[i], rule, W, b, rho0, L, phi=phi)
        # the truncated check's tolerance (2e-3 of scale) relative to the push, which is
        # twice as large here; it includes the reference's own O(eps) error (8e-4 of scale)
        assert abs(f["u_x"][k, i] - exact) < 4e-3 * scale, (i, f["u_x"][k, i], exact)
    if rule == 1.0:   # twice the truncated push: phi = 1/2 at the wall
        assert f["u_x"][k, -1] < -1.0 * scale and f["u_x"][k, 0] > 1.0 * scale


def test_kinematic_comparison_reports_the_flux_of_the_wall_treatment():
    from spotpde.analysis import comparison

    g = Grid(2, (-4.0, 4.0), (0.0, 24.0), 0.25)
    parts = dict(grid=g, orifice=Orifice(x=0.0, width=2.0, rate=1.0), spots=Spots(b=1.3),
                 kernel=kernels.Uniform(dims=2, **DISK))
    deficit = {w: comparison.compare_with_kinematic(dict(parts, walls=w), n_streamlines=3)
               .flux_deficit for w in ("renormalise", "truncate")}
    high = slice(len(deficit["truncate"]) // 2, None)   # heights where J_z is nearly uniform
    assert np.abs(deficit["renormalise"][high]).max() < 1e-3
    assert deficit["truncate"][high].min() > 0.1        # 13 % lost in an 8 d silo


def test_monte_carlo_records_and_validates_the_wall_treatment():
    from spotpde import montecarlo as mc

    g = Grid(2, (-3.0, 3.0), (0.0, 4.0), 0.5)
    k = kernels.Uniform(dims=2, **DISK)
    args = (g, Orifice(x=0.0, width=6.0, rate=2.0), Spots(b=1.3), k)
    with pytest.raises(ValueError, match="walls: must be one of"):
        mc.simulate(*args, t_end=1.0, walls="mirror")
    r = mc.simulate(*args, t_end=1.0, walls="truncate")
    assert r.walls == "truncate" and mc.measure(r).attrs["kernel_walls"] == "truncate"
