"""The report's numbers can be redone by a reader: every verdict from the printed limits, w,
value and U; every action from the budget CSV; the plan's warning before signing from the
plan's own rules. Checked on the rendered PDFs' text (pdftotext) of the demo, rendered once
for the whole run (conftest's ``demo_report``), and on the small study for an instrument
whose calibration ran out."""

from __future__ import annotations

import copy
import json
import math
import re
import subprocess

import pandas as pd
import pytest

from tests.reports.conftest import need

_NUM = r"-?\d+(?:\.\d+)?"


def _text(pdf, layout=False) -> str:
    need("pdftotext")
    args = ["pdftotext"] + (["-layout"] if layout else []) + [str(pdf), "-"]
    return subprocess.run(args, check=True, capture_output=True, text=True).stdout


def _flat(text: str) -> str:
    return " ".join(text.split())


def _zone(y, lo, hi, w) -> str:
    """ISO 14253-1's zone of ``y`` with the tolerance [lo, hi] and guard band ``w``."""
    if lo + w <= y <= hi - w:
        return "pass"
    if y < lo - w or y > hi + w:
        return "fail"
    return "conditional pass" if lo <= y <= hi else "conditional fail"


def test_every_verdict_is_redone_from_the_printed_row(demo_report):
    """From the report's text alone: each row's acceptance limits are its tolerance reduced
    by its printed w, and its printed value falls in the zone its verdict names."""
    folder, _ = demo_report
    text = _text(folder / "report.pdf", layout=True)
    row = re.compile(rf"^\s*\d\s.*?±(?P<t>{_NUM})(?:\s*µ(?:m|rad))?\s+\[(?P<lo>{_NUM}), "
                     rf"(?P<hi>{_NUM})\]\s+(?P<w>{_NUM})\s+(?P<y>{_NUM})(?: †)?\s+"
                     rf"(?P<U>{_NUM})(?: ‡)? \((?P<Up>{_NUM})\)\s+(?P<c>{_NUM}) %\s+"
                     rf"(?:\[(?P<rlo>{_NUM}), (?P<rhi>{_NUM})\]\s+|-\s+)?"
                     r"(?P<v>conditional pass|conditional "
                     r"fail|pass|fail)\s*$", re.M)
    rows = list(row.finditer(text))
    verdicts = pd.read_csv(folder / "results" / "verdicts.csv")
    assert len(rows) == len(verdicts), [m[0] for m in rows]
    for m in rows:
        t, lo, hi, w, y = (float(m[k]) for k in ("t", "lo", "hi", "w", "y"))
        step = 10 ** -max(len(m["w"].partition(".")[2]), 0)
        assert math.isclose(lo, -t + w, abs_tol=step / 2) and math.isclose(hi, t - w,
                                                                            abs_tol=step / 2), m[0]
        assert _zone(y, -t, t, w) == m["v"], m[0]
        if m["rlo"] is not None:  # the residual after compensation: an interval about 0
            assert float(m["rlo"]) <= 0.0 <= float(m["rhi"]), m[0]
    assert "How w was rounded" in _flat(text)


def _labels(procedure) -> dict:
    """{plain label printed: source name} of a procedure's error sources."""
    from mtplan.models import get
    from mtplan.models.protocol import fields_info
    from mtplan.reports.labels import field_label

    proc = get(procedure)
    out = {}
    for name in proc.sources(proc.Setup()):
        f = next((f for f in fields_info(proc.Setup) if f.name.startswith(f"{name}_")), None)
        if f is not None:
            out[field_label(f.name, f.doc or "").split(" [")[0]] = name
    return out


def test_every_action_is_recomputed_from_the_budget_csv(demo_report):
    """Each action's U without a source, halved, after the action and with every source the
    laboratory can act on removed agrees within 2 % with the budget CSV's shares and the
    plan's U; the sources it acts on are never the machine's own."""
    from mtplan.plans.actions import ACTIONABLE

    folder, _ = demo_report
    text = _flat(_text(folder / "report.pdf"))
    verdicts = pd.read_csv(folder / "results" / "verdicts.csv")
    found = 0
    for v in verdicts[verdicts["verdict"].str.startswith("conditional")].itertuples():
        k = 1 + list(dict.fromkeys(verdicts["test"])).index(v.test)
        budget = pd.read_csv(folder / "results" / f"{v.procedure}_{k}_budget.csv")
        rows = budget[budget["output"] == v.measurand]
        share = dict(zip(rows["input"], rows["share"] / rows["share"].sum(), strict=True))
        labels = _labels(v.procedure)
        m = re.search(rf"\({v.measurand}\): conditional \w+ \(inside the guard band\)(.*?)"
                      r"(?= • |Contents)", text)
        assert m, v.measurand
        action = m.group(1)
        for label, owner, pct, without, halved in re.findall(
                rf"(?:: |; )([^;:()]+?) \((\w+), (\d+) %: U ({_NUM}) without it, ({_NUM}) "
                r"halved\)", action):
            s = share[labels[label.strip()]]
            assert abs(100 * s - float(pct)) <= 0.5 + 1e-9
            assert float(without) == pytest.approx(v.U * math.sqrt(1 - s), rel=0.02)
            assert float(halved) == pytest.approx(v.U * math.sqrt(1 - 0.75 * s), rel=0.02)
            found += 1
        floor = re.search(rf"U is still ({_NUM})", action)
        if floor:
            from mtplan.plans.actions import source_owners
            from mtplan.models import get

            owners = source_owners(get(v.procedure))
            acted = sum(s for src, s in share.items()
                        if s >= 0.01 and owners.get(src, "") in ACTIONABLE)
            assert float(floor[1]) == pytest.approx(v.U * math.sqrt(1 - acted), rel=0.02)
        did = re.search(rf"with (.+?) (halved|removed), U ({_NUM})", action)
        if did:
            names = [labels[n.strip()] for n in did[1].split(", ")]
            f = 0.75 if did[2] == "halved" else 1.0
            assert float(did[3]) == pytest.approx(
                v.U * math.sqrt(1 - f * sum(share[n] for n in names)), rel=0.02)
    assert found >= 4
    # EC0Y: the path residual is the machine's own; no instrument removes it
    ec0y = re.search(r"\(EC0Y\): conditional pass(.*?)(?= • |Contents)", text)[1]
    assert "path residual (machine" in ec0y and "No set-up or calibration can decide it" in ec0y
    assert re.search(r"grid plate's own error \(instrument, \d+ %", ec0y)  # share: above


