"""The ``spotpde`` command line: ``run``, ``check``, ``plot``, ``sweep``, ``compare``, ``fit``
(in ``_fit``), ``--version``.

Exit status (docs/interface.md): 0 done; 2 invalid case, unreadable input or an output
path that cannot or must not be written (one line per problem on standard error, no
traceback, no output file); 1 numerical failure or a failed write (no output file); 130
interrupted by Ctrl-C, 128 + the signal number for SIGTERM and SIGHUP (no output file, or
a complete one: results are written to a temporary file in the target directory and
then renamed). Output paths are checked before any computing (:mod:`spotpde.app._outputs`).
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import time
import warnings
from pathlib import Path

from tqdm import tqdm

from .._version import __version__
from . import _fit
from ..app._outputs import (FIGURE_FORMATS, Terminated, check_signals, file_identity,
                            handle_termination, held_signals, output_problem)
from ..errors import CaseError, NumericalError, WriteError

EXIT_OK, EXIT_NUMERICAL, EXIT_INVALID, EXIT_INTERRUPTED = 0, 1, 2, 130


class Progress:
    """Stage progress on standard error: a tqdm bar on a terminal, plain lines otherwise.

    Plain lines look like ``spotpde: spot density 50%`` and are printed when a stage
    starts and each time it crosses a multiple of ``step`` percent (at most
    ``1 + 100 / step`` lines per stage), so a log stays short.

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
        """Report ``fraction`` (0..1) of ``stage`` done (the pipeline's callback); a stop
        signal whose exception was dropped is raised here (``check_signals``)."""
        check_signals()
        pct = int(round(100 * min(max(fraction, 0.0), 1.0)))
        if stage != self.stage:
            self.close()
            self.stage = stage
            self.last = -1
            if self.tty:
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
        """Finish the current stage's bar (no-op for plain lines)."""
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def _say(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _problems(err: CaseError) -> None:
    for line in err.problems:
        _say(line)


def cmd_check(args) -> int:
    """``spotpde check CASE.toml``: validate the case, print its grid; exit status 0."""
    from ..app.cases import load_case

    case = load_case(args.case)
    _check_outputs([("output.path", case.output_path, None)], inputs=[args.case])
    g = case.grid
    cells = " x ".join(str(n) for n in g.shape)
    _say(f"spotpde: {args.case} is valid ({g.geometry.description}, {cells} cells, "
         f"model {case.model})")
    _estimate(case, getattr(args, "allow_long", False))
    return EXIT_OK


def _estimate(case, allow_long: bool, quiet: bool = False, fields=None) -> None:
    """Print the tracer run-time estimate (unless ``quiet``); refuse (CaseError) a run over a
    day. From the steady ``fields`` when given (``run``: the fields its pipeline computed),
    else computing them (``check``)."""
    from ..app import estimate
    try:
        est = (estimate.case_estimate(case) if fields is None else
               estimate.fields_estimate(case, fields))
    except Exception:      # the run itself reports what is wrong with the fields
        est = None
    if quiet:
        pass
    elif est is not None:
        _say(f"spotpde: {estimate.describe(est)}")
    elif case.tracer is not None and case.tracer.t_end == float("inf"):
        _say("spotpde: tracer: t_end = inf: the geometrical propagator as the steady state "
             "of the scheme (a few sparse solves)")
    estimate.refuse_if_long(case, est, allow_long)


def _run_libraries(case) -> None:
    """Import what ``spotpde run`` of ``case`` will use, so that it can be done inside
    :class:`~spotpde.app._localdask.deferred_signals`: the pipeline and io (xarray,
    netCDF4 and xarray's backends, found through entry points on first use), the spot
    density, field (with the FFT convolution: pyfftw) and kinematic solvers, and the
    tracer."""
    from ..app._localdask import import_libraries

    import_libraries(dask=False)
    try:     # xarray's netCDF writer asks dask for its scheduler, and dask imports distributed
        import distributed  # noqa: F401
    except ImportError:
        pass
    particle = case.model != "void"
    for name in ("spotpde.app.pipeline", "spotpde.app.estimate",
                 "spotpde.density.spot_density", "spotpde.density.kinematic",
                 "spotpde.fields.coefficients" if particle else "spotpde.fields.void",
                 "spotpde.fields.convolution" if particle else None,   # pyfftw
                 "spotpde.tracer" if case.tracer is not None else None,
                 "spotpde.density.traffic" if case.spots.rho_max is not None else None,
                 "spotpde.pair" if case.pair is not None else None):
        if name is not None:
            importlib.import_module(name)


def _warmup(case):
    """Start compiling the run's tracer kernel in a child process (:mod:`._warmup`) when
    the run will step a 2D tracer and numba's cache has never held that kernel."""
    from ..app import _warmup as warmup

    t = case.tracer
    if t is None or t.t_end == float("inf") or case.grid.dims != 2 or \
            case.tracer_options.get("stepping") == "implicit" or not warmup.needed():
        return None
    try:                        # numba's default thread count: the cores this process may use
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - non-Linux
        cores = os.cpu_count() or 1
    cores = int(os.environ.get("NUMBA_NUM_THREADS", cores))
    threads = 1 if case.grid.size < 65536 else cores     # as tracer.solve chooses
    return warmup.Warmup(case.tracer_options.get("limiter", "weno5"), threads)


def cmd_run(args) -> int:
    """``spotpde run CASE.toml [-o OUT.nc] [--plot [FIG.png]]``: run, stream to the file.

    A signal received while the command imports its libraries is acted upon after the
    imports (:class:`~spotpde.app._localdask.deferred_signals`), so an early Ctrl-C exits
    with the documented status and one line. The progress starts with the spot density
    stage once the case is valid and the outputs writable: loading the solvers is its
    first part. The run-time estimate is made from the fields the run computes, before
    the tracer starts and before any file is created; with transient spots, before the
    spot density stage (:func:`~spotpde.app.estimate.transient_estimate`).
    """
    from ..app._localdask import deferred_signals

    with deferred_signals():    # a signal during the imports is acted upon after them
        from ..app.cases import load_case

        case = load_case(args.case, frames_in_memory=False)   # frames are streamed to the file
        if args.output is not None:
            case = case.with_output(args.output)
        out = case.output_path
        fig = None
        if args.plot is not None:
            fig = Path(args.plot) if args.plot else out.with_suffix(".png")
        _check_outputs([("output.path", out, None), ("--plot", fig, FIGURE_FORMATS)],
                       inputs=[args.case])
    if case.spots.mode == "transient":     # before the spot density is time-stepped
        _estimate(case, args.allow_long, args.quiet)
    progress = None if args.quiet else Progress()
    t0 = time.monotonic()
    args.target = (out, file_identity(out))     # replaced by this run, if it gets that far
    warm = _warmup(case) if args.command_line else None
    try:
        if progress is not None:
            progress("spot density", 0.0)
        with deferred_signals():
            _run_libraries(case)
            from ..app.pipeline import run

        def on_fields(fields):
            if progress is not None:
                progress.close()        # a bar is finished before the estimate's line
            _estimate(case, args.allow_long, args.quiet, fields=fields)
            if warm is not None:
                warm.wait()             # the tracer kernel is in numba's cache now

        ds = run(case, progress=progress, path=out, on_fields=on_fields)
        check_signals()     # a signal dropped in the last stage: the file is complete
    finally:
        if warm is not None:
            warm.stop()
        if progress is not None:
            progress.close()
    args.written = out
    _say(f"spotpde: wrote {out} ({time.monotonic() - t0:.1f} s)")
    if fig is not None:
        with deferred_signals():
            from ..app.plotting import plot_result

        plot_result(ds, fig)
        _say(f"spotpde: wrote {fig}")
    return EXIT_OK


def cmd_plot(args) -> int:
    """``spotpde plot OUT.nc [-o FIG.png]``: the standard figure, in the format of the
    extension; 2 for unreadable input or coordinates that cannot be drawn, 1 for a
    failed write. Imports xarray, netCDF4 and matplotlib only (no solver, no numba)."""
    from ..app import io
    from ..app.plotting import plot_result, plottable

    fig = Path(args.output) if args.output else Path(args.result).with_suffix(".png")
    _check_outputs([("-o", fig, FIGURE_FORMATS)], inputs=[args.result])
    try:
        ds = io.read_netcdf(args.result)
        io.check_single_run(ds, args.result)
        ds = plottable(ds, args.result)
    except ValueError as exc:
        _say(str(exc))
        return EXIT_INVALID
    plot_result(ds, fig)
    _say(f"spotpde: wrote {fig}")
    return EXIT_OK


def cmd_sweep(args) -> int:
    """``spotpde sweep CASE.toml --set KEY=V1,V2 ...``: 1 when a member failed.

    Interrupted (SIGINT, SIGTERM, SIGHUP) at any moment, it stops its Dask workers at
    once, keeps the finished members, removes every temporary file, prints one line and
    exits with 128 + the signal (130 for Ctrl-C) through ``os._exit``, so that no
    finaliser of distributed prints at interpreter exit (:mod:`spotpde.app._localdask`).
    """
    try:
        return _sweep_command(args)
    except KeyboardInterrupt as exc:
        if not getattr(args, "command_line", False):    # main() called from Python
            raise
        from ..app._localdask import before_exit

        status = _interrupted(args, exc)
        before_exit()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)


