"""Limited upwind face values of the tracer's advection, face by face (private; used by
:mod:`._steady_limited`).

The time-stepped kernels (:mod:`._fp_kernels`) reconstruct the upwind value ``P*_f`` of
every face and use it at once in the flux ``u_f P*_f``; the steady solve of the same
scheme needs the values themselves (as the ratio ``P*_f / P_up``). This module evaluates
them with the kernels' own reconstruction, :func:`._fp_kernels.recon`, with the same
boundary fallbacks (WENO5 -> Koren -> donor cell where the stencil leaves the grid),
for the interior faces along one axis. Boundary faces are not included: the tracer's
boundary faces carry outflow only, with the boundary cell's value (first order).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import _fp_kernels as K


@njit(cache=True, fastmath=K.FASTMATH, error_model="numpy")
def _faces_axis0(P, uf, limiter, eps, out):
    """``out[f - 1, j]`` = the upwind value at the face ``f`` (between cells ``f - 1`` and
    ``f``) of column ``j``, for ``f = 1 .. n - 1``; ``P`` is ``(n, m)``, ``uf`` the
    ``(n + 1, m)`` face velocities (the sign picks the upwind side), ``eps`` the WENO scale
    ``1 / P_scale**2``. The arguments of :func:`._fp_kernels.recon` are those of the 2D
    kernel's edge faces (``_xface_edge``), which equal its interior ones away from a
    boundary."""
    n, m = P.shape
    for f in range(1, n):
        i = f - 1
        for j in range(m):
            if uf[f, j] > 0.0:
                out[i, j] = K.recon(P[max(i - 2, 0), j], P[max(i - 1, 0), j], P[i, j],
                                    P[i + 1, j], P[min(i + 2, n - 1), j],
                                    i >= 2, i >= 1, i + 2 <= n - 1, limiter, eps)
            else:
                out[i, j] = K.recon(P[min(i + 3, n - 1), j], P[min(i + 2, n - 1), j],
                                    P[i + 1, j], P[i, j], P[max(i - 1, 0), j],
                                    i + 3 <= n - 1, i + 2 <= n - 1, i >= 1, limiter, eps)


def face_values(P: np.ndarray, uf: np.ndarray, axis: int, limiter: int,
                eps: float) -> np.ndarray:
    """Upwind face values of ``P`` at the interior faces along ``axis``.

    Args:
        P: cell values (any number of dimensions), 1/d**dims or, for the steady
            propagator, time/d**dims.
        uf: face velocities along ``axis`` (one more entry than ``P`` along it), d/time.
        axis: array axis.
        limiter: kernel code (:data:`._fp_kernels.WENO5`, ...).
        eps: WENO scale ``1 / P_scale**2`` (units of ``1 / P**2``).

    Returns:
        Array shaped as ``P`` with one entry fewer along ``axis``: the value at the face
        between cells ``c`` and ``c + 1``, from the side ``uf`` flows from.
    """
    Pm = np.ascontiguousarray(np.moveaxis(P, axis, 0))
    um = np.ascontiguousarray(np.moveaxis(uf, axis, 0))
    n = Pm.shape[0]
    rest = Pm.shape[1:]
    out = np.empty((n - 1, int(np.prod(rest))))
    _faces_axis0(Pm.reshape(n, -1), um.reshape(n + 1, -1), int(limiter), float(eps), out)
    return np.moveaxis(out.reshape((n - 1,) + rest), 0, axis)
