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

Public functions: :func:`simulate` -> :class:`MCResult`; :func:`measure` -> an
``xarray.Dataset`` with the continuum result's variable names; Lagrangian statistics
:func:`displacement_statistics`, :func:`velocity_correlation`, :func:`propagator`,
:func:`particle_frames`; particle sets :func:`lattice`, :func:`random_packing`,
:func:`blob`, :func:`layer_mask`; :func:`from_case` to run a case file's parameters;
:func:`spot_walks` for the walk alone; :func:`uniform_flow_prediction`, what the discrete
model predicts in uniform flow beyond mean field (the midpoint rule diffuses less than the
continuum ``D_p``; vertical shot noise).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import xarray as xr

from . import _mc_kernels as K
from .._version import __version__
from ..grid import Grid
from ..parameters import Orifice, Spots, in_bands

STEPS = ("gaussian", "binary")

__all__ = [
    "MCResult", "simulate", "measure", "displacement_statistics", "velocity_correlation",
    "propagator", "lattice", "random_packing", "blob", "from_case", "spot_walks",
    "kernel_params", "kernel_evaluate", "layer_mask", "uniform_flow_prediction",
    "particle_frames",
]


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
        V1, V2: the kernel's ``integral w`` and ``integral w**2`` in d**2.
    """

    shape: int
    size: float
    size_v: float
    amp: float
    reach: tuple[float, float]
    V1: float
    V2: float


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
        ValueError: for a 3D kernel or an unknown kernel class.
    """
    if getattr(kernel, "dims", 2) != 2:
        raise ValueError("kernel: the Monte Carlo is 2D only, got a 3D kernel")
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
    amp = float(np.asarray(kernel.evaluate(np.array([0.0]), np.array([0.0]))).ravel()[0])
    if code == K.SHAPE_UNIFORM:
        rho = 1.0
    elif code == K.SHAPE_GAUSSIAN:
        rho = math.sqrt(-2.0 * math.log(cutoff))
    else:
        rho = -math.log(cutoff)
    return KernelParams(code, size, size_v, amp, (rho * size, rho * size_v),
                        float(kernel.V1), float(kernel.V2))


def kernel_evaluate(kp: KernelParams, x, z) -> np.ndarray:
    """The Monte Carlo's own (numba) evaluation of ``w`` at offsets ``(x, z)`` in d."""
    x, z = np.broadcast_arrays(np.asarray(x, float), np.asarray(z, float))
    out = K.kernel_eval(kp.shape, np.ascontiguousarray(x), np.ascontiguousarray(z),
                        kp.size, kp.size_v, kp.amp, kp.reach[0], kp.reach[1])
    return out.reshape(x.shape)


# ---------------------------------------------------------------------------------------
# Particle sets
# ---------------------------------------------------------------------------------------
def _region(grid: Grid, region):
    if region is None:
        return grid.x_range[0], grid.x_range[1], grid.z_range[0], grid.z_range[1]
    return tuple(float(v) for v in region)


def lattice(grid: Grid, spacing: float = 1.0, kind: str = "triangular",
            region: Sequence[float] | None = None) -> np.ndarray:
    """Particles on a lattice filling the box (or ``region = (x0, x1, z0, z1)``).

    Args:
        grid: the silo (its box).
        spacing: nearest-neighbour distance in d.
        kind: ``"triangular"`` (rows ``spacing * sqrt(3)/2`` apart, alternate rows shifted
            by half a spacing) or ``"square"``.
        region: sub-box to fill.

    Returns:
        ``(N, 2)`` array of ``(x, z)`` in d.
    """
    if kind not in ("triangular", "square"):
        raise ValueError(f"lattice kind: must be one of 'triangular', 'square', got {kind!r}")
    x0, x1, z0, z1 = _region(grid, region)
    dz = spacing * (math.sqrt(3.0) / 2.0 if kind == "triangular" else 1.0)
    rows = np.arange(z0 + 0.5 * dz, z1, dz)
    pts = []
    for k, z in enumerate(rows):
        shift = 0.5 * spacing * (k % 2) if kind == "triangular" else 0.0
        xs = np.arange(x0 + 0.5 * spacing + shift, x1, spacing)
        pts.append(np.column_stack([xs, np.full_like(xs, z)]))
    return np.concatenate(pts) if pts else np.zeros((0, 2))


def random_packing(grid: Grid, phi: float = 0.5, seed: int = 0,
                   region: Sequence[float] | None = None, diameter: float = 1.0,
                   max_tries: int = 20000) -> np.ndarray:
    """Random sequential addition of non-overlapping disks of diameter ``diameter``.

    Disks are tried at uniformly random positions until the area fraction ``phi`` is
    reached (RSA jams near 0.547 in 2D: ask for less) or ``max_tries`` consecutive
    failures per disk occur.

    Returns:
        ``(N, 2)`` array of centres ``(x, z)`` in d.
    """
    x0, x1, z0, z1 = _region(grid, region)
    area = (x1 - x0) * (z1 - z0)
    n_target = int(phi * area / (math.pi * diameter**2 / 4.0))
    return _rsa(x0, x1, z0, z1, n_target, diameter, seed, max_tries)


