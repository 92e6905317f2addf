"""Resources of a run: available memory, the peak-memory estimate, tracer snapshots.

A case is refused before any work when the arrays of its run would not fit:
:func:`estimate_bytes` counts every grid array in float64 (8 bytes a cell) and the
complex zero-padded FFT arrays of the kernel convolution (16 bytes a cell), and every
allocation that grows with a key rather than with the grid: the padding of open walls
(``spots.b``), the passage quadrature (its wavenumber grid grows like ``spots.b /
kernel.size``, :func:`passage_bytes`), the ``[pair]`` solver (:func:`pair_bytes`) and
the random rate of ``orifice.noise`` (:func:`noise_bytes`). :func:`memory_problem`
compares ``estimate + BASELINE_BYTES`` with ``MEMORY_FRACTION * available_memory()``
and names the key to change. The public
names are re-exported by :mod:`spotpde.cases` (the validation there reads
``spotpde.cases.available_memory``, so replacing that one function replaces the
machine's memory).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import psutil

from ._schema import _ellipsoid_measure, kernel_dims

#: Fraction of the available memory a run may plan to use.
MEMORY_FRACTION = 0.6
#: Memory of the interpreter and libraries of a run (numpy, numba, xarray, matplotlib).
BASELINE_BYTES = 512 * 1024**2
#: Horizontal reach of a kernel in units of its ``size``, used only if the kernel cannot
#: be built (the estimate otherwise asks the kernel class: ``kernel_halfwidths``); the
#: smooth kernels are cut where ``w = 1e-14 w(0)``.
_REACH = {"uniform": 1.0, "gaussian": 8.0, "exponential": 32.3}
#: Peak bytes of the pair solver per cell of its annulus (the mesh, the generator and its
#: LU factors, the stored snapshots: 920-1020 measured at 2e3-5e4 cells).
PAIR_BYTES_PER_CELL = 1200.0


def available_memory() -> int:
    """Bytes of memory available to a new run: :func:`psutil.virtual_memory`
    ``available`` (on Linux ``MemAvailable`` of ``/proc/meminfo``).

    Returns:
        Available memory in bytes (4 GiB if the system does not say).
    """
    try:
        return int(psutil.virtual_memory().available)
    except Exception:  # noqa: BLE001 - a platform psutil cannot read
        return 4 * 1024**3


def auto_snapshots(data: Mapping) -> int:
    """``tracer.snapshots = "auto"``: one snapshot per time a spot needs to rise by the
    kernel's vertical size (``kernel.size / kernel.aspect / max v_s``) over
    ``[0, tracer.t_end]``, at least 21 and at most 401.

    Args:
        data: a validated case mapping with a tracer and transient spots.
    """
    s, k, t = data["spots"], data["kernel"], data["tracer"]
    drift = s["drift"]
    v = float(np.max(np.abs(drift["values"] if isinstance(drift, Mapping) else drift)))
    n = math.ceil(t["t_end"] * v * k["aspect"] / k["size"]) + 1
    return int(min(max(n, 21), 401))


def estimate_bytes(data: Mapping, frames_in_memory: bool = True) -> int:
    """Estimate the memory a run of a validated case holds at its peak.

    Counts every grid array of the run (spot density, kinematic speed, drift and
    diffusivity fields, solver scratch), the zero-padded FFT arrays of the kernel
    convolution, the sampled kernel stencil, and the tracer frames.

    Args:
        data: a mapping that passed the per-key checks (``validate`` internals).
        frames_in_memory: count the tracer frames (``False`` when they are streamed to
            the result file one at a time).

    Returns:
        Estimated peak bytes (a float-safe int).
    """
    return _estimate(data, frames_in_memory)


def kernel_halfwidths(data: Mapping) -> tuple[int, int]:
    """Half-widths ``(vertical, horizontal)`` in cells of the sampled kernel stencil of a
    validated case, from the kernel class's own reach (``Kernel.halfwidths``); the
    stencil has ``2 m + 1`` cells along each axis (e.g. 65 for a Gaussian of sigma 1 at
    h = 0.25, 259 for an exponential kernel of decay length 1).
    """
    m = _kernel(data).halfwidths(data["domain"]["spacing"])
    return m[0], m[-1]


def _grid_cells(d: Mapping) -> tuple[float, float, float]:
    """Cells ``(nz, ny, nx)`` of the domain (``ny = nx`` when absent)."""
    h = d["spacing"]
    nx = (d["x"][1] - d["x"][0]) / h
    ny = (d["y"][1] - d["y"][0]) / h if "y" in d else nx
    return (d["z"][1] - d["z"][0]) / h, ny, nx


def _largest(value) -> float:
    """The largest value of a coefficient: a number, or a profile's ``values``."""
    return float(max(value["values"]) if isinstance(value, Mapping) else value)


