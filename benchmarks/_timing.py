"""Best-of-N timing shared by the benchmark scripts (run as ``python benchmarks/X.py``)."""

from __future__ import annotations

import time


def best_time(fn, repeat, clock=time.perf_counter):
    """Best time of ``repeat`` calls of ``fn`` after one warm-up call.

    The warm-up pays for numba compilation, FFTW plans, kernel spectra and imports.
    ``clock=time.thread_time`` counts only this thread's CPU time (meaningful with one
    numba thread on a shared machine).

    Returns:
        ``(best, result)``: the best time in seconds (of ``clock``) and the result of
        the last call.
    """
    result = fn()
    best = float("inf")
    for _ in range(repeat):
        t0 = clock()
        result = fn()
        best = min(best, clock() - t0)
    return best, result


def best_times(fns, repeat, clock=time.perf_counter):
    """Best time of each function, calls interleaved so that all see the same machine load.

    Each function is called once first (warm-up: plans, spectrum cache).

    Returns:
        list of best times in seconds, in the order of ``fns``.
    """
    for fn in fns:
        fn()
    best = [float("inf")] * len(fns)
    for _ in range(repeat):
        for k, fn in enumerate(fns):
            t0 = clock()
            fn()
            best[k] = min(best[k], clock() - t0)
    return best
