"""A thin 3D slab (``domain.y``, a slot orifice across the depth): cases/slab3d.toml at a
reduced resolution end to end, and what a slab must give.

* the shipped case, at spacing d (40 000 cells instead of 2.6 M), runs end to end: its
  tracer keeps the mass budget, and every field and the tracer are mirror symmetric in
  y (and x), as the slab, its slot and its walls are;
* a slot across the depth makes the spot density independent of y: ``L_y rho_s`` is the
  2D (quasi-2D) spot density of the same slot, to round-off;
* with free-volume-conserving walls the depth-integrated drift of a slab is the 2D
  model's drift: for a Gaussian kernel (separable, so the sampled 3D stencil is the 2D
  one times its y factor and the walls' coverage ``phi`` factorises),
  ``integral u_p dy = u_p(2D)`` with the same ``V1`` and the 2D spot density (the
  derivation is in docs/geometry.md, "Thin slabs"), to round-off.
"""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path

import numpy as np
import pytest

import spotpde
from spotpde import coefficients, kernels, spot_density
from spotpde.grid import Grid
from spotpde.parameters import Orifice, Spots

ROOT = Path(__file__).resolve().parents[2]


def slab_data(spacing: float = 1.0) -> dict:
    """cases/slab3d.toml with a coarser spacing (the geometry and physics unchanged)."""
    data = tomllib.loads((ROOT / "cases" / "slab3d.toml").read_text())
    data["domain"]["spacing"] = spacing
    return data


def flat(data: dict) -> dict:
    """The same case as a quasi-2D silo: no depth, the slot as a 2D orifice."""
    two = copy.deepcopy(data)
    two["domain"]["dims"] = 2
    del two["domain"]["y"]
    del two["orifice"]["shape"]
    return two


@pytest.fixture(scope="module")
def slab_run():
    case = spotpde.load_case(slab_data())
    assert case.grid.shape == (100, 8, 50)
    return case, spotpde.run(case)


def test_the_shipped_slab_is_the_experiments_geometry():
    case = spotpde.load_case(ROOT / "cases" / "slab3d.toml")
    g = case.grid
    assert g.shape == (400, 32, 200) and g.spacing == 0.25
    assert (g.x_range, g.y_range, g.z_range) == ((-25.0, 25.0), (-4.0, 4.0), (0.0, 100.0))
    assert case.orifice.shape == "slot" and case.orifice.width == 4.0
    # the flagship's time unit: 1 d^2 of particles per unit time and unit depth
    assert case.kernel.V1 * case.orifice.rate / 8.0 == pytest.approx(1.0, rel=1e-3)
    flagship = spotpde.load_case(ROOT / "cases" / "quasi2d_layers.toml")
    assert case.tracer.t_end == flagship.tracer.t_end
    assert case.tracer.start.spacing == flagship.tracer.start.spacing


def test_reduced_slab_runs_and_keeps_the_mass_budget(slab_run):
    case, ds = slab_run
    total = ds["mass"].values + ds["outflow"].values
    np.testing.assert_allclose(total, 1.0, rtol=0, atol=1e-9)
    assert ds["outflow"].values[-1] > 0.01          # the layers drain through the slot
    assert np.all(ds["P"].values >= 0)


@pytest.mark.parametrize("name", ["rho_s", "u_x", "u_y", "u_z", "D_xx", "D_yy", "D_zz",
                                  "P_height", "P"])
def test_reduced_slab_is_mirror_symmetric(slab_run, name):
    """The slab, its slot and its walls are symmetric under y -> -y and x -> -x: so are
    the fields (``u_y`` odd in y, ``u_x`` odd in x) and the tracer, to round-off."""
    _, ds = slab_run
    a = ds[name].values
    scale = np.abs(a).max()
    assert scale > 0 or name == "u_y"
    y_sign = -1.0 if name == "u_y" else 1.0
    x_sign = -1.0 if name == "u_x" else 1.0
    np.testing.assert_allclose(a, y_sign * a[..., ::-1, :], rtol=0, atol=1e-10 * max(scale, 1e-300))
    np.testing.assert_allclose(a, x_sign * a[..., ::-1], rtol=0, atol=1e-10 * max(scale, 1e-300))


