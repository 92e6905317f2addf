"""Parameter sweeps on a Dask LocalCluster: product of values, combination, resume, failures,
and signals at any moment of a ``spotpde sweep`` (real subprocesses)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import spotpde
from spotpde.app import sweep
from spotpde.cli import main
from spotpde.app import io as sio
from spotpde.errors import CaseError, NumericalError
from conftest import session_dir

ROOT = Path(__file__).resolve().parents[2]
_CACHE = str(session_dir("sweep-cache"))   # removed with the session (conftest)

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


# -- signals: Ctrl-C, SIGTERM and SIGHUP at any moment of `spotpde sweep` ----------------------

#: a member with a tracer: t_end = 1 takes seconds, 1e9 minutes (the one interrupted)
LONG = """
[domain]
x = [-4.0, 4.0]
z = [0.0, 8.0]
spacing = 0.5

[orifice]
width = 2.0

[tracer]
start = { x = 0.0, z = 6.0, width = 1.0 }
limiter = "upwind"
t_end = 1.0
frames = 3

[output]
path = "r.nc"
"""


def cli(*args, cwd):
    env = dict(os.environ, PYTHONPATH=str(ROOT), SPOTPDE_CACHE_DIR=_CACHE)
    return subprocess.run([sys.executable, "-m", "spotpde", *map(str, args)], cwd=cwd,
                          env=env, capture_output=True, text=True, timeout=300)


class _Sweep:
    """``spotpde sweep`` in its own session (so that ``os.killpg`` reaches it and its
    workers, as a terminal's Ctrl-C does), with SIGINT at its default disposition even
    when the test runs in a background job; standard error is read line by line."""

    def __init__(self, cwd, *args):
        env = dict(os.environ, PYTHONPATH=str(ROOT), SPOTPDE_CACHE_DIR=_CACHE)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "spotpde", "sweep", *map(str, args)], cwd=cwd, env=env,
            stderr=subprocess.PIPE, text=True, start_new_session=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        self.lines: list[str] = []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()
        self.workers: list[int] = []

    def _read(self):
        for line in self.proc.stderr:
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, condition, what, timeout=180):
        deadline = time.monotonic() + timeout
        while not condition():
            assert self.proc.poll() is None, f"exited before {what}: {self.lines}"
            assert time.monotonic() < deadline, f"no {what} within {timeout} s: {self.lines}"
            time.sleep(0.02)

    def line(self, text, timeout=180):
        self.wait_for(lambda: any(text in l for l in self.lines), repr(text), timeout)

    def children(self) -> list[int]:
        import psutil

        try:
            return [c.pid for c in psutil.Process(self.proc.pid).children(recursive=True)]
        except psutil.Error:
            return []

    def imports_numpy(self) -> bool:
        try:
            return "_multiarray_umath" in Path(f"/proc/{self.proc.pid}/maps").read_text()
        except OSError:
            return False

    def spawns_a_worker(self) -> bool:
        import psutil

        for pid in self.children():
            try:
                if "spawn_main" in " ".join(psutil.Process(pid).cmdline()):
                    return True
            except psutil.Error:
                pass
        return False

    def send(self, sig, group=True):
        self.workers = self.children()
        self.before = len(self.lines)
        (os.killpg if group else os.kill)(self.proc.pid, sig)
        self.proc.wait(timeout=60)          # a hang guard, not a speed check
        self.reader.join(timeout=10)
        return self.lines[self.before:]


def _all_stopped(pids, timeout=10.0) -> bool:
    import psutil

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        alive = []
        for pid in pids:
            try:
                if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                    alive.append(pid)
            except psutil.Error:
                pass
        if not alive:
            return True
        time.sleep(0.05)
    return False


@pytest.fixture(scope="module")
def tracer_cache(tmp_path_factory):
    """numba's cache warmed for the tracer (a sweep member then takes seconds)."""
    d = tmp_path_factory.mktemp("warm")
    (d / "w.toml").write_text(LONG)
    proc = cli("run", "w.toml", "-q", cwd=d)
    assert proc.returncode == 0, proc.stderr


#: where the signal lands: (name, signal, to the process group, the sweep's --set)
SIGNAL_MOMENTS = [
    ("importing", signal.SIGINT, True),       # the parent imports numpy, xarray, dask
    ("cluster start-up", signal.SIGINT, True),  # just after "0/2": LocalCluster starting
    ("worker start-up", signal.SIGINT, True),   # a worker process is being spawned
    ("mid-sweep", signal.SIGINT, True),       # one member done, the other running
    ("mid-sweep", signal.SIGTERM, False),     # `kill PID`
    ("mid-sweep", signal.SIGHUP, True),       # the terminal hangs up
    ("combining", signal.SIGINT, True),       # all members done: closing, combining, writing
]


@pytest.mark.slow
@pytest.mark.parametrize("moment, sig, group", SIGNAL_MOMENTS,
                         ids=[f"{m}-{signal.Signals(s).name}" for m, s, _ in SIGNAL_MOMENTS])
def test_ctrl_c_during_a_sweep_is_quiet(tracer_cache, tmp_path, moment, sig, group):
    """A sweep stopped by a signal at any moment: status 128 + n, one line, no traceback,
    no temporary file, no partial output, its workers gone, finished members kept (and
    reused by a rerun)."""
    (tmp_path / "long.toml").write_text(LONG)
    quick, slow = "1.0", ("2.0" if moment == "combining" else "1.0e9")
    # mid-sweep, two workers: one runs the long member, the other is idle (its event loop
    # takes a signal at once: the traceback of the issue)
    workers = "2" if moment == "mid-sweep" else "1"
    sweep = _Sweep(tmp_path, "long.toml", "--set", f"tracer.t_end={quick},{slow}",
                   "-o", "l.nc", "--workers", workers)
    if moment == "importing":
        sweep.wait_for(sweep.imports_numpy, "numpy imported")
    elif moment == "cluster start-up":
        sweep.line("0/2 members finished")
    elif moment == "worker start-up":
        sweep.wait_for(sweep.spawns_a_worker, "a worker process")
    elif moment == "mid-sweep":
        sweep.line("1/2 members finished")
        time.sleep(0.5)
    else:
        sweep.line("2/2 members finished")
    after = sweep.send(sig, group)
    assert sweep.proc.returncode == 128 + sig, sweep.lines
    err = "\n".join(sweep.lines)
    assert "Traceback" not in err and "Error" not in err and "Warning" not in err, err
    said = [l for l in after if "members finished" not in l]
    assert len(said) == 1, err                 # one line: what happened, what is left
    what = "interrupted" if sig == signal.SIGINT else f"terminated by signal {int(sig)}"
    assert said[0].startswith(f"spotpde: {what}"), err
    assert sorted(p.name for p in tmp_path.rglob("*") if p.name.endswith(".tmp")) == []
    assert _all_stopped(sweep.workers), "worker processes outlived the sweep"
    if said[0].endswith("no result written"):
        # a signal after the rename but before the message could leave a complete file
        assert moment == "combining" or not (tmp_path / "l.nc").exists()
    else:
        assert moment == "combining" and said[0].endswith("l.nc is complete"), err
    if (tmp_path / "l.nc").exists():           # never a partial file
        assert sio.read_netcdf(tmp_path / "l.nc")["status"].values.tolist() == [0, 0]
    if moment == "mid-sweep":                  # the finished member is kept, complete
        (member,) = (tmp_path / "l.nc.members").glob("member-*.nc")
        assert "P" in sio.read_netcdf(member)
    if moment == "mid-sweep" and sig == signal.SIGINT:   # a rerun reuses it
        again = cli("sweep", "long.toml", "--set", f"tracer.t_end={quick}", "-o", "l.nc",
                    cwd=tmp_path)
        assert again.returncode == 0, again.stderr
        assert again.stderr.splitlines()[0] == "spotpde: sweep 1/1 members finished"
