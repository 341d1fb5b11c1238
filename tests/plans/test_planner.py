"""The planner: cheapest set-up meeting targets, confirmation, Pareto front, design search."""

from __future__ import annotations

import numpy as np
import pytest

from mtplan._validate import InvalidInput
from mtplan.plans.planner import optimize_design, parse_target, pareto_front, plan, readings_jacobian
from mtplan.testing import template as toy_line

P = toy_line.PROCEDURE
GRID = {"n_points": [3, 5, 9, 17, 33], "probe_noise_um": [0.5, 1.0, 2.0]}


def test_cheapest_candidate_meeting_targets_is_confirmed():
    r = plan(P, vary=GRID, targets={"offset": 0.2, "slope": 5.0}, trials=4000)
    t = r.table
    feasible = t[t.feasible]
    assert r.best["duration_s"] == feasible["duration_s"].min()
    # the prediction for a straight-line fit is exact: u(offset) = sigma / sqrt(n)
    row = t.loc[r.best["candidate"]]
    assert row["u_offset"] == pytest.approx(row["probe_noise_um"] / np.sqrt(row["n_points"]))
    check = r.confirmation[-1]
    assert check["met"] and check["candidate"] == r.best["candidate"]
    for name in ("offset", "slope"):  # Monte Carlo agrees with the prediction within its error
        assert abs(check["ratio"][name] - 1) < 4 / np.sqrt(2 * (4000 - 1))
    doc = r.to_dict()
    assert {"best", "pareto", "confirmation"} <= set(doc)


def test_expanded_targets_use_k():
    r1 = plan(P, vary=GRID, targets={"offset": 0.25}, trials=2000)
    r2 = plan(P, vary=GRID, targets={"offset": 0.25}, k=2, trials=2000)
    assert r2.best["duration_s"] >= r1.best["duration_s"]
    assert r2.best["predicted"]["offset"] <= 0.25


def test_impossible_and_unknown_targets_say_what_is_wrong():
    with pytest.raises(InvalidInput) as exc:
        plan(P, vary=GRID, targets={"offset": 0.01})
    msg = str(exc.value)
    assert "offset<=0.01" in msg and "best reachable value is 0.087" in msg
    with pytest.raises(InvalidInput, match="'nope' names no measurand"):
        plan(P, vary=GRID, targets={"nope": 1.0})
    with pytest.raises(InvalidInput):
        parse_target("offset<=-1")
    assert parse_target("EX0C<=2.5") == ("EX0C", 2.5)


def test_pareto_front():
    cost = np.array([1, 2, 3, 4, 2])
    value = np.array([5, 3, 4, 1, 6])
    assert list(pareto_front(cost, value)) == [0, 1, 3]


def test_design_search_beats_the_grid_on_a_continuous_field():
    base = P.setup(length_mm=50.0)
    grid = plan(P, base, vary={"length_mm": [20.0, 50.0, 100.0]}, targets={"slope": 100.0},
                trials=1000)
    best_grid = grid.table["u_slope"].min()
    found = optimize_design(P, base, {"length_mm": (10.0, 150.0)}, criterion="u:slope")
    assert found["value"] <= best_grid * (1 + 1e-6)
    assert found["setup"].length_mm == pytest.approx(150.0, rel=1e-3)  # longest baseline wins
    with pytest.raises(InvalidInput):
        optimize_design(P, base, {"n_points": (1, 3)})


def test_readings_jacobian_rank():
    J, names = readings_jacobian(P)
    assert J.shape == (P.Setup().n_points, 2) and np.linalg.matrix_rank(J) == 2


def test_a_reliability_target_tells_circle_centre_how_many_points_it_needs():
    """``reliability:centre_x<=4``: a bad contact the fit check misses must not move
    centre_x by more than 4 um. The default three points cannot hold it (one contact's
    radial error is checked only by the two start points, 15 um of centre_x unseen), six
    neither; eight can. Each candidate's figure is that of the reliability service."""
    from mtplan.evaluation.reliability import reliability
    from mtplan.models import get

    proc = get("circle_centre")
    default = proc.Setup().n_points
    res = plan(proc, vary={"n_points": [3, 6, 8]}, targets={"reliability:centre_x": 4.0},
               trials=100, confirm=1)
    assert res.best["setup"]["n_points"] == 8 > default
    shifts = res.table.set_index("n_points")["u_reliability:centre_x"]
    for n in (3, 6, 8):
        assert shifts[n] == pytest.approx(
            reliability(proc, proc.Setup(n_points=n)).shift("centre_x"), rel=1e-9)
    assert shifts[default] > 4.0
    with pytest.raises(InvalidInput, match="reliability:radius<=1 um cannot be met"):
        plan(proc, targets={"reliability:radius": 1.0}, trials=100)
    with pytest.raises(InvalidInput, match="names no measurand"):
        plan(proc, targets={"reliability:nothing": 1.0}, trials=100)
