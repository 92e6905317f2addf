"""Monte Carlo of the discrete spot model (eq. discrete of Bazant 2004), the reference
against which every continuum prediction of spotpde is checked.

Model (2D, ``(x, z)``, lengths in d; derivations and checks in ``docs/montecarlo.md``):

* Spots are injected on the floor ``z = z0`` as a Poisson process of rate ``Q0`` (at
  the orifice profile: point, uniform slot, Gaussian) and make directed random walks
  upward. Time advances in ticks ``dt = Delta / v_s``; in each tick every active spot
  makes one step ``dR = (dx, Delta [+ sqrt(2 b_par Delta) eta])``. The horizontal step is
  ``sqrt(2 b0 Delta) xi_n`` with a unit-variance step variable ``xi_n`` of
  autocorrelation ``gamma**k`` (Gaussian AR(1) or a persistent +-1 walk), so that the
  long-distance diffusion length is ``b = b0 (1 + gamma) / (1 - gamma)`` (eq. bper);
  callers give ``b`` (the continuum's ``spots.b``) and ``b0`` follows.
* Spots leave through the top ``z >= z1``; reflecting side walls mirror them (and turn
  their persistent direction around), ``"open"`` walls remove them; the floor reflects
  vertical noise.
* At every spot step each particle within reach moves by
  ``-w(r_p - r_s - lam dR) dR`` (``lam`` = ``rule``: 1 the printed eq. discrete, 1/2 the
  midpoint rule). Particles leaving through the floor have left through the orifice.
  Particles are found through a cell list (cells of the kernel reach plus a skin,
  rebuilt only when some particle may have left its cell), so a spot step costs
  O(particles within reach).
* Frozen probes at the grid's cell centres accumulate the same displacements without
  moving: their time averages are the mean-field drift ``u_p`` and diffusivity ``D_p``
  exactly as the continuum defines them (mean over spots at a fixed point).

This module: :func:`simulate` (or :func:`from_case`, a case file's parameters) ->
:class:`MCResult`; :func:`kernel_params` reduces a kernel to :class:`KernelParams`.
Beside it: ``_mc_kernels`` (the numba loop), ``_particles`` (particle sets),
``_measure`` (fields and Lagrangian statistics of a result), ``_predict`` (free spot
walks and the uniform-flow prediction beyond mean field).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from . import _mc_kernels as K
from ._mc3d import kernel_eval3
from ..fields._walls import coverage_table
from ..grid import Grid
from ..parameters import Orifice, Spots
from ._particles import blob, lattice, random_packing, tracking
from ._relax import Relax, particle_diameters, relax_params
from ._geometry import geometry_particles, runs_in_geometry, simulate_geometry
from ._settings import case_settings
from ._result import STEPS, MCResult
from ._simulate3d import case_particles3d, run3d

__all__ = ["STEPS", "CUTOFF", "KernelParams", "MCResult", "simulate", "from_case",
           "kernel_params", "kernel_evaluate"]


# ---------------------------------------------------------------------------------------
# Kernels as numba parameters
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class KernelParams:
    """A kernel reduced to what the numba loop evaluates.

    Attributes:
        shape: 0 uniform, 1 gaussian, 2 exponential (``_mc_kernels.SHAPE_*``).
        size: horizontal size (radius R, sigma or decay length) in d.
        size_v: vertical size ``size / aspect`` in d.
        amp: ``w`` at the centre (dimensionless).
        reach: ``(horizontal, vertical)`` cut-off half-axes in d.
        V1, V2: the kernel's ``integral w`` and ``integral w**2`` in d**dims.
        dims: 2, or 3 for a 3D kernel (horizontal size along ``x`` and ``y``).
    """

    shape: int
    size: float
    size_v: float
    amp: float
    reach: tuple[float, float]
    V1: float
    V2: float
    dims: int = 2


_SHAPE_CODES = {"uniform": K.SHAPE_UNIFORM, "gaussian": K.SHAPE_GAUSSIAN,
                "exponential": K.SHAPE_EXPONENTIAL}

#: default relative cut-off of the smooth kernels in the Monte Carlo: ``w`` is set to 0
#: where it is below ``CUTOFF * w(0)``. The lost fraction of ``V1`` is ``CUTOFF`` (Gaussian)
#: or ``(1 - ln CUTOFF) * CUTOFF`` (exponential), in 2D.
CUTOFF = 1e-6


def kernel_params(kernel, cutoff: float = CUTOFF) -> KernelParams:
    """Reduce a ``spotpde.kernels`` kernel to the numbers the numba loop evaluates.

    Reads the kernel's class (``Uniform``, ``Gaussian``, ``Exponential``), horizontal
    scale ``a_h`` (radius, sigma or length), vertical scale ``a_z = a_h / aspect`` and
    centre value ``evaluate(0, 0)``. The sharp uniform kernel is exact; the smooth ones
    are cut off at ``w = cutoff * w(0)`` (the library's own ``reach`` uses 1e-14, which
    makes the Monte Carlo 2-4 times slower for no measurable gain).

    Raises:
        ValueError: for an unknown kernel class.
    """
    dims = int(getattr(kernel, "dims", 2))
    name = type(kernel).__name__.lower()
    if name not in _SHAPE_CODES:
        name = str(getattr(kernel, "shape_name", name)).lower()
    if name not in _SHAPE_CODES:
        raise ValueError(f"kernel: the Monte Carlo supports {tuple(_SHAPE_CODES)}, got {name!r}")
    code = _SHAPE_CODES[name]
    aspect = float(getattr(kernel, "aspect", 1.0))
    size = float(getattr(kernel, "a_h", None) or getattr(kernel, {"uniform": "radius",
                 "gaussian": "sigma", "exponential": "length"}[name]))
    size_v = size / aspect
    amp = float(np.asarray(kernel.evaluate(*[np.array([0.0])] * dims)).ravel()[0])
    if code == K.SHAPE_UNIFORM:
        rho = 1.0
    elif code == K.SHAPE_GAUSSIAN:
        rho = math.sqrt(-2.0 * math.log(cutoff))
    else:
        rho = -math.log(cutoff)
    return KernelParams(code, size, size_v, amp, (rho * size, rho * size_v),
                        float(kernel.V1), float(kernel.V2), dims)


def kernel_evaluate(kp: KernelParams, x, z, *more) -> np.ndarray:
    """The Monte Carlo's own (numba) evaluation of ``w`` at offsets ``(x, z)`` in d, or
    at ``(x, y, z)`` (three arguments, in that order) for a 3D kernel."""
    if kp.dims == 3:

        if len(more) != 1:
            raise TypeError("kernel_evaluate: a 3D kernel takes offsets (x, y, z)")
        x, y, z = np.broadcast_arrays(*(np.asarray(v, float) for v in (x, z, more[0])))
        out = kernel_eval3(kp.shape, *(np.ascontiguousarray(v).ravel() for v in (x, y, z)),
                           kp.size, kp.size_v, kp.amp, kp.reach[0], kp.reach[1])
        return out.reshape(x.shape)
    x, z = np.broadcast_arrays(np.asarray(x, float), np.asarray(z, float))
    out = K.kernel_eval(kp.shape, np.ascontiguousarray(x), np.ascontiguousarray(z),
                        kp.size, kp.size_v, kp.amp, kp.reach[0], kp.reach[1])
    return out.reshape(x.shape)


# ---------------------------------------------------------------------------------------
# Simulation
# ---------------------------------------------------------------------------------------
def _scalar(name, value) -> float:
    if np.ndim(value) != 0:
        raise ValueError(f"{name}: the Monte Carlo needs a constant, got an array")
    return float(value)


def simulate(grid: Grid, orifice: Orifice, spots: Spots, kernel, rule: float = 0.5, *,
             particles: np.ndarray | None = None, tracked=None,
             t_end: float | None = None, n_spots: int | None = None, seed: int = 0,
             gamma: float = 0.0, step: float | None = None, steps: str = "gaussian",
             probes: bool | None = None, batches: int = 20, records: int = 20,
             levels: np.ndarray | None = None, skin: float | None = None,
             cutoff: float = CUTOFF, progress: Callable[[float], None] | None = None,
             walls: str = "renormalise", relax: Relax | dict | None = None,
             diameters: np.ndarray | None = None) -> MCResult:
    """Run the discrete spot model in the box of ``grid``.

    Args:
        grid: 2D :class:`~spotpde.grid.Grid`; its box is the silo, its cell centres are
            the probe points, its walls (``"reflecting"``/``"open"``) bound spots and
            particles. A 3D grid (``dims = 3``, e.g. a thin slab with ``y_range`` a few
            d deep) runs the 3D model (``_simulate3d``, docs/packing.md): spots walk in
            ``x`` and ``y``, the side, front and back walls bound them. A wedge hopper,
            or an axisymmetric grid (cylinder, cone; a 3D kernel, particles ``(N, 3)``
            as ``(x, z, y)``) runs ``_geometry`` (docs/montecarlo.md 7b).
        orifice: spot source on the floor (``rate`` = Q0 in spots per unit time,
            constant).
        spots: ``drift`` v_s (d per unit time), ``b`` and ``b_par`` (d), constants.
            ``b`` is the long-distance horizontal diffusion length, persistence included.
        kernel: a ``spotpde.kernels`` kernel (Uniform, Gaussian, Exponential) of the
            grid's ``dims``.
        rule: lam, where along the step the influence is evaluated (1/2 midpoint, 1 end).
        particles: ``(N, 2)`` initial ``(x, z)`` (see :func:`lattice`,
            :func:`random_packing`, :func:`blob`); ``None`` for probes only. 3D:
            ``(N, 3)`` in columns ``(x, z, y)``, the depth last (:func:`dense_packing`
            of a 3D grid); positions, snapshots and ``final`` keep that order.
        tracked: ``None`` (no trajectories), ``"all"``, or indices of particles whose
            positions are snapshot and whose level crossings are recorded.
        t_end: duration; or ``n_spots``: duration ``n_spots / Q0`` (expected spot count).
        seed: random seed (the run is reproducible for a given seed and arguments).
        gamma: correlation coefficient of successive horizontal steps, ``0 <= gamma < 1``.
        step: vertical step Delta in d (default: a quarter of the kernel's vertical size).
        steps: ``"gaussian"`` steps ``sqrt(2 b0 Delta) xi`` or ``"binary"`` ``+-sqrt(2 b0 Delta)``.
        probes: accumulate the probe fields and the spot density on the grid (default:
            yes in 2D, no in 3D, where a spot step visits ``(2 R / h)**3`` probes).
        batches: number of time batches for standard errors of probe fields.
        records: number of snapshots of tracked particles (evenly spaced, last at t_end).
        levels: heights at which first crossings are recorded (default ``grid.z``).
        skin: cell-list skin in d (default 0.5).
        cutoff: relative cut-off of smooth kernels (see :func:`kernel_params`).
        progress: called with the fraction done.
        walls: ``"renormalise"`` (default): every displacement is divided by the fraction
            ``phi`` of the kernel between the reflecting walls, evaluated at the spot's
            ``x_s + lam dx`` (tabulated, ``_walls.coverage_table``), so a spot step
            displaces ``V1 dR``; ``"truncate"``: the kernel beyond a wall displaces
            nothing. Identical with open walls (docs/walls.md).
        relax: packing constraints (docs/packing.md): ``None`` (default, grains do not
            interact), a :class:`~spotpde.montecarlo.Relax` or a dict of its fields. The
            grains near each spot are relaxed by soft-core repulsion after its steps, with
            the block's centre of mass held; reflecting walls repel, and so does the floor
            beside ``relax.opening`` if one is given.
        diameters: ``(N,)`` grain diameters in d (with ``relax``; default: drawn from
            ``relax.polydispersity`` and ``relax.distribution`` with ``seed``).

    Returns:
        :class:`MCResult`.

    Raises:
        ValueError: invalid parameters (the message names the argument).
    """
    if probes is None:
        probes = grid.dims == 2
    v_s, b, b_par, Q0 = _constants(grid, orifice, spots, kernel, rule, gamma, steps, t_end,
                                   n_spots, walls)
    relax = Relax.of(relax)
    kp = kernel_params(kernel, cutoff)
    if t_end is None:
        t_end = float(n_spots) / Q0
    if step is None:
        step = 0.25 * min(kp.size_v, kp.reach[1])
    step = float(step)
    if not (t_end > 0 and step > 0):
        raise ValueError(f"t_end: must be > 0 (and step > 0), got t_end={t_end}, step={step}")
    dt = step / v_s
    n_ticks = max(1, int(round(t_end / dt)))
    t_end = n_ticks * dt
    b0 = b * (1.0 - gamma) / (1.0 + gamma)
    profile = K.PROFILE_POINT if orifice.width <= 0 else (
        K.PROFILE_UNIFORM if orifice.profile == "uniform" else K.PROFILE_GAUSSIAN)
    skin = 0.5 if skin is None else float(skin)
    cell = max(kp.reach[0], kp.reach[1], 0.25) + skin
    batches = max(1, min(int(batches), n_ticks))
    run = dict(rule=float(rule), gamma=float(gamma), step=step, steps=steps, seed=int(seed),
               t_end=t_end, dt=dt, n_ticks=n_ticks, Q0=Q0, b0=b0, b_par=b_par,
               profile=profile, particles=particles, tracked=tracked, records=records,
               batches=batches, walls=walls, progress=progress, probes=bool(probes))
    if runs_in_geometry(grid):  # wedge hopper, cylinder, cone: _geometry
        if relax is not None:
            raise ValueError("relax: packing constraints run in boxes only, not in "
                             "hoppers or cylinders")
        return simulate_geometry(grid, orifice, spots, kp, kernel=kernel, **run)
    run.update(skin=skin, cell=cell, levels=levels, relax=relax, diameters=diameters)
    if grid.dims == 3:
        return run3d(grid, orifice, spots, kp, relax_reach=_relax_reach(kp), **run)
    return _run_box(grid, orifice, spots, kp, v_s=v_s, **run)


def _constants(grid, orifice, spots, kernel, rule, gamma, steps, t_end, n_spots, walls):
    """``(v_s, b, b_par, Q0)`` of a run (d per unit time, d, d, spots per unit time), or
    one ValueError naming every bad argument."""
    problems = []
    if getattr(kernel, "dims", 2) != grid.geometry.kernel_dims:
        problems.append(f"kernel: a {getattr(kernel, 'dims', 2)}D kernel in a {grid.dims}D grid"
                        + (" of rings (needs 3D)" if grid.geometry.curved else ""))
    v_s = _scalar("spots.drift", spots.drift)
    b = _scalar("spots.b", spots.b)
    b_par = _scalar("spots.b_par", spots.b_par)
    if callable(orifice.rate):
        problems.append("orifice.rate: the Monte Carlo needs a constant rate, got a function of time")
        Q0 = 0.0
    else:
        Q0 = float(orifice.rate)
    if not v_s > 0:
        problems.append(f"spots.drift: must be > 0, got {v_s}")
    if not b >= 0:
        problems.append(f"spots.b: must be >= 0, got {b}")
    if not b_par >= 0:
        problems.append(f"spots.b_par: must be >= 0, got {b_par}")
    if not Q0 > 0:
        problems.append(f"orifice.rate: must be > 0, got {Q0}")
    if not 0.0 <= gamma < 1.0:
        problems.append(f"gamma: must be in [0, 1), got {gamma}")
    if steps not in STEPS:
        problems.append(f"steps: must be one of {STEPS}, got {steps!r}")
    if not 0.0 <= rule <= 1.0:
        problems.append(f"rule: must be in [0, 1], got {rule}")
    if (t_end is None) == (n_spots is None):
        problems.append(f"t_end, n_spots: give exactly one of them, got t_end={t_end!r}, n_spots={n_spots!r}")
    if walls not in ("renormalise", "truncate"):
        problems.append(f'walls: must be one of "renormalise", "truncate", got {walls!r}')
    if problems:
        raise ValueError("; ".join(problems))
    return v_s, b, b_par, Q0


def _box_params(grid, orifice, kp, *, rule, gamma, step, steps, dt, n_ticks, Q0, b0, b_par,
                profile, skin, cell, walls, batches, probes):
    """The numba loop's constants (:func:`_mc_kernels.make_params`) of a 2D box, with the
    wall-coverage table of renormalised reflecting walls."""
    x0, x1 = grid.x_range
    z0, z1 = grid.z_range
    tab_x0, tab_dx = 0.0, 0.0
    if walls == "renormalise" and grid.walls == "reflecting":
        name = {c: n for n, c in _SHAPE_CODES.items()}[kp.shape]
        tab_x0, tab_dx, phi_tab = coverage_table(
            name, kp.size, kp.size_v, kp.amp, kp.reach, x0, x1)
    else:
        phi_tab = np.zeros(0)
    prm = K.make_params(
        x0=x0, x1=x1, z0=z0, z1=z1, xc=orifice.x, width=orifice.width, rate=Q0 * dt,
        step=step, sigx=math.sqrt(2.0 * b0 * step), sigz=math.sqrt(2.0 * b_par * step),
        gamma=gamma, lam=rule, ksize=kp.size, ksize_v=kp.size_v, kamp=kp.amp,
        reach_h=kp.reach[0], reach_v=kp.reach[1], cell=cell, skin=skin,
        probe_x0=grid.x[0], probe_z0=grid.z[0], probe_h=grid.spacing, dt=dt,
        tab_x0=tab_x0, tab_dx=tab_dx, shape=kp.shape, profile=profile,
        walls=K.WALLS_OPEN if grid.walls == "open" else K.WALLS_REFLECTING,
        steps=STEPS.index(steps), ncx=max(1, int(math.ceil((x1 - x0) / cell))),
        ncz=max(1, int(math.ceil((z1 - z0) / cell))), pnx=grid.nx, pnz=grid.nz,
        n_batch=batches, ticks_total=n_ticks, probes=int(bool(probes)))
    return prm, phi_tab


def _run_box(grid, orifice, spots, kp, *, v_s, rule, gamma, step, steps, seed, t_end, dt,
             n_ticks, Q0, b0, b_par, profile, particles, tracked, records, batches, walls,
             progress, probes, skin, cell, levels, relax, diameters) -> MCResult:
    """The 2D box: particles, tracking and probes set up, the numba loop run in chunks
    (:func:`_advance`), the record assembled."""
    z0, z1 = grid.z_range
    prm, phi_tab = _box_params(grid, orifice, kp, rule=rule, gamma=gamma, step=step,
                               steps=steps, dt=dt, n_ticks=n_ticks, Q0=Q0, b0=b0,
                               b_par=b_par, profile=profile, skin=skin, cell=cell,
                               walls=walls, batches=batches, probes=probes)
    if particles is None:
        particles = np.zeros((0, 2))
    P = np.asarray(particles, dtype=float).reshape(-1, 2)
    n = P.shape[0]
    px = np.ascontiguousarray(P[:, 0]).copy()
    pz = np.ascontiguousarray(P[:, 1]).copy()
    status = np.zeros(n, np.int64)
    status[pz < z0] = K.P_ORIFICE
    diam = particle_diameters(n, relax, diameters, seed)
    if relax is not None:
        relax = relax.resolved(_relax_reach(kp))
    rp = relax_params(relax, diam, orifice.x, grid.walls == "reflecting")
    bk = tracking(tracked, n, records, n_ticks, grid.z if levels is None else levels,
                  lambda i: pz[i], 2)
    if probes:
        probe = np.zeros((5, batches, grid.nz, grid.nx))
        rho_hist = np.zeros((batches, grid.nz, grid.nx))
    else:
        probe = np.zeros((5, 1, 1, 1))
        rho_hist = np.zeros((1, 1, 1))
    # spots: capacity for the expected number in flight, grown on demand
    mean_active = Q0 * (z1 - z0) / v_s
    cap = int(mean_active * 1.2 + 10.0 * math.sqrt(mean_active) + 64)
    K.seed(int(seed) % (2**32))
    cnt, wall, cpu = _advance(prm, n_ticks, cap, px, pz, status, bk, probe, rho_hist,
                              phi_tab, rp, diam, progress)
    batch_of_tick = np.arange(n_ticks) * batches // n_ticks
    return MCResult(
        grid=grid, orifice=orifice, spots=spots, kernel=kp, rule=float(rule), gamma=float(gamma),
        step=step, steps=steps, seed=int(seed), t_end=t_end, dt=dt, n_ticks=n_ticks,
        initial=P.copy(), final=np.column_stack([px, pz]), status=status,
        exit_x=bk["exit_x"], exit_t=bk["exit_t"], tracked=bk["tracked"],
        times=(bk["rec_ticks"] + 1) * dt, positions=bk["tpos"], levels=bk["levels"],
        cross_x=bk["cross_x"], cross_t=bk["cross_t"],
        probe=probe if probes else None, rho_hist=rho_hist if probes else None,
        batch_ticks=np.bincount(batch_of_tick, minlength=batches),
        counters={"spots_injected": int(cnt[K.C_INJECTED]), "spot_steps": int(cnt[K.C_STEPS]),
                  "particle_updates": int(cnt[K.C_UPDATES]),
                  "cell_rebuilds": int(cnt[K.C_REBUILDS]), "spots_removed": int(cnt[K.C_REMOVED]),
                  "relaxations": int(cnt[K.C_RELAXATIONS]), "grains_relaxed": int(cnt[K.C_RELAXED])},
        wall_time=wall, cpu_time=cpu, walls=walls, relax=relax, diameters=diam,
    )


def _advance(prm, n_ticks, cap, px, pz, status, bk, probe, rho_hist, phi_tab, rp, diam,
             progress):
    """Run the numba loop (:func:`_mc_kernels.advance`) over all ``n_ticks`` in chunks of
    about 1/200 of the run (progress between them), doubling the spot arrays from ``cap``
    when they fill. Returns ``(counters, wall seconds, CPU seconds)``; particles,
    tracking and probes are updated in place."""
    n = px.size
    moved = np.zeros(n)
    blk = np.zeros(max(n, 1), np.int64)
    old = np.zeros((max(n, 1), 2))
    cell_start = np.zeros(prm.ncx * prm.ncz + 1, np.int64)
    cell_idx = np.zeros(max(n, 1), np.int64)
    if n:
        K.build_cells(px, pz, status, prm.x0, prm.z0, prm.cell, prm.ncx, prm.ncz,
                      cell_start, cell_idx)
    sx, sz, sxi = np.zeros(cap), np.zeros(cap), np.zeros(cap)
    srel = np.zeros((cap, 3))
    cnt = np.zeros(K.NC, np.int64)
    cnt[K.C_PENDING] = -1
    chunk = max(1, n_ticks // 200)
    wall = cpu = 0.0
    while cnt[K.C_TICK] < n_ticks:
        todo = min(chunk, n_ticks - cnt[K.C_TICK])
        t0 = time.perf_counter()
        c0 = time.process_time()
        K.advance(prm, cnt, todo, sx, sz, sxi, px, pz, status, moved, cell_start, cell_idx,
                  bk["track_slot"], bk["tpos"], bk["rec_ticks"], bk["levels"], bk["lev_next"],
                  bk["cross_x"], bk["cross_t"], bk["exit_x"], bk["exit_t"],
                  probe, rho_hist, phi_tab, rp, diam, srel, blk, old)
        wall += time.perf_counter() - t0
        cpu += time.process_time() - c0
        if cnt[K.C_PENDING] >= 0:  # spot arrays full: grow and carry on
            sx, sz, sxi = (np.concatenate([a, np.zeros(a.size)]) for a in (sx, sz, sxi))
            srel = np.concatenate([srel, np.zeros_like(srel)])
        if progress is not None:
            progress(cnt[K.C_TICK] / n_ticks)
    return cnt, wall, cpu


def _relax_reach(kp: KernelParams) -> float:
    """Distance (d) at which the kernel falls to 1 % of ``w(0)``, along its longer axis."""
    size = max(kp.size, kp.size_v)
    if kp.shape == K.SHAPE_UNIFORM:
        return size
    if kp.shape == K.SHAPE_GAUSSIAN:
        return math.sqrt(2.0 * math.log(100.0)) * size
    return math.log(100.0) * size


@case_settings
def from_case(case, *, particles="lattice", spacing: float = 1.0, **kwargs) -> MCResult:
    """Run the Monte Carlo with a :class:`spotpde.cases.Case`'s parameters.

    The case's ``[montecarlo]`` table (``case.montecarlo``, docs/cases.md) gives the run
    settings; keywords given here override it, keys it leaves out keep the defaults below.

    Args:
        case: a loaded case (2D or 3D); its grid, orifice, spots, kernel and rule are used.
        particles: ``"lattice"`` (triangular lattice of ``spacing``), ``"random"``
            (:func:`random_packing`, phi 0.5), ``"tracer"`` (2000 particles from the
            tracer blob, all tracked), ``None``, or an ``(N, 2)`` array. 3D: a simple
            cubic lattice, :func:`dense_packing` at phi 0.5, no ``"tracer"``; arrays
            ``(N, 3)`` in columns ``(x, z, y)``. Hoppers and cylinders:
            ``"lattice"`` is :func:`geometry_particles` (inside the material only).
        **kwargs: passed to :func:`simulate` (``t_end`` defaults to ``case.tracer.t_end``;
            for ``tracer.model = "void"`` the step defaults to 1 d, larger than the void's
            radius, so that a void displaces a given particle at most once).
    """
    grid = case.grid
    if runs_in_geometry(grid) and isinstance(particles, str):
        if particles != "lattice":
            raise ValueError(f"particles: hoppers and cylinders take 'lattice', None or an "
                             f"array of positions, got {particles!r}")
        particles = geometry_particles(grid, spacing)
    if grid.dims == 3 and isinstance(particles, str):
        particles = case_particles3d(grid, particles, spacing, kwargs.get("seed", 0))
    if isinstance(particles, str):
        if particles == "lattice":
            particles = lattice(grid, spacing)
        elif particles == "random":
            particles = random_packing(grid, 0.5, seed=kwargs.get("seed", 0))
        elif particles == "tracer":
            st = case.tracer.start
            particles = blob(st.x, st.z, st.width, 2000, seed=kwargs.get("seed", 0))
            kwargs.setdefault("tracked", "all")
        else:
            raise ValueError(f"particles: unknown {particles!r}; valid: 'lattice', "
                            "'random', 'tracer', None or an (N, 2) array of positions")
    if "t_end" not in kwargs and "n_spots" not in kwargs:
        if case.tracer is None:
            raise ValueError("t_end: give t_end or n_spots for a case without [tracer]")
        kwargs["t_end"] = case.tracer.t_end
    kwargs.setdefault("rule", case.rule)
    kwargs.setdefault("walls", getattr(case, "kernel_walls", "renormalise"))
    if case.model == "void":
        # a void moves one particle diameter per step, so it never displaces a particle twice
        kwargs.setdefault("step", 1.0)
    return simulate(grid, case.orifice, case.spots, case.kernel, particles=particles, **kwargs)
