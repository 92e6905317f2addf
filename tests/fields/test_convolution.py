"""The FFT convolution engine against direct summation, conservation and symmetry."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from spotpde.fields import _fft
from spotpde.fields import kernels as K
from spotpde.fields.convolution import Convolver, convolve, fft_shape

BACKENDS = ["scipy"] + (["pyfftw"] if _fft.HAVE_PYFFTW else [])


@pytest.fixture(autouse=True)
def _private_cache(tmp_path, monkeypatch):
    """Keep FFTW wisdom written by the tests out of the user's cache; plan quickly
    (the planner effort changes speed only, never the sums)."""
    monkeypatch.setenv("SPOTPDE_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("SPOTPDE_FFTW_PLANNER", "FFTW_ESTIMATE")


def direct(f, s, periodic=False):
    """out[i] = sum_j s[j] f[i - j], j centred; loops over stencil offsets (no FFT)."""
    m = [(k - 1) // 2 for k in s.shape]
    out = np.zeros_like(f)
    n = f.shape
    for j in itertools.product(*[range(-mm, mm + 1) for mm in m]):
        w = s[tuple(jj + mm for jj, mm in zip(j, m))]
        if periodic:
            out += w * np.roll(f, j, axis=tuple(range(f.ndim)))
            continue
        # out[i] += w f[i - j] where 0 <= i - j < n
        dst = tuple(slice(max(jj, 0), nn + min(jj, 0)) for jj, nn in zip(j, n))
        src = tuple(slice(max(-jj, 0), nn - max(jj, 0)) for jj, nn in zip(j, n))
        if all(d.stop > d.start for d in dst):
            out[dst] += w * f[src]
    return out


CASES = [
    ((9, 12), (3, 5)),          # odd x even
    ((8, 10), (7, 3)),          # even x even
    ((6, 7), (17, 21)),         # stencil wider than the field (cropped)
    ((5, 6, 7), (3, 5, 7)),
    ((4, 6, 5), (9, 3, 11)),
]


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("mode", ["linear", "periodic"])
@pytest.mark.parametrize("shape, sshape", CASES)
def test_matches_direct_summation(backend, mode, shape, sshape):
    rng = np.random.default_rng(hash((shape, sshape)) % 2**32)
    f = rng.normal(size=shape)
    s = rng.normal(size=sshape)
    out = convolve(f, s, mode=mode, backend=backend)
    ref = direct(f, s, periodic=(mode == "periodic"))
    assert out.shape == f.shape
    np.testing.assert_allclose(out, ref, atol=1e-12 * np.abs(s).sum() * np.abs(f).max())


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("kernel", [
    K.Gaussian(sigma=0.6, volume=0.05, dims=2, aspect=2.0),
    K.Uniform(radius=1.1, height=0.01, dims=3, aspect=2.0),
    K.Exponential(length=0.3, volume=0.05, dims=2, aspect=0.5),
], ids=lambda k: f"{type(k).__name__}-{k.dims}D")
def test_anisotropic_kernel_stencils_match_direct_summation(backend, kernel):
    h = 0.25
    shape = (11, 14) if kernel.dims == 2 else (7, 9, 8)
    f = np.random.default_rng(3).random(shape)
    s = kernel.sample(h)
    np.testing.assert_allclose(convolve(f, s, backend=backend), direct(f, s), rtol=1e-11, atol=1e-16)


def test_backends_agree_to_round_off():
    if len(BACKENDS) < 2:
        pytest.fail("pyfftw is a declared dependency and must be importable")
    rng = np.random.default_rng(5)
    for shape in ((64, 48), (17, 20, 13)):
        f = rng.normal(size=shape)
        s = rng.normal(size=tuple(2 * (n // 3) + 1 for n in shape))
        for mode in ("linear", "periodic"):
            a = convolve(f, s, mode=mode, backend="pyfftw")
            b = convolve(f, s, mode=mode, backend="scipy")
            np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * np.abs(b).max())


def test_linear_mode_never_wraps():
    f = np.zeros((16, 16))
    f[0, 0] = 1.0  # a unit source in the corner
    s = np.ones((7, 7))
    for backend in BACKENDS:
        out = convolve(f, s, backend=backend)
        assert np.abs(out[4:, :]).max() < 1e-14 and np.abs(out[:, 4:]).max() < 1e-14
        np.testing.assert_allclose(out[:4, :4], 1.0, atol=1e-14)
        # periodic mode does wrap: the source reappears on the far sides
        per = convolve(f, s, mode="periodic", backend=backend)
        np.testing.assert_allclose(per[-3:, -3:], 1.0, atol=1e-14)


@pytest.mark.parametrize("backend", BACKENDS)
def test_conservation(backend):
    """sum(out) = sum(f) sum(stencil): always in periodic mode, and in linear mode when
    f vanishes within the stencil half-width of the boundary."""
    rng = np.random.default_rng(9)
    s = K.Exponential(length=0.5, volume=1.0, dims=2, aspect=2.0).sample(0.5)
    f = rng.random((40, 300))
    per = convolve(f, s, mode="periodic", backend=backend)
    assert per.sum() == pytest.approx(f.sum() * s.sum(), rel=1e-12)
    mz, mx = s.shape[0] // 2, s.shape[1] // 2
    g = np.zeros((2 * mz + 10, 2 * mx + 10))
    g[mz:-mz, mx:-mx] = rng.random((10, 10))
    lin = convolve(g, s, backend=backend)
    assert lin.sum() == pytest.approx(g.sum() * s.sum(), rel=1e-12)


@pytest.mark.parametrize("backend", BACKENDS)
def test_mirror_symmetry(backend):
    """A symmetric stencil commutes with reflections of the field (2D and 3D)."""
    rng = np.random.default_rng(4)
    for kernel, shape in ((K.Gaussian(0.7, 1.0, 2, 2.0), (20, 31)), (K.Uniform(1.0, 1.0, 3, 1.0), (9, 10, 11))):
        s = kernel.sample(0.5)
        f = rng.random(shape)
        out = convolve(f, s, backend=backend)
        for axis in range(f.ndim):
            flipped = convolve(np.flip(f, axis), s, backend=backend)
            np.testing.assert_allclose(flipped, np.flip(out, axis), rtol=1e-12)


@pytest.mark.parametrize("backend", BACKENDS)
def test_several_fields_share_one_call(backend):
    rng = np.random.default_rng(6)
    s = rng.normal(size=(5, 9))
    fields = [rng.normal(size=(12, 15)) for _ in range(3)]
    singles = [convolve(f, s, backend=backend) for f in fields]
    as_list = convolve(fields, s, backend=backend)
    as_tuple = convolve(tuple(fields), s, backend=backend)
    stacked = convolve(np.stack(fields), s, backend=backend)
    assert isinstance(as_list, list) and isinstance(as_tuple, tuple)
    assert isinstance(stacked, np.ndarray) and stacked.shape == (3, 12, 15)
    for a, b, c, d in zip(singles, as_list, as_tuple, stacked):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)
        np.testing.assert_array_equal(a, d)
    assert convolve([], s, backend=backend) == []


def test_reuses_plans_and_spectra():
    if not _fft.HAVE_PYFFTW:
        pytest.fail("pyfftw is a declared dependency and must be importable")
    rng = np.random.default_rng(8)
    s = rng.normal(size=(5, 5))
    f = rng.normal(size=(30, 40))
    c1 = Convolver(s, f.shape, backend="pyfftw")
    c2 = Convolver(s, f.shape, backend="pyfftw")
    np.testing.assert_array_equal(c1(f), c2(f))
    assert _fft.get_plan(c1.fft_shape) is _fft.get_plan(c2.fft_shape)
    # padding by the half-width only, to a 5-smooth length
    assert fft_shape((30, 40), (5, 5), backend="pyfftw") == (32, 45)
    assert c1.fft_shape == (32, 45)
    # a different field shape sharing the same plan must not see stale data in the padding
    g = rng.normal(size=(31, 42))
    assert Convolver(s, g.shape, backend="pyfftw").fft_shape == (36, 45)
    np.testing.assert_allclose(convolve(g, s), direct(g, s), atol=1e-12)
    h = rng.normal(size=(29, 41))
    np.testing.assert_allclose(convolve(h, s), direct(h, s), atol=1e-12)


def test_continuum_convolution_of_gaussians():
    """h^2 (w * f) for Gaussian w and f is the Gaussian with the summed variances."""
    sig_f, sig_w, h = 2.0, 0.8, 0.2
    ax = np.arange(-60, 61) * h
    Z, X = np.meshgrid(ax, ax, indexing="ij")
    f = np.exp(-(X**2 + Z**2) / (2 * sig_f**2))
    w = K.Gaussian(sigma=sig_w, volume=1.0, dims=2, aspect=2.0)
    out = h**2 * convolve(f, w.sample(h))
    vx, vz = sig_f**2 + sig_w**2, sig_f**2 + (sig_w / 2) ** 2
    exact = sig_f**2 / np.sqrt(vx * vz) * np.exp(-X**2 / (2 * vx) - Z**2 / (2 * vz))
    # the cell average adds h^2/12 to each kernel variance: a second-order error, at most
    # about (h^2/12) |d exact / d variance| summed over the two axes (~ h^2/12 / sig_f^2)
    err = np.abs(out - exact).max()
    assert err < h**2 / 12 / sig_f**2
    assert err > 0.1 * h**2 / 12 / sig_f**2  # the bias is really there (cell averages, not points)


def test_wisdom_file_is_written_and_bad_files_are_harmless(tmp_path, monkeypatch):
    if not _fft.HAVE_PYFFTW:
        pytest.fail("pyfftw is a declared dependency and must be importable")
    monkeypatch.setenv("SPOTPDE_CACHE_DIR", str(tmp_path / "c"))
    assert _fft.save_wisdom()
    path = tmp_path / "c" / "fftw_wisdom"
    assert path.read_bytes().startswith(_fft._MAGIC)
    assert not [p for p in path.parent.iterdir() if p.name != "fftw_wisdom"]  # no temp files left
    assert _fft._read_wisdom(path) is not None
    path.write_bytes(b"garbage")
    monkeypatch.setattr(_fft, "_wisdom_loaded", False)
    assert _fft.load_wisdom() is False
    # an unwritable cache location is harmless too
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setenv("SPOTPDE_CACHE_DIR", str(blocker / "sub"))
    assert _fft.save_wisdom() is False


def test_plans_are_estimated_and_keep_no_wisdom_unless_asked_to_measure(tmp_path, monkeypatch):
    """The default planner measures nothing, so it neither reads nor writes wisdom (a plan
    measured on a loaded machine and kept would slow every later run); a measuring
    planner keeps its wisdom. Both give the same sums."""
    if not _fft.HAVE_PYFFTW:
        pytest.fail("pyfftw is a declared dependency and must be importable")
    monkeypatch.setenv("SPOTPDE_CACHE_DIR", str(tmp_path / "c"))
    monkeypatch.delenv("SPOTPDE_FFTW_PLANNER")
    monkeypatch.setattr(_fft, "_wisdom_loaded", False)
    loaded = []
    monkeypatch.setattr(_fft, "load_wisdom", lambda: loaded.append(1) or False)
    assert _fft.planner() == "FFTW_ESTIMATE" and not _fft.measures()
    rng = np.random.default_rng(5)
    f, s = rng.normal(size=(37, 29)), rng.normal(size=(5, 3))
    _fft.clear_plans()
    estimated = convolve(f, s, backend="pyfftw")
    assert not (tmp_path / "c" / "fftw_wisdom").exists() and not loaded
    monkeypatch.setenv("SPOTPDE_FFTW_PLANNER", "FFTW_MEASURE")
    assert _fft.measures()
    _fft.clear_plans()
    measured = convolve(f, s, backend="pyfftw")
    assert (tmp_path / "c" / "fftw_wisdom").exists() and loaded
    _fft.clear_plans()
    np.testing.assert_allclose(measured, estimated, rtol=0, atol=1e-12 * np.abs(direct(f, s)).max())
    np.testing.assert_allclose(estimated, direct(f, s), rtol=0, atol=1e-12 * np.abs(direct(f, s)).max())


def test_falls_back_to_scipy_without_pyfftw(monkeypatch):
    rng = np.random.default_rng(12)
    f, s = rng.normal(size=(13, 16)), rng.normal(size=(5, 7))
    with_pyfftw = convolve(f, s)
    monkeypatch.setattr(_fft, "HAVE_PYFFTW", False)
    assert _fft.resolve_backend(None) == "scipy"
    with pytest.raises(ValueError, match="pyfftw is not importable"):
        _fft.resolve_backend("pyfftw")
    np.testing.assert_allclose(convolve(f, s), with_pyfftw, atol=1e-13)
    np.testing.assert_allclose(convolve(f, s), direct(f, s), atol=1e-13)


def test_thread_count(monkeypatch):
    import os

    monkeypatch.delenv("SPOTPDE_FFT_THREADS", raising=False)
    cores = len(os.sched_getaffinity(0))
    monkeypatch.setattr(_fft, "_other_runnable", lambda: 0)      # an idle machine
    assert _fft.threads() == cores
    # other tasks running: their cores are left to them (if this process sees the whole
    # machine), never fewer than one thread
    whole = cores == os.cpu_count()
    monkeypatch.setattr(_fft, "_other_runnable", lambda: 1)
    assert _fft.threads() == (max(1, cores - 1) if whole else cores)
    monkeypatch.setattr(_fft, "_other_runnable", lambda: 10 * cores)
    assert _fft.threads() == (1 if whole else cores)
    monkeypatch.undo()
    assert 0 <= _fft._other_runnable()
    monkeypatch.setattr(_fft, "_other_runnable", lambda: 10 * cores)
    monkeypatch.setenv("SPOTPDE_FFT_THREADS", "1")
    assert _fft.threads() == 1
    monkeypatch.setenv("SPOTPDE_FFT_THREADS", "many")  # ignored
    assert _fft.threads() >= 1


def test_results_do_not_depend_on_the_thread_count(monkeypatch):
    """The thread count follows the load (threads()), so a run must give the same numbers
    whatever it gets: the FFTW transforms, with one thread or two, bit for bit."""
    if _fft.resolve_backend(None) != "pyfftw":
        pytest.skip("pyfftw not installed")
    rng = np.random.default_rng(5)
    f = rng.random((520, 500))                    # above THREAD_MIN_SIZE once padded
    st = rng.random((21, 21))
    out = []
    for n in ("1", "2"):
        monkeypatch.setenv("SPOTPDE_FFT_THREADS", n)
        assert _fft.plan_threads((540, 520)) == int(n)
        out.append(convolve(f, st, backend="pyfftw"))
    assert np.array_equal(out[0], out[1])


@pytest.mark.parametrize("kwargs, match", [
    (dict(mode="wrap"), "mode must be one of"),
    (dict(backend="fftpack"), "backend must be one of"),
])
def test_rejects_bad_options(kwargs, match):
    with pytest.raises(ValueError, match=match):
        convolve(np.zeros((4, 4)), np.ones((3, 3)), **kwargs)


def test_rejects_bad_inputs():
    with pytest.raises(ValueError, match="odd"):
        convolve(np.zeros((4, 4)), np.ones((2, 3)))
    with pytest.raises(ValueError, match="share one shape"):
        convolve([np.zeros((4, 4)), np.zeros((4, 5))], np.ones((3, 3)))
    with pytest.raises(ValueError, match="dimensions"):
        convolve(np.zeros((4, 4, 4, 4)), np.ones((3, 3)))
    with pytest.raises(ValueError, match="real"):
        convolve(np.zeros((4, 4), complex), np.ones((3, 3)))
    with pytest.raises(ValueError, match="NaN"):
        convolve(np.zeros((4, 4)), np.full((3, 3), np.nan))
