"""The Kinematic Model in a cylinder: the Fourier-Bessel series (private).

Re-exported by :mod:`spotpde.density.kinematic`. With constant ``b`` the axisymmetric
Kinematic Model ``dv/dz = b (1/r) d/dr (r dv/dr)`` depends on height only through
``s = b z`` (d**2). Between the axis and a reflecting wall at ``r = a``
(``dv/dr = 0`` there: no flux through the wall), from the orifice's profile ``p(r)``
(unit flux, ``integral 2 pi r p dr = 1``)::

    v(r, s) = 1 / (pi a**2) + sum_n c_n J0(k_n r) exp(-k_n**2 s),   J1(k_n a) = 0,
    c_n = p^(k_n) / (pi a**2 J0(k_n a)**2),   p^(k) = integral 2 pi r p(r) J0(k r) dr

(the ``J0(k_n r)`` are orthogonal with weight ``r`` on ``[0, a]``, ``integral_0^a r J0(k_n
r)**2 dr = a**2 J0(k_n a)**2 / 2``, and each integrates to 0 over the disk, so every
height carries the unit flux). ``p^``: a point orifice 1, a uniform disk of radius
``R = width/2`` ``2 J1(k R) / (k R)``, a Gaussian of standard deviation ``width/2`` per
horizontal axis ``exp(-k**2 width**2 / 8)`` (its free-space transform, exact while it
stays inside the wall). Terms are kept while ``exp(-k_n**2 s) > 1e-13``.

Far from the wall (or with open walls) the free-space solution is used: a point
``exp(-r**2 / (4 s)) / (4 pi s)``, a Gaussian of variance ``2 s + sigma**2`` per axis, a
disk the probability that a 2D normal of variance ``2 s`` per axis around ``r`` lands in
the disk (a non-central chi-squared distribution) over its area.
"""

from __future__ import annotations

import numpy as np
from scipy.special import j0, j1, jn_zeros
from scipy.stats import ncx2


def cylinder_profile(r, s, orifice, r_range: tuple[float, float] | None = None,
                     walls: str = "reflecting"):
    """Closed-form downward speed of the axisymmetric Kinematic Model (module docstring).

    Args:
        r: radii in d (array, ``>= 0``).
        s: ``b z`` in d**2, > 0 (float, or an array broadcasting with ``r``).
        orifice: the orifice on the axis (``width`` its diameter, ``profile``; its ``x``
            and rate are ignored).
        r_range: ``(0, a)``: the cylinder's radius ``a`` in d (None: no wall).
        walls: ``"reflecting"`` (the wall at ``r = a``) or ``"open"`` (free space).

    Returns:
        ``v`` in 1/d**2 (unit flux through every height: ``integral 2 pi r v dr = 1``),
        the broadcast shape of ``r`` and ``s``.
    """
    r = np.abs(np.asarray(r, dtype=float))
    s = np.asarray(s, dtype=float)
    if not np.all(s > 0):
        raise ValueError(f"s: must be > 0 (b z in d**2), got {s.min() if s.size else s!r}")
    if walls not in ("reflecting", "open"):
        raise ValueError(f'walls: must be "reflecting" or "open", got {walls!r}')
    width = float(orifice.width)
    disk = width > 0 and orifice.profile == "uniform"
    R = 0.5 * width
    sig2 = R * R if (width > 0 and not disk) else 0.0
    open_ = walls == "open" or r_range is None
    a = None if r_range is None else float(r_range[1])
    if not open_:
        if disk and R >= a:                      # the whole floor: uniform flow
            return np.broadcast_to(1.0 / (np.pi * a * a), np.broadcast(r, s).shape).copy()
        # the nearest image (reflection in the wall) below e**-40 of the peak: free space
        gap = a - (R if disk else 0.0)
        open_ = gap * gap > 80.0 * (2.0 * float(np.max(s)) + sig2)
    rr, ss = np.broadcast_arrays(r, s)
    if open_:
        if disk:
            var = 2.0 * ss
            return ncx2.cdf(R * R / var, 2, rr * rr / var) / (np.pi * R * R)
        var = 2.0 * ss + sig2
        return np.exp(-rr**2 / (2.0 * var)) / (2.0 * np.pi * var)
    s_min = float(np.min(s)) + 0.5 * sig2
    n_max = int(np.ceil(a / np.pi * np.sqrt(30.0 / max(s_min, 1e-12)))) + 2
    k = jn_zeros(1, n_max) / a
    if disk:
        hat = 2.0 * j1(k * R) / (k * R)
    else:
        hat = np.exp(-0.5 * k**2 * sig2)
    c = hat / (np.pi * a * a * j0(k * a) ** 2)
    terms = c * j0(np.multiply.outer(rr, k)) * np.exp(-np.multiply.outer(ss, k**2))
    return 1.0 / (np.pi * a * a) + terms.sum(axis=-1)

