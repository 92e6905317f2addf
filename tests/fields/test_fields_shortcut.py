"""v_kin without a second steady solve (issue 16, item 5): with uniform b and b_par = 0
the kinematic equation is the spot flux's, so the pipeline scales rho_s; it must equal
the kinematic solve to round-off, for any drift and for open walls (padded grid)."""

from __future__ import annotations

import numpy as np
import pytest

import spotpde
from spotpde.density import kinematic
from spotpde.app.cases import load_case


@pytest.mark.parametrize("walls,drift", [("reflecting", 1.0), ("reflecting", 2.5),
                                         ("open", 0.4)])
def test_v_kin_equals_the_kinematic_solve(walls, drift):
    case = load_case({"domain": {"x": [-6.0, 6.0], "z": [0.0, 12.0], "spacing": 0.25,
                                 "walls": walls},
                      "orifice": {"width": 2.0, "rate": 0.7},
                      "spots": {"drift": drift, "b": 1.1}})
    ds = spotpde.run(case)
    ref = kinematic.speed(case.grid, case.orifice, 1.1) * float(ds.attrs["V1"]) * 0.7
    assert np.abs(ds["v_kin"].values - ref).max() < 1e-13 * ref.max()
    # flux V1 Q0 through every height (reflecting walls)
    if walls == "reflecting":
        flux = ds["v_kin"].values.sum(axis=1) * 0.25
        assert np.allclose(flux, float(ds.attrs["V1"]) * 0.7, rtol=1e-12)
