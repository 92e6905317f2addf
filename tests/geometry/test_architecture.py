"""The package's structure, read from the syntax tree of every module.

* Imports follow the data flow: a module imports only from its own unit or from a unit
  of an earlier layer (:data:`LAYERS`), inside functions too, so there is no loop across
  subpackages.
* No import sits inside a function except the lazy imports listed here, each with its
  reason.
"""

import ast
import pathlib
import sys

import pytest

import spotpde

PACKAGE = pathlib.Path(spotpde.__file__).parent

#: The command line (``spotpde.cli``, and ``python -m spotpde``) sits on top of
#: everything; ``app/`` (cases, pipeline, io, sweep, plotting) builds and runs cases and
#: is used by tracks, observables and calibration.
FRONT = {"spotpde.__main__"}

#: Units in data-flow order: each may import the units of earlier layers only.
#: ``fields`` (kernels, convolution) comes before ``density``, which convolves with
#: them; the Monte Carlo checks the tracer, ``pair`` runs on the Monte Carlo's kernels;
#: ``analysis`` measures results without running them; ``app`` runs cases (its
#: ``layers`` adds the runs to ``analysis.layers``); tracks, observables and
#: calibration read and fit data through cases; the command line and the package's
#: short names are last.
LAYERS = [
    {"_version", "errors", "_roundoff", "_cache"},
    {"_figures", "geometry"},
    {"grid", "parameters"},
    {"fields"},
    {"density"},
    {"tracer"},
    {"montecarlo"},
    {"pair"},
    {"analysis"},
    {"app"},
    {"tracks"},
    {"observables"},
    {"calibration"},
    {"cli"},
    {"spotpde", "kernels", "kinematic"},
]
RANK = {u: i for i, layer in enumerate(LAYERS) for u in layer}

#: Third-party modules that may be imported inside a function, with the reason.
LAZY_THIRD_PARTY = {
    "matplotlib": "heavy; prepare_matplotlib() must run first, and non-plotting runs "
                  "never load it",
    "pde": "py-pde: the optional cross-check solver, slow to import",
    "dask": "Dask only for replicas / sweeps on a cluster",
    "distributed": "Dask's cluster only for sweeps and --scheduler",
    "emcee": "optional extra (posterior)",
    "numba": "_cache patches numba's caching before numba's first import",
    "netCDF4": "the netCDF C library, loaded where files are written or preloaded in "
               "Dask workers",
    "xarray": "preloaded in Dask workers (_localdask.import_libraries)",
}

#: spotpde modules imported inside a function outside ``app/``: numba-compiled kernels
#: loaded only by the cases that need them, and py-pde.
LAZY_INTERNAL = {
    ("spotpde.fields.kernels", "spotpde.fields._cellavg_exp"):
        "numba cell averages, exponential kernels only",
    ("spotpde.density.spot_density", "spotpde.density._pde"): "py-pde cross-check solver",
}



def _module(path):
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _unit(module):
    if module in FRONT:
        return "cli"
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "spotpde"


def _imports():
    """``[(module, target, line, inside_a_function)]`` for every import statement."""
    out = []
    for path in sorted(PACKAGE.rglob("*.py")):
        module = _module(path)
        package = module if path.name == "__init__.py" else module.rsplit(".", 1)[0]
        tree = ast.parse(path.read_text())
        inner = {id(n) for f in ast.walk(tree)
                 if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
                 for n in ast.walk(f)}
        for n in ast.walk(tree):
            if isinstance(n, ast.ImportFrom) and n.level:
                base = package.split(".")[:len(package.split(".")) - (n.level - 1)]
                if n.module:
                    targets = [".".join(base + [n.module])]
                else:
                    targets = [".".join(base + [a.name]) for a in n.names]
            elif isinstance(n, ast.ImportFrom):
                targets = [n.module]
            elif isinstance(n, ast.Import):
                targets = [a.name for a in n.names]
            else:
                continue
            out += [(module, t, n.lineno, id(n) in inner) for t in targets]
    return out


