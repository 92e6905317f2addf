"""Independent Monte Carlo runs of a case, one per seed (``[montecarlo] replicas``).

Beside :mod:`._settings` (which reads the case table) because it runs the simulation:
``_simulate`` imports the settings, this module imports both.
"""

from __future__ import annotations

from . import mcstats
from ._settings import MonteCarloSettings
from ._simulate import from_case

__all__ = ["replicas_from_case"]


def replicas_from_case(case, *, replicas: int | None = None, scheduler: str | None = None,
                       **kwargs) -> list:
    """Independent runs of :func:`~spotpde.montecarlo.from_case`, one per seed.

    Seeds ``seed, seed + 1, ..., seed + replicas - 1`` with ``seed`` and ``replicas`` from
    the keywords, else from the case's ``[montecarlo]`` table, else 0 and 1; every other
    keyword goes to ``from_case`` (over the table). Errors of a quantity are its scatter
    over the returned runs (``mcstats.replica_mean``).

    Args:
        replicas: number of runs (>= 1).
        scheduler: ``None`` (one after the other) or a Dask scheduler name
            (``mcstats.replicas``).

    Returns:
        list of :class:`~spotpde.montecarlo.MCResult`, in seed order.

    Raises:
        ValueError: ``replicas`` or ``seed`` invalid.
    """
    settings = getattr(case, "montecarlo", None) or MonteCarloSettings()
    n = replicas if replicas is not None else (settings.replicas or 1)
    base = kwargs.pop("seed", None)
    base = base if base is not None else (settings.seed or 0)
    if not (isinstance(n, int) and not isinstance(n, bool) and n >= 1):
        raise ValueError(f"replicas: must be an integer >= 1, got {n!r}")
    if not (isinstance(base, int) and not isinstance(base, bool) and base >= 0):
        raise ValueError(f"seed: must be an integer >= 0, got {base!r}")
    return mcstats.replicas(lambda s: from_case(case, seed=s, **kwargs),
                            range(base, base + n), scheduler=scheduler)
