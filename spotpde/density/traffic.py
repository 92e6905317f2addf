"""Interacting spots: kinematic density waves, shocks and saturation (``[spots] rho_max``).

The paper's section *Spot Interactions and Density Waves* replaces the free upward flux
``v_s rho`` of independent spots by a concave flux-density relation, as in traffic flow:

    d rho_s/dt + d/dz q(rho_s) = lap_perp (m D_perp rho_s) + d/dz (m d/dz (D_par rho_s)) + S,
    q(rho) = rho v_s (1 - rho / rho_max)          (spots.flux = "greenshields", default)

with ``rho_c = rho_max / 2``, capacity ``q_max = v_s rho_max / 4`` and characteristic speed
``c(rho) = q'(rho) = v_s (1 - 2 rho / rho_max)``: upward below ``rho_c``, downward above.
``c`` obeys Burgers' equation ``c_t + c c_z = D_par c_zz`` (uniform ``v_s``, ``D_par``,
``diffusion_scaling = "fixed"``), so Cole-Hopf gives exact viscous solutions
(:func:`viscous_shock`, :func:`n_wave`). ``spots.flux = "triangular"``:
``q = v_s min(rho, rho_max - rho)``, waves at ``+v_s`` below ``rho_c`` and ``-v_s`` above.

``m`` is 1 for ``spots.diffusion_scaling = "fixed"`` (default: ``D_s = b v_s`` whatever
the crowding) and ``m = q / (v_s rho)`` for ``"speed"`` (constant ``b``: the spots'
diffusivity follows their local speed ``q / rho``). Numerics: :mod:`spotpde.density._traffic`
(MUSCL + demand-supply Godunov flux + SSP-RK2, explicit). Units: ``rho`` spots per
d**dims, ``v_s`` d per unit time, ``q`` spots per d**(dims-1) per unit time.

The orifice injects ``min(Q0(t) s(x), Sup(rho_bottom))`` (the bottom cell's supply); the
refused part is reported. Only transient runs: a steady case with ``rho_max`` is a
:class:`~spotpde.CaseError` (docs/interacting_spots.md). Cylinders and hoppers: the same
law on the geometry's ring volumes, face areas and staircase
(:mod:`spotpde.density._traffic_metric`); ``rho`` is then per d**3 on rings.

``free_volume``: the free-volume fraction a particle at ``r`` sees,
``phi_f(r) = (w * rho_s)(r) = integral w(r - r_s) rho_s(r_s) dr_s`` (the kernel ``w`` is
the fraction of a particle's volume a spot displaces; convolution over the silo only,
zero padding), dimensionless; ``-> V1 rho_s`` where ``rho_s`` varies slowly.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from . import _geometry, _traffic, _traffic_metric
from ._spots import _pad, check_spots, pad_cells
from ._traffic import FLUXES, FluxShape, flux_from_name
from .._figures import figure_format, prepare_matplotlib, save_figure
from ..fields import _rings
from ..fields.convolution import convolve
from ..grid import Grid
from .orifice import check_orifice, source_profile
from ..parameters import Orifice, Spots

__all__ = ["FLUXES", "FluxShape", "flux_from_name", "transient", "free_volume",
           "riemann", "viscous_shock", "n_wave", "solve_case", "add_outputs",
           "space_time", "plot_space_time", "DIFFUSION_SCALINGS"]

DIFFUSION_SCALINGS = ("fixed", "speed")


# -- the solver on a grid ------------------------------------------------------------------
def transient(grid: Grid, orifice: Orifice, spots: Spots, t_end: float, times=None, *,
              rho0: np.ndarray | None = None, cfl: float = 0.9, limiter: str = "mc",
              dt: float | None = None, progress=None, full_output: bool = False):
    """Time-dependent interacting spot density from an empty silo (or ``rho0``).

    Args:
        grid: the grid: a box, a cylinder (rings, ``rho`` per d**3) or a hopper (the
            staircase); reflecting walls, open walls solved on a padded window.
        orifice: the source; ``rate`` a constant or a callable ``Q0(t)`` (spots/time).
        spots: ``drift`` v_s, ``b``, ``b_par`` (floats or grid arrays), ``rho_max`` (> 0,
            spots per d**dims; ``None`` or ``inf``: independent spots), ``flux``,
            ``diffusion_scaling``.
        t_end: final time (> 0).
        times: frame times in ``[0, t_end]`` (default: ``t_end`` only).
        rho0: initial density (grid shape), default 0.
        cfl: fraction of the bound-preserving explicit step (<= 1).
        limiter: MUSCL slope limiter, ``"mc"``, ``"vanleer"`` or ``"minmod"``.
        dt: fixed step instead of the automatic one.
        progress: called with the fraction done.
        full_output: return the diagnostics dict of :func:`spotpde.density._traffic.integrate`
            (``frames``, ``times``, per-frame ``injected``/``requested``/``outflow`` rates,
            their running time integrals, ``mass``, ``dt``, ``steps``).

    Returns:
        ``rho_s`` at ``t_end`` (``times`` None), frames ``(len(times),) + grid.shape``,
        or the dict.
    """
    if not (np.isfinite(t_end) and t_end > 0):
        raise ValueError(f"t_end: must be > 0, got {t_end!r}")
    rho_max = np.inf if spots.rho_max is None else float(spots.rho_max)
    if not rho_max > 0:
        raise ValueError(f"spots.rho_max: must be > 0, got {spots.rho_max!r}")
    flux = flux_from_name(spots.flux)
    if spots.diffusion_scaling not in DIFFUSION_SCALINGS:
        raise ValueError(f"spots.diffusion_scaling: must be one of {DIFFUSION_SCALINGS}, "
                         f"got {spots.diffusion_scaling!r}")
    check_spots(grid, spots)
    check_orifice(grid, orifice)
    frame_times = np.array([t_end], float) if times is None else np.sort(np.asarray(times, float))
    if frame_times.size and (frame_times[0] < 0 or frame_times[-1] > t_end * (1 + 1e-12)):
        raise ValueError(f"times: must lie in [0, {t_end}]")
    if not grid.geometry.uniform_cells:     # rings or a staircase: measures and walls
        return _metric_transient(grid, orifice, spots, t_end, frame_times, times is None,
                                 rho0, rho_max, flux, cfl, limiter, dt, progress, full_output)
    g, (v, b, b_par), crop = _pad(grid, spots)
    profile = source_profile(g, orifice)
    if rho0 is not None and g.shape != grid.shape:
        p = pad_cells(grid, spots.b)
        rho0 = np.pad(np.asarray(rho0, float), [(0, 0)] + [(p, p)] * (grid.dims - 1))
    solver = _traffic.Solver(g.shape, g.spacing, v, b * v, b_par * v, rho_max, flux,
                             spots.diffusion_scaling, limiter,
                             lambda t: orifice.rate_at(t) * profile)
    res = _traffic.integrate(solver, t_end, frame_times, orifice.rate_at, rho0=rho0, cfl=cfl,
                             dt=dt, progress=progress)
    res["frames"] = crop(res["frames"])
    if full_output:
        return res
    return res["frames"][-1] if times is None else res["frames"]


def _metric_transient(grid, orifice, spots, t_end, frame_times, last_only, rho0, rho_max,
                      flux, cfl, limiter, dt, progress, full_output):
    """:func:`transient` on a grid with ring cells or a staircase (``_traffic_metric``):
    the window padded outward from a symmetry axis, the hopper kept."""
    p = pad_cells(grid, spots.b)
    g, (v, b, b_par), crop = _geometry.pad(grid, p, [spots.drift, spots.b, spots.b_par])
    profile = source_profile(g, orifice)
    if rho0 is not None and g.shape != grid.shape:
        rho0 = np.pad(np.asarray(rho0, float), [(0, 0), grid.geometry.padding(p)])
    solver = _traffic_metric.MetricSolver(g, v, b * v, b_par * v, rho_max, flux,
                                          spots.diffusion_scaling, limiter,
                                          lambda t: orifice.rate_at(t) * profile)
    res = _traffic.integrate(solver, t_end, frame_times, orifice.rate_at, rho0=rho0, cfl=cfl,
                             dt=dt, progress=progress)
    res["frames"] = crop(res["frames"])
    if full_output:
        return res
    return res["frames"][-1] if last_only else res["frames"]


def free_volume(grid: Grid, rho_s: np.ndarray, kernel) -> np.ndarray:
    """Free-volume fraction a particle sees, ``(w * rho_s)(r)`` (dimensionless).

    ``h**dims * convolve(rho_s, kernel.sample(h))``, zero padding (spots outside the
    silo do not exist); frames ``(nt,) + grid.shape`` are convolved frame by frame.
    Ring cells (``grid.geometry.curved``): the 3D convolution by the ``m = 0``
    ring-integrated weights of :mod:`spotpde.fields._rings` (``kernel`` 3D, ``rho_s`` per
    d**3). Inactive hopper cells hold no spots (``rho_s = 0`` there).

    Args:
        grid: the grid.
        rho_s: spot density (spots per d**dims), grid shape or frames.
        kernel: a :mod:`spotpde.kernels` kernel (``w`` dimensionless).
    """

    rho = np.asarray(rho_s, dtype=float)
    if rho.shape != grid.shape and rho.shape[1:] != grid.shape:
        raise ValueError(f"rho_s: must have the grid shape {grid.shape} (or frames of it), "
                         f"got {rho.shape}")
    if grid.geometry.curved:
        W = _rings.ring_weights(kernel, grid.spacing, grid.nx, 1, 0)
        frames = rho.reshape((-1,) + grid.shape)
        return np.stack(_rings.ring_convolve(list(frames), W)).reshape(rho.shape)
    stencil = kernel.sample(grid.spacing) * grid.cell_volume
    if rho.shape == grid.shape:
        return convolve(rho, stencil)
    return np.stack([convolve(r, stencil) for r in rho])


# -- exact solutions (Greenshields) ------------------------------------------------------
def riemann(rho_L: float, rho_R: float, z, t: float, v_s: float = 1.0, rho_max: float = 1.0):
    """Entropy solution of the Greenshields Riemann problem, jump at ``z = 0``, ``t > 0``.

    ``rho_L`` below, ``rho_R`` above. ``rho_L < rho_R``: a shock at
    ``s = v_s (1 - (rho_L + rho_R) / rho_max)``. ``rho_L > rho_R``: a fan
    ``c(rho) = z / t``, i.e. ``rho = (rho_max / 2) (1 - z / (v_s t))`` between
    ``c(rho_L) t`` and ``c(rho_R) t``.
    """
    z = np.asarray(z, dtype=float)
    if rho_L < rho_R:
        s = v_s * (1.0 - (rho_L + rho_R) / rho_max)
        return np.where(z < s * t, rho_L, rho_R)
    fan = 0.5 * rho_max * (1.0 - z / (v_s * t))
    return np.clip(fan, rho_R, rho_L)


def viscous_shock(z, t: float, rho_L: float, rho_R: float, D: float, v_s: float = 1.0,
                  rho_max: float = 1.0, z0: float = 0.0):
    """Cole-Hopf travelling viscous shock (``rho_L < rho_R``, uniform ``D = D_par``).

    ``rho = (rho_L + rho_R)/2 + (Delta/2) tanh((z - z0 - s t) / delta)``, ``Delta =
    rho_R - rho_L``, width ``delta = 2 D rho_max / (v_s Delta)``, speed ``s`` as for the
    inviscid shock.
    """
    z = np.asarray(z, dtype=float)
    d = rho_R - rho_L
    s = v_s * (1.0 - (rho_L + rho_R) / rho_max)
    width = 2.0 * D * rho_max / (v_s * d)
    return 0.5 * (rho_L + rho_R) + 0.5 * d * np.tanh((z - z0 - s * t) / width)


def n_wave(z, t: float, rho0: float, A: float, D: float, v_s: float = 1.0,
           rho_max: float = 1.0, z0: float = 0.0):
    """Exact viscous N-wave on a background ``rho0`` (Cole-Hopf; Whitham 1974, sec. 4.5).

    In the frame moving at ``c0 = c(rho0)`` with ``x = z - z0 - c0 t``, the Burgers
    variable ``u = c(rho) - c0`` is ``u = (x/t) R / (1 + R)``, ``R = A t**-1/2
    exp(-x**2 / (4 D t))``, ``A > 0`` (heat-equation solution ``1 + R``). For
    ``A >> sqrt(D)`` it is the inviscid N-wave ``u = x/t`` on ``|x| < sqrt(4 D t ln(A
    / sqrt t))`` and its amplitude decays like ``t**-1/2`` (up to the slowly varying
    log). Returns ``rho = rho0 - rho_max u / (2 v_s)``.
    """
    z = np.asarray(z, dtype=float)
    c0 = v_s * (1.0 - 2.0 * rho0 / rho_max)
    x = z - z0 - c0 * t
    R = A / np.sqrt(t) * np.exp(-x * x / (4.0 * D * t))
    u = (x / t) * R / (1.0 + R)
    return rho0 - rho_max * u / (2.0 * v_s)


# -- pipeline ----------------------------------------------------------------------------
@dataclasses.dataclass
class CaseResult:
    """Outputs of an interacting-spot case: final density and space-time frames."""

    rho_s: np.ndarray
    times: np.ndarray
    frames: np.ndarray
    diagnostics: dict


def solve_case(case, progress=None) -> CaseResult:
    """Run the interacting-spot solver of a case to ``spots.t_end``.

    Frames: ``spots.frames`` equally spaced times on ``[0, spots.t_end]`` (default 101).
    """
    t_end = float(case.spots.t_end)
    n = case.spots.frames
    times = np.linspace(0.0, t_end, int(n))
    res = transient(case.grid, case.orifice, case.spots, t_end, times, progress=progress,
                    full_output=True)
    return CaseResult(rho_s=res["frames"][-1], times=times, frames=res["frames"], diagnostics=res)


def add_outputs(ds, case, result: CaseResult):
    """Add the interacting-spot variables to a result Dataset (returns it).

    Variables: ``free_volume`` (grid dims, at ``spots.t_end``), ``rho_s_t`` and
    ``free_volume_t`` (``("t_s", *axes)``: space-time frames), ``injected_rate``,
    ``requested_rate``, ``spot_outflow`` and ``spot_mass`` (``("t_s",)``); coordinate
    ``t_s``; attributes ``rho_max``, ``flux``, ``diffusion_scaling``, ``q_max_total``
    (the capacity times the orifice's floor area is not defined for a point source, so
    this is the capacity per unit floor area ``q_max``), the time-integrated
    ``injected_total``, ``requested_total``, ``outflow_total`` and ``mass_budget_error``.
    """
    grid = case.grid
    axes = grid.axes
    kernel = case.kernel
    res = result.diagnostics
    fv = free_volume(grid, result.frames, kernel)
    dims = grid.dims
    ds = ds.assign_coords(t_s=("t_s", result.times, {"units": "t", "long_name":
                                                     "time of the spot-density frames"}))
    ds["free_volume"] = (axes, fv[-1], {
        "units": "1", "long_name": "free-volume fraction seen by particles, w * rho_s "
        "(kernel convolved with the spot density)"})
    ds["rho_s_t"] = (("t_s", *axes), result.frames, {
        "units": f"d-{dims}", "long_name": "interacting spot density at the frame times"})
    ds["free_volume_t"] = (("t_s", *axes), fv, {
        "units": "1", "long_name": "free-volume fraction w * rho_s at the frame times"})
    for name, key, long in (
            ("injected_rate", "injected", "spots injected through the orifice per unit time"),
            ("requested_rate", "requested", "orifice rate Q0(t) asked for (with noise)"),
            ("spot_outflow", "outflow", "spots leaving through the top per unit time")):
        ds[name] = (("t_s",), res[key], {"units": "t-1", "long_name": long})
    ds["spot_mass"] = (("t_s",), res["mass"], {"units": "1",
                                               "long_name": "number of spots in the silo"})
    s = case.spots
    flux = flux_from_name(s.flux)
    budget = res["mass"][-1] - res["mass"][0] - (res["injected_total"][-1]
                                                 - res["outflow_total"][-1])
    ds.attrs.update({
        "rho_max": float(s.rho_max), "v_s": float(np.max(s.drift)), "flux": s.flux, "diffusion_scaling": s.diffusion_scaling,
        "q_max": float(flux.q_max(float(np.max(s.drift)), float(s.rho_max))),
        "injected_total": float(res["injected_total"][-1]),
        "requested_total": float(res["requested_total"][-1]),
        "outflow_total": float(res["outflow_total"][-1]),
        "mass_budget_error": float(budget),
    })
    return ds


# -- space-time diagrams -------------------------------------------------------------------
def space_time(ds, variable: str = "free_volume_t", x: float | None = None,
               z: float | None = None):
    """A space-time slice of a frame variable.

    Default: ``(t_s, z)`` along the vertical line at ``x`` (3D: and the middle of ``y``),
    ``x`` defaulting to the middle of the domain (the axis). With ``z``: ``(t_s, x)``
    across the silo at the height nearest ``z`` (3D: the middle of ``y``). Axisymmetric
    results (dimension ``r``): ``x`` is the radius, default the axis ``r = 0``.
    """
    if variable not in ds:
        raise ValueError(f"variable: {variable!r} is not in the Dataset (an interacting-spot "
                         "run has rho_s_t and free_volume_t)")
    da = ds[variable]
    if z is not None:
        da = da.sel(z=float(z), method="nearest")
        if "y" in da.dims:
            da = da.isel(y=da.sizes["y"] // 2)
        return da
    across = "r" if "r" in da.dims else "x"
    xs = ds[across].values
    x0 = (0.0 if across == "r" else 0.5 * (xs[0] + xs[-1])) if x is None else float(x)
    da = da.sel({across: x0}, method="nearest")
    if "y" in da.dims:
        da = da.isel(y=da.sizes["y"] // 2)
    return da


def plot_space_time(ds, variable: str = "free_volume_t", x: float | None = None, ax=None,
                    path=None, characteristics: bool = False):
    """Space-time diagram (time across, height up) of ``variable`` along the axis.

    With ``characteristics``, dashed lines of slope ``c(rho) = q'(rho)`` (the run's flux
    shape, ``_traffic.FluxShape.c``, at the drift ``v_s`` attribute) for the space-time mean
    density of the later half of the run mark the speed of small waves: meaningful only
    for a nearly uniform column.
    Returns the matplotlib Figure; ``path`` also saves it (the format of its extension,
    written atomically: :func:`spotpde._figures.save_figure`).
    """

    if path is not None:
        figure_format(path)          # an unsupported extension: refused before drawing
    prepare_matplotlib()
    import matplotlib
    if ax is None:
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    da = space_time(ds, variable, x)
    fig = ax.figure if ax is not None else plt.figure(figsize=(7, 4)).gca().figure
    ax = ax if ax is not None else fig.axes[0]
    t, z = da["t_s"].values, da["z"].values
    m = ax.pcolormesh(t, z, da.values.T, shading="auto", cmap="viridis")
    fig.colorbar(m, ax=ax, label=f"{variable} ({da.attrs.get('units', '?')})")
    if characteristics and "rho_max" in ds.attrs:
        rho = space_time(ds, "rho_s_t", x).values
        late = rho[len(rho) // 2:]
        rho0 = float(np.mean(late))
        flux = _traffic.flux_from_name(ds.attrs.get("flux", "greenshields"))
        c0 = float(flux.c(rho0, float(ds.attrs.get("v_s", 1.0)), float(ds.attrs["rho_max"])))
        for z0 in np.linspace(z[0], z[-1], 5):
            ax.plot(t, z0 + c0 * (t - t[len(t) // 2]), "w--", lw=0.7)
        ax.set_title(f"{variable}: dashed lines at c(rho) = {c0:.3g} d/t (mean rho)")
    ax.set_xlabel("t")
    ax.set_ylabel("z (d)")
    ax.set_ylim(z[0], z[-1])
    if path is not None:
        save_figure(fig, path, dpi=110, bbox_inches="tight")
    return fig
