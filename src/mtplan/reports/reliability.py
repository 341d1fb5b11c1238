"""What one bad reading can do unseen, in the plan (before the test) and the report (after).

Both documents draw the same :class:`~mtplan.evaluation.reliability.Reliability`: the
plan the one of the agreed set-up at its design readings (``ProcedureOutcome.reliability``),
the report the one of the measured readings (the readings evaluation's
``sections["reliability"]``). Per test: the smallest error of one reading, or of one
error the procedure declares (circle_centre: a bad contact along its probing direction),
that the fit check detects with 80 % power (its minimal detectable bias, MDB), and per
measurand the largest shift such an error causes unseen, also in units of its u.
"""

from __future__ import annotations

import math

from mtplan.reports.labels import unit
from mtplan.reports.model import Section, Table

__all__ = ["mdb_sentence", "shift_table", "plan_blocks", "report_section"]


def _num(x) -> str:
    return "no limit" if x is None or not math.isfinite(x) else f"{x:.3g}"


def mdb_sentence(rel) -> str:
    """The MDB per reading array (and per declared error) in one sentence."""
    if rel.reason:
        return f"What one bad reading can do unseen is not stated: {rel.reason}."
    parts = []
    for m in rel.mdb:
        low, high = _num(m["smallest"]), _num(m["largest"])
        span = high if low == high else f"{low} to {high}"
        parts.append(f"{m['readings']} {span} {unit(m['unit'])} (largest at {m['at']})"
                     + (f", {m['undetectable']} undetectable" if m.get("undetectable") else ""))
    return (f"The fit check (significance level {rel.alpha:g}) detects with "
            f"{100 * rel.power:.0f} % probability a gross error of one reading of "
            + "; ".join(parts) + ".")


def shift_table(rel, caption: str) -> Table:
    """Per measurand: u, the largest undetected shift, in units of u, and the error
    that causes it with its MDB."""
    rows = []
    for name, r in rel.measurands.items():
        rows.append([name, unit(r["unit"]), "-" if r["u"] is None else f"{r['u']:.3g}",
                     # no first-order response to any one reading (a quantised or
                     # blind estimator): not "0", a gross error may still move it a step
                     "not at first order" if r["shift"] == 0 else _num(r["shift"]),
                     "-" if r["in_u"] is None else f"{r['in_u']:.2g}",
                     f"{r['at']} ({_num(r['mdb'])} {unit(r['mdb_unit'])})"])
    return Table(caption, ["measurand", "unit", "u", "largest shift unseen", "in u",
                           "caused by (its MDB)"], rows, grow=5, size=7.0)


def plan_blocks(k, o) -> list:
    """The plan's blocks for test ``k``: before the test, at the agreed set-up."""
    rel = getattr(o, "reliability", None)
    if rel is None:
        return []
    if rel.reason:
        return [mdb_sentence(rel)]
    return [mdb_sentence(rel), shift_table(
        rel, f"Test {k}: what one bad reading can do unseen, predicted for the agreed "
        "set-up: the largest shift of each measurand that an error of one reading of its "
        "MDB causes (an error the fit check misses one time in five), u the predicted "
        "standard uncertainty.")]


def report_section(result) -> Section | None:
    """The report's section: per test with readings, the figures at its readings."""
    blocks = []
    for k, o in enumerate(result.outcomes, start=1):
        m = o.measured
        rel = None if m is None else getattr(m, "sections", {}).get("reliability")
        if rel is None:
            continue
        blocks += [f"Test {k}: {mdb_sentence(rel)}"]
        if not rel.reason:
            blocks.append(shift_table(
                rel, f"Test {k}: the largest shift of each measurand that one bad reading "
                "of its MDB could have caused unseen at these readings, u the achieved "
                "standard uncertainty. A passed fit check does not exclude it."))
    if not blocks:
        return None
    return Section("What one bad reading can do unseen", level=2, blocks=[
        "A gross error of one reading (a chip, swarf, a late trigger, a typing error) "
        "smaller than its MDB passes the fit check more often than not; the table says "
        "how far it can move each result."] + blocks)
