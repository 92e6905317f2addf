"""Cross-key consistency of a case whose tables passed their per-key checks.

One function, :func:`check_consistency`, records every problem between keys on the
validator of :mod:`._schema`, each naming the key to change:

* the grid: ``domain.z`` starts at the floor ``z = 0``; ``domain.spacing`` h divides
  each extent into at least 4 whole cells (at most 1e9); ``domain.y`` only in 3D,
  also a whole number of at least 4 cells;
* the orifice lies on the floor ``domain.x`` (the whole slot ``[x - width/2,
  x + width/2]`` for a uniform profile; ``orifice.y`` only in 3D, on the y extent
  ``domain.y`` or, without it, ``domain.x``); ``orifice.shape`` only in 3D, and a
  slot (across the whole depth) has no ``orifice.y``;
  a Gaussian profile needs ``width > 0``; a uniform slot is a point (0) or at least h;
* time-dependent inputs (a rate table, ``orifice.noise``, ``spots.rho_max``) need
  ``spots.mode = "transient"`` with ``spots.t_end > 0``, a steady run has ``t_end = 0``;
* a uniform kernel's influence ``w = volume / (spot area or volume) <= 1``;
  ``kernel.height`` only for the uniform shape;
* the tracer: ``t_end = inf`` only for steady spots, ``snapshots`` only for transient
  ones, a start blob inside the domain and at least h wide, layer bands of at least 2 h
  and less than twice the height;
* ``[pair]``: a 2D domain, the point inside it and inside a hopper's walls (in the
  material), in a cylinder a start at a horizontal distance ``pair.start.x >= 0``;
* axisymmetric coordinates: ``dims = 2``, ``domain.x = [0, a]`` (the radius), the
  orifice on the axis (``orifice.x = 0``);
* a hopper (``domain.hopper_angle``): a 2D or axisymmetric domain, a uniform orifice
  (its edges are where the walls start), and walls that leave the floor open (a
  vertical hopper needs an orifice of width > 0).

Lengths in particle diameters d, times in the case's time unit.
"""

from __future__ import annotations

import math

from ..parameters import HEIGHT_RANGE, VOLUME_ROUNDING
from ._schema import _ellipsoid_measure, _show, _Validator, kernel_dims


def check_consistency(v: _Validator, data: dict) -> None:
    """Record on ``v`` every inconsistency between the keys of ``data``.

    Args:
        v: the validator whose ``bad`` collects the problems.
        data: the mapping returned by ``v.tables`` (every table passed its own checks).
    """
    d = data["domain"]
    h = d["spacing"]
    y_extent = _check_depth(v, d)
    if d["z"][0] != 0.0:
        v.bad("domain.z", "must start at 0 (the orifice is the floor z = 0)", d["z"])
    for name, (a, b) in (("x", d["x"]), ("z", d["z"])):
        extent = f"the domain.{name} extent {_show(b - a)}"
        _check_cells(v, "domain.spacing", h, b - a, h, {
            "many": f"is far too small for {extent} ({{n:.3g}} cells)",
            "few": f"must give at least 4 cells across {extent}",
            "partial": f"must divide {extent} into whole cells"})
    _check_orifice(v, d, data["orifice"], y_extent)
    _check_spots(v, data["orifice"], data["spots"])
    _check_kernel_keys(v, d, data["kernel"])
    _check_tracer(v, d, data["spots"], data.get("tracer"), y_extent)
    _check_geometry(v, data)
    _check_pair(v, data, data.get("pair"))


