"""The test plan agreed before and the test report (certificate) after: the plan's number
and fingerprint cited and its rules applied, a changed rule refused, the ISO/IEC 17025
7.8.2.1 items on the pages, the overall result and its actions, probabilities that agree
with the intervals, and every measured value in results/measured.csv."""

from __future__ import annotations

import copy
import json
import re
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mtplan.reports.certificate import WATERMARK
from tests.reports.conftest import need


def _pages(pdf) -> list[str]:
    need("pdftotext")
    text = subprocess.run(["pdftotext", "-layout", str(pdf), "-"], check=True,
                          capture_output=True, text=True).stdout
    return [p for p in text.split("\f") if p.strip()]


def _flat(pages) -> str:
    return " ".join(" ".join(pages).split())


# ------------------------------------------------------------------ plan and report
def test_plan_has_number_and_fingerprint_and_report_cites_both(small_report):
    from mtplan.plans.agreement import fingerprint, signed_content

    plan = json.loads((small_report / "plan.json").read_text(encoding="utf-8"))
    assert plan["fingerprint"] == fingerprint(signed_content(plan))
    assert len(plan["fingerprint"]) == 64
    # everything the parties sign is under the fingerprint
    assert {"document", "revision", "issued", "parties", "conditions", "rules"} <= set(plan)
    assert plan["parties"]["customer"] == "Customer & <i>Co</i>"
    assert plan["document"] == "DOC-<b>1</b>-PLAN"
    plan_text = _flat(_pages(small_report / "plan.pdf"))
    assert plan["document"] in plan_text and plan["fingerprint"] in plan_text
    cover = " ".join(_pages(small_report / "report.pdf")[0].split())
    assert plan["document"] in cover and plan["fingerprint"] in cover  # all 64 digits


def test_plan_only_then_report_against_it(small_study_file, tmp_path, capsys):
    """The workflow: --plan-only before the test (no readings used, no report), then
    --plan plan.json after it: the report cites that plan and lists no deviation."""
    from mtplan.cli import main

    plan_dir, report_dir = tmp_path / "plan", tmp_path / "report"
    assert main(["report", str(small_study_file), "--out", str(plan_dir), "--plan-only"]) == 0
    assert (plan_dir / "plan.pdf").exists() and (plan_dir / "plan.json").exists()
    assert not (plan_dir / "report.pdf").exists()
    assert not (plan_dir / "results" / "measured.csv").exists()
    plan = json.loads((plan_dir / "plan.json").read_text(encoding="utf-8"))
    capsys.readouterr()
    assert main(["report", str(small_study_file), "--out", str(report_dir), "--plan",
                 str(plan_dir / "plan.json")]) == 0
    out = capsys.readouterr().out
    assert str(report_dir / "report.pdf") in out and "plan.pdf" not in out
    text = _flat(_pages(report_dir / "report.pdf"))
    assert plan["fingerprint"] in text
    assert "Deviations from the test plan, additions and exclusions: • none" in text
    verdicts = pd.read_csv(report_dir / "results" / "verdicts.csv").set_index("measurand")
    assert verdicts.loc["centre_x", "verdict"] == "fail"


def test_report_applies_the_plans_guard_bands(small_report):
    plan = json.loads((small_report / "plan.json").read_text(encoding="utf-8"))
    verdicts = pd.read_csv(small_report / "results" / "verdicts.csv").set_index("measurand")
    for rule in plan["rules"]:
        row = verdicts.loc[rule["measurand"]]
        assert row["guard_band"] == rule["guard_band"]
        assert row["acceptance_upper"] == rule["acceptance_upper"]
        assert row["u"] == rule["u_planned"]


@pytest.mark.parametrize("old, new, field", [
    ("upper = 20.0", "upper = 25.0", "upper"),
    ('rule = "guard:0.5"', 'rule = "iso14253"', "rule"),
    ('population_source = "bores of 12 earlier parts"', 'population_source = "a guess"',
     "population_source"),
])
def test_changed_rule_after_the_plan_is_refused_in_one_line(small_study_file, small_report,
                                                            tmp_path, capsys, old, new,
                                                            field):
    from mtplan.cli import main

    text = small_study_file.read_text(encoding="utf-8")
    assert old in text
    changed = tmp_path / "changed.toml"
    changed.write_text(text.replace(old, new, 1), encoding="utf-8")
    code = main(["report", str(changed), "--out", str(tmp_path / "out"), "--plan",
                 str(small_report / "plan.json")])
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1, err
    assert f"centre_x {field}: plan DOC-<b>1</b>-PLAN says" in err, err
    assert not (tmp_path / "out" / "report.pdf").exists()


