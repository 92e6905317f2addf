"""Time to solution of long time-dependent tracer runs: explicit SSP-RK3 against implicit
TR-BDF2 (issue 16, item 2), measured in the same run.

Sections (each prints its times, the ratio and the accuracy):

Schemes: ``explicit`` (today's default: WENO5, SSP-RK3, Strang-split implicit diffusion,
``dt`` at the positivity limit of the fastest cell), ``imex`` (``stepping="imex"``,
``--split`` 5: the fast cells next to the orifice implicit, ``dt`` 5 times larger) and
``implicit`` (``stepping="implicit"``, adaptive TR-BDF2 on the hybrid operator, ``--tol``).

* ``void`` (default): the void-model propagator of ``benchmarks/steady.py`` (280 x 320
  cells, release 60 d up a point orifice) to ``t = 4e5`` with 41 frames.
  - implicit: ``tracer.solve(..., stepping="implicit")`` for the whole run, timed;
  - explicit (WENO5, SSP-RK3, implicit diffusion; today's default): timed on
    ``[0, --t-cut]`` and **extrapolated** linearly to 4e5 (steady fields: a constant
    number of steps per unit time), labelled as such; imex likewise on
    ``[0, 20 t_cut]``;
  - accuracy: ``P_height`` at 4e5 against the steady solve (``solve_steady``, the
    drained limit of the same operator), the exit probabilities, and with
    ``--time-error`` the time error (the same run with ``tol / 100``: L1 of
    ``mass(t)``, ``outflow(t)``, ``P_height``).
* ``--window T``: the same case on ``[0, T]`` with 5 frames, explicit and implicit both run
  in full (T = 2000 takes 10-30 min explicit here): L1 distance of the frames, of
  ``mass(t)`` and of ``P_height``.
* ``--convergence``: a smaller void case (release 20 d up, 30 x 30 d) at h = 0.5, 0.25,
  0.125, both schemes, against explicit WENO5 at h = 0.125 (the finer reference), to
  ``t = --conv-t``: error of the frames, of ``outflow(t)`` and of ``P_height``.
* ``--orifice-row``: the same smaller void case at h = 0.25: the time error of ``P_height``
  (against explicit at cfl 0.2 on the same grid) in the orifice row and above, for
  explicit and multirate at several steps: the error grows like the step (the splitting
  of the orifice row's stiff diffusion from its outflow), whence ``MAX_AUTO_SPLIT``.
* ``--cylinder``: the void model in a cylinder (axisymmetric, point orifice on the axis)
  at h = 0.25 to ``--cyl-t``, every scheme against explicit WENO5 at h = 0.125, timed
  (best of ``--repeat``); and ``auto_split`` of a small ``cases/cylinder_hopper.toml``.
* ``--flagship``: ``cases/quasi2d_layers.toml`` as it is (t_end = 600, 13 frames), both
  schemes, timed, and their distance (L1 of frames and ``P_height``); ``--flagship-ref``
  adds explicit WENO5 at h = 0.125 as the finer reference.

Run: ``python benchmarks/long_runs.py [--t-cut 20] [--window 2000] [--convergence]
[--orifice-row] [--flagship [--flagship-ref]] [--cylinder [--cyl-t 150]] [--no-void]``.
"""

from __future__ import annotations

import argparse
import pathlib
import time
import tomllib

import numpy as np

from steady import void_case

from spotpde import tracer
from spotpde.tracer import _advection, _implicit, _linsolve
from spotpde._roundoff import clip_roundoff
from spotpde.app import pipeline
from spotpde.app.cases import load_case
from spotpde.density import spot_density


def setup(case):
    grid = case.grid
    rho = clip_roundoff(spot_density.solve(grid, case.orifice, case.spots))
    return grid, pipeline.case_fields(case, rho), pipeline.initial_density(grid, case.tracer.start)


def timed(fn):
    t0 = time.perf_counter()
    r = fn()
    return time.perf_counter() - t0, r


def l1(a, b, hv):
    return float(np.abs(np.asarray(a) - np.asarray(b)).sum()) * hv


