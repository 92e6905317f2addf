"""Benchmark: spotpde.convolution against scipy.signal.fftconvolve, measured in the same run.

For 512^2 and 1024^2 fields (and 128^3) prints the time per convolution of spotpde's
engine (``convolve`` with its cached plans and kernel spectrum, i.e. the steady state of
a solver that convolves many fields with one kernel) and of
``scipy.signal.fftconvolve(f, stencil, mode="same")`` on the same inputs, and their
ratio, for

* a full-domain kernel: a Gaussian stencil as wide as the domain (``n + 1`` cells), and
* a cut kernel: ``Gaussian(sigma=2).sample(h=0.5)``, cut at 1e-14 of the peak (65 cells).

Each timing is the best of several repetitions after one warm-up call (plan building and
the kernel spectrum are excluded from spotpde's time: they are paid once per run); the
two codes are called alternately so that both see the same machine load. The two results
are compared, so the ratio is between equal computations. The load average is printed:
on a shared machine, threaded FFTs suffer most from other processes.

Usage::

    .venv/bin/python benchmarks/convolution.py [--quick] [--backend pyfftw|scipy]
"""

from __future__ import annotations

import argparse
import os

import numpy as np
from _timing import best_times
from scipy.signal import fftconvolve

from spotpde.fields import _fft, kernels
from spotpde.fields.convolution import convolve


def full_stencil(n, dims):
    """Gaussian of width n/6 cells sampled on (n+1)^dims offsets: spans the whole domain."""
    j = np.arange(-(n // 2), n // 2 + 1, dtype=float)
    g = np.exp(-0.5 * (j / (n / 6.0)) ** 2)
    out = g
    for _ in range(dims - 1):
        out = np.multiply.outer(out, g)
    return out / out.sum()


def cut_stencil(dims):
    return kernels.Gaussian(sigma=2.0, volume=1.0, dims=dims).sample(0.5) * 0.5**dims


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="only 512^2, one repetition")
    parser.add_argument("--backend", default=None, choices=("pyfftw", "scipy"))
    args = parser.parse_args()
    cases = [((512, 512), 15), ((1024, 1024), 7), ((128, 128, 128), 4)]
    if args.quick:
        cases = [((512, 512), 1)]
    rng = np.random.default_rng(0)
    print(f"cores available: {len(os.sched_getaffinity(0))}, backend: {args.backend or 'default'}, "
          f"FFT threads: {_fft.threads()}, load average: {os.getloadavg()[0]:.2f}")
    header = f"{'field':>12} {'kernel':>14} {'stencil':>16} {'spotpde [ms]':>13} {'fftconvolve [ms]':>17} {'ratio':>7} {'max|diff|':>10}"
    print(header)
    print("-" * len(header))
    for shape, repeat in cases:
        dims = len(shape)
        f = rng.random(shape)
        for label, s in (("full-domain", full_stencil(shape[0], dims)), ("cut (support)", cut_stencil(dims))):
            ours = convolve(f, s, backend=args.backend)
            ref = fftconvolve(f, s, mode="same")
            diff = np.abs(ours - ref).max()
            t_ours, t_ref = best_times([lambda: convolve(f, s, backend=args.backend),
                                        lambda: fftconvolve(f, s, mode="same")], repeat)
            print(f"{'x'.join(map(str, shape)):>12} {label:>14} {'x'.join(map(str, s.shape)):>16} "
                  f"{1e3 * t_ours:13.1f} {1e3 * t_ref:17.1f} {t_ref / t_ours:7.2f} {diff:10.1e}")
    print(f"load average at the end: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
