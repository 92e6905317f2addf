"""Faults a user meets outside the happy path, each reproduced with real processes.

Every command runs as ``python -m spotpde`` in a subprocess: exit statuses, the
one-line messages on standard error, files left (or not left) behind, signals
(SIGTERM, SIGHUP; signals to a sweep are in test_sweep.py), ``resource.setrlimit`` for
a full disk, a non-root user without a writable HOME, a read-only directory, and
servers that are not Dask schedulers.
"""

from __future__ import annotations

import os
import pathlib
import resource
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import spotpde
from spotpde.app import io as sio
from spotpde.app.cases import estimate_bytes, kernel_halfwidths, load_case, validate
from conftest import FIELDS, session_dir

ROOT = Path(__file__).resolve().parents[2]

#: the same with a tracer that runs for a long time (for the signals)
LONG = FIELDS + """
[tracer]
start = { x = 0.0, z = 6.0, width = 1.0 }
limiter = "upwind"
t_end = 1.0e6
frames = 3
"""
#: a bigger field-only case: its result file is well over 64 kB
BIG = FIELDS.replace("x = [-4.0, 4.0]", "x = [-16.0, 16.0]").replace(
    "z = [0.0, 8.0]", "z = [0.0, 32.0]").replace("spacing = 0.5", "spacing = 0.25")

_CACHE = str(session_dir("faults-cache"))   # removed with the session (conftest)


def cli(*args, cwd, env=None, timeout=300, prefix=(), **popen):
    """Run ``spotpde ARGS`` in a new process (after ``prefix``, e.g. ``setpriv ...``);
    returns the CompletedProcess (text)."""
    full = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg", SPOTPDE_CACHE_DIR=_CACHE)
    full.update(env or {})
    return subprocess.run([*prefix, sys.executable, "-m", "spotpde", *map(str, args)],
                          cwd=cwd,
                          env={k: v for k, v in full.items() if v is not None},
                          capture_output=True, text=True, timeout=timeout, **popen)


def one_line(proc) -> str:
    lines = proc.stderr.strip().splitlines()
    assert "Traceback" not in proc.stderr, proc.stderr
    assert len(lines) == 1, proc.stderr
    return lines[0]


def leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.endswith(".tmp"))


@pytest.fixture(scope="module")
def result_dir(tmp_path_factory):
    """A directory with the field-only case and its result (also warms numba's cache)."""
    d = tmp_path_factory.mktemp("faults")
    (d / "c.toml").write_text(FIELDS)
    proc = cli("run", "c.toml", "-q", cwd=d)
    assert proc.returncode == 0, proc.stderr
    return d


def test_result_file_carries_cf_metadata(result_dir):
    """CF-1.10: units "1" (not UDUNITS' day "d"), axes, history naming the case file."""
    ds = sio.read_netcdf(result_dir / "r.nc")
    assert ds.attrs["Conventions"] == "CF-1.10"
    assert "c.toml" in ds.attrs["history"] and ds.attrs["source"].startswith("spotpde")
    assert "Bazant" in ds.attrs["references"]
    assert ds.z.attrs["positive"] == "up" and ds.z.attrs["axis"] == "Z"
    assert {ds[v].attrs["units"] for v in list(ds.data_vars) + list(ds.coords)} == {"1"}
    assert ds.u_z.attrs["spotpde_units"] == "d t-1"
    assert ds.u_z.attrs["long_name"].endswith("in d per time unit")


# -- outputs that are inputs or other outputs ---------------------------------------------