def describe(name, t, r):
    o = r.options
    extra = (f", {o['factorisations']} LU ({o['seconds_factorisation']:.1f} s), "
             f"{o['rejected_steps']} rejected, {o['fallback_steps']} backward-Euler, dt "
             f"{o['dt_min']:.3g}..{o['dt_max']:.3g}" if o.get("stepping") == "implicit"
             else f", {o['limiter']}, {o['time_scheme']}")
    print(f"  {name:9s}: {t:9.2f} s, {r.steps} steps{extra}; mass error {r.mass_error:.1e}, "
          f"min P {min(float(np.min(p)) for p in r.P) if r.P is not None else float('nan'):.1e}")


def compare(name, a, b, grid):
    """L1 distances of ``a`` from ``b`` (TracerResults on the same grid)."""
    hv, hh = grid.cell_volume, grid.spacing ** (grid.dims - 1) * grid.spacing
    frames = max(l1(pa, pb, hv) for pa, pb in zip(a.P, b.P)) if a.P is not None and \
        b.P is not None else float("nan")
    print(f"  {name}: max over frames L1(P) {frames:.2e}; max |mass| {np.abs(a.mass - b.mass).max():.2e}, "
          f"max |outflow| {np.abs(a.outflow - b.outflow).max():.2e}; "
          f"L1(P_height) {l1(a.P_height, b.P_height, hh):.2e} (of "
          f"{float(np.abs(b.P_height).sum()) * hh:.3g})")


def void(args):
    case = void_case(280, 320)
    grid, f, P0 = setup(case)
    hv = grid.cell_volume
    print(f"void model, point orifice, release 60 d up; {grid.shape[1]} x {grid.shape[0]} "
          f"cells, h = {grid.spacing}; t_end = 4e5, 41 frames")
    if not args.no_implicit:
        t_imp, ri = timed(lambda: tracer.solve(grid, f, P0, 4e5, 41, stepping="implicit",
                                               tol=args.tol))
        describe("implicit", t_imp, ri)
    tracer.solve(grid, f, P0, 1.0, 2)                # numba compilation, not timed
    # the explicit scheme as it was (SuperLU for its diffusion half steps) and as it is
    # (the tridiagonal solver), and each IMEX / multirate split, interleaved in every
    # repeat (another job on the machine then hits all alike); best of --repeat
    runs = [("before", None, args.t_cut), ("explicit", None, args.t_cut)]
    runs += [("imex", s, s * args.t_cut) for s in args.splits]
    runs += [("multirate", s, s * args.t_cut) for s in args.multirate_splits]
    for mode, split, _ in runs[2:]:
        tracer.solve(grid, f, P0, 10.0, 2, stepping=mode, split=split)   # warm-up
    best, res = {}, {}
    for _ in range(args.repeat):
        for key in runs:
            mode, split, T = key
            kw = {} if split is None else {"stepping": mode, "split": split}
            _linsolve.TRIDIAGONAL = mode != "before"
            try:
                t, r = timed(lambda: tracer.solve(grid, f, P0, T, 2, **kw))
            finally:
                _linsolve.TRIDIAGONAL = True
            if t < best.get(key, float("inf")):
                best[key], res[key] = t, r
    to_end = {key: best[key] / key[2] * 4e5 for key in runs}
    t_exp_old, t_exp = to_end[runs[0]], to_end[runs[1]]
    for key in runs:
        mode, split, T = key
        r = res[key]
        line = (f"  {mode:9s}: {best[key]:7.2f} s for t = {T:g} ({r.steps} steps, "
                f"{1e3 * best[key] / r.steps:.1f} ms a step")
        if split is None:
            line += (", SuperLU diffusion solves" if mode == "before" else
                     ", tridiagonal diffusion solves")
        else:
            line += (f", split {split:g}, dt {r.options['dt']:.3g}, "
                     f"{r.options['cells_implicit']} fast cells")
        line += (f"); to 4e5 EXTRAPOLATED: {r.steps / T * 4e5:.3g} steps, "
                 f"{to_end[key]:.3g} s = {to_end[key] / 3600:.2f} h")
        if split is not None:
            line += (f"; speed-up {t_exp_old / to_end[key]:.1f}x against the explicit "
                     f"scheme before, {t_exp / to_end[key]:.1f}x against it now")
        print(line)
    print(f"  (best of {args.repeat}, interleaved; extrapolation linear in t: steady "
          f"fields, fixed steps)")
    if args.no_implicit:
        return
    print(f"  time to 4e5, explicit before (extrapolated) / implicit (run in full): "
          f"{t_exp_old / t_imp:.0f}x   (target >= 10x)")
    s = tracer.solve_steady(grid, f, P0, scheme="hybrid")   # the implicit operator
    hh = grid.spacing ** 2
    ob = ri.outflow_by_boundary
    print(f"  P_height(4e5) vs steady solve (drained limit of the same operator): L1 "
          f"{l1(ri.P_height, s.P_height, hh):.2e}; mass left at 4e5 {ri.mass[-1]:.2e}; exits "
          f"implicit floor {ob['floor']:.6f} sides {ob['sides']:.2e}; steady floor "
          f"{s.exit['floor']:.6f} sides {s.exit['sides']:.2e}")
    if not args.time_error:
        return
    t_ref, rr = timed(lambda: tracer.solve(grid, f, P0, 4e5, 41, stepping="implicit",
                                           tol=args.tol / 100))
    describe(f"tol/100", t_ref, rr)
    print(f"  time error of tol = {args.tol:g} (against tol/100): max |mass| "
          f"{np.abs(ri.mass - rr.mass).max():.2e}, max |outflow| "
          f"{np.abs(ri.outflow - rr.outflow).max():.2e}, L1(P_height) "
          f"{l1(ri.P_height, rr.P_height, hh):.2e}, max L1(P) over frames "
          f"{max(l1(a, b, hv) for a, b in zip(ri.P, rr.P)):.2e}")


