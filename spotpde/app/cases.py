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

This module is the public face; the work is done beside it: ``_schema`` (the tables,
:data:`DEFAULTS` and the per-key checks), ``_consistency`` (checks between keys) and
``_resources`` (available memory, the memory estimate, tracer snapshots). Their public
names are re-exported here.
"""

from __future__ import annotations

import os
import tomllib
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import tomli_w

from ..errors import CaseError
from ..grid import Grid, Hopper
from ..parameters import (ComparisonSettings, Orifice, PairParams, Spots, Tracer,
                          TracerStart)
from ._consistency import check_consistency
from ._nesting import MAX_NESTING, text_problem
from ._resources import (BASELINE_BYTES, MEMORY_FRACTION, auto_snapshots, available_memory,
                         estimate_bytes, kernel_halfwidths, memory_problem)
from ._schema import (DEFAULTS, DIFFUSION_MODES, DIFFUSION_SCALINGS, DIFFUSIVITIES,
                      FLUX_SHAPES, KERNEL_SHAPES, KERNEL_WALLS, LAYERS_KEYS, LIMITERS,
                      MAX_FRAMES, MAX_LENGTH, NOISE_KEYS, PAIR_START_KEYS, PROFILE_KEYS,
                      STEPPING_MODES,
                      RATE_TABLE_KEYS, START_KEYS, _ellipsoid_measure, _plain, _show,
                      kernel_dims,
                      _Validator)

__all__ = [
    "Case", "load_case", "validate", "dump_toml", "CaseError",
    "available_memory", "auto_snapshots", "estimate_bytes", "kernel_halfwidths",
    "DEFAULTS", "KERNEL_SHAPES", "KERNEL_WALLS", "LIMITERS", "DIFFUSION_MODES",
    "DIFFUSIVITIES", "STEPPING_MODES", "FLUX_SHAPES", "DIFFUSION_SCALINGS", "RATE_TABLE_KEYS",
    "PROFILE_KEYS", "NOISE_KEYS", "START_KEYS", "LAYERS_KEYS", "PAIR_START_KEYS",
    "MAX_LENGTH", "MAX_FRAMES", "MAX_NESTING", "MEMORY_FRACTION", "BASELINE_BYTES",
]


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
        pair: :class:`spotpde.parameters.PairParams`, or ``None`` without a ``[pair]`` table.
        comparison: :class:`spotpde.parameters.ComparisonSettings` (where the rate and
            the spot profiles come from).
        rule: lam, where along a spot step its influence is evaluated (1 for the void model).
        tracer_options: keyword options of ``spotpde.tracer.solve`` (``limiter``, ``cfl``,
            ``diffusion``, ``stepping``, ``tol``, ``split``), empty without a tracer.
        output_path: ``output.path`` resolved against the current directory.
        montecarlo: the ``[montecarlo]`` run settings
            (:class:`spotpde.montecarlo.MonteCarloSettings`).
    """

    def __init__(self, data: dict, text: str | None = None, source: str | None = None):
        self.data = data
        self.source = source
        self.text = text if text is not None else self.to_toml()
        d, o, s, k = data["domain"], data["orifice"], data["spots"], data["kernel"]
        hopper = None
        if d.get("hopper_angle") is not None:
            half = 0.5 * o["width"] if o["profile"] == "uniform" else 0.0
            hopper = Hopper(angle=d["hopper_angle"], centre=o["x"], half_width=half)
        self.grid = Grid(dims=d["dims"], x_range=tuple(d["x"]), z_range=tuple(d["z"]),
                         spacing=d["spacing"], walls=d["walls"],
                         coordinates=d.get("coordinates", "cartesian"), hopper=hopper,
                         y_range=tuple(d["y"]) if "y" in d else None)
        rate = o["rate"]
        if isinstance(rate, dict):
            from ..density.orifice import rate_from_table

            rate = rate_from_table(rate["times"], rate["values"])
        if o.get("noise") is not None:
            from ..density.noise import noisy_rate

            rate = noisy_rate(rate, **o["noise"])
        self.orifice = Orifice(x=o["x"], width=o["width"], profile=o["profile"],
                               rate=rate, y=o.get("y"), shape=o.get("shape", "disk"))
        self.spots = Spots(drift=_field(s["drift"], self.grid), b=_field(s["b"], self.grid),
                           b_par=_field(s["b_par"], self.grid), mode=s["mode"],
                           t_end=s["t_end"], rho_max=s.get("rho_max"),
                           flux=s.get("flux") or "greenshields",
                           diffusion_scaling=s.get("diffusion_scaling") or "fixed",
                           frames=s.get("frames") or 101)
        p = data.get("pair")
        start = None if p is None else p.get("start")
        self.pair = None if p is None else PairParams(
            x=p["x"], z=p["z"], contact=p["contact"], separation=p["separation"],
            start=(start["x"], start["z"]) if isinstance(start, Mapping) else start,
            spacing=p.get("spacing"), frames=p["frames"])
        self.comparison = ComparisonSettings(
            rate=("noise" if o.get("noise") is not None
                  else "table" if isinstance(o["rate"], Mapping) else "constant"),
            profiles=tuple(key for key in ("b", "drift") if isinstance(s[key], Mapping)))
        self.tracer = _tracer(data.get("tracer"), self.grid, self.orifice)
        t = data.get("tracer")
        self.tracer_options = ({} if t is None else
                               {k: t[k] for k in ("limiter", "cfl", "diffusion", "stepping",
                                                  "tol", "split") if k in t})
        volume = (k["height"] * _ellipsoid_measure(k["size"], k["aspect"], kernel_dims(d))
                  if "height" in k else k["volume"])
        self.kernel_spec = {"shape": k["shape"], "size": k["size"], "volume": volume,
                            "aspect": k["aspect"],
                            # an axisymmetric silo is 3D: its spots have a 3D kernel
                            "dims": self.grid.geometry.kernel_dims}
        self._kernel = None

    # -- derived --------------------------------------------------------------------
    @property
    def model(self) -> str:
        """``"spot"`` or ``"void"`` (``tracer.model``; ``"spot"`` without a tracer)."""
        return self.tracer.model if self.tracer is not None else "spot"

    @property
    def rule(self) -> float:
        """lam: ``kernel.rule``, or 1 for the void model; ``kernel.rule = "kinematic"`` is
        ``1/2 + V2 / (2 V1)``, the rule whose mean flow is exactly kinematic."""
        if self.model == "void":
            return 1.0
        rule = self.data["kernel"]["rule"]
        if rule == "kinematic":
            return 0.5 + 0.5 * float(self.kernel.V2) / float(self.kernel.V1)
        return float(rule)

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
    def montecarlo(self):
        """The ``[montecarlo]`` table as :class:`spotpde.montecarlo.MonteCarloSettings`
        (read once; every field ``None`` without the table), the run settings of
        ``spotpde.montecarlo.from_case``."""
        if getattr(self, "_montecarlo", None) is None:
            from ..montecarlo import MonteCarloSettings

            self._montecarlo = MonteCarloSettings.from_table(self.data.get("montecarlo"))
        return self._montecarlo

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