def test_unchanged_study_passes_and_an_edited_plan_is_refused(small_study_file, small_report,
                                                              tmp_path):
    from mtplan._validate import InvalidInput
    from mtplan.plans.agreement import check_study, read_plan
    from mtplan.plans.study import load_study

    plan = read_plan(small_report / "plan.json")
    check_study(load_study(small_study_file), plan)  # the same rules: no problem
    plan["rules"][0]["guard_band"] *= 2
    edited = tmp_path / "plan.json"
    edited.write_text(json.dumps(plan), encoding="utf-8")
    with pytest.raises(InvalidInput, match="does not match its fingerprint"):
        read_plan(edited)


def _cli(argv, capsys) -> tuple[int, str]:
    from mtplan.cli import main

    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err.strip()


@pytest.mark.parametrize("field, value", [("issued", "2023-12-01"), ("revision", "C"),
                                          ("parties", {"customer": "Someone else"})])
def test_an_edited_plan_fails_its_fingerprint_and_is_refused(small_study_file, small_report,
                                                             tmp_path, capsys, field, value):
    """The fingerprint covers the issue date, the revision and the parties, not only the
    rules: a plan.json edited in any of them is refused in one line that prints the full
    fingerprint, and no report is written."""
    plan = json.loads((small_report / "plan.json").read_text(encoding="utf-8"))
    plan[field] = value
    edited = tmp_path / "plan.json"
    edited.write_text(json.dumps(plan), encoding="utf-8")
    code, err = _cli(["report", small_study_file, "--out", tmp_path / "out", "--plan", edited],
                     capsys)
    assert code == 2 and len(err.splitlines()) == 1, err
    assert "does not match its fingerprint" in err and plan["fingerprint"] in err
    assert not (tmp_path / "out" / "report.pdf").exists()


def _plan_issued(small_report, tmp_path, issued) -> Path:
    """The small study's plan as if issued on ``issued`` (fingerprint renewed: a genuine
    plan of that date)."""
    from mtplan.plans.agreement import fingerprint, signed_content

    plan = json.loads((small_report / "plan.json").read_text(encoding="utf-8"))
    plan["issued"] = issued
    plan["fingerprint"] = fingerprint(signed_content(plan))
    path = tmp_path / "late-plan.json"
    path.write_text(json.dumps(plan), encoding="utf-8")
    return path


def test_a_plan_issued_after_the_test_is_refused(small_study_file, small_report, tmp_path,
                                                 capsys):
    late = _plan_issued(small_report, tmp_path, "2024-01-15")  # the test: 2024-01-02
    code, err = _cli(["report", small_study_file, "--out", tmp_path / "out", "--plan", late],
                     capsys)
    assert code == 2 and len(err.splitlines()) == 1, err
    assert "issued on 2024-01-15, after the test on 2024-01-02" in err
    assert "late_plan" in err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
    # the same study stating its own late plan date is refused too
    text = small_study_file.read_text(encoding="utf-8")
    dated = tmp_path / "dated.toml"
    dated.write_text(text.replace("plan_date = 2023-12-20", "plan_date = 2024-02-01", 1),
                     encoding="utf-8")
    code, err = _cli(["report", dated, "--out", tmp_path / "out2"], capsys)
    assert code == 2 and "after the test on 2024-01-02" in err, err


def test_a_late_plan_the_study_accepts_is_a_deviation(small_study_file, small_report,
                                                      tmp_path, capsys):
    late = _plan_issued(small_report, tmp_path, "2024-01-15")
    text = small_study_file.read_text(encoding="utf-8")
    accepted = tmp_path / "accepted.toml"
    accepted.write_text(text.replace(
        'revision = "B"', 'revision = "B"\nlate_plan = "accepted by the customer, letter of '
        '2024-01-16"', 1), encoding="utf-8")
    code, err = _cli(["report", accepted, "--out", tmp_path / "out", "--plan", late], capsys)
    assert code == 0, err
    text = _flat(_pages(tmp_path / "out" / "report.pdf"))
    assert ("The test plan DOC-<b>1</b>-PLAN was issued on 2024-01-15, after the test on "
            "2024-01-02; accepted as recorded in the study: accepted by the customer, letter "
            "of 2024-01-16.") in text


