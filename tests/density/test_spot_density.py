"""Mean spot density against closed forms (derivations: docs/spot_density.md)."""

import numpy as np
import pytest
from scipy.integrate import quad_vec
from scipy.special import erf, k0

from spotpde.density import _elliptic, _marching, _transient
from spotpde.density import spot_density as sd
from spotpde.grid import Grid
from spotpde.density.kinematic import point_source
from spotpde.density.orifice import rate_from_table, source_profile
from spotpde.parameters import Orifice, Spots


def gauss(x, var):
    return np.exp(-x**2 / (2 * var)) / np.sqrt(2 * np.pi * var)


def images(x, x0, var, lo, hi, m=4):
    """Free Gaussian of variance ``var`` from ``x0`` plus its images in walls at lo, hi."""
    L = hi - lo
    return sum(gauss(x - (x0 + 2 * k * L), var) + gauss(x - (2 * lo - x0 + 2 * k * L), var)
               for k in range(-m, m + 1))


def gauss_avg(x, var, h):
    """Average over the cell [x - h/2, x + h/2] of the centred Gaussian of variance ``var``."""
    s = np.sqrt(2 * var)
    return (erf((x + h / 2) / s) - erf((x - h / 2) / s)) / (2 * h)


def images_avg(x, x0, var, lo, hi, h, m=4):
    """Cell averages of :func:`images` (the spectral solver returns cell averages)."""
    L = hi - lo
    return sum(gauss_avg(x - (x0 + 2 * k * L), var, h) + gauss_avg(x - (2 * lo - x0 + 2 * k * L), var, h)
               for k in range(-m, m + 1))


# -- D_par = 0, constant b: exact in height ---------------------------------------------------
@pytest.mark.parametrize("x0", [0.0, 1.3, -4.6])
def test_point_2d_reflecting_equals_images(x0):
    g = Grid(2, (-5, 5), (0, 12), 0.25)
    v_s, b, Q0 = 2.0, 1.3, 3.0
    rho = sd.steady(g, Orifice(x=x0, rate=Q0), Spots(drift=v_s, b=b))
    Z, X = g.mesh()
    exact = Q0 / v_s * images_avg(X, x0, 2 * b * Z, -5, 5, g.spacing)
    np.testing.assert_allclose(rho, exact, rtol=0, atol=1e-13 * exact.max())


@pytest.mark.parametrize("dims", [2, 3])
def test_point_open_walls_equals_free_space(dims):
    g = Grid(dims, (-6, 6), (0, 10), 0.25, "open")
    rho = sd.steady(g, Orifice(x=0.0, y=0.0), Spots(drift=1.0, b=1.1))
    mesh = g.mesh()
    exact = 1.0
    for c in mesh[1:]:
        exact = exact * gauss_avg(c, 2 * 1.1 * mesh[0], g.spacing)
    np.testing.assert_allclose(rho, exact, rtol=0, atol=1e-13 * exact.max())
    # point values (the public closed form, kinematic.point_source) differ from cell averages by O(h^2)
    r = np.sqrt(sum(c**2 for c in mesh[1:]))
    far = np.broadcast_to(mesh[0] > 2, g.shape)
    point = point_source(r, mesh[0], 1.1, dims=dims)
    assert np.abs(rho - point)[far].max() < g.spacing**2 * point[far].max()


def test_point_3d_reflecting_equals_images():
    g = Grid(3, (-3, 3), (0, 6), 0.25)
    x0, y0, b = 1.1, -2.6, 0.9
    rho = sd.steady(g, Orifice(x=x0, y=y0), Spots(drift=1.0, b=b))
    Z, Y, X = g.mesh()
    exact = images_avg(X, x0, 2 * b * Z, -3, 3, 0.25) * images_avg(Y, y0, 2 * b * Z, -3, 3, 0.25)
    # row 0 (z = h/2) needs the folded modes beyond the grid's (exp(-b pi^2 z / h^2) ~ 2e-8)
    np.testing.assert_allclose(rho, exact, rtol=0, atol=1e-13 * exact.max())


