"""Faults of the estimates and limits made before a run (issue 30, items 7-10, 12, 14, 20).

Each test reproduces the fault as it was reported: a memory estimate that left out the
passage quadrature (``spots.b = 5e4`` on a 20 x 20 grid: "valid", then killed at
24 GB), a MemoryError traceback, a sweep of 10^6 members validated for 50 minutes in
silence, 12 worker processes for 2 members, a transient run of ``t_end = 1e9`` started
without an estimate, kernel amplitudes whose square underflows, an environment
variable parsed at import, and a 613-character refusal. Nothing here starts a Dask
cluster or allocates what it refuses (the solvers that would are replaced by functions
that fail the test if reached).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tracemalloc
from pathlib import Path

import numpy as np
import pytest

import spotpde
from spotpde.app import _resources, cases, estimate, pipeline, sweep
from spotpde.cli import main
from spotpde.errors import CaseError
from spotpde.fields import _passage, kernels

ROOT = Path(__file__).resolve().parents[2]

#: a 20 x 20 grid
SMALL = """
[domain]
x = [-5.0, 5.0]
z = [0.0, 10.0]
spacing = 0.5

[orifice]
width = 2.0

[output]
path = "r.nc"
"""
BASE = {"domain": {"dims": 2, "x": [-4.0, 4.0], "z": [0.0, 6.0], "spacing": 0.5},
        "orifice": {"width": 1.0}}


def write(tmp_path, text, name="c.toml") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def cli(*args, cwd, env=None):
    """``python -m spotpde ARGS`` in a new process (the environment of the tests)."""
    full = dict(os.environ, PYTHONPATH=str(ROOT), **(env or {}))
    return subprocess.run([sys.executable, "-m", "spotpde", *map(str, args)], cwd=cwd,
                          env=full, capture_output=True, text=True, timeout=300)


def one_line(text: str) -> str:
    assert "Traceback" not in text, text
    lines = text.strip().splitlines()
    assert len(lines) == 1, text
    return lines[0]


@pytest.fixture
def memory(monkeypatch):
    """A machine with 16 GiB available (the estimates' verdicts do not depend on this one)."""
    monkeypatch.setattr(cases, "available_memory", lambda: 16 * 1024**3)


@pytest.fixture
def no_quadrature(monkeypatch):
    """The passage quadrature fails the test if it is ever started."""
    def never(*args, **kwargs):
        raise AssertionError("the refused quadrature was started")

    monkeypatch.setattr(_passage, "_single", never)


# -- item 7: every allocation that grows with a key is in the memory estimate ----------

def test_large_spots_b_is_refused_by_check_naming_the_key(tmp_path):
    """spots.b = 1e6 on a 20 x 20 grid (184 GiB asked for): refused by ``check`` (exit 2,
    one line naming spots.b), not reported valid and then killed while computing."""
    path = write(tmp_path, SMALL + "\n[spots]\nb = 1e6\n")
    proc = cli("check", path, cwd=tmp_path)
    line = one_line(proc.stderr)
    assert proc.returncode == 2
    assert line.startswith("spots.b: the passage diffusivity's quadrature needs about")
    assert 'kernel.diffusivity = "mean-field"' in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]


def test_the_refusal_comes_before_the_quadrature_and_mean_field_is_accepted(
        tmp_path, capsys, memory, no_quadrature):
    path = write(tmp_path, SMALL + "\n[spots]\nb = 5e4\n")
    assert main(["check", path]) == 2
    assert main(["run", path, "-q"]) == 2
    assert capsys.readouterr().err.count("spots.b: ") == 2
    assert not (tmp_path / "r.nc").exists()
    # the mean field needs no quadrature: the same b is accepted
    data = cases.validate({**BASE, "spots": {"b": 5e4},
                           "kernel": {"diffusivity": "mean-field"}})
    assert _resources.passage_bytes(data) == 0.0


@pytest.mark.parametrize("shape, dims, b, b_par", [("gaussian", 2, 5.0, 0.0),
                                                   ("exponential", 2, 2.0, 0.5),
                                                   ("uniform", 2, 2.0, 0.0),
                                                   ("gaussian", 3, 2.0, 0.0)])
def test_quadrature_estimate_is_its_measured_peak(shape, dims, b, b_par):
    """The estimate is the quadrature's own peak (tracemalloc), from its own grid."""
    kernel = kernels.from_spec(shape, 1.0, 0.05, 1.0, dims)
    estimated = _passage.quadrature_bytes(kernel, b, b_par)
    _passage._CACHE.clear()
    tracemalloc.start()
    try:
        _passage.length_tensor(kernel, b, b_par)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert 0.9 * estimated <= peak <= estimated