def _kernel(data: Mapping, **changes):
    """The case's kernel (``changes`` replace ``size``, ``aspect``)."""
    from ..fields import kernels

    d, k = data["domain"], {**data["kernel"], **changes}
    dims = kernel_dims(d)
    volume = (k["height"] * _ellipsoid_measure(k["size"], k["aspect"], dims)
              if "height" in k else k["volume"])
    return kernels.from_spec(k["shape"], k["size"], volume, k["aspect"], dims)


def passage_bytes(data: Mapping, **changes) -> float:
    """Peak bytes of the passage quadrature of a validated case (0 without one): with
    ``kernel.diffusivity = "passage"`` and the spot model, at the largest ``spots.b`` and
    ``spots.b_par`` (``changes``: ``b``, ``b_par``, ``size``, ``aspect`` replaced, to find
    the key to blame)."""
    t = data.get("tracer")
    if data["kernel"]["diffusivity"] != "passage" or (t is not None and t["model"] == "void"):
        return 0.0
    from ..fields import _passage

    s = data["spots"]
    b = changes.pop("b", _largest(s["b"]))
    b_par = changes.pop("b_par", _largest(s["b_par"]))
    try:
        return _passage.quadrature_bytes(_kernel(data, **changes), b, b_par)
    except (ValueError, ArithmeticError):   # refused later, by cases._check_kernel
        return 0.0


def pair_bytes(data: Mapping) -> float:
    """Peak bytes of the ``[pair]`` table's solver (0 without one): the annulus
    ``contact <= r < separation`` in cells of ``pair.spacing`` (:data:`PAIR_BYTES_PER_CELL`
    each), its ``pair.frames`` over the square around it, and the pair quadrature
    (``kernel.diffusivity = "passage"``)."""
    p = data.get("pair")
    if p is None:
        return 0.0
    c, s = p["contact"], p["separation"]
    h = p.get("spacing") or c / 16
    box = 4.0 * (s / h + 1.0) ** 2
    total = PAIR_BYTES_PER_CELL * math.pi * (s * s - c * c) / (h * h) + 8.0 * p["frames"] * box
    if data["kernel"]["diffusivity"] == "passage":
        from ..fields import _passage, _passage_grids
        from ..fields.kernels import Uniform

        t = data.get("tracer")
        kern = (Uniform(radius=0.5, height=1.0) if t is not None and t["model"] == "void"
                else _kernel(data))
        b, b_par = _largest(data["spots"]["b"]), _largest(data["spots"]["b_par"])
        # the tensor over the separations, then the one-particle tensor (one at a time)
        total += max(_passage_grids.pair_bytes(kern, b, b_par, s),
                     _passage.quadrature_bytes(kern, b, b_par))
    return total


def noise_bytes(data: Mapping) -> float:
    """Bytes of ``orifice.noise``'s random process: 16 nodes per ``correlation_time`` up to
    the last time the rate is asked for, held twice while it grows."""
    noise = data["orifice"].get("noise")
    if not noise:
        return 0.0
    t = data.get("tracer")
    last = max(data["spots"]["t_end"], t["t_end"] if t is not None else 0.0)
    return 16.0 * (16.0 * last / noise["correlation_time"] + 2.0)


