"""The passage diffusivity: the discrete spot model's Lagrangian diffusion in uniform flow.

spotpde.fields._passage.length_tensor against closed forms (Gaussian kernel, straight paths,
rules 0 and 1), the paper's-disk reference numbers, a direct passage Monte Carlo of the
discrete model at decreasing step size, the pair tensor's limits, and the local form in
coefficients.particle_fields, the case key and a tracer run on passage fields.
"""

from __future__ import annotations

import math
import subprocess
import sys
import warnings

import numpy as np
import pytest
from scipy import integrate, special

import spotpde
from spotpde.fields import _passage as P
from spotpde.fields import coefficients as C
from spotpde.fields import kernels
from spotpde import montecarlo
from spotpde.density import spot_density
from spotpde.grid import Grid
from spotpde.parameters import Orifice, Spots

B = 1.3
W = 0.0024
DISK = kernels.Uniform(radius=2.5, height=W, dims=2)


# -- closed forms --------------------------------------------------------------------------

def _gaussian_closed_form(kernel, b, lam):
    """b_p of a Gaussian kernel with b_par = 0: the k_z integral in closed form,
    int dk_z/2pi exp(-k_z^2 s_z^2) G / (G^2 + k_z^2) = erfcx(G s_z) / 2, G = b k^2,
    then one k integral by scipy (docs/coefficients.md)."""
    s, sz, V1 = kernel.sigma, kernel.sigma / kernel.aspect, kernel.V1
    c = 8.0 * lam * (1.0 - lam) * b * b

    def f(k, p):  # |w^|^2 (k_z integral done) times k^p
        return V1 * V1 * np.exp(-(k * s) ** 2) * 0.5 * special.erfcx(b * k * k * sz) * k**p

    def q(p):  # int_0^inf f k^p dk / 2pi
        return integrate.quad(f, 0, np.inf, args=(p,), epsabs=0, epsrel=1e-12)[0] / (2 * np.pi)

    if kernel.dims == 2:  # int dk_x / 2pi over the whole line
        xx, zz = -c * 2 * q(2), 2.0 * 2 * q(0)
    else:  # int d^2k / (2pi)^2 = int k dk / 2pi; k_x^2 -> k^2 / 2
        xx, zz = -c * 0.5 * q(3), 2.0 * q(1)
    return {"xx": b * kernel.V2 / V1 + xx / (2 * V1), "zz": zz / (2 * V1)}


@pytest.mark.parametrize("dims,aspect", [(2, 1.0), (2, 2.0), (3, 1.0), (3, 0.5)])
@pytest.mark.parametrize("lam", [0.25, 0.5])
def test_gaussian_closed_form(dims, aspect, lam):
    kernel = kernels.Gaussian(sigma=1.0, volume=0.05, dims=dims, aspect=aspect)
    got = P.length_tensor(kernel, B, 0.0, lam)
    want = _gaussian_closed_form(kernel, B, lam)
    assert got["xx"] == pytest.approx(want["xx"], rel=2e-4)
    assert got["zz"] == pytest.approx(want["zz"], rel=2e-4)
    assert got["xz"] == 0.0
    if dims == 3:
        assert got["yy"] == got["xx"] and got["xy"] == got["yz"] == 0.0
    # the correction is a real reduction, far beyond the quadrature error
    assert got["xx"] < 0.9 * B * kernel.V2 / kernel.V1


