"""Fast paths of the steady fields pipeline equal the plain computations they replace.

Each shortcut (issue 16, item 5) is exact algebra, so each is checked against the
computation it replaces at round-off: the renormalised walls of a rectangular silo as one
transform plus wall strips, the grid derivative against ``numpy.gradient``, the spectral
spot flux without its underflowed modes, the round-off clip and the finiteness check.
"""

from __future__ import annotations

import numpy as np
import pytest

from spotpde._roundoff import clip_roundoff
from spotpde.density import _spectral
from spotpde.fields import _walls
from spotpde.fields import coefficients as C
from spotpde.fields import kernels
from spotpde.grid import Grid, derivative
from spotpde.parameters import Spots


def _kernel(shape: str, dims: int):
    if shape == "uniform":      # w**2 = height * w: one transform for u_p and D_p
        return kernels.Uniform(radius=1.5, height=0.05, dims=dims, aspect=1.2)
    return kernels.Gaussian(sigma=0.6, volume=0.05, dims=dims, aspect=1.5)


@pytest.mark.parametrize("dims, half", [(2, 4.0), (2, 1.0), (3, 4.0)])
@pytest.mark.parametrize("shape", ["uniform", "gaussian"])
@pytest.mark.parametrize("rule", [0.0, 0.5, 1.0])
def test_renormalised_walls_by_strips_equal_the_general_path(dims, half, shape, rule):
    """Scalar coefficients take ``renormalised_constant_fields`` (S/phi = S + S (1/phi - 1),
    the second term on the wall strips only); the same coefficients as arrays take the
    general path (every source divided by phi, one transform each). Random rho_s: strong
    boundaries. ``half = 1`` is narrower than the kernel: the strips meet in the middle."""
    grid = Grid(dims, (-half, half), (0.0, 6.0), 0.25 if dims == 2 else 0.5,
                walls="reflecting")
    kernel = _kernel(shape, dims)
    rho = np.random.default_rng(11).random(grid.shape) + 1.0
    ones = np.ones(grid.shape)
    tensor = ({"D_xx": 1.3, "D_xz": 0.4, "D_zz": 0.7} if dims == 2 else
              {"D_xx": 1.3, "D_yy": 0.9, "D_xz": 0.4, "D_yz": -0.2, "D_zz": 0.7})
    def runs(arrays: bool):   # (spots, keyword arguments): scalars or the same as arrays
        c = ones if arrays else 1.0
        yield (Spots(drift=1.4 * c), dict(diffusivity="mean-field",
               spot_diffusivity_tensor={k: v * c for k, v in tensor.items()}))
        yield Spots(drift=1.4 * c, b=1.3, b_par=0.4), dict(diffusivity="passage")

    for (s1, kw1), (s2, kw2) in zip(runs(False), runs(True)):
        f1 = C.particle_fields(grid, rho, s1, kernel, rule=rule, **kw1)
        f2 = C.particle_fields(grid, rho, s2, kernel, rule=rule, **kw2)
        for k in f1:
            np.testing.assert_allclose(f1[k], f2[k], rtol=0, atol=1e-13 * np.abs(f2[k]).max(),
                                       err_msg=k)
        # and the renormalisation does something: the truncated fields differ at the walls
        trunc = C.particle_fields(grid, rho, s1, kernel, rule=rule, walls="truncate", **kw1)
        assert np.abs(trunc["u_z"] - f1["u_z"]).max() > 1e-3 * np.abs(f1["u_z"]).max()


