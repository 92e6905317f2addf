"""The soft-core relaxation of the Monte Carlo (spotpde.montecarlo._relax; docs/packing.md):
it holds the relaxed block's centre of mass to round-off, removes overlaps to the stated
tolerance, leaves an overlap-free packing exactly as it is, and keeps the packing of a
flowing silo free of the overlaps that the plain spot model builds up."""

from __future__ import annotations

import numpy as np
import pytest

from spotpde import montecarlo as mc
from spotpde.analysis.packing import pair_overlaps
from spotpde.fields import kernels
from spotpde.grid import Grid
from spotpde.montecarlo import _mc_kernels as K
from spotpde.montecarlo import _relax
from spotpde.parameters import Orifice, Spots

EPS = np.finfo(float).eps
BOX = (0.0, 24.0, 0.0, 24.0)


@pytest.fixture(scope="module")
def packing():
    g = Grid(2, BOX[:2], BOX[2:], 1.0)
    P, d, worst = mc.dense_packing(g, 0.8, seed=4)
    assert worst <= 1e-3
    return P, d


def _block(P, d, centre, relax, shift=None):
    """Relax the block around ``centre`` through the Monte Carlo's own cell list."""
    px, pz = P[:, 0].copy(), P[:, 1].copy()
    if shift is not None:
        px += shift[:, 0]
        pz += shift[:, 1]
    n = len(d)
    cell, skin = 3.0, 0.5
    ncx = ncz = 8
    status = np.zeros(n, np.int64)
    cs, ci = np.zeros(ncx * ncz + 1, np.int64), np.zeros(n, np.int64)
    K.build_cells(px, pz, status, BOX[0], BOX[2], cell, ncx, ncz, cs, ci)
    rx = mc.Relax.of({"radius": 3.5, **relax}).resolved(2.5)
    rp = _relax.relax_params(rx, d, 12.0, True)
    blk, old = np.zeros(n, np.int64), np.zeros((n, 2))
    nb = _relax.relax_block(*BOX, rp, centre[0], centre[1], centre[0], centre[1] + 0.1, px, pz,
                            d, status, cs, ci, cell, ncx, ncz, skin, blk, old)
    return np.column_stack([px, pz]), blk[:nb], old[:nb]


def test_block_relaxation_holds_the_centre_of_mass(packing):
    P, d = packing
    rng = np.random.default_rng(0)
    # the spot's block displacement: grains within 2.5 d of (12, 12) moved down by 0.05 d,
    # plus a random jiggle everywhere: overlaps at the block's rim and inside it
    shift = 0.02 * rng.standard_normal(P.shape)
    shift[np.hypot(P[:, 0] - 12, P[:, 1] - 12) < 2.5, 1] -= 0.05
    new, blk, old = _block(P, d, (12.0, 12.0), {"iterations": 8}, shift)
    m = d[blk] ** 2
    moved = new[blk] - old
    com = (m[:, None] * moved).sum(axis=0) / m.sum()
    # round-off relative to the data: coordinates of size |r| <= 24 d carry eps |r| each
    assert np.all(np.abs(com) <= 64 * EPS * np.abs(P).max()), com
    assert np.abs(moved).max() > 1e-3  # the relaxation did move the grains
    assert len(blk) > 20
    # grains beyond the radius (3.5 d) are not moved
    far = np.setdiff1d(np.arange(len(d)), blk)
    np.testing.assert_array_equal(new[far], P[far] + shift[far])


