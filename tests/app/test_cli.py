"""The command line: exit statuses, messages, atomic output, progress, Ctrl-C, figures."""

from __future__ import annotations

import io as stdio
import os
import signal
import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import spotpde
from spotpde import cli
from spotpde.app import pipeline
from spotpde.app import io as sio
from spotpde.app.cases import load_case

ROOT = Path(__file__).resolve().parents[2]
CASE_FILES = sorted((ROOT / "cases").glob("*.toml"))

SMALL = """
[domain]
x = [-4.0, 4.0]
z = [0.0, 8.0]
spacing = 0.5

[orifice]
width = 2.0

[tracer]
layers = { spacing = 2.0 }
t_end = 1.0
frames = 3

[output]
path = "small.nc"
"""


def fake_dataset(case):
    """A result Dataset of the right form without running a solver."""
    grid = case.grid
    Z, X = grid.mesh()[0], grid.mesh()[-1]
    v = np.broadcast_to(np.exp(-X**2 / (4 * 1.3 * (Z + 1))) / np.sqrt(Z + 1), grid.shape)
    fields = {"rho_s": v, "v_kin": 0.05 * v, "u_x": -0.01 * X * v, "u_z": -0.05 * v,
              "D_xx": 1e-4 * v, "D_xz": 0 * v, "D_zz": 0 * v}
    if grid.dims == 3:
        fields.update(u_y=0 * v, D_yy=1e-4 * v, D_xy=0 * v, D_yz=0 * v)
    times = None
    if case.tracer is not None:
        times = np.linspace(0, case.tracer.t_end, case.tracer.frames)
        P0 = pipeline.initial_density(grid, case.tracer.start)
        decay = np.exp(-times)
        fields.update(P=np.stack([P0 * d for d in decay]), P_height=0.1 * v, mass=decay,
                      outflow=1 - decay)
    attrs = {"V1": 0.05, "V2": 1e-3, "rule": case.rule, "model": case.model,
             "spotpde_version": spotpde.__version__, "case": case.to_toml()}
    return sio.make_dataset(grid, fields, times=times, attrs=attrs)


@pytest.fixture
def fake_run(monkeypatch):
    def run(case, progress=None, *, path=None, on_fields=None):
        for stage in pipeline.STAGES:
            for f in np.linspace(0, 1, 21):
                if progress:
                    progress(stage, f)
        ds = fake_dataset(case)
        if path is not None:
            sio.write_netcdf(ds, path)
        return ds

    monkeypatch.setattr(pipeline, "run", run)
    return run


