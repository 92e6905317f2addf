"""Parameter sweeps on Dask: the product of case-key values, run in parallel, one Dataset.

A sweep takes a validated base case and, for each swept key, a list of values
(``--set kernel.size=1,2,3 --set spots.b=1.3,2.3``). Every combination is a *member*:
a full case, validated before anything runs. Members run as Dask tasks, on an embedded
``dask.distributed.LocalCluster`` (one single-threaded worker process per core, nothing
to start) or on a user's scheduler (``scheduler="tcp://host:8786"``; its workers need
spotpde installed). Each finished member is written, atomically, to
``<output>.members/member-<hash>.nc`` (the hash is that of the member's case text), so
a sweep that is interrupted or partly failed is *resumed* by running it again: members
whose file exists are read, not rerun.

The members are combined into one Dataset whose leading dimensions are the swept keys,
in the order given, named by the key with its dots replaced by underscores
(:func:`dim_name`: ``kernel.size`` -> ``kernel_size``, a valid netCDF/CF name; the
coordinate's ``case_key`` attribute keeps the dotted key). A member file that cannot be
read (a run killed while the file was copied, a truncated file) is removed and the
member run again. A scheduler address is checked before use: it must be a Dask address
(``tcp://host:port`` or ``host:port``), answer within :func:`connect_timeout` seconds,
and not speak first (a service that sends a banner is not a Dask scheduler). Per-member
numbers that are global attributes of a single run (``V1``, ``V2``, ``rule``) become
variables over the swept dimensions. A member that failed is not dropped: its fields
are NaN, ``status`` is 1 there, and the global attribute ``failed_members`` lists it by
its parameters with the error message.

An embedded cluster's workers never take a terminal's Ctrl-C. An interrupt (SIGINT,
SIGTERM, SIGHUP) at any moment kills them at once and quietly, removes the temporary
files of unfinished member writes and keeps the finished members; ``spotpde sweep`` then
prints one line and exits with 128 + the signal (:mod:`._localdask`, docs/sweeps.md).
"""

from __future__ import annotations

import contextlib
import copy
import hashlib
import itertools
import math
import os
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Callable

import numpy as np
import xarray as xr

from .._version import __version__
from .cases import Case, check_arguments, load_case
from ..errors import CaseError, NumericalError
from ._connect import CONNECT_TIMEOUT, MAX_CONNECT_TIMEOUT, connect, connect_timeout  # noqa: F401

#: Keys that change the grid cannot be swept into one Dataset.
FIXED_KEYS = ("domain.dims", "domain.x", "domain.z", "domain.spacing", "output.path")
#: Most members a sweep runs without ``allow_many`` (``spotpde sweep --allow-many``):
#: every member is a whole run and its validation alone takes milliseconds.
MAX_MEMBERS = 10_000
#: Global attributes of a single run that become variables over the swept dimensions.
MEMBER_NUMBERS = {"V1": ("d{dims}", "first interaction volume: integral of w"),
                  "V2": ("d{dims}", "second interaction volume: integral of w**2"),
                  "rule": ("1", "lam: where along a spot step its influence is evaluated")}


def parse_settings(items: Sequence[str]) -> dict[str, list]:
    """Parse ``--set KEY=V1,V2,...`` items.

    Each value is read as a TOML value (``1``, ``2.5``, ``true``, ``"gaussian"``); a bare
    word that is not TOML is taken as a string, so ``kernel.shape=uniform,gaussian`` works.

    Args:
        items: strings ``"table.key=v1,v2,..."``.

    Returns:
        Values by dotted key, in the order given.

    Raises:
        spotpde.CaseError: a malformed item, a repeated or unsweepable key.
    """
    settings: dict[str, list] = {}
    problems = []
    for item in items:
        key, sep, values = item.partition("=")
        key = key.strip()
        if not sep or not key or not values.strip():
            problems.append(f"--set {item}: expected KEY=V1,V2,... (e.g. spots.b=1.3,2.3)")
            continue
        if key.count(".") < 1:
            problems.append(f"--set {key}: expected a dotted key table.key (e.g. kernel.size)")
            continue
        if key in FIXED_KEYS:
            problems.append(f"--set {key}: cannot be swept (it changes the grid or the output); "
                            f"sweepable: any key of orifice, spots, kernel, tracer, and "
                            f"domain.walls")
            continue
        if key in settings:
            problems.append(f"--set {key}: given twice; list all its values once")
            continue
        settings[key] = [_parse_value(v.strip()) for v in values.split(",")]
    if problems:
        raise CaseError(problems)
    return settings


