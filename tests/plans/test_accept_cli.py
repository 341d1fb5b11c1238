"""`mtplan accept` and the acceptance-driven `mtplan plan` on the command line."""

from __future__ import annotations

import json

import pytest

from mtplan import cli


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_accept_reference_case_json(capsys):
    code, out, err = run(capsys, "accept", "--lower", "9", "--upper", "10", "--u", "0.1",
                         "--prior", "normal:9.5,0.3", "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert set(doc) == {"acceptance_limits", "specific_risk", "pfa", "pfr", "conditional_pfa",
                        "tur", "cm", "judgement"}
    assert doc["judgement"]["quality"] == "is decided, at the risks stated"
    assert doc["pfa"] == pytest.approx(0.0189422, abs=5e-8)
    assert doc["pfr"] == pytest.approx(0.0372078, abs=5e-8)


def test_accept_one_sided_target_pfa(capsys):
    code, out, err = run(capsys, "accept", "--upper", "2", "--u", "0.25", "--prior", "gamma:4,0.25",
                         "--rule", "target-pfa:0.001", "--json")
    assert code == 0, err
    assert json.loads(out)["acceptance_limits"][1] == pytest.approx(1.67183, abs=5e-6)


def test_accept_specific_risk_text(capsys):
    code, out, _ = run(capsys, "accept", "--lower", "9", "--upper", "10", "--u", "0.1",
                       "--measured", "9.8")
    assert code == 0 and "2.275 %" in out


@pytest.mark.parametrize("argv", [
    ["accept", "--lower", "9", "--upper", "10", "--u", "0.1", "--prior", "bogus"],
    ["accept", "--lower", "9", "--upper", "10", "--u", "-1"],
    ["accept", "--lower", "9", "--upper", "10", "--u", "0.1", "--rule", "guard:x"],
    ["accept", "--u", "0.1"],
])
def test_accept_bad_input(capsys, argv):
    code, _, err = run(capsys, *argv)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_plan_keeps_false_accept_under_the_limit(capsys):
    code, out, err = run(capsys, "plan", "circle_centre", "--estimator", "geometric",
                         "--vary", "n_points=3,4,5,8", "--tolerance", "centre_x=-3,3",
                         "--prior", "normal:0,1.5", "--max-pfa", "0.01", "--trials", "2000",
                         "--json")
    assert code == 0, err
    doc = json.loads(out)
    best = doc["best"]
    assert best["setup"]["n_points"] == 5  # 3 and 4 points leave too much false accept
    from mtplan.plans.acceptance import plan_acceptance

    assert plan_acceptance(-3, 3, best["confirmed"]["centre_x"], prior="normal:0,1.5").pfa <= 0.01
    code, _, err = run(capsys, "plan", "circle_centre", "--vary", "n_points=3,4",
                       "--tolerance", "centre_x=-3,3", "--prior", "normal:0,1.5",
                       "--max-pfa", "0.0001", "--trials", "500")
    assert code == 2 and "lowest reachable" in err
    code, _, err = run(capsys, "plan", "circle_centre", "--tolerance", "nope=-3,3",
                       "--prior", "normal:0,1.5", "--max-pfa", "0.01")
    assert code == 2 and "nope" in err


def test_plan_optimize_searches_the_a_axis_angles(capsys):
    """Continuous design search: the A-axis angles within +-27 deg (the sensor's table at
    the 10 deg incline) for u(EB0A), against a grid."""
    code, out, err = run(capsys, "plan", "rotary_axis", "--set", "axis=A", "--set",
                         "angles_deg=-27,-18,-9,0,9,18,27", "--optimize", "angles_deg=-27:27",
                         "--criterion", "u:EB0A", "--vary",
                         "angles_deg=-27,-18,-9,0,9,18,27|-27,-24,-21,0,21,24,27", "--json")
    assert code == 0, err
    doc = json.loads(out)["design_search"]
    assert doc["value"] <= doc["grid_best"]["value"] * (1 + 1e-9)
    assert doc["value"] < 0.9 * doc["start_value"]  # ends-and-middle beats equal spacing
    angles = sorted(doc["setup"]["angles_deg"])
    assert angles[0] == pytest.approx(-27, abs=0.5) and angles[-1] == pytest.approx(27, abs=0.5)
    code, _, err = run(capsys, "plan", "rotary_axis", "--optimize", "incline_deg=10")
    assert code == 2 and "LO:HI" in err


def test_the_pareto_front_names_the_set_up_as_given(capsys):
    """A candidate that changes nothing (circle_centre's default three points) is named on
    the front, not printed as an empty line."""
    code, out, err = run(capsys, "plan", "circle_centre", "--vary", "n_points=3,4",
                         "--target", "centre_x<=5", "--trials", "100")
    assert code == 0, err
    front = out.split("Pareto front")[1].splitlines()[1:]
    assert front[0].endswith("the set-up as given") and front[1].endswith("n_points=4")
