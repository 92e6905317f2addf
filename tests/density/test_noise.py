"""The random orifice rate's Ornstein-Uhlenbeck process (spotpde.density.noise)."""

from __future__ import annotations

import numpy as np

from spotpde.density import noise


def test_the_path_does_not_depend_on_how_it_was_asked_for():
    """Asked for a far time at once, or step by step up to it, the process has the same
    nodes bit for bit: nodes come in whole blocks from one random stream."""
    tau = 2.0
    far = noise.OrnsteinUhlenbeck(tau, seed=7)
    steps = noise.OrnsteinUhlenbeck(tau, seed=7)
    t = np.linspace(0.0, 40 * noise._BLOCK * far.dt, 17)
    for ti in t:
        steps(ti)
    assert np.array_equal(far(t), steps(t))
    assert np.array_equal(far._x, steps._x)


def test_unit_variance_and_the_stated_correlation_time():
    """``var X = 1`` and ``<X(t) X(t + s)> = exp(-s / tau)`` over a long path, within
    the sampling error of ~3000 correlation times (lag-one estimates from nodes)."""
    tau = 1.0
    X = noise.OrnsteinUhlenbeck(tau, seed=3)
    n_tau = 3000
    t = np.arange(0.0, n_tau * tau, X.dt)
    x = X(t)
    # independent blocks of 10 tau each: the standard error of the variance estimate
    blocks = x[: len(x) // 300 * 300].reshape(300, -1)
    var_blocks = blocks.var(axis=1)
    se = var_blocks.std(ddof=1) / np.sqrt(len(var_blocks))
    assert abs(x.var() - 1.0) < 4 * se
    lag = int(round(tau / X.dt))
    c = np.mean(x[:-lag] * x[lag:]) / x.var()
    assert abs(c - np.exp(-1.0)) < 0.05
