"""Results as left (readings taken again after an adjustment) and a position tolerance as a
diameter zone (ISO 1101): what the study accepts, how each is decided and what the
certificate says."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mtplan._validate import InvalidInput
from tests.reports.conftest import EXAMPLES

ROTARY = """
title = "C axis adjusted"
seed = 5
trials = 300
[[procedure]]
name = "rotary_axis"
label = "C axis location"
setup = {{ axis = "C", incline_deg = 30, positions = 6, sensor_range_mm = 2.0, sensor_reversal = true }}
estimators = ["patent"]
budget = "mc"
budget_trials = 100
  [[procedure.acceptance]]
  measurand = "EX0C"
  lower = -10.0
  upper = 10.0
  rule = "iso14253"
  [procedure.readings]
  file = "{found}"
  uncertainty = "mc"
  trials = 300
{as_left}
"""

AS_LEFT = """  [procedure.as_left]
  file = "left.csv"
  adjustment = "C axis location corrected by -16 um in X"
"""

BORE = """
title = "Bore position"
seed = 5
trials = 300
[[procedure]]
name = "circle_centre"
label = "Bore"
setup = {{ bore_radius_mm = 250 }}
estimators = ["kasa"]
standards = {standards}
  [[procedure.acceptance]]
  measurand = "bore_position"
  position = ["centre_x", "centre_y"]
  nominal = {nominal}
  diameter = 800.0
  rule = "iso14253"
  [procedure.readings]
  file = "{readings}"
  uncertainty = "mc"
  trials = 300