@pytest.mark.parametrize("due, agreement, state", [
    ("calibration_due = 2023-12-31", "", "expired"),
    ("", "", "no due date"),
    ("calibration_due = 2023-12-31", 'customer_agreement = "e-mail of 2024-01-02"', "agreed"),
])
def test_an_instrument_not_valid_on_the_test_date(small_study_file, small_result,
                                                  small_report, tmp_path, due, agreement,
                                                  state):
    """An expired or missing calibration is a deviation, and the tests that used the
    instrument get no statement of conformity unless the study records the customer's
    agreement (then the deviation says so and the verdicts stand)."""
    from mtplan.plans.agreement import NO_INSTRUMENT
    from mtplan.plans.study import load_study
    from mtplan.reports import write_report

    text = small_study_file.read_text(encoding="utf-8")
    text = text.replace("calibration_due = 2025-08-15", due + "\n" + agreement, 1)
    path = tmp_path / "study.toml"
    path.write_text(text, encoding="utf-8")
    result = copy.deepcopy(small_result)
    result.study = load_study(path)
    plan = json.loads((small_report / "plan.json").read_text(encoding="utf-8"))
    write_report(result, tmp_path / "out", plan)
    pdf = _flat(_pages(tmp_path / "out" / "report.pdf"))
    verdicts = pd.read_csv(tmp_path / "out" / "results" / "verdicts.csv")
    if state == "agreed":
        assert ("Touch probe (serial TP-0042): its calibration ran out on 2023-12-31, before "
                "the test on 2024-01-02; used for") in pdf
        assert "customer's agreement recorded in the study: e-mail of 2024-01-02" in pdf
        assert NO_INSTRUMENT not in set(verdicts["verdict"])
        return
    why = ("its calibration ran out on 2023-12-31, before the test on 2024-01-02"
           if state == "expired" else "its calibration states no due date")
    assert f"Touch probe (serial TP-0042): {why}; no statement of conformity is made" in pdf
    assert set(verdicts["verdict"]) == {NO_INSTRUMENT}
    assert ("EXPIRED" if state == "expired" else "MISSING") in pdf
    assert "Overall result for machine SN-42 (test 1): no decision" in pdf


def test_certificates_named_as_what_they_are(small_study_file, tmp_path):
    """A verification is called a verification, each certificate accredited or not, and
    the traceability is stated as declared by a named party."""
    from mtplan.plans.study import load_study
    from mtplan.reports.certificate import _instruments

    text = small_study_file.read_text(encoding="utf-8").replace(
        'certificate = "CAL-2024-0815"', 'certificate = "CAL-2024-0815"\nkind = '
        '"verification"\naccredited = false\ndeclared_by = "the maker"', 1)
    path = tmp_path / "v.toml"
    path.write_text(text, encoding="utf-8")
    row = _instruments(load_study(path))[0]
    assert row[2] == "verification CAL-2024-0815 (not accredited)"
    assert row[5] == "PTB via DAkkS D-K-99999 (as declared by the maker)"


def test_an_estimator_changed_against_the_plan_is_a_deviation(small_study_file, small_report,
                                                              tmp_path, capsys):
    """The estimator is part of the method: readings evaluated with another estimator than
    the plan's are a deviation, phrased in the document's units (µm, never um)."""
    text = small_study_file.read_text(encoding="utf-8")
    changed = tmp_path / "estimator.toml"
    changed.write_text(text.replace('uncertainty = "mc"\n  trials = 300',
                                    'uncertainty = "mc"\n  trials = 300\n  estimator = '
                                    '"kasa"', 1), encoding="utf-8")
    plan = json.loads((small_report / "plan.json").read_text(encoding="utf-8"))
    assert {r["estimator"] for r in plan["rules"]} == {"three_point"}
    code, err = _cli(["report", changed, "--out", tmp_path / "out", "--plan",
                      small_report / "plan.json"], capsys)
    assert code == 0, err
    pdf = _flat(_pages(tmp_path / "out" / "report.pdf"))
    assert ("decided with the kasa estimator, not the three_point estimator the plan agreed "
            "(a change of method): centre_x (U ") in pdf
    start = pdf.index("Deviations from the test plan")
    deviations = pdf[start:pdf.index("Glossary", start)]
    assert not re.search(r"\bum\b", deviations) and "µm" in deviations


def test_the_fit_check_is_in_the_report_and_in_measured_csv(small_result, small_report):
    fit = small_result.outcomes[0].measured.fit
    measured = pd.read_csv(small_report / "results" / "measured.csv")
    assert {"fit_chi2", "fit_dof", "fit_p", "fit_ok", "fit_worst"} <= set(measured.columns)
    assert np.allclose(measured["fit_chi2"], fit.chi2) and (measured["fit_dof"] == fit.dof).all()
    text = _flat(_pages(small_report / "report.pdf"))
    assert "Fit check of each test's readings" in text
    # p: the smallest alpha at which the check flags the readings (both tests), which the
    # caption's "p below alpha: no decision" reads
    assert f"{fit.chi2:.1f}" in text and f"{fit.p_overall:.2g}" in text
    assert np.allclose(measured["fit_p"], fit.p_overall)


