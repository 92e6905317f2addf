"""The ``[montecarlo]`` case table (spotpde.app._schema_mc, montecarlo._settings;
docs/cases.md): checked with the rest of the case (one line per problem naming the
dotted key, ``spotpde check`` exits 2), read once into
:class:`~spotpde.montecarlo.MonteCarloSettings`, and used by ``from_case`` under the
caller's Python keywords."""

from __future__ import annotations

import copy
import math
import tomllib
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import spotpde
from spotpde import montecarlo as mc
from spotpde import cli
from spotpde.app import _schema_mc
from spotpde.app.cases import load_case

ROOT = Path(__file__).resolve().parents[2]


def small(montecarlo=None):
    """A small valid case (a 2D silo 8 d x 8 d, a uniform kernel) with ``[montecarlo]``."""
    data = {
        "domain": {"dims": 2, "x": [-4.0, 4.0], "z": [0.0, 8.0], "spacing": 0.5},
        "orifice": {"x": 0.0, "width": 2.0, "rate": 4.0},
        "kernel": {"shape": "uniform", "size": 1.5, "height": 0.01},
    }
    if montecarlo is not None:
        data["montecarlo"] = montecarlo
    return data


def problems_of(data) -> list[str]:
    with pytest.raises(spotpde.CaseError) as info:
        load_case(data)
    return info.value.problems


def test_the_table_is_read_into_typed_settings_and_round_trips():
    table = {"particles": "random", "spacing": 1.5, "seed": 7, "t_end": 3.0, "step": 0.5,
             "gamma": 0.2, "steps": "binary", "probes": False, "batches": 4, "records": 5,
             "tracked": "all", "relax": {"radius": 3.0, "every": 2, "distribution": "gaussian"}}
    case = load_case(small(table))
    s = case.montecarlo
    assert isinstance(s, mc.MonteCarloSettings)
    assert (s.particles, s.spacing, s.seed, s.t_end, s.step, s.gamma, s.steps, s.probes,
            s.batches, s.records, s.tracked) == ("random", 1.5, 7, 3.0, 0.5, 0.2, "binary",
                                                   False, 4, 5, "all")
    assert s.relax == mc.Relax(radius=3.0, every=2, distribution="gaussian")
    assert case.montecarlo is s  # read once
    again = load_case(tomllib.loads(case.to_toml()))
    assert again.data == case.data and again.montecarlo == s
    # relax = true: the defaults; false: off; no table: nothing set
    assert load_case(small({"relax": True})).montecarlo.relax == mc.Relax()
    assert load_case(small({"relax": False})).montecarlo.keywords() == {"relax": None}
    assert load_case(small()).montecarlo == mc.MonteCarloSettings()
    assert load_case(small({"particles": "none", "tracked": "none"})).montecarlo.keywords() == {
        "particles": None, "tracked": None}


@pytest.mark.parametrize("table, expected", [
    ({"particles": "grid"},
     'montecarlo.particles: must be one of "lattice", "random", "tracer", "none", got "grid"'),
    ({"spacing": 0.0}, "montecarlo.spacing: must be > 0, got 0.0"),
    ({"seed": -1}, "montecarlo.seed: must be >= 0, got -1"),
    ({"seed": 1.5}, "montecarlo.seed: must be an integer, got 1.5"),
    ({"t_end": math.inf}, "montecarlo.t_end: must be a finite number, got inf"),
    ({"n_spots": 0}, "montecarlo.n_spots: must be >= 1, got 0"),
    ({"gamma": 1.0}, "montecarlo.gamma: must be < 1, got 1.0"),
    ({"steps": "levy"}, 'montecarlo.steps: must be one of "gaussian", "binary", got "levy"'),
    ({"probes": 1}, "montecarlo.probes: must be true or false, got 1"),
    ({"batches": 0}, "montecarlo.batches: must be >= 1, got 0"),
    ({"records": 10**6}, "montecarlo.records: must be <= 10000, got 1000000"),
    ({"replicas": 0}, "montecarlo.replicas: must be >= 1, got 0"),
    ({"tracked": [1, 2]}, 'montecarlo.tracked: must be one of "all", "none", got [1, 2]'),
    ({"relax": 1}, "montecarlo.relax: must be true, false or a table of alpha, iterations, "
                   "every, radius, polydispersity, distribution, opening, margin, got 1"),
    ({"relax": {"alpha": 0.7}}, "montecarlo.relax.alpha: must be <= 0.5, got 0.7"),
    ({"relax": {"every": 0}}, "montecarlo.relax.every: must be >= 1, got 0"),
    ({"relax": {"radius": -1.0}}, "montecarlo.relax.radius: must be > 0, got -1.0"),
    ({"relax": {"polydispersity": 0.5}}, "montecarlo.relax.polydispersity: must be < 0.5, got 0.5"),
    ({"relax": {"distribution": "log"}},
     'montecarlo.relax.distribution: must be one of "uniform", "gaussian", got "log"'),
    ({"t_end": 2.0, "n_spots": 10},
     "montecarlo.n_spots: give either montecarlo.t_end or montecarlo.n_spots, not both"),
])
def test_each_bad_key_is_one_problem_naming_it(table, expected):
    assert problems_of(small(table)) == [expected]