def window(args):
    case = void_case(280, 320)
    grid, f, P0 = setup(case)
    T = args.window
    print(f"void model, window [0, {T:g}], 5 frames, both run in full")
    t_imp, ri = timed(lambda: tracer.solve(grid, f, P0, T, 5, stepping="implicit", tol=args.tol))
    describe("implicit", t_imp, ri)
    t_mx, rm = timed(lambda: tracer.solve(grid, f, P0, T, 5, stepping="imex", split=args.split))
    describe("imex", t_mx, rm)
    t_exp, re = timed(lambda: tracer.solve(grid, f, P0, T, 5))
    describe("explicit", t_exp, re)
    print(f"  ratio explicit / implicit: {t_exp / t_imp:.1f}x, explicit / imex "
          f"{t_exp / t_mx:.1f}x")
    compare("implicit vs explicit", ri, re, grid)
    compare("imex vs explicit", rm, re, grid)


def small_void(h, T):
    nx = int(round(30 / h))
    return load_case({
        "domain": {"dims": 2, "x": [-15.0, 15.0], "z": [0.0, 30.0], "spacing": h},
        "orifice": {"x": 0.0, "width": 0.0, "rate": 1.2732},
        "spots": {"b": 1.3},
        "kernel": {"shape": "uniform", "size": 0.5, "volume": 0.7854, "rule": 1.0},
        "tracer": {"model": "void", "start": {"x": 0.0, "z": 20.0, "width": 1.0},
                   "t_end": T, "frames": 5}})