def test_wall_boxes_cover_exactly_the_cells_where_the_kernel_leaves_the_silo():
    """phi < 1 (to more than round-off) exactly on the boxes; the boxes are disjoint."""
    grid = Grid(3, (-3.0, 3.0), (0.0, 2.0), 0.25, walls="reflecting")
    kernel = kernels.Uniform(radius=1.0, height=0.05, dims=3)
    half = [(k - 1) // 2 for k in kernel.sample(grid.spacing).shape]
    count = np.zeros(grid.shape, dtype=int)
    for box in _walls._wall_boxes(grid, half):
        count[box] += 1
    assert count.max() == 1
    phi = _walls.coverage(grid, kernel)
    np.testing.assert_array_equal(count == 1, phi < 1.0 - 1e-12)


@pytest.mark.parametrize("shape", [(7, 5), (64, 33), (5, 6, 7), (3, 4)])
def test_derivative_is_numpy_gradient_bit_for_bit(shape):
    f = np.random.default_rng(3).random(shape)
    for axis in range(len(shape)):
        np.testing.assert_array_equal(derivative(f, 0.13, axis),
                                      np.gradient(f, 0.13, axis=axis, edge_order=2))


@pytest.mark.parametrize("b, b_par", [(1.3, 0.0), (1.3, 0.4), (0.02, 0.0), (40.0, 2.0)])
def test_spectral_profile_without_underflowed_modes_is_the_full_one(b, b_par):
    """Modes decayed past exp(-746) are skipped row block by row block: the result is the
    full evaluation to the last bit (they underflow to 0 there too)."""
    L, n = 128.0, 1024
    k2 = (np.pi * np.arange(n) / L) ** 2
    zeta = (np.arange(n) + 0.5) / 8
    full = _spectral.mode_profile(k2[None, :], zeta[:, None], b, b_par, 160.0)
    live = _spectral._live_modes(k2, zeta, b, b_par, 160.0)
    np.testing.assert_array_equal(live, full)
    assert np.count_nonzero(full[-1]) < n           # the shortcut had work to skip


def test_clip_roundoff_zeroes_roundoff_negatives_only():
    a = np.array([1.0, -1e-17, 2.0, 0.0])
    np.testing.assert_array_equal(clip_roundoff(a), [1.0, 0.0, 2.0, 0.0])
    b = np.array([1.0, -1e-3, -1e-17])              # a real negative: left for checks
    np.testing.assert_array_equal(clip_roundoff(b), [1.0, -1e-3, 0.0])
    c = np.array([1.0, 2.0])
    assert clip_roundoff(c) is c                     # nothing to do: the same array
    d = np.array([np.nan, -1e-17])
    assert np.isnan(clip_roundoff(d)[0])


def test_finiteness_check_is_not_fooled_by_an_overflowing_sum():
    from spotpde.app.pipeline import _check_finite
    from spotpde.errors import NumericalError

    _check_finite("big", np.array([1e308, 1e308, -1e308]))        # sum overflows: finite
    _check_finite("empty", np.zeros(0))
    for bad in ([1.0, np.nan], [np.inf, -np.inf], [1e308, np.inf]):
        with pytest.raises(NumericalError, match="1 values|2 values"):
            _check_finite("f", np.array(bad))


# -- the 2D one-pass fields, the in-place transform, the batched box convolutions -----------

@pytest.mark.parametrize("walls, kernel_walls", [("reflecting", "truncate"), ("open", "renormalise"),
                                                 ("reflecting", "renormalise")])
@pytest.mark.parametrize("shape", ["uniform", "gaussian"])
@pytest.mark.parametrize("rule", [0.0, 0.5, 1.0])
def test_one_pass_2d_fields_equal_the_general_path(walls, kernel_walls, shape, rule):
    """Scalar coefficients of a 2D grid take ``_constant.fields_2d`` (one numba pass over
    the transform read in place, boundary planes as box convolutions, the passage drift
    div(D_p - D_p_mf) from the same pass); the same coefficients as arrays take the general
    path and ``_passage.keep_flux_velocity``, whose numpy passes it replaces. Mean field
    with a cross term (planes on both axes), passage with and without D_par (D_zz of
    D_s zero: the whole D_zz is the passage excess); the Gaussian has its own w**2
    transform. Narrow grid (``half = 1``): the strips and planes meet."""
    kernel = _kernel(shape, 2)
    for half in (4.0, 1.0):
        grid = Grid(2, (-half, half), (0.0, 5.0), 0.25, walls=walls)
        rho = np.random.default_rng(5).random(grid.shape) + 1.0
        ones = np.ones(grid.shape)
        tensor = {"D_xx": 1.3, "D_xz": 0.4, "D_zz": 0.7}
        runs = [(lambda c: Spots(drift=1.4 * c), lambda c: dict(
                    diffusivity="mean-field",
                    spot_diffusivity_tensor={k: v * c for k, v in tensor.items()})),
                (lambda c: Spots(drift=1.4 * c, b=1.3, b_par=0.4), lambda c: {}),
                (lambda c: Spots(drift=0.8 * c, b=1.1, b_par=0.0), lambda c: {})]
        for spots, kw in runs:
            f1 = C.particle_fields(grid, rho, spots(1.0), kernel, rule=rule,
                                   walls=kernel_walls, **kw(1.0))
            f2 = C.particle_fields(grid, rho, spots(ones), kernel, rule=rule,
                                   walls=kernel_walls, **kw(ones))
            # round-off relative to the drift's (diffusivity's) largest component: with
            # T_xx = D_xx to round-off the passage drift u_x is itself round-off
            scale = {c: max(np.abs(f2[k]).max() for k in f2 if k.startswith(c))
                     for c in ("u_", "D_")}
            for k in f1:
                np.testing.assert_allclose(f1[k], f2[k], rtol=0, atol=1e-13 * scale[k[:2]],
                                           err_msg=k)
            assert np.abs(f1["u_z"]).max() > 0 and np.abs(f1["D_zz"]).max() > 0


@pytest.mark.parametrize("backend", ["pyfftw", "scipy"])
def test_convolve_padded_is_convolve_of_the_padded_field(backend):
    """The transform read in place equals ``convolve(np.pad(f, 1))``; a plain convolution
    sharing the plan before or after it sees no stale data in the padding."""
    from spotpde.fields.convolution import convolve, convolve_padded

    rng = np.random.default_rng(2)
    s = rng.normal(size=(7, 5))
    f, g = rng.normal(size=(30, 41)), rng.normal(size=(32, 43))   # g: f's padded shape
    want = convolve(np.pad(f, 1), s, backend=backend)
    for _ in range(2):
        with convolve_padded(f, s, 1, backend=backend) as got:
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-14)
        np.testing.assert_allclose(convolve(g, s, backend=backend),
                                   convolve(g, s, backend="scipy"), rtol=0, atol=1e-13)
    with pytest.raises(ValueError, match="does not match"):
        from spotpde.fields.convolution import Convolver
        with Convolver(s, (30, 41), backend=backend).padded(f, 1):
            pass