def test_unknown_keys_are_named_with_a_hint():
    problems = problems_of(small({"seeds": 3, "relax": {"radiu": 2.0}}))
    assert problems[0].startswith("montecarlo.seeds: unknown key (did you mean 'seed'?)")
    assert problems[1].startswith("montecarlo.relax.radiu: unknown key (did you mean 'radius'?)")
    assert len(problems) == 2


def test_choices_are_the_monte_carlos_own():
    assert _schema_mc.STEPS == mc.STEPS
    assert _schema_mc.DISTRIBUTIONS == mc.DISTRIBUTIONS
    assert set(_schema_mc.RELAX_KEYS) == {f for f in mc.Relax.__dataclass_fields__}


KEYS = sorted(_schema_mc.MONTECARLO_KEYS)
VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(-10**20, 10**20),
    st.floats(allow_nan=True, allow_infinity=True), st.floats(-2, 2),
    st.text(max_size=8),
    st.sampled_from(["lattice", "random", "tracer", "none", "all", "gaussian", "binary"]),
    st.lists(st.floats(-5, 5), max_size=2),
    st.dictionaries(st.sampled_from(sorted(_schema_mc.RELAX_KEYS) + ["q"]),
                    st.one_of(st.floats(-1, 5), st.integers(-2, 20), st.text(max_size=4)),
                    max_size=3),
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.dictionaries(st.one_of(st.sampled_from(KEYS), st.text(min_size=1, max_size=5)),
                       VALUES, max_size=4))
def test_any_table_loads_into_settings_or_raises_case_error_naming_montecarlo_keys(table):
    try:
        case = load_case(small(copy.deepcopy(table)))
    except spotpde.CaseError as err:
        assert err.problems
        assert all(p.startswith("montecarlo.") for p in err.problems), err.problems
    else:
        kw = case.montecarlo.keywords()
        assert set(kw) <= set(KEYS)
        if "relax" in kw and kw["relax"] is not None:
            assert isinstance(kw["relax"], mc.Relax)


def test_check_exits_2_with_one_line_per_problem(tmp_path, capsys):
    text = (ROOT / "cases" / "montecarlo_layers.toml").read_text()
    bad = tmp_path / "bad.toml"
    assert "\nseed = 1\n" in text
    bad.write_text(text.replace("\nseed = 1\n", "\nseed = -2\nrelax = { alpha = 2.0, every = 0 }\n"))
    assert cli.main(["check", str(bad)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == ["montecarlo.seed: must be >= 0, got -2",
                   "montecarlo.relax.alpha: must be <= 0.5, got 2.0",
                   "montecarlo.relax.every: must be >= 1, got 0"]


def test_from_case_uses_the_table_under_the_callers_keywords():
    table = {"particles": "random", "seed": 3, "t_end": 2.0, "step": 0.5, "probes": False,
             "records": 4, "tracked": "all", "relax": {"radius": 2.0, "iterations": 2}}
    case = load_case(small(table))
    r = mc.from_case(case)
    assert r.seed == 3 and r.step == 0.5 and r.probe is None
    assert r.t_end == pytest.approx(2.0)
    assert r.relax.radius == 2.0 and r.relax.iterations == 2
    assert r.positions.shape[0] == 4 and r.tracked.size == r.initial.shape[0]
    # the table's packing is random_packing with the table's seed
    assert (r.initial == mc.random_packing(case.grid, 0.5, seed=3)).all()
    # Python keywords override the table; a duration given in Python replaces the table's
    q = mc.from_case(case, seed=5, particles="lattice", spacing=2.0, n_spots=4,
                     relax=None, tracked=None)
    assert q.seed == 5 and q.relax is None and q.tracked.size == 0
    assert q.t_end == pytest.approx(4 / case.orifice.rate, rel=0.2)
    assert (q.initial == mc.lattice(case.grid, 2.0)).all()
    # the shipped example case carries a table, and it runs
    ex = load_case(ROOT / "cases" / "montecarlo_layers.toml")
    assert ex.montecarlo.particles == "lattice" and ex.montecarlo.seed is not None


def test_replicas_from_case_runs_independent_seeds():
    case = load_case(small({"seed": 4, "replicas": 3, "t_end": 1.0, "particles": "random",
                            "probes": False}))
    assert case.montecarlo.replicas == 3 and "replicas" not in case.montecarlo.keywords()
    runs = mc.replicas_from_case(case)
    assert [r.seed for r in runs] == [4, 5, 6]
    # independent: each its own packing and its own spots
    assert not (runs[0].initial == runs[1].initial).all()
    # keywords override the table; the single run of from_case is the replica of its seed
    two = mc.replicas_from_case(case, replicas=2, seed=9, t_end=0.75)
    assert [r.seed for r in two] == [9, 10] and two[0].t_end == pytest.approx(0.75)
    one = mc.from_case(case, seed=9, t_end=0.75)
    assert (one.final == two[0].final).all()
    with pytest.raises(ValueError, match="^replicas"):
        mc.replicas_from_case(case, replicas=0)
