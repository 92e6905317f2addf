"""The serial and parallel variants of the 2D tracer kernel agree to round-off.

A run on one numba thread (the default below 65536 cells) compiles only the serial
variant of ``spotpde.tracer._fp_kernels.rhs_2d_kernel``, which cuts about a third of the
first-run compilation (docs/tracer.md, Performance); larger runs use the ``parallel=True``
variant.
Both evaluate each chunk of rows with the same floating-point operations, but the kernels
are compiled with fast-math reassociation and contraction, and LLVM may contract the two
differently built functions (a plain loop, a gufunc body) differently: a fresh CI build
differed in the last bits. So every output array of one right-hand
side and of one fused Runge-Kutta stage is compared to round-off (1e-13 of its largest
value), for the default WENO5 and for Koren, on grids with one and with several chunks,
with and without the cross terms; what the solver calls on one thread is the serial
variant itself, bit for bit.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest

from spotpde.tracer import _fp_kernels as K
from spotpde.tracer import _solve
from spotpde.tracer._advection import LIMITERS

from test_tracer_kernel import random_problem


def outputs(op, P, grid, kernel, stage):
    """(stage or R, floor/top fluxes, accumulated fluxes) of one call of ``kernel``."""
    ws = _solve._Workspace(grid, P.max())
    ws.Fz_acc[:] = 1.0
    out = np.empty_like(P)
    if stage:
        P0, ca, cb, cc, tiny = 0.5 * P, 0.75, 0.25, 0.25 * 0.3 / op.rate, ws.tiny
    else:
        P0, ca, cb, cc, tiny = P, 0.0, 0.0, 1.0, 0.0
    f = op.faces
    kernel(P, f["x"], f["z"], op.Axx, op.Azz, op.C, op.k_cross, op.eps, op.h, out,
           ws.Fz_edge, ws.Fz_acc, 0.7, P0, ca, cb, cc, tiny)
    return out, ws.Fz_edge, ws.Fz_acc


@pytest.mark.parametrize("name", ["weno5", "koren"])
@pytest.mark.parametrize("nz,nx", [(5, 6), (97, 64)])
@pytest.mark.parametrize("cross", [True, False])
def test_serial_and_parallel_kernels_agree_to_round_off(name, nz, nx, cross):
    grid, f, P = random_problem(2, nz, nx, seed=nz * 100 + nx, cross=cross)
    op = _solve._Operator(grid, f, LIMITERS[name].code, np.ones(grid.shape[1:], bool),
                          implicit=False, p_scale=P.max())
    assert op.k_cross == cross
    dispatch = K.rhs_2d_kernel(LIMITERS[name].code)
    saved = numba.get_num_threads()
    try:
        for stage in (False, True):
            numba.set_num_threads(1)
            serial = outputs(op, P, grid, dispatch.variant(False), stage)
            # what the solver calls on one thread is the serial variant
            called = outputs(op, P, grid, dispatch, stage)
            numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
            parallel = outputs(op, P, grid, dispatch.variant(True), stage)
            for s, c, p in zip(serial, called, parallel):
                scale = np.abs(s).max()
                assert scale > 0
                assert s.tobytes() == c.tobytes()
                np.testing.assert_allclose(p, s, rtol=0, atol=1e-13 * scale)
    finally:
        numba.set_num_threads(saved)


@pytest.mark.slow
def test_the_warmup_child_compiles_the_kernel_the_run_loads(tmp_path):
    """``spotpde run`` compiles its tracer kernel in a child process
    (``spotpde.app._warmup``) while it computes the fields: the child's tiny solve must
    compile the very variant (argument types) a case run calls, so that the run finds it
    in numba's cache: no compilation in the run (cache hit, no miss)."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, SPOTPDE_CACHE_DIR=str(tmp_path), PYTHONPATH=os.getcwd())
    env.pop("NUMBA_CACHE_DIR", None)
    probe = ("import spotpde; from spotpde.app import _warmup; print(_warmup.needed())")
    check = lambda: subprocess.run([sys.executable, "-c", probe], env=env, text=True,
                                   capture_output=True, check=True).stdout.strip()
    assert check() == "True"                            # a fresh cache: a child is due
    subprocess.run([sys.executable, "-m", "spotpde.app._warmup", "weno5", "1"], env=env,
                   check=True, timeout=300)
    assert check() == "False"                           # the kernel's index is written
    run = """
import spotpde
from spotpde.tracer import _fp_kernels as K
case = spotpde.load_case({"domain": {"x": [-2.0, 2.0], "z": [0.0, 4.0], "spacing": 0.25},
                          "orifice": {"width": 1.0},
                          "tracer": {"start": {"x": 0.0, "z": 3.0, "width": 0.5},
                                     "t_end": 1.0, "frames": 2}})
spotpde.run(case)
from spotpde.tracer._advection import limiter_from_name
stats = K._rhs_2d_variant(limiter_from_name("weno5").code, False).stats
print(sum(stats.cache_hits.values()), sum(stats.cache_misses.values()))
"""
    out = subprocess.run([sys.executable, "-c", run], env=env, text=True, capture_output=True,
                         check=True, timeout=300).stdout.split()
    hits, misses = int(out[-2]), int(out[-1])
    assert hits >= 1 and misses == 0
