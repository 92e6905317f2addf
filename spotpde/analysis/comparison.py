"""The spot model's mean particle flow against the Kinematic Model, height by height.

The mean (Eulerian) particle velocity a kinematic model describes is the flux velocity
``u_f = u_p - div D_p`` (docs/conventions.md section 3; :func:`spotpde.coefficients.flux_velocity`).
The Kinematic Model with the same ``b`` and orifice, carrying the flux ``V1 Q0``, is
``v_kin`` (downward speed, ``dv/dz = b lap_perp v``) with ``u_perp = b grad_perp v_kin``.

In the local limit with constant coefficients and ``D_par = 0``
(docs/coefficients.md)::

    -u_f,z   = V1 v_s rho_s                         = v_kin      (any rule)
    u_f,perp = (2 lam V1 - V2) b v_s grad_perp rho_s = (2 lam - V2/V1) b grad_perp v

so the downward speeds agree for every ``lam`` while the horizontal (converging)
velocity matches the kinematic ``b grad_perp v`` only for ``lam = 1/2 + V2 / (2 V1)``:
the midpoint rule is off by the factor ``1 - V2/V1`` (``V2/V1 = w`` for a uniform
kernel, 0.24 % with the paper's numbers), the printed end-point rule ``lam = 1`` by
``2 - V2/V1``: its particles converge about twice as fast as the downward speed allows,
so the mean flow is compressible (``div u_f != 0``) and its streamlines differ.

:func:`compare_with_kinematic` measures all of this on a case: per height the relative
L2 difference of the downward speeds, the effective ``b`` of Gaussian fits to both
profiles, the effective ``b`` of the horizontal flux velocity (least-squares
``u_f,x = b_h d_x v_spot``), the incompressibility defect, and streamlines of both flows.
In a cylinder the same radially (ring-area weights, Fourier-Bessel fits:
:func:`spotpde.density.kinematic.cylinder_profile`); in a hopper on the cells whose kernel
sees only material (``_compare_geometry``; no width fits: NaN).
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.optimize import OptimizeWarning, curve_fit

from . import _compare_geometry as _shape
from ..fields import coefficients
from ..density import kinematic, spot_density
from .._figures import figure_format, prepare_matplotlib, save_figure
from ..grid import Grid
from ..parameters import RULE_RANGE

__all__ = ["KinematicComparison", "compare_with_kinematic", "compare_rules", "case_problems",
           "gaussian_width2", "plot_comparison"]


@dataclasses.dataclass
class KinematicComparison:
    """Per-height comparison of the spot-model mean flow with the Kinematic Model.

    Attributes:
        rule: lam used for the spot model.
        b: the spots' horizontal diffusion length (the kinematic model's ``b``), d.
        V1, V2: kernel interaction volumes, d**dims.
        z: compared heights (cell centres), d.
        speed_l2: ``||v_spot - v_kin|| / ||v_kin||`` across each height, with
            ``v_spot = -u_f,z`` the spot model's mean downward speed.
        width2_spot, width2_kin: squared widths ``2 s`` of the Kinematic Model with the
            case's orifice and walls fitted to each profile (``spotpde.kinematic.fit_profile``;
            3D: of Gaussian fits)
            ``A exp(-(x - x0)**2 / (2 s**2))`` to the two speed profiles, d**2.
        b_speed_spot, b_speed_kin: effective ``b = (1/2) d(width2)/dz`` of those fits, d
            (the Kinematic Model's own reads its ``b``).
        b_horizontal: least-squares ``b_h`` in ``u_f,x = b_h d_x v_spot``, d (the
            kinematic model has ``b_h = b``).
        horizontal_l2: ``||u_f,x - b d_x v_kin|| / ||b d_x v_kin||`` across each height.
        defect: ``||div u_f|| / ||d_z v_spot||`` across each height (0: incompressible).
        flux_deficit: ``1 - integral(v_spot dA) / (V1 Q0)`` per height (whole cross
            section), the particle flux lost because spots near a wall move no particles
            beyond it.
        starts: streamline start points ``(m, dims)``.
        streamlines_spot, streamlines_kin: paths ``(n, dims)`` (columns ``x, [y,] z``).
        streamline_shift: per start, ``|x_spot - x_kin|`` at the height ``shift_height``.
        shift_height: where the streamlines are compared, d.
        horizontal: the horizontal coordinate, ``"x"`` or ``"r"`` (a cylinder).

    All per-height numbers except ``flux_deficit`` use the columns farther than the
    kernel's horizontal reach from the side walls (3D: the plane through the orifice).
    In a cylinder (``domain.coordinates = "axisymmetric"``) the profiles are radial: the
    rings farther than the reach from the wall ``r = a`` (the axis is no wall), norms and
    least squares weighted by the ring areas ``2 pi r h``, widths from the Fourier-Bessel
    series (:func:`spotpde.density.kinematic.fit_radial_profile`), the flux through the
    whole cross-section ``integral 2 pi r v dr``. In a hopper (wedge, cone) each height
    uses its cells farther than the reach plus a cell from the walls at the kernel's
    lowest height; the widths and ``b_speed_*`` are NaN (no closed form between walls).
    """

    rule: float
    b: float
    V1: float
    V2: float
    z: np.ndarray
    speed_l2: np.ndarray
    width2_spot: np.ndarray
    width2_kin: np.ndarray
    b_speed_spot: np.ndarray
    b_speed_kin: np.ndarray
    b_horizontal: np.ndarray
    horizontal_l2: np.ndarray
    defect: np.ndarray
    flux_deficit: np.ndarray
    starts: np.ndarray
    streamlines_spot: list
    streamlines_kin: list
    streamline_shift: np.ndarray
    shift_height: float
    horizontal: str = "x"

    def summary(self) -> dict[str, float]:
        """Medians over the compared heights, and the largest streamline shift."""
        def med(a):
            a = np.asarray(a, dtype=float)
            return float(np.nanmedian(a)) if np.any(np.isfinite(a)) else float("nan")

        return {
            "rule": self.rule,
            "b": self.b,
            "V2/V1": self.V2 / self.V1,
            "speed_l2": med(self.speed_l2),
            "b_speed_spot": med(self.b_speed_spot),
            "b_speed_kin": med(self.b_speed_kin),
            "b_horizontal": med(self.b_horizontal),
            "b_horizontal/b": med(self.b_horizontal) / self.b,
            "horizontal_l2": med(self.horizontal_l2),
            "defect": med(self.defect),
            "flux_deficit": med(self.flux_deficit),
            "streamline_shift_max": float(np.nanmax(self.streamline_shift))
            if self.streamline_shift.size else float("nan"),
        }


def _parts(case_or_parts):
    """(grid, orifice, spots, kernel, rule, rho_s or None) from a Case or a mapping."""
    if isinstance(case_or_parts, Mapping):
        p = case_or_parts
        missing = [k for k in ("grid", "orifice", "spots", "kernel") if k not in p]
        if missing:
            raise ValueError(f"compare_with_kinematic: parts lack {missing}; need grid, orifice, "
                             "spots, kernel (optional: rule, rho_s)")
        return p["grid"], p["orifice"], p["spots"], p["kernel"], p.get("rule", 0.5), p.get("rho_s")
    c = case_or_parts
    for attr in ("grid", "orifice", "spots", "kernel", "rule"):
        if not hasattr(c, attr):
            raise ValueError("compare_with_kinematic: expected a spotpde Case or a mapping with "
                             f"grid, orifice, spots, kernel; got {type(c).__name__} without {attr!r}")
    return c.grid, c.orifice, c.spots, c.kernel, c.rule, None


def _compared_rows(grid: Grid, kernel, z_min: float | None = None) -> np.ndarray:
    """Indices of the compared heights: from ``z_min`` (default 10 % of the height) up to
    the kernel's vertical reach below the top (no spots above it)."""
    z0, z1 = grid.z_range
    z_min = z0 + 0.1 * (z1 - z0) if z_min is None else float(z_min)
    top = z1 - float(kernel.reach[1]) - grid.spacing
    return np.nonzero((grid.z >= z_min) & (grid.z <= top))[0]


def _compared_cols(grid: Grid, kernel) -> np.ndarray:
    """Indices of the columns farther than the kernel's reach from the side walls (near a
    wall the zero padding, no particles or spots beyond it, lowers ``v_spot``: reported
    as ``flux_deficit``)."""
    reach_h = float(kernel.reach[0])
    x0, x1 = grid.x_range
    low = grid.x - x0 > reach_h if not grid.geometry.has_axis else True   # the axis: no wall
    return np.nonzero(low & (x1 - grid.x > reach_h))[0]


def case_problems(case, rules: Sequence[float] = ()) -> list[str]:
    """What keeps :func:`compare_rules` from comparing a validated case with the
    Kinematic Model, one line per problem naming the case key (``spotpde compare``
    prints them and exits with status 2).

    Args:
        case: a :class:`spotpde.cases.Case`.
        rules: the rules ``lam`` asked for (``spotpde compare --rules``): each in
            ``kernel.rule``'s range (0, 1].

    Returns:
        The problems (empty: the comparison can run).
    """
    problems = []
    lo, hi = RULE_RANGE
    bad = [r for r in rules if not lo < r <= hi]
    if bad:
        problems.append(f"--rules: each rule must be in ({lo:g}, {hi:g}] like kernel.rule, "
                        f"got {', '.join(f'{r:g}' for r in bad)}")
    if case.spots.rho_max is not None:
        problems.append("spots.rho_max: interacting spots have no steady state to compare "
                        "with the steady Kinematic Model; remove spots.rho_max (and "
                        'spots.mode = "transient") to compare spots that do not interact')
    if case.comparison.rate != "constant":
        key = "orifice.noise" if case.comparison.rate == "noise" else "orifice.rate"
        problems.append(f"{key}: the comparison needs a constant rate Q0 (the steady flow)")
    for key in case.comparison.profiles:
        problems.append(f"spots.{key}: the Kinematic Model has one b and one speed; "
                        "give a number, not a profile")
    if problems:
        return problems
    kernel = case.kernel
    rows = _compared_rows(case.grid, kernel)
    if rows.size < 3:
        problems.append(f"domain.z: too short to compare: {rows.size} heights between 10 % "
                        "of the height and the kernel's vertical reach "
                        f"({float(kernel.reach[1]):g} d) below the top, need 3")
    cols = _compared_cols(case.grid, kernel)
    if cols.size < 5:
        problems.append(f"domain.x: too narrow to compare: fewer than 5 columns farther "
                        f"than the kernel's reach ({float(kernel.reach[0]):g} d) from the "
                        "side walls")
    elif rows.size >= 3 and _shape.hopper_cells(case.grid, kernel, rows, cols)[0].size < 3:
        problems.append("domain.hopper_angle: the hopper is too narrow to compare: fewer "
                        "than 3 heights with 5 columns farther than the kernel's reach "
                        f"({float(kernel.reach[0]):g} d) inside its walls")
    return problems


def gaussian_width2(x: np.ndarray, profile: np.ndarray) -> float:
    """Squared width ``s**2`` of a least-squares Gaussian ``A exp(-(x - x0)**2 / (2 s**2))``.

    Args:
        x: positions, d.
        profile: non-negative values at ``x``.

    Returns:
        ``s**2`` in d**2 (NaN if the fit fails).
    """
    p = np.asarray(profile, dtype=float)
    total = p.sum()
    if not np.isfinite(total) or total <= 0:
        return float("nan")
    m = (x * p).sum() / total
    var = ((x - m) ** 2 * p).sum() / total
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OptimizeWarning)  # covariance not needed
            popt, _ = curve_fit(lambda x, A, x0, s2: A * np.exp(-(x - x0) ** 2 / (2 * s2)), x, p,
                                p0=(p.max(), m, max(var, 1e-6)), maxfev=2000)
    except (RuntimeError, ValueError):
        return float("nan")
    return float(popt[2])


