"""The run pipeline: stage wiring (with stand-in solvers), initial tracer densities,
and the real pipeline end to end on tiny cases."""

from __future__ import annotations

import math
import sys
import tomllib
import types

import numpy as np
import pytest

import spotpde
from spotpde.app import pipeline
from spotpde.app.cases import load_case
from spotpde.grid import Grid
from spotpde.parameters import TracerStart


def small(**tables):
    data = {
        "domain": {"dims": 2, "x": [-4.0, 4.0], "z": [0.0, 8.0], "spacing": 0.5},
        "orifice": {"x": 0.0, "width": 2.0, "rate": 10.0},
        "spots": {"b": 1.3},
        "kernel": {"shape": "gaussian", "size": 1.0, "volume": 0.05, "rule": 0.5},
        "tracer": {"start": {"x": 0.0, "z": 5.0, "width": 1.0}, "t_end": 2.0, "frames": 4},
    }
    for name, body in tables.items():
        if body is None:
            data.pop(name, None)
        else:
            data.setdefault(name, {}).update(body)
    return data


# -- stand-in solvers -------------------------------------------------------------------

class Calls(list):
    pass


@pytest.fixture
def fakes(monkeypatch):
    """Replace the solver modules by simple stand-ins recording their calls."""
    calls = Calls()

    def unit(grid, orifice, b):
        Z, X = grid.mesh()[0], grid.mesh()[-1]
        v = np.exp(-(X - orifice.x) ** 2 / (4 * b * (Z + 1.0))) + 0 * Z
        return np.broadcast_to(v, grid.shape) / (v.sum(axis=-1, keepdims=True) * grid.spacing)

    def unit_speed(grid, orifice, b):
        calls.append(("kinematic.speed", b))
        return unit(grid, orifice, b)

    def solve_rho(grid, orifice, spots, progress=None):
        calls.append(("spot_density.solve", spots.mode))
        for f in (0.0, 0.5, 1.0):
            if progress:
                progress(f)
        return unit(grid, orifice, spots.b) * orifice.rate / spots.drift

    def fields(grid, rho_s, V1, V2):
        out = {"u_x": 0.1 * rho_s, "u_z": -V1 * rho_s, "D_xx": V2 * rho_s,
               "D_xz": 0 * rho_s, "D_zz": 0 * rho_s}
        if grid.dims == 3:
            out.update(u_y=0 * rho_s, D_yy=V2 * rho_s, D_xy=0 * rho_s, D_yz=0 * rho_s)
        return out

    def particle_fields(grid, rho_s, spots, kernel, rule=0.5, **options):
        assert set(options) <= {"walls", "diffusivity"}  # kernel.walls, kernel.diffusivity
        calls.append(("coefficients.particle_fields", rule))
        return fields(grid, rho_s, kernel.V1, kernel.V2)

    def void_fields(grid, rho_s, spots, V1):
        calls.append(("void.void_fields", V1))
        return fields(grid, rho_s, V1, V1)

    def tracer_solve(grid, flds, P0, t_end, frames, progress=None, on_frame=None, **options):
        calls.append(("tracer.solve", t_end, frames, float(P0.sum() * grid.cell_volume),
                      options))
        times = np.linspace(0.0, t_end, frames)
        decay = np.exp(-0.1 * times)
        if progress:
            progress(1.0)
        P = np.stack([P0 * d for d in decay])
        if on_frame is not None:
            for j, frame in enumerate(P):
                on_frame(j, times[j], frame)
            P = None
        return types.SimpleNamespace(times=times, P=P, mass=decay, outflow=1 - decay,
                                     P_height=np.full(grid.shape, 0.5))

    mods = {
        "spotpde.density.spot_density": types.SimpleNamespace(solve=solve_rho),
        "spotpde.fields.coefficients": types.SimpleNamespace(particle_fields=particle_fields,
                                                             release_caches=lambda: None),
        "spotpde.density.kinematic": types.SimpleNamespace(speed=unit_speed),
        "spotpde.tracer": types.SimpleNamespace(solve=tracer_solve),
        "spotpde.fields.void": types.SimpleNamespace(void_fields=void_fields),
    }
    for name, mod in mods.items():
        monkeypatch.setitem(sys.modules, name, mod)
    return calls


