"""Result Datasets and netCDF files: attributes, round trip, atomic writes."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from spotpde.app import io
from spotpde.grid import Grid


def result(dims=2, tracer=True):
    grid = Grid(dims=dims, x_range=(-2.0, 2.0), z_range=(0.0, 3.0), spacing=0.5)
    rng = np.random.default_rng(1)
    names = ["rho_s", "v_kin", "u_x", "u_z", "D_xx", "D_xz", "D_zz"]
    if dims == 3:
        names += ["u_y", "D_yy", "D_xy", "D_yz"]
    fields = {n: rng.random(grid.shape) for n in names}
    times = None
    if tracer:
        times = np.linspace(0.0, 2.0, 3)
        fields.update(P=rng.random((3, *grid.shape)), P_height=rng.random(grid.shape),
                      mass=np.array([1.0, 0.9, 0.8]), outflow=np.array([0.0, 0.1, 0.2]))
    attrs = {"V1": 0.05, "V2": 0.001, "rule": 0.5, "spotpde_version": "0.1.0",
             "case": "[domain]\ndims = 2\n"}
    return grid, io.make_dataset(grid, fields, times=times, attrs=attrs)


@pytest.mark.parametrize("dims", [2, 3])
def test_every_variable_and_coordinate_has_units_and_long_name(dims):
    grid, ds = result(dims)
    for name in list(ds.data_vars) + list(ds.coords):
        assert ds[name].attrs.get("units"), name
        assert ds[name].attrs.get("long_name"), name
    assert ds.rho_s.dims == grid.axes
    assert ds.P.dims == ("t", *grid.axes)
    assert ds.mass.dims == ("t",)
    # CF: no unit string UDUNITS reads as something else ("d" is a day, "t" a tonne)
    for name in list(ds.data_vars) + list(ds.coords):
        assert ds[name].attrs["units"] == "1", name
    assert ds.rho_s.attrs["spotpde_units"] == f"d-{dims}"
    assert "per d**" in ds.rho_s.attrs["long_name"]
    assert "particle diameters" in ds.z.attrs["long_name"]
    assert ds.z.attrs["axis"] == "Z" and ds.z.attrs["positive"] == "up"
    assert ds.x.attrs["axis"] == "X" and ds.t.attrs["axis"] == "T"
    assert ds.attrs["Conventions"] == "CF-1.10"
    for key in ("source", "references", "length_scale", "time_scale"):   # history: a run's
        assert ds.attrs[key], key
    np.testing.assert_array_equal(ds.x, grid.x)
    np.testing.assert_array_equal(ds.z, grid.z)
    assert "units_note" in ds.attrs


def test_make_dataset_rejects_arrays_of_the_wrong_shape():
    grid = Grid(dims=2, x_range=(-2.0, 2.0), z_range=(0.0, 3.0), spacing=0.5)
    with pytest.raises(ValueError, match="rho_s: array of shape"):
        io.make_dataset(grid, {"rho_s": np.zeros((3, 3))})
    with pytest.raises(KeyError):
        io.variable_attrs("banana", 2)


@pytest.mark.parametrize("dims", [2, 3])
def test_netcdf_round_trip_gives_the_same_dataset(tmp_path, dims):
    _, ds = result(dims)
    path = io.write_netcdf(ds, tmp_path / "r.nc")
    assert path == tmp_path / "r.nc"
    back = io.read_netcdf(path)
    xr.testing.assert_identical(back, ds)
    assert back.rho_s.encoding.get("zlib") is True
    assert [p.name for p in tmp_path.iterdir()] == ["r.nc"]


def test_compression_makes_smooth_fields_small(tmp_path):
    grid = Grid(dims=2, x_range=(-20.0, 20.0), z_range=(0.0, 40.0), spacing=0.25)
    ds = io.make_dataset(grid, {"rho_s": np.zeros(grid.shape)})
    io.write_netcdf(ds, tmp_path / "z.nc")
    assert (tmp_path / "z.nc").stat().st_size < grid.nbytes() / 4


def test_interrupted_write_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    _, ds = result()
    target = tmp_path / "r.nc"
    target.write_bytes(b"old")

    def broken(self, path, *args, **kwargs):
        with open(path, "wb") as fh:
            fh.write(b"half")
        raise KeyboardInterrupt

    monkeypatch.setattr(xr.Dataset, "to_netcdf", broken)
    with pytest.raises(KeyboardInterrupt):
        io.write_netcdf(ds, target)
    assert target.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["r.nc"]


def test_failed_write_creates_nothing(tmp_path, monkeypatch):
    _, ds = result()

    def broken(self, path, *args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(xr.Dataset, "to_netcdf", broken)
    with pytest.raises(OSError):
        io.write_netcdf(ds, tmp_path / "r.nc")
    assert list(tmp_path.iterdir()) == []


def test_read_rejects_missing_garbage_and_foreign_files(tmp_path):
    with pytest.raises(ValueError, match="no such result file"):
        io.read_netcdf(tmp_path / "none.nc")
    garbage = tmp_path / "g.nc"
    garbage.write_text("not netcdf")
    with pytest.raises(ValueError, match="not a readable netCDF file"):
        io.read_netcdf(garbage)
    foreign = tmp_path / "f.nc"
    xr.Dataset({"a": ("x", np.arange(3.0))}).to_netcdf(foreign)
    with pytest.raises(ValueError, match="not a spotpde result"):
        io.read_netcdf(foreign)
