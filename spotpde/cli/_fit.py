"""``spotpde fit``: the spot model's parameters fitted to tracked grains (private; the
command line's ``fit`` subcommand, see :mod:`spotpde.cli` and docs/calibration.md).

    spotpde fit CASE.toml TRACKS --free KEY[=LO:HI] [--free ...] [--scale S] [--fps F]
                [--origin X,Y] [--y-down] [--observables A,B] [--blocks N]
                [--workers N] [--sample WALKERS,STEPS] -o FIT.nc [--plot [FIG]]

Exit status: 0 fitted (whatever the fit says of the model: the report is the answer);
2 an invalid case, tracks file or option (one line naming it); 1 the model failed or the
result could not be written.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import time
from pathlib import Path

from ..errors import CaseError

__all__ = ["add_parser", "parse_free"]


def parse_free(items) -> dict:
    """``["spots.b=0.5:4", "kernel.size"]`` -> ``{"spots.b": (0.5, 4.0), "kernel.size": None}``.

    Raises:
        spotpde.CaseError: ``--free: ...`` for a malformed item.
    """
    if not items:
        raise CaseError("--free: give at least one case key to fit, e.g. --free spots.b=0.5:4")
    out = {}
    for item in items:
        key, sep, bounds = item.partition("=")
        key = key.strip()
        if not key or "." not in key:
            raise CaseError(f"--free: {item!r}: expected KEY or KEY=LO:HI with a dotted case "
                            "key such as spots.b")
        if not sep:
            out[key] = None
            continue
        lo, colon, hi = bounds.partition(":")
        try:
            lo_f, hi_f = float(lo), float(hi)
        except ValueError:
            raise CaseError(f"--free: {item!r}: bounds must be LO:HI numbers, e.g. "
                            f"{key}=0.5:4") from None
        if not colon or not (math.isfinite(lo_f) and math.isfinite(hi_f) and lo_f < hi_f):
            raise CaseError(f"--free: {item!r}: bounds must be finite LO:HI with LO < HI")
        out[key] = (lo_f, hi_f)
    return out


def _origin(text: str):
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) not in (2, 3) or not all(math.isfinite(v) for v in values):
        raise CaseError(f"--origin: must be X,Y (or X,Y,DEPTH) numbers, got {text!r}")
    return values


def _sample(text: str | None):
    if text is None:
        return None
    try:
        walkers, steps = (int(v) for v in text.split(","))
    except ValueError:
        raise CaseError(f"--sample: must be WALKERS,STEPS integers, got {text!r}") from None
    if walkers < 2 or steps < 1:
        raise CaseError(f"--sample: need WALKERS >= 2 and STEPS >= 1, got {text!r}")
    return {"walkers": walkers, "steps": steps}


def add_parser(sub, check_outputs, figure_formats) -> None:
    """Register ``fit`` on the command line's subparsers."""
    p = sub.add_parser("fit", help="fit spot-model parameters to tracked grains")
    p.add_argument("case", metavar="CASE.toml")
    p.add_argument("tracks", metavar="TRACKS", help="trackpy CSV/Parquet, LAMMPS dump or tracks netCDF")
    p.add_argument("--free", action="append", metavar="KEY[=LO:HI]",
                   help="a case key to fit, with bounds (repeat for more keys)")
    p.add_argument("--scale", type=float, default=1.0, help="file length units per grain diameter")
    p.add_argument("--fps", type=float, default=1.0, help="frames (LAMMPS: timesteps) per unit time")
    p.add_argument("--origin", default="0,0", metavar="X,Y", help="orifice centre in the file's units")
    p.add_argument("--y-down", action="store_true", help="the file's vertical axis points down")
    p.add_argument("--observables", default=None, metavar="A,B",
                   help="observables to fit (default velocity,diffusion)")
    p.add_argument("--blocks", type=int, default=10, help="time blocks of the errors (default 10)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="Dask worker processes for the Jacobian's columns (default: none)")
    p.add_argument("--sample", default=None, metavar="WALKERS,STEPS",
                   help="also sample the posterior with emcee")
    p.add_argument("-o", "--output", required=True, metavar="FIT.nc")
    p.add_argument("--plot", nargs="?", const="", default=None, metavar="FIG.png",
                   help="also draw data against the best fit (default FIT.png)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=lambda args: cmd_fit(args, check_outputs, figure_formats))


def _say(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def cmd_fit(args, check_outputs, figure_formats) -> int:
    """Run ``spotpde fit`` (module docstring)."""
    free = parse_free(args.free)
    origin = _origin(args.origin)
    sample = _sample(args.sample)
    figure = None
    if args.plot is not None:
        figure = Path(args.plot) if args.plot else Path(args.output).with_suffix(".png")
    check_outputs([("-o", args.output, None), ("--plot", figure, figure_formats)],
                  inputs=[args.case, args.tracks])
    if args.workers is not None and args.workers < 1:
        raise CaseError(f"--workers: must be >= 1, got {args.workers}")
    if args.blocks < 2:
        raise CaseError(f"--blocks: must be >= 2, got {args.blocks}")
    # the calibration stack (lmfit, the observables, the solvers) loads only for this command
    from ..calibration import fit, plot_fit
    from ..tracks import read
    from ..app.cases import load_case
    from ..app.io import write_netcdf

    case = load_case(args.case)
    try:
        tracks = read(args.tracks, scale=args.scale, fps=args.fps, origin=origin,
                      y_down=args.y_down)
    except (ValueError, TypeError) as exc:
        raise CaseError(f"TRACKS: {exc}") from None
    observables = None if args.observables is None else [
        s.strip() for s in args.observables.split(",") if s.strip()]
    began = time.monotonic()

    def progress(n, chi2):
        if not args.quiet:
            _say(f"spotpde: fit: model evaluation {n}, chi2 = {chi2:.6g} "
                 f"({time.monotonic() - began:.0f} s)")

    with _client(args.workers) as client:
        try:
            ds = fit(case, tracks, free, observables, blocks=args.blocks, client=client,
                     sample=sample, progress=progress)
        except (ValueError, TypeError) as exc:
            if isinstance(exc, CaseError):
                raise
            raise CaseError(str(exc).splitlines()[0]) from None
    write_netcdf(ds, args.output)
    args.written = os.path.abspath(args.output)
    if not args.quiet:
        _say(ds.attrs["report"])
    _say(f"spotpde: wrote {args.output}")
    if figure is not None:
        _save_figure(plot_fit(ds), figure)
        _say(f"spotpde: wrote {figure}")
    return 0


@contextlib.contextmanager
def _client(workers):
    if workers is None:
        yield None
        return
    from ..app.sweep import _dask_client    # the sweeps' embedded cluster and its clean abort

    with _dask_client(None, workers, workers, Path.cwd()) as client:
        yield client


def _save_figure(fig, path: Path) -> None:
    """Write a pyplot figure atomically (:func:`spotpde._figures.save_figure`), then close it."""
    import matplotlib.pyplot as plt

    from .._figures import save_figure

    try:
        save_figure(fig, path)
    finally:
        plt.close(fig)