@pytest.fixture
def small_case(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "small.toml"
    path.write_text(SMALL)
    return path


# -- check ----------------------------------------------------------------------------

@pytest.mark.parametrize("path", CASE_FILES, ids=[p.stem for p in CASE_FILES])
def test_every_shipped_case_passes_check(path, capsys):
    assert cli.main(["check", str(path)]) == 0
    assert "is valid" in capsys.readouterr().err


def test_check_of_an_invalid_case_lists_each_problem(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[spots]\nb = -1.0\nzap = 2\n[kernel]\nrule = 3.0\n")
    assert cli.main(["check", str(bad)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert "spots.b: must be > 0, got -1.0" in err
    assert any(line.startswith("spots.zap: unknown key") for line in err)
    assert "kernel.rule: must be <= 1, got 3.0" in err
    assert len(err) == 3


def test_check_of_missing_and_malformed_files(tmp_path, capsys):
    assert cli.main(["check", str(tmp_path / "nope.toml")]) == 2
    (tmp_path / "m.toml").write_text("[domain]\nx = [1, \n")
    assert cli.main(["check", str(tmp_path / "m.toml")]) == 2
    err = capsys.readouterr().err
    assert "cannot read the case file" in err and "malformed TOML" in err
    assert "Traceback" not in err


def test_version_and_usage(capsys):
    assert cli.main(["--version"]) == 0
    assert spotpde.__version__ in capsys.readouterr().out
    assert cli.main([]) == 2
    assert cli.main(["frobnicate"]) == 2


# -- run ------------------------------------------------------------------------------

def test_run_writes_a_readable_result_where_output_path_says(small_case, fake_run, capsys):
    assert cli.main(["run", str(small_case)]) == 0
    out = small_case.parent / "small.nc"
    ds = sio.read_netcdf(out)
    case = load_case(small_case)
    xr.testing.assert_identical(ds, fake_dataset(case))
    assert sorted(p.name for p in small_case.parent.iterdir()) == ["small.nc", "small.toml"]
    err = capsys.readouterr().err
    assert "spotpde: spot density 0%" in err and "spotpde: tracer 100%" in err
    assert len(err.splitlines()) <= 4 * 5 + 2          # not too many progress lines


def test_run_output_option_and_plot(small_case, fake_run, tmp_path):
    target = tmp_path / "sub" / "r.nc"
    target.parent.mkdir()
    fig = tmp_path / "f.png"
    assert cli.main(["run", str(small_case), "-o", str(target), "--plot", str(fig), "-q"]) == 0
    assert target.is_file() and fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not (tmp_path / "small.nc").exists()


def test_run_of_an_invalid_case_writes_nothing(tmp_path, fake_run, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    bad = tmp_path / "bad.toml"
    bad.write_text(SMALL.replace("spacing = 0.5", "spacing = -0.5"))
    assert cli.main(["run", str(bad)]) == 2
    assert capsys.readouterr().err.strip() == "domain.spacing: must be > 0, got -0.5"
    assert [p.name for p in tmp_path.iterdir()] == ["bad.toml"]


def test_run_into_a_missing_directory_is_invalid(small_case, fake_run, capsys, tmp_path):
    assert cli.main(["run", str(small_case), "-o", "no/such/dir/r.nc"]) == 2
    assert capsys.readouterr().err.startswith("output.path: the directory")
    assert cli.main(["run", str(small_case), "-o", str(tmp_path)]) == 2
    assert capsys.readouterr().err.startswith("output.path: must name a file, not a directory")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small.toml"]


def test_numerical_failure_exits_1_without_a_file(small_case, monkeypatch, capsys):
    def blow_up(case, progress=None, **_):
        raise spotpde.NumericalError("P < 0 at t = 3")

    monkeypatch.setattr(pipeline, "run", blow_up)
    assert cli.main(["run", str(small_case)]) == 1
    assert "numerical failure" in capsys.readouterr().err
    assert not (small_case.parent / "small.nc").exists()


def test_ctrl_c_during_the_run_exits_130_without_a_file(small_case, monkeypatch, capsys):
    def interrupted(case, progress=None, **_):
        raise KeyboardInterrupt

    monkeypatch.setattr(pipeline, "run", interrupted)
    assert cli.main(["run", str(small_case)]) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "Traceback" not in err
    assert sorted(p.name for p in small_case.parent.iterdir()) == ["small.toml"]


def test_ctrl_c_during_the_write_leaves_no_file(small_case, fake_run, monkeypatch):
    real = xr.Dataset.to_netcdf

    def slow_write(self, path, *args, **kwargs):
        real(self, path, *args, **kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(xr.Dataset, "to_netcdf", slow_write)
    assert cli.main(["run", str(small_case)]) == 130
    assert sorted(p.name for p in small_case.parent.iterdir()) == ["small.toml"]


def test_progress_lines_and_bar():
    lines = stdio.StringIO()
    p = cli.Progress(stream=lines, tty=False)
    for f in np.linspace(0, 1, 101):
        p("spot density", f)
    p("tracer", 0.0)
    p("tracer", 0.5)
    assert lines.getvalue().splitlines() == [
        "spotpde: spot density 0%", "spotpde: spot density 25%", "spotpde: spot density 50%",
        "spotpde: spot density 75%", "spotpde: spot density 100%", "spotpde: tracer 0%",
        "spotpde: tracer 50%"]
    bar = stdio.StringIO()
    p = cli.Progress(stream=bar, tty=True)
    for f in np.linspace(0, 1, 11):
        p("tracer", f)
    p.close()
    assert "spotpde: tracer" in bar.getvalue() and "100%" in bar.getvalue()


# -- plot -----------------------------------------------------------------------------

@pytest.mark.parametrize("variant", ["layers", "blob 3d", "no tracer"])
def test_plot_writes_a_png(tmp_path, variant, capsys):
    text = SMALL
    if variant == "blob 3d":
        text = text.replace("layers = { spacing = 2.0 }",
                            "start = { x = 1.0, z = 5.0, width = 1.0 }")
        text = text.replace("[domain]", "[domain]\ndims = 3")
    elif variant == "no tracer":
        text = text.split("[tracer]")[0] + "[output]\npath = \"small.nc\"\n"
    case = load_case(tomllib.loads(text))
    nc = sio.write_netcdf(fake_dataset(case), tmp_path / "r.nc")
    other = variant == "blob 3d"
    args = ["plot", str(nc)] + (["-o", str(tmp_path / "g.png")] if other else [])
    assert cli.main(args) == 0
    png = tmp_path / ("g.png" if other else "r.png")
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert png.stat().st_size > 10_000
    assert "wrote" in capsys.readouterr().err


def test_plot_of_unreadable_input_exits_2(tmp_path, capsys):
    assert cli.main(["plot", str(tmp_path / "none.nc")]) == 2
    (tmp_path / "junk.nc").write_text("junk")
    assert cli.main(["plot", str(tmp_path / "junk.nc")]) == 2
    err = capsys.readouterr().err
    assert "no such result file" in err and "not a readable netCDF file" in err
    assert not list(tmp_path.glob("*.png"))


# -- the real process ---------------------------------------------------------------

def _spotpde(*args, **kwargs):
    return subprocess.run([sys.executable, "-m", "spotpde", *args], capture_output=True,
                          text=True, timeout=120, **kwargs)


def test_process_exit_status_and_no_traceback(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[spots]\nb = -1.0\n")
    r = _spotpde("run", str(bad), cwd=tmp_path)
    assert r.returncode == 2
    assert r.stderr == "spots.b: must be > 0, got -1.0\n"
    assert r.stdout == ""
    assert _spotpde("check", str(ROOT / "cases" / "quasi2d_layers.toml")).returncode == 0


def test_sigint_stops_a_run_with_130_and_no_file(tmp_path):
    (tmp_path / "small.toml").write_text(SMALL)
    script = textwrap.dedent("""
        import sys, time
        import spotpde.app.pipeline, spotpde.cli
        def slow(case, progress=None, **_):
            progress("spot density", 0.0)
            while True:
                time.sleep(0.05)
        spotpde.app.pipeline.run = slow
        sys.exit(spotpde.cli.main(["run", "small.toml"]))
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=tmp_path,
                            stderr=subprocess.PIPE, text=True)
    try:
        for _ in range(50):                      # skip any warnings printed first
            line = proc.stderr.readline()
            if line.startswith("spotpde: spot density 0%") or not line:
                break
        assert line.startswith("spotpde: spot density 0%")
        proc.send_signal(signal.SIGINT)
        err = proc.stderr.read()
        assert proc.wait(timeout=30) == 130
    finally:
        if proc.poll() is None:
            proc.kill()
    assert "Traceback" not in err and "interrupted" in err
    assert sorted(os.listdir(tmp_path)) == ["small.toml"]


#: sitecustomize of the early-signal test: the process sends itself a signal when it
#: starts importing one module (a deterministic moment inside the imports, whatever the load)
SIGNAL_ON_IMPORT = """
import os, signal, sys

class SignalOnImport:
    def find_spec(self, name, path=None, target=None):
        if name == os.environ["SPOTPDE_TEST_MODULE"]:
            sys.meta_path.remove(self)
            os.kill(os.getpid(), getattr(signal, os.environ["SPOTPDE_TEST_SIGNAL"]))
        return None

sys.meta_path.insert(0, SignalOnImport())
"""


@pytest.mark.parametrize("module,sig", [("numba", "SIGINT"), ("netCDF4", "SIGTERM"),
                                        ("netCDF4", "SIGINT")])
def test_a_signal_during_the_imports_is_a_quiet_interrupt(tmp_path, module, sig):
    """``spotpde run`` signalled while it imports its libraries (numba: while it validates
    the case; netCDF4: once the spot density stage has started) exits with 130 or
    128 + n and one line, no traceback, no file: the signal is acted upon after the
    imports."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(SIGNAL_ON_IMPORT)
    work = tmp_path / "work"
    work.mkdir()
    (work / "small.toml").write_text(SMALL)
    env = dict(os.environ, PYTHONPATH=f"{site}{os.pathsep}{ROOT}", MPLBACKEND="Agg",
               SPOTPDE_TEST_MODULE=module, SPOTPDE_TEST_SIGNAL=sig)
    r = subprocess.run([sys.executable, "-m", "spotpde", "run", "small.toml", "--plot"],
                       cwd=work, env=env, capture_output=True, text=True, timeout=300)
    signum = getattr(signal, sig)
    assert r.returncode == (130 if signum == signal.SIGINT else 128 + signum), r.stderr
    lines = [line for line in r.stderr.splitlines() if not line.endswith("%")]
    assert "Traceback" not in r.stderr and len(lines) == 1, r.stderr
    assert lines[0].endswith("no result written")
    assert sorted(os.listdir(work)) == ["small.toml"]


def test_a_run_computes_its_spot_density_and_fields_once(small_case, monkeypatch, capsys):
    """The run-time estimate is made from the fields of the run itself (not recomputed),
    after the particle-fields stage and before the tracer stage."""
    from spotpde.density import spot_density

    calls = []
    solve, fields = spot_density.solve, pipeline.case_fields
    monkeypatch.setattr(spot_density, "solve",
                        lambda *a, **k: calls.append("rho_s") or solve(*a, **k))
    monkeypatch.setattr(pipeline, "case_fields",
                        lambda *a, **k: calls.append("fields") or fields(*a, **k))
    assert cli.main(["run", str(small_case)]) == 0
    assert calls == ["rho_s", "fields"]
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "spotpde: spot density 0%"
    estimate = next(i for i, line in enumerate(err) if "steps of dt" in line)
    assert err.index("spotpde: particle fields 100%") < estimate
    tracer = next(i for i, line in enumerate(err) if line.startswith("spotpde: tracer ")
                  and line.endswith("%"))
    assert estimate < tracer


def test_real_run_of_a_tiny_case(small_case, capsys):
    assert cli.main(["run", str(small_case), "--plot"]) == 0
    ds = sio.read_netcdf(small_case.parent / "small.nc")
    assert ds.P.dims == ("t", "z", "x") and ds.sizes["t"] == 3
    assert (small_case.parent / "small.png").is_file()
    np.testing.assert_allclose((ds.mass + ds.outflow).values, 1.0, atol=1e-6)
