"""Honest statistics (spotpde.mcstats): calibrated Monte Carlo errors, and the layered
silo's drainage against the continuum started from the particles' own distribution.

The standard errors themselves are tested: over independent seeds the scatter of the
estimates must match the errors each run quotes (so tripled or thirded errors fail),
and the seed-averaged estimates must agree with the exact values within a few honest
standard errors (docs/montecarlo.md, section 9).
"""

from __future__ import annotations

import copy
import math
from pathlib import Path

import numpy as np
import pytest

import spotpde
from spotpde.fields import kernels
from spotpde.montecarlo import mcstats
from spotpde.app import pipeline
from spotpde import montecarlo as mc
from spotpde.grid import Grid
from spotpde.parameters import Orifice, Spots

ROOT = Path(__file__).resolve().parents[2]
NSIG = 4.0
B = 1.3


# ---------------------------------------------------------------------------------------
# the tools, on samples with known errors
# ---------------------------------------------------------------------------------------
def test_calibration_tools_accept_right_errors_and_reject_wrong_ones():
    rng = np.random.default_rng(12)
    sd = np.array([0.5, 2.0, 0.01])
    est = 3.0 + sd * rng.standard_normal((10, 3))       # 10 replicas of 3 quantities
    se = np.broadcast_to(sd, est.shape)
    assert mcstats.se_calibration(est, se)["calibrated"]
    for wrong in (3.0, 1 / 3):
        assert not mcstats.se_calibration(est, wrong * se)["calibrated"], wrong
    z = (est - 3.0) / se
    assert mcstats.zscore_spread(z)["calibrated"]
    for wrong in (3.0, 1 / 3):
        assert not mcstats.zscore_spread(z / wrong)["calibrated"], wrong
    m, s = mcstats.replica_mean(est[:, 0])
    assert s == pytest.approx(est[:, 0].std(ddof=1) / math.sqrt(10))
    with pytest.raises(ValueError, match="seeds"):
        mcstats.replicas(lambda s: s, [1, 1])
    assert mcstats.replicas(lambda s: 2 * s, [1, 2, 3]) == [2, 4, 6]
    assert mcstats.replicas(lambda s: 2 * s, [1, 2], scheduler="synchronous") == [2, 4]


def test_se_calibration_accepts_right_errors_at_the_stated_rate():
    """With exact errors and Gaussian estimates, ``ratio^2 ~ chi2(m (R - 1)) / (m (R - 1))``
    (sample variances over ``R`` replicas lose one degree of freedom each): the
    acceptance interval is that distribution's central ``1 - level`` interval, so right
    errors are accepted in ``1 - level`` of independent trials (``m R`` degrees of freedom
    would accept only 70 % here)."""
    R, m, level, trials = 3, 2, 0.2, 2000
    rng = np.random.default_rng(5)
    sd = np.array([0.3, 4.0])
    est = 1.0 + sd * rng.standard_normal((trials, R, m))
    se = np.broadcast_to(sd, (R, m))
    accepted = [mcstats.se_calibration(e, se, level=level)["calibrated"] for e in est]
    rate = float(np.mean(accepted))
    _se = math.sqrt(level * (1 - level) / trials)
    assert abs(rate - (1 - level)) <= NSIG * _se, (rate, _se)
    one = mcstats.se_calibration(est[0], se, level=level)
    assert one["dof"] == m * (R - 1)


def test_particle_density_and_drained_fraction_bookkeeping():
    g = Grid(2, (-2.0, 2.0), (0.0, 4.0), 0.5)
    pts = np.array([[0.1, 0.1], [0.1, 0.2], [-1.9, 3.9], [np.nan, np.nan]])
    P0 = mcstats.particle_density(g, pts)
    assert P0.sum() * g.cell_volume == pytest.approx(1.0)
    assert P0[0, 4] == pytest.approx(2 / 3 / g.cell_volume)
    with pytest.raises(ValueError, match="points"):
        mcstats.particle_density(g, np.zeros((3, 3)))


# ---------------------------------------------------------------------------------------
# montecarlo.measure: probe standard errors against the scatter over seeds
# ---------------------------------------------------------------------------------------
W, Q0, T_WARM = 24.0, 6.0, 30.0
PROBE_X = [-7.5, 0.5, 7.5]   # 7 d apart (> 2R): no spot reaches two of them at once
PROBE_Z = 15.5


