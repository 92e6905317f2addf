"""The void model: lattice dynamics, continuum limit, closed form, coefficient fields.

Derivations and the meaning of every tolerance: docs/void_model.md.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from spotpde.density import kinematic
from spotpde.fields import void
from spotpde.grid import Grid
from spotpde.parameters import Spots

THREE_POINT = ((-1, 0.25), (0, 0.5), (1, 0.25))  # square lattice, b = 1/4


def _moments(sites, p):
    m = p @ sites
    return m, p @ sites.astype(float) ** 2 - m * m


# ------------------------------------------------------------------ lattice, exact --------
def test_lattice_b_follows_eq_blattice():
    assert void.lattice_b(void.STAGGERED) == pytest.approx(0.5, abs=1e-15)
    assert void.lattice_b(THREE_POINT) == pytest.approx(0.25, abs=1e-15)
    assert void.lattice_b(void.STAGGERED, site_spacing=0.5, row_spacing=0.25) == pytest.approx(0.5)


def test_lattice_void_density_is_binomial():
    sites, rho = void.lattice_void_density(20)
    for k in (1, 7, 20):
        expect = np.where((sites + k) % 2 == 0, stats.binom.pmf((sites + k) // 2, k, 0.5), 0.0)
        np.testing.assert_allclose(rho[k], expect, atol=1e-15)
        assert rho[k].sum() == pytest.approx(1.0, abs=1e-13)


@pytest.mark.parametrize("x0", [0, 8, -12])
def test_lattice_propagator_is_exact_random_walk_bridge(x0):
    """Transfer matrix = reversed void path conditioned on (x0, z0) = hypergeometric law."""
    n = 30
    sites, P = void.lattice_propagator(x0, n)
    up = (n + x0) // 2  # up-steps of the bridge
    for k in range(0, n + 1, 3):
        plus = (sites + k) / 2  # number of + steps among the first k
        ok = ((sites + k) % 2 == 0) & (plus >= 0) & (plus <= k)
        expect = np.zeros_like(P[k])
        expect[ok] = stats.hypergeom.pmf(plus[ok].astype(int), n, up, k)
        np.testing.assert_allclose(P[k], expect, atol=1e-13)
    assert P[0][sites == 0][0] == pytest.approx(1.0, abs=1e-13)  # ends at the orifice


def test_lattice_particle_step_drift_is_minus_x_over_z():
    """Mean step of a particle leaving (i, k+1): exactly -i/(k+1), toward the axis.

    The printed eq. Pcp would give +i/(2(k+1)) (away from the axis).
    """
    for steps in (void.STAGGERED, THREE_POINT):
        sites, rho = void.lattice_void_density(25, steps)
        for k in (3, 10, 24):
            reach = rho[k + 1] > 1e-300
            mean_step = np.zeros_like(rho[k + 1])
            for o, p in steps:  # came from j = i - o: displacement -o
                mean_step += -o * p * np.roll(rho[k], o)
            i = sites[reach]
            np.testing.assert_allclose(mean_step[reach] / rho[k + 1][reach], -i / (k + 1),
                                       atol=1e-12)


@pytest.mark.parametrize("steps,x0,z0,n",
                         [(void.STAGGERED, 6, 30, 8000), (THREE_POINT, 5, 24, 4000)])
def test_montecarlo_of_voids_matches_exact_lattice(steps, x0, z0, n):
    """Voids injected at the orifice displace the particle: agrees with the master equation."""
    X = void.lattice_void_montecarlo(x0, z0, n, steps=steps, seed=12345)
    assert np.all(X[:, z0] == x0)
    assert np.all(X[:, 0] == 0)  # every particle leaves through the orifice site
    assert np.all(np.abs(np.diff(X, axis=1)) <= 1)
    sites, P = void.lattice_propagator(x0, z0, steps)
    for k in (z0 // 4, z0 // 2, 3 * z0 // 4):
        m, v = _moments(sites, P[k])
        m4 = P[k] @ (sites - m) ** 4.0
        se_m = np.sqrt(v / n)
        se_v = np.sqrt((m4 - v * v) / n)
        assert abs(X[:, k].mean() - m) < 4 * se_m
        assert abs(X[:, k].var() - v) < 4 * se_v
    # full distribution at mid height: chi-square on bins with >= 5 expected counts
    k = z0 // 2
    counts = np.array([(X[:, k] == s).sum() for s in sites])
    expected = n * P[k]
    big = expected >= 5
    obs = np.append(counts[big], counts[~big].sum())
    exp = np.append(expected[big], expected[~big].sum())
    keep = exp > 0
    chi2 = ((obs[keep] - exp[keep]) ** 2 / exp[keep]).sum()
    assert chi2 < stats.chi2.ppf(0.999, keep.sum() - 1)


# ------------------------------------------------------------------ continuum limit -------
def test_lattice_converges_to_continuum_bridge():
    """At fixed physical z0, x0, b: n rows, x0 ~ sqrt(n) sites; errors fall like 1/n."""
    b = void.lattice_b(void.STAGGERED)
    l1 = []
    for n in (16, 64, 256):
        x0 = int(np.sqrt(n)) // 2
        sites, P = void.lattice_propagator(x0, n)
        worst = 0.0
        for k in (n // 4, n // 2, 3 * n // 4):
            m, v = _moments(sites, P[k])
            mc, vc = void.bridge_moments(k, x0, n, b)
            assert m == pytest.approx(mc, abs=1e-9)
            assert abs(v / vc - 1) <= 1.0 / (n - 1)
            on = (sites + k) % 2 == 0  # occupied sublattice, spacing 2 sites
            dens = 2.0 * void.geometric_propagator(sites[on].astype(float), k, x0, n, b)
            worst = max(worst, np.abs(P[k][on] - dens).sum() + P[k][~on].sum())
        l1.append(worst)
    assert l1[0] < 0.1
    assert l1[1] < 0.35 * l1[0] and l1[2] < 0.35 * l1[1]  # 1/n would give 0.25


def test_lattice_disagrees_with_printed_eq():
    n, x0, k = 48, 6, 12
    b = void.lattice_b(void.STAGGERED)
    sites, P = void.lattice_propagator(x0, n)
    m, v = _moments(sites, P[k])
    X = void.lattice_void_montecarlo(x0, n, 1000, seed=7)
    se = np.sqrt(X[:, k].var() / X.shape[0])
    mp, vp = void.printed_moments(k, x0, n, b)
    mb, vb = void.bridge_moments(k, x0, n, b)
    assert abs(X[:, k].mean() - mb) < 4 * se
    assert abs(X[:, k].mean() - mp) > 20 * se  # printed eq: particle drifts away from axis
    assert mp > x0 > m  # printed moves out, lattice moves in
    assert vp > 5 * v


# ------------------------------------------------------------------ closed forms ---------
def test_geometric_propagator_is_doob_transform():
    """P = rho_v(x, z) G(x0 - x, z0 - z) / rho_v(x0, z0), normalised, bridge moments."""
    b, x0, z0 = 1.3, 4.0, 30.0
    x = np.linspace(-60, 60, 24001)
    dx = x[1] - x[0]
    for z in (3.0, 15.0, 27.0):
        P = void.geometric_propagator(x, z, x0, z0, b)
        G = np.exp(-((x0 - x) ** 2) / (4 * b * (z0 - z))) / np.sqrt(4 * np.pi * b * (z0 - z))
        doob = void.point_void_density(x, z, b) * G / void.point_void_density(x0, z0, b)
        np.testing.assert_allclose(P, doob, rtol=1e-10, atol=1e-300)
        assert P.sum() * dx == pytest.approx(1.0, abs=1e-10)
        assert (P * x).sum() * dx == pytest.approx(x0 * z / z0, abs=1e-9)
    # 3D: product of independent bridges, each with variance 2 b z (z0 - z) / z0
    X, Y = np.meshgrid(np.linspace(-25, 25, 501), np.linspace(-25, 25, 501))
    z = 10.0
    P3 = void.geometric_propagator((X, Y), z, (x0, -2.0), z0, b, dims=3)
    P3_doob = (void.point_void_density((X, Y), z, b, dims=3)
               * np.exp(-((X - x0) ** 2 + (Y + 2) ** 2) / (4 * b * (z0 - z)))
               / (4 * np.pi * b * (z0 - z))
               / void.point_void_density((x0, -2.0), z0, b, dims=3))
    np.testing.assert_allclose(P3, P3_doob, rtol=1e-10, atol=1e-300)
    with pytest.raises(ValueError):
        void.geometric_propagator(x, z0, x0, z0, b)


@pytest.mark.parametrize("form", ["derived", "printed"])
def test_marcher_reproduces_closed_forms(form):
    """Each closed form solves its PDE: march from z0 - 2 and compare moments."""
    b, x0, z0 = 1.3, 5.0, 40.0
    dx = 0.1
    x = np.arange(-100.0, 100.0, dx) + dx / 2
    prop = void.geometric_propagator if form == "derived" else void.printed_propagator
    mom = void.bridge_moments if form == "derived" else void.printed_moments
    z_out = [30.0, 20.0, 10.0]
    Ps = void.march_propagator(x, prop(x, z0 - 2, x0, z0, b), z0 - 2, z_out,
                               lambda x, z: -x**2 / (4 * b * z), b, form=form, dz=0.02)
    for z, P in zip(z_out, Ps):
        assert P.sum() * dx == pytest.approx(1.0, abs=1e-10)
        m = (P * x).sum() * dx
        v = (P * x * x).sum() * dx - m * m
        mc, vc = mom(z, x0, z0, b)
        assert m == pytest.approx(mc, rel=1e-3)
        assert v == pytest.approx(vc, rel=1e-3)
        assert P.min() > -1e-12


def test_pcp_rhs_forms_differ_in_drift_sign_and_size():
    """Mean horizontal velocity per unit fall: derived 2b <d log rho>, printed -b <d log rho>."""
    b, x0, z0, z = 1.3, 5.0, 40.0, 20.0
    dx = 0.05
    x = np.arange(-60.0, 60.0, dx) + dx / 2
    P = void.geometric_propagator(x, z, x0, z0, b)
    logr = -x**2 / (4 * b * z)
    grad = (P * (-x / (2 * b * z))).sum() * dx  # <d_x log rho_v>
    d_mean_derived = (x * void.pcp_rhs(P, x, logr, b)).sum() * dx
    d_mean_printed = (x * void.printed_eq_pcp_rhs(P, x, logr, b)).sum() * dx
    assert d_mean_derived == pytest.approx(2 * b * grad, rel=1e-4)
    assert d_mean_printed == pytest.approx(-b * grad, rel=1e-4)


# ------------------------------------------------------------------ grid fields ----------
def _point_fields(h, rule=1.0, V1=0.8, v_s=1.5, b=1.3):
    grid = Grid(2, (-16.0, 16.0), (0.0, 32.0), h, walls="open")
    Z, X = grid.mesh()
    rho = void.point_void_density(X, Z, b) / v_s  # Q0 = 1
    f = void.void_fields(grid, rho, Spots(drift=v_s, b=b), V1, rule=rule)
    return grid, Z, X, rho, f


def test_void_fields_give_lattice_drift_and_diffusion_per_fall():
    """u_x/|u_z| = 2 b d_x log rho = -x/z and D_xx/|u_z| = b; error O(h^2)."""
    b = 1.3
    errs = []
    for h in (0.5, 0.25):
        grid, Z, X, rho, f = _point_fields(h, b=b)
        sel = np.broadcast_to(Z >= 4.0, grid.shape)
        drift = f["u_x"] / -f["u_z"]
        errs.append(np.abs(drift + X / Z)[sel].max())
        np.testing.assert_allclose(f["D_xx"] / -f["u_z"], b, rtol=1e-12)
        assert np.all(f["D_zz"] == 0) and np.all(f["D_xz"] == 0)
    assert errs[1] < 0.05 * np.abs(X / Z).max()
    assert errs[0] / errs[1] > 3.5  # second order


def test_void_flux_velocity_is_kinematic():
    """u_p - div D_p = (b d_x v, -v), v = V1 v_s rho (lam = 1); lam = 1/2 has no horizontal part."""
    V1, v_s, b = 0.8, 1.5, 1.3
    errs = []
    for h in (0.5, 0.25):
        grid, Z, X, rho, f = _point_fields(h, V1=V1, v_s=v_s, b=b)
        flux_x = f["u_x"] - np.gradient(f["D_xx"], h, axis=1, edge_order=2)
        v = V1 * v_s * rho
        kin_x = b * v * (-X / (2 * b * Z))  # b d_x v, analytic
        sel = np.broadcast_to(Z >= 4.0, grid.shape)
        errs.append(np.abs(flux_x - kin_x)[sel].max() / np.abs(kin_x)[sel].max())
        np.testing.assert_allclose(f["u_z"], -v, rtol=1e-12)
        # drift alone is twice the kinematic horizontal velocity
        assert np.abs(f["u_x"] - 2 * kin_x)[sel].max() < 0.02 * np.abs(kin_x)[sel].max()
    assert errs[1] < 0.01 and errs[0] / errs[1] > 3.5
    grid, Z, X, rho, f = _point_fields(0.5, rule=0.5, V1=V1, v_s=v_s, b=b)
    flux_x = f["u_x"] - np.gradient(f["D_xx"], 0.5, axis=1, edge_order=2)
    assert np.abs(flux_x).max() < 1e-12 * np.abs(f["u_x"]).max()


def test_void_fields_variable_coefficients_and_3d():
    """Space-varying b uses div(D_s rho_s); 3D has the full key set and symmetric u_x/u_y."""
    errs = []
    for h in (0.25, 0.125):
        grid = Grid(2, (-8.0, 8.0), (0.0, 8.0), h, walls="open")
        Z, X = grid.mesh()
        rho = 1.0 + 0.3 * np.sin(X / 3) * np.exp(-Z / 10) + 0 * Z
        bfield = 1.0 + 0.2 * np.cos(X / 4) + 0 * Z
        bpar = 0.5 + 0.1 * Z / 8 + 0 * X
        f = void.void_fields(grid, rho, Spots(drift=2.0, b=bfield, b_par=bpar), 1.0)
        # analytic d_x(rho D_perp) and d_z(rho D_par), v_s = 2
        dFx = 2.0 * (0.3 * np.cos(X / 3) / 3 * np.exp(-Z / 10) * bfield
                     + rho * (-0.2 * np.sin(X / 4) / 4))
        dFz = 2.0 * (0.3 * np.sin(X / 3) * (-0.1) * np.exp(-Z / 10) * bpar + rho * 0.1 / 8)
        errs.append((np.abs(f["u_x"] - 2 * dFx).max() / np.abs(2 * dFx).max(),
                     np.abs(f["u_z"] + (rho * 2.0 - 2 * dFz)).max() / np.abs(2 * dFz).max()))
        np.testing.assert_allclose(f["D_zz"], rho * bpar * 2.0, rtol=1e-12)
        np.testing.assert_allclose(f["D_xx"], rho * bfield * 2.0, rtol=1e-12)
    for coarse, fine in zip(*errs):
        assert fine < 1e-3 and coarse / fine > 3.5  # second order, boundaries included

    g3 = Grid(3, (-6.0, 6.0), (0.0, 12.0), 0.5, walls="open")
    Z, Y, X = g3.mesh()
    rho3 = void.point_void_density((X, Y), Z, 1.3, dims=3)
    f3 = void.void_fields(g3, rho3, Spots(drift=1.0, b=1.3), 1.0)
    assert set(f3) == {"u_x", "u_y", "u_z", "D_xx", "D_yy", "D_zz", "D_xy", "D_xz", "D_yz"}
    assert all(a.shape == g3.shape for a in f3.values())
    np.testing.assert_allclose(f3["u_y"], np.swapaxes(f3["u_x"], 1, 2), atol=1e-14)
    sel = np.broadcast_to(Z >= 4.0, g3.shape)
    drift_x = f3["u_x"] / -f3["u_z"]
    exact = np.broadcast_to(-X / Z, g3.shape)
    assert np.abs(drift_x - exact)[sel].max() < 0.05 * np.abs(exact)[sel].max()
    with pytest.raises(ValueError):
        void.void_fields(g3, rho3[:-1], Spots(), 1.0)


def test_void_density_is_the_kinematic_point_source():
    """Eq. rhov for voids and the kinematic speed share one closed form (docs/conventions.md section 4)."""
    x = np.linspace(-8, 8, 33)
    for z in (0.5, 3.0, 20.0):
        np.testing.assert_allclose(void.point_void_density(x, z, 1.3),
                                   kinematic.point_source(x, z, 1.3), rtol=1e-13)
        X, Y = np.meshgrid(x, x)
        np.testing.assert_allclose(void.point_void_density((X, Y), z, 1.3, dims=3),
                                   kinematic.point_source(np.hypot(X, Y), z, 1.3, dims=3),
                                   rtol=1e-13)
