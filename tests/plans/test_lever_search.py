"""The planner's default search: every declared lever at its options, and the calibrations a
procedure offers at their cost; ``--vary`` narrows it."""

from __future__ import annotations

import json

import pytest

from mtplan import cli
from mtplan.evaluation.first_order import first_order
from mtplan.models import get
from mtplan.models.fields import lever_options, param
from mtplan.models.protocol import fields_info
from mtplan.plans import levers
from mtplan.plans.planner import plan

FAST = ["--trials", "300", "--confirm", "2"]


def test_a_lever_takes_its_declared_options_else_the_generic_ones():
    infos = {i.name: i for i in fields_info(get("rotary_axis").Setup)}
    assert lever_options(infos["sensor_reversal"], False) == (False, True)  # a bool
    assert lever_options(infos["a_order"], "patent") == ("patent", "ascending")  # choices
    assert lever_options(infos["lattice_nx"], 5) == (5, 3, 7)  # declared levels
    assert lever_options(infos["lattice_nx"], 4) == (4, 3, 5, 7)  # the set-up's value first
    assert lever_options(infos["incline_deg"], 20.0) == (20.0,)  # continuous: held
    with pytest.raises(ValueError, match="'levels'.*Got 2"):
        param(3, doc="a count", low=3, high=5, levels=(2, 4))


def test_rotary_axis_finds_the_reversal_without_being_told(capsys):
    """EX0C <= 5 um: the data sheet's angle influence leaves 33 um at the defaults; the
    0/180 deg reversal cancels its odd part, and the search finds it with no --vary."""
    assert cli.main(["plan", "rotary_axis", "--target", "EX0C<=5", *FAST, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    best = doc["best"]
    assert best["setup"]["sensor_reversal"] is True
    assert best["changes"]["sensor_reversal"] is True
    assert best["confirmed"]["EX0C"] <= 5 and doc["confirmation"][-1]["met"]
    assert "sensor_reversal" in doc["search"]
    # the cheapest: no candidate of the search's front that meets the target costs less
    met = [c["cost_s"] for c in doc["pareto"] if c["worst"] <= 1]
    assert best["cost_s"] == min(met)


def test_an_unreachable_target_names_the_best_levers_and_calibration_with_the_cost(capsys):
    assert cli.main(["plan", "rotary_axis", "--target", "EX0C<=0.5", *FAST]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "cannot be met" in err and "best reachable" in err
    assert "sensor_reversal=True" in err and "cost" in err
    # the value named is the smallest of the search, which takes the calibration
    proc = get("rotary_axis")
    best = proc.setup(sensor_reversal=True, positions=12,
                      **proc.capabilities.calibrations[0].values)
    u = first_order(proc, best).u()["EX0C"]
    assert f"the best reachable value is {u:.3g} um" in err
    assert "'sensor angle characteristic'" in err


def test_vary_narrows_the_search_and_names_the_lever_outside_it(capsys):
    proc = get("rotary_axis")
    r = plan(proc, None, {"sensor_reversal": [False, True]}, {"EX0C": 5.0}, trials=300,
             confirm=1)
    assert len(r.table) == 2 and r.best["setup"]["sensor_reversal"] is True
    assert r.search == ""
    assert cli.main(["plan", "rotary_axis", "--target", "EX0C<=5", "--vary", "positions=3,6",
                     *FAST]) == 2
    err = capsys.readouterr().err
    assert "cannot be met" in err and "(at positions=6)" in err
    assert "outside the grid, sensor_reversal=True would meet the targets" in err


def test_a_calibration_is_an_option_at_its_cost():
    """A axis, EZ0A: the angle influence's even part, which the reversal does not cancel;
    a target between the calibrated u and the base's is met only by the calibration, and
    the candidate's cost is the test's duration plus the calibration's."""
    proc = get("rotary_axis")
    base = proc.setup(axis="A")
    cal = proc.capabilities.calibrations[0]
    u_cal = first_order(proc, proc.setup(axis="A", **cal.values)).u()["EZ0A"]
    u_rev = first_order(proc, proc.setup(axis="A", sensor_reversal=True)).u()["EZ0A"]
    target = 1.5 * u_cal
    assert u_rev > 2 * target  # the precondition: the reversal alone does not do it
    r = plan(proc, base, None, {"EZ0A": target}, trials=300, confirm=2)
    best = r.best
    assert best["calibration"] == cal.name == best["changes"]["calibration"]
    assert best["cost_s"] == pytest.approx(best["duration_s"] + cal.cost_s)
    rows = r.table[r.table["calibration"] == cal.name]
    assert len(rows) and (rows["cost_s"] - rows["duration_s"]).round(9).eq(cal.cost_s).all()
    plain = r.table[r.table["calibration"] == ""]
    assert (plain["cost_s"] == plain["duration_s"]).all()


def test_the_search_is_bounded_and_prunes_levers_without_effect():
    proc = get("rotary_axis")
    base = proc.Setup()
    calls = []

    def evaluate(setup):
        calls.append(setup)
        u = first_order(proc, setup).u()["EX0C"]
        return levers.Score(values=[u / 5], worst=u / 5, feasible=u <= 5)

    found = levers.search(proc, base, evaluate, max_candidates=8)
    options = proc.lever_options(base)
    n_options = sum(len(v) for v in options.values() if len(v) > 1) + 2  # + the calibration
    assert len(calls) <= n_options + 8 + levers.PASSES * n_options
    assert "a_order" in found.pruned  # the A order does nothing on a C axis
    assert found.product[0] == "sensor_reversal"  # the largest effect on EX0C
    assert found.setups[0] is base and len(found.setups) == len(found.scores)
    only = plan(proc, base, None, {"EX0C": 50.0}, levers=False, trials=300, confirm=1)
    assert len(only.table) == 1 and only.best["changes"] == {}