IMPORTS = _imports()


def test_every_unit_has_a_layer():
    units = {_unit(m) for m, *_ in IMPORTS}
    assert units <= set(RANK), units - set(RANK)
    assert {"app", "analysis", "geometry", "cli"} <= units


def test_imports_follow_the_data_flow():
    """No module imports a unit of a later layer (nor of its own layer but another
    unit), so no loop runs across subpackages; ``analysis`` never imports ``app``."""
    wrong = [f"{m}:{line} -> {t}" for m, t, line, _ in IMPORTS
             if t.startswith("spotpde") and _unit(t) != _unit(m)
             and RANK[_unit(t)] >= RANK[_unit(m)]]
    assert wrong == []
    assert not [t for m, t, *_ in IMPORTS
                if m.startswith("spotpde.analysis") and t.startswith("spotpde.app")]


def test_the_order_check_can_fail():
    """The check above finds an upward import when there is one."""
    assert RANK[_unit("spotpde.app.cases")] > RANK[_unit("spotpde.analysis.layers")]
    assert RANK[_unit("spotpde.cli")] > RANK[_unit("spotpde.calibration")]


def _allowed(module, target):
    root = target.split(".")[0]
    if root in LAZY_THIRD_PARTY:
        return True
    if (module, target) in LAZY_INTERNAL:
        return True
    # app and the command line load the stages (numba kernels), Dask and their own
    # heavy modules on demand: ``spotpde check`` and ``spotpde plot`` start without them
    # (tests/app/test_faults_figures.py::test_plot_imports_no_solver_and_no_numba)
    return module.startswith(("spotpde.app", "spotpde.cli")) and target.startswith("spotpde.")


def test_imports_inside_functions_are_the_listed_lazy_ones():
    inside = [(m, t, line) for m, t, line, fn in IMPORTS if fn]
    stray = [f"{m}:{line} -> {t}" for m, t, line in inside if not _allowed(m, t)]
    assert stray == []
    # nothing from the standard library hides in a function
    assert not [f"{m}:{line} -> {t}" for m, t, line in inside
                if t.split(".")[0] in sys.stdlib_module_names]


# -- one place for the shared tables and terms ------------------------------------------------