def test_slot_open_walls_is_erf():
    """Slot [x1, x2]: rho = Q0 / (v_s W) * [erf((x - x1)/sqrt(4bz)) - erf((x - x2)/sqrt(4bz))] / 2.

    Cell averages use F(u) = u erf(u/s) + s exp(-u^2/s^2) / sqrt(pi), F' = erf(u/s).
    """
    h = 0.125
    g = Grid(2, (-8, 8), (0, 10), h, "open")
    W, xc, b = 3.0, 0.7, 1.3
    rho = sd.steady(g, Orifice(x=xc, width=W, rate=2.0), Spots(drift=1.0, b=b))
    Z, X = g.mesh()
    s = np.sqrt(4 * b * Z)
    F = lambda u: u * erf(u / s) + s * np.exp(-(u / s) ** 2) / np.sqrt(np.pi)
    avg_erf = lambda x1: (F(X + h / 2 - x1) - F(X - h / 2 - x1)) / h
    exact = 2.0 / W * 0.5 * (avg_erf(xc - W / 2) - avg_erf(xc + W / 2))
    np.testing.assert_allclose(rho, exact, atol=1e-12)


def test_gaussian_source_3d_open():
    """Gaussian source of sigma: variance sigma^2 + 2 b z per horizontal axis."""
    g = Grid(3, (-5, 5), (0, 5), 0.25, "open")
    sigma, b = 0.75, 1.0
    rho = sd.steady(g, Orifice(x=0.4, y=-0.3, width=2 * sigma, profile="gaussian"), Spots(b=b))
    Z, Y, X = g.mesh()
    var = sigma**2 + 2 * b * Z
    exact = gauss_avg(X - 0.4, var, 0.25) * gauss_avg(Y + 0.3, var, 0.25)
    np.testing.assert_allclose(rho, exact, atol=1e-13)


@pytest.mark.parametrize("dims", [2, 3])
@pytest.mark.parametrize("varying", [False, True])
def test_flux_equals_Q0_at_every_height(dims, varying):
    g = Grid(dims, (-4, 4), (0, 6), 0.25)
    Z = g.mesh()[0]
    X = g.mesh()[-1]
    b = 1.3 if not varying else np.broadcast_to(0.8 + 0.4 * np.cos(X) ** 2 + 0.05 * Z, g.shape)
    v_s = np.broadcast_to(1.0 + 0.3 * np.sin(X) ** 2 + 0 * Z, g.shape)
    Q0 = 2.5
    rho = sd.steady(g, Orifice(x=0.3, width=1.0, rate=Q0), Spots(drift=v_s, b=b))
    flux = (v_s * rho).reshape(g.nz, -1).sum(axis=1) * g.horizontal_cell_measure
    np.testing.assert_allclose(flux, Q0, rtol=1e-13)


# -- D_par = 0, b varying: height marching ------------------------------------------------------
def _b_of_z_error(h, walls="reflecting"):
    """b = b0 (1 + z/z1): exact Gaussian of variance 2 tau(z), tau = b0 (z + z^2 / (2 z1))."""
    g = Grid(2, (-8, 8), (0, 8), h, walls)
    b0, z1, x0 = 0.8, 4.0, 1.0   # x0 on a cell face for every h: CIC adds h^2/4 of variance
    Z, X = g.mesh()
    b = b0 * (1 + Z / z1) + 0 * X
    rho = sd.steady(g, Orifice(x=x0), Spots(b=b))
    tau = b0 * (Z + Z**2 / (2 * z1))
    exact = images(X, x0, 2 * tau, -8, 8) if walls == "reflecting" else gauss(X - x0, 2 * tau)
    far = np.broadcast_to(Z >= 2.0, g.shape)
    return np.max(np.abs(rho - exact)[far]) / exact.max()


