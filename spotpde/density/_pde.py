"""The spot Fokker-Planck equation as a py-pde ``PDEBase`` (explicit cross-check path).

The right-hand side is the conservative finite-volume operator of
:mod:`spotpde.density._elliptic`, ``d rho/dt = A rho + Q0(t) q``, in py-pde's axis order
(``x`` first, ``z`` last). The numba version is a compiled CSR matrix-vector product
(constant ``Q0`` only; a time-dependent ``Q0`` uses the numpy backend). Boundary
conditions live in ``A`` (no flux through walls and floor, inflow through the orifice,
outflow at the top), so py-pde's boundary-condition machinery is not used. Axisymmetric
and hopper grids use the metric / staircase operator of :mod:`spotpde.density._geometry`
(on py-pde's ``CylindricalSymGrid`` / ``CartesianGrid``, which only carry the data).

py-pde's explicit solvers (with its adaptive step control, ``MemoryStorage`` for frames
and ``CallbackTracker`` for progress) fit this equation only on small grids: stability
needs ``dt < h**2 / (2 dims D)``, about 25 times below the Courant step of the BDF2
default (:mod:`spotpde.density._transient`); its implicit solver is a fixed-point iteration that
does not converge once ``D dt / h**2 > 1``. Hence it serves as an independent
time-integration check of the BDF2 stepping (``tests/density/test_spot_density.py``).
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import pde

from . import _geometry
from ._elliptic import assemble
from ..grid import Grid


class SpotDensityPDE(pde.PDEBase):
    """``d rho/dt = A rho + Q0(t) q`` on a spotpde grid, for py-pde solvers.

    Args:
        grid: the (reflecting, possibly padded) grid.
        v, D_perp, D_par: drift and diffusivities (floats or grid-shaped arrays).
        q: floor source per unit rate, flattened in spotpde order (``_elliptic.floor_source``).
        rate: ``Q0``: a float or a callable of time.
    """

    check_implementation = True

    def __init__(self, grid: Grid, v, D_perp, D_par, q: np.ndarray,
                 rate: float | Callable[[float], float]):
        super().__init__()
        self.spot_grid = grid
        if not grid.geometry.uniform_cells:     # rings / staircase: the metric operator
            A, _ = _geometry.assemble(grid, v, D_perp, D_par)
        else:
            A, _ = assemble(grid.shape, grid.spacing, v, D_perp, D_par)
        self.A = A
        self.q = np.asarray(q, dtype=float).ravel()
        self.rate = rate
        self.explicit_time_dependence = callable(rate)
        idx = np.arange(grid.size).reshape(grid.shape)
        perm = grid.to_pde_data(idx).ravel()          # pde-flat position -> spotpde index
        self._A_pde = A[perm][:, perm].tocsr()
        self._q_pde = self.q[perm]

    def _rate(self, t: float) -> float:
        return float(self.rate(t)) if callable(self.rate) else float(self.rate)

    def evolution_rate(self, state, t: float = 0):
        g = self.spot_grid
        rho = g.from_pde_data(state.data).ravel()
        r = (self.A @ rho + self._rate(t) * self.q).reshape(g.shape)
        return pde.ScalarField(state.grid, g.to_pde_data(r))

    def make_evolution_rate(self, state, backend):
        if callable(self.rate):
            raise NotImplementedError("SpotDensityPDE: a time-dependent rate needs backend='numpy'")
        indptr = self._A_pde.indptr.copy()
        indices = self._A_pde.indices.copy()
        vals = self._A_pde.data.copy()
        src = self._q_pde * float(self.rate)
        shape = tuple(state.data.shape)
        n = src.size

        def rhs(data, t):
            flat = data.ravel()
            out = np.empty(n)
            for i in range(n):
                s = src[i]
                for p in range(indptr[i], indptr[i + 1]):
                    s += vals[p] * flat[indices[p]]
                out[i] = s
            return out.reshape(shape)

        return rhs


def integrate(grid: Grid, v, D_perp, D_par, q: np.ndarray, rate, t_end: float,
              times: np.ndarray, rho0: np.ndarray | None = None,
              progress: Callable[[float], None] | None = None, backend: str = "numpy") -> np.ndarray:
    """Integrate with py-pde's adaptive Runge-Kutta solver; frames at ``times``.

    Args:
        grid, v, D_perp, D_par, q, rate: as :class:`SpotDensityPDE`.
        t_end: final time; times: frame times in ``[0, t_end]``.
        rho0: initial density (default 0); progress: called with the fraction done.
        backend: py-pde backend, ``"numpy"`` (sparse product; fastest on small grids,
            nothing to compile) or ``"numba"`` (compiled CSR product, constant rate only).

    Returns:
        frames, shape ``(len(times),) + grid.shape``, spotpde order.
    """
    eq = SpotDensityPDE(grid, v, D_perp, D_par, q, rate)
    data = np.zeros(grid.shape) if rho0 is None else np.asarray(rho0, float)
    state = pde.ScalarField(grid.to_pde(), grid.to_pde_data(data))
    storage = pde.MemoryStorage()
    trackers = [storage.tracker(list(np.asarray(times, float)))]
    if progress is not None:
        trackers.append(pde.CallbackTracker(lambda s, t: progress(min(1.0, t / t_end)),
                                            interrupts=t_end / 100))
    dmax = float(np.max(np.maximum(D_perp, D_par)))
    dt0 = 0.1 * grid.spacing**2 / max(dmax, 1e-300)
    eq.solve(state, t_range=t_end, dt=dt0, solver="runge-kutta", tolerance=1e-8, tracker=trackers,
             backend=backend if not callable(rate) else "numpy")
    frames = np.array([grid.from_pde_data(f.data) for f in storage])
    if len(frames) != len(times):
        raise RuntimeError(f"py-pde stored {len(frames)} frames, expected {len(times)}")
    return frames