def _rsa(x0, x1, z0, z1, n_target, d, seed, max_tries):
    rng = np.random.default_rng(seed)
    cell = d / math.sqrt(2.0)  # at most one centre per cell
    ncx = int(math.ceil((x1 - x0) / cell))
    ncz = int(math.ceil((z1 - z0) / cell))
    occ = -np.ones((ncz + 4, ncx + 4), np.int64)
    pts = np.empty((n_target, 2))
    n = 0
    fails = 0
    batch = 4096
    while n < n_target and fails < max_tries:
        cand = rng.random((batch, 2)) * [x1 - x0, z1 - z0] + [x0, z0]
        for x, z in cand:
            cx = int((x - x0) / cell) + 2
            cz = int((z - z0) / cell) + 2
            ok = occ[cz, cx] < 0
            if ok:
                block = occ[cz - 2:cz + 3, cx - 2:cx + 3]
                idx = block[block >= 0]
                if idx.size and np.any(np.sum((pts[idx] - (x, z)) ** 2, axis=1) < d * d):
                    ok = False
            if ok:
                occ[cz, cx] = n
                pts[n] = (x, z)
                n += 1
                fails = 0
                if n == n_target:
                    break
            else:
                fails += 1
                if fails >= max_tries:
                    break
    return pts[:n].copy()


def blob(x: float, z: float, width: float, n: int, seed: int = 0) -> np.ndarray:
    """``n`` tracer particles drawn from a Gaussian blob (standard deviation ``width``).

    The discrete counterpart of ``[tracer] start = {x, z, width}``.
    """
    rng = np.random.default_rng(seed)
    return np.column_stack([x + width * rng.standard_normal(n), z + width * rng.standard_normal(n)])


def layer_mask(z, spacing: float) -> np.ndarray:
    """True for heights in the coloured bands ``[k s, k s + s/2)`` (the layered silo)."""
    return in_bands(z, spacing)