def test_marching_converges_second_order_to_point_source():
    """Off-centre point source (cloud in cell) marched with b(z): error ~ h^2 for z >= 2."""
    e = [_b_of_z_error(h) for h in (0.5, 0.25, 0.125)]
    orders = np.log2(np.array(e[:-1]) / np.array(e[1:]))
    assert e[-1] < 5e-4
    assert np.all(orders > 1.8), (e, orders)


def test_marching_open_walls_padded():
    assert _b_of_z_error(0.25, "open") < 1.2 * _b_of_z_error(0.25, "reflecting")


def test_marching_b_of_x_relaxes_to_inverse_b():
    """Between reflecting walls d phi/dz = (b phi)_xx relaxes to b phi = const: phi ~ 1/b."""
    g = Grid(2, (-1, 1), (0, 30), 0.125)      # slowest mode decays like exp(-0.4 pi^2 z / 4)
    Z, X = g.mesh()
    b = 1.0 + 0.6 * np.sin(np.pi * X / 2) + 0 * Z
    rho = sd.steady(g, Orifice(x=-0.5, width=0.5), Spots(b=b))
    inv = 1.0 / b[-1]
    np.testing.assert_allclose(rho[-1], inv / (inv.sum() * g.spacing), rtol=1e-9)


def test_marching_3d_agrees_with_exact_modes():
    """ADI marching with a constant-valued b array vs the exact cosine-mode solution."""
    errs = []
    for h in (0.5, 0.25):
        g = Grid(3, (-3, 3), (0, 4), h)
        o = Orifice(x=0.5, y=-0.5, width=1.5, profile="gaussian")
        exact = sd.steady(g, o, Spots(b=1.0))
        phi = _marching.march(source_profile(g, o), np.full(g.shape, 1.0), h)
        flux = phi.sum(axis=(1, 2)) * h**2
        np.testing.assert_allclose(flux, 1.0, rtol=1e-13)
        # the Rannacher start leaves an O(h^2) error with a large constant near the floor;
        # compare where it has decayed (z >= 1)
        errs.append(np.abs(phi - exact)[g.z >= 1].max() / exact.max())
    assert errs[1] < 5e-3 and errs[0] / errs[1] > 3.5, errs


# -- D_par > 0: elliptic, against the anisotropic free-space point source ------------------------
def _free_point(x, z, v, Dp, Dz, dims):
    """Steady v d rho/dz = D_perp lap_perp rho + D_par rho_zz + Q delta, Q = 1, whole space.

    Scaling x' = x / sqrt(D_perp), z' = z / sqrt(D_par) and rho = exp(v z / 2 D_par) g
    gives (lap' - a^2) g = -delta' / sqrt(D_perp^dh D_par), a = v / (2 sqrt(D_par)).
    """
    rp = np.sqrt(x**2 / Dp + z**2 / Dz)
    a = v / (2 * np.sqrt(Dz))
    if dims == 2:
        return np.exp(v * z / (2 * Dz)) * k0(a * rp) / (2 * np.pi * np.sqrt(Dp * Dz))
    return np.exp(v * z / (2 * Dz)) * np.exp(-a * rp) / (4 * np.pi * Dp * np.sqrt(Dz) * rp)


def _interior_point_error(h, dims, v=1.0, Dp=1.3, Dz=0.6, rmin=1.5):
    """FV steady state with a one-cell source at (0, 0) inside a box much larger than the plume."""
    half = 6.0 if dims == 3 else 12.0
    top = 9.0 if dims == 3 else 16.0
    g = Grid(dims, (-half - h / 2, half + h / 2), (-4 - h / 2, top + h / 2), h)
    q = np.zeros(g.shape)
    k = int(round((0 - g.z[0]) / h))
    c = g.nx // 2
    q[(k,) + (c,) * (dims - 1)] = 1.0 / h**dims
    rho = _elliptic.solve_steady(g.shape, h, v, Dp, Dz, q.ravel())
    mesh = g.mesh()
    r = np.sqrt(sum(m**2 for m in mesh[1:]))
    Z = mesh[0]
    exact = _free_point(r, Z, v, Dp, Dz, dims)
    region = (np.hypot(r, Z) > rmin) & (Z < top / 2) & (r < half / 2)
    return np.max(np.abs(rho - exact)[region] / exact[region].max())