def _estimate(data: Mapping, frames_in_memory: bool = True, *, pad: bool = True,
              stencil: bool = True, frames: bool = True, passage: bool = True,
              pair: bool = True, noise: bool = True) -> int:
    """:func:`estimate_bytes`; ``pad``/``stencil``/``frames`` False leave out the open-wall
    padding, the kernel stencil (a 1-cell stencil) or the tracer frames (one frame),
    ``passage``/``pair``/``noise`` the passage quadrature, the pair solver or the random
    rate, to find which key makes a case too large."""
    d, k = data["domain"], data["kernel"]
    dims, h = d["dims"], d["spacing"]
    nz, ny, nx = _grid_cells(d)
    if d["walls"] == "open" and pad:   # the spot density is solved on a padded, wider grid
        b = data["spots"]["b"]
        b = max(b["values"]) if isinstance(b, Mapping) else b
        widen = 2 * math.ceil(6.0 * math.sqrt(b * (d["z"][1] - d["z"][0])) / h)
        nx, ny = nx + widen, ny + widen
    cells = nz * nx * (ny if dims == 3 else 1)
    if not stencil:
        sx = sz = 1
    else:
        try:
            mz, mh = kernel_halfwidths(data)
            sx, sz = 2 * mh + 1, 2 * mz + 1
        except (ValueError, ArithmeticError):   # refused later, by cases._check_kernel
            reach_h = _REACH[k["shape"]] * k["size"]
            sx = 2 * math.ceil(reach_h / h) + 1
            sz = 2 * math.ceil(reach_h / k["aspect"] / h) + 1
    stencil = sz * sx ** (dims - 1)
    padded = (nz + sz) * (nx + sx) * ((ny + sx) if dims == 3 else 1)
    if d.get("coordinates") == "axisymmetric":
        # ring-integrated kernel weights: for every output radius a band of source radii
        # times the vertical stencil, for w and w**2, scalar and radial (cos) parts
        stencil = 4 * nx * sx * sz
    n_fields = 1 + 1 + (5 if dims == 2 else 9)     # rho_s, v_kin, u_*, D_**
    scratch = 12                                    # spot-density and coefficient work arrays
    tracer = data.get("tracer")
    n_tracer = 0
    if tracer is not None:
        # frames (one in flight when streamed), P_height, scheme fluxes and stages
        n_tracer = (tracer["frames"] if frames_in_memory and frames else 1) + 1 + 16
        if tracer["t_end"] == math.inf:
            # steady solve: no frames; the sparse matrix and its LU factors (fill
            # measured: ~50 entries of 12 bytes per cell on a 2D grid of 9e4 cells; 3D
            # fill grows like cells**(1/3))
            n_tracer = 4 + (80 if dims == 2 else 10 * cells ** (1 / 3))
        if data["spots"]["mode"] == "transient":
            # spot-density snapshots (one more in flight), the fields of three of them,
            # and the tracer's cache of operators (face velocities, diffusion splitting,
            # the interpolated fields) for a few stage times
            n = tracer["snapshots"]
            n_tracer += ((auto_snapshots(data) if n == "auto" else n) + 1 + 3 * n_fields
                         + 5 * (n_fields + 2 * dims + 4))
    if data["spots"].get("rho_max") is not None:
        # interacting spots: space-time frames of rho_s and free_volume, solver stages
        n_tracer += 2 * (data["spots"].get("frames") or 101) + 8
    arrays = 8.0 * cells * (n_fields + scratch + n_tracer)
    total = arrays + 16.0 * padded * 6 + 8.0 * stencil * 2
    # the quadratures run with the grid arrays alive, not with the FFT arrays
    total = max(total, arrays + (passage_bytes(data) if passage else 0.0),
                arrays + (pair_bytes(data) if pair else 0.0))
    total += noise_bytes(data) if noise else 0.0
    return int(min(total, 1e30))