@pytest.mark.parametrize("args, victim, key", [
    (["run", "c.toml", "-o", "c.toml"], "c.toml", "output.path"),
    (["run", "c.toml", "-o", "r.png", "--plot"], None, "--plot"),
    (["run", "c.toml", "-o", "r.nc", "--plot", "r.nc"], "r.nc", "--plot"),
    (["plot", "r.nc", "-o", "r.nc"], "r.nc", "-o"),
    (["sweep", "c.toml", "--set", "spots.b=1,2", "-o", "c.toml"], "c.toml", "-o"),
])
def test_output_that_is_an_input_or_another_output_is_refused(result_dir, args, victim, key):
    before = {p.name: p.read_bytes() for p in result_dir.iterdir() if p.is_file()}
    proc = cli(*args, cwd=result_dir)
    assert proc.returncode == 2
    assert one_line(proc).startswith(f"{key}: ")
    after = {p.name: p.read_bytes() for p in result_dir.iterdir() if p.is_file()}
    assert after == before          # nothing replaced, nothing added
    if victim:
        assert victim in proc.stderr


def test_the_same_file_under_another_name_is_caught(result_dir):
    link = result_dir / "alias.toml"
    link.symlink_to(result_dir / "c.toml")
    try:
        proc = cli("run", "c.toml", "-o", "alias.toml", cwd=result_dir)
    finally:
        link.unlink()
    assert proc.returncode == 2 and "input file" in one_line(proc)
    assert (result_dir / "c.toml").read_text() == FIELDS


# -- targets that are not regular files -------------------------------------------------

@pytest.mark.parametrize("kind", ["fifo", "device", "directory"])
def test_output_onto_a_non_regular_file_is_refused(result_dir, tmp_path, kind):
    if kind == "fifo":
        target = tmp_path / "pipe.nc"
        os.mkfifo(target)
    elif kind == "device":
        target = Path("/dev/null")
    else:
        target = tmp_path / "dir.nc"
        target.mkdir()
    mode = os.stat(target).st_mode
    proc = cli("run", "c.toml", "-o", target, cwd=result_dir)
    assert proc.returncode == 2
    assert one_line(proc).startswith("output.path: ")
    assert os.stat(target).st_mode == mode        # still the FIFO / device / directory


def test_plot_onto_an_existing_directory_is_refused_before_computing(result_dir, tmp_path):
    fig = tmp_path / "fig.png"
    fig.mkdir()
    proc = cli("run", "c.toml", "-o", tmp_path / "out.nc", "--plot", fig, cwd=result_dir)
    assert proc.returncode == 2 and one_line(proc).startswith("--plot: ")
    assert "directory" in proc.stderr
    assert not (tmp_path / "out.nc").exists()      # refused before computing


@pytest.mark.parametrize("args", [["plot", "r.nc", "-o", "fig.xyz"],
                                  ["compare", "c.toml", "-o", "fig.xyz"]])
def test_unsupported_figure_formats_are_refused(result_dir, args):
    proc = cli(*args, cwd=result_dir)
    assert proc.returncode == 2
    line = one_line(proc)
    assert line.startswith("-o: unsupported format '.xyz'") and ".png" in line
    assert not (result_dir / "fig.xyz").exists()


# -- unwritable outputs, checked before computing -------------------------------------------

def test_file_name_too_long_for_its_temporary_sibling(result_dir):
    name = "a" * (255 - 3) + ".nc"        # 255 bytes: legal, but not with a .tmp sibling
    proc = cli("run", "c.toml", "-o", name, cwd=result_dir)
    assert proc.returncode == 2
    line = one_line(proc)
    assert line.startswith("output.path: ") and "too long" in line
    assert leftovers(result_dir) == []


@pytest.fixture
def public_dir():
    """A world-readable scratch directory (tmp_path is private to root)."""
    d = Path(tempfile.mkdtemp(prefix="spotpde-faults-"))
    d.chmod(0o755)
    yield d
    shutil.rmtree(d, ignore_errors=True)


def _unprivileged() -> list[str]:
    """A command prefix that makes root obey file permissions (drops CAP_DAC_OVERRIDE),
    as an ordinary user does; nothing for a non-root user."""
    if os.geteuid() != 0:
        return []
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv: file permissions cannot be tested")
    return ["setpriv", "--bounding-set=-dac_override,-dac_read_search"]


