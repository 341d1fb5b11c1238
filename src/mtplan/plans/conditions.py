"""The test conditions a plan requires, compared with those a study records.

A plan's ``[requirements]`` state the band of the ambient temperature, its largest change
per hour, the shortest warm-up, whether the machine's error compensation is on and which
controller and compensation tables' version it runs (one value, or one per machine serial
number). The study's ``[conditions]`` record what was measured during the test: the lowest
and highest ambient temperature, the largest change, the warm-up, the compensation state
and the controller, each with how it was measured (``how``).

:func:`check_conditions` compares each required condition with the record:

- "within": recorded, and inside the agreement;
- "outside": recorded outside it (a deviation);
- "not recorded": required but not recorded (a deviation: a condition that nobody
  recorded was not checked, and is never taken as kept).

A deviation removes the statements of conformity of the tests run under it (for a
condition stated per machine, the tests on that machine) unless the plan's clause
``outside_effect`` says its verdicts stand for that condition; each deviation names the
clause that applied.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

__all__ = ["ConditionFinding", "check_conditions", "NO_CONDITION", "WITHIN", "OUTSIDE",
           "NOT_RECORDED"]

#: the verdict of a toleranced measurand whose test ran under a condition outside the
#: agreement, or one not recorded, where the plan's clause does not keep the verdicts
NO_CONDITION = "no statement: a test condition was outside the agreement or not recorded"
WITHIN, OUTSIDE, NOT_RECORDED = "within", "outside", "not recorded"
#: (check, its label, the requirement's key): the conditions compared, in the report's order
_CHECKS = (("temperature", "ambient temperature (lowest to highest)", "temperature_c"),
           ("temperature_change", "ambient temperature change", "gradient_c_per_h"),
           ("warm_up", "warm-up", "warm_up_min"),
           ("compensation", "machine's error compensation", "compensation"),
           ("controller", "controller and compensation tables' version", "controller"))


@dataclass(frozen=True)
class ConditionFinding:
    """One required condition against the record.

    ``check``: its name (:data:`~mtplan.plans.study.CONDITION_CHECKS`); ``machine``: the
    serial number it applies to ("" for every machine); ``required`` and ``recorded``: as the
    documents print them; ``how``: how it was measured, as the study records it ("" where
    it does not); ``state``: :data:`WITHIN`, :data:`OUTSIDE` or :data:`NOT_RECORDED`;
    ``blocks``: whether it removes the statements of conformity of its tests; ``clause``:
    the plan's clause that applied, in words ("" when within); ``tests``: the numbers of the
    tests it applies to where it is not every test (of its machine): a test whose time the
    temperature log does not span."""

    check: str
    label: str
    machine: str
    required: str
    recorded: str
    how: str
    state: str
    blocks: bool
    clause: str
    tests: tuple = ()  # the test numbers it applies to, where not every test's (or machine's)


def _band(req, rec) -> tuple[str, str]:
    """(state, recorded text) of the ambient temperature against the band [low, high]:
    from the lowest and highest recorded, else from one reading (which can show the band
    left, never kept)."""
    low, high = req
    lo, hi = rec.get("temperature_min_c"), rec.get("temperature_max_c")
    one = rec.get("ambient_temperature_c")
    outside = any(x is not None and not low <= x <= high for x in (lo, hi, one))
    if lo is not None and hi is not None:
        log = f" ({rec['temperature_log']})" if rec.get("temperature_log") else ""
        return (OUTSIDE if outside else WITHIN), f"{lo:.1f} to {hi:.1f} °C{log}"
    parts = [f"lowest {lo:.1f} °C" if lo is not None else "",
             f"highest {hi:.1f} °C" if hi is not None else "",
             f"one reading of {one:.1f} °C" if one is not None else ""]
    shown = ", ".join(p for p in parts if p)
    if outside:
        return OUTSIDE, shown
    return NOT_RECORDED, ("not recorded" if not shown else
                          f"not recorded: only {shown}, not the lowest and highest during the "
                          "test")


def _at_most(limit, value, unit) -> tuple[str, str]:
    if value is None:
        return NOT_RECORDED, "not recorded"
    return (WITHIN if value <= limit else OUTSIDE), f"{value:g} {unit}"


def _warm_up(req, rec) -> tuple[str, str, str]:
    """(state, required, recorded) of the warm-up: its duration against the shortest one
    the plan requires; a plan that states the warm-up in words only is met by a recorded
    warm-up, whose description the report prints beside the plan's."""
    minutes, text = rec.get("warm_up_min"), rec.get("warm_up", "")
    shown = "; ".join(p for p in (f"{minutes:g} min" if minutes is not None else "", text) if p)
    if "warm_up_min" in req:
        required = f"at least {req['warm_up_min']:g} min" + (f" ({req['warm_up']})"
                                                             if req.get("warm_up") else "")
        if minutes is None:
            return NOT_RECORDED, required, (f"not recorded: its duration (warm-up "
                                            f"\u201c{text}\u201d)" if text else "not recorded")
        return (WITHIN if minutes >= req["warm_up_min"] else OUTSIDE), required, shown
    required = f"{req['warm_up']} (no duration stated to compare)"
    return (WITHIN if shown else NOT_RECORDED), required, shown or "not recorded"


def _per_machine(value, serial):
    return value.get(serial) if isinstance(value, dict) else value