def coarsen(P, m):
    """Mean over m x m blocks (fine cell density to the coarse grid)."""
    nz, nx = P.shape[-2:]
    return P.reshape(P.shape[:-2] + (nz // m, m, nx // m, m)).mean(axis=(-3, -1))


def convergence(args):
    T = args.conv_t
    print(f"void model, release 20 d up a point orifice, 30 x 30 d, t in [0, {T:g}] "
          f"(5 frames); reference: explicit WENO5 at h = 0.125")
    runs = {}
    for h in (0.125, 0.25, 0.5):
        grid, f, P0 = setup(small_void(h, T))
        for name, kw in (("explicit", {}), ("imex", {"stepping": "imex", "split": args.split}),
                         ("multirate", {"stepping": "multirate", "split": 10.0}),
                         ("implicit", {"stepping": "implicit", "tol": args.tol})):
            if name == "explicit":
                tracer.solve(grid, f, P0, 1.0, 2)
            t, r = timed(lambda: tracer.solve(grid, f, P0, T, 5, **kw))
            runs[(h, name)] = (grid, t, r)
            describe(f"{name} h={h}", t, r)
    gref, _, ref = runs[(0.125, "explicit")]
    for (h, name), (grid, t, r) in sorted(runs.items()):
        if (h, name) == (0.125, "explicit"):
            continue
        m = int(round(h / 0.125))
        Pref = [coarsen(p, m) for p in ref.P]
        # P_height: mean over m columns of every m-th face row, at the coarse centres
        fz = ref.P_height_faces[::m]
        phr = coarsen(np.repeat(0.5 * (fz[:-1] + fz[1:]), m, axis=0), m) if m > 1 else ref.P_height
        hv, hh = grid.cell_volume, grid.spacing ** 2
        e_p = max(l1(a, b, hv) for a, b in zip(r.P, Pref))
        e_o = np.abs(r.outflow - ref.outflow).max()
        e_m = np.abs(r.mass - ref.mass).max()
        e_h = l1(r.P_height, phr, hh)
        print(f"  h = {h:5.3f} {name}: {t:8.2f} s; error vs reference: max L1(P) {e_p:.2e}, "
              f"max |outflow| {e_o:.2e}, max |mass| {e_m:.2e}, L1(P_height) {e_h:.2e}")


def accuracy(args):
    """Errors of the multirate splits and of the explicit scheme on the small void case
    (h = 0.25, t in [0, --conv-t], the passage through the orifice) against two
    references: explicit WENO5 at h = 0.125 (the converged solution: total error) and
    explicit at h = 0.25 with cfl 0.1 (the same grid, time-converged: time error)."""
    T = args.conv_t
    print(f"accuracy: void model, release 20 d up a point orifice, 30 x 30 d, h = 0.25, t in "
          f"[0, {T:g}] (5 frames)")
    gf, ff, Pf = setup(small_void(0.125, T))
    tracer.solve(gf, ff, Pf, 1.0, 2)
    t_f, rf = timed(lambda: tracer.solve(gf, ff, Pf, T, 5))
    fz = rf.P_height_faces[::2]
    fine = {"P": [coarsen(p, 2) for p in rf.P], "outflow": rf.outflow,
            "P_height": coarsen(np.repeat(0.5 * (fz[:-1] + fz[1:]), 2, axis=0), 2)}
    grid, f, P0 = setup(small_void(0.25, T))
    t_t, rt = timed(lambda: tracer.solve(grid, f, P0, T, 5, cfl=0.1))
    print(f"  references: h = 0.125 explicit {t_f:.0f} s ({rf.steps} steps); h = 0.25 cfl 0.1 "
          f"{t_t:.0f} s ({rt.steps} steps)")
    hv, hh = grid.cell_volume, grid.spacing ** 2

    same_grid = {"P": rt.P, "outflow": rt.outflow, "P_height": rt.P_height}

    def errors(r, ref):
        return (max(l1(a, b, hv) for a, b in zip(r.P, ref["P"])),
                float(np.abs(r.outflow - ref["outflow"]).max()),
                l1(r.P_height, ref["P_height"], hh))

    rows = [("explicit", {})] + [(f"multirate {s:g}", {"stepping": "multirate", "split": s})
                                 for s in args.multirate_splits]
    base = None
    print("  scheme        steps | total error: frames  outflow  P_height (x explicit) | "
          "time error: frames  outflow  P_height")
    for name, kw in rows:
        r = tracer.solve(grid, f, P0, T, 5, **kw)
        tot, tim = errors(r, fine), errors(r, same_grid)
        base = base or tot
        ratio = "  ".join(f"{e:.2e} ({e / b:.2f})" for e, b in zip(tot, base))
        print(f"  {name:13s} {r.steps:5d} | {ratio} | "
              + "  ".join(f"{e:.2e}" for e in tim))


def orifice_row(args):
    """The multirate scheme's orifice-row error (docs/long_runs.md): the time error of
    ``P_height`` against a time-converged run on the same grid (explicit, cfl 0.2), split
    into the orifice row (and its columns over the point orifice) and the rows above, for
    explicit and multirate steps of several sizes; with the error per unit step and the
    two fast rates of the orifice row, the outflow ``|u_z| / h`` and the horizontal
    diffusion ``2 D_xx / h**2``, times the step."""
    T = args.conv_t
    grid, f, P0 = setup(small_void(0.25, T))
    h, hh = grid.spacing, grid.spacing ** 2
    ic = grid.shape[1] // 2
    cols = slice(ic - 3, ic + 3)
    t_r, ref = timed(lambda: tracer.solve(grid, f, P0, T, 5, cfl=0.2))
    out = float(np.abs(np.asarray(f["u_z"])[0, cols]).max()) / h
    dif = 2 * float(np.asarray(f["D_xx"])[0, cols].max()) / hh
    print(f"orifice row: void model, point orifice, h = {h}, t in [0, {T:g}]; reference "
          f"explicit cfl 0.2 ({ref.steps} steps, {t_r:.0f} s); orifice row: outflow "
          f"|u_z|/h <= {out:.2f}, diffusion 2 D_xx/h**2 <= {dif:.1f} per unit time")
    print("  run                      dt    fast | L1 time error of P_height: all   orifice "
          "row (6 columns)  rows above | outflow  | row error / dt | dt*outflow dt*diffusion")
    rows = [("explicit", {}), ("explicit, cfl 0.45", {"cfl": 0.45})] + [
        (f"multirate {s:g}" + (", cfl 0.45" if c else ""),
         {"stepping": "multirate", "split": s, **({"cfl": 0.45} if c else {})})
        for s, c in ((5.0, False), (10.0, False), (10.0, True), (20.0, False), (20.0, True))]
    for name, kw in rows:
        r = tracer.solve(grid, f, P0, T, 5, **kw)
        d = np.abs(r.P_height - ref.P_height) * hh
        dt = r.options.get("dt", T / r.steps)
        fast = r.options.get("cells_implicit", 0)
        print(f"  {name:22s} {dt:6.3f} {fast:5d} | {d.sum():.2e}  {d[0].sum():.2e} "
              f"({d[0, cols].sum():.2e})  {d[1:].sum():.2e} | "
              f"{np.abs(r.outflow - ref.outflow).max():.2e} | {d[0].sum() / dt:.3f} | "
              f"{dt * out:5.2f} {dt * dif:6.1f}")


def flagship(args):
    path = pathlib.Path(__file__).resolve().parent.parent / "cases" / "quasi2d_layers.toml"
    raw = tomllib.loads(path.read_text())
    case = load_case(raw)
    grid, f, P0 = setup(case)
    T, fr = case.tracer.t_end, case.tracer.frames
    print(f"flagship (cases/quasi2d_layers.toml): {grid.shape[1]} x {grid.shape[0]} cells, "
          f"t_end = {T:g}, {fr} frames")
    tracer.solve(grid, f, P0, 1.0, 2)
    t_exp, re = timed(lambda: tracer.solve(grid, f, P0, T, fr))
    describe("explicit", t_exp, re)
    t_imp, ri = timed(lambda: tracer.solve(grid, f, P0, T, fr, stepping="implicit", tol=args.tol))
    describe("implicit", t_imp, ri)
    t_mx, rm = timed(lambda: tracer.solve(grid, f, P0, T, fr, stepping="imex", split=args.split))
    describe("imex", t_mx, rm)
    ra = tracer.solve(grid, f, P0, T, fr, stepping="auto")
    print(f"  auto chooses {ra.options['stepping']}; auto split here would be "
          f"{_implicit.auto_split(_advection.face_velocities(f, grid.walls, np.ones(grid.shape[1:], bool)), grid.spacing):.2f}")
    print(f"  ratio explicit / implicit: {t_exp / t_imp:.2f}x, explicit / imex {t_exp / t_mx:.2f}x")
    compare("implicit vs explicit", ri, re, grid)
    compare("imex vs explicit", rm, re, grid)
    if args.flagship_ref:
        raw["domain"]["spacing"] = 0.125
        gf, ff, P0f = setup(load_case(raw))
        t_ref, rf = timed(lambda: tracer.solve(gf, ff, P0f, T, fr))
        describe("reference h=0.125", t_ref, rf)
        hv, hh = grid.cell_volume, grid.spacing ** 2
        Pref = [coarsen(p, 2) for p in rf.P]
        fz = rf.P_height_faces[::2]
        phr = coarsen(np.repeat(0.5 * (fz[:-1] + fz[1:]), 2, axis=0), 2)
        for name, r in (("explicit", re), ("imex", rm), ("implicit", ri)):
            print(f"  {name} error vs h = 0.125: max L1(P) "
                  f"{max(l1(a, b, hv) for a, b in zip(r.P, Pref)):.2e}, L1(P_height) "
                  f"{l1(r.P_height, phr, hh):.2e}, max |outflow| "
                  f"{np.abs(r.outflow - rf.outflow).max():.2e}")


def void_cylinder(h, T, radius=6.0, top=12.0, rate=9.0):
    """The void model in a cylinder (axisymmetric), a point orifice on the axis: the
    speed grows like 1 / r**2 next to it, so a few cells set the explicit step."""
    return load_case({
        "domain": {"dims": 2, "coordinates": "axisymmetric", "x": [0.0, radius],
                   "z": [0.0, top], "spacing": h, "walls": "reflecting"},
        "orifice": {"x": 0.0, "width": 0.0, "rate": rate},
        "spots": {"b": 1.3},
        "kernel": {"shape": "uniform", "size": 0.5, "volume": 0.5236, "rule": 1.0},
        "tracer": {"model": "void", "start": {"x": 1.0, "z": 8.0, "width": 1.0},
                   "t_end": T, "frames": 5}})


def cylinder(args):
    """Axisymmetric long runs: the void cylinder at h = 0.25 against explicit WENO5 at
    h = 0.125 (frames coarsened by mass, P_height by flux), every scheme timed (best of
    --repeat, interleaved); and the auto choice on a small cylinder_hopper.toml."""
    T = args.cyl_t
    print(f"void model, cylinder r < 6, z < 12, point orifice on the axis, release (1, 8), "
          f"t in [0, {T:g}] (5 frames); reference: explicit WENO5 at h = 0.125")
    fine, ff, fP0 = setup(void_cylinder(0.125, T))
    t, ref = timed(lambda: tracer.solve(fine, ff, fP0, T, 5))
    describe("explicit h=0.125 (reference)", t, ref)
    grid, f, P0 = setup(void_cylinder(0.25, T))
    geo, fgeo = grid.geometry, fine.geometry
    from spotpde.tracer import _geometry, _solve
    op = _geometry.operator(grid, _solve._check_fields(grid, f, "fields"), 6,
                            np.ones(grid.shape[1:], bool), implicit=False)
    print(f"  h = 0.25: {grid.size} cells, auto_split {_implicit.auto_split(op.faces, 0.25):.2f}"
          f" (auto takes multirate beyond {_solve.AUTO_IMEX_STEPS} explicit steps)")
    nz, nx = grid.shape
    mass_ref = (ref.P * fgeo.cell_volumes).reshape(5, nz, 2, nx, 2).sum(axis=(2, 4))
    flux_ref = (ref.P_height_faces[::2] * fgeo.horizontal_measures).reshape(
        nz + 1, nx, 2).sum(axis=2)
    schemes = (("explicit", {}), ("multirate", {"stepping": "multirate"}),
               ("imex", {"stepping": "imex"}), ("implicit", {"stepping": "implicit"}),
               ("auto", {"stepping": "auto"}))
    for _, kw in schemes:                       # compile
        tracer.solve(grid, f, P0, 1.0, 2, **kw)
    best, runs = {}, {}
    for _ in range(args.repeat):
        for name, kw in schemes:
            t, r = timed(lambda: tracer.solve(grid, f, P0, T, 5, **kw))
            best[name] = min(best.get(name, np.inf), t)
            runs[name] = r
    for name, _ in schemes:
        r = runs[name]
        describe(name, best[name], r)
        e_p = max(float(np.abs(p * geo.cell_volumes - m).sum()) for p, m in zip(r.P, mass_ref))
        e_o = float(np.abs(r.outflow - ref.outflow).max())
        e_h = float(np.abs(r.P_height_faces * geo.horizontal_measures - flux_ref).sum())
        o = r.options
        print(f"  {name}: {best[name]:.2f} s ({best['explicit'] / best[name]:.1f}x), "
              f"{r.steps} steps, split {o.get('split', '-')}, box {o.get('box_cells', 0)} "
              f"cells, {o.get('substeps', 0)} sub-steps; error vs reference: "
              f"max L1(P) {e_p:.2e}, max |outflow| {e_o:.2e}, L1(P_height) "
              f"{e_h * grid.spacing:.2e}; mass error {r.mass_error:.1e}, "
              f"min P {r.P.min():.1e}")
    path = pathlib.Path(__file__).resolve().parents[1] / "cases" / "cylinder_hopper.toml"
    raw = tomllib.loads(path.read_text())
    raw.pop("output", None)
    raw["domain"].update(x=[0.0, 8.0], z=[0.0, 24.0])
    grid, f, P0 = setup(load_case(raw))
    op = _geometry.operator(grid, _solve._check_fields(grid, f, "fields"), 6,
                            np.ones(grid.shape[1:], bool), implicit=False)
    print(f"cylinder_hopper.toml, r < 8, z < 24 (spot model, cone, 4 d orifice): auto_split "
          f"{_implicit.auto_split(op.faces, grid.spacing):.2f} (below MIN_SPLIT = "
          f"{_implicit.MIN_SPLIT:g}: \"auto\" stays explicit however long the run)")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t-cut", type=float, default=20.0)
    ap.add_argument("--repeat", type=int, default=1,
                    help="void section: best of this many timed runs of each scheme")
    ap.add_argument("--no-implicit", action="store_true",
                    help="void section: skip the implicit run to 4e5")
    ap.add_argument("--tol", type=float, default=1e-5)
    ap.add_argument("--split", type=float, default=5.0)
    ap.add_argument("--splits", type=float, nargs="*", default=[5.0, 20.0],
                    help="void section: IMEX splits to time")
    ap.add_argument("--multirate-splits", type=float, nargs="*", default=[10.0, 20.0],
                    help="void section: multirate splits to time")
    ap.add_argument("--time-error", action="store_true",
                    help="void section: also the implicit run with tol / 100")
    ap.add_argument("--window", type=float, default=0.0)
    ap.add_argument("--convergence", action="store_true")
    ap.add_argument("--accuracy", action="store_true",
                    help="total and time errors of explicit and --multirate-splits")
    ap.add_argument("--conv-t", type=float, default=400.0)
    ap.add_argument("--orifice-row", action="store_true",
                    help="time error of P_height in the orifice row against the step size")
    ap.add_argument("--flagship", action="store_true")
    ap.add_argument("--flagship-ref", action="store_true")
    ap.add_argument("--no-void", action="store_true", help="skip the default void section")
    ap.add_argument("--cylinder", action="store_true",
                    help="axisymmetric: the void cylinder's schemes against h / 2")
    ap.add_argument("--cyl-t", type=float, default=150.0)
    args = ap.parse_args()
    if not args.no_void:
        void(args)
    if args.window > 0:
        window(args)
    if args.convergence:
        convergence(args)
    if args.accuracy:
        accuracy(args)
    if args.orifice_row:
        orifice_row(args)
    if args.flagship:
        flagship(args)
    if args.cylinder:
        cylinder(args)


if __name__ == "__main__":
    main()