@pytest.mark.parametrize("b, bp", [(1.3, 0.6), (0.3, 2.8)])
def test_b_par_against_adaptive_quadrature(b, bp):
    """b_par > 0 (the pole pair of 1/Gamma, the k_z-dependent N): the grid quadrature
    against scipy's adaptive double integral of the same integrand. A long vertical
    length (the paper's b_par = 2.8 d) with a short horizontal one puts the pole's
    residue far from its b_par = 0 value: the subtraction must use the true pole
    ``k_z = i kappa``, ``kappa = 2 G / (1 + sqrt(1 + 4 b_par G))``, or the grid's error
    reaches 5e-4 in ``zz`` (measured with ``1 + 2 b_par G``; 3e-5 at the first pair)."""
    kernel = kernels.Gaussian(sigma=1.0, volume=0.05, dims=2, aspect=1.5)
    lam = 0.5
    s, sz, V1 = kernel.sigma, kernel.sigma / kernel.aspect, kernel.V1

    def M(kz, kx, key):
        gam = b * kx * kx + bp * kz * kz + 1j * kz
        Dk = (b * kx, bp * kz)
        if key == "xx":
            N = -8 * lam * (1 - lam) * Dk[0] ** 2
            return 2 * b + (N / gam).real
        N = 2 - 8 * lam * (1 - lam) * Dk[1] ** 2 - 4j * Dk[1]
        return 2 * bp + (N / gam).real

    def inner(kx, key):  # the Lorentzian in k_z has width ~ G = b k_x^2: tell quad
        G = b * kx * kx
        f = lambda kz: np.exp(-(kx * s) ** 2 - (kz * sz) ** 2) * M(kz, kx, key)
        pts = sorted(p for p in {0.0, G, -G, 10 * G, -10 * G} if -30 < p < 30)
        return integrate.quad(f, -30, 30, points=pts, limit=500, epsabs=1e-11, epsrel=1e-10)[0]

    got = P.length_tensor(kernel, b, bp, lam)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", integrate.IntegrationWarning)
        for key in ("xx", "zz"):
            val = 2 * integrate.quad(inner, 0, 12, args=(key,), limit=200, epsabs=1e-11,
                                     epsrel=1e-10)[0]
            want = V1 * V1 * val / (2 * np.pi) ** 2 / (2 * V1)
            assert got[key] == pytest.approx(want, rel=1e-4), key


@pytest.mark.parametrize("kernel", [
    DISK,
    kernels.Exponential(length=0.8, volume=0.03, dims=2, aspect=2.0),
    kernels.Gaussian(sigma=1.0, volume=0.05, dims=3, aspect=0.7),
], ids=["disk", "exponential", "gaussian3d"])
@pytest.mark.parametrize("lam", [0.0, 1.0])
def test_rules_0_and_1_are_mean_field_horizontally(kernel, lam):
    """Ito (lam 0) is a martingale; lam 1 is its time reversal: D_xx = V2 rho_s D_s."""
    got = P.length_tensor(kernel, B, 0.0, lam)
    assert got["xx"] == pytest.approx(B * kernel.V2 / kernel.V1, rel=1e-9)
    # while lam 1/2 is well below it
    assert P.length_tensor(kernel, B, 0.0, 0.5)["xx"] < 0.9 * B * kernel.V2 / kernel.V1


def test_paper_disk_reference_numbers():
    """R = 2.5, w = 0.0024, b = 1.3, b_par = 0 (independently computed numbers)."""
    got = P.length_tensor(DISK, B, 0.0, 0.5)
    assert got["xx"] / (W * B) == pytest.approx(1 - 1.6455 / 4, abs=3e-4)
    assert got["zz"] / W == pytest.approx(1.536, abs=2e-3)
    # the shot noise does not depend on the rule
    assert P.length_tensor(DISK, B, 0.0, 1.0)["zz"] == pytest.approx(got["zz"], rel=1e-9)


def test_straight_path_limit_of_the_shot_noise():
    """b -> 0: each spot crosses on a straight line, b_p_par = int (int w dz)^2 dx / 2V1."""
    R = 2.5
    got = P.length_tensor(DISK, 1e-7, 0.0, 0.5)["zz"]
    assert got == pytest.approx(8 * W * R / (3 * np.pi), rel=2e-4)
    sphere = kernels.Uniform(radius=R, height=W, dims=3)
    got3 = P.length_tensor(sphere, 1e-7, 0.0, 0.5)["zz"]
    # 3D: int (2 w sqrt(R^2 - r^2))^2 2 pi r dr / 2 V1 = pi w^2 R^4 / V1 = 3 w R / 4
    assert got3 == pytest.approx(math.pi * W * W * R**4 / sphere.V1, rel=2e-3)


