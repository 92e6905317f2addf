"""Figure files, written atomically, and a home for matplotlib's own files.

:func:`save_figure` is the only way spotpde writes a figure: ``spotpde plot``,
``run --plot``, ``compare -o``, ``fit --plot`` and the ``path`` argument of
:func:`~spotpde.plotting.plot_result`, :func:`~spotpde.comparison.plot_comparison`,
:func:`~spotpde.calibration.plot_fit` and :func:`~spotpde.traffic.plot_space_time`.

* The format is the one the file's extension names (``fig.pdf`` is a PDF, ``fig.svg``
  an SVG); an extension outside :data:`FIGURE_FORMATS` is refused.
* The figure is drawn into a temporary file that :func:`tempfile.mkstemp` creates
  exclusively (``O_EXCL``) under an unpredictable name in the target's directory
  (``.NAME.XXXXXXXX.tmp``), flushed to the disk (``fsync``), given the usual permissions
  (0666 minus the umask) and renamed onto the target (:func:`os.replace`). A symbolic
  link planted at some name cannot redirect the write, and concurrent writers to one
  target each have their own temporary file: the target is always one complete figure.
* On any exception, Ctrl-C and SIGTERM (:class:`~spotpde.app._outputs.Terminated`)
  included, the temporary file is removed and an existing target is left untouched; an
  :class:`OSError` (disk full, file-size limit) becomes a
  :class:`~spotpde.errors.WriteError` naming the target.

:func:`prepare_matplotlib`, called before matplotlib is imported, gives matplotlib a
persistent directory in spotpde's cache when its own configuration or cache directory
cannot be written (no writable ``HOME``, an unwritable ``MPLCONFIGDIR``). matplotlib
would otherwise warn on standard error, rebuild its font list in a new temporary
``matplotlib-XXXXXXXX`` directory on every start, and leave that directory behind
whenever the process ends without the interpreter's clean-up (the command line's quick
exit after ``run``).
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

from . import _cache
from .errors import WriteError

#: Extensions of the figures matplotlib's Agg, PDF, PS and SVG backends write.
FIGURE_FORMATS = ("png", "pdf", "svg", "svgz", "eps", "ps", "jpg", "jpeg", "tif", "tiff",
                  "webp")

__all__ = ["figure_format", "prepare_matplotlib", "save_figure"]


def figure_format(path: str | os.PathLike) -> str:
    """The matplotlib format named by ``path``'s extension (lower case, no dot).

    Raises:
        ValueError: ``path: unsupported figure format ...`` for an extension outside
            :data:`FIGURE_FORMATS` (or none).
    """
    suffix = Path(os.fspath(path)).suffix
    fmt = suffix.lower().lstrip(".")
    if fmt not in FIGURE_FORMATS:
        raise ValueError(f"path: unsupported figure format {suffix or '(no extension)'!r}; "
                         "use one of " + ", ".join("." + f for f in FIGURE_FORMATS)
                         + f", got {os.fspath(path)!r}")
    return fmt


def save_figure(fig, path: str | os.PathLike, **savefig_kwargs) -> Path:
    """Write a matplotlib Figure to ``path`` atomically, in the format of its extension.

    Args:
        fig: a :class:`matplotlib.figure.Figure`.
        path: the figure file; its directory must exist.
        **savefig_kwargs: passed to :meth:`~matplotlib.figure.Figure.savefig` (``dpi``
            in dots per inch, ``bbox_inches``, ...), except ``format``.

    Returns:
        ``path`` as a :class:`~pathlib.Path`.

    Raises:
        ValueError: an unsupported extension (:func:`figure_format`).
        spotpde.errors.WriteError: the file could not be written (the message names
            ``path`` and the cause); nothing is left behind.
    """
    fmt = figure_format(path)
    if "format" in savefig_kwargs:
        raise TypeError("savefig_kwargs: the format is taken from path's extension; "
                        "do not pass format")
    target = Path(os.path.abspath(os.fspath(path)))
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp",
                                   dir=target.parent)
    except OSError as exc:
        raise _write_error(target, exc) from None
    try:
        with os.fdopen(fd, "wb") as fh:
            fig.savefig(fh, format=fmt, **savefig_kwargs)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, target)
    except BaseException as exc:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(exc, OSError) and not isinstance(exc, WriteError):
            raise _write_error(target, exc) from None
        raise
    return Path(path)


def _write_error(path: Path, exc: OSError) -> WriteError:
    why = exc.strerror or str(exc) or type(exc).__name__
    return WriteError(f"could not write {path} ({why}); nothing was written")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _usable(directory: Path) -> bool:
    """matplotlib's own test of its configuration and cache directories: created if
    missing, then writable by :func:`os.access`."""
    try:
        directory = directory.resolve()
        directory.mkdir(parents=True, exist_ok=True)
    except (OSError, RuntimeError):
        return False
    return directory.is_dir() and os.access(directory, os.W_OK)


def _matplotlib_dirs() -> list[Path] | None:
    """The directories matplotlib would use (Linux and BSD: XDG), or None when it would
    fall back to a temporary directory before trying any."""
    env = os.environ.get("MPLCONFIGDIR")
    if env:
        return [Path(env)]
    try:
        home = Path.home()
    except (RuntimeError, KeyError):
        home = None
    dirs = []
    for var, default in (("XDG_CONFIG_HOME", ".config"), ("XDG_CACHE_HOME", ".cache")):
        base = os.environ.get(var)
        if not base:
            if home is None:
                return None
            base = home / default
        dirs.append(Path(base) / "matplotlib")
    return dirs


def prepare_matplotlib() -> Path | None:
    """Point ``MPLCONFIGDIR`` at spotpde's cache when matplotlib cannot use its own
    directories (module docstring). Call before matplotlib is imported.

    Does nothing when matplotlib is imported already, outside Linux and the BSDs, or
    when matplotlib's directories (``MPLCONFIGDIR``, else the XDG configuration and
    cache directories) can be written.

    Returns:
        The directory chosen (``<spotpde cache>/matplotlib``, else
        ``<tmp>/spotpde-<uid>/matplotlib``), or ``None`` when nothing was changed.
    """
    if "matplotlib" in sys.modules or not sys.platform.startswith(("linux", "freebsd")):
        return None
    dirs = _matplotlib_dirs()
    if dirs is not None and all(_usable(d) for d in dirs):
        return None
    for candidate in (_cache.user_cache_dir() / "matplotlib",
                      _cache.fallback_dir() / "matplotlib"):
        if _cache.writable(candidate):
            os.environ["MPLCONFIGDIR"] = str(candidate)
            return candidate
    return None
