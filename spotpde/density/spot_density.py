"""Mean spot density ``rho_s``: steady and transient (docs/conventions.md section 1).

    d rho_s/dt + d/dz (v_s rho_s) = lap_perp (D_perp rho_s) + d2/dz2 (D_par rho_s) + S

Spots enter through the orifice on the floor at ``Q0(t) s(x)`` (:mod:`spotpde.orifice`),
leave through the top, and do not cross reflecting side walls. Which solver runs:

=====================  ===============================  ==================================
case                   method                           error
=====================  ===============================  ==================================
steady, v_s, b, b_par  cosine modes, exact in height    round-off (modes beyond the grid's
uniform (D_par = 0:    (each mode's ODE in z solved     folded in); flux ``Q0`` to
only b uniform)        in closed form, ``_spectral``)   round-off at every height
steady, D_par = 0,     Crank-Nicolson / ADI marching    ``O(h**2)``, flux to round-off
b varying              in height (:mod:`._marching`)
steady, D_par > 0,     finite volumes + sparse LU       ``O(h**2)``, outflow ``Q0`` to
coefficients varying   (:mod:`spotpde.density._elliptic`)       round-off
transient              same finite volumes, BDF2        ``O(h**2 + dt**2)``
                       (:mod:`spotpde.density._transient`)
transient, rho_max     MUSCL + demand-supply Godunov    ``O(h**2)`` smooth, ``O(h)``
(interacting spots)    flux, SSP-RK2 (``traffic``)      L1 at shocks; 0 <= rho <= rho_max
transient,             py-pde adaptive Runge-Kutta on   cross-check; explicit, so small
``method="py-pde"``    the same operator (``_pde``)     grids only
=====================  ===============================  ==================================

Axisymmetric grids (``(z, r)``, ``rho_s`` per unit volume) and hoppers (the staircase
``grid.active``) use finite volumes with the metric (``_geometry``): marching in height
(``_metric_march``: Crank-Nicolson, BDF2 in hoppers) for ``D_par = 0``, sparse LU for
``D_par > 0``, BDF2 in time; ``O(h**2)`` (staircase walls: first order in the wall
position), flux ``Q0`` to round-off (docs/spot_density.md section 9).

Open walls (a window on a wider silo) are solved on a window padded by
``p = 6 sqrt(b_max H)`` on each side (``H`` the height; coefficients extended by
their edge values) with reflecting far walls, then cropped: the far walls' images
change the window by ``exp(-p**2 / (b H)) = exp(-36)`` relative.

Units: ``rho_s`` in spots per d**dims (per d**3 when axisymmetric); ``v_s`` in d per
unit time; ``Q0`` spots per unit time. Derivations and checks: docs/spot_density.md.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from . import _elliptic, _geometry, _marching, _metric_march, _spectral, _transient, traffic
from ._spots import _pad, check_spots, pad_cells
from ..errors import NumericalError
from ..grid import Grid
from .orifice import check_orifice, source_profile
from ..parameters import Orifice, Spots

__all__ = ["steady", "transient", "solve", "check_spots", "pad_cells"]

Progress = Callable[[float], None] | None


def _is_zero(c) -> bool:
    return bool(np.all(np.asarray(c) == 0))


def _is_uniform(c) -> bool:
    return np.ndim(c) == 0 or bool(np.ptp(c) == 0)


def _constant_rate(orifice: Orifice) -> float:
    if callable(orifice.rate):
        raise ValueError("orifice.rate: a steady solve needs a constant rate Q0, got a function of time")
    return float(orifice.rate)


# -- steady --------------------------------------------------------------------------------
def steady(grid: Grid, orifice: Orifice, spots: Spots, progress: Progress = None) -> np.ndarray:
    """Steady mean spot density.

    ``D_par = 0``: ``d(v_s rho_s)/dz = lap_perp(b v_s rho_s)`` marched in height from
    ``v_s rho_s = Q0 s(x)`` on the floor. ``D_par > 0``: the elliptic problem
    ``div J = 0`` with inflow ``Q0 s`` through the orifice, no flux through walls and the
    rest of the floor, advective (Danckwerts) outflow at the top. Uniform coefficients
    (for ``D_par = 0`` only ``b`` need be uniform) are solved exactly in height mode by
    mode (``_spectral``); otherwise by marching (``D_par = 0``) or finite volumes.
    Between reflecting walls ``v_s * sum(rho_s) * h**(dims-1) = Q0`` at every height
    to round-off for ``D_par = 0`` and for uniform coefficients, and the outflow through
    the top equals ``Q0`` to round-off in the finite-volume case.

    Args:
        grid: the grid (walls reflecting or open).
        orifice: the source; its rate must be a constant Q0 (spots per unit time).
        spots: ``v_s`` (d / time), ``b`` and ``b_par`` (d): floats or grid-shaped arrays.
        progress: called with the fraction done.

    Axisymmetric grids and hoppers (docs/spot_density.md section 9): finite volumes with
    the metric on the staircase ``grid.active``, marching for ``D_par = 0`` (any ``b``),
    sparse LU for ``D_par > 0``; ``v_s * sum(rho_s * grid.horizontal_measures) = Q0`` at
    every height to round-off for ``D_par = 0``, the top outflow ``Q0`` for ``D_par > 0``.

    Returns:
        ``rho_s``, grid shape, spots per d**dims: at each cell-centre height, the
        average over each cell's horizontal extent (exact for uniform ``b``; finite-volume
        cell values otherwise). Axisymmetric: ``(z, r)``, spots per d**3; hoppers: 0 on
        inactive cells.
    """
    check_spots(grid, spots)
    check_orifice(grid, orifice)
    if spots.rho_max is not None:
        raise ValueError('spots.rho_max: interacting spots have no steady solver; use '
                        'spots.mode = "transient" (spotpde.traffic)')
    Q0 = _constant_rate(orifice)
    if not grid.geometry.uniform_cells:   # rings or a staircase: the metric operator
        return _steady_geometry(grid, orifice, spots, Q0, progress)
    g, (v, b, b_par), crop = _pad(grid, spots)
    if _is_uniform(b) and _is_uniform(b_par) and (_is_zero(b_par) or _is_uniform(v)):
        phi = _spectral.steady_flux(g, orifice, float(np.ravel(b)[0]), Q0, float(np.ravel(b_par)[0]))
        rho = np.divide(phi, v, out=phi)     # phi is ours: divided in place
    elif _is_zero(b_par):
        bb = np.broadcast_to(np.asarray(b, dtype=float), g.shape)
        phi = _marching.march(Q0 * source_profile(g, orifice), bb, g.spacing, progress)
        rho = phi / v
    else:
        q = _elliptic.floor_source(g.shape, g.spacing, Q0 * source_profile(g, orifice))
        rho = _elliptic.solve_steady(g.shape, g.spacing, v, b * v, b_par * v, q)
    if progress is not None:
        progress(1.0)
    return crop(rho)


# -- transient -------------------------------------------------------------------------------
TRANSIENT_METHODS = ("bdf2", "py-pde")


def transient(grid: Grid, orifice: Orifice, spots: Spots, t_end: float, times=None,
              progress: Progress = None, dt: float | None = None, rho0: np.ndarray | None = None,
              full_output: bool = False, method: str = "bdf2"):
    """Time-dependent mean spot density from an empty silo (or ``rho0``) at ``t = 0``.

    Solves the spot Fokker-Planck equation with anisotropic, spatially varying
    coefficients and the time-varying floor inflow ``Q0(t) s(x)`` by BDF2 on the
    conservative finite volumes of ``_elliptic`` (``_transient``). With a constant
    ``Q0`` it tends to :func:`steady` (exactly the same discrete operator when
    ``D_par > 0``; within ``O(h**2)`` of the marching solution when ``D_par = 0``).

    Args:
        grid: the grid.
        orifice: the source; ``rate`` a constant or a callable ``Q0(t)``.
        spots: coefficients as for :func:`steady`.
        t_end: final time (> 0), case time unit.
        times: optional frame times in ``[0, t_end]``.
        progress: called with the fraction done.
        dt: time step (default ``h / max(v_s)``, at least 20 steps).
        rho0: initial density (grid shape), default 0.
        full_output: return the diagnostics dict instead of the density.
        method: ``"bdf2"`` (default: implicit, factorised, :mod:`._transient`) or
            ``"py-pde"`` (py-pde's adaptive explicit Runge-Kutta on the same operator,
            :mod:`._pde`; small grids only, a cross-check; ``dt`` is ignored). On
            axisymmetric and hopper grids both run on the metric / staircase operator
            (``_geometry``); interacting spots (``rho_max``) use the same measures
            and staircase (``_traffic_metric``).

    Returns:
        ``times is None``: ``rho_s`` at ``t_end`` (grid shape). Otherwise an array
        ``(len(times),) + grid.shape`` of frames. With ``full_output``: a dict with
        ``times``, ``frames``, ``outflow`` and ``inflow`` (spots per unit time through
        the top and the orifice at each frame), ``dt`` and ``steps``.
    """
    check_spots(grid, spots)
    check_orifice(grid, orifice)
    if not (np.isfinite(t_end) and t_end > 0):
        raise ValueError(f"spots.t_end: must be > 0 for a transient run, got {t_end!r}")
    if spots.rho_max is not None:          # interacting spots: the nonlinear solver
        res = traffic.transient(grid, orifice, spots, t_end, times, rho0=rho0, dt=dt,
                                progress=progress, full_output=full_output)
        return {**res, "inflow": res["injected"]} if full_output else res
    frame_times = np.array([t_end], float) if times is None else np.sort(np.asarray(times, float))
    if frame_times.size and (frame_times[0] < 0 or frame_times[-1] > t_end * (1 + 1e-12)):
        raise ValueError(f"spots.t_end: frame times must lie in [0, {t_end}]")
    if not grid.geometry.uniform_cells:   # rings or a staircase: the metric operator
        return _transient_geometry(grid, orifice, spots, t_end, frame_times, times is None,
                                   progress, dt, rho0, full_output, method)
    g, (v, b, b_par), crop = _pad(grid, spots)
    base = _elliptic.floor_source(g.shape, g.spacing, source_profile(g, orifice))
    if rho0 is not None and g.shape != grid.shape:
        p = pad_cells(grid, spots.b)
        widths = [(0, 0)] + [(p, p)] * (grid.dims - 1)
        rho0 = np.pad(np.asarray(rho0, float), widths, mode="constant")

    def q(t):
        return orifice.rate_at(t) * base

    if method == "bdf2":
        res = _transient.integrate(g.shape, g.spacing, v, b * v, b_par * v, q, t_end, frame_times,
                                   dt=dt, rho0=rho0, progress=progress)
    elif method == "py-pde":
        from . import _pde
        fr = _pde.integrate(g, v, b * v, b_par * v, base, orifice.rate, t_end, frame_times,
                            rho0=rho0, progress=progress)
        _, out_row = _elliptic.assemble(g.shape, g.spacing, v, b * v, b_par * v)
        res = {"frames": fr, "outflow": np.array([(out_row @ f.ravel())[0] for f in fr]),
               "inflow": np.array([orifice.rate_at(t) for t in frame_times]),
               "dt": None, "steps": None}
    else:
        raise ValueError(f"spots.method: must be one of {', '.join(map(repr, TRANSIENT_METHODS))}, "
                        f"got {method!r}")
    frames = crop(res["frames"])
    if full_output:
        return {**res, "frames": frames, "times": frame_times}
    return frames[-1] if times is None else frames


# -- axisymmetric grids and hoppers (docs/spot_density.md section 9) ------------------------
def _pad_geometry(grid: Grid, spots: Spots):
    p = pad_cells(grid, spots.b)
    g, coeffs, crop = _geometry.pad(grid, p, [spots.drift, spots.b, spots.b_par])
    return g, coeffs, crop, p


def _steady_geometry(grid, orifice, spots, Q0, progress):
    """Steady ``rho_s`` on a metric / staircase grid: marching (``D_par = 0``) or FV + LU."""
    g, (v, b, b_par), crop, _ = _pad_geometry(grid, spots)
    flux_floor = Q0 * source_profile(g, orifice)
    m, w, _, active = _geometry.metric(g)
    if _is_zero(b_par):
        bb = np.broadcast_to(np.asarray(b, dtype=float), g.shape)
        scheme = "bdf2" if g.geometry.masked else "cn"   # BDF2: L-stable where cells join
        rho = _metric_march.march(flux_floor, bb, g.spacing, m, w, active, progress, scheme) / v
    else:
        A, _ = _geometry.assemble(g, v, b * v, b_par * v)
        q = _elliptic.floor_source(g.shape, g.spacing, flux_floor)
        rho = _elliptic.factorize(A, 2)(-q).reshape(g.shape)
        if not np.all(np.isfinite(rho)):
            raise NumericalError("spot density: the steady solve produced non-finite values")
    if progress is not None:
        progress(1.0)
    return crop(np.where(active, rho, 0.0))


def _transient_geometry(grid, orifice, spots, t_end, frame_times, last_only, progress, dt,
                        rho0, full_output, method):
    """BDF2 (or py-pde's RK) on the metric / staircase finite volumes (``_geometry.assemble``)."""
    if method not in TRANSIENT_METHODS:
        raise ValueError(f"spots.method: must be one of {', '.join(map(repr, TRANSIENT_METHODS))}, "
                         f"got {method!r}")
    g, (v, b, b_par), crop, p = _pad_geometry(grid, spots)
    base = _elliptic.floor_source(g.shape, g.spacing, source_profile(g, orifice))
    if rho0 is not None and g.shape != grid.shape:
        rho0 = np.pad(np.asarray(rho0, float), [(0, 0), grid.geometry.padding(p)], mode="constant")
    operator = _geometry.assemble(g, v, b * v, b_par * v)
    if method == "py-pde":
        from . import _pde
        fr = _pde.integrate(g, v, b * v, b_par * v, base, orifice.rate, t_end, frame_times,
                            rho0=rho0, progress=progress)
        res = {"frames": fr, "outflow": np.array([(operator[1] @ f.ravel())[0] for f in fr]),
               "inflow": np.array([orifice.rate_at(t) for t in frame_times]),
               "dt": None, "steps": None}
    else:
        volumes = np.broadcast_to(g.cell_volumes, g.shape).ravel()
        res = _transient.integrate(g.shape, g.spacing, v, b * v, b_par * v,
                                   lambda t: orifice.rate_at(t) * base, t_end, frame_times,
                                   dt=dt, rho0=rho0, progress=progress, operator=operator,
                                   volumes=volumes)
    frames = crop(res["frames"])
    if full_output:
        return {**res, "frames": frames, "times": frame_times}
    return frames[-1] if last_only else frames


def solve(grid: Grid, orifice: Orifice, spots: Spots, progress: Progress = None) -> np.ndarray:
    """Dispatch on ``spots.mode``: :func:`steady`, or :func:`transient` to ``spots.t_end``.

    Returns:
        ``rho_s`` (grid shape, spots per d**dims): steady, or at ``t = spots.t_end``.
    """
    check_spots(grid, spots)
    if spots.mode == "steady":
        return steady(grid, orifice, spots, progress)
    return transient(grid, orifice, spots, spots.t_end, progress=progress)