def test_the_key_that_enlarges_the_quadrature_is_named(monkeypatch):
    """A case too large for 1 GiB through its quadrature names the key whose default
    would shrink it: the tiny kernel, the long b, the long b_par."""
    monkeypatch.setattr(cases, "available_memory", lambda: 1024**3)

    def refusal(**tables):
        with pytest.raises(CaseError) as err:
            cases.validate({**BASE, **tables})
        (line,) = err.value.problems
        return line

    assert refusal(kernel={"size": 0.01}).startswith("kernel.size: the passage")
    assert refusal(spots={"b": 2000.0}).startswith("spots.b: the passage")
    assert refusal(spots={"b_par": 2000.0}).startswith("spots.b_par: the passage")
    profile = {"z": [0.0, 6.0], "values": [1.3, 2000.0]}     # the largest value counts
    assert refusal(spots={"b": profile}).startswith("spots.b: the passage")
    cases.validate({**BASE, "spots": {"b": 20.0}})          # moderate lengths fit


def test_pair_solver_and_random_rate_are_in_the_estimate(memory):
    with pytest.raises(CaseError, match=r"^pair\.spacing: the pair solver needs about"):
        cases.validate({**BASE, "kernel": {"diffusivity": "mean-field"},
                        "pair": {"x": 0.0, "z": 3.0, "separation": 200.0}})
    with pytest.raises(CaseError,
                       match=r"^orifice\.noise\.correlation_time: the random rate needs"):
        cases.validate({**BASE, "spots": {"mode": "transient", "t_end": 1e6},
                        "orifice": {"width": 1.0, "noise": {"amplitude": 0.1,
                                                            "correlation_time": 1e-9}}})
    ok = cases.validate({**BASE, "pair": {"x": 0.0, "z": 3.0}})
    assert _resources.pair_bytes(ok) > 0


def test_out_of_memory_in_a_run_is_one_line_and_exit_1(tmp_path, capsys, memory,
                                                       monkeypatch):
    """An allocation the estimate did not foresee: one line, exit 1, no result and no
    temporary file (it was a MemoryError traceback)."""
    def allocate(*args, **kwargs):
        raise MemoryError("Unable to allocate 6.15 GiB for an array with shape "
                          "(57469, 14368) and data type float64")

    monkeypatch.setattr(_passage, "_single", allocate)
    path = write(tmp_path, SMALL + "\n[spots]\nb = 1.2345\n")   # not in the tensor cache
    assert main(["run", path, "-q"]) == 1
    line = one_line(capsys.readouterr().err)
    assert line == ("spotpde: out of memory, no result written: Unable to allocate 6.15 GiB "
                    "for an array with shape (57469, 14368) and data type float64")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]


# -- item 8: a sweep's size is limited, its validation reports progress ---------------

def test_a_million_members_are_refused_before_any_is_validated(tmp_path, capsys,
                                                               monkeypatch):
    def never(*args, **kwargs):
        raise AssertionError("a member was validated")

    case = spotpde.load_case(BASE)
    monkeypatch.setattr(sweep, "load_case", never)
    values = [1.0 + i / 1000 for i in range(1000)]
    settings = {"spots.b": values, "kernel.size": values}
    with pytest.raises(CaseError) as err:
        sweep.members(case, settings)
    assert err.value.problems == [
        "--set: the sweep has 1,000,000 members (1000 x 1000 values), more than 10,000; "
        "sweep fewer values, or pass --allow-many (Python: allow_many=True)"]
    assert sweep.count_members(settings, allow_many=True) == 10**6
    path = write(tmp_path, SMALL)
    listed = ",".join(map(str, values))
    args = ["sweep", path, "--set", f"spots.b={listed}", "--set", f"kernel.size={listed}"]
    assert main(args) == 2
    assert one_line(capsys.readouterr().err).startswith("--set: the sweep has 1,000,000")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]


