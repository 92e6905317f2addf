"""Tracer frames streamed to the result file: same content, bounded memory, atomic."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

import spotpde
from spotpde.app import cases
from spotpde import tracer
from spotpde.cli import main
from spotpde.errors import CaseError

SMALL = {
    "domain": {"dims": 2, "x": [-6.0, 6.0], "z": [0.0, 12.0], "spacing": 0.5},
    "orifice": {"width": 2.0, "rate": 20.0},
    "kernel": {"shape": "uniform", "size": 2.5, "height": 0.0024},
    "tracer": {"layers": {"spacing": 4.0}, "t_end": 20.0, "frames": 6},
}


def test_streamed_file_equals_the_in_memory_result(tmp_path):
    case = spotpde.load_case(SMALL)
    in_memory = spotpde.run(case)
    streamed = spotpde.run(case, path=tmp_path / "r.nc")
    assert streamed["P"].chunks[0] == (1,) * 6          # read lazily, a frame at a time
    # identical but for the global attribute history, the time each of the two runs was made
    loaded = streamed.load()
    assert loaded.attrs.pop("history") and in_memory.attrs.pop("history")
    xr.testing.assert_identical(loaded, in_memory)
    with xr.open_dataset(tmp_path / "r.nc") as back:
        assert back["P"].encoding["zlib"] and back["P"].encoding["chunksizes"][0] == 1
        back = back.load()
        assert back.attrs.pop("history")
        xr.testing.assert_identical(back, in_memory)


def test_on_frame_receives_every_frame_and_nothing_is_kept():
    case = spotpde.load_case(SMALL)
    ds = spotpde.run(case)
    fields = {k: ds[k].values for k in tracer.required_fields(2)}
    seen = []
    res = tracer.solve(case.grid, fields, ds["P"].values[0], 20.0, 6,
                       on_frame=lambda j, t, P: seen.append((j, t, P.copy())))
    assert res.P is None
    assert [j for j, _, _ in seen] == list(range(6))
    np.testing.assert_allclose([t for _, t, _ in seen], ds["t"].values, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.stack([P for _, _, P in seen]), ds["P"].values)
    np.testing.assert_array_equal(res.mass, ds["mass"].values)


def test_interrupted_stream_leaves_no_file_and_keeps_an_old_one(tmp_path, monkeypatch):
    out = tmp_path / "r.nc"
    out.write_bytes(b"an older result")
    real = spotpde.io.FrameWriter.__call__

    def interrupt(self, index, time, P):
        if index == 3:
            raise KeyboardInterrupt
        real(self, index, time, P)

    monkeypatch.setattr(spotpde.io.FrameWriter, "__call__", interrupt)
    with pytest.raises(KeyboardInterrupt):
        spotpde.run(spotpde.load_case(SMALL), path=out)
    assert out.read_bytes() == b"an older result"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.nc"]


def test_streaming_lifts_the_frame_memory_limit(monkeypatch, tmp_path):
    """Many frames of a fine grid: refused when held in memory, accepted when streamed."""
    monkeypatch.setattr(cases, "available_memory", lambda: 2 * 1024**3)
    big = {**SMALL, "domain": {**SMALL["domain"], "spacing": 0.0625},
           "tracer": {**SMALL["tracer"], "frames": 5000}}     # 192^2 cells: 1.4 GiB of frames
    with pytest.raises(CaseError, match=r"^tracer\.frames: .*stream them to the result file"):
        spotpde.load_case(big)
    case = spotpde.load_case(big, frames_in_memory=False)
    assert case.tracer.frames == 5000
    path = tmp_path / "big.toml"
    path.write_text(case.to_toml())
    assert main(["check", str(path)]) == 2              # check: frames held in memory