def _check_orifice(v: _Validator, d: dict, o: dict, y_extent) -> None:
    """The orifice on the floor (``orifice.x``, ``.y``, ``.shape``, ``.width``)."""
    dims, h = d["dims"], d["spacing"]
    x0, x1 = d["x"]
    y0, y1 = y_extent
    ywhere = "domain.y" if "y" in d else "domain.x"
    half = 0.5 * o["width"] if o["profile"] == "uniform" else 0.0
    # axisymmetric: the orifice is the disk r <= width/2 around the axis r = x0 = 0
    below = 0.0 if d.get("coordinates") == "axisymmetric" else half
    if not (x0 <= o["x"] - below and o["x"] + half <= x1):
        what = "the slot [x - width/2, x + width/2]" if half else "the centre"
        v.bad("orifice.x", f"{what} must lie on the floor "
              f"domain.x = [{_show(x0)}, {_show(x1)}] (orifice.width = "
              f"{_show(o['width'])})", o["x"])
    if "shape" in o and dims != 3:
        v.bad("orifice.shape", "is only used when domain.dims = 3 (a 2D orifice is a "
              "slot); remove it", o["shape"])
    if "y" in o:
        if dims != 3:
            v.bad("orifice.y", "is only used when domain.dims = 3; remove it",
                  o["y"])
        elif o.get("shape") == "slot":
            v.bad("orifice.y", 'is not used by orifice.shape = "slot" (the slot spans '
                  "the whole depth in y); remove it", o["y"])
        elif not (y0 <= o["y"] - half and o["y"] + half <= y1):
            v.bad("orifice.y", f"the orifice must lie on the floor, y in "
                  f"[{_show(y0)}, {_show(y1)}] (the {ywhere} extent)", o["y"])
    if o["profile"] == "gaussian" and o["width"] == 0.0:
        v.bad("orifice.width", 'must be > 0 for profile = "gaussian" '
              '(use profile = "uniform" with width = 0 for a point source)', 0.0)
    if 0.0 < o["width"] < h and o["profile"] == "uniform":
        v.bad("orifice.width", f"must be 0 (a point source) or at least one cell "
              f"(domain.spacing = {_show(h)})", o["width"])


def _check_spots(v: _Validator, o: dict, s: dict) -> None:
    """The spots' mode against the rate, the end time and the interacting-spot keys."""
    if isinstance(o["rate"], dict) and s["mode"] != "transient":
        v.bad("orifice.rate", 'a table of rates needs spots.mode = "transient"; '
              "give a number for a steady run", o["rate"])
    if s["mode"] == "transient" and s["t_end"] <= 0:
        v.bad("spots.t_end", 'must be > 0 when spots.mode = "transient"', s["t_end"])
    if "rho_max" in s and s["mode"] != "transient":
        v.bad("spots.rho_max", 'interacting spots need spots.mode = "transient" '
              "(no steady solver; run to a late spots.t_end)", s["rho_max"])
    for key in ("flux", "diffusion_scaling", "frames"):
        if key in s and "rho_max" not in s:
            v.bad(f"spots.{key}", "is only used with spots.rho_max (interacting "
                  "spots); set spots.rho_max or remove it", s[key])
    if o.get("noise") is not None and s["mode"] != "transient":
        v.bad("orifice.noise", 'a random rate needs spots.mode = "transient"; '
              "remove it for a steady run", o["noise"])
    if s["mode"] == "steady" and s["t_end"] != 0:
        v.bad("spots.t_end", 'is only used when spots.mode = "transient"; '
              'set it to 0 or remove it', s["t_end"])


def _check_kernel_keys(v: _Validator, d: dict, k: dict) -> None:
    """A uniform kernel's volume or height against its influence ``w <= 1``."""
    dims = d["dims"]
    if k["shape"] == "uniform" and "volume" in k:
        w = k["volume"] / _ellipsoid_measure(k["size"], k["aspect"], kernel_dims(d))
        if w > HEIGHT_RANGE[1] * (1 + VOLUME_ROUNDING):   # w = 1 (the void model's spot),
            # volume rounded to 4 digits, is fine
            v.bad("kernel.volume", f'with shape = "uniform" and kernel.size = '
                  f'{_show(k["size"])} implies the influence w = volume / spot '
                  f"{'area' if dims == 2 else 'volume'} = {w:.3g} > 1 (a spot moves "
                  "each particle by at most its own step); use a smaller volume or "
                  "a larger size", k["volume"])
    if "height" in k:
        if k["shape"] != "uniform":
            v.bad("kernel.height", 'is only for shape = "uniform" (the influence w '
                  'inside the disk/sphere); give kernel.volume instead', k["height"])


