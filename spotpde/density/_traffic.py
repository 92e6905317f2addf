"""Interacting spots: the nonlinear transient spot-density solver (private).

Equation (kinematic-wave / traffic-flow form of the spot Fokker-Planck equation):

    d rho/dt + d/dz q(rho; v_s) = div_perp J_perp + d/dz J_par + S,
    q = v_s rho_max g(rho / rho_max),       g concave, g(0) = 0, g'(0) = 1,

with diffusive fluxes (``m(rho) = g(y)/y``, the local spot speed over ``v_s``;
``m = 1`` for ``diffusion_scaling = "fixed"``)

    J_perp = -m(rho) grad_perp (D_perp rho),     J_par = -m(rho) d/dz (D_par rho).

``"fixed"``: the Ito form of the independent spots (``D_s`` does not know about the
other spots). ``"speed"``: ``D_s = b u(rho)``, ``u = q/rho`` the local speed, in the
Fickian form ``-D_s grad rho`` (for uniform ``D``); the Ito form ``-grad(b q(rho))``
would be backward-parabolic above ``rho_c`` (its effective diffusivity ``b q'(rho)``
is negative there), an ill-posed equation, so it is not offered.

Discretisation (finite volumes on the grid's cells, conservative, every face flux
evaluated once):

* vertical advective face flux: MUSCL reconstruction in ``z`` with a TVD slope limiter
  (``mc`` default, ``vanleer``, ``minmod``; van Leer 1979) and the demand-supply
  (Godunov) flux of the concave ``q`` (Lebacque 1996; Daganzo 1995),
  ``F = min(Dem(rho_-), Sup(rho_+))``, ``Dem(r) = q(min(r, rho_c))``,
  ``Sup(r) = q(max(r, rho_c))`` with the face drift ``v_f`` (mean of the two cells).
  This is the exact Godunov flux for a concave ``q``: it picks ``q(rho_c)`` across a
  transonic rarefaction (the entropy fix) and never admits a shock with density falling
  upward. The boundary cells use zero slope (first order there).
* diffusion: the pairwise exchanges of :mod:`spotpde.density._elliptic` (second-order central
  differences of ``D rho``), multiplied by ``m`` at the face (mean of the two cells).
* time: SSP-RK2 (Heun; Shu & Osher 1988), explicit, with

      dt <= cfl / (2 L / h + 2 (sum_axes D_max) / h**2),    L = max |q'| = v_max max|g'|,

  which makes each forward-Euler stage a convex combination of a MUSCL step at CFL
  number <= 1/2 and a diffusion step at ``2 D dt / h**2 <= 1`` per axis, so (``cfl <= 1``)
  ``0 <= rho <= rho_max`` holds for uniform ``D`` (Harten 1983; LeVeque, *Finite Volume
  Methods for Hyperbolic Problems*, 2002, sec. 6.12 and 12.11). Heun is a convex
  combination of two such stages and keeps the bounds. With spatially varying ``D``
  in the Ito form, density may pile up where ``D`` drops (the physics of independent
  walkers) and only ``rho >= 0`` is guaranteed.

Boundaries (the paper gives none; docs/interacting_spots.md):

* floor: the orifice asks for the flux density ``Q0(t) s(x)``; the bottom cell accepts
  at most its supply ``Sup(rho[0])`` (``q_max`` while it is below ``rho_c``), so the
  injected flux is ``min(Q0 s, Sup(rho[0]))``. The refused part is reported
  (``requested`` and ``injected`` rates), never lost silently. No diffusive flux.
* top: a free exit into empty material: the outside supplies ``q_max``, so the flux out
  is the top cell's demand ``Dem(rho[-1])``. No diffusive flux (Danckwerts).
* side walls: reflecting (zero flux); cylinders and hoppers: the ring measures and the
  staircase's closed faces of :mod:`spotpde.density._traffic_metric`; open walls are
  solved on a padded window by the
  caller, as for the linear solver.

Mass: ``sum(rho) h**dims`` changes by exactly ``dt * (injected - outflow)`` of each
stage, so the budget ``mass(t) - mass(0) = int injected - int outflow`` holds to
round-off with the integrals accumulated by the same Heun weights.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from numba import njit

from ..errors import NumericalError

LIMITERS = ("mc", "vanleer", "minmod")
_LIMITER_CODE = {"mc": 0, "vanleer": 1, "minmod": 2}
_FLUX_CODE = {"greenshields": 0, "triangular": 1}


@dataclass(frozen=True)
class FluxShape:
    """A concave upward-flux shape ``q = v_s rho_max g(y)``, ``y = rho / rho_max``.

    Attributes:
        name: option value of ``spots.flux``.
        y_c: critical fraction ``rho_c / rho_max`` (the maximum of ``g``).
        slope_max: ``max |g'|`` on ``[0, 1]`` (the largest characteristic speed over v_s).
        speed: the characteristic speed ``c(rho) = q'(rho)`` as a formula.
    """

    name: str
    y_c: float
    slope_max: float
    speed: str
    description: str

    def g(self, y):
        """Normalised flux ``g(y)`` (dimensionless)."""
        if self.name == "greenshields":
            return y * (1.0 - y)
        return np.minimum(y, 1.0 - y)            # triangular

    def dg(self, y):
        """``g'(y)``: the characteristic speed over ``v_s``."""
        if self.name == "greenshields":
            return 1.0 - 2.0 * y
        return np.where(y < 0.5, 1.0, -1.0)

    def m(self, y):
        """Local speed over ``v_s``: ``g(y) / y`` (1 at ``y = 0``)."""
        if self.name == "greenshields":
            return 1.0 - y
        return np.where(y <= 0.5, 1.0, (1.0 - y) / np.maximum(y, 0.5))

    def q(self, rho, v, rho_max):
        """Upward spot flux ``q(rho)`` in spots per d**(dims-1) per unit time."""
        if np.isinf(rho_max):
            return v * rho
        return v * rho_max * self.g(rho / rho_max)

    def c(self, rho, v, rho_max):
        """Characteristic speed ``q'(rho)`` in d per unit time (upward positive)."""
        if np.isinf(rho_max):
            return v * np.ones_like(np.asarray(rho, float))
        return v * self.dg(np.asarray(rho, float) / rho_max)

    def q_max(self, v, rho_max):
        """Capacity ``q(rho_c)``."""
        return v * rho_max * self.g(self.y_c)


