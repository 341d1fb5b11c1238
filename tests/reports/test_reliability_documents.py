"""What one bad reading can do unseen, in the plan (at the agreed set-up, before the test)
and in the report (at the measured readings): the figures the reliability service gives."""

from __future__ import annotations

import pytest

from mtplan.evaluation.reliability import reliability
from mtplan.evaluation.readings import read_readings
from tests.reports.test_certificate import _flat, _pages


def test_plan_and_report_state_the_mdb_and_the_largest_unseen_shift(small_result,
                                                                    small_report):
    o = small_result.outcomes[0]
    ps = o.spec
    before = reliability(ps.procedure, ps.setup, ps.truth, estimator=o.recommended)
    assert o.reliability.measurands.keys() == before.measurands.keys()
    for name, row in before.measurands.items():
        shown = o.reliability.measurands[name]
        assert shown["shift"] == pytest.approx(row["shift"], rel=1e-9)
        u = float(o.results[o.recommended].mc.std[[m.name for m in
                                                   o.results[o.recommended].measurands]
                                                  .index(name)])
        assert shown["in_u"] == pytest.approx(row["shift"] / u, rel=1e-9)
    plan = _flat(_pages(small_report / "plan.pdf"))
    assert "what one bad reading can do unseen, predicted for the agreed set-up" in plan
    assert "a contact along its probing direction" in plan
    for row in o.reliability.measurands.values():
        assert f"{row['shift']:.3g}" in plan and f"{row['in_u']:.2g}" in plan

    after = o.measured.sections["reliability"]
    readings = read_readings(ps.procedure, o.measured.setup, ps.readings["file"])
    again = reliability(ps.procedure, o.measured.setup, readings=readings,
                        estimator=o.measured.estimator)
    report = _flat(_pages(small_report / "report.pdf"))
    assert "What one bad reading can do unseen" in report
    for name, row in after.measurands.items():
        assert row["shift"] == pytest.approx(again.measurands[name]["shift"], rel=1e-6)
        assert f"{row['shift']:.3g}" in report
    assert "MDB" in report and "minimal detectable bias" in report
