"""The Void Model's closed forms, its 1D reference marcher and the lattice void model
(private; :mod:`spotpde.fields.void` re-exports every public name here).

Point orifice, unbounded silo: the void density, the Brownian-bridge moments of the
geometrical propagator and the printed eq. Pcp's moments, the propagators built from
them, the right-hand sides of both forms of the propagator equation and a marcher in the
fall variable; the lattice void model solved by a transfer matrix and by a Monte Carlo
of particles displaced by voids. Lengths in particle diameters d, ``z`` up, orifice at
``(x, z) = (0, 0)``; ``b`` in d per horizontal component (docs/void_model.md).
"""

from __future__ import annotations

from typing import Callable, Sequence

import numba
import numpy as np
from scipy.linalg import solve_banded

#: Staggered ("triangular-like") lattice: a void steps up one row and left or right by
#: one site with probability 1/2 each. Step variance 1 site**2 per row: ``b = 1/2``
#: in lattice units (site spacing = row spacing = 1).
STAGGERED: tuple[tuple[int, float], ...] = ((-1, 0.5), (1, 0.5))

FORMS = ("derived", "printed")


# ---------------------------------------------------------------------------------------
# Closed forms for a point orifice
# ---------------------------------------------------------------------------------------
def point_void_density(x, z, b: float, dims: int = 2) -> np.ndarray:
    """Void (spot) density of a point orifice in an unbounded silo, per unit ``Q0 / v_s``.

    Solves ``d rho_v/dz = b lap_perp rho_v`` (eq. rhov) with ``rho_v -> delta(x)`` as
    ``z -> 0``: ``exp(-r**2 / 4bz) / (4 pi b z)**(d_h / 2)``.

    Args:
        x: horizontal position in d; in 3D a pair ``(x, y)`` of broadcastable arrays.
        z: height above the orifice in d (> 0).
        b: void diffusion length in d.
        dims: 2 or 3.

    Returns:
        Density in 1/d**(dims-1) (integral over the horizontal section is 1).
    """
    z = np.asarray(z, dtype=float)
    r2, d_h = _radius2(x, dims)
    return np.exp(-r2 / (4.0 * b * z)) / (4.0 * np.pi * b * z) ** (d_h / 2.0)