def _row(grid: Grid, a: np.ndarray, y_index: int) -> np.ndarray:
    """The ``(z, x)`` plane through ``y_index`` (3D) or the array itself (2D)."""
    return a if grid.dims == 2 else a[:, y_index, :]


def _norm_rows(a: np.ndarray, w=1.0) -> np.ndarray:
    """Norm of each row, weighted by ``w`` (a cylinder's ring areas; 1 in a box)."""
    return np.sqrt(np.sum(w * a * a, axis=-1))


def _path_x_at(path: np.ndarray, z: float) -> float:
    """Horizontal position where a downward path crosses height ``z`` (NaN if never)."""
    zz = path[:, -1]
    below = np.nonzero(zz <= z)[0]
    if below.size == 0 or below[0] == 0:
        return float("nan")
    i = below[0]
    t = (z - zz[i - 1]) / (zz[i] - zz[i - 1])
    return float(path[i - 1, 0] + t * (path[i, 0] - path[i - 1, 0]))


def compare_with_kinematic(case_or_parts, rule: float | None = None, *, z_min: float | None = None,
                           n_streamlines: int = 7, start_height: float | None = None,
                           shift_height: float | None = None, _shared: dict | None = None
                           ) -> KinematicComparison:
    """Compare the spot model's mean particle flow with the Kinematic Model.

    Args:
        case_or_parts: a :class:`spotpde.cases.Case`, or a mapping with ``grid``,
            ``orifice``, ``spots``, ``kernel`` and optionally ``rule``, ``rho_s`` and
            ``walls`` (``kernel.walls``: ``"renormalise"``, the default, or ``"truncate"``).
        rule: lam for the spot model (default: the case's).
        z_min: lowest compared height, d (default: 10 % of the height, away from the
            orifice singularity; fits need at least 3 heights). Heights within the
            kernel's vertical reach of the top are left out.
        n_streamlines: number of streamlines of each flow (starts spread over the middle
            half of the width at ``start_height``).
        start_height: where streamlines start, d (default 90 % of the height).
        shift_height: where streamlines are compared, d (default 25 % of the height).

    Returns:
        :class:`KinematicComparison`. The spot fields use the steady spot density of the
        case; ``b`` must be uniform (the kinematic model's single ``b``).
    """
    grid, orifice, spots, kernel, case_rule, rho_s = _parts(case_or_parts)
    lam = float(case_rule if rule is None else rule)
    if np.ndim(spots.b) != 0 or np.ndim(spots.drift) != 0:
        raise ValueError("case_or_parts: spots.b and spots.drift must be uniform "
                         "(the kinematic model has one b)")
    if rho_s is None and spots.rho_max is not None:
        raise ValueError("case_or_parts: interacting spots (spots.rho_max) have no steady "
                         "spot density to compare; give rho_s")
    b = float(spots.b)
    shared = {} if _shared is None else _shared
    if rho_s is None:
        if "rho_s" not in shared:
            shared["rho_s"] = spot_density.steady(grid, orifice, spots)
        rho_s = shared["rho_s"]
    V1, V2 = float(kernel.V1), float(kernel.V2)
    if "kin" not in shared:
        flux = V1 * orifice.rate_at(0.0)
        kin = kinematic.velocity(grid, orifice, b)
        shared["kin"] = {k: v * flux for k, v in kin.items()}
    kin = shared["kin"]

    # kernel.walls of a case (a mapping may give "walls"); default: renormalise
    walls = (case_or_parts.get("walls", "renormalise") if isinstance(case_or_parts, Mapping)
             else getattr(case_or_parts, "kernel_walls", "renormalise"))
    fields = coefficients.particle_fields(grid, rho_s, spots, kernel, rule=lam, walls=walls)
    flow = coefficients.flux_velocity(grid, fields)
    defect_field = coefficients.incompressibility_defect(grid, fields)

    h = grid.spacing
    z0, z1 = grid.z_range
    rows = _compared_rows(grid, kernel, z_min)
    if rows.size < 3:
        raise ValueError(f"z_min: leaves {rows.size} heights to compare, need at least 3")
    yi = int(np.argmin(np.abs(grid.y - (orifice.y if orifice.y is not None else grid.y_centre)))) \
        if grid.dims == 3 else 0

    reach_h = float(kernel.reach[0])
    x0, x1 = grid.x_range
    cols = _compared_cols(grid, kernel)
    if cols.size < 5:
        raise ValueError(f"case_or_parts: the domain is too narrow for the kernel reach "
                         f"{reach_h:g} d to leave columns away from the walls")
    rows, inside = _shape.hopper_cells(grid, kernel, rows, cols)   # (None: no hopper)
    if rows.size < 3:
        raise ValueError(f"case_or_parts: the hopper is too narrow for the kernel reach "
                         f"{reach_h:g} d to leave 3 heights of 5 columns inside its walls")
    sel = np.ix_(rows, cols)
    full_v_spot = _row(grid, -flow["u_z"], yi)
    horizontal_axes = tuple(range(1, grid.dims))
    curved = grid.geometry.curved       # a cylinder: radial profiles, ring-area weights
    flux_deficit = 1.0 - (-flow["u_z"][rows] * grid.geometry.horizontal_measures).sum(
        axis=horizontal_axes) / (V1 * orifice.rate_at(0.0))
    w = grid.geometry.horizontal_measures[cols] if curved else 1.0
    if inside is not None:          # a hopper: the cells beyond the reach from its walls
        w = w * inside
    hkey = grid.geometry.drift_keys[0]
    v_spot = full_v_spot[sel]
    v_kin = _row(grid, -kin["u_z"], yi)[sel]
    ux_spot = _row(grid, flow[hkey], yi)[sel]
    ux_kin = _row(grid, kin[hkey], yi)[sel]
    dx_v_spot = (_shape.radial_gradient(full_v_spot, h) if curved
                 else np.gradient(full_v_spot, h, axis=-1, edge_order=2))[sel]
    dz_v_spot = np.gradient(full_v_spot, h, axis=0, edge_order=2)[sel]
    defect = _norm_rows(_row(grid, defect_field, yi)[sel], w) / _norm_rows(dz_v_spot, w)

    speed_l2 = _norm_rows(v_spot - v_kin, w) / _norm_rows(v_kin, w)
    horizontal_l2 = _norm_rows(ux_spot - ux_kin, w) / _norm_rows(ux_kin, w)
    b_h = np.sum(w * ux_spot * dx_v_spot, axis=-1) / np.sum(w * dx_v_spot**2, axis=-1)
    w2_spot, w2_kin = _profile_widths(grid, orifice, cols, (v_spot, v_kin), inside)
    zc = grid.z[rows]
    b_spot = 0.5 * np.gradient(w2_spot, zc)
    b_kin = 0.5 * np.gradient(w2_kin, zc)

    start_height = z0 + 0.9 * (z1 - z0) if start_height is None else float(start_height)
    shift_height = z0 + 0.25 * (z1 - z0) if shift_height is None else float(shift_height)
    starts, paths_spot, paths_kin, shift = _streamlines(
        grid, orifice, (flow, kin), yi, n_streamlines, start_height, shift_height)

    return KinematicComparison(
        rule=lam, b=b, V1=V1, V2=V2, z=zc, speed_l2=speed_l2, width2_spot=w2_spot,
        width2_kin=w2_kin, b_speed_spot=b_spot, b_speed_kin=b_kin, b_horizontal=b_h,
        horizontal_l2=horizontal_l2, defect=defect, flux_deficit=flux_deficit, starts=starts,
        streamlines_spot=paths_spot,
        streamlines_kin=paths_kin, streamline_shift=shift, shift_height=shift_height,
        horizontal="r" if curved else "x")


