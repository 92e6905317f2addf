"""Faults of figure writing (issue 30, items 1, 2, 3, 15, 16, 18), each reproduced.

Every figure goes through one atomic writer, :func:`spotpde._figures.save_figure`.
Interruptions, full disks and races are made deterministic by replacing
``Figure.savefig`` with a function that writes part of a figure into the file it is
given and then sends the process a real SIGTERM or raises the ``OSError`` of a full disk,
or that waits at a barrier until every writer is inside it. Commands run in-process
through :func:`spotpde.cli.main` (solvers replaced by the fake result of test_cli),
except where the process itself matters (a file-size limit, the quick exit after
``run``, the modules ``plot`` imports).
"""

from __future__ import annotations

import errno
import os
import re
import resource
import signal
import subprocess
import sys
import threading
import tomllib
from pathlib import Path

import pytest
from matplotlib.figure import Figure

from spotpde import _figures
from spotpde import cli
from spotpde.app import _outputs, pipeline, plotting
from spotpde.app import io as sio
from spotpde.app.cases import load_case
from spotpde.errors import WriteError

from test_cli import SMALL, fake_dataset

from conftest import FIELDS

ROOT = Path(__file__).resolve().parents[2]
PNG = b"\x89PNG\r\n\x1a\n"
OLD = b"the user's old figure, which must survive"

#: a field-only case the comparison with the Kinematic Model accepts (a few seconds)
COMPARE = """
[domain]
x = [-12.0, 12.0]
z = [0.0, 20.0]
spacing = 1.0

[orifice]
width = 2.0

[output]
path = "r.nc"
"""

#: leading bytes of each format matplotlib writes for spotpde
MAGIC = {"png": [PNG], "pdf": [b"%PDF"], "svg": [b"<?xml", b"<svg"], "svgz": [b"\x1f\x8b"],
         "eps": [b"%!PS-Adobe-3.0 EPSF"], "ps": [b"%!PS"], "jpg": [b"\xff\xd8\xff"],
         "jpeg": [b"\xff\xd8\xff"], "tif": [b"II*\x00", b"MM\x00*"],
         "tiff": [b"II*\x00", b"MM\x00*"], "webp": [b"RIFF"]}


def leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.startswith(".")
                  or p.name.endswith(".tmp"))


def one_line(err: str, command: str = "") -> str:
    """The one line a command printed (after ``run``'s line naming its result)."""
    lines = err.strip().splitlines()
    assert "Traceback" not in err and len(lines) == (2 if command == "run --plot" else 1), err
    return lines[-1]


def env(**changes):
    full = dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg")
    full.update(changes)
    return {k: v for k, v in full.items() if v is not None}


@pytest.fixture(autouse=True)
def _signal_handlers():
    """cli.main installs SIGTERM/SIGHUP handlers; put the previous ones back."""
    saved = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGHUP)}
    yield
    for s, handler in saved.items():
        signal.signal(s, handler)