def _sweep_command(args) -> int:
    """:func:`cmd_sweep` without its handling of interrupts."""
    from ..app._localdask import deferred_signals, import_libraries

    with deferred_signals():    # a signal during the imports is acted upon after them
        from ..app.cases import load_case
        from ..app.sweep import parse_settings, sweep_case

        if args.workers is not None and args.workers < 1:
            raise CaseError(f"--workers: must be >= 1, got {args.workers}")
        settings = parse_settings(args.set or [])
        case = load_case(args.case)
        output = args.output if args.output is not None else case.output_path
        _check_outputs([("output.path" if args.output is None else "-o", output, None)],
                       inputs=[args.case])
        import_libraries()

    def progress(done: int, total: int) -> None:
        if not args.quiet:
            _say(f"spotpde: sweep {done}/{total} members finished")

    def validating(done: int, total: int) -> None:
        if not args.quiet and total >= 100:     # about a second or more
            _say(f"spotpde: sweep {done}/{total} members validated")

    t0 = time.monotonic()
    ds = sweep_case(case, settings, output, scheduler=args.scheduler,
                    n_workers=args.workers, progress=progress,
                    allow_many=args.allow_many, validating=validating)
    args.written = os.path.abspath(output)
    _say(f"spotpde: wrote {os.path.abspath(output)} ({time.monotonic() - t0:.1f} s)")
    failed = ds.attrs.get("failed_members", "")
    if failed:
        for line in failed.splitlines():
            _say(f"spotpde: member failed: {line}")
        return EXIT_NUMERICAL
    return EXIT_OK