def test_readings_that_do_not_fit_get_no_verdict(small_result, small_report):
    """Where the fit check says the readings do not fit the model (``measured.fit.ok``
    False), the report gives no verdict, says why, and the overall result is no decision."""
    import dataclasses

    from mtplan.plans.agreement import FIT_NO_DECISION, apply_plan, read_plan
    from mtplan.reports.certificate import overall_result

    result = copy.deepcopy(small_result)
    measured = result.outcomes[0].measured
    assert measured.fit is not None and measured.fit.ok is not None
    measured.fit = dataclasses.replace(measured.fit, ok=False, p_value=1e-9)
    apply_plan(result, read_plan(small_report / "plan.json"))
    assert {v.verdict for v in result.verdicts} == {FIT_NO_DECISION}
    assert all("chi-square" in v.reason for v in result.verdicts)
    assert overall_result(result)[0] == "no decision"


# ------------------------------------------------------------------ ISO/IEC 17025 7.8.2.1
def test_every_page_identified_numbered_and_watermarked(small_report):
    for name in ("report", "plan"):
        pages = _pages(small_report / f"{name}.pdf")
        n = len(pages)
        for i, page in enumerate(pages, start=1):
            flat = " ".join(page.split())
            assert f"page {i} of {n}" in flat, (name, i)
            assert "DOC-<b>1</b>" in flat, (name, i)
            # the plan uses no readings: no readings stamp on it
            assert ("SIMULATED READINGS" in flat) == (name == "report"), (name, i)
    last = " ".join(_pages(small_report / "report.pdf")[-1].split())
    assert "End of report" in last


def test_report_has_the_17025_items(small_report):
    text = _flat(_pages(small_report / "report.pdf"))
    for item in ("Test report", "Lab <b>One</b>", "1 Gauge Street", "place of the test",
                 "Customer & <i>Co</i>", "SN-42", "condition of the item", "date of the test",
                 "2024-01-02", "date of issue", "results relate only to the item tested",
                 "Results as found", "µm", "Deviations from the plan", "authorised by",
                 "method", "Circle centre measuring"):
        assert item in text, item


def test_conditions_and_instruments_come_from_the_study(small_report):
    text = _flat(_pages(small_report / "report.pdf"))
    for item in ("ambient temperature - 20.5 °C", "machine temperature - 21.0 °C",
                 "part (artefact) temperature - 20.7 °C", "45 min axis cycling",
                 "machine's error compensation off off", "Touch probe", "TP-0042",
                 "CAL-2024-0815", "2025-08-15", "PTB via DAkkS D-K-99999", "Traceability"):
        assert item in text, item


def test_glossary_and_plain_names(small_report):
    text = _flat(_pages(small_report / "report.pdf"))
    for term in ("Glossary", "guard band w", "three_point", "kasa",
                 "the outcomes of ILAC-G8:09/2019"):
        assert term in text, term
    assert "X of the bore centre from its nominal position (centre_x)" in text
    # each document's glossary defines only the terms it uses: the observability indices
    # are the plan's, not the report's
    assert "O1-O5" not in text
    assert "O1-O5" in _flat(_pages(small_report / "plan.pdf"))
    assert "no decision (guard band)" not in text


def test_customer_words(small_report):
    """No developer words ("the seed's"), no negative zero, the method cited by its title."""
    for name in ("report", "plan"):
        text = _flat(_pages(small_report / f"{name}.pdf"))
        assert "seed's" not in text, name
        assert not re.search(r"(?<![\d.])-0(\.0+)?(?![\d.])", text), name
        # units as printed, also in notes made by the library (e.g. "held at EY0A = 10 um")
        assert not re.search(r"\d u(m|rad)\b", text), name


# ------------------------------------------------------------------ probabilities
@pytest.mark.parametrize("u", [0.5, 2.0, 8.0])
def test_probability_never_certain_where_the_interval_overlaps_a_limit(u):
    """A sweep of measured values across both limits of a +-20 tolerance: where the 95 %
    interval overlaps a limit the printed probability is neither 100 % nor 0 % (nor one
    that rounds to them), and it lies on the side of 50 % the value does."""
    from mtplan.plans.agreement import p_conform_measured
    from mtplan.reports.wording import probability_text

    for y in np.linspace(-40, 40, 801):
        low, high = y - 2 * u, y + 2 * u
        p = p_conform_measured(y, u, -20.0, 20.0)
        text = probability_text(p)
        assert text not in ("100 %", "0 %", "100.0 %", "0.0 %"), (y, text)
        overlaps = low <= -20 <= high or low <= 20 <= high
        if overlaps:
            value = float(re.sub(r"[<> %]", "", text))
            assert 0.1 <= value <= 99.9, (y, text)
        if abs(y) > 20 + 1e-9:
            assert p < 0.5, y
        elif abs(y) < 20 - 1e-9:
            assert p > 0.5, y