def test_elliptic_2d_k0_closed_form_second_order():
    e1, e2 = _interior_point_error(0.5, 2), _interior_point_error(0.25, 2)
    assert e2 < 1.5e-2 and e1 / e2 > 3.0, (e1, e2)


def test_elliptic_3d_closed_form_second_order():
    with np.errstate(divide="ignore"):
        e1, e2 = _interior_point_error(1.0, 3, rmin=3.0), _interior_point_error(0.5, 3, rmin=3.0)
    assert e2 < 4e-2 and e1 / e2 > 3.0, (e1, e2)


def test_elliptic_flux_balance_and_uniform_flow():
    """FV (varying drift forces it): outflow = Q0; uniform flow: rho = Q0 / (v_s L) exactly."""
    g = Grid(2, (-4, 4), (0, 10), 0.25)
    v = np.broadcast_to(1.5 + 0.2 * np.cos(g.mesh()[1]) + 0 * g.mesh()[0], g.shape)
    rho = sd.steady(g, Orifice(x=1.0, width=1.0, rate=2.0), Spots(drift=v, b=1.3, b_par=2.8))
    A, out = _elliptic.assemble(g.shape, g.spacing, v, 1.3 * v, 2.8 * v)
    assert (out @ rho.ravel())[0] == pytest.approx(2.0, rel=1e-12)
    assert np.abs(A @ rho.ravel() + _elliptic.floor_source(
        g.shape, g.spacing, 2.0 * source_profile(g, Orifice(x=1.0, width=1.0)))).max() < 1e-10
    for drift in (1.5, np.full(g.shape, 1.5)):          # exact modes and finite volumes
        uni = sd.steady(g, Orifice(width=8.0, rate=2.0), Spots(drift=drift, b=1.3, b_par=2.8))
        np.testing.assert_allclose(uni, 2.0 / (1.5 * 8.0), rtol=1e-12)


@pytest.mark.parametrize("dims", [2, 3])
def test_exact_modes_with_d_par_conserve_flux_and_match_finite_volumes(dims):
    """Uniform coefficients, D_par > 0: each cosine mode solves its ODE in z exactly
    (``_spectral.mode_profile``); mode 0 is constant, so v_s sum(rho) h^(dims-1) = Q0 at
    every height, and the FV solution converges to it."""
    errs = []
    for h in ((0.5, 0.25) if dims == 2 else (1.0, 0.5)):
        g = Grid(dims, (-4, 4), (0, 8), h)
        o = Orifice(x=0.7, y=0.3, width=2.0, rate=1.5)
        exact = sd.steady(g, o, Spots(drift=1.3, b=1.3, b_par=0.8))
        flux = 1.3 * exact.reshape(g.nz, -1).sum(axis=1) * h ** (dims - 1)
        np.testing.assert_allclose(flux, 1.5, rtol=1e-13)
        assert exact.min() > 0
        q = _elliptic.floor_source(g.shape, h, 1.5 * source_profile(g, o))
        fv = _elliptic.solve_steady(g.shape, h, 1.3, 1.3 * 1.3, 0.8 * 1.3, q)
        errs.append(np.abs(fv - exact)[g.z >= 2].max() / exact.max())
    assert errs[1] < 2e-2 and errs[0] / errs[1] > 3.0, errs


