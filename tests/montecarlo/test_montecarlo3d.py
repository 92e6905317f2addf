"""The 3D discrete spot model (spheres in a box or a thin slab; spotpde.montecarlo with a
3D grid, docs/packing.md): its kernels and wall coverage against closed forms, the
relaxation of spheres (centre of mass held to round-off, overlaps removed to the
tolerance, a relaxed packing left alone), uniform flow against the continuum's
prediction and the symmetry of a centred slab, with standard errors from independent
replicas (different seeds), never from correlated samples of one run."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import special

from spotpde import montecarlo as mc
from spotpde.analysis.packing import pair_overlaps
from spotpde.fields import kernels
from spotpde.grid import Grid
from spotpde.montecarlo import _mc3d, _relax, _relax3d, _simulate3d
from spotpde.parameters import Orifice, Spots

EPS = np.finfo(float).eps
NSIG = 4.0
B = 1.3
# a slab 10 d wide, 10 d high, 4 d deep, in the order of the particle columns (x, z, y)
BOX = (0.0, 10.0, 0.0, 10.0, 0.0, 4.0)
NUMBA_BOX = (BOX[0], BOX[1], BOX[4], BOX[5], BOX[2], BOX[3])  # (x0, x1, y0, y1, z0, z1)


def _close(measured, se, expected, nsig=NSIG):
    assert np.isfinite(se) and se > 0
    assert abs(measured - expected) <= nsig * se, (measured, se, expected, (measured - expected) / se)


def _replicas(values):
    """Mean and standard error over independent replicas."""
    v = np.asarray(values, float)
    return v.mean(), v.std(ddof=1) / math.sqrt(v.size)


# ---------------------------------------------------------------------------------------
# kernels and wall coverage
# ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("kernel", [
    kernels.Uniform(radius=2.5, height=0.0024, dims=3, aspect=2.0),
    kernels.Gaussian(sigma=1.0, volume=0.05, dims=3, aspect=1.5),
    kernels.Exponential(length=0.7, volume=0.05, dims=3, aspect=2.0),
])
def test_numba_3d_kernel_matches_kernels_module(kernel):
    kp = mc.kernel_params(kernel)
    assert kp.dims == 3
    rng = np.random.default_rng(0)
    x, y, z = (rng.uniform(-1.2, 1.2, 4000) * r for r in (kp.reach[0], kp.reach[0], kp.reach[1]))
    got = mc.kernel_evaluate(kp, x, y, z)
    ref = kernel.evaluate(x, y, z)
    inside = (x * x + y * y) / kp.reach[0] ** 2 + (z / kp.reach[1]) ** 2 <= 1.0
    if kp.shape == 0:   # the sharp sphere: exact (away from its surface)
        q = (x * x + y * y) / kp.size**2 + (z / kp.size_v) ** 2
        ok = np.abs(q - 1) > 1e-9
        np.testing.assert_array_equal(got[ok], ref[ok])
    else:               # smooth kernels: exact inside the cut-off, zero beyond
        np.testing.assert_allclose(got[inside], ref[inside], rtol=1e-13, atol=0)
        assert np.all(got[~inside] == 0) and ref[~inside].max() <= 1e-5 * kp.amp
    assert 0.3 < inside.mean() < 0.7


def test_coverage_table_3d_against_closed_forms():
    # Gaussian: phi(x, y) = phi_x(x) phi_y(y), each a difference of error functions
    # (the cut-off at 1e-6 w(0) changes it by far less than the tolerance)
    kp = mc.kernel_params(kernels.Gaussian(sigma=0.8, volume=0.05, dims=3))
    x0, x1, y0, y1 = -5.0, 5.0, -2.0, 2.0
    tx, dx, ty, dy, tab = _simulate3d.coverage_table3(kp, (x0, x1), (y0, y1))
    xs, ys = tx + dx * np.arange(tab.shape[1]), ty + dy * np.arange(tab.shape[0])

    def cover(s, lo, hi):
        return 0.5 * (special.erf((hi - s) / (0.8 * math.sqrt(2))) - special.erf((lo - s) / (0.8 * math.sqrt(2))))

    ref = cover(ys, y0, y1)[:, None] * cover(xs, x0, x1)[None, :]
    # midpoint sums on 400 x 400 squares of side 2 reach / 400: error (h/sigma)^2 / 24
    assert np.abs(tab - ref).max() < 1e-3
    assert tab[ys.size // 2, xs.size // 2] == pytest.approx(ref[ys.size // 2, xs.size // 2], abs=1e-4)
    # sphere of radius 2.5 in a slab 4 d deep, at a corner of the box: brute force
    kp = mc.kernel_params(kernels.Uniform(radius=2.5, height=0.01, dims=3))
    tx, dx, ty, dy, tab = _simulate3d.coverage_table3(kp, (x0, x1), (y0, y1))
    # 10^6 points uniform in the ball: the fraction inside has SE <= 5e-4
    rng = np.random.default_rng(3)
    Q = rng.uniform(-2.5, 2.5, (2_000_000, 3))
    Q = Q[(Q**2).sum(axis=1) < 2.5**2][:1_000_000]
    for (cx, cy) in ((0.0, 0.0), (-4.0, -1.5), (4.9, 1.0)):
        u, v = Q[:, 0] + cx, Q[:, 1] + cy
        expected = np.mean((u > x0) & (u < x1) & (v > y0) & (v < y1))
        got = 1.0 / _mc3d.coverage_inverse2(cx, cy, tx, dx, ty, dy, tab)
        assert got == pytest.approx(expected, abs=3e-3)
    assert 0.3 < 1.0 / _mc3d.coverage_inverse2(-4.0, -1.5, tx, dx, ty, dy, tab) < 0.6


# ---------------------------------------------------------------------------------------
# relaxation of spheres
# ---------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def packing():
    g = Grid(3, BOX[:2], BOX[2:4], 1.0, y_range=BOX[4:])
    P, d, worst = mc.dense_packing(g, seed=4)
    assert worst <= 1e-3 and P.shape == (len(d), 3)
    assert math.pi / 6 * np.sum(d**3) / 400.0 == pytest.approx(0.55)
    return P, d


def _block(P, d, centre, relax, shift=None, walls=True):
    """Relax the block around ``centre`` through the 3D Monte Carlo's own cell list
    (``walls``: the side, front and back walls repel)."""
    px, pz, py = (P[:, k].copy() for k in range(3))
    if shift is not None:
        px += shift[:, 0]
        pz += shift[:, 1]
        py += shift[:, 2]
    n = len(d)
    cell, skin = 3.0, 0.5
    ncx, ncy, ncz = 4, 2, 4
    status = np.zeros(n, np.int64)
    cs, ci = np.zeros(ncx * ncy * ncz + 1, np.int64), np.zeros(n, np.int64)
    _mc3d.build_cells3(px, py, pz, status, BOX[0], BOX[4], BOX[2], cell, ncx, ncy, ncz, cs, ci)
    rx = mc.Relax.of({"radius": 2.5, **relax}).resolved(2.5)
    rp = _relax.relax_params(rx, d, 5.0, walls)
    blk, old = np.zeros(n, np.int64), np.zeros((n, 3))
    cx, cz, cy = centre
    nb = _relax3d.relax_block3(*NUMBA_BOX, rp, cx, cy, cz, cx, cy, cz + 0.1, px, py, pz, d,
                               status, cs, ci, cell, ncx, ncy, ncz, skin, blk, old)
    return np.column_stack([px, pz, py]), blk[:nb], old[:nb][:, [0, 2, 1]]


def test_3d_block_relaxation_holds_the_centre_of_mass(packing):
    P, d = packing
    rng = np.random.default_rng(0)
    centre = np.array([5.0, 5.0, 2.0])   # (x, z, y)
    shift = 0.02 * rng.standard_normal(P.shape)
    shift[np.linalg.norm(P - centre, axis=1) < 2.0, 1] -= 0.05
    # every block of a slab 4 d deep reaches the front and back walls, which are external
    # and may push it; without them its centre of mass (weights d^3) stays put
    new, blk, old = _block(P, d, centre, {"iterations": 8}, shift, walls=False)
    m = d[blk] ** 3
    moved = new[blk] - old
    com = (m[:, None] * moved).sum(axis=0) / m.sum()
    assert np.all(np.abs(com) <= 64 * EPS * np.abs(P).max()), com
    assert np.abs(moved).max() > 1e-3 and len(blk) > 20
    assert np.abs(moved[:, 2]).max() > 1e-3      # in the depth too
    far = np.setdiff1d(np.arange(len(d)), blk)
    np.testing.assert_array_equal(new[far], P[far] + shift[far])
    # with the walls the grains pressed into the front and back walls are pushed back
    walled, blk2, _ = _block(P, d, centre, {"iterations": 8}, shift, walls=True)
    np.testing.assert_array_equal(blk2, blk)
    into = np.maximum(0.5 * d[blk] - (new[blk, 2] - BOX[4]), 0) + np.maximum(0.5 * d[blk] - (BOX[5] - new[blk, 2]), 0)
    into_w = np.maximum(0.5 * d[blk] - (walled[blk, 2] - BOX[4]), 0) + np.maximum(0.5 * d[blk] - (BOX[5] - walled[blk, 2]), 0)
    assert into.max() > 0.02 and into_w.max() < 0.5 * into.max()


def test_3d_relaxation_removes_overlaps_to_the_tolerance(packing):
    P, d = packing
    rng = np.random.default_rng(1)
    jiggled = P + 0.05 * rng.standard_normal(P.shape)
    assert pair_overlaps(jiggled, d)[0].max() > 0.05
    lo, hi = np.array(BOX[0::2]), np.array(BOX[1::2])
    assert np.any(jiggled - 0.5 * d[:, None] < lo - 0.01)     # into the walls too
    for tol in (1e-2, 1e-3):
        Q, sweeps, worst = mc.relax_packing(jiggled, d, BOX, tolerance=tol)
        assert Q.shape == P.shape and worst <= tol and sweeps > 0
        assert pair_overlaps(Q, d)[0].max() <= tol   # measured independently (k-d tree)
        assert np.all(Q - 0.5 * d[:, None] >= lo - tol)
        assert np.all(Q + 0.5 * d[:, None] <= hi + tol)


def test_3d_relaxation_leaves_a_relaxed_packing_unchanged(packing):
    P, d = packing
    d = 0.98 * d
    assert len(pair_overlaps(P, d)[0]) == 0
    new, blk, _ = _block(P, d, (5.0, 5.0, 2.0), {})
    assert len(blk) > 20
    np.testing.assert_array_equal(new, P)
    Q, sweeps, worst = mc.relax_packing(P, d, BOX)
    np.testing.assert_array_equal(Q, P)
    assert sweeps == 0 and worst == 0.0


def _slab_flow(relax, P, d, seed=2, t_end=30.0, skin=None, tracked=None):
    g = Grid(3, BOX[:2], BOX[2:4], 1.0, y_range=BOX[4:])
    k = kernels.Uniform(radius=2.0, height=0.01, dims=3)
    return mc.simulate(g, Orifice(x=5.0, width=4.0, rate=8.0, shape="slot"), Spots(drift=1.0, b=1.3),
                       k, particles=P, diameters=d, t_end=t_end, step=0.25, probes=False,
                       relax=relax, seed=seed, skin=skin, tracked=tracked)


def test_3d_flow_with_relaxation_keeps_overlaps_below_the_tolerance(packing):
    P, d = packing
    free = _slab_flow(None, P, d)
    relaxed = _slab_flow(mc.Relax(), P, d)
    ins = [r.status == 0 for r in (free, relaxed)]
    assert free.final.shape == P.shape
    assert 20 < (relaxed.status == 1).sum() < 0.5 * len(d)    # grains drained
    assert pair_overlaps(free.final[ins[0]], d[ins[0]])[0].max() > 0.1
    # spheres have about twice the disks' neighbours: the defaults (4 sweeps) hold them
    # below 0.05 d (measured 0.033 d; 0.019 d with 8 sweeps), the disks below 0.02 d
    assert pair_overlaps(relaxed.final[ins[1]], d[ins[1]])[0].max() < 0.05
    assert relaxed.counters["relaxations"] == relaxed.counters["spot_steps"]
    # every grain stays in the slab
    f = relaxed.final[ins[1]]
    assert np.all((f[:, 2] >= BOX[4]) & (f[:, 2] <= BOX[5]))
    # the cell-list gathering is exact: one cell over the whole box gives the same run
    brute = _slab_flow(mc.Relax(), P, d, skin=100.0, t_end=5.0)
    short = _slab_flow(mc.Relax(), P, d, t_end=5.0)
    np.testing.assert_allclose(brute.final, short.final, rtol=0, atol=1e-12)
    again = _slab_flow(mc.Relax(), P, d, t_end=5.0)
    np.testing.assert_array_equal(again.final, short.final)    # reproducible


# ---------------------------------------------------------------------------------------
# uniform flow and symmetry, errors from replicas
# ---------------------------------------------------------------------------------------
def test_3d_uniform_flow_drift_and_diffusivity_match_the_continuum():
    """Spots across the whole floor of a 10 x 10 x 16 d box; particles more than a kernel's
    reach (2.63 d) from every wall, the floor and the top all along (they fall 1.2 d):
    uniform flow. Each
    replica (own seed) averages over its particles and time windows (20 time units, four
    spot passages); the error is the scatter of 8 replicas. Midpoint rule: ``D_xx = D_yy``
    below the mean field ``flux b V2`` by the passage correlation (docs/montecarlo.md
    section 4), and resolved as such. ``D_zz`` (the passages' shot noise) is not asserted:
    it reads 7 +- 2 % above the small-step prediction at this step, 1 +- 2 % at half of it
    (docs/packing.md, section 6: finite steps)."""
    kernel = kernels.Gaussian(sigma=0.5, volume=0.02, dims=3)
    W, flux = 10.0, 0.25
    g = Grid(3, (-W / 2, W / 2), (0.0, 16.0), 1.0, y_range=(-W / 2, W / 2))
    P = np.stack(np.meshgrid(np.arange(-2.0, 2.5), np.arange(6.5, 13.0), np.arange(-2.0, 2.5),
                             indexing="ij"), axis=-1).reshape(-1, 3)   # columns (x, z, y)
    stats = []
    for seed in range(8):
        r = mc.simulate(g, Orifice(x=0.0, width=W, rate=flux * W * W, shape="slot"),
                        Spots(drift=1.0, b=B), kernel, rule=0.5, particles=P, tracked="all",
                        records=12, t_end=240.0, step=0.1, seed=seed, probes=False)
        assert r.positions.shape == (12, len(P), 3)
        assert np.all(np.isfinite(r.positions))
        # the first window (20 time units) is the start-up: spots fill the box in 16
        stats.append(mc.displacement_statistics(r, skip=1))
    pred = mc.uniform_flow_prediction(kernel, B, flux, rule=0.5)
    for key, expected in (("u_x", 0.0), ("u_y", 0.0), ("u_z", pred["u_z"]),
                          ("D_xx", pred["D_xx"]), ("D_yy", pred["D_xx"])):
        m, se = _replicas([s[key] for s in stats])
        _close(m, se, expected)
        if key.startswith("D"):
            assert se < 0.08 * expected
    m, se = _replicas([s["D_xx"] for s in stats])
    assert pred["D_xx_meanfield"] - m > 2 * NSIG * se    # the midpoint effect is resolved


def test_centred_slab_has_no_mean_horizontal_displacement():
    """A slab 12 d x 4 d x 12 d, centred slot, relaxation on: the mean x and y
    displacement of the grains is zero (replicas: own packing and seed each)."""
    g = Grid(3, (-6.0, 6.0), (0.0, 12.0), 1.0, y_range=(-2.0, 2.0))
    k = kernels.Uniform(radius=2.0, height=0.01, dims=3)
    mx, my, mz = [], [], []
    for seed in range(6):
        P, d, _ = mc.dense_packing(g, 0.5, seed=10 + seed)
        r = mc.simulate(g, Orifice(x=0.0, width=4.0, rate=8.0, shape="slot"),
                        Spots(drift=1.0, b=1.3), k, particles=P, diameters=d, t_end=15.0,
                        step=0.25, probes=False, relax={}, seed=seed)
        inside = r.status == 0
        disp = r.final[inside] - P[inside]
        mx.append(disp[:, 0].mean())
        mz.append(disp[:, 1].mean())
        my.append(disp[:, 2].mean())
    for v in (mx, my):
        m, se = _replicas(v)
        _close(m, se, 0.0)
    m, se = _replicas(mz)
    assert m < -NSIG * se      # they do fall: the test can tell a displacement from none


def test_3d_arguments_are_checked():
    g = Grid(3, (-3.0, 3.0), (0.0, 6.0), 1.0, y_range=(-1.0, 1.0))
    k3 = kernels.Uniform(radius=1.0, height=0.01, dims=3)
    common = dict(t_end=1.0)
    with pytest.raises(ValueError, match="kernel"):
        mc.simulate(g, Orifice(width=2.0, rate=1.0), Spots(),
                    kernels.Uniform(radius=1.0, height=0.01, dims=2), probes=False, **common)
    with pytest.raises(ValueError, match="^particles"):
        mc.simulate(g, Orifice(width=2.0, rate=1.0), Spots(), k3, probes=False,
                    particles=np.zeros((3, 2)), **common)
    with pytest.raises(ValueError, match="^box"):
        mc.relax_packing(np.zeros((3, 3)), np.ones(3), (0, 1, 0, 1))
    # the depth is the last column everywhere: a dense packing of a slab 2 d deep
    P, d, _ = mc.dense_packing(g, 0.3, seed=1)
    assert P[:, 2].min() >= -1.0 and P[:, 2].max() <= 1.0 and P[:, 1].max() > 4.0
    with pytest.raises(ValueError, match="^phi"):
        mc.dense_packing(g, 0.8)


def test_from_case_runs_the_slab3d_case():
    import pathlib

    import spotpde

    case = spotpde.load_case(pathlib.Path(__file__).parents[2] / "cases" / "slab3d.toml")
    r = mc.from_case(case, t_end=3.0, tracked=[0, 1, 2], seed=1)
    n = 50 * 100 * 8                      # the simple cubic lattice of the 50 x 100 x 8 d slab
    assert r.initial.shape == r.final.shape == (n, 3)
    assert r.positions.shape[1:] == (3, 3) and r.kernel.dims == 3
    assert r.counters["spots_injected"] > 0 and r.counters["particle_updates"] > 0
    inside = r.status == 0
    assert np.all(np.abs(r.final[inside, 2]) <= 4.0) and np.all(np.abs(r.final[inside, 0]) <= 25.0)
    assert np.any(r.final[:, 1] != r.initial[:, 1])
    with pytest.raises(ValueError, match="^particles"):
        mc.from_case(case, t_end=1.0, particles="tracer")