def test_coverage_of_a_rectangular_2d_silo_is_the_2d_sum_it_replaces():
    """phi of a rectangular 2D silo by the 1D convolution of chi's row with the stencil's
    column sums equals the 'valid' 2D convolution of the edge-padded chi."""
    import scipy.signal

    for walls in ("reflecting", "open"):
        for kernel in (_kernel("uniform", 2), _kernel("gaussian", 2)):
            for half in (4.0, 0.5):
                grid = Grid(2, (-half, half), (0.0, 2.0), 0.25, walls=walls)
                stencil = kernel.sample(grid.spacing, power=1)
                widths = [(n - 1) // 2 for n in stencil.shape]
                chi = _walls._pad(np.ones((1, grid.nx)), widths,
                                  {1} if walls == "reflecting" else set())
                want = scipy.signal.fftconvolve(chi, stencil, mode="valid") / stencil.sum()
                np.testing.assert_allclose(_walls.coverage(grid, kernel),
                                           np.broadcast_to(want, grid.shape), rtol=0, atol=1e-15)


@pytest.mark.parametrize("batch_bytes", [None, 1])
def test_box_convolutions_and_their_derivatives_are_the_whole_grid_ones(batch_bytes,
                                                                        monkeypatch):
    """Batched box convolutions (boxes reaching one ghost cell beyond the grid, stencil
    spectra cached; with ``batch_bytes = 1`` each source its own batch) equal the full
    convolution of the zero-extended source cut to the grid, and ``add_derivative``
    equals the whole-grid derivative of that sum."""
    import scipy.signal

    from spotpde.fields import _strips

    if batch_bytes is not None:
        monkeypatch.setattr(_strips, "BATCH_BYTES", batch_bytes)

    rng = np.random.default_rng(4)
    shape, h = (17, 23), 0.3
    stencil = rng.random((7, 9))
    boxes = [(slice(0, 17), slice(-1, 1)), (slice(0, 17), slice(3, 8)),
             (slice(-1, 1), slice(0, 23)), (slice(16, 18), slice(0, 23))]
    requests = [(("u", float(i)), box, rng.normal(size=tuple(s.stop - s.start for s in box)), 1)
                for i, box in enumerate(boxes)]
    for _ in range(2):                              # the second call: cached spectra
        parts = {}
        for name, dst, values in _strips.box_convolutions(requests, {1: stencil}, shape):
            parts.setdefault(name, []).append((dst, values))
        for name, box, src, _ in requests:
            big = np.zeros((21, 27))                # the grid with 2 ghost cells a side
            big[tuple(slice(s.start + 2, s.stop + 2) for s in box)] = src
            want = scipy.signal.fftconvolve(big, stencil, mode="same")[2:-2, 2:-2]
            got = np.zeros(shape)
            _strips.add(got, parts[name], 1.0)
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-13)
            for axis in (0, 1):
                dgot = np.zeros(shape)
                _strips.add_derivative(dgot, parts[name], h, axis, 2.0)
                np.testing.assert_allclose(dgot, 2.0 * derivative(want, h, axis), rtol=0,
                                           atol=1e-12)


