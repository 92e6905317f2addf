"""The fit's forward model (private; see :mod:`spotpde.calibration`): free case keys in,
the model's observables at the data's points out.

:class:`Targets` flattens the measured observables into one data vector ``y`` with its
standard errors ``sigma`` and jackknife replicates; :class:`Forward` maps parameter
values to the model vector ``m`` at the same entries (a case with the values set, run
without its tracer, then :func:`spotpde.observables.predict` with ``like=`` the
measurement). :func:`jacobian` evaluates finite-difference columns, in parallel on Dask
when a client is given.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence

import numpy as np
import xarray as xr

from ..app.cases import Case, load_case
from ..app.pipeline import run
from ..errors import CaseError, NumericalError
from ..observables import FIT_DEFAULT, TARGETS, predict

__all__ = ["Targets", "Forward", "assign", "jacobian", "DEFAULT_BOUNDS", "FITTABLE",
           "bounds_for", "observables_for_fit"]

#: Bounds of common free keys when the caller gives none (lengths in d).
DEFAULT_BOUNDS = {
    "spots.b": (0.05, 20.0), "spots.b_par": (0.0, 20.0), "spots.drift": (0.01, 100.0),
    "kernel.size": (0.25, 20.0), "kernel.height": (1e-5, 1.0), "kernel.volume": (1e-5, 10.0),
    "kernel.aspect": (0.1, 10.0), "kernel.rule": (0.01, 1.0),
}
#: Observables a fit may use (``layers`` needs a tracer run and has no time blocks).
FITTABLE = ("velocity", "profiles", "width", "diffusion", "growth", "correlation", "pairs")


def _key_path(key: str) -> list:
    """``"spots.b.values[1]"`` -> ``["spots", "b", "values", 1]``: table keys, and list
    indices for an entry of a profile (``spots.b = { z = [...], values = [...] }``)."""
    out = []
    for part in key.split("."):
        name, bracket, rest = part.partition("[")
        out.append(name)
        while bracket:
            index, _, rest = rest.partition("]")
            out.append(int(index))
            bracket, rest = (rest[:1] == "[", rest[1:])
    return out


def assign(data: dict, key: str, value) -> None:
    """Set the dotted ``key`` of a case mapping (``"spots.b"``, ``"spots.b.values[1]"``)."""
    *path, last = _key_path(key)
    node = data
    for t in path:
        node = node[t]
    node[last] = value


def _lookup(data: Mapping, key: str):
    try:
        path = _key_path(key)
    except ValueError:
        return None
    node = data
    for t in path:
        if isinstance(t, int):
            if not isinstance(node, list) or not -len(node) <= t < len(node):
                return None
        elif not isinstance(node, Mapping) or t not in node:
            return None
        node = node[t]
    return node


def bounds_for(case: Case, free: Mapping) -> dict[str, tuple[float, float, float]]:
    """``{key: (start, lower, upper)}`` of the free keys, checked against the case.

    Raises:
        ValueError: ``free: ...`` naming a key that is not a numeric case key, bounds that
            are not increasing, or a start value outside its bounds.
    """
    if not isinstance(free, Mapping) or not free:
        raise ValueError("free: give the case keys to fit, e.g. {'spots.b': (0.5, 4.0)}")
    out = {}
    for key, bounds in free.items():
        value = _lookup(case.data, key)
        if key == "kernel.rule" and value == "kinematic":
            raise ValueError("free: kernel.rule is \"kinematic\" in the case (it follows the "
                             "kernel); set a number to fit it")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"free: {key!r} is not a numeric key of the case (its value is "
                             f"{value!r}); numeric keys include {', '.join(DEFAULT_BOUNDS)}, "
                             "orifice.rate, orifice.width, and entries of profiles such as "
                             "spots.b.values[1]")
        if bounds is None:
            bounds = DEFAULT_BOUNDS.get(key.split(".values[")[0], (value / 10.0, value * 10.0) if value > 0
                                        else (value - 1.0, value + 1.0))
        try:
            lo, hi = (float(b) for b in bounds)
        except (TypeError, ValueError):
            raise ValueError(f"free: {key}: bounds must be (lower, upper), got {bounds!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise ValueError(f"free: {key}: bounds must be finite with lower < upper, got {bounds!r}")
        if not lo <= value <= hi:
            raise ValueError(f"free: {key}: the case's value {value:g} (the fit's start) lies "
                             f"outside the bounds [{lo:g}, {hi:g}]")
        out[key] = (float(value), lo, hi)
    return out


class Targets:
    """The data vector of a fit: every target variable of the chosen observables.

    The velocity field enters on a grid thinned to the coarse-graining width (``stride``
    cells) and ``margin`` d away from the side walls and the floor.

    Attributes:
        y, sigma: values and standard errors (finite, ``sigma > 0``), flattened.
        replicates: ``(B, n)`` jackknife replicates of ``y``.
        slices: ``{(observable, variable): (slice, mask, shape)}`` to put a vector back.
    """

    def __init__(self, measurement: xr.Dataset, observables: Mapping[str, Sequence[str]],
                 stride: int = 1, margin: float = 2.0):
        self.measurement = measurement
        self.observables = tuple(observables)
        ys, ss, rs, self.slices = [], [], [], {}
        start = 0
        for name, variables in observables.items():
            for var in variables:
                v = measurement[var].values
                se = measurement[var + "_se"].values
                mask = np.isfinite(v) & np.isfinite(se) & (se > 0)
                if name == "velocity":
                    # thinned to the coarse-graining width; away from the side walls and
                    # the floor, whose layers the continuum's uniform-density mean
                    # velocity does not describe (docs/calibration.md, section 4)
                    thin = np.zeros_like(mask)
                    thin[::stride, ::stride] = True
                    x, z = measurement["x"].values, measurement["z"].values
                    inner = ((x >= x.min() + margin) & (x <= x.max() - margin))[None, :] \
                        & (z >= z.min() + margin)[:, None]
                    mask &= thin & inner
                n = int(mask.sum())
                ys.append(v[mask])
                ss.append(se[mask])
                rs.append(measurement[var + "_jk"].values[:, mask])
                self.slices[(name, var)] = (slice(start, start + n), mask, v.shape)
                start += n
        if start == 0:
            raise ValueError("observables: the measurement has no finite value with a standard "
                             "error to fit (too few tracks in the silo?)")
        self.y, self.sigma = np.concatenate(ys), np.concatenate(ss)
        self.replicates = np.concatenate(rs, axis=1)

    def vector(self, model: xr.Dataset) -> np.ndarray:
        """The model's values at the data's entries."""
        out = np.empty(self.y.size)
        for (name, var), (sl, mask, _) in self.slices.items():
            out[sl] = np.broadcast_to(model[var].values, mask.shape)[mask]
        return out

    def unflatten(self, vec: np.ndarray, name: str, var: str) -> np.ndarray:
        """A flattened vector's entries of one variable, on the variable's dims (NaN elsewhere)."""
        sl, mask, shape = self.slices[(name, var)]
        out = np.full(shape, np.nan)
        out[mask] = vec[sl]
        return out


class Forward:
    """Parameter values -> the model vector at the data's entries.

    Args:
        case: the base case (its tracer, if any, is dropped).
        keys: the free dotted keys, in parameter order.
        targets: the :class:`Targets`.
    """

    def __init__(self, case: Case, keys: Sequence[str], targets: Targets):
        self.data = copy.deepcopy(case.data)
        self.data.pop("tracer", None)
        self.data.pop("pair", None)
        self.keys = list(keys)
        self.targets = targets
        self.like = targets.measurement
        self.evaluations = 0

    def case(self, values: Sequence[float]) -> Case:
        data = copy.deepcopy(self.data)
        for key, value in zip(self.keys, values):
            assign(data, key, float(value))
        return load_case(data)

    def model(self, values: Sequence[float]) -> xr.Dataset:
        """The model's observables (a Dataset) at these values."""
        label = ", ".join(f"{k} = {v:.6g}" for k, v in zip(self.keys, values))
        try:
            case = self.case(values)
            result = run(case)
            return predict(result, case, like=self.like)
        except (CaseError, NumericalError, ValueError) as exc:
            raise NumericalError(f"the model failed at {label}: {str(exc).splitlines()[0]}") from None

    def __call__(self, values: Sequence[float]) -> np.ndarray:
        self.evaluations += 1
        m = self.targets.vector(self.model(values))
        if not np.all(np.isfinite(m)):
            bad = [f"{n}.{v}" for (n, v), (sl, _, _) in self.targets.slices.items()
                   if not np.all(np.isfinite(m[sl]))]
            raise NumericalError("the model has no value where the data do ("
                                 + ", ".join(bad) + ") at "
                                 + ", ".join(f"{k} = {v:.6g}" for k, v in zip(self.keys, values)))
        return m


