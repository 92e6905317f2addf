"""The case schema: every table's keys, defaults and allowed values, and the per-key checks.

:data:`DEFAULTS` lists every key of a case, table by table (docs/cases.md), and
:class:`_Validator` checks one table at a time: each key's type, range and finiteness
(lengths in particle diameters d, times in the case's time unit, all bounded by
:data:`MAX_LENGTH` in magnitude), unknown tables and keys (with a close-match hint),
and the small nested tables (``orifice.rate``, ``orifice.noise``, coefficient
profiles, ``tracer.start``, ``tracer.layers``, ``pair.start``). Problems are
collected, never raised here, as ``"dotted.key: message, got value"``.

Nesting deeper than :data:`MAX_NESTING` is refused before these checks, by
:mod:`._nesting` (its ``plain``, here ``_plain``, also turns numpy values into plain
ones).

The checks between keys live in :mod:`._consistency`, the memory estimate in
:mod:`._resources`; :func:`spotpde.cases.validate` runs the three in turn. The public
names are re-exported by :mod:`spotpde.cases`.
"""

from __future__ import annotations

import difflib
import math
import os
from collections.abc import Mapping
from typing import Any

from ..grid import COORDINATES, WALLS
from ..parameters import (DIFFUSIVITIES, HEIGHT_RANGE, ORIFICE_SHAPES, PROFILES, RULE_RANGE, SPOT_MODES,
                          TRACER_MODELS)
from ._nesting import MAX_NESTING, plain as _plain  # noqa: F401 - re-exported

KERNEL_SHAPES = ("uniform", "gaussian", "exponential")
#: Wall treatments of the influence kernel (``spotpde.fields._walls.WALL_TREATMENTS``).
KERNEL_WALLS = ("renormalise", "truncate")
#: Options of the tracer solver (``spotpde.tracer.solve``).
LIMITERS = ("koren", "vanleer", "mc", "minmod", "weno5", "upwind")
DIFFUSION_MODES = ("auto", "explicit", "implicit")
#: ``tracer.stepping`` (``spotpde.tracer.STEPPING_MODES``): SSP Runge-Kutta at the CFL
#: limit, or the long-run schemes of docs/long_runs.md.
STEPPING_MODES = ("explicit", "multirate", "imex", "implicit", "auto")
#: ``kernel.diffusivity``: the discrete model's passage diffusivity, or the paper's eq. Dp.

#: Defaults of every key, table by table (docs/interface.md). ``None`` marks an optional key
#: without a default. The ``tracer`` table itself is optional.
DEFAULTS: dict[str, dict[str, Any]] = {
    "domain": {"dims": 2, "x": [-30.0, 30.0], "y": None, "z": [0.0, 100.0], "spacing": 0.25,
               "walls": "reflecting", "coordinates": "cartesian", "hopper_angle": None},
    "orifice": {"x": 0.0, "y": None, "width": 0.0, "profile": "uniform", "rate": 1.0,
                "noise": None, "shape": None},
    "spots": {"drift": 1.0, "b": 1.3, "b_par": 0.0, "mode": "steady", "t_end": 0.0,
              "rho_max": None, "flux": None, "diffusion_scaling": None, "frames": None},
    "kernel": {"shape": "gaussian", "size": 1.0, "volume": 0.05, "height": None,
               "aspect": 1.0, "rule": 0.5, "walls": "renormalise"},
    "tracer": {"model": "spot", "start": None, "layers": None, "t_end": 100.0, "frames": 20,
               "limiter": "weno5", "cfl": 0.9, "diffusion": "auto", "snapshots": "auto",
               "stepping": "explicit", "split": None, "tol": 1e-5},
    "output": {"path": "out.nc"},
    # optional: cage breaking of a pair at a point of the flow (spotpde.pair, docs/pair.md)
    "pair": {"x": None, "z": None, "contact": 1.0, "separation": 2.0, "start": None,
             "spacing": None, "frames": 8},
}
DEFAULTS["kernel"]["diffusivity"] = "passage"
RATE_TABLE_KEYS = {"times": None, "values": None}
PROFILE_KEYS = {"x": None, "z": None, "values": None}
#: ``orifice.noise``: log-normal Ornstein-Uhlenbeck modulation of Q0 (spotpde.noise)
NOISE_KEYS = {"amplitude": None, "correlation_time": None, "seed": 0}
#: interacting spots (spotpde.traffic): flux shapes and diffusion scalings
FLUX_SHAPES = ("greenshields", "triangular")
DIFFUSION_SCALINGS = ("fixed", "speed")
START_KEYS = {"x": None, "y": None, "z": None, "width": 1.0}
LAYERS_KEYS = {"spacing": 10.0}
PAIR_START_KEYS = {"x": None, "z": None}

