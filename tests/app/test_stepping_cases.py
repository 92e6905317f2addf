"""The case keys of the long-run schemes: tracer.stepping, tracer.split, tracer.tol.

They reach ``tracer.solve`` from a case file; a multirate run keeps the tracer's mass
budget and agrees with the explicit run within the explicit scheme's own error; invalid
combinations name the key.
"""

from __future__ import annotations

import numpy as np
import pytest

import spotpde

BASE = {"domain": {"x": [-6.0, 6.0], "z": [0.0, 12.0], "spacing": 0.5},
        "orifice": {"width": 0.0, "rate": 20.0},
        "kernel": {"shape": "gaussian", "size": 1.0, "volume": 0.05},
        "tracer": {"model": "void", "start": {"x": 0.0, "z": 8.0, "width": 1.0},
                   "t_end": 40.0, "frames": 3}}


def _case(**tracer):
    return spotpde.load_case({**BASE, "tracer": {**BASE["tracer"], **tracer}})


def test_stepping_reaches_the_solver_and_is_recorded():
    case = _case(stepping="multirate", split=4.0)
    assert case.tracer_options["stepping"] == "multirate"
    assert case.tracer_options["split"] == 4.0
    assert "stepping = \"multirate\"" in case.to_toml()


@pytest.fixture(scope="module")
def explicit_run():
    return spotpde.run(_case(stepping="explicit", t_end=200.0))


@pytest.mark.parametrize("stepping", ["multirate", "implicit"])
def test_long_run_schemes_keep_the_budget(stepping, explicit_run):
    """Both are positive and conservative; by t = 200 most of the tracer has drained, and
    the geometrical propagator (time-integrated flux) through a height below the release
    is the explicit run's to its time error."""
    kw = {"split": 4.0} if stepping == "multirate" else {}
    other = spotpde.run(_case(stepping=stepping, t_end=200.0, **kw))
    assert np.allclose(np.asarray(other.mass + other.outflow), 1.0, atol=1e-10)
    assert float(np.nanmin(other.P.values)) >= -1e-12
    h = 0.5
    row = int(np.searchsorted(other.z.values, 5.0))      # 3 d below the release
    crossed = [float(np.nansum(ds.P_height.values[row])) * h for ds in (explicit_run, other)]
    assert crossed[0] > 0.99
    assert crossed[1] == pytest.approx(crossed[0], rel=1e-5)


def test_multirate_frames_have_the_explicit_accuracy(explicit_run):
    """Multirate steps the fast cells by the explicit scheme: its outflow history equals
    the explicit one to well below the scheme's own time error (docs/long_runs.md); the
    implicit scheme, first order along the flow, is visibly off in the frames."""
    multirate = spotpde.run(_case(stepping="multirate", split=4.0, t_end=200.0))
    implicit = spotpde.run(_case(stepping="implicit", t_end=200.0))
    mid = float(explicit_run.outflow[1])              # t = 100: about 0.82 has drained
    assert 0.5 < mid < 0.95
    assert float(multirate.outflow[1]) == pytest.approx(mid, rel=2e-3)
    assert abs(float(implicit.outflow[1]) - mid) > 10 * abs(float(multirate.outflow[1]) - mid)


@pytest.mark.parametrize("tracer, key", [
    ({"stepping": "sideways"}, "tracer.stepping"),
    ({"stepping": "explicit", "split": 5.0}, "tracer.split"),
    ({"stepping": "multirate", "split": 0.0}, "tracer.split"),
    ({"tol": 0.0}, "tracer.tol"),
])
def test_bad_stepping_keys_name_the_key(tracer, key):
    with pytest.raises(spotpde.CaseError) as info:
        _case(**tracer)
    assert any(p.startswith(key + ":") for p in info.value.problems), info.value.problems


def test_long_run_schemes_refuse_starting_flows():
    data = {**BASE, "spots": {"mode": "transient", "t_end": 10.0},
            "tracer": {**BASE["tracer"], "stepping": "implicit"}}
    with pytest.raises(spotpde.CaseError, match="tracer.stepping"):
        spotpde.load_case(data)