def test_read_only_directory_and_no_writable_home(public_dir):
    """A user without a writable HOME (numba's cache falls back to a temporary
    directory) and a read-only output directory (refused before computing, exit 2)."""
    (public_dir / "c.toml").write_text(FIELDS)
    (public_dir / "c.toml").chmod(0o644)
    ro = public_dir / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    env = {"HOME": "/nonexistent/home", "XDG_CACHE_HOME": None, "NUMBA_CACHE_DIR": None,
           "SPOTPDE_CACHE_DIR": None}
    if os.geteuid() == 0:
        env["HOME"] = str(public_dir / "c.toml")     # under a file: never creatable
    proc = cli("run", "c.toml", "-o", ro / "r.nc", cwd=public_dir, env=env,
               prefix=_unprivileged())
    assert proc.returncode == 2, proc.stderr
    line = one_line(proc)
    assert line.startswith("output.path: cannot write in") and str(ro) in line
    # the same user can run: numba compiles into the fallback cache
    proc = cli("run", "c.toml", "-o", public_dir / "ok.nc", "-q", cwd=public_dir, env=env,
               prefix=_unprivileged())
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert (public_dir / "ok.nc").is_file()


def test_numba_cache_is_never_written_into_the_package(tmp_path):
    """Without NUMBA_CACHE_DIR, spotpde points numba at the user cache directory."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), HOME=str(tmp_path), XDG_CACHE_HOME="")
    env.pop("NUMBA_CACHE_DIR", None)
    env.pop("SPOTPDE_CACHE_DIR", None)
    code = ("import os, spotpde, numba; from spotpde.density import _marching; "
            "print(os.environ['NUMBA_CACHE_DIR']); print(numba.config.CACHE_DIR)")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True, timeout=300).stdout.split()
    expected = str(tmp_path / ".cache" / "spotpde" / "numba")
    assert out == [expected, expected]
    # a user's own NUMBA_CACHE_DIR is respected
    env["NUMBA_CACHE_DIR"] = str(tmp_path / "mine")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True, timeout=300).stdout.split()
    assert out == [str(tmp_path / "mine")] * 2


# -- disk full ------------------------------------------------------------------------------

def _limit_file_size(limit):
    def apply():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return apply


def test_disk_full_exits_1_with_one_line_and_leaves_nothing(tmp_path):
    (tmp_path / "big.toml").write_text(BIG)
    # warm the cache without a limit (numba's cache files are larger than the limit)
    assert cli("run", "big.toml", "-q", "-o", "warm.nc", cwd=tmp_path).returncode == 0
    os.unlink(tmp_path / "warm.nc")
    proc = cli("run", "big.toml", "-q", "-o", "big.nc", cwd=tmp_path,
               preexec_fn=_limit_file_size(64 * 1024))
    assert proc.returncode == 1, proc.stderr
    line = one_line(proc)
    assert line.startswith("spotpde: could not write") and "big.nc" in line
    assert not (tmp_path / "big.nc").exists()
    assert leftovers(tmp_path) == []


def test_frame_writer_removes_its_file_when_the_disk_fills(tmp_path):
    """FrameWriter under RLIMIT_FSIZE: a WriteError, no temporary file, closed once."""
    grid = load_case({"domain": {"x": [-16.0, 16.0], "z": [0.0, 32.0],
                                 "spacing": 0.25}}).grid
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    rng = np.random.default_rng(0)
    resource.setrlimit(resource.RLIMIT_FSIZE, (256 * 1024, hard))
    try:
        with pytest.raises(OSError, match="could not write"):
            with sio.FrameWriter(tmp_path / "r.nc", grid, 20) as writer:
                for i in range(20):          # incompressible frames: 128 kB each
                    writer(i, float(i), rng.random(grid.shape))
                writer.finish(xr.Dataset())
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    assert list(tmp_path.iterdir()) == []
    writer.abort()                            # safe to call again


# -- signals --------------------------------------------------------------------------------

@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_behave_like_ctrl_c(tmp_path, sig):
    (tmp_path / "long.toml").write_text(LONG)
    env = dict(os.environ, PYTHONPATH=str(ROOT), SPOTPDE_CACHE_DIR=_CACHE)
    proc = subprocess.Popen([sys.executable, "-m", "spotpde", "run", "long.toml", "-q"],
                            cwd=tmp_path, env=env, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 240
    while not leftovers(tmp_path):            # the run is under way: its temporary file
        assert proc.poll() is None, proc.stderr.read()
        assert time.monotonic() < deadline
        time.sleep(0.05)
    time.sleep(0.5)
    proc.send_signal(sig)
    err = proc.communicate(timeout=120)[1]
    assert proc.returncode == 128 + sig, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert "no result written" in err
    assert leftovers(tmp_path) == [] and not (tmp_path / "r.nc").exists()


# -- plot on the wrong kind of file ----------------------------------------------------------

def test_plot_refuses_a_sweep_result_and_other_dimensions(result_dir, tmp_path):
    ds = sio.read_netcdf(result_dir / "r.nc")
    sweep = xr.concat([ds, ds], dim="kernel_size").assign_coords(kernel_size=[1.0, 2.0])
    sweep.attrs["sweep_keys"] = "kernel.size"
    sweep.to_netcdf(tmp_path / "sweep.nc")
    proc = cli("plot", "sweep.nc", cwd=tmp_path)
    assert proc.returncode == 2
    line = one_line(proc)
    assert "not a single-run result" in line and "kernel_size" in line
    other = xr.Dataset({name: (("a", "b"), np.zeros((3, 4))) for name in sio.REQUIRED})
    other.to_netcdf(tmp_path / "other.nc")
    proc = cli("plot", "other.nc", cwd=tmp_path)
    assert proc.returncode == 2 and "not a single-run result" in one_line(proc)
    assert not (tmp_path / "sweep.png").exists() and not (tmp_path / "other.png").exists()


# -- sweeps: schedulers that are not, a truncated member (Ctrl-C: test_sweep.py) ------------

def test_scheduler_that_is_not_an_address(result_dir):
    proc = cli("sweep", "c.toml", "--set", "spots.b=1,2", "-o", "s.nc", "--scheduler",
               "not an address", cwd=result_dir)
    assert proc.returncode == 2
    assert one_line(proc).startswith("--scheduler: not a Dask scheduler address")


def _serve(banner: bytes | None):
    """A local TCP server: sends ``banner`` on connect, or accepts and stays silent."""
    srv = socket.create_server(("127.0.0.1", 0))
    conns = []

    def loop():
        while True:
            try:
                conn, _ = srv.accept()
            except OSError:
                return
            conns.append(conn)
            if banner:
                conn.sendall(banner)

    threading.Thread(target=loop, daemon=True).start()
    return srv, conns


@pytest.mark.parametrize("banner, words", [
    (b"SSH-2.0-OpenSSH_9.6\r\n" + b"\xff" * 64, "is not a Dask scheduler"),
    (None, "no Dask scheduler at"),
])
def test_scheduler_that_answers_with_a_banner_or_stays_silent(result_dir, banner, words):
    srv, conns = _serve(banner)
    port = srv.getsockname()[1]
    try:
        t0 = time.monotonic()
        proc = cli("sweep", "c.toml", "--set", "spots.b=1,2", "-o", "s.nc", "--scheduler",
                   f"tcp://127.0.0.1:{port}", cwd=result_dir,
                   env={"SPOTPDE_CONNECT_TIMEOUT": "3"}, timeout=120)
        took = time.monotonic() - t0
    finally:
        srv.close()
        for c in conns:
            c.close()
    assert proc.returncode == 2, proc.stderr
    assert words in one_line(proc)
    assert took < 100          # the connect timeout applies (it would hang forever)
    assert not (result_dir / "s.nc").exists()


@pytest.mark.slow
def test_sweep_recomputes_a_truncated_member(result_dir, tmp_path):
    shutil.copy(result_dir / "c.toml", tmp_path / "c.toml")
    args = ("sweep", "c.toml", "--set", "spots.b=1,2", "-o", "s.nc", "--workers", "1")
    first = cli(*args, cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    reference = sio.read_netcdf(tmp_path / "s.nc")
    members = sorted((tmp_path / "s.nc.members").glob("*.nc"))
    assert len(members) == 2
    blob = members[0].read_bytes()
    members[0].write_bytes(blob[: len(blob) // 3])          # truncated by a crash
    again = cli(*args, cwd=tmp_path)
    assert again.returncode == 0 and "Traceback" not in again.stderr, again.stderr
    assert "1/2 members finished" in again.stderr          # one read, one recomputed
    redone = sio.read_netcdf(tmp_path / "s.nc")
    np.testing.assert_allclose(redone["rho_s"].values, reference["rho_s"].values)
    assert redone["rho_s"].dims[:1] == ("spots_b",)


# -- cases and the Python API ----------------------------------------------------------------

def test_utf8_bom_is_accepted(tmp_path):
    (tmp_path / "bom.toml").write_bytes(b"\xef\xbb\xbf" + FIELDS.encode())
    proc = cli("check", "bom.toml", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert load_case(tmp_path / "bom.toml").data == load_case(
        {"domain": {"x": [-4.0, 4.0], "z": [0.0, 8.0], "spacing": 0.5},
         "orifice": {"width": 2.0}, "output": {"path": "r.nc"}}).data


def test_python_api_accepts_numpy_numbers_arrays_and_paths(tmp_path):
    plain = {"domain": {"dims": 2, "x": [-4.0, 4.0], "z": [0.0, 8.0], "spacing": 0.5},
             "orifice": {"width": 2.0},
             "tracer": {"start": {"x": 0.0, "z": 6.0, "width": 1.0}, "frames": 3,
                        "t_end": 1.0},
             "output": {"path": str(tmp_path / "r.nc")}}
    numpy = {"domain": {"dims": np.int64(2), "x": np.array([-4.0, 4.0]),
                        "z": (np.float32(0.0), np.int32(8)), "spacing": np.float64(0.5)},
             "orifice": {"width": np.float64(2.0)},
             "tracer": {"start": {"x": np.int64(0), "z": np.float64(6.0), "width": 1.0},
                        "frames": np.int16(3), "t_end": np.float64(1.0)},
             "output": {"path": pathlib.Path(tmp_path / "r.nc")}}
    assert validate(numpy) == validate(plain)
    assert isinstance(validate(numpy)["tracer"]["frames"], int)


def test_run_to_a_missing_directory_raises_naming_the_path_before_computing(monkeypatch,
                                                                            tmp_path):
    from spotpde.app import pipeline

    def never(*args, **kwargs):
        raise AssertionError("computed before checking the output path")

    monkeypatch.setattr(pipeline, "_run", never)
    case = load_case({"domain": {"x": [-4.0, 4.0], "z": [0.0, 8.0], "spacing": 0.5}})
    missing = tmp_path / "no" / "such" / "r.nc"
    with pytest.raises(ValueError, match=r"^path: the directory .*no/such does not exist"):
        spotpde.run(case, path=missing)
    with pytest.raises(ValueError, match="^path: is a directory"):
        spotpde.run(case, path=tmp_path)


def test_uniform_kernel_implying_w_above_1_is_refused(tmp_path):
    (tmp_path / "w.toml").write_text(FIELDS + """