@pytest.fixture
def work(tmp_path, monkeypatch):
    """A directory with the small case, its fake result r.nc, and an old figure."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "small.toml").write_text(SMALL)
    (tmp_path / "cmp.toml").write_text(COMPARE)
    sio.write_netcdf(fake_dataset(load_case(tomllib.loads(SMALL))), tmp_path / "r.nc")
    return tmp_path


@pytest.fixture(scope="module")
def comparisons():
    from spotpde.analysis.comparison import compare_rules

    return compare_rules(load_case(tomllib.loads(COMPARE)), [0.5, 1.0])


@pytest.fixture
def commands(work, monkeypatch, comparisons):
    """Each figure-writing command, as an argument list writing ``fig.<ext>``; the
    solvers are replaced by the fake result and the comparison computed once."""
    def run(case, progress=None, *, path=None, on_fields=None):
        ds = fake_dataset(case)
        if path is not None:
            sio.write_netcdf(ds, path)
        return ds

    monkeypatch.setattr(pipeline, "run", run)
    import spotpde.analysis.comparison as comparison
    monkeypatch.setattr(comparison, "compare_rules", lambda case, rules: comparisons)
    return {"plot": lambda name: ["plot", "r.nc", "-o", name],
            "run --plot": lambda name: ["run", "small.toml", "-q", "-o", "out.nc",
                                        "--plot", name],
            "compare": lambda name: ["compare", "cmp.toml", "-o", name]}


def _partial(fname):
    """Write the start of a PNG into what savefig was given (a path or a file)."""
    if hasattr(fname, "write"):
        fname.write(PNG + b"truncated")
        fname.flush()
    else:
        Path(fname).write_bytes(PNG + b"truncated")


# -- item 1: interrupted writes leave the old figure --------------------------------------

@pytest.mark.parametrize("command", ["compare", "plot", "run --plot"])
def test_sigterm_while_a_figure_is_written_keeps_the_old_one(commands, work, monkeypatch,
                                                              command, capsys):
    """Item 1: ``compare -o cmp.png`` wrote in place; a SIGTERM while writing left a
    truncated PNG where the old figure was."""
    def savefig(self, fname, *args, **kwargs):
        _partial(fname)
        os.kill(os.getpid(), signal.SIGTERM)     # handled as Terminated at once
        raise AssertionError("SIGTERM was not delivered")

    (work / "fig.png").write_bytes(OLD)
    capsys.readouterr()
    monkeypatch.setattr(Figure, "savefig", savefig)
    status = cli.main(commands[command]("fig.png"))
    assert status == 128 + signal.SIGTERM
    assert "terminated by signal 15" in one_line(capsys.readouterr().err, command)
    assert (work / "fig.png").read_bytes() == OLD
    assert leftovers(work) == []


def test_ctrl_c_in_the_library_writer_removes_its_temporary(tmp_path, monkeypatch):
    def savefig(self, fname, *args, **kwargs):
        _partial(fname)
        raise KeyboardInterrupt

    (tmp_path / "f.pdf").write_bytes(OLD)
    monkeypatch.setattr(Figure, "savefig", savefig)
    with pytest.raises(KeyboardInterrupt):
        _figures.save_figure(Figure(), tmp_path / "f.pdf")
    assert (tmp_path / "f.pdf").read_bytes() == OLD
    assert leftovers(tmp_path) == []


def test_every_figure_in_the_package_goes_through_the_atomic_writer():
    """No other ``savefig`` onto a path: one writer, atomic for every command and for
    the library's ``path=`` arguments."""
    calls = []
    for path in (ROOT / "spotpde").rglob("*.py"):
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if re.search(r"\.savefig\(", line) and not line.lstrip().startswith("#"):
                calls.append(f"{path.relative_to(ROOT)}:{n}")
    assert [c.split(":")[0] for c in calls] == ["spotpde/_figures.py"], calls


# -- item 2: no predictable temporary name, no race ----------------------------------------

def test_a_planted_symlink_cannot_redirect_the_figure_onto_the_input(work, capsys):
    """Item 2: with ``ln -s r.nc .fig.png.tmp.png``, ``plot r.nc -o fig.png`` overwrote
    the input r.nc with PNG data and exited 0."""
    before = (work / "r.nc").read_bytes()
    (work / ".fig.png.tmp.png").symlink_to("r.nc")
    assert cli.main(["plot", "r.nc", "-o", "fig.png"]) == 0
    assert (work / "r.nc").read_bytes() == before
    assert os.readlink(work / ".fig.png.tmp.png") == "r.nc"
    assert (work / "fig.png").read_bytes().startswith(PNG)
    assert leftovers(work) == [".fig.png.tmp.png"]       # only the planted link


