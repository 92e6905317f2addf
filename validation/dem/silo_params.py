"""Parameters of a DEM silo run: read a TOML file, apply ``--set`` overrides, validate.

Units: lengths in the mean grain diameter d, accelerations in g, times in sqrt(d/g),
masses in the mass m of a grain of diameter d (2D disks: m = D^2, 3D spheres:
m = D^3 for a grain of diameter D). Stiffnesses are in m g / d.

Errors raise ``ParamError`` whose message starts with the dotted key at fault.
"""

from __future__ import annotations

import copy
import math
import tomllib
from pathlib import Path

DEFAULTS = {
    "silo": {"dims": 2, "width": 40.0, "fill_height": 53.0, "orifice": 6.0,
             "depth": 8.0},
    "grains": {"polydispersity": 0.1, "packing_fraction": None},
    "contacts": {"stiffness": 1.0e4, "tangential_stiffness": 2.0 / 7.0,
                 "restitution": 0.9, "tangential_damping": 0.5, "friction": 0.5,
                 "wall_friction": 0.5},
    "time": {"step": 5.0e-4, "settle": 20.0, "warm": 40.0, "measure": 200.0,
             "output": 0.2, "reinsert": 0.25, "clog": 20.0},
    "run": {"seed": 1, "compress": True},
}

#: settled packing fraction used to count the grains for a fill height (disks, spheres)
PACKING = {2: 0.82, 3: 0.60}


class ParamError(ValueError):
    """An invalid parameter; the message starts with its dotted key."""


def load(path: str | Path, overrides: list[str] | None = None) -> dict:
    """Parameters from the TOML file at ``path`` with ``KEY=VALUE`` overrides applied."""
    with open(path, "rb") as f:
        raw = tomllib.load(f)
    for item in overrides or []:
        key, sep, value = item.partition("=")
        if not sep:
            raise ParamError(f"{item}: an override is KEY=VALUE, e.g. contacts.stiffness=4e4")
        _set(raw, key.strip(), value.strip())
    return resolve(raw)


def _set(raw: dict, key: str, text: str) -> None:
    table, _, name = key.rpartition(".")
    if table not in DEFAULTS or name not in DEFAULTS[table]:
        valid = ", ".join(f"{t}.{k}" for t in DEFAULTS for k in DEFAULTS[t])
        raise ParamError(f"{key}: unknown key; valid keys: {valid}")
    try:
        value = tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        value = text
    raw.setdefault(table, {})[name] = value


def resolve(raw: dict) -> dict:
    """Fill defaults, check types and ranges, and return a new parameter dict."""
    p = copy.deepcopy(DEFAULTS)
    for table, values in raw.items():
        if table not in DEFAULTS:
            raise ParamError(f"{table}: unknown table; valid tables: {', '.join(DEFAULTS)}")
        if not isinstance(values, dict):
            raise ParamError(f"{table}: must be a table")
        for name, value in values.items():
            if name not in DEFAULTS[table]:
                valid = ", ".join(DEFAULTS[table])
                raise ParamError(f"{table}.{name}: unknown key; valid keys: {valid}")
            p[table][name] = value
    _check(p)
    return p


def _number(p, table, name, low=None, high=None, low_open=False, integer=False):
    value = p[table][name]
    kind = int if integer else (int, float)
    if isinstance(value, bool) or not isinstance(value, kind) or not math.isfinite(value):
        raise ParamError(f"{table}.{name}: must be a {'whole' if integer else ''} number, "
                         f"got {value!r}".replace("a  ", "a "))
    if low is not None and (value < low or (low_open and value == low)):
        raise ParamError(f"{table}.{name}: must be {'>' if low_open else '>='} {low}, "
                         f"got {value}")
    if high is not None and value > high:
        raise ParamError(f"{table}.{name}: must be <= {high}, got {value}")
    return value