def test_slot_across_the_depth_gives_the_quasi_2d_spot_density():
    data = slab_data()
    three, two = spotpde.load_case(data), spotpde.load_case(flat(data))
    rho3 = spot_density.steady(three.grid, three.orifice, three.spots)
    rho2 = spot_density.steady(two.grid, two.orifice, two.spots)
    depth = three.grid.y_range[1] - three.grid.y_range[0]
    scale = rho2.max()
    for j in range(three.grid.ny):
        np.testing.assert_allclose(depth * rho3[:, j, :], rho2, rtol=0, atol=1e-12 * scale)


@pytest.mark.parametrize("aspect", [1.0, 2.0])
def test_depth_integrated_drift_of_a_slab_is_the_2d_drift(aspect):
    """Free-volume-conserving walls, separable (Gaussian) kernel, midpoint rule, mean
    field: sum_y h u_p(3D) = u_p(2D) for u_x and u_z, with V1 the same number."""
    h, depth = 0.5, 4.0
    g3 = Grid(3, (-6.0, 6.0), (0.0, 12.0), h, y_range=(-0.5 * depth, 0.5 * depth))
    g2 = Grid(2, (-6.0, 6.0), (0.0, 12.0), h)
    Q0, spots = 30.0, Spots(b=1.3)
    rho3 = spot_density.steady(g3, Orifice(width=2.0, shape="slot", rate=Q0), spots)
    rho2 = spot_density.steady(g2, Orifice(width=2.0, rate=Q0), spots)
    k3 = kernels.Gaussian(sigma=1.0, volume=0.05, dims=3, aspect=aspect)
    k2 = kernels.Gaussian(sigma=1.0, volume=0.05, dims=2, aspect=aspect)
    f3 = coefficients.particle_fields(g3, rho3, spots, k3, rule=0.5, diffusivity="mean-field")
    f2 = coefficients.particle_fields(g2, rho2, spots, k2, rule=0.5, diffusivity="mean-field")
    for name in ("u_x", "u_z"):
        scale = np.abs(f2[name]).max()
        np.testing.assert_allclose(h * f3[name].sum(axis=1), f2[name], rtol=0,
                                   atol=1e-11 * scale)
    # the walls matter: the drift is not uniform across the depth, only its integral is
    u_z = f3["u_z"]
    assert np.abs(u_z[:, 0, :] - u_z[:, g3.ny // 2, :]).max() > 1e-3 * np.abs(u_z).max()


def test_single_precision_transforms_keep_the_fields_within_their_tolerance(monkeypatch):
    """Large 3D grids transform in float32 (convolution.precision_for): the fields then
    differ from the double-precision ones by about 1e-7 of the drift's or the tensor's
    largest component (far below the discretisation error), and D_p's round-off
    negatives are still cleared."""
    from spotpde.fields import convolution

    case = spotpde.load_case(slab_data(0.5))
    g = case.grid
    rho = spot_density.steady(g, case.orifice, case.spots)
    assert convolution.precision_for(g.shape) == "double"
    double = coefficients.particle_fields(g, rho, case.spots, case.kernel, rule=case.rule)
    monkeypatch.setattr(convolution, "SINGLE_PRECISION_CELLS", g.size)
    assert convolution.precision_for(g.shape) == "single"
    single = coefficients.particle_fields(g, rho, case.spots, case.kernel, rule=case.rule)
    # errors relative to the vector's or the tensor's largest component (u_y, a small
    # difference of passage terms, is a few 1e-4 of u_z)
    scales = {kind: max(np.abs(a).max() for n, a in double.items() if n[0] == kind)
              for kind in "uD"}
    for name, a in double.items():
        scale = scales[name[0]]
        err = np.abs(single[name] - a).max()
        assert single[name].dtype == np.float64
        assert err <= 2e-6 * scale, (name, err / max(scale, 1e-300))
        if name in ("D_xx", "D_yy", "D_zz"):
            assert single[name].min() >= 0.0
            assert err > 0.0        # the single-precision path was taken