def _parse_value(text: str) -> Any:
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text


def _check_settings(settings: Mapping) -> None:
    """Settings given as a mapping from Python: ValueError / TypeError naming
    ``settings[KEY]`` for what ``--set`` would refuse (a key that is not dotted or cannot
    be swept, no values, a string or a number instead of a list of values)."""
    if not isinstance(settings, Mapping):
        raise TypeError(f"settings: must be a mapping {{key: [values]}}, got "
                        f"{type(settings).__name__}")
    for key, values in settings.items():
        name = f"settings[{key!r}]"
        if not isinstance(key, str) or key.count(".") < 1:
            raise ValueError(f"{name}: expected a dotted case key table.key "
                             "(e.g. \"kernel.size\")")
        if key in FIXED_KEYS:
            raise ValueError(f"{name}: cannot be swept (it changes the grid or the output)")
        if isinstance(values, (str, bytes, Mapping)) or not isinstance(
                values, (Sequence, np.ndarray)):
            raise TypeError(f"{name}: must be a list of values, got {type(values).__name__}")
        if len(values) == 0:
            raise ValueError(f"{name}: has no values; give at least one")


def count_members(settings: Mapping[str, Sequence], allow_many: bool = False) -> int:
    """The number of members of a sweep (the product of the numbers of values).

    Raises:
        spotpde.CaseError: more than :data:`MAX_MEMBERS` members and not ``allow_many``.
    """
    counts = [len(v) for v in settings.values()]
    total = math.prod(counts)
    if total > MAX_MEMBERS and not allow_many:
        raise CaseError(f"--set: the sweep has {total:,} members ("
                        f"{' x '.join(map(str, counts))} values), more than {MAX_MEMBERS:,}; "
                        "sweep fewer values, or pass --allow-many (Python: allow_many=True)")
    return total