def check_arguments(case, **paths) -> None:
    """TypeError naming the argument: ``case`` must be a Case, a case file name, TOML text
    or a mapping; each of ``paths`` a file name (str or os.PathLike) or None. The check
    that ``spotpde.run`` and ``sweep_case`` make before anything is read or written."""
    if not isinstance(case, (Case, str, os.PathLike, Mapping)):
        raise TypeError("case: must be a Case, a case file name, TOML text or a mapping, "
                        f"got {type(case).__name__}")
    for name, path in paths.items():
        if path is not None and not isinstance(path, (str, os.PathLike)):
            raise TypeError(f"{name}: must be a file name (str or os.PathLike) or None, got "
                            f"{type(path).__name__}")


def load_case(source: str | os.PathLike | Mapping, *, frames_in_memory: bool = True) -> Case:
    """Read and validate a case.

    Args:
        source: path of a TOML case file; TOML text (a string holding a line break,
            which no file name does); or a mapping with the same tables and keys.
        frames_in_memory: count the tracer frames in the memory check. ``False`` for a
            run that streams them to its result file (``spotpde.run(case, path=...)``,
            what ``spotpde run`` does).

    Returns:
        The validated :class:`Case` (``source`` is ``None`` unless read from a file).

    Raises:
        TypeError: ``source`` is none of these.
        spotpde.CaseError: one line per problem (unreadable file, malformed TOML,
            tables or lists nested more than ``MAX_NESTING`` deep, unknown or
            mistyped key, value out of range, inconsistent keys, a grid too large for
            memory).
    """
    text = None
    path = None
    if isinstance(source, Mapping):
        raw = source
    elif isinstance(source, str) and "\n" in source:     # TOML text, not a file name
        text = source.removeprefix("\ufeff")
        raw = _parse_toml(text, "case text")
    elif isinstance(source, (str, os.PathLike)):
        path = os.fspath(source)
        try:
            with open(path, "rb") as fh:
                blob = fh.read()
        except OSError as exc:
            hint = ("; TOML text (not a file name) must hold a line break"
                    if isinstance(path, str) and "=" in path else "")
            raise CaseError(f"{path}: cannot read the case file "
                            f"({exc.strerror or exc}){hint}") from None
        try:
            text = blob.decode("utf-8-sig")   # a byte-order mark (some editors) is fine
        except UnicodeDecodeError:
            raise CaseError(f"{path}: malformed TOML: not UTF-8 text") from None
        raw = _parse_toml(text, path)
    else:
        raise TypeError("source: must be a path to a TOML file, TOML text or a mapping, "
                        f"got {type(source).__name__}")
    data = validate(raw, frames_in_memory=frames_in_memory)
    case = Case(data, text, path)
    _check_kernel(case)
    _warn_wide_kernel(data)
    return case