def test_demo_probabilities_agree_with_the_intervals(demo_report):
    report, _ = demo_report
    v = pd.read_csv(report / "results" / "verdicts.csv")
    v = v[v["measured"].notna()]
    for r in v.itertuples():
        crosses = any(r.measured_low <= lim <= r.measured_high for lim in (r.lower, r.upper))
        if crosses:
            assert 0.01 < r.p_conform < 0.99, r.measurand
        if r.measured_low > r.upper or r.measured_high < r.lower:
            assert r.p_conform < 0.5, r.measurand
    text = _flat(_pages(report / "report.pdf"))
    assert not re.search(r"(?<![\d.])(100|0)(\.0)? %", text)


# ------------------------------------------------------------------ the demo
def test_demo_overall_result_and_the_c_axis_action(demo_report):
    report, _ = demo_report
    page = " ".join(" ".join(_pages(report / "report.pdf")[:3]).split())
    # the overall result follows the cover at once (the box on page 1 states it first)
    assert "Overall result and actions" in page.split("Contents")[0]
    assert ("Overall result for machine DEMO-5AX-0001 (tests 1, 2, 3, 4): not accepted: "
            "EX0C.") in page
    cover = " ".join(_pages(report / "report.pdf")[0].split())
    assert "Overall result Machine DEMO-5AX-0001 (tests 1, 2, 3, 4): NOT ACCEPTED: fail EX0C" \
        in cover
    assert "Machine DEMO-GTY-0002 (test 5):" in cover
    assert "Adjust the x position of the C axis at the reference height (EX0C)" in page
    assert "re-test test 1 (C axis location from an inclined plane)" in page
    assert "EC0Y" in page  # no decision, with the lever or repeats that would decide it


def test_measured_csv_has_every_measured_measurand(demo_report):
    report, _ = demo_report
    measured = pd.read_csv(report / "results" / "measured.csv")
    from mtplan.models import get
    from mtplan.plans.study import load_study
    from mtplan.cli.report import demo_study_path

    from mtplan.plans.study.runner import _along_setup

    study = load_study(demo_study_path())
    for ps in study.procedures:  # with the errors along the travel the readings state
        setup = _along_setup(get(ps.name), ps.setup, ps.readings)
        names = {m.name for m in get(ps.name).measurands(setup)}
        got = set(measured.loc[measured["procedure"] == ps.name, "measurand"])
        assert got == names, ps.name
    ok = measured[measured["determinable"]]
    assert np.allclose(ok["U"], 2 * ok["u"]) and (ok["low"] <= ok["high"]).all()


# ------------------------------------------------------------------ figures and tables
@pytest.fixture()
def captured_figures(monkeypatch):
    """The matplotlib figures the report draws, kept open instead of turned into PNG."""
    import matplotlib.pyplot as plt

    from mtplan.reports import figures

    kept = []

    def keep(fig):
        kept.append(fig)
        return b""

    monkeypatch.setattr(figures, "_png", keep)
    yield kept
    for fig in kept:
        plt.close(fig)


def test_every_plotted_marker_equals_its_table_value(small_result, captured_figures):
    """The star of the lever figure (drawn at k = 2) is the study's set-up with the
    recommended estimator, at exactly the U = 2u the test's results table prints."""
    from mtplan.reports.document import test_section

    o = small_result.outcomes[0]
    sec = test_section(1, o)
    table = next(b for b in sec.blocks if hasattr(b, "rows"))
    first = o.results[o.recommended]
    u = {m.name: float(first.mc.std[i]) for i, m in enumerate(first.measurands)}
    printed = {r[0].split(" [")[0]: float(r[2]) for r in table.rows}
    fig, = captured_figures
    stars = 0
    for ax in fig.axes:
        for line in ax.get_lines():
            if line.get_marker() == "*":
                name = ax.get_title()
                assert line.get_ydata()[0] == pytest.approx(2 * u[name], rel=1e-12)
                assert line.get_ydata()[0] == pytest.approx(printed[name], rel=0.05)
                stars += 1
    assert stars == len([ax for ax in fig.axes if ax.get_visible() and ax.get_title()])


def test_budget_colours_are_distinct_within_each_figure(captured_figures):
    """Up to 25 error sources in one budget: every source's bars have their own colour."""
    from matplotlib.colors import to_hex

    from mtplan.reports import figures

    sources = [f"source_{j}" for j in range(25)]
    budget = pd.DataFrame([{"output": f"m{i}", "input": s, "share": 1 / 25}
                           for i in range(3) for s in sources])
    figures.budget_figure(budget)
    fig, = captured_figures
    ax = fig.axes[0]
    colours = [to_hex(c.patches[0].get_facecolor()) for c in ax.containers]
    assert len(colours) == 25 and len(set(colours)) == 25
    assert len(set(figures.qualitative_colors(60))) == 60


