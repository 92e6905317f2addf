"""The record of a Monte Carlo run (:class:`MCResult`) and the spot step laws (``STEPS``).

Its own module so that every driver (``_simulate``: boxes; ``_simulate3d``: 3D boxes and
slabs; ``_geometry``: hoppers and cylinders) returns the same record without importing
another driver.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..grid import Grid
from ..parameters import Orifice, Spots
from ._relax import Relax

if TYPE_CHECKING:   # annotation only: KernelParams lives with the kernel reduction
    from ._simulate import KernelParams

#: The laws of a spot's step: Gaussian, or binary (+-sqrt(2 b Delta) sideways)
STEPS = ("gaussian", "binary")

__all__ = ["STEPS", "MCResult"]


@dataclass
class MCResult:
    """Everything a Monte Carlo run recorded (all lengths in d, times in the case unit).

    Attributes:
        grid, orifice, spots, kernel (:class:`KernelParams`), rule, gamma, step (Delta),
            steps ("gaussian"/"binary"), seed, t_end, dt (time per tick), n_ticks.
        initial: ``(N, 2)`` initial particle positions ``(x, z)`` (3D: ``(N, 3)``,
            ``(x, z, y)``: the depth last); ``final``: final ones.
        status: per particle 0 inside, 1 left through the orifice, 2 left through an
            open side. ``exit_x``, ``exit_t``: where and when it left (NaN if not).
        tracked: indices of tracked particles. ``times``: snapshot times;
            ``positions``: ``(n_times, n_tracked, 2)`` (3D: ``(.., 3)``), NaN once a
            particle has left.
        levels: crossing heights; ``cross_x``/``cross_t``: ``(n_tracked, n_levels)`` x and
            time at which each tracked particle first fell through each level (NaN: not).
        probe: ``(5, n_batch, nz, nx)`` probe sums (see ``_mc_kernels.advance``; 3D:
            ``(9, n_batch, nz, ny, nx)``, ``_mc3d.advance3``; None without probes);
            ``rho_hist``: ``(n_batch, nz, nx)`` (3D ``(n_batch, nz, ny, nx)``) spot samples;
            ``batch_ticks``: ticks per batch.
        counters: injected spots, spot steps, particle updates, cell-list rebuilds.
        wall_time, cpu_time: wall-clock and CPU seconds spent in the numba loop.
        walls: the wall treatment (``"renormalise"`` or ``"truncate"``).
        relax: the resolved :class:`~spotpde.montecarlo.Relax` (``None``: grains do not
            interact). diameters: ``(N,)`` grain diameters in d.
    """

    grid: Grid
    orifice: Orifice
    spots: Spots
    kernel: KernelParams
    rule: float
    gamma: float
    step: float
    steps: str
    seed: int
    t_end: float
    dt: float
    n_ticks: int
    initial: np.ndarray
    final: np.ndarray
    status: np.ndarray
    exit_x: np.ndarray
    exit_t: np.ndarray
    tracked: np.ndarray
    times: np.ndarray
    positions: np.ndarray
    levels: np.ndarray
    cross_x: np.ndarray
    cross_t: np.ndarray
    probe: np.ndarray | None
    rho_hist: np.ndarray | None
    batch_ticks: np.ndarray
    counters: dict = field(default_factory=dict)
    wall_time: float = 0.0
    cpu_time: float = 0.0
    walls: str = "renormalise"
    relax: Relax | None = None
    diameters: np.ndarray | None = None

    @property
    def performance(self) -> dict:
        """Spot steps and particle updates per CPU second of the numba loop.

        CPU (process) time rather than wall time, so that the numbers do not depend on
        what else the machine runs; the first call of a session includes numba's loading
        of its cache (or compilation).
        """
        ct = max(self.cpu_time, 1e-12)
        return {"spot_steps_per_second": self.counters["spot_steps"] / ct,
                "particle_updates_per_second": self.counters["particle_updates"] / ct,
                "cpu_time": self.cpu_time, "wall_time": self.wall_time}