def test_relaxation_removes_overlaps_to_the_tolerance(packing):
    P, d = packing
    rng = np.random.default_rng(1)
    jiggled = P + 0.05 * rng.standard_normal(P.shape)
    assert pair_overlaps(jiggled, d)[0].max() > 0.05
    for tol in (1e-2, 1e-3):
        Q, sweeps, worst = mc.relax_packing(jiggled, d, BOX, tolerance=tol)
        assert worst <= tol and sweeps > 0
        assert pair_overlaps(Q, d)[0].max() <= tol  # measured independently (k-d tree)
        assert np.all(Q - 0.5 * d[:, None] >= np.array(BOX[0::2]) - tol)  # walls and floor
        assert np.all(Q + 0.5 * d[:, None] <= np.array(BOX[1::2]) + tol)  # walls and lid
    # a block alone, its centre of mass held, relaxes its interior to the same level when
    # the jiggle leaves the centre of mass where it was (else the held block presses on
    # the fixed grains around it, by design)
    inner = np.hypot(P[:, 0] - 12, P[:, 1] - 12) < 2.0
    shift = np.where(inner[:, None], 0.05 * rng.standard_normal(P.shape), 0.0)
    m = d[inner] ** 2
    shift[inner] -= (m[:, None] * shift[inner]).sum(axis=0) / m.sum()
    new, blk, _ = _block(P, d, (12.0, 12.0), {"iterations": 400}, shift)
    core = np.hypot(new[:, 0] - 12, new[:, 1] - 12) < 5.0
    assert pair_overlaps(new[core], d[core])[0].max() <= 1e-3


def test_relaxation_leaves_a_relaxed_packing_unchanged(packing):
    P, d = packing
    d = 0.98 * d  # strictly no contact left
    assert len(pair_overlaps(P, d)[0]) == 0
    new, blk, _ = _block(P, d, (12.0, 12.0), {})
    assert len(blk) > 20
    np.testing.assert_array_equal(new, P)
    Q, sweeps, worst = mc.relax_packing(P, d, BOX)
    np.testing.assert_array_equal(Q, P)
    assert sweeps == 0 and worst == 0.0


def _flow(relax, skin=None, seed=2, t_end=60.0):
    g = Grid(2, (-6.0, 6.0), (0.0, 16.0), 1.0)
    P, d, _ = mc.dense_packing(g, 0.8, seed=1)
    disk = kernels.Uniform(radius=2.5, height=0.01, dims=2)
    return mc.simulate(g, Orifice(x=0.0, width=12.0, rate=12.0), Spots(drift=1.0, b=1.3), disk,
                       rule=0.5, particles=P, diameters=d, t_end=t_end, step=0.25, probes=False,
                       relax=relax, seed=seed, skin=skin), d


def test_flow_with_relaxation_keeps_overlaps_below_the_tolerance():
    free, d = _flow(None)
    relaxed, _ = _flow(mc.Relax())
    inside = [r.status == 0 for r in (free, relaxed)]
    ov_free = pair_overlaps(free.final[inside[0]], d[inside[0]])[0]
    ov_relax = pair_overlaps(relaxed.final[inside[1]], d[inside[1]])[0]
    assert ov_free.max() > 0.1  # the plain model packs grains into each other
    assert ov_relax.max() < 0.02  # the stated tolerance of the defaults (docs/packing.md)
    assert relaxed.counters["relaxations"] == relaxed.counters["spot_steps"]
    # the cell-list gathering is exact: one cell over the whole box gives the same run
    brute, _ = _flow(mc.Relax(), skin=100.0, t_end=10.0)
    short, _ = _flow(mc.Relax(), t_end=10.0)
    np.testing.assert_allclose(brute.final, short.final, rtol=0, atol=1e-12)


def test_relax_arguments_are_checked():
    with pytest.raises(ValueError, match="^relax: unknown keys"):
        mc.Relax.of({"alfa": 0.1})
    with pytest.raises(ValueError, match="^alpha"):
        mc.Relax(alpha=0.9)
    with pytest.raises(TypeError, match="^relax"):
        mc.Relax.of(3)
    # the case table's values: true (the defaults) and false (none)
    assert mc.Relax.of(True) == mc.Relax() and mc.Relax.of(False) is None
    with pytest.raises(ValueError, match="^diameters"):
        g = Grid(2, (-3.0, 3.0), (0.0, 6.0), 1.0)
        mc.simulate(g, Orifice(width=2.0, rate=1.0), Spots(drift=1.0, b=1.0),
                    kernels.Uniform(radius=1.0, height=0.01, dims=2), particles=mc.lattice(g),
                    diameters=np.ones(3), relax={}, t_end=1.0)