def _words_with_boxes(pdf):
    """(page width, page height, [(xmin, ymin, xmax, ymax, word)]) per page, from
    poppler's pdftotext -bbox."""
    need("pdftotext")
    html_text = subprocess.run(["pdftotext", "-bbox", str(pdf), "-"], check=True,
                               capture_output=True, text=True).stdout
    pages = []
    for m in re.finditer(r'<page width="([\d.]+)" height="([\d.]+)">(.*?)</page>', html_text,
                         re.S):
        words = [(float(a), float(b), float(c), float(d), w) for a, b, c, d, w in re.findall(
            r'<word xMin="([\d.-]+)" yMin="([\d.-]+)" xMax="([\d.-]+)" yMax="([\d.-]+)">'
            r'(.*?)</word>', m[3])]
        pages.append((float(m[1]), float(m[2]), words))
    return pages


def test_no_text_clipped_by_the_page(small_report):
    """Every word of both documents lies inside the page's 2 cm side margins (a table as
    wide as the margins, drawn in a frame that pads 6 pt, once overran them)."""
    for name in ("report", "plan"):
        for k, (width, height, words) in enumerate(_words_with_boxes(
                small_report / f"{name}.pdf"), start=1):
            assert words, (name, k)
            for x0, y0, x1, y1, word in words:
                assert 0 <= y0 and y1 <= height, (name, k, word)
                margin = 72 * 2 / 2.54
                assert margin <= x0 + 0.5 and x1 <= width - margin + 0.5, (name, k, word, x1)


def test_no_text_clipped_by_a_cell(tmp_path):
    """A table whose cells hold long words: each word's box stays inside its column (the
    column edges found from the header words' positions)."""
    from mtplan.reports.model import Document, Section, Table
    from mtplan.reports.render import column_widths, render_pdf

    t = Table("Long words", ["alpha", "beta", "gamma", "delta"],
              [["Perpendicularity", "Straightnesses", "-12.345", "conditional"],
               ["Observability", "x", "7.1", "Repeatability-limited"]])
    prov = {"date": "today", "study_sha256": "0" * 64, "versions": {"mtplan": "x"}}
    doc = Document(title="Cells", subtitle="", meta={}, provenance=prov,
                   sections=[Section("Table", blocks=[t], anchor="t")])
    pdf = tmp_path / "cells.pdf"
    pdf.write_bytes(render_pdf(doc))
    _, _, words = _words_with_boxes(pdf)[1]
    from mtplan.reports.render import _table_size

    size = _table_size(t, 470.0)
    edges = np.cumsum([72 * 2 / 2.54 + 6] + column_widths(t, 470.0, size))
    for row in t.rows:
        for j, cell in enumerate(row):
            for x0, _, x1, _, w in words:
                if w == cell:
                    assert edges[j] - 0.5 <= x0 and x1 <= edges[j + 1] + 0.5, (cell, x0, x1)


def test_an_outlier_is_marked_not_squashing_the_rest(captured_figures):
    """A bias of -1500 u among biases below 1 u: the axis stays on the others and the
    outlier is a triangle at the edge with its value printed."""
    from types import SimpleNamespace

    from mtplan.reports import figures

    names = [SimpleNamespace(name=f"m{i}") for i in range(8)]
    ok = SimpleNamespace(measurands=names, bias=np.full(8, 0.1), mc=SimpleNamespace(
        std=np.ones(8)))
    bad = SimpleNamespace(measurands=names, bias=np.r_[-1500.0, np.full(7, 0.2)],
                          mc=SimpleNamespace(std=np.ones(8)))
    figures.estimator_figure({"patent": ok, "joint": bad})
    fig, = captured_figures
    ax = fig.axes[0]
    low, high = ax.get_xlim()
    assert -20 < low < -2 and 2 < high < 20
    marks = [ln for ln in ax.get_lines() if ln.get_marker() == "<"]
    assert len(marks) == 1 and marks[0].get_xdata()[0] == pytest.approx(0.97 * low)
    assert any(t.get_text() == "-1.5e+03" for t in ax.texts)


def test_no_legend_entry_without_its_curve(captured_figures):
    """A sweep where one estimator is u = 0 (not drawn) everywhere: no legend entry for it."""
    from mtplan.reports import figures

    rows = []
    for x in (3, 6):
        rows.append({"n": x, "measurand": "a", "estimator": "kasa", "u": 1.0 / x,
                     "trials": 200})
        rows.append({"n": x, "measurand": "a", "estimator": "flat", "u": 0.0,
                     "trials": 200})
    figures.lever_figure(pd.DataFrame(rows), "n", ["a"], {"a": "um"}, estimator="kasa",
                         recommended="kasa", base=3, targets={}, xlabel="n",
                         marked={"a": 1 / 3})
    fig, = captured_figures
    labels = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert "kasa (recommended)" in labels and not any("flat" in x for x in labels)


