"""What the plan agrees is checked in the report, not only printed: the recorded test
conditions against the required ones, the date and time of the test, and the terms under
the fingerprint (the map of tests to machines, the set-ups, the instruments). Each case is
read from the rendered PDF's text; the small study's result is computed once
(conftest.py) and decided again under an altered study, so each case costs one render."""

from __future__ import annotations

import copy
import json
import re
import subprocess

import pandas as pd
import pytest

from tests.reports.conftest import need


def _text(pdf) -> str:
    need("pdftotext")
    out = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], check=True,
                         capture_output=True, text=True).stdout
    return " ".join(out.split())


def _altered(small_study_file, tmp_path, *changes) -> object:
    """The small study with each (old, new) text replaced once."""
    from mtplan.plans.study import load_study

    text = small_study_file.read_text(encoding="utf-8")
    for old, new in changes:
        assert old in text, old
        text = text.replace(old, new, 1)
    path = tmp_path / "altered.toml"
    path.write_text(text, encoding="utf-8")
    return path


def _report(small_result, small_report, study_path, out, plan=None):
    """The small study's result decided with ``plan`` (default: the small report's plan) as
    if the study were ``study_path``: (the report's text, verdicts.csv)."""
    from mtplan.plans.study import load_study
    from mtplan.reports import write_report

    result = copy.deepcopy(small_result)
    result.study = load_study(study_path)
    if plan is None:
        plan = json.loads((small_report / "plan.json").read_text(encoding="utf-8"))
    write_report(result, out, plan)
    return (_text(out / "report.pdf"),
            pd.read_csv(out / "results" / "verdicts.csv").set_index("measurand"))


def _agreed(result, **requirements) -> dict:
    """The plan of the small study's result with these required conditions (a genuine plan:
    issued, fingerprinted)."""
    from mtplan.plans.agreement import fingerprint, issue_plan, signed_content

    plan = issue_plan(result)
    plan["conditions"] = {**plan["conditions"], **requirements}
    plan["fingerprint"] = fingerprint(signed_content(plan))
    return plan


UNKEPT = [("temperature_max_c = 20.8", "temperature_max_c = 23.5\n"
           "temperature_change_c_per_h = 0.9\nwarm_up_min = 5"),
          ("compensation = false\n[requirements]", "compensation = false\n"
           "how = { temperature = \"two air thermometers, logged\" }\n[requirements]")]


def test_conditions_outside_the_agreement_or_not_recorded(small_study_file, small_result,
                                                          small_report, tmp_path):
    """Temperature, its change, the warm-up and the compensation recorded outside what the
    plan requires, and a required controller not recorded: each a deviation naming the
    clause that applied, and no statement of conformity on the test (the plan's clause
    keeps no verdict). Set-ups and instruments changed since the plan are listed item by
    item in the same report."""
    from mtplan.plans.conditions import NO_CONDITION

    path = _altered(small_study_file, tmp_path, *UNKEPT,
                    ('serial = "TP-0042"', 'serial = "TP-0043"'),
                    ('estimators = ["three_point", "kasa"]',
                     'estimators = ["three_point", "kasa"]\nsetup = { n_points = 6 }'))
    plan = _agreed(small_result,
                   gradient_c_per_h=0.5, warm_up_min=30.0, compensation=True,
                   controller="CNC 9 rev. 4",
                   outside="the test stops until the condition is back")
    text, verdicts = _report(small_result, small_report, path, tmp_path / "out", plan)
    assert set(verdicts["verdict"]) == {NO_CONDITION}
    assert "Overall result for machine SN-42 (test 1): no decision" in text
    clause = ("Clause applied: “Outside a required condition: the test stops until the "
              "condition is back”, which keeps no verdict; no statement of conformity is made "
              "on test 1.")
    for line in ("Test condition ambient temperature (lowest to highest): required 19.5 to "
                 "21.5 °C; recorded 20.2 to 23.5 °C (outside the agreement).",
                 "Test condition ambient temperature change: required at most 0.5 °C/h; "
                 "recorded 0.9 °C/h (outside the agreement).",
                 "Test condition warm-up: required at least 30 min; recorded 5 min; 45 min axis "
                 "cycling (outside the agreement).",
                 "Test condition machine's error compensation: required on; recorded off "
                 "(outside the agreement).",
                 "Test condition controller and compensation tables' version: required CNC 9 "
                 "rev. 4; not recorded."):
        assert line + " " + clause in text, line
    # the conditions table: required, recorded, how measured, finding
    table = text[text.index("Test conditions (ISO 230-1 6.1)"):text.index("Instruments used")]
    assert table.count("OUTSIDE") == 4, table
    assert len(re.findall(r"NOT (\S+ ){0,4}RECORDED", table)) == 1, table  # a cell may wrap
    assert "two air thermometers" in table and "20.2 to 23.5 °C" in table
    # the terms under the fingerprint, item by item
    assert ("The set-up of test 1 (Bore <script>alert(1)</script> & co) differs from plan "
            "DOC-<b>1</b>-PLAN: n_points 3 in the plan, 6 in the study.") in text
    assert ("Instrument Touch probe: serial TP-0043 used, plan DOC-<b>1</b>-PLAN agrees serial "
            "TP-0042 (replaced).") in text