def test_an_instrument_out_of_calibration_gets_a_calibration_not_a_set_up(
        small_study_file, small_result, small_report, tmp_path):
    """No statement of conformity, no probability of conformity, and the action is to
    calibrate the instrument: never a set-up, never "part temperature None"."""
    from mtplan.plans.agreement import NO_INSTRUMENT
    from mtplan.plans.study import load_study
    from mtplan.reports import write_report

    text = small_study_file.read_text(encoding="utf-8")
    path = tmp_path / "study.toml"
    path.write_text(text.replace("calibration_due = 2025-08-15", "calibration_due = 2023-12-31",
                                 1), encoding="utf-8")
    result = copy.deepcopy(small_result)
    result.study = load_study(path)
    plan = json.loads((small_report / "plan.json").read_text(encoding="utf-8"))
    write_report(result, tmp_path / "out", plan)
    verdicts = pd.read_csv(tmp_path / "out" / "results" / "verdicts.csv")
    assert set(verdicts["verdict"]) == {NO_INSTRUMENT}
    assert verdicts["p_conform"].isna().all()
    pdf = _flat(_text(tmp_path / "out" / "report.pdf"))
    actions = pdf.split("the actions that would follow.")[1].split("Contents")[0]
    assert actions.count("Action (calibration): calibrate Touch probe (serial TP-0042)") == 2
    assert "None" not in actions and "set-up:" not in actions and "planner" not in actions
    assert not re.search(r"centre_\w: (> |< )?\d+(\.\d)? % from the measurement", pdf)


def test_the_plan_warns_before_signing_with_a_fix_that_works(demo_report):
    """EC0Y's warning is on page 1 above the signatures and in the agreement, and the rule
    it proposes brings PFR under the bound when recomputed from plan.json."""
    from mtplan.plans import acceptance as acc
    from mtplan.plans.signing import PFR_BOUND

    folder, _ = demo_report
    pages = _text(folder / "plan.pdf").split("\f")
    cover = _flat(pages[0])
    plan = json.loads((folder / "plan.json").read_text(encoding="utf-8"))
    r = next(r for r in plan["rules"] if r["measurand"] == "EC0Y")
    assert cover.index(f"EC0Y (test 2): PFR {100 * r['pfr']:.0f} %") < cover.index("Sign-off")
    agreement = _flat(" ".join(pages[1:4]))
    m = re.search(rf"EC0Y \(test 2\): .*? Would fix it: .*?the rule (guard:{_NUM}|simple) "
                  rf"\(w ({_NUM}) µrad: PFR ({_NUM}) %", agreement)
    assert m, agreement[:400]
    fixed = acc.plan_acceptance(r["lower"], r["upper"], r["u_planned"], prior=r["prior"],
                                rule=m[1], resolution=acc.agreed_resolution(r["u_planned"],
                                                                            400))
    assert fixed.pfr < PFR_BOUND
    assert 100 * fixed.pfr == pytest.approx(float(m[3]), rel=0.05, abs=0.05)
    assert r["pfr"] > PFR_BOUND  # the agreed rule itself is the one warned about


def test_p_values_and_field_names_in_plain_words(demo_report):
    """p with its real precision (never "1"), every field by its label, the posterior's
    thinning in words."""
    folder, _ = demo_report
    report, plan = _flat(_text(folder / "report.pdf")), _flat(_text(folder / "plan.pdf"))
    layout = _text(folder / "report.pdf", layout=True)
    ps = re.findall(r"^\s+\d\s+\d+\.\d\s+\d+\s+(> 0\.99|< 0\.001|\S+)\s+row", layout,
                    re.M)
    assert len(ps) == 5, ps
    for p in ps:
        assert p in ("> 0.99", "< 0.001") or re.fullmatch(r"0\.\d+", p), p
    for raw in ("start_scatter off", "(state air_gradient_k_per_m)", "twice True",
                "every 1. step"):
        assert raw not in report and raw not in plan, raw
    measured = pd.read_csv(folder / "results" / "measured.csv")
    assert "fit_p_text" in measured and "1" not in set(measured["fit_p_text"].astype(str))


def test_every_error_source_names_its_owner():
    """The actions phrase each source by its owner: every source of every built-in
    procedure's default set-up declares one on the set-up field that sizes it."""
    from mtplan.models import get
    from mtplan.models.fields import OWNERS
    from mtplan.plans.actions import owner_of, source_owners

    for name in ("rotary_axis", "geometry21", "circle_centre", "line_laser", "tracker_frame"):
        proc = get(name)
        owners = source_owners(proc)
        found = {s: owner_of(owners, s) for s in proc.sources(proc.Setup())}
        assert all(o in OWNERS for o in found.values()), (name, found)