"""


def _study(tmp_path, text, name="study.toml"):
    from mtplan.plans.study import load_study

    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return load_study(path)


def _decided(study):
    from mtplan.plans import agreement
    from mtplan.plans.study import run_study

    result = run_study(study, progress=False)
    plan = agreement.issue_plan(result)
    agreement.apply_plan(result, plan)
    return result, plan


@pytest.fixture(scope="module")
def adjusted(tmp_path_factory):
    """The demo's C axis, 16 um off in X (as found), measured again with the axis 2 um off
    (as left): a simulated measurement after the adjustment."""
    from mtplan.cli import main

    folder = tmp_path_factory.mktemp("as_left")
    assert main(["simulate", "rotary_axis", "--set", "incline_deg=30", "--set",
                 "sensor_range_mm=2", "--set",
                 "sensor_reversal=true", "--truth",
                 "EX0C_um=2", "--trials", "1", "--seed", "12", "--readings-out",
                 str(folder / "left.csv")]) == 0
    study = _study(folder, ROTARY.format(found=(EXAMPLES / "demo_rotary_axis_reversed.csv")
                                         .as_posix(), as_left=AS_LEFT))
    return _decided(study)


def test_as_left_decides_the_overall_result(adjusted):
    from mtplan.plans.decisions import CONFORMS, DOES_NOT_CONFORM
    from mtplan.reports.certificate import final_verdicts, overall_result

    result, _ = adjusted
    (o,) = result.outcomes
    (found,), (left,) = o.verdicts, o.as_left_verdicts
    assert found.verdict == DOES_NOT_CONFORM and left.verdict == CONFORMS
    # the same rule for both: the plan's guard band, with each evaluation's own U
    assert left.guard_band == found.guard_band and left.measured_u > 0
    assert abs(left.measured) < 10 - left.guard_band < found.measured
    assert final_verdicts(result) == [left]
    assert overall_result(result)[0] == "accepted"


def test_without_as_left_the_result_stays_not_accepted(tmp_path):
    from mtplan.reports.certificate import overall_result

    study = _study(tmp_path, ROTARY.format(found=(EXAMPLES / "demo_rotary_axis_reversed.csv")
                                           .as_posix(), as_left=""))
    result, _ = _decided(study)
    assert not result.outcomes[0].as_left_verdicts
    assert overall_result(result)[0] == "not accepted"


def test_certificate_shows_as_found_and_as_left_side_by_side(adjusted):
    from mtplan.reports.certificate import build_report
    from mtplan.reports.model import Table

    result, plan = adjusted
    doc = build_report(result, plan)
    overall = next(s for s in doc.sections if s.anchor == "overall")
    words = " ".join(b for b in overall.blocks if isinstance(b, str))
    assert "Overall result for the machine tested (test 1): accepted." in words
    assert "uses the results as left" in words and "corrected by -16 um" in words
    results = next(s for s in doc.sections if s.anchor == "results")
    assert results.title == "Results as found and as left"
    (table,) = [b for b in results.blocks if isinstance(b, Table) and "as left" in b.header]
    (row,) = table.rows
    cells = dict(zip(table.header, row, strict=True))
    assert cells["verdict as found"] == "fail"
    assert cells["verdict as left"] == "pass"
    measured = doc.csv["measured"]
    assert set(measured["state"]) == {"as found", "as left"}


def test_as_left_is_validated(tmp_path):
    found = (EXAMPLES / "demo_rotary_axis_reversed.csv").as_posix()
    bad = ROTARY.format(found=found, as_left='  [procedure.as_left]\n  file = "nope.csv"\n'
                        '  when = "later"\n')
    with pytest.raises(InvalidInput) as exc:
        _study(tmp_path, bad)
    text = " ".join(exc.value.problems)
    assert "as_left file 'nope.csv' does not exist" in text
    assert "unknown key 'when'" in text
    no_readings = ROTARY.format(found=found, as_left=AS_LEFT).replace(
        f'  [procedure.readings]\n  file = "{found}"\n  uncertainty = "mc"\n  trials = 300\n',
        "")
    (tmp_path / "left.csv").write_text((EXAMPLES / "demo_rotary_axis_reversed.csv").read_text())
    with pytest.raises(InvalidInput, match=r"'as_left' needs the readings as found"):
        _study(tmp_path, no_readings)


# ------------------------------------------------------------------ ISO 1101 position
def _bore(tmp_path, nominal="[0.0, 0.0]", standards='["ISO 10360-5:2020", "ISO 1101:2017"]'):
    return _study(tmp_path, BORE.format(
        nominal=nominal, standards=standards,
        readings=(EXAMPLES / "circle_centre_readings.csv").as_posix()), "bore.toml")


@pytest.fixture(scope="module")
def bore(tmp_path_factory):
    return _decided(_bore(tmp_path_factory.mktemp("bore")))


def test_position_zone_is_decided_from_the_samples(bore):
    from mtplan.plans.decisions import CONDITIONAL_FAIL, CONDITIONAL_PASS

    result, _ = bore
    (o,) = result.outcomes
    (v,) = o.verdicts
    m = o.measured
    x, y = m.value[0], m.value[1]
    # the example bore lies about 404 um from nominal: a deviation of about 808 um in a
    # zone of 800 um, within the guard band (U about 8 um)
    assert v.measured == pytest.approx(2 * math.hypot(x, y), rel=1e-12)
    assert v.upper == 800.0 and v.lower is None
    assert v.measured_low < 800.0 < v.measured_high
    assert v.verdict in (CONDITIONAL_PASS, CONDITIONAL_FAIL)
    assert 0 < v.p_conform < 0.5 and v.p_conform == v.p_conform_samples
    # far from nominal P is nearly normal: u is twice the coordinates' radial u (the
    # standard deviation of a standard deviation of 300 samples: 4 % at 1 sigma)
    radial = np.array([x, y]) / math.hypot(x, y)
    u_radial = math.sqrt(radial @ m.covariance[:2, :2] @ radial)
    assert v.measured_u == pytest.approx(2 * u_radial, rel=5 * math.sqrt(1 / (2 * 299)))


def test_position_near_nominal_is_rice_not_normal(tmp_path):
    """At the nominal, P = 2|d| of a bivariate normal: its mean over the samples matches a
    large draw from the measured covariance within five standard errors, and its interval
    starts at about zero (a normal interval would reach below it)."""
    from mtplan.plans.decisions import CONFORMS

    probe = _decided(_bore(tmp_path))[0].outcomes[0].measured
    x, y = probe.value[0], probe.value[1]
    result, _ = _decided(_bore(tmp_path, nominal=f"[{float(x)!r}, {float(y)!r}]"))
    (v,) = result.outcomes[0].verdicts
    assert v.measured == pytest.approx(0.0, abs=1e-9)
    assert v.verdict == CONFORMS
    cov = result.outcomes[0].measured.covariance[:2, :2]
    rng = np.random.default_rng(np.random.SeedSequence(2024))
    big = 2 * np.hypot(*rng.multivariate_normal([0, 0], cov, size=400_000).T)
    assert 0 <= v.measured_low < 0.2 * big.std()
    assert v.measured_high > 3 * np.sqrt(np.trace(cov) / 2)
    assert v.measured_u == pytest.approx(big.std(), rel=5 / math.sqrt(2 * 299))


def test_iso1101_cited_only_with_a_position_zone(tmp_path, bore):
    from mtplan.reports.certificate import build_report

    text = BORE.format(nominal="[0.0, 0.0]", standards='["ISO 1101:2017"]',
                       readings=(EXAMPLES / "circle_centre_readings.csv").as_posix())
    per_coordinate = text.split("  [[procedure.acceptance]]")[0]
    with pytest.raises(InvalidInput, match=r"cites 'ISO 1101:2017', which requires a "
                                           r"position tolerance as a diameter zone"):
        _study(tmp_path, per_coordinate)
    result, plan = bore
    doc = build_report(result, plan)
    assert "ISO\u00a01101:2017" in doc.methods[0][2]
    (rule,) = plan["rules"]
    assert rule["position"] == ["centre_x", "centre_y"] and rule["upper"] == 800.0


def test_position_zone_is_validated_and_held_to_the_plan(tmp_path, bore):
    from mtplan.plans import agreement

    bad = BORE.format(nominal='["a", 0]', standards="[]", readings=(
        EXAMPLES / "circle_centre_readings.csv").as_posix()).replace(
        '"centre_y"]', '"centre_q"]').replace("800.0", "-1")
    with pytest.raises(InvalidInput) as exc:
        _study(tmp_path, bad)
    text = " ".join(exc.value.problems)
    assert "'position' must name two different coordinate measurands" in text
    assert "'nominal' must be the two coordinates' nominal values" in text
    assert "'diameter' must be a number > 0" in text
    _, plan = bore
    moved = _bore(tmp_path, nominal="[0.0, 10.0]")
    with pytest.raises(InvalidInput, match=r"bore_position nominal: plan .* says \[0.0, 0.0\]"):
        agreement.check_study(moved, plan)


def test_as_left_is_compared_with_the_residual_predicted_after_compensation(adjusted):
    """The corrected EX0C as left against the residual predicted from the readings as
    found (the compensation package's, printed as it computes it), with E_n."""
    from mtplan.compensation.predicted import Predicted
    from mtplan.reports.certificate import build_report
    from mtplan.reports.labels import fmt
    from mtplan.reports.model import Table

    result, plan = adjusted
    (o,) = result.outcomes
    assert isinstance(o.compensation, Predicted)
    lo, hi, _ = o.compensation.of("EX0C")
    doc = build_report(result, plan)
    section = next(s for s in doc.sections if s.anchor == "along")
    (table,) = [b for b in section.blocks if isinstance(b, Table)]
    (row,) = table.rows
    cells = dict(zip(table.header, row, strict=True))
    (left,) = o.as_left_verdicts
    U = 2 * left.measured_u
    assert cells["predicted after compensation"] == f"[{fmt(lo, U)}, {fmt(hi, U)}]"
    en = (left.measured - (lo + hi) / 2) / np.hypot((hi - lo) / 2, U)
    assert cells["E_n"] == f"{en:.2f}"
    assert cells["agreement"] == ("consistent" if abs(en) <= 1 else "NOT consistent")
    results = next(s for s in doc.sections if s.anchor == "results")
    verdicts = next(b for b in results.blocks if isinstance(b, Table)
                    and "after compensation (predicted)" in b.header)
    cells = dict(zip(verdicts.header, verdicts.rows[0], strict=True))
    assert cells["after compensation (predicted)"] == \
        f"[{fmt(lo, 2 * o.verdicts[0].measured_u)}, {fmt(hi, 2 * o.verdicts[0].measured_u)}]"
