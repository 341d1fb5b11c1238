"""Tolerances of every kind, two-sided and one-sided on either side, judged, drawn and
curved by one implementation (mtplan.plans.acceptance) for the designer, `mtplan accept`
and the reports."""

from __future__ import annotations

import math

import pytest

from mtplan.plans.acceptance import (CURVE_GUARDS, judgement, plan_acceptance, risk_curve,
                                     zones)

U_STD = 17.5
KINDS = {"two-sided": (-100.0, 100.0), "upper": (None, 100.0), "lower": (-100.0, None)}


@pytest.mark.parametrize("kind", KINDS)
def test_the_risk_curve_is_the_guard_rule_at_each_limit_the_tolerance_has(kind):
    lower, upper = KINDS[kind]
    curve = risk_curve(lower, upper, U_STD, "normal:0,30")
    assert len(curve["guard_band"]) == len(CURVE_GUARDS)  # every point leaves a zone here
    for w, pfa, pfr, r in zip(curve["guard_band"], curve["pfa"], curve["pfr"], CURVE_GUARDS):
        ref = plan_acceptance(lower, upper, U_STD, prior="normal:0,30", rule=f"guard:{r}")
        assert (w, pfa, pfr) == (ref.guard_band, ref.pfa, ref.pfr)
    assert curve["pfa"] == sorted(curve["pfa"], reverse=True)  # a wider band accepts less
    assert curve["pfr"] == sorted(curve["pfr"])


def test_a_two_sided_curve_stops_where_no_acceptance_zone_is_left():
    curve = risk_curve(-30.0, 30.0, U_STD, "normal:0,30")
    assert curve["guard_band"] and max(curve["guard_band"]) < 30.0
    assert len(curve["guard_band"]) < len(CURVE_GUARDS)


def test_the_sides_mirror_each_other():
    up = plan_acceptance(None, 100.0, U_STD, prior="normal:0,30", rule="iso14253")
    lo = plan_acceptance(-100.0, None, U_STD, prior="normal:0,30", rule="iso14253")
    assert up.pfa == pytest.approx(lo.pfa, rel=1e-12)
    assert up.pfr == pytest.approx(lo.pfr, rel=1e-12)
    assert up.acceptance_limits[1] == pytest.approx(-lo.acceptance_limits[0], rel=1e-15)
    assert judgement(up) == judgement(lo)


@pytest.mark.parametrize("kind", KINDS)
def test_zones_leave_the_open_side_accepted(kind):
    lower, upper = KINDS[kind]
    r = plan_acceptance(lower, upper, U_STD, prior="normal:0,30", rule="iso14253")
    z = zones(r)
    assert z["tolerance"] == [lower, upper]
    assert z["acceptance"] == list(r.acceptance_limits)
    assert len(z["reject"]) == (lower is not None) + (upper is not None)
    assert len(z["uncertainty"]) == len(z["reject"])
    for a, b in z["uncertainty"]:
        assert b - a == pytest.approx(4 * U_STD)
    x0, x1 = z["view"]
    assert math.isfinite(x0) and math.isfinite(x1) and x0 < x1
    for limit in (lower, upper, *r.acceptance_limits):  # everything finite is in view
        assert limit is None or x0 < limit < x1
    assert (z["acceptance"][0] is None) == (lower is None)  # never a limit at 0


@pytest.mark.parametrize("kind", ["upper", "lower"])
def test_a_one_sided_tolerance_is_judged_on_its_risks_never_on_a_missing_tur(kind):
    lower, upper = KINDS[kind]
    r = plan_acceptance(lower, upper, U_STD, prior="normal:0,30", rule="iso14253")
    assert r.tur is None
    j = judgement(r, items="machines")
    # PFA 0.0004 %, PFR 2.6 %: decided at its risks (it said "cannot be decided well
    # (TUR -)" when a missing TUR compared as less than 2)
    assert j["quality"] == "is decided, at the risks stated", j
    assert "one-sided: no TUR" in j["text"] and "good machines would be rejected" in j["text"]
    tight = plan_acceptance(lower, upper and 40.0, U_STD, prior="normal:0,30",
                            rule="iso14253") if kind == "upper" else \
        plan_acceptance(-40.0, None, U_STD, prior="normal:0,30", rule="iso14253")
    assert judgement(tight)["quality"] == "cannot be decided well"  # a third rejected
    wide = plan_acceptance(lower and -300.0, upper and 300.0, U_STD, prior="normal:0,30",
                           rule="iso14253")
    assert judgement(wide)["quality"] == "is decided well"
    alone = judgement(plan_acceptance(lower, upper, U_STD, rule="iso14253"))
    assert alone["quality"] == "is not judged" and "prior" in alone["text"]


def test_two_sided_judgements_keep_their_tur_rules():
    assert judgement(plan_acceptance(-60, 60, U_STD, prior="normal:0,8",
                                     rule="simple"))["quality"] == "cannot be decided well"
    good = judgement(plan_acceptance(-300, 300, U_STD, prior="normal:0,30", rule="iso14253"))
    assert good["quality"] == "is decided well" and "TUR 8.57" in good["text"]
    assert judgement(plan_acceptance(-300, 300, U_STD))["quality"] == \
        "is decided, at the risks stated"  # no prior: no risks to judge, only the TUR