def test_mode_profile_solves_its_ode():
    """G'' b_par - G' - b k^2 G = 0, G - b_par G' = 1 at z = 0, G'(H) = 0 (finite differences)."""
    from spotpde.density._spectral import mode_profile
    b, bp, H, e = 1.3, 0.8, 6.0, 1e-4
    for k2 in (0.0, 0.3, 4.0):
        G = lambda z: mode_profile(np.array(k2), np.asarray(z, float), b, bp, H)
        z = np.array([0.5, 2.0, 5.0])
        d1 = (G(z + e) - G(z - e)) / (2 * e)
        d2 = (G(z + e) - 2 * G(z) + G(z - e)) / e**2
        np.testing.assert_allclose(bp * d2 - d1 - b * k2 * G(z), 0, atol=1e-6)
        assert G(0.0) - bp * (G(e) - G(-e)) / (2 * e) == pytest.approx(1.0, abs=1e-7)
        assert (G(H + e) - G(H - e)) / (2 * e) == pytest.approx(0.0, abs=1e-7)


def test_elliptic_without_d_par_tends_to_marching():
    """With D_par = 0 the FV steady state (BDF2 in height) approaches the exact modes as h^2."""
    errs = []
    for h in (0.5, 0.25):
        g = Grid(2, (-6, 6), (0, 8), h)
        o = Orifice(x=0.0, width=2.0)
        exact = sd.steady(g, o, Spots(b=1.3))
        q = _elliptic.floor_source(g.shape, h, source_profile(g, o))
        fv = _elliptic.solve_steady(g.shape, h, 1.0, 1.3, 0.0, q)
        errs.append(np.abs(fv - exact)[g.z > 2].max())
    assert errs[0] / errs[1] > 3.0, errs