def test_a_sweep_figure_at_k_2_labels_every_panel(captured_figures):
    """Drawn at k = 2, every panel of a sweep is U (k = 2), the star and the target line
    included (a loop variable once shadowed k: the first panel read "k = 0", the rest u)."""
    from mtplan.reports import figures

    rows = [{"n": x, "measurand": m, "estimator": "kasa", "u": 1.0 / x, "trials": 200}
            for x in (3, 6) for m in ("a", "b")]
    figures.lever_figure(pd.DataFrame(rows), "n", ["a", "b"], {"a": "um", "b": "um"},
                         estimator="kasa", recommended="kasa", base=3,
                         targets={"b": (0.25, "u for TUR = 4")}, xlabel="n",
                         marked={"a": 1 / 3, "b": 1 / 3}, coverage=2.0)
    fig, = captured_figures
    panels = [ax for ax in fig.axes if ax.get_visible() and ax.get_title()]
    assert [ax.get_ylabel() for ax in panels] == ["U (k = 2) [µm]"] * 2
    for ax in panels:
        star, = [ln for ln in ax.get_lines() if ln.get_marker() == "*"]
        assert star.get_ydata()[0] == pytest.approx(2 / 3)
    assert any(ln.get_ydata()[0] == pytest.approx(0.5) for ln in panels[1].get_lines()
               if ln.get_linestyle() == "--")
    labels = [t.get_text() for leg in fig.legends for t in leg.get_texts()]
    assert "U for TUR = 4" in labels


def test_a_value_rounding_to_zero_has_no_sign():
    from mtplan.reports.model import Table

    t = Table("zeros", ["a", "b", "c"], [["-0.00", "-0", "-0.05"]])
    assert t.rows == [["0.00", "0", "-0.05"]]


# ------------------------------------------------------------------ words and layout
def test_values_cut_at_a_bound_or_not_resolved_are_warned():
    """The line-laser case: alpha_x by the source method, mean 14845 urad with interval
    [0, 46610] against a true 1000, is warned twice; a resolved value is not."""
    from mtplan.reports.wording import value_warnings

    lines, flagged = value_warnings([("alpha_x", 1000.0, 16014.0, 0.0, 46610.0),
                                     ("alpha_y", -2000.0, 2.7, -2005.4, -1994.4),
                                     ("zero", 0.0, 1.0, -2.0, 2.0)])
    assert flagged == {"alpha_x"}
    assert "physical bound 0" in lines[0] and "not resolved" in lines[1]
    cut, _ = value_warnings([("alpha_x", 1000.0, 16014.0, 0.0, 46610.0)], resolution=False)
    assert len(cut) == 1 and "bound" in cut[0]
    # EZX: U is larger than the value, but the printed interval excludes zero: it differs
    # from zero, decided by the interval the reader sees
    assert value_warnings([("EZX", -0.48, 0.30, -0.96, -0.01)]) == ([], set())
    assert value_warnings([("EZX", -0.48, 0.30, -0.96, 0.01)])[1] == {"EZX"}


def test_value_and_U_rounded_together_and_an_asymmetric_interval_marked():
    """centre_y -201.14 with U 1.7 is printed -201.1; an interval that is not value ± U is
    marked and explained."""
    from mtplan.reports.certificate import _asymmetric_mark
    from mtplan.reports.labels import fmt, fmt_u

    assert (fmt(-201.14, 2 * 0.85), fmt_u(2 * 0.85)) == ("-201.1", "1.7")
    assert _asymmetric_mark(-14.5, 14.0, -27.6, -1.3) == " †"   # origin_y_1
    assert _asymmetric_mark(-14.5, 14.0, -28.5, -0.5) == ""


def test_the_simulation_table_warns_where_an_estimator_is_cut_or_blind():
    from types import SimpleNamespace

    from mtplan.reports.appendix import _uncertainty_table
    from mtplan.reports.model import Table

    def result(mean, std, low, high):
        return SimpleNamespace(
            measurands=[SimpleNamespace(name="alpha_x", unit="urad"),
                        SimpleNamespace(name="alpha_z", unit="urad")],
            true=np.array([1000.0, 1500.0]), bias=np.asarray(mean) - [1000.0, 1500.0],
            mc=SimpleNamespace(mean=np.asarray(mean), std=np.asarray(std),
                               low=np.asarray(low), high=np.asarray(high), trials=400,
                               digits=None, coverage=0.95, converged=True))

    outcome = SimpleNamespace(gum=None, recommended="pattern", results={
        "patent": result([14845.0, 0.0], [16014.0, 1443.0], [0.0, -2375.0], [46610.0, 2375.0]),
        "pattern": result([1004.0, 1500.0], [166.0, 40.0], [679.0, 1424.0], [1323.0, 1579.0])})
    blocks = _uncertainty_table(outcome)
    table = blocks[0]
    assert isinstance(table, Table)
    marked = [r[:2] for r in table.rows if r[1].endswith(" *")]
    assert marked == [["patent", "alpha_x *"], ["patent", "alpha_z *"]]
    text = " ".join(blocks[2])
    assert "alpha_x (patent): the interval ends at the physical bound 0" in text
    assert "alpha_z (patent)" in text and "pattern" not in text