def _probe_replica(seed):
    g = Grid(2, (-W / 2, W / 2), (0.0, 30.0), 1.0)
    k = kernels.Uniform(radius=2.5, height=0.0024, dims=2)
    r = mc.simulate(g, Orifice(x=0.0, width=W, rate=Q0), Spots(drift=1.0, b=B), k, rule=0.5,
                    t_end=T_WARM + 400.0, step=0.25, seed=seed, batches=43)
    ds = mc.measure(mcstats.discard(r, T_WARM))   # the first 30 time units: spots filling the silo
    assert float(ds.attrs["t_end"]) == pytest.approx(400.0, abs=10.0)
    return {n: (ds[n].sel(z=PROBE_Z, x=PROBE_X).values, ds[n + "_se"].sel(z=PROBE_Z, x=PROBE_X).values)
            for n in ("u_z", "D_xx", "rho_s")}, k


def test_measure_standard_errors_match_the_scatter_over_seeds():
    """Uniform flow (the whole floor injects): u_z = -V1 f, D_xx = V2 f b, rho_s = f / v_s
    (f = Q0 / W). Ten seeds; the quoted errors must match the scatter between them."""
    runs = mcstats.replicas(_probe_replica, range(1, 11))
    k = runs[0][1]
    flux = Q0 / W
    exact = {"u_z": -k.V1 * flux, "D_xx": k.V2 * flux * B, "rho_s": flux}
    for name, value in exact.items():
        est = np.array([r[0][name][0] for r in runs])
        se = np.array([r[0][name][1] for r in runs])
        cal = mcstats.se_calibration(est, se)
        assert cal["calibrated"], (name, cal)
        # the same data reject tripled and thirded errors
        assert not mcstats.se_calibration(est, 3 * se)["calibrated"], name
        assert not mcstats.se_calibration(est, se / 3)["calibrated"], name
        # the seed average against the exact value, with the honest (replica) error
        m, s = mcstats.replica_mean(est.mean(axis=1))
        assert abs(m - value) < NSIG * s, (name, m, s, value)
        assert s < 0.02 * abs(value)


# ---------------------------------------------------------------------------------------
# the layered silo: drainage of the coloured particles (issue: the 6 % gap)
# ---------------------------------------------------------------------------------------
def _small_layers_case():
    case = spotpde.load_case(ROOT / "cases" / "montecarlo_layers.toml")
    data = copy.deepcopy(case.data)
    data["domain"]["spacing"] = 0.5
    data["tracer"].update(t_end=300.0, frames=2)
    return spotpde.load_case(data)


def _drainage_replica(case, warm, seed, particles="lattice"):
    g = case.grid
    P = mc.lattice(g, 1.0) if particles == "lattice" else mc.random_packing(g, 0.5, seed=seed)
    T = case.tracer.t_end
    r = mc.simulate(g, case.orifice, case.spots, case.kernel, rule=case.rule, particles=P,
                    tracked="all", t_end=warm + T, records=int(round((warm + T) / 30.0)),
                    step=0.25, seed=seed, probes=False)
    start = mcstats.positions_at(r, warm)
    coloured = np.isfinite(start).all(axis=1) & mc.layer_mask(start[:, 1], case.tracer.start.spacing)
    return (mcstats.drained_fraction(r, coloured, warm, warm + T),
            mcstats.particle_density(g, start[coloured]))


@pytest.mark.slow
def test_layer_drainage_matches_the_continuum_started_from_the_particles():
    """cases/montecarlo_layers.toml, small configuration (h = 0.5 d, T = 300, midpoint rule).

    The Monte Carlo colours its particles by the bands at the end of the warm-up (60 time
    units, spots filling the silo). With a triangular lattice (rows 0.866 d apart: 3 or 4
    rows to a 3 d band) the warm-up's fall of about 3 d near the slot puts 4 rows into
    the bands that drain first, so the coloured particles drain 6 % more than uniform
    bands: the continuum's nominal P0 is rejected by > 6 SE. Started from the particles'
    actual distribution (seed-averaged, the tracer is linear) it agrees within 3 SE
    (SE from the scatter over 8 independent seeds). docs/montecarlo.md, section 9.
    """
    case = _small_layers_case()
    g = case.grid
    warm = (g.z_range[1] - g.z_range[0]) / float(case.spots.drift)
    ds = pipeline.run(case)
    fields = {c: ds[c].values for c in ("u_x", "u_z", "D_xx", "D_xz", "D_zz")}
    T = case.tracer.t_end
    nominal = mcstats.continuum_drainage(g, fields, pipeline.initial_density(g, case.tracer.start),
                                         T, **case.tracer_options)
    assert nominal == pytest.approx(float(ds.outflow[-1]), abs=1e-9)
    reps = mcstats.replicas(lambda s: _drainage_replica(case, warm, s), range(1, 9))
    frac = np.array([f for f, _ in reps])
    m, se = mcstats.replica_mean(frac)
    P0 = np.mean([p for _, p in reps], axis=0)
    from_particles = mcstats.continuum_drainage(g, fields, P0, T, **case.tracer_options)
    assert abs(m - from_particles) < 3 * se, (m, se, from_particles)
    assert m - nominal > 6 * se, (m, se, nominal)          # the gap is the initial distribution
    # the vertical shot noise (b_p_par ~ 1.5 w, docs/montecarlo.md) changes the drained fraction by
    # far less than the error: an added D_zz = 1.536 w |u_z| moves it by < 0.1 SE
    w = float(case.kernel.V2 / case.kernel.V1)
    noisy = dict(fields, D_zz=fields["D_zz"] + 1.536 * w * np.abs(fields["u_z"]))
    shot = mcstats.continuum_drainage(g, noisy, P0, T, **case.tracer_options)
    assert abs(shot - from_particles) < 0.1 * se