def test_a_clause_that_keeps_the_verdicts_is_named(small_study_file, small_result,
                                                   small_report, tmp_path):
    """A condition outside the agreement whose clause in the plan keeps the verdicts
    (``outside_effect``): a deviation that says so, and the verdicts stand."""
    path = _altered(small_study_file, tmp_path, ("compensation = false\n[requirements]",
                                                 "compensation = true\n[requirements]"))
    plan = _agreed(small_result, outside_effect={"compensation": "verdicts stand"})
    text, verdicts = _report(small_result, small_report, path, tmp_path / "out", plan)
    assert verdicts.loc["centre_x", "verdict"] == "fail"
    assert ("Test condition machine's error compensation: required off; recorded on (outside "
            "the agreement). Clause applied: the plan's outside_effect keeps the verdicts for "
            "compensation; the verdicts of test 1 stand.") in text
    assert "OUTSIDE" in text


def test_a_calibration_that_cannot_be_checked_blocks_the_statement(small_study_file,
                                                                    small_result, small_report,
                                                                    tmp_path):
    """Without a test date no calibration can be checked: a deviation, and no statement of
    conformity on the tests that used the instrument (as for an expired one)."""
    from mtplan.plans.agreement import NO_INSTRUMENT

    path = _altered(small_study_file, tmp_path, ("date = 2024-01-02\n", ""))
    text, verdicts = _report(small_result, small_report, path, tmp_path / "out")
    assert set(verdicts["verdict"]) == {NO_INSTRUMENT}
    assert ("Touch probe (serial TP-0042): the date of the test is not stated, so its "
            "calibration could not be checked against it; no statement of conformity is made "
            "on the tests that used it") in text
    assert "not checked" in text
    assert "Date of the test: not recorded" in text


def _cli(capsys, *argv) -> tuple[int, str]:
    from mtplan.cli import main

    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err.strip()


@pytest.mark.parametrize("old, new, missing", [
    ("date = 2024-01-02\n", "",
     "The study does not record the date of the test ([header] date)"),
    ('time = "09:00-10:30"\n', "", "does not record the time of test 1"),
])
def test_a_report_under_a_plan_needs_the_date_and_time(small_study_file, small_report,
                                                       tmp_path, capsys, old, new, missing):
    path = _altered(small_study_file, tmp_path, (old, new))
    code, err = _cli(capsys, "report", path, "--out", tmp_path / "out", "--plan",
                     small_report / "plan.json")
    assert code == 2 and len(err.splitlines()) == 1, err
    assert missing in err, err
    assert not (tmp_path / "out").exists()


def test_plan_only_refuses_a_plan_dated_after_the_test(small_study_file, tmp_path, capsys):
    path = _altered(small_study_file, tmp_path,
                    ("plan_date = 2023-12-20", "plan_date = 2024-01-05"))
    code, err = _cli(capsys, "report", path, "--out", tmp_path / "out", "--plan-only")
    assert code == 2 and len(err.splitlines()) == 1, err
    assert "issued on 2024-01-05, after the test on 2024-01-02" in err


def test_the_plan_keeps_its_terms_and_when_it_was_computed(small_report, small_result):
    plan = json.loads((small_report / "plan.json").read_text(encoding="utf-8"))
    assert plan["computed"] == small_result.provenance["date"]
    assert plan["tests"][0]["machine"] == "SN-42"
    assert plan["tests"][0]["setup"]["n_points"] == 3
    assert [i["serial"] for i in plan["instruments"]] == ["TP-0042"]
    assert plan["item"]["machine_serial"] == "SN-42" and plan["method_version"]


def test_a_test_moved_to_another_machine_is_refused(small_study_file, small_report, tmp_path,
                                                    capsys):
    """The plan agrees test 1 on SN-42; the study runs it on SN-43 (both machines on the
    cover of each): refused in one line naming the test and both machines."""
    from mtplan.plans.agreement import fingerprint, signed_content

    plan = json.loads((small_report / "plan.json").read_text(encoding="utf-8"))
    plan["item"]["machine_serial"] = "SN-42, SN-43"
    plan["fingerprint"] = fingerprint(signed_content(plan))
    agreed = tmp_path / "plan.json"
    agreed.write_text(json.dumps(plan), encoding="utf-8")
    path = _altered(small_study_file, tmp_path,
                    ('machine_serial = "SN-42"', 'machine_serial = "SN-42, SN-43"'),
                    ('time = "09:00-10:30"', 'time = "09:00-10:30"\nmachine = "SN-43"'))
    code, err = _cli(capsys, "report", path, "--out", tmp_path / "out", "--plan", agreed)
    assert code == 2 and len(err.splitlines()) == 1, err
    assert ("The study runs test 1 (Bore <script>alert(1)</script> & co) on machine SN-43, "
            "plan DOC-<b>1</b>-PLAN on SN-42: the plan agrees each test's machine") in err