def _check(p: dict) -> None:
    if p["silo"]["dims"] not in (2, 3):
        raise ParamError(f"silo.dims: must be 2 (disks) or 3 (a slab), got {p['silo']['dims']!r}")
    _number(p, "silo", "width", 4.0)
    _number(p, "silo", "fill_height", 2.0)
    _number(p, "silo", "orifice", 0.0, p["silo"]["width"] - 2.0, low_open=True)
    _number(p, "silo", "depth", 1.5)
    _number(p, "grains", "polydispersity", 0.0, 0.4)
    if p["grains"]["packing_fraction"] is None:
        p["grains"]["packing_fraction"] = PACKING[p["silo"]["dims"]]
    _number(p, "grains", "packing_fraction", 0.1, 0.95)
    _number(p, "contacts", "stiffness", 0.0, low_open=True)
    _number(p, "contacts", "tangential_stiffness", 0.0, 1.0)
    _number(p, "contacts", "restitution", 0.0, 1.0, low_open=True)
    _number(p, "contacts", "tangential_damping", 0.0)
    _number(p, "contacts", "friction", 0.0)
    _number(p, "contacts", "wall_friction", 0.0)
    _number(p, "run", "seed", 0, integer=True)
    if not isinstance(p["run"]["compress"], bool):
        raise ParamError(f"run.compress: must be true or false, got {p['run']['compress']!r}")
    t = p["time"]
    _number(p, "time", "step", 0.0, low_open=True)
    for name in ("settle", "warm", "measure", "output", "reinsert", "clog"):
        _number(p, "time", name, 0.0, low_open=name not in ("warm", "measure"))
    for name in ("settle", "warm", "measure", "output", "reinsert"):
        steps = t[name] / t["step"]
        if abs(steps - round(steps)) > 1e-6 * max(1.0, steps):
            raise ParamError(f"time.{name}: must be a whole number of time steps "
                             f"(time.step = {t['step']}), got {t[name]}")
    if t["step"] > collision_time(p) / 10:
        raise ParamError(f"time.step: must resolve a contact with >= 10 steps; the collision "
                         f"time is {collision_time(p):.4g}, so time.step <= "
                         f"{collision_time(p) / 10:.4g}, got {t['step']}")


def gamma_n(p: dict) -> float:
    """LAMMPS's normal damping gamma_n (1/time) giving ``contacts.restitution`` for two mean grains.

    A Hookean contact with damping force ``-m_eff gamma_n v_n`` is a damped oscillator;
    its restitution is ``e = exp(-gamma_n pi / (2 omega))``, ``omega^2 = k_n/m_eff -
    gamma_n^2/4``, solved here for ``gamma_n`` with ``m_eff = m/2`` (two grains of mass 1).
    """
    omega0 = math.sqrt(p["contacts"]["stiffness"] / 0.5)
    beta = -math.log(p["contacts"]["restitution"]) / math.pi
    return 2.0 * beta * omega0 / math.sqrt(1.0 + beta * beta)


def collision_time(p: dict) -> float:
    """Duration of a binary collision of two mean grains, pi / omega (time units)."""
    omega0_sq = p["contacts"]["stiffness"] / 0.5
    return math.pi / math.sqrt(omega0_sq - gamma_n(p) ** 2 / 4.0)


def steps(p: dict, name: str) -> int:
    """The duration ``time.<name>`` in time steps."""
    return int(round(p["time"][name] / p["time"]["step"]))


def grain_count(p: dict) -> int:
    """Grains filling the silo to ``silo.fill_height`` at ``grains.packing_fraction``."""
    s, g = p["silo"], p["grains"]
    poly = g["polydispersity"]
    if s["dims"] == 2:
        mean_size = math.pi / 4 * (1 + poly**2 / 3)            # <D^2> pi/4, D uniform
        volume = s["width"] * s["fill_height"]
    else:
        mean_size = math.pi / 6 * (1 + poly**2)                 # <D^3> pi/6
        volume = s["width"] * s["depth"] * s["fill_height"]
    return int(round(g["packing_fraction"] * volume / mean_size))
