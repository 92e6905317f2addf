"""spotpde.fit and ``spotpde fit``: parameter recovery from the discrete spot model's own
tracks (written as trackpy would, in pixels with image rows), the jackknife errors, the
report, and the command line's exit statuses."""

from __future__ import annotations

import copy
import subprocess
import sys

import numpy as np
import pytest
import tomli_w

import spotpde
from spotpde import montecarlo as mc, tracks as T

TRUTH = {"domain": {"dims": 2, "x": [-8.0, 8.0], "z": [0.0, 24.0], "spacing": 0.5},
         "orifice": {"x": 0.0, "width": 3.0, "rate": 16.0}, "spots": {"b": 1.3},
         "kernel": {"shape": "gaussian", "size": 1.0, "volume": 0.05, "rule": 1.0}}
SCALE, FPS, ORIGIN = 12.5, 2.0, (300.0, 640.0)     # pixels per d, frames per time unit


def monte_carlo_tracks(seed, t_end=500.0):
    """Tracks of the discrete model at TRUTH, below 12 d (the silo stays full there),
    after the spots' first transit (the flow is steady)."""
    case = spotpde.load_case(TRUTH)
    r = mc.from_case(case, particles="lattice", spacing=1.0, tracked="all",
                     records=int(t_end), t_end=t_end, seed=seed, probes=False)
    tr = T.read(r).sel(t=slice(30, None))
    tr = tr.assign_coords(t=np.round(tr["t"].values * FPS) / FPS)
    return tr.where(tr["z"] < 12.0)


@pytest.fixture(scope="module")
def pixel_file(tmp_path_factory):
    """A trackpy CSV in pixels, image rows down, of a Monte Carlo run."""
    df = T.to_trackpy(monte_carlo_tracks(seed=11), scale=SCALE, fps=FPS, origin=ORIGIN,
                      y_down=True)
    path = tmp_path_factory.mktemp("tracks") / "mc_tracks.csv"
    df.to_csv(path, index=False)
    return path


def start_case(volume=0.05):
    """The fit's start: b and the rate off the truth (the volume as given)."""
    raw = copy.deepcopy(TRUTH)
    raw["spots"]["b"] = 2.2
    raw["orifice"]["rate"] = 11.0
    raw["kernel"]["volume"] = volume
    return raw


@pytest.mark.slow
def test_fit_recovers_the_mean_flow_of_the_discrete_model_within_its_errors(pixel_file):
    tracks = T.read(pixel_file, scale=SCALE, fps=FPS, origin=ORIGIN, y_down=True)
    fit = spotpde.fit(start_case(), tracks, {"spots.b": (0.3, 5.0), "orifice.rate": (4.0, 60.0)},
                      observables=["velocity"])
    truth = {"spots.b": 1.3, "orifice.rate": 16.0}
    for key, value, se in zip(fit["parameter"].values, fit["value"].values, fit["stderr"].values):
        assert abs(value - truth[key]) < 4 * se, (key, value, se)
        assert se < 0.1 * truth[key]                     # the errors say something
    # the naive errors (every cell independent) are not the reported ones
    assert np.all(fit["stderr"].values != fit["stderr_naive"].values)
    assert fit.attrs["success"] == 1 and fit.attrs["not_reproduced"] == "", fit.attrs["report"]
    for name in ("data_u_z", "data_u_z_se", "model_u_z", "residual_u_z"):
        assert name in fit


@pytest.mark.slow
def test_fit_recovers_the_kernel_volume_from_diffusion_in_uniform_flow(tmp_path):
    """Uniform flow (the orifice spans the floor): the flux fixes V1 Q0 and the diffusion
    length b V2/V1 fixes the Gaussian kernel's volume; both are recovered."""
    raw = {"domain": {"dims": 2, "x": [-8.0, 8.0], "z": [0.0, 16.0], "spacing": 0.5},
           "orifice": {"x": 0.0, "width": 16.0, "rate": 64.0}, "spots": {"b": 1.3},
           "kernel": {"shape": "gaussian", "size": 1.0, "volume": 0.01, "rule": 1.0}}
    r = mc.from_case(spotpde.load_case(raw), particles="lattice", spacing=1.0, tracked="all",
                     records=600, t_end=300.0, seed=3, probes=False)
    tr = T.read(r).sel(t=slice(20, None))
    tr = tr.where(tr["z"] < 8.0)
    start = copy.deepcopy(raw)
    start["orifice"]["rate"], start["kernel"]["volume"] = 40.0, 0.02
    fit = spotpde.fit(start, tr, {"orifice.rate": (10.0, 400.0), "kernel.volume": (0.001, 0.1)},
                      ["velocity", "diffusion"], options={"diffusion": {"bins": (7.5, 12.0)}})
    truth = {"orifice.rate": 64.0, "kernel.volume": 0.01}
    for key, value, se in zip(fit["parameter"].values, fit["value"].values, fit["stderr"].values):
        assert abs(value - truth[key]) < 4 * se, (key, value, se, fit.attrs["report"])
        assert se < 0.25 * truth[key]
    corr = fit["correlation"].sel(parameter="orifice.rate", parameter_2="kernel.volume").item()
    assert corr < -0.5          # the flux is V1 Q0: the two trade off