def memory_problem(data: Mapping, frames_in_memory: bool, have: int
                   ) -> tuple[str, str, object] | None:
    """Whether a run of ``data`` fits in memory, and if not, which key to blame.

    The run fits when ``estimate_bytes(data) + BASELINE_BYTES <= MEMORY_FRACTION * have``.
    Otherwise the key is ``domain.spacing`` (the grid itself is too large), or, when the
    bare grid fits, what is added to it: ``spots.b`` (the padding of open walls,
    ``6 sqrt(b H)`` on each side), the key that most enlarges the passage quadrature
    (``spots.b``, ``spots.b_par``, ``kernel.size`` or ``kernel.aspect``: its grid grows
    like ``b / size``), ``pair.spacing`` (the pair solver's annulus),
    ``orifice.noise.correlation_time`` (the random rate's nodes), ``kernel.size`` /
    ``kernel.aspect`` (the kernel stencil widening every FFT array) or ``tracer.frames``
    (frames held in memory).

    Args:
        data: a validated case mapping (tables and cross-key checks passed).
        frames_in_memory: count the tracer frames (``False`` when streamed).
        have: bytes of memory available (``available_memory()``).

    Returns:
        ``None`` if the run fits, else ``(dotted key, message, offending value)``.
    """
    need = estimate_bytes(data, frames_in_memory) + BASELINE_BYTES
    if need <= MEMORY_FRACTION * have:
        return None
    d = data["domain"]
    nz, ny, nx = _grid_cells(d)
    cells = " x ".join(f"{n:,.0f}" for n in ([nz] + ([ny] if d["dims"] == 3 else []) + [nx]))
    snaps = data.get("tracer") is not None and data["spots"]["mode"] == "transient"
    limit = MEMORY_FRACTION * have - BASELINE_BYTES
    spare = f"more than the {_gb(MEMORY_FRACTION * have)} this machine can spare"
    parts = dict(pad=False, stencil=False, frames=False, passage=False, pair=False,
                 noise=False)

    def over(**part) -> bool:     # the bare grid with one part added does not fit
        return _estimate(data, frames_in_memory, **{**parts, **part}) > limit

    if over():
        return "domain.spacing", (
            f"the grid of {cells} cells (with kernel stencil and tracer frames) needs "
            f"about {_gb(need)}, {spare}; use a larger spacing, a smaller domain or "
            f"fewer tracer.frames" + (" or tracer.snapshots" if snaps else "")), d["spacing"]
    k, s = data["kernel"], data["spots"]
    if d["walls"] == "open" and over(pad=True):
        return "spots.b", (
            f"the grid of {cells} cells widened for open walls needs about {_gb(need)}, "
            f'{spare}; with domain.walls = "open" the spot density is solved on a grid '
            "widened by 6 sqrt(b H) on each side; use a smaller b or reflecting walls"
            ), s["b"]
    if over(passage=True):
        key, value = _passage_key(data)
        return key, (
            f"the passage diffusivity's quadrature needs about {_gb(passage_bytes(data))}"
            f", {spare}; its wavenumber grid grows like spots.b / kernel.size (here "
            f"{_largest(s['b']):.3g} / {k['size']:.3g}); use a smaller {key} or "
            f'kernel.diffusivity = "mean-field"'), value
    if over(pair=True):
        p = data["pair"]
        return "pair.spacing", (
            f"the pair solver needs about {_gb(pair_bytes(data))}, {spare}: "
            f"{p['separation'] / (p.get('spacing') or p['contact'] / 16):.3g} cells across "
            "pair.separation; use a larger pair.spacing or a smaller pair.separation"
            ), p.get("spacing") or p["contact"] / 16
    if over(noise=True):
        n = data["orifice"]["noise"]
        return "orifice.noise.correlation_time", (
            f"the random rate needs about {_gb(noise_bytes(data))} (16 nodes "
            f"per correlation_time up to t_end), {spare}; use a longer "
            "correlation_time or a shorter t_end"), n["correlation_time"]
    if over(stencil=True):
        mz, mh = kernel_halfwidths(data)
        key, value = (("kernel.aspect", k["aspect"]) if k["aspect"] < 1 and mz > mh else
                      ("kernel.size", k["size"]))
        return key, (
            f"the grid of {cells} cells with the kernel stencil of {2 * mz + 1:.3g} x "
            f"{2 * mh + 1:.3g} cells needs about {_gb(need)}, {spare}; the stencil widens "
            "every FFT array; use a smaller kernel.size, an aspect nearer 1 or a larger "
            "domain.spacing"), value
    if data.get("tracer") is not None and frames_in_memory and over(frames=True):
        return "tracer.frames", (
            f"the grid of {cells} cells with its tracer frames needs about {_gb(need)}, "
            f"{spare}; use fewer frames, or stream them to the result file (spotpde run, "
            "or spotpde.run(case, path=...))"), data["tracer"]["frames"]
    return "domain.spacing", (
        f"the grid of {cells} cells (with kernel stencil and tracer frames) needs about "
        f"{_gb(need)}, {spare}; use a larger spacing, a smaller domain or fewer "
        "tracer.frames" + (" or tracer.snapshots" if snaps else "")), d["spacing"]


def _passage_key(data: Mapping) -> tuple[str, object]:
    """The key whose default value would most shrink the passage quadrature."""
    s, k = data["spots"], data["kernel"]
    options = [("spots.b", s["b"], {"b": 1.3}), ("spots.b_par", s["b_par"], {"b_par": 0.0}),
               ("kernel.size", k["size"], {"size": max(k["size"], 1.0)}),
               ("kernel.aspect", k["aspect"], {"aspect": 1.0})]
    key, value, _ = min(options, key=lambda o: passage_bytes(data, **o[2]))
    return key, value


def _gb(n: float) -> str:
    """Bytes ``n`` as GB (1024**3 bytes) to 3 digits, for the memory message."""
    return f"{n / 1024**3:.3g} GB" if n < 1e25 else "an impossible amount of memory"