def test_the_demo_records_its_conditions_inside_the_agreement():
    """The demo records every condition its plan requires, inside the agreement: no
    condition deviation, no blocked test."""
    from mtplan.cli.report import demo_study_path
    from mtplan.plans.conditions import WITHIN, check_conditions
    from mtplan.plans.study import load_study

    study = load_study(demo_study_path())
    findings, deviations, blocked = check_conditions(study, study.requirements)
    assert {f.check for f in findings} == {"temperature", "temperature_change", "warm_up",
                                          "compensation", "controller"}
    assert all(f.state == WITHIN and f.how for f in findings), findings
    assert deviations == [] and blocked == {}
    assert all(ps.time for ps in study.procedures)


def test_a_condition_per_machine_affects_that_machines_tests_only():
    """Compensation agreed on for both machines, recorded off on the gantry: the gantry's
    test gets no statement, the other machine's tests keep theirs."""
    import dataclasses

    from mtplan.cli.report import demo_study_path
    from mtplan.plans.conditions import OUTSIDE, check_conditions
    from mtplan.plans.study import load_study

    study = load_study(demo_study_path())
    off = {"DEMO-5AX-0001": True, "DEMO-GTY-0002": False}
    altered = dataclasses.replace(study, conditions={**study.conditions, "compensation": off})
    findings, deviations, blocked = check_conditions(altered, study.requirements)
    assert [(f.machine, f.state) for f in findings if f.state != "within"] == [
        ("DEMO-GTY-0002", OUTSIDE)]
    assert [label for _, label in blocked] == [study.procedures[4].label]
    assert deviations == [
        "Test condition machine's error compensation on machine DEMO-GTY-0002: required on; "
        "recorded off (outside the agreement). Clause applied: “Outside a required "
        f"condition: {study.requirements['outside']}”, which keeps no verdict; no statement "
        "of conformity is made on test 5."]


def test_a_test_on_a_machine_the_cover_does_not_name_is_refused(small_study_file, tmp_path):
    from mtplan._validate import InvalidInput
    from mtplan.plans.study import load_study

    path = _altered(small_study_file, tmp_path,
                    ('time = "09:00-10:30"', 'time = "09:00-10:30"\nmachine = "SN-99"'))
    with pytest.raises(InvalidInput, match="'machine' 'SN-99' is not among the header's "
                                           r"'machine_serial' \(SN-42\)"):
        load_study(path)


def test_a_temperature_log_gives_the_band_and_the_change_per_hour(small_study_file, tmp_path):
    """A log instead of the lowest and highest: its extremes, and the largest change within
    any hour (here 0.8 °C between 09:20 and 10:10, although the log drifts back); a test
    whose time the log does not span has no recorded temperature."""
    from mtplan.plans.conditions import NOT_RECORDED, OUTSIDE, WITHIN, check_conditions
    from mtplan.plans.study import load_study

    (tmp_path / "log.csv").write_text(
        "time,temperature_c\n08:00,20.4\n09:20,20.3\n09:50,20.8\n10:10,21.1\n11:30,20.5\n",
        encoding="utf-8")
    path = _altered(small_study_file, tmp_path,
                    ("temperature_min_c = 20.2\ntemperature_max_c = 20.8",
                     'temperature_log = "log.csv"'))
    study = load_study(path)
    assert study.conditions["temperature_min_c"] == 20.3
    assert study.conditions["temperature_max_c"] == 21.1
    assert study.conditions["temperature_change_c_per_h"] == pytest.approx(0.8)
    findings, deviations, _ = check_conditions(study, {"temperature_c": [19.5, 21.5],
                                                       "gradient_c_per_h": 0.5})
    assert [f.state for f in findings] == [WITHIN, OUTSIDE]
    assert findings[0].recorded == ("20.3 to 21.1 °C (log log.csv, 5 readings from 08:00 to "
                                    "11:30)")
    # a log that starts after the test did: the test's temperature is not recorded
    (tmp_path / "log.csv").write_text("time,temperature_c\n09:30,20.4\n11:30,20.5\n",
                                      encoding="utf-8")
    findings, deviations, blocked = check_conditions(load_study(path),
                                                     {"temperature_c": [19.5, 21.5]})
    assert [(f.state, f.tests) for f in findings] == [(WITHIN, ()), (NOT_RECORDED, (1,))]
    assert deviations[0].startswith(
        "Test condition ambient temperature (lowest to highest): required 19.5 to 21.5 °C; "
        "not recorded during test 1: the log spans 09:30 to 11:30. Clause applied:")
    assert len(blocked) == 1
    bad = _altered(small_study_file, tmp_path, ("temperature_min_c = 20.2",
                                                'temperature_log = "log.csv"'))
    (tmp_path / "log.csv").write_text("time,temperature_c\n08:00,20.4\n07:00,hot\n",
                                      encoding="utf-8")
    from mtplan._validate import InvalidInput

    with pytest.raises(InvalidInput) as err:
        load_study(bad)
    text = " ".join(err.value.problems)
    assert "state temperature_max_c and a 'temperature_log': give one or the other" in text
