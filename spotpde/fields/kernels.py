"""Spot influence kernels w: uniform (sharp), Gaussian and exponential, 2D or 3D.

A spot at ``r_s`` that steps by ``dR_s`` moves a particle at ``r_p`` by
``-w(r_p - r_s) dR_s``; ``w`` is dimensionless and its moments are the interaction
volumes ``V_k = int w^k dr`` (d**dims). Every kernel here is a function of the
*scaled distance*

    rho = sqrt((x^2 + y^2) / a_h^2 + z^2 / a_z^2),   a_z = a_h / aspect,

so ``aspect = horizontal size / vertical size`` (aspect 2: twice as wide as tall, as in
the experiments), and ``w(r) = A g(rho)`` with

* ``Uniform``:     ``g = 1`` for ``rho < 1`` (``a_h = R``), ``A = height``;
* ``Gaussian``:    ``g = exp(-rho^2 / 2)`` (``a_h = sigma``),
  ``A = V1 / ((2 pi)^(d/2) sigma_h^(d-1) sigma_z)``;
* ``Exponential``: ``g = exp(-rho)`` (``a_h = length``), ``A = V1 / (c_d l_h^(d-1) l_z)``
  with ``c_2 = 2 pi``, ``c_3 = 8 pi``.

Because ``w`` depends on ``r`` only through ``rho``, the normalised autocorrelation
``C(r) = int w(s) w(s + r) ds / int w^2`` of an anisotropic kernel is the isotropic
unit-size correlation evaluated at the scaled separation (substitute ``s = S s'`` with
``S = diag(a_h, [a_h,] a_z)``): ``C(dx, [dy,] dz) = C_1(rho(dx, [dy,] dz))``. The closed
forms ``C_1`` are derived in docs/kernels.md:

* disk   (2D): ``C_1(s) = (2/pi) [acos(u) - u sqrt(1 - u^2)]``, ``u = s/2``;
* sphere (3D): ``C_1(s) = 1 - 3 s / 4 + s^3 / 16`` for ``s < 2``;
* Gaussian:    ``C_1(s) = exp(-s^2 / 4)``;
* exponential: ``C_1(s) = s^2 K_2(s) / 2`` (2D), ``(1 + s + s^2/3) exp(-s)`` (3D).

``correlation(r)`` is for isotropic kernels (aspect 1) and raises otherwise unless an
``axis`` ("x", "y" or "z") says along which direction ``r`` is measured;
``correlation_vector(dx, [dy,] dz)`` is the general form.

Array order of sampled stencils follows the grid: ``(z, x)`` in 2D, ``(z, y, x)`` in 3D.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special

from ..parameters import HEIGHT_RANGE, VOLUME_ROUNDING
from . import _cellavg

__all__ = [
    "Kernel", "Uniform", "Gaussian", "Exponential", "from_spec", "SHAPES",
    "disk_overlap", "sphere_overlap", "alpha_printed",
]

SHAPES = ("uniform", "gaussian", "exponential")

#: relative cut-off of the smooth kernels: ``w < CUTOFF * w(0)`` outside ``reach``.
CUTOFF = 1e-14


# ----------------------------------------------------------------------------------------
# Overlap (correlation) functions of the sharp kernels
# ----------------------------------------------------------------------------------------


def disk_overlap(r, R=1.0):
    """Overlap area of two disks of radius R at distance r, divided by pi R^2.

    ``(2/pi) [acos(u) - u sqrt(1 - u^2)]`` with ``u = r / 2R``, zero for ``r >= 2R``
    (derivation in docs/kernels.md). Equals C(r) of the uniform 2D kernel.

    Args:
        r: separation(s) in d (array-like, >= 0).
        R: disk radius in d.

    Returns:
        ndarray of the same shape as ``r``, 1 at r = 0.
    """
    u = np.clip(np.abs(np.asarray(r, dtype=float)) / (2.0 * R), 0.0, 1.0)
    return (2.0 / np.pi) * (np.arccos(u) - u * np.sqrt(1.0 - u * u))


def sphere_overlap(r, R=1.0):
    """Overlap volume of two spheres of radius R at distance r, divided by 4 pi R^3 / 3.

    Lens volume ``pi (4R + r)(2R - r)^2 / 12`` normalised: ``1 - 3r/4R + r^3/16R^3``
    for ``r < 2R``, zero beyond. Equals C(r) of the uniform 3D kernel. This is the
    correct form of the paper's eq. (alpha); see :func:`alpha_printed`.

    Args:
        r: separation(s) in d (array-like, >= 0).
        R: sphere radius in d.

    Returns:
        ndarray of the same shape as ``r``, 1 at r = 0.
    """
    s = np.minimum(np.abs(np.asarray(r, dtype=float)) / R, 2.0)
    return 1.0 - 0.75 * s + s**3 / 16.0


def alpha_printed(r, R=1.0):
    """The paper's printed eq. (alpha), ``1 - 3r/4R + r^2/16R^2``: WRONG, kept for comparison.

    The printed polynomial is not the overlap of two spheres: it does not vanish at
    ``r = 2R`` (it gives -1/4 there and crosses zero at ``r = (6 - 2 sqrt 5) R ~ 1.53 R``);
    it agrees with the true overlap only at ``r = 0`` and ``r = R``. The correct overlap is
    :func:`sphere_overlap`.

    Args:
        r: separation(s) in d.
        R: sphere radius in d.

    Returns:
        ndarray, the printed polynomial (not clipped).
    """
    s = np.asarray(r, dtype=float) / R
    return 1.0 - 0.75 * s + s**2 / 16.0


def _positive(name, value):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number > 0, got {value!r}") from None
    if not (np.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return v


def _check_dims(dims):
    if dims not in (2, 3) or isinstance(dims, bool):
        raise ValueError(f"dims must be 2 or 3, got {dims!r}")
    return int(dims)


# ----------------------------------------------------------------------------------------
# Base class
# ----------------------------------------------------------------------------------------


class Kernel:
    """Common machinery of the kernels ``w(r) = A g(rho)`` (see the module docstring).

    Subclasses set ``dims``, ``aspect``, ``a_h`` (horizontal scale), ``amplitude`` ``A``
    and implement ``_g(rho)``, ``_rho_reach``, ``_unit_integral(power)``
    (``int g^power`` over the unit isotropic space), ``_corr1(s)``, ``_fourier1(q)`` and
    ``_cell_average(mz, mh, hz, hh, power)`` (scaled cell averages of ``g^power`` on the
    non-negative octant).
    """

    dims: int
    aspect: float
    a_h: float
    amplitude: float
    shape_name: str = ""

    # -- geometry --------------------------------------------------------------------
    @property
    def a_z(self) -> float:
        """Vertical scale length ``a_h / aspect`` in d."""
        return self.a_h / self.aspect

    def _scaled_volume(self) -> float:
        """``a_h^(d-1) a_z``: Jacobian from scaled to physical coordinates."""
        return self.a_h ** (self.dims - 1) * self.a_z

    def _rho(self, coords) -> np.ndarray:
        if len(coords) != self.dims:
            names = "(x, z)" if self.dims == 2 else "(x, y, z)"
            raise ValueError(f"a {self.dims}D kernel takes {self.dims} offsets {names}, got {len(coords)}")
        *horiz, z = (np.asarray(c, dtype=float) for c in coords)
        rho2 = (z / self.a_z) ** 2
        for c in horiz:
            rho2 = rho2 + (c / self.a_h) ** 2
        return np.sqrt(rho2)

    # -- moments ---------------------------------------------------------------------
    @property
    def V1(self) -> float:
        """``int w dr`` in d**dims."""
        return self.moment(1)

    @property
    def V2(self) -> float:
        """``int w^2 dr`` in d**dims."""
        return self.moment(2)

    @property
    def participation_area(self) -> float:
        """``V1^2 / V2`` in d**dims: the area (3D: volume) of the uniform spot with the same
        ``V1`` and ``V2``, a size measure common to every shape (``pi R^2`` for a disk)."""
        return self.V1**2 / self.V2

    def moment(self, power: int) -> float:
        """``V_k = int w^k dr = A^k a_h^(d-1) a_z int g^k`` (exact closed form), d**dims."""
        return self.amplitude**power * self._scaled_volume() * self._unit_integral(power)

    # -- pointwise -------------------------------------------------------------------
    def evaluate(self, *coords) -> np.ndarray:
        """Pointwise ``w`` at offsets ``(x, z)`` (2D) or ``(x, y, z)`` (3D) in d.

        Args:
            *coords: offsets from the spot centre in d, numpy-broadcasting arrays.

        Returns:
            ndarray of ``w`` (dimensionless), the broadcast shape of the offsets.
        """
        return self.amplitude * self._g(self._rho(coords))

    __call__ = evaluate

    @property
    def reach(self) -> tuple[float, float]:
        """Support radii ``(horizontal, vertical)`` in d.

        Exact for the uniform kernel; for the smooth kernels the radius where
        ``w = CUTOFF * w(0)`` (1e-14 of the peak).
        """
        return (self._rho_reach * self.a_h, self._rho_reach * self.a_z)

    # -- sampling --------------------------------------------------------------------
    def halfwidths(self, spacing: float) -> tuple[int, ...]:
        """Stencil half-widths in cells, array order: cells ``|j| <= m`` cover the reach."""
        h = _positive("spacing", spacing)
        rh, rz = self.reach
        mh = max(0, math.ceil(rh / h - 0.5 - 1e-12))
        mz = max(0, math.ceil(rz / h - 0.5 - 1e-12))
        return (mz, mh) if self.dims == 2 else (mz, mh, mh)

    def sample(self, spacing: float, power: int = 1) -> np.ndarray:
        """Cell-averaged ``w**power`` on an odd, centred stencil (array order ``(z,[y,]x)``).

        Entry ``[mz + k, mh + i]`` is ``(1/h^d) int_cell w^power`` over the cell
        ``[(i - 1/2) h, (i + 1/2) h] x [(k - 1/2) h, (k + 1/2) h]`` (3D likewise), so
        ``stencil.sum() * h**dims`` is ``V1`` (power 1) or ``V2`` (power 2). The cell
        averages are exact in closed form (disk, Gaussian) or computed to ~1e-13
        (sphere, exponential; see :mod:`spotpde.fields._cellavg`); a final rescaling by a factor
        within ~1e-12 of 1 (the 1e-14 cut-off tail and quadrature error) makes the sum
        equal ``V_power`` to round-off.

        Args:
            spacing: grid spacing ``h`` in d.
            power: 1 for ``w``, 2 for ``w**2`` (any positive integer works).

        Returns:
            float64 ndarray of shape ``(2 mz + 1, 2 mh + 1)`` or ``(2 mz + 1, 2 mh + 1, 2 mh + 1)``.
        """
        cache = self.__dict__.setdefault("_sample_cache", {})
        key = (float(spacing), power)
        if key not in cache:
            raw = self._sample_raw(spacing, power)
            total = raw.sum() * float(spacing) ** self.dims
            while len(cache) >= 2:  # keep the last two (w and w**2 of one spacing)
                cache.pop(next(iter(cache)))
            cache[key] = raw * (self.moment(power) / total)
        return cache[key].copy()

    def _sample_raw(self, spacing: float, power: int = 1) -> np.ndarray:
        """Cell averages before the final normalisation (for tests of the quadrature)."""
        if int(power) != power or power < 1:
            raise ValueError(f"power must be a positive integer, got {power!r}")
        power = int(power)
        h = _positive("spacing", spacing)
        m = self.halfwidths(h)
        mz, mh = m[0], m[-1]
        octant = self._cell_average(mz, mh, h / self.a_z, h / self.a_h, power)
        full = octant
        for axis in range(self.dims):
            mirrored = np.flip(np.take(full, np.arange(1, full.shape[axis]), axis=axis), axis=axis)
            full = np.concatenate([mirrored, full], axis=axis)
        return self.amplitude**power * np.ascontiguousarray(full)

    # -- correlation -----------------------------------------------------------------
    def correlation(self, r, axis: str | None = None) -> np.ndarray:
        """Normalised autocorrelation ``C(r) = int w(s) w(s + r) ds / V2`` at distance ``r``.

        This is the particle velocity correlation ``C_p`` in uniform flow (paper,
        section "Spatial Velocity Correlation Tensor").

        Args:
            r: separations in d (array-like).
            axis: ``None`` (the kernel must be isotropic, aspect 1), or ``"x"``, ``"y"``
                (3D) or ``"z"``: the direction of the separation for anisotropic kernels.

        Returns:
            ndarray of ``C`` (1 at r = 0), the shape of ``r``.
        """
        r = np.abs(np.asarray(r, dtype=float))
        if axis is None:
            if self.aspect != 1.0:
                raise ValueError(
                    f"correlation(r) needs an isotropic kernel (aspect 1, got {self.aspect}); "
                    "pass axis='x', 'y' or 'z', or use correlation_vector(dx, [dy,] dz)")
            return self._corr1(r / self.a_h)
        valid = ("x", "z") if self.dims == 2 else ("x", "y", "z")
        if axis not in valid:
            raise ValueError(f"axis must be one of {valid} or None, got {axis!r}")
        return self._corr1(r / (self.a_z if axis == "z" else self.a_h))

    def correlation_vector(self, *offsets) -> np.ndarray:
        """``C`` at separation vector ``(dx, dz)`` (2D) or ``(dx, dy, dz)`` (3D), in d.

        ``C(dr) = C_1(rho(dr))`` with ``rho`` the scaled distance (module docstring).
        """
        return self._corr1(self._rho(offsets))

    # -- Fourier transform ---------------------------------------------------------------
    def fourier(self, *k) -> np.ndarray:
        """``w_hat(k) = int w(r) exp(-i k . r) dr`` at angular wavenumbers ``(kx, [ky,] kz)``.

        Real (w is even): ``V1 F_1(q)`` with ``q = sqrt(a_h^2 (kx^2 + ky^2) + a_z^2 kz^2)``
        and ``F_1`` the unit isotropic transform (see the subclass docstrings).

        Args:
            *k: wavenumbers in 1/d, ``(kx, kz)`` or ``(kx, ky, kz)``, broadcasting.

        Returns:
            ndarray of ``w_hat`` in d**dims.
        """
        if len(k) != self.dims:
            raise ValueError(f"a {self.dims}D kernel takes {self.dims} wavenumbers, got {len(k)}")
        *kh, kz = (np.asarray(c, dtype=float) for c in k)
        q2 = (kz * self.a_z) ** 2
        for c in kh:
            q2 = q2 + (c * self.a_h) ** 2
        return self.V1 * self._fourier1(np.sqrt(q2))

    def __repr__(self):
        return (f"{type(self).__name__}({self._size_name}={self.a_h!r}, V1={self.V1!r}, "
                f"dims={self.dims}, aspect={self.aspect!r})")


# ----------------------------------------------------------------------------------------
# Concrete kernels
# ----------------------------------------------------------------------------------------


class Uniform(Kernel):
    """Sharp-cutoff uniform spot: ``w = height`` inside the ellipse/ellipsoid of horizontal
    radius ``radius`` and vertical radius ``radius / aspect``, 0 outside.

    ``V1 = height * |B|``, ``V2 = height^2 * |B|`` with ``|B| = pi R_h R_z`` (2D) or
    ``4/3 pi R_h^2 R_z`` (3D). ``C(r)`` is :func:`disk_overlap` / :func:`sphere_overlap`.
    Fourier transform: ``V1 * 2 J_1(q)/q`` (2D), ``V1 * 3 (sin q - q cos q)/q^3`` (3D).

    Args:
        radius: horizontal radius R in d.
        height: w inside the spot (dimensionless, e.g. 0.0024), in [1e-12, 1] as
            ``kernel.height`` (``spotpde.parameters.HEIGHT_RANGE``): a spot moves a
            particle by at most its own step.
        dims: 2 or 3.
        aspect: horizontal / vertical radius.

    Raises:
        ValueError: naming the argument out of range.
    """

    shape_name = "uniform"
    _size_name = "radius"
    _rho_reach = 1.0

    def __init__(self, radius: float, height: float, dims: int = 2, aspect: float = 1.0):
        self.dims = _check_dims(dims)
        self.a_h = _positive("radius", radius)
        self.amplitude = _positive("height", height)
        if not HEIGHT_RANGE[0] <= self.amplitude <= HEIGHT_RANGE[1]:
            raise ValueError(f"height must be in [{HEIGHT_RANGE[0]:g}, {HEIGHT_RANGE[1]:g}] "
                             "(a spot moves a particle by at most its own step), "
                             f"got {height!r}")
        self.aspect = _positive("aspect", aspect)

    @property
    def radius(self) -> float:
        """Horizontal radius ``R`` of the disk/sphere in d (vertical: ``R / aspect``)."""
        return self.a_h

    @property
    def height(self) -> float:
        """The influence ``w`` inside the disk/sphere (dimensionless)."""
        return self.amplitude

    def __repr__(self):
        return (f"Uniform(radius={self.a_h!r}, height={self.amplitude!r}, dims={self.dims}, "
                f"aspect={self.aspect!r})")

    def _g(self, rho):
        return (rho < 1.0).astype(float)

    def _unit_integral(self, power):
        return math.pi if self.dims == 2 else 4.0 * math.pi / 3.0

    def _corr1(self, s):
        return disk_overlap(s, 1.0) if self.dims == 2 else sphere_overlap(s, 1.0)

    def _fourier1(self, q):
        q = np.asarray(q, dtype=float)
        small = q < 1e-4
        qs = np.where(small, 1.0, q)
        if self.dims == 2:
            val = 2.0 * special.j1(qs) / qs
            series = 1.0 - q**2 / 8.0
        else:
            val = 3.0 * (np.sin(qs) - qs * np.cos(qs)) / qs**3
            series = 1.0 - q**2 / 10.0
        return np.where(small, series, val)

    def _cell_average(self, mz, mh, hz, hh, power):
        # fraction of each cell inside the unit ball (scaled coordinates); g^p = g.
        kz = np.arange(mz + 1, dtype=float)
        kh = np.arange(mh + 1, dtype=float)
        z0, z1 = (kz - 0.5) * hz, (kz + 0.5) * hz
        x0, x1 = (kh - 0.5) * hh, (kh + 0.5) * hh
        if self.dims == 2:
            area = _cellavg.rect_disk_area(x0[None, :], x1[None, :], z0[:, None], z1[:, None])
            return area / (hz * hh)
        Z0, Y0, X0 = np.meshgrid(z0, x0, x0, indexing="ij")
        # nearest and farthest points of each cell from the origin (cells in the octant)
        near = np.sqrt(np.maximum(Z0, 0) ** 2 + np.maximum(Y0, 0) ** 2 + np.maximum(X0, 0) ** 2)
        far = np.sqrt((Z0 + hz) ** 2 + (Y0 + hh) ** 2 + (X0 + hh) ** 2)
        frac = np.where(far <= 1.0, 1.0, 0.0)
        cut = (near < 1.0) & (far > 1.0)
        vol = _cellavg.box_ball_volume(X0[cut], X0[cut] + hh, Y0[cut], Y0[cut] + hh,
                                       Z0[cut], Z0[cut] + hz)
        frac[cut] = vol / (hz * hh * hh)
        return frac


class Gaussian(Kernel):
    """Gaussian spot ``w = V1 / ((2 pi)^(d/2) sigma_h^(d-1) sigma_z) exp(-rho^2 / 2)``.

    ``rho^2 = (x^2 + y^2)/sigma_h^2 + z^2/sigma_z^2``, ``sigma_z = sigma / aspect``.
    ``V2 = V1^2 / ((4 pi)^(d/2) sigma_h^(d-1) sigma_z)``; ``C(r) = exp(-r^2 / 4 sigma^2)``
    (aspect 1; the paper's result); ``w_hat = V1 exp(-q^2 / 2)``.
    Cell averages are exact products of ``erf`` differences (the kernel is separable).

    Args:
        sigma: horizontal standard deviation in d.
        volume: V1 in d**dims.
        dims: 2 or 3.
        aspect: horizontal / vertical width.
    """

    shape_name = "gaussian"
    _size_name = "sigma"
    _rho_reach = math.sqrt(-2.0 * math.log(CUTOFF))

    def __init__(self, sigma: float, volume: float, dims: int = 2, aspect: float = 1.0):
        self.dims = _check_dims(dims)
        self.a_h = _positive("sigma", sigma)
        volume = _positive("volume", volume)
        self.aspect = _positive("aspect", aspect)
        self.amplitude = volume / ((2.0 * math.pi) ** (self.dims / 2) * self._scaled_volume())

    @property
    def sigma(self) -> float:
        """Horizontal standard deviation in d (vertical: ``sigma / aspect``)."""
        return self.a_h

    def _g(self, rho):
        return np.exp(-0.5 * rho * rho)

    def _unit_integral(self, power):
        return (2.0 * math.pi / power) ** (self.dims / 2)

    def _corr1(self, s):
        return np.exp(-0.25 * s * s)

    def _fourier1(self, q):
        return np.exp(-0.5 * q * q)

    @staticmethod
    def _axis_average(m, hs, power):
        """Cell averages of exp(-p X^2/2) over ``[(k-1/2) hs, (k+1/2) hs]``, k = 0..m (exact)."""
        c = math.sqrt(power / 2.0)
        k = np.arange(m + 1, dtype=float)
        lo, hi = (k - 0.5) * hs * c, (k + 0.5) * hs * c
        # erfc differences for cells on the positive side avoid cancellation in the tail
        diff = np.where(lo >= 0, special.erfc(lo) - special.erfc(hi), special.erf(hi) - special.erf(lo))
        return diff * math.sqrt(math.pi) / (2.0 * c * hs)

    def _cell_average(self, mz, mh, hz, hh, power):
        az = self._axis_average(mz, hz, power)
        ah = self._axis_average(mh, hh, power)
        if self.dims == 2:
            return az[:, None] * ah[None, :]
        return az[:, None, None] * ah[None, :, None] * ah[None, None, :]


class Exponential(Kernel):
    """Exponential spot ``w = A exp(-rho)``, ``A = V1 / (c_d l_h^(d-1) l_z)``.

    ``c_2 = 2 pi``, ``c_3 = 8 pi`` (``int exp(-rho)`` over unit space), ``l_z = l / aspect``,
    ``V2 = V1^2 / (2^d c_d l_h^(d-1) l_z)``. ``C`` in closed form (derived in
    docs/kernels.md from the Fourier transform): ``s^2 K_2(s) / 2`` (2D),
    ``(1 + s + s^2/3) e^(-s)`` (3D), ``s`` the scaled separation. ``w_hat = V1 (1 + q^2)^(-3/2)``
    (2D), ``V1 (1 + q^2)^(-2)`` (3D). Reach ``l ln(1e14) ~ 32 l``.

    Args:
        length: horizontal decay length in d.
        volume: V1 in d**dims.
        dims: 2 or 3.
        aspect: horizontal / vertical decay length.
    """

    shape_name = "exponential"
    _size_name = "length"
    _rho_reach = -math.log(CUTOFF)

    def __init__(self, length: float, volume: float, dims: int = 2, aspect: float = 1.0):
        self.dims = _check_dims(dims)
        self.a_h = _positive("length", length)
        volume = _positive("volume", volume)
        self.aspect = _positive("aspect", aspect)
        self.amplitude = volume / (self._unit_integral(1) * self._scaled_volume())

    @property
    def length(self) -> float:
        """Horizontal decay length in d (vertical: ``length / aspect``)."""
        return self.a_h

    def _g(self, rho):
        return np.exp(-rho)

    def _unit_integral(self, power):
        c = 2.0 * math.pi if self.dims == 2 else 8.0 * math.pi
        return c / power**self.dims

    def _corr1(self, s):
        s = np.asarray(s, dtype=float)
        if self.dims == 3:
            return (1.0 + s + s * s / 3.0) * np.exp(-s)
        small = s < 1e-6
        ss = np.where(small, 1.0, s)
        return np.where(small, 1.0 - s * s / 4.0, 0.5 * ss * ss * special.kn(2, ss))

    def _fourier1(self, q):
        return (1.0 + q * q) ** (-1.5 if self.dims == 2 else -2.0)

    def _cell_average(self, mz, mh, hz, hh, power):
        # numba, imported on first use: validating a case builds its kernel, and only an
        # exponential one needs the compiled cell averages
        from . import _cellavg_exp

        if self.dims == 2:
            return _cellavg_exp.exp_cell_avg_2d(mz, mh, hz, hh, float(power))
        return _cellavg_exp.exp_cell_avg_3d(mz, mh, hz, hh, float(power))


# ----------------------------------------------------------------------------------------
# Factory
# ----------------------------------------------------------------------------------------


def from_spec(shape: str, size: float, volume: float, aspect: float = 1.0, dims: int = 2) -> Kernel:
    """Build a kernel from the ``[kernel]`` table of a case.

    Args:
        shape: ``"uniform"``, ``"gaussian"`` or ``"exponential"``.
        size: horizontal radius R, sigma, or decay length, in d.
        volume: V1 = int w, in d**dims. For ``"uniform"`` the height is
            ``V1 / (pi R_h R_z)`` (2D) or ``V1 / (4/3 pi R_h^2 R_z)`` (3D), at most 1
            (``kernel.volume``: up to ``1 + VOLUME_ROUNDING`` for a volume written to
            four digits).
        aspect: horizontal size / vertical size.
        dims: 2 or 3.

    Returns:
        The kernel.

    Raises:
        ValueError: naming the bad argument and the allowed values.
    """
    if shape not in SHAPES:
        raise ValueError(f"shape must be one of {SHAPES}, got {shape!r}")
    dims = _check_dims(dims)
    size = _positive("size", size)
    volume = _positive("volume", volume)
    aspect = _positive("aspect", aspect)
    if shape == "uniform":
        unit = math.pi if dims == 2 else 4.0 * math.pi / 3.0
        height = volume / (unit * size ** (dims - 1) * (size / aspect))
        if not height <= HEIGHT_RANGE[1] * (1 + VOLUME_ROUNDING):
            raise ValueError(f"volume: a uniform kernel of size {size:g} with volume "
                             f"{volume:g} has the influence w = {height:.3g} > 1 (a spot "
                             "moves a particle by at most its own step)")
        if not height >= HEIGHT_RANGE[0]:
            raise ValueError(f"volume: a uniform kernel of size {size:g} with volume "
                             f"{volume:g} has the influence w = {height:.3g} < "
                             f"{HEIGHT_RANGE[0]:g} (w**2 would leave floating point)")
        kernel = Uniform(radius=size, height=min(height, HEIGHT_RANGE[1]), dims=dims,
                         aspect=aspect)
        kernel.amplitude = height    # V1 as given (w a rounding above 1 allowed)
        return kernel
    if shape == "gaussian":
        return Gaussian(sigma=size, volume=volume, dims=dims, aspect=aspect)
    return Exponential(length=size, volume=volume, dims=dims, aspect=aspect)