# -- transient ------------------------------------------------------------------------------------
def test_transient_startup_matches_propagator_quadrature():
    """Constant injection at (0, 0) from t = 0: rho = Q int_0^t P(x, z, tau) dtau, P Gaussian."""
    v, Dp, Dz, t_end = 1.0, 1.3, 0.6, 6.0
    errs = []
    for h in (0.5, 0.25):
        g = Grid(2, (-10 - h / 2, 10 + h / 2), (-4 - h / 2, 14 + h / 2), h)
        q = np.zeros(g.shape)
        q[int(round(-g.z[0] / h)), g.nx // 2] = 1.0 / h**2
        res = _transient.integrate(g.shape, h, v, Dp, Dz, lambda t: q.ravel(), t_end,
                                   np.array([t_end]), dt=h / 5)
        rho = res["frames"][0]
        Z, X = (np.broadcast_to(m, g.shape) for m in g.mesh())
        region = np.broadcast_to((np.hypot(X, Z) > 1.5) & (np.abs(X) < 5) & (Z < 9), g.shape)

        def P(tau):
            return np.exp(-X[region]**2 / (4 * Dp * tau) - (Z[region] - v * tau)**2 / (4 * Dz * tau)) \
                / (4 * np.pi * tau * np.sqrt(Dp * Dz))
        exact, _ = quad_vec(P, 1e-9, t_end, epsabs=1e-12)
        errs.append(np.max(np.abs(rho[region] - exact)) / exact.max())
    assert errs[1] < 1.5e-2 and errs[0] / errs[1] > 3.0, errs   # as the steady K0 check


@pytest.mark.parametrize("b_par", [0.0, 1.0])
def test_transient_converges_to_steady(b_par):
    g = Grid(2, (-4, 4), (0, 8), 0.25)
    o = Orifice(x=0.5, width=1.0, rate=1.5)
    s = Spots(drift=1.0, b=1.3, b_par=b_par)
    rho_t = sd.transient(g, o, s, t_end=60.0)
    q = _elliptic.floor_source(g.shape, g.spacing, 1.5 * source_profile(g, o))
    rho_fv = _elliptic.solve_steady(g.shape, g.spacing, 1.0, 1.3, b_par, q)
    np.testing.assert_allclose(rho_t, rho_fv, atol=1e-8 * rho_fv.max())
    # the exact-mode steady state differs by the O(h^2) discretisation error only
    far = g.z > 2
    exact = sd.steady(g, o, s)
    assert np.abs(rho_t - exact)[far].max() < 2e-2 * exact.max()


def test_transient_mass_budget_with_time_varying_rate():
    """Before spots reach the top, spots inside = int_0^t Q0 dt' (BDF2: error O(dt^2))."""
    g = Grid(2, (-4, 4), (0, 20), 0.25)
    rate = rate_from_table([0.0, 2.0, 4.0, 6.0], [0.0, 2.0, 0.5, 1.0])
    o = Orifice(x=0.0, width=1.0, rate=rate)
    s = Spots(drift=1.0, b=1.3, b_par=0.5)
    times = np.array([1.0, 3.0, 5.0])
    exact = np.array([np.trapezoid(rate(np.linspace(0, t, 20001)), np.linspace(0, t, 20001)) for t in times])
    errs = []
    for dt in (0.1, 0.05):
        res = sd.transient(g, o, s, 5.0, times=times, dt=dt, full_output=True)
        mass = res["frames"].sum(axis=(1, 2)) * g.spacing**2
        np.testing.assert_allclose(res["inflow"], rate(times), rtol=1e-12)
        assert np.all(res["outflow"] < 1e-9)     # the plume has not reached the top
        errs.append(np.abs(mass - exact).max())
    assert errs[1] < 2e-3 and errs[0] / errs[1] > 3.0, errs


def test_solve_dispatches_on_mode():
    g = Grid(2, (-3, 3), (0, 3), 0.25)
    o = Orifice(width=1.0)
    steady = sd.solve(g, o, Spots(b=1.0, b_par=0.5))
    trans = sd.solve(g, o, Spots(b=1.0, b_par=0.5, mode="transient", t_end=1.0))
    assert trans.sum() < steady.sum()          # only part of the column is filled by t = 1
    np.testing.assert_allclose(trans, sd.transient(g, o, Spots(b=1.0, b_par=0.5), 1.0))


def test_invalid_spots_name_the_key():
    g = Grid(2, (-3, 3), (0, 3), 0.25)
    with pytest.raises(ValueError, match=r"spots.b: must be > 0"):
        sd.steady(g, Orifice(), Spots(b=-1.0))
    with pytest.raises(ValueError, match=r"spots.drift: an array must have the grid shape"):
        sd.steady(g, Orifice(), Spots(drift=np.ones(5)))
    with pytest.raises(ValueError, match=r"spots.mode: must be one of 'steady', 'transient'"):
        sd.solve(g, Orifice(), Spots(mode="fast"))
    with pytest.raises(ValueError, match=r"orifice.rate"):
        sd.steady(g, Orifice(rate=lambda t: 1.0), Spots())


def test_py_pde_runge_kutta_agrees_with_bdf2():
    """py-pde's adaptive RK (same operator) vs BDF2: the difference is BDF2's O(dt^2) error."""
    g = Grid(2, (-3, 3), (0, 6), 0.25)
    o = Orifice(x=0.5, width=1.0, rate=rate_from_table([0.0, 2.0, 4.0], [1.0, 2.0, 0.5]))
    s = Spots(b=1.3, b_par=0.5)
    times = np.array([0.0, 1.0, 2.5, 4.0])
    ref = {dt: sd.transient(g, o, s, 4.0, times=times, dt=dt) for dt in (0.02, 0.01)}
    rk = sd.transient(g, o, s, 4.0, times=times, method="py-pde")
    bdf2_error = np.abs(ref[0.02] - ref[0.01]).max() / 3          # Richardson, order 2
    assert np.abs(rk - ref[0.01]).max() < 2 * bdf2_error
    assert bdf2_error < 1e-4 * ref[0.01].max()


def test_py_pde_numba_rhs_matches_operator():
    from spotpde.density._pde import SpotDensityPDE
    import pde
    g = Grid(2, (-2, 2), (0, 3), 0.25)
    Z, X = g.mesh()
    v = np.broadcast_to(1 + 0.2 * np.cos(X) + 0 * Z, g.shape)
    q = _elliptic.floor_source(g.shape, g.spacing, source_profile(g, Orifice(width=1.0)))
    eq = SpotDensityPDE(g, v, 1.3 * v, 0.4 * v, q, 2.0)
    rho = np.exp(-X**2 - (Z - 1) ** 2) + 0 * Z
    state = pde.ScalarField(g.to_pde(), g.to_pde_data(rho))
    rhs = eq.make_pde_rhs(state, backend="numba")(state.data, 0.0)
    A, _ = _elliptic.assemble(g.shape, g.spacing, v, 1.3 * v, 0.4 * v)
    expected = (A @ rho.ravel() + 2.0 * q).reshape(g.shape)
    np.testing.assert_allclose(g.from_pde_data(rhs), expected, rtol=1e-12, atol=1e-12)


def test_iterative_solver_matches_direct(monkeypatch):
    """Above DIRECT_LIMIT the steady solve is ILU-preconditioned GMRES: same solution."""
    g = Grid(3, (-2, 2), (0, 3), 0.25)
    o = Orifice(x=0.3, y=0.1, width=1.0)
    s = Spots(drift=np.full(g.shape, 1.0), b=1.3, b_par=0.7)      # array drift: finite volumes
    direct = sd.steady(g, o, s)
    monkeypatch.setitem(_elliptic.DIRECT_LIMIT, 3, 100)
    iterative = sd.steady(g, o, s)
    np.testing.assert_allclose(iterative, direct, rtol=0, atol=1e-9 * direct.max())


@pytest.mark.parametrize("mode", ["steady_varying", "transient"])
def test_progress_reports_fractions_up_to_one(mode):
    g = Grid(2, (-3, 3), (0, 12), 0.25)
    calls = []
    if mode == "transient":
        sd.transient(g, Orifice(), Spots(b=1.0, b_par=0.3), 30.0, progress=calls.append)
    else:
        b = np.broadcast_to(1.0 + 0.1 * g.mesh()[0], g.shape)
        sd.steady(g, Orifice(), Spots(b=b), progress=calls.append)
    assert 2 <= len(calls) <= 300
    assert np.all(np.diff(calls) >= 0) and calls[-1] == 1.0 and calls[0] >= 0.0


def test_open_walls_transient_matches_wide_reflecting_silo():
    """An open window equals the middle of a much wider reflecting silo."""
    s = Spots(b=1.0, b_par=0.5)
    o = Orifice(x=1.0, width=1.0)
    g = Grid(2, (-3, 3), (0, 6), 0.25, "open")
    wide = Grid(2, (-30, 30), (0, 6), 0.25)
    a = sd.transient(g, o, s, 5.0)
    b = sd.transient(wide, o, s, 5.0)
    i0 = int(round(27 / 0.25))
    np.testing.assert_allclose(a, b[:, i0:i0 + g.nx], atol=1e-12 * b.max())


def test_transient_3d_converges_to_steady_and_keeps_symmetry():
    g = Grid(3, (-2, 2), (0, 3), 0.25)
    o = Orifice(x=0.0, y=0.0, width=1.5, rate=2.0)
    s = Spots(drift=1.0, b=1.0, b_par=0.5)
    rho_t = sd.transient(g, o, s, t_end=40.0)
    q = _elliptic.floor_source(g.shape, g.spacing, 2.0 * source_profile(g, o))
    rho_s = _elliptic.solve_steady(g.shape, g.spacing, 1.0, 1.0, 0.5, q)
    np.testing.assert_allclose(rho_t, rho_s, atol=1e-8 * rho_s.max())
    np.testing.assert_allclose(rho_s, np.swapaxes(rho_s, 1, 2), atol=1e-12 * rho_s.max())
    np.testing.assert_allclose(rho_s, rho_s[:, ::-1, :], atol=1e-12 * rho_s.max())
