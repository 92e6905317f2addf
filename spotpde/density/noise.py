"""Reproducible random orifice rate: ``Q0(t) = Q0_mean(t) * M(t)`` (``[orifice] noise``).

The modulation is log-normal over an Ornstein-Uhlenbeck process ``X`` of unit variance
and correlation time ``tau``:

    M(t) = exp(a X(t) - a**2 / 2),     dX = -X dt / tau + sqrt(2 / tau) dW,   X(0) ~ N(0, 1),

so ``M > 0`` always, ``E[M] = 1`` (the mean rate is the requested one),
``Var M = exp(a**2) - 1`` and ``corr(X(t), X(t + s)) = exp(-|s| / tau)``. ``X`` is
sampled exactly (the AR(1) recursion ``X_{k+1} = e X_k + sqrt(1 - e**2) N_k``,
``e = exp(-dt/tau)``) on the fixed grid ``t_k = k tau / 16``, extended on demand from
``t = 0`` in blocks, and interpolated linearly between nodes; the sequence depends on
the seed only (not on the solver's steps or on the order of queries), so a case
reproduces exactly. The amplitude ``a`` is the standard deviation of ``log M``
(``a = 0`` gives the mean rate exactly).
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.signal import lfilter

__all__ = ["OrnsteinUhlenbeck", "noisy_rate"]

_NODES_PER_TAU = 16
_BLOCK = 4096


class OrnsteinUhlenbeck:
    """Unit-variance OU process ``X(t)``, ``t >= 0``, piecewise linear between nodes.

    Args:
        correlation_time: ``tau`` (> 0), case time unit.
        seed: integer seed of :func:`numpy.random.default_rng`.
    """

    def __init__(self, correlation_time: float, seed: int = 0):
        tau = float(correlation_time)
        if not (np.isfinite(tau) and tau > 0):
            raise ValueError(f"correlation_time: must be > 0, got {correlation_time!r}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise TypeError(f"seed: must be an integer >= 0, got {seed!r}")
        self.tau = tau
        self.dt = tau / _NODES_PER_TAU
        self._rng = np.random.default_rng(int(seed))
        self._x = np.array([self._rng.standard_normal()])
        self._e = np.exp(-self.dt / tau)

    def _extend(self, n: int) -> None:
        """Nodes up to index ``n - 1``, drawn in whole blocks of ``_BLOCK`` (so the path
        does not depend on how often it was asked for), in one filter pass: linear in
        the nodes added."""
        if self._x.size >= n:
            return
        blocks = -(-(n - self._x.size) // _BLOCK)
        z = self._rng.standard_normal(blocks * _BLOCK)
        s = np.sqrt(1.0 - self._e ** 2)
        # x_i = e x_{i-1} + s z_i, started from the last node (a first-order filter)
        x, _ = lfilter([s], [1.0, -self._e], z, zi=[self._e * self._x[-1]])
        self._x = np.concatenate([self._x, x])

    def __call__(self, t):
        """``X(t)`` for a time or an array of times (>= 0)."""
        tt = np.asarray(t, dtype=float)
        if np.any(tt < 0) or not np.all(np.isfinite(tt)):
            raise ValueError("t: must be finite and >= 0")
        k = tt / self.dt
        self._extend(int(np.max(k, initial=0.0)) + 2)
        i = np.floor(k).astype(int)
        f = k - i
        out = (1.0 - f) * self._x[i] + f * self._x[i + 1]
        return float(out) if np.ndim(out) == 0 else out


def noisy_rate(rate, amplitude: float, correlation_time: float, seed: int = 0
               ) -> Callable[[float], float]:
    """``Q0(t) * exp(a X(t) - a**2/2)``: a reproducible, positive, mean-preserving random rate.

    Args:
        rate: the mean rate ``Q0`` (spots per unit time): a number or a callable of ``t``.
        amplitude: ``a >= 0``, the standard deviation of the log-modulation.
        correlation_time: ``tau > 0`` of the OU process (case time unit).
        seed: integer >= 0.

    Returns:
        ``Q0(t)``, a float for a float time.
    """
    a = float(amplitude)
    if not (np.isfinite(a) and a >= 0):
        raise ValueError(f"amplitude: must be >= 0, got {amplitude!r}")
    X = OrnsteinUhlenbeck(correlation_time, seed)
    base = rate if callable(rate) else (lambda t, q=float(rate): q)

    def q(t):
        return base(t) * np.exp(a * X(t) - 0.5 * a * a)

    q.amplitude, q.correlation_time, q.seed = a, float(correlation_time), int(seed)
    return q
