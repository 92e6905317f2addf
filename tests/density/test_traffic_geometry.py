"""Interacting spots (``spots.rho_max``) in cylinders, wedge hoppers and cone hoppers
(docs/interacting_spots.md, "Cylinders and hoppers"): the conservation law on the
geometry's ring volumes, face areas and staircase."""

import numpy as np
import pytest

from spotpde.app.cases import load_case
from spotpde.density import spot_density as sd
from spotpde.density import traffic
from spotpde.grid import Grid, Hopper
from spotpde.parameters import Orifice, Spots

W = 2.0          # orifice width (the cone's: diameter)


def shape(kind, h, a=3.0, H=6.0):
    """A cylinder of radius ``a``, a wedge hopper ``2a`` wide or a cone in radius ``a``."""
    if kind == "cylinder":
        return Grid(2, (0, a), (0, H), h, "reflecting", coordinates="axisymmetric")
    if kind == "cone":
        return Grid(2, (0, a), (0, H), h, "reflecting", coordinates="axisymmetric",
                    hopper=Hopper(30.0, 0.0, W / 2))
    return Grid(2, (-a, a), (0, H), h, "reflecting", hopper=Hopper(30.0, 0.0, W / 2))


def volumes(g):
    return np.broadcast_to(g.cell_volumes, g.shape)


def rel_l1(a, b, g):
    return float(np.sum(np.abs(a - b) * volumes(g)) / np.sum(np.abs(b) * volumes(g)))


# -- conservation --------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["cylinder", "wedge", "cone"])
def test_spot_number_changes_only_by_inflow_minus_outflow(kind):
    """Congested runs (a random start up to rho_max; the orifice asks for more than it
    can take; with and without a capacity drop above z = 3): spots in the silo, counted
    here from the frames and the ring or cell volumes, change by the injected minus the
    outflow total to round-off; inactive cells hold no spots; with uniform
    coefficients 0 <= rho <= rho_max (a varying drift varies D, and the Ito form may
    then pile spots up, as in a box)."""
    g = shape(kind, 0.25)
    rng = np.random.default_rng(3)
    rho_max = 0.4
    rho0 = rho_max * rng.random(g.shape)
    drop = np.where(g.z[:, None] < 3.0, 1.0, 0.4) * np.ones(g.shape)
    o = Orifice(x=0.0, width=W, rate=3.0)
    times = np.linspace(0.0, 6.0, 7)
    active = np.asarray(g.active)
    for drift, flux, scaling in ((drop, "greenshields", "fixed"), (1.0, "triangular", "speed"),
                                 (1.0, "greenshields", "fixed")):
        s = Spots(drift=drift, b=0.6, b_par=0.3, rho_max=rho_max, mode="transient", t_end=6.0,
                  flux=flux, diffusion_scaling=scaling)
        res = traffic.transient(g, o, s, 6.0, times, rho0=rho0, full_output=True)
        frames = res["frames"]
        mass = (frames * volumes(g)).sum(axis=(1, 2))
        assert mass[0] == pytest.approx((np.where(active, rho0, 0.0) * volumes(g)).sum(),
                                        rel=1e-15)
        budget = mass - mass[0] - (res["injected_total"] - res["outflow_total"])
        assert np.abs(budget).max() < 1e-13 * mass.max()
        assert res["requested_total"][-1] > 1.5 * res["injected_total"][-1]   # capped
        assert frames.min() >= 0.0 and np.all(frames[:, ~active] == 0.0)
        if drift is not drop:
            assert frames.max() <= rho_max * (1 + 1e-12)


@pytest.mark.parametrize("hopper", [None, Hopper(30.0, 0.0, W / 2)])
def test_open_cylinder_wall_pads_outward_only(hopper):
    """An open wall: the window of a wider reflecting silo (padded from r = a outward,
    never across the axis), equal to that silo's solve cropped."""
    h, a = 0.25, 3.0
    s = Spots(b=0.6, b_par=0.3, rho_max=0.4, mode="transient", t_end=4.0)
    o = Orifice(x=0.0, width=W, rate=0.3)
    g = Grid(2, (0, a), (0, 6.0), h, "open", coordinates="axisymmetric", hopper=hopper)
    p = int(np.ceil(6.0 * np.sqrt(0.6 * 6.0) / h))
    wide = Grid(2, (0, a + p * h), (0, 6.0), h, "reflecting", coordinates="axisymmetric",
                hopper=hopper)
    rho = traffic.transient(g, o, s, 4.0)
    ref = traffic.transient(wide, o, s, 4.0)[:, :g.nx]
    np.testing.assert_allclose(rho, ref, rtol=0, atol=1e-15 * ref.max())
    assert rho[:, -1].max() > 1e-3 * rho.max()          # spots do reach the open wall