def members(case: Case, settings: Mapping[str, Sequence], *, allow_many: bool = False,
            progress: Callable[[int, int], None] | None = None) -> list[tuple[tuple, Case]]:
    """Every combination of the swept values as a validated case.

    Args:
        case: the base case.
        settings: values by dotted key.
        allow_many: validate more than :data:`MAX_MEMBERS` members.
        progress: ``progress(validated, total)``, called before the first member, at
            every tenth of them and after the last.

    Returns:
        ``[(values, member_case), ...]`` in row-major order of the swept keys.

    Raises:
        ValueError, TypeError: ``settings[KEY]`` with no values, not a list, or a key
            that cannot be swept.
        spotpde.CaseError: too many members (:func:`count_members`), or every problem
            of every invalid member, each line naming the key and the member it belongs to.
    """
    if not settings:
        raise CaseError("--set: give at least one KEY=V1,V2,... to sweep")
    _check_settings(settings)
    total = count_members(settings, allow_many)
    every = max(1, -(-total // 10))
    if progress is not None:
        progress(0, total)
    out, problems = [], []
    for done, values in enumerate(itertools.product(*settings.values()), 1):
        data = copy.deepcopy(case.data)
        label = _label(settings, values)
        try:
            for key, value in zip(settings, values):
                _assign(data, key, value)
            out.append((values, load_case(data)))
        except CaseError as err:
            problems.extend(f"{line} (sweep member {label})" for line in err.problems)
        if progress is not None and (done % every == 0 or done == total):
            progress(done, total)
    if problems:
        raise CaseError(list(dict.fromkeys(problems)))
    return out


def _assign(data: dict, key: str, value: Any) -> None:
    *tables, last = key.split(".")
    node = data
    for i, t in enumerate(tables):
        if not isinstance(node.get(t), dict):
            where = ".".join(tables[: i + 1])
            raise CaseError(f"{key}: the base case has no [{where}] table to sweep in")
        node = node[t]
    node[last] = value


def _label(settings: Mapping, values: Sequence) -> str:
    return ", ".join(f"{k}={v}" for k, v in zip(settings, values))


def dim_name(key: str) -> str:
    """The sweep dimension of a dotted case key: dots replaced by underscores."""
    return key.replace(".", "_")


def _readable(path: Path) -> bool:
    """True if ``path`` is a complete member result; an unreadable one is removed."""
    if not path.is_file():
        return False
    try:
        with xr.open_dataset(path, engine="netcdf4") as ds:
            ok = "rho_s" in ds.data_vars
            if ok:
                ds["rho_s"].values   # reads the data, not only the header
    except Exception:  # noqa: BLE001 - truncated/corrupt HDF5 raises assorted errors
        ok = False
    if not ok:
        try:
            path.unlink()
        except OSError:
            pass
    return ok


def member_path(directory: Path, member: Case) -> Path:
    """Where a member's result is kept: named by the hash of its case text."""
    digest = hashlib.sha1(member.to_toml().encode()).hexdigest()[:16]
    return directory / f"member-{digest}.nc"


def run_member(case_text: str, path: str) -> tuple[str, str]:
    """Run one member and write its result file (the Dask task).

    Args:
        case_text: the member's case as TOML.
        path: the member's result file.

    Returns:
        ``("ok", path)`` or ``("failed", "ErrorType: message")``. Failures are returned,
        not raised, so one bad member does not stop the sweep.
    """
    from .io import write_netcdf
    from .pipeline import run

    try:
        ds = run(load_case(tomllib.loads(case_text)))
        write_netcdf(ds, path)
    except Exception as exc:  # reported by parameters in the combined result
        return "failed", f"{type(exc).__name__}: {exc}".strip()
    return "ok", path


def sweep_case(
    case: Case | str | Mapping,
    settings: Mapping[str, Sequence] | Sequence[str],
    output: str | os.PathLike | None = None,
    *,
    scheduler: str | Any | None = None,
    n_workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    allow_many: bool = False,
    validating: Callable[[int, int], None] | None = None,
) -> xr.Dataset:
    """Run a parameter sweep and combine the members into one Dataset.

    Args:
        case: base case (a :class:`Case`, a path, TOML text, or a mapping).
        settings: values by dotted key (each a non-empty list), or ``--set`` strings for
            :func:`parse_settings` (a list of them, or one string).
        output: the combined netCDF file to write (atomically); its member files go to
            ``<output>.members/``. ``None``: the base case's ``output.path``.
        scheduler: address of a running Dask scheduler, or a ``distributed.Client``;
            ``None`` starts an embedded ``LocalCluster``.
        n_workers: LocalCluster worker processes (default: the number of cores); never
            more than the cores this process may use or the members still to run.
        progress: ``progress(done, total)`` called as members finish.
        allow_many: run more than :data:`MAX_MEMBERS` members.
        validating: ``validating(validated, total)`` while the members are validated.

    Returns:
        The combined Dataset (also written to ``output``).

    Raises:
        TypeError, ValueError: ``case`` or ``settings`` of the wrong type or empty
            (named), before anything is written.
        spotpde.CaseError: invalid settings, too many members or an invalid member (before
            any work).
    """
    check_arguments(case, output=output)
    if not isinstance(case, Case):
        case = load_case(case)
    if isinstance(settings, str):          # one --set item
        settings = [settings]
    if not isinstance(settings, (Mapping, Sequence)):
        raise TypeError("settings: must be a mapping {key: [values]} or a list of "
                        f"\"KEY=V1,V2\" strings, got {type(settings).__name__}")
    if not isinstance(settings, Mapping):
        if not all(isinstance(item, str) for item in settings):
            raise TypeError("settings: a list of \"KEY=V1,V2\" strings must hold strings "
                            "only")
        settings = parse_settings(settings)
    todo_members = members(case, settings, allow_many=allow_many, progress=validating)
    output = Path(os.path.abspath(output if output is not None else case.output_path))
    if not output.parent.is_dir():
        raise CaseError(f"output.path: the directory {output.parent} does not exist")
    own_client = None
    if isinstance(scheduler, str):      # checked before anything is written or reported
        scheduler = own_client = connect(scheduler)
    try:
        return _sweep(case, settings, todo_members, output, scheduler, n_workers, progress)
    finally:
        if own_client is not None:
            own_client.close()


def _sweep(case, settings, todo_members, output, scheduler, n_workers, progress):
    """:func:`sweep_case` once the members are validated and the scheduler connected."""
    from .io import read_netcdf, write_netcdf

    directory = output.with_name(output.name + ".members")
    directory.mkdir(exist_ok=True)

    paths = [member_path(directory, m) for _, m in todo_members]
    status: dict[int, tuple[str, str]] = {
        i: ("ok", os.fspath(p)) for i, p in enumerate(paths) if _readable(p)}
    todo = [i for i in range(len(paths)) if i not in status]
    done = len(status)
    if progress is not None:
        progress(done, len(paths))
    if todo:
        tasks = [(todo_members[i][1].to_toml(), os.fspath(paths[i])) for i in todo]
        with _dask_client(scheduler, n_workers, len(tasks), directory) as client:
            for i, result in _run_on_dask(tasks, client):
                status[todo[i]] = result
                done += 1
                if progress is not None:
                    progress(done, len(paths))

    results = []
    for i, (values, _) in enumerate(todo_members):
        kind, detail = status[i]
        results.append((values, read_netcdf(detail) if kind == "ok" else detail))
    ds = combine(case, settings, results)
    write_netcdf(ds, output)
    return ds


def _run_on_dask(tasks: list[tuple[str, str]], client):
    """Yield ``(task index, run_member result)`` as tasks finish on ``client``."""
    from distributed import as_completed

    futures = [client.submit(run_member, text, path, pure=False) for text, path in tasks]
    index = {f.key: i for i, f in enumerate(futures)}
    for future in as_completed(futures):
        try:
            result = future.result()
        except Exception as exc:  # a worker died: report, do not drop
            result = ("failed", f"{type(exc).__name__}: {exc}")
        yield index[future.key], result


@contextlib.contextmanager
def _dask_client(scheduler, n_workers: int | None, n_tasks: int, directory: Path):
    """The Client that runs the members: the user's (``scheduler`` an address or a
    Client) or that of an embedded LocalCluster.

    The LocalCluster's workers never receive a terminal's Ctrl-C; on KeyboardInterrupt
    (SIGINT, or SIGTERM/SIGHUP as :class:`~spotpde.app._outputs.Terminated`) anywhere in
    the block, its worker processes are killed at once and quietly and the temporary
    files of their unfinished member writes removed (:mod:`._localdask`); finished
    members stay in ``directory``.
    """
    from ._localdask import LocalDask

    if scheduler is not None:
        client = connect(scheduler) if isinstance(scheduler, str) else scheduler
        try:
            yield client
        finally:
            if client is not scheduler:
                client.close()
        return
    local = LocalDask(worker_count(n_workers, n_tasks))
    interrupted = False
    try:
        yield local.start()
    except KeyboardInterrupt:
        interrupted = True
        raise
    finally:
        if interrupted:
            local.abort(directory)
        else:
            try:
                local.close()
            except KeyboardInterrupt:
                local.abort(directory)
                raise


def worker_count(n_workers: int | None, n_tasks: int) -> int:
    """Worker processes of an embedded cluster: ``n_workers`` (default: the cores), at
    most the cores this process may use and the members to run, at least 1 (a worker
    beyond either only costs memory and start-up time)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - non-Linux
        cores = os.cpu_count() or 1
    return max(1, min(n_workers or cores, cores, n_tasks))


def combine(case: Case, settings: Mapping[str, Sequence], results: list) -> xr.Dataset:
    """Combine member results into one Dataset with the swept keys as dimensions.

    Args:
        case: the base case.
        settings: values by dotted key (fixes the dimension order).
        results: ``[(values, Dataset or failure message), ...]`` in member order.

    Returns:
        The combined Dataset; failed members are NaN with ``status`` 1.

    Raises:
        spotpde.NumericalError: every member failed (there is nothing to combine).
    """
    from .io import cf_attrs, cf_units

    good = [r for _, r in results if isinstance(r, xr.Dataset)]
    failed = [(values, r) for values, r in results if not isinstance(r, xr.Dataset)]
    if not good:
        raise NumericalError("every sweep member failed: " + "; ".join(
            f"{_label(settings, v)}: {msg}" for v, msg in failed))
    template = good[0]
    numbers = {name: [float(r.attrs[name]) if isinstance(r, xr.Dataset) else np.nan
                      for _, r in results] for name in MEMBER_NUMBERS}
    parts = [r if isinstance(r, xr.Dataset) else xr.full_like(template, np.nan)
             for _, r in results]
    shape = tuple(len(v) for v in settings.values())
    stacked = xr.concat(parts, dim="member", join="outer", combine_attrs="drop")
    index = [np.asarray(v) for v in settings.values()]
    data_vars = {}
    swept = tuple(dim_name(k) for k in settings)
    for name, var in stacked.data_vars.items():
        arr = var.values.reshape(shape + var.shape[1:])
        data_vars[name] = (swept + var.dims[1:], arr, template[name].attrs)
    dims = case.grid.dims
    for name, vals in numbers.items():
        units, long_name = MEMBER_NUMBERS[name]
        data_vars[name] = (swept, np.reshape(vals, shape),
                           cf_units(units.format(dims=dims), long_name))
    status = np.reshape([0 if isinstance(r, xr.Dataset) else 1 for _, r in results], shape)
    data_vars["status"] = (swept, status.astype(np.int8),
                           {"units": "1", "long_name": "member status: 0 finished, 1 failed",
                            "flag_values": np.array([0, 1], dtype=np.int8),
                            "flag_meanings": "finished failed"})
    coords = {dim_name(k): (dim_name(k), idx, {**_units_of(k, dims), "case_key": k})
              for k, idx in zip(settings, index)}
    for d in stacked.dims:
        if d != "member":
            coords[d] = (d, stacked[d].values, template[d].attrs)
    out = xr.Dataset(data_vars, coords=coords)
    out.attrs.update(cf_attrs(case))
    out.attrs.update({
        "spotpde_version": __version__,
        "case": case.to_toml(),
        "sweep_keys": ", ".join(settings),
        "failed_members": "\n".join(f"{_label(settings, v)}: {msg}" for v, msg in failed),
        "title": f"spotpde sweep over {', '.join(settings)}",
    })
    return out


def _units_of(key: str, dims: int) -> dict[str, str]:
    """CF attributes of a swept case key (docs/cases.md): ``units = "1"`` and a long name
    giving the scale (:func:`spotpde.io.cf_units`)."""
    from .io import cf_units

    units = {"orifice.x": "d", "orifice.y": "d", "orifice.width": "d", "orifice.rate": "t-1",
             "spots.drift": "d t-1", "spots.b": "d", "spots.b_par": "d", "spots.t_end": "t",
             "kernel.size": "d", "kernel.volume": f"d{dims}", "tracer.t_end": "t"}
    return cf_units(units.get(key, "1"), f"swept case key {key}")


__all__ = ["parse_settings", "members", "sweep_case", "combine", "run_member"]