@pytest.mark.parametrize("dims", [2, 3])
def test_run_builds_the_contract_dataset(fakes, dims):
    case = load_case(small(domain={"dims": dims}))
    ds = spotpde.run(case)
    grid = case.grid
    horizontal = ["u_x", "D_xx", "D_xz"] + (["u_y", "D_yy", "D_xy", "D_yz"] if dims == 3
                                             else [])
    for name in ["rho_s", "v_kin", "u_z", "D_zz", "P_height", *horizontal]:
        assert ds[name].dims == grid.axes, name
    assert ds.P.dims == ("t", *grid.axes)
    assert ds.mass.dims == ds.outflow.dims == ("t",)
    assert ds.sizes["t"] == 4
    for name in list(ds.data_vars) + list(ds.coords):
        assert ds[name].attrs["units"] and ds[name].attrs["long_name"]
    assert ds.attrs["V1"] == pytest.approx(case.kernel.V1)
    assert ds.attrs["V2"] == pytest.approx(case.kernel.V2)
    assert ds.attrs["rule"] == 0.5
    assert ds.attrs["spotpde_version"] == spotpde.__version__
    assert load_case(tomllib.loads(ds.attrs["case"])).data == case.data
    names = [c[0] for c in fakes]
    # uniform b, b_par = 0: v_kin is v_s rho_s scaled, no second solve (kinematic.speed)
    assert names == ["spot_density.solve", "coefficients.particle_fields", "tracer.solve"]
    assert fakes[-1][1:3] == (2.0, 4)
    assert fakes[-1][3] == pytest.approx(1.0)       # P0 normalised
    assert fakes[-1][4] == {"limiter": "weno5", "cfl": 0.9, "diffusion": "auto",
                            "stepping": "explicit", "tol": 1e-5}


def test_v_kin_carries_the_flux_V1_Q0(fakes):
    case = load_case(small(tracer=None))
    ds = spotpde.run(case)
    assert "P" not in ds and "t" not in ds.dims
    flux = ds.v_kin.sum("x") * case.grid.spacing
    np.testing.assert_allclose(flux, case.kernel.V1 * 10.0, rtol=1e-12)


def test_void_model_uses_the_void_fields(fakes):
    case = load_case(small(tracer={"model": "void"}))
    ds = spotpde.run(case)
    assert ("void.void_fields", pytest.approx(case.kernel.V1)) in fakes
    assert not any(c[0] == "coefficients.particle_fields" for c in fakes)
    assert ds.attrs["rule"] == 1.0 and ds.attrs["model"] == "void"
    assert ds.attrs["V2"] == ds.attrs["V1"]


def test_progress_reports_each_stage_in_order(fakes):
    seen = []
    spotpde.run(load_case(small()), progress=lambda s, f: seen.append((s, f)))
    stages = list(dict.fromkeys(s for s, _ in seen))
    assert stages == list(pipeline.STAGES)
    assert all(0.0 <= f <= 1.0 for _, f in seen)
    assert ("tracer", 1.0) in seen


def test_nan_from_a_solver_is_a_numerical_error(fakes, monkeypatch):
    def bad(grid, orifice, spots, progress=None):
        out = np.ones(grid.shape)
        out[2, 3] = np.nan
        return out

    monkeypatch.setattr(sys.modules["spotpde.density.spot_density"], "solve", bad)
    with pytest.raises(spotpde.NumericalError, match="rho_s: 1 values are NaN"):
        spotpde.run(load_case(small()))


def test_run_accepts_a_mapping(fakes):
    assert "rho_s" in spotpde.run(small(tracer=None))


# -- initial tracer densities ---------------------------------------------------------

@pytest.mark.parametrize("dims", [2, 3])
def test_blob_is_normalised_and_centred(dims):
    grid = Grid(dims=dims, x_range=(-5.0, 5.0), z_range=(0.0, 10.0), spacing=0.25)
    P = pipeline.initial_density(grid, TracerStart(kind="blob", x=1.0, z=6.0, width=1.0))
    assert P.sum() * grid.cell_volume == pytest.approx(1.0)
    assert P.min() >= 0
    Z, X = grid.mesh()[0], grid.mesh()[-1]
    w = P * grid.cell_volume
    assert (w * X).sum() == pytest.approx(1.0, abs=1e-3)
    assert (w * Z).sum() == pytest.approx(6.0, abs=1e-3)
    assert (w * (X - 1.0) ** 2).sum() == pytest.approx(1.0, rel=1e-2)


def test_layers_fill_the_lower_half_of_every_band():
    grid = Grid(dims=2, x_range=(-2.0, 2.0), z_range=(0.0, 12.0), spacing=0.5)
    P = pipeline.initial_density(grid, TracerStart(kind="layers", spacing=4.0))
    assert P.sum() * grid.cell_volume == pytest.approx(1.0)
    on = P[:, 0] > 0
    expected = np.mod(grid.z, 4.0) < 2.0
    np.testing.assert_array_equal(on, expected)
    assert np.ptp(P[on]) == 0.0                    # uniform on the bands
    assert np.all(P == P[:, :1])                   # uniform in x


