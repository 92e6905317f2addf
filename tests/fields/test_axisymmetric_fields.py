"""Particle fields of cylindrical silos: ring convolutions on axisymmetric grids.

Closed forms and references used (docs/walls.md, "Axisymmetric silos"):
* the same problem on a 3D Cartesian grid (the plane through the axis; the ring weights
  and the Cartesian stencil are independent discretisations of the same 3D integral);
* Gaussian blob ``rho_s = exp(-|x - x_c|^2 / 2 s^2)`` and Gaussian kernel ``sigma``:
  ``w * rho_s = V1 (s^2 / S^2)^(3/2) exp(-|x - x_c|^2 / 2 S^2)``, ``S^2 = s^2 + sigma^2``,
  so ``u_z = -v_s w * rho_s`` and ``u_r = 2 lam D_perp d_r(w * rho_s)``;
* reflecting cylinder of radius ``a``: the steady spot density
  ``Q0/(pi a^2 v_s) sum_n J0(j_n r/a)/J0(j_n)^2 exp(-b j_n^2 (z + z0)/a^2)`` (``j_n`` the
  zeros of J1, ``j_0 = 0``; a source ``z0`` below the floor keeps it smooth) carries the
  spot flux ``Q0`` through every height; each spot step displaces ``V1 dR`` of particles,
  so ``-int u_z 2 pi r dr = V1 Q0``;
* uniform spot density: ``u_z = -V1 rho_s v_s``, ``D_rr = V2 rho_s D_perp`` away from the
  boundaries, and the wall layer ``(1 - 2 lam) D_perp rho_s / phi_w * a int dt dz w cos t``.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate, special
from scipy.interpolate import CubicSpline

from spotpde.fields import coefficients as C, kernels, void
from spotpde.grid import Grid
from spotpde.parameters import Spots

from _grids import cylinder as _cylinder


def _blob(grid, s, zc):
    Z, R = grid.mesh()
    return np.exp(-(R**2 + (Z - zc) ** 2) / (2 * s * s)) * np.ones(grid.shape)


def _bessel_density(grid, b=1.3, z0=3.0, n=60, Q0=1.0, v_s=1.0):
    a = grid.x_range[1]
    Z, R = grid.mesh()
    out = np.ones(grid.shape)
    for j in special.jn_zeros(1, n):
        out = out + special.j0(j * R / a) / special.j0(j) ** 2 * np.exp(-b * j * j * (Z + z0) / a**2)
    return Q0 / (np.pi * a * a * v_s) * out


# -- 1. against a 3D Cartesian run of the same problem ---------------------------------------

@pytest.mark.slow
@pytest.mark.parametrize("kernel", [
    kernels.Gaussian(sigma=1.0, volume=0.05, dims=3, aspect=2.0),
    kernels.Uniform(radius=1.5, height=0.01, dims=3),
])
@pytest.mark.parametrize("rule, diffusivity, b_par", [(0.5, "mean-field", 0.3), (1.0, "passage", 0.0)])
def test_fields_match_a_3d_cartesian_run(kernel, rule, diffusivity, b_par):
    a, H, h, s = 6.0, 12.0, 0.125, 1.5
    spots = Spots(drift=1.0, b=1.3, b_par=b_par)
    ga = _cylinder(a, H, h, walls="open")
    fa = C.particle_fields(ga, _blob(ga, s, H / 2), spots, kernel, rule=rule,
                           diffusivity=diffusivity, walls="truncate")
    g3 = Grid(3, (-a, a), (0.0, H), h, walls="open")
    Z, Y, X = g3.mesh()
    rho3 = np.exp(-(X**2 + Y**2 + (Z - H / 2) ** 2) / (2 * s * s)) * np.ones(g3.shape)
    f3 = C.particle_fields(g3, rho3, spots, kernel, rule=rule, diffusivity=diffusivity,
                           walls="truncate")
    # the 3D cells nearest the axis plane: y = h/2, x = (i + 1/2) h > 0
    jy, half = g3.nx // 2, slice(g3.nx // 2, None)
    x, y = g3.x[half], g3.y[jy]
    r = np.hypot(x, y)

    def at(f, odd=False):   # cubic in r, continued across the axis (even or odd)
        rr = np.concatenate([-ga.r[::-1], ga.r])
        ff = np.concatenate([(-1.0 if odd else 1.0) * f[:, ::-1], f], axis=1)
        return CubicSpline(rr, ff, axis=1)(r)

    plane = (slice(None), jy, half)
    pairs = {
        "u_z": (at(fa["u_z"]), f3["u_z"][plane]),
        "u_r": (at(fa["u_r"], odd=True), (f3["u_x"][plane] * x + f3["u_y"][plane] * y) / r),
        "D_rr": (at(fa["D_rr"]), f3["D_xx"][plane]),   # D_xx = D_rr cos^2 + D_tt sin^2
        "D_zz": (at(fa["D_zz"]), f3["D_zz"][plane]),
    }
    for key, (axi, cart) in pairs.items():
        scale = np.abs(cart).max()
        assert scale > 0, key
        assert np.abs(axi - cart).max() < 1e-3 * scale, key


# -- 2. closed forms, local limit, convergence, the axis ---------------------------------------

def _blob_closed_form(grid, s, zc, sigma, V1):
    Z, R = grid.mesh()
    S2 = s * s + sigma * sigma
    conv = V1 * (s * s / S2) ** 1.5 * np.exp(-(R**2 + (Z - zc) ** 2) / (2 * S2))
    return conv, -R / S2 * conv          # w * rho_s and its d_r


@pytest.mark.parametrize("rule", [0.5, 1.0])
def test_gaussian_blob_fields_converge_at_second_order(rule):
    kernel = kernels.Gaussian(sigma=1.0, volume=0.05, dims=3)
    s, zc, b = 1.5, 7.0, 1.3
    errs = {"u_z": [], "u_r": [], "D_rr": []}
    for h in (0.5, 0.25, 0.125):
        g = _cylinder(7.0, 14.0, h, walls="open")
        f = C.particle_fields(g, _blob(g, s, zc), Spots(b=b), kernel, rule=rule,
                              diffusivity="mean-field", walls="truncate")
        conv, d_r = _blob_closed_form(g, s, zc, 1.0, kernel.V1)
        conv2, _ = _blob_closed_form(g, s, zc, 1.0 / np.sqrt(2.0), kernel.V2)
        exact = {"u_z": -conv, "u_r": 2 * rule * b * d_r, "D_rr": b * conv2}
        for k in errs:
            errs[k].append(np.abs(f[k] - exact[k]).max() / np.abs(exact[k]).max())
    # measured at h = 1/8: 3.1e-4 (u_z), 4.2e-4 (D_rr), 2.1e-3 (u_r: its source, the
    # central difference of rho_s, errs by h^2 rho_s''' / 6)
    bound = {"u_z": 1e-3, "D_rr": 1e-3, "u_r": 3e-3}
    for k, e in errs.items():
        orders = np.log2(np.array(e[:-1]) / np.array(e[1:]))
        assert e[-1] < bound[k], k
        assert np.all(orders > 1.8), (k, e)


@pytest.mark.parametrize("kernel", [
    kernels.Uniform(radius=1.3, height=0.01, dims=3, aspect=0.8),
    kernels.Exponential(length=0.12, volume=0.05, dims=3, aspect=1.5),
])
def test_uniform_density_gives_the_local_fields(kernel):
    g = _cylinder(8.0, 10.0, 0.25, walls="open")
    spots = Spots(drift=1.7, b=1.3, b_par=0.4)
    f = C.particle_fields(g, np.full(g.shape, 2.5), spots, kernel, rule=1.0,
                          diffusivity="mean-field", walls="truncate")
    rh, rz = kernel.reach
    Z, R = g.mesh()
    inside = np.broadcast_to((R < 8.0 - rh) & (Z > rz) & (Z < 10.0 - rz), g.shape)
    np.testing.assert_allclose(f["u_z"][inside], -kernel.V1 * 2.5 * 1.7, rtol=1e-12)
    np.testing.assert_allclose(f["D_rr"][inside], kernel.V2 * 2.5 * 1.3 * 1.7, rtol=1e-12)
    np.testing.assert_allclose(f["D_zz"][inside], kernel.V2 * 2.5 * 0.4 * 1.7, rtol=1e-12)
    np.testing.assert_allclose(f["u_r"], 0.0, atol=1e-14)   # round-off of the differences
    np.testing.assert_array_equal(f["D_rz"], 0.0)
    assert tuple(f) == g.drift_keys + g.diffusivity_keys


def test_local_limit_and_a_regular_axis():
    """Small kernels: ``u_p -> -V1 (rho_s u_s - 2 lam div(D_s rho_s))``, error O(sigma^2);
    ``u_r`` is odd across the axis: ``u_r ~ r`` in the first cells."""
    h, lam, b = 1.0 / 16.0, 1.0, 1.3
    g = _cylinder(4.0, 8.0, h, walls="open")
    Z, R = g.mesh()
    rho = np.exp(-R**2 / 8.0) * (1.0 + 0.3 * np.sin(Z / 2.0)) * np.ones(g.shape)
    d_r = -R / 4.0 * rho
    errs = []
    for sigma in (0.3, 0.15):
        kernel = kernels.Gaussian(sigma=sigma, volume=0.05, dims=3)
        f = C.particle_fields(g, rho, Spots(b=b), kernel, rule=lam, diffusivity="mean-field",
                              walls="truncate")
        inside = np.broadcast_to((R < 4.0 - kernel.reach[0]) & (Z > kernel.reach[1])
                                 & (Z < 8.0 - kernel.reach[1]), g.shape)
        local_r = 2 * lam * kernel.V1 * b * d_r
        local_z = -kernel.V1 * rho
        errs.append((np.abs(f["u_r"] - local_r)[inside].max() / np.abs(local_r).max(),
                     np.abs(f["u_z"] - local_z)[inside].max() / np.abs(local_z).max()))
        # regular axis: u_r(r0) / u_r(r1) = r0 / r1 = 1/3 to O(h^2)
        ratio = f["u_r"][inside[:, 0], 0] / f["u_r"][inside[:, 0], 1]
        np.testing.assert_allclose(ratio, 1.0 / 3.0, atol=2e-3)
    (er1, ez1), (er2, ez2) = errs
    assert er1 < 0.05 and ez1 < 0.05
    assert np.log2(er1 / er2) > 1.8 and np.log2(ez1 / ez2) > 1.8


def test_cylindrical_divergences_of_linear_fields():
    """``div u`` of ``u_r = r`` is ``(1/r) d_r(r^2) = 2`` (not ``d_r u_r = 1``), and the
    tensor ``D_rz = r`` has ``(div D)_z = (1/r) d_r(r^2) = 2``, ``(div D)_r = d_z D_rz = 0``:
    so ``u_p - div D_p = (0, -2)``. The differences are exact for quadratics, the axis
    cell included (even continuation of ``r^2``), the outer wall (one-sided) too."""
    g = _cylinder(3.0, 4.0, 0.25)
    Z, R = g.mesh()
    zero = np.zeros(g.shape)
    ring = {"u_r": R * np.ones(g.shape), "u_z": zero, "D_rr": zero, "D_rz": zero, "D_zz": zero}
    np.testing.assert_allclose(C.incompressibility_defect(g, ring), 2.0, rtol=1e-12)
    shear = {"u_r": zero, "u_z": zero, "D_rr": zero, "D_rz": R * np.ones(g.shape), "D_zz": zero}
    flux = C.flux_velocity(g, shear)
    np.testing.assert_allclose(flux["u_z"], -2.0, rtol=1e-12)
    np.testing.assert_allclose(flux["u_r"], 0.0, atol=1e-12)
    # and d_z: u_z = 3 z has div u = 3 (the same rows the defect of a real case uses)
    lift = {**ring, "u_r": zero, "u_z": 3.0 * Z * np.ones(g.shape)}
    np.testing.assert_allclose(C.incompressibility_defect(g, lift), 3.0, rtol=1e-12)


@pytest.mark.parametrize("rule", [0.0, 0.5, 1.0])
def test_incompressibility_defect_of_a_cylinder_is_the_rule_s(rule):
    """The paper's sphere (``w^2 = height w``), ``rho_s`` solving ``d_z rho = b lap_perp rho``
    (the 2D heat kernel in ``r``), mean field: ``div(u_p - div D_p) =
    (2 lam - 1 - height) b v_s w * lap_perp rho_s = (1 + height - 2 lam) d_z u_z``, since
    ``d_z u_z = -v_s w * d_z rho_s``. So the cylindrical flow is incompressible (to grid
    accuracy) only near the midpoint rule (exactly at ``lam = (1 + height)/2``), and the
    defect of the other rules is of the size of ``d_z u_z`` (measured: 1e-5 relative at lam = 0, 8e-3 at lam = 1;
    at lam = 1/2, 6e-3 of ``d_z u_z``, the grid error of a height-sized defect)."""
    b, height = 1.3, 0.0024
    kernel = kernels.Uniform(radius=2.5, height=height, dims=3)
    g = _cylinder(6.0, 20.0, 0.25, walls="open")     # the ring weights of the flux test
    Z, R = g.mesh()
    rho = np.exp(-R**2 / (4 * b * (Z + 3.0))) / (4 * np.pi * b * (Z + 3.0))
    inside = (R < 3.0) & (Z > 5.5) & (Z < 17.0)      # a kernel radius from the open edges
    f = C.particle_fields(g, rho, Spots(b=b), kernel, rule=rule, diffusivity="mean-field")
    defect = C.incompressibility_defect(g, f)[inside]
    zero = np.zeros(g.shape)
    d_z_u_z = C.incompressibility_defect(g, {"u_r": zero, "u_z": f["u_z"], "D_rr": zero,
                                             "D_rz": zero, "D_zz": zero})[inside]
    scale = np.linalg.norm(d_z_u_z)
    if rule == 0.5:
        assert np.linalg.norm(defect) < 0.01 * scale
    else:
        expected = (1.0 + height - 2.0 * rule) * d_z_u_z
        assert np.linalg.norm(defect - expected) < 0.02 * scale


# -- 3. the cylinder wall: free volume and the wall layer --------------------------------------

@pytest.mark.parametrize("kernel", [
    kernels.Uniform(radius=2.5, height=0.0024, dims=3),
    kernels.Gaussian(sigma=1.0, volume=0.05, dims=3, aspect=2.0),
])
@pytest.mark.parametrize("rule", [0.5, 1.0])
def test_particle_flux_is_V1_Q0_through_every_height(kernel, rule):
    g = _cylinder(6.0, 20.0, 0.25)
    rho = _bessel_density(g)
    rz = kernel.reach[1]
    rows = (g.z > 2 * rz) & (g.z < 20.0 - rz - g.spacing)

    def flux(walls):
        f = C.particle_fields(g, rho, Spots(b=1.3), kernel, rule=rule, walls=walls)
        return -(f["u_z"] * g.horizontal_measures[None, :]).sum(axis=1)[rows] / kernel.V1

    assert np.abs(flux("renormalise") - 1.0).max() < 1e-3
    assert flux("truncate").max() < 0.9        # the check can fail: free volume lost


@pytest.mark.parametrize("walls", ["truncate", "renormalise"])
@pytest.mark.parametrize("rule", [0.0, 1.0])
def test_wall_layer_of_the_cylinder_matches_the_ring_integral(walls, rule):
    sig, V1, a, b, rho0 = 1.0, 0.05, 6.0, 1.3, 2.0
    kernel = kernels.Gaussian(sigma=sig, volume=V1, dims=3)
    g = _cylinder(a, 16.0, 0.25)
    f = C.particle_fields(g, np.full(g.shape, rho0), Spots(b=b), kernel, rule=rule,
                          diffusivity="mean-field", walls=walls)
    amp = V1 / (2 * np.pi * sig * sig)          # horizontal Gaussian, z integrated out

    def ring(r):   # a int dt w_h(|x - x_w|) cos t, w_h the kernel integrated over height
        return integrate.quad(lambda t: a * amp * np.exp(-(r * r + a * a - 2 * r * a * np.cos(t))
                                                         / (2 * sig * sig)) * np.cos(t),
                              -np.pi, np.pi, epsabs=1e-14)[0]

    phi_w = 1.0
    if walls == "renormalise":   # coverage at the wall: (1/V1) int_{r' < a} w_h
        phi_w = integrate.quad(lambda rp: rp * 2 * np.pi * amp / V1 * np.exp(-(a - rp) ** 2 / (2 * sig**2))
                               * special.ive(0, a * rp / sig**2), 0.0, a, epsabs=1e-14)[0]
    k = g.nz // 2
    cols = g.r > a - 4.0
    exact = np.array([(1 - 2 * rule) * b * rho0 * ring(r) / phi_w for r in g.r[cols]])
    got = f["u_r"][k, cols]
    assert np.abs(exact).max() > 0.01
    assert np.abs(got - exact).max() < 2e-3 * np.abs(exact).max()


# -- 4. the void model's local fields ----------------------------------------------------------

def test_void_fields_axisymmetric_are_the_local_cylindrical_fields():
    lam, V1, b, b_par = 1.0, 1.0, 0.5, 0.2
    errs = []
    for h in (0.25, 0.125):
        g = _cylinder(6.0, 12.0, h, walls="open")
        rho = _blob(g, 1.5, 6.0)
        Z, R = g.mesh()
        f = void.void_fields(g, rho, Spots(b=b, b_par=b_par), V1, rule=lam)
        assert tuple(f) == g.drift_keys + g.diffusivity_keys
        exact_r = 2 * lam * V1 * b * (-R / 1.5**2) * rho
        exact_z = -V1 * (rho - 2 * lam * b_par * (-(Z - 6.0) / 1.5**2) * rho)
        np.testing.assert_allclose(f["D_rr"], V1 * b * rho, rtol=1e-14)
        np.testing.assert_allclose(f["D_zz"], V1 * b_par * rho, rtol=1e-14)
        np.testing.assert_array_equal(f["D_rz"], 0.0)
        errs.append(max(np.abs(f["u_r"] - exact_r).max() / np.abs(exact_r).max(),
                        np.abs(f["u_z"] - exact_z).max() / np.abs(exact_z).max()))
    assert errs[1] < 1e-2 and np.log2(errs[0] / errs[1]) > 1.8


def test_axisymmetric_inputs_are_checked():
    g = _cylinder(4.0, 8.0, 0.25)
    rho = np.ones(g.shape)
    with pytest.raises(ValueError, match="^kernel"):
        C.particle_fields(g, rho, Spots(), kernels.Gaussian(sigma=1.0, volume=0.05, dims=2))
    k3 = kernels.Gaussian(sigma=1.0, volume=0.05, dims=3)
    with pytest.raises(ValueError, match="^spot_diffusivity_tensor"):
        C.particle_fields(g, rho, Spots(), k3, spot_diffusivity_tensor={"D_xx": 1.0})
    with pytest.raises(ValueError, match="^rho_s"):
        C.particle_fields(g, rho[:, :-1], Spots(), k3)
    with pytest.raises(ValueError, match="^walls"):
        C.particle_fields(g, rho, Spots(), k3, walls="mirror")


@pytest.mark.parametrize("rule", [0.5, 1.0])
def test_passage_keeps_the_mean_flow_of_the_mean_field(rule):
    """``u_p - div D_p`` (cylindrical divergence) is the same for both diffusivities: the
    passage drift adds ``div(D_p - D_p_mf)``; renormalised walls and the wall layer."""
    kernel = kernels.Uniform(radius=2.5, height=0.0024, dims=3)
    g = _cylinder(6.0, 20.0, 0.25)
    rho = _bessel_density(g)
    u = {}
    for dif in ("mean-field", "passage"):
        f = C.particle_fields(g, rho, Spots(b=1.3), kernel, rule=rule, diffusivity=dif)
        u[dif] = C.flux_velocity(g, f)
    assert np.abs(u["passage"]["u_r"]).max() > 0
    for k in ("u_r", "u_z"):
        scale = np.abs(u["mean-field"][k]).max()
        np.testing.assert_allclose(u["passage"][k], u["mean-field"][k], rtol=0, atol=1e-12 * scale)


def test_ring_weight_cache_failure_costs_only_the_computation(tmp_path, monkeypatch):
    """A cache write that fails half-way (disk full) returns the weights and leaves no
    temporary file in the cache directory."""
    import numpy as np
    from spotpde.fields import _rings

    monkeypatch.setenv("SPOTPDE_CACHE_DIR", str(tmp_path))

    def full_disk(fh, arr, allow_pickle=False):
        fh.write(b"\x93NUMPY")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(_rings.np, "save", full_disk)
    expected = np.arange(6.0)
    got = _rings._disk(("test-key", 1), lambda: expected)
    assert got is expected
    assert list((tmp_path / "rings").iterdir()) == []
