"""The data flow of the package, read from its imports: ``docs/figures/architecture.png``.

Each box is a stage (a subpackage, or the shared modules at the bottom), in the order
data flows through them: a case becomes a grid and parameters, then the spot density,
the coefficient fields, the tracer or pair, a Dataset, files and figures. Each arrow is
an import from one stage of another, found by parsing every module (imports inside
functions count too). Arrows run from the importing stage down to the stage it uses;
an arrow against the flow would be drawn red, and the script prints it.

    python docs/figures/make_architecture.py

The picture is computed from the code, so it is redrawn, not edited, when the code
changes. The order of the stages is the one tests/geometry/test_architecture.py checks
(its ``LAYERS``, read from there so the picture and the check cannot disagree).
"""

from __future__ import annotations

import ast
import importlib.util
from collections import defaultdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "spotpde"

#: (row, column, stage, what it holds); rows from the bottom (shared) to the top (app).
LAYOUT = [
    (0, 1, "core", "grid, parameters, errors, figures\ngeometry: the silo's shape"),
    (1, 0, "fields", "kernels, FFT convolution,\nstage 2: u_p, D_p"),
    (2, 0, "density", "stage 1: spot density rho_s,\norifice, Kinematic Model"),
    (3, 0, "tracer", "stage 3: propagator P,\nP_height"),
    (3, 2, "montecarlo", "the discrete spot model,\npacking relaxation"),
    (4, 2, "pair", "relative diffusion,\ncage breaking"),
    (4, 0, "analysis", "Kinematic comparison,\nlayers, packing"),
    (5, 1, "app", "case -> Dataset -> netCDF,\nfigures, sweeps"),
    (6, 3, "tracks", "data in: tracked grains"),
    (7, 3, "observables", "the same observables from\ndata and from the model"),
    (8, 2, "calibration", "spotpde.fit"),
    (9, 1, "cli", "the spotpde command"),
]


def _layers() -> list[set[str]]:
    """The architecture test's ``LAYERS`` (units in data-flow order)."""
    path = ROOT / "tests" / "geometry" / "test_architecture.py"
    spec = importlib.util.spec_from_file_location("_architecture", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.LAYERS


#: top-level modules that belong to the shared core
CORE = {"grid", "parameters", "errors", "geometry", "_cache", "_roundoff", "_version",
        "_figures", "kernels", "kinematic"}


#: the command line's modules: the front end on top of everything
FRONT = {("__main__.py",), ("__main__",)}


def stage_of(parts: tuple[str, ...]) -> str | None:
    """The stage of module ``spotpde.<parts>``."""
    if not parts:
        return None
    if tuple(parts) in FRONT:
        return "cli"
    head = parts[0].removesuffix(".py")
    return "core" if head in CORE else head


def imports() -> dict[tuple[str, str], int]:
    """``{(importer stage, imported stage): number of import statements}``."""
    edges: dict[tuple[str, str], int] = defaultdict(int)
    for path in PACKAGE.rglob("*.py"):
        rel = path.relative_to(PACKAGE).parts
        src = stage_of(rel)
        if src is None or rel == ("__init__.py",) or rel in (("kernels.py",), ("kinematic.py",)):
            continue
        package = rel[:-1]
        for node in ast.walk(ast.parse(path.read_text())):
            targets = []
            if isinstance(node, ast.ImportFrom) and node.level:
                base = package[:len(package) - (node.level - 1)] if node.level > 1 else package
                mod = tuple(node.module.split(".")) if node.module else ()
                targets = [base + mod] if node.module else [base + (a.name,) for a in node.names]
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("spotpde."):
                targets = [tuple(node.module.split(".")[1:])]
            elif isinstance(node, ast.Import):
                targets = [tuple(a.name.split(".")[1:]) for a in node.names
                           if a.name.startswith("spotpde.")]
            for t in targets:
                dst = stage_of(t)
                if dst and dst != src:
                    edges[(src, dst)] += 1
    return dict(edges)


def main() -> None:
    where = {stage: (col, row) for row, col, stage, _ in LAYOUT}
    layers = _layers()
    unit_rank = {u: i for i, layer in enumerate(layers) for u in layer}
    rank = {stage: unit_rank["grid" if stage == "core" else stage] for stage in where}
    edges = imports()
    fig, ax = plt.subplots(figsize=(11, 12))
    for row, col, stage, text in LAYOUT:
        ax.add_patch(FancyBboxPatch((col * 3.0 - 1.25, row * 1.5 - 0.45), 2.5, 0.9,
                                    boxstyle="round,pad=0.05", fc="#eef3fb", ec="#34568b"))
        ax.text(col * 3.0, row * 1.5 + 0.2, stage, ha="center", va="center",
                fontsize=11, weight="bold")
        ax.text(col * 3.0, row * 1.5 - 0.15, text, ha="center", va="center", fontsize=8)
    against = []
    for (src, dst), n in sorted(edges.items()):
        if src not in where or dst not in where:
            continue
        up = rank[dst] > rank[src]
        if up:
            against.append((src, dst, n))
        (x0, y0), (x1, y1) = where[src], where[dst]
        below = y1 < y0 or (y1 == y0 and x1 != x0)
        start = (x0 * 3.0, y0 * 1.5 + (-0.45 if below else 0.45))
        end = (x1 * 3.0, y1 * 1.5 + (0.45 if below else -0.45))
        if y1 == y0:                     # side by side: from side to side
            start = (x0 * 3.0 + 1.25 * (1 if x1 > x0 else -1), y0 * 1.5)
            end = (x1 * 3.0 - 1.25 * (1 if x1 > x0 else -1), y1 * 1.5)
        ax.add_patch(FancyArrowPatch(start, end,
                                     arrowstyle="-|>", mutation_scale=12,
                                     connectionstyle="arc3,rad=0.08",
                                     color="red" if up else "#555555",
                                     lw=0.6 + 0.25 * min(n, 8), alpha=0.8))
    ax.set_xlim(-1.6, 10.6)
    ax.set_ylim(-0.8, 14.3)
    ax.set_axis_off()
    ax.set_title("spotpde: stages and the imports between them (arrow: imports)")
    out = ROOT / "docs" / "figures" / "architecture.png"
    fig.savefig(out, dpi=110, bbox_inches="tight")
    print(f"{len(edges)} arrows between stages; against the flow: {against or 'none'}")
    print(f"wrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
