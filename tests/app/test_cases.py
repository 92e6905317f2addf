"""Case files: loading, defaults, validation messages, memory refusal, TOML round trip."""

from __future__ import annotations

import copy
import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import spotpde
from spotpde.app import cases
from spotpde.app.cases import DEFAULTS, dump_toml, load_case

ROOT = Path(__file__).resolve().parents[2]
CASE_FILES = sorted((ROOT / "cases").glob("*.toml"))

INTERFACE_TOML = """
[domain]
dims = 2
x = [-30.0, 30.0]
z = [0.0, 100.0]
spacing = 0.25
walls = "reflecting"

[orifice]
x = 0.0
width = 0.0
profile = "uniform"
rate = 1.0

[spots]
drift = 1.0
b = 1.3
b_par = 0.0
mode = "steady"
t_end = 0.0

[kernel]
shape = "gaussian"
size = 1.0
volume = 0.05
aspect = 1.0
rule = 0.5

[tracer]
model = "spot"
start = { x = 5.0, z = 60.0, width = 1.0 }
t_end = 200.0
frames = 20

[output]
path = "out.nc"
"""

# Each line "<dotted key>: <message>".
LINE = re.compile(r"^[^\s:]+: \S")


def small(**tables):
    """A small valid case mapping, with tables updated from ``tables``."""
    data = {
        "domain": {"dims": 2, "x": [-4.0, 4.0], "z": [0.0, 8.0], "spacing": 0.5},
        "orifice": {"x": 0.0, "width": 2.0},
        "kernel": {"shape": "gaussian", "size": 1.0, "volume": 0.05},
        "tracer": {"start": {"x": 0.0, "z": 5.0, "width": 1.0}, "t_end": 1.0, "frames": 2},
    }
    for name, body in tables.items():
        if body is None:
            data.pop(name, None)
        else:
            data.setdefault(name, {}).update(body)
    return data


def problems_of(data) -> list[str]:
    with pytest.raises(spotpde.CaseError) as info:
        load_case(data)
    return info.value.problems


# -- valid cases ---------------------------------------------------------------------

