"""Physics checks of the particle drift u_p and diffusivity D_p (spotpde.coefficients).

Closed forms used (derivations in docs/coefficients.md):
* uniform spot density, away from every boundary: u_p = -V1 rho_s u_s, D_p = V2 rho_s D_s;
* local limit: u_p -> -V1 (rho_s u_s - 2 lam div(D_s rho_s)) + O(sigma^2), with the
  leading correction (sigma^2 / 2) lap of the local field for a Gaussian kernel;
* point orifice, D_par = 0, Gaussian kernel: one-dimensional integrals over height;
* reflecting walls: the wall layer (1 - 2 lam) int (D_s rho_s) n w dA, checked against
  the exact average of the discrete spot-step rule near a reflecting wall;
* uniform flow: C_p(r) = kernel correlation, D_rel = 2 D_p (1 - C_p).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate

from spotpde.fields import coefficients as C
from spotpde.fields import kernels
from spotpde.grid import Grid
from spotpde.parameters import Spots
from _quadrature import discrete_rule_drift


def _interior(grid, kernel=None, margin=0.0):
    """Boolean mask of cells farther than the kernel reach (+ margin) from every boundary."""
    rh, rz = kernel.reach if kernel is not None else (0.0, 0.0)
    mesh = dict(zip(grid.axes, grid.mesh()))
    ok = (mesh["z"] - grid.z_range[0] > rz + margin) & (grid.z_range[1] - mesh["z"] > rz + margin)
    for a in grid.axes[1:]:
        c = mesh[a]
        ok = ok & (c - grid.x_range[0] > rh + margin) & (grid.x_range[1] - c > rh + margin)
    return np.broadcast_to(ok, grid.shape)


# -- 1. uniform spot density: the local identities hold exactly ----------------------------

@pytest.mark.parametrize("dims, make", [
    (2, lambda d: kernels.Gaussian(sigma=0.6, volume=0.05, dims=d, aspect=2.0)),
    (3, lambda d: kernels.Gaussian(sigma=0.6, volume=0.05, dims=d, aspect=2.0)),
    (2, lambda d: kernels.Uniform(radius=1.3, height=0.01, dims=d, aspect=1.0)),
    (3, lambda d: kernels.Uniform(radius=1.3, height=0.01, dims=d, aspect=0.8)),
    (2, lambda d: kernels.Exponential(length=0.12, volume=0.05, dims=d, aspect=1.5)),
])
@pytest.mark.parametrize("rule", [0.5, 1.0])
def test_uniform_density_gives_local_fields_exactly(dims, make, rule):
    kernel = make(dims)
    grid = Grid(dims, (-6.0, 6.0), (0.0, 12.0), 0.25 if dims == 2 else 0.5, walls="open")
    spots = Spots(drift=1.7, b=1.3, b_par=0.4)
    rho = np.full(grid.shape, 2.5)
    f = C.particle_fields(grid, rho, spots, kernel, rule=rule, diffusivity="mean-field")
    inside = _interior(grid, kernel)
    assert inside.sum() > 10
    np.testing.assert_allclose(f["u_z"][inside], -kernel.V1 * 2.5 * 1.7, rtol=1e-12)
    np.testing.assert_allclose(f["u_x"][inside], 0.0, atol=1e-14)
    np.testing.assert_allclose(f["D_xx"][inside], kernel.V2 * 2.5 * 1.3 * 1.7, rtol=1e-12)
    np.testing.assert_allclose(f["D_zz"][inside], kernel.V2 * 2.5 * 0.4 * 1.7, rtol=1e-12)
    np.testing.assert_array_equal(f["D_xz"], 0.0)
    if dims == 3:
        np.testing.assert_allclose(f["D_yy"][inside], f["D_xx"][inside], rtol=1e-12)
        np.testing.assert_allclose(f["u_y"][inside], 0.0, atol=1e-14)
    # near the floor fewer spots are in reach (zero padding): |u_z| is smaller there
    assert abs(f["u_z"][0].max()) < 0.75 * kernel.V1 * 2.5 * 1.7


def test_full_spot_tensor_gives_full_particle_tensor():
    """An off-diagonal spot diffusivity appears in D_p as V2 rho_s D_s^xz (local limit)."""
    grid = Grid(2, (-5.0, 5.0), (0.0, 10.0), 0.25, walls="open")
    kernel = kernels.Gaussian(sigma=0.5, volume=0.05, dims=2)
    D = {"D_xx": 1.0, "D_xz": 0.3, "D_zz": 0.5}
    rho = np.full(grid.shape, 2.0)
    f = C.particle_fields(grid, rho, Spots(), kernel, spot_diffusivity_tensor=D, diffusivity="mean-field")
    inside = _interior(grid, kernel)
    for k, v in D.items():
        np.testing.assert_allclose(f[k][inside], kernel.V2 * 2.0 * v, rtol=1e-12)


# -- 2. local limit with varying density and coefficients: convergence order -------------

def _smooth_case():
    grid = Grid(2, (-6.0, 6.0), (0.0, 12.0), 1.0 / 32.0, walls="open")
    Z, X = grid.mesh()
    kx, kz = 2 * np.pi / 6.0, 2 * np.pi / 8.0
    rho = 2.0 + np.cos(kx * X) * np.sin(kz * Z)
    D_perp = 1.0 + 0.3 * np.sin(kx * X + 0.4) * np.cos(kz * Z)
    v_s = 1.0 + 0.2 * np.cos(kz * Z) + 0.0 * X
    # analytic local fields -V1 (rho u_s - 2 lam div(D_s rho)), D_par = 0
    drho_x = -kx * np.sin(kx * X) * np.sin(kz * Z)
    dD_x = 0.3 * kx * np.cos(kx * X + 0.4) * np.cos(kz * Z)
    div_x = dD_x * rho + D_perp * drho_x
    spots = Spots(drift=v_s, b=D_perp / v_s, b_par=0.0)
    return grid, spots, rho, {"x": div_x, "z_src": rho * v_s}


@pytest.mark.parametrize("rule", [0.5, 1.0])
def test_local_limit_converges_at_second_order(rule):
    grid, spots, rho, parts = _smooth_case()
    local_ux = -(-2 * rule * parts["x"])
    local_uz = -parts["z_src"]
    errs = []
    for sigma in (0.3, 0.15, 0.075):
        kernel = kernels.Gaussian(sigma=sigma, volume=0.05, dims=2)
        f = C.particle_fields(grid, rho, spots, kernel, rule=rule, diffusivity="mean-field")
        inside = _interior(grid, margin=4 * 0.3)
        e = max(np.abs(f["u_x"] / kernel.V1 - local_ux)[inside].max(),
                np.abs(f["u_z"] / kernel.V1 - local_uz)[inside].max())
        errs.append(e)
        # leading correction for a Gaussian: (sigma^2 / 2) lap(local field)
        if sigma == 0.075:
            lap = sum(np.gradient(np.gradient(local_uz, grid.spacing, axis=a), grid.spacing, axis=a)
                      for a in (0, 1))
            pred = 0.5 * sigma**2 * lap
            resid = f["u_z"] / kernel.V1 - local_uz
            assert np.abs(resid - pred)[inside].max() < 0.05 * np.abs(pred)[inside].max()
    order = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all((order > 1.85) & (order < 2.15)), (errs, order)


def test_variable_diffusivity_uses_divergence_not_gradient():
    """div(D_s rho_s) differs from D_s grad rho_s when D_s varies; the fields follow div."""
    grid, spots, rho, parts = _smooth_case()
    kernel = kernels.Gaussian(sigma=0.1, volume=0.05, dims=2)
    f = C.particle_fields(grid, rho, spots, kernel, rule=1.0, diffusivity="mean-field")
    inside = _interior(grid, margin=1.0)
    Z, X = grid.mesh()
    kx, kz = 2 * np.pi / 6.0, 2 * np.pi / 8.0
    grad_only = 2 * spots.D_perp * (-kx * np.sin(kx * X) * np.sin(kz * Z))
    div_form = 2 * parts["x"]
    err_div = np.abs(f["u_x"] / kernel.V1 - div_form)[inside].max()
    err_grad = np.abs(f["u_x"] / kernel.V1 - grad_only)[inside].max()
    assert err_div < 0.05 * err_grad


# -- 3. quadrature: point orifice, D_par = 0, Gaussian kernel -----------------------------

def _gauss(x, var):
    return np.exp(-x**2 / (2 * var)) / np.sqrt(2 * np.pi * var)


@pytest.mark.parametrize("rule", [0.5, 1.0])
def test_point_orifice_fields_match_height_quadrature(rule):
    """rho_s = (Q0/v_s) N(x; 2bz); with w = V1 N(x; sx^2) N(z; sz^2):

    u_z(x,z) = -Q0 V1 int_0^inf N(z - z'; sz^2) N(x; 2bz' + sx^2) dz'
    u_x(x,z) = 2 lam b Q0 V1 int_0^inf N(z - z'; sz^2) d/dx N(x; 2bz' + sx^2) dz'
    D_xx     = b Q0 V2 int_0^inf N(z - z'; sz^2/2) N(x; 2bz' + sx^2/2) dz'
    """
    b, v_s, Q0 = 1.3, 1.5, 2.0
    sx, aspect = 1.0, 2.0
    sz = sx / aspect
    kernel = kernels.Gaussian(sigma=sx, volume=0.05, dims=2, aspect=aspect)
    grid = Grid(2, (-24.0, 24.0), (0.0, 24.0), 0.125, walls="open")
    Z, X = grid.mesh()
    rho = Q0 / v_s * _gauss(X, 2 * b * Z)
    f = C.particle_fields(grid, rho, Spots(drift=v_s, b=b, b_par=0.0), kernel, rule=rule, diffusivity="mean-field")

    def quad(fun, z, var_z):
        lo, hi = max(0.0, z - 12 * np.sqrt(var_z)), z + 12 * np.sqrt(var_z)
        return integrate.quad(lambda zp: _gauss(z - zp, var_z) * fun(zp), lo, hi,
                              epsabs=0, epsrel=1e-10, limit=200)[0]

    xs_idx = np.arange(0, grid.nx, 16)[8:-8]
    for z_target in (8.0, 14.0):
        k = int(np.argmin(np.abs(grid.z - z_target)))
        z = grid.z[k]
        ref = {"u_z": [], "u_x": [], "D_xx": []}
        for i in xs_idx:
            x = grid.x[i]
            ref["u_z"].append(-Q0 * kernel.V1 * quad(lambda zp: _gauss(x, 2 * b * zp + sx**2), z, sz**2))
            ref["u_x"].append(2 * rule * b * Q0 * kernel.V1 * quad(
                lambda zp: -x / (2 * b * zp + sx**2) * _gauss(x, 2 * b * zp + sx**2), z, sz**2))
            ref["D_xx"].append(b * Q0 * kernel.V2 * quad(
                lambda zp: _gauss(x, 2 * b * zp + sx**2 / 2), z, sz**2 / 2))
        for key, r in ref.items():
            r = np.array(r)
            got = f[key][k, xs_idx]
            assert np.abs(got - r).max() < 1e-3 * np.abs(r).max(), (key, z)
    np.testing.assert_array_equal(f["D_zz"], 0.0)


# -- 4. reflecting walls: the wall layer against the exact discrete-step average ----------

@pytest.mark.parametrize("rule", [0.0, 0.5, 1.0])
def test_wall_layer_matches_discrete_rule_at_reflecting_walls(rule):
    sigma, V1, b, rho0, L = 1.0, 0.05, 1.3, 2.0, 6.0
    kernel = kernels.Gaussian(sigma=sigma, volume=V1, dims=2)
    grid = Grid(2, (-L, L), (0.0, 24.0), 0.25, walls="reflecting")
    # the exact average below moves particles by the plain kernel W: the truncated
    # treatment (the renormalised one, W / phi, is checked the same way in test_walls.py)
    f = C.particle_fields(grid, np.full(grid.shape, rho0), Spots(drift=1.0, b=b), kernel,
                          rule=rule, walls="truncate", diffusivity="mean-field")
    k = grid.nz // 2

    def W(x):  # kernel integrated over z
        return V1 * _gauss(x, sigma**2)

    scale = b * rho0 * W(0.0)
    for i in (grid.nx - 1, grid.nx - 4, 2):
        exact = discrete_rule_drift(grid.x[i], rule, W, b, rho0, L)
        assert abs(f["u_x"][k, i] - exact) < 2e-3 * scale, (i, f["u_x"][k, i], exact)
    if rule == 1.0:  # the printed rule pushes particles away from the walls
        assert f["u_x"][k, -1] < -0.5 * scale and f["u_x"][k, 0] > 0.5 * scale


# -- 5. diagnostics --------------------------------------------------------------------------

def test_flux_velocity_and_defect_of_uniform_kernel_vanish_for_matched_rule():
    """Disk kernel, constant coefficients, D_par = 0, rho_s solving d rho/dz = b rho_xx:

    div(u_p - div D_p) = (2 lam - 1) b v_s w * rho_xx - b v_s w^2 * rho_xx, and
    w^2 = height * w, so the defect vanishes for lam = (1 + height)/2 and is
    proportional to (2 lam - 1 - height) otherwise (up to O(h^2) grid error, which the
    wide Gaussian solution keeps at a few per cent of the height-sized defect).
    """
    b, v_s, height = 1.3, 1.0, 0.0024
    kernel = kernels.Uniform(radius=1.0, height=height, dims=2)
    grid = Grid(2, (-12.0, 12.0), (0.0, 16.0), 0.0625, walls="open")
    Z, X = grid.mesh()
    rho = _gauss(X, 2 * b * (Z + 30.0))
    spots = Spots(drift=v_s, b=b)
    inside = _interior(grid, kernel, margin=2 * grid.spacing)
    defect = {}
    for lam in (0.5 * (1 + height), 0.5, 1.0):
        f = C.particle_fields(grid, rho, spots, kernel, rule=lam, diffusivity="mean-field")
        defect[lam] = np.linalg.norm(C.incompressibility_defect(grid, f)[inside])
        flux = C.flux_velocity(grid, f)
        np.testing.assert_array_equal(flux["u_z"], f["u_z"])  # D_zz = D_xz = 0
    assert defect[0.5 * (1 + height)] < 0.05 * defect[0.5]
    assert defect[1.0] / defect[0.5] == pytest.approx((1.0 - height) / height, rel=0.03)


@pytest.mark.parametrize("make", [
    lambda: kernels.Gaussian(sigma=1.0, volume=0.05, dims=2),
    lambda: kernels.Uniform(radius=1.5, height=0.01, dims=2),
])
def test_uniform_flow_correlation_equals_kernel_correlation(make):
    kernel = make()
    grid = Grid(2, (-12.0, 12.0), (0.0, 24.0), 0.25, walls="reflecting")
    rho = np.full(grid.shape, 3.0)
    spots = Spots(drift=1.0, b=1.3, b_par=0.7)
    r1 = np.array([0.1, 12.0])
    for r in (0.0, 0.6, 1.3, 2.2):
        for direction in (np.array([1.0, 0.0]), np.array([0.6, 0.8])):
            r2 = r1 + r * direction
            c = C.velocity_correlation(grid, rho, spots, kernel, r1, r2)
            expect = kernel.correlation(r)
            assert abs(c["C_xx"] - expect) < 2e-3, (r, c, expect)
            assert abs(c["C_zz"] - expect) < 2e-3
            assert c["C_xz"] == 0.0
            d = C.pair_diffusivity(grid, rho, spots, kernel, r1, r2, diffusivity="mean-field")
            Dp = kernel.V2 * 3.0 * 1.3
            assert abs(d["D_xx"] - 2 * Dp * (1 - expect)) < 5e-3 * Dp
    # far apart: (almost) no shared spots, (almost) no correlation
    far = C.velocity_correlation(grid, rho, spots, kernel, r1, r1 + np.array([0.0, 9.5]))
    assert abs(far["C_xx"] - kernel.correlation(9.5)) < 1e-9


def test_correlation_is_symmetric_and_bounded_in_nonuniform_flow():
    grid = Grid(3, (-4.0, 4.0), (0.0, 8.0), 0.5, walls="reflecting")
    kernel = kernels.Gaussian(sigma=0.8, volume=0.05, dims=3)
    Z, Y, X = grid.mesh()
    rho = np.broadcast_to(np.exp(-(X**2 + Y**2) / (4 * 1.3 * (Z + 1))) / (Z + 1), grid.shape)
    spots = Spots(drift=1.0, b=1.3, b_par=0.2)
    r1, r2 = (0.3, -0.5, 4.0), (1.1, 0.2, 4.7)
    c12 = C.velocity_correlation(grid, rho, spots, kernel, r1, r2)
    c21 = C.velocity_correlation(grid, rho, spots, kernel, r2, r1)
    for key in ("C_xx", "C_yy", "C_zz"):
        assert 0.0 < c12[key] < 1.0
        assert c12[key] == pytest.approx(c21[key], rel=1e-12)
    assert C.velocity_correlation(grid, rho, spots, kernel, r1, r1)["C_yy"] == pytest.approx(1.0)


def test_invalid_inputs_name_the_problem():
    grid = Grid(2, (-2.0, 2.0), (0.0, 4.0), 0.5)
    kernel = kernels.Gaussian(sigma=0.5, volume=0.05, dims=2)
    with pytest.raises(ValueError, match="rule"):
        C.particle_fields(grid, np.ones(grid.shape), Spots(), kernel, rule=2.0)
    with pytest.raises(ValueError, match="rho_s"):
        C.particle_fields(grid, np.ones((3, 3)), Spots(), kernel)
    with pytest.raises(ValueError, match="dims"):
        C.particle_fields(grid, np.ones(grid.shape), Spots(),
                          kernels.Gaussian(sigma=0.5, volume=0.05, dims=3))
    with pytest.raises(ValueError, match="valid"):
        C.particle_fields(grid, np.ones(grid.shape), Spots(), kernel,
                          spot_diffusivity_tensor={"D_yy": 1.0})


@pytest.mark.parametrize("dims", [2, 3])
@pytest.mark.parametrize("rule", [0.0, 0.5, 1.0])
def test_constant_coefficient_path_equals_general_path(dims, rule):
    """Scalar coefficients take the one-convolution path (w * grad = delta(w * rho) - planes);
    the same coefficients as arrays take the general one. Random rho_s: strong boundaries."""
    kernel = kernels.Gaussian(sigma=0.6, volume=0.05, dims=dims, aspect=1.5)
    grid = Grid(dims, (-4.0, 4.0), (0.0, 6.0), 0.25 if dims == 2 else 0.5)
    rho = np.random.default_rng(7).random(grid.shape) + 1.0
    tensor = ({"D_xx": 1.3, "D_xz": 0.4, "D_zz": 0.7} if dims == 2 else
              {"D_xx": 1.3, "D_yy": 0.9, "D_xz": 0.4, "D_yz": -0.2, "D_zz": 0.7})
    ones = np.ones(grid.shape)
    f1 = C.particle_fields(grid, rho, Spots(drift=1.4), kernel, rule=rule,
                           spot_diffusivity_tensor=tensor, diffusivity="mean-field")
    f2 = C.particle_fields(grid, rho, Spots(drift=1.4 * ones), kernel, rule=rule,
                           spot_diffusivity_tensor={k: v * ones for k, v in tensor.items()}, diffusivity="mean-field")
    for k in f1:
        np.testing.assert_allclose(f1[k], f2[k], rtol=0, atol=1e-13 * np.abs(f2[k]).max())


def test_3d_point_orifice_fields_are_symmetric():
    """Rotating the silo by 90 degrees about z swaps x and y: u_x(z, y, x) = u_y(z, x, y)."""
    from spotpde.density import spot_density
    from spotpde.parameters import Orifice

    grid = Grid(3, (-6.0, 6.0), (0.0, 8.0), 0.5, walls="reflecting")
    spots = Spots(drift=1.0, b=1.3, b_par=0.0)
    rho = spot_density.steady(grid, Orifice(x=0.0, width=3.0), spots)
    kernel = kernels.Uniform(radius=1.5, height=0.01, dims=3, aspect=1.2)
    f = C.particle_fields(grid, rho, spots, kernel, rule=1.0, diffusivity="mean-field")  # wall layers on all four walls
    swap = (0, 2, 1)
    scale = np.abs(f["u_x"]).max()
    np.testing.assert_allclose(f["u_x"], np.transpose(f["u_y"], swap), atol=1e-12 * scale)
    np.testing.assert_allclose(f["u_x"], -f["u_x"][:, :, ::-1], atol=1e-12 * scale)
    for a, b in (("D_xx", "D_yy"), ("u_z", "u_z")):
        np.testing.assert_allclose(f[a], np.transpose(f[b], swap), rtol=0,
                                   atol=1e-12 * np.abs(f[a]).max())
    assert np.all(f["u_z"] < 0)


def test_diagonal_diffusivity_is_never_negative_where_spots_vanish():
    """Far from a slot the spot density underflows to 0 and the FFT leaves round-off
    negatives (~-5e-18) in w^2 * (rho_s D_s); D_p's diagonal must still be >= 0 (the
    tracer rejects negative diffusivities), while real values are untouched."""
    from spotpde.density import spot_density
    from spotpde.fields.convolution import convolve
    from spotpde.parameters import Orifice

    grid = Grid(2, (-48.0, 48.0), (0.0, 4.0), 0.125)
    spots = Spots(b=1.3)
    rho_s = np.maximum(spot_density.steady(grid, Orifice(width=0.0, rate=21.22), spots), 0)
    kernel = kernels.Uniform(radius=2.5, height=0.0024, dims=2)
    raw = convolve(rho_s * spots.D_perp, kernel.sample(grid.spacing, power=2)) * grid.cell_volume
    assert raw.min() < 0                       # the round-off this test is about is there
    D_xx = C.particle_fields(grid, rho_s, spots, kernel, diffusivity="mean-field")["D_xx"]
    assert D_xx.min() >= 0
    # elsewhere the same field, to FFT round-off of the peak
    np.testing.assert_allclose(D_xx, raw, rtol=0, atol=1e-13 * raw.max())
