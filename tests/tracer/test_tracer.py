"""Physics checks of the tracer Fokker-Planck solver (spotpde.tracer).

Closed forms used:
* uniform drift ``u`` and constant tensor ``D``: a Gaussian stays Gaussian, its mean
  moves by ``u t`` and its covariance grows by ``2 D t`` (cross terms included);
* first-order upwinding adds the numerical diffusivity ``|u| h / 2`` (modified
  equation; the SSP-RK3 time error is third order and does not contribute);
* the kinematic point-source field ``v = exp(-x^2/4bz)/sqrt(4 pi b z)``,
  ``u = (b dv/dx, -v)`` for a converging silo flow (divergence free).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from spotpde import tracer
from spotpde.errors import NumericalError
from spotpde.grid import Grid


def gaussian(grid, centre, cov):
    """Normalised Gaussian density on the cell centres; centre and cov in (x, z) order."""
    Z, X = grid.mesh()
    Ci = np.linalg.inv(cov)
    dx, dz = X - centre[0], Z - centre[1]
    q = Ci[0, 0] * dx**2 + 2 * Ci[0, 1] * dx * dz + Ci[1, 1] * dz**2
    return np.exp(-q / 2) / (2 * np.pi * np.sqrt(np.linalg.det(cov))) * np.ones(grid.shape)


def moments(grid, P):
    """Mean (x, z) and covariance matrix (x, z order) of a 2D density."""
    Z, X = grid.mesh()
    m = P.sum()
    mx, mz = (P * X).sum() / m, (P * Z).sum() / m
    cxx = (P * (X - mx) ** 2).sum() / m
    czz = (P * (Z - mz) ** 2).sum() / m
    cxz = (P * (X - mx) * (Z - mz)).sum() / m
    return np.array([mx, mz]), np.array([[cxx, cxz], [cxz, czz]])


def kinematic_fields(grid, b=1.3, z_shift=1.0, diff=0.05, floor=0.002):
    """Converging silo flow: the kinematic point source shifted below the floor.

    ``v`` is evaluated at ``z + z_shift`` (a regularised orifice of width ~ sqrt(2 b z_shift))
    and scaled to unit peak speed; ``D = (diff v + floor) I``.
    """
    Z, X = grid.mesh()
    zz = Z + z_shift
    v = np.exp(-X**2 / (4 * b * zz)) / np.sqrt(4 * np.pi * b * zz) * np.ones(grid.shape)
    v /= v.max()
    D = diff * v + floor
    return {"u_x": b * (-X / (2 * b * zz)) * v, "u_z": -v, "D_xx": D, "D_zz": D,
            "D_xz": np.zeros(grid.shape)}


# -- (a) accuracy in uniform flow at high cell Peclet number ------------------------------

def test_uniform_flow_spreading_and_drift_at_cell_peclet_20():
    h, u, D, t = 0.25, 1.0, 0.0125, 40.0
    assert u * h / D >= 20
    grid = Grid(2, (-6.0, 6.0), (0.0, 60.0), h)          # orifice across the whole floor
    fields = {"u_x": 0.0, "u_z": -u, "D_xx": D, "D_xz": 0.0, "D_zz": D}
    P0 = gaussian(grid, (0.0, 50.0), np.eye(2))
    res = tracer.solve(grid, fields, P0, t, 3)
    m0, c0 = moments(grid, res.P[0])
    m1, c1 = moments(grid, res.P[-1])
    assert abs((m0[1] - m1[1]) - u * t) / (u * t) < 0.02
    assert abs((c1[1, 1] - c0[1, 1]) / (2 * D * t) - 1) < 0.05
    assert abs((c1[0, 0] - c0[0, 0]) / (2 * D * t) - 1) < 0.05
    # the same run with first-order upwinding is off by an order of magnitude
    up = tracer.solve(grid, fields, P0, t, 2, limiter="upwind")
    assert (moments(grid, up.P[-1])[1][1, 1] - c0[1, 1]) / (2 * D * t) > 5


def test_numerical_diffusion_helper():
    # first-order upwind: modified equation gives D_num = |u| h / 2
    up = tracer.numerical_diffusion(1.0, 0.0025, 0.25, sigma=1.0, limiter="upwind")
    assert abs(up["D_num"] / (0.5 * 1.0 * 0.25) - 1) < 0.05
    # the paper's regime, cell Peclet 100, a 4-cell wide profile travelling 160 cells:
    # the default (WENO5) adds < 5 % of the physical diffusivity, Koren does not manage
    we = tracer.numerical_diffusion(1.0, 0.0025, 0.25, sigma=1.0)
    assert we["cell_peclet"] == pytest.approx(100.0)
    assert abs(we["ratio"]) < 0.05
    assert we["drift_error"] < 0.01
    ko = tracer.numerical_diffusion(1.0, 0.0025, 0.25, sigma=1.0, limiter="koren")
    assert ko["ratio"] > 0.1


# -- (b) convergence order on a smooth problem ---------------------------------------------

@pytest.mark.parametrize("limiter", ["weno5", "koren"])
def test_second_order_convergence_with_full_tensor(limiter):
    u = np.array([0.3, -0.5])
    D = np.array([[0.02, 0.01], [0.01, 0.015]])
    t = 4.0
    errs = []
    for h in (0.4, 0.2, 0.1):
        grid = Grid(2, (-6.0, 6.0), (0.0, 12.0), h)
        fields = {"u_x": u[0], "u_z": u[1], "D_xx": D[0, 0], "D_xz": D[0, 1], "D_zz": D[1, 1]}
        c0 = np.array([-1.0, 7.0])
        res = tracer.solve(grid, fields, gaussian(grid, c0, np.eye(2)), t, 2, limiter=limiter)
        exact = gaussian(grid, c0 + u * t, np.eye(2) + 2 * D * t)
        errs.append(np.abs(res.P[-1] - exact).sum() * grid.cell_volume)
    order = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(order > 1.8), order


# -- (c) conservation: mass + outflow ------------------------------------------------------

@pytest.mark.parametrize("walls,diffusion", [("open", "explicit"), ("reflecting", "implicit")])
def test_mass_plus_outflow_conserved_in_converging_flow(walls, diffusion):
    grid = Grid(2, (-6.0, 6.0), (0.0, 12.0), 0.25, walls=walls)
    f = kinematic_fields(grid)
    f["D_xz"] = 0.3 * f["D_xx"]                        # exercise the cross terms
    P0 = gaussian(grid, (1.5, 7.0), 0.5**2 * np.eye(2))
    res = tracer.solve(grid, f, P0, 30.0, 5, diffusion=diffusion)
    total = res.mass + res.outflow
    assert np.max(np.abs(total - res.mass[0])) / res.mass[0] < 1e-10
    assert res.outflow[-1] > 0.3                       # a real budget, not a trivial one
    assert np.all(np.diff(res.outflow) >= 0)
    assert res.P.min() >= 0.0
    # P_height: the time-integrated net downward flux through the face z_k equals the
    # probability that was above z_k at t = 0 minus what is above it at t_end
    h = grid.spacing
    above0 = np.cumsum(res.P[0][::-1].sum(axis=1))[::-1] * h * h
    above1 = np.cumsum(res.P[-1][::-1].sum(axis=1))[::-1] * h * h
    crossed = res.P_height_faces[:-1].sum(axis=1) * h
    if walls == "reflecting":                          # (open sides also lose probability)
        np.testing.assert_allclose(crossed, above0 - above1 - res.outflow_by_boundary["top"],
                                   atol=1e-12)
    np.testing.assert_allclose(res.P_height_faces[0].sum() * h, res.outflow_by_boundary["floor"],
                               rtol=1e-12)
    np.testing.assert_allclose(res.P_height, 0.5 * (res.P_height_faces[:-1] + res.P_height_faces[1:]))


# -- (d) positivity with a strongly anisotropic tensor -------------------------------------

def _rotated(theta, d1, d2):
    R = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    return R @ np.diag([d1, d2]) @ R.T


def test_positivity_with_anisotropic_tensor_from_a_single_cell():
    grid = Grid(2, (-4.0, 4.0), (0.0, 8.0), 0.25)
    D = _rotated(np.pi / 4, 0.1, 0.001)                # 100:1, principal axis along x = z
    fields = {"u_x": 0.05, "u_z": -0.1, "D_xx": D[0, 0], "D_xz": D[0, 1], "D_zz": D[1, 1]}
    P0 = np.zeros(grid.shape)
    P0[16, 16] = 1.0 / grid.cell_volume                # a single cell: the hardest start
    res = tracer.solve(grid, fields, P0, 4.0, 9)
    assert res.P.min() >= 0.0
    assert np.all(np.abs(res.mass + res.outflow - res.mass[0]) < 1e-12)
    # the textbook central cross-derivative stencil makes P < 0 from the same start
    h = grid.spacing
    q = P0 * D[0, 1]
    cross = 2 * (np.roll(np.roll(q, 1, 0), 1, 1) + np.roll(np.roll(q, -1, 0), -1, 1)
                 - np.roll(np.roll(q, 1, 0), -1, 1) - np.roll(np.roll(q, -1, 0), 1, 1)) / (4 * h * h)
    assert (P0 + 0.1 * cross).min() < 0


@pytest.mark.parametrize("theta", [np.pi / 4, -np.pi / 4, np.pi / 3])
def test_tensor_diffusion_covariance_is_exact(theta):
    # the exchange stencil has second moments 2 D exactly, and moments evolve linearly
    # in time, so SSP-RK3 reproduces cov(t) - cov(0) = 2 D t up to wall effects
    grid = Grid(2, (-6.0, 6.0), (-6.0, 6.0), 0.25)
    D = _rotated(theta, 0.1, 0.02 if theta == np.pi / 3 else 0.001)
    assert abs(D[0, 1]) <= min(D[0, 0], D[1, 1])      # diagonally dominant cases only
    fields = {"u_x": 0.0, "u_z": 0.0, "D_xx": D[0, 0], "D_xz": D[0, 1], "D_zz": D[1, 1]}
    P0 = np.zeros(grid.shape)
    P0[24, 24] = 1.0 / grid.cell_volume
    res = tracer.solve(grid, fields, P0, 2.0, 2)
    _, cov0 = moments(grid, res.P[0])
    _, cov1 = moments(grid, res.P[-1])
    np.testing.assert_allclose(cov1 - cov0, 2 * D * 2.0, rtol=1e-5, atol=1e-8)
    assert res.P.min() >= 0.0


def test_non_dominant_tensor_warns_and_negative_density_raises():
    grid = Grid(2, (-3.0, 3.0), (0.0, 6.0), 0.25)
    th = np.pi / 6
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    D = R @ np.diag([0.1, 0.0]) @ R.T                  # |D_xz| > D_zz: not diagonally dominant
    fields = {"u_x": 0.0, "u_z": 0.0, "D_xx": D[0, 0], "D_xz": D[0, 1], "D_zz": D[1, 1]}
    P0 = np.zeros(grid.shape)
    P0[12, 12] = 1.0
    with pytest.warns(UserWarning, match="not diagonally dominant"):
        with pytest.raises(NumericalError, match=r"negative probability .* t = "):
            tracer.solve(grid, fields, P0, 1.0, 3)


# -- time-dependent coefficients, implicit diffusion, 3D -------------------------------------

def test_time_dependent_drift():
    grid = Grid(2, (-4.0, 4.0), (0.0, 24.0), 0.25)
    D = 0.01

    def fields(t):
        return {"u_x": 0.0, "u_z": -(1.0 + 0.5 * np.sin(t)), "D_xx": D, "D_xz": 0.0,
                "D_zz": D * (1.0 + t)}

    P0 = gaussian(grid, (0.0, 18.0), np.eye(2))
    t = 6.0
    res = tracer.solve(grid, fields, P0, t, 4)
    m0, c0 = moments(grid, res.P[0])
    m1, c1 = moments(grid, res.P[-1])
    drift = t + 0.5 * (1 - np.cos(t))                  # integral of 1 + sin(t)/2
    assert abs((m0[1] - m1[1]) / drift - 1) < 0.01
    spread = 2 * D * (t + t**2 / 2)                    # integral of 2 D (1 + t)
    assert abs((c1[1, 1] - c0[1, 1]) / spread - 1) < 0.05
    assert abs(res.mass[-1] - res.mass[0]) / res.mass[0] < 1e-10


def test_time_dependent_implicit_diffusion_conserves_and_drifts():
    grid = Grid(2, (-6.0, 6.0), (0.0, 16.0), 0.25)

    def fields(t):
        D = 0.3 * (1.0 + 0.5 * t)
        return {"u_x": 0.1, "u_z": -(1.0 + 0.5 * t), "D_xx": D, "D_xz": 0.1 * D, "D_zz": D}

    P0 = gaussian(grid, (0.0, 11.0), np.eye(2))
    t = 2.0
    res = tracer.solve(grid, fields, P0, t, 3, diffusion="implicit")
    assert res.options["diffusion"] == "implicit"
    m0, _ = moments(grid, res.P[0])
    m1, _ = moments(grid, res.P[-1])
    assert abs((m0[1] - m1[1]) / (t + 0.25 * t**2) - 1) < 0.02
    assert abs((m1[0] - m0[0]) / (0.1 * t) - 1) < 0.05
    assert np.max(np.abs(res.mass + res.outflow - res.mass[0])) < 1e-12
    assert res.P.min() >= 0


def test_implicit_diffusion_for_void_like_coefficients():
    h, u, D, t = 0.25, 1.0, 0.5, 2.0                   # cell Peclet 0.5: diffusion bound
    grid = Grid(2, (-6.0, 6.0), (0.0, 16.0), h)
    fields = {"u_x": 0.0, "u_z": -u, "D_xx": D, "D_xz": 0.0, "D_zz": D}
    P0 = gaussian(grid, (0.0, 10.0), np.eye(2))
    res = tracer.solve(grid, fields, P0, t, 3)         # "auto" must choose implicit
    assert res.options["diffusion"] == "implicit"
    advective_steps = np.ceil(t / 2 * (2 * u / h) / 0.9) * 2   # frames: 2 intervals of t/2
    explicit_steps = t * (2 * u / h + 4 * D / h**2) / 0.9      # positivity limit, explicit
    assert res.steps == advective_steps and res.steps < explicit_steps / 4
    m0, c0 = moments(grid, res.P[0])
    m1, c1 = moments(grid, res.P[-1])
    assert abs((m0[1] - m1[1]) / (u * t) - 1) < 0.02
    np.testing.assert_allclose(np.diag(c1 - c0), 2 * D * t, rtol=0.03)
    assert res.P.min() >= 0
    assert abs(res.mass[-1] + res.outflow[-1] - res.mass[0]) < 1e-12


def test_3d_uniform_flow_with_full_tensor():
    grid = Grid(3, (-4.0, 4.0), (0.0, 10.0), 0.25)
    u = np.array([0.1, -0.05, -0.5])                     # (x, y, z)
    D = np.array([[0.02, 0.005, 0.004], [0.005, 0.015, -0.003], [0.004, -0.003, 0.01]])
    names = "xyz"
    fields = {f"u_{a}": u[i] for i, a in enumerate(names)}
    fields.update({f"D_{names[i]}{names[j]}": D[i, j] for i in range(3) for j in range(i, 3)})
    Z, Y, X = grid.mesh()
    c0 = np.array([0.0, 0.0, 6.0])
    P0 = np.exp(-((X - c0[0]) ** 2 + (Y - c0[1]) ** 2 + (Z - c0[2]) ** 2) / 2)
    t = 3.0
    res = tracer.solve(grid, fields, P0, t, 2)
    P = res.P[-1]
    r = [X, Y, Z]
    m = P.sum()
    mean = np.array([(P * c).sum() / m for c in r])
    cov = np.array([[(P * (r[i] - mean[i]) * (r[j] - mean[j])).sum() / m for j in range(3)]
                    for i in range(3)])
    np.testing.assert_allclose(mean - c0, u * t, atol=0.01)
    np.testing.assert_allclose(cov - np.eye(3), 2 * D * t, atol=0.003)
    assert abs(res.mass[-1] + res.outflow[-1] - res.mass[0]) / res.mass[0] < 1e-10
    assert res.P.min() >= 0


# -- independent check: Euler-Maruyama ensemble ----------------------------------------------

def test_grid_solution_matches_sde_ensemble_in_converging_flow():
    grid = Grid(2, (-8.0, 8.0), (0.0, 16.0), 0.25)
    f = kinematic_fields(grid)
    s0, start = 0.5, np.array([8.0, 2.0])                # (z, x)
    t = 20.0
    P0 = gaussian(grid, start[::-1], s0**2 * np.eye(2))
    res = tracer.solve(grid, f, P0, t, 2)
    n = 8000
    rng = np.random.default_rng(7)
    starts = start + s0 * rng.standard_normal((n, 2))
    pos = tracer.sde_ensemble(grid, f, starts, t, n, 0.04, seed=8)
    alive = ~np.isnan(pos[:, 0])
    p_out = 1 - alive.mean()
    se = np.sqrt(p_out * (1 - p_out) / n)
    assert abs(res.outflow[-1] - p_out) < 4 * se + 0.01
    assert res.outflow[-1] > 0.5
    h = grid.spacing
    P = res.P[-1] * h * h
    for axis, col in ((0, 1), (1, 0)):                   # z marginal, x marginal
        edges = (grid.z if col == 0 else grid.x) + h / 2
        cdf_grid = np.cumsum(P.sum(axis=axis))
        cdf_sde = np.searchsorted(np.sort(pos[alive, col]), edges) / n
        assert np.abs(cdf_grid - cdf_sde).max() < 0.02


# -- interface ---------------------------------------------------------------------------------

def test_result_shapes_progress_and_errors():
    grid = Grid(2, (-2.0, 2.0), (0.0, 4.0), 0.25)
    fields = {"u_x": 0.0, "u_z": -0.2, "D_xx": 0.01, "D_xz": 0.0, "D_zz": 0.01}
    P0 = gaussian(grid, (0.0, 2.0), 0.5**2 * np.eye(2))
    seen = []
    res = tracer.solve(grid, fields, P0, 2.0, 5, progress=seen.append)
    assert res.P.shape == (5,) + grid.shape and res.times.shape == (5,)
    assert res.P_height.shape == grid.shape and res.P_height_faces.shape == (17, 16)
    np.testing.assert_allclose(res.times, np.linspace(0, 2.0, 5))
    assert seen and seen[-1] == 1.0 and all(np.diff(seen) >= 0)
    assert 0 < res.max_cfl <= 0.9 + 1e-12
    bad = dict(fields)
    del bad["D_xz"]
    with pytest.raises(ValueError, match="D_xz"):
        tracer.solve(grid, bad, P0, 1.0, 2)
    with pytest.raises(ValueError, match="koren"):
        tracer.solve(grid, fields, P0, 1.0, 2, limiter="superbee2")
    with pytest.raises(ValueError, match="^frames: must be an integer"):
        tracer.solve(grid, fields, P0, 1.0, 1)
    with pytest.raises(ValueError, match="positive semidefinite"):
        tracer.solve(grid, dict(fields, D_xz=0.02), P0, 1.0, 2)


def test_sde_ensemble_moments_in_uniform_3d_flow():
    # Euler-Maruyama with a full tensor: mean u t and covariance 2 D t (exact for
    # constant coefficients); 4000 particles, tolerances of about 4 standard errors
    grid = Grid(3, (-2.0, 2.0), (0.0, 4.0), 0.5)
    f = {"u_x": 0.1, "u_y": 0.0, "u_z": -0.2, "D_xx": 0.02, "D_yy": 0.02, "D_zz": 0.01,
         "D_xy": 0.01, "D_xz": -0.005, "D_yz": 0.0}
    n, t = 4000, 2.0
    pos = tracer.sde_ensemble(grid, f, [3.0, 0.0, 0.0], t, n, 0.02, seed=3)
    assert not np.isnan(pos).any()
    mean = pos.mean(axis=0)                               # (z, y, x)
    np.testing.assert_allclose(mean, [3.0 - 0.4, 0.0, 0.2], atol=4 * np.sqrt(0.08 / n))
    cov = np.cov(pos.T)
    D = np.array([[0.01, 0.0, -0.005], [0.0, 0.02, 0.01], [-0.005, 0.01, 0.02]])  # (z, y, x)
    np.testing.assert_allclose(cov, 2 * D * t, atol=4 * 0.08 * np.sqrt(2 / n))


def test_P_height_in_uniform_flow_is_the_crossing_distribution():
    # a blob at z = 15 falling at u = 1: every particle crosses z = 5, at a horizontal
    # position spread by diffusion during the 10 time units of the fall
    grid = Grid(2, (-4.0, 4.0), (0.0, 20.0), 0.25)
    D = 0.01
    P0 = gaussian(grid, (0.0, 15.0), np.eye(2))
    res = tracer.solve(grid, {"u_x": 0.0, "u_z": -1.0, "D_xx": D, "D_xz": 0.0, "D_zz": D},
                       P0, 25.0, 2)
    k = int(np.argmin(np.abs(grid.z - 5.0)))
    row = res.P_height[k]
    assert abs(row.sum() * grid.spacing - res.mass[0]) < 1e-6   # all of it crossed
    var = 1.0 + 2 * D * (15.0 - grid.z[k])
    expected = np.exp(-grid.x**2 / (2 * var)) / np.sqrt(2 * np.pi * var)
    assert np.abs(row - expected).max() < 0.01 * expected.max()


@pytest.mark.parametrize("diffusion", ["explicit", "implicit"])
def test_3d_P_height_budget_with_cross_terms(diffusion):
    # sum over the horizontal plane of the time-integrated downward flux through face k
    # = probability above it at t = 0 minus above it at t_end (minus what left at the top)
    grid = Grid(3, (-2.0, 2.0), (0.0, 6.0), 0.25)
    f = {"u_x": 0.05, "u_y": 0.0, "u_z": -0.3, "D_xx": 0.05, "D_yy": 0.04, "D_zz": 0.03,
         "D_xy": 0.01, "D_xz": -0.01, "D_yz": 0.01}
    Z, Y, X = grid.mesh()
    P0 = np.exp(-((Z - 3) ** 2 + X**2 + Y**2) / 0.5) * np.ones(grid.shape)
    res = tracer.solve(grid, f, P0, 5.0, 2, diffusion=diffusion)
    h3 = grid.cell_volume
    above0 = np.cumsum(res.P[0][::-1].sum(axis=(1, 2)))[::-1] * h3
    above1 = np.cumsum(res.P[-1][::-1].sum(axis=(1, 2)))[::-1] * h3
    crossed = res.P_height_faces[:-1].sum(axis=(1, 2)) * grid.spacing**2
    np.testing.assert_allclose(crossed, above0 - above1 - res.outflow_by_boundary["top"],
                               atol=1e-12 * res.mass[0])
    assert res.outflow[-1] > 0.01
    assert res.mass_error < 1e-12 and res.P.min() >= 0


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), walls=st.sampled_from(["reflecting", "open"]),
       limiter=st.sampled_from(["weno5", "koren"]),
       diffusion=st.sampled_from(["explicit", "implicit"]))
def test_positivity_and_conservation_for_rough_random_fields(seed, walls, limiter, diffusion):
    # cell-by-cell random velocities and diagonally dominant tensors and a rough P0: the
    # forward-Euler positivity bound (docs/tracer.md) must hold whatever the data
    rng = np.random.default_rng(seed)
    grid = Grid(2, (0.0, 3.0), (0.0, 3.0), 0.25, walls=walls)
    shape = grid.shape
    Dxx = rng.uniform(0, 0.05, shape)
    Dzz = rng.uniform(0, 0.05, shape)
    f = {"u_x": rng.uniform(-1, 1, shape), "u_z": rng.uniform(-1, 1, shape), "D_xx": Dxx,
         "D_zz": Dzz, "D_xz": rng.uniform(-1, 1, shape) * np.minimum(Dxx, Dzz)}
    P0 = rng.uniform(0, 1, shape) * (rng.uniform(0, 1, shape) < 0.3)
    res = tracer.solve(grid, f, P0, 1.0, 3, limiter=limiter, diffusion=diffusion)
    assert res.P.min() >= -1e-14 * P0.max()
    assert np.max(np.abs(res.mass + res.outflow - res.mass[0])) < 1e-12 * res.mass[0]
    assert res.max_cfl <= 1.0
