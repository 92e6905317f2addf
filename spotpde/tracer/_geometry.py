"""The tracer on axisymmetric grids and in hoppers (private; used by :mod:`._solve`, :mod:`._steady`).

**Axisymmetric grids** (``grid.axisymmetric``, array order ``(z, r)``). For an
axisymmetric density ``P(r, z)`` (1/d**3) in axisymmetric fields with cylindrical
components ``u_r, u_z, D_rr, D_rz, D_zz, D_tt`` (``D_tt`` the azimuthal diffusivity),
the 3D Ito equation ``dP/dt + div J = 0``, ``J = u P - div(D P)``, has

    J_r = u_r P - d_r(D_rr P) - (D_rr - D_tt) P / r - d_z(D_rz P)
    J_z = u_z P - d_r(D_rz P) - D_rz P / r - d_z(D_zz P)

(the divergence of a symmetric axisymmetric tensor in cylindrical coordinates). With
``Q = 2 pi r P`` (probability per unit r per unit z) and ``r`` times the equation,
``2 pi r d_r(f P) = d_r(f Q) - f Q / r``, it becomes the 2D Cartesian Ito equation

    dQ/dt + d_r((u_r + D_tt/r) Q - d_r(D_rr Q) - d_z(D_rz Q))
          + d_z(u_z Q - d_r(D_rz Q) - d_z(D_zz Q)) = 0

exactly, with one extra radial drift ``D_tt / r`` (here ``D_tt = D_rr``, the spot model's
horizontally isotropic spots). The tracer therefore steps ``Q`` on the Cartesian twin of
the grid (same cells; ``mass = sum Q h**2 = sum P * grid.cell_volumes``) with the
Cartesian advection kernel, and this module supplies the geometry:

* the metric drift is split as ``D_tt / r = A_r / r + |D_rz| / r`` with
  ``A_r = D_rr - |D_rz|`` the axial radial exchange coefficient of the positive tensor
  splitting (:mod:`._diffusion`). The first part gets a *central* face value and is
  merged into the radial exchange across the face at ``r_f``:

      E = (r_f / h**2) (A_r,a Q_a / r_a - A_r,b Q_b / r_b)
        = 2 pi r_f (A_r,a P_a - A_r,b P_b) / h**2

  i.e. the finite-volume flux of ``-d_r(A_r P)`` through the face area ``2 pi r_f h``
  (for ``D_tt = D_rr`` the hoop term cancels from ``J_r``). Its coefficients
  ``A r_f / r >= 0`` keep the exchange positive, it keeps the equilibrium ``P = c / D``
  of a drift-free isotropic ``D`` steady (the drift upwinded at the axis would put the
  axis cell 18 % too high: the donor value ``Q_0`` where ``Q ~ r``), and a
  cell's loss rate ``(A / h**2)(r_{i+1/2} + r_{i-1/2}) / r_i = 2 A / h**2`` is the
  Cartesian one, so the time-step bound is unchanged. The second part (zero for the
  spot model's diagonal tensor) is an outward drift upwinded with ``u_r``;
* the axis ``r = 0`` is a wall (a face of zero area: no flux of any kind); the wall at
  ``r = a`` is reflecting or open (advective outflow of the boundary cell's ``P``
  through the area ``2 pi a h``: face velocity ``u_r a / r_c`` on ``Q``).

**Hoppers** (``grid.hopper``, staircase ``grid.active``). Every face between an active
and an inactive cell is a wall: face velocity 0 and no exchange across it; a diagonal
(cross-term ``D_xz``) exchange is kept only when all four cells around its corner are
active, so none reaches across a wall face. Inactive cells keep ``P = 0``; positivity
and conservation hold as on a box (pairwise exchanges and face fluxes only).

Diffusion: the exchanges above (built by :meth:`_Geometry.diffusion`) are added after the
advection kernel by the face-coefficient kernel :func:`._geometry_kernels.exchange_2d`;
the steady solver and implicit diffusion use the same exchanges as a sparse matrix.
Derivation and measurements: docs/tracer.md, docs/steady.md.
"""