def _parse_toml(text: str, where: str) -> dict:
    """``tomllib.loads(text)``, nesting checked first (:mod:`._nesting`); problems as a
    :class:`CaseError` starting with ``where`` (the file, or ``"case text"``)."""
    problem = text_problem(text)
    if problem is not None:
        raise CaseError(f"{where}: malformed TOML: {problem}")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CaseError(f"{where}: malformed TOML: {exc}") from None
    except RecursionError:        # the scan above leaves tomllib no reason to recurse
        raise CaseError(f"{where}: malformed TOML: nested too deeply to read (at most "
                        f"{MAX_NESTING} nested tables and lists in a case)") from None


def validate(raw: Mapping, *, frames_in_memory: bool = True) -> dict:
    """Validate a raw case mapping.

    Three passes, each run only if the one before found nothing: the per-key checks of
    every table (``_schema``), the checks between keys (``_consistency``), and the
    memory check (``_resources.memory_problem`` against :func:`available_memory` of
    this module).

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
        check_consistency(v, data)
    if not v.problems:
        problem = memory_problem(data, frames_in_memory, available_memory())
        if problem is not None:
            v.bad(*problem)
    if v.problems:
        raise CaseError(v.problems)
    return data


# -- helpers of Case and load_case -------------------------------------------------

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
    try:
        orifice.source_profile(case.grid, case.orifice)
    except ValueError as exc:      # the library names its argument: orifice.x, ...
        raise CaseError(str(exc).splitlines()) from None


def _warn_wide_kernel(data: Mapping) -> None:
    """Warn when the kernel's size (R, sigma or decay length) spans more than the domain:
    every spot then moves the whole silo, and the fields are mostly the walls' images."""
    d, k = data["domain"], data["kernel"]
    width, height = d["x"][1] - d["x"][0], d["z"][1] - d["z"][0]
    depth = d["y"][1] - d["y"][0] if "y" in d and d["dims"] == 3 else width
    size_h, size_v = k["size"], k["size"] / k["aspect"]
    if 2 * size_h > min(width, depth) or 2 * size_v > height:
        box = f"{_show(width)} x {_show(depth)} x {_show(height)}" if depth != width else \
            f"{_show(width)} x {_show(height)}"
        warnings.warn(f"kernel.size: the kernel ({_show(2 * size_h)} d wide, "
                      f"{_show(2 * size_v)} d tall) is wider than the domain "
                      f"({box} d); the fields will mostly show "
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
    """The :class:`Tracer` of a validated ``[tracer]`` table (a 3D blob without ``y``
    starts above the orifice, or mid-domain), or ``None`` without one."""
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


# -- TOML out ----------------------------------------------------------------------

def dump_toml(data: Mapping) -> str:
    """Write a case mapping as TOML (with ``tomli_w``; ``None`` values are left out).

    Args:
        data: ``{table: {key: value}}`` with bool, int, float, str, lists of those and
            one level of nested mappings (written as inline tables).

    Returns:
        TOML text that :func:`tomllib.loads` reads back to an equal mapping.
    """
    def drop_none(node):
        if isinstance(node, Mapping):
            return {k: drop_none(v) for k, v in node.items() if v is not None}
        if isinstance(node, (list, tuple)):
            return [drop_none(v) for v in node]
        return node

    return tomli_w.dumps(drop_none(_plain(data)))