def _word(check, value) -> str:
    if value is None:
        return "not recorded"
    return ("on" if value else "off") if check == "compensation" else str(value)


def check_conditions(study, required: dict) -> tuple[list, list[str], dict]:
    """Each condition the plan requires (``required``: the plan's ``conditions``, the
    study's ``[requirements]``) against the study's ``[conditions]``.

    Returns
    -------
    findings : list of ConditionFinding
        One per required condition (per machine where the plan or the record states it per
        machine), in the order of :data:`_CHECKS`.
    deviations : list of str
        One line per condition outside the agreement or not recorded, naming the plan's
        clause that applied and what it does to the verdicts.
    blocked : dict
        ``{(procedure, test title): reason}``: the tests that get no statement of
        conformity (:data:`NO_CONDITION`).
    """
    from mtplan.plans.study import machine_serials

    rec = study.conditions
    how = rec.get("how", {})
    effect = required.get("outside_effect", {})
    serials = machine_serials(study.header, study.procedures)
    default = study.header.get("machine_serial", "")
    findings = []
    for check, label, key in _CHECKS:
        if key not in required and not (check == "warm_up" and "warm_up" in required):
            continue
        req = required.get(key)
        per_machine = check in ("compensation", "controller") and (
            isinstance(req, dict) or isinstance(rec.get(check), dict))
        for serial in (serials if per_machine else [""]):
            if check == "temperature":
                state, recorded = _band(req, rec)
                text = f"{req[0]:g} to {req[1]:g} °C"
            elif check == "temperature_change":
                state, recorded = _at_most(req, rec.get("temperature_change_c_per_h"), "°C/h")
                text = f"at most {req:g} °C/h"
            elif check == "warm_up":
                state, text, recorded = _warm_up(required, rec)
            else:
                want = _per_machine(req, serial)
                if want is None:  # required for some machines only
                    continue
                got = _per_machine(rec.get(check), serial)
                text, recorded = _word(check, want), _word(check, got)
                state = (NOT_RECORDED if got is None else
                         WITHIN if (got == want if check == "compensation"
                                    else got.casefold() == want.casefold()) else OUTSIDE)
            stands = effect.get(check) == "verdicts stand"
            findings.append(ConditionFinding(
                check=check, label=label, machine=serial, required=text, recorded=recorded,
                how=how.get(check, ""), state=state, blocks=state != WITHIN and not stands,
                clause="" if state == WITHIN else _clause(required, check, stands)))
            unlogged = _unlogged(study, rec) if check in ("temperature",
                                                          "temperature_change") else []
            if unlogged and state == WITHIN:  # the log is silent on some tests' times
                findings.append(dataclasses.replace(
                    findings[-1], state=NOT_RECORDED, blocks=not stands,
                    clause=_clause(required, check, stands), tests=tuple(unlogged),
                    recorded=f"not recorded during test{'s' if len(unlogged) > 1 else ''} "
                             f"{', '.join(map(str, unlogged))}: the log spans "
                             f"{_clock(rec['temperature_log_span'][0])} to "
                             f"{_clock(rec['temperature_log_span'][1])}"))
    deviations, blocked = [], {}
    for f in findings:
        if f.state == WITHIN:
            continue
        tests = [(k, ps) for k, ps in enumerate(study.procedures, start=1)
                 if (not f.machine or (ps.machine or default) == f.machine)
                 and (not f.tests or k in f.tests)]
        where = f" on machine {f.machine}" if f.machine else ""
        numbers = ", ".join(str(k) for k, _ in tests)
        numbers = ("test " if len(tests) == 1 else "tests ") + numbers
        outcome = (f"no statement of conformity is made on {numbers}" if f.blocks else
                   f"the verdicts of {numbers} stand")
        found = (f"recorded {f.recorded} (outside the agreement)" if f.state == OUTSIDE
                 else f.recorded)
        deviations.append(f"Test condition {f.label}{where}: required {f.required}; {found}. "
                          f"Clause applied: {f.clause}; {outcome}.")
        if f.blocks:
            for _, ps in tests:
                blocked.setdefault((ps.name, ps.label),
                                   f"{f.label}{where} {f.state}: required {f.required}; "
                                   f"{found}")
    return findings, deviations, blocked


def _minutes(clock: str) -> float:
    hours, minutes = clock.split(":")[:2]
    return 60 * int(hours) + int(minutes)


def _clock(minutes: float) -> str:
    return f"{int(minutes) // 60:02d}:{int(minutes) % 60:02d}"


def _unlogged(study, rec) -> list[int]:
    """The numbers of the tests whose time (``[[procedure]] time``) the temperature log
    does not span (none without a log or a test's time)."""
    span = rec.get("temperature_log_span")
    if not span:
        return []
    out = []
    for k, ps in enumerate(study.procedures, start=1):
        if ps.time:
            start, _, end = ps.time.partition("-")
            if _minutes(start) < span[0] or _minutes(end or start) > span[1]:
                out.append(k)
    return out


def _clause(required, check, stands) -> str:
    """The plan's clause that applies to a condition outside the agreement or not
    recorded, in words."""
    if stands:
        return f"the plan's outside_effect keeps the verdicts for {check}"
    if required.get("outside"):
        return (f"\u201cOutside a required condition: {required['outside']}\u201d, which keeps "
                "no verdict")
    return "none stated in the plan, so the default"
