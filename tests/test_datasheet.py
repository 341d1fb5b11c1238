"""The instruments' data sheets: no default set-up is outside them, and a set-up outside
them (accepted explicitly) says so in every output: simulate, linearize and estimate (their
JSON), the test plan and the test report.

The rule is the procedure contract's (``SetupBase.datasheet_notes``, generic none), so the
first test runs over every registered procedure; rotary_axis is the procedure whose
instrument states a range a set-up can leave (its sensor's angle table ends at 30 deg).
"""

from __future__ import annotations

import json

import pytest

from mtplan import cli
from mtplan.models import get, registry
from mtplan.models.protocol import DATASHEET_NOTE, SetupBase

#: the patent's A test, +-45 deg at a 20 deg incline: 48.4 deg of tilt, beyond the table
WIDE = dict(axis="A", incline_deg=20.0, range_deg=90.0, sensor_max_tilt_deg=50.0,
            sensor_extrapolate_table=True)
WIDE_ARGS = [a for k, v in WIDE.items() for a in ("--set", f"{k}={v}")]


@pytest.mark.parametrize("name", sorted(registry()))
def test_no_default_set_up_is_outside_its_data_sheets(name):
    proc = get(name)
    setup = proc.Setup()
    assert setup.datasheet_notes() == []
    assert not any(n.startswith(DATASHEET_NOTE) for n in setup.notes())
    # the notes are the contract's combination: a procedure overrides its parts only, so
    # that no output can leave the data-sheet notes out
    assert type(setup).notes is SetupBase.notes


def test_the_rotary_axis_defaults_of_every_axis_stay_within_the_table():
    proc = get("rotary_axis")
    for axis in ("C", "A", "CA"):
        assert proc.setup(axis=axis).datasheet_notes() == []
    note = proc.setup(WIDE).datasheet_notes()
    assert len(note) == 1 and note[0].startswith(DATASHEET_NOTE) and "48.4 deg" in note[0]


def _json(capsys, *argv) -> dict:
    code = cli.main(list(argv))
    out = capsys.readouterr().out
    assert code == 0, out
    return json.loads(out)


def _has_note(notes) -> bool:
    return any(n.startswith(DATASHEET_NOTE) and "48.4 deg" in n and "extrapolated" in n
               for n in notes)


def test_a_set_up_outside_the_data_sheet_says_so_in_simulate_linearize_and_estimate(
        capsys, tmp_path):
    readings = tmp_path / "wide.csv"
    doc = _json(capsys, "simulate", "rotary_axis", *WIDE_ARGS, "--trials", "40", "--seed", "1",
                "--json", "--readings-out", str(readings))
    assert _has_note(doc["notes"])
    doc = _json(capsys, "linearize", "rotary_axis", *WIDE_ARGS, "--json")
    assert _has_note(doc["notes"])
    doc = _json(capsys, "estimate", "rotary_axis", str(readings), *WIDE_ARGS, "--trials", "40",
                "--jobs", "1", "--json")
    assert _has_note(doc["notes"])
    # and the default set-up's outputs carry none
    doc = _json(capsys, "linearize", "rotary_axis", "--set", "axis=A", "--json")
    assert not any(n.startswith(DATASHEET_NOTE) for n in doc["notes"])


STUDY = """
title = "Data sheet"
seed = 5
trials = 200
simulated = true
[header]
document = "DS-1"
date = 2024-01-02
[[procedure]]
name = "rotary_axis"
label = "A axis beyond the table"
setup = {{ axis = "A", incline_deg = 20, range_deg = 90, sensor_max_tilt_deg = 50, sensor_extrapolate_table = true }}
estimators = ["patent"]
  [[procedure.acceptance]]
  measurand = "EY0A"
  lower = -40.0
  upper = 40.0
  rule = "simple"
  [procedure.readings]
  file = "{readings}"
  uncertainty = "mc"
  trials = 200
"""


def test_a_set_up_outside_the_data_sheet_says_so_in_the_plan_and_the_report(tmp_path, capsys):
    from mtplan.plans import agreement
    from mtplan.plans.study import load_study, run_study
    from mtplan.reports.certificate import build_plan, build_report
    from mtplan.reports.render import render_html

    readings = tmp_path / "wide.csv"
    assert cli.main(["simulate", "rotary_axis", *WIDE_ARGS, "--trials", "1", "--seed", "2",
                     "--readings-out", str(readings)]) == 0
    capsys.readouterr()
    path = tmp_path / "study.toml"
    path.write_text(STUDY.format(readings=readings.as_posix()), encoding="utf-8")
    result = run_study(load_study(path), progress=False, command="test")
    plan = agreement.issue_plan(result)
    plan_html = render_html(build_plan(result, plan))
    agreement.apply_plan(result, plan)
    report_html = render_html(build_report(result, plan))
    for html in (plan_html, report_html):
        assert "Outside the instruments" in html
        assert "48.4 deg" in html and "extrapolated" in html
    # the plan twice (the agreement's annex and the test's page), the report with the results
    assert plan_html.count("Outside the instruments") >= 2