#: Upper bounds that keep every derived number finite and every index an int.
MAX_LENGTH = 1.0e6
MAX_FRAMES = 10_000
#: Ranges of the kernel's keys (d, d**dims, 1, 1): beyond them a kernel is absurd and its
#: numbers leave floating point (``w**2`` of a height of 1e-320 is 0, the spot area of an
#: aspect of 1e-300 overflows).
KERNEL_SIZES = (1e-3, MAX_LENGTH)
KERNEL_VOLUMES = (1e-12, MAX_LENGTH)
KERNEL_ASPECTS = (1e-3, 1e3)
KERNEL_HEIGHTS = HEIGHT_RANGE


# -- value helpers ------------------------------------------------------------------

def kernel_dims(domain: dict) -> int:
    """Dimension of the spots' kernel: ``domain.dims``, or 3 for an axisymmetric silo
    (its spots are 3D; the grid is the (r, z) half-plane)."""
    return 3 if domain.get("coordinates") == "axisymmetric" else domain["dims"]


def _ellipsoid_measure(radius: float, aspect: float, dims: int) -> float:
    """Area of the ellipse (2D) or volume of the spheroid (3D) with horizontal radius
    ``radius`` and vertical radius ``radius / aspect``, in d**dims."""
    if dims == 2:
        return math.pi * radius * radius / aspect
    return 4.0 / 3.0 * math.pi * radius**3 / aspect


