"""Mutation audit: does the test suite catch the physics bugs that matter? (issue 32)

Each entry of :data:`MUTATIONS` is one single-line change to the physics code (a factor,
a sign, a dropped term, a wrong index, a moved pole), with the tests that cover that
code. The script copies the working tree (its files as they are, committed or not) to a
scratch directory, checks that those tests pass there unmutated (the baseline), then for
each mutation writes the mutated file into the scratch copy, runs its tests
(``python -m pytest -x``, the scratch copy first on the path), restores the file and
prints whether a test failed (``caught``) or all passed (``SURVIVED``). The working
tree is never modified. Exit status 1 if a mutation survived (or the baseline failed).

Run (from the repository root, with the project's interpreter):

    python benchmarks/mutation.py                 # all mutations, about 15 min on 2 cores
    python benchmarks/mutation.py -k pair -k mc   # the mutations whose name has "pair"/"mc"
    python benchmarks/mutation.py --list          # the list, with files and tests
    python benchmarks/mutation.py --files         # each against its whole test files

The scratch copy lives in ``<spotpde user cache>/mutation/<hash of the tree's path>``
and is kept between runs (so numba's cache of the unmutated kernels is reused; a
mutated kernel is recompiled, and recompiled back after). ``--fresh`` starts it anew.
Timings vary with the machine's load; the result (caught or survived) does not, as
every test uses fixed seeds.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SKIP = shutil.ignore_patterns(".git", ".venv", "__pycache__", "*.egg-info", ".pytest_cache",
                              ".hypothesis", "build", "dist", "*.nc", "out")


@dataclass(frozen=True)
class Mutation:
    """One single-line mutation: ``old`` (exactly once in ``path``) becomes ``new``."""

    name: str
    path: str
    old: str
    new: str
    tests: tuple[str, ...]
    what: str
    issue32: bool = False      # one of the ten the issue found surviving


M = Mutation
F, T = "spotpde/fields/", "tests/"
MUTATIONS = (
    # -- the ten survivors of the audit in issue 32 -----------------------------------------
    M("axisym-div-u", "spotpde/geometry/_shapes.py",
      'radial = masked_derivative(r * u["u_r"], h, 1, act, even_axis=True) / r',
      'radial = masked_derivative(u["u_r"], h, 1, act, even_axis=True)',
      (T + "fields/test_axisymmetric_fields.py::test_cylindrical_divergences_of_linear_fields",
       T + "fields/test_axisymmetric_fields.py::test_incompressibility_defect_of_a_cylinder_is_the_rule_s"),
      "div u_p on a cylinder: (1/r) d_r(r u_r) -> d_r u_r", True),
    M("axisym-div-Drz", "spotpde/geometry/_shapes.py",
      'out["z"] += masked_derivative(r * rz, h, 1, act, even_axis=True) / r',
      'out["z"] += masked_derivative(rz, h, 1, act, even_axis=True)',
      (T + "fields/test_axisymmetric_fields.py::test_cylindrical_divergences_of_linear_fields",),
      "(div D)_z on a cylinder: (1/r) d_r(r D_rz) -> d_r D_rz", True),
    M("walls-general-phi2", F + "_walls.py",
      'conv.request("rho_phi2", rho_s * inv * inv, 2)',
      'conv.request("rho_phi2", rho_s * inv, 2)',
      (T + "fields/test_walls.py::test_general_renormalised_path_matches_the_closed_form",),
      "renormalised walls, general path: D_p source rho_s / phi^2 -> rho_s / phi", True),
    M("pair-bp-ratio", "spotpde/pair/_solver.py",
      "ratio = {k: b_p[k] / float(far[k])",
      "ratio = {k: float(far[k]) / b_p[k]",
      (T + "pair/test_pair.py::test_passage_tensor_scales_with_the_local_b_p",),
      "pair passage tensor with a local b_p: ratio b_p / b_uniform inverted", True),
    M("mc-vertical-midpoint", "spotpde/montecarlo/_mc_kernels.py",
      "cz_ = oz + lam * dz", "cz_ = oz + dz",
      (T + "montecarlo/test_montecarlo.py::test_vertical_midpoint_keeps_the_particle_flux_where_spots_leave",),
      "Monte Carlo: the influence's vertical centre at the step's end, whatever lam", True),
    M("mc-phi-nearest-node", "spotpde/montecarlo/_mc_kernels.py",
      "return 1.0 / ((1.0 - ft) * phi_tab[kt] + ft * phi_tab[kt + 1])",
      "return 1.0 / (phi_tab[kt] if ft < 0.5 else phi_tab[kt + 1])",
      (T + "montecarlo/test_montecarlo.py::test_coverage_between_table_nodes_is_the_closed_form",),
      "Monte Carlo: 1/phi at the nearest table node instead of interpolated", True),
    M("mc-persistence", "spotpde/montecarlo/_mc_kernels.py",
      "return math.sqrt(1.0 - gamma * gamma), 0.5 * (1.0 + gamma)",
      "return math.sqrt(1.0 - gamma * gamma), 0.5 * (1.0 + 0.9 * gamma)",
      (T + "montecarlo/test_montecarlo.py::test_persistent_walk_diffusion_length",),
      "Monte Carlo: binary walk keeps its sign with (1 + 0.9 gamma)/2", True),
    M("traffic-characteristic-speed", "spotpde/density/_traffic.py",
      "return 1.0 - 2.0 * y", "return 1.0 - y",
      (T + "density/test_traffic.py::test_small_bump_moves_at_c",
       T + "density/test_traffic.py::test_run_dataset_variables"),
      "interacting spots: c = q'(rho) = v_s (1 - 2 rho/rho_max) -> v_s (1 - rho/rho_max)", True),
    M("se-calibration-dof", "spotpde/montecarlo/mcstats.py",
      "dof = m * (R - 1)", "dof = m * R",
      (T + "montecarlo/test_mcstats.py::test_se_calibration_accepts_right_errors_at_the_stated_rate",),
      "se_calibration: chi-square degrees of freedom m (R - 1) -> m R", True),
    M("passage-pole", F + "_passage.py",
      "Q = np.sqrt(1.0 + 4.0 * b_par * G)", "Q = np.sqrt(1.0 + 2.0 * b_par * G)",
      (T + "fields/test_passage.py::test_b_par_against_adaptive_quadrature",),
      "passage quadrature: the subtracted pole of 1/Gamma moved (b_par > 0 only)", True),
    # -- caught in the audit (as reconstructed) ------------------------------------------------
    M("walls-general-2lam", F + "_walls.py",
      'u_terms[a].append((2.0 * lam, conv.request(f"div_{a}_phi"',
      'u_terms[a].append((lam, conv.request(f"div_{a}_phi"',
      (T + "fields/test_fields_fastpaths.py::test_renormalised_walls_by_strips_equal_the_general_path",),
      "renormalised walls, general path: 2 lam div(D_s rho_s) -> lam div(D_s rho_s)"),
    M("walls-coverage-beyond-wall", F + "_walls.py",
      'out = np.pad(out, pad, mode="constant")', 'out = np.pad(out, pad, mode="edge")',
      (T + "fields/test_walls.py::test_coverage_is_the_kernel_fraction_inside_the_walls_2d_and_3d",
       T + "fields/test_walls.py::test_particle_flux_is_V1_Q0_at_every_height_2d"),
      "coverage phi: material continued beyond a reflecting wall"),
    M("wall-layer-rule", F + "_wall_layer.py",
      "(1.0 - 2.0 * lam) * _wall_layer(", "(1.0 - lam) * _wall_layer(",
      (T + "fields/test_walls.py::test_uniform_flow_between_walls_matches_closed_form_at_second_order",),
      "wall layer: (1 - 2 lam) -> (1 - lam)"),
    M("wall-layer-renormalised", F + "_wall_layer.py",
      "faces = {s: v / _walls.face_value(phi, axis, s) for s, v in faces.items()}",
      "faces = {s: v for s, v in faces.items()}",
      (T + "fields/test_walls.py::test_wall_layer_of_rule_one_is_divided_by_the_coverage_at_the_wall",),
      "wall layer of renormalised walls: not divided by phi on the wall"),
    M("constant-fields-rule", F + "_constant.py",
      "g = lam * hd / h            # 2 lam D^ab", "g = 0.5 * lam * hd / h      # 2 lam D^ab",
      (T + "fields/test_coefficients.py::test_point_orifice_fields_match_height_quadrature",),
      "2D one-pass fields: 2 lam div(D_s rho_s) -> lam div(D_s rho_s)"),
    M("passage-rule-factor", F + "_passage.py",
      "out = -8.0 * lam * (1.0 - lam) * Dk[i] * Dk[j]",
      "out = -4.0 * lam * (1.0 - lam) * Dk[i] * Dk[j]",
      (T + "fields/test_passage.py::test_gaussian_closed_form",),
      "passage tensor: 8 lam (1 - lam) -> 4 lam (1 - lam)"),
    M("passage-shot-noise", F + "_passage.py",
      "out = out + 2.0", "out = out + 1.0",
      (T + "fields/test_passage.py::test_gaussian_closed_form",),
      "passage tensor: vertical shot noise 2 v_s^2 -> v_s^2"),
    M("passage-mean-field-term", F + "_passage.py",
      "M += 2.0 * (b_par if i == z else b)", "M += 2.0 * b",
      (T + "fields/test_passage.py::test_b_par_against_adaptive_quadrature",),
      "passage tensor: the mean-field term of zz uses b instead of b_par"),
    M("pair-absorbing-circle", "spotpde/pair/_solver.py",
      "beyond = out & (xo**2 + zo**2 >= s * s)", "beyond = out & (xo**2 + zo**2 >= 0.0)",
      (T + "pair/test_pair.py::test_1d_constant_B_mean_fall",
       T + "pair/test_pair.py::test_2d_isotropic_constant_B_closed_form"),
      "pair solver: the hard core absorbs like the cage's circle"),
    M("pair-kushner-reduction", "spotpde/pair/_solver.py",
      "cf = np.maximum(coef[J, I] - mixed[J, I], 0.0)", "cf = coef[J, I]",
      (T + "pair/test_pair.py::test_mass_and_positivity_anisotropic",
       T + "pair/test_pair.py::test_monte_carlo_cage_breaking_against_the_equation"),
      "pair solver: axis rates not reduced by the diagonal (mixed) rates"),
    M("steady-hybrid-bound", "spotpde/tracer/_steady.py",
      "np.clip(2.0 * A_down / np.where(au > 0, au, 1.0)",
      "np.clip(4.0 * A_down / np.where(au > 0, au, 1.0)",
      (T + "tracer/test_steady.py::test_advection_dominated_positive_and_matches_time_stepping",
       T + "tracer/test_steady.py::test_void_point_orifice_gives_brownian_bridge"),
      "steady propagator: central weight beyond the M-matrix bound (cell Peclet 4)"),
    M("steady-floor-flux", "spotpde/tracer/_steady.py",
      "F[0] = uf[0] * G[0]", "F[0] = uf[0] * G[1]",
      (T + "tracer/test_steady.py::test_void_point_orifice_gives_brownian_bridge",
       T + "tracer/test_steady.py::test_steady_equals_time_stepped_limit_and_mean_exit_time"),
      "steady propagator: the floor's P_height from the second row"),
    M("traffic-shock", "spotpde/density/_traffic.py",
      "F[k + 1, j] = min(dem, sup)", "F[k + 1, j] = max(dem, sup)",
      (T + "density/test_traffic.py::test_shock_speed",),
      "interacting spots: Godunov flux min(demand, supply) -> max"),
    M("traffic-fan", "spotpde/density/_traffic.py",
      "dem = _q(min(lo, rc), v, rho_max, kind)", "dem = _q(lo, v, rho_max, kind)",
      (T + "density/test_traffic.py::test_transonic_rarefaction_entropy_fix",
       T + "density/test_traffic.py::test_fan_converges_to_closed_form"),
      "interacting spots: demand not capped at the critical density (transonic fans)"),
    M("mc-horizontal-midpoint", "spotpde/montecarlo/_mc_kernels.py",
      "cx_ = ox + lam * dx", "cx_ = ox + dx",
      (T + "montecarlo/test_montecarlo.py::test_converging_silo_mean_velocity_matches_continuum",),
      "Monte Carlo: the influence's horizontal centre at the step's end, whatever lam"),
    M("spectral-decay", "spotpde/density/_spectral.py",
      "return 2.0 * b * k2 / (1.0 + np.sqrt(1.0 + 4.0 * b * b_par * k2))",
      "return 2.0 * b * k2 / (1.0 + np.sqrt(1.0 + 2.0 * b * b_par * k2))",
      (T + "density/test_spot_density.py::test_exact_modes_with_d_par_conserve_flux_and_match_finite_volumes",
       T + "density/test_spot_density.py::test_mode_profile_solves_its_ode"),
      "spot density with D_par: decay rate of a mode from the wrong root"),
    M("kinematic-point-source", "spotpde/density/kinematic.py",
      "four_bz = 4.0 * b * zz if", "four_bz = 2.0 * b * zz if",
      (T + "density/test_kinematic.py::test_point_source_solves_kinematic_equation",),
      "Kinematic Model: point source exp(-x^2/4bz) -> exp(-x^2/2bz)"),
    M("void-drift", F + "void.py",
      '"u_x": 2.0 * lam * V1 * derivative(Fh, h, ax["x"]),',
      '"u_x": lam * V1 * derivative(Fh, h, ax["x"]),',
      (T + "fields/test_void.py::test_void_fields_give_lattice_drift_and_diffusion_per_fall",
       T + "fields/test_void.py::test_void_flux_velocity_is_kinematic"),
      "void model: drift 2 lam d_x(D_perp rho_s) -> lam d_x(...)"),
    M("tracer-tensor-split", "spotpde/tracer/_diffusion.py",
      "axial[a] = axial[a] - np.abs(c)", "axial[a] = axial[a]",
      (T + "tracer/test_steady.py::test_exit_probabilities_sum_to_one_and_positive",
       T + "tracer/test_tracer.py::test_tensor_diffusion_covariance_is_exact"),
      "tracer diffusion: the axial rates not reduced by the cross terms (9-point split)"),
    M("spectral-decay-no-bpar", "spotpde/density/_spectral.py",
      "    if b_par == 0:\n        return b * k2", "    if b_par == 0:\n        return 2.0 * b * k2",
      (T + "density/test_spot_density.py::test_slot_open_walls_is_erf",
       T + "density/test_spot_density.py::test_point_2d_reflecting_equals_images"),
      "spot density, D_par = 0: modes decay at 2 b k^2 instead of b k^2"),
)


# ------------------------------------------------------------------------------------------
def scratch_dir(fresh: bool, worker: int) -> Path:
    """A copy of the tree under the spotpde user cache, refreshed from the working tree."""
    sys.path.insert(0, str(ROOT))
    from spotpde._cache import user_cache_dir

    tag = hashlib.sha1(str(ROOT).encode()).hexdigest()[:12]
    dest = user_cache_dir() / "mutation" / tag / f"w{worker}"
    if fresh and dest.exists():
        shutil.rmtree(dest)
    for top in ("spotpde", "tests", "cases", "notebooks", "docs"):
        if (dest / top).exists():
            shutil.rmtree(dest / top)      # files removed from the tree must go too
    dest.mkdir(parents=True, exist_ok=True)
    for item in ROOT.iterdir():
        if item.name in {".git", ".venv", "benchmarks"} or SKIP(str(ROOT), [item.name]):
            continue
        if item.is_dir():
            # copy2 keeps modification times: numba's cache of unchanged kernels stays valid
            shutil.copytree(item, dest / item.name, ignore=SKIP, dirs_exist_ok=True)
        else:
            shutil.copy2(item, dest / item.name)
    return dest


def pytest(scratch: Path, tests, timeout: float):
    """Run ``tests`` in ``scratch``; returns (status, seconds, first failing test)."""
    env = {**os.environ, "PYTHONPATH": str(scratch), "PYTHONDONTWRITEBYTECODE": "1",
           "MPLBACKEND": "Agg"}
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-rfE", "-p", "no:cacheprovider",
           "-o", "addopts=", *tests]
    t0 = time.perf_counter()
    try:
        out = subprocess.run(cmd, cwd=scratch, env=env, capture_output=True, text=True,
                             timeout=timeout)
    except subprocess.TimeoutExpired:
        return "timeout", time.perf_counter() - t0, ""
    dt = time.perf_counter() - t0
    failed = [ln.split(" ", 2)[1] for ln in out.stdout.splitlines()
              if ln.startswith(("FAILED ", "ERROR "))]
    if out.returncode == 0:
        return "passed", dt, ""
    if out.returncode == 1 and failed:
        return "failed", dt, failed[0]
    tail = (out.stdout + out.stderr).strip().splitlines()
    return "error", dt, tail[-1] if tail else f"exit status {out.returncode}"


def apply(scratch: Path, m: Mutation) -> tuple[str, int]:
    """Write the mutated file into ``scratch``; returns (original text, line number)."""
    p = scratch / m.path
    text = p.read_text()
    if text.count(m.old) != 1:
        raise SystemExit(f"mutation {m.name}: {m.old!r} occurs {text.count(m.old)} times in "
                         f"{m.path} (must be exactly once): update MUTATIONS")
    line = text[:text.index(m.old)].count("\n") + 1
    p.write_text(text.replace(m.old, m.new))
    return text, line


def restore(scratch: Path, m: Mutation, text: str) -> None:
    p = scratch / m.path
    p.write_text(text)
    src = ROOT / m.path
    st = src.stat()
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns))   # the original's stamp again


def selection(m: Mutation, files: bool) -> list[str]:
    return sorted({t.split("::")[0] for t in m.tests}) if files else list(m.tests)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-k", action="append", default=[],
                    help="only mutations whose name contains this (repeatable)")
    ap.add_argument("--list", action="store_true", help="print the mutations and exit")
    ap.add_argument("--files", action="store_true",
                    help="run each mutation against its whole test files")
    ap.add_argument("--no-baseline", action="store_true",
                    help="skip the unmutated run of the selected tests")
    ap.add_argument("--fresh", action="store_true", help="new scratch copy (no numba cache)")
    ap.add_argument("--timeout", type=float, default=1200.0, help="seconds per mutation")
    args = ap.parse_args(argv)

    chosen = [m for m in MUTATIONS if not args.k or any(k in m.name for k in args.k)]
    if args.list:
        for m in chosen:
            print(f"{m.name:30s} {m.path}  [{'issue 32' if m.issue32 else 'audit'}]\n"
                  f"    {m.what}\n    tests: {' '.join(selection(m, args.files))}")
        return 0
    if not chosen:
        print("no mutation matches", args.k)
        return 2
    load = os.getloadavg()[0]
    print(f"mutation audit: {len(chosen)} mutations; load average {load:.2f}")
    scratch = scratch_dir(args.fresh, 0)
    probe = subprocess.run([sys.executable, "-c", "import spotpde; print(spotpde.__file__)"],
                           cwd=scratch, env={**os.environ, "PYTHONPATH": str(scratch)},
                           capture_output=True, text=True)
    if not probe.stdout.strip().startswith(str(scratch)):
        print(f"spotpde does not import from the scratch copy {scratch}: {probe.stdout}"
              f"{probe.stderr}")
        return 2
    if not args.no_baseline:
        tests = sorted({t for m in chosen for t in selection(m, args.files)})
        status, dt, what = pytest(scratch, tests, args.timeout * 2)
        print(f"baseline (unmutated, {len(tests)} selections): {status} in {dt:.0f} s {what}")
        if status != "passed":
            return 1
    results = []
    for m in chosen:
        text, line = apply(scratch, m)
        try:
            status, dt, what = pytest(scratch, selection(m, args.files), args.timeout)
        finally:
            restore(scratch, m, text)
        verdict = {"failed": "caught", "timeout": "caught (timeout)",
                   "passed": "SURVIVED"}.get(status, f"ERROR ({what})")
        results.append((m, verdict))
        print(f"{verdict:16s} {m.name:30s} {m.path}:{line:<5d} {dt:6.0f} s  {what}", flush=True)
    caught = sum(v.startswith("caught") for _, v in results)
    survived = [m.name for m, v in results if v == "SURVIVED"]
    errors = [m.name for m, v in results if v.startswith("ERROR")]
    i32 = [(m, v) for m, v in results if m.issue32]
    print(f"total: {caught} caught, {len(survived)} survived, {len(errors)} errors of "
          f"{len(results)} mutations" + (f" (issue 32's ten: "
          f"{sum(v.startswith('caught') for _, v in i32)} of {len(i32)} caught)" if i32 else ""))
    if survived:
        print("survived:", ", ".join(survived))
    return 1 if survived or errors else 0


if __name__ == "__main__":
    sys.exit(main())