def bridge_moments(z, x0, z0: float, b: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of one horizontal coordinate of a void-model particle at height z.

    Brownian bridge in the fall variable ``s = z0 - z`` from ``x0`` to the orifice:
    ``mean = x0 z / z0``, ``var = 2 b z (z0 - z) / z0`` (derived in docs/void_model.md).

    Args:
        z: height(s) in d, ``0 <= z <= z0``.
        x0: release position (one horizontal component) in d, relative to the orifice.
        z0: release height in d.
        b: void diffusion length in d.

    Returns:
        ``(mean, variance)`` in d and d**2.
    """
    z = np.asarray(z, dtype=float)
    return np.asarray(x0, dtype=float) * z / z0, 2.0 * b * z * (z0 - z) / z0


def printed_moments(z, x0, z0: float, b: float) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance predicted by the printed eq. Pcp for a point orifice.

    The printed drift per unit fall is ``-b d_x log rho_v = x / 2z``, so (with
    ``dm/ds = m / 2z`` and ``dV/ds = V / z + 2b``, ``s = z0 - z``)::

        mean = x0 sqrt(z0 / z),   var = b (z0**2 - z**2) / z

    Both diverge as ``z -> 0``: the particle never reaches the orifice.

    Args:
        z: height(s) in d, ``0 < z <= z0``.
        x0: release position (one component) in d.
        z0: release height in d.
        b: diffusion length in d.

    Returns:
        ``(mean, variance)`` in d and d**2.
    """
    z = np.asarray(z, dtype=float)
    return np.asarray(x0, dtype=float) * np.sqrt(z0 / z), b * (z0**2 - z**2) / z


def geometric_propagator(x, z, x0, z0: float, b: float, dims: int = 2) -> np.ndarray:
    """Closed-form geometrical propagator of the void model for a point orifice.

    ``P(x | z; x0, z0)``: density over horizontal position of a particle released at
    ``(x0, z0)`` when it crosses height ``z``. It solves
    ``-dP/dz = b div_perp(grad_perp P - 2 P grad_perp log rho_v)`` with the point-orifice
    ``rho_v``; each horizontal component is an independent Brownian bridge
    ``N(x0 z / z0, 2 b z (z0 - z) / z0)``. Equivalently (Doob transform)
    ``P = rho_v(x, z) G(x0 - x, z0 - z) / rho_v(x0, z0)`` with ``G`` the heat kernel.

    Args:
        x: horizontal position in d (orifice at 0); in 3D a pair ``(x, y)``.
        z: height in d, ``0 < z < z0``.
        x0: release position; in 3D a pair ``(x0, y0)``.
        z0: release height in d.
        b: void diffusion length in d.
        dims: 2 (one horizontal dimension) or 3 (two).

    Returns:
        Density in 1/d**(dims-1).
    """
    return _gaussian_product(x, x0, z, z0, b, dims, bridge_moments, "geometric_propagator")


def printed_propagator(x, z, x0, z0: float, b: float, dims: int = 2) -> np.ndarray:
    """Solution of the printed eq. Pcp for a point orifice (for comparison only).

    Gaussian per horizontal component with the moments of :func:`printed_moments`.

    Args:
        x: horizontal position in d; in 3D a pair ``(x, y)``.
        z: height in d, ``0 < z < z0``.
        x0: release position; in 3D a pair.
        z0: release height in d.
        b: diffusion length in d.
        dims: 2 or 3.

    Returns:
        Density in 1/d**(dims-1).
    """
    return _gaussian_product(x, x0, z, z0, b, dims, printed_moments, "printed_propagator")


def _radius2(x, dims):
    if dims == 2:
        return np.asarray(x, dtype=float) ** 2, 1
    if dims == 3:
        xx, yy = x
        return np.asarray(xx, dtype=float) ** 2 + np.asarray(yy, dtype=float) ** 2, 2
    raise ValueError(f"dims must be 2 or 3, got {dims!r}")


def _gaussian_product(x, x0, z, z0, b, dims, moments, name):
    """Product over horizontal components of Gaussians with ``moments(z, x0, z0, b)``."""
    z = np.asarray(z, dtype=float)
    if np.any(z <= 0) or np.any(z >= z0):
        raise ValueError(f"{name} needs 0 < z < z0, got z in [{z.min():g}, {z.max():g}] "
                         f"and z0 = {z0:g}")
    if dims == 2:
        comps = [(x, x0)]
    elif dims == 3:
        comps = list(zip(x, x0))
    else:
        raise ValueError(f"dims must be 2 or 3, got {dims!r}")
    out = 1.0
    for xc, x0c in comps:
        m, v = moments(z, x0c, z0, b)
        dev2 = (np.asarray(xc, dtype=float) - m) ** 2
        out = out * np.exp(-dev2 / (2 * v)) / np.sqrt(2 * np.pi * v)
    return out


# ---------------------------------------------------------------------------------------
# Continuum equation for the propagator: right-hand side and a 1D reference marcher
# ---------------------------------------------------------------------------------------
def _form_exponent(form: str) -> float:
    """``q`` such that the flux is ``J = -b rho**-q d_x(rho**q P)``: drift ``-q b d_x log rho``."""
    if form == "derived":
        return -2.0
    if form == "printed":
        return 1.0
    raise ValueError(f"form must be one of {FORMS}, got {form!r}")


def _face_rates(log_rho: np.ndarray, b: float, dx: float, q: float):
    """Rates of the conservative Scharfetter-Gummel-like discretisation (zero-flux ends).

    Face flux ``J_{i+1/2} = -(b/dx) (e^{q dL/2} P_{i+1} - e^{-q dL/2} P_i)``, ``dL`` the
    jump of ``log rho`` across the face; consistent to O(dx**2) with
    ``J = -b (d_x P + q P d_x log rho)``; exact equilibrium ``P ∝ rho**-q``.
    """
    dL = np.diff(log_rho)
    up = (b / dx**2) * np.exp(0.5 * q * dL)  # coefficient of P_{i+1} in row i
    lo = (b / dx**2) * np.exp(-0.5 * q * dL)  # coefficient of P_i in row i+1
    return up, lo


def pcp_rhs(P: np.ndarray, x: np.ndarray, log_rho_v: np.ndarray, b: float,
            form: str = "derived") -> np.ndarray:
    """``-dP/dz`` of the geometrical-propagator equation on a uniform 1D grid.

    ``form="derived"``: ``b d_x(d_x P - 2 P d_x log rho_v)`` (this module's result);
    ``form="printed"``: ``b d_x(d_x P + P d_x log rho_v)`` (eq. Pcp as printed).
    Conservative finite volumes, zero flux at the ends.

    Args:
        P: propagator on the cell centres ``x`` (1/d).
        x: uniform cell centres in d.
        log_rho_v: ``log rho_v`` at ``x`` (any additive constant).
        b: diffusion length in d.
        form: ``"derived"`` or ``"printed"``.

    Returns:
        ``-dP/dz`` (the rate of change per unit fall), same shape as ``P``.
    """
    q = _form_exponent(form)
    dx = float(x[1] - x[0])
    up, lo = _face_rates(np.asarray(log_rho_v, float), b, dx, q)
    # flux through face i+1/2 times 1/dx:
    F = -(up * P[1:] - lo * P[:-1])
    out = np.zeros_like(P, dtype=float)
    out[:-1] -= F
    out[1:] += F
    return out


def printed_eq_pcp_rhs(P: np.ndarray, x: np.ndarray, log_rho_v: np.ndarray, b: float) -> np.ndarray:
    """``-dP/dz`` of the printed eq. Pcp, ``b d_x(d_x P + P d_x log rho_v)``.

    For comparison with the derived equation; see :func:`pcp_rhs` (same arguments).
    """
    return pcp_rhs(P, x, log_rho_v, b, form="printed")


def march_propagator(x: np.ndarray, P_start: np.ndarray, z_start: float,
                     z_out: Sequence[float], log_rho_v: Callable[[np.ndarray, float], np.ndarray],
                     b: float, form: str = "derived", dz: float = 0.01) -> np.ndarray:
    """March the 1D propagator equation downward from ``z_start`` (Crank-Nicolson in z).

    Reference solver for either form of the equation (see :func:`pcp_rhs`), for a
    general steady void density given as ``log rho_v(x, z)``.

    Args:
        x: uniform cell centres in d.
        P_start: propagator at ``z_start`` (1/d).
        z_start: starting height in d.
        z_out: heights (below ``z_start``, > 0 for a point orifice) at which to return P.
        log_rho_v: callable ``(x, z) -> log rho_v``.
        b: diffusion length in d.
        form: ``"derived"`` or ``"printed"``.
        dz: largest step in z (d); each output height is hit exactly.

    Returns:
        Array ``(len(z_out), len(x))``.
    """
    q = _form_exponent(form)
    x = np.asarray(x, float)
    dx = float(x[1] - x[0])
    P = np.array(P_start, dtype=float)
    out = np.empty((len(z_out), x.size))
    z = float(z_start)
    for n, zt in enumerate(z_out):
        if zt > z + 1e-12:
            raise ValueError("z_out must be decreasing and below z_start")
        steps = max(1, int(np.ceil((z - zt) / dz - 1e-9))) if zt < z else 0
        h = (z - zt) / steps if steps else 0.0
        for m in range(steps):
            up, lo = _face_rates(log_rho_v(x, z - (m + 0.5) * h), b, dx, q)
            diag = np.zeros(x.size)
            diag[:-1] -= lo
            diag[1:] -= up
            ab = np.zeros((3, x.size))
            ab[0, 1:] = -0.5 * h * up
            ab[1] = 1.0 - 0.5 * h * diag
            ab[2, :-1] = -0.5 * h * lo
            rhs = P + 0.5 * h * _apply(up, lo, diag, P)
            P = solve_banded((1, 1), ab, rhs)
        z = zt
        out[n] = P
    return out


def _apply(up, lo, diag, P):
    r = diag * P
    r[:-1] += up * P[1:]
    r[1:] += lo * P[:-1]
    return r



# ---------------------------------------------------------------------------------------
# The lattice void model
# ---------------------------------------------------------------------------------------
def _steps_arrays(steps):
    offsets = np.array([int(o) for o, _ in steps], dtype=np.int64)
    probs = np.array([float(p) for _, p in steps], dtype=float)
    if np.any(probs < 0) or abs(probs.sum() - 1.0) > 1e-12:
        raise ValueError("step probabilities must be >= 0 and sum to 1")
    if abs(np.dot(offsets, probs)) > 1e-12:
        raise ValueError("the void step distribution must have zero mean")
    return offsets, probs


def lattice_b(steps=STAGGERED, site_spacing: float = 1.0, row_spacing: float = 1.0) -> float:
    """Void diffusion length of a lattice, eq. blattice: ``b = var(dx) / (2 d_h dz)``, d_h = 1.

    Args:
        steps: ``((offset, probability), ...)`` of one upward void step, offsets in sites.
        site_spacing: horizontal distance between sites (d).
        row_spacing: vertical distance between rows (d).

    Returns:
        ``b`` in d.
    """
    offsets, probs = _steps_arrays(steps)
    return float(np.dot(probs, offsets.astype(float) ** 2)) * site_spacing**2 / (2.0 * row_spacing)


def _shift(f: np.ndarray, o: int) -> np.ndarray:
    """``g[i] = f[i - o]`` with zeros shifted in."""
    g = np.zeros_like(f)
    if o > 0:
        g[o:] = f[:-o]
    elif o < 0:
        g[:o] = f[-o:]
    else:
        g[:] = f
    return g


def lattice_void_density(n_rows: int, steps=STAGGERED) -> tuple[np.ndarray, np.ndarray]:
    """Exact per-void visit probability of every lattice site, point orifice, unbounded.

    A void enters at site 0 of row 0 and steps up one row per step with the given
    horizontal step distribution; ``rho_v[k, i]`` is the probability that it visits site
    ``i`` of row ``k`` (the ``k``-fold convolution of the step law; binomial for
    :data:`STAGGERED`). The lattice is wide enough that no void reaches its edge.

    Args:
        n_rows: highest row.
        steps: ``((offset, probability), ...)``.

    Returns:
        ``(sites, rho_v)``: site indices ``-W..W`` and array ``(n_rows + 1, 2W + 1)``.
    """
    offsets, probs = _steps_arrays(steps)
    W = int(np.abs(offsets).max()) * int(n_rows)
    rho = np.zeros((n_rows + 1, 2 * W + 1))
    rho[0, W] = 1.0
    for k in range(n_rows):
        for o, p in zip(offsets, probs):
            rho[k + 1] += p * _shift(rho[k], int(o))
    return np.arange(-W, W + 1), rho


def lattice_propagator(x0: int, z0: int, steps=STAGGERED) -> tuple[np.ndarray, np.ndarray]:
    """Exact lattice geometrical propagator of the void model (transfer matrix).

    When a void steps from site ``j`` of row ``k`` to site ``i'`` of row ``k+1``, the
    particle at ``(i', k+1)`` drops into ``(j, k)``. Voids are independent, so given that
    a void arrives at the particle's site, it came from ``j`` with probability
    ``rho_v(j, k) p(i' - j) / rho_v(i', k + 1)``: the master equation marched here is::

        P_k(j) = rho_v(j, k) sum_i' p(i' - j) P_{k+1}(i') / rho_v(i', k + 1)

    Args:
        x0: release site (index, orifice at 0).
        z0: release row (> 0).
        steps: void step law ``((offset, probability), ...)``.

    Returns:
        ``(sites, P)``: site indices and array ``(z0 + 1, n_sites)``; row ``k`` is the
        probability of each site when the particle is in row ``k`` (row ``z0`` is the
        release, row 0 the orifice).
    """
    offsets, probs = _steps_arrays(steps)
    sites, rho = lattice_void_density(z0, steps)
    W = (sites.size - 1) // 2
    if abs(x0) > W or rho[z0, x0 + W] == 0:
        raise ValueError(f"no void ever reaches site {x0} of row {z0}: the particle never moves")
    P = np.zeros_like(rho)
    P[z0, x0 + W] = 1.0
    for k in range(z0 - 1, -1, -1):
        ratio = np.divide(P[k + 1], rho[k + 1], out=np.zeros_like(rho[k + 1]), where=rho[k + 1] > 0)
        acc = np.zeros_like(ratio)
        for o, p in zip(offsets, probs):
            acc += p * _shift(ratio, -int(o))  # ratio at j + o
        P[k] = rho[k] * acc
    return sites, P


@numba.njit(cache=True)
def _void_mc_kernel(x0, z0, n_particles, offsets, cum, reach, seed, out):  # pragma: no cover
    np.random.seed(seed)
    n_off = offsets.size
    for p in range(n_particles):
        i = x0
        k = z0
        out[p, k] = i
        while k > 0:
            # one void from the orifice, followed up to the particle's row
            j = 0
            r = 0
            while r < k:
                u = np.random.random()
                s = 0
                while s < n_off - 1 and cum[s] < u:
                    s += 1
                jn = j + offsets[s]
                r += 1
                if r == k:
                    if jn == i:  # the void enters the particle's site
                        i = j  # the particle drops into the site the void left
                        k -= 1
                        out[p, k] = i
                    break
                j = jn
                if abs(i - j) > reach * (k - r):
                    break  # this void can no longer reach the particle
    return out


def lattice_void_montecarlo(x0: int, z0: int, n_particles: int, steps=STAGGERED,
                            seed: int = 0) -> np.ndarray:
    """Monte Carlo of the lattice void model: particles displaced by simulated voids.

    Each particle is followed in its own realisation: voids are injected one at a time at
    site 0 of row 0 and random-walk upward with the step law ``steps``; when a void steps
    from ``(j, k-1)`` into the particle's site ``(i, k)``, the particle drops into
    ``(j, k-1)``. Voids that cannot reach the particle any more are abandoned (they
    cannot affect it). This simulates the mechanism directly and shares no formula with
    :func:`lattice_propagator`.

    Args:
        x0: release site index (orifice at 0).
        z0: release row (> 0).
        n_particles: number of independent particles.
        steps: void step law ``((offset, probability), ...)``.
        seed: random seed.

    Returns:
        Integer array ``(n_particles, z0 + 1)``: column ``k`` is the site at which each
        particle arrives in row ``k`` (column ``z0`` is ``x0``).
    """
    offsets, probs = _steps_arrays(steps)
    cum = np.cumsum(probs)
    cum[-1] = 1.0
    out = np.zeros((int(n_particles), int(z0) + 1), dtype=np.int64)
    return _void_mc_kernel(int(x0), int(z0), int(n_particles), offsets, cum,
                           int(np.abs(offsets).max()), int(seed), out)