# -- the real pipeline ----------------------------------------------------------------

def test_real_pipeline_on_a_tiny_layered_case():
    case = load_case(small(domain={"x": [-4.0, 4.0], "z": [0.0, 8.0], "spacing": 0.5},
                           tracer={"start": None, "layers": {"spacing": 2.0},
                                   "t_end": 1.0, "frames": 2}))
    ds = spotpde.run(case)
    grid = case.grid
    assert ds.rho_s.shape == grid.shape and float(ds.rho_s.min()) >= 0
    # spot flux through every height equals Q0 (steady state, reflecting walls)
    flux = (ds.rho_s.sum("x") * grid.spacing * case.spots.drift).values
    np.testing.assert_allclose(flux, 10.0, rtol=1e-12)
    # kinematic flux V1 Q0 and particles falling on average
    v_flux = ds.v_kin.sum("x").values * grid.spacing
    np.testing.assert_allclose(v_flux, case.kernel.V1 * 10.0, rtol=1e-6)
    assert float(ds.u_z.mean()) < 0
    budget = (ds.mass + ds.outflow).values
    np.testing.assert_allclose(budget, 1.0, atol=1e-6)
    assert float(ds.P.min()) >= -1e-12


def test_real_pipeline_void_model_3d():
    case = load_case(small(domain={"dims": 3, "x": [-2.0, 2.0], "z": [0.0, 4.0]},
                           tracer={"model": "void",
                                   "start": {"x": 0.0, "z": 3.0, "width": 1.0},
                                   "t_end": 0.5, "frames": 2}))
    ds = spotpde.run(case)
    assert ds.P.dims == ("t", "z", "y", "x")
    assert ds.attrs["V1"] == ds.attrs["V2"] == pytest.approx(case.kernel.V1)
    assert math.isfinite(float(ds.P.sum()))


def test_roundoff_negatives_of_rho_s_are_cleared_and_solver_refusals_are_numerical(
        fakes, monkeypatch):
    solve = sys.modules["spotpde.density.spot_density"].solve

    def noisy(grid, orifice, spots, progress=None):
        rho = solve(grid, orifice, spots, progress)
        rho[0, 0] = -1e-16
        rho[1, 0] = -0.5 * rho.max()
        return rho

    monkeypatch.setattr(sys.modules["spotpde.density.spot_density"], "solve", noisy)
    ds = spotpde.run(load_case(small(tracer=None)))
    assert float(ds.rho_s[0, 0]) == 0.0
    assert float(ds.rho_s[1, 0]) < 0          # a real negative is not hidden

    def refuse(*args, **kwargs):
        raise spotpde.CaseError(["fields.D_xx: must be >= 0, min -0.1"])

    monkeypatch.setattr(sys.modules["spotpde.tracer"], "solve", refuse)
    with pytest.raises(spotpde.NumericalError, match="fields.D_xx: must be >= 0"):
        spotpde.run(load_case(small()))


def test_tracer_options_match_the_tracer_solver():
    from spotpde.tracer import _advection
    from spotpde.app import cases
    from spotpde import tracer

    assert set(cases.LIMITERS) == set(_advection.LIMITERS)
    assert set(cases.DIFFUSION_MODES) == set(tracer.DIFFUSION_MODES)
    assert set(cases.STEPPING_MODES) == set(tracer.STEPPING_MODES)
    case = load_case(small(tracer={"limiter": "upwind", "cfl": 0.5, "diffusion": "implicit"}))
    assert case.tracer_options == {"limiter": "upwind", "cfl": 0.5, "diffusion": "implicit",
                                   "stepping": "explicit", "tol": 1e-5}
    case = load_case(small(tracer={"stepping": "multirate", "split": 8.0}))
    assert case.tracer_options["stepping"] == "multirate" and case.tracer_options["split"] == 8.0


def test_real_pipeline_with_spot_coefficient_profiles():
    case = load_case(small(spots={"drift": {"x": [-4.0, 0.0, 4.0], "values": [0.5, 1.0, 0.5]},
                                  "b": {"z": [0.0, 8.0], "values": [1.0, 2.0]}},
                           tracer=None))
    ds = spotpde.run(case)
    grid = case.grid
    flux = (ds.rho_s * case.spots.drift).sum("x").values * grid.spacing
    np.testing.assert_allclose(flux, 10.0, rtol=1e-12)     # v_s rho_s carries Q0
    assert ds.attrs["case"].count("values") == 2
