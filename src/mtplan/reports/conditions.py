"""The test conditions as the report shows them: each condition the plan requires beside
what the study recorded, how it was measured and what the comparison found
(:func:`mtplan.plans.conditions.check_conditions`), then the other recorded conditions,
and the date and time of each test. Formatting only."""

from __future__ import annotations

from mtplan.reports.model import Table

__all__ = ["condition_blocks"]

#: the recorded keys each check reads (shown in its row, not again as a recorded condition)
_READS = {"temperature": ("temperature_min_c", "temperature_max_c", "temperature_log"),
          "temperature_change": ("temperature_change_c_per_h",),
          "warm_up": ("warm_up", "warm_up_min"),
          "compensation": ("compensation",), "controller": ("controller",)}
_FINDING = {"within": "within", "outside": "OUTSIDE", "not recorded": "NOT RECORDED"}


def _recorded(key, kind, value) -> str:
    if isinstance(value, dict):  # per machine serial number
        return "; ".join(f"machine {k}: {_recorded(key, kind, v)}" for k, v in value.items())
    if kind == "temperature":
        return f"{value:.1f} °C"
    if kind in ("bool", "per_machine_bool"):
        return "on" if value else "off"
    if kind == "rate":
        return f"{value:g} °C/h"
    if kind == "minutes":
        return f"{value:g} min"
    return str(value)


def condition_blocks(study, required: dict) -> list:
    """The blocks of the report's test conditions: the table of the required conditions
    against the record, and the date and time of each test."""
    from mtplan.plans.conditions import check_conditions
    from mtplan.plans.study import CONDITION_KEYS

    findings = check_conditions(study, required)[0]
    rows = [[f.label + (f" (machine {f.machine})" if f.machine else "")
             + (f" (test{'s' if len(f.tests) > 1 else ''} {', '.join(map(str, f.tests))})"
                if f.tests else ""), f.required,
             f.recorded, f.how or "not stated", _FINDING[f.state]] for f in findings]
    shown = {key for f in findings for key in _READS[f.check]}
    how = study.conditions.get("how", {})
    for key, (label, kind) in CONDITION_KEYS.items():
        value = study.conditions.get(key)
        if value is None or key in shown or key == "how":
            continue
        check = next((c for c, keys in _READS.items() if key in keys), "")
        rows.append([label, "-", _recorded(key, kind, value), how.get(check, "") or "-",
                     "not required"])
    caption = ("Test conditions (ISO 230-1 6.1): each condition the plan requires against "
               "the record of the test, and how it was measured; a condition outside the "
               "agreement or not recorded is a deviation (below), which says what it does to "
               "the verdicts.")
    blocks = [Table(caption, ["condition", "required", "recorded", "how measured", "finding"],
                    rows)] if rows else ["No test conditions are required or recorded."]
    times = [f"test {k} {ps.time or 'not recorded'}"
             for k, ps in enumerate(study.procedures, start=1)]
    blocks.append(f"Date of the test: {study.header.get('date', 'not recorded')}; time of "
                  f"each test: {', '.join(times)}.")
    return blocks
