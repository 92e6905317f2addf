"""The ``[montecarlo]`` case table as a typed object (:class:`MonteCarloSettings`) and
its merge with the Python keywords of :func:`~spotpde.montecarlo.from_case`.

The table is checked with the rest of the case (``spotpde.app._schema_mc``); here it is
read once into :class:`MonteCarloSettings` (``Case.montecarlo``). Keys left out of the
table keep the Python defaults, Python keywords override the table (docs/cases.md).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, fields
from typing import Mapping

from ._relax import Relax

__all__ = ["MonteCarloSettings", "UNSET", "case_settings", "with_settings"]


class _Unset:
    """Marks a keyword of ``from_case`` that the caller did not give."""

    def __repr__(self) -> str:
        return "UNSET"


UNSET = _Unset()


@dataclass(frozen=True)
class MonteCarloSettings:
    """Run settings of the discrete spot model from a case's ``[montecarlo]`` table.

    Every field is ``None`` when the table leaves it out (the Python default applies).
    The names are the keywords of :func:`~spotpde.montecarlo.from_case` and
    :func:`~spotpde.montecarlo.simulate`.

    Attributes:
        particles: ``"lattice"``, ``"random"``, ``"tracer"`` or ``"none"`` (no particles).
        spacing: lattice spacing in d.
        seed: random seed (an integer >= 0).
        t_end: duration in the case's time unit; or n_spots: the expected spot count.
        step: vertical spot step Delta in d.
        gamma: correlation of successive horizontal steps, in [0, 1).
        steps: ``"gaussian"`` or ``"binary"``.
        probes: accumulate the probe fields (bool).
        batches: time batches of the probe fields; records: snapshots of tracked particles.
        tracked: ``"all"`` or ``"none"``.
        replicas: number of independent runs of :func:`replicas_from_case` (seeds
            ``seed, seed + 1, ...``); ``from_case`` runs one.
        relax: a :class:`~spotpde.montecarlo.Relax` (relaxation on), ``False`` (off).
    """

    particles: str | None = None
    spacing: float | None = None
    seed: int | None = None
    t_end: float | None = None
    n_spots: int | None = None
    step: float | None = None
    gamma: float | None = None
    steps: str | None = None
    probes: bool | None = None
    batches: int | None = None
    records: int | None = None
    tracked: str | None = None
    replicas: int | None = None
    relax: Relax | bool | None = None

    @classmethod
    def from_table(cls, table: Mapping | None) -> "MonteCarloSettings":
        """The settings of a validated ``[montecarlo]`` table (``case.data["montecarlo"]``;
        ``None``: no table, every field ``None``)."""
        table = dict(table or {})
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(table) - names)
        if unknown:
            raise ValueError(f"table: unknown keys {unknown}; valid: {sorted(names)}")
        relax = table.pop("relax", None)
        if relax is True:
            relax = Relax()
        elif isinstance(relax, Mapping):
            relax = Relax.of(dict(relax))
        return cls(relax=relax, **table)

    def keywords(self) -> dict:
        """The given settings as keywords of ``from_case`` (``"none"`` -> ``None``,
        ``relax = False`` -> ``None``)."""
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if value is None or f.name == "replicas":
                continue
            if f.name in ("particles", "tracked") and value == "none":
                value = None
            elif f.name == "relax" and value is False:
                value = None
            out[f.name] = value
        return out


def with_settings(case, particles, spacing, kwargs: dict):
    """``(particles, spacing, kwargs)`` for ``from_case``: the case's ``[montecarlo]``
    settings under the caller's keywords (``UNSET``: not given by the caller)."""
    settings = getattr(case, "montecarlo", None)
    merged = {**(settings.keywords() if settings is not None else {}), **kwargs}
    table_particles = merged.pop("particles", "lattice")
    table_spacing = merged.pop("spacing", 1.0)
    if "t_end" in kwargs or "n_spots" in kwargs:  # the caller's duration replaces the table's
        for key in ("t_end", "n_spots"):
            if key not in kwargs:
                merged.pop(key, None)
    return (table_particles if particles is UNSET else particles,
            table_spacing if spacing is UNSET else spacing, merged)


def case_settings(run):
    """Decorate ``from_case(case, *, particles, spacing, **kwargs)`` so that the case's
    ``[montecarlo]`` settings fill in the keywords its caller did not give."""

    @functools.wraps(run)
    def wrapper(case, *, particles=UNSET, spacing=UNSET, **kwargs):
        particles, spacing, kwargs = with_settings(case, particles, spacing, kwargs)
        return run(case, particles=particles, spacing=spacing, **kwargs)

    return wrapper