def test_validation_reports_progress(tmp_path, capsys, monkeypatch):
    case = spotpde.load_case(BASE)
    seen = []
    out = sweep.members(case, {"spots.b": [1.0 + i / 10 for i in range(25)]},
                        progress=lambda done, total: seen.append((done, total)))
    assert len(out) == 25
    assert seen[0] == (0, 25) and seen[-1] == (25, 25) and len(seen) <= 12
    assert [d for d, _ in seen] == sorted(d for d, _ in seen)
    # the command line prints it for a sweep of 100 members or more, before connecting

    def refuse(address, timeout=None):
        raise CaseError("--scheduler: not reached in this test")

    monkeypatch.setattr(sweep, "connect", refuse)
    path = write(tmp_path, SMALL)
    listed = ",".join(str(1.0 + i / 100) for i in range(120))
    assert main(["sweep", path, "--set", f"spots.b={listed}", "--scheduler", "x:1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0] == "spotpde: sweep 0/120 members validated"
    assert err[-2] == "spotpde: sweep 120/120 members validated"
    assert err[-1] == "--scheduler: not reached in this test"


# -- item 9: no more workers than members and cores -----------------------------------

def test_workers_are_capped_at_the_members_and_the_cores(tmp_path, monkeypatch):
    from spotpde.app import _localdask

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2, 3})
    assert sweep.worker_count(12, 2) == 2
    assert sweep.worker_count(12, 100) == 4
    assert sweep.worker_count(None, 3) == 3
    assert sweep.worker_count(1, 100) == 1

    started = []

    class Recorder:     # records the cluster a sweep would start, and starts nothing
        def __init__(self, n_workers):
            started.append(n_workers)

        def start(self):
            raise RuntimeError("no cluster in this test")

        def close(self):
            pass

    monkeypatch.setattr(_localdask, "LocalDask", Recorder)
    with pytest.raises(RuntimeError, match="no cluster in this test"):
        sweep.sweep_case(BASE, {"spots.b": [1.0, 2.0]}, tmp_path / "s.nc", n_workers=12)
    assert started == [2]


# -- item 10: transient runs are estimated and refused when too long ------------------

TRANSIENT = SMALL + """
[spots]
mode = "transient"
t_end = {spots}
"""
TRACER = """
[tracer]
start = {{ x = 0.0, z = 6.0, width = 1.0 }}
t_end = {tracer}
frames = 3
"""


def test_transient_runs_of_1e9_are_refused_before_the_spot_density(tmp_path, capsys,
                                                                     monkeypatch, memory):
    from spotpde.density import spot_density

    def never(*args, **kwargs):
        raise AssertionError("the refused run was started")

    monkeypatch.setattr(spot_density, "transient", never)
    with_tracer = write(tmp_path, (TRANSIENT + TRACER).format(spots=10.0, tracer=1e9))
    without = write(tmp_path, TRANSIENT.format(spots=1e6).replace("spacing = 0.5",
                                                                  "spacing = 0.05"), "s.toml")
    for path, key in ((with_tracer, "tracer.t_end"), (without, "spots.t_end")):
        assert main(["check", path]) == 2
        line = capsys.readouterr().err.strip().splitlines()[-1]
        assert line.startswith(f"{key}: the run would take about")
        assert "the transient spot density" in line and "--allow-long" in line
        assert main(["run", path, "-q"]) == 2
        assert one_line(capsys.readouterr().err).startswith(f"{key}: the run would take")
    assert main(["check", with_tracer, "--allow-long"]) == 0
    assert not (tmp_path / "r.nc").exists()


def test_transient_estimate_counts_the_solvers_steps(tmp_path):
    """The spot density's steps are the solver's own (BDF2, interacting spots); the tracer's
    in changing fields are those of the steady fields it fills towards."""
    from spotpde import tracer
    from spotpde.density import spot_density

    for extra in ({}, {"rho_max": 2.0}):
        case = spotpde.load_case({**BASE, "spots": {"mode": "transient", "t_end": 7.0,
                                                    **extra}})
        (run,) = estimate.spot_density_runs(case)
        res = spot_density.transient(case.grid, case.orifice, case.spots, 7.0,
                                     full_output=True)
        assert run["steps"] == res["steps"] and run["key"] == "spots.t_end"
    case = spotpde.load_case({
        "domain": {"x": [-4.0, 4.0], "z": [0.0, 8.0], "spacing": 0.5},
        "orifice": {"width": 2.0}, "kernel": {"volume": 1.0},
        "spots": {"mode": "transient", "t_end": 40.0},
        "tracer": {"start": {"x": 0.0, "z": 6.0, "width": 1.0}, "t_end": 40.0, "frames": 3,
                   "limiter": "koren", "snapshots": 21}})
    est = estimate.case_estimate(case)
    assert [r["key"] for r in est["spot_density"]] == ["tracer.t_end"]   # one solve
    res = tracer.solve(case.grid, pipeline.SnapshotFields(
        case.snapshot_times(),
        spot_density.transient(case.grid, case.orifice, case.spots, 40.0,
                               times=case.snapshot_times()),
        lambda r: pipeline.case_fields(case, r)),
        pipeline.initial_density(case.grid, case.tracer.start), 40.0, 3, limiter="koren")
    assert 0.85 * res.steps <= est["steps"] <= 1.15 * res.steps