def test_concurrent_plots_to_one_name_all_succeed(work, monkeypatch, capsys):
    """Item 2: four concurrent plots to one name; 3 failed with "No such file or
    directory" (one fixed temporary name, renamed away by the first). Every writer here
    has drawn its temporary file before any of them renames."""
    writers = 4
    barrier = threading.Barrier(writers, timeout=120)
    drawing = threading.Lock()
    original = Figure.savefig

    def savefig(self, *args, **kwargs):
        with drawing:
            original(self, *args, **kwargs)
        barrier.wait()

    monkeypatch.setattr(Figure, "savefig", savefig)
    statuses = [None] * writers

    def plot(i):
        statuses[i] = cli.main(["plot", "r.nc", "-o", "fig.png"])

    threads = [threading.Thread(target=plot, args=(i,)) for i in range(writers)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert statuses == [0] * writers, capsys.readouterr().err
    assert (work / "fig.png").read_bytes().startswith(PNG)
    assert leftovers(work) == []


# -- item 3: the extension's format --------------------------------------------------------

@pytest.mark.parametrize("fmt", _outputs.FIGURE_FORMATS)
def test_the_writer_writes_the_format_of_the_extension(tmp_path, fmt):
    fig = Figure(figsize=(2, 2))
    fig.subplots().plot([0, 1], [1, 0])
    _figures.save_figure(fig, tmp_path / f"f.{fmt.upper()}", dpi=30)
    data = (tmp_path / f"f.{fmt.upper()}").read_bytes()
    assert any(data.startswith(m) for m in MAGIC[fmt]), data[:20]
    if fmt == "webp":
        assert data[8:12] == b"WEBP"
    assert oct(os.stat(tmp_path / f"f.{fmt.upper()}").st_mode & 0o777) == \
        oct(0o666 & ~_figures._umask())
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("command, name, magic", [
    ("plot", "fig.svg", (b"<?xml", b"<svg")), ("run --plot", "fig.pdf", (b"%PDF",)),
    ("compare", "fig.eps", (b"%!PS-Adobe-3.0 EPSF",))])
def test_commands_write_the_format_their_extension_names(commands, work, command, name,
                                                         magic, capsys):
    """Item 3: ``--plot fig.pdf`` and ``plot -o fig.svg`` exited 0 with PNG bytes."""
    assert cli.main(commands[command](name)) == 0, capsys.readouterr().err
    assert (work / name).read_bytes().startswith(magic)


@pytest.mark.parametrize("name", ["fig.pgf", "fig", "fig.xyz"])
def test_the_library_refuses_other_extensions_by_name(work, name):
    ds = sio.read_netcdf(work / "r.nc")
    with pytest.raises(ValueError, match=r"^path: unsupported figure format .*\.png"):
        plotting.plot_result(ds, work / name)
    assert not (work / name).exists() and leftovers(work) == []


# -- item 15: results plot draws, or refuses in one line ----------------------------------

def _variant(work, name, change):
    ds = change(sio.read_netcdf(work / "r.nc"))
    ds.to_netcdf(work / name)
    return name


def test_plot_of_a_result_without_p_height_or_mass(work, capsys):
    """Item 15: a result with P but no P_height failed with an AttributeError."""
    name = _variant(work, "nop.nc", lambda ds: ds.drop_vars(["P_height", "mass", "outflow"]))
    assert cli.main(["plot", name, "-o", "nop.png"]) == 0, capsys.readouterr().err
    assert (work / "nop.png").read_bytes().startswith(PNG)


def test_plot_of_a_result_with_decreasing_z_is_the_same_figure(work, capsys):
    """Item 15: decreasing z failed in matplotlib's streamplot (ValueError). The same
    silo stored upside down draws the same figure, byte for byte."""
    name = _variant(work, "flip.nc", lambda ds: ds.isel(z=slice(None, None, -1),
                                                         x=slice(None, None, -1)))
    assert cli.main(["plot", "r.nc", "-o", "a.png"]) == 0
    assert cli.main(["plot", name, "-o", "b.png"]) == 0, capsys.readouterr().err
    assert (work / "a.png").read_bytes() == (work / "b.png").read_bytes()


def test_plot_refuses_unequal_spacing_in_one_line(work, capsys):
    def stretch(ds):
        z = ds.z.values.copy()
        z[-1] += 3.0
        return ds.assign_coords(z=z)

    name = _variant(work, "bent.nc", stretch)
    capsys.readouterr()
    assert cli.main(["plot", name, "-o", "bent.png"]) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith("bent.nc: coordinate z is not equally spaced")
    assert not (work / "bent.png").exists() and leftovers(work) == []


# -- item 16: failed writes exit 1 and name the path ----------------------------------------

@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EFBIG])
@pytest.mark.parametrize("command", ["plot", "run --plot", "compare"])
def test_a_full_disk_while_writing_a_figure_exits_1_naming_it(commands, work, monkeypatch,
                                                              command, code, capsys):
    """Item 16: failed figure writes exited 2 without naming the path."""
    def savefig(self, fname, *args, **kwargs):
        _partial(fname)
        raise OSError(code, os.strerror(code))

    (work / "fig.png").write_bytes(OLD)
    capsys.readouterr()
    monkeypatch.setattr(Figure, "savefig", savefig)
    assert cli.main(commands[command]("fig.png")) == 1
    line = one_line(capsys.readouterr().err, command)
    assert line == (f"spotpde: could not write {work / 'fig.png'} ({os.strerror(code)}); "
                    "nothing was written")
    assert (work / "fig.png").read_bytes() == OLD
    assert leftovers(work) == []


