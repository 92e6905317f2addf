"""Spot density and Kinematic Model in axisymmetric (r, z) coordinates against closed forms
(docs/spot_density.md section 9)."""

import numpy as np
import pytest
from scipy.special import j0, jn_zeros

from spotpde.density import _geometry, kinematic
from spotpde.density import spot_density as sd
from spotpde.density.orifice import cosine_coefficients, rate_from_table, source_profile
from spotpde.grid import Grid
from spotpde.parameters import Orifice, Spots

from _grids import cylinder


def flux(g, rho, v=1.0):
    """Spots per unit time through every height: v_s sum(rho_s * 2 pi r h)."""
    return (v * rho * g.horizontal_measures).sum(axis=1)


def orders(errors):
    e = np.asarray(errors)
    return np.log2(e[:-1] / e[1:])


def bessel_series(r, z, a, b, Q0, terms=400):
    """Q0/(pi a^2) sum_n J0(j_n r/a)/J0(j_n)^2 exp(-b j_n^2 z/a^2), j_n the zeros of J1 (j_0 = 0)."""
    out = 0.0
    for j in np.concatenate([[0.0], jn_zeros(1, terms)]):
        out = out + j0(j * r / a) / j0(j) ** 2 * np.exp(-b * j * j * z / a**2)
    return Q0 / (np.pi * a * a) * out


# -- orifice ----------------------------------------------------------------------------------
def test_ring_profiles_are_exact_ring_masses():
    g = cylinder(4, 2, 0.5)
    meas = g.horizontal_measures
    s = source_profile(g, Orifice(x=0.0, width=2.3))            # disk R = 1.15
    R = 1.15
    expect = np.array([0.25, 0.75, R**2 - 1.0, 0, 0, 0, 0, 0]) / R**2   # (r+^2 - r-^2) / R^2
    np.testing.assert_allclose(s * meas, expect, rtol=1e-14, atol=1e-16)
    sg = source_profile(g, Orifice(x=0.0, width=1.0, profile="gaussian"))   # sigma = 1/2
    edges = 0.5 * np.arange(10)                                   # 8 sigma = 4 = a, plus a cell
    ring = np.exp(-edges[:-1] ** 2 / 0.5) - np.exp(-edges[1:] ** 2 / 0.5)
    ring[7] += ring[8]                                            # mirrored about r = a
    np.testing.assert_allclose(sg * meas, ring[:8] / ring[:8].sum(), rtol=1e-13)
    sp = source_profile(g, Orifice(x=0.0))                        # point: the disk r < h
    assert sp[0] == pytest.approx(1.0 / (np.pi * 0.25)) and np.all(sp[1:] == 0)
    for o in (Orifice(x=0.0, width=7.0, profile="gaussian"), Orifice(x=0.0, width=9.0)):
        assert np.sum(source_profile(g, o) * meas) == pytest.approx(1.0, abs=1e-14)
    uni = source_profile(g, Orifice(x=0.0, width=8.0))            # the whole floor
    np.testing.assert_allclose(uni, 1.0 / (np.pi * 16.0), rtol=1e-15)


def test_off_axis_orifice_and_unsupported_paths_raise():
    g = cylinder(3, 3, 0.5)
    with pytest.raises(ValueError, match="^orifice.x"):
        source_profile(g, Orifice(x=1.0))
    with pytest.raises(ValueError, match="^grid"):
        cosine_coefficients(g, Orifice(x=0.0))
    with pytest.raises(ValueError, match="^spots.method"):
        sd.transient(g, Orifice(x=0.0), Spots(), 1.0, method="euler")


def test_py_pde_runge_kutta_agrees_with_bdf2_on_a_cylinder():
    """py-pde's adaptive RK on the same metric operator vs BDF2: BDF2's O(dt^2) error."""
    g = cylinder(2, 4, 0.25)
    o = Orifice(x=0.0, width=1.0, rate=rate_from_table([0.0, 1.0, 2.0], [1.0, 2.0, 0.5]))
    s = Spots(b=1.3, b_par=0.5)
    times = np.array([0.0, 1.0, 2.0])
    ref = {dt: sd.transient(g, o, s, 2.0, times=times, dt=dt) for dt in (0.02, 0.01)}
    rk = sd.transient(g, o, s, 2.0, times=times, method="py-pde")
    bdf2_error = np.abs(ref[0.02] - ref[0.01]).max() / 3          # Richardson, order 2
    assert np.abs(rk - ref[0.01]).max() < 2 * bdf2_error
    assert bdf2_error < 1e-4 * ref[0.01].max()


