"""Probe fields of the 3D Monte Carlo (``simulate(..., probes=True)`` on a 3D grid;
docs/packing.md section 6): in uniform flow the frozen probes read the mean-field drift
and diffusivity of the discrete model, all three components, within the replica
standard errors; ``measure`` returns them on ``(z, y, x)``, and ``mcstats.discard``
drops the start-up batches of a 3D run as of a 2D one."""

from __future__ import annotations

import numpy as np
import pytest

from spotpde import mcstats
from spotpde import montecarlo as mc
from spotpde.fields import kernels
from spotpde.grid import Grid
from spotpde.parameters import Orifice, Spots

B, B_PAR = 1.3, 0.5  # horizontal and vertical spot diffusion lengths (d)
W, H = 10.0, 12.0
FLUX = 0.25  # spots per d**2 of floor and unit time


def _uniform(seed, t_end=60.0, **kw):
    kernel = kernels.Gaussian(sigma=0.5, volume=0.02, dims=3)
    g = Grid(3, (-W / 2, W / 2), (0.0, H), 1.0, y_range=(-W / 2, W / 2))
    r = mc.simulate(g, Orifice(x=0.0, width=W, rate=FLUX * W * W, shape="slot"),
                    Spots(drift=1.0, b=B, b_par=B_PAR), kernel, rule=0.5, t_end=t_end, step=0.1,
                    seed=seed, probes=True, batches=6, **kw)
    return kernel, r


def test_3d_probes_read_the_mean_field_in_uniform_flow():
    """Spots over the whole floor of a 10 x 10 x 12 d box; probes farther than the
    kernel's reach (2.63 d) from the side, front and back walls, the floor and the top;
    the first 12 time units (the spots filling the box) discarded. Mean field: ``u_z =
    -flux V1``, ``D_xx = D_yy = flux b V2``, ``D_zz = flux b_par V2``, ``rho_s = flux /
    v_s``; ``u_x``, ``u_y`` and the off-diagonal ``D`` zero. Each replica averages its interior probes; errors from
    8 replicas."""
    n = 8
    vals = {}
    for seed in range(n):
        kernel, r = _uniform(seed)
        assert r.probe.shape == (9, 6, 12, 10, 10) and r.rho_hist.shape == (6, 12, 10, 10)
        ds = mc.measure(mcstats.discard(r, 12.0))
        assert ds.u_z.dims == ("z", "y", "x")
        inner = ds.sel(x=slice(-2, 2), y=slice(-2, 2), z=slice(3, 9))
        for key in ("u_x", "u_y", "u_z", "D_xx", "D_yy", "D_zz", "D_xy", "D_xz", "D_yz", "rho_s"):
            vals.setdefault(key, []).append(float(inner[key].mean()))
    lim = mcstats.t_limit(n)
    expected = {"u_x": 0.0, "u_y": 0.0, "u_z": -FLUX * kernel.V1, "D_xx": FLUX * B * kernel.V2,
                "D_yy": FLUX * B * kernel.V2, "D_zz": FLUX * B_PAR * kernel.V2, "D_xy": 0.0, "D_xz": 0.0, "D_yz": 0.0,
                "rho_s": FLUX / 1.0}
    for key, exact in expected.items():
        m, se = mcstats.replica_mean(vals[key])
        assert abs(m - exact) < lim * se, (key, m, se, exact)
    for key in ("u_z", "D_xx", "D_yy", "D_zz", "rho_s"):  # resolved: errors well below the values
        m, se = mcstats.replica_mean(vals[key])
        assert se < 0.05 * abs(expected[key]), (key, se)


def test_3d_probes_are_off_by_default_and_on_when_asked():
    g = Grid(3, (-3.0, 3.0), (0.0, 6.0), 1.0, y_range=(-1.0, 1.0))
    k3 = kernels.Uniform(radius=1.0, height=0.01, dims=3)
    P = np.array([[0.0, 3.0, 0.0], [1.0, 2.0, 0.5]])
    args = (g, Orifice(width=2.0, rate=4.0, shape="slot"), Spots(), k3)
    r = mc.simulate(*args, particles=P, t_end=3.0, seed=2)
    assert r.probe is None and r.rho_hist is None
    with pytest.raises(ValueError, match="^result"):
        mcstats.discard(r, 1.0)
    q = mc.simulate(*args, particles=P, t_end=3.0, seed=2, probes=True, batches=3)
    assert q.probe.shape == (9, 3, 6, 2, 6) and q.batch_ticks.sum() == q.n_ticks
    ds = mc.measure(q)
    assert float(ds.u_z.min()) < 0.0 and "D_yz" in ds and ds.rho_s.dims == ("z", "y", "x")


