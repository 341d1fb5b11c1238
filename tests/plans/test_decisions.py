"""What a study concludes: verdict zones, the recommended estimator, the levers ranked."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from mtplan.models.protocol import Measurand
from mtplan.plans import decisions as d


@pytest.mark.parametrize("value, lower, upper, w, verdict", [
    (0.0, -10, 10, 2.5, d.CONFORMS),
    (7.5, -10, 10, 2.5, d.CONFORMS),            # on the acceptance limit
    (7.6, -10, 10, 2.5, d.CONDITIONAL_PASS),
    (10.0, -10, 10, 2.5, d.CONDITIONAL_PASS),   # on the tolerance limit
    (10.1, -10, 10, 2.5, d.CONDITIONAL_FAIL),
    (12.5, -10, 10, 2.5, d.CONDITIONAL_FAIL),   # on the widened limit
    (12.6, -10, 10, 2.5, d.DOES_NOT_CONFORM),
    (-12.6, -10, 10, 2.5, d.DOES_NOT_CONFORM),
    (10.1, -10, 10, 0.0, d.DOES_NOT_CONFORM),   # simple acceptance decides everything
    (9.9, None, 10, 1.0, d.CONDITIONAL_PASS),   # one-sided
    (-1e9, None, 10, 1.0, d.CONFORMS),
])
def test_decide_zones(value, lower, upper, w, verdict):
    assert d.decide(value, lower, upper, w) == verdict


def _result(name, std, bias, trials=4000):
    ms = tuple(Measurand(n, "um") for n in ("a", "b"))
    std, bias = np.asarray(std, float), np.asarray(bias, float)
    return SimpleNamespace(estimator=name, measurands=ms, bias=bias, true=np.zeros(2),
                           mc=SimpleNamespace(std=std, trials=trials, mean=bias,
                                              low=bias - 2 * std, high=bias + 2 * std))


def test_recommend_keeps_the_first_estimator_within_monte_carlo_error():
    results = {"patent": _result("patent", [1.0, 1.0], [0, 0]),
               "joint": _result("joint", [0.99, 1.0], [0, 0])}
    assert d.recommend_estimator(results, ["a", "b"]) == "patent"


def test_recommend_weighs_bias_and_ignores_an_estimator_without_spread():
    results = {"patent": _result("patent", [1.0, 0.0], [3.0, 5.0]),
               "fit": _result("fit", [1.2, 1.1], [0.0, 0.0])}
    assert d.recommend_estimator(results, ["a", "b"]) == "fit"
    assert d.recommend_estimator(results, ["b"]) == "fit"  # u = 0 is not a result


def test_conformity_from_readings_stated_values_and_undeterminable():
    result = _result("fit", [2.0, 1.0], [0, 0])
    measured = SimpleNamespace(
        measurands=result.measurands, estimator="fit", uncertainty="mc",
        value=np.array([30.0, np.nan]), std=np.array([2.0, np.nan]),
        low=np.array([26.0, np.nan]), high=np.array([34.0, np.nan]),
        determinable=np.array([True, False]), reasons={"b": "alpha is quantised"})
    specs = [{"measurand": "a", "lower": -20.0, "upper": 20.0, "rule": "iso14253"},
             {"measurand": "b", "lower": -5.0, "upper": 5.0, "prior": "normal:0,2"}]
    va, vb = d.conformity("p", "Test", specs, result, measured)
    assert va.verdict == d.DOES_NOT_CONFORM and va.guard_band == pytest.approx(4.0)
    assert va.acceptance_limits == pytest.approx((-16.0, 16.0))
    assert va.tur == pytest.approx(40 / 8)
    assert vb.verdict == d.NOT_DETERMINABLE and "quantised" in vb.reason
    assert vb.pfa is not None  # the plan is made even when the value is not determinable
    stated = d.conformity("p", "Test", [{**specs[0], "measured": 1.0}], result, None)[0]
    assert stated.verdict == d.CONFORMS and stated.measured_source == "stated in the study"
    assert d.conformity("p", "Test", specs[:1], result, None)[0].verdict == d.NOT_MEASURED


def test_measured_result_without_the_determinable_field_counts_as_determinable():
    result = _result("fit", [2.0, 1.0], [0, 0])
    measured = SimpleNamespace(measurands=result.measurands, estimator="fit",
                               uncertainty="posterior", value=np.array([1.0, 2.0]),
                               std=np.array([0.5, 0.5]), low=np.array([0.0, 1.0]),
                               high=np.array([2.0, 3.0]))
    v = d.conformity("p", "T", [{"measurand": "a", "upper": 10.0}], result, measured)[0]
    assert v.verdict == d.CONFORMS and "posterior" in v.measured_source


def test_lever_effects_rank_levers_and_skip_properties():
    rows = []
    for field, values, us in (("positions", [3, 6, 12], [2.0, 1.0, 0.5]),
                              ("incline_deg", [10, 20, 30], [1.2, 1.0, 0.9]),
                              ("probe_noise_um", [0.5, 1.0, 2.0], [0.5, 1.0, 2.0])):
        for v, u in zip(values, us, strict=True):
            rows.append({field: v, "estimator": "e", "measurand": "a", "unit": "um",
                         "u": u, "trials": 4000, "duration_s": 10.0 * v, "error": ""})
    frame = pd.DataFrame(rows)
    sweeps = [({"vary": {f: []}}, frame[frame[f].notna()]) for f in
              ("positions", "incline_deg", "probe_noise_um")]
    setup = SimpleNamespace(as_dict=lambda: {"positions": 6, "incline_deg": 20,
                                             "probe_noise_um": 1.0})
    effects = d.lever_effects(("positions", "incline_deg"), setup, sweeps, ["a"], "e")
    assert [e.field for e in effects] == ["positions", "incline_deg"]
    top = effects[0]
    assert (top.base_value, top.u_base, top.best_value, top.u_best) == (6, 1.0, 12, 0.5)
    assert top.gain == pytest.approx(2.0) and top.significant
    assert effects[1].gain == pytest.approx(1.0 / 0.9) and effects[1].significant


def test_u_targets_and_dominant_sources():
    v = d.Verdict(procedure="p", label="T", measurand="a", unit="um", description="",
                  estimator="e", lower=-8.0, upper=8.0, u=1.0, rule="simple")
    assert d.u_targets(None, [v]) == {"a": (1.0, "u for TUR = 4")}
    assert d.u_targets({"targets": {"a": 2.0}, "k": 2}, [v]) == {"a": (1.0, "plan target")}
    budget = pd.DataFrame({"output": ["a", "a", "b"], "input": ["noise", "dwell", "noise"],
                           "share": [0.7, 0.3, 0.4]})
    (top,) = d.dominant_sources(budget, ("dwell_s",), {"noise": "noise_um", "dwell": "dwell_s"})
    assert top["source"] == "noise" and top["field"] == "noise_um" and not top["lever"]
    assert top["measurands"] == [("a", 0.7)]
    assert math.isclose(d.K, 2.0)


def test_readings_that_do_not_fit_get_no_decision_with_why():
    from mtplan.evaluation.fitcheck import FitCheck

    result = _result("fit", [2.0, 1.0], [0, 0])
    bad = FitCheck(chi2=512.0, dof=146, p_value=1e-40, ok=False,
                   worst=[{"row": 40, "column": "z_mm", "reading": "z_mm[1,14]", "z": 31.0}])
    measured = SimpleNamespace(measurands=result.measurands, estimator="fit", uncertainty="mc",
                               value=np.array([1.0, 2.0]), std=np.array([0.5, 0.5]),
                               low=np.array([0.0, 1.0]), high=np.array([2.0, 3.0]), fit=bad)
    specs = [{"measurand": "a", "upper": 10.0}, {"measurand": "b", "lower": 5.0}]
    for v in d.conformity("p", "T", specs, result, measured):  # conforms / not, were it fit
        assert v.verdict == d.NO_FIT == "no decision: the readings do not fit the model"
        assert "chi-square 512" in v.reason and "row 40 z_mm" in v.reason
        assert v.measured is not None  # the value is still shown
    rows = d.summary_rows("s", "p", "T", result, ["a"], [], measured, {}, 1.0)
    assert rows[0].verdict == d.NO_FIT
    for ok in (True, None):  # a passed check, or one that could not be made, decides as usual
        measured.fit = FitCheck(chi2=1.0, dof=1, p_value=0.3, ok=ok)
        assert d.conformity("p", "T", specs[:1], result, measured)[0].verdict == d.CONFORMS


def test_repeats_average_only_the_random_share_of_the_budget():
    """EC0Y's case: 82 % of u^2 is the grid plate's own error, which repeats do not
    average: no number of repeats reaches a U of 10.7 from 13.6, two give about 13.0."""
    import pandas as pd

    budget = pd.DataFrame({"output": ["EC0Y"] * 3 + ["EXX"],
                           "input": ["grid_error", "encoder_noise", "repeatability",
                                     "grid_error"],
                           "share": [0.82, 0.10, 0.08, 1.0]})
    share, top, top_share = d.random_share(budget, "EC0Y")
    assert share == pytest.approx(0.18) and top == "grid_error"
    assert top_share == pytest.approx(0.82)
    assert d.repeats_needed(13.6, 10.7, share) is None
    assert d.repeated_U(13.6, share, 2) == pytest.approx(13.0, abs=0.05)
    # all random: the square-root law; a target already met needs one test
    assert d.repeats_needed(10.0, 5.0, 1.0) == 4
    assert d.repeats_needed(10.0, 12.0, 0.5) == 1
    assert d.repeats_needed(10.0, 9.0, 0.5) == 2  # 10 sqrt(0.5 + 0.25) = 8.66
    assert d.random_share(budget, "nothing") is None