def cmd_compare(args) -> int:
    """``spotpde compare CASE.toml [--rules LAM ...] [-o FIG.png]``: spot vs kinematic flow.

    Prints one line per rule ``lam`` on standard output: the medians over the compared
    heights of :meth:`spotpde.comparison.KinematicComparison.summary` (``key=value``;
    speeds in d per unit time, lengths in d); with ``-o`` also writes the comparison
    figure (:func:`spotpde.comparison.plot_comparison`). Exit status 0, or 2 for an
    invalid case, a rule outside ``kernel.rule``'s range (0, 1], or a case the comparison
    cannot use (:func:`spotpde.comparison.case_problems`, e.g. a profile of ``spots.b``:
    one line per problem naming the key, on standard error).
    """
    from ..app.cases import load_case
    from ..analysis.comparison import case_problems, compare_rules, plot_comparison

    if args.output:
        _check_outputs([("-o", args.output, FIGURE_FORMATS)], inputs=[args.case])
    try:
        case = load_case(args.case)
        problems = case_problems(case, args.rules)   # by case key and --rules
        if problems:
            raise CaseError(problems)
        results = compare_rules(case, args.rules)
    except (CaseError, ValueError) as exc:
        _say(str(exc))
        return EXIT_INVALID
    for c in results.values():
        print(" ".join(f"{k}={v:.6g}" for k, v in c.summary().items()))
    if args.output:
        plot_comparison(results, args.output)
    return EXIT_OK