def test_the_metric_solver_on_a_plain_box_is_the_box_solver():
    """Nothing in the metric path is special to rings or hoppers: given a box it
    reproduces the box solver (its numba kernels) to round-off."""
    from spotpde.density import _traffic, _traffic_metric
    from spotpde.density.orifice import source_profile

    g = Grid(2, (-3, 3), (0, 6), 0.25, "reflecting")
    o = Orifice(x=0.0, width=W, rate=3.0)
    s = Spots(b=0.6, b_par=0.3, rho_max=0.4, diffusion_scaling="speed")
    rho0 = 0.4 * np.random.default_rng(5).random(g.shape)
    profile = source_profile(g, o)
    solver = _traffic_metric.MetricSolver(g, 1.0, 0.6, 0.3, 0.4, _traffic.FLUXES["greenshields"],
                                          "speed", "mc", lambda t: 3.0 * profile)
    res = _traffic.integrate(solver, 4.0, np.array([4.0]), lambda t: 3.0, rho0=rho0)
    box = traffic.transient(g, o, s, 4.0, rho0=rho0)
    np.testing.assert_allclose(res["frames"][-1], box, rtol=0, atol=1e-13)


@pytest.mark.parametrize("kind", ["cylinder", "wedge", "cone"])
def test_an_overfull_orifice_injects_the_capacity_of_its_area(kind):
    """Asked for 3 q_max A (A: the disk pi (W/2)**2 or the slot W), an empty silo takes
    exactly q_max A: the bottom cells stay at or below rho_c, whose supply is q_max per
    unit area; the refused 2 q_max A t is reported."""
    g = shape(kind, 0.25)
    area = np.pi * (W / 2) ** 2 if g.geometry.curved else W
    rho_max = 0.4
    q_max = rho_max / 4
    times = np.linspace(0.0, 4.0, 5)
    res = traffic.transient(g, Orifice(x=0.0, width=W, rate=3 * q_max * area),
                            Spots(b=0.6, b_par=0.0, rho_max=rho_max), 4.0, times,
                            full_output=True)
    np.testing.assert_allclose(res["injected"], q_max * area, rtol=1e-12)
    refused = res["requested_total"] - res["injected_total"]
    np.testing.assert_allclose(refused, 2 * q_max * area * times, rtol=1e-12, atol=1e-12)


# -- the dilute limit ----------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["cylinder", "wedge", "cone"])
def test_dilute_limit_converges_to_the_independent_spot_solver(kind):
    """rho << rho_max: the nonlinear solver and the linear BDF2 solver of the same
    geometry differ by the two schemes' errors, which shrink at second order."""
    diff = []
    for h in (0.5, 0.25):
        g = shape(kind, h, a=4.0, H=12.0)
        o = Orifice(x=0.0, width=W, rate=0.5)
        dilute = traffic.transient(g, o, Spots(b=1.3, b_par=0.5, rho_max=1e6), 8.0)
        assert dilute.max() < 1e-6 * 1e6
        linear = sd.transient(g, o, Spots(b=1.3, b_par=0.5), 8.0, dt=h / 8)
        diff.append(rel_l1(dilute, linear, g))
    assert diff[1] < 3e-3
    assert np.log2(diff[0] / diff[1]) > 1.6


# -- the closed form: a radially uniform Riemann problem ------------------------------------
def channel(kind, h, a):
    """A cylinder of radius ``a``, or a vertical cone / wedge channel of half-width ``a``
    cut by the staircase out of a silo twice as wide; and the floor area it feeds."""
    if kind == "cylinder":
        return Grid(2, (0, a), (0, 12.0), h, "reflecting", coordinates="axisymmetric"), np.pi * a * a
    if kind == "vertical cone":
        return Grid(2, (0, 2 * a), (0, 12.0), h, "reflecting", coordinates="axisymmetric",
                    hopper=Hopper(0.0, 0.0, a)), np.pi * a * a
    return Grid(2, (-2 * a, 2 * a), (0, 12.0), h, "reflecting",
                hopper=Hopper(0.0, 0.0, a)), 2 * a


