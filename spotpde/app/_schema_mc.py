"""The optional ``[montecarlo]`` case table: run settings of the discrete spot model
(``spotpde.montecarlo.from_case``; docs/cases.md, docs/montecarlo.md).

Every key is optional and has no default here: a key left out keeps the default of the
Python keyword of the same name (``from_case`` / ``simulate``), and a Python keyword
given to ``from_case`` overrides the table. The names are those keywords:

``particles`` ("lattice", "random", "tracer", "none"), ``spacing`` (d), ``seed``,
``t_end`` or ``n_spots``, ``step`` (d), ``gamma``, ``steps``, ``probes``, ``batches``,
``records``, ``tracked`` ("all", "none"), ``replicas`` (independent runs, seeds
``seed, seed + 1, ...``: ``montecarlo.replicas_from_case``), and ``relax`` = ``true`` (the defaults of
``montecarlo.Relax``), ``false``, or a table of ``Relax``'s fields (``alpha``,
``iterations``, ``every``, ``radius``, ``polydispersity``, ``distribution``, ``opening``,
``margin``).

The choices are spelled out here rather than imported, so that checking a case does not
load the Monte Carlo's compiled kernels; ``tests/montecarlo/test_montecarlo_case.py`` checks they
match ``montecarlo.STEPS`` and ``montecarlo.DISTRIBUTIONS``.
"""

from __future__ import annotations

from typing import Any

#: the ``[montecarlo]`` keys (all optional, no defaults: see the module docstring)
MONTECARLO_KEYS: dict[str, Any] = {
    "particles": None, "spacing": None, "seed": None, "t_end": None, "n_spots": None,
    "step": None, "gamma": None, "steps": None, "probes": None, "batches": None,
    "records": None, "tracked": None, "replicas": None, "relax": None}
#: the ``montecarlo.relax`` table's keys: ``spotpde.montecarlo.Relax``'s fields
RELAX_KEYS: dict[str, Any] = {
    "alpha": None, "iterations": None, "every": None, "radius": None,
    "polydispersity": None, "distribution": None, "opening": None, "margin": None}
PARTICLES = ("lattice", "random", "tracer", "none")
TRACKED = ("all", "none")
STEPS = ("gaussian", "binary")
DISTRIBUTIONS = ("uniform", "gaussian")
MAX_COUNT = 10_000  # batches, records
MAX_ITERATIONS = 10_000  # relax.iterations, relax.every
MAX_SEED = 2**63 - 1


def check_montecarlo(v, t: dict) -> dict:
    """Check a ``[montecarlo]`` table (defaults filled in by ``_Validator.table``) with
    the validator ``v``; returns the keys that were given, normalised (a failed key is
    ``None``)."""
    k = "montecarlo."
    out: dict[str, Any] = {}
    num = {"spacing": dict(gt=0), "t_end": dict(gt=0, limit=1e9), "step": dict(gt=0),
           "gamma": dict(ge=0, lt=1)}
    ints = {"seed": dict(ge=0, limit=MAX_SEED), "n_spots": dict(ge=1, limit=10**12),
            "batches": dict(ge=1, le=MAX_COUNT), "records": dict(ge=1, le=MAX_COUNT),
            "replicas": dict(ge=1, le=MAX_COUNT)}
    for key, value in t.items():
        if value is None:
            continue
        if key in num:
            out[key] = v.number(k + key, value, **num[key])
        elif key in ints:
            out[key] = v.number(k + key, value, integer=True, **ints[key])
        elif key == "particles":
            out[key] = v.choice(k + key, value, PARTICLES)
        elif key == "tracked":
            out[key] = v.choice(k + key, value, TRACKED)
        elif key == "steps":
            out[key] = v.choice(k + key, value, STEPS)
        elif key == "probes":
            out[key] = _boolean(v, k + key, value)
        elif key == "relax":
            out[key] = _relax(v, value)
    if "t_end" in out and "n_spots" in out:
        v.problems.append("montecarlo.n_spots: give either montecarlo.t_end or "
                          "montecarlo.n_spots, not both")
    return out


def _boolean(v, key, value):
    if not isinstance(value, bool):
        v.bad(key, "must be true or false", value)
        return None
    return value


def _relax(v, value):
    """``relax = true | false | { alpha, iterations, ... }``."""
    if isinstance(value, bool):
        return value
    if not isinstance(value, dict):
        v.bad("montecarlo.relax", "must be true, false or a table of "
              + ", ".join(RELAX_KEYS), value)
        return None
    t = v.table("montecarlo.relax", value, RELAX_KEYS)
    if t is None:
        return None
    k = "montecarlo.relax."
    out: dict[str, Any] = {}
    for key, val in t.items():
        if val is None:
            continue
        if key == "alpha":
            out[key] = v.number(k + key, val, gt=0, le=0.5)
        elif key in ("iterations", "every"):
            out[key] = v.number(k + key, val, integer=True, ge=1, le=MAX_ITERATIONS)
        elif key == "polydispersity":
            out[key] = v.number(k + key, val, ge=0, lt=0.5)
        elif key == "distribution":
            out[key] = v.choice(k + key, val, DISTRIBUTIONS)
        elif key == "opening":
            out[key] = v.number(k + key, val, ge=0)
        else:  # radius, margin
            out[key] = v.number(k + key, val, gt=0)
    return out
