"""The Kinematic Model in a cylinder and ``spotpde compare`` on axisymmetric cases.

The Fourier-Bessel series (spotpde/density/_bessel.py) against the unbounded closed form
``exp(-r**2 / (4 b z)) / (4 pi b z)`` where the wall is far, its flux through every
height, its fit to the numerical solution; then the comparison of the spot model's mean
flow with the kinematic one in a cylinder and in hoppers (the local identities of
tests/test_comparison.py hold there too, in a hopper on the cells whose kernel sees only
material) and its command line.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate

from spotpde.analysis import comparison
from spotpde import cli
from spotpde.density import kinematic
from spotpde.fields import kernels
from spotpde.grid import Grid, Hopper
from spotpde.app.cases import load_case
from spotpde.parameters import Orifice, Spots

B, HEIGHT = 1.3, 0.0024
POINT, DISK = Orifice(x=0.0, width=0.0), Orifice(x=0.0, width=3.0)


def _series_is_used(a, s, width=0.0):
    """The series (not the free-space switch): the wall is nearer than sqrt(80 var)."""
    return (a - width / 2) ** 2 <= 80.0 * 2.0 * s


@pytest.mark.parametrize("s", [0.2, 0.5])
def test_bessel_series_is_the_unbounded_solution_where_the_wall_is_far(s):
    a = 5.0
    assert _series_is_used(a, s)
    r = np.linspace(0.0, 2.0, 21)
    free = np.exp(-r**2 / (4 * s)) / (4 * np.pi * s)
    series = kinematic.cylinder_profile(r, s, POINT, (0.0, a))
    # the wall's reflection is of order exp(-(2a - r)**2 / 4s) < 1e-13 of the peak
    np.testing.assert_allclose(series, free, rtol=1e-9, atol=1e-12 * free[0])
    assert np.array_equal(kinematic.cylinder_profile(r, s, POINT, (0.0, a), "open"), free)
    # a disk: the same against its free-space form (a non-central chi-squared)
    disk = kinematic.cylinder_profile(r, s, DISK, (0.0, 7.0))
    assert _series_is_used(7.0, s, 3.0)
    np.testing.assert_allclose(disk, kinematic.cylinder_profile(r, s, DISK, None),
                               rtol=1e-9, atol=1e-12 * disk[0])


@pytest.mark.parametrize("orifice", [POINT, DISK, Orifice(x=0.0, width=2.0, profile="gaussian")])
@pytest.mark.parametrize("s", [0.3, 4.0, 40.0])
def test_bessel_series_carries_the_orifice_flux_through_every_height(orifice, s):
    a = 5.0

    def flux(lo, hi):
        return integrate.quad(lambda r: 2 * np.pi * r * kinematic.cylinder_profile(
            r, s, orifice, (0.0, a)), lo, hi, limit=400, epsabs=1e-13, epsrel=1e-11)[0]

    assert flux(0.0, 1.5) + flux(1.5, a) == pytest.approx(1.0, abs=1e-9)
    # the wall is a no-flux wall: dv/dr = 0 at r = a
    h = 1e-4
    v = kinematic.cylinder_profile(np.array([a - 2 * h, a - h, a, 0.0]), s, orifice, (0.0, a))
    assert abs(3 * v[2] - 4 * v[1] + v[0]) / (2 * h) < 1e-6 * v[3] / a
    # late: uniform over the cross-section
    assert kinematic.cylinder_profile(np.array([0.0, a]), 1e4, orifice, (0.0, a)) == \
        pytest.approx(1.0 / (np.pi * a * a), rel=1e-12)


def test_bessel_series_is_the_numerical_kinematic_solution():
    """kinematic.speed on an axisymmetric grid (ring averages, unit flux through every
    height) against the series at the ring centres: O(h**2), and fitting the series to
    it recovers b."""
    a, b = 8.0, B
    errors = []
    for h in (0.5, 0.25):
        grid = Grid(2, (0.0, a), (0.0, 24.0), h, coordinates="axisymmetric")
        v = kinematic.speed(grid, DISK, b)
        flux = (v * grid.geometry.horizontal_measures).sum(axis=1)
        np.testing.assert_allclose(flux, 1.0, rtol=1e-10)
        k = int(np.argmin(np.abs(grid.z - 16.0)))
        exact = kinematic.cylinder_profile(grid.x, b * grid.z[k], DISK, (0.0, a))
        errors.append(np.max(np.abs(v[k] - exact)) / exact.max())
        s, A = kinematic.fit_radial_profile(grid.x, v[k], DISK, (0.0, a))
        assert s / grid.z[k] == pytest.approx(b, rel=2e-2) and A == pytest.approx(1.0, rel=1e-2)
    assert errors[1] < errors[0] / 3          # second order


@pytest.fixture(scope="module")
def results():
    grid = Grid(2, (0.0, 20.0), (0.0, 30.0), 0.5, coordinates="axisymmetric")
    parts = dict(grid=grid, orifice=Orifice(x=0.0, width=0.0, rate=2.0),
                 spots=Spots(drift=1.5, b=B),
                 kernel=kernels.Uniform(radius=2.5, height=HEIGHT, dims=3))
    return comparison.compare_rules(parts, (0.5, 1.0), n_streamlines=5)


@pytest.mark.parametrize("rule", [0.5, 1.0])
def test_cylinder_comparison_has_the_local_identities(results, rule):
    """In a cylinder as in a box: the downward speeds agree for every rule, the radial
    flux velocity is (2 lam - V2/V1) b dv/dr, the Bessel fits of the kinematic speed read
    its b, and the flux through every height is the orifice's."""
    c = results[rule]
    assert c.horizontal == "r" and c.V2 / c.V1 == pytest.approx(HEIGHT, rel=1e-12)
    # measured: within 0.5 % (rule 1/2) and 0.6 % (rule 1) at h = d/2
    np.testing.assert_allclose(c.b_horizontal, B * (2 * rule - HEIGHT), rtol=1e-2)
    assert np.median(c.b_speed_kin) == pytest.approx(B, rel=2e-3)
    assert np.max(np.abs(c.flux_deficit)) < 1e-4
    assert np.max(c.speed_l2) < 0.07 and np.median(c.speed_l2) < 0.03
    # the kinematic rule's flow is (nearly) incompressible, the end-point rule's is not
    if rule == 0.5:
        assert np.median(c.defect) < 0.05 and np.median(c.horizontal_l2) < 0.05
    else:
        assert np.median(c.defect) > 0.9 and np.median(c.horizontal_l2) > 0.9
    assert c.streamline_shift.size == 5


