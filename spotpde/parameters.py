"""Typed physical parameters of a case: the orifice, the spots, the tracer.

These are what :mod:`spotpde.cases` produces from a TOML case and what the solvers
consume; they hold no numerics. Coefficients that may vary in space accept either a
float or an array of the grid's shape (array order ``(z, x)`` / ``(z, y, x)``).
Units: lengths in particle diameters d, times in the case's time unit (one unit of
``t`` is the time in which a spot rises ``v_s`` diameters).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Union

import numpy as np

Coefficient = Union[float, np.ndarray]

PROFILES = ("uniform", "gaussian")
#: Shapes of a 3D orifice: a disk (or radially Gaussian spot), or a slot across the
#: whole depth y (the profile in x as in 2D, uniform in y: a thin slab's orifice).
ORIFICE_SHAPES = ("disk", "slot")
SPOT_MODES = ("steady", "transient")
TRACER_MODELS = ("spot", "void")
#: ``(lo, hi)``: a rule lam (``kernel.rule``, ``spotpde compare --rules``) lies in
#: ``(lo, hi]``, from just after the start of a spot step to its end point.
RULE_RANGE = (0, 1)
#: Particle diffusivities: ``"passage"`` (the steps of one spot passing a particle, the
#: discrete model's own) or ``"mean-field"`` (``D_p = w^2 rho_s D_s``, the paper's eq. Dp).
#: The one table (``kernel.diffusivity``, the ``diffusivity`` arguments of fields, pair).
DIFFUSIVITIES = ("passage", "mean-field")
#: ``[lo, hi]``: a rule lam the library functions accept (``rule`` arguments); a case's
#: ``kernel.rule`` lies in :data:`RULE_RANGE`, which leaves out the step's start.
RULE_LIMITS = (0.0, 1.0)
#: ``(lo, hi)``: a uniform kernel's influence w (``kernel.height``,
#: ``spotpde.kernels.Uniform(height=)``) lies in ``[lo, hi]``: a spot moves a particle by
#: at most its own step, and by enough that ``w**2`` (the diffusivity's factor) stays a
#: normal floating-point number.
HEIGHT_RANGE = (1e-12, 1.0)
#: A uniform kernel given by its volume (``kernel.volume``) may imply ``w`` up to
#: ``HEIGHT_RANGE[1] * (1 + VOLUME_ROUNDING)`` (a volume written to four digits), taken as
#: ``w = 1``.
VOLUME_ROUNDING = 1e-3


def check_diffusivity(diffusivity, name: str = "diffusivity") -> str:
    """``diffusivity`` if it is one of :data:`DIFFUSIVITIES`, else ValueError naming
    ``name`` (the caller's argument)."""
    if diffusivity not in DIFFUSIVITIES:
        raise ValueError(f"{name}: must be one of {list(DIFFUSIVITIES)}, got {diffusivity!r}")
    return diffusivity


def check_rule(rule, name: str = "rule") -> float:
    """The rule lam as a float in :data:`RULE_LIMITS` (0.5 midpoint, 1 end point of a
    spot's step), else ValueError naming ``name``."""
    try:
        lam = float(rule)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: must be a number (0.5 midpoint, 1 end point), got {rule!r}")
    if not np.isfinite(lam) or not RULE_LIMITS[0] <= lam <= RULE_LIMITS[1]:
        raise ValueError(f"{name}: must lie in [0, 1] (0.5 midpoint, 1 end point), got {rule!r}")
    return lam


def drift_weight(lam: float) -> float:
    """``2 lam``: the weight of the rule's term in the particle drift,
    ``u_p = -w * (rho_s u_s - 2 lam div(D_s rho_s))`` (dimensionless)."""
    return 2.0 * lam


def wall_weight(lam: float) -> float:
    """``1 - 2 lam``: what the rule leaves of a spot's step next to a wall (the wall
    layer's and the metric's weight; 0 at the midpoint rule), dimensionless."""
    return 1.0 - drift_weight(lam)


@dataclass(frozen=True)
class Orifice:
    """Spot source on the floor ``z = z0``.

    Args:
        x: centre in d.
        width: 0 for a point source; slot width W (``uniform``) or two standard
            deviations (``gaussian``). In 3D the orifice is a disk of diameter
            ``width`` (or a radially Gaussian source) centred at ``(x, y)``, or with
            ``shape = "slot"`` a slot of that width across the whole depth in y.
        profile: ``"uniform"`` or ``"gaussian"``.
        rate: Q0 in spots per unit time; a constant, or for transient runs a
            callable ``Q0(t)``.
        y: 3D only: centre in y (default: the middle of the y extent; unused by a slot).
        shape: 3D only: ``"disk"`` or ``"slot"`` (:data:`ORIFICE_SHAPES`).
    """

    x: float = 0.0
    width: float = 0.0
    profile: str = "uniform"
    rate: Union[float, Callable[[float], float]] = 1.0
    y: float | None = None
    shape: str = "disk"

    def rate_at(self, t: float) -> float:
        """Q0(t) in spots per unit time."""
        return float(self.rate(t)) if callable(self.rate) else float(self.rate)


@dataclass(frozen=True)
class Spots:
    """Spot dynamics: drift ``v_s`` (up), diffusion lengths ``b`` and ``b_par``.

    ``D_perp = b * v_s`` (per horizontal component) and ``D_par = b_par * v_s``,
    in d**2 per unit time. Each may be a float or a grid-shaped array.
    """

    drift: Coefficient = 1.0
    b: Coefficient = 1.3
    b_par: Coefficient = 0.0
    mode: str = "steady"
    t_end: float = 0.0
    #: interacting spots (spotpde.traffic): maximum density, None = independent spots
    rho_max: float | None = None
    flux: str = "greenshields"
    diffusion_scaling: str = "fixed"
    #: interacting spots: frames saved on ``[0, t_end]`` (``spots.frames``)
    frames: int = 101

    @property
    def D_perp(self) -> Coefficient:
        """Horizontal spot diffusivity ``b v_s`` (per component) in d**2 per unit time."""
        return self.b * self.drift

    @property
    def D_par(self) -> Coefficient:
        """Vertical spot diffusivity ``b_par v_s`` in d**2 per unit time."""
        return self.b_par * self.drift

    @property
    def is_uniform(self) -> bool:
        """True when drift, b and b_par are all constants."""
        return not _is_array(self.drift, self.b, self.b_par)


@dataclass(frozen=True)
class TracerStart:
    """Initial tracer density: a Gaussian blob or horizontal layers.

    Args:
        kind: ``"blob"`` or ``"layers"``.
        x, z, width: blob centre and standard deviation in d (3D: y at the orifice's y).
        spacing: layers: bands ``[k*spacing, k*spacing + spacing/2)`` in z carry P.
    """

    kind: str = "blob"
    x: float = 0.0
    z: float = 0.0
    width: float = 1.0
    spacing: float = 10.0
    y: float | None = None


def in_bands(height, spacing: float) -> np.ndarray:
    """True for heights in the coloured bands ``[k s, k s + s/2)`` of a layered start.

    Args:
        height: height(s) above the floor in d.
        spacing: layer period ``s`` in d (a band and a gap).

    Returns:
        Boolean array of ``height``'s shape.
    """
    return np.mod(np.asarray(height, float), spacing) < 0.5 * spacing


@dataclass(frozen=True)
class Tracer:
    """Tracer propagator run: model, initial density, duration, number of frames."""

    model: str = "spot"
    start: TracerStart = field(default_factory=TracerStart)
    t_end: float = 100.0
    frames: int = 20


def _is_array(*values) -> bool:
    return any(np.ndim(v) > 0 for v in values)


@dataclass(frozen=True)
class PairParams:
    """Cage breaking of a pair at a point of the flow (``[pair]``, :mod:`spotpde.pair`).

    Args:
        x, z: the point of the flow where the pair falls, in d.
        contact: the hard-core distance in d.
        separation: the cage's radius in d (> ``contact``).
        start: the initial separation ``(x, z)`` in d, ``"contact"`` (uniform over the
            contact directions) or ``None`` (the solver's default).
        spacing: the solver's cell size in d (``None``: ``contact / 16``).
        frames: frames of the separation's density.
    """

    x: float
    z: float
    contact: float = 1.0
    separation: float = 2.0
    start: tuple[float, float] | str | None = None
    spacing: float | None = None
    frames: int = 8


@dataclass(frozen=True)
class ComparisonSettings:
    """What a case says about its flow beyond the typed orifice and spots that the
    comparison with the Kinematic Model must know (:func:`spotpde.comparison.case_problems`
    names these keys when it refuses).

    Args:
        rate: where ``Q0`` comes from: ``"constant"``, ``"table"`` (``orifice.rate`` a
            table of times and values) or ``"noise"`` (``orifice.noise``).
        profiles: the spot keys given as profiles instead of numbers (``"b"``, ``"drift"``).
    """

    rate: str = "constant"
    profiles: tuple[str, ...] = ()