def test_uniform_flow_prediction_uses_the_quadrature():
    pred = montecarlo.uniform_flow_prediction(DISK, B, 0.25, rule=0.5)
    assert np.isfinite(pred["D_xx"])
    assert pred["b_p"] == pytest.approx(P.length_tensor(DISK, B, 0.0, 0.5)["xx"], rel=1e-12)
    assert pred["D_xx"] == pytest.approx(pred["D_xx_meanfield"] - 0.25 * 0.25 * pred["EY2"] / 2,
                                         rel=1e-9)
    assert pred["EY2"] / (8 * DISK.V1 * W * B) == pytest.approx(1.6455 / 4, abs=3e-4)


def test_bad_arguments():
    with pytest.raises(ValueError, match="b:"):
        P.length_tensor(DISK, -1.0)
    with pytest.raises(ValueError, match="b_par"):
        P.length_tensor(DISK, 1.0, -0.1)
    with pytest.raises(ValueError, match="rule"):
        P.length_tensor(DISK, 1.0, 0.0, 1.5)
    with pytest.raises(ValueError, match="diffusivity"):
        P.length_tensor(DISK, 1.0, diffusivity="meanfield")
    with pytest.raises(ValueError, match="separation"):
        P.length_tensor(DISK, 1.0, separation=(np.zeros(3),))
    with pytest.raises(TypeError, match="kernel"):
        P.length_tensor("disk", 1.0)


# -- the discrete model: a direct passage Monte Carlo ------------------------------------------

def _passages(kernel, b, lam, step, n, seed, X=20.0, Z=7.0):
    """int dx0 E[Y_i Y_j] / 2 V1 for spots crossing a fixed particle at the origin.

    Uniform flow in a box periodic in x (width 2X): spot passages are independent, each
    starts at a uniform offset x0 at height -Z and walks up with steps (N(0, 2 b step), step),
    displacing the particle by -w(r_p - r_s - lam dR) dR per step (the discrete model; the
    particle's own O(w) motion during one passage is neglected).
    """
    rng = np.random.default_rng(seed)
    x = rng.uniform(-X, X, n)
    z = np.full(n, -Z)
    Y = np.zeros((2, n))
    sd = math.sqrt(2 * b * step)
    for _ in range(int(math.ceil(2 * Z / step))):
        dx = rng.normal(0.0, sd, n)
        w = kernel.evaluate(-x - lam * dx, -z - lam * step)
        Y[0] -= w * dx
        Y[1] -= w * step
        x += dx
        z += step
    norm = 2 * X / (2 * kernel.V1)
    return norm * np.mean(Y[0] ** 2), norm * np.mean(Y[1] ** 2)


@pytest.mark.slow
@pytest.mark.parametrize("lam", [0.0, 0.25, 0.5, 1.0])
def test_direct_passage_monte_carlo_extrapolated_in_the_step(lam):
    """The discrete model at steps 0.2 and 0.1 d, extrapolated linearly to step 0, against
    the quadrature within 3.5 standard errors (independent replicas, i.e. independent seeds)."""
    kernel = kernels.Gaussian(sigma=1.0, volume=0.05, dims=2)
    reps = 6
    est = {}
    for step in (0.2, 0.1):
        r = np.array([_passages(kernel, B, lam, step, 40_000, seed=int(1000 * step) + i)
                      for i in range(reps)])
        est[step] = (r.mean(axis=0), r.std(axis=0, ddof=1) / math.sqrt(reps))
    mean = 2 * est[0.1][0] - est[0.2][0]
    se = np.sqrt(4 * est[0.1][1] ** 2 + est[0.2][1] ** 2)
    want = P.length_tensor(kernel, B, 0.0, lam)
    for i, key in enumerate(("xx", "zz")):
        assert abs(mean[i] - want[key]) < 3.5 * se[i], (key, mean[i], want[key], se[i])
        assert se[i] < 0.03 * want[key]
    if lam == 0.5:  # the mean field is excluded
        assert B * kernel.V2 / kernel.V1 - mean[0] > 10 * se[0]


# -- pairs --------------------------------------------------------------------------------------