def _check_outputs(outputs, inputs) -> None:
    """Refuse, before any computing, outputs that cannot or must not be written.

    Args:
        outputs: ``(key, path or None, formats or None)`` in order; each is also checked
            against the ones before it.
        inputs: the command's input files.

    Raises:
        spotpde.CaseError: one line per problem, naming the key (``output.path``,
            ``--plot``, ``-o``).
    """
    problems, earlier = [], []
    for key, path, formats in outputs:
        if path is None:
            continue
        msg = output_problem(path, inputs=inputs, others=earlier, formats=formats)
        if msg:
            problems.append(f"{key}: {msg}")
        earlier.append((f"output given by {key}", path))
    if problems:
        raise CaseError(problems)


def _warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Warnings as one line on standard error (``spotpde: warning: ...``)."""
    _say(f"spotpde: warning: {message}")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``spotpde`` command."""
    p = argparse.ArgumentParser(
        prog="spotpde",
        description="Continuum spot model of dense granular drainage (Bazant 2004).")
    p.add_argument("--version", action="version", version=f"spotpde {__version__}")
    sub = p.add_subparsers(dest="command", metavar="{run,check,plot,sweep,compare,fit}")
    sub.required = True
    r = sub.add_parser("run", help="run a case and write one netCDF file")
    r.add_argument("case", metavar="CASE.toml")
    r.add_argument("-o", "--output", metavar="OUT.nc", help="overrides output.path")
    r.add_argument("--plot", nargs="?", const="", default=None, metavar="FIG.png",
                   help="also write the standard figure (default: OUT.png next to OUT.nc)")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    r.add_argument("--allow-long", action="store_true",
                   help="start a tracer run estimated at more than a day")
    r.set_defaults(func=cmd_run)
    c = sub.add_parser("check", help="validate a case without running it")
    c.add_argument("case", metavar="CASE.toml")
    c.add_argument("--allow-long", action="store_true",
                   help="accept a tracer run estimated at more than a day")
    c.set_defaults(func=cmd_check)
    f = sub.add_parser("plot", help="the standard figure of a result file")
    f.add_argument("result", metavar="OUT.nc")
    f.add_argument("-o", "--output", metavar="FIG.png", help="default: OUT.png")
    f.set_defaults(func=cmd_plot)
    w = sub.add_parser("sweep", help="run the product of case-key values on Dask, one netCDF file")
    w.add_argument("case", metavar="CASE.toml")
    w.add_argument("--set", action="append", metavar="KEY=V1,V2,...",
                   help="values of one case key to sweep (repeat for more keys)")
    w.add_argument("-o", "--output", metavar="SWEEP.nc", help="overrides output.path")
    w.add_argument("--scheduler", metavar="ADDRESS",
                   help="a running Dask scheduler (default: an embedded LocalCluster)")
    w.add_argument("--workers", type=int, metavar="N",
                   help="LocalCluster worker processes (default and at most: the cores; "
                        "at most the members)")
    w.add_argument("--allow-many", action="store_true",
                   help="run a sweep of more than 10000 members")
    w.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    w.set_defaults(func=cmd_sweep)
    k = sub.add_parser("compare", help="spot-model mean flow against the Kinematic Model, "
                                       "rule by rule (numbers and a figure)")
    k.add_argument("case", metavar="CASE.toml")
    k.add_argument("--rules", type=float, nargs="+", default=[0.5, 1.0], metavar="LAM",
                   help="rules lam to compare (default: 0.5 1)")
    k.add_argument("-o", "--output", metavar="FIG.png", help="write the comparison figure")
    k.set_defaults(func=cmd_compare)
    _fit.add_parser(sub, _check_outputs, FIGURE_FORMATS)
    return p


