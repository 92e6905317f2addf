"""Case files: TOML in, a validated :class:`Case` out.

A case is read with :mod:`tomllib` (or given as a mapping with the same keys) and
validated completely before any work: every key's type, range and finiteness, unknown
tables and keys, and cross-key consistency (the orifice on the floor, increasing
ranges, a grid that divides the domain, and a grid whose arrays fit in memory,
estimated before anything is allocated). All problems are collected and raised
together as one :class:`spotpde.CaseError`, one line per problem, each naming the key
by its dotted name::

    spots.b: must be > 0, got -1.0

Every key, its type, default, range and meaning is listed in ``docs/cases.md``.
Lengths are in particle diameters d; times in the case's time unit.
"""

from __future__ import annotations

import difflib
import math
import os
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import CaseError
from ..grid import WALLS, Grid
from ..parameters import PROFILES, SPOT_MODES, TRACER_MODELS, Orifice, Spots, Tracer, TracerStart

KERNEL_SHAPES = ("uniform", "gaussian", "exponential")
#: Wall treatments of the influence kernel (``spotpde._walls.WALL_TREATMENTS``).
KERNEL_WALLS = ("renormalise", "truncate")
#: Options of the tracer solver (``spotpde.tracer.solve``).
LIMITERS = ("koren", "vanleer", "mc", "minmod", "weno5", "upwind")
DIFFUSION_MODES = ("auto", "explicit", "implicit")
#: ``kernel.diffusivity``: the discrete model's passage diffusivity, or the paper's eq. Dp.
DIFFUSIVITIES = ("passage", "mean-field")

