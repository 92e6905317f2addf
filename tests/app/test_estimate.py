"""Run-time estimate before a tracer run (spotpde.app.estimate): the predicted number of
steps is the solver's own, and runs estimated at more than a day are refused (exit 2,
one line naming tracer.t_end or tracer.cfl) unless --allow-long."""

from __future__ import annotations

import numpy as np
import pytest

from spotpde.app import estimate
from spotpde import tracer
from spotpde.cli import main
from spotpde.grid import Grid


@pytest.mark.parametrize("diffusion,D", [("explicit", 0.01), ("implicit", 0.5)])
def test_predicted_steps_are_the_solvers(diffusion, D):
    grid = Grid(2, (-2.0, 2.0), (0.0, 4.0), 0.25)
    Z, X = grid.mesh()
    zero = 0 * X + 0 * Z
    fields = {"u_x": -0.1 * X + zero, "u_z": -1.0 - 0.2 * Z + zero, "D_xx": D + zero,
              "D_xz": zero, "D_zz": D + zero}
    P0 = np.exp(-(X**2 + (Z - 3) ** 2)) + zero
    est = estimate.tracer_steps(grid, fields, 3.0, 4, limiter="koren", cfl=0.7,
                                diffusion="auto")
    res = tracer.solve(grid, fields, P0, 3.0, 4, limiter="koren", cfl=0.7)
    assert est["steps"] == res.steps
    assert est["implicit"] == (res.options["diffusion"] == "implicit")
    assert est["implicit"] == (diffusion == "implicit")
    assert est["seconds"] > 0


def _write(tmp_path, t_end, cfl=0.9):
    text = f"""
[domain]
x = [-8.0, 8.0]
z = [0.0, 16.0]
spacing = 0.125
[orifice]
width = 2.0
[tracer]
start = {{ x = 0.0, z = 12.0, width = 0.5 }}
t_end = {t_end}
cfl = {cfl}
frames = 2
"""
    p = tmp_path / "case.toml"
    p.write_text(text)
    return str(p)