def _show(value: Any) -> str:
    """A value as the user would write it in TOML."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return _toml_string(value)
    if isinstance(value, Mapping):
        return "a table"
    if isinstance(value, (list, tuple)):
        if len(value) <= 4:
            return "[" + ", ".join(_show(x) for x in value) + "]"
        return f"a list of {len(value)} values"
    return type(value).__name__


def _is_number(value: Any) -> bool:
    """An int or float, not a bool (TOML's ``true`` is not a number)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _toml_string(s: str) -> str:
    """``s`` as a TOML basic string: quotes and backslashes escaped, control characters
    as ``\\uXXXX`` (so an error message shows a bad name unambiguously)."""
    out = ['"']
    for c in s:
        if c == '"':
            out.append('\\"')
        elif c == "\\":
            out.append("\\\\")
        elif ord(c) < 0x20 or ord(c) == 0x7F:
            out.append(f"\\u{ord(c):04X}")
        else:
            out.append(c)
    out.append('"')
    return "".join(out)


# -- the per-table checks -----------------------------------------------------------

class _Validator:
    """Per-key checks of a raw case mapping; problems collect in :attr:`problems`.

    :meth:`tables` returns the normalised mapping (defaults filled in, numbers as
    ``float``/``int``; a key that failed its check is ``None``), the other methods check
    one value each and return it normalised, or ``None`` after recording a problem.
    """

    def __init__(self):
        self.problems: list[str] = []

    def bad(self, key: str, message: str, value: Any = None):
        """Record ``"key: message, got value"``."""
        self.problems.append(f"{key}: {message}, got {_show(value)}")

    # -- generic checks ------------------------------------------------------------
    def unknown(self, prefix: str, raw: Mapping, valid) -> None:
        for key in raw:
            if key not in valid:
                name = f"{prefix}{key}" if prefix else str(key)
                what = "table" if not prefix else "key"
                hint = difflib.get_close_matches(str(key), list(valid), n=1)
                extra = f" (did you mean {hint[0]!r}?)" if hint else ""
                choices = ", ".join(valid)
                self.problems.append(f"{name}: unknown {what}{extra}; valid {what}s: {choices}")

    def number(self, key, value, *, gt=None, ge=None, le=None, lt=None, integer=False,
               limit=MAX_LENGTH):
        """A finite number in range; returns float/int or None after recording a problem."""
        kind = "an integer" if integer else "a number"
        if integer:
            ok = isinstance(value, int) and not isinstance(value, bool)
        else:
            ok = _is_number(value)
        if not ok:
            self.bad(key, f"must be {kind}", value)
            return None
        if not integer:
            try:
                value = float(value)
            except OverflowError:
                value = math.inf
            if not math.isfinite(value):
                self.bad(key, "must be a finite number", value)
                return None
        conds = []
        if gt is not None and not value > gt:
            conds.append(f"> {_show(gt)}")
        if ge is not None and not value >= ge:
            conds.append(f">= {_show(ge)}")
        if le is not None and not value <= le:
            conds.append(f"<= {_show(le)}")
        if lt is not None and not value < lt:
            conds.append(f"< {_show(lt)}")
        if conds:
            self.bad(key, "must be " + " and ".join(conds), value)
            return None
        if limit is not None and abs(value) > limit:
            self.bad(key, f"must be at most {_show(limit)} in magnitude", value)
            return None
        return value

    def span(self, key, value, lo, hi):
        """A finite number in ``[lo, hi]``; out of range, one message with the whole range."""
        value = self.number(key, value, limit=None)
        if value is not None and not lo <= value <= hi:
            self.bad(key, f"must be in [{lo:g}, {hi:g}]", value)
            return None
        return value

    def choice(self, key, value, choices):
        if not isinstance(value, str) or value not in choices:
            allowed = ", ".join(f'"{c}"' for c in choices)
            self.bad(key, f"must be one of {allowed}", value)
            return None
        return value

    def pair(self, key, value):
        """Two finite increasing numbers ``[a, b]``."""
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            self.bad(key, "must be a list of two numbers [start, end]", value)
            return None
        a = self.number(f"{key}[0]", value[0])
        b = self.number(f"{key}[1]", value[1])
        if a is None or b is None:
            return None
        if not b > a:
            self.bad(key, "must be increasing (start < end)", value)
            return None
        return [a, b]

    def table(self, key, raw, defaults) -> dict | None:
        if not isinstance(raw, Mapping):
            self.bad(key, "must be a table", raw)
            return None
        self.unknown(f"{key}.", raw, defaults)
        out = dict(defaults)
        out.update({k: v for k, v in raw.items() if k in defaults})
        return out

    # -- tables --------------------------------------------------------------------
    def tables(self, raw: Mapping) -> dict:
        self.unknown("", raw, DEFAULTS)
        self.given = {name: set(t) for name, t in raw.items() if isinstance(t, Mapping)}
        data: dict[str, Any] = {}
        for name, defaults in DEFAULTS.items():
            if name in ("tracer", "pair", "montecarlo") and name not in raw:
                continue
            t = self.table(name, raw.get(name, {}), defaults)
            if t is None:
                continue
            data[name] = getattr(self, f"_{name}")(t)
        return data

    def _domain(self, t):
        return {
            "dims": self.dims(t["dims"]),
            "x": self.pair("domain.x", t["x"]),
            **({} if t["y"] is None else {"y": self.pair("domain.y", t["y"])}),
            "z": self.pair("domain.z", t["z"]),
            "spacing": self.number("domain.spacing", t["spacing"], gt=0),
            "walls": self.choice("domain.walls", t["walls"], WALLS),
            "coordinates": self.choice("domain.coordinates", t["coordinates"], COORDINATES),
            **({} if t["hopper_angle"] is None else
               {"hopper_angle": self.number("domain.hopper_angle", t["hopper_angle"], ge=0,
                                            lt=90)}),
        }

    def dims(self, value):
        if not isinstance(value, int) or isinstance(value, bool) or value not in (2, 3):
            self.bad("domain.dims", "must be 2 (x, z) or 3 (x, y, z)", value)
            return None
        return value

    def _orifice(self, t):
        out = {
            "x": self.number("orifice.x", t["x"]),
            "width": self.number("orifice.width", t["width"], ge=0),
            "profile": self.choice("orifice.profile", t["profile"], PROFILES),
            "rate": (self.rate_table(t["rate"]) if isinstance(t["rate"], Mapping)
                     else self.number("orifice.rate", t["rate"], gt=0)),
        }
        if t["y"] is not None:
            out["y"] = self.number("orifice.y", t["y"])
        if t["shape"] is not None:
            out["shape"] = self.choice("orifice.shape", t["shape"], ORIFICE_SHAPES)
        if t["noise"] is not None:
            out["noise"] = self.noise(t["noise"])
        return out

    def noise(self, raw):
        """``orifice.noise = { amplitude, correlation_time, seed }`` (spotpde.noise)."""
        t = self.table("orifice.noise", raw, NOISE_KEYS)
        if t is None:
            return None
        for key in ("amplitude", "correlation_time"):
            if t[key] is None:
                self.problems.append(f"orifice.noise.{key}: required in an orifice.noise table")
        return {"amplitude": (None if t["amplitude"] is None else
                              self.number("orifice.noise.amplitude", t["amplitude"], ge=0,
                                          le=10)),
                "correlation_time": (None if t["correlation_time"] is None else
                                     self.number("orifice.noise.correlation_time",
                                                 t["correlation_time"], gt=0)),
                "seed": self.number("orifice.noise.seed", t["seed"], ge=0, integer=True,
                                    limit=2**63 - 1)}

    def rate_table(self, raw):
        """``orifice.rate = { times = [...], values = [...] }``: Q0(t) for transient runs."""
        t = self.table("orifice.rate", raw, RATE_TABLE_KEYS)
        if t is None:
            return None
        out = {}
        for key in ("times", "values"):
            seq = t[key]
            if not isinstance(seq, (list, tuple)) or not 1 <= len(seq) <= 10_000:
                self.bad(f"orifice.rate.{key}", "must be a list of 1 to 10000 numbers", seq)
                return None
            nums = [self.number(f"orifice.rate.{key}[{i}]", v, ge=0 if key == "values"
                                else None, limit=1e9) for i, v in enumerate(seq)]
            if any(v is None for v in nums):
                return None
            out[key] = nums
        if len(out["times"]) != len(out["values"]):
            self.problems.append(f"orifice.rate: times and values must have the same length, "
                                 f"got {len(out['times'])} times and {len(out['values'])} "
                                 "values")
            return None
        if any(b <= a for a, b in zip(out["times"], out["times"][1:])):
            self.bad("orifice.rate.times", "must be strictly increasing", out["times"])
            return None
        if max(out["values"]) <= 0:
            self.bad("orifice.rate.values", "must include a value > 0", out["values"])
            return None
        return out

    def coefficient(self, key, value, **bounds):
        """A number, or a profile ``{ x | z = [...], values = [...] }`` (piecewise linear)."""
        if not isinstance(value, Mapping):
            return self.number(key, value, **bounds)
        t = self.table(key, value, PROFILE_KEYS)
        if t is None:
            return None
        axes = [a for a in ("x", "z") if t[a] is not None]
        if len(axes) != 1 or t["values"] is None:
            self.problems.append(f"{key}: a profile needs exactly one coordinate list (x or z) "
                                 "and a values list, e.g. { z = [0.0, 50.0], values = [1.0, 2.0] }")
            return None
        axis = axes[0]
        out = {}
        for name, kw in ((axis, {}), ("values", bounds)):
            seq = t[name]
            if not isinstance(seq, (list, tuple)) or not 2 <= len(seq) <= 10_000:
                self.bad(f"{key}.{name}", "must be a list of 2 to 10000 numbers", seq)
                return None
            nums = [self.number(f"{key}.{name}[{i}]", v, **kw) for i, v in enumerate(seq)]
            if any(v is None for v in nums):
                return None
            out[name] = nums
        if len(out[axis]) != len(out["values"]):
            self.problems.append(f"{key}: {axis} and values must have the same length, got "
                                 f"{len(out[axis])} and {len(out['values'])}")
            return None
        if any(b <= a for a, b in zip(out[axis], out[axis][1:])):
            self.bad(f"{key}.{axis}", "must be strictly increasing", out[axis])
            return None
        return out

    def _spots(self, t):
        return {
            "drift": self.coefficient("spots.drift", t["drift"], gt=0),
            "b": self.coefficient("spots.b", t["b"], gt=0),
            "b_par": self.coefficient("spots.b_par", t["b_par"], ge=0),
            "mode": self.choice("spots.mode", t["mode"], SPOT_MODES),
            "t_end": self.number("spots.t_end", t["t_end"], ge=0),
            **self.interacting(t),
        }

    def interacting(self, t):
        """Optional interacting-spot keys (spotpde.traffic); absent keys stay absent."""
        out = {}
        if t["rho_max"] is not None:
            out["rho_max"] = self.number("spots.rho_max", t["rho_max"], gt=0, limit=1e12)
        if t["flux"] is not None:
            out["flux"] = self.choice("spots.flux", t["flux"], FLUX_SHAPES)
        if t["diffusion_scaling"] is not None:
            out["diffusion_scaling"] = self.choice("spots.diffusion_scaling",
                                                   t["diffusion_scaling"], DIFFUSION_SCALINGS)
        if t["frames"] is not None:
            out["frames"] = self.number("spots.frames", t["frames"], ge=2, integer=True,
                                        limit=MAX_FRAMES)
        return out

    def _rule(self, value):
        """``kernel.rule``: lam in (0, 1], or ``"kinematic"`` (``1/2 + V2 / (2 V1)``)."""
        if value == "kinematic":
            return value
        if isinstance(value, str):
            self.bad("kernel.rule", 'must be a number in (0, 1] or "kinematic"', value)
            return None
        return self.number("kernel.rule", value, gt=RULE_RANGE[0], le=RULE_RANGE[1])

    def _kernel(self, t):
        out = {
            "shape": self.choice("kernel.shape", t["shape"], KERNEL_SHAPES),
            "size": self.span("kernel.size", t["size"], *KERNEL_SIZES),
            "volume": self.span("kernel.volume", t["volume"], *KERNEL_VOLUMES),
            "aspect": self.span("kernel.aspect", t["aspect"], *KERNEL_ASPECTS),
            "rule": self._rule(t["rule"]),
            "walls": self.choice("kernel.walls", t["walls"], KERNEL_WALLS),
            "diffusivity": self.choice("kernel.diffusivity", t["diffusivity"], DIFFUSIVITIES),
        }
        if t["height"] is not None:
            out["height"] = self.span("kernel.height", t["height"], *KERNEL_HEIGHTS)
            del out["volume"]
            if "volume" in self.given.get("kernel", ()):
                self.problems.append("kernel.volume: give either kernel.volume or "
                                     "kernel.height (uniform kernel), not both")
        return out

    def _tracer(self, t):
        out = {
            "model": self.choice("tracer.model", t["model"], TRACER_MODELS),
            "t_end": (math.inf if _is_number(t["t_end"]) and float(t["t_end"]) == math.inf
                      else self.number("tracer.t_end", t["t_end"], gt=0, limit=1e9)),
            "frames": self.number("tracer.frames", t["frames"], integer=True, ge=2,
                                  le=MAX_FRAMES),
            "limiter": self.choice("tracer.limiter", t["limiter"], LIMITERS),
            "cfl": self.number("tracer.cfl", t["cfl"], gt=0, le=1),
            "diffusion": self.choice("tracer.diffusion", t["diffusion"], DIFFUSION_MODES),
            "snapshots": t["snapshots"],
            "stepping": self.choice("tracer.stepping", t["stepping"], STEPPING_MODES),
            "tol": self.number("tracer.tol", t["tol"], gt=0, lt=1),
        }
        if t["split"] is not None:
            out["split"] = self.number("tracer.split", t["split"], ge=1, limit=1e6)
        n = t["snapshots"]
        if n != "auto" and not (isinstance(n, int) and not isinstance(n, bool)
                                and 2 <= n <= MAX_FRAMES):
            self.bad("tracer.snapshots", f'must be "auto" or an integer in [2, {MAX_FRAMES}]',
                     n)
        if t["start"] is not None and t["layers"] is not None:
            self.problems.append(
                "tracer: give either tracer.start (a Gaussian blob) or tracer.layers, not both")
        elif t["start"] is None and t["layers"] is None:
            self.problems.append(
                "tracer: missing the initial density; give tracer.start = { x, z, width } "
                "or tracer.layers = { spacing }")
        elif t["start"] is not None:
            s = self.table("tracer.start", t["start"], START_KEYS)
            if s is not None:
                start = {}
                for key in ("x", "y", "z"):
                    if s[key] is not None:
                        start[key] = self.number(f"tracer.start.{key}", s[key])
                    elif key != "y":
                        self.problems.append(f"tracer.start.{key}: required (a number, in d)")
                start["width"] = self.number("tracer.start.width", s["width"], gt=0)
                out["start"] = start
        else:
            s = self.table("tracer.layers", t["layers"], LAYERS_KEYS)
            if s is not None:
                out["layers"] = {"spacing": self.number("tracer.layers.spacing", s["spacing"],
                                                        gt=0)}
        return out

    def _pair(self, t):
        out = {}
        for key in ("x", "z"):
            if t[key] is None:
                self.problems.append(f"pair.{key}: required (a number, in d): the point of "
                                     "the flow where the pair falls")
            else:
                out[key] = self.number(f"pair.{key}", t[key])
        out["contact"] = self.number("pair.contact", t["contact"], gt=0)
        out["separation"] = self.number("pair.separation", t["separation"], gt=0)
        if t["spacing"] is not None:
            out["spacing"] = self.number("pair.spacing", t["spacing"], gt=0)
        out["frames"] = self.number("pair.frames", t["frames"], integer=True, ge=1,
                                    le=MAX_FRAMES)
        c, s = out["contact"], out["separation"]
        if c is not None and s is not None and not s > c:
            self.bad("pair.separation", f"must be > pair.contact = {_show(c)}", s)
            c = s = None
        if t["start"] == "contact":
            out["start"] = "contact"      # uniform over the contact directions
        elif t["start"] is not None:
            st = self.table("pair.start", t["start"], PAIR_START_KEYS)
            if st is not None:
                sx = self.number("pair.start.x", 0.0 if st["x"] is None else st["x"])
                sz = self.number("pair.start.z", 0.0 if st["z"] is None else st["z"])
                out["start"] = {"x": sx, "z": sz}
                if None not in (sx, sz, c, s):
                    r = math.hypot(sx, sz)
                    if r < c:
                        self.problems.append(f"pair.start: is inside the core: |start| = "
                                             f"{r:.6g} < pair.contact = {_show(c)}")
                    elif r >= s:
                        self.problems.append(f"pair.start: is outside the cage: |start| = "
                                             f"{r:.6g} >= pair.separation = {_show(s)}")
        if out.get("spacing") is not None and c is not None and out["spacing"] > c / 2:
            self.bad("pair.spacing", f"must be at most pair.contact / 2 = {_show(c / 2)}",
                     out["spacing"])
        return out

    def _output(self, t):
        path = t["path"]
        if not isinstance(path, str) or not path.strip() or "\x00" in path:
            self.bad("output.path", "must be a non-empty file name (string)", path)
            path = None
        elif path.endswith(("/", os.sep)) or os.path.isdir(os.path.expanduser(path)):
            self.bad("output.path", "must name a file, not a directory", path)
            path = None
        return {"path": path}


# -- the optional [montecarlo] table: the Monte Carlo's run settings (_schema_mc) -------
from ._schema_mc import MONTECARLO_KEYS, check_montecarlo  # noqa: E402

DEFAULTS["montecarlo"] = MONTECARLO_KEYS
_Validator._montecarlo = check_montecarlo