def _profile_widths(grid, orifice, cols, profiles, inside):
    """``(s**2 of the spot flow, s**2 of the Kinematic Model)`` at each compared height:
    the Kinematic Model's profile for this orifice and these walls fitted to each
    downward-speed profile (a plain Gaussian's width would be biased by the walls and
    the slot; ``b = d(s**2 / 2)/dz``); radial in a cylinder, Gaussian in 3D, NaN in a
    hopper (``inside`` given: no closed form between its walls)."""
    v_spot, v_kin = profiles
    if inside is not None:
        nan = np.full(len(v_spot), np.nan)
        return nan, nan.copy()
    if grid.dims == 2:
        fit = kinematic.fit_radial_profile if grid.geometry.curved else kinematic.fit_profile
        walled = [[fit(grid.x[cols], p, orifice, grid.x_range, grid.walls)[0]
                   for p in prof] for prof in (v_spot, v_kin)]
        return tuple(2.0 * np.asarray(sv) for sv in walled)
    return (np.array([gaussian_width2(grid.x[cols], p) for p in v_spot]),
            np.array([gaussian_width2(grid.x[cols], p) for p in v_kin]))


def _streamlines(grid, orifice, flows, yi, n, start_height, shift_height):
    """Streamlines of both flows (spot, kinematic) from the same ``n`` starts spread over
    the middle half of the width at ``start_height`` (d), by the same integrator, and
    their horizontal distance at ``shift_height`` (d). Returns ``(starts, spot paths,
    kinematic paths, shifts)``."""
    flow, kin = flows
    h = grid.spacing
    x0, x1 = grid.x_range
    xc = orifice.x
    half = 0.25 * (x1 - x0)
    xs = _shape.streamline_starts(grid, np.linspace(max(x0 + h, xc - half),
                                                    min(x1 - h, xc + half), n),
                                  start_height, xc)
    if grid.dims == 2:
        starts = np.column_stack([xs, np.full_like(xs, start_height)])
    else:
        starts = np.column_stack([xs, np.full_like(xs, grid.y[yi]),
                                  np.full_like(xs, start_height)])
    if n <= 0:
        return starts, [], [], np.zeros(0)
    paths_spot = kinematic.streamlines(flow, grid, starts)
    paths_kin = kinematic.streamlines(kin, grid, starts)
    shift = np.array([abs(_path_x_at(p, shift_height) - _path_x_at(q, shift_height))
                      for p, q in zip(paths_spot, paths_kin)])
    return starts, paths_spot, paths_kin, shift



