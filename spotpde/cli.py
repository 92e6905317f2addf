"""The ``spotpde`` command line: ``run``, ``check``, ``plot`` and ``--version``.

Exit status (CONTRACT.md): 0 done; 2 invalid case or unreadable input (one line per
problem on standard error, no traceback, no output file); 1 numerical failure (no
output file); 130 interrupted by Ctrl-C (no output file, or a complete one: results
are written to a temporary file in the target directory and then renamed).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from ._version import __version__
from .errors import CaseError, NumericalError

EXIT_OK, EXIT_NUMERICAL, EXIT_INVALID, EXIT_INTERRUPTED = 0, 1, 2, 130


class Progress:
    """Stage progress on standard error: a tqdm bar on a terminal, plain lines otherwise.

    Plain lines look like ``spotpde: spot density 40%`` and are printed at most every
    ``step`` percent and at most every few seconds, so a log stays short.

    Args:
        stream: where to write (default ``sys.stderr``).
        tty: force bar (True) or lines (False); default: ``stream.isatty()``.
        step: percent between plain lines.
    """

    def __init__(self, stream=None, tty: bool | None = None, step: int = 25):
        self.stream = stream if stream is not None else sys.stderr
        self.tty = self.stream.isatty() if tty is None else tty
        self.step = step
        self.stage = None
        self.bar = None
        self.last = -1

    def __call__(self, stage: str, fraction: float) -> None:
        pct = int(round(100 * min(max(fraction, 0.0), 1.0)))
        if stage != self.stage:
            self.close()
            self.stage = stage
            self.last = -1
            if self.tty:
                from tqdm import tqdm

                self.bar = tqdm(total=100, desc=f"spotpde: {stage}", file=self.stream,
                                unit="%", leave=True,
                                bar_format="{desc} {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}]")
        if self.bar is not None:
            if pct > self.bar.n:
                self.bar.update(pct - self.bar.n)
            return
        if self.last < 0 or pct // self.step > self.last // self.step:
            print(f"spotpde: {stage} {pct}%", file=self.stream, flush=True)
            self.last = pct

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def _say(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _problems(err: CaseError) -> None:
    for line in err.problems:
        _say(line)


def cmd_check(args) -> int:
    from .cases import load_case

    case = load_case(args.case)
    g = case.grid
    cells = " x ".join(str(n) for n in g.shape)
    _say(f"spotpde: {args.case} is valid ({g.dims}D, {cells} cells, model {case.model})")
    return EXIT_OK


def cmd_run(args) -> int:
    from . import io
    from .cases import load_case
    from .pipeline import run

    case = load_case(args.case)
    if args.output is not None:
        case = case.with_output(args.output)
    out = case.output_path
    if not out.parent.is_dir():
        raise CaseError(f"output.path: the directory {out.parent} does not exist, "
                        f"got {str(out)!r}")
    fig = None
    if args.plot is not None:
        fig = Path(args.plot) if args.plot else out.with_suffix(".png")
        if not fig.parent.resolve().is_dir():
            raise CaseError(f"--plot: the directory {fig.parent} does not exist")
    progress = None if args.quiet else Progress()
    t0 = time.monotonic()
    try:
        ds = run(case, progress=progress)
    finally:
        if progress is not None:
            progress.close()
    io.write_netcdf(ds, out)
    args.written = out
    _say(f"spotpde: wrote {out} ({time.monotonic() - t0:.1f} s)")
    if fig is not None:
        from .plotting import plot_result

        plot_result(ds, fig)
        _say(f"spotpde: wrote {fig}")
    return EXIT_OK


def cmd_plot(args) -> int:
    from . import io
    from .plotting import plot_result

    try:
        ds = io.read_netcdf(args.result)
    except ValueError as exc:
        _say(str(exc))
        return EXIT_INVALID
    fig = Path(args.output) if args.output else Path(args.result).with_suffix(".png")
    plot_result(ds, fig)
    _say(f"spotpde: wrote {fig}")
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``spotpde`` command."""
    p = argparse.ArgumentParser(
        prog="spotpde",
        description="Continuum spot model of dense granular drainage (Bazant 2004).")
    p.add_argument("--version", action="version", version=f"spotpde {__version__}")
    sub = p.add_subparsers(dest="command", metavar="{run,check,plot}")
    sub.required = True
    r = sub.add_parser("run", help="run a case and write one netCDF file")
    r.add_argument("case", metavar="CASE.toml")
    r.add_argument("-o", "--output", metavar="OUT.nc", help="overrides output.path")
    r.add_argument("--plot", nargs="?", const="", default=None, metavar="FIG.png",
                   help="also write the standard figure (default: OUT.png next to OUT.nc)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    r.set_defaults(func=cmd_run)
    c = sub.add_parser("check", help="validate a case without running it")
    c.add_argument("case", metavar="CASE.toml")
    c.set_defaults(func=cmd_check)
    f = sub.add_parser("plot", help="the standard figure of a result file")
    f.add_argument("result", metavar="OUT.nc")
    f.add_argument("-o", "--output", metavar="FIG.png", help="default: OUT.png")
    f.set_defaults(func=cmd_plot)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``spotpde`` command.

    Args:
        argv: arguments without the program name (default ``sys.argv[1:]``).

    Returns:
        The exit status (0, 1, 2 or 130).
    """
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:   # --help, --version, usage errors (status 2)
        return int(exc.code or 0)
    try:
        return args.func(args)
    except CaseError as err:
        _problems(err)
        return EXIT_INVALID
    except NumericalError as err:
        _say(f"spotpde: numerical failure, no result written: {err}")
        return EXIT_NUMERICAL
    except KeyboardInterrupt:
        written = getattr(args, "written", None)
        _say(f"spotpde: interrupted; {written} is complete" if written else
             "spotpde: interrupted, no result written")
        return EXIT_INTERRUPTED
    except OSError as err:
        _say(f"spotpde: {err.strerror or err}: {err.filename or ''}".rstrip(": "))
        return EXIT_INVALID if args.command != "run" else EXIT_NUMERICAL


if __name__ == "__main__":
    sys.exit(main())