def test_contract_example_loads_with_its_values(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text(INTERFACE_TOML)
    case = load_case(path)
    assert case.grid.shape == (400, 240)
    assert case.grid.walls == "reflecting"
    assert case.orifice.width == 0.0 and case.orifice.rate == 1.0
    assert case.spots.b == 1.3 and case.spots.mode == "steady"
    assert case.rule == 0.5
    assert case.tracer.start.kind == "blob"
    assert (case.tracer.start.x, case.tracer.start.z) == (5.0, 60.0)
    assert case.tracer.t_end == 200.0 and case.tracer.frames == 20
    assert case.text == path.read_text()
    assert case.source == str(path)


def test_empty_mapping_gets_every_contract_default():
    case = load_case({})
    for table, body in DEFAULTS.items():
        if table in ("tracer", "pair"):       # optional tables
            assert table not in case.data
            continue
        for key, value in body.items():
            if value is not None:
                assert case.data[table][key] == value, f"{table}.{key}"
    assert case.tracer is None
    assert case.grid.shape == (400, 240)


@pytest.mark.parametrize("path", CASE_FILES, ids=[p.stem for p in CASE_FILES])
def test_every_shipped_case_loads(path):
    case = load_case(path)
    assert case.output_path.suffix == ".nc"


def test_required_case_files_exist():
    names = {p.stem for p in CASE_FILES}
    assert {"quasi2d_layers", "quasi2d_layers_void", "slot_walls", "silo3d",
            "transient_startup", "kinematic_rule_half", "kinematic_rule_one"} <= names


def test_flagship_uses_the_papers_parameters():
    case = load_case(ROOT / "cases" / "quasi2d_layers.toml")
    assert case.spots.b == 1.3
    assert case.kernel_spec["shape"] == "uniform" and case.kernel_spec["size"] == 2.5
    assert case.kernel_spec["volume"] == pytest.approx(0.0024 * math.pi * 2.5**2)
    assert case.tracer.start.kind == "layers"
    void = load_case(ROOT / "cases" / "quasi2d_layers_void.toml")
    assert void.model == "void" and void.rule == 1.0
    # same mean flow: V1 * Q0 equal
    assert void.kernel_spec["volume"] * void.orifice.rate == pytest.approx(
        case.kernel_spec["volume"] * case.orifice.rate, rel=1e-3)


def test_kernel_height_gives_the_uniform_volume():
    case = load_case(small() | {"kernel": {"shape": "uniform", "size": 2.5,
                                           "height": 0.0024}})
    assert case.kernel_spec["volume"] == pytest.approx(0.0024 * math.pi * 6.25)
    assert case.kernel.V1 == pytest.approx(0.0024 * math.pi * 6.25, rel=1e-9)


def test_layers_and_3d_blob_default_y():
    case = load_case(small(tracer={"start": None, "layers": {"spacing": 2.0}}))
    assert case.tracer.start.kind == "layers" and case.tracer.start.spacing == 2.0
    case3 = load_case(small(domain={"dims": 3}))
    assert case3.grid.shape == (16, 16, 16)
    assert case3.tracer.start.y == case3.grid.y_centre
    slab = load_case(small(domain={"dims": 3, "y": [0.0, 3.0]}))
    assert slab.grid.shape == (16, 6, 16) and slab.grid.y_range == (0.0, 3.0)
    assert slab.tracer.start.y == 1.5 == slab.grid.y_centre
    assert tomllib.loads(slab.to_toml())["domain"]["y"] == [0.0, 3.0]


def test_void_model_fixes_rule_to_one():
    case = load_case(small(tracer={"model": "void"}, kernel={"rule": 0.5}))
    assert case.model == "void" and case.rule == 1.0


def test_relative_output_path_resolves_against_the_current_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    case = load_case(small(output={"path": "sub/r.nc"}))
    assert case.output_path == tmp_path / "sub" / "r.nc"
    other = case.with_output("x.nc")
    assert other.output_path == tmp_path / "x.nc"
    assert case.output_path == tmp_path / "sub" / "r.nc"     # the original is unchanged
    assert 'path = "x.nc"' in other.to_toml()


def test_to_toml_round_trips():
    case = load_case(small() | {"kernel": {"shape": "uniform", "size": 1.0, "height": 0.01}})
    again = load_case(tomllib.loads(case.to_toml()))
    assert again.data == case.data
    assert again.kernel_spec == case.kernel_spec


@settings(max_examples=60, deadline=None)
@given(st.text(max_size=20), st.floats(allow_nan=False), st.integers(-2**70, 2**70),
       st.booleans())
def test_dump_toml_round_trips_scalars(s, f, i, b):
    data = {"t": {"s": s, "f": f, "i": i, "b": b, "l": [f, f], "n": {"k": s}}}
    assert tomllib.loads(dump_toml(data)) == data


# -- invalid cases ---------------------------------------------------------------------

@pytest.mark.parametrize("tables, expected", [
    ({"spots": {"b": -1.0}}, "spots.b: must be > 0, got -1.0"),
    ({"spots": {"b": "1.3"}}, 'spots.b: must be a number, got "1.3"'),
    ({"spots": {"drift": math.nan}}, "spots.drift: must be a finite number, got nan"),
    ({"orifice": {"rate": math.inf}}, "orifice.rate: must be a finite number, got inf"),
    ({"domain": {"dims": 4}}, "domain.dims: must be 2 (x, z) or 3 (x, y, z), got 4"),
    ({"domain": {"dims": 2.0}}, "domain.dims: must be 2 (x, z) or 3 (x, y, z), got 2.0"),
    ({"domain": {"walls": "sticky"}}, 'domain.walls: must be one of "reflecting", "open"'),
    ({"domain": {"x": [4.0, -4.0]}}, "domain.x: must be increasing"),
    ({"domain": {"x": [4.0]}}, "domain.x: must be a list of two numbers"),
    ({"domain": {"z": [1.0, 8.0]}}, "domain.z: must start at 0"),
    ({"domain": {"spacing": 0.3}}, "domain.spacing: must divide the domain.x extent"),
    ({"domain": {"spacing": 4.0}}, "domain.spacing: must give at least 4 cells"),
    ({"domain": {"spacing": True}}, "domain.spacing: must be a number, got true"),
    ({"orifice": {"x": 3.5}}, "orifice.x: the slot [x - width/2, x + width/2] must lie"),
    ({"orifice": {"x": 9.0, "width": 0.0}}, "orifice.x: the centre must lie on the floor"),
    ({"orifice": {"y": 0.0}}, "orifice.y: is only used when domain.dims = 3"),
    ({"domain": {"y": [-2.0, 2.0]}}, "domain.y: is only used when domain.dims = 3"),
    ({"domain": {"dims": 3, "y": [2.0, -2.0]}}, "domain.y: must be increasing"),
    ({"domain": {"dims": 3, "y": [-2.0, 2.3]}}, "domain.y: must be a whole number of cells "
                                                "of domain.spacing = 0.5"),
    ({"domain": {"dims": 3, "y": [-0.5, 0.5]}}, "domain.y: must be at least 4 cells of "
                                                "domain.spacing = 0.5 deep"),
    ({"domain": {"dims": 3, "y": [-2.0, math.inf]}}, "domain.y[1]: must be a finite number"),
    ({"domain": {"dims": 3, "y": [-2.0, 2.0]}, "orifice": {"y": 1.5}},
     "orifice.y: the orifice must lie on the floor, y in [-2.0, 2.0] (the domain.y extent)"),
    ({"domain": {"dims": 3, "y": [-2.0, 2.0]},
      "tracer": {"start": {"x": 0.0, "y": 3.0, "z": 5.0, "width": 1.0}}},
     "tracer.start.y: must lie in [-2.0, 2.0] (the domain.y extent)"),
    ({"orifice": {"shape": "slot"}}, "orifice.shape: is only used when domain.dims = 3"),
    ({"domain": {"dims": 3}, "orifice": {"shape": "square"}},
     'orifice.shape: must be one of "disk", "slot", got "square"'),
    ({"domain": {"dims": 3}, "orifice": {"shape": "slot", "y": 0.0}},
     'orifice.y: is not used by orifice.shape = "slot"'),
    ({"orifice": {"profile": "gaussian", "width": 0.0}}, "orifice.width: must be > 0"),
    ({"orifice": {"profile": "square"}}, 'orifice.profile: must be one of "uniform", '
                                         '"gaussian", got "square"'),
    ({"spots": {"mode": "transient"}}, "spots.t_end: must be > 0 when spots.mode"),
    ({"spots": {"t_end": 5.0}}, "spots.t_end: is only used when spots.mode"),
    ({"kernel": {"rule": 0.0}}, "kernel.rule: must be > 0, got 0.0"),
    ({"kernel": {"rule": 1.5}}, "kernel.rule: must be <= 1, got 1.5"),
    ({"kernel": {"shape": "cone"}}, 'kernel.shape: must be one of "uniform", "gaussian", '
                                    '"exponential"'),
    ({"kernel": {"height": 0.01}}, "kernel.volume: give either kernel.volume or "
                                   "kernel.height"),
    ({"tracer": {"frames": 1}}, "tracer.frames: must be >= 2, got 1"),
    ({"tracer": {"frames": 2.5}}, "tracer.frames: must be an integer, got 2.5"),
    ({"tracer": {"t_end": -1.0}}, "tracer.t_end: must be > 0, got -1.0"),
    ({"tracer": {"model": "ghost"}}, 'tracer.model: must be one of "spot", "void"'),
    ({"tracer": {"limiter": "superbee"}}, 'tracer.limiter: must be one of "koren", '
                                          '"vanleer", "mc", "minmod", "weno5", "upwind"'),
    ({"tracer": {"cfl": 1.5}}, "tracer.cfl: must be <= 1, got 1.5"),
    ({"tracer": {"diffusion": "fast"}}, 'tracer.diffusion: must be one of "auto"'),
    ({"tracer": {"snapshots": 1}}, 'tracer.snapshots: must be "auto" or an integer in [2, '),
    ({"tracer": {"snapshots": "many"}}, 'tracer.snapshots: must be "auto" or an integer'),
    ({"tracer": {"snapshots": 2.5}}, 'tracer.snapshots: must be "auto" or an integer'),
    ({"tracer": {"snapshots": True}}, 'tracer.snapshots: must be "auto" or an integer'),
    ({"tracer": {"snapshots": 10}}, "tracer.snapshots: is only used when spots.mode = "
                                    '"transient"'),
    ({"tracer": {"layers": {"spacing": 2.0}}}, "tracer: give either tracer.start"),
    ({"tracer": {"start": {"x": 0.0, "width": 1.0}}}, "tracer.start.z: required"),
    ({"tracer": {"start": {"x": 0.0, "z": 9.0}}}, "tracer.start.z: must lie inside"),
    ({"tracer": {"start": {"x": 0.0, "z": 5.0, "width": 0.1}}},
     "tracer.start.width: must be at least domain.spacing"),
    ({"tracer": {"start": {"x": 0.0, "z": 5.0, "colour": 1}}},
     "tracer.start.colour: unknown key; valid keys: x, y, z, width"),
    ({"tracer": {"start": None, "layers": {"spacing": 0.5}}},
     "tracer.layers.spacing: must be at least 2 * domain.spacing"),
    ({"output": {"path": 3}}, "output.path: must be a non-empty file name"),
    ({"output": {"path": ""}}, "output.path: must be a non-empty file name"),
    ({"spots": {"bb": 1.0}}, "spots.bb: unknown key (did you mean 'b'?); valid keys: "
                             "drift, b, b_par, mode, t_end"),
    ({"orifise": {"x": 0.0}}, "orifise: unknown table (did you mean 'orifice'?)"),
    ({"spots": 3}, "spots: must be a table, got 3"),
])
def test_invalid_values_name_the_key_and_the_allowed_values(tables, expected):
    data = small()
    for name, body in tables.items():
        if isinstance(body, dict):
            data.setdefault(name, {})
            for k, v in body.items():
                if v is None:
                    data[name].pop(k, None)
                else:
                    data[name][k] = v
        else:
            data[name] = body
    problems = problems_of(data)
    assert any(p.startswith(expected) for p in problems), problems
    assert all(LINE.match(p) and "\n" not in p for p in problems)


def test_every_problem_is_reported_at_once():
    data = small(spots={"b": -1.0, "drift": 0.0, "zz": 1}, kernel={"rule": 2.0})
    problems = problems_of(data)
    keys = {p.split(":")[0] for p in problems}
    assert {"spots.b", "spots.drift", "spots.zz", "kernel.rule"} <= keys
    assert len(problems) == 4


def test_case_error_is_a_value_error_with_one_line_per_problem():
    with pytest.raises(ValueError) as info:
        load_case(small(spots={"b": -1.0, "b_par": -2.0}))
    assert str(info.value).splitlines() == info.value.problems
    assert len(info.value.problems) == 2


def test_malformed_and_missing_files(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[domain\nx = 1\n")
    with pytest.raises(spotpde.CaseError, match="malformed TOML"):
        load_case(bad)
    with pytest.raises(spotpde.CaseError, match="cannot read the case file"):
        load_case(tmp_path / "missing.toml")
    binary = tmp_path / "bin.toml"
    binary.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(spotpde.CaseError, match="malformed TOML"):
        load_case(binary)
    with pytest.raises(TypeError, match="^source: must be a path"):
        load_case(42)


def test_a_grid_too_large_for_memory_is_refused_before_any_work(monkeypatch):
    monkeypatch.setattr(cases, "available_memory", lambda: 1024**3)
    assert load_case(small()).grid.shape == (16, 16)
    problems = problems_of(small(domain={"x": [-250.0, 250.0], "z": [0.0, 500.0],
                                         "spacing": 0.25}))
    assert len(problems) == 1
    assert problems[0].startswith("domain.spacing: the grid of 2,000 x 2,000 cells")
    assert "GB" in problems[0] and problems[0].endswith("got 0.25")


def test_memory_estimate_counts_tracer_frames_and_3d():
    mean_field = {"diffusivity": "mean-field"}     # no passage quadrature (grid-sized peak)
    base = cases.validate(small(kernel=mean_field))
    more = copy.deepcopy(base)
    more["tracer"]["frames"] = 200
    assert cases.estimate_bytes(more) > cases.estimate_bytes(base) + 8 * 16 * 16 * 190
    three = cases.validate(small(domain={"dims": 3}, kernel=mean_field))
    assert cases.estimate_bytes(three) > 10 * cases.estimate_bytes(base)
    # domain.y absent is the domain.x extent; a slab a quarter as deep needs less
    square = cases.validate(small(domain={"dims": 3, "y": [-4.0, 4.0]}, kernel=mean_field))
    assert cases.estimate_bytes(square) == cases.estimate_bytes(three)
    slab = cases.validate(small(domain={"dims": 3, "y": [-1.0, 1.0]}, kernel=mean_field))
    assert cases.estimate_bytes(slab) < 0.8 * cases.estimate_bytes(three)
    assert cases.available_memory() > 0


def test_absurd_spacing_is_an_invalid_case_not_a_crash():
    problems = problems_of(small(domain={"x": [-1e6, 1e6], "z": [0.0, 1e6],
                                         "spacing": 1e-9}))
    assert problems and all(p.startswith("domain.spacing") for p in problems)


# -- property test: mutations of a valid case ---------------------------------------

def _paths(data, prefix=()):
    for k, v in data.items():
        yield prefix + (k,)
        if isinstance(v, dict):
            yield from _paths(v, prefix + (k,))


VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(-10**20, 10**20),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-100, 100), st.sampled_from([0, 1, 2, 3, 0.0, 0.25, 0.5, 1.0, -1.0]),
    st.text(max_size=8),
    st.sampled_from(["uniform", "gaussian", "exponential", "steady", "transient", "spot",
                     "void", "open", "reflecting", "out.nc", "/", ""]),
    st.lists(st.floats(-50, 50), max_size=3),
    st.lists(st.one_of(st.integers(-5, 5), st.text(max_size=2)), max_size=3),
    st.dictionaries(st.sampled_from(["x", "z", "width", "spacing", "y", "q"]),
                    st.floats(-20, 20), max_size=3),
)
BASES = [small(), small(tracer={"start": None, "layers": {"spacing": 2.0}}),
         small(domain={"dims": 3}), small(tracer=None)]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_mutated_cases_load_or_raise_case_error(data):
    case = copy.deepcopy(data.draw(st.sampled_from(BASES)))
    for _ in range(data.draw(st.integers(1, 3))):
        paths = list(_paths(case))
        action = data.draw(st.sampled_from(["set", "delete", "add"]))
        if action == "add" or not paths:
            table = data.draw(st.sampled_from([None, *[p for p in paths if len(p) == 1]]))
            key = data.draw(st.text(min_size=1, max_size=6))
            target = case if table is None else case[table[0]]
            if isinstance(target, dict):
                target[key] = data.draw(VALUES)
            continue
        path = data.draw(st.sampled_from(paths))
        parent = case
        for k in path[:-1]:
            parent = parent[k]
        if action == "delete":
            del parent[path[-1]]
        else:
            parent[path[-1]] = data.draw(VALUES)
    try:
        result = load_case(case)
    except spotpde.CaseError as err:
        assert err.problems
        assert all(": " in p for p in err.problems)
    else:
        assert result.grid.size > 0
        assert tomllib.loads(result.to_toml()) is not None


def test_rate_table_for_transient_runs():
    case = load_case(small(spots={"mode": "transient", "t_end": 4.0},
                           orifice={"rate": {"times": [0.0, 2.0], "values": [0.0, 10.0]}}))
    assert case.orifice.rate_at(1.0) == pytest.approx(5.0)
    assert case.orifice.rate_at(3.0) == pytest.approx(10.0)
    again = load_case(tomllib.loads(case.to_toml()))
    assert again.data == case.data
    problems = problems_of(small(orifice={"rate": {"times": [0.0, 2.0], "values": [1.0]}}))
    assert problems == ["orifice.rate: times and values must have the same length, got 2 "
                        "times and 1 values"]
    problems = problems_of(small(orifice={"rate": {"times": [0.0], "values": [1.0]}}))
    assert problems == ['orifice.rate: a table of rates needs spots.mode = "transient"; '
                        'give a number for a steady run, got a table']
    problems = problems_of(small(spots={"mode": "transient", "t_end": 4.0},
                                 orifice={"rate": {"times": [2.0, 1.0], "values": [1.0, -1.0]}}))
    assert problems == ["orifice.rate.values[1]: must be >= 0, got -1.0"]
    problems = problems_of(small(spots={"mode": "transient", "t_end": 4.0},
                                 orifice={"rate": {"times": [2.0, 1.0], "values": [1.0, 1.0]}}))
    assert problems == ["orifice.rate.times: must be strictly increasing, got [2.0, 1.0]"]


@settings(max_examples=60, deadline=None)
@given(st.one_of(st.text(max_size=200), st.binary(max_size=100),
                 st.sampled_from(["[domain]\nspacing = 0.5e", "[domain]\ndims = 3\n[domain]\n",
                                  "domain = 3", "[[domain]]\nx = 1", "[tracer.start]\nx = 1"])))
def test_arbitrary_files_load_or_raise_case_error(tmp_path_factory, content):
    path = tmp_path_factory.mktemp("h") / "case.toml"
    if isinstance(content, str):
        path.write_text(content, encoding="utf-8")
    else:
        path.write_bytes(content)
    try:
        load_case(path)
    except spotpde.CaseError as err:
        assert err.problems and all(": " in p for p in err.problems)


def test_spot_coefficient_profiles_become_grid_fields():
    case = load_case(small(spots={"drift": {"x": [-4.0, 4.0], "values": [0.5, 1.5]},
                                  "b": {"z": [0.0, 8.0], "values": [1.0, 3.0]}}))
    grid = case.grid
    assert case.spots.drift.shape == case.spots.b.shape == grid.shape
    np.testing.assert_allclose(case.spots.drift[3], 1.0 + grid.x / 8.0)
    np.testing.assert_allclose(case.spots.b[:, 5], 1.0 + grid.z / 4.0)
    assert case.spots.b_par == 0.0
    assert load_case(tomllib.loads(case.to_toml())).data == case.data
    three = load_case(small(domain={"dims": 3},
                            spots={"drift": {"x": [-4.0, 4.0], "values": [0.5, 1.5]}}))
    assert three.spots.drift.shape == three.grid.shape
    np.testing.assert_allclose(three.spots.drift[2, 7], 1.0 + three.grid.x / 8.0)


@pytest.mark.parametrize("profile, expected", [
    ({"x": [0.0, 1.0], "z": [0.0, 1.0], "values": [1.0, 1.0]},
     "spots.b: a profile needs exactly one coordinate list (x or z)"),
    ({"z": [0.0, 1.0]}, "spots.b: a profile needs exactly one coordinate list"),
    ({"z": [0.0, 1.0], "values": [1.0, -1.0]}, "spots.b.values[1]: must be > 0, got -1.0"),
    ({"z": [1.0, 0.0], "values": [1.0, 1.0]}, "spots.b.z: must be strictly increasing"),
    ({"z": [0.0, 1.0, 2.0], "values": [1.0, 1.0]},
     "spots.b: z and values must have the same length, got 3 and 2"),
    ({"z": [0.0], "values": [1.0]}, "spots.b.z: must be a list of 2 to 10000 numbers"),
    ({"y": [0.0, 1.0], "values": [1.0, 1.0]}, "spots.b.y: unknown key"),
])
def test_invalid_coefficient_profiles(profile, expected):
    problems = problems_of(small(spots={"b": profile}))
    assert any(p.startswith(expected) for p in problems), problems