from __future__ import annotations

import functools

import numpy as np
import scipy.sparse as sp

from . import _advection, _diffusion
from . import _fp_kernels as K
from . import _geometry_kernels as GK
from ._operator import _check_fields, _Operator
from ..grid import Grid

#: Cylindrical field names and the Cartesian names of the twin grid.
_RENAME = {"u_r": "u_x", "u_z": "u_z", "D_rr": "D_xx", "D_rz": "D_xz", "D_zz": "D_zz"}


def special(grid: Grid) -> bool:
    """True when the grid needs this module: its cells are rings or a staircase
    (``grid.geometry.uniform_cells`` is False)."""
    return not grid.geometry.uniform_cells


class _Geometry:
    """Static geometry of one grid: the Cartesian twin, the weight ``Q / P``, wall masks."""

    def __init__(self, grid: Grid):
        self.grid = grid
        self.twin = Grid(2, grid.x_range, grid.z_range, grid.spacing, walls=grid.walls)
        self.h = grid.spacing
        self.shape = nz, nx = grid.shape
        geometry = grid.geometry
        #: ring cells: the metric drift, the face areas r_f, physical names renamed
        self.axi = geometry.curved
        #: ``Q = weight * P``: ``2 pi r`` (axisymmetric) or 1, shape (1, nx)
        self.weight = geometry.density_weight
        act = np.asarray(grid.active, dtype=bool)
        self.active = act
        #: a staircase: walls between active and inactive cells
        self.hopper = geometry.masked
        # open faces: x faces (nz, nx+1), z faces (nz+1, nx); boundary faces follow
        # their one cell
        open_x, open_z = geometry.open_faces()
        xm = np.zeros((nz, nx + 1), dtype=bool)
        xm[:, 1:nx] = open_x
        xm[:, 0] = act[:, 0]
        xm[:, nx] = act[:, -1]
        zm = np.zeros((nz + 1, nx), dtype=bool)
        zm[1:nz] = open_z
        zm[0] = act[0]
        zm[nz] = act[-1]
        self.xmask, self.zmask = xm, zm
        # corners whose four cells are active (diagonal exchanges allowed)
        self.corner = act[:-1, :-1] & act[:-1, 1:] & act[1:, :-1] & act[1:, 1:]

    # -- fields --------------------------------------------------------------------------
    def cartesian_fields(self, fields, where: str) -> dict:
        """Checked fields (physical names, :func:`._operator._check_fields`) renamed to the
        twin's Cartesian names; values on inactive cells are ignored (set to 0)."""
        if not hasattr(fields, "keys"):
            raise ValueError(f"{where}: expected a dict of arrays, got {type(fields).__name__}")
        if self.hopper:
            fields = {k: self._masked(v) for k, v in fields.items()}
        f = _check_fields(self.grid, fields, where)
        return {_RENAME[k]: v for k, v in f.items()} if self.axi else f

    def _masked(self, v):
        try:
            a = np.asarray(v, dtype=float)
        except (TypeError, ValueError):
            return v                    # left for _check_fields to report by name
        if a.ndim == 0:
            a = np.full(self.shape, float(a))
        return np.where(self.active, a, 0.0) if a.shape == self.shape else a

    # -- advection -------------------------------------------------------------------------
    def faces(self, f: dict, outlet: np.ndarray) -> dict:
        """Face velocities of ``Q`` (twin names ``x``, ``z``) with the boundary conditions,
        the metric drift ``|D_rz| / r`` and the hopper walls built in."""
        faces = _advection.face_velocities(f, self.grid.walls, outlet)
        fx = faces["x"]
        if self.axi:
            r = self.grid.x
            e = np.abs(f["D_xz"]) / r[None, :]
            if np.any(e):
                fx[:, 1:-1] += 0.5 * (e[:, :-1] + e[:, 1:])
            fx[:, 0] = 0.0                      # the axis: zero area
            fx[:, -1] *= self.grid.x_range[1] / r[-1]   # open wall: P_c through 2 pi a h
        if self.hopper:
            fx *= self.xmask
            faces["z"] *= self.zmask
        return faces

    # -- diffusion -------------------------------------------------------------------------
    def diffusion(self, f: dict):
        """The exchange operator of the module docstring.

        Returns:
            ``(terms, n_bad, L, Bz, axial, coef)``: the tensor splitting of
            :func:`._diffusion.split_tensor`, the sparse operator ``L`` (``dQ/dt = L Q``,
            column sums 0, off-diagonals >= 0), ``Bz`` the map to the upward diffusive
            flux through every horizontal face (1/d per unit time, diagonal exchanges split
            half to each column, :func:`._diffusion.vertical_flux_operator`), and ``axial``
            the per-cell exchange coefficients a face's hybrid weight of the steady solve
            may rely on (the smallest over the cell's radial faces, ``A r_f / r``), and
            ``coef`` the same exchanges as face arrays for :func:`._geometry_kernels.exchange_2d`:
            ``coef[offset] = (alpha, beta) / h**2`` with ``E = alpha P_a - beta P_b`` for
            the pairs ``a, b = a + offset`` (shapes ``(nz, nx-1)`` for ``(0, 1)``,
            ``(nz-1, nx)`` for ``(1, 0)``, ``(nz-1, nx-1)`` for the diagonals, ``(1, -1)``
            indexed by the left column; 0 where blocked).
        """
        h = self.h
        nz, nx = shape = self.shape
        n = nz * nx
        terms, n_bad = _diffusion.split_tensor(f, 2)
        act = self.active.ravel()
        corner = np.zeros(shape, dtype=bool)      # corner above-right of cell (k, i)
        corner[:-1, :-1] = self.corner
        corner = corner.ravel()
        r = self.grid.x
        rows, cols, vals = [], [], []
        brows, bcols, bvals = [], [], []
        diag = np.zeros(n)
        coef = {}
        ih2 = 1.0 / h**2
        for off, A in terms:
            a, b, _ = _diffusion._pairs(shape, off)
            Af = A.ravel()
            alpha, beta = Af[a], Af[b]
            if self.axi and off == (0, 1):
                ia, ib = a % nx, b % nx
                rf = (ia + 1) * h
                alpha = alpha * (rf / r[ia])
                beta = beta * (rf / r[ib])
            if self.hopper:
                if off[1] == 0 or off[0] == 0:
                    keep = act[a] & act[b]
                elif off == (1, 1):          # corner above-right of a
                    keep = corner[a]
                else:                        # (1, -1): corner above-left of a
                    keep = corner[a - 1]
            else:
                keep = np.ones(a.shape, dtype=bool)
            pshape = (nz - abs(off[0]), nx - abs(off[1]))
            coef[off] = (np.where(keep, alpha * ih2, 0.0).reshape(pshape),
                         np.where(keep, beta * ih2, 0.0).reshape(pshape))
            if self.hopper:
                a, b, alpha, beta = a[keep], b[keep], alpha[keep], beta[keep]
            diag -= np.bincount(a, alpha * ih2, n) + np.bincount(b, beta * ih2, n)
            rows += [a, b]
            cols += [b, a]
            vals += [beta * ih2, alpha * ih2]
            if off[0] == 1:
                face_row = a // nx + 1
                parts = ((a, 0.5), (b, 0.5)) if off[1] else ((a, 1.0),)
                for cell, w in parts:
                    rr = face_row * nx + cell % nx
                    brows += [rr, rr]
                    bcols += [a, b]
                    bvals += [w * alpha / h, -w * beta / h]
        rows.append(np.arange(n))
        cols.append(np.arange(n))
        vals.append(diag)
        L = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                          shape=(n, n))
        if brows:
            Bz = sp.csr_matrix((np.concatenate(bvals), (np.concatenate(brows),
                                                        np.concatenate(bcols))),
                               shape=((nz + 1) * nx, n))
        else:
            Bz = sp.csr_matrix(((nz + 1) * nx, n))
        ax = {o: A for o, A in terms}
        axial = {"z": ax.get((1, 0), np.zeros(shape)), "x": ax.get((0, 1), np.zeros(shape))}
        if self.axi:
            fac = np.where(np.arange(nx) == 0, 2.0, (r - 0.5 * h) / r)
            axial["x"] = axial["x"] * fac[None, :]
        return terms, n_bad, L, Bz, axial, coef

    def check_P0(self, P: np.ndarray, name: str = "P0") -> None:
        """ValueError unless ``P`` vanishes on the inactive cells."""
        if self.hopper and np.any(P[~self.active] != 0):
            raise ValueError(f"{name}: must be 0 on the inactive cells of the hopper "
                             f"(grid.active is False on {int((~self.active).sum())} cells; "
                             f"mass there {float((P * self.grid.cell_volumes)[~self.active].sum()):.3g})")


