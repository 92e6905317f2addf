"""Explicit sub-stepping of the fast faces for ``stepping="multirate"`` (private).

The fast cells of :func:`spotpde.tracer._implicit.imex_result` (explicit positivity rate
above ``max(a) / split``, next to a point orifice) lie in a small box. Instead of the
implicit hybrid (first-order upwind) advection, their faces keep the explicit limited
high-order scheme (WENO5, SSP-RK3), stepped ``m = ceil(tau a_box / cfl)`` times per
``tau`` on the box only: the box is the fast cells' bounding box grown by 4 cells, so
every fast face has its whole 6-cell WENO5 stencil inside it and the same face values
as on the full grid; the box's own edge faces carry no velocity (only fast faces move
probability here). Each sub-step is a convex combination of forward-Euler steps with
``dt a_box <= cfl`` (positive); its face fluxes go into the run's ``P_height``
(``Fz_acc``) and outflow budget (conservative). Coupled to the slow faces by Strang
splitting, ``E(dt) = F(dt/2) S(dt) F(dt/2)`` (second order), inside the IMEX splitting
with the implicit diffusion.
"""

from __future__ import annotations

import copy
import math
import types

import numba
import numpy as np

from ._operator import _Workspace
from ._advection import advective_rate
from ._stepping import _rk_step

HALO = 4


def box_of(fast):
    """The box of the fast cells: their bounding box grown by ``HALO`` cells, clipped to
    the grid (a tuple of slices)."""
    return tuple(slice(max(0, int(i.min()) - HALO), min(n, int(i.max()) + 1 + HALO))
                 for i, n in zip(np.nonzero(fast), fast.shape))


class FastBox:
    """The fast faces' explicit operator on their box.

    Args:
        op: the explicit full-grid operator (``implicit=True``: no diffusion).
        faces_fast: face velocities with only the fast faces non-zero (full grid).
        fast: boolean cell mask of the fast cells.
        ws: the run's workspace (its ``Fz_acc`` receives the box's z fluxes).
        scheme: SSP Runge-Kutta scheme.
        cfl: fraction of the box's positivity limit used by each sub-step.
        p_scale: ``max(P0)``.
    """

    def __init__(self, op, faces_fast, fast, ws, scheme, cfl, p_scale):
        dims = fast.ndim
        self.box = box_of(fast)
        shape = tuple(s.stop - s.start for s in self.box)
        names = ["z", "y", "x"] if dims == 3 else ["z", "x"]
        faces = {}
        for axis, name in enumerate(names):
            sl = tuple(slice(s.start, s.stop + 1) if d == axis else s
                       for d, s in enumerate(self.box))
            faces[name] = np.ascontiguousarray(faces_fast[name][sl])
        self.op = copy.copy(op)
        self.op.faces = faces
        if dims == 2:
            zero = np.zeros(shape)
            self.op.Axx = self.op.Azz = self.op.C = zero
            self.op.k_cross = False
        self.op.terms = []
        self.rate = float(advective_rate(faces, op.h).max())
        self.ws = _Workspace(types.SimpleNamespace(shape=shape, dims=dims), p_scale)
        self.run_ws = ws
        self.scheme = scheme
        self.cfl = cfl
        self.cells = int(np.prod(shape))
        self.substeps = 0
        zb = self.box[0]
        self.fz_slice = (slice(zb.start, zb.stop + 1),) + self.box[1:]

    def advance(self, P, tau, budget):
        """Advance ``P`` (full grid, in place on the box) by ``tau`` along the fast faces."""
        if self.rate == 0.0:
            return P
        m = max(1, math.ceil(tau * self.rate / self.cfl - 1e-9))
        d = tau / m
        Pb = np.ascontiguousarray(P[self.box])
        ops = [self.op] * self.scheme.stages
        self.ws.Fz_acc[...] = 0.0
        # one thread: on a box of a few hundred cells a parallel region costs more than
        # the work (6 ms a call measured with 2 threads on the loaded machine)
        threads = numba.get_num_threads()
        numba.set_num_threads(1)
        try:
            for _ in range(m):
                Pb = _rk_step(ops, Pb, d, self.scheme, self.ws, budget)
        finally:
            numba.set_num_threads(threads)
        P[self.box] = Pb
        self.run_ws.Fz_acc[self.fz_slice] += self.ws.Fz_acc
        self.substeps += m
        return P