FLUXES = {
    "greenshields": FluxShape(
        "greenshields", 0.5, 1.0, "c = v_s (1 - 2 rho / rho_max)",
        "q = v_s rho (1 - rho/rho_max) (Greenshields 1935): rho_c = rho_max/2, "
        "q_max = v_s rho_max / 4"),
    "triangular": FluxShape(
        "triangular", 0.5, 1.0, "c = +v_s for rho < rho_max/2, -v_s above",
        "q = v_s min(rho, rho_max - rho) (Newell-Daganzo triangle, symmetric): free flow at "
        "v_s below rho_c = rho_max/2, q_max = v_s rho_max / 2; waves at +-v_s only"),
}


def flux_from_name(name: str) -> FluxShape:
    """The :class:`FluxShape` called ``name``; ValueError naming ``flux`` and the choices."""
    try:
        return FLUXES[name]
    except (KeyError, TypeError):
        raise ValueError(f"flux: unknown flux shape {name!r}; valid choices: "
                         f"{', '.join(FLUXES)}") from None


def _slopes(rho: np.ndarray, limiter: str) -> np.ndarray:
    """Limited slopes (per cell, in density units) along axis 0; zero in boundary cells."""
    s = np.zeros_like(rho)
    dl = rho[1:-1] - rho[:-2]
    dr = rho[2:] - rho[1:-1]
    same = dl * dr > 0
    a, b = np.abs(dl), np.abs(dr)
    if limiter == "minmod":
        mag = np.minimum(a, b)
    elif limiter == "vanleer":
        mag = 2.0 * a * b / np.where(same, a + b, 1.0)
    else:                                        # mc
        mag = np.minimum(np.minimum(2.0 * a, 2.0 * b), 0.5 * (a + b))
    s[1:-1] = np.where(same, np.sign(dr) * mag, 0.0)
    return s


