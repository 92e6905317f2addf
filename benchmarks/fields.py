"""Benchmark: every field of a 2D case without tracer, spotpde against a plain SciPy version.

What ``spotpde.run`` computes for a case without a tracer is the steady spot density
``rho_s``, the particle drift ``u_p`` and diffusivity ``D_p`` and the kinematic speed
``v_kin``. This script times, side by side in one run on the same 2D case (1024 x 1024
cells by default: spacing d/8, the paper's disk kernel R = 2.5 d, height 0.0024,
b = 1.3 d, a slot orifice 4 d wide, reflecting walls, rule 1/2):

* spotpde: ``spot_density.steady`` + ``coefficients.particle_fields`` +
  ``kinematic.speed`` (what the pipeline calls);
* a straightforward SciPy implementation of the same equations: Crank-Nicolson marching
  in height of ``d phi/dz = b d2 phi/dx2`` (``phi = v_s rho_s``; finite-volume Laplacian
  with no-flux walls; ``scipy.linalg.solve_banded`` per step), once for ``rho_s`` and once
  for ``v_kin``; then ``scipy.signal.fftconvolve(..., mode="same")`` per field with the
  kernel stencil cut to its support (``u_x``, ``u_z`` with ``w``; ``D_xx``, ``D_zz`` with
  ``w**2``), the divergence by ``np.gradient``.

Both use the same cell-averaged stencils (``kernel.sample``). Prints the best-of-N wall
time of each (after one warm-up run, which also builds FFTW plans), their ratio, and the
agreement of the two results: the largest difference of each field relative to that
field's maximum magnitude, over the cells at least 4 d above the orifice (below that the
reference's Crank-Nicolson steps of h = d/8 are not yet converged on the singular slot
edges: b dz / h**2 = 10), and over all cells.

Usage::

    .venv/bin/python benchmarks/fields.py [--n 1024] [--repeat 3]
"""

from __future__ import annotations

import argparse

import numpy as np
from _timing import best_time, best_times
from scipy.linalg import solve_banded
from scipy.signal import fftconvolve
from scipy.special import erf

from spotpde.fields import coefficients, kernels
from spotpde.density import kinematic, spot_density
from spotpde.grid import Grid
from spotpde.density.orifice import source_profile
from spotpde.parameters import Orifice, Spots


def case(n: int):
    h = 1.0 / 8.0
    half = n * h / 2
    grid = Grid(2, (-half, half), (0.0, n * h), h, walls="reflecting")
    orifice = Orifice(x=0.0, width=4.0, profile="uniform", rate=1.0)
    spots = Spots(drift=1.0, b=1.3, b_par=0.0)
    kernel = kernels.Uniform(radius=2.5, height=0.0024, dims=2)
    return grid, orifice, spots, kernel, 0.5


def spotpde_fields(grid, orifice, spots, kernel, rule, diffusivity="mean-field"):
    rho_s = spot_density.steady(grid, orifice, spots)
    # the SciPy reference below truncates the kernel at the walls (kernel.walls = "truncate")
    fields = coefficients.particle_fields(grid, rho_s, spots, kernel, rule=rule,
                                          diffusivity=diffusivity, walls="truncate")
    v_kin = kinematic.speed(grid, orifice, float(spots.b)) * kernel.V1 * orifice.rate_at(0.0)
    return {"rho_s": rho_s, "v_kin": v_kin, **fields}


def cn_march(phi0: np.ndarray, b: float, h: float, nz: int) -> np.ndarray:
    """Crank-Nicolson in height for d phi/dz = b phi_xx, no-flux walls, cell centres.

    Starts from ``phi0`` on the floor, a half step to the first cell centre, then steps h.
    """
    n = phi0.size

    def matrices(dz):
        r = b * dz / h**2
        # A = I - r/2 L, L the finite-volume Laplacian (-1 on the diagonal at the walls)
        diag = np.full(n, 1.0 + r)
        diag[0] = diag[-1] = 1.0 + r / 2
        ab = np.zeros((3, n))
        ab[0, 1:] = -r / 2
        ab[1] = diag
        ab[2, :-1] = -r / 2
        return ab, r

    def step(phi, ab, r):
        lap = np.empty_like(phi)
        lap[1:-1] = phi[2:] - 2 * phi[1:-1] + phi[:-2]
        lap[0] = phi[1] - phi[0]
        lap[-1] = phi[-2] - phi[-1]
        return solve_banded((1, 1), ab, phi + 0.5 * r * lap)

    out = np.empty((nz, n))
    ab, r = matrices(h / 2)
    out[0] = step(phi0, ab, r)
    ab, r = matrices(h)
    for k in range(1, nz):
        out[k] = step(out[k - 1], ab, r)
    return out


