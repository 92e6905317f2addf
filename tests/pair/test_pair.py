"""spotpde.pair: the relative Fokker-Planck equation of two tracers against closed forms.

Closed forms (docs/pair.md): 1D constant B, start at contact: mean fall (s - c)^2 / 2B;
2D isotropic constant B, reflecting at a, absorbing at 2a, start at a:
(3/4 - ln 2 / 2) a^2 / B; 1D variable B: int_c^s (s - y) / B(y) dy (Ito; the paper's disk
at lam = 1: 246.0 d, while the Fickian form gives 196.7 d); stationary P ~ 1/B on a closed
domain; far field <|r|^2> = |r0|^2 + 4 (b_p + b_p_par) zeta; survival of the 1D problem by
its eigenfunction series.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from spotpde import pair
from spotpde.fields.kernels import Exponential, Gaussian, Uniform

# a kernel so narrow that C = 0 beyond contact: B = 2 b_p is constant in the annulus
POINT = Gaussian(sigma=0.01, volume=0.05)
DISK = Uniform(radius=2.5, height=0.0024)         # the paper's spot


def _bp(kernel, b):
    return b * kernel.V2 / kernel.V1


def test_1d_constant_B_mean_fall():
    # b_par = 0: no vertical relative motion, the pair side by side stays on Z = 0
    c, s = 1.0, 3.0
    ds = pair.cage_breaking(POINT, 1.3, diffusivity="mean-field", contact=c, separation=s)
    B = 2 * _bp(POINT, 1.3)
    assert ds.attrs["mean_fall"] == pytest.approx((s - c) ** 2 / (2 * B), rel=2e-3)


def test_1d_constant_B_survival_series():
    # S(zeta) = sum_n 4 (-1)^n / ((2n+1) pi) exp(-(2n+1)^2 pi^2 B zeta / (4 L^2)), start at c
    c, s = 1.0, 2.0
    ds = pair.cage_breaking(POINT, 1.0, diffusivity="mean-field", contact=c, separation=s,
                            steps_per_mean=400)
    B, L = 2 * _bp(POINT, 1.0), s - c
    zeta = ds["fall"].values
    n = np.arange(200)[:, None]
    exact = (4 * (-1.0) ** n / ((2 * n + 1) * np.pi)
             * np.exp(-(2 * n + 1) ** 2 * np.pi**2 * B * zeta / (4 * L**2))).sum(axis=0)
    exact[0] = 1.0
    late = zeta > 0.05 * ds.attrs["mean_fall"]
    assert np.max(np.abs(ds["survival"].values - exact)[late]) < 5e-3
    # median of the series, by bisection
    lo, hi = 0.0, 10 * L**2 / B
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        sm = (4 * (-1.0) ** n[:, 0] / ((2 * n[:, 0] + 1) * np.pi)
              * np.exp(-(2 * n[:, 0] + 1) ** 2 * np.pi**2 * B * mid / (4 * L**2))).sum()
        lo, hi = (mid, hi) if sm > 0.5 else (lo, mid)
    assert ds.attrs["median_fall"] == pytest.approx(lo, rel=5e-3)


def test_2d_isotropic_constant_B_closed_form():
    a = 1.0
    ds = pair.cage_breaking(POINT, 1.0, b_par=1.0, diffusivity="mean-field", contact=a,
                            separation=2 * a)
    B = 2 * _bp(POINT, 1.0)
    exact = (0.75 - math.log(2) / 2) * a**2 / B
    assert exact * B == pytest.approx(0.4034, abs=1e-4)
    assert ds.attrs["mean_fall"] == pytest.approx(exact, rel=2e-3)


def test_3d_isotropic_constant_B_closed_form():
    # spherical shell a < |r| < 2a, start at a: B (T'' + 2 T'/r) = -1, T'(a) = 0,
    # T(2a) = 0 gives T(a) = a^2 / 3B. Axisymmetric (R, Z) finite volumes.
    point3 = Gaussian(sigma=0.01, volume=0.05, dims=3)
    ds = pair.cage_breaking(point3, 1.0, b_par=1.0, diffusivity="mean-field")
    B = 2 * _bp(point3, 1.0)
    assert ds.attrs["mean_fall"] == pytest.approx(1 / (3 * B), rel=2e-3)
    assert ds.attrs["mass_error"] < 1e-10 and ds.attrs["min_P"] >= 0


def test_3d_sphere_horizontal_pair_closed_form():
    # b_par = 0: the pair moves in its horizontal plane, a 2D radial problem in R:
    # beta (T'' + T'/R) = -1, so T(c) = int_c^s (1/R) int_c^R rho / beta(rho) drho dR
    from scipy import integrate

    k = Uniform(radius=2.5, height=0.0024, dims=3)
    beta = lambda r: 2 * _bp(k, 1.3) * (1 - k.correlation(r))  # noqa: E731
    exact = integrate.quad(lambda R: integrate.quad(lambda r: r / beta(r), 1, R)[0] / R,
                           1, 2)[0]
    ds = pair.cage_breaking(k, 1.3, diffusivity="mean-field")
    assert ds.attrs["mean_fall"] == pytest.approx(exact, rel=3e-3)
    with pytest.raises(ValueError, match="diffusivity"):
        pair.cage_breaking(k, 1.3, diffusivity="passage")


def test_2d_convergence_second_order():
    B = 2 * _bp(POINT, 1.0)
    exact = (0.75 - math.log(2) / 2) / B
    errs = []
    for h in (1 / 4, 1 / 8, 1 / 16):
        ds = pair.cage_breaking(POINT, 1.0, b_par=1.0, diffusivity="mean-field", spacing=h,
                                fall_end=1e-9)
        errs.append(abs(ds.attrs["mean_fall"] - exact) / exact)
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(orders > 1.5), (errs, orders)


def test_disk_ito_mean_fall_246_not_fickian():
    # the paper's disk, mean field, lam = 1, b_par = 0: 1D variable B along Z = 0
    b = 1.3
    Bx = lambda y: 2 * _bp(DISK, b) * (1 - DISK.correlation(y))  # noqa: E731
    ito = pair.mean_fall_1d(Bx)
    assert ito == pytest.approx(246.0, abs=0.05)
    # the Fickian form d/dy (B dP/dy): mean fall int_c^s (s - y)/B ... with B at the
    # flux-weighted point differs; its closed form int_c^s int_c^y dy'/B(y) ... = 196.7
    from scipy import integrate
    fick = integrate.quad(lambda y: (y - 1.0) / Bx(y), 1.0, 2.0)[0]
    assert fick == pytest.approx(196.7, abs=0.05)
    ds = pair.cage_breaking(DISK, b, rule=1.0, diffusivity="mean-field")
    assert ds.attrs["mean_fall"] == pytest.approx(ito, rel=3e-3)
    assert abs(ds.attrs["mean_fall"] - fick) > 40


def test_start_averaged_over_contact_directions():
    # isotropic constant B: every contact direction has the same mean fall, so the
    # average over directions equals the closed forms (2D a^2 (3/4 - ln2/2)/B, 3D a^2/3B)
    B = 2 * _bp(POINT, 1.0)
    ds = pair.cage_breaking(POINT, 1.0, b_par=1.0, diffusivity="mean-field", start="contact")
    assert ds.attrs["mean_fall"] == pytest.approx((0.75 - math.log(2) / 2) / B, rel=2e-3)
    point3 = Gaussian(sigma=0.01, volume=0.05, dims=3)
    B3 = 2 * _bp(point3, 1.0)
    ds3 = pair.cage_breaking(point3, 1.0, b_par=1.0, diffusivity="mean-field",
                             start="contact")
    assert ds3.attrs["mean_fall"] == pytest.approx(1 / (3 * B3), rel=2e-3)
    # the paper's disk with b_par = 0: vertical neighbours stay together longer
    disk = pair.cage_breaking(DISK, 1.3, diffusivity="mean-field", start="contact",
                              spacing=1 / 8)
    side = pair.cage_breaking(DISK, 1.3, diffusivity="mean-field", spacing=1 / 8)
    assert disk.attrs["mean_fall"] > 1.3 * side.attrs["mean_fall"]
    # the cage-breaking density integrates to the absorbed probability
    dz = np.diff(disk["fall"].values)[0]
    absorbed = dz * disk["breaking"].values[1:].sum()
    assert absorbed == pytest.approx(1 - disk["survival"].values[-1], abs=1e-10)


def test_anisotropic_kernel_enters_by_scaled_separation():
    k = Exponential(length=1.0, volume=0.05, aspect=2.0)
    b = 1.3
    Bx = lambda y: 2 * _bp(k, b) * (1 - k.correlation(y, axis="x"))  # noqa: E731
    ds = pair.cage_breaking(k, b, diffusivity="mean-field")
    assert ds.attrs["mean_fall"] == pytest.approx(pair.mean_fall_1d(Bx), rel=3e-3)
    # mean field B is diagonal in (x, z) and scales with the scaled separation
    T = pair.mean_field_tensor(k, b, 0.7, X=np.array([0.3, 1.1]), Z=np.array([0.4, -1.2]))
    assert np.all(T["xz"] == 0)
    C = k.correlation_vector(np.array([0.3, 1.1]), np.array([0.4, -1.2]))
    np.testing.assert_allclose(T["zz"], 2 * _bp(k, 0.7) * (1 - C), rtol=1e-14)


def test_stationary_density_is_inverse_B_on_a_closed_domain():
    # no absorption: the chain is closed; its stationary P satisfies B P = const (Ito)
    mesh = pair._solver._mesh(1.0, 2.0, 1 / 8)
    B = pair.mean_field_tensor(DISK, 1.3, 0.9, mesh.cx, mesh.cz)
    Q, kill, index = pair._solver._generator(mesh, B, 2.0, absorbing=False)
    assert np.all(kill == 0)
    n = Q.shape[0]
    # the null vector of Q^T: replace one equation by the normalisation
    A = Q.T.tolil()
    A[0, :] = np.ones(n)
    rhs = np.zeros(n)
    rhs[0] = 1.0
    m = spla.spsolve(A.tocsc(), rhs)
    P = m / mesh.area[mesh.active]
    for comp in ("xx", "zz"):
        BP = B[comp][mesh.active] * P
        assert np.ptp(BP) / BP.mean() < 1e-9
    assert m.min() > 0


def test_far_field_msd_grows_by_4_b_p():
    # far from both circles (tiny kernel, C = 0): <|r|^2> = r0^2 + 4 (b_p + b_p_par) zeta
    b, b_par = 1.0, 0.5
    x0 = 10.25                     # a cell centre on the grid of spacing 0.5
    zeta_end = 0.25 / (2 * _bp(POINT, b))  # spread sqrt(2 B zeta) = 0.7 d << 9 d to the walls
    ds = pair.cage_breaking(POINT, b, b_par=b_par, diffusivity="mean-field", contact=1.0,
                            separation=20.0, start=(x0, 0.0), spacing=0.5,
                            fall_end=zeta_end, steps_per_mean=50)
    zeta = ds["fall"].values
    expected = x0**2 + 4 * (_bp(POINT, b) + _bp(POINT, b_par)) * zeta
    np.testing.assert_allclose(ds["msd"].values, expected, rtol=1e-6)
    assert ds["survival"].values[-1] > 1 - 1e-9


def test_mass_and_positivity_anisotropic():
    k = Uniform(radius=2.5, height=0.0024, aspect=2.0)
    ds = pair.cage_breaking(k, 1.3, b_par=0.6, diffusivity="mean-field",
                            start=(0.6, 0.9), spacing=1 / 8)
    assert ds.attrs["mass_error"] < 1e-10
    assert ds.attrs["min_P"] >= 0.0
    P = ds["P"].values
    assert np.nanmin(P) >= 0.0
    # probability on the grid equals the survival at each frame
    area = ds.attrs["spacing"] ** 2
    S = np.interp(ds["frame"].values, ds["fall"].values, ds["survival"].values)
    # cut cells carry less than h^2; the total over full cells bounds it from above
    assert np.all(np.nansum(P, axis=(1, 2)) * area >= S * (1 - 1e-12))
    s = ds["survival"].values
    assert np.all(np.diff(s) <= 1e-15) and s[-1] <= 0.01
    assert 0 < ds.attrs["median_fall"] < ds.attrs["mean_fall"] * 2


def test_survival_integrates_to_the_steady_mean():
    ds = pair.cage_breaking(DISK, 1.3, b_par=0.5, diffusivity="mean-field", spacing=1 / 8)
    dz = np.diff(ds["fall"].values)[0]
    s = ds["survival"].values
    # backward Euler: dzeta * sum_{n>=1} S_n = the chain's mean exit fall, exactly; the
    # tail beyond the last step decays geometrically with the last step's ratio
    q = s[-1] / s[-2]
    tail = dz * s[-1] * q / (1 - q)
    assert dz * s[1:].sum() + tail == pytest.approx(ds.attrs["mean_fall"], rel=1e-3)


def test_dataset_units_and_attributes():
    ds = pair.cage_breaking(DISK, 1.3, diffusivity="mean-field", spacing=1 / 8)
    for name in list(ds.data_vars) + list(ds.coords):
        assert "units" in ds[name].attrs and "long_name" in ds[name].attrs, name
    for key in ("mean_fall", "median_fall", "contact", "separation", "b", "b_par", "rule",
                "diffusivity", "kernel"):
        assert key in ds.attrs
    assert ds["survival"].dims == ("fall",)
    assert ds["P"].dims == ("frame", "Z", "X")


@pytest.mark.parametrize("kwargs, name", [
    ({"contact": 2.0, "separation": 2.0}, "separation"),
    ({"contact": 2.0, "separation": 1.5}, "separation"),
    ({"start": (0.5, 0.0)}, "start"),
    ({"start": (1.0, 1.9)}, "start"),
    ({"b": -1.0}, "b"),
    ({"diffusivity": "fickian"}, "diffusivity"),
    ({"contact": 0.0}, "contact"),
])
def test_bad_arguments_name_the_argument(kwargs, name):
    args = {"b": 1.3, "diffusivity": "mean-field", **kwargs}
    b = args.pop("b")
    with pytest.raises(ValueError, match=name):
        pair.cage_breaking(DISK, b, **args)


def test_passage_diffusivity_lengthens_the_cage_at_midpoint_rule():
    mf = pair.cage_breaking(DISK, 1.3, rule=0.5, diffusivity="mean-field")
    pa = pair.cage_breaking(DISK, 1.3, rule=0.5, diffusivity="passage")
    # B_passage / B_mf = 0.20 ... 0.30 between d and 2d: the cage lasts 2.5-5 times longer
    # (vertical shot noise shortens it somewhat)
    assert 2.0 < pa.attrs["mean_fall"] / mf.attrs["mean_fall"] < 5.5
    B = pair.relative_tensor(DISK, 1.3, 0.5, 0.0, "passage", X=np.array([1.0, 1.5, 2.0]),
                             Z=np.zeros(3))
    Bm = pair.mean_field_tensor(DISK, 1.3, 0.0, X=np.array([1.0, 1.5, 2.0]), Z=np.zeros(3))
    np.testing.assert_allclose(B["xx"] / Bm["xx"], [0.20, 0.26, 0.30], atol=0.02)


def test_passage_tensor_scales_with_the_local_b_p():
    """Local uniform-flow approximation: the passage tensor with local single-particle
    lengths ``b_p = diag(s_x, s_z) b_u`` (``b_u`` the uniform-flow ones) is ``S B_u S``,
    ``S = diag(sqrt(s_x), sqrt(s_z))``: ``B^xx`` times ``s_x``, ``B^zz`` times ``s_z``, the
    cross term (not zero off the axes) times ``sqrt(s_x s_z)``, and a local ``b_p^xz`` adds
    its mean-field form ``2 b_p^xz (1 - C)``; ``b_p = 2 b_u`` halves the mean fall (the
    equation is linear in ``B``)."""
    from spotpde.fields import _passage

    k = Gaussian(sigma=1.0, volume=0.05)
    b, b_par = 1.3, 0.4
    uniform = _passage.length_tensor(k, b, b_par, 0.5)
    X, Z = np.array([1.0, 1.2, 1.5, 0.0, 0.7]), np.array([0.0, 0.5, 1.0, 1.5, -0.9])
    B_u = pair.relative_tensor(k, b, 0.5, b_par, "passage", X, Z)
    assert np.abs(B_u["xz"]).max() > 0.2 * B_u["xx"].max()
    sx, sz, xz = 2.0, 0.5, 1e-3
    local = {"xx": sx * uniform["xx"], "xz": xz, "zz": sz * uniform["zz"]}
    B = pair.relative_tensor(k, b, 0.5, b_par, "passage", X, Z, b_p=local)
    np.testing.assert_allclose(B["xx"], sx * B_u["xx"], rtol=1e-14)
    np.testing.assert_allclose(B["zz"], sz * B_u["zz"], rtol=1e-14)
    # sqrt(s_x s_z) = 1: the uniform cross term, plus the local one's mean-field form
    np.testing.assert_allclose(B["xz"], B_u["xz"] + 2 * xz * (1 - k.correlation_vector(X, Z)),
                               rtol=1e-12)
    uni = pair.cage_breaking(k, b, rule=0.5, b_par=b_par, spacing=0.25, steps_per_mean=50)
    fast = pair.cage_breaking(k, b, rule=0.5, b_par=b_par, spacing=0.25, steps_per_mean=50,
                              b_p={key: 2.0 * v for key, v in uniform.items()})
    assert fast.attrs["mean_fall"] == pytest.approx(uni.attrs["mean_fall"] / 2.0, rel=1e-9)


# -- the [pair] table of a case ---------------------------------------------------------
UNIFORM_CASE = {
    "domain": {"x": [-5.0, 5.0], "z": [0.0, 10.0], "spacing": 0.5},
    "orifice": {"width": 10.0},                 # the whole floor: uniform flow
    "spots": {"b": 1.3},
    "kernel": {"shape": "gaussian", "size": 1.0, "volume": 0.05, "diffusivity": "mean-field"},
    "pair": {"x": 0.0, "z": 6.0, "spacing": 0.125},
}


def test_case_pair_in_uniform_flow_equals_the_library_call():
    import spotpde

    ds = spotpde.run(UNIFORM_CASE)
    k = Gaussian(sigma=1.0, volume=0.05)
    b_p = {key: ds.attrs[f"pair_b_p_{key}"] for key in ("xx", "xz", "zz")}
    ref = pair.cage_breaking(k, 1.3, rule=0.5, diffusivity="mean-field", spacing=0.125,
                             b_p=b_p)
    uni = pair.cage_breaking(k, 1.3, rule=0.5, diffusivity="mean-field", spacing=0.125)
    # local b_p = D_xx / |u_z| = b V2 / V1 in uniform flow (up to the fields' sampling of
    # the kernel on the 0.5 d grid); no vertical diffusion with b_par = 0
    assert b_p["xx"] == pytest.approx(_bp(k, 1.3), rel=1e-3)
    assert abs(b_p["xz"]) < 1e-9 * b_p["xx"] and b_p["zz"] == 0.0
    assert ds.attrs["pair_mean_fall"] == pytest.approx(ref.attrs["mean_fall"], rel=1e-9)
    assert ds.attrs["pair_mean_fall"] == pytest.approx(uni.attrs["mean_fall"], rel=1e-3)
    assert ds["pair_survival"].dims == ("pair_fall",)
    for name in ("pair_survival", "pair_msd", "pair_P", "pair_B_xx"):
        assert {"units", "long_name"} <= set(ds[name].attrs)


@pytest.mark.parametrize("table, key", [
    ({"contact": 2.0, "separation": 2.0}, "pair.separation"),
    ({"start": {"x": 0.5, "z": 0.0}}, "pair.start: is inside the core"),
    ({"start": {"x": 1.5, "z": 1.5}}, "pair.start: is outside the cage"),
    ({"contact": -1.0}, "pair.contact"),
    ({"spacng": 0.1}, "did you mean 'spacing'"),
    ({"x": 50.0}, "pair.x"),
])
def test_case_bad_pair_table_names_the_key(table, key):
    import spotpde

    raw = {k: dict(v) for k, v in UNIFORM_CASE.items()}
    raw["pair"].update(table)
    with pytest.raises(spotpde.CaseError) as err:
        spotpde.load_case(raw)
    assert any(key in line for line in err.value.problems), err.value.problems


def test_case_pair_start_contact_is_accepted():
    import spotpde

    raw = {k: dict(v) for k, v in UNIFORM_CASE.items()}
    raw["pair"]["start"] = "contact"
    assert spotpde.load_case(raw).data["pair"]["start"] == "contact"
    raw["pair"]["start"] = "contacts"
    with pytest.raises(spotpde.CaseError, match="pair.start"):
        spotpde.load_case(raw)


def test_cli_bad_pair_exits_2_without_output(tmp_path):
    import subprocess
    import sys

    case = tmp_path / "bad.toml"
    out = tmp_path / "out.nc"
    case.write_text('[pair]\nx = 0.0\nz = 10.0\nstart = { x = 0.5, z = 0.0 }\n'
                    f'[output]\npath = "{out}"\n')
    proc = subprocess.run([sys.executable, "-m", "spotpde", "run", str(case)],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        "pair.start: is inside the core: |start| = 0.5 < pair.contact = 1.0"]
    assert not out.exists()


# -- Monte Carlo of two particles in the discrete model ------------------------------------
RADII = np.array([1.0, 1.5, 2.0])
ANGLES = np.array([0.0, np.pi / 4, np.pi / 2])


def _probe_table(kernel, rule, spots, seed=11):
    from spotpde.pair import _mc as _pair_mc

    R, A = np.meshgrid(RADII, ANGLES, indexing="ij")
    tab = _pair_mc.probe_tensor(kernel, 1.3, rule, (R * np.cos(A)).ravel(),
                                (R * np.sin(A)).ravel(), spots=spots, seed=seed)
    table = {k: tab[k].reshape(3, 3) for k in ("xx", "xz", "zz")}
    rel_se = max(float(np.max(tab[k + "_se"] / np.abs(tab[k]))) for k in ("xx", "zz"))
    return table, rel_se


def test_frozen_pair_tensor_rule_one_near_mean_field_rule_half_far_below():
    k = Uniform(radius=2.5, height=0.01)
    mf = pair.mean_field_tensor(k, 1.3, 0.0, X=1.5, Z=0.0)["xx"]
    from spotpde.pair import _mc as _pair_mc

    one = _pair_mc.probe_tensor(k, 1.3, 1.0, [1.5], [0.0], spots=40_000, seed=1)
    half = _pair_mc.probe_tensor(k, 1.3, 0.5, [1.5], [0.0], spots=40_000, seed=2)
    # rule 1: mean field up to O(w) (particles move while the spot passes: measured
    # 0.93 at w = 0.03); rule 1/2: passage correlations, about 0.3 of it
    assert abs(one["xx"][0] / mf - 1) < 3 * one["xx_se"][0] / mf + 3 * 0.01
    assert half["xx"][0] / mf < 0.45
    # vertical shot noise: a relative vertical diffusion that mean field (b_par = 0) lacks
    assert one["zz"][0] > 10 * one["zz_se"][0]


@pytest.mark.slow
def test_monte_carlo_cage_breaking_against_the_equation():
    # Two particles in the discrete model (paper's disk with w = 0.03 to keep it short,
    # b = 1.3 d, step 0.05 d), 400 independent pairs per rule, start side by side at
    # contact. The hard core reflects along B n (conormal), the reflection whose density
    # obeys the zero-Ito-flux condition. Reference: the 2D equation with the discrete
    # model's own B(r), measured on frozen pairs (3 radii x 3 angles).
    from spotpde.pair import _mc as _pair_mc

    k = Uniform(radius=2.5, height=0.03)
    mf = pair.cage_breaking(k, 1.3, diffusivity="mean-field").attrs["mean_fall"]
    means = {}
    for rule in (1.0, 0.5):
        table, rel_se = _probe_table(k, rule, spots=40_000)
        fp = pair.solve(_pair_mc.tabulated_tensor(table, RADII, ANGLES), 1.0, 2.0)["mean_fall"]
        f = _pair_mc.cage_breaking_mc(k, 1.3, rule=rule, replicas=400, seed=5,
                                      contact_tensor=(ANGLES, {c: v[0] for c, v in table.items()}))
        assert np.all(np.isfinite(f))
        se = f.std(ddof=1) / np.sqrt(len(f))
        se_fp = rel_se * fp            # the mean fall scales like 1/B
        assert abs(f.mean() - fp) < 3 * np.hypot(se, se_fp), (rule, f.mean(), se, fp)
        means[rule] = (f.mean(), se)
    # rule 1: mean field within the standard error; rule 1/2: far from it
    assert abs(means[1.0][0] - mf) < 3 * means[1.0][1]
    assert (means[0.5][0] - mf) / means[0.5][1] > 8


@pytest.mark.slow
def test_frozen_pair_tensor_converges_to_the_passage_quadrature():
    # Smooth kernel (Gaussian sigma = 1 d, small V1 = 0.01: no motion during a passage),
    # b = 1.3 d, lam = 1/2, step 0.05 d: the discrete model's frozen-pair B^xx, B^xz, B^zz
    # at d, 1.5 d, 2 d and 0, 45, 90 degrees agree with the Fourier quadrature. (The sharp
    # uniform disk converges only like step^0.7 at its edge: 46 % above the quadrature
    # at contact at step 0.05 d, 7 % at 0.003 d; docs/pair.md, section 3.)
    from spotpde.fields import _passage
    from spotpde.pair import _mc as _pair_mc

    k = Gaussian(sigma=1.0, volume=0.01)
    R, A = np.meshgrid(RADII, ANGLES, indexing="ij")
    X, Z = (R * np.cos(A)).ravel(), (R * np.sin(A)).ravel()
    q = _passage.length_tensor(k, 1.3, 0.0, 0.5, separation=(X, Z))
    mc = _pair_mc.probe_tensor(k, 1.3, 0.5, X, Z, spots=40_000, seed=3, step=0.05)
    for c in ("xx", "xz", "zz"):
        z = (mc[c] - q[c]) / mc[c + "_se"]
        assert np.all(np.abs(z) < 3.5), (c, mc[c], q[c], mc[c + "_se"])


@pytest.mark.slow
def test_monte_carlo_rule_half_agrees_with_passage():
    # Two particles in the discrete model at lam = 1/2 against the passage equation
    # (w -> 0, step -> 0 limit). The uniform disk of the issue (R = 2.5 d, w = 0.03) is
    # not converged in the step (its sharp edge: B^xx 18-46 % above the quadrature at
    # step 0.05 d, docs/pair.md), so the check uses a smooth kernel whose discrete B
    # matches the quadrature at step 0.05 d (test above): Gaussian sigma = 1 d with
    # V1 = 0.377 (w(0) = 0.06; motion during a passage lowers B^xx by 4 %, B^zz by 7 %,
    # below the standard error of the mean fall), b = 1.3 d, 100 pairs side by side at
    # contact, conormal hard core.
    from spotpde.pair import _mc as _pair_mc

    k = Gaussian(sigma=1.0, volume=0.377)
    pa = pair.cage_breaking(k, 1.3, rule=0.5, diffusivity="passage",
                            fall_end=1.0).attrs["mean_fall"]
    mf = pair.cage_breaking(k, 1.3, rule=0.5, diffusivity="mean-field",
                            fall_end=1.0).attrs["mean_fall"]
    at_contact = pair.relative_tensor(k, 1.3, 0.5, 0.0, "passage", X=np.cos(ANGLES),
                                      Z=np.sin(ANGLES))
    f = _pair_mc.cage_breaking_mc(k, 1.3, rule=0.5, replicas=100, seed=7, step=0.05,
                                  contact_tensor=(ANGLES, at_contact))
    assert np.all(np.isfinite(f))
    se = f.std(ddof=1) / np.sqrt(len(f))
    # passage 46.4 d, mean field 19.2 d; measured 46.0 +- 3.1 d (this test), 45.0 +- 2.6 d
    # (150 pairs), 47.3 +- 3.7 d (100 pairs, step 0.025 d)
    assert abs(f.mean() - pa) < 3 * se, (f.mean(), se, pa)
    assert (f.mean() - mf) / se > 8, (f.mean(), se, mf)
    assert abs(f.mean() - pa) < abs(f.mean() - mf) / 2