@njit(cache=True, inline="always")
def _g(y, kind):
    if kind == 0:
        return y * (1.0 - y)
    return min(y, 1.0 - y)


@njit(cache=True, inline="always")
def _q(r, v, rho_max, kind):
    if kind < 0:                                  # rho_max = inf: free flux
        return v * r
    return v * rho_max * _g(r / rho_max, kind)


@njit(cache=True, inline="always")
def _slope(a, b, c, lim):
    dl = b - a
    dr = c - b
    if dl * dr <= 0.0:
        return 0.0
    al, ar = abs(dl), abs(dr)
    if lim == 2:
        mag = min(al, ar)
    elif lim == 1:
        mag = 2.0 * al * ar / (al + ar)
    else:
        mag = min(2.0 * al, 2.0 * ar, 0.5 * (al + ar))
    return mag if dr > 0 else -mag


@njit(cache=True)
def _vertical_flux_kernel(rho, vf, rho_max, y_c, kind, lim, floor_request, F):
    """Fused MUSCL + demand-supply fluxes on ``rho`` of shape ``(nz, n_h)`` into ``F``
    ``(nz + 1, n_h)``; the same arithmetic as :meth:`Solver.vertical_flux_numpy`."""
    nz, nh = rho.shape
    rc = y_c * rho_max
    for j in range(nh):                            # floor: min(request, supply of cell 0)
        r0 = rho[0, j]
        if kind < 0:
            sup = np.inf
        elif r0 <= rc:
            sup = _q(rc, vf[0, j], rho_max, kind)
        else:
            sup = _q(r0, vf[0, j], rho_max, kind)
        F[0, j] = min(floor_request[j], sup)
    s_prev = np.zeros(nh)                          # slopes of row k (zero at boundaries)
    s_next = np.zeros(nh)
    for k in range(nz - 1):
        for j in range(nh):
            s_next[j] = 0.0
            if k + 2 < nz:
                s_next[j] = _slope(rho[k, j], rho[k + 1, j], rho[k + 2, j], lim)
            lo = rho[k, j] + 0.5 * s_prev[j]
            hi = rho[k + 1, j] - 0.5 * s_next[j]
            v = vf[k + 1, j]
            if kind < 0:
                F[k + 1, j] = v * lo
            else:
                dem = _q(min(lo, rc), v, rho_max, kind)
                sup = _q(rc, v, rho_max, kind) if hi <= rc else _q(hi, v, rho_max, kind)
                F[k + 1, j] = min(dem, sup)
        s_prev, s_next = s_next, s_prev
    for j in range(nh):                            # top: demand of the top cell
        rt = rho[nz - 1, j]
        F[nz, j] = _q(rt if kind < 0 else min(rt, rc), vf[nz, j], rho_max, kind)


@njit(cache=True, inline="always")
def _mob(a, b, rho_max, kind, speed):
    if not speed or kind < 0:
        return 1.0
    y = 0.5 * (a + b) / rho_max
    if kind == 0:
        return 1.0 - y
    return 1.0 if y <= 0.5 else (1.0 - y) / y


@njit(cache=True)
def _diffusion_kernel(rho, Dz, Dp, rho_max, kind, speed, h2, out):
    """Add the pairwise diffusive exchanges of :meth:`Solver.rhs` to ``out``; arrays
    ``(nz, ny, nx)`` (``ny = 1`` in 2D)."""
    nz, ny, nx = rho.shape
    for k in range(nz):
        for j in range(ny):
            for i in range(nx):
                r = rho[k, j, i]
                if k + 1 < nz:
                    E = (Dz[k, j, i] * r - Dz[k + 1, j, i] * rho[k + 1, j, i]) \
                        * _mob(r, rho[k + 1, j, i], rho_max, kind, speed) / h2
                    out[k, j, i] -= E
                    out[k + 1, j, i] += E
                if j + 1 < ny:
                    E = (Dp[k, j, i] * r - Dp[k, j + 1, i] * rho[k, j + 1, i]) \
                        * _mob(r, rho[k, j + 1, i], rho_max, kind, speed) / h2
                    out[k, j, i] -= E
                    out[k, j + 1, i] += E
                if i + 1 < nx:
                    E = (Dp[k, j, i] * r - Dp[k, j, i + 1] * rho[k, j, i + 1]) \
                        * _mob(r, rho[k, j, i + 1], rho_max, kind, speed) / h2
                    out[k, j, i] -= E
                    out[k, j, i + 1] += E