[kernel]
shape = "uniform"
size = 0.01
volume = 0.05
""")
    proc = cli("check", "w.toml", cwd=tmp_path)
    assert proc.returncode == 2
    line = one_line(proc)
    assert line.startswith("kernel.volume: ") and "w = volume / spot area = 159" in line


def test_kernel_wider_than_the_domain_warns(tmp_path):
    wide = FIELDS + '\n[kernel]\nshape = "gaussian"\nsize = 5.0\n'
    (tmp_path / "wide.toml").write_text(wide)
    proc = cli("check", "wide.toml", cwd=tmp_path)
    assert proc.returncode == 0
    lines = proc.stderr.strip().splitlines()
    assert lines[0].startswith("spotpde: warning: kernel.size: the kernel (10.0 d wide")
    assert "is valid" in lines[-1]
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        load_case(tmp_path / "wide.toml")
    assert any("wider than the domain" in str(w.message) for w in seen)


def test_check_and_run_agree_on_a_missing_output_directory(tmp_path):
    (tmp_path / "c.toml").write_text(FIELDS.replace('path = "r.nc"', 'path = "no/r.nc"'))
    check = cli("check", "c.toml", cwd=tmp_path)
    run = cli("run", "c.toml", cwd=tmp_path)
    assert check.returncode == run.returncode == 2
    assert one_line(check) == one_line(run)
    assert "output.path: the directory" in one_line(check)


# -- the memory estimate -------------------------------------------------------------------

@pytest.mark.parametrize("shape, cells", [("gaussian", 65), ("exponential", 259),
                                          ("uniform", 9)])
def test_memory_estimate_uses_the_kernels_own_stencil(shape, cells):
    # (the mean field: no passage quadrature, whose peak would outgrow these arrays)
    data = validate({"domain": {"x": [-8.0, 8.0], "z": [0.0, 16.0], "spacing": 0.25},
                     "kernel": {"shape": shape, "size": 1.0, "volume": 0.05,
                                "diffusivity": "mean-field"}})
    mz, mh = kernel_halfwidths(data)
    assert 2 * mz + 1 == 2 * mh + 1 == cells
    k = spotpde.kernels.from_spec(shape, 1.0, 0.05, 1.0, 2)
    assert k.sample(0.25).shape == (cells, cells)
    # the estimate grows with the stencil: padded FFT arrays of (n + s)**2 complex numbers
    n = 64
    small = dict(data, kernel=dict(data["kernel"], size=0.25))
    grow = estimate_bytes(data) - estimate_bytes(small)
    ms, _ = kernel_halfwidths(small)
    s, s0 = cells, 2 * ms + 1
    expected = 16.0 * 6 * ((n + s) ** 2 - (n + s0) ** 2) + 16.0 * (s * s - s0 * s0)
    assert grow == pytest.approx(expected, rel=1e-9)


def test_memory_refusals_name_the_key_that_causes_them(monkeypatch):
    from spotpde.app import cases

    monkeypatch.setattr(cases, "available_memory", lambda: 2 * 1024**3)
    base = {"domain": {"x": [-8.0, 8.0], "z": [0.0, 16.0], "spacing": 0.25}}

    def refusal(**tables):
        raw = {**base, **{k: dict(base.get(k, {}), **v) for k, v in tables.items()}}
        with pytest.raises(spotpde.CaseError) as err:
            validate(raw)
        assert len(err.value.problems) == 1
        return err.value.problems[0]

    assert refusal(kernel={"shape": "exponential", "size": 40.0}).startswith("kernel.size: ")
    assert refusal(kernel={"shape": "gaussian", "size": 1.0, "aspect": 0.0005}).startswith(
        "kernel.aspect: ")
    assert refusal(domain={"walls": "open", "z": [0.0, 16.0]},
                   spots={"b": 1.0e5}).startswith("spots.b: ")
    assert refusal(domain={"spacing": 0.001}).startswith("domain.spacing: ")