@pytest.mark.parametrize("kind", ["cylinder", "vertical cone", "vertical wedge"])
@pytest.mark.parametrize("rho_L, rho_R", [(0.1, 0.3), (0.4, 0.1), (0.8, 0.2)])
def test_whole_floor_orifice_is_the_riemann_problem(kind, rho_L, rho_R):
    """Uniform orifice over the whole floor of a cylinder (or of a vertical channel cut
    by the staircase's closed walls), a horizontally uniform step at z0, no vertical
    diffusion: every active column is the 1D entropy solution (a shock, a fan, a
    transonic fan), uniform across to round-off, equal to the box solver's column,
    converging at first order in L1; the shock sits where conservation puts it."""
    a, H, z0, t = 0.8, 12.0, 4.0, 6.0
    q_L = rho_L * (1.0 - rho_L)                 # rho_max = 1, v_s = 1
    s = Spots(b=1e-3, b_par=0.0, rho_max=1.0, mode="transient", t_end=t)
    errors = []
    for h in (0.2, 0.1, 0.05):
        g, area = channel(kind, h, a)
        act = np.asarray(g.active)
        rho0 = np.where(g.z[:, None] < z0, rho_L, rho_R) * np.ones(g.shape)
        rho = traffic.transient(g, Orifice(x=0.0, width=2 * a, rate=q_L * area), s, t,
                                rho0=rho0)
        col = rho[:, act[0]]
        assert act[0].sum() == round(a / h) * (1 if g.geometry.curved else 2)
        assert np.abs(col - col[:, :1]).max() < 1e-12 and np.all(rho[~act] == 0)
        box = Grid(2, (-a, a), (0, H), h, "reflecting")
        rb = traffic.transient(box, Orifice(x=0.0, width=2 * a, rate=q_L * 2 * a), s, t,
                               rho0=np.where(box.z[:, None] < z0, rho_L, rho_R)
                               * np.ones(box.shape))
        np.testing.assert_allclose(col[:, 0], rb[:, 0], rtol=0, atol=1e-12)
        exact = traffic.riemann(rho_L, rho_R, g.z - z0, t)
        errors.append(float(np.sum(np.abs(col[:, 0] - exact)) * h))
        if rho_L < rho_R:                       # shock: position from the column's spots
            zs = (rho_R * H - col[:, 0].sum() * h) / (rho_R - rho_L)
            assert zs == pytest.approx(z0 + (1.0 - rho_L - rho_R) * t, abs=1e-12 * H)
        if rho_L > 0.5 > rho_R:                 # transonic: rho_c at the jump
            k = int(round(z0 / h))
            assert 0.5 * (col[k - 1, 0] + col[k, 0]) == pytest.approx(0.5, abs=1e-12)
    orders = np.log2(np.array(errors[:-1]) / errors[1:])
    assert np.all(orders > 0.9), orders
    assert errors[-1] < 0.02


