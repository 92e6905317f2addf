"""spotpde.geometry: one object per silo shape, asked by the stages instead of branching.

Closed forms in every shape (cell measures, the divergence of polynomial tensors, wall
faces), the one statement of what each shape supports, and the package's structure:
the stages converted so far read no geometry flag, and ``spotpde.fields`` has no import
cycle and no import inside a function that dodges one.
"""

import ast
import pathlib

import numpy as np
import pytest

import spotpde
from spotpde.geometry import (BOX_ONLY, FEATURES, AxisymmetricGeometry, BoxGeometry, ConeGeometry,
                              WedgeGeometry, geometry_of)
from spotpde.grid import Grid, Hopper

PACKAGE = pathlib.Path(spotpde.__file__).parent


def _shapes():
    return {
        "box": Grid(2, (-4.0, 4.0), (0.0, 10.0), 0.5),
        "box3": Grid(3, (-2.0, 2.0), (0.0, 4.0), 0.5, y_range=(0.0, 3.0)),
        "axisymmetric": Grid(2, (0.0, 4.0), (0.0, 10.0), 0.5, coordinates="axisymmetric"),
        "wedge": Grid(2, (-8.0, 8.0), (0.0, 20.0), 1.0, hopper=Hopper(30.0, 0.0, 1.5)),
        "cone": Grid(2, (0.0, 8.0), (0.0, 20.0), 1.0, coordinates="axisymmetric",
                     hopper=Hopper(30.0, 0.0, 1.5)),
    }


def test_each_grid_gets_its_shape_and_names():
    g = _shapes()
    assert type(g["box"].geometry) is BoxGeometry and g["box"].geometry.uniform_cells
    assert type(g["box3"].geometry) is BoxGeometry
    assert type(g["axisymmetric"].geometry) is AxisymmetricGeometry
    assert type(g["wedge"].geometry) is WedgeGeometry and g["wedge"].geometry.masked
    assert type(g["cone"].geometry) is ConeGeometry
    assert g["cone"].geometry.curved and g["cone"].geometry.masked
    assert g["axisymmetric"].axes == ("z", "r")
    assert g["axisymmetric"].drift_keys == ("u_r", "u_z")
    assert g["cone"].diffusivity_keys == ("D_rr", "D_rz", "D_zz")
    assert g["box3"].axes == ("z", "y", "x") and g["box3"].geometry.components == ("x", "y", "z")
    assert g["wedge"].geometry.kernel_dims == 2 and g["cone"].geometry.kernel_dims == 3
    assert g["box"].geometry is g["box"].geometry            # cached on the grid
    assert geometry_of(g["box"]) is not g["box"].geometry    # a fresh one when asked


def test_cell_measures_add_up_to_the_silo():
    g = _shapes()
    a, H = 4.0, 10.0
    box = g["box"]
    assert np.sum(np.broadcast_to(box.cell_volumes, box.shape)) == pytest.approx(8.0 * H, rel=1e-14)
    cyl = g["axisymmetric"]
    vol = np.sum(np.broadcast_to(cyl.cell_volumes, cyl.shape))
    assert vol == pytest.approx(np.pi * a * a * H, rel=1e-13)          # rings are exact
    assert np.sum(cyl.horizontal_measures) == pytest.approx(np.pi * a * a, rel=1e-13)
    m, faces = cyl.geometry.column_weights
    h = cyl.spacing
    np.testing.assert_array_equal(m * h, cyl.x)                          # r_i / h
    np.testing.assert_array_equal(faces * h, np.arange(cyl.nx + 1) * h)  # r_{i-1/2} / h
    # the cone's material: the frustum r <= 1.5 + z tan 30 up to the silo wall r = 8
    cone = g["cone"]
    t = np.tan(np.radians(30.0))
    z_meet = (8.0 - 1.5) / t
    frustum = np.pi / (3 * t) * ((1.5 + z_meet * t) ** 3 - 1.5**3)
    exact = frustum + np.pi * 64.0 * (20.0 - z_meet)
    got = np.sum(np.broadcast_to(cone.cell_volumes, cone.shape) * cone.material)
    assert got == pytest.approx(exact, rel=2e-4)     # midpoint rule in the cells the wall cuts