# -- steady, D_par = 0 ------------------------------------------------------------------------
def test_point_orifice_converges_second_order_to_closed_form():
    """Open wall (a window on a wide silo): Q0/(4 pi b z) exp(-r^2/4bz) for z >= 3.

    The point orifice fills the first ring (second moment h^2/2), so the field differs
    by O(h^2 / (b z)); measured 5.8e-3, 1.5e-3, 3.7e-4 of the peak at h = 1/4, 1/8, 1/16.
    """
    b, Q0, errs = 0.8, 2.0, []
    for h in (0.25, 0.125, 0.0625):
        g = cylinder(6, 6, h, "open")
        rho = sd.steady(g, Orifice(x=0.0, rate=Q0), Spots(drift=1.0, b=b))
        Z, R = g.mesh()
        exact = Q0 * kinematic.point_source(R, Z, b, dims=3)
        sel = np.broadcast_to(Z >= 3, rho.shape)
        errs.append(np.abs(rho - exact)[sel].max() / exact[sel].max())
    assert np.all(orders(errs) > 1.9), errs
    assert errs[-1] < 5e-4


def test_reflecting_cylinder_matches_bessel_series_and_conserves_flux():
    a, b, Q0, errs = 3.0, 1.0, 1.5, []
    for h in (0.25, 0.125, 0.0625):
        g = cylinder(a, 8, h)
        rho = sd.steady(g, Orifice(x=0.0, rate=Q0), Spots(drift=1.0, b=b))
        np.testing.assert_allclose(flux(g, rho), Q0, rtol=0, atol=1e-13)
        Z, R = g.mesh()
        exact = bessel_series(R, Z, a, b, Q0)
        sel = np.broadcast_to(Z >= 3, rho.shape)
        errs.append(np.abs(rho - exact)[sel].max() / exact[sel].max())
    # measured 2.2e-3, 5.8e-4, 1.5e-4 (z >= 3; 4.9e-2, 1.2e-2, 2.9e-3 for z >= 1)
    assert np.all(orders(errs) > 1.9) and errs[-1] < 2e-4, errs
    # far up, only the uniform mode Q0 / (pi a^2) is left
    g = cylinder(a, 30, 0.25)
    rho = sd.steady(g, Orifice(x=0.0, width=2.0, rate=Q0), Spots(drift=1.0, b=b))
    np.testing.assert_allclose(rho[-1], Q0 / (np.pi * a * a), rtol=1e-6)


def test_varying_b_of_z_is_a_gaussian_of_integrated_b():
    """b = b0 (1 + z/z1): tau = b0 (z + z^2/2 z1), rho = Q0 exp(-r^2/4 tau)/(4 pi tau) (open wall)."""
    b0, z1, errs = 0.6, 4.0, []
    for h in (0.25, 0.125):
        g = cylinder(8, 6, h, "open")
        Z, R = g.mesh()
        b = np.broadcast_to(b0 * (1 + Z / z1), g.shape).copy()
        rho = sd.steady(g, Orifice(x=0.0), Spots(drift=1.0, b=b))
        tau = b0 * (Z + Z**2 / (2 * z1))
        exact = np.exp(-R**2 / (4 * tau)) / (4 * np.pi * tau)
        sel = np.broadcast_to(Z >= 3, rho.shape)
        errs.append(np.abs(rho - exact)[sel].max() / exact[sel].max())
    assert orders(errs)[0] > 1.9 and errs[-1] < 6e-4, errs      # measured 2.1e-3, 4.5e-4