def scipy_fields(grid, orifice, spots, kernel, rule):
    h, b, v_s, Q0 = grid.spacing, float(spots.b), float(spots.drift), orifice.rate_at(0.0)
    s = source_profile(grid, orifice)
    rho_s = cn_march(Q0 * s, b, h, grid.nz) / v_s
    v_kin = cn_march(s, b, h, grid.nz) * kernel.V1 * Q0
    return {"rho_s": rho_s, "v_kin": v_kin,
            **scipy_particle_fields(grid, rho_s, spots, kernel, rule)}


def lean_fields(grid, orifice, spots, kernel, rule):
    """The lean SciPy reference of issue 16: one Crank-Nicolson march (v_kin is the same
    profile as v_s rho_s for uniform b and b_par = 0), then one fftconvolve per non-zero
    field (D_zz and D_xz vanish for b_par = 0)."""
    h, b, v_s, Q0 = grid.spacing, float(spots.b), float(spots.drift), orifice.rate_at(0.0)
    phi = cn_march(Q0 * source_profile(grid, orifice), b, h, grid.nz)
    rho_s = phi / v_s
    w1, w2 = kernel.sample(h, 1), kernel.sample(h, 2)
    hd = h**2
    div_x = np.gradient(b * v_s * rho_s, h, axis=1, edge_order=2)
    return {"rho_s": rho_s, "v_kin": kernel.V1 * phi,
            "u_x": hd * fftconvolve(2 * rule * div_x, w1, mode="same"),
            "u_z": hd * fftconvolve(-v_s * rho_s, w1, mode="same"),
            "D_xx": hd * fftconvolve(b * v_s * rho_s, w2, mode="same"),
            "D_xz": np.zeros(grid.shape), "D_zz": np.zeros(grid.shape)}


def lean_default_fields(grid, orifice, spots, kernel, rule):
    """The lean SciPy reference of what ``spotpde.run`` computes by default.

    Renormalised walls: ``phi(x) = (1/V1) w * chi`` (the kernel's column sums convolved
    with the material indicator's row, zero beyond the walls) divides every source, ``phi**2`` the
    diffusivity's. Passage diffusivity: ``D_p = w^2 * (rho_s v_s b_eff / phi^2)`` with the
    model constants ``b_eff`` (``_passage.effective_spot_length``; D_zz is a multiple of
    D_xx), and the drift gains ``div(D_p - D_p_mf)`` (``np.gradient``). The wall layer
    vanishes at the midpoint rule of this case. One Crank-Nicolson march as in
    :func:`lean_fields`; three ``fftconvolve`` of the whole grid."""
    from spotpde.fields import _passage

    h, b, v_s, Q0 = grid.spacing, float(spots.b), float(spots.drift), orifice.rate_at(0.0)
    phi_flux = cn_march(Q0 * source_profile(grid, orifice), b, h, grid.nz)
    rho_s = phi_flux / v_s
    w1, w2 = kernel.sample(h, 1), kernel.sample(h, 2)
    m = (w1.shape[1] - 1) // 2     # chi is 1 in the silo, 0 beyond the walls, any height
    row = np.pad(np.ones(grid.nx), m)
    phi = (np.convolve(row, w1.sum(axis=0), mode="valid") / w1.sum())[None, :]
    be = _passage.effective_spot_length(kernel, b, 0.0, rule)
    T_xx, T_zz = v_s * be["xx"], v_s * be["zz"]
    hd = h**2
    div_x = np.gradient(b * v_s * rho_s, h, axis=1, edge_order=2)
    D_xx = T_xx * hd * fftconvolve(rho_s / phi**2, w2, mode="same")
    D_zz = (T_zz / T_xx) * D_xx
    u_x = hd * fftconvolve(2 * rule * div_x / phi, w1, mode="same")
    u_z = hd * fftconvolve(-v_s * rho_s / phi, w1, mode="same")
    u_x += np.gradient((1.0 - b * v_s / T_xx) * D_xx, h, axis=1, edge_order=2)
    u_z += np.gradient(D_zz, h, axis=0, edge_order=2)
    return {"rho_s": rho_s, "v_kin": kernel.V1 * phi_flux, "u_x": u_x, "u_z": u_z,
            "D_xx": D_xx, "D_xz": np.zeros(grid.shape), "D_zz": D_zz}