@pytest.mark.slow
def test_layer_sharpness_full_grid_matches_the_particles():
    """The notebook's sharpness check at full resolution (h = 0.25 d): the first Fourier
    mode in z of the coloured bands in the plug flow (|x| < 5 d, 25 < z < 52 d),
    |<exp(2 pi i z / 6 d)>|, of the continuum P is that of the Monte Carlo's coloured
    particles (mean of 3 seeds) times exp(-k^2 s^2 / 2), s the continuum's own edge width
    (layers.interface_width), within 10 %, for t <= 300 (two-sided, as on the 0.5 d grid
    of the notebook's small configuration)."""
    from spotpde.analysis import layers

    case = spotpde.load_case(ROOT / "cases" / "montecarlo_layers.toml")
    data = copy.deepcopy(case.data)
    data["tracer"].update(t_end=300.0, frames=7)
    case = spotpde.load_case(data)
    g = case.grid
    assert g.spacing == 0.25
    ds = pipeline.run(case)
    warm = (g.z_range[1] - g.z_range[0]) / float(case.spots.drift)
    spacing = case.tracer.start.spacing
    k_z = 2 * np.pi / spacing
    x_max, z_rng = 5.0, (25.0, 52.0)
    times = ds.t.values
    amp_m = []
    for seed in (1, 2, 3):
        r = mc.simulate(g, case.orifice, case.spots, case.kernel, rule=case.rule,
                        particles=mc.lattice(g, 1.0), tracked="all", t_end=warm + times[-1],
                        records=int(round((warm + times[-1]) / 10.0)), step=0.25, seed=seed,
                        probes=False)
        s0 = mcstats.positions_at(r, warm)
        col = np.isfinite(s0).all(axis=1) & mc.layer_mask(s0[:, 1], spacing)
        row = []
        for t in times:
            p = mcstats.positions_at(r, warm + t)
            sel = col & np.isfinite(p).all(axis=1) & (np.abs(p[:, 0]) < x_max) \
                & (p[:, 1] > z_rng[0]) & (p[:, 1] < z_rng[1])
            row.append(abs(np.mean(np.exp(1j * k_z * p[sel, 1]))))
        amp_m.append(row)
    amp_m = np.mean(amp_m, axis=0)
    amp_c = []
    for i in range(times.size):
        Pc = ds.P.isel(t=i).sel(x=slice(-x_max, x_max), z=slice(*z_rng))
        amp_c.append(abs(complex(np.sum(Pc * np.exp(1j * k_z * Pc.z)) / np.sum(Pc))))
    amp_c = np.array(amp_c)
    s_c = layers.interface_width(ds, x_max=x_max, z_range=z_rng)
    blur = np.exp(-0.5 * (k_z * s_c) ** 2)
    print("amplitude MC", amp_m.round(3), "continuum", amp_c.round(3), "MC x blur", (amp_m * blur).round(3))
    assert np.all(np.abs(amp_c / (amp_m * blur) - 1) < 0.1), (amp_m, amp_c, blur)
    # measured at h = 0.25 d: the continuum's bands are 9-13 % less sharp than the
    # particles' for t >= 150 (the notebook's former "within 10 %" never ran; it fails)
    assert np.all(amp_c <= amp_m * 1.02), (amp_m, amp_c)