CYLINDER = ('[domain]\ncoordinates = "axisymmetric"\nx = [0.0, 12.0]\nz = [0.0, 16.0]\n'
            'spacing = 0.5\n[orifice]\nx = 0.0\nwidth = 2.0\n'
            '[kernel]\nshape = "uniform"\nsize = 2.5\nheight = 0.0024\n')


def test_compare_command_line_on_a_cylinder(tmp_path, capsys):
    case = tmp_path / "cyl.toml"
    case.write_text(CYLINDER)
    fig = tmp_path / "cmp.png"
    assert cli.main(["compare", str(case), "--rules", "0.5", "-o", str(fig)]) == 0
    out = capsys.readouterr()
    lines = out.out.splitlines()
    assert len(lines) == 1 and lines[0].startswith("rule=0.5 b=1.3 "), out
    summary = dict(item.split("=") for item in lines[0].split())
    assert abs(float(summary["b_horizontal/b"]) - (1 - HEIGHT)) < 2e-2
    assert abs(float(summary["flux_deficit"])) < 1e-3
    assert fig.stat().st_size > 1000
    # the figure's axes carry their units (d); the radius is r
    comparisons = comparison.compare_rules(load_case(str(case)), [0.5], n_streamlines=2)
    f = comparison.plot_comparison(comparisons)
    assert [a.get_xlabel() for a in f.axes] == ["z (d)", "z (d)", "r (d)"]
    assert f.axes[2].get_ylabel() == "z (d)" and f.axes[1].get_ylabel() == "effective b (d)"


@pytest.mark.parametrize("axisymmetric", [False, True], ids=["wedge", "cone"])
def test_hopper_comparison_in_the_material_away_from_the_walls(axisymmetric):
    """In a hopper the numerical kinematic solution with the wall mask is compared on the
    cells whose kernel sees only material: the rules' local identities hold there
    (medians), the widths have no closed form (NaN), the streamlines start inside."""
    x = (0.0, 20.0) if axisymmetric else (-20.0, 20.0)
    grid = Grid(2, x, (0.0, 30.0), 0.5, coordinates="axisymmetric" if axisymmetric
                else "cartesian", hopper=Hopper(angle=30.0, centre=0.0, half_width=2.0))
    kernel = kernels.Uniform(radius=2.5, height=HEIGHT, dims=3 if axisymmetric else 2)
    parts = dict(grid=grid, orifice=Orifice(x=0.0, width=4.0, rate=2.0),
                 spots=Spots(drift=1.5, b=B), kernel=kernel)
    res = comparison.compare_rules(parts, (0.5, 1.0), n_streamlines=5)
    for rule, c in res.items():
        # measured medians: 1.0072 (wedge), 1.0056 (cone) and 2.0169, 2.0135 of b
        assert np.median(c.b_horizontal) / B == pytest.approx(2 * rule - HEIGHT, rel=2e-2)
        assert np.all(np.isnan(c.b_speed_kin)) and np.all(np.isnan(c.width2_spot))
        assert np.median(c.speed_l2) < 0.03 and abs(np.median(c.flux_deficit)) < 5e-3
        assert np.all(grid.geometry.clearance(c.starts[:, 0], c.starts[:, -1]) > 0)
    assert np.median(res[0.5].defect) < 0.03 and np.median(res[1.0].defect) > 0.9
    assert res[1.0].streamline_shift.max() > 10 * res[0.5].streamline_shift.max()


def test_compare_command_line_on_a_hopper(tmp_path, capsys):
    case = tmp_path / "cone.toml"
    case.write_text(CYLINDER.replace("spacing = 0.5", "spacing = 0.5\nhopper_angle = 30.0")
                    .replace("width = 2.0", "width = 4.0").replace("z = [0.0, 16.0]",
                                                                  "z = [0.0, 24.0]"))
    assert cli.main(["compare", str(case), "--rules", "0.5"]) == 0
    summary = dict(item.split("=") for item in capsys.readouterr().out.split())
    assert summary["b_speed_kin"] == "nan" and abs(float(summary["b_horizontal/b"]) - 1) < 3e-2
    # too narrow a hopper for the kernel: refused by name
    narrow = tmp_path / "narrow.toml"
    narrow.write_text(case.read_text().replace("hopper_angle = 30.0", "hopper_angle = 5.0"))
    assert cli.main(["compare", str(narrow)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("domain.hopper_angle: the hopper is too narrow")