def test_particle_density_of_3d_positions():
    """Columns (x, z, y) land in cells (z, y, x) of the 3D grid, normalised to 1."""
    g = Grid(3, (-2.0, 2.0), (0.0, 4.0), 1.0, y_range=(-1.0, 1.0))
    pts = np.array([[0.5, 0.5, -0.5], [0.5, 0.6, -0.5], [-1.5, 3.5, 0.5], [np.nan] * 3])
    P0 = mcstats.particle_density(g, pts)
    assert P0.shape == (4, 2, 4)
    assert P0.sum() * g.cell_volume == pytest.approx(1.0)
    assert P0[0, 0, 2] == pytest.approx(2 / 3 / g.cell_volume)   # z 0.5, y -0.5, x 0.5
    assert P0[3, 1, 0] == pytest.approx(1 / 3 / g.cell_volume)   # z 3.5, y 0.5, x -1.5
    with pytest.raises(ValueError, match="^points"):
        mcstats.particle_density(g, pts[:, :2])


def test_3d_velocity_correlation_of_the_depth_component_matches_the_horizontal_one():
    """Spots walk alike in x and y, so in uniform flow ``C(r)`` of the ``y`` displacement
    equals that of ``x`` within the errors (windows of 10 time units, two spot passages,
    from 4 replicas pooled by averaging), and it is positive at short range. A 2D run has
    no ``y``."""
    P = np.stack(np.meshgrid(np.arange(-2.0, 2.5), np.arange(4.0, 8.5), np.arange(-2.0, 2.5),
                             indexing="ij"), axis=-1).reshape(-1, 3)   # columns (x, z, y)
    bins = np.array([0.5, 1.2, 2.2, 3.5])
    cx, cy = [], []
    for seed in range(4):
        _, r = _uniform(seed, t_end=132.0, particles=P, tracked="all", records=12)
        c = {comp: mc.velocity_correlation(r, bins, component=comp, skip=2)
             for comp in ("x", "y")}
        assert c["x"].C.size == bins.size - 1 == c["y"].C.size
        cx.append(c["x"].C.values)
        cy.append(c["y"].C.values)
    mx, sx = mcstats.replica_mean(cx)
    my, sy = mcstats.replica_mean(cy)
    assert np.all(np.abs(mx - my) < mcstats.t_limit(4) * np.hypot(sx, sy)), (mx, my, sx, sy)
    assert my[0] > 3 * sy[0]
    g2 = Grid(2, (-3.0, 3.0), (0.0, 6.0), 1.0)
    r2 = mc.simulate(g2, Orifice(width=2.0, rate=4.0), Spots(),
                     kernels.Uniform(radius=1.0, height=0.01, dims=2),
                     particles=np.array([[0.0, 3.0], [1.0, 3.0]]), tracked="all", records=3,
                     t_end=3.0, probes=False)
    with pytest.raises(ValueError, match="^component"):
        mc.velocity_correlation(r2, bins, component="y")


def test_3d_case_table_replicas_and_probes():
    """A 3D case with a ``[montecarlo]`` table: replicas from the table's seeds, probes
    and tracked particles as in 2D (``mcstats.positions_at``, ``drained_fraction``)."""
    from pathlib import Path

    import spotpde

    data = spotpde.load_case(Path(__file__).parents[2] / "cases" / "slab3d.toml").data
    data = {**data, "domain": {**data["domain"], "x": [-6.0, 6.0], "z": [0.0, 12.0],
                               "spacing": 1.0},
            "orifice": {**data["orifice"], "width": 4.0},
            "montecarlo": {"particles": "lattice", "spacing": 1.0, "seed": 3, "replicas": 2,
                           "t_end": 6.0, "probes": True, "batches": 3, "records": 3,
                           "tracked": "all"}}
    case = spotpde.load_case(data)
    runs = mc.replicas_from_case(case)
    assert [r.seed for r in runs] == [3, 4]
    for r in runs:
        assert r.probe.shape[:2] == (9, 3) and r.positions.shape[2] == 3
        ds = mc.measure(r)
        assert ds.u_z.dims == ("z", "y", "x") and float(ds.u_z.min()) < 0.0
        start = mcstats.positions_at(r, 0.0)
        low = start[:, 1] < 3.0
        assert 0.0 < mcstats.drained_fraction(r, low, 0.0, r.times[-1]) <= 1.0
    assert not np.array_equal(runs[0].final, runs[1].final)
