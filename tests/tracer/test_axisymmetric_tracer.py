"""The tracer on axisymmetric grids (docs/tracer.md, "Axisymmetric grids"; docs/steady.md).

The solver steps ``Q = 2 pi r P`` with the Cartesian kernels plus the metric exchange.
Checks: a 3D Cartesian run of the same problem, the closed forms of uniform drift and
of a linear converging flow (the radial second moment evolves exactly), the void
model's 3D Brownian bridge by the steady solve, mass conservation and positivity with
an open outer wall and a full tensor, and the steady solve as the limit of the
time-stepped one.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator

from spotpde import tracer
from spotpde.grid import Grid

from _grids import cylinder

RADIUS, TOP, D, ALPHA, W, Z0, S0, T_END = 10.0, 14.0, 0.2, 0.05, 0.5, 8.0, 2.0, 10.0


def _axi_grid(h, walls="reflecting", radius=RADIUS, z=(0.0, TOP)):
    return cylinder(radius, z[1], h, walls, bottom=z[0])


def _converging_axi(grid, alpha=ALPHA, d_rz=0.0):
    Z, R = grid.mesh()
    zero = 0.0 * R + 0.0 * Z
    return {"u_r": -alpha * R + zero, "u_z": -W + zero, "D_rr": D + zero,
            "D_rz": d_rz * R / (1.0 + R) + zero, "D_zz": D + zero}


def _blob_axi(grid, z0=Z0, s0=S0):
    Z, R = grid.mesh()
    P0 = np.exp(-(R**2 + (Z - z0) ** 2) / (2 * s0**2)) + 0 * R
    return P0 / (P0 * grid.cell_volumes).sum()


def _r2(grid, P):
    """Radial second moment ``<r**2>`` of a density (per unit volume)."""
    Z, R = grid.mesh()
    w = P * grid.cell_volumes
    return float((w * R**2).sum() / w.sum())


@pytest.mark.slow
def test_axisymmetric_equals_3d_cartesian_run():
    """Same fields (converging flow u_r = -alpha r, uniform fall, isotropic D), same blob
    on the axis, same spacing, box walls 5 widths away: mass(t), the horizontally
    integrated P_height, the radial moments of P_height and P itself agree."""
    h = 0.5
    ga = _axi_grid(h)
    ra = tracer.solve(ga, _converging_axi(ga), _blob_axi(ga), T_END, 6, diffusion="explicit")
    g3 = Grid(3, (-RADIUS, RADIUS), (0.0, TOP), h)
    Z, Y, X = g3.mesh()
    zero = 0.0 * X + 0.0 * Y + 0.0 * Z
    f3 = {"u_x": -ALPHA * X + zero, "u_y": -ALPHA * Y + zero, "u_z": -W + zero,
          "D_xx": D + zero, "D_yy": D + zero, "D_zz": D + zero, "D_xy": zero, "D_xz": zero,
          "D_yz": zero}
    P3 = np.exp(-(X**2 + Y**2 + (Z - Z0) ** 2) / (2 * S0**2)) + zero
    P3 /= P3.sum() * h**3
    r3 = tracer.solve(g3, f3, P3, T_END, 6, diffusion="explicit")
    # mass(t) and outflow(t): about 15 % drains through the floor
    assert ra.mass[-1] < 0.9
    assert np.abs(ra.mass - r3.mass).max() < 1e-6
    assert np.abs(ra.outflow - r3.outflow).max() < 1e-6
    # P_height integrated over each horizontal section (d**-2 times the annuli)
    cross_a = (ra.P_height * ga.horizontal_measures).sum(axis=1)
    cross_3 = r3.P_height.sum(axis=(1, 2)) * h * h
    assert np.abs(cross_a - cross_3).max() < 1e-5
    # its radial second moment, per height where it is not tiny; each scheme's cell
    # values carry the finite-volume offset of its own cells (h**2/12 per Cartesian axis
    # of the reconstruction: one in r, two in x and y), taken out before comparing
    Za, Ra = ga.mesh()
    keep = cross_a > 0.05
    m2a = (ra.P_height * ga.horizontal_measures * Ra**2).sum(axis=1)[keep] / cross_a[keep]
    m23 = (r3.P_height * (X**2 + Y**2)[0]).sum(axis=(1, 2))[keep] * h * h / cross_3[keep]
    assert np.abs((m2a - h * h / 12) / (m23 - h * h / 6) - 1).max() < 1e-3
    # P at the final time: the axisymmetric solution interpolated (cubic) at the 3D cell
    # centres inside the cylinder; relative L1 difference (both schemes are second order
    # here: 2.7e-3 at h = 0.25, docs/tracer.md)
    it = RegularGridInterpolator((ga.z, ga.r), ra.P[-1], method="cubic")
    rr = np.broadcast_to(np.sqrt(X**2 + Y**2), g3.shape)
    zz = np.broadcast_to(Z, g3.shape)
    inside = rr < RADIUS - h
    Pi = it(np.stack([zz[inside], rr[inside]], axis=1))
    l1 = np.abs(Pi - r3.P[-1][inside]).sum() / r3.P[-1].sum()
    assert l1 < 5e-3                       # measured 3.4e-3 (8.3e-4 at h = 0.25)


def test_uniform_drift_spreads_as_gaussian():
    """Uniform fall, isotropic D, a blob on the axis: the radial variance grows by 2 D t per
    horizontal component exactly (the metric exchange's second moment), and P follows
    the 3D Gaussian; mass + outflow = 1, P >= 0."""
    h = 0.25
    g = _axi_grid(h, radius=16.0, z=(0.0, 24.0))     # P at the wall below 1e-13 of the peak
    f = _converging_axi(g, alpha=0.0)
    s0, z0, t_end = 1.0, 17.0, 8.0
    P0 = _blob_axi(g, z0=z0, s0=s0)
    # closed floor (no outlet): the tail that reaches it (1e-9) would bias the moments
    res = tracer.solve(g, f, P0, t_end, 5, outlet=np.zeros(g.nx, dtype=bool),
                       diffusion="explicit")
    assert res.options["coordinates"] == "axisymmetric"
    assert res.outflow[-1] == 0.0
    r2_0 = _r2(g, res.P[0])
    for j, t in enumerate(res.times):
        assert abs(res.mass[j] + res.outflow[j] - 1.0) < 1e-10
        assert res.P[j].min() >= 0.0
        # variance per horizontal component: <r**2>/2
        assert (_r2(g, res.P[j]) - r2_0) / 2 == pytest.approx(2 * D * t, rel=1e-11, abs=1e-12)
    Z, R = g.mesh()
    s2 = s0**2 + 2 * D * t_end
    exact = np.exp(-(R**2 + (Z - z0 + W * t_end) ** 2) / (2 * s2)) / (2 * np.pi * s2) ** 1.5
    # second order in space: 4.6e-3 of the peak at h = 0.25, on the axis (where the
    # cell-centre samples of P0 differ most from cell averages)
    assert np.abs(res.P[-1] - exact).max() < 1e-2 * exact.max()
    # P_height per unit area integrates to what crossed each height
    crossed = (res.P_height_faces * g.horizontal_measures).sum(axis=1)
    k = int(round((z0 - W * t_end) / h))              # face at the blob's final centre
    assert crossed[k] == pytest.approx(0.5, abs=0.02)


def test_linear_converging_flow_second_moment_closed_form():
    """u_r = -alpha r with isotropic D: the Ornstein-Uhlenbeck closed form
    ``m(t) = m(0) e^{-2 alpha t} + (2D / alpha)(1 - e^{-2 alpha t})`` for
    ``m = <r**2> - h**2/12`` (the cell offset of the reconstruction of Q); the residual
    error, from the nonlinear WENO weights and the reconstruction near the axis (measured
    1.7e-4 at h = 0.5, 3.6e-6 at h = 0.25), falls at least tenfold when h is halved."""
    errors = []
    for h in (0.5, 0.25):
        g = _axi_grid(h, z=(0.0, 20.0))
        res = tracer.solve(g, _converging_axi(g), _blob_axi(g, z0=12.0, s0=1.5), 8.0, 5,
                           outlet=np.zeros(g.nx, dtype=bool))
        assert res.outflow[-1] == 0.0
        m0 = _r2(g, res.P[0]) - h * h / 12
        err = 0.0
        for j, t in enumerate(res.times):
            e = math.exp(-2 * ALPHA * t)
            exact = m0 * e + 2 * D / ALPHA * (1 - e)
            err = max(err, abs((_r2(g, res.P[j]) - h * h / 12) / exact - 1))
        errors.append(err)
    assert errors[0] < 3e-4
    assert errors[1] < 0.1 * errors[0]


B, Z0_VOID, SIGMA_VOID = 1.3, 20.0, 0.75


def test_void_model_3d_brownian_bridge_steady():
    """Steady solve of the void propagator from a release on the axis over a point orifice
    (3D void density, b_par = 0): P_height at height z is a 2D Gaussian with variance
    ``2 b z (z0 - z)/z0`` per component (averaged over the released blob); the exits sum
    to 1 and G >= 0. Floor at z = 3, as the Cartesian test (tests/tracer/test_steady.py)."""
    h = 0.5
    g = _axi_grid(h, walls="open", radius=16.0, z=(3.0, 23.0))
    Z, R = g.mesh()
    rho = np.exp(-R**2 / (4 * B * Z)) / (4 * np.pi * B * Z)
    # void fields (docs/void_model.md, lam = 1, V1 = v_s = 1): u = 2 b grad_h rho - rho e_z
    f = {"u_r": -rho * R / Z, "u_z": -rho + 0 * R, "D_rr": B * rho, "D_rz": 0 * rho,
         "D_zz": 0 * rho}
    P0 = _blob_axi(g, z0=Z0_VOID, s0=SIGMA_VOID)
    st = tracer.solve_steady(g, f, P0)
    assert sum(st.exit.values()) == pytest.approx(1.0, abs=1e-10)
    assert st.exit["floor"] == pytest.approx(1.0, abs=1e-6)
    assert st.residence.min() >= 0.0
    w = P0 * g.cell_volumes
    for z_target in (6.0, 10.0, 12.5, 15.0):
        k = int(np.argmin(np.abs(g.z - z_target)))
        z = g.z[k]
        ph = st.P_height[k] * g.horizontal_measures
        crossed = ph.sum()
        assert crossed == pytest.approx(1.0, abs=1e-3)
        assert (ph * g.r).sum() / crossed > 0     # a distribution over the annuli
        var = 0.5 * (ph * g.r**2).sum() / crossed  # per horizontal component
        above = np.where(Z > z, w, 0.0)
        v = 2 * B * z * (Z - z) / Z
        expected = 0.5 * (above * (2 * v + (R * z / Z) ** 2)).sum() / above.sum()
        assert abs(var / expected - 1) < 0.02     # measured within 0.9 %


def test_steady_equals_drained_time_stepped_with_open_wall_and_full_tensor():
    """A draining converging flow with a radial outflow part, an open outer wall and a
    cross diffusivity D_rz: with the same (upwind) face values the drained time-stepped
    P_height, the exit probabilities and the mean exit time equal the steady solve's;
    mass + outflow = 1 to 1e-10 and P >= 0 throughout."""
    h = 0.5
    g = _axi_grid(h, walls="open", radius=4.0, z=(0.0, 10.0))
    f = _converging_axi(g, alpha=-0.1, d_rz=0.05)      # u_r = +0.1 r: outward
    P0 = _blob_axi(g, z0=6.0, s0=0.8)
    ts = tracer.solve(g, f, P0, 80.0, 801, limiter="upwind")
    assert ts.mass[-1] < 1e-10
    assert ts.mass_error < 1e-10
    assert np.all(ts.P >= 0)
    assert ts.outflow_by_boundary["sides"] > 0.05 and ts.outflow_by_boundary["floor"] > 0.05
    st = tracer.solve_steady(g, f, P0, scheme="upwind")
    assert sum(st.exit.values()) == pytest.approx(1.0, abs=1e-10)
    scale = np.abs(st.P_height).max()
    assert np.abs(ts.P_height - st.P_height).max() < 1e-8 * scale
    for key in ("floor", "sides", "top"):
        assert ts.outflow_by_boundary[key] == pytest.approx(st.exit[key], abs=1e-10)
    mean_ts = float(np.sum(0.5 * (ts.mass[1:] + ts.mass[:-1]) * np.diff(ts.times)))
    assert st.mean_exit_time == pytest.approx(mean_ts, rel=1e-4)


def test_axisymmetric_field_names_are_checked():
    g = _axi_grid(0.5, radius=2.0, z=(0.0, 2.0))
    f = _converging_axi(g)
    P0 = _blob_axi(g, z0=1.0, s0=0.5)
    bad = {k: v for k, v in f.items() if k != "u_r"}
    bad["u_x"] = f["u_r"]
    with pytest.raises(ValueError, match="fields: missing u_r"):
        tracer.solve(g, bad, P0, 1.0, 2)
    with pytest.raises(ValueError, match="fields: missing u_r"):
        tracer.solve_steady(g, bad, P0)
    neg = dict(f, D_rr=-1.0)
    with pytest.raises(ValueError, match="fields.D_rr"):
        tracer.solve(g, neg, P0, 1.0, 2)


def test_metric_keeps_the_cartesian_step_and_callable_fields_match():
    """The metric exchange leaves each cell's loss rate at the Cartesian 2 (D_rr + D_zz)/h**2
    (so the positivity step is unchanged; max dt a <= 1 in the run); time-dependent
    (callable) fields and ``on_frame`` give the same physical frames as steady fields."""
    from spotpde.tracer import _geometry
    h = 0.5
    g = _axi_grid(h, radius=4.0, z=(0.0, 8.0))
    f = _converging_axi(g)
    op = _geometry.operator(g, f, 6, np.ones(g.nx, dtype=bool), implicit=False)
    assert op.rate_diff == pytest.approx(2 * (D + D) / h**2, rel=1e-12)
    P0 = _blob_axi(g, z0=5.0, s0=0.8)
    a = tracer.solve(g, f, P0, 4.0, 5, diffusion="explicit")
    assert a.max_cfl <= 1.0
    frames = {}
    b = tracer.solve(g, lambda t: f, P0, 4.0, 5, diffusion="explicit",
                     on_frame=lambda j, t, P: frames.__setitem__(j, P.copy()))
    assert b.P is None and sorted(frames) == list(range(5))
    for j in range(5):
        np.testing.assert_allclose(frames[j], a.P[j], rtol=1e-12, atol=1e-14 * a.P[0].max())
    np.testing.assert_allclose(b.P_height, a.P_height, rtol=1e-12, atol=1e-14)
    with pytest.raises(ValueError, match=r"fields\(t=0\): missing u_r"):
        tracer.solve(g, lambda t: {"u_z": 0.0}, P0, 1.0, 2)


def test_equilibrium_P_times_D_uniform_is_steady_up_to_the_axis():
    """No drift, isotropic D(r, z) (D_tt = D_rr): the Ito equation's equilibrium
    ``P = c / D`` is a discrete steady state, axis cells included (the metric exchange is
    ``2 pi r_f (D_a P_a - D_b P_b) / h**2``); the drift D/r upwinded by the Cartesian
    kernel would not keep it (the axis cell 18 % too high, docs/tracer.md)."""
    g = _axi_grid(0.5, radius=5.0, z=(0.0, 6.0))
    Z, R = g.mesh()
    Dv = 0.2 + 0.1 * np.sin(R) * np.cos(Z) + 0 * R
    f = {"u_r": 0.0, "u_z": 0.0, "D_rr": Dv, "D_rz": 0.0, "D_zz": Dv}
    P0 = 1.0 / Dv
    P0 /= (P0 * g.cell_volumes).sum()
    for mode in ("explicit", "implicit"):
        res = tracer.solve(g, f, P0, 20.0, 3, diffusion=mode)
        assert np.abs(res.P[-1] / P0 - 1).max() < 1e-12