def test_a_file_size_limit_in_a_real_process(work):
    (work / "fig.png").write_bytes(OLD)

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))

    proc = subprocess.run([sys.executable, "-m", "spotpde", "plot", "r.nc", "-o", "fig.png"],
                          cwd=work, env=env(), capture_output=True, text=True, timeout=300,
                          preexec_fn=limit)
    assert proc.returncode == 1, proc.stderr
    assert one_line(proc.stderr) == (f"spotpde: could not write {work / 'fig.png'} "
                                     "(File too large); nothing was written")
    assert (work / "fig.png").read_bytes() == OLD
    assert leftovers(work) == []


def test_a_full_file_system_is_not_reported_as_permission_denied(tmp_path, monkeypatch):
    """Item 16: a completely full output file system was reported as "Permission
    denied". A file system that refuses a new file with EACCES while the directory is
    writable and statvfs shows no free block is reported as full."""
    class Full:
        f_blocks, f_bavail, f_files, f_favail = 1000, 0, 1000, 10

    def refuse(*args, **kwargs):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES))

    monkeypatch.setattr(_outputs.tempfile, "mkstemp", refuse)
    monkeypatch.setattr(_outputs.os, "statvfs", lambda d: Full)
    monkeypatch.setattr(_outputs.os, "access", lambda d, mode: True)
    msg = _outputs.output_problem(tmp_path / "fig.png")
    assert msg == (f"cannot write in {tmp_path} (No space left on device: the file "
                   f"system is full), got {str(tmp_path / 'fig.png')!r}")
    monkeypatch.setattr(_outputs.os, "access", lambda d, mode: False)
    assert "(Permission denied; the file system is full too)" in \
        _outputs.output_problem(tmp_path / "fig.png")
    Full.f_bavail = 5
    assert "(Permission denied)" in _outputs.output_problem(tmp_path / "fig.png")


def test_the_writer_names_the_path_when_its_directory_is_gone(tmp_path):
    with pytest.raises(WriteError, match=r"could not write .*gone/f\.png \(No such file"):
        _figures.save_figure(Figure(), tmp_path / "gone" / "f.png")


# -- item 18: matplotlib's temporary directories -------------------------------------------