def test_spectral_profile_factors_are_the_products_bit_for_bit():
    """``_live_modes(..., factors=(a, half))`` multiplies block by block: the same bits as
    ``(_live_modes(...) * a) * half`` over the whole array, which it replaces."""
    L, n = 64.0, 512
    k2 = (np.pi * np.arange(n) / L) ** 2
    zeta = (np.arange(300) + 0.5) / 8
    a = np.random.default_rng(1).normal(size=n)
    half = np.where(np.arange(n) == 0, 1.0, 0.5)
    for b_par in (0.0, 0.4):
        plain = (_spectral._live_modes(k2, zeta, 1.3, b_par, 40.0) * a[None, :]) * half
        np.testing.assert_array_equal(
            _spectral._live_modes(k2, zeta, 1.3, b_par, 40.0, factors=(a, half)), plain)


def test_clip_roundoff_in_place_gives_the_copy_s_values():
    for a in ([1.0, -1e-17, 2.0, 0.0], [1.0, -1e-3, -1e-17], [1.0, 2.0]):
        want = clip_roundoff(np.array(a))
        b = np.array(a)
        got = clip_roundoff(b, inplace=True)
        assert got is b
        np.testing.assert_array_equal(got, want)


def test_rho_s_check_by_its_sum_still_finds_every_non_finite_value():
    """``particle_fields`` checks ``rho_s`` by its sum first (one pass): NaN and infinities
    are still refused, finite values whose sum overflows still accepted."""
    grid = Grid(2, (-2.0, 2.0), (0.0, 2.0), 0.25)
    kernel = _kernel("uniform", 2)
    big = np.full(grid.shape, 1e306)                  # the sum overflows; all finite
    C.particle_fields(grid, big, Spots(), kernel, diffusivity="mean-field")
    for bad in (np.nan, np.inf, -np.inf):
        rho = np.ones(grid.shape)
        rho[3, 4] = bad
        with pytest.raises(ValueError, match="rho_s: contains NaN"):
            C.particle_fields(grid, rho, Spots(), kernel)


def test_parallel_one_pass_kernel_gives_the_serial_values():
    """The row-split parallel kernel does the serial one's operations cell by cell."""
    from spotpde.fields import _constant

    rng = np.random.default_rng(9)
    nz, nx = 37, 29
    c, cD = rng.random((nz + 2, nx + 2)), rng.random((nz + 2, nx + 2))
    coeffs = tuple(rng.normal(size=9))       # a0, gxx, gxz, gzx, gzz, px, pz, axx, azz
    for same, cd in ((True, c), (False, cD)):
        outs = []
        for run in (lambda *a: _constant._fields_2d_kernel(*a, same),
                    lambda *a: _constant._fields_2d_kernel_parallel(*a, same, 3)):
            o = [np.full((nz, nx), np.nan) for _ in range(4)]
            run(c, cd, 0.3, *coeffs, *o)
            outs.append(o)
        for a, b in zip(*outs):
            assert np.all(np.isfinite(a))
            np.testing.assert_array_equal(a, b)
