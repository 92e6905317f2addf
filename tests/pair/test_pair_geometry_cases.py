"""The ``[pair]`` table of a case in cylinders and hoppers (spotpde/pair/_case.py).

Local: the pair sees the flow at ``(pair.x, pair.z)``. In a cylinder in plug flow the
pair is the 3D pair of uniform flow wherever it sits (on the axis or off it); in a hopper
it is the box's where the flows agree; a point outside the material is refused by name.
"""

from __future__ import annotations

import copy

import pytest

import spotpde
from spotpde import pair
from spotpde.fields.kernels import Gaussian

KERNEL = {"shape": "gaussian", "size": 0.7, "volume": 0.05, "diffusivity": "mean-field"}
CYLINDER = {
    "domain": {"coordinates": "axisymmetric", "x": [0.0, 8.0], "z": [0.0, 16.0],
               "spacing": 0.25},
    "orifice": {"x": 0.0, "width": 16.0},         # the whole floor: plug flow
    "spots": {"b": 1.3},
    "kernel": KERNEL,
    "pair": {"x": 0.0, "z": 8.0, "spacing": 0.25},
}


def _with(base, **tables):
    raw = copy.deepcopy(base)
    for name, table in tables.items():
        raw[name].update(table)
    return raw


def test_cylinder_pair_is_the_3d_pair_of_the_local_flow_on_and_off_the_axis():
    k = Gaussian(sigma=0.7, volume=0.05, dims=3)
    uniform = pair.cage_breaking(k, 1.3, diffusivity="mean-field", spacing=0.25)
    falls = []
    # the axisymmetric fields on the axis are second order in h: 1.6e-2, 4.3e-3 of b V2/V1
    # at h = d/2, d/4 (3.9e-5, 1.1e-5 at r = 3 d)
    for r, tol in ((0.0, 6e-3), (3.0, 1e-4)):
        ds = spotpde.run(_with(CYLINDER, pair={"x": r}))
        b_p = {key: ds.attrs[f"pair_b_p_{key}"] for key in ("xx", "xz", "zz")}
        ref = pair.cage_breaking(k, 1.3, diffusivity="mean-field", spacing=0.25, b_p=b_p)
        assert ds.attrs["pair_mean_fall"] == pytest.approx(ref.attrs["mean_fall"], rel=1e-9)
        assert ds.attrs["pair_relative_tensor"] == "mean-field"
        assert ds.attrs["pair_dims"] == 3 and ds["pair_X"].attrs["long_name"].startswith(
            "horizontal distance")
        # plug flow: b_p = b V2 / V1, no mixed term, the pair of uniform flow
        assert b_p["xx"] == pytest.approx(1.3 * k.V2 / k.V1, rel=tol)
        assert abs(b_p["xz"]) < 1e-9 * b_p["xx"] and b_p["zz"] == 0.0
        falls.append(ds.attrs["pair_mean_fall"])
    assert falls[0] == pytest.approx(uniform.attrs["mean_fall"], rel=6e-3)
    assert falls[1] == pytest.approx(uniform.attrs["mean_fall"], rel=1e-4)


def test_cylinder_pair_start_is_a_horizontal_distance():
    raw = _with(CYLINDER, pair={"start": {"x": -1.5, "z": 0.0}})
    with pytest.raises(spotpde.CaseError) as err:
        spotpde.load_case(raw)
    assert any(p.startswith("pair.start.x: must be >= 0 in a cylinder")
               for p in err.value.problems), err.value.problems


WEDGE = {
    "domain": {"x": [-10.0, 10.0], "z": [0.0, 20.0], "spacing": 0.5, "hopper_angle": 20.0},
    "orifice": {"x": 0.0, "width": 4.0},
    "spots": {"b": 1.3},
    "kernel": dict(KERNEL, diffusivity="passage"),
    "pair": {"x": 0.0, "z": 12.0, "spacing": 0.25},
}


def test_hopper_pair_follows_the_local_flow_and_is_the_box_where_the_flows_agree():
    ds = spotpde.run(WEDGE)
    b_p = {key: ds.attrs[f"pair_b_p_{key}"] for key in ("xx", "xz", "zz")}
    k = Gaussian(sigma=0.7, volume=0.05)
    ref = pair.cage_breaking(k, 1.3, diffusivity="passage", spacing=0.25, b_p=b_p)
    assert ds.attrs["pair_mean_fall"] == pytest.approx(ref.attrs["mean_fall"], rel=1e-9)
    # the converging flow of the wedge is not uniform flow: its local lengths differ
    assert abs(b_p["xx"] - 1.3 * k.V2 / k.V1) > 0.01 * b_p["xx"]
    # a vertical hopper over the whole floor is the box: the same pair
    plug = {"domain": {"hopper_angle": 0.0}, "orifice": {"width": 20.0}}
    box = copy.deepcopy(_with(WEDGE, **plug))
    del box["domain"]["hopper_angle"]
    a, b = spotpde.run(_with(WEDGE, **plug)), spotpde.run(box)
    assert a.attrs["pair_mean_fall"] == pytest.approx(b.attrs["pair_mean_fall"], rel=1e-9)


def test_hopper_pair_outside_the_material_is_refused_by_name():
    # at z = 5 the walls are 2 + 5 tan(20 deg) = 3.82 d from the axis
    with pytest.raises(spotpde.CaseError) as err:
        spotpde.load_case(_with(WEDGE, pair={"x": 5.0, "z": 5.0}))
    assert err.value.problems == [
        "pair.x: lies outside the material: at pair.z = 5 the hopper's walls are 3.82 d "
        "from orifice.x = 0; move the point inside them, got 5.0"], err.value.problems
    spotpde.load_case(_with(WEDGE, pair={"x": 3.5, "z": 5.0}))