class Solver:
    """Right-hand side, boundary fluxes and time step of the nonlinear spot equation.

    Args:
        shape: grid shape ``(nz, [ny,] nx)``.
        h: spacing in d.
        v, D_perp, D_par: drift (d/time, > 0) and diffusivities (d**2/time), floats or
            grid-shaped arrays.
        rho_max: maximum spot density (spots per d**dims), ``np.inf`` for independent spots.
        flux: a :class:`FluxShape`.
        diffusion_scaling: ``"fixed"`` or ``"speed"`` (module docstring).
        limiter: ``"mc"``, ``"vanleer"`` or ``"minmod"``.
        request: ``request(t)`` -> floor array ``(shape[1:])`` of the requested injection
            flux density ``Q0(t) s(x)`` (spots per d**(dims-1) per unit time).
    """

    def __init__(self, shape, h, v, D_perp, D_par, rho_max, flux: FluxShape,
                 diffusion_scaling: str, limiter: str, request: Callable[[float], np.ndarray]):
        if limiter not in LIMITERS:
            raise ValueError(f"limiter: must be one of {', '.join(LIMITERS)}, got {limiter!r}")
        if diffusion_scaling not in ("fixed", "speed"):
            raise ValueError(f"diffusion_scaling: must be 'fixed' or 'speed', got "
                             f"{diffusion_scaling!r}")
        if not rho_max > 0:
            raise ValueError(f"rho_max: must be > 0, got {rho_max!r}")
        self.shape = tuple(shape)
        self.h = float(h)
        full = lambda c: np.broadcast_to(np.asarray(c, dtype=float), self.shape)
        self.v, self.Dp, self.Dz = full(v), full(D_perp), full(D_par)
        self.rho_max = float(rho_max)
        self.flux = flux
        self.scaling = diffusion_scaling
        self.limiter = limiter
        self.request = request
        self.area = self.h ** (len(self.shape) - 1)
        self.vf = np.concatenate([self.v[:1], 0.5 * (self.v[:-1] + self.v[1:]), self.v[-1:]])
        self.backend = "numba"       # or "numpy": the same fluxes, array by array
        self._kind = -1 if np.isinf(self.rho_max) else _FLUX_CODE[flux.name]
        self._shape3 = (self.shape[0], 1, self.shape[1]) if len(self.shape) == 2 else self.shape
        self._Dz3 = np.ascontiguousarray(self.Dz).reshape(self._shape3)
        self._Dp3 = np.ascontiguousarray(self.Dp).reshape(self._shape3)
        self.diffusive = bool(np.any(self.Dp > 0) or np.any(self.Dz > 0))

    # -- fluxes ---------------------------------------------------------------------
    def demand(self, r, v):
        rc = self.flux.y_c * self.rho_max
        return self.flux.q(np.minimum(r, rc), v, self.rho_max)

    def supply(self, r, v):
        rc = self.flux.y_c * self.rho_max
        qmax = self.flux.q_max(v, self.rho_max)
        return np.where(r <= rc, qmax, self.flux.q(np.maximum(r, rc), v, self.rho_max))

    def vertical_flux(self, rho: np.ndarray, t: float) -> np.ndarray:
        """Upward advective flux through the ``nz + 1`` horizontal faces (floor first)."""
        if self.backend == "numpy" or self.shape[0] < 3:
            return self.vertical_flux_numpy(rho, t)
        nz = self.shape[0]
        nh = rho.size // nz
        F = np.empty((nz + 1,) + self.shape[1:])
        request = np.broadcast_to(np.asarray(self.request(t), float), self.shape[1:])
        _vertical_flux_kernel(np.ascontiguousarray(rho).reshape(nz, nh),
                              np.ascontiguousarray(self.vf).reshape(nz + 1, nh),
                              self.rho_max, self.flux.y_c, self._kind,
                              _LIMITER_CODE[self.limiter],
                              np.ascontiguousarray(request).reshape(nh), F.reshape(nz + 1, nh))
        return F

    def vertical_flux_numpy(self, rho: np.ndarray, t: float) -> np.ndarray:
        """:meth:`vertical_flux` in vectorised NumPy (the reference of the numba kernel)."""
        F = np.empty((self.shape[0] + 1,) + self.shape[1:])
        s = _slopes(rho, self.limiter) if self.shape[0] > 2 else np.zeros_like(rho)
        lo = rho[:-1] + 0.5 * s[:-1]
        hi = rho[1:] - 0.5 * s[1:]
        vf = self.vf[1:-1]
        F[1:-1] = np.minimum(self.demand(lo, vf), self.supply(hi, vf))
        F[0] = np.minimum(self.request(t), self.supply(rho[0], self.vf[0]))
        F[-1] = self.demand(rho[-1], self.vf[-1])
        return F

    def _mobility(self, a, b):
        if self.scaling == "fixed" or np.isinf(self.rho_max):
            return 1.0
        return self.flux.m(0.5 * (a + b) / self.rho_max)

    def rhs(self, rho: np.ndarray, t: float):
        """``(d rho/dt, injected, outflow)``: the semi-discrete right-hand side and the
        boundary rates (spots per unit time) it implies."""
        F = self.vertical_flux(rho, t)
        out = -(F[1:] - F[:-1]) / self.h
        if self.diffusive and self.backend == "numba":
            as3 = lambda a: np.ascontiguousarray(a).reshape(self._shape3)
            _diffusion_kernel(as3(rho), self._Dz3, self._Dp3, self.rho_max, self._kind,
                              self.scaling == "speed", self.h * self.h, out.reshape(self._shape3))
        elif self.diffusive:
            h2 = self.h * self.h
            for ax in range(len(self.shape)):
                D = self.Dz if ax == 0 else self.Dp
                n = self.shape[ax]
                if n < 2 or not np.any(D > 0):
                    continue
                Dr = D * rho
                lo = [slice(None)] * rho.ndim
                hi = [slice(None)] * rho.ndim
                lo[ax] = slice(0, n - 1)
                hi[ax] = slice(1, n)
                lo, hi = tuple(lo), tuple(hi)
                # exchange from cell lo to cell hi: -(D rho)_hi + (D rho)_lo, times m
                E = (Dr[lo] - Dr[hi]) * self._mobility(rho[lo], rho[hi]) / h2
                out[lo] -= E
                out[hi] += E
        inj = float(F[0].sum()) * self.area
        outflow = float(F[-1].sum()) * self.area
        return out, inj, outflow

    def mass(self, rho: np.ndarray) -> float:
        """Spots in the silo, ``sum(rho) h**dims``."""
        return rho.sum() * self.h ** len(self.shape)

    def initial(self, rho0):
        """The starting density: ``rho0`` (grid shape) or 0."""
        if rho0 is None:
            return np.zeros(self.shape)
        return np.array(rho0, dtype=float).reshape(self.shape)

    def max_dt(self, cfl: float = 0.9) -> float:
        """Largest stable, bound-preserving step (module docstring)."""
        L = float(np.max(self.v)) * (self.flux.slope_max if np.isfinite(self.rho_max) else 1.0)
        rate = 2.0 * L / self.h
        Dsum = float(np.max(self.Dz)) + (len(self.shape) - 1) * float(np.max(self.Dp))
        rate += 2.0 * Dsum / self.h ** 2
        return cfl / rate