def test_divergence_is_exact_for_quadratic_tensors():
    g = _shapes()
    box = g["box"]
    Z, X = box.mesh()
    T = {"D_xx": np.broadcast_to(X * X, box.shape), "D_xz": 0.0,
         "D_zz": np.broadcast_to(Z * Z, box.shape)}
    div = box.geometry.divergence(T)
    np.testing.assert_allclose(div["x"], np.broadcast_to(2 * X, box.shape), atol=1e-12)
    np.testing.assert_allclose(div["z"], np.broadcast_to(2 * Z, box.shape), atol=1e-12)
    # cylindrical: (div T)_r = d_r T_rr + d_z T_rz, (div T)_z = (1/r) d_r(r T_rz) + d_z T_zz
    cyl = g["axisymmetric"]
    Z, R = cyl.mesh()
    T = {"D_rr": np.broadcast_to(R * R, cyl.shape), "D_rz": np.broadcast_to(R * Z, cyl.shape),
         "D_zz": np.broadcast_to(Z, cyl.shape)}
    div = cyl.geometry.divergence(T)
    np.testing.assert_allclose(div["r"], np.broadcast_to(2 * R + R, cyl.shape), atol=1e-12)
    np.testing.assert_allclose(div["z"], np.broadcast_to(2 * Z + 1.0, cyl.shape), atol=1e-12)
    u = {"u_r": np.broadcast_to(R, cyl.shape), "u_z": np.broadcast_to(-2 * Z, cyl.shape)}
    np.testing.assert_allclose(cyl.geometry.velocity_divergence(u), 0.0, atol=1e-12)  # 2 - 2


def test_staircase_divergence_never_reaches_across_a_wall():
    wedge = _shapes()["wedge"]
    act = wedge.active
    Z, X = wedge.mesh()
    # linear inside, wild outside: one-sided differences must not see the outside
    T = {"D_xx": np.where(act, 3 * X, 1e6), "D_xz": 0.0, "D_zz": np.where(act, 2 * Z, -1e6)}
    div = wedge.geometry.divergence(T)
    np.testing.assert_allclose(div["x"][act], 3.0, atol=1e-12)
    np.testing.assert_allclose(div["z"][act], 2.0, atol=1e-12)
    assert np.all(div["x"][~act] == 0.0) and np.all(div["z"][~act] == 0.0)
    np.testing.assert_array_equal(wedge.geometry.restrict(np.ones(wedge.shape)), act)


def test_wall_faces_of_each_shape():
    g = _shapes()
    box = g["box"]
    faces = box.geometry.wall_faces()
    assert len(faces) == 2 * box.nz and not box.geometry.horizontal_faces()
    assert {(j, d) for _, j, d in faces} == {(0, -1), (box.nx - 1, 1)}
    assert not Grid(2, (-4.0, 4.0), (0.0, 10.0), 0.5, walls="open").geometry.wall_faces()
    cyl = g["axisymmetric"]      # the axis is never a wall
    assert {(j, d) for _, j, d in cyl.geometry.wall_faces()} == {(cyl.nx - 1, 1)}
    wedge = g["wedge"]
    act = wedge.active
    for k, j, d in wedge.geometry.wall_faces():
        assert act[k, j] and (not 0 <= j + d < wedge.nx or not act[k, j + d])
    steps = wedge.geometry.horizontal_faces()
    assert steps and all(act[k, j] and not act[k + d, j] for k, j, d in steps)
    open_x, open_z = wedge.geometry.open_faces()
    # every face is open or a wall, never both: the staircase walls are the closed ones
    closed_x = {(k, j, 1) for k, j in np.argwhere(act[:, :-1] & ~open_x)}
    assert closed_x == {f for f in wedge.geometry.wall_faces() if f[2] == 1 and f[1] < wedge.nx - 1}
    assert open_z.sum() + len([f for f in steps if f[2] == 1]) == (act[:-1]).sum()
    assert all(o.all() for o in box.geometry.open_faces())