def test_flux_is_Q0_at_every_height_with_b_and_v_varying():
    g = cylinder(3, 6, 0.25)
    Z, R = g.mesh()
    b = np.broadcast_to(0.7 + 0.4 * np.sin(R) * np.exp(-Z / 5), g.shape).copy()
    v = np.broadcast_to(1.0 + 0.3 * np.cos(R + Z), g.shape).copy()
    rho = sd.steady(g, Orifice(x=0.0, width=1.5, rate=2.5), Spots(drift=v, b=b))
    np.testing.assert_allclose(flux(g, rho, v), 2.5, rtol=0, atol=1e-13)


def test_axisymmetric_equals_3d_cartesian_solve():
    """The same silo (Gaussian orifice, small b, short height: walls 5 d away do not matter
    for r < 3) on both grids.

    3D Cartesian: exact modes (cell averages); axisymmetric: finite volumes, read at
    the Cartesian cell centres (x_i, h/2) by linear interpolation in r. Both carry
    O(h^2) (cell averages, interpolation, the FV error): the difference is measured
    1.1e-2, 2.8e-3 (and 7.1e-4 at h = 1/16) of the peak at z >= 1 for h = 1/4, 1/8.
    """
    b, diffs = 0.25, []
    o = Orifice(x=0.0, y=0.0, width=1.0, profile="gaussian")
    for h in (0.25, 0.125):
        cart = Grid(3, (-5, 5), (0, 3), h, "reflecting")
        rc = sd.steady(cart, o, Spots(drift=1.0, b=b))
        axi = cylinder(5, 3, h)
        ra = sd.steady(axi, Orifice(x=0.0, width=1.0, profile="gaussian"), Spots(drift=1.0, b=b))
        j = cart.nx // 2                                   # the row of cells at y = +h/2
        x = cart.x[cart.nx // 2:]
        r = np.hypot(x, 0.5 * h)
        line = rc[:, j, cart.nx // 2:]
        interp = np.array([np.interp(r, axi.r, row) for row in ra])
        near = r < 3
        diffs.append(np.abs(line - interp)[cart.z >= 1][:, near].max() / line.max())
        # the spot flux through a height agrees to round-off (both conserve it exactly)
        np.testing.assert_allclose(rc.sum(axis=(1, 2)) * h * h, flux(axi, ra), rtol=1e-12)
    assert diffs[1] < diffs[0] / 3.5 and diffs[1] < 4e-3, diffs


def _on_cartesian_line(rc, ra, cart, axi, zmin, rmax):
    """max |Cartesian cells at y = h/2 - axisymmetric interpolated at their radius| / peak."""
    h, j = cart.spacing, cart.nx // 2
    r = np.hypot(cart.x[j:], 0.5 * h)
    line = rc[:, j, j:]
    interp = np.array([np.interp(r, axi.r, row) for row in ra])
    return np.abs(line - interp)[cart.z >= zmin][:, r < rmax].max() / line.max()


def test_axisymmetric_equals_3d_cartesian_with_b_par_steady_and_transient():
    """b_par = 0.5: steady (3D exact modes with the Danckwerts top vs axisymmetric FV)
    and transient from an empty silo to t = 2 (BDF2 on both, dt = 0.05). Measured
    6.7e-3, 1.7e-3 (steady, h = 1/4, 1/8) and 2.4e-2, 7.9e-3 (transient, h = 1/2, 1/4)."""
    sp = Spots(drift=1.0, b=0.25, b_par=0.5)
    o3 = Orifice(x=0.0, y=0.0, width=1.0, profile="gaussian")
    o2 = Orifice(x=0.0, width=1.0, profile="gaussian")
    steady = [_on_cartesian_line(sd.steady(Grid(3, (-4, 4), (0, 3), h), o3, sp),
                                 sd.steady(cylinder(4, 3, h), o2, sp),
                                 Grid(3, (-4, 4), (0, 3), h), cylinder(4, 3, h), 1.0, 2.5)
              for h in (0.25, 0.125)]
    assert steady[1] < steady[0] / 3.5 and steady[1] < 2.5e-3, steady
    trans = [_on_cartesian_line(sd.transient(Grid(3, (-3, 3), (0, 3), h), o3, sp, 2.0, dt=0.05),
                                sd.transient(cylinder(3, 3, h), o2, sp, 2.0, dt=0.05),
                                Grid(3, (-3, 3), (0, 3), h), cylinder(3, 3, h), 0.5, 2.5)
             for h in (0.5, 0.25)]
    assert trans[1] < trans[0] / 2.5 and trans[1] < 1e-2, trans


# -- b_par > 0 and transient -------------------------------------------------------------------
def test_b_par_steady_conserves_flux_and_transient_tends_to_it():
    g = cylinder(3, 6, 0.25)
    o, sp = Orifice(x=0.0, width=1.0, rate=1.2), Spots(drift=1.5, b=0.9, b_par=0.8)
    rho = sd.steady(g, o, sp)
    np.testing.assert_allclose(_geometry.level_fluxes(g, rho, 1.5, 0.8 * 1.5), 1.2, rtol=1e-12)
    res = sd.transient(g, o, sp, 40.0, full_output=True)
    np.testing.assert_allclose(res["frames"][-1], rho, rtol=0, atol=1e-8 * rho.max())
    assert res["outflow"][-1] == pytest.approx(1.2, rel=1e-9)
    assert res["inflow"][-1] == pytest.approx(1.2, rel=1e-13)


def test_b_par_converges_to_d_par_free_marching():
    """b_par -> 0: the FV steady solve tends to the marching (both O(h^2))."""
    g = cylinder(3, 6, 0.125)
    o = Orifice(x=0.0, width=2.0)
    march = sd.steady(g, o, Spots(b=0.9))
    fv = sd.steady(g, o, Spots(b=0.9, b_par=1e-9))
    Z, _ = g.mesh()
    sel = np.broadcast_to(Z >= 2, fv.shape)
    assert np.abs(fv - march)[sel].max() < 5e-3 * march.max()


def test_transient_mass_is_the_injected_spots():
    """Before spots reach the top, sum(rho * 2 pi r h^2) = Q0 t: BDF2 keeps the mass exactly."""
    g = cylinder(3, 30, 0.25)
    Q0, dt = 0.7, 0.05
    times = dt * np.array([10, 40, 100])
    res = sd.transient(g, Orifice(x=0.0, width=1.0, rate=Q0), Spots(drift=1.0, b=0.9, b_par=0.5),
                       5.0, times=times, dt=dt, full_output=True)
    mass = (res["frames"] * g.cell_volumes).sum(axis=(1, 2))
    np.testing.assert_allclose(mass, Q0 * times, rtol=1e-10)


# -- Kinematic Model -------------------------------------------------------------------------------
def test_kinematic_unit_flux_and_velocity_second_order():
    b, errs = 0.8, []
    for h in (0.25, 0.125, 0.0625):
        g = cylinder(6, 6, h, "open")
        u = kinematic.velocity(g, Orifice(x=0.0), b)
        assert set(u) == {"u_r", "u_z"}
        Z, R = g.mesh()
        v = kinematic.point_source(R, Z, b, dims=3)
        ur = -R * v / (2 * Z)                      # b dv/dr of the closed form
        sel = np.broadcast_to(Z >= 3, v.shape)
        errs.append(np.abs(u["u_r"] - ur)[sel].max() / np.abs(ur[sel]).max())
        assert np.all(u["u_r"] <= 0)               # toward the axis
    # measured 7.7e-3, 2.0e-3, 5.0e-4
    assert np.all(orders(errs) > 1.9), errs
    g = cylinder(2, 5, 0.25)
    v = kinematic.speed(g, Orifice(x=0.0, width=1.0), 1.1)
    np.testing.assert_allclose(2 * np.pi * (v * g.r).sum(axis=1) * g.spacing, 1.0, rtol=0, atol=1e-13)


def test_streamlines_follow_the_similarity_paths():
    """Point orifice: psi = 2 pi int_0^r v r' dr' = 1 - exp(-r^2/4bz) is constant on a path."""
    b = 0.8
    g = cylinder(6, 6, 0.125, "open")
    u = kinematic.velocity(g, Orifice(x=0.0), b)
    for P in kinematic.streamlines(u, g, [[1.0, 5.0], [2.0, 5.5]]):
        c = P[:, 0] / np.sqrt(P[:, 1].clip(1e-300))
        up = P[:, 1] > 2.0
        assert np.ptp(c[up]) < 3e-3 * c[0]
        assert P[-1, 1] == pytest.approx(0.0, abs=1e-12)