def _column(forward: Forward, values, j: int, step: float) -> np.ndarray:
    shifted = np.array(values, float)
    shifted[j] += step
    return forward(shifted)


def jacobian(forward: Forward, values, steps, base: np.ndarray | None = None,
             client=None) -> np.ndarray:
    """Forward-difference Jacobian ``dm/dtheta`` (``n x p``), columns in parallel on a
    Dask ``client`` when given (each column one model evaluation)."""
    values = np.asarray(values, float)
    base = forward(values) if base is None else base
    if client is None:
        cols = [_column(forward, values, j, steps[j]) for j in range(values.size)]
    else:
        remote = client.scatter(forward, broadcast=True)
        futures = [client.submit(_column, remote, values, j, float(steps[j]), pure=False)
                   for j in range(values.size)]
        cols = client.gather(futures)
        forward.evaluations += values.size
    return np.column_stack([(c - base) / s for c, s in zip(cols, steps)])


def observables_for_fit(observables) -> dict[str, tuple[str, ...]]:
    """The fit's observables and their fitted variables, checked.

    Each entry is an observable (``"diffusion"``: all its target variables) or one
    variable of it (``"diffusion.b_p"``: the horizontal diffusion alone). ``layers``
    cannot be fitted (it needs a tracer run and has no time blocks).

    Returns:
        ``{observable: variables}`` in the order given.
    """
    names = FIT_DEFAULT if observables is None else (
        (observables,) if isinstance(observables, str) else tuple(observables))
    out: dict[str, tuple[str, ...]] = {}
    bad = []
    for entry in names:
        name, _, var = str(entry).partition(".")
        if name not in FITTABLE or (var and var not in TARGETS[name]):
            bad.append(entry)
            continue
        chosen = (var,) if var else TARGETS[name]
        out[name] = tuple(dict.fromkeys(out.get(name, ()) + chosen))
    if bad or not out:
        raise ValueError(f"observables: cannot fit {', '.join(map(repr, bad)) or 'nothing'}; "
                         f"valid: {', '.join(FITTABLE)}, or one variable of one "
                         "(e.g. 'diffusion.b_p'); layers: predict them with "
                         "spotpde.observables.predict")
    return out