def test_snapshot_fields_are_computed_once_each():
    """The tracer's stage times go back and forth across a snapshot and it asks once for
    t_end: each snapshot's fields are computed once (t_end's at most twice)."""
    computed = []

    def fields_of(rho):
        computed.append(float(rho.flat[0]))
        return {"u": rho}

    times = np.linspace(0.0, 10.0, 11)
    snaps = pipeline.SnapshotFields(times, times[:, None] * np.ones((11, 2)), fields_of)
    snaps(10.0)                              # the solver's probe at t_end
    t, dt = 0.0, 0.7
    while t < 10.0:
        for stage in (t, t + dt, t + 0.5 * dt):     # SSP-RK3 stage times
            snaps(min(stage, 10.0))
        t += dt
    assert [computed.count(j) for j in range(10)] == [1] * 10
    assert computed.count(10.0) <= 2


# -- item 12: kernel amplitudes whose square underflows -------------------------------

@pytest.mark.parametrize("key, shown", [("height", "[1e-12, 1]"),
                                        ("volume", "[1e-12, 1e+06]")])
def test_underflowing_kernel_amplitude_is_refused_by_name(tmp_path, capsys, key, shown):
    path = write(tmp_path, SMALL + f'\n[kernel]\nshape = "uniform"\n{key} = 1e-320\n')
    assert main(["check", path]) == 2
    assert one_line(capsys.readouterr().err) == \
        f"kernel.{key}: must be in {shown}, got 1e-320"


def test_effective_spot_length_names_its_kernel_argument():
    # a uniform kernel this weak is refused where it is made, by its argument's name
    with pytest.raises(ValueError, match=r"^height must be in \[1e-12, 1\]"):
        kernels.Uniform(radius=1.0, height=1e-320)
    with pytest.raises(ValueError, match=r"^volume: .* < 1e-12"):
        kernels.from_spec("uniform", 1.0, 1e-320, 1.0, 2)
    # one whose w**2 underflows (V2 = 0) is refused by the passage length, naming kernel
    for kernel in (kernels.Gaussian(sigma=1.0, volume=1e-320),
                   kernels.from_spec("exponential", 1.0, 1e-320, 1.0, 2)):
        with pytest.raises(ValueError, match=r"^kernel: its volumes V1 = .* and V2 = 0 must"):
            _passage.effective_spot_length(kernel, 1.3)


# -- item 14: environment variables are checked when used -----------------------------

def test_connect_timeout_is_read_when_connecting(tmp_path, capsys, monkeypatch):
    env = dict(os.environ, PYTHONPATH=str(ROOT), SPOTPDE_CONNECT_TIMEOUT="abc")
    proc = subprocess.run([sys.executable, "-c", "import spotpde.app.sweep"], env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr      # it broke every sweep at import
    for value in ("abc", "-5", "inf", "nan", "0"):
        monkeypatch.setenv("SPOTPDE_CONNECT_TIMEOUT", value)
        with pytest.raises(CaseError) as err:
            sweep.connect("127.0.0.1:9")
        assert err.value.problems == [f"SPOTPDE_CONNECT_TIMEOUT: must be a number of "
                                      f"seconds in (0, 3600], got {value!r}"]
    with pytest.raises(ValueError, match=r"^timeout: must be a number of seconds"):
        sweep.connect("127.0.0.1:9", timeout=-5)
    monkeypatch.setenv("SPOTPDE_CONNECT_TIMEOUT", "2.5")
    assert sweep.connect_timeout() == 2.5
    monkeypatch.setenv("SPOTPDE_CONNECT_TIMEOUT", "-5")
    path = write(tmp_path, SMALL)
    assert main(["sweep", path, "--set", "spots.b=1,2", "--scheduler", "127.0.0.1:9"]) == 2
    assert one_line(capsys.readouterr().err).startswith("SPOTPDE_CONNECT_TIMEOUT: ")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.toml"]


# -- item 20: absurd values are refused by range, in short lines ----------------------

def test_absurd_kernel_values_give_short_lines(tmp_path, monkeypatch):
    for text in ("aspect = 1e-300", "size = 1e-300", "aspect = 1e300"):
        path = write(tmp_path, SMALL + f"\n[kernel]\n{text}\n")
        proc = cli("check", path, cwd=tmp_path)
        line = one_line(proc.stderr)
        key = text.split()[0]
        assert proc.returncode == 2 and line.startswith(f"kernel.{key}: must be in [")
        assert len(line) < 80 and not re.search(r"\d{8}", line)
    # the stencil refusal states its numbers compactly too
    monkeypatch.setattr(cases, "available_memory", lambda: 2 * 1024**3)
    with pytest.raises(CaseError) as err:
        cases.validate({**BASE, "domain": {**BASE["domain"], "spacing": 0.01},
                        "kernel": {"aspect": 0.001, "diffusivity": "mean-field"}})
    (line,) = err.value.problems
    assert line.startswith("kernel.aspect: ") and "kernel stencil of" in line
    assert len(line) < 300 and not re.search(r"\d{8}", line)