def spotpde_run_case(n: int, **kernel_keys):
    """The same case as a spotpde case (for ``spotpde.run``); ``kernel_keys`` are added
    to its ``[kernel]`` table (``walls``, ``diffusivity``)."""
    from spotpde.app.cases import load_case
    h = 1.0 / 8.0
    half = n * h / 2
    return load_case({"domain": {"x": [-half, half], "z": [0.0, n * h], "spacing": h},
                      "orifice": {"width": 4.0, "rate": 1.0},
                      "spots": {"drift": 1.0, "b": 1.3},
                      "kernel": {"shape": "uniform", "size": 2.5, "height": 0.0024,
                                 "rule": 0.5, **kernel_keys}})


def scipy_particle_fields(grid, rho_s, spots, kernel, rule):
    """u_p, D_p by fftconvolve per field; div by np.gradient (second order at the edges)."""
    h, b, v_s = grid.spacing, float(spots.b), float(spots.drift)
    w1, w2 = kernel.sample(h, 1), kernel.sample(h, 2)
    D_perp, D_par = b * v_s, float(spots.b_par) * v_s
    div_x = np.gradient(D_perp * rho_s, h, axis=1, edge_order=2)
    div_z = np.gradient(D_par * rho_s, h, axis=0, edge_order=2)
    hd = h**2
    return {
        "u_x": hd * fftconvolve(2 * rule * div_x, w1, mode="same"),
        "u_z": hd * fftconvolve(2 * rule * div_z - v_s * rho_s, w1, mode="same"),
        "D_xx": hd * fftconvolve(D_perp * rho_s, w2, mode="same"),
        "D_xz": np.zeros(grid.shape),
        "D_zz": hd * fftconvolve(D_par * rho_s, w2, mode="same"),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=1024, help="cells per side (default 1024)")
    parser.add_argument("--repeat", type=int, default=3, help="timed repetitions (best kept)")
    args = parser.parse_args()
    parts = case(args.n)
    grid = parts[0]
    t_ref, ref = best_time(lambda: scipy_fields(*parts), args.repeat)
    t_new, new = best_time(lambda: spotpde_fields(*parts), args.repeat)
    print(f"grid {grid.nz} x {grid.nx}, spacing {grid.spacing} d, disk R = 2.5 d "
          f"(stencil {parts[3].sample(grid.spacing).shape}), rule {parts[4]}")
    print(f"scipy reference : {t_ref:8.3f} s")
    print(f"spotpde         : {t_new:8.3f} s")
    print(f"ratio spotpde / scipy = {t_new / t_ref:.3f}  (target <= 0.5)")
    # issue 16: spotpde.run (the whole pipeline, Dataset included) against a lean SciPy
    # reference of the same work, timed interleaved in the same run: the paper's fields
    # (truncated walls, mean field) and the defaults (renormalised walls, passage)
    import spotpde
    plain_case = spotpde_run_case(args.n, walls="truncate", diffusivity="mean-field")
    default_case = spotpde_run_case(args.n)
    t_lean, t_plain, t_lean_d, t_default = best_times(
        [lambda: lean_fields(*parts), lambda: spotpde.run(plain_case),
         lambda: lean_default_fields(*parts), lambda: spotpde.run(default_case)], args.repeat)
    print("spotpde.run against a lean SciPy reference of the same work (issue 16 target <= 0.3):")
    print(f"  truncated walls, mean field : lean {t_lean:.3f} s, spotpde.run {t_plain:.3f} s, "
          f"ratio {t_plain / t_lean:.3f}")
    print(f"  defaults (renormalised, passage): lean {t_lean_d:.3f} s, spotpde.run "
          f"{t_default:.3f} s, ratio {t_default / t_lean_d:.3f}")
    got = spotpde.run(default_case)
    lean_d = lean_default_fields(*parts)
    print("  defaults, agreement max |run - lean| / max |lean| (z >= 4 d):",
          ", ".join(f"{k} {np.abs(got[k].values - lean_d[k])[grid.z >= 4.0].max() / np.abs(lean_d[k]).max():.1e}"
                    for k in ("u_x", "u_z", "D_xx", "D_zz")))
    above = grid.z >= 4.0
    print("agreement: max |spotpde - scipy| / max |scipy|   (z >= 4 d)   (all cells)")
    for name in ("rho_s", "v_kin", "u_x", "u_z", "D_xx", "D_xz", "D_zz"):
        r, a = ref[name], new[name]
        scale = np.abs(r).max()
        if scale == 0.0:
            print(f"  {name:6s} both zero: {np.abs(a).max() == 0.0}")
            continue
        d_above = np.abs(a - r)[above].max() / scale
        d_all = np.abs(a - r).max() / scale
        print(f"  {name:6s} {d_above:10.2e} {d_all:10.2e}")
    # the particle-field stage alone: the reference's convolutions of spotpde's rho_s
    alone = scipy_particle_fields(grid, new["rho_s"], parts[2], parts[3], parts[4])
    print("particle fields from the same rho_s: max |spotpde - scipy| / max |scipy|")
    for name in ("u_x", "u_z", "D_xx"):
        r = alone[name]
        print(f"  {name:6s} {np.abs(new[name] - r).max() / np.abs(r).max():10.2e}")
    # the passage diffusivity against the mean field (the reference above is eq. Dp):
    # the particle-field stage alone, same rho_s, calls interleaved (same machine load);
    # the passage quadrature itself (once per kernel, b, b_par, rule; cached) timed apart
    from spotpde.fields import _passage

    rho_s, (g, o, sp, k, lam) = new["rho_s"], parts
    _passage._CACHE.clear()
    t_quad, _ = best_time(lambda: (_passage._CACHE.clear(),
                                   _passage.effective_spot_length(k, float(sp.b), 0.0, lam)), 1)
    t_mf, t_pa = best_times([
        lambda: coefficients.particle_fields(g, rho_s, sp, k, rule=lam, diffusivity="mean-field"),
        lambda: coefficients.particle_fields(g, rho_s, sp, k, rule=lam, diffusivity="passage"),
    ], args.repeat)
    print(f"particle_fields {grid.nz} x {grid.nx}: mean-field {t_mf:.3f} s, passage {t_pa:.3f} s, "
          f"ratio passage / mean-field = {t_pa / t_mf:.3f}  (target <= 1.5); "
          f"passage quadrature (once, cached) {t_quad:.3f} s")
    # a b field (b = 1.3 + 0.3 cos(x / 10)): the passage tensor varies from cell to cell
    X = np.broadcast_to(g.x[None, :], g.shape)
    spb = Spots(drift=1.0, b=1.3 + 0.3 * np.cos(X / 10.0), b_par=0.0)
    t_mf, t_pa = best_times([
        lambda: coefficients.particle_fields(g, rho_s, spb, k, rule=lam, diffusivity="mean-field"),
        lambda: coefficients.particle_fields(g, rho_s, spb, k, rule=lam, diffusivity="passage"),
    ], args.repeat)
    print(f"  with a b field: mean-field {t_mf:.3f} s, passage {t_pa:.3f} s, "
          f"ratio {t_pa / t_mf:.3f}")
    # which one is right: both against the free-space slot solution, 4 d <= z <= 32 d
    # (the walls, >= 7 widths away there, change it by less than 1e-10)
    Z, X = grid.mesh()
    b, W, Q0 = float(parts[2].b), parts[1].width, parts[1].rate_at(0.0)
    root = np.sqrt(4 * b * Z)
    exact = Q0 / (2 * W) * (erf((X + W / 2) / root) - erf((X - W / 2) / root)) / float(parts[2].drift)
    band = (grid.z >= 4.0) & (grid.z <= 32.0)
    scale = np.abs(exact[band]).max()
    print("rho_s against the closed-form slot solution (4 d <= z <= 32 d), max error / max:")
    print(f"  scipy (Crank-Nicolson) {np.abs(ref['rho_s'] - exact)[band].max() / scale:10.2e}")
    print(f"  spotpde                {np.abs(new['rho_s'] - exact)[band].max() / scale:10.2e}")


if __name__ == "__main__":
    main()
