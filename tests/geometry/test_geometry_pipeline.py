"""Cylinders and hoppers through the whole pipeline: case -> Dataset -> netCDF -> figure.

The stages are checked against closed forms and 3D Cartesian runs in their own test
files (test_axisymmetric_*.py, test_hopper_*.py); here: the result's names, dims and
units, NaN outside a hopper, the conservation laws seen in the result, the netCDF round
trip and the mirrored figure of the command line.
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

import spotpde
from spotpde.app import pipeline
from spotpde.app.plotting import mirror_section

CYLINDER = {
    "domain": {"coordinates": "axisymmetric", "x": [0.0, 8.0], "z": [0.0, 16.0],
               "spacing": 0.5, "hopper_angle": 30.0},
    "orifice": {"x": 0.0, "width": 2.0, "rate": 50.0},
    "kernel": {"shape": "gaussian", "size": 1.0, "volume": 0.1},
    "tracer": {"layers": {"spacing": 4.0}, "t_end": 40.0, "frames": 3},
}
WEDGE = {
    "domain": {"x": [-8.0, 8.0], "z": [0.0, 16.0], "spacing": 0.5, "hopper_angle": 30.0},
    "orifice": {"width": 2.0, "rate": 20.0},
    "kernel": {"shape": "gaussian", "size": 1.0, "volume": 0.05},
    "tracer": {"start": {"x": 1.0, "z": 10.0, "width": 1.0}, "t_end": 40.0, "frames": 3},
}


@pytest.fixture(scope="module")
def cylinder():
    case = spotpde.load_case(CYLINDER)
    return case, spotpde.run(case)


@pytest.fixture(scope="module")
def wedge():
    case = spotpde.load_case(WEDGE)
    return case, spotpde.run(case)


def test_axisymmetric_result_has_cylindrical_names_and_3d_units(cylinder):
    case, ds = cylinder
    assert ds.rho_s.dims == ("z", "r") and ds.P.dims == ("t", "z", "r")
    for name in ("u_r", "u_z", "D_rr", "D_rz", "D_zz", "P_height", "v_kin"):
        assert ds[name].dims == ("z", "r"), name
    for name in ("u_x", "D_xx", "x"):
        assert name not in ds, name
    assert ds.rho_s.attrs["spotpde_units"] == "d-3"
    assert ds.P.attrs["spotpde_units"] == "d-3"
    assert ds.P_height.attrs["spotpde_units"] == "d-2"
    assert ds.attrs["coordinate_system"] == "axisymmetric" and ds.attrs["hopper_angle"] == 30.0
    assert np.array_equal(ds.r.values, case.grid.r)


def test_nan_exactly_outside_the_hopper(cylinder, wedge):
    for case, ds in (cylinder, wedge):
        outside = ~case.grid.active
        assert outside.any() and case.grid.active.any()
        for name in ("rho_s", "v_kin", "u_z", "P_height"):
            a = ds[name].values
            assert np.all(np.isnan(a[outside])), name
            assert np.all(np.isfinite(a[~outside])), name
        assert np.all(np.isnan(ds.P.values[:, outside]))


def test_conservation_seen_in_the_result(cylinder, wedge):
    for case, ds in (cylinder, wedge):
        g = case.grid
        # spot flux Q0 through every height (ring areas when axisymmetric)
        flux = (np.nan_to_num(ds.rho_s.values) * g.horizontal_measures).sum(axis=1)
        assert np.allclose(flux * float(case.spots.drift), case.orifice.rate_at(0.0),
                           rtol=1e-10)
        # Kinematic Model: V1 Q0 through every height
        kin = (np.nan_to_num(ds.v_kin.values) * g.horizontal_measures).sum(axis=1)
        assert np.allclose(kin, ds.attrs["V1"] * case.orifice.rate_at(0.0), rtol=1e-10)
        # tracer: what is inside plus what left is 1; the initial frame is normalised
        assert np.allclose(ds.mass + ds.outflow, 1.0, atol=1e-10)
        P0 = np.nan_to_num(ds.P.isel(t=0).values)
        assert float((P0 * g.cell_volumes).sum()) == pytest.approx(1.0, abs=1e-12)
        assert float(ds.outflow[-1]) > 0.0     # the tracer drains through the orifice


def test_initial_density_is_zero_outside_and_normalised_on_rings():
    case = spotpde.load_case(CYLINDER)
    g = case.grid
    P0 = pipeline.initial_density(g, case.tracer.start)
    assert np.all(P0[~g.active] == 0.0)
    assert float((P0 * g.cell_volumes).sum()) == pytest.approx(1.0, abs=1e-13)
    # a blob on the axis is a 3D Gaussian: its mean r^2 is 2 sigma^2 (a disk's two
    # components) when the cylinder is wide and the blob far from the walls
    data = {**CYLINDER, "domain": {**CYLINDER["domain"], "x": [0.0, 12.0], "spacing": 0.25}}
    data.pop("tracer")
    g = spotpde.load_case(data).grid
    from spotpde.parameters import TracerStart
    P = pipeline.initial_density(g, TracerStart(kind="blob", x=0.0, z=12.0, width=1.0))
    Z, R = g.mesh()
    r2 = float((P * g.cell_volumes * R**2).sum())
    assert r2 == pytest.approx(2.0, rel=0.02)


def test_mirrored_section_is_even_and_odd(cylinder):
    _, ds = cylinder
    m = mirror_section(ds)
    n = ds.sizes["r"]
    assert m.sizes["x"] == 2 * n
    assert np.array_equal(m.x.values, np.concatenate([-ds.r.values[::-1], ds.r.values]))
    left, right = m.isel(x=slice(None, n)), m.isel(x=slice(n, None))
    np.testing.assert_array_equal(left.rho_s.values[:, ::-1], right.rho_s.values)
    np.testing.assert_array_equal(left.u_x.values[:, ::-1], -right.u_x.values)
    np.testing.assert_array_equal(right.u_x.values, ds.u_r.values)
    np.testing.assert_array_equal(left.D_xx.values[:, ::-1], right.D_xx.values)


def test_command_line_runs_a_cylinder_and_draws_the_section(tmp_path):
    import tomli_w

    case_file = tmp_path / "cyl.toml"
    data = {**CYLINDER, "output": {"path": "cyl.nc"}}
    case_file.write_text(tomli_w.dumps(data))
    r = subprocess.run([sys.executable, "-m", "spotpde", "run", str(case_file), "--plot",
                        "-q"], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    ds = spotpde.io.read_netcdf(tmp_path / "cyl.nc")
    assert ds.rho_s.dims == ("z", "r")
    assert (tmp_path / "cyl.png").stat().st_size > 10_000
    r = subprocess.run([sys.executable, "-m", "spotpde", "plot", "cyl.nc", "-o", "again.png"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "again.png").stat().st_size > 10_000


def test_steady_propagator_in_a_cone(cylinder):
    """t_end = inf in a cone: exit probabilities sum to 1, P_height carries the tracer
    through every height below its release (the time-integrated flux of probability 1)."""
    data = {**CYLINDER, "tracer": {"start": {"x": 0.0, "z": 12.0, "width": 1.0},
                                   "t_end": math.inf}}
    case = spotpde.load_case(data)
    ds = spotpde.run(case)
    assert "P" not in ds and "residence" in ds
    exits = sum(v for k, v in ds.attrs.items() if k.startswith("exit_"))
    assert exits == pytest.approx(1.0, abs=1e-10)
    g = case.grid
    crossing = (np.nan_to_num(ds.P_height.values) * g.horizontal_measures).sum(axis=1)
    below = g.z < 8.0      # well below the blob: everything released crosses
    assert np.allclose(crossing[below], 1.0, atol=2e-3)
