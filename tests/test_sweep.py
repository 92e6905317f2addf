"""Parameter sweeps on a Dask LocalCluster: product of values, combination, resume, failures."""

from __future__ import annotations

import os

import numpy as np
import pytest
import xarray as xr

import spotpde
from spotpde.app import sweep
from spotpde.app.cli import main
from spotpde.errors import CaseError, NumericalError

BASE = {
    "domain": {"dims": 2, "x": [-4.0, 4.0], "z": [0.0, 6.0], "spacing": 0.5},
    "orifice": {"width": 1.0},
    "kernel": {"shape": "gaussian", "size": 0.5, "volume": 0.05},
}


def test_parse_settings_reads_toml_values_and_bare_words():
    s = sweep.parse_settings(["kernel.size=1,2.5", "kernel.shape=uniform,gaussian",
                              "domain.walls=open"])
    assert s == {"kernel.size": [1, 2.5], "kernel.shape": ["uniform", "gaussian"],
                 "domain.walls": ["open"]}


@pytest.mark.parametrize("item, key", [
    ("kernel.size", "kernel.size"), ("size=1,2", "size"), ("domain.spacing=0.5,1", "domain.spacing"),
])
def test_parse_settings_rejects_bad_items_naming_the_key(item, key):
    with pytest.raises(CaseError) as err:
        sweep.parse_settings([item])
    assert err.value.problems[0].startswith(f"--set {key}")


def test_invalid_member_is_refused_before_any_work(tmp_path):
    case = spotpde.load_case(BASE)
    with pytest.raises(CaseError) as err:
        sweep.members(case, {"spots.b": [1.0, -1.0]})
    (line,) = err.value.problems
    assert line.startswith("spots.b: ") and "sweep member spots.b=-1.0" in line
    with pytest.raises(CaseError, match=r"tracer\.t_end: the base case has no \[tracer\]"):
        sweep.members(case, {"tracer.t_end": [1.0]})


def test_sweep_on_local_cluster_combines_resumes(tmp_path):
    out = tmp_path / "sweep.nc"
    settings = {"kernel.size": [0.5, 1.0], "spots.b": [1.0, 2.0, 3.0]}
    seen = []
    ds = sweep.sweep_case(BASE, settings, out, n_workers=2,
                          progress=lambda done, total: seen.append((done, total)))
    assert seen[-1] == (6, 6)
    assert ds["rho_s"].dims == ("kernel_size", "spots_b", "z", "x")   # CF names: no dots
    assert (ds["status"] == 0).all()
    np.testing.assert_array_equal(ds["spots_b"], [1.0, 2.0, 3.0])
    assert ds["spots_b"].attrs["case_key"] == "spots.b"
    # each member equals a direct run of the same case
    direct = spotpde.run(spotpde.load_case(
        {**BASE, "kernel": {**BASE["kernel"], "size": 1.0}, "spots": {"b": 2.0}}))
    member = ds.sel({"kernel_size": 1.0, "spots_b": 2.0})
    for name in ("rho_s", "u_x", "u_z", "D_xx", "v_kin"):
        np.testing.assert_allclose(member[name], direct[name], rtol=1e-12, atol=0)
    assert float(member["V2"]) == pytest.approx(direct.attrs["V2"], rel=1e-14)
    # V2 of a Gaussian scales as 1/size**2 in 2D: the swept dimension is the right one
    v2 = ds["V2"].isel({"spots_b": 0}).values
    assert v2[0] / v2[1] == pytest.approx(4.0, rel=1e-12)
    # the written file reads back to the same Dataset
    with xr.open_dataset(out) as back:
        xr.testing.assert_allclose(back.load(), ds)
        assert back["rho_s"].attrs["units"] and back["kernel_size"].attrs["spotpde_units"] == "d"
    # resuming reruns nothing: member files are reused, untouched
    members_dir = tmp_path / "sweep.nc.members"
    stamps = {p: p.stat().st_mtime_ns for p in members_dir.iterdir()}
    assert len(stamps) == 6
    seen.clear()
    again = sweep.sweep_case(BASE, settings, out)
    assert seen == [] and {p: p.stat().st_mtime_ns for p in members_dir.iterdir()} == stamps
    xr.testing.assert_identical(again.drop_attrs(), ds.drop_attrs())


def test_failed_member_is_reported_by_its_parameters(tmp_path, monkeypatch):
    from distributed import Client, LocalCluster

    real_run = spotpde.pipeline.run

    def flaky(case, progress=None):
        if case.spots.b == 2.0:
            raise NumericalError("P < 0 at t = 1.5")
        return real_run(case, progress)

    monkeypatch.setattr(spotpde.pipeline, "run", flaky)
    with LocalCluster(n_workers=1, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        ds = sweep.sweep_case(BASE, {"spots.b": [1.0, 2.0]}, tmp_path / "s.nc",
                              scheduler=client)
    assert ds["status"].values.tolist() == [0, 1]
    assert np.isnan(ds["rho_s"].sel({"spots_b": 2.0})).all()
    assert np.isfinite(ds["rho_s"].sel({"spots_b": 1.0})).all()
    assert ds.attrs["failed_members"] == "spots.b=2.0: NumericalError: P < 0 at t = 1.5"
    # the failed member left no file, so a later run retries it
    assert len(os.listdir(tmp_path / "s.nc.members")) == 1


def test_cli_sweep_and_bad_set(tmp_path, capsys):
    case = tmp_path / "c.toml"
    case.write_text(spotpde.load_case(BASE).to_toml())
    out = tmp_path / "sw.nc"
    assert main(["sweep", str(case), "--set", "kernel.size=0.5,1", "-o", str(out),
                 "--workers", "1", "-q"]) == 0
    with xr.open_dataset(out) as ds:
        assert ds.sizes["kernel_size"] == 2
    assert main(["sweep", str(case), "--set", "kernel.rule=0.5,7", "-o",
                 str(tmp_path / "bad.nc")]) == 2
    err = capsys.readouterr().err
    assert "kernel.rule: " in err and "Traceback" not in err
    assert not (tmp_path / "bad.nc").exists()
