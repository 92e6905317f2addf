"""DEM silo drainage with LAMMPS: a 2D silo of disks or a thin 3D slab of spheres.

    python validation/dem/silo.py validation/dem/silo2d.toml -o RUNDIR [--set KEY=VALUE ...]

Frictional grains (Hookean normal and tangential springs with tangential history,
LAMMPS ``pair_style gran/hooke/history``, Coulomb friction, velocity damping set by a
restitution coefficient) fill a flat-bottomed silo with rough walls and drain through a
slot at ``x = 0`` on the floor. Grains that leave are reinserted (with new ids, so
that each id is one passage) in a band above the free surface, so the flow is steady.
Phases: ``settle`` (orifice closed by a flat plate), ``warm`` (flow starts and becomes
steady), ``measure`` (grains dumped every ``time.output``). Units: d = 1 (mean grain
diameter), g = 1, time sqrt(d/g), mass of a grain of diameter d = 1.

Writes into RUNDIR: ``tracks.dump.gz`` (LAMMPS ``dump custom``, columns ``id type x y z
radius`` of the mobile grains; time = timestep * time.step from the start of the
measuring window), ``exits.txt`` (grains through the orifice per reinsertion interval),
``params.toml`` (the resolved parameters), ``provenance.json`` and ``log.lammps``.

Exit status: 0 done; 2 bad parameters or command line; 3 the flow stopped (clog);
4 LAMMPS cannot be loaded.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import shlex
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import tomli_w

sys.path.insert(0, os.fspath(Path(__file__).resolve().parent))
import _git  # noqa: E402
import _lmp  # noqa: E402
import silo_geometry as geo  # noqa: E402
import silo_params as prm  # noqa: E402

EXIT_BAD_INPUT, EXIT_CLOG, EXIT_NO_LAMMPS = 2, 3, 4
DUMP_FORMAT = '"%d %d %.4f %.4f %.4f %.4f"'


class Clog(RuntimeError):
    """The flow stopped: no grain left through the orifice for ``time.clog``."""


def _write_data(path: Path, p: dict, walls, grains, diam, lo, hi) -> None:
    """A LAMMPS data file (atom_style sphere: id type diameter density x y z)."""
    lines = ["silo grains (spotpde validation/dem)", "",
             f"{len(walls) + len(grains)} atoms", "2 atom types", "",
             f"{lo[0]} {hi[0]} xlo xhi", f"{lo[1]} {hi[1]} ylo yhi",
             f"{lo[2]} {hi[2]} zlo zhi", "", "Atoms # sphere", ""]
    ident = 1
    for c, d in zip(grains, diam):
        lines.append(f"{ident} 1 {d:.6f} 1.0 {c[0]:.6f} {c[1]:.6f} {c[2]:.6f}")
        ident += 1
    for c in walls:
        lines.append(f"{ident} 2 1.0 1.0 {c[0]:.6f} {c[1]:.6f} {c[2]:.6f}")
        ident += 1
    path.write_text("\n".join(lines) + "\n")


class Silo:
    """One LAMMPS run of the silo described by the parameters ``p``, writing into ``out``."""

    def __init__(self, p: dict, out: Path, params_file: str):
        self.p, self.out = p, out
        self.dims, self.iv = p["silo"]["dims"], geo.vertical(p)
        self.rng = np.random.default_rng(p["run"]["seed"])
        self.n_grains = prm.grain_count(p)
        self.exits = {"settle": 0, "warm": 0, "measure": 0}
        self.exit_log: list[tuple[float, int]] = []
        self.pending = 0
        self.timing: dict[str, dict] = {}
        # at the start: the scripts this run used, and its parameter file
        self.git = _git.state("silo.py", "_lmp.py", "silo_geometry.py", "silo_params.py",
                              os.path.abspath(params_file))
        self.git["params_file_sha256"] = hashlib.sha256(Path(params_file).read_bytes()).hexdigest()
        self.lmp = _lmp.open_lammps(out / "log.lammps")

    def cmd(self, text: str) -> None:
        self.lmp.command(text)

    # ---------------------------------------------------------------- setup
    def setup(self) -> None:
        p, s, c = self.p, self.p["silo"], self.p["contacts"]
        pos, diam = geo.initial_grains(p, self.n_grains, self.rng)
        top = max(float(pos[:, self.iv].max()) + 1.0, geo.insert_band(p)[1] + 1.0)
        self.walls = geo.wall_grains(p, top)
        lo, hi = geo.box(p, top)
        data = self.out / "initial.data"
        _write_data(data, p, self.walls, pos, diam, lo, hi)
        self.next_id = len(pos) + len(self.walls) + 1
        self.first_wall_id = len(pos) + 1
        kn = c["stiffness"]
        gn = prm.gamma_n(p)
        self.contact = (f"{kn:.10g} {c['tangential_stiffness'] * kn:.10g} {gn:.10g} "
                        f"{c['tangential_damping'] * gn:.10g}")
        for line in [
            "units lj", "atom_style sphere", f"dimension {self.dims}",
            f"boundary f f {'p' if self.dims == 2 else 'f'}", "newton off",
            "comm_modify vel yes", "atom_modify map array",
            f"read_data {data}",
            f"pair_style gran/hooke/history {self.contact} {c['friction']:.10g} 1",
            "pair_coeff * *", "neighbor 0.3 bin", "neigh_modify delay 0 every 1 check yes",
            "neigh_modify exclude type 2 2",
            "group mobile type 1", "group walls type 2",
            "fix freeze walls freeze",
            f"fix move mobile nve/sphere{' disc' if self.dims == 2 else ''}",
            "fix gravity mobile gravity 1.0 vector 0 {} {}".format(
                *((-1, 0) if self.dims == 2 else (0, -1))),
            f"timestep {p['time']['step']:.10g}",
            "thermo_style custom step atoms ke", f"thermo {prm.steps(p, 'output') * 10}",
            "thermo_modify lost error",
        ]:
            self.cmd(line)
        if self.dims == 2:
            self.cmd("fix flat all enforce2d")
        else:
            y = s["depth"] / 2
            self.cmd(f"fix plates mobile wall/gran hooke/history {self.contact} "
                     f"{c['wall_friction']:.10g} 1 yplane {-y:.10g} {y:.10g}")
        self._set_masses(range(1, self.next_id))
        axis = "yplane" if self.dims == 2 else "zplane"
        self.cmd(f"fix plug mobile wall/gran hooke/history {self.contact} "
                 f"{c['friction']:.10g} 1 {axis} 0.0 NULL")
        lo_v = [-1e9] * 3
        hi_v = [1e9] * 3
        hi_v[self.iv] = geo.EXIT_LEVEL
        lims = " ".join(f"{a:.10g} {b:.10g}" for a, b in zip(lo_v, hi_v))
        self.cmd(f"region below block {lims} units box")

    def _set_masses(self, ids) -> None:
        """Mass D^dims (grains of diameter 1 have mass 1) for the atoms with ``ids``."""
        tag = self.lmp.numpy.extract_atom("id")
        radius = self.lmp.numpy.extract_atom("radius")
        rmass = self.lmp.numpy.extract_atom("rmass")
        wanted = np.isin(tag, np.fromiter(ids, dtype=np.int64))
        rmass[wanted] = geo.grain_mass(2 * radius[wanted], self.dims)

    # ---------------------------------------------------------------- phases
    def _run(self, steps: int, fresh: bool) -> None:
        self.cmd(f"run {steps} pre {'yes' if fresh else 'no'} post no")

    def _reinsert(self) -> tuple[int, bool]:
        """Delete grains below the exit level, insert as many new ones at the top."""
        before = self.lmp.get_natoms()
        self.cmd("delete_atoms region below compress no")
        left = before - self.lmp.get_natoms()
        self.pending += left
        if self.pending == 0:
            return 0, False
        x = self.lmp.numpy.extract_atom("x")
        radius = self.lmp.numpy.extract_atom("radius")
        nlocal = self.lmp.extract_global("nlocal")
        x, radius = x[:nlocal], radius[:nlocal]
        near = x[:, self.iv] > geo.insert_band(self.p)[0] - 2.0
        poly = self.p["grains"]["polydispersity"]
        diam = self.rng.uniform(1.0 - poly, 1.0 + poly, self.pending)
        centres = geo.place(self.p, self.rng, diam, x[near], radius[near])
        n = len(centres)
        if n == 0:
            return left, left > 0
        ids = list(range(self.next_id, self.next_id + n))
        self.next_id += n
        self.lmp.create_atoms(n, ids, [1] * n, centres.ravel().tolist(), v=[0.0] * (3 * n))
        tag = self.lmp.numpy.extract_atom("id")
        radius = self.lmp.numpy.extract_atom("radius")
        new = {i: k for k, i in enumerate(ids)}
        for j, t in enumerate(tag[: self.lmp.extract_global("nlocal")]):
            if int(t) in new:
                radius[j] = diam[new[int(t)]] / 2
        self._set_masses(ids)
        self.cmd(f"group mobile id {ids[0]}:{ids[-1]}")
        self.pending -= n
        return left, True

    def flow(self, phase: str, t0: float) -> None:
        """Run ``phase`` (warm or measure) in reinsertion intervals; count exits; detect clogs."""
        p = self.p
        chunk, total = prm.steps(p, "reinsert"), prm.steps(p, phase)
        dt, done, fresh = p["time"]["step"], 0, True
        last_exit = t0
        while done < total:
            n = min(chunk, total - done)
            self._run(n, fresh)
            done += n
            t = t0 + done * dt
            left, fresh = self._reinsert()
            self.exits[phase] += left
            self.exit_log.append((t, left))
            if left:
                last_exit = t
            elif t - last_exit >= p["time"]["clog"]:
                raise Clog(f"clogged: no grain left through the orifice for "
                           f"{t - last_exit:.4g} time units ({phase} phase, t = {t:.4g} "
                           f"from the start of the measuring window)")

    def go(self) -> None:
        p = self.p
        self.setup()
        self._timed("settle", lambda: self._run(prm.steps(p, "settle"), True))
        self.surface = self._surface_height()
        self.cmd("unfix plug")
        self._timed("warm", lambda: self.flow("warm", -p["time"]["warm"]))
        self.cmd("reset_timestep 0")
        style = "custom/gz" if p["run"]["compress"] else "custom"
        name = "tracks.dump.gz" if p["run"]["compress"] else "tracks.dump"
        self.cmd(f"dump tracks mobile {style} {prm.steps(p, 'output')} {self.out / name} "
                 "id type x y z radius")
        self.cmd(f"dump_modify tracks sort id format line {DUMP_FORMAT}")
        self._timed("measure", lambda: self.flow("measure", 0.0))
        self.cmd("undump tracks")

    def _timed(self, phase, action) -> None:
        wall, cpu = time.perf_counter(), time.process_time()
        try:
            action()
        finally:
            self.timing[phase] = {"steps": prm.steps(self.p, phase),
                                  "wall_s": round(time.perf_counter() - wall, 2),
                                  "cpu_s": round(time.process_time() - cpu, 2)}

    def _surface_height(self) -> float:
        """Mean over 2 d wide columns of the highest grain top after settling (in d)."""
        x = self.lmp.numpy.extract_atom("x")[: self.lmp.extract_global("nlocal")]
        tag = self.lmp.numpy.extract_atom("id")[: len(x)]
        r = self.lmp.numpy.extract_atom("radius")[: len(x)]
        mob = tag < self.first_wall_id
        cols = np.floor(x[mob, 0] / 2.0).astype(int)
        tops = x[mob, self.iv] + r[mob]
        return float(np.mean([tops[cols == k].max() for k in np.unique(cols)]))

    def write_exits(self) -> None:
        lines = ["# t n  (t: end of a reinsertion interval, in sqrt(d/g) from the start of "
                 "the measuring window; n: grains that left through the orifice in it)"]
        lines += [f"{t:.6g} {n}" for t, n in self.exit_log]
        _atomic_write(self.out / "exits.txt", "\n".join(lines) + "\n")


def _atomic_write(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)


def provenance(run: Silo, status: str, wall: float, cpu: float, argv: list[str]) -> dict:
    p = run.p
    return {
        "status": status,
        "command": shlex.join(["python", *argv]),
        "git": run.git,
        "versions": {**_lmp.versions(run.lmp), "python": platform.python_version(),
                     "numpy": np.__version__},
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "load_average_at_end": list(os.getloadavg())},
        "params": p,
        "derived": {
            "grains": run.n_grains, "wall_grains": len(run.walls),
            "gamma_n": prm.gamma_n(p), "gamma_t": prm.gamma_n(p) * p["contacts"]["tangential_damping"],
            "collision_time": prm.collision_time(p),
            "steps_per_collision": prm.collision_time(p) / p["time"]["step"],
            "surface_height_after_settle": round(run.surface, 3),
            "insert_band": list(geo.insert_band(p)), "exit_level": geo.EXIT_LEVEL,
            "last_id": run.next_id - 1, "first_wall_id": run.first_wall_id,
        },
        "grains_through_orifice": run.exits,
        "flow_rate_measure": run.exits["measure"] / p["time"]["measure"] if p["time"]["measure"] else None,
        "timing": {**run.timing, "total_wall_s": round(wall, 2), "total_cpu_s": round(cpu, 2)},
        "files": sorted(f.name for f in run.out.iterdir() if not f.name.endswith(".tmp")),
        "conventions": {
            "units": "length d (mean grain diameter), time sqrt(d/g), mass of a grain of diameter d",
            "axes": ("2D: x horizontal, y vertical up, z = 0" if run.dims == 2 else
                     "3D slab: x across the width, y across the depth, z vertical up"),
            "orifice": "centred at x = 0 on the floor (vertical coordinate 0), |x| < orifice/2",
            "dump_time": "t = timestep * params.time.step, t = 0 at the start of the measuring window",
            "ids": "each id is one passage: grains that leave are reinserted with a new id",
            "dump_types": "1 = mobile grains (walls, type 2, are not dumped)",
        },
    }


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(prog="silo.py", description=__doc__.split("\n\n")[0])
    ap.add_argument("params", help="parameter TOML file")
    ap.add_argument("-o", "--out", required=True, help="run directory (new or empty)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a parameter, e.g. --set contacts.stiffness=4e4")
    args = ap.parse_args(argv)
    out = Path(args.out)
    try:
        p = prm.load(args.params, args.set)
    except OSError as exc:
        print(f"silo.py: params: cannot read {args.params}: {exc.strerror}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except tomllib.TOMLDecodeError as exc:
        print(f"silo.py: params: {args.params} is not valid TOML: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except prm.ParamError as exc:
        print(f"silo.py: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if out.exists() and any(out.iterdir()):
        print(f"silo.py: --out: {out} exists and is not empty; give a new directory",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    out.mkdir(parents=True, exist_ok=True)
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        run = Silo(p, out, args.params)
    except _lmp.LammpsMissing as exc:
        print(f"silo.py: {exc}", file=sys.stderr)
        return EXIT_NO_LAMMPS
    status, code = "done", 0
    try:
        run.go()
    except Clog as exc:
        status, code = str(exc), EXIT_CLOG
        print(f"silo.py: {exc}", file=sys.stderr)
    run.write_exits()
    _atomic_write(out / "params.toml", tomli_w.dumps(p))
    prov = provenance(run, status, time.perf_counter() - wall, time.process_time() - cpu,
                      [os.path.relpath(sys.argv[0]) if sys.argv[0] else "silo.py", *argv])
    run.lmp.close()
    (out / "initial.data").unlink(missing_ok=True)
    prov["files"] = sorted(f.name for f in out.iterdir()) + ["provenance.json"]
    _atomic_write(out / "provenance.json", json.dumps(prov, indent=1) + "\n")
    if code == 0:
        print(f"silo.py: {run.n_grains} grains, {run.exits['measure']} through the orifice in "
              f"the measuring window, {prov['timing']['total_cpu_s']:.0f} CPU s -> {out}")
    return code


if __name__ == "__main__":
    sys.exit(main())