class _GeometryOperator(_Operator):
    """The tracer operator of ``Q`` for one coefficient snapshot (the attributes of
    :class:`._operator._Operator`); explicit diffusion by the exchange kernel, implicit
    by the sparse exchange matrix."""

    def __init__(self, geometry: _Geometry, grid: Grid, fields: dict, limiter: int,
                 outlet: np.ndarray, implicit: bool, p_scale: float = 1.0):
        self.grid = grid
        self.eps = 1.0 / max(p_scale, 1e-150) ** 2
        self.h = h = grid.spacing
        self.dims = 2
        self.limiter = limiter
        self.implicit = implicit
        self.faces = geometry.faces(fields, outlet)
        self.terms, self.n_bad, self._L, self._Bz, self._axial, coef = \
            geometry.diffusion(fields)
        zx, zz, zd = (np.zeros((n, m)) for n, m in ((grid.nz, grid.nx - 1),
                                                    (grid.nz - 1, grid.nx),
                                                    (grid.nz - 1, grid.nx - 1)))
        self.coef = [c for off, z in (((0, 1), zx), ((1, 0), zz), ((1, 1), zd), ((1, -1), zd))
                     for c in coef.get(off, (z, z))]
        self.has_diag = (1, 1) in coef or (1, -1) in coef
        a_adv = _advection.advective_rate(self.faces, h)
        a_diff = np.maximum(-self._L.diagonal().reshape(grid.shape), 0.0)
        self.rate_adv = float(a_adv.max())
        self.rate_diff = float(a_diff.max())
        self.rate_explicit = float((a_adv + a_diff).max())
        self.rate = self.rate_adv if implicit else self.rate_explicit
        self.umax = max(float(np.abs(self.faces["x"]).max()), float(np.abs(self.faces["z"]).max()))
        self.has_cross = len(self.terms) > 2
        self.Axx = self.Azz = self.C = np.zeros(grid.shape)
        self.k_cross = False
        self._lu = {}

    def implicit_parts(self):
        """:meth:`._operator._Operator.implicit_parts` of this geometry: the exchange
        matrix ``L`` of ``Q`` (metric, walls), its flux map ``Bz`` and the axial
        coefficients the steady solve's hybrid weights use, so the long-run steppers
        step the explicit scheme's operator."""
        return self._axial, self._L, self._Bz, self.n_bad

    def rhs(self, P: np.ndarray, ws, w_acc: float, stage: tuple | None = None):
        """:func:`._operator._rhs` for this operator: the advection kernel, then the
        exchange kernel (explicit diffusion), then the Runge-Kutta stage combination."""
        h = self.h
        f = self.faces
        z = self.Axx
        K.rhs_2d_kernel(self.limiter)(P, f["x"], f["z"], z, z, z, False, self.eps, h, ws.R,
                                      ws.Fz_edge, ws.Fz_acc, w_acc, P, 0.0, 0.0, 1.0, 0.0)
        if not self.implicit and self.rate_diff > 0.0:
            GK.exchange_2d(P, *self.coef, self.has_diag, ws.R, ws.Fz_acc, w_acc, h)
        side = np.dot(f["x"][:, -1], P[:, -1]) - np.dot(f["x"][:, 0], P[:, 0])
        floor = -ws.Fz_edge[0].sum()
        top = ws.Fz_edge[1].sum()
        if stage is not None:
            a, P0, dt, out = stage
            K.combine(a, P0.ravel(), 1.0 - a, P.ravel(), (1.0 - a) * dt, ws.R.ravel(),
                      out.ravel(), ws.tiny)
        return h * floor, h * side, h * top


