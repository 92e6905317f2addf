"""Interacting spots (spots.rho_max): Riemann problems, Cole-Hopf solutions, limits,
budgets, noise and bad input (spotpde.traffic, spotpde.density._traffic, spotpde.noise)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from spotpde.density import _traffic as T
from spotpde.density import noise, spot_density, traffic
from spotpde.grid import Grid
from spotpde.parameters import Orifice, Spots

ROOT = Path(__file__).resolve().parents[2]
GS = T.FLUXES["greenshields"]
ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(
    [str(ROOT)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])}


def q(rho, v=1.0, rho_max=1.0):
    return v * rho * (1.0 - rho / rho_max)


def column(rho0, t_end, h, D=0.0, floor_flux=0.0, rho_max=1.0, limiter="mc",
           scaling="fixed", flux=GS, times=None):
    """1D column (one cell wide): the solver on shape (nz, 1), v_s = 1."""
    nz = rho0.size
    solver = T.Solver((nz, 1), h, 1.0, 0.0, D, rho_max, flux, scaling, limiter,
                      lambda t: np.full(1, floor_flux))
    times = np.array([t_end]) if times is None else np.asarray(times, float)
    res = T.integrate(solver, t_end, times, lambda t: floor_flux * h, rho0=rho0.reshape(nz, 1))
    res["rho"] = res["frames"][:, :, 0]
    return res


def cells(lo, hi, h):
    return lo + (np.arange(int(round((hi - lo) / h))) + 0.5) * h


# -- Riemann problems -----------------------------------------------------------------------
@pytest.mark.parametrize("rho_L, rho_R", [(0.2, 0.6), (0.1, 0.3), (0.6, 0.9)])
def test_shock_speed(rho_L, rho_R):
    """Density rising upward: one shock at s = v_s (1 - (rho_L + rho_R)/rho_max)."""
    h, t = 0.025, 8.0
    z = cells(-20.0, 20.0, h)
    rho = column(np.where(z < 0, rho_L, rho_R), t, h, floor_flux=q(rho_L))["rho"][-1]
    s = 1.0 - (rho_L + rho_R)
    # position from conservation over a window the boundaries have not reached
    win = np.abs(z - s * t) < 6.0
    a, b = z[win][0] - h / 2, z[win][-1] + h / 2
    pos = b - (np.sum(rho[win]) * h - rho_L * (b - a)) / (rho_R - rho_L)
    assert abs(pos - s * t) < 1e-6
    # sharp: the transition spans a few cells; plateaus exact
    mid = np.abs(rho - 0.5 * (rho_L + rho_R)) < 0.45 * (rho_R - rho_L)
    assert np.count_nonzero(mid & win) <= 4
    far = win & (np.abs(z - s * t) > 10 * h)
    np.testing.assert_allclose(rho[far], traffic.riemann(rho_L, rho_R, z[far], t), atol=1e-9)


def test_fan_converges_to_closed_form():
    """rho_max below, 0 above: rho = (rho_max/2)(1 - z/(v_s t)), L1 error O(h)."""
    t = 5.0
    errors = []
    for h in (0.1, 0.05, 0.025):
        z = cells(-10.0, 10.0, h)
        rho = column(np.where(z < 0, 1.0, 0.0), t, h)["rho"][-1]
        errors.append(np.sum(np.abs(rho - 0.5 * np.clip(1 - z / t, 0, 2))) * h)
    assert errors[-1] < 3e-3
    order = np.log2(np.array(errors[:-1]) / errors[1:])
    assert np.all(order > 0.9), errors
    # interior of the fan, away from the corners: second order in max norm
    inner = np.abs(z) < 0.6 * t
    fan = 0.5 * (1 - z / t)
    assert np.max(np.abs(rho - fan)[inner]) < 2e-3


def test_transonic_rarefaction_entropy_fix():
    """rho_L = 0.8 below, rho_R = 0.2 above (rho_max = 1): the fan crosses rho_c, and the
    density at the initial jump is exactly 1/2 (q' = 0 there) for all t > 0."""
    h = 0.05
    z = cells(-10.0, 10.0, h)
    res = column(np.where(z < 0, 0.8, 0.2), 5.0, h, floor_flux=q(0.8), times=[1.0, 3.0, 5.0])
    for rho in res["rho"]:
        at_jump = 0.5 * (rho[z.size // 2 - 1] + rho[z.size // 2])
        assert abs(at_jump - 0.5) < 1e-12
    ex = traffic.riemann(0.8, 0.2, z, 5.0)
    win = np.abs(z) < 8
    assert np.sum(np.abs(res["rho"][-1] - ex)[win]) * h < 5e-3


def test_oleinik_bound():
    """c(rho) is one-sided Lipschitz: c(z + a) - c(z) <= a / t for random initial data
    (a = 1 d, ten cells or more; the excess over 1 is O(h) and shrinks with h)."""
    rng = np.random.default_rng(2)
    blocks = rng.uniform(0, 1, 40)
    excess = []
    for h in (0.05, 0.025):
        z = cells(0.0, 40.0, h)
        res = column(blocks[(z // 1).astype(int)], 4.0, h, times=[1.0, 2.0, 4.0])
        k = int(round(1.0 / h))
        worst = max(np.max((1 - 2 * r)[k:] - (1 - 2 * r)[:-k]) * t / 1.0
                    for r, t in zip(res["rho"], (1.0, 2.0, 4.0)))
        excess.append(worst - 1.0)
    assert excess[1] < 0.03
    assert excess[1] < excess[0]


# -- viscous (Cole-Hopf) solutions ----------------------------------------------------------
def test_viscous_shock_second_order():
    """Travelling tanh shock of width 2 D rho_max / (v_s Delta rho): the numerical
    solution converges to it at second order (smooth problem)."""
    D, t = 0.5, 10.0
    errs = []
    for h in (0.4, 0.2, 0.1):
        z = cells(-30.0, 30.0, h)
        rho = column(traffic.viscous_shock(z, 0.0, 0.1, 0.4, D), t, h, D=D,
                     floor_flux=q(0.1))["rho"][-1]
        errs.append(np.max(np.abs(rho - traffic.viscous_shock(z, t, 0.1, 0.4, D))))
    order = np.log2(np.array(errs[:-1]) / errs[1:])
    assert np.all(order > 1.8), (errs, order)
    assert errs[-1] < 2e-5


def test_n_wave_decays_as_inverse_sqrt_t():
    """Cole-Hopf N-wave on rho0 = rho_c (c0 = 0): the solver follows the exact solution
    and the amplitude falls by (t2/t1)**-1/2 up to the exact log factor."""
    h, D, A, rho0 = 0.05, 0.05, np.exp(30.0), 0.5
    z = cells(-30.0, 30.0, h)
    t1 = 10.0
    res = column(traffic.n_wave(z, t1, rho0, A, D), 30.0, h, D=D, floor_flux=q(rho0),
                 times=[10.0, 30.0])
    amp0 = np.max(np.abs(traffic.n_wave(z, t1, rho0, A, D) - rho0))
    for rho, dt in zip(res["rho"], (10.0, 30.0)):
        t2 = t1 + dt
        exact = traffic.n_wave(z, t2, rho0, A, D)
        assert np.sum(np.abs(rho - exact)) * h < 1e-3
        ratio = np.max(np.abs(rho - rho0)) / amp0
        log_factor = np.sqrt(np.log(A / np.sqrt(t2)) / np.log(A / np.sqrt(t1)))
        assert ratio == pytest.approx((t2 / t1) ** -0.5 * log_factor, rel=0.01)


@pytest.mark.parametrize("rho0", [0.25, 0.75])
def test_small_bump_moves_at_c(rho0):
    """A small bump on rho0 travels at c(rho0) = v_s (1 - 2 rho0 / rho_max), upward
    below rho_c, downward above; the centroid drifts by the exact -(v_s/rho_max)
    int d**2 / int d correction, of relative size eps."""
    h, eps, t = 0.05, 1e-3, 10.0
    z = cells(-30.0, 30.0, h)
    bump = eps * np.exp(-0.5 * (z / 2.0) ** 2)
    rho = column(rho0 + bump, t, h, D=0.05, floor_flux=q(rho0))["rho"][-1]
    # window of 15 d around the bump: above rho_c the free exit at the top opens a fan
    # whose edge runs down to about z = 30 - 0.5 t = 25; the floor is quiet (q(rho0))
    c0 = float(GS.c(rho0, 1.0, 1.0))     # the library's c(rho), against the measured speed
    win = np.abs(z - c0 * t) < 15
    d = (rho - rho0)[win]
    speed = np.sum(z[win] * d) / np.sum(d) / t
    assert abs(speed - c0) < 2 * eps
    assert np.sum(d) * h == pytest.approx(np.sum(bump) * h, rel=1e-9)


# -- limits, budgets, bounds ---------------------------------------------------------------
def test_independent_limit_matches_linear_transient_solver():
    """rho_max -> infinity is today's linear transient solver (BDF2): the two schemes
    differ by their discretisation errors, which fall at second order."""
    diffs = []
    for h in (0.5, 0.25):
        g = Grid(2, (-10.0, 10.0), (0.0, 20.0), h, "reflecting")
        o = Orifice(x=0.0, width=4.0, rate=1.0)
        s = Spots(drift=1.0, b=1.3, b_par=0.5, mode="transient", t_end=10.0)
        lin = spot_density.transient(g, o, s, 10.0, dt=h / 10)
        big = traffic.transient(g, o, Spots(drift=1.0, b=1.3, b_par=0.5, rho_max=1e12), 10.0)
        none = traffic.transient(g, o, s, 10.0)
        np.testing.assert_allclose(big, none, rtol=1e-9, atol=1e-14)
        diffs.append(np.abs(none - lin).sum() / np.abs(lin).sum())
    assert diffs[1] < 2e-3
    assert diffs[0] / diffs[1] > 3.0


def test_orifice_saturates_at_capacity():
    """Asked for three times q_max W (whole floor), the floor injects q_max W (the bottom
    cell's supply) from the first step on, the refused rate is reported, and the column
    fills as the fan rho = (rho_max/2)(1 - z/(v_s t)) from the floor (rho_c is sonic:
    the outflow approaches q_max W only as 1 - (H/t)**2)."""
    h, H, t = 0.1, 20.0, 40.0
    g = Grid(2, (0.0, 2.0), (0.0, H), h, "reflecting")
    q_cap = 0.25 * 2.0
    o = Orifice(x=1.0, width=2.0, rate=3.0 * q_cap)
    # the flow is uniform across, so b only limits the explicit step: keep it small
    s = Spots(drift=1.0, b=1e-3, b_par=0.0, rho_max=1.0)
    res = traffic.transient(g, o, s, t, times=[1.0, t], full_output=True)
    np.testing.assert_allclose(res["injected"], q_cap, rtol=1e-12)
    np.testing.assert_allclose(res["requested"], 3 * q_cap)
    refused = res["requested_total"][-1] - res["injected_total"][-1]
    assert refused == pytest.approx(2 * q_cap * t, rel=1e-12)
    z = g.z
    fan = 0.5 * (1.0 - z / t)
    assert np.max(np.abs(res["frames"][-1][:, 0] - fan)[z > 1.0]) < 2e-3
    assert np.ptp(res["frames"][-1], axis=1).max() < 1e-12          # uniform across
    out = res["outflow"][-1] / q_cap
    assert out == pytest.approx(1.0 - (H / t) ** 2, abs=2e-3)


@pytest.mark.parametrize("dims, scaling", [(2, "fixed"), (2, "speed"), (3, "fixed")])
def test_mass_budget_and_maximum_principle(dims, scaling):
    """Random start, noisy overfull orifice: mass - mass0 = int injected - int outflow to
    round-off, and 0 <= rho <= rho_max at every frame."""
    rng = np.random.default_rng(5)
    h = 0.5
    g = Grid(dims, (-3.0, 3.0), (0.0, 10.0), h, "reflecting")
    rho0 = rng.uniform(0.0, 2.0, g.shape)
    rate = noise.noisy_rate(6.0, 1.0, 2.0, seed=3)
    o = Orifice(x=0.0, width=2.0, rate=rate)
    s = Spots(drift=1.0, b=1.3, b_par=0.7, rho_max=2.0, diffusion_scaling=scaling)
    res = traffic.transient(g, o, s, 6.0, times=np.linspace(0, 6, 7), rho0=rho0,
                            full_output=True)
    budget = res["mass"] - res["mass"][0] - (res["injected_total"] - res["outflow_total"])
    assert np.max(np.abs(budget)) < 1e-12 * res["mass"][0]
    assert res["frames"].min() >= 0.0
    assert res["frames"].max() <= 2.0 * (1 + 1e-14)
    assert np.all(res["injected_total"] <= res["requested_total"] * (1 + 1e-3))


def test_diffusion_scaling_speed_limit_and_effect():
    """'speed': D_s = b q/rho vanishes as rho -> rho_max, so a dense step spreads less."""
    h = 0.1
    z = cells(-10.0, 10.0, h)
    step = np.where(z < 0, 0.9, 0.7)
    fixed = column(step, 2.0, h, D=0.5, floor_flux=q(0.9))["rho"][-1]
    speed = column(step, 2.0, h, D=0.5, floor_flux=q(0.9), scaling="speed")["rho"][-1]
    win = np.abs(z) < 5          # the free exit at the top opens a fan down from z = 10
    for r in (fixed, speed):
        assert np.all(np.diff(r[win]) <= 1e-15)          # monotone, no overshoot
    width = lambda r: np.count_nonzero(((r > 0.71) & (r < 0.89))[win])
    assert width(speed) < width(fixed)


def test_triangular_flux_waves_at_plus_minus_v():
    """Triangular flux: small bumps move at +v_s below rho_c and -v_s above."""
    h, eps, t = 0.05, 1e-3, 5.0
    z = cells(-20.0, 20.0, h)
    tri = T.FLUXES["triangular"]
    for rho0, c in ((0.2, 1.0), (0.8, -1.0)):
        assert float(tri.c(rho0, 1.0, 1.0)) == c
        bump = eps * np.exp(-0.5 * (z / 1.5) ** 2)
        rho = column(rho0 + bump, t, h, floor_flux=tri.q(rho0, 1.0, 1.0), flux=tri)["rho"][-1]
        win = np.abs(z - c * t) < 10        # the top exit's jump runs down from z = 20 at -v_s
        d = (rho - rho0)[win]
        assert np.sum(z[win] * d) / np.sum(d) / t == pytest.approx(c, abs=1e-4)


# -- noise ------------------------------------------------------------------------------
def test_noise_reproducible_and_statistics():
    """Same seed, same Q0(t) whatever the query order; E[M] = 1 and the OU correlation
    exp(-s/tau), from 200 independent seeds (standard errors from the replicas)."""
    t = np.linspace(0.0, 50.0, 501)
    a = noise.noisy_rate(2.0, 0.5, 3.0, seed=7)
    b = noise.noisy_rate(2.0, 0.5, 3.0, seed=7)
    late_first = b(t[::-1])[::-1]
    np.testing.assert_array_equal(a(t), late_first)
    assert not np.allclose(a(t), noise.noisy_rate(2.0, 0.5, 3.0, seed=8)(t))
    assert np.all(a(t) > 0)
    tau, lag = 3.0, 3.0
    m, c = [], []
    for seed in range(200):
        X = noise.OrnsteinUhlenbeck(tau, seed)
        x0, x1 = X(10.0), X(10.0 + lag)
        m.append(np.exp(0.5 * x0 - 0.125))
        c.append(x0 * x1)
    m, c = np.array(m), np.array(c)
    assert abs(m.mean() - 1.0) < 4 * m.std(ddof=1) / np.sqrt(m.size)
    assert abs(c.mean() - np.exp(-lag / tau)) < 4 * c.std(ddof=1) / np.sqrt(c.size)


# -- free volume, pipeline, bad input ------------------------------------------------------
def test_free_volume_local_limit():
    """w * rho_s = V1 (rho_s + (R**2/8) d2 rho_s/dz2) + O(k**4) for the uniform disk
    (second moment V1 R**2 / 4 per axis), away from the walls."""
    from spotpde.fields import kernels

    g = Grid(2, (-20.0, 20.0), (0.0, 40.0), 0.25, "reflecting")
    Z, X = np.broadcast_arrays(*g.mesh())
    kz = 2 * np.pi / 40.0
    rho = 0.3 + 0.05 * np.sin(kz * Z)
    k = kernels.Uniform(radius=2.5, height=0.0024, dims=2)
    fv = traffic.free_volume(g, rho, k)
    inner = (np.abs(X) < 15) & (Z > 5) & (Z < 35)
    local = k.V1 * (rho - 2.5**2 / 8 * kz**2 * (rho - 0.3))
    np.testing.assert_allclose(fv[inner], local[inner], rtol=3e-5)
    assert np.max(np.abs(fv / (k.V1 * rho) - 1)[inner]) < 5e-3


SMALL_CASE = """
[domain]
dims = 2
x = [-4.0, 4.0]
z = [0.0, 12.0]
spacing = 0.5

[orifice]
width = 4.0
rate = 0.4
noise = {{ amplitude = 0.3, correlation_time = 2.0, seed = 4 }}

[spots]
mode = "{mode}"
t_end = {t_end}
rho_max = {rho_max}
frames = 11
{extra}

[kernel]
shape = "uniform"
size = 2.5
height = 0.0024

[output]
path = "{out}"
"""


def _case(tmp_path, mode="transient", t_end=12.0, rho_max=0.5, extra=""):
    p = tmp_path / "case.toml"
    p.write_text(SMALL_CASE.format(mode=mode, t_end=t_end, rho_max=rho_max, extra=extra,
                                   out=tmp_path / "out.nc"))
    return p


def test_run_dataset_variables(tmp_path):
    import spotpde

    ds = spotpde.run(spotpde.load_case(_case(tmp_path)))
    for name in ("free_volume", "rho_s_t", "free_volume_t", "injected_rate", "requested_rate",
                 "spot_outflow", "spot_mass"):
        assert "units" in ds[name].attrs and "long_name" in ds[name].attrs
    assert ds["rho_s_t"].dims == ("t_s", "z", "x") and ds.sizes["t_s"] == 11
    np.testing.assert_allclose(ds["rho_s_t"][-1], ds["rho_s"], rtol=0, atol=0)
    assert abs(ds.attrs["mass_budget_error"]) < 1e-12
    assert float(ds["rho_s_t"].max()) <= 0.5
    axis = traffic.space_time(ds, "free_volume_t")
    across = traffic.space_time(ds, "rho_s_t", z=6.0)
    assert axis.dims == ("t_s", "z") and across.dims == ("t_s", "x")
    np.testing.assert_allclose(axis[-1], ds["free_volume"].sel(x=0.25), rtol=1e-12)
    again = spotpde.run(spotpde.load_case(_case(tmp_path)))
    np.testing.assert_array_equal(ds["requested_rate"], again["requested_rate"])
    # the space-time plot's characteristics: slope c = v_s (1 - 2 rho / rho_max) at the
    # mean density of the later half on the axis
    fig = traffic.plot_space_time(ds, characteristics=True)
    line = fig.axes[0].lines[0]
    t, zl = line.get_xdata(), line.get_ydata()
    rho = traffic.space_time(ds, "rho_s_t").values
    rho0 = float(np.mean(rho[len(rho) // 2:]))
    c = ds.attrs["v_s"] * (1.0 - 2.0 * rho0 / ds.attrs["rho_max"])
    assert (zl[-1] - zl[0]) / (t[-1] - t[0]) == pytest.approx(c, rel=1e-12)
    assert len(fig.axes[0].lines) == 5


@pytest.mark.parametrize("kwargs, key", [
    ({"rho_max": 0.0}, "spots.rho_max"),
    ({"rho_max": -1.0}, "spots.rho_max"),
    ({"extra": 'flux = "parabolic"'}, "spots.flux"),
    ({"extra": 'diffusion_scaling = "local"'}, "spots.diffusion_scaling"),
    ({"mode": "steady", "t_end": 0.0}, "orifice.noise"),
])
def test_bad_input_exit_2(tmp_path, kwargs, key):
    path = _case(tmp_path, **kwargs)
    proc = subprocess.run([sys.executable, "-m", "spotpde", "check", str(path)],
                          capture_output=True, text=True, cwd=tmp_path, env=ENV)
    assert proc.returncode == 2
    assert key in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "out.nc").exists()


def test_negative_noise_amplitude_exit_2(tmp_path):
    p = _case(tmp_path)
    p.write_text(p.read_text().replace("amplitude = 0.3", "amplitude = -0.3"))
    proc = subprocess.run([sys.executable, "-m", "spotpde", "run", str(p)],
                          capture_output=True, text=True, cwd=tmp_path, env=ENV)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "orifice.noise.amplitude" in proc.stderr
    assert not (tmp_path / "out.nc").exists()


def test_steady_with_rho_max_exit_2(tmp_path):
    p = _case(tmp_path, mode="steady", t_end=0.0)
    text = p.read_text().replace("noise = {", "# noise = {").replace("frames = 11", "")
    p.write_text(text)
    proc = subprocess.run([sys.executable, "-m", "spotpde", "check", str(p)],
                          capture_output=True, text=True, cwd=tmp_path, env=ENV)
    assert proc.returncode == 2
    assert proc.stderr.startswith("spots.rho_max:") and proc.stderr.count("\n") == 1


def test_tracer_follows_interacting_spots(tmp_path):
    """With a tracer, the coefficient snapshots come from the nonlinear solver: the
    tracer in a saturated column moves with the fields of the capped density, and its
    probability is conserved (inside + out through the orifice)."""
    import spotpde

    text = _case(tmp_path, t_end=12.0).read_text() + (
        "\n[tracer]\nstart = { x = 0.0, z = 6.0, width = 1.0 }\nt_end = 12.0\nframes = 3\n")
    (tmp_path / "tr.toml").write_text(text)
    case = spotpde.load_case(tmp_path / "tr.toml")
    ds = spotpde.run(case)
    snaps = spot_density.transient(case.grid, case.orifice, case.spots, 12.0,
                                   times=case.snapshot_times())
    np.testing.assert_array_equal(snaps[-1], ds["rho_s"])     # same steps, other frames
    np.testing.assert_array_equal(ds["rho_s_t"][-1], ds["rho_s"])
    assert float(snaps.max()) <= 0.5
    total = ds["mass"].values + ds["outflow"].values
    np.testing.assert_allclose(total, 1.0, atol=1e-9)


@pytest.mark.parametrize("shape", [(24, 7), (16, 5, 4)])
@pytest.mark.parametrize("scaling", ["fixed", "speed"])
@pytest.mark.parametrize("flux, rho_max", [("greenshields", 1.0), ("triangular", 1.0),
                                           ("greenshields", np.inf)])
def test_numba_kernels_match_numpy_reference(shape, scaling, flux, rho_max):
    """The fused numba right-hand side equals the vectorised NumPy one to round-off
    (random varying drift and diffusivities, every limiter)."""
    rng = np.random.default_rng(11)
    v = rng.uniform(0.5, 1.5, shape)
    Dz, Dp = rng.uniform(0.0, 1.0, shape), rng.uniform(0.1, 1.0, shape)
    req = rng.uniform(0.0, 0.6, shape[1:])
    rho = rng.uniform(0.0, 1.0, shape)
    for limiter in T.LIMITERS:
        s = T.Solver(shape, 0.5, v, Dp, Dz, rho_max, T.FLUXES[flux], scaling, limiter,
                     lambda t: req)
        fast, i1, o1 = s.rhs(rho, 0.0)
        s.backend = "numpy"
        ref, i2, o2 = s.rhs(rho, 0.0)
        np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-13)
        assert (i1, o1) == pytest.approx((i2, o2), rel=1e-14)