def _check_tracer(v: _Validator, d: dict, s: dict, t: dict | None, y_extent) -> None:
    """The tracer's end time, stepping, snapshots, start and layers against the domain
    and the spots."""
    dims, h = d["dims"], d["spacing"]
    x0, x1 = d["x"]
    z0, z1 = d["z"]
    y0, y1 = y_extent
    ywhere = "domain.y" if "y" in d else "domain.x"
    if t is not None and t.get("t_end") == math.inf and s["mode"] == "transient":
        v.bad("tracer.t_end", 'inf (the steady propagator) needs spots.mode = '
              '"steady"; give a finite time for a tracer in a starting flow', math.inf)
    long_run = t is not None and t.get("stepping") in ("multirate", "imex", "implicit")
    if long_run and s["mode"] == "transient":
        v.bad("tracer.stepping", f'"{t["stepping"]}" needs steady fields (spots.mode = '
              '"steady"); use "explicit" or "auto" in a starting flow', t["stepping"])
    if t is not None and "split" in t and t.get("stepping") not in ("multirate", "imex", "auto"):
        v.bad("tracer.split", 'is only used with tracer.stepping = "multirate", "imex" or '
              '"auto"; remove it', t["split"])
    if t is not None and t.get("snapshots", "auto") != "auto" and s["mode"] != "transient":
        v.bad("tracer.snapshots", 'is only used when spots.mode = "transient"; '
              'remove it or set it to "auto"', t["snapshots"])
    if t is not None and "start" in t:
        st = t["start"]
        if not x0 <= st["x"] <= x1:
            v.bad("tracer.start.x", f"must lie in domain.x = [{_show(x0)}, "
                  f"{_show(x1)}]", st["x"])
        if not z0 < st["z"] < z1:
            v.bad("tracer.start.z", f"must lie inside domain.z = ({_show(z0)}, "
                  f"{_show(z1)})", st["z"])
        if "y" in st:
            if dims != 3:
                v.bad("tracer.start.y", "is only used when domain.dims = 3; remove it",
                      st["y"])
            elif not y0 <= st["y"] <= y1:
                v.bad("tracer.start.y", f"must lie in [{_show(y0)}, {_show(y1)}] "
                      f"(the {ywhere} extent)", st["y"])
        if st["width"] < h:
            v.bad("tracer.start.width", f"must be at least domain.spacing = "
                  f"{_show(h)} so the blob is resolved", st["width"])
    if t is not None and "layers" in t:
        sp = t["layers"]["spacing"]
        if sp < 2 * h:
            v.bad("tracer.layers.spacing", f"must be at least 2 * domain.spacing = "
                  f"{_show(2 * h)} so every band covers a cell", sp)
        elif sp >= 2 * (z1 - z0):
            v.bad("tracer.layers.spacing", f"must be < 2 * the domain height "
                  f"{_show(z1 - z0)} to leave a band and a gap in the silo", sp)


def _check_pair(v: _Validator, data: dict, p: dict | None) -> None:
    """The ``[pair]`` point inside a 2D domain, and in the material."""
    d = data["domain"]
    dims = d["dims"]
    x0, x1 = d["x"]
    z0, z1 = d["z"]
    if p is not None:
        if dims != 2:
            v.bad("pair", "needs domain.dims = 2 (the pair solver is 2D)", dims)
        if p.get("x") is not None and not x0 <= p["x"] <= x1:
            v.bad("pair.x", f"must lie in domain.x = [{_show(x0)}, {_show(x1)}]",
                  p["x"])
        if p.get("z") is not None and not z0 < p["z"] < z1:
            v.bad("pair.z", f"must lie inside domain.z = ({_show(z0)}, {_show(z1)})",
                  p["z"])
        _check_pair_in_material(v, data, p)


def _check_depth(v: _Validator, d: dict) -> tuple[float, float]:
    """``domain.y`` (3D only; a whole number of at least 4 cells); returns the y extent
    (``domain.y``, else ``domain.x``)."""
    if "y" not in d:
        return tuple(d["x"])
    y, h = d["y"], d["spacing"]
    if d["dims"] != 3:
        v.bad("domain.y", "is only used when domain.dims = 3 (the depth of a 3D silo); "
              "remove it", y)
        return tuple(d["x"])
    cells, extent = f"cells of domain.spacing = {_show(h)}", _show(y[1] - y[0])
    _check_cells(v, "domain.y", y, y[1] - y[0], h, {
        "many": f"spans far too many {cells} ({{n:.3g}})",
        "few": f"must be at least 4 {cells} deep, got an extent of {extent}",
        "partial": f"must be a whole number of {cells}, got an extent of {extent} "
                   "({n:.6g} cells)"})
    return tuple(y)