def operator(grid: Grid, fields: dict, limiter: int, outlet: np.ndarray, implicit: bool,
             p_scale: float = 1.0) -> _Operator:
    """The operator of one snapshot of (checked, physical-name) fields on any grid: the
    Cartesian :class:`._operator._Operator`, or :class:`_GeometryOperator` on the
    Cartesian twin (for run-time estimates: the rates are those of the solve)."""
    if not special(grid):
        return _Operator(grid, fields, limiter, outlet, implicit, p_scale)
    geo = _Geometry(grid)
    return _GeometryOperator(geo, geo.twin, geo.cartesian_fields(fields, "fields"), limiter,
                             outlet, implicit, p_scale)


def _to_physical(res, w):
    """Divide the ``Q`` arrays of a result by ``w = Q / P`` in place."""
    for name in ("P", "P_height", "P_height_faces", "residence"):
        a = getattr(res, name, None)
        if a is not None:
            a /= w
    return res


def solve(core, grid, fields, P, t_end, frames, progress, lim, scheme, diffusion, cfl, outlet,
          check_mass, on_frame=None, stepping="explicit", tol=1e-5, split=None):
    """:func:`._solve._solve` (``core``) on an axisymmetric or hopper grid: steps ``Q`` on
    the Cartesian twin with :class:`_GeometryOperator` (every ``stepping``: the long-run
    schemes take its faces and exchanges, :meth:`_GeometryOperator.implicit_parts`) and
    returns physical ``P``, ``P_height`` (per unit horizontal area when axisymmetric)."""
    geo = _Geometry(grid)
    geo.check_P0(P)
    w = geo.weight
    Q = np.ascontiguousarray(P * w)
    if callable(fields):
        fq = lambda t: geo.cartesian_fields(fields(t), f"fields(t={t:g})")
    else:
        fq = geo.cartesian_fields(fields, "fields")
    on_q = None if on_frame is None else (lambda j, t, Qj: on_frame(j, t, Qj / w))
    make_op = functools.partial(_GeometryOperator, geo)
    res = core(geo.twin, fq, Q, t_end, frames, progress, lim, scheme, diffusion, cfl, outlet,
               check_mass, on_q, stepping, tol, split, make_op=make_op)
    res.options["coordinates"] = grid.coordinates
    return _to_physical(res, w)


def solve_steady(core, grid, fields, P, outlet, scheme, **options):
    """:func:`._steady.solve_steady` (``core``, with the keyword ``options``) on an
    axisymmetric or hopper grid (physical field names): the steady state of ``Q`` on the
    twin (this module's operator), ``G = G_Q / (2 pi r)``."""
    geo = _Geometry(grid)
    fq = geo.cartesian_fields(fields, "fields")
    geo.check_P0(P)
    w = geo.weight

    def pieces(fc, out):
        terms, n_bad, L, Bz, axial, _ = geo.diffusion(fc)
        return geo.faces(fc, out), axial, L, Bz, n_bad

    res = core(geo.twin, fq, np.ascontiguousarray(P * w), outlet, scheme=scheme, pieces=pieces,
               make_op=functools.partial(_GeometryOperator, geo), **options)
    res.options["coordinates"] = grid.coordinates
    return _to_physical(res, w)