def test_one_statement_of_what_each_shape_supports():
    g = _shapes()
    assert set(BOX_ONLY) < set(FEATURES)
    for feature in BOX_ONLY:
        assert g["box"].geometry.supports(feature).ok
        assert g["box3"].geometry.supports(feature) == (True, "")
        for name in ("axisymmetric", "wedge", "cone"):
            s = g[name].geometry.supports(feature)
            assert not s.ok and s.reason
    # lifted: two-point statistics and the kinematic comparison work in every shape
    assert "two-point statistics" not in FEATURES and "kinematic comparison" not in FEATURES
    # lifted: interacting spots run on rings and staircases (tests/density/test_traffic_geometry.py)
    assert "interacting spots" not in FEATURES
    with pytest.raises(ValueError, match="^feature"):
        g["cone"].geometry.require("interacting spots", "spots.rho_max")
    with pytest.raises(ValueError, match="^feature"):
        g["box"].geometry.supports("teleportation")


def test_shape_answers_for_the_stages():
    """What the app and observables ask instead of testing flags: description, result
    metadata, integral, blanking, the py-pde grid and the refusals of track observables."""
    g = _shapes()
    assert g["box"].geometry.description == "2D" and g["box3"].geometry.description == "3D"
    assert g["axisymmetric"].geometry.description == "axisymmetric (z, r)"
    assert g["wedge"].geometry.description == "2D, hopper 30 degrees"
    assert g["cone"].geometry.description == "axisymmetric (z, r), hopper 30 degrees"
    assert g["box"].geometry.result_attrs == {} == g["axisymmetric"].geometry.result_attrs
    assert g["cone"].geometry.result_attrs == {"hopper_angle": 30.0}
    # the integral of a uniform density 1 is the volume of the silo (rings exactly)
    cyl = g["axisymmetric"]
    assert cyl.geometry.total(np.ones(cyl.shape)) == pytest.approx(np.pi * 16.0 * 10.0, rel=1e-13)
    assert g["box3"].geometry.total(np.ones(g["box3"].shape)) == pytest.approx(4.0 * 4.0 * 3.0)
    wedge = g["wedge"]
    ones = np.ones(wedge.shape)
    blanked = wedge.geometry.blank(ones)
    assert np.all(np.isnan(blanked[~wedge.active])) and np.all(blanked[wedge.active] == 1.0)
    assert g["box"].geometry.blank(ones[:20, :16]) is not None
    assert cyl.geometry.blank(ones) is ones and cyl.axisymmetric and not g["wedge"].axisymmetric
    for name in ("box", "wedge"):
        assert g[name].geometry.supports("track observables").ok
    s = g["box3"].geometry.supports("track observables")
    assert not s.ok and "got dims = 3;" in s.reason
    with pytest.raises(ValueError, match="^case: observables .* got dims = 2, axisymmetric;"):
        g["cone"].geometry.require("track observables", "case")
    with pytest.raises(ValueError, match="centred on the axis"):
        Grid(2, (0.0, 4.0), (0.0, 4.0), 1.0, coordinates="axisymmetric", hopper=Hopper(30.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="^coordinates must be one of"):
        Grid(2, (0.0, 4.0), (0.0, 4.0), 1.0, coordinates="polar")
    pde = pytest.importorskip("pde")
    assert isinstance(cyl.to_pde(), pde.CylindricalSymGrid)
    assert isinstance(g["box3"].to_pde(), pde.CartesianGrid) and g["box3"].to_pde().shape == (8, 6, 8)


# -- structure -----------------------------------------------------------------------------

#: Every module outside :mod:`spotpde.geometry` asks ``grid.geometry`` instead of testing
#: which grid it has: the subpackages and the top-level modules.
CONVERTED = tuple(sorted(p.name for p in PACKAGE.iterdir()
                         if p.is_dir() and (p / "__init__.py").exists() and p.name != "geometry")
                  + sorted(p.name for p in PACKAGE.glob("*.py")))

def _flag_tests(path):
    """Lines reading ``.axisymmetric`` / ``.hopper`` of anything but ``self``, or comparing
    ``.coordinates`` (copying it into result metadata is not a test)."""
    tree = ast.parse(path.read_text())
    lines = []
    for n in ast.walk(tree):
        if isinstance(n, ast.Attribute) and n.attr in ("axisymmetric", "hopper") \
                and not (isinstance(n.value, ast.Name) and n.value.id == "self"):
            lines.append(n.lineno)
        if isinstance(n, ast.Compare) and any(
                isinstance(a, ast.Attribute) and a.attr == "coordinates"
                for a in [n.left, *n.comparators]):
            lines.append(n.lineno)
    return lines


def test_every_package_but_geometry_is_converted():
    names = set(CONVERTED)
    assert {"app", "montecarlo", "observables", "pair", "grid.py", "parameters.py"} <= names
    assert "geometry" not in names
    # the detector finds what it looks for: the geometry package itself reads the flags
    assert _flag_tests(PACKAGE / "geometry" / "_shapes.py")


@pytest.mark.parametrize("package", CONVERTED)
def test_converted_stages_read_no_geometry_flag(package):
    root = PACKAGE / package
    files = sorted(root.rglob("*.py")) if root.is_dir() else [root]
    reads = {}
    for p in files:
        rel = p.relative_to(PACKAGE).as_posix()
        reads[rel] = _flag_tests(p)
    assert {k: v for k, v in reads.items() if v} == {}


def _imports(package):
    """``{module: [(target, inside_a_function)]}`` for the package's own modules."""
    out = {}
    for p in sorted((PACKAGE / package).glob("*.py")):
        mod = p.stem
        tree = ast.parse(p.read_text())
        inner = {id(n) for f in ast.walk(tree)
                 if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
                 for n in ast.walk(f) if isinstance(n, (ast.Import, ast.ImportFrom))}
        found = []
        for n in ast.walk(tree):
            if isinstance(n, ast.ImportFrom) and n.level == 1:
                names = [n.module] if n.module else [a.name for a in n.names]
                found += [(t, id(n) in inner) for t in names]
        out[mod] = found
    return out


#: The imports left inside functions, none of them dodging a cycle: numba's compiled
#: cell averages (exponential kernels only) and py-pde (the optional cross-check solver).
LAZY = {"fields": {("kernels", "_cellavg_exp")}, "density": {("spot_density", "_pde")}}


@pytest.mark.parametrize("package", sorted(LAZY))
def test_imports_run_one_way(package):
    graph = _imports(package)
    inside = {(m, t) for m, ts in graph.items() for t, fn in ts if fn}
    assert inside == LAZY[package]
    edges = {m: {t for t, _ in ts if t in graph} for m, ts in graph.items()}
    state = {}

    def visit(m, path):
        state[m] = "open"
        for t in edges[m]:
            assert state.get(t) != "open", f"import cycle: {' -> '.join(path + [t])}"
            if t not in state:
                visit(t, path + [t])
        state[m] = "done"

    for m in edges:
        if m not in state:
            visit(m, [m])


# -- public short names ---------------------------------------------------------------------

def test_short_names_are_attributes_and_no_import_hook_is_installed():
    """``spotpde.<short>`` is the stage module itself (no second copy); the two short
    names of the public interface import as modules too; nothing is put on
    ``sys.meta_path`` (the old-name import hook is gone)."""
    import sys

    import spotpde
    from spotpde.density import kinematic as density_kinematic
    from spotpde.fields import coefficients, kernels as field_kernels

    assert not [f for f in sys.meta_path if type(f).__module__.startswith("spotpde")]
    assert spotpde.coefficients is coefficients
    assert spotpde.cases is sys.modules["spotpde.app.cases"]
    from spotpde.kernels import Gaussian
    from spotpde.kinematic import point_source
    assert Gaussian is field_kernels.Gaussian
    assert point_source is density_kinematic.point_source
    assert set(spotpde.kernels.__all__) == set(field_kernels.__all__)
    with pytest.raises(AttributeError, match="no attribute 'teleport'"):
        spotpde.teleport
    with pytest.raises(ModuleNotFoundError):
        import spotpde.pipeline  # noqa: F401  (statement form of a short name: gone)