#: Defaults of every key, table by table (docs/interface.md). ``None`` marks an optional key
#: without a default. The ``tracer`` table itself is optional.
DEFAULTS: dict[str, dict[str, Any]] = {
    "domain": {"dims": 2, "x": [-30.0, 30.0], "z": [0.0, 100.0], "spacing": 0.25,
               "walls": "reflecting"},
    "orifice": {"x": 0.0, "y": None, "width": 0.0, "profile": "uniform", "rate": 1.0,
                "noise": None},
    "spots": {"drift": 1.0, "b": 1.3, "b_par": 0.0, "mode": "steady", "t_end": 0.0,
              "rho_max": None, "flux": None, "diffusion_scaling": None, "frames": None},
    "kernel": {"shape": "gaussian", "size": 1.0, "volume": 0.05, "height": None,
               "aspect": 1.0, "rule": 0.5, "walls": "renormalise"},
    "tracer": {"model": "spot", "start": None, "layers": None, "t_end": 100.0, "frames": 20,
               "limiter": "weno5", "cfl": 0.9, "diffusion": "auto", "snapshots": "auto"},
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
#: Fraction of the available memory a run may plan to use.
MEMORY_FRACTION = 0.6
#: Memory of the interpreter and libraries of a run (numpy, numba, xarray, matplotlib).
BASELINE_BYTES = 512 * 1024**2
#: Horizontal reach of a kernel in units of its ``size``, used only if the kernel cannot
#: be built (the estimate otherwise asks the kernel class: ``kernel_halfwidths``); the
#: smooth kernels are cut where ``w = 1e-14 w(0)``.
_REACH = {"uniform": 1.0, "gaussian": 8.0, "exponential": 32.3}


class Case:
    """A validated case: typed parameters plus the canonical mapping it came from.

    Attributes:
        data: the validated mapping with every default filled in (plain Python types).
        text: the TOML text the case was read from (or :meth:`to_toml` for a mapping).
        source: the case file's path, or ``None`` for a mapping.
        grid: :class:`spotpde.grid.Grid`.
        orifice: :class:`spotpde.parameters.Orifice`.
        spots: :class:`spotpde.parameters.Spots`.
        tracer: :class:`spotpde.parameters.Tracer`, or ``None`` without a ``[tracer]`` table.
        rule: lam, where along a spot step its influence is evaluated (1 for the void model).
        tracer_options: keyword options of ``spotpde.tracer.solve`` (``limiter``, ``cfl``,
            ``diffusion``), empty without a tracer.
        output_path: ``output.path`` resolved against the current directory.
    """

    def __init__(self, data: dict, text: str | None = None, source: str | None = None):
        self.data = data
        self.source = source
        self.text = text if text is not None else self.to_toml()
        d, o, s, k = data["domain"], data["orifice"], data["spots"], data["kernel"]
        self.grid = Grid(dims=d["dims"], x_range=tuple(d["x"]), z_range=tuple(d["z"]),
                         spacing=d["spacing"], walls=d["walls"])
        rate = o["rate"]
        if isinstance(rate, dict):
            from ..density.orifice import rate_from_table

            rate = rate_from_table(rate["times"], rate["values"])
        if o.get("noise") is not None:
            from ..density.noise import noisy_rate

            rate = noisy_rate(rate, **o["noise"])
        self.orifice = Orifice(x=o["x"], width=o["width"], profile=o["profile"],
                               rate=rate, y=o.get("y"))
        self.spots = Spots(drift=_field(s["drift"], self.grid), b=_field(s["b"], self.grid),
                           b_par=_field(s["b_par"], self.grid), mode=s["mode"],
                           t_end=s["t_end"], rho_max=s.get("rho_max"),
                           flux=s.get("flux") or "greenshields",
                           diffusion_scaling=s.get("diffusion_scaling") or "fixed")
        self.tracer = _tracer(data.get("tracer"), self.grid, self.orifice)
        t = data.get("tracer")
        self.tracer_options = ({} if t is None else
                               {k: t[k] for k in ("limiter", "cfl", "diffusion")})
        volume = (k["height"] * _ellipsoid_measure(k["size"], k["aspect"], d["dims"])
                  if "height" in k else k["volume"])
        self.kernel_spec = {"shape": k["shape"], "size": k["size"], "volume": volume,
                            "aspect": k["aspect"], "dims": d["dims"]}
        self._kernel = None

    # -- derived --------------------------------------------------------------------
    @property
    def model(self) -> str:
        """``"spot"`` or ``"void"`` (``tracer.model``; ``"spot"`` without a tracer)."""
        return self.tracer.model if self.tracer is not None else "spot"

    @property
    def rule(self) -> float:
        """lam: ``kernel.rule``, or 1 for the void model."""
        return 1.0 if self.model == "void" else float(self.data["kernel"]["rule"])

    @property
    def kernel_walls(self) -> str:
        """``kernel.walls``: ``"renormalise"`` (free volume conserved at walls) or ``"truncate"``."""
        return str(self.data["kernel"].get("walls", "renormalise"))

    @property
    def diffusivity(self) -> str:
        """``kernel.diffusivity``: ``"passage"`` or ``"mean-field"`` (``"mean-field"`` for the
        void model, whose fields are exact: a void never displaces a particle twice)."""
        return "mean-field" if self.model == "void" else str(self.data["kernel"]["diffusivity"])

    @property
    def kernel(self):
        """The influence kernel, ``spotpde.kernels.from_spec(shape, size, volume, aspect, dims)``."""
        if self._kernel is None:
            from ..fields import kernels

            self._kernel = kernels.from_spec(**self.kernel_spec)
        return self._kernel

    @property
    def output_path(self) -> Path:
        """``output.path``; a relative path is resolved against the current directory."""
        return Path(os.path.abspath(os.path.expanduser(self.data["output"]["path"])))

    def with_output(self, path: str | os.PathLike) -> "Case":
        """A copy of this case writing to ``path`` (the command line's ``-o``).

        Raises:
            spotpde.CaseError: ``output.path: ...`` for a path that is not a file name.
        """
        data = {t: dict(v) if isinstance(v, dict) else v for t, v in self.data.items()}
        data["output"]["path"] = os.fspath(path)
        return Case(validate(data), None, self.source)

    def snapshot_times(self) -> np.ndarray | None:
        """Times of the spot-density snapshots behind a tracer in a transient flow.

        With ``spots.mode = "transient"`` and a tracer, the tracer's drift and diffusivity
        follow the flow as it starts: the spot density is kept at these times and the
        coefficient fields are interpolated linearly in time between them. The times are
        ``tracer.snapshots`` equally spaced times over ``[0, tracer.t_end]`` (the reported
        ``rho_s`` is solved separately, at ``spots.t_end``).

        Returns:
            Times in the case time unit, or ``None`` (steady spots, or no tracer).
        """
        t = self.data.get("tracer")
        if t is None or self.data["spots"]["mode"] != "transient":
            return None
        n = t["snapshots"]
        if n == "auto":
            n = auto_snapshots(self.data)
        return np.linspace(0.0, t["t_end"], n)

    def to_toml(self) -> str:
        """The validated case as TOML text, every default written out."""
        return dump_toml(self.data)

    def __repr__(self) -> str:
        return f"Case(source={self.source!r}, grid={self.grid!r}, model={self.model!r})"


# -- loading ------------------------------------------------------------------------

def load_case(source: str | os.PathLike | Mapping, *, frames_in_memory: bool = True) -> Case:
    """Read and validate a case.

    Args:
        source: path of a TOML case file, or a mapping with the same tables and keys.
        frames_in_memory: count the tracer frames in the memory check. ``False`` for a
            run that streams them to its result file (``spotpde.run(case, path=...)``,
            what ``spotpde run`` does).

    Returns:
        The validated :class:`Case`.

    Raises:
        spotpde.CaseError: one line per problem (unreadable file, malformed TOML,
            unknown or mistyped key, value out of range, inconsistent keys, a grid
            too large for memory).
    """
    text = None
    path = None
    if isinstance(source, Mapping):
        raw = source
    elif isinstance(source, (str, os.PathLike)):
        path = os.fspath(source)
        try:
            with open(path, "rb") as fh:
                blob = fh.read()
        except OSError as exc:
            raise CaseError(f"{path}: cannot read the case file ({exc.strerror or exc})") from None
        try:
            text = blob.decode("utf-8-sig")   # a byte-order mark (some editors) is fine
            raw = tomllib.loads(text)
        except UnicodeDecodeError:
            raise CaseError(f"{path}: malformed TOML: not UTF-8 text") from None
        except tomllib.TOMLDecodeError as exc:
            raise CaseError(f"{path}: malformed TOML: {exc}") from None
    else:
        raise CaseError(
            f"case: must be a path to a TOML file or a mapping, got {type(source).__name__}")
    data = validate(raw, frames_in_memory=frames_in_memory)
    case = Case(data, text, path)
    _check_kernel(case)
    _warn_wide_kernel(data)
    return case


def validate(raw: Mapping, *, frames_in_memory: bool = True) -> dict:
    """Validate a raw case mapping.

    Args:
        raw: tables and keys as read from TOML.
        frames_in_memory: count the tracer frames in the memory check.

    Returns:
        The normalised mapping (floats as ``float``, every default filled in).

    Raises:
        spotpde.CaseError: listing every problem found.
    """
    v = _Validator()
    data = v.tables(_plain(raw))
    if not v.problems:
        v.cross(data)
    if not v.problems:
        v.memory(data, frames_in_memory)
    if v.problems:
        raise CaseError(v.problems)
    return data


def _plain(value: Any) -> Any:
    """A case mapping from Python code with plain TOML types: numpy scalars become
    ``int``/``float``/``bool``, numpy arrays and tuples lists, paths strings (so that
    ``{"domain": {"dims": np.int64(2), "x": np.array([-4.0, 4.0])}}`` and
    ``{"output": {"path": pathlib.Path("r.nc")}}`` are accepted)."""
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    return value


# -- helpers used by the pipeline ----------------------------------------------------

def available_memory() -> int:
    """Bytes of memory available to a new run (:func:`psutil.virtual_memory`
    ``available``; else ``MemAvailable`` of ``/proc/meminfo``, else free pages).

    Returns:
        Available memory in bytes (4 GiB if the system does not say).
    """
    try:
        import psutil

        return int(psutil.virtual_memory().available)
    except Exception:  # noqa: BLE001 - psutil missing or unsupported platform
        pass
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 4 * 1024**3


def auto_snapshots(data: Mapping) -> int:
    """``tracer.snapshots = "auto"``: one snapshot per time a spot needs to rise by the
    kernel's vertical size (``kernel.size / kernel.aspect / max v_s``) over
    ``[0, tracer.t_end]``, at least 21 and at most 401.

    Args:
        data: a validated case mapping with a tracer and transient spots.
    """
    s, k, t = data["spots"], data["kernel"], data["tracer"]
    drift = s["drift"]
    v = float(np.max(np.abs(drift["values"] if isinstance(drift, Mapping) else drift)))
    n = math.ceil(t["t_end"] * v * k["aspect"] / k["size"]) + 1
    return int(min(max(n, 21), 401))


def estimate_bytes(data: Mapping, frames_in_memory: bool = True) -> int:
    """Estimate the memory a run of a validated case holds at its peak.

    Counts every grid array of the run (spot density, kinematic speed, drift and
    diffusivity fields, solver scratch), the zero-padded FFT arrays of the kernel
    convolution, the sampled kernel stencil, and the tracer frames.

    Args:
        data: a mapping that passed the per-key checks (``validate`` internals).
        frames_in_memory: count the tracer frames (``False`` when they are streamed to
            the result file one at a time).

    Returns:
        Estimated peak bytes (a float-safe int).
    """
    return _estimate(data, frames_in_memory)


def kernel_halfwidths(data: Mapping) -> tuple[int, int]:
    """Half-widths ``(vertical, horizontal)`` in cells of the sampled kernel stencil of a
    validated case, from the kernel class's own reach (``Kernel.halfwidths``); the
    stencil has ``2 m + 1`` cells along each axis (e.g. 65 for a Gaussian of sigma 1 at
    h = 0.25, 259 for an exponential kernel of decay length 1).
    """
    from ..fields import kernels

    d, k = data["domain"], data["kernel"]
    volume = (k["height"] * _ellipsoid_measure(k["size"], k["aspect"], d["dims"])
              if "height" in k else k["volume"])
    kern = kernels.from_spec(k["shape"], k["size"], volume, k["aspect"], d["dims"])
    m = kern.halfwidths(d["spacing"])
    return m[0], m[-1]


def _estimate(data: Mapping, frames_in_memory: bool = True, *, pad: bool = True,
              stencil: bool = True, frames: bool = True) -> int:
    """:func:`estimate_bytes`; ``pad``/``stencil``/``frames`` False leave out the open-wall
    padding, the kernel stencil (a 1-cell stencil) or the tracer frames (one frame), to
    find which key makes a case too large."""
    d, k = data["domain"], data["kernel"]
    dims, h = d["dims"], d["spacing"]
    nx = (d["x"][1] - d["x"][0]) / h
    nz = (d["z"][1] - d["z"][0]) / h
    if d["walls"] == "open" and pad:   # the spot density is solved on a padded, wider grid
        b = data["spots"]["b"]
        b = max(b["values"]) if isinstance(b, Mapping) else b
        nx += 2 * math.ceil(6.0 * math.sqrt(b * (d["z"][1] - d["z"][0])) / h)
    cells = nz * nx ** (dims - 1)
    if not stencil:
        sx = sz = 1
    else:
        try:
            mz, mh = kernel_halfwidths(data)
            sx, sz = 2 * mh + 1, 2 * mz + 1
        except (ValueError, ArithmeticError):   # refused later, by _check_kernel
            reach_h = _REACH[k["shape"]] * k["size"]
            sx = 2 * math.ceil(reach_h / h) + 1
            sz = 2 * math.ceil(reach_h / k["aspect"] / h) + 1
    stencil = sz * sx ** (dims - 1)
    padded = (nz + sz) * (nx + sx) ** (dims - 1)
    n_fields = 1 + 1 + (5 if dims == 2 else 9)     # rho_s, v_kin, u_*, D_**
    scratch = 12                                    # spot-density and coefficient work arrays
    tracer = data.get("tracer")
    n_tracer = 0
    if tracer is not None:
        # frames (one in flight when streamed), P_height, scheme fluxes and stages
        n_tracer = (tracer["frames"] if frames_in_memory and frames else 1) + 1 + 16
        if tracer["t_end"] == math.inf:
            # steady solve: no frames; the sparse matrix and its LU factors (fill
            # measured: ~50 entries of 12 bytes per cell on a 2D grid of 9e4 cells; 3D
            # fill grows like cells**(1/3))
            n_tracer = 4 + (80 if dims == 2 else 10 * cells ** (1 / 3))
        if data["spots"]["mode"] == "transient":
            # spot-density snapshots (one more in flight), the fields of three of them,
            # and the tracer's cache of operators (face velocities, diffusion splitting,
            # the interpolated fields) for a few stage times
            n = tracer["snapshots"]
            n_tracer += ((auto_snapshots(data) if n == "auto" else n) + 1 + 3 * n_fields
                         + 5 * (n_fields + 2 * dims + 4))
    if data["spots"].get("rho_max") is not None:
        # interacting spots: space-time frames of rho_s and free_volume, solver stages
        n_tracer += 2 * (data["spots"].get("frames") or 101) + 8
    total = 8.0 * cells * (n_fields + scratch + n_tracer)
    total += 16.0 * padded * 6 + 8.0 * stencil * 2
    return int(min(total, 1e30))


# -- validation internals --------------------------------------------------------------

def _show(value: Any) -> str:
    """A value as the user would write it in TOML."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float, str)):
        return _toml_value(value)
    if isinstance(value, Mapping):
        return "a table"
    if isinstance(value, (list, tuple)):
        if len(value) <= 4:
            return "[" + ", ".join(_show(x) for x in value) + "]"
        return f"a list of {len(value)} values"
    return type(value).__name__


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


class _Validator:
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

    def number(self, key, value, *, gt=None, ge=None, le=None, integer=False,
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
        if conds:
            self.bad(key, "must be " + " and ".join(conds), value)
            return None
        if limit is not None and abs(value) > limit:
            self.bad(key, f"must be at most {_show(limit)} in magnitude", value)
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
            if name in ("tracer", "pair") and name not in raw:
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
            "z": self.pair("domain.z", t["z"]),
            "spacing": self.number("domain.spacing", t["spacing"], gt=0),
            "walls": self.choice("domain.walls", t["walls"], WALLS),
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

    def _kernel(self, t):
        out = {
            "shape": self.choice("kernel.shape", t["shape"], KERNEL_SHAPES),
            "size": self.number("kernel.size", t["size"], gt=0),
            "volume": self.number("kernel.volume", t["volume"], gt=0),
            "aspect": self.number("kernel.aspect", t["aspect"], gt=0, le=1000),
            "rule": self.number("kernel.rule", t["rule"], gt=0, le=1),
            "walls": self.choice("kernel.walls", t["walls"], KERNEL_WALLS),
            "diffusivity": self.choice("kernel.diffusivity", t["diffusivity"], DIFFUSIVITIES),
        }
        if t["height"] is not None:
            out["height"] = self.number("kernel.height", t["height"], gt=0, le=1)
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
        }
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

    # -- cross-key consistency -----------------------------------------------------
    def cross(self, data):
        d, o, s, k = data["domain"], data["orifice"], data["spots"], data["kernel"]
        dims, h = d["dims"], d["spacing"]
        x0, x1 = d["x"]
        z0, z1 = d["z"]
        if z0 != 0.0:
            self.bad("domain.z", "must start at 0 (the orifice is the floor z = 0)", d["z"])
        for name, (a, b) in (("x", d["x"]), ("z", d["z"])):
            n = (b - a) / h
            if not math.isfinite(n) or n > 1e9:
                self.bad("domain.spacing", f"is far too small for the domain.{name} extent "
                         f"{_show(b - a)} ({n:.3g} cells)", h)
            elif round(n) < 4:
                self.bad("domain.spacing", f"must give at least 4 cells across the "
                         f"domain.{name} extent {_show(b - a)}", h)
            elif abs(n - round(n)) > 1e-6 * max(1.0, n):
                self.bad("domain.spacing", f"must divide the domain.{name} extent "
                         f"{_show(b - a)} into whole cells", h)
        # orifice on the floor
        half = 0.5 * o["width"] if o["profile"] == "uniform" else 0.0
        if not (x0 <= o["x"] - half and o["x"] + half <= x1):
            what = "the slot [x - width/2, x + width/2]" if half else "the centre"
            self.bad("orifice.x", f"{what} must lie on the floor "
                     f"domain.x = [{_show(x0)}, {_show(x1)}] (orifice.width = "
                     f"{_show(o['width'])})", o["x"])
        if "y" in o:
            if dims != 3:
                self.bad("orifice.y", "is only used when domain.dims = 3; remove it",
                         o["y"])
            elif not (x0 <= o["y"] - half and o["y"] + half <= x1):
                self.bad("orifice.y", f"the orifice must lie on the floor, y in "
                         f"[{_show(x0)}, {_show(x1)}] (y uses the domain.x extent)", o["y"])
        if o["profile"] == "gaussian" and o["width"] == 0.0:
            self.bad("orifice.width", 'must be > 0 for profile = "gaussian" '
                     '(use profile = "uniform" with width = 0 for a point source)', 0.0)
        if 0.0 < o["width"] < h and o["profile"] == "uniform":
            self.bad("orifice.width", f"must be 0 (a point source) or at least one cell "
                     f"(domain.spacing = {_show(h)})", o["width"])
        # spots
        if isinstance(o["rate"], dict) and s["mode"] != "transient":
            self.bad("orifice.rate", 'a table of rates needs spots.mode = "transient"; '
                     "give a number for a steady run", o["rate"])
        if s["mode"] == "transient" and s["t_end"] <= 0:
            self.bad("spots.t_end", 'must be > 0 when spots.mode = "transient"', s["t_end"])
        if "rho_max" in s and s["mode"] != "transient":
            self.bad("spots.rho_max", 'interacting spots need spots.mode = "transient" '
                     "(no steady solver; run to a late spots.t_end)", s["rho_max"])
        for key in ("flux", "diffusion_scaling", "frames"):
            if key in s and "rho_max" not in s:
                self.bad(f"spots.{key}", "is only used with spots.rho_max (interacting "
                         "spots); set spots.rho_max or remove it", s[key])
        if o.get("noise") is not None and s["mode"] != "transient":
            self.bad("orifice.noise", 'a random rate needs spots.mode = "transient"; '
                     "remove it for a steady run", o["noise"])
        if s["mode"] == "steady" and s["t_end"] != 0:
            self.bad("spots.t_end", 'is only used when spots.mode = "transient"; '
                     'set it to 0 or remove it', s["t_end"])
        # kernel
        if k["shape"] == "uniform" and "volume" in k:
            w = k["volume"] / _ellipsoid_measure(k["size"], k["aspect"], dims)
            if w > 1.001:   # w = 1 (the void model's spot), volume rounded to 4 digits, is fine
                self.bad("kernel.volume", f'with shape = "uniform" and kernel.size = '
                         f'{_show(k["size"])} implies the influence w = volume / spot '
                         f"{'area' if dims == 2 else 'volume'} = {w:.3g} > 1 (a spot moves "
                         "each particle by at most its own step); use a smaller volume or "
                         "a larger size", k["volume"])
        if "height" in k:
            if k["shape"] != "uniform":
                self.bad("kernel.height", 'is only for shape = "uniform" (the influence w '
                         'inside the disk/sphere); give kernel.volume instead', k["height"])
        # tracer
        t = data.get("tracer")
        if t is not None and t.get("t_end") == math.inf and s["mode"] == "transient":
            self.bad("tracer.t_end", 'inf (the steady propagator) needs spots.mode = '
                     '"steady"; give a finite time for a tracer in a starting flow', math.inf)
        if t is not None and t.get("snapshots", "auto") != "auto" and s["mode"] != "transient":
            self.bad("tracer.snapshots", 'is only used when spots.mode = "transient"; '
                     'remove it or set it to "auto"', t["snapshots"])
        if t is not None and "start" in t:
            st = t["start"]
            if not x0 <= st["x"] <= x1:
                self.bad("tracer.start.x", f"must lie in domain.x = [{_show(x0)}, "
                         f"{_show(x1)}]", st["x"])
            if not z0 < st["z"] < z1:
                self.bad("tracer.start.z", f"must lie inside domain.z = ({_show(z0)}, "
                         f"{_show(z1)})", st["z"])
            if "y" in st:
                if dims != 3:
                    self.bad("tracer.start.y", "is only used when domain.dims = 3; remove it",
                             st["y"])
                elif not x0 <= st["y"] <= x1:
                    self.bad("tracer.start.y", f"must lie in [{_show(x0)}, {_show(x1)}] "
                             "(y uses the domain.x extent)", st["y"])
            if st["width"] < h:
                self.bad("tracer.start.width", f"must be at least domain.spacing = "
                         f"{_show(h)} so the blob is resolved", st["width"])
        if t is not None and "layers" in t:
            sp = t["layers"]["spacing"]
            if sp < 2 * h:
                self.bad("tracer.layers.spacing", f"must be at least 2 * domain.spacing = "
                         f"{_show(2 * h)} so every band covers a cell", sp)
            elif sp >= 2 * (z1 - z0):
                self.bad("tracer.layers.spacing", f"must be < 2 * the domain height "
                         f"{_show(z1 - z0)} to leave a band and a gap in the silo", sp)

        p = data.get("pair")
        if p is not None:
            if dims != 2:
                self.bad("pair", "needs domain.dims = 2 (the pair solver is 2D)", dims)
            if p.get("x") is not None and not x0 <= p["x"] <= x1:
                self.bad("pair.x", f"must lie in domain.x = [{_show(x0)}, {_show(x1)}]",
                         p["x"])
            if p.get("z") is not None and not z0 < p["z"] < z1:
                self.bad("pair.z", f"must lie inside domain.z = ({_show(z0)}, {_show(z1)})",
                         p["z"])

    def memory(self, data, frames_in_memory=True):
        need = estimate_bytes(data, frames_in_memory) + BASELINE_BYTES
        have = available_memory()
        if need > MEMORY_FRACTION * have:
            d = data["domain"]
            nx = (d["x"][1] - d["x"][0]) / d["spacing"]
            nz = (d["z"][1] - d["z"][0]) / d["spacing"]
            cells = " x ".join(f"{n:,.0f}" for n in ([nz] + [nx] * (d["dims"] - 1)))
            snaps = data.get("tracer") is not None and data["spots"]["mode"] == "transient"
            limit = MEMORY_FRACTION * have - BASELINE_BYTES
            key, value, advice = "domain.spacing", d["spacing"], (
                "use a larger spacing, a smaller domain or fewer tracer.frames"
                + (" or tracer.snapshots" if snaps else ""))
            if _estimate(data, frames_in_memory, pad=False, stencil=False,
                         frames=False) <= limit:
                # the grid itself fits: blame what is added to it
                k = data["kernel"]
                if d["walls"] == "open" and _estimate(data, frames_in_memory, stencil=False,
                                                      frames=False) > limit:
                    key, value, advice = "spots.b", data["spots"]["b"], (
                        'with domain.walls = "open" the spot density is solved on a grid '
                        "widened by 6 sqrt(b H) on each side; use a smaller b or reflecting "
                        "walls")
                elif _estimate(data, frames_in_memory, frames=False, pad=False) > limit:
                    mz, mh = kernel_halfwidths(data)
                    if k["aspect"] < 1 and mz > mh:
                        key, value = "kernel.aspect", k["aspect"]
                    else:
                        key, value = "kernel.size", k["size"]
                    advice = (f"the kernel stencil of {2 * mz + 1} x {2 * mh + 1} cells "
                              "widens every FFT array; use a smaller kernel.size, an aspect "
                              "nearer 1 or a larger domain.spacing")
                elif data.get("tracer") is not None and frames_in_memory:
                    key, value = "tracer.frames", data["tracer"]["frames"]
                    advice = ("use fewer frames, or stream them to the result file "
                              "(spotpde run, or spotpde.run(case, path=...))")
            self.bad(key, f"the grid of {cells} cells (with kernel stencil and "
                     f"tracer frames) needs about {_gb(need)}, more than the "
                     f"{_gb(MEMORY_FRACTION * have)} this machine can spare; {advice}", value)


def _gb(n: float) -> str:
    return f"{n / 1024**3:.3g} GB" if n < 1e25 else "an impossible amount of memory"


def _ellipsoid_measure(radius: float, aspect: float, dims: int) -> float:
    """Area of the ellipse (2D) or volume of the spheroid (3D) with horizontal radius
    ``radius`` and vertical radius ``radius / aspect``, in d**dims."""
    if dims == 2:
        return math.pi * radius * radius / aspect
    return 4.0 / 3.0 * math.pi * radius**3 / aspect


def _check_kernel(case: Case) -> None:
    """Build the kernel and the orifice profile once, so that the solvers' own checks
    run at load time (cheap: the kernel's parameters and one floor-sized array)."""
    from ..density import orifice

    try:
        case.kernel
    except CaseError:
        raise
    except (ValueError, ArithmeticError, TypeError) as exc:
        lines = str(exc).splitlines() or [type(exc).__name__]
        raise CaseError([f"kernel: {line}" for line in lines]) from None
    orifice.source_profile(case.grid, case.orifice)


def _warn_wide_kernel(data: Mapping) -> None:
    """Warn when the kernel's size (R, sigma or decay length) spans more than the domain:
    every spot then moves the whole silo, and the fields are mostly the walls' images."""
    import warnings

    d, k = data["domain"], data["kernel"]
    width, height = d["x"][1] - d["x"][0], d["z"][1] - d["z"][0]
    size_h, size_v = k["size"], k["size"] / k["aspect"]
    if 2 * size_h > width or 2 * size_v > height:
        warnings.warn(f"kernel.size: the kernel ({_show(2 * size_h)} d wide, "
                      f"{_show(2 * size_v)} d tall) is wider than the domain "
                      f"({_show(width)} x {_show(height)} d); the fields will mostly show "
                      "the walls", UserWarning, stacklevel=3)


def _field(value, grid: Grid):
    """A constant, or a grid-shaped array from a piecewise-linear profile in x or z."""
    if not isinstance(value, Mapping):
        return value
    axis = "x" if "x" in value else "z"
    line = np.interp(grid.coords()[axis], value[axis], value["values"])
    shape = [1] * len(grid.shape)
    index = grid.axes.index(axis)
    shape[index] = line.size
    return np.ascontiguousarray(np.broadcast_to(line.reshape(shape), grid.shape), dtype=float)


def _tracer(t: Mapping | None, grid: Grid, orifice: Orifice) -> Tracer | None:
    if t is None:
        return None
    if "layers" in t:
        start = TracerStart(kind="layers", spacing=t["layers"]["spacing"])
    else:
        st = t["start"]
        y = st.get("y")
        if grid.dims == 3 and y is None:
            y = orifice.y if orifice.y is not None else grid.y_centre
        start = TracerStart(kind="blob", x=st["x"], z=st["z"], width=st["width"], y=y)
    return Tracer(model=t["model"], start=start, t_end=t["t_end"], frames=t["frames"])


# -- a tiny TOML writer for case mappings ------------------------------------------

def dump_toml(data: Mapping) -> str:
    """Write a case mapping as TOML (with ``tomli_w``; ``None`` values are left out).

    Args:
        data: ``{table: {key: value}}`` with bool, int, float, str, lists of those and
            one level of nested mappings (written as inline tables).

    Returns:
        TOML text that :func:`tomllib.loads` reads back to an equal mapping.
    """
    import tomli_w

    def drop_none(node):
        if isinstance(node, Mapping):
            return {k: drop_none(v) for k, v in node.items() if v is not None}
        if isinstance(node, (list, tuple)):
            return [drop_none(v) for v in node]
        return node

    return tomli_w.dumps(drop_none(_plain(data)))


def _toml_key(key: str) -> str:
    if key and all(c.isascii() and (c.isalnum() or c in "_-") for c in key):
        return key
    return _toml_string(key)


def _toml_string(s: str) -> str:
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


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return _toml_string(v)
    if isinstance(v, Mapping):
        inner = ", ".join(f"{_toml_key(k)} = {_toml_value(x)}" for k, x in v.items()
                          if x is not None)
        return "{ " + inner + " }" if inner else "{}"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {type(v).__name__} as TOML")