def test_day_long_runs_are_refused(tmp_path, capsys):
    path = _write(tmp_path, 1e9)
    assert main(["check", path]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("tracer.t_end: the run would take about")
    assert main(["check", path, "--allow-long"]) == 0
    out = tmp_path / "never.nc"
    assert main(["run", path, "-o", str(out)]) == 2
    assert not out.exists()
    path = _write(tmp_path, 10.0, cfl=1e-300)
    assert main(["check", path]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].startswith("tracer.cfl:")
    path = _write(tmp_path, 10.0)
    assert main(["check", path]) == 0
    assert "steps of dt" in capsys.readouterr().err


def test_a_refused_run_stops_before_the_tracer_and_its_file(tmp_path, capsys, monkeypatch):
    """``spotpde run`` estimates from the fields its pipeline computed and refuses there:
    one line (with -q), status 2, no tracer step, no result or temporary file opened."""
    from spotpde.app import pipeline

    def never(*args, **kwargs):
        raise AssertionError("a refused run must not reach this")

    monkeypatch.setattr(tracer, "solve", never)
    monkeypatch.setattr(pipeline, "FrameWriter", never)
    path = _write(tmp_path, 1e9)
    assert main(["run", path, "-o", str(tmp_path / "never.nc"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("tracer.t_end: the run would take about")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["case.toml"]
    assert main(["run", _write(tmp_path, 10.0, cfl=1e-300), "-o", str(tmp_path / "n.nc"),
                 "-q"]) == 2
    assert capsys.readouterr().err.startswith("tracer.cfl:")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["case.toml"]


def test_multirate_and_auto_estimates_are_the_solvers(monkeypatch):
    """The void model next to a point orifice: multirate, and auto once the explicit run
    counts as long (threshold lowered), take the estimated steps and split."""
    from spotpde.tracer import _solve
    from _problems import void_problem as _void
    grid, fields, P0 = _void(0.25)
    explicit = estimate.tracer_steps(grid, fields, 20.0, 3, stepping="auto")
    assert explicit["stepping"] == "explicit"           # a short run stays explicit
    monkeypatch.setattr(_solve, "AUTO_IMEX_STEPS", 100)
    for stepping in ("multirate", "auto"):
        est = estimate.tracer_steps(grid, fields, 20.0, 3, stepping=stepping)
        res = tracer.solve(grid, fields, P0, 20.0, 3, stepping=stepping)
        assert est["stepping"] == res.options["stepping"] == "multirate"
        assert est["split"] == res.options["split"]
        assert est["steps"] == res.steps
        # the grid steps at the slow cells' limit, max(a_slow) <= max(a) / split: at
        # least split times fewer steps (within the rounding of the two ceilings)
        assert est["steps"] * est["split"] <= explicit["steps"] + 2 * est["split"]
    with pytest.raises(ValueError, match="^stepping"):
        estimate.tracer_steps(grid, fields, 20.0, 3, stepping="imex")


def test_choose_stepping_keeps_short_transient_and_even_runs_explicit():
    """auto: explicit for short runs, for time-dependent fields and for even rates;
    multirate only for a long steady run with a few fast cells (the split then at most
    their ratio); explicit modes and default splits pass through."""
    from spotpde.tracer import _advection, _implicit
    from spotpde.tracer._solve import (AUTO_IMEX_STEPS, DEFAULT_SPLIT, MAX_AUTO_SPLIT,
                                       choose_stepping)
    from _problems import void_problem as _void
    grid, fields, _ = _void(0.25)
    faces = _advection.face_velocities(fields, grid.walls, np.ones(grid.shape[1:], bool))
    ratio = _implicit.auto_split(faces, grid.spacing)
    assert ratio > _implicit.MIN_SPLIT
    long = AUTO_IMEX_STEPS + 1
    assert choose_stepping("auto", None, faces, grid.spacing, AUTO_IMEX_STEPS) == \
        ("explicit", 1.0)
    assert choose_stepping("auto", None, faces, grid.spacing, long, steady=False)[0] == \
        "explicit"
    assert choose_stepping("auto", None, faces, grid.spacing, long) == \
        ("multirate", min(DEFAULT_SPLIT["multirate"], ratio))
    even = {k: np.where(v != 0, 1.0, 0.0) for k, v in faces.items()}
    assert choose_stepping("auto", None, even, grid.spacing, long)[0] == "explicit"
    assert choose_stepping("multirate", None, faces, grid.spacing, 1) == \
        ("multirate", DEFAULT_SPLIT["multirate"])
    # auto never goes past the bound of its time error, whatever split asks (one face 100
    # times faster than the rest: auto_split 50); an explicit multirate request is the user's
    steep = {k: v.copy() for k, v in even.items()}
    steep["z"][5, 5] = -100.0
    assert _implicit.auto_split(steep, grid.spacing) > 40.0
    assert choose_stepping("auto", 40.0, steep, grid.spacing, long) == \
        ("multirate", MAX_AUTO_SPLIT)
    assert choose_stepping("multirate", 40.0, faces, grid.spacing, 1) == ("multirate", 40.0)
    assert choose_stepping("imex", 3.0, faces, grid.spacing, 1) == ("imex", 3.0)


def test_axisymmetric_runs_are_estimated_as_the_solver_steps_them(monkeypatch):
    """tracer.solve takes the long-run steppers on axisymmetric grids too, by the box's
    rule on the geometry's own face velocities; the estimate prices what it runs."""
    from spotpde.tracer import _solve
    grid = Grid(2, (0.0, 4.0), (0.0, 8.0), 0.25, coordinates="axisymmetric")
    from spotpde.tracer import _geometry, _implicit
    Z, R = grid.mesh()
    zero = 0 * R + 0 * Z
    r = np.hypot(R, Z)
    speed = 1.0 / (0.005 + r**2)                   # a point sink at the axis: fast cells
    fields = {"u_r": -speed * R / r + zero, "u_z": -speed * Z / r + zero,
              "D_rr": 0.01 + zero, "D_rz": zero, "D_zz": zero}
    op = _geometry.operator(grid, _solve._check_fields(grid, fields, "fields"), 6,
                            np.ones(grid.shape[1:], bool), implicit=False)
    assert _implicit.auto_split(op.faces, grid.spacing) > _implicit.MIN_SPLIT
    for stepping in ("auto", "multirate"):
        est = estimate.tracer_steps(grid, fields, 1e6, 3, stepping=stepping)
        assert est["stepping"] == "multirate"
    assert _solve.AUTO_IMEX_STEPS < est["steps"]
    # a short run with the threshold lowered: the solver takes the estimated steps
    monkeypatch.setattr(_solve, "AUTO_IMEX_STEPS", 10)
    P0 = np.where((np.abs(R - 2.0) < 0.6) & (np.abs(Z - 6.0) < 0.6), 1.0, 0.0)
    for stepping in ("auto", "multirate"):
        est = estimate.tracer_steps(grid, fields, 2.0, 3, stepping=stepping)
        res = tracer.solve(grid, fields, P0, 2.0, 3, stepping=stepping)
        assert est["stepping"] == res.options["stepping"] == "multirate"
        assert est["split"] == res.options["split"] and est["steps"] == res.steps