# -- convergence and the axis ----------------------------------------------------------------
def _coarsen(g, rho):
    """Volume-weighted mean of each 2 x 2 block of cells (the coarse grid's cells)."""
    nz, nx = g.shape
    vol = volumes(g) * np.ones(g.shape)
    block = lambda a: a.reshape(nz // 2, 2, nx // 2, 2).sum(axis=(1, 3))
    return block(rho * vol) / block(vol)


@pytest.fixture(scope="module")
def cylinder_runs():
    """A smooth nonlinear run (Gaussian orifice on the axis, peak rho ~ rho_max / 4) on
    three grids."""
    out = {}
    for h in (0.25, 0.125, 0.0625):
        g = shape("cylinder", h)
        o = Orifice(x=0.0, width=W, rate=0.12, profile="gaussian")
        s = Spots(b=1.3, b_par=0.5, rho_max=0.1, mode="transient", t_end=4.0)
        out[h] = (g, traffic.transient(g, o, s, 4.0))
    return out


def test_second_order_under_refinement_in_a_cylinder(cylinder_runs):
    (g1, r1), (g2, r2), (g3, r3) = (cylinder_runs[h] for h in (0.25, 0.125, 0.0625))
    assert r3.max() > 0.1 * 0.1             # the flux is far from linear there
    e1 = rel_l1(_coarsen(g2, r2), r1, g1)
    e2 = rel_l1(_coarsen(g3, r3), r2, g2)
    assert np.log2(e1 / e2) > 1.8, (e1, e2)


def test_regular_at_the_axis(cylinder_runs):
    """Even in r near the axis: rho = a + c r**2 gives (rho_1 - rho_0) / (rho_2 - rho_1)
    = (r_1**2 - r_0**2) / (r_2**2 - r_1**2) = 1/2, approached at O(h**2); no flux through
    r = 0 and no kink there."""
    dev = []
    for h in (0.25, 0.125, 0.0625):
        g, r = cylinder_runs[h]
        k = int(np.argmin(np.abs(g.z - 2.0)))
        dev.append(abs((r[k, 1] - r[k, 0]) / (r[k, 2] - r[k, 1]) - 0.5))
    assert dev[-1] < 5e-3
    assert np.log2(dev[0] / dev[1]) > 1.5 and np.log2(dev[1] / dev[2]) > 1.5


# -- cases and outputs ----------------------------------------------------------------------
CONE_CASE = """
[domain]
dims = 2
coordinates = "axisymmetric"
x = [0.0, 4.0]
z = [0.0, 8.0]
spacing = 0.5
hopper_angle = 30.0
[orifice]
x = 0.0
width = 2.0
rate = 0.2
[spots]
mode = "transient"
t_end = 4.0
rho_max = 0.1
frames = 3
[kernel]
shape = "uniform"
size = 1.0
height = 0.01
[tracer]
layers = { spacing = 2.0 }
t_end = 4.0
frames = 3
[output]
path = "cone.nc"
"""


def test_a_cone_case_with_rho_max_runs_end_to_end(tmp_path, monkeypatch):
    """Was refused at validation (spots.rho_max: "interacting spots are solved in
    Cartesian coordinates only"); now the CLI runs it, tracer included, and the result
    carries the interacting-spot outputs with a round-off budget."""
    import xarray as xr

    from spotpde import cli

    (tmp_path / "cone.toml").write_text(CONE_CASE)
    monkeypatch.chdir(tmp_path)
    assert cli.main(["run", "cone.toml", "-q"]) == 0
    with xr.open_dataset(tmp_path / "cone.nc") as ds:
        assert {"rho_s_t", "free_volume_t", "spot_mass"} <= set(ds.data_vars)
        assert abs(ds.attrs["mass_budget_error"]) < 1e-13 * float(ds["spot_mass"].max())
        assert ds.attrs["injected_total"] > 0
        # the space-time diagram runs along the axis (was a KeyError: no "x" in the result)
        st = traffic.space_time(ds, "rho_s_t")
        assert st.dims == ("t_s", "z")
        np.testing.assert_array_equal(st.values, ds["rho_s_t"].values[:, :, 0])
        assert traffic.space_time(ds, "rho_s_t", z=3.0).dims == ("t_s", "r")


def test_a_cylinder_case_with_rho_max_is_valid_and_runs(tmp_path):
    """Was refused ("interacting spots are solved in Cartesian coordinates only")."""
    case = load_case({
        "domain": {"coordinates": "axisymmetric", "x": [0.0, 3.0], "z": [0.0, 6.0],
                   "spacing": 0.5},
        "orifice": {"x": 0.0, "width": 2.0, "rate": 0.2},
        "spots": {"mode": "transient", "t_end": 2.0, "rho_max": 0.1, "frames": 3},
        "kernel": {"shape": "uniform", "size": 1.0, "height": 0.01},
        "output": {"path": str(tmp_path / "out.nc")},
    })
    result = traffic.solve_case(case)
    fv = traffic.free_volume(case.grid, result.frames, case.kernel)
    # far from the floor, the top and the wall, w * rho -> V1 rho where rho varies slowly
    assert fv.shape == result.frames.shape and fv.min() >= -1e-12 * fv.max()
    uniform = np.full(case.grid.shape, 0.05)
    fu = traffic.free_volume(case.grid, uniform, case.kernel)
    assert fu[6, 0] == pytest.approx(case.kernel.V1 * 0.05, rel=1e-6)