def integrate(solver: Solver, t_end: float, times: np.ndarray, rate: Callable[[float], float],
              rho0: np.ndarray | None = None, cfl: float = 0.9, dt: float | None = None,
              progress: Callable[[float], None] | None = None) -> dict:
    """SSP-RK2 from ``t = 0`` to ``t_end`` in equal steps, frames at ``times``.

    Args:
        solver: the :class:`Solver`.
        t_end: final time (> 0).
        times: sorted frame times in ``[0, t_end]``.
        rate: ``Q0(t)`` (spots per unit time), reported as the requested rate.
        rho0: initial density (default 0: an empty silo).
        cfl: fraction of :meth:`Solver.max_dt` (<= 1 keeps the bounds).
        dt: largest explicit step (default ``solver.max_dt(cfl)``); the step used is
            ``t_end / ceil(t_end / dt)``.
        progress: called with the fraction done.

    Returns:
        dict: ``frames`` ``(len(times),) + shape``; per frame ``injected``, ``requested``
        and ``outflow`` rates (spots per unit time, from the frame's state); running
        totals ``injected_total``, ``requested_total``, ``outflow_total`` (time integrals
        to each frame, Heun weights) and ``mass`` (:meth:`Solver.mass`); ``dt``, ``steps``.
    """
    shape = solver.shape
    if not 0 < cfl <= 1:
        raise ValueError(f"cfl: must be in (0, 1] (bounds and stability), got {cfl!r}")
    dt_max = solver.max_dt(cfl) if dt is None else float(dt)
    if not 0 < dt_max <= solver.max_dt(1.0) * (1 + 1e-12):
        raise ValueError(f"dt: must be in (0, {solver.max_dt(1.0):.6g}], the explicit "
                         f"bound-preserving step, got {dt!r}")
    rho = solver.initial(rho0)
    # a uniform step that does not depend on the frame times: the state at t_end is the
    # same whichever frames are asked for; frames between steps are linear interpolants
    # (second order; convex combinations, so the bounds and the budget hold for them)
    steps = max(1, int(np.ceil(t_end / dt_max - 1e-9)))
    step = t_end / steps
    nf = len(times)
    res = {k: np.empty(nf) for k in ("injected", "requested", "outflow", "injected_total",
                                     "requested_total", "outflow_total", "mass")}
    frames = np.empty((nf,) + shape)
    totals = np.zeros(3)
    every = max(1, steps // 200)
    tol = 1e-12 * max(1.0, t_end)
    j = 0

    def record(t_old, rho_old, tot_old, t_new, rho_new, tot_new):
        nonlocal j
        while j < nf and times[j] <= t_new + tol:
            w = 1.0 if t_new == t_old else min(1.0, max(0.0, (times[j] - t_old) / (t_new - t_old)))
            r = (1.0 - w) * rho_old + w * rho_new
            frames[j] = r
            _, inj, out = solver.rhs(r, times[j])
            res["injected"][j], res["outflow"][j] = inj, out
            res["requested"][j] = rate(times[j])
            tot = (1.0 - w) * tot_old + w * tot_new
            res["injected_total"][j], res["requested_total"][j], res["outflow_total"][j] = tot
            res["mass"][j] = solver.mass(r)
            j += 1

    record(0.0, rho, totals, 0.0, rho, totals)
    for n in range(steps):
        t = n * step
        k1, i1, o1 = solver.rhs(rho, t)
        r1 = rho + step * k1
        k2, i2, o2 = solver.rhs(r1, t + step)
        new = 0.5 * (rho + r1 + step * k2)
        new_totals = totals + 0.5 * step * np.array([i1 + i2, rate(t) + rate(t + step),
                                                     o1 + o2])
        t_new = t_end if n == steps - 1 else (n + 1) * step
        record(t, rho, totals, t_new, new, new_totals)
        rho, totals = new, new_totals
        if (n + 1) % every == 0:
            if not np.all(np.isfinite(rho)):
                raise NumericalError(f"interacting spot density is not finite at t = {t_new:g}")
            if progress is not None:
                progress((n + 1) / steps)
    if not np.all(np.isfinite(frames)):
        raise NumericalError("interacting spot density is not finite")
    if progress is not None:
        progress(1.0)
    return {"frames": frames, "times": np.asarray(times, float), **res, "dt": step,
            "steps": steps}
