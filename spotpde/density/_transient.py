"""Implicit time stepping of the spot Fokker-Planck equation ``d rho/dt = A rho + q(t)``.

``A`` is the conservative finite-volume operator of :mod:`spotpde.density._elliptic`. Diffusion
makes the system stiff (``D dt / h**2`` of order 10 at a Courant number of 1), so the
stepping is implicit: BDF2 (second order, A-stable and strongly damping, so a sharp
start-up front does not ring as it would under Crank-Nicolson),

    (3 rho^{n+1} - 4 rho^n + rho^{n-1}) / (2 dt) = A rho^{n+1} + q(t_{n+1}),

started by one backward-Euler step; each of the two matrices ``I - dt A`` and
``I - 2/3 dt A`` is factorised once (SuperLU) and reused, since ``dt`` is constant.
Frames at requested times are linear interpolants between steps (second order, the
order of the scheme). Reference: Hundsdorfer & Verwer, *Numerical Solution of
Time-Dependent Advection-Diffusion-Reaction Equations* (Springer 2003), IV.1.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import scipy.sparse as sp

from ._elliptic import assemble, factorize
from ..errors import NumericalError


def integrate(shape, h, v, D_perp, D_par, q: Callable[[float], np.ndarray], t_end: float,
              times: np.ndarray, dt: float | None = None, rho0: np.ndarray | None = None,
              progress: Callable[[float], None] | None = None, operator=None,
              volumes: np.ndarray | None = None) -> dict:
    """Integrate from ``t = 0`` to ``t_end`` and return frames at ``times``.

    Args:
        shape, h, v, D_perp, D_par: grid and coefficients (see ``_elliptic.assemble``).
        q: source vector as a function of time (flattened, spots / d**dims / time).
        t_end: final time (> 0).
        times: sorted frame times in ``[0, t_end]``.
        dt: time step; default ``h / max(v)`` (Courant number 1), at least 20 steps.
        rho0: initial density (grid shape), default zero (an empty silo).
        progress: called with the fraction done.
        operator: ``(A, out_row)`` built by the caller (default ``_elliptic.assemble``;
            the metric / staircase grids pass ``_geometry.assemble``).
        volumes: flattened cell volumes for the ``inflow`` diagnostic (default ``h**dims``).

    Returns:
        dict with ``frames`` (``(len(times),) + shape``), ``outflow`` (spots per unit time
        through the top at each frame), ``inflow`` (``q`` integrated over the domain at
        each frame), ``dt`` and ``steps``.
    """
    A, out_row = assemble(shape, h, v, D_perp, D_par) if operator is None else operator
    N = A.shape[0]
    vmax = float(np.max(v))
    if dt is None:
        dt = h / vmax if vmax > 0 else t_end / 20
    steps = max(20, int(np.ceil(t_end / dt - 1e-9)))
    dt = t_end / steps
    I = sp.identity(N, format="csc")
    be = factorize(I - dt * A, len(shape))
    bdf = factorize(I - (2.0 / 3.0) * dt * A, len(shape))
    cell = h ** len(shape)

    rho = np.zeros(N) if rho0 is None else np.asarray(rho0, dtype=float).ravel().copy()
    prev = None
    frames = np.empty((len(times), N))
    outflow = np.empty(len(times))
    inflow = np.empty(len(times))
    j = 0
    t = 0.0

    def record(upto_t, rho_old, rho_new, t_old):
        nonlocal j
        while j < len(times) and times[j] <= upto_t + 1e-12 * max(1.0, t_end):
            w = 0.0 if upto_t == t_old else (times[j] - t_old) / (upto_t - t_old)
            frames[j] = (1.0 - w) * rho_old + w * rho_new
            outflow[j] = (out_row @ frames[j])[0]
            inflow[j] = (q(times[j]).sum() * cell if volumes is None
                         else float(np.dot(q(times[j]), volumes)))
            j += 1

    record(0.0, rho, rho, 0.0)
    every = max(1, steps // 200)
    for n in range(steps):
        t_new = (n + 1) * dt
        if prev is None:
            new = be(rho + dt * q(t_new))
        else:
            new = bdf((4.0 * rho - prev) / 3.0 + (2.0 / 3.0) * dt * q(t_new))
        if not np.all(np.isfinite(new)):
            raise NumericalError(f"spot density: non-finite values at t = {t_new:g}")
        record(t_new, rho, new, t)
        prev, rho, t = rho, new, t_new
        if progress is not None and n % every == 0:
            progress((n + 1) / steps)
    if progress is not None:
        progress(1.0)
    return {
        "frames": frames.reshape((len(times),) + tuple(shape)),
        "outflow": outflow,
        "inflow": inflow,
        "dt": dt,
        "steps": steps,
    }