def _interrupted(args, exc: KeyboardInterrupt) -> int:
    """Say what an interrupt left (one line); returns the exit status, 130 or 128 + n.

    A further signal is dropped meanwhile; temporary files whose own clean-up a second
    signal cut are removed. The result counts as written when the run renamed its file
    into place (the target is another file than before the run), whenever the signal came.
    """
    with held_signals(drop=True):
        io = sys.modules.get("spotpde.app.io")
        if io is not None and getattr(args, "command_line", False):   # the process's own
            io.remove_temporaries()
        written = getattr(args, "written", None)
        target, before = getattr(args, "target", (None, None))
        if written is None and target is not None and file_identity(target) not in (None,
                                                                                     before):
            written = target
        what = (f"terminated by signal {exc.signum}" if isinstance(exc, Terminated)
                else "interrupted")
        _say(f"spotpde: {what}; {written} is complete" if written else
             f"spotpde: {what}, no result written")
    return 128 + exc.signum if isinstance(exc, Terminated) else EXIT_INTERRUPTED


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
    args.command_line = argv is None   # the process is this command (may os._exit)
    handle_termination()          # SIGTERM and SIGHUP: like Ctrl-C
    status = _dispatch(args)
    if args.command_line and args.command in QUICK_EXIT:
        _quick_exit(status)
    return status


#: commands whose process ends without the interpreter's teardown once they are done
QUICK_EXIT = ("run", "check", "plot")


def _quick_exit(status: int) -> None:
    """End the process at once with ``status``, its output flushed.

    Everything the command writes is closed by then (the netCDF result is renamed into
    place, the figure saved, numba's cache and FFTW's wisdom are written when made). What
    ``os._exit`` skips is the interpreter's teardown of the scientific libraries' modules
    and extension state, which took about 1 s after a flagship run (0.2-0.3 s each for
    numba, pyfftw, dask, matplotlib; C code, no Python frames), a part of the first run's
    time (issue 16: under 15 s), and 0.3 s of the 4 s of CPU time of ``plot``. matplotlib
    keeps its files in a lasting directory (:func:`spotpde._figures.prepare_matplotlib`), so
    the skipped clean-up of a temporary one leaves nothing behind."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(status)


def _dispatch(args) -> int:
    """Run the chosen command; errors become one line and an exit status."""
    warnings.showwarning = _warning
    try:
        return args.func(args)
    except CaseError as err:
        _problems(err)
        return EXIT_INVALID
    except NumericalError as err:
        _say(f"spotpde: numerical failure, no result written: {err}")
        return EXIT_NUMERICAL
    except KeyboardInterrupt as exc:
        return _interrupted(args, exc)
    except MemoryError as err:    # an allocation the estimate did not foresee
        detail = " ".join(str(err).split()) or "an allocation failed"
        _say(f"spotpde: out of memory, no result written: {detail}")
        return EXIT_NUMERICAL
    except WriteError as err:     # disk full, file-size limit: nothing left behind
        _say(f"spotpde: {err}")
        return EXIT_NUMERICAL
    except OSError as err:
        _say(f"spotpde: {err.strerror or err}: {err.filename or ''}".rstrip(": "))
        return EXIT_INVALID if args.command != "run" else EXIT_NUMERICAL


if __name__ == "__main__":
    sys.exit(main())
