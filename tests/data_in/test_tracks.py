"""spotpde.tracks: every reader on small files in the real formats, the one transformation
(pixels, image rows, frames -> d, z up, time), and every malformed file refused by name."""

from __future__ import annotations

import gzip
import shutil
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from hypothesis import given, settings, strategies as st

from spotpde import tracks as T

DATA = Path(__file__).parents[1] / "data"


def test_trackpy_csv_in_pixels_with_image_rows():
    # trackpy's own output columns (y, x, mass, size, ..., frame, particle); 20 px per d,
    # 50 frames per time unit, orifice at pixel (400, 700), image rows pointing down
    ds = T.read(DATA / "trackpy_small.csv", scale=20.0, fps=50.0, origin=(400.0, 700.0),
                y_down=True)
    assert ds.sizes == {"particle": 3, "t": 3}
    np.testing.assert_allclose(ds["t"].values, [0.0, 0.02, 0.04])
    p0 = ds.sel(particle=0)
    np.testing.assert_allclose(p0["x"].values, (np.array([401.1, 401.0, 400.9]) - 400) / 20)
    np.testing.assert_allclose(p0["z"].values, (700 - np.array([612.4, 612.8, 613.3])) / 20)
    # untracked frames are NaN: particle 1 misses frame 2, particle 2 frame 0
    assert np.isnan(ds["x"].sel(particle=1).values[2]) and np.isnan(ds["z"].sel(particle=2).values[0])
    assert ds["x"].attrs["spotpde_units"] == "d" and ds["t"].attrs["spotpde_units"] == "t"
    assert ds.attrs["format"] == "trackpy" and ds.attrs["y_down"] == "True"


def test_lammps_dump_splits_reinserted_grains_and_keeps_diameters(tmp_path):
    ds = T.read(DATA / "liggghts_small.dump", fps=1000.0)   # dt = 1e-3 time units per step
    np.testing.assert_allclose(ds["t"].values, [20.0, 21.0, 22.0])
    # grain 7 falls through the orifice and comes back at the top: two tracks
    ids = ds["id"].values
    assert sorted(ids.tolist()) == [5, 7, 7, 12, 31]
    first, second = (ds.isel(particle=i) for i in np.nonzero(ids == 7)[0])
    assert np.isnan(first["z"].values[2]) and np.isclose(first["z"].values[1], 5.04)
    assert np.all(np.isnan(second["z"].values[:2])) and np.isclose(second["z"].values[2], 68.5)
    np.testing.assert_allclose(ds["diameter"].values[ids == 12], [0.98])
    # 2D dump (constant z): x horizontal, y vertical, no depth coordinate
    assert "y" not in ds and ds.attrs["columns"] == "x<-x z<-y"
    # the same file gzip-compressed
    gz = tmp_path / "small.dump.gz"
    with open(DATA / "liggghts_small.dump", "rb") as src, gzip.open(gz, "wb") as dst:
        shutil.copyfileobj(src, dst)
    again = T.read(gz, fps=1000.0)
    xr.testing.assert_identical(again.drop_attrs(), ds.drop_attrs())


def test_lammps_scaled_coordinates_are_unscaled_with_the_box(tmp_path):
    text = (DATA / "liggghts_small.dump").read_text()
    scaled = text.replace("ITEM: ATOMS id type x y z vx vy vz radius",
                          "ITEM: ATOMS id type xs ys zs vx vy vz radius")
    lines = []
    for line in scaled.splitlines():
        parts = line.split()
        if len(parts) == 9 and not line.startswith("ITEM"):
            x, y = float(parts[2]), float(parts[3])
            parts[2], parts[3] = f"{(x + 20) / 40:.12f}", f"{y / 70:.12f}"
            parts[4] = "0.5"
            line = " ".join(parts)
        lines.append(line)
    path = tmp_path / "scaled.dump"
    path.write_text("\n".join(lines) + "\n")
    a, b = T.read(path), T.read(DATA / "liggghts_small.dump")
    np.testing.assert_allclose(a["x"].values, b["x"].values, atol=1e-9)
    np.testing.assert_allclose(a["z"].values, b["z"].values, atol=1e-9)


def test_parquet_dataframe_and_netcdf_round_trip(tmp_path):
    rng = np.random.default_rng(3)
    x = rng.normal(size=(6, 9))
    z = 10 + rng.normal(size=(6, 9))
    x[2, 4:] = z[2, 4:] = np.nan
    ds = T.make(x, z, np.arange(9) * 0.5)
    df = T.to_trackpy(ds, scale=12.5, fps=2.0, origin=(320.0, 480.0), y_down=True)
    for source in (df, _parquet(df, tmp_path)):
        back = T.read(source, scale=12.5, fps=2.0, origin=(320.0, 480.0), y_down=True)
        np.testing.assert_allclose(back["x"].values, x, atol=1e-12)
        np.testing.assert_allclose(back["z"].values, z, atol=1e-12)
        np.testing.assert_allclose(back["t"].values, np.arange(9) * 0.5)
    path = tmp_path / "tracks.nc"
    ds.to_netcdf(path)
    np.testing.assert_allclose(T.read(path)["z"].values, z)


def _parquet(df, tmp_path):
    path = tmp_path / "tracks.parquet"
    df.to_parquet(path)
    return path


