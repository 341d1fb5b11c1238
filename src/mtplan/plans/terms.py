"""What a plan agrees beyond its rules: the item, the tests and the machine each is run
on, each test's set-up and standards, the instruments and the method's version.

:func:`agreed_terms` is what ``plan.json`` stores of them (under its fingerprint, with the
rules and the conditions); :func:`compare_terms` holds a study to them after the test:

- refused (one line naming the item): another item (maker, type or serial numbers), a
  test added, left out or run on another machine than agreed (the plan does not cover
  the machine it was run on: issue a new plan);
- listed as deviations in the report, item by item: a set-up field changed, an instrument
  replaced, added or not used, or its certificate changed, and another mtplan version
  than the plan's (the method's version).
"""

from __future__ import annotations

import json

__all__ = ["agreed_terms", "compare_terms", "TERM_KEYS"]

#: the keys of ``plan.json`` that :func:`agreed_terms` fills
TERM_KEYS = ("item", "tests", "instruments", "method_version")
_ITEM = ("machine_maker", "machine_type", "machine_serial")
_INSTRUMENT = ("name", "serial", "certificate", "kind", "accredited", "calibration_due",
               "used_in")


def _plain(value):
    """A value as JSON keeps it (tuples as lists, paths and other objects as text)."""
    return json.loads(json.dumps(value, default=str))


def _version() -> str:
    import importlib.metadata as md

    try:
        return md.version("mtplan")
    except md.PackageNotFoundError:
        return "unknown"


def agreed_terms(study) -> dict:
    """The terms of a study that the plan agrees: ``item`` (maker, type, serial numbers of
    the cover), ``tests`` (per test in order: procedure, title, machine serial, set-up,
    standards), ``instruments`` (name, serial, certificate, kind, accreditation, due date,
    the procedures it serves) and ``method_version`` (mtplan's)."""
    default = study.header.get("machine_serial", "")
    tests = [{"test": k, "procedure": ps.name, "title": ps.label,
              "machine": ps.machine or default,
              "setup": _plain(ps.setup.as_dict() if ps.setup is not None else {}),
              "standards": list(ps.standards)}
             for k, ps in enumerate(study.procedures, start=1)]
    instruments = [{key: _plain(inst.get(key)) for key in _INSTRUMENT}
                   for inst in study.instruments]
    return {"item": {key: study.header.get(key, "") for key in _ITEM}, "tests": tests,
            "instruments": instruments, "method_version": _version()}


def _shown(value) -> str:
    return "not stated" if value in (None, "", []) else json.dumps(value, ensure_ascii=False)


def compare_terms(study, plan) -> tuple[list[str], list[str]]:
    """The study's terms against the plan's.

    Returns
    -------
    refusals : list of str
        What the plan does not cover (another item, test or machine), one line each.
    deviations : list of str
        What changed within the agreement, one line per item: a set-up field, an
        instrument, the method's version.
    """
    number = plan.get("document", "the plan")
    now, agreed = agreed_terms(study), {k: plan.get(k) for k in TERM_KEYS}
    refusals, deviations = [], []
    for key in _ITEM:
        was, new = (agreed.get("item") or {}).get(key, ""), now["item"][key]
        if was != new:
            refusals.append(f"The study's item {key.replace('_', ' ')} is {new!r}, plan "
                            f"{number} agrees {was!r}: the plan covers the item it names "
                            "(issue a new plan).")
    planned = agreed.get("tests") or []
    if [(t["procedure"], t["title"]) for t in planned] != [(t["procedure"], t["title"])
                                                           for t in now["tests"]]:
        refusals.append(f"The study's tests ({_list(now['tests'])}) are not those of plan "
                        f"{number} ({_list(planned)}): issue a new plan.")
        return refusals, deviations
    for was, new in zip(planned, now["tests"], strict=True):
        test = f"test {new['test']} ({new['title']})"
        if was["machine"] != new["machine"]:
            refusals.append(f"The study runs {test} on machine {new['machine'] or 'not stated'}"
                            f", plan {number} on {was['machine'] or 'not stated'}: the plan "
                            "agrees each test's machine (issue a new plan).")
        changed = [f"{name} {_shown(was['setup'].get(name))} in the plan, "
                   f"{_shown(new['setup'].get(name))} in the study"
                   for name in sorted(set(was["setup"]) | set(new["setup"]))
                   if was["setup"].get(name) != new["setup"].get(name)]
        if changed:
            deviations.append(f"The set-up of {test} differs from plan {number}: "
                              + "; ".join(changed) + ".")
        if was["standards"] != new["standards"]:
            deviations.append(f"The standards of {test} differ from plan {number}: "
                              f"{', '.join(was['standards']) or 'none'} in the plan, "
                              f"{', '.join(new['standards']) or 'none'} in the study.")
    deviations += _instrument_changes(agreed.get("instruments") or [], now["instruments"],
                                      number)
    if agreed.get("method_version") != now["method_version"]:
        deviations.append(f"The readings were evaluated with mtplan {now['method_version']}, "
                          f"plan {number} agrees mtplan {agreed.get('method_version')} (the "
                          "method's version).")
    return refusals, deviations


def _list(tests) -> str:
    return ", ".join(f"{t['procedure']} {t['title']!r}" for t in tests) or "none"


def _instrument_changes(planned, used, number) -> list[str]:
    """One line per instrument the plan names and the study does not (by serial number),
    per instrument the study adds, and per field changed of one both name."""
    was = {i["serial"]: i for i in planned}
    now = {i["serial"]: i for i in used}
    gone = {i["name"]: s for s, i in was.items() if s not in now}
    out = []
    for serial, inst in now.items():
        if serial in was:
            continue
        if inst["name"] in gone:  # the same instrument, another item of it
            old = gone.pop(inst["name"])
            out.append(f"Instrument {inst['name']}: serial {serial} used, plan {number} agrees "
                       f"serial {old} (replaced).")
        else:
            out.append(f"Instrument {inst['name']} (serial {serial}) is not in plan {number}: "
                       "used besides the agreed instruments.")
    for name, serial in gone.items():
        out.append(f"Instrument {name} (serial {serial}), agreed in plan {number}, is not among "
                   "the instruments of the study (not used).")
    for serial, inst in now.items():
        if serial not in was:
            continue
        changed = [f"{key.replace('_', ' ')} {_shown(was[serial].get(key))} in the plan, "
                   f"{_shown(inst.get(key))} in the study"
                   for key in _INSTRUMENT if was[serial].get(key) != inst.get(key)]
        if changed:
            out.append(f"Instrument {inst['name']} (serial {serial}) differs from plan "
                       f"{number}: " + "; ".join(changed) + ".")
    return out