def _check_cells(v: _Validator, key: str, value, extent: float, h: float,
                 messages: dict[str, str]) -> None:
    """Record on ``v`` (naming ``key``) what is wrong with the number of cells of spacing
    ``h`` across ``extent``: ``messages["many"]`` (not finite or over 1e9), ``["few"]``
    (under 4) or ``["partial"]`` (not whole), each formatted with ``n`` the cells."""
    n = extent / h
    if not math.isfinite(n) or n > 1e9:
        problem = "many"
    elif round(n) < 4:
        problem = "few"
    elif abs(n - round(n)) > 1e-6 * max(1.0, n):
        problem = "partial"
    else:
        return
    v.bad(key, messages[problem].format(n=n), value)


def _check_geometry(v: _Validator, data: dict) -> None:
    """``domain.coordinates`` and ``domain.hopper_angle`` against the other keys."""
    d, o = data["domain"], data["orifice"]
    axisymmetric = d.get("coordinates") == "axisymmetric"
    if axisymmetric:
        if d["dims"] != 2:
            v.bad("domain.dims", 'must be 2 with domain.coordinates = "axisymmetric" '
                  "(the (r, z) half-plane of a cylinder)", d["dims"])
        if d["x"][0] != 0.0:
            v.bad("domain.x", 'must be [0, a] with domain.coordinates = "axisymmetric" '
                  "(x is the radius; the axis is r = 0)", d["x"])
        if o["x"] != 0.0:
            v.bad("orifice.x", 'must be 0 with domain.coordinates = "axisymmetric" '
                  "(the orifice is centred on the axis; orifice.width is its diameter)",
                  o["x"])
    if "hopper_angle" not in d:
        return
    angle = d["hopper_angle"]
    if d["dims"] != 2:
        v.bad("domain.hopper_angle", "needs domain.dims = 2 (a wedge in (x, z), or a "
              'cone with domain.coordinates = "axisymmetric")', angle)
    if o["profile"] != "uniform":
        v.bad("domain.hopper_angle", 'needs orifice.profile = "uniform" (the hopper '
              "walls start at the orifice's edges)", angle)
    if angle == 0.0 and o["width"] == 0.0:
        v.bad("domain.hopper_angle", "0 with a point orifice (orifice.width = 0) closes "
              "the domain: give orifice.width > 0 or an angle > 0", angle)
    elif o["width"] < 2 * d["spacing"]:
        v.bad("orifice.width", "must be at least 2 * domain.spacing = "
              f"{_show(2 * d['spacing'])} with a hopper, so that the hopper's floor has "
              "open cells (the solvers resolve its walls cell by cell)", o["width"])


def _check_pair_in_material(v: _Validator, data: dict, p: dict) -> None:
    """``[pair]`` in the material: inside a hopper's walls at ``pair.z``; in a cylinder
    ``pair.start.x`` is the pair's horizontal distance (``>= 0``)."""
    d, o = data["domain"], data["orifice"]
    start = p.get("start")
    if (d.get("coordinates") == "axisymmetric" and isinstance(start, dict)
            and start.get("x", 0.0) < 0):
        v.bad("pair.start.x", "must be >= 0 in a cylinder (the horizontal distance of the "
              "pair's separation; the pair is 3D)", start["x"])
    if "hopper_angle" not in d or p.get("x") is None or p.get("z") is None:
        return
    half = 0.5 * o["width"] + (p["z"] - d["z"][0]) * math.tan(math.radians(d["hopper_angle"]))
    if abs(p["x"] - o["x"]) > half:
        v.bad("pair.x", f"lies outside the material: at pair.z = {p['z']:g} the hopper's "
              f"walls are {half:.3g} d from orifice.x = {o['x']:g}; move the point inside "
              "them", p["x"])