# ---------------------------------------------------------------------------------------
# Result
# ---------------------------------------------------------------------------------------
@dataclass
class MCResult:
    """Everything a Monte Carlo run recorded (all lengths in d, times in the case unit).

    Attributes:
        grid, orifice, spots, kernel (:class:`KernelParams`), rule, gamma, step (Delta),
            steps ("gaussian"/"binary"), seed, t_end, dt (time per tick), n_ticks.
        initial: ``(N, 2)`` initial particle positions ``(x, z)``; ``final``: final ones.
        status: per particle 0 inside, 1 left through the orifice, 2 left through an
            open side. ``exit_x``, ``exit_t``: where and when it left (NaN if not).
        tracked: indices of tracked particles. ``times``: snapshot times;
            ``positions``: ``(n_times, n_tracked, 2)``, NaN once a particle has left.
        levels: crossing heights; ``cross_x``/``cross_t``: ``(n_tracked, n_levels)`` x and
            time at which each tracked particle first fell through each level (NaN: not).
        probe: ``(5, n_batch, nz, nx)`` probe sums (see ``_mc_kernels.advance``);
            ``rho_hist``: ``(n_batch, nz, nx)`` spot samples; ``batch_ticks``: ticks per batch.
        counters: injected spots, spot steps, particle updates, cell-list rebuilds.
        wall_time, cpu_time: wall-clock and CPU seconds spent in the numba loop.
        walls: the wall treatment (``"renormalise"`` or ``"truncate"``).
    """

    grid: Grid
    orifice: Orifice
    spots: Spots
    kernel: KernelParams
    rule: float
    gamma: float
    step: float
    steps: str
    seed: int
    t_end: float
    dt: float
    n_ticks: int
    initial: np.ndarray
    final: np.ndarray
    status: np.ndarray
    exit_x: np.ndarray
    exit_t: np.ndarray
    tracked: np.ndarray
    times: np.ndarray
    positions: np.ndarray
    levels: np.ndarray
    cross_x: np.ndarray
    cross_t: np.ndarray
    probe: np.ndarray | None
    rho_hist: np.ndarray | None
    batch_ticks: np.ndarray
    counters: dict = field(default_factory=dict)
    wall_time: float = 0.0
    cpu_time: float = 0.0
    walls: str = "renormalise"

    @property
    def performance(self) -> dict:
        """Spot steps and particle updates per CPU second of the numba loop.

        CPU (process) time rather than wall time, so that the numbers do not depend on
        what else the machine runs; the first call of a session includes numba's loading
        of its cache (or compilation).
        """
        ct = max(self.cpu_time, 1e-12)
        return {"spot_steps_per_second": self.counters["spot_steps"] / ct,
                "particle_updates_per_second": self.counters["particle_updates"] / ct,
                "cpu_time": self.cpu_time, "wall_time": self.wall_time}


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
             probes: bool = True, batches: int = 20, records: int = 20,
             levels: np.ndarray | None = None, skin: float | None = None,
             cutoff: float = CUTOFF, progress: Callable[[float], None] | None = None,
             walls: str = "renormalise") -> MCResult:
    """Run the discrete spot model in the box of ``grid``.

    Args:
        grid: 2D :class:`~spotpde.grid.Grid`; its box is the silo, its cell centres are
            the probe points, its walls (``"reflecting"``/``"open"``) bound spots and
            particles.
        orifice: spot source on the floor (``rate`` = Q0 in spots per unit time,
            constant).
        spots: ``drift`` v_s (d per unit time), ``b`` and ``b_par`` (d), constants.
            ``b`` is the long-distance horizontal diffusion length, persistence included.
        kernel: a ``spotpde.kernels`` kernel (Uniform, Gaussian, Exponential; 2D).
        rule: lam, where along the step the influence is evaluated (1/2 midpoint, 1 end).
        particles: ``(N, 2)`` initial ``(x, z)`` (see :func:`lattice`,
            :func:`random_packing`, :func:`blob`); ``None`` for probes only.
        tracked: ``None`` (no trajectories), ``"all"``, or indices of particles whose
            positions are snapshot and whose level crossings are recorded.
        t_end: duration; or ``n_spots``: duration ``n_spots / Q0`` (expected spot count).
        seed: random seed (the run is reproducible for a given seed and arguments).
        gamma: correlation coefficient of successive horizontal steps, ``0 <= gamma < 1``.
        step: vertical step Delta in d (default: a quarter of the kernel's vertical size).
        steps: ``"gaussian"`` steps ``sqrt(2 b0 Delta) xi`` or ``"binary"`` ``+-sqrt(2 b0 Delta)``.
        probes: accumulate the probe fields and the spot density on the grid.
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

    Returns:
        :class:`MCResult`.

    Raises:
        ValueError: invalid parameters (the message names the argument).
    """
    problems = []
    if grid.dims != 2:
        problems.append(f"grid: the Monte Carlo is 2D only, got dims = {grid.dims}")
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
    x0, x1 = grid.x_range
    z0, z1 = grid.z_range
    profile = K.PROFILE_POINT if orifice.width <= 0 else (
        K.PROFILE_UNIFORM if orifice.profile == "uniform" else K.PROFILE_GAUSSIAN)
    skin = 0.5 if skin is None else float(skin)
    cell = max(kp.reach[0], kp.reach[1], 0.25) + skin
    ncx = max(1, int(math.ceil((x1 - x0) / cell)))
    ncz = max(1, int(math.ceil((z1 - z0) / cell)))
    batches = max(1, min(int(batches), n_ticks))

    fp = np.zeros(K.NF)
    fp[[K.F_X0, K.F_X1, K.F_Z0, K.F_Z1]] = x0, x1, z0, z1
    fp[[K.F_XC, K.F_WIDTH, K.F_RATE]] = orifice.x, orifice.width, Q0 * dt
    fp[[K.F_STEP, K.F_SIGX, K.F_SIGZ, K.F_GAMMA]] = (
        step, math.sqrt(2.0 * b0 * step), math.sqrt(2.0 * b_par * step), gamma)
    fp[K.F_LAM] = rule
    fp[[K.F_KSIZE, K.F_KSIZEV, K.F_KAMP]] = kp.size, kp.size_v, kp.amp
    fp[[K.F_REACHH, K.F_REACHV]] = kp.reach
    fp[[K.F_CELL, K.F_SKIN]] = cell, skin
    fp[[K.F_PX0, K.F_PZ0, K.F_PH]] = grid.x[0], grid.z[0], grid.spacing
    fp[K.F_DT] = dt
    phi_tab = np.zeros(0)
    if walls == "renormalise" and grid.walls == "reflecting":
        from ..fields._walls import coverage_table

        name = {c: n for n, c in _SHAPE_CODES.items()}[kp.shape]
        fp[K.F_TAB_X0], fp[K.F_TAB_DX], phi_tab = coverage_table(
            name, kp.size, kp.size_v, kp.amp, kp.reach, x0, x1)
    ip = np.zeros(K.NI, np.int64)
    ip[K.I_SHAPE] = kp.shape
    ip[K.I_PROFILE] = profile
    ip[K.I_WALLS] = K.WALLS_OPEN if grid.walls == "open" else K.WALLS_REFLECTING
    ip[K.I_STEPS] = STEPS.index(steps)
    ip[[K.I_NCX, K.I_NCZ, K.I_PNX, K.I_PNZ]] = ncx, ncz, grid.nx, grid.nz
    ip[K.I_NBATCH], ip[K.I_TICKS_TOTAL], ip[K.I_PROBES] = batches, n_ticks, int(bool(probes))

    # particles
    if particles is None:
        particles = np.zeros((0, 2))
    P = np.asarray(particles, dtype=float).reshape(-1, 2)
    n = P.shape[0]
    px = np.ascontiguousarray(P[:, 0]).copy()
    pz = np.ascontiguousarray(P[:, 1]).copy()
    status = np.zeros(n, np.int64)
    status[pz < z0] = K.P_ORIFICE
    moved = np.zeros(n)
    cell_start = np.zeros(ncx * ncz + 1, np.int64)
    cell_idx = np.zeros(max(n, 1), np.int64)
    if n:
        K.build_cells(px, pz, status, x0, z0, cell, ncx, ncz, cell_start, cell_idx)
    if tracked is None:
        tracked = np.zeros(0, np.int64)
    elif isinstance(tracked, str):
        if tracked != "all":
            raise ValueError(f"tracked: must be 'all', None or indices, got {tracked!r}")
        tracked = np.arange(n)
    tracked = np.asarray(tracked, np.int64)
    track_slot = -np.ones(n, np.int64)
    track_slot[tracked] = np.arange(tracked.size)
    records = max(1, int(records)) if tracked.size else 0
    rec_ticks = (np.round(np.linspace(0, n_ticks, records + 1)[1:]).astype(np.int64) - 1
                 if records else np.zeros(0, np.int64))
    rec_ticks = np.unique(np.clip(rec_ticks, 0, n_ticks - 1))
    tpos = np.full((rec_ticks.size, tracked.size, 2), np.nan)
    levels = np.asarray(grid.z if levels is None else levels, float)
    levels = np.sort(levels)
    lev_next = np.searchsorted(levels, pz[tracked], side="right").astype(np.int64) - 1
    cross_x = np.full((tracked.size, levels.size), np.nan)
    cross_t = np.full((tracked.size, levels.size), np.nan)
    exit_x = np.full(n, np.nan)
    exit_t = np.full(n, np.nan)
    if probes:
        probe = np.zeros((5, batches, grid.nz, grid.nx))
        rho_hist = np.zeros((batches, grid.nz, grid.nx))
    else:
        probe = np.zeros((5, 1, 1, 1))
        rho_hist = np.zeros((1, 1, 1))

    # spots: capacity for the expected number in flight, grown on demand
    transit = (z1 - z0) / v_s
    mean_active = Q0 * transit
    cap = int(mean_active * 1.2 + 10.0 * math.sqrt(mean_active) + 64)
    sx = np.zeros(cap)
    sz = np.zeros(cap)
    sxi = np.zeros(cap)
    cnt = np.zeros(K.NC, np.int64)
    cnt[K.C_PENDING] = -1

    K.seed(int(seed) % (2**32))
    chunk = max(1, n_ticks // 200)
    wall = 0.0
    cpu = 0.0
    while cnt[K.C_TICK] < n_ticks:
        todo = min(chunk, n_ticks - cnt[K.C_TICK])
        t0 = time.perf_counter()
        c0 = time.process_time()
        K.advance(fp, ip, cnt, todo, sx, sz, sxi, px, pz, status, moved, cell_start, cell_idx,
                  track_slot, tpos, rec_ticks, levels, lev_next, cross_x, cross_t, exit_x, exit_t,
                  probe, rho_hist, phi_tab)
        wall += time.perf_counter() - t0
        cpu += time.process_time() - c0
        if cnt[K.C_PENDING] >= 0:  # spot arrays full: grow and carry on
            cap *= 2
            sx, sz, sxi = (np.concatenate([a, np.zeros(a.size)]) for a in (sx, sz, sxi))
        if progress is not None:
            progress(cnt[K.C_TICK] / n_ticks)

    batch_of_tick = np.arange(n_ticks) * batches // n_ticks
    batch_ticks = np.bincount(batch_of_tick, minlength=batches)
    return MCResult(
        grid=grid, orifice=orifice, spots=spots, kernel=kp, rule=float(rule), gamma=float(gamma),
        step=step, steps=steps, seed=int(seed), t_end=t_end, dt=dt, n_ticks=n_ticks,
        initial=P.copy(), final=np.column_stack([px, pz]), status=status,
        exit_x=exit_x, exit_t=exit_t, tracked=tracked, times=(rec_ticks + 1) * dt,
        positions=tpos, levels=levels, cross_x=cross_x, cross_t=cross_t,
        probe=probe if probes else None, rho_hist=rho_hist if probes else None,
        batch_ticks=batch_ticks,
        counters={"spots_injected": int(cnt[K.C_INJECTED]), "spot_steps": int(cnt[K.C_STEPS]),
                  "particle_updates": int(cnt[K.C_UPDATES]),
                  "cell_rebuilds": int(cnt[K.C_REBUILDS]), "spots_removed": int(cnt[K.C_REMOVED])},
        wall_time=wall, cpu_time=cpu, walls=walls,
    )


def from_case(case, *, particles="lattice", spacing: float = 1.0, **kwargs) -> MCResult:
    """Run the Monte Carlo with a :class:`spotpde.cases.Case`'s parameters.

    Args:
        case: a loaded case (2D); its grid, orifice, spots, kernel and rule are used.
        particles: ``"lattice"`` (triangular lattice of ``spacing``), ``"random"``
            (:func:`random_packing`, phi 0.5), ``"tracer"`` (2000 particles from the
            tracer blob, all tracked), ``None``, or an ``(N, 2)`` array.
        **kwargs: passed to :func:`simulate` (``t_end`` defaults to ``case.tracer.t_end``;
            for ``tracer.model = "void"`` the step defaults to 1 d, larger than the void's
            radius, so that a void displaces a given particle at most once).
    """
    grid = case.grid
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


def spot_walks(b: float, step: float, n_walks: int, n_steps: int, gamma: float = 0.0,
               steps: str = "gaussian", seed: int = 0) -> np.ndarray:
    """Horizontal positions of free spot walks (no walls), the step rule of :func:`simulate`.

    Args:
        b: long-distance diffusion length in d; the single-step one is
            ``b0 = b (1 - gamma) / (1 + gamma)``.
        step: vertical step Delta in d.
        n_walks, n_steps: number of walks and steps.
        gamma: step autocorrelation. steps: ``"gaussian"`` or ``"binary"``.
        seed: random seed.

    Returns:
        ``(n_walks, n_steps)``: x after each step (height ``(n + 1) * step``).
    """
    b0 = b * (1.0 - gamma) / (1.0 + gamma)
    return K.spot_walks(int(n_walks), int(n_steps), math.sqrt(2.0 * b0 * step), float(gamma),
                        STEPS.index(steps), int(seed))


# ---------------------------------------------------------------------------------------
# What the discrete model predicts in uniform flow (docs/montecarlo.md, section 4)
# ---------------------------------------------------------------------------------------
def uniform_flow_prediction(kernel, b: float, flux: float, rule: float = 0.5,
                            resolution: int = 16, cutoff: float = CUTOFF,
                            b_par: float = 0.0) -> dict:
    """Lagrangian drift and diffusivities of the discrete model in uniform flow.

    Uniform flow: spots cross each height at ``flux = rho_s v_s`` per unit length (area in
    3D) and unit time (``Q0 / W``), straight up on average. For small steps
    (``Delta -> 0``) the displacement of a particle by one passing spot is the stochastic
    integral ``Y = -int w(r - s) o_lam ds`` along the spot path; passages are independent,
    so ``D = flux/2 <Y Y>`` (averaged over the spot's horizontal offset). Derivation in
    docs/montecarlo.md section 4 and docs/coefficients.md ("Beyond mean field"); the
    numbers come from the one quadrature of ``spotpde._passage.length_tensor``:

    * ``u_z = -V1 flux`` (the continuum's ``-V1 rho_s v_s``);
    * ``D_xx = flux b V2 - lam (1 - lam) flux/2 E[Y^2]``: the mean field, exact for
      ``lam`` = 0 and 1, minus the passage correlation (``E[Y^2]`` finite for every kernel,
      the sharp disk and sphere included);
    * ``D_zz``: with ``b_par = 0`` the shot noise of the Poisson passages,
      ``flux/2 E[Z^2]``, absent from the mean-field ``D_p``.

    Args:
        kernel: a ``spotpde.kernels`` kernel (2D or 3D).
        b: spot diffusion length in d. flux: ``rho_s v_s`` in spots / (d^(dims-1) time).
        rule: lam. b_par: vertical spot diffusion length in d.
        resolution, cutoff: ignored (kept for old callers; the quadrature sets its own
            resolution, docs/coefficients.md).

    Returns:
        dict with ``u_z``, ``D_xx``, ``D_xx_meanfield``, ``D_zz``, ``b_p``,
        ``b_p_meanfield`` (``= b V2 / V1``), ``b_p_par``, ``EY2``, ``EZ2``
        (``E[Y^2]`` and ``E[Z^2]`` integrated over the offset, in d**(dims+1)).
    """
    from ..fields import _passage

    lam = float(rule)
    V1, V2 = float(kernel.V1), float(kernel.V2)
    bp = _passage.length_tensor(kernel, b, b_par, lam)
    mid = bp if lam == 0.5 else _passage.length_tensor(kernel, b, b_par, 0.5)
    b_mf = b * V2 / V1
    EY2 = 8.0 * V1 * (b_mf - mid["xx"])
    u_z = -V1 * flux
    D_xx = V1 * flux * bp["xx"]
    D_zz = V1 * flux * bp["zz"]
    EZ2 = 2.0 * V1 * (bp["zz"] - b_par * V2 / V1)
    return {"u_z": u_z, "D_xx": D_xx, "D_xx_meanfield": flux * b * V2, "D_zz": D_zz,
            "b_p": bp["xx"], "b_p_meanfield": b_mf, "b_p_par": bp["zz"], "EY2": EY2,
            "EZ2": EZ2}


# ---------------------------------------------------------------------------------------
# Measurements
# ---------------------------------------------------------------------------------------
def _da(data, grid, units, long_name, **attrs):
    # CF: lengths in d and times in the case unit are pure numbers (units "1"; "d" would
    # read as a day); the scale goes into the long name and spotpde_units
    return xr.DataArray(data, dims=("z", "x"), attrs={
        "units": "1", "long_name": f"{long_name}, in {units.replace('time', 'time unit')}",
        "spotpde_units": units, **attrs})


def measure(result: MCResult, tracer: bool = True) -> xr.Dataset:
    """Fields of a run as an ``xarray.Dataset`` with the continuum result's names.

    Probe fields (frozen particles at the grid's cell centres, time averages over the
    run, each with a standard error ``*_se`` from the scatter of time batches):

    * ``rho_s``: spot density (spots per d**2);
    * ``u_x``, ``u_z``: mean particle drift ``u_p`` (d per unit time);
    * ``D_xx``, ``D_xz``, ``D_zz``: ``(1/2T) sum w**2 (dR - <dR>)(dR - <dR>)^T``, the
      mean-field particle diffusivity of the continuum (d**2 per unit time).

    With tracked particles, ``tracer=True`` and the default crossing levels (``grid.z``):
    ``P_height`` (density over x of where the tracked particles first cross each height,
    normalised by their number). For other levels call :func:`propagator`.

    Attributes: ``V1``, ``V2``, ``rule``, ``gamma``, ``step``, ``t_end``, ``seed``,
    counters and performance, ``spotpde_version``, ``source = "montecarlo"``.
    """
    g = result.grid
    coords = {"z": ("z", g.z, {"units": "1", "long_name": "height above the orifice, in particle diameters"}),
              "x": ("x", g.x, {"units": "1", "long_name": "horizontal position, in particle diameters"})}
    ds = xr.Dataset(coords=coords)
    if result.probe is not None:
        bt = result.batch_ticks.astype(float) * result.dt  # duration of each batch
        ok = bt > 0
        per = result.probe[:, ok] / bt[ok][None, :, None, None]
        nb = per.shape[1]
        mean = result.probe.sum(axis=1) / result.t_end
        se = per.std(axis=1, ddof=1) / math.sqrt(nb) if nb > 1 else np.full_like(mean, np.nan)
        names = [("u_x", "d / time", "particle drift u_p, x component"),
                 ("u_z", "d / time", "particle drift u_p, z component"),
                 ("D_xx", "d**2 / time", "particle diffusivity D_p, xx"),
                 ("D_xz", "d**2 / time", "particle diffusivity D_p, xz"),
                 ("D_zz", "d**2 / time", "particle diffusivity D_p, zz")]
        for k, (name, units, ln) in enumerate(names):
            f = 1.0 if k < 2 else 0.5
            ds[name] = _da(f * mean[k], g, units, ln + " (Monte Carlo probes)")
            ds[name + "_se"] = _da(f * se[k], g, units, "standard error of " + name)
        h2 = g.spacing**2
        rb = result.rho_hist[ok] / (result.batch_ticks[ok][:, None, None] * h2)
        ds["rho_s"] = _da(result.rho_hist.sum(axis=0) / (result.n_ticks * h2), g, "1 / d**2",
                          "spot density (Monte Carlo)")
        ds["rho_s_se"] = _da(rb.std(axis=0, ddof=1) / math.sqrt(nb) if nb > 1
                             else np.full(g.shape, np.nan), g, "1 / d**2",
                             "standard error of rho_s")
    same_levels = (result.levels.size == g.nz and np.allclose(result.levels, g.z))
    if tracer and result.tracked.size and same_levels:
        ds["P_height"] = propagator(result).assign_coords(z=g.z, x=g.x)
    kp = result.kernel
    ds.attrs.update({
        "V1": kp.V1, "V2": kp.V2, "rule": result.rule, "gamma": result.gamma,
        "step": result.step, "t_end": result.t_end, "seed": result.seed,
        "steps": result.steps, "source": "montecarlo", "spotpde_version": __version__,
        "kernel_walls": result.walls,
        **{k: v for k, v in result.counters.items()},
        **{k: v for k, v in result.performance.items()},
    })
    return ds


def particle_frames(result: MCResult, layer_spacing: float | None = None) -> xr.Dataset:
    """Tracked particle positions as a Dataset on dims ``("t", "particle")``.

    Frame 0 is the initial state (``t = 0``), then one frame per snapshot. With
    ``layer_spacing`` a boolean ``layer`` variable marks particles that started in the
    coloured bands ``[k s, k s + s/2)`` (the layered-silo picture, docs/interface.md, ``tracer.layers``),
    so the discrete layered silo is ``plt.scatter(f.x[k], f.z[k], c=f.layer)``.
    """
    start = result.initial[result.tracked]
    pos = np.concatenate([start[None], result.positions], axis=0)
    t = np.concatenate([[0.0], result.times])
    ds = xr.Dataset(
        {"x": (("t", "particle"), pos[..., 0], {"units": "1", "long_name": "particle x (NaN: gone), in particle diameters"}),
         "z": (("t", "particle"), pos[..., 1], {"units": "1", "long_name": "particle z (NaN: gone), in particle diameters"})},
        coords={"t": ("t", t, {"units": "1", "long_name": "time, in the case's time unit"}),
                "particle": ("particle", result.tracked)})
    if layer_spacing is not None:
        ds["layer"] = ("particle", layer_mask(start[:, 1], layer_spacing),
                       {"units": "1", "long_name": f"started in a coloured band (spacing {layer_spacing} d)"})
    return ds


def propagator(result: MCResult, select: np.ndarray | None = None) -> xr.DataArray:
    """Geometrical propagator ``P_height`` of the tracked particles.

    At each crossing level (``result.levels``; by default the grid's cell centres), the
    density over x of where the selected tracked particles first fell through it: a
    histogram over the grid's x cells divided by (number of particles * h). Its integral
    over x is the fraction that reached that height.

    Args:
        result: a run with tracked particles.
        select: boolean mask over the tracked particles (default all).
    """
    g = result.grid
    cx = result.cross_x if select is None else result.cross_x[np.asarray(select)]
    n = max(cx.shape[0], 1)
    edges = np.concatenate([g.x - 0.5 * g.spacing, [g.x[-1] + 0.5 * g.spacing]])
    out = np.zeros((result.levels.size, g.nx))
    for k in range(result.levels.size):
        v = cx[:, k]
        v = v[np.isfinite(v)]
        out[k] = np.histogram(v, bins=edges)[0] / (n * g.spacing)
    return xr.DataArray(out, dims=("z", "x"),
                        coords={"z": ("z", result.levels, {"units": "1", "long_name": "in particle diameters"}), "x": ("x", g.x, {"units": "1", "long_name": "in particle diameters"})},
                        attrs={"units": "1", "spotpde_units": "1 / d", "long_name":
                               "geometrical propagator: density over x of first crossings of height z "
                               "(Monte Carlo), per particle diameter", "n_particles": int(cx.shape[0])})


def _windows(result: MCResult, select=None):
    """Displacement increments of tracked particles between consecutive snapshots.

    Returns (dx, dz, tau, start) with dx, dz of shape (n_windows, n_tracked) (NaN where a
    particle was gone at either end), tau the window durations, start the positions at
    each window's start (n_windows, n_tracked, 2).
    """
    pos = np.concatenate([result.initial[result.tracked][None], result.positions], axis=0)
    times = np.concatenate([[0.0], result.times])
    if select is not None:
        pos = pos[:, np.asarray(select)]
    d = pos[1:] - pos[:-1]
    return d[..., 0], d[..., 1], np.diff(times), pos[:-1]


def displacement_statistics(result: MCResult, select=None, skip: int = 0) -> dict:
    """Lagrangian drift, diffusivities and diffusion lengths of the tracked particles.

    Windows are the intervals between snapshots. In each window ``k`` the mean over
    particles of ``dx``, ``dz`` and of the centred squares gives ``U_k``, ``D_k``; the
    results are the window averages and their standard errors (windows are nearly
    independent when long compared with a spot's passage). Intended for uniform flow
    (spatially uniform statistics).

    Args:
        result: a run with tracked particles and several snapshots.
        select: boolean mask over tracked particles (e.g. away from walls).
        skip: number of initial windows to drop (transient).

    Returns:
        dict with ``u_x``, ``u_z`` (d/time), ``D_xx``, ``D_zz``, ``D_xz`` (d**2/time),
        ``b_p = D_xx / |u_z|`` and ``b_p_par = D_zz / |u_z|`` (d), each with ``*_se``,
        and ``n_windows``, ``n_particles``.
    """
    dx, dz, tau, _ = _windows(result, select)
    dx, dz, tau = dx[skip:], dz[skip:], tau[skip:]
    ok = np.isfinite(dx) & np.isfinite(dz)
    keep = ok.all(axis=0)
    dx, dz = dx[:, keep], dz[:, keep]
    ux = dx.mean(axis=1) / tau
    uz = dz.mean(axis=1) / tau
    mx = dx.mean()  # the drift is common to all windows when tau is constant
    mz = dz.mean()
    Dxx = ((dx - mx) ** 2).mean(axis=1) / (2 * tau)
    Dzz = ((dz - mz) ** 2).mean(axis=1) / (2 * tau)
    Dxz = ((dx - mx) * (dz - mz)).mean(axis=1) / (2 * tau)
    n = ux.size
    out = {"n_windows": n, "n_particles": int(keep.sum())}
    for name, v in (("u_x", ux), ("u_z", uz), ("D_xx", Dxx), ("D_zz", Dzz), ("D_xz", Dxz)):
        out[name] = float(v.mean())
        out[name + "_se"] = float(v.std(ddof=1) / math.sqrt(n)) if n > 1 else math.nan
    # ratios with jackknife errors over windows
    for name, num in (("b_p", Dxx), ("b_p_par", Dzz)):
        est = num.mean() / abs(uz.mean())
        if n > 2:
            jk = np.array([np.delete(num, i).mean() / abs(np.delete(uz, i).mean()) for i in range(n)])
            se = math.sqrt((n - 1) / n * np.sum((jk - jk.mean()) ** 2))
        else:
            se = math.nan
        out[name] = float(est)
        out[name + "_se"] = float(se)
    return out


def velocity_correlation(result: MCResult, bins: np.ndarray, select=None, component: str = "x",
                         skip: int = 0, centre: str = "ensemble") -> xr.Dataset:
    """Spatial correlation of tracked particles' displacement fluctuations.

    ``C(r) = <dq_i dq_j> / <dq**2>`` over pairs whose separation at the window's start
    falls in each bin, the discrete counterpart of the continuum ``C_p(r)`` (eq. Cp).
    ``dq`` is the displacement component minus the mean drift of the whole run (mean
    rate over all windows and particles, times the window's duration). Standard errors
    from the scatter over windows (make windows longer than a spot's passage, ``2R/v_s``).

    ``centre="window"`` subtracts each window's own mean over its ``N`` particles instead;
    that removes the common displacement the particles share and biases ``C`` low by about
    ``2/N sum_k C(r_ik)`` (-0.02 to -0.04 for 150 particles on a 1.5 d lattice with a
    Gaussian kernel of sigma 1): kept only to show the bias.

    Args:
        bins: separation bin edges in d.
        select: boolean mask over tracked particles. component: ``"x"`` or ``"z"``.
        skip: number of initial windows to drop.
        centre: ``"ensemble"`` (default, unbiased) or ``"window"``.

    Returns:
        Dataset with ``C`` and ``C_se`` on dim ``r`` (the mean separation of the pairs in
        each bin, d) and ``pairs``; bins with pairs in fewer than two windows (no
        standard error) are left out.
    """
    if centre not in ("ensemble", "window"):
        raise ValueError(f"centre: must be 'ensemble' or 'window', got {centre!r}")
    dx, dz, tau, start = _windows(result, select)
    d = (dx if component == "x" else dz)[skip:]
    tau = tau[skip:]
    start = start[skip:]
    with np.errstate(invalid="ignore"):
        rate = float(np.nanmean(d / tau[:, None]))
    bins = np.asarray(bins, float)
    nbin = bins.size - 1
    per = np.full((d.shape[0], nbin), np.nan)
    pairs = np.zeros(nbin, np.int64)
    rsum = np.zeros(nbin)
    for k in range(d.shape[0]):
        ok = np.isfinite(d[k])
        q = d[k, ok] - (d[k, ok].mean() if centre == "window" else rate * tau[k])
        p = start[k, ok]
        var = np.mean(q * q)
        iu, ju = np.triu_indices(q.size, 1)
        r = np.hypot(*(p[iu] - p[ju]).T)
        which = np.digitize(r, bins) - 1
        good = (which >= 0) & (which < nbin)
        prod = q[iu][good] * q[ju][good] / var
        s = np.bincount(which[good], weights=prod, minlength=nbin)
        c = np.bincount(which[good], minlength=nbin)
        per[k] = np.where(c > 0, s / np.maximum(c, 1), np.nan)
        pairs += c
        rsum += np.bincount(which[good], weights=r[good], minlength=nbin)
    n = np.sum(np.isfinite(per), axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        C = np.array([np.mean(c[np.isfinite(c)]) if m else np.nan for c, m in zip(per.T, n)])
        se = np.array([np.std(c[np.isfinite(c)], ddof=1) / math.sqrt(m) if m > 1 else np.nan
                       for c, m in zip(per.T, n)])
        rc = np.where(pairs > 0, rsum / np.maximum(pairs, 1), np.nan)
    keep = n >= 2   # pairs in at least two windows: a mean and a standard error
    C, se, pairs, rc = C[keep], se[keep], pairs[keep], rc[keep]
    return xr.Dataset(
        {"C": ("r", C, {"units": "1", "long_name": f"velocity correlation C_p ({component}), Monte Carlo"}),
         "C_se": ("r", se, {"units": "1", "long_name": "standard error of C"}),
         "pairs": ("r", pairs, {"units": "1", "long_name": "pair samples per bin"})},
        coords={"r": ("r", rc, {"units": "1", "long_name": "separation, in particle diameters"})})