def compare_rules(case_or_parts, rules: Sequence[float] = (0.5, 1.0), **kwargs
                  ) -> dict[float, KinematicComparison]:
    """:func:`compare_with_kinematic` for several rules, sharing ``rho_s`` and ``v_kin``.

    Args:
        case_or_parts: as :func:`compare_with_kinematic`.
        rules: the lam values to compare.
        **kwargs: passed on to :func:`compare_with_kinematic`.

    Returns:
        ``{lam: KinematicComparison}``.
    """
    shared: dict = {}
    return {float(r): compare_with_kinematic(case_or_parts, r, _shared=shared, **kwargs)
            for r in rules}


def plot_comparison(comparisons: Mapping[float, KinematicComparison], path=None):
    """Figure: speed difference, effective b (vertical and horizontal), streamlines.

    Args:
        comparisons: ``{lam: KinematicComparison}`` (e.g. from :func:`compare_rules`).
        path: where to save the figure (the format of its extension, written
            atomically: :func:`spotpde._figures.save_figure`); ``None`` returns the
            figure unsaved.

    Returns:
        The matplotlib figure.
    """

    if path is not None:
        figure_format(path)          # an unsupported extension: refused before drawing
    prepare_matplotlib()
    from matplotlib.figure import Figure

    fig = Figure(figsize=(13, 4.2), layout="tight")   # off-screen, no pyplot state
    ax = fig.subplots(1, 3)
    for i, (lam, c) in enumerate(comparisons.items()):
        colour = f"C{i}"
        ax[0].semilogy(c.z, c.speed_l2, color=colour, label=f"speed, rule {lam:g}")
        ax[0].semilogy(c.z, c.horizontal_l2, "--", color=colour,
                       label=f"horizontal, rule {lam:g}")
        ax[1].plot(c.z, c.b_speed_spot, color=colour, label=f"b from v_spot, rule {lam:g}")
        ax[1].plot(c.z, c.b_horizontal, "--", color=colour, label=f"b from u_x, rule {lam:g}")
        for j, p in enumerate(c.streamlines_spot):
            ax[2].plot(p[:, 0], p[:, -1], color=colour, lw=1.2,
                       label=f"rule {lam:g}" if j == 0 else None)
    first = next(iter(comparisons.values()))
    ax[1].plot(first.z, first.b_speed_kin, "k:", label="b from v_kin")
    for j, p in enumerate(first.streamlines_kin):
        ax[2].plot(p[:, 0], p[:, -1], "k:", lw=1.2, label="kinematic" if j == 0 else None)
    ax[0].set(xlabel="z (d)", ylabel="relative L2 difference", title="spot vs kinematic")
    ax[1].set(xlabel="z (d)", ylabel="effective b (d)")
    ax[2].set(xlabel=f"{first.horizontal} (d)", ylabel="z (d)",
              title="streamlines (dotted: kinematic)")
    for a in ax:
        a.legend(fontsize=7)
    if path is not None:
        save_figure(fig, path, dpi=120)
    return fig