def test_results_table_names_wrap_at_most_twice(small_result, small_report):
    """Every measurand's name in the results table fits its column in two lines."""
    import json as _json

    from reportlab.lib.utils import simpleSplit

    from mtplan.plans.agreement import apply_plan
    from mtplan.reports.certificate import build_report
    from mtplan.reports.model import Table
    from mtplan.reports.render import _FONT, _PAD, _register_fonts, _table_size, column_widths

    result = copy.deepcopy(small_result)
    plan = _json.loads((small_report / "plan.json").read_text())
    apply_plan(result, plan)
    doc = build_report(result, plan)
    results = next(s for s in doc.sections if s.anchor == "results")
    table = next(b for b in results.blocks if isinstance(b, Table))  # then the fit check
    _register_fonts()
    size = _table_size(table, 470.0)
    width = column_widths(table, 470.0, size)[1] - 2 * _PAD - 1
    for row in table.rows:
        assert len(simpleSplit(row[1], _FONT, size, width)) <= 2, row[1]


def test_coinciding_path_points_share_one_label(captured_figures):
    from mtplan.reports import figures

    figures.path_figure({"points": {"p1": (0.0, -250.0), "p2": (0.0, 250.0),
                                    "d3": (0.5, -250.0)}})
    (fig,) = captured_figures
    labels = sorted(t.get_text() for t in fig.axes[0].texts)
    assert labels == ["p1 = d3", "p2"]


def test_the_plan_states_the_agreement(small_report):
    """The plan as a contract, checked on the rendered PDF: numeric acceptance limits, the
    rule in ILAC-G8 words, the burden of proof, the overall rule, the required conditions,
    the clauses, the duration, the machine map and the three signatures."""
    plan = json.loads((small_report / "plan.json").read_text(encoding="utf-8"))
    assert plan["conditions"]["temperature_c"] == [19.5, 21.5]
    text = _flat(_pages(small_report / "plan.pdf"))
    agreement = text[text.index("The agreement Parties:"):text.index("Contents")]
    rule = next(r for r in plan["rules"] if r["measurand"] == "centre_x")
    for item in ("Acceptance limits per measurand", "tolerance source",
                 "conditional pass (inside the tolerance) or conditional fail (outside it)",
                 "Burden of proof (ISO 14253-1)", "Overall acceptance rule, per machine",
                 "19.5 to 21.5 °C", "On a fail or a conditional result: the builder may adjust "
                 "once.", "Re-tests allowed after an adjustment: 1.", "Total duration",
                 "SN-42", "mtplan procedure circle_centre", "ISO/IEC 17025 7.8.2.2"):
        assert item in agreement, item
    assert f"{rule['acceptance_upper']:.1f}"[:3] in agreement
    cover = " ".join(_pages(small_report / "plan.pdf")[0].split())
    for party in ("agreed for the laboratory", "agreed for the customer",
                  "agreed for the machine builder"):
        assert party in cover, party


@pytest.mark.parametrize("clause", ["widen", "no decision", None])
def test_the_clause_for_an_achieved_U_larger_than_agreed(small_result, small_report, clause):
    """An achieved U more than 10 % above the agreed one: the plan's clause widens the guard
    band in proportion, or withholds the decision; without a clause only a deviation."""
    from mtplan.plans.agreement import LARGER_U_NO_DECISION, apply_plan

    result = copy.deepcopy(small_result)
    plan = json.loads((small_report / "plan.json").read_text(encoding="utf-8"))
    plan["conditions"] = {"larger_u": clause} if clause else {}
    rule = next(r for r in plan["rules"] if r["measurand"] == "centre_y")
    for v in result.outcomes[0].verdicts:
        if v.measurand == "centre_y":
            v.measured_u = 3 * rule["u_planned"]
    deviations = apply_plan(result, plan)
    v = next(v for v in result.verdicts if v.measurand == "centre_y")
    assert any(d.startswith("centre_y: the measurement's U") for d in deviations)
    if clause == "widen":
        assert v.guard_band == pytest.approx(3 * rule["guard_band"])
        assert "widened" in " ".join(deviations)
    elif clause == "no decision":
        assert v.verdict == LARGER_U_NO_DECISION
    else:
        assert v.guard_band == rule["guard_band"] and v.verdict == "pass"