def test_monte_carlo_result_is_read_as_tracks():
    from spotpde import montecarlo as mc
    from spotpde.grid import Grid
    from spotpde.kernels import Gaussian
    from spotpde.parameters import Orifice, Spots

    grid = Grid(dims=2, x_range=(-4.0, 4.0), z_range=(0.0, 8.0), spacing=0.5)
    parts = mc.lattice(grid, 1.5)
    r = mc.simulate(grid, Orifice(x=0.0, width=2.0, rate=4.0), Spots(b=1.0),
                    Gaussian(sigma=1.0, volume=0.05, dims=2), particles=parts, tracked="all",
                    t_end=10.0, records=5, seed=1, probes=False)
    ds = T.read(r)
    assert ds.sizes["t"] == r.times.size + 1
    np.testing.assert_allclose(ds["x"].values[:, 0], parts[:, 0])
    live = np.isfinite(r.positions[-1, :, 0])
    np.testing.assert_allclose(ds["z"].values[live, -1], r.positions[-1, live, 1])


@pytest.mark.parametrize("text, problem", [
    ("frame,particle,x\n0,1,2.0\n", "missing column 'y'"),
    ("frame,x,y\n0,2.0,3.0\n", "missing column 'particle'"),
    ("frame,particle,x,y\n0,1,2.0,3.0\n0,1,2.5,3.5\n", "duplicate rows for particle 1 in frame 0"),
    ("frame,particle,x,y\n0,1,2 px,3.0\n", "column 'x' is not numeric"),
    ("frame,particle,x,y\n0.5,1,2.0,3.0\n", "column 'frame' must hold integers"),
])
def test_malformed_trackpy_files_are_refused_by_name(tmp_path, text, problem):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match="source: .*" + problem.replace("(", r"\(")):
        T.read(path)


def _dump(steps, columns="id type x y z", rows=None):
    out = []
    for k, step in enumerate(steps):
        body = rows[k] if rows else ["1 1 0.0 5.0 0.0", "2 1 1.0 6.0 0.0"]
        out += ["ITEM: TIMESTEP", str(step), "ITEM: NUMBER OF ATOMS", str(len(body)),
                "ITEM: BOX BOUNDS pp ff pp", "-5 5", "0 10", "-0.5 0.5", f"ITEM: ATOMS {columns}",
                *body]
    return "\n".join(out) + "\n"


@pytest.mark.parametrize("text, problem", [
    (_dump([100, 50]), "frames are not increasing .TIMESTEP 50 after 100."),
    (_dump([100, 100]), "frames are not increasing"),
    (_dump([0], columns="type x y z", rows=[["1 0.0 5.0 0.0"]]), "missing column 'id'"),
    (_dump([0], columns="id type xs y z", rows=[["1 1 0.5 5.0 0.0"]]), "mixed units: xs scaled"),
    (_dump([0]).replace("2 1 1.0 6.0 0.0\n", ""), "truncated snapshot at TIMESTEP 0"),
    (_dump([0], rows=[["1 1 abc 5.0 0.0", "2 1 1.0 6.0 0.0"]]), "non-numeric atom data"),
    (_dump([0], rows=[["1 1 0.0 5.0 0.0", "1 1 1.0 6.0 0.0"]]), "duplicate rows for particle 1"),
])
def test_malformed_lammps_dumps_are_refused_by_name(tmp_path, text, problem):
    path = tmp_path / "bad.dump"
    path.write_text(text)
    with pytest.raises(ValueError, match=problem):
        T.read(path)


def test_mixed_units_in_a_tracks_dataset_are_refused():
    ds = T.make(np.zeros((2, 3)), np.ones((2, 3)), [0.0, 1.0, 2.0])
    ds["z"].attrs["spotpde_units"] = "px"
    with pytest.raises(ValueError, match="mixed units"):
        T.read(ds)


@pytest.mark.parametrize("kwargs, name", [
    ({"scale": 0.0}, "scale"), ({"fps": -1.0}, "fps"), ({"scale": float("nan")}, "scale"),
    ({"origin": (1.0,)}, "origin"), ({"origin": "ab"}, "origin"), ({"dims": 4}, "dims"),
    ({"max_jump": 0.0}, "max_jump"), ({"vertical": "q"}, "vertical"),
])
def test_bad_arguments_name_the_argument(kwargs, name):
    with pytest.raises(ValueError, match=f"^{name}: "):
        T.read(DATA / "trackpy_small.csv", **kwargs)


def test_unknown_source_types_and_missing_files():
    with pytest.raises(TypeError, match="^source: "):
        T.read(42)
    with pytest.raises(ValueError, match="no such file"):
        T.read("/nonexistent/tracks.csv")


@settings(max_examples=40, deadline=None)
@given(scale=st.floats(0.1, 100.0), fps=st.floats(0.5, 500.0),
       ox=st.floats(-1e3, 1e3), oy=st.floats(-1e3, 1e3), y_down=st.booleans())
def test_read_inverts_to_trackpy_for_any_transformation(scale, fps, ox, oy, y_down):
    rng = np.random.default_rng(0)
    x, z = rng.uniform(-5, 5, (4, 5)), rng.uniform(0, 20, (4, 5))
    ds = T.make(x, z, np.arange(5) / fps)
    df = T.to_trackpy(ds, scale=scale, fps=fps, origin=(ox, oy), y_down=y_down)
    back = T.read(df, scale=scale, fps=fps, origin=(ox, oy), y_down=y_down, max_jump=None)
    tol = 1e-9 * (1 + abs(ox) + abs(oy)) / scale
    np.testing.assert_allclose(back["x"].values, x, atol=tol)
    np.testing.assert_allclose(back["z"].values, z, atol=tol)