def test_pair_tensor_paper_disk():
    dx = np.array([1.0, 1.5, 2.0, 40.0])
    sep = (dx, np.zeros_like(dx))
    got = P.length_tensor(DISK, B, 0.0, 0.5, separation=sep)
    mf = P.length_tensor(DISK, B, 0.0, 0.5, diffusivity="mean-field", separation=sep)
    np.testing.assert_allclose(got["xx"][:3] / mf["xx"][:3], [0.20, 0.26, 0.30], atol=0.01)
    # far apart the two particles diffuse independently: B -> 2 b_p
    one = P.length_tensor(DISK, B, 0.0, 0.5)
    assert got["xx"][-1] == pytest.approx(2 * one["xx"], rel=2e-3)
    assert got["zz"][-1] == pytest.approx(2 * one["zz"], rel=2e-3)
    # horizontal separations: no xz coupling (mirror symmetry z -> -z is broken, x -> -x not)
    assert np.all(np.abs(got["xz"]) < 1e-4 * got["xx"])


@pytest.mark.parametrize("kernel", [DISK, kernels.Gaussian(sigma=1.0, volume=0.05, dims=2,
                                                           aspect=2.0)], ids=["disk", "gauss"])
def test_pair_tensor_rule_1_is_mean_field(kernel):
    rng = np.random.default_rng(3)
    dx, dz = rng.uniform(-4, 4, 20), rng.uniform(-4, 4, 20)
    got = P.length_tensor(kernel, B, 0.0, 1.0, separation=(dx, dz))
    mf = P.length_tensor(kernel, B, 0.0, 1.0, diffusivity="mean-field", separation=(dx, dz))
    scale = 2 * B * kernel.V2 / kernel.V1
    np.testing.assert_allclose(got["xx"], mf["xx"], rtol=0, atol=2e-3 * scale)
    # symmetry: B(-Delta) = B(Delta)
    back = P.length_tensor(kernel, B, 0.0, 1.0, separation=(-dx, -dz))
    for k in got:
        np.testing.assert_allclose(back[k], got[k], rtol=0, atol=1e-6 * scale)
    # B is a covariance rate: positive semi-definite at every separation
    assert np.all(got["xx"] * got["zz"] - got["xz"] ** 2 > -1e-6 * scale**2)


@pytest.mark.slow
def test_pair_tensor_3d_axes():
    """3D: a separation along x seen by xx equals the same separation along y seen by yy."""
    kernel = kernels.Gaussian(sigma=1.0, volume=0.05, dims=3)
    r = np.array([1.0, 2.0])
    z0 = np.zeros(2)
    a = P.length_tensor(kernel, B, 0.2, 0.5, separation=(r, z0, z0))
    b = P.length_tensor(kernel, B, 0.2, 0.5, separation=(z0, r, z0))
    np.testing.assert_allclose(a["xx"], b["yy"], rtol=1e-3)
    np.testing.assert_allclose(a["yy"], b["xx"], rtol=1e-3)
    np.testing.assert_allclose(a["zz"], b["zz"], rtol=1e-3)


# -- the local form in particle_fields ------------------------------------------------------------

def _uniform_flow(dims, kernel, b=B, b_par=0.0):
    """Orifice across the whole floor: rho_s = Q0 / (W v_s) everywhere (reflecting walls)."""
    h = 0.5 if dims == 2 else 1.0
    g = Grid(dims, (-12.0, 12.0), (0.0, 24.0), h)
    spots = Spots(drift=1.5, b=b, b_par=b_par)
    rho = spot_density.steady(g, Orifice(x=0.0, width=24.0, rate=3.0), spots)
    return g, spots, rho


