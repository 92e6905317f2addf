"""The spot model's mean flow against the Kinematic Model (spotpde.comparison).

Local limit, constant coefficients, D_par = 0 (docs/coefficients.md):
  -u_f,z = v_kin for every rule; u_f,x = (2 lam - V2/V1) b d_x v;
  div u_f = (2 lam - 1 - V2/V1) b d_xx v, i.e. (2 lam - 1 - V2/V1) d_z v;
  point source: v ~ exp(-x^2 / 4bz), so streamlines dx/dz = u_x/u_z obey
  x ~ z^((2 lam - V2/V1) / 2): parabolas (x^2 ~ z) for the kinematic model, straight
  rays for the printed rule lam = 1.
For the uniform (disk) kernel these hold exactly away from the walls, since w^2 = height w.
"""

from __future__ import annotations

import numpy as np
import pytest

from spotpde import cli
from spotpde.analysis import comparison
from spotpde.fields import kernels
from spotpde.grid import Grid
from spotpde.parameters import Orifice, Spots

B, HEIGHT = 1.3, 0.0024


@pytest.fixture(scope="module")
def results():
    grid = Grid(2, (-40.0, 40.0), (0.0, 40.0), 0.5)
    parts = dict(grid=grid, orifice=Orifice(x=0.0, width=0.0, rate=2.0), spots=Spots(drift=1.5, b=B),
                 kernel=kernels.Uniform(radius=2.5, height=HEIGHT, dims=2))
    return comparison.compare_rules(parts, (0.5, 1.0), n_streamlines=5)


@pytest.mark.parametrize("rule", [0.5, 1.0])
def test_horizontal_flow_has_b_times_2lam_minus_V2_over_V1(results, rule):
    c = results[rule]
    assert c.V2 / c.V1 == pytest.approx(HEIGHT, rel=1e-12)
    np.testing.assert_allclose(c.b_horizontal, B * (2 * rule - HEIGHT), rtol=2e-4)


@pytest.mark.parametrize("rule", [0.5, 1.0])
def test_downward_speed_follows_kinematic_b_for_every_rule(results, rule):
    c = results[rule]
    np.testing.assert_allclose(c.b_speed_kin, B, rtol=1e-4)  # walls 40 d away: images
    # the disk smooths the profile; its Gaussian fit approaches b once s^2 = 2bz >> R^2
    high = c.z > 20
    np.testing.assert_allclose(c.b_speed_spot[high], B, rtol=5e-3)
    assert np.all(np.diff(c.b_speed_spot) < 0) and np.all(c.b_speed_spot > B)
    assert np.all(c.speed_l2[high] < 0.02)
    assert np.all(np.abs(c.flux_deficit) < 1e-3)
    np.testing.assert_array_equal(c.speed_l2, results[0.5].speed_l2)  # D_par = 0: rule-free


def test_only_the_midpoint_rule_keeps_the_flow_incompressible(results):
    half, one = results[0.5], results[1.0]
    # relative defect (2 lam - 1 - V2/V1): 0.0024 and 0.9976, plus O(h^2) grid error
    assert np.median(half.defect) < 0.05
    assert np.median(one.defect) == pytest.approx(1.0 - HEIGHT, rel=0.03)
    assert np.all(one.defect > 20 * half.defect)
    assert np.median(half.horizontal_l2) < 0.05
    assert np.median(one.horizontal_l2) == pytest.approx(1.0, abs=0.08)


@pytest.mark.parametrize("rule", [0.5, 1.0])
def test_streamline_exponent(results, rule):
    """x ~ z^p with p = (2 lam - V2/V1)/2 for the spot flow, p = 1/2 for the kinematic one.

    The disk adds the variance R^2/4 to the spot profiles, which shifts the spot flow's
    origin: x ~ (z + z_k)^p with z_k = R^2 / (8 b).
    """
    c = results[rule]
    z_k = 2.5**2 / (8 * B)
    for kind, paths, p_expect, shift in (
            ("spot", c.streamlines_spot, (2 * rule - HEIGHT) / 2, z_k),
            ("kinematic", c.streamlines_kin, 0.5, 0.0)):
        for path in paths:
            x, z = path[:, 0], path[:, -1]
            keep = (z > 8.0) & (z < 34.0) & (np.abs(x) > 1.0)
            if keep.sum() < 5:
                continue  # the central streamline, x = 0
            p = np.polyfit(np.log(z[keep] + shift), np.log(np.abs(x[keep])), 1)[0]
            assert p == pytest.approx(p_expect, abs=0.005), (kind, rule, p)
    if rule == 1.0:
        assert np.nanmax(c.streamline_shift) > 2.0
    else:
        assert np.nanmax(c.streamline_shift) < 0.3


def test_compare_with_kinematic_rejects_bad_input():
    grid = Grid(2, (-10.0, 10.0), (0.0, 10.0), 0.5)
    with pytest.raises(ValueError, match="grid, orifice, spots, kernel"):
        comparison.compare_with_kinematic({"grid": grid})
    parts = dict(grid=grid, orifice=Orifice(), kernel=kernels.Uniform(radius=1.0, height=0.01, dims=2),
                 spots=Spots(b=np.full(grid.shape, 1.3)))
    with pytest.raises(ValueError, match="uniform"):
        comparison.compare_with_kinematic(parts)


def test_command_line_prints_summary_and_writes_figure(tmp_path, capsys):
    """``spotpde compare``: the one command line of the comparison."""
    def entry(argv):
        return cli.main(["compare", *argv])

    case = tmp_path / "c.toml"
    case.write_text('[domain]\nx = [-20.0, 20.0]\nz = [0.0, 20.0]\nspacing = 0.5\n'
                    '[kernel]\nshape = "uniform"\nsize = 2.5\nvolume = 0.0471238898038469\n')
    fig = tmp_path / "cmp.png"
    assert entry([str(case), "--rules", "0.5", "1", "-o", str(fig)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 2 and out[0].startswith("rule=0.5") and out[1].startswith("rule=1")
    assert fig.stat().st_size > 1000
    assert entry([str(tmp_path / "missing.toml")]) == 2
    # a rule outside kernel.rule's range (0, 1]: status 2, one line naming --rules, no figure
    capsys.readouterr()
    bad = tmp_path / "bad.png"
    assert entry([str(case), "--rules", "2", "-o", str(bad)]) == 2
    err = capsys.readouterr()
    assert err.out == "" and err.err.startswith("--rules:") and not bad.exists()