def _literals(predicate):
    """``[module:line]`` of the syntax nodes matching ``predicate`` in every module."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for n in ast.walk(ast.parse(path.read_text())):
            if predicate(n):
                found.append(f"{_module(path)}:{n.lineno}")
    return found


def _is_diffusivity_table(n):
    return isinstance(n, ast.Tuple) and {getattr(e, "value", None) for e in n.elts} \
        == {"passage", "mean-field"}


def _is_two_lam(n):
    return isinstance(n, ast.BinOp) and isinstance(n.op, ast.Mult) \
        and isinstance(n.left, ast.Constant) and n.left.value == 2.0 \
        and isinstance(n.right, ast.Name) and n.right.id == "lam"


#: Modules other branches are rewriting (their copies go when they land).
TABLES_LEFT = {"spotpde.fields._pairs", "spotpde.montecarlo._simulate"}


def test_the_diffusivity_table_and_the_rule_terms_are_written_once():
    tables = [s for s in _literals(_is_diffusivity_table) if s.split(":")[0] not in TABLES_LEFT]
    assert [s.split(":")[0] for s in tables] == ["spotpde.parameters"], tables
    terms = [s for s in _literals(_is_two_lam) if s.split(":")[0] not in TABLES_LEFT]
    assert [s.split(":")[0] for s in terms] == ["spotpde.parameters"], terms


def test_one_check_of_rule_and_diffusivity_names_the_argument():
    from spotpde import parameters as P
    from spotpde.fields import _passage
    from spotpde.fields.kernels import Uniform
    from spotpde.pair import cage_breaking

    assert P.check_rule(1) == 1.0 and P.check_rule(0.0) == 0.0
    for bad in (1.5, -0.1, float("nan"), "half"):
        with pytest.raises(ValueError, match=r"^rule: must"):
            P.check_rule(bad)
    with pytest.raises(ValueError, match=r"^lam: must lie in \[0, 1\]"):
        P.check_rule(2.0, "lam")
    with pytest.raises(ValueError, match=r"^diffusivity: must be one of \['passage', 'mean-field'\]"):
        P.check_diffusivity("passing")
    assert P.drift_weight(0.5) == 1.0 and P.wall_weight(0.5) == 0.0 and P.wall_weight(1.0) == -1.0
    kernel = Uniform(radius=2.5, height=0.0024)
    # the library's callers now share the statement and its wording
    with pytest.raises(ValueError, match=r"^rule: must lie in \[0, 1\]"):
        cage_breaking(kernel, 1.3, rule=1.2)
    with pytest.raises(ValueError, match=r"^diffusivity: must be one of"):
        cage_breaking(kernel, 1.3, diffusivity="passing")
    with pytest.raises(ValueError, match=r"^rule: must lie in \[0, 1\]"):
        _passage.length_tensor(kernel, 1.3, 0.0, -0.5)


def test_cases_still_speak_in_case_keys(tmp_path):
    import spotpde

    data = {"domain": {"dims": 2, "x": [-4.0, 4.0], "z": [0.0, 8.0], "spacing": 1.0},
            "kernel": {"diffusivity": "passing"}}
    with pytest.raises(spotpde.CaseError, match="kernel.diffusivity"):
        spotpde.load_case(data)
    data["kernel"] = {"rule": 0.0}
    with pytest.raises(spotpde.CaseError, match="kernel.rule"):
        spotpde.load_case(data)


# -- typed parameters ----------------------------------------------------------------------

#: Units that may read a case's raw mapping: the app builds the typed objects from it,
#: and calibration fits parameters named by their case keys (and reloads the case).
READS_CASE_DATA = {"app", "cli", "calibration"}


def _reads_case_data(n):
    return isinstance(n, ast.Attribute) and n.attr == "data" \
        and isinstance(n.value, ast.Name) and n.value.id == "case"


def test_no_stage_reads_the_raw_case():
    reads = [s for s in _literals(_reads_case_data) if _unit(s.split(":")[0]) not in READS_CASE_DATA]
    assert reads == []
    assert _literals(_reads_case_data)     # the detector finds the app's reads


def test_the_case_builds_the_typed_pair_spots_and_comparison_settings():
    import spotpde
    from spotpde.analysis.comparison import case_problems
    from spotpde.parameters import ComparisonSettings, PairParams

    base = {"domain": {"dims": 2, "x": [-6.0, 6.0], "z": [0.0, 12.0], "spacing": 1.0}}
    case = spotpde.load_case(base)
    assert case.pair is None and case.spots.frames == 101
    assert case.comparison == ComparisonSettings("constant", ())
    case = spotpde.load_case({**base, "pair": {"x": 0.0, "z": 6.0, "start": {"x": 1.5, "z": 0.0}},
                              "spots": {"b": {"z": [0.0, 12.0], "values": [1.0, 1.3]},
                                        "frames": 7, "rho_max": 2.0, "mode": "transient",
                                        "t_end": 1.0},
                              "orifice": {"width": 2.0, "rate": {"times": [0.0, 1.0],
                                                                 "values": [1.0, 2.0]}}})
    assert case.pair == PairParams(x=0.0, z=6.0, contact=1.0, separation=2.0,
                                   start=(1.5, 0.0), spacing=None, frames=8)
    assert case.spots.frames == 7
    assert case.comparison == ComparisonSettings("table", ("b",))
    problems = case_problems(case)
    assert [p.split(":")[0] for p in problems] == ["spots.rho_max", "orifice.rate", "spots.b"]