def test_run_plot_without_a_writable_home_leaves_no_matplotlib_directory(tmp_path):
    """Item 18: with an unwritable HOME (or MPLCONFIGDIR), every ``run --plot`` left a
    ``matplotlib-XXXXXXXX`` directory in the temporary directory (the quick exit skips
    matplotlib's clean-up) and printed matplotlib's warnings."""
    (tmp_path / "c.toml").write_text(FIELDS)
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    cache = tmp_path / "cache"
    run_env = env(HOME=str(tmp_path / "c.toml"), XDG_CONFIG_HOME=None, XDG_CACHE_HOME=None,
                  MPLCONFIGDIR=None, TMPDIR=str(tmp), SPOTPDE_CACHE_DIR=str(cache))
    for unusable in ({}, {"MPLCONFIGDIR": str(tmp_path / "c.toml" / "mpl")}):
        proc = subprocess.run([sys.executable, "-m", "spotpde", "run", "c.toml", "-q",
                               "--plot"], cwd=tmp_path, env={**run_env, **unusable},
                              capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr
        lines = proc.stderr.splitlines()            # no warning from matplotlib
        assert [line.split()[:2] for line in lines] == [["spotpde:", "wrote"]] * 2, lines
        assert (tmp_path / "r.png").read_bytes().startswith(PNG)
        assert list(tmp.iterdir()) == []
        assert (cache / "matplotlib").is_dir()                # the font list persists
    # plot ends with the same quick exit
    proc = subprocess.run([sys.executable, "-m", "spotpde", "plot", "r.nc", "-o", "p.png"],
                          cwd=tmp_path, env=run_env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0 and one_line(proc.stderr).startswith("spotpde: wrote")
    assert (tmp_path / "p.png").read_bytes().startswith(PNG)
    assert list(tmp.iterdir()) == []


def test_plot_with_usable_matplotlib_directories_changes_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv("MPLCONFIGDIR", str(tmp_path))
    monkeypatch.delitem(sys.modules, "matplotlib")
    assert _figures.prepare_matplotlib() is None
    assert os.environ["MPLCONFIGDIR"] == str(tmp_path)


# -- speed: plot loads no solver ------------------------------------------------------------

def test_plot_imports_no_solver_and_no_numba(work):
    """``spotpde plot`` took 13-17 s: it must load xarray, netCDF4 and matplotlib only
    (the solvers' modules would import numba and load compiled kernels)."""
    code = ("import sys; from spotpde import cli; status = cli.main(['plot', 'r.nc']); "
            "print(status, sorted(m for m in sys.modules if m.split('.')[0] == 'numba' or "
            "m.startswith(('spotpde.density', 'spotpde.fields', 'spotpde.tracer', "
            "'spotpde.pair', 'spotpde.montecarlo', 'spotpde.calibration'))))")
    proc = subprocess.run([sys.executable, "-c", code], cwd=work, env=env(),
                          capture_output=True, text=True, timeout=300)
    assert proc.stdout.split(None, 1) == ["0", "[]\n"], proc.stdout + proc.stderr
    assert (work / "r.png").read_bytes().startswith(PNG)


def test_the_figure_layout_keeps_every_panel_inside_the_figure(work, monkeypatch):
    """The fixed layout that replaced matplotlib's constrained layout (which drew the
    figure twice): no panel, colour bar or label leaves the figure or overlaps another."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    ds = sio.read_netcdf(work / "r.nc")
    figures = []
    monkeypatch.setattr(plotting, "save_figure", lambda fig, path, **kw: figures.append(fig))
    plotting.plot_result(ds, work / "f.png")
    fig, = figures
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    box = fig.bbox
    boxes = {}
    for i, ax in enumerate(fig.axes):
        tight = ax.get_tightbbox(renderer)
        name = ax.get_title() or f"colour bar {i}"
        assert box.x0 - 1 <= tight.x0 and tight.x1 <= box.x1 + 1, name
        assert box.y0 - 1 <= tight.y0 and tight.y1 <= box.y1 + 1, name
        boxes[name] = tight
    assert sum(1 for ax in fig.axes if ax.get_title()) == 8
    names = list(boxes)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert not boxes[a].overlaps(boxes[b]), (a, b)