@pytest.mark.parametrize("dims", [2, 3])
@pytest.mark.parametrize("shape", ["uniform", "gaussian"])
def test_particle_fields_in_uniform_flow_equal_the_quadrature(dims, shape):
    kernel = kernels.from_spec(shape, 1.5, 0.03, dims=dims)
    g, spots, rho = _uniform_flow(dims, kernel)
    ix = tuple(n // 2 for n in g.shape)
    flux = float(rho[ix]) * 1.5
    for lam in (0.0, 0.25, 0.5, 1.0):
        f = C.particle_fields(g, rho, spots, kernel, rule=lam)
        want = P.length_tensor(kernel, B, 0.0, lam)
        for key in ("xx", "zz") + (("yy",) if dims == 3 else ()):
            assert f["D_" + key][ix] / (kernel.V1 * flux) == pytest.approx(want[key], rel=1e-6)
        assert f["D_xz"][ix] == 0.0
    mf = C.particle_fields(g, rho, spots, kernel, rule=0.5, diffusivity="mean-field")
    assert mf["D_zz"][ix] == 0.0   # b_par = 0: no vertical mean-field diffusion
    assert f["D_zz"][ix] > 0.0     # but shot noise


def test_particle_fields_variable_b_uses_the_local_length():
    """A b field with two values: far from the interface each side has its own uniform-flow
    tensor; a smooth field goes through the Chebyshev table."""
    kernel = kernels.Gaussian(sigma=1.0, volume=0.05, dims=2)
    g, _, _ = _uniform_flow(2, kernel)
    rho = np.full(g.shape, 0.2)
    X = np.broadcast_to(g.x[None, :], g.shape)
    bf = np.where(X < 0.0, 0.8, 1.6)
    # truncated walls: renormalised sources within a kernel reach of the walls at +-12 d
    # would feel phi < 1 at x = +-8 (docs/walls.md); this test is about the local tensor
    f = C.particle_fields(g, rho, Spots(drift=1.0, b=bf), kernel, rule=0.5, walls="truncate")
    k = g.shape[0] // 2
    for x0, b in ((-8.0, 0.8), (8.0, 1.6)):
        i = int(np.argmin(np.abs(g.x - x0)))
        want = P.length_tensor(kernel, b, 0.0, 0.5)
        assert f["D_xx"][k, i] / (kernel.V1 * 0.2) == pytest.approx(want["xx"], rel=1e-6)
        assert f["D_zz"][k, i] / (kernel.V1 * 0.2) == pytest.approx(want["zz"], rel=1e-6)
    smooth = 1.0 + 0.5 * np.sin(X / 3.0) ** 2
    fs = C.particle_fields(g, rho, Spots(drift=1.0, b=smooth), kernel, rule=0.5,
                           walls="truncate")
    sp = Spots(drift=1.0, b=smooth)
    src = P.source_tensor(g, sp, C.spot_diffusivity(g, sp), kernel, 0.5)
    i = int(np.argmin(np.abs(g.x - 2.0)))
    exact = P.effective_spot_length(kernel, float(smooth[k, i]), 0.0, 0.5)["xx"]
    assert src["D_xx"][k, i] == pytest.approx(exact, rel=1e-6)
    assert np.all(fs["D_xx"] >= 0) and np.all(fs["D_zz"] >= 0)


def test_mean_field_option_is_the_old_eq_Dp():
    kernel = kernels.Uniform(radius=1.5, height=0.01, dims=2)
    g, spots, rho = _uniform_flow(2, kernel, b_par=0.3)
    f = C.particle_fields(g, rho, spots, kernel, rule=0.5, diffusivity="mean-field")
    ix = (g.shape[0] // 2, g.shape[1] // 2)
    assert f["D_xx"][ix] == pytest.approx(kernel.V2 * rho[ix] * spots.D_perp, rel=1e-10)
    assert f["D_zz"][ix] == pytest.approx(kernel.V2 * rho[ix] * spots.D_par, rel=1e-10)
    with pytest.raises(ValueError, match="diffusivity"):
        C.particle_fields(g, rho, spots, kernel, diffusivity="exact")
    # the mean flow (probability-flux velocity) is the same for both diffusivities; the
    # drift itself differs by div(D_p - D_p_mf), zero in uniform flow
    p = C.particle_fields(g, rho, spots, kernel, rule=0.5)
    fp, fm = C.flux_velocity(g, p), C.flux_velocity(g, f)
    for a in ("u_x", "u_z"):
        np.testing.assert_allclose(fp[a], fm[a], rtol=0, atol=1e-13 * np.abs(fm["u_z"]).max())
    assert p["u_z"][ix] == pytest.approx(f["u_z"][ix], rel=1e-10)


def test_passage_keeps_the_mean_flow_in_a_converging_silo():
    """Point orifice, variable b: u_p - div D_p is the mean field's, D_p is not."""
    kernel = kernels.Gaussian(sigma=1.0, volume=0.05, dims=2)
    g = Grid(2, (-10.0, 10.0), (0.0, 20.0), 0.25)
    X = np.broadcast_to(g.x[None, :], g.shape)
    spots = Spots(drift=1.0, b=1.0 + 0.4 * np.cos(X / 4.0) ** 2, b_par=0.2)
    rho = spot_density.steady(g, Orifice(x=0.0, width=2.0, rate=1.0), spots)
    p = C.particle_fields(g, rho, spots, kernel, rule=0.5)
    m = C.particle_fields(g, rho, spots, kernel, rule=0.5, diffusivity="mean-field")
    fp, fm = C.flux_velocity(g, p), C.flux_velocity(g, m)
    scale = np.abs(fm["u_z"]).max()
    for a in ("u_x", "u_z"):
        np.testing.assert_allclose(fp[a], fm[a], rtol=0, atol=1e-12 * scale)
    assert np.abs(p["D_xx"] - m["D_xx"]).max() > 0.2 * np.abs(m["D_xx"]).max()


# -- the case key, the Dataset and a tracer on passage fields ------------------------------

def _case(**kernel):
    return {"domain": {"dims": 2, "x": [-8.0, 8.0], "z": [0.0, 16.0], "spacing": 0.5},
            "orifice": {"width": 4.0, "rate": 1.0},
            "kernel": {"shape": "gaussian", "size": 1.0, "volume": 0.2, **kernel},
            "tracer": {"start": {"x": 0.0, "z": 10.0, "width": 1.0}, "t_end": 20.0, "frames": 3}}


def test_case_key_and_dataset_attribute_and_tracer():
    case = spotpde.load_case(_case())
    ds = spotpde.run(case)
    assert ds.attrs["diffusivity"] == "passage"
    P_ = ds["P"].values
    assert P_.min() >= -1e-12 * P_.max()
    budget = ds["mass"].values + ds["outflow"].values
    np.testing.assert_allclose(budget, 1.0, atol=1e-6)
    mf = spotpde.run(spotpde.load_case(_case(diffusivity="mean-field")))
    assert mf.attrs["diffusivity"] == "mean-field"
    assert float(mf["D_zz"].max()) == 0.0 < float(ds["D_zz"].max())
    # the same mean flow: u_p - div D_p
    g = case.grid
    fp = C.flux_velocity(g, {k: ds[k].values for k in ("u_x", "u_z", "D_xx", "D_xz", "D_zz")})
    fm = C.flux_velocity(g, {k: mf[k].values for k in ("u_x", "u_z", "D_xx", "D_xz", "D_zz")})
    np.testing.assert_allclose(fp["u_z"], fm["u_z"], rtol=0, atol=1e-12 * np.abs(fm["u_z"]).max())


def test_unknown_diffusivity_is_an_invalid_case(tmp_path):
    with pytest.raises(spotpde.CaseError, match="kernel.diffusivity"):
        spotpde.load_case(_case(diffusivity="exact"))
    path = tmp_path / "bad.toml"
    path.write_text('[kernel]\ndiffusivity = "meanfield"\n')
    out = tmp_path / "out.nc"
    r = subprocess.run([sys.executable, "-m", "spotpde", "run", str(path), "-o", str(out)],
                       capture_output=True, text=True)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "kernel.diffusivity" in lines[0] and "mean-field" in lines[0]
    assert "Traceback" not in r.stderr and not out.exists()


def test_pair_diffusivity_passage_option_in_uniform_flow():
    """coefficients.pair_diffusivity: mean field from the quadrature of the fields, plus the
    passage correction; in uniform flow it is V1 f B_passage(Delta)."""
    kernel = kernels.Gaussian(sigma=1.0, volume=0.05, dims=2)
    g = Grid(2, (-10.0, 10.0), (0.0, 20.0), 0.25)
    rho = np.full(g.shape, 0.4)
    spots = Spots(drift=1.5, b=B)
    r1, r2 = (0.6, 10.0), (-0.9, 10.0)
    pa = C.pair_diffusivity(g, rho, spots, kernel, r1, r2, rule=0.5)
    mf = C.pair_diffusivity(g, rho, spots, kernel, r1, r2, diffusivity="mean-field")
    want = P.length_tensor(kernel, B, 0.0, 0.5, separation=(np.array([1.5]), np.array([0.0])))
    f = 0.4 * 1.5
    assert pa["D_xx"] == pytest.approx(kernel.V1 * f * want["xx"][0], rel=2e-3)
    assert pa["D_zz"] == pytest.approx(kernel.V1 * f * want["zz"][0], rel=2e-3)
    assert pa["D_xx"] < 0.8 * mf["D_xx"]
    one = C.pair_diffusivity(g, rho, spots, kernel, r1, r2, rule=1.0)
    assert one["D_xx"] == pytest.approx(mf["D_xx"], rel=2e-3)


@pytest.mark.slow
def test_source_tensor_table_when_b_and_b_par_both_vary():
    """Both lengths as fields: the 6 x 6 Chebyshev table against direct quadratures."""
    kernel = kernels.Gaussian(sigma=1.0, volume=0.05, dims=2)
    g = Grid(2, (-10.0, 10.0), (0.0, 20.0), 0.5)
    Z, X = np.broadcast_arrays(*g.mesh())
    sp = Spots(drift=1.0 + 0.1 * Z / 20, b=1.0 + 0.5 * np.sin(X / 3) ** 2,
               b_par=0.1 + 0.3 * Z / 20)
    src = P.source_tensor(g, sp, C.spot_diffusivity(g, sp), kernel, 0.5)
    for i, j in ((3, 5), (20, 30), (39, 39)):
        be = P.effective_spot_length(kernel, float(sp.b[i, j]), float(sp.b_par[i, j]), 0.5)
        v = float(sp.drift[i, j])
        assert src["D_xx"][i, j] == pytest.approx(v * be["xx"], rel=1e-6)
        assert src["D_zz"][i, j] == pytest.approx(v * be["zz"], rel=1e-6)


def test_pair_diffusivity_passage_is_each_particles_own_plus_the_passage_cross_term():
    """In a converging flow the passage pair tensor is D_p(r1) + D_p(r2) (each particle's
    own passage diffusivity, as particle_fields gives it) minus twice the cross term; a pair
    side by side and 12 d apart shares no spot, so the cross term vanishes there."""
    from spotpde.parameters import Orifice

    grid = Grid(2, (-10.0, 10.0), (0.0, 16.0), 0.25, walls="reflecting")
    spots = Spots(drift=1.0, b=1.3)
    rho = spot_density.steady(grid, Orifice(x=0.0, width=2.0), spots)
    kernel = kernels.Gaussian(sigma=0.8, volume=0.05, dims=2)
    f = C.particle_fields(grid, rho, spots, kernel, rule=0.5, walls="truncate")
    k, i1, i2 = 48, 15, 63                                   # z = 12.1, x = -6.1 and 5.9
    r1, r2 = (grid.x[i1], grid.z[k]), (grid.x[i2], grid.z[k])
    pair = C.pair_diffusivity(grid, rho, spots, kernel, r1, r2, rule=0.5)
    mf = C.pair_diffusivity(grid, rho, spots, kernel, r1, r2, rule=0.5, diffusivity="mean-field")
    for key in ("D_xx", "D_zz"):
        assert pair[key] == pytest.approx(f[key][k, i1] + f[key][k, i2], rel=2e-3), key
    assert pair["D_xx"] < 0.7 * mf["D_xx"]          # the midpoint rule's passage correlations
    assert pair["D_zz"] > 0 == mf["D_zz"]            # vertical shot noise (b_par = 0)