@pytest.mark.slow
def test_a_wrong_model_is_reported_as_not_reproducing_the_diffusion(pixel_file):
    """With the kernel's volume held at a third of the truth, b_p is a third too small
    wherever the flow goes: the report must say the diffusion is not reproduced."""
    tracks = T.read(pixel_file, scale=SCALE, fps=FPS, origin=ORIGIN, y_down=True)
    raw = start_case()
    raw["kernel"]["volume"] = 0.05 / 3
    raw["orifice"]["rate"] = 16.0 * 3
    fit = spotpde.fit(raw, tracks, {"spots.b": (0.3, 5.0), "orifice.rate": (4.0, 200.0)})
    assert "diffusion.b_p" in fit.attrs["not_reproduced"], fit.attrs["report"]
    assert "does NOT reproduce" in fit.attrs["report"]


def test_free_keys_and_observables_are_checked_by_name():
    tracks = T.make(np.zeros((3, 4)), np.full((3, 4), 5.0), np.arange(4.0))
    case = spotpde.load_case(TRUTH)
    with pytest.raises(ValueError, match="^free: 'spots.mode' is not a numeric key"):
        spotpde.fit(case, tracks, {"spots.mode": None})
    with pytest.raises(ValueError, match="outside the bounds"):
        spotpde.fit(case, tracks, {"spots.b": (2.0, 4.0)})
    with pytest.raises(ValueError, match="^observables: cannot fit 'layers'"):
        spotpde.fit(case, tracks, {"spots.b": None}, observables=["layers"])
    with pytest.raises(ValueError, match="^free: give the case keys"):
        spotpde.fit(case, tracks, {})
    with pytest.raises(ValueError, match=r"^free: 'spots.b.values\[0\]' is not a numeric key"):
        spotpde.fit(case, tracks, {"spots.b.values[0]": None})   # b is a number here


def test_profile_entries_are_free_keys():
    from spotpde.calibration._forward import assign, bounds_for

    raw = copy.deepcopy(TRUTH)
    raw["spots"]["b"] = {"z": [0.0, 24.0], "values": [1.0, 2.0]}
    case = spotpde.load_case(raw)
    start = bounds_for(case, {"spots.b.values[1]": (0.5, 4.0)})
    assert start == {"spots.b.values[1]": (2.0, 0.5, 4.0)}
    data = copy.deepcopy(case.data)
    assign(data, "spots.b.values[1]", 3.0)
    b = spotpde.load_case(data).spots.b
    assert abs(b[-1, 0] - (1.0 + 2.0 * case.grid.z[-1] / 24.0)) < 1e-12


def _cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "spotpde", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=900)


@pytest.mark.slow
def test_cli_fit_writes_the_result_and_figure(pixel_file, tmp_path):
    case = tmp_path / "case.toml"
    case.write_text(tomli_w.dumps(start_case()))
    out = tmp_path / "fit.nc"
    r = _cli("fit", case, pixel_file, "--free", "spots.b=0.3:5", "--free", "orifice.rate=4:60",
             "--scale", SCALE, "--fps", FPS, "--origin", f"{ORIGIN[0]},{ORIGIN[1]}", "--y-down",
             "-o", out, "--plot", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    import xarray as xr

    with xr.open_dataset(out) as ds:
        assert list(ds["parameter"].values) == ["spots.b", "orifice.rate"]
        assert np.all(ds["stderr"].values > 0)
        assert "chi2_reduced" in ds.attrs and "report" in ds.attrs
    assert (tmp_path / "fit.png").stat().st_size > 0
    assert "spotpde fit: converged" in r.stderr


@pytest.mark.parametrize("args, message", [
    (["--free", "spots.b=4:0.5"], "--free: 'spots.b=4:0.5': bounds must be finite LO:HI"),
    (["--free", "spotsb"], "--free: 'spotsb': expected KEY"),
    (["--free", "spots.b", "--origin", "1"], "--origin: must be X,Y"),
    (["--free", "spots.b", "--blocks", "1"], "--blocks: must be >= 2"),
    (["--free", "spots.mode"], "free: 'spots.mode' is not a numeric key"),
])
def test_cli_fit_refuses_bad_options_with_one_line(tmp_path, args, message):
    case = tmp_path / "case.toml"
    case.write_text(tomli_w.dumps(TRUTH))
    tracks = tmp_path / "t.csv"
    tracks.write_text("frame,particle,x,y\n0,1,0.0,5.0\n1,1,0.0,4.9\n")
    out = tmp_path / "fit.nc"
    r = _cli("fit", case, tracks, *args, "-o", out, cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert message in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()


def test_cli_fit_refuses_a_malformed_tracks_file(tmp_path):
    case = tmp_path / "case.toml"
    case.write_text(tomli_w.dumps(TRUTH))
    tracks = tmp_path / "t.csv"
    tracks.write_text("frame,particle,x\n0,1,0.0\n")
    r = _cli("fit", case, tracks, "--free", "spots.b", "-o", tmp_path / "fit.nc", cwd=tmp_path)
    assert r.returncode == 2
    assert r.stderr.strip().startswith("TRACKS: source:") and "missing column 'y'" in r.stderr
    assert r.stderr.count("\n") == 1 and not (tmp_path / "fit.nc").exists()
