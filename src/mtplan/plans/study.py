"""Studies: what a report covers, read from a TOML file and computed in one go.

A study names procedures, their base set-ups, sweeps, planning targets,
tolerances with their acceptance rules and optionally measured readings, and
carries the header of the document a customer receives. :func:`load_study`
validates the whole file and lists every problem at once; :func:`run_study`
computes every result (Monte Carlo, GUM budget, sweeps, plan, measured data,
verdicts, advice) into a :class:`StudyResult` that the reports render without
computing anything.

Example::

    title = "Acceptance of machine 42"
    seed = 1
    digits = 2                      # adaptive Monte Carlo of each base set-up
    [header]
    document = "MT-2024-017"
    revision = "A"
    customer = "Example GmbH"
    machine_maker = "Maker"
    machine_type = "5-axis machining centre"
    machine_serial = "SN 4711"
    location = "Hall 3"
    operator = "A. Person"
    date = 2024-11-20
    ambient_temperature_c = 20.4
    prepared_by = "A. Person"
    checked_by = "B. Person"
    approved_by = "C. Person"
    [[procedure]]
    name = "rotary_axis"
    label = "C axis"
    setup = { axis = "C", incline_deg = 20 }
    estimators = ["patent", "joint"]
    standards = ["ISO 230-7:2015", "ISO 230-1:2012"]
      [[procedure.sweep]]
      vary = { incline_deg = [10, 20, 30] }
      trials = 2000
      [procedure.plan]
      targets = { EX0C = 1.0 }
      vary = { positions = [3, 6, 12] }
      [[procedure.acceptance]]          # one table per toleranced measurand
      measurand = "EX0C"
      lower = -10.0
      upper = 10.0
      prior = "normal:0,4"
      rule = "iso14253"
      [procedure.readings]
      file = "rotary_axis_readings.csv"   # relative to the study file
      uncertainty = "mc"                   # or "posterior"
      estimator = "joint"                  # default: the recommended estimator
"""

from __future__ import annotations

import datetime
import hashlib
import math
import tomllib
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mtplan._validate import InvalidInput

__all__ = ["Study", "ProcedureStudy", "StudyResult", "HEADER_KEYS", "load_study", "run_study",
           "run_study_cached", "study_cache_key"]

#: the document header's keys, in the order the cover shows them
HEADER_KEYS = ("document", "revision", "plan_document", "plan_date", "customer",
               "customer_address", "machine_maker", "machine_type", "machine_serial",
               "item_condition", "location", "operator", "date", "issue_date",
               "ambient_temperature_c", "prepared_by", "checked_by", "approved_by",
               "late_plan")
_DATE_KEYS = {"date", "issue_date", "plan_date"}
_TOP_KEYS = {"title", "subtitle", "customer", "machine", "author", "header", "seed", "digits",
             "trials", "max_trials", "coverage", "procedure", "simulated", "laboratory",
             "conditions", "instrument", "requirements"}
_LAB_KEYS = {"name", "address", "accreditation"}
#: the clause for an achieved U more than 10 % above the agreed one: the guard band widened
#: in proportion (w times U achieved / U agreed), or no decision on that measurand
LARGER_U = ("widen", "no decision")
#: what the plan requires and agrees before the test (the contract's clauses): key ->
#: (label, kind); kinds: band [low, high] in degC, number, bool, int, text
REQUIREMENT_KEYS = {
    "temperature_c": ("ambient temperature during the test [°C]", "band"),
    "gradient_c_per_h": ("largest temperature change [°C/h]", "number"),
    "warm_up": ("warm-up before the test", "text"),
    "compensation": ("machine's error compensation", "bool"),
    "outside": ("outside a required condition", "text"),
    "adjustment": ("on a fail or a conditional result: adjustment", "text"),
    "retests": ("re-tests allowed after an adjustment", "int"),
    "as_left": ("results after an adjustment", "text"),
    "larger_u": ("achieved U more than 10 % above the agreed U", "choice"),
    "schedule": ("schedule", "text"),
}
#: the test conditions (ISO 230-1 6, ISO 230-2 5.1): key -> (label, kind)
CONDITION_KEYS = {"ambient_temperature_c": ("ambient temperature", "temperature"),
                  "machine_temperature_c": ("machine temperature", "temperature"),
                  "part_temperature_c": ("part (artefact) temperature", "temperature"),
                  "warm_up": ("warm-up before the test", "text"),
                  "compensation": ("machine's error compensation", "bool"),
                  "notes": ("other conditions", "text")}
#: standards a study may not cite because no procedure computes what they require
#: ("honoured or not cited"): standard -> what it requires
UNHONOURED_STANDARDS = {
    "ISO 230-2": "the bidirectional positioning values A, E, M, R and B per axis from "
                 "repeated runs in both directions",
    "ISO 1101": "a position tolerance as a diameter zone (an acceptance table with "
                "'position', 'nominal' and 'diameter')",
}
_INSTRUMENT_KEYS = {"name", "serial", "certificate", "calibration_due", "traceability",
                    "used_in", "kind", "accredited", "declared_by", "customer_agreement"}
#: what an instrument's certificate records: a calibration (a relation to a reference,
#: VIM 2.39) or a verification (conformity to a specification, VIM 2.44: ISO 10360-10's
#: tests of a laser tracker, a maker's check)
INSTRUMENT_KINDS = ("calibration", "verification")
_PROC_KEYS = {"name", "label", "setup", "truth", "estimators", "sweep", "plan", "acceptance",
              "readings", "as_left", "trials", "digits", "max_trials", "budget", "budget_trials",
              "notes", "standards", "machine"}
_SWEEP_KEYS = {"vary", "trials", "estimators"}
_PLAN_KEYS = {"targets", "vary", "k", "estimator", "trials"}
_ACCEPT_KEYS = {"measurand", "lower", "upper", "prior", "rule", "measured", "tolerance_source",
                "frame",
                "population_source"}
#: a position tolerance as a diameter zone (ISO 1101): the deviation 2 sqrt(dx^2 + dy^2) of
#: two coordinate measurands from their nominal within the zone's diameter (their unit)
_POSITION_KEYS = {"measurand", "position", "nominal", "diameter", "prior", "rule",
                  "tolerance_source", "frame",
                  "population_source"}
_READ_KEYS = {"file", "uncertainty", "estimator", "trials", "options", "allow_unconverged"}
#: readings taken again after an adjustment, evaluated as the readings are
_AS_LEFT_KEYS = {"file", "adjustment"}


def _unknown(problems, where, table, allowed):
    if isinstance(table, dict):
        for key in sorted(set(table) - allowed):
            problems.append(f"{where} has an unknown key {key!r}; allowed: "
                            f"{', '.join(sorted(allowed))}.")


def _subtable(problems, where, name, value, allowed) -> dict | None:
    """An optional sub-table ``name`` of a procedure: None when absent; a problem when it
    is not a table; its unknown keys listed."""
    if value is None:
        return None
    if not isinstance(value, dict):
        problems.append(f"{where} {name!r} must be a table.")
        return None
    _unknown(problems, f"{where} {name}", value, allowed)
    return value


def _count(problems, where, value, low):
    if value is not None and not (isinstance(value, int) and not isinstance(value, bool)
                                  and value >= low):
        problems.append(f"{where} must be an int >= {low}. Got {value!r} instead.")


def _digits(problems, where, value):
    if value is not None and not (isinstance(value, int) and 1 <= value <= 4):
        problems.append(f"{where} must be an int from 1 to 4. Got {value!r} instead.")


@dataclass
class ProcedureStudy:
    name: str
    label: str
    setup: object
    truth: object
    estimators: list
    sweeps: list = field(default_factory=list)        # dicts: vary, trials, estimators
    plan: dict | None = None
    acceptance: list = field(default_factory=list)    # dicts: one per toleranced measurand
    readings: dict | None = None
    as_left: dict | None = None       # file (readings after adjustment), adjustment (text)
    trials: int | None = None
    digits: int | None = None
    max_trials: int | None = None
    budget: str = "gum"                # "gum" (law of propagation) or "mc" (one source at a time)
    budget_trials: int = 2000
    notes: str = ""
    standards: list = field(default_factory=list)     # standards the test follows
    machine: str = ""                  # serial of the machine the test is run on ("": the one)


@dataclass
class Study:
    title: str
    path: Path | None
    digest: str                        # SHA-256 of the study file (64 hex)
    seed: int
    digits: int | None
    trials: int | None
    coverage: float
    meta: dict
    procedures: list
    max_trials: int = 200_000
    header: dict = field(default_factory=dict)        # HEADER_KEYS -> value (those given)
    laboratory: dict = field(default_factory=dict)    # name, address, accreditation
    conditions: dict = field(default_factory=dict)    # CONDITION_KEYS -> value (those given)
    instruments: list = field(default_factory=list)   # dicts: _INSTRUMENT_KEYS
    simulated: bool = False                           # readings simulated, not measured
    requirements: dict = field(default_factory=dict)  # REQUIREMENT_KEYS -> value (those given)


def load_study(source) -> Study:
    """Read and validate a study (a TOML path, or an already parsed dict).

    Raises
    ------
    InvalidInput
        Every problem of the file at once, each naming its place.
    """
    from mtplan.models import registry

    data, raw, path = _read(source)
    problems: list[str] = []
    for key in sorted(set(data) - _TOP_KEYS):
        problems.append(f"The study has an unknown key {key!r}; allowed: "
                        f"{', '.join(sorted(_TOP_KEYS))}.")
    top = _top_level(data, problems)
    header = _header(data, problems)
    certificate = _certificate(data, header, problems)
    entries = data.get("procedure", [])
    if not isinstance(entries, list) or not entries:
        problems.append("The study needs at least one [[procedure]] table.")
        entries = []
    procs = registry()
    out = [_procedure(i, entry, procs, path, problems) for i, entry in enumerate(entries)]
    names = {ps.name for ps in out if ps is not None}
    for j, inst in enumerate(certificate["instruments"]):
        for used in inst.get("used_in", []):
            if used not in names:
                problems.append(f"instrument #{j + 1} 'used_in' names {used!r}, which is no "
                                f"procedure of the study ({', '.join(sorted(names))}).")
    if problems:
        raise InvalidInput(problems)
    meta = {k: str(data[k]) for k in ("subtitle", "customer", "machine", "author") if k in data}
    return Study(title=str(data.get("title", "mtplan study")), path=path,
                 digest=hashlib.sha256(raw).hexdigest(), meta=meta, procedures=out,
                 header=header, **certificate, **top)


def _read(source):
    """(parsed dict, raw bytes for the digest, path or None) of a study source."""
    if isinstance(source, dict):
        return source, repr(sorted(source.items())).encode(), None
    path = Path(source)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise InvalidInput([f"No such study file {str(path)!r}."]) from None
    except OSError as exc:
        raise InvalidInput([f"Cannot read the study file {str(path)!r}: {exc.strerror}."]) from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InvalidInput([f"The study file {str(path)!r} is not valid TOML: {exc}."]) from None
    return data, raw, path


def _top_level(data, problems) -> dict:
    """The study-wide numbers: seed, digits, trials, max_trials, coverage."""
    seed = data.get("seed", 0)
    if not (isinstance(seed, int) and seed >= 0):
        problems.append(f"The study's 'seed' must be an int >= 0. Got {seed!r} instead.")
    _digits(problems, "The study's 'digits'", data.get("digits"))
    trials = data.get("trials")
    if trials is not None and not (isinstance(trials, int) and trials >= 100):
        problems.append(f"The study's 'trials' must be an int >= 100. Got {trials!r} instead.")
    max_trials = data.get("max_trials", 200_000)
    _count(problems, "The study's 'max_trials'", max_trials, 1000)
    coverage = data.get("coverage", 0.95)
    if not (isinstance(coverage, float) and 0 < coverage < 1):
        problems.append(f"The study's 'coverage' must be a number in (0, 1). Got {coverage!r} "
                        "instead.")
    return {"seed": seed, "digits": data.get("digits"), "trials": trials,
            "max_trials": max_trials, "coverage": coverage}


def _header(data, problems) -> dict:
    """The document header: ``[header]``, with the older top-level ``customer``,
    ``machine`` and ``author`` as fall-backs."""
    table = data.get("header", {})
    if not isinstance(table, dict):
        problems.append("The study's 'header' must be a table.")
        table = {}
    _unknown(problems, "The study's header", table, set(HEADER_KEYS))
    legacy = {"customer": data.get("customer"), "machine_type": data.get("machine"),
              "prepared_by": data.get("author")}
    out = {}
    for key in HEADER_KEYS:
        value = table.get(key, legacy.get(key))
        if value is None:
            continue
        if key == "ambient_temperature_c":
            if not (isinstance(value, int | float) and not isinstance(value, bool)
                    and -30 <= value <= 60):
                problems.append("The study's header 'ambient_temperature_c' must be a number "
                                f"from -30 to 60 [degC]. Got {value!r} instead.")
                continue
            out[key] = float(value)
        elif key in _DATE_KEYS and isinstance(value, datetime.date | datetime.datetime):
            out[key] = value.isoformat()
        elif isinstance(value, str | int) and not isinstance(value, bool):
            out[key] = str(value)
        else:
            problems.append(f"The study's header {key!r} must be text. Got {value!r} instead.")
    return out


def _certificate(data, header, problems) -> dict:
    """The laboratory, the test conditions, the instruments and whether the readings are
    simulated: what a test report needs beyond the results (ISO/IEC 17025 7.8)."""
    lab = data.get("laboratory", {})
    if not isinstance(lab, dict):
        problems.append("The study's 'laboratory' must be a table.")
        lab = {}
    _unknown(problems, "The study's laboratory", lab, _LAB_KEYS)
    cond = data.get("conditions", {})
    if not isinstance(cond, dict):
        problems.append("The study's 'conditions' must be a table.")
        cond = {}
    _unknown(problems, "The study's conditions", cond, set(CONDITION_KEYS))
    conditions = {}
    if "ambient_temperature_c" in header:
        conditions["ambient_temperature_c"] = header["ambient_temperature_c"]
    for key, value in cond.items():
        kind = CONDITION_KEYS.get(key, (None, None))[1]
        if kind == "temperature" and not (isinstance(value, int | float)
                                          and not isinstance(value, bool)
                                          and -30 <= value <= 60):
            problems.append(f"The study's conditions {key!r} must be a number from -30 to 60 "
                            f"[degC]. Got {value!r} instead.")
        elif kind == "bool" and not isinstance(value, bool):
            problems.append(f"The study's conditions {key!r} must be true (on) or false "
                            f"(off). Got {value!r} instead.")
        elif kind == "text" and not isinstance(value, str):
            problems.append(f"The study's conditions {key!r} must be text. Got {value!r} "
                            "instead.")
        elif kind is not None:
            conditions[key] = float(value) if kind == "temperature" else value
    instruments = data.get("instrument", [])
    if not isinstance(instruments, list) or not all(isinstance(x, dict) for x in instruments):
        problems.append("The study's 'instrument' must be an array of tables ([[instrument]]).")
        instruments = []
    shown = []
    for j, inst in enumerate(instruments):
        at = f"instrument #{j + 1}"
        _unknown(problems, at, inst, _INSTRUMENT_KEYS)
        for key in ("name", "serial", "certificate"):
            if not (isinstance(inst.get(key), str) and inst[key].strip()):
                problems.append(f"{at} needs {key!r} (text). Got {inst.get(key)!r} instead.")
        due = inst.get("calibration_due")
        if due is not None and not isinstance(due, datetime.date):
            problems.append(f"{at} 'calibration_due' must be a date (2025-06-30). Got {due!r} "
                            "instead.")
        kind = inst.get("kind", "calibration")
        if kind not in INSTRUMENT_KINDS:
            problems.append(f"{at} 'kind' must be one of {', '.join(INSTRUMENT_KINDS)}. Got "
                            f"{kind!r} instead.")
        accredited = inst.get("accredited")
        if accredited is not None and not isinstance(accredited, bool):
            problems.append(f"{at} 'accredited' must be true or false (the certificate issued "
                            f"under an accreditation or not). Got {accredited!r} instead.")
            accredited = None
        for key in ("declared_by", "customer_agreement"):
            if key in inst and not (isinstance(inst[key], str) and inst[key].strip()):
                problems.append(f"{at} {key!r} must be text. Got {inst[key]!r} instead.")
        used = inst.get("used_in", [])
        if not (isinstance(used, list) and all(isinstance(x, str) for x in used)):
            problems.append(f"{at} 'used_in' must be a list of procedure names. Got {used!r} "
                            "instead.")
            used = []
        shown.append({**{k: str(v) for k, v in inst.items()
                         if k not in ("used_in", "accredited")},
                      "used_in": list(used), "accredited": accredited,
                      "kind": kind if kind in INSTRUMENT_KINDS else "calibration"})
    req = data.get("requirements", {})
    if not isinstance(req, dict):
        problems.append("The study's 'requirements' must be a table.")
        req = {}
    _unknown(problems, "The study's requirements", req, set(REQUIREMENT_KEYS))
    requirements = {}
    for key, value in req.items():
        kind = REQUIREMENT_KEYS.get(key, (None, None))[1]
        number = isinstance(value, int | float) and not isinstance(value, bool)
        if kind == "band" and not (isinstance(value, list) and len(value) == 2
                                   and all(isinstance(x, int | float)
                                           and not isinstance(x, bool) for x in value)
                                   and value[0] < value[1]):
            problems.append(f"The study's requirements {key!r} must be a band [low, high] of "
                            f"two numbers, low < high. Got {value!r} instead.")
        elif kind == "number" and not (number and value > 0):
            problems.append(f"The study's requirements {key!r} must be a number > 0. Got "
                            f"{value!r} instead.")
        elif kind == "int" and not (isinstance(value, int) and not isinstance(value, bool)
                                    and value >= 0):
            problems.append(f"The study's requirements {key!r} must be an integer >= 0. Got "
                            f"{value!r} instead.")
        elif kind == "bool" and not isinstance(value, bool):
            problems.append(f"The study's requirements {key!r} must be true or false. Got "
                            f"{value!r} instead.")
        elif kind == "text" and not isinstance(value, str):
            problems.append(f"The study's requirements {key!r} must be text. Got {value!r} "
                            "instead.")
        elif kind == "choice" and value not in LARGER_U:
            problems.append(f"The study's requirements {key!r} must be one of "
                            f"{', '.join(map(repr, LARGER_U))}. Got {value!r} instead.")
        elif kind is not None:
            requirements[key] = ([float(x) for x in value] if kind == "band" else
                                 float(value) if kind == "number" else value)
    simulated = data.get("simulated", False)
    if not isinstance(simulated, bool):
        problems.append(f"The study's 'simulated' must be true or false. Got {simulated!r} "
                        "instead.")
        simulated = False
    return {"laboratory": {k: str(v) for k, v in lab.items()}, "conditions": conditions,
            "instruments": shown, "simulated": simulated, "requirements": requirements}


def _procedure(i, entry, procs, path, problems) -> ProcedureStudy | None:
    """One ``[[procedure]]`` table, validated; None when it cannot be read at all."""
    from mtplan.models.protocol import fields_info, make, resolve_file_fields

    where = f"procedure #{i + 1}"
    if not isinstance(entry, dict):
        problems.append(f"{where} must be a table.")
        return None
    name = entry.get("name")
    where = f"procedure #{i + 1} ({name})"
    _unknown(problems, where, entry, _PROC_KEYS)
    if name not in procs:
        problems.append(f"{where}: unknown procedure; the procedures are: {', '.join(procs)}.")
        return None
    proc = procs[name]
    _count(problems, f"{where} 'trials'", entry.get("trials"), 100)
    _count(problems, f"{where} 'max_trials'", entry.get("max_trials"), 1000)
    _count(problems, f"{where} 'budget_trials'", entry.get("budget_trials"), 100)
    _digits(problems, f"{where} 'digits'", entry.get("digits"))
    if entry.get("budget", "gum") not in ("gum", "mc"):
        problems.append(f"{where} 'budget' must be 'gum' or 'mc'. Got {entry.get('budget')!r} "
                        "instead.")
    setup = truth = None
    stated = entry.get("setup", {})
    if path is not None and isinstance(stated, dict):  # file fields: from the study's folder
        stated = resolve_file_fields(proc.Setup, stated, path.parent)
    try:
        setup = make(proc.Setup, stated, owner=f"{where} setup")
    except InvalidInput as exc:
        problems += exc.problems
    try:
        truth = make(proc.Truth, entry.get("truth", {}), owner=f"{where} truth")
    except InvalidInput as exc:
        problems += exc.problems
    estimators = _estimators(proc, entry.get("estimators", [proc.default_estimator]), where,
                             problems)
    fields = {f["name"] for f in fields_info(proc.Setup)}
    measurands = {m.name for m in proc.measurands(setup)} if setup is not None else set()
    sweeps = _sweeps(proc, entry.get("sweep", []), fields, where, problems)
    plan = _plan(entry.get("plan"), fields, measurands, where, problems)
    if setup is not None:  # every set-up of every grid must be valid, said before computing
        grids = [(f"sweep #{j + 1}", sw.get("vary")) for j, sw in enumerate(sweeps)
                 if isinstance(sw, dict)]
        if plan is not None:
            grids.append(("plan", plan.get("vary")))
        for what, vary in grids:
            problems += _grid_problems(proc, stated, vary, fields,
                                       f"{where} {what}")
    acceptance = _acceptance(entry.get("acceptance"), measurands, path, where, problems)
    readings = _readings(proc, entry.get("readings"), path, where, problems)
    as_left = _as_left(entry.get("as_left"), readings, path, where, problems)
    standards = entry.get("standards", [])
    if not (isinstance(standards, list) and all(isinstance(x, str) for x in standards)):
        problems.append(f"{where} 'standards' must be a list of texts. Got {standards!r} "
                        "instead.")
        standards = []
    machine = entry.get("machine", "")
    if not isinstance(machine, str):
        problems.append(f"{where} 'machine' must be the serial number (text) of the machine "
                        f"the test is run on. Got {machine!r} instead.")
        machine = ""
    positioned = any("position" in a for a in acceptance)
    for cited in standards:
        for std, needs in UNHONOURED_STANDARDS.items():
            if std == "ISO 1101" and positioned:  # a position zone honours it
                continue
            if cited.replace("\u00a0", " ").startswith(std):
                problems.append(f"{where} cites {cited!r}, which requires {needs}; this "
                                "procedure does not evaluate that: remove it from "
                                "'standards'.")
    return ProcedureStudy(name=name, label=str(entry.get("label", proc.title)), setup=setup,
                          truth=truth, estimators=estimators, sweeps=list(sweeps), plan=plan,
                          acceptance=acceptance, readings=readings,
                          as_left=as_left, trials=entry.get("trials"),
                          digits=entry.get("digits"),
                          max_trials=entry.get("max_trials"), budget=entry.get("budget", "gum"),
                          budget_trials=entry.get("budget_trials", 2000),
                          notes=str(entry.get("notes", "")), standards=list(standards),
                          machine=machine.strip())


def _estimators(proc, estimators, where, problems) -> list:
    if estimators == "all":
        estimators = list(proc.estimators)
    if isinstance(estimators, str):
        estimators = [estimators]
    if not isinstance(estimators, list) or not estimators:
        problems.append(f"{where}: 'estimators' must be 'all', a name or a non-empty list.")
        return [proc.default_estimator]
    for e in estimators:
        if e not in proc.estimators:
            problems.append(f"{where}: unknown estimator {e!r}; allowed: "
                            f"{', '.join(proc.estimators)}.")
    return list(estimators)


def _sweeps(proc, sweeps, fields, where, problems) -> list:
    sweeps = [sweeps] if isinstance(sweeps, dict) else sweeps
    for j, sw in enumerate(sweeps):
        at = f"{where} sweep #{j + 1}"
        _unknown(problems, at, sw, _SWEEP_KEYS)
        if isinstance(sw, dict):
            _count(problems, f"{at} 'trials'", sw.get("trials"), 2)
            for e in ([sw["estimators"]] if isinstance(sw.get("estimators"), str)
                      else sw.get("estimators", [])):
                if e not in proc.estimators:
                    problems.append(f"{at}: unknown estimator {e!r}; allowed: "
                                    f"{', '.join(proc.estimators)}.")
        vary = sw.get("vary", {}) if isinstance(sw, dict) else None
        if not vary or not isinstance(vary, dict):
            problems.append(f"{at} needs a non-empty 'vary' table.")
            continue
        for f, values in vary.items():
            if f not in fields:
                problems.append(f"{at} varies {f!r}, which is no set-up field "
                                f"({', '.join(sorted(fields))}).")
            elif not isinstance(values, list) or not values:
                problems.append(f"{at}: the values of {f!r} must be a non-empty list.")
    return sweeps


def _plan(plan, fields, measurands, where, problems) -> dict | None:
    if _subtable(problems, where, "plan", plan, _PLAN_KEYS) is None:
        return None
    for f in plan.get("vary", {}):
        if f not in fields:
            problems.append(f"{where} plan varies {f!r}, which is no set-up field.")
    for m in plan.get("targets", {}):
        if m not in measurands:
            problems.append(f"{where} plan targets {m!r}, which is no measurand "
                            f"({', '.join(sorted(measurands))}).")
    if not plan.get("targets"):
        problems.append(f"{where} plan needs a 'targets' table.")
    return plan


def _acceptance(tables, measurands, path, where, problems) -> list:
    """``[procedure.acceptance]`` (one table) or ``[[procedure.acceptance]]`` (one per
    toleranced measurand), each checked; prior files relative to the study file."""
    from mtplan.plans import acceptance as _acc

    if tables is None:
        return []
    tables = [tables] if isinstance(tables, dict) else tables
    if not isinstance(tables, list) or not all(isinstance(t, dict) for t in tables):
        problems.append(f"{where} 'acceptance' must be a table or a list of tables.")
        return []
    out, seen = [], set()
    for j, acc in enumerate(tables):
        at = f"{where} acceptance" + (f" #{j + 1}" if len(tables) > 1 else "")
        if "position" not in acc:
            _unknown(problems, at, acc, _ACCEPT_KEYS)
        prior = acc.get("prior")
        if isinstance(prior, str) and path is not None and not Path(prior).is_absolute() \
                and not prior.lower().startswith(("normal:", "gamma:")):
            acc = {**acc, "prior": str(path.parent / prior)}
        for key, parse in (("prior", _acc.parse_prior), ("rule", _acc.parse_rule)):
            if acc.get(key) is not None:
                try:
                    parse(acc[key])
                except InvalidInput as exc:
                    problems += [f"{at}: {p}" for p in exc.problems]
        if "position" in acc:
            out.append(_position(acc, measurands, seen, at, problems))
            continue
        name = acc.get("measurand")
        if name not in measurands:
            problems.append(f"{at} names measurand {name!r}, which is no measurand "
                            f"({', '.join(sorted(measurands))}).")
        elif name in seen:
            problems.append(f"{at} repeats measurand {name!r}; one tolerance per measurand.")
        seen.add(name)
        for key in ("population_source", "tolerance_source", "frame"):
            source = acc.get(key)
            if source is not None and not isinstance(source, str):
                problems.append(f"{at} {key!r} must be text. Got {source!r} instead.")
        for key in ("lower", "upper", "measured"):
            v = acc.get(key)
            if v is not None and not (isinstance(v, int | float) and not isinstance(v, bool)
                                      and math.isfinite(v)):
                problems.append(f"{at} '{key}' must be a number. Got {v!r} instead.")
        lo, hi = acc.get("lower"), acc.get("upper")
        if lo is None and hi is None:
            problems.append(f"{at} needs 'lower' and/or 'upper' limits.")
        elif isinstance(lo, int | float) and isinstance(hi, int | float) and not hi > lo:
            problems.append(f"{at} 'upper' must be > 'lower' = {lo!r}. Got {hi!r} instead.")
        out.append(acc)
    return out


def _position(acc, measurands, seen, at, problems) -> dict:
    """A position tolerance as a diameter zone (ISO 1101): ``position`` (two coordinate
    measurands), ``nominal`` (their nominal values), ``diameter`` (the zone, > 0, in their
    unit) and a name (``measurand``, default ``position``) that no measurand has; its
    prior and rule are checked by :func:`_acceptance`."""
    _unknown(problems, at, acc, _POSITION_KEYS)
    acc = {"measurand": "position", **acc}
    pos, nominal, d = acc.get("position"), acc.get("nominal"), acc.get("diameter")
    if not (isinstance(pos, list) and len(pos) == 2 and all(p in measurands for p in pos)
            and pos[0] != pos[1]):
        problems.append(f"{at} 'position' must name two different coordinate measurands "
                        f"({', '.join(sorted(measurands))}). Got {pos!r} instead.")
    if not (isinstance(nominal, list) and len(nominal) == 2
            and all(isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
                    for x in nominal)):
        problems.append(f"{at} 'nominal' must be the two coordinates' nominal values "
                        f"[x, y]. Got {nominal!r} instead.")
    if not (isinstance(d, int | float) and not isinstance(d, bool) and math.isfinite(d)
            and d > 0):
        problems.append(f"{at} 'diameter' must be a number > 0 (the zone's diameter in the "
                        f"coordinates' unit). Got {d!r} instead.")
    name = acc["measurand"]
    if not isinstance(name, str) or name in measurands or name in seen:
        problems.append(f"{at} 'measurand' names the position {name!r}, which must be a new "
                        "name (no measurand of the procedure and no other tolerance's).")
    seen.add(name)
    # a deviation is >= 0: the zone is a one-sided tolerance, 0 to the diameter
    return {**acc, "lower": None, "upper": float(d) if isinstance(d, int | float) else None}


def _as_left(table, readings, path, where, problems) -> dict | None:
    """``[procedure.as_left]``: readings taken again after an adjustment (``file``, same
    format as the readings), evaluated and decided as the readings are; ``adjustment``
    says what was adjusted."""
    if _subtable(problems, where, "as_left", table, _AS_LEFT_KEYS) is None:
        return None
    if readings is None:
        problems.append(f"{where} 'as_left' needs the readings as found ([procedure.readings]) "
                        "too.")
    note = table.get("adjustment", "")
    if not isinstance(note, str):
        problems.append(f"{where} as_left 'adjustment' must be text. Got {note!r} instead.")
    f = table.get("file")
    rp = Path(f) if isinstance(f, str) and f else None
    if rp is not None and not rp.is_absolute() and path is not None:
        rp = path.parent / rp
    if rp is None or not rp.exists():
        problems.append(f"{where} as_left file {f!r} does not exist.")
        return table
    return {**table, "file": rp}


def _readings(proc, readings, path, where, problems) -> dict | None:
    if _subtable(problems, where, "readings", readings, _READ_KEYS) is None:
        return None
    if readings.get("estimator") is not None and readings["estimator"] not in proc.estimators:
        problems.append(f"{where} readings: unknown estimator {readings.get('estimator')!r}; "
                        f"allowed: {', '.join(proc.estimators)}.")
    f = readings.get("file")
    rp = Path(f) if f else None
    if rp is not None and not rp.is_absolute() and path is not None:
        rp = path.parent / rp
    if rp is None or not rp.exists():
        problems.append(f"{where} readings file {f!r} does not exist.")
    else:
        readings = {**readings, "file": rp}
    if readings.get("uncertainty", "mc") not in ("mc", "posterior"):
        problems.append(f"{where} readings 'uncertainty' must be 'mc' or 'posterior'.")
    return readings


def _grid_problems(proc, base, vary, fields, where) -> list[str]:
    import itertools

    from mtplan.models.protocol import make

    if not isinstance(vary, dict) or not vary:
        return []
    vary = {f: v for f, v in vary.items() if f in fields and isinstance(v, list) and v}
    found = []
    for combo in itertools.product(*vary.values()):
        at = dict(zip(vary, combo, strict=True))
        try:
            make(proc.Setup, {**base, **at}, owner="")
        except InvalidInput as exc:
            shown = ", ".join(f"{k}={v}" for k, v in at.items())
            found += [f"{where} at {shown}: {p.lstrip(': ')}" for p in exc.problems]
        if len(found) >= 5:
            found.append(f"{where}: (further problems in this grid left out)")
            break
    return found


@dataclass
class ProcedureOutcome:
    """Everything computed for one procedure of a study (display units).

    ``recommended`` is the estimator the study recommends (:func:`decisions.
    recommend_estimator`) over the measurands in ``key`` (toleranced and targeted ones);
    ``verdicts`` holds a :class:`~mtplan.plans.decisions.Verdict` per toleranced measurand,
    ``summary`` the procedure's rows of the summary page, ``levers`` the swept levers
    ranked by their effect, ``dominant`` the error sources that dominate, ``targets`` the
    target u per measurand for the figures, ``setup_shown`` the set-up fields a reader needs.
    """

    spec: ProcedureStudy
    title: str
    results: dict                      # estimator -> ProcedureResult
    gum: object                        # GUMResult of the recommended estimator, or None
    budget: object                     # DataFrame: measurand, source, contribution, share
    sweeps: list                       # (spec dict, DataFrame)
    plan: object | None = None         # PlanResult or an error message
    measured: object | None = None     # result of the readings evaluation
    identifiability: object | None = None
    extras: dict = field(default_factory=dict)
    recommended: str = ""
    key: list = field(default_factory=list)
    verdicts: list = field(default_factory=list)
    summary: list = field(default_factory=list)
    levers: list = field(default_factory=list)
    dominant: list = field(default_factory=list)
    comparison: dict = field(default_factory=dict)
    targets: dict = field(default_factory=dict)
    setup_shown: dict = field(default_factory=dict)
    duration_s: float = math.nan
    budget_estimator: str = ""
    as_left: object | None = None      # readings after adjustment, evaluated
    as_left_verdicts: list = field(default_factory=list)


@dataclass
class StudyResult:
    study: Study
    outcomes: list
    provenance: dict
    #: what ``run_study``'s ``then`` gave for each test (in test order), or None
    then: list | None = None

    @property
    def verdicts(self) -> list:
        """Every toleranced measurand's verdict, in study order."""
        return [v for o in self.outcomes for v in o.verdicts]


def _git_commit() -> str | None:
    """The git commit of the mtplan source when it runs from a checkout, else None."""
    import subprocess

    package = Path(__file__).resolve().parent.parent
    try:
        top = subprocess.run(["git", "-C", str(package), "rev-parse", "--show-toplevel"],
                             capture_output=True, text=True, timeout=10, check=True)
        if Path(top.stdout.strip()).resolve() / "src" / "mtplan" != package:
            return None
        head = subprocess.run(["git", "-C", str(package), "rev-parse", "HEAD"],
                              capture_output=True, text=True, timeout=10, check=True)
        dirty = subprocess.run(["git", "-C", str(package), "status", "--porcelain",
                                "--untracked-files=no", "--", str(package)],
                               capture_output=True, text=True, timeout=10, check=True)
    except (OSError, subprocess.SubprocessError):
        return None
    return head.stdout.strip() + (" with uncommitted changes" if dirty.stdout.strip() else "")


def _sha256(path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _provenance(study: Study, command: str | None) -> dict:
    import importlib.metadata as md
    import platform

    versions = {}
    for pkg in ("mtplan", "numpy", "scipy", "pandas", "matplotlib", "joblib", "emcee", "jinja2",
                "reportlab"):
        try:
            versions[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            versions[pkg] = "not installed"
    readings = [(ps.label, str(ps.readings["file"]), _sha256(ps.readings["file"]))
                for ps in study.procedures if ps.readings is not None]
    readings += [(f"{ps.label} (as left)", str(ps.as_left["file"]),
                  _sha256(ps.as_left["file"])) for ps in study.procedures if ps.as_left]
    return {
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "command": command or "(called from Python)",
        "git_commit": _git_commit(),
        "study_file": str(study.path) if study.path else "(in memory)",
        "study_sha256": study.digest,
        "readings": readings,
        "seed": study.seed,
        "python": platform.python_version(),
        "versions": versions,
    }


def run_study(study: Study, *, progress=None, n_jobs: int = 1,
              command: str | None = None, readings: bool = True, then=None) -> StudyResult:
    """Compute every result a study asks for (the reports only render them).

    The work is cut into stages, each computed on one core: each estimator's Monte Carlo,
    each distinct set-up of a procedure's sweeps (one stage for every sweep that holds it:
    the base set-up is in most), and each procedure's plan, identifiability and extras;
    then, as soon as a procedure's Monte Carlo stages are done and so its recommended
    estimator is known, its budget and its readings evaluation. ``n_jobs`` worker
    processes take the ready stages, the readings and budgets first (the longest, on which
    the procedure waits), the sweeps' set-ups last, those of the procedures whose Monte
    Carlo was quickest first (:func:`_order`). Every stage
    draws from the study's seed exactly as a serial run does, so the result does not depend
    on ``n_jobs`` nor on the order the stages ran in (beyond the last bits of floating-point
    sums, which numpy and BLAS may add in another order in another process).

    Parameters
    ----------
    study : Study
    progress : bool or None
        A progress bar on stderr: True, False, or None (only on a terminal).
    n_jobs : int
        Parallel worker processes (-1: all cores).
    command : str, optional
        The command line that asked for the study, for the provenance.
    readings : bool
        Evaluate the readings (False: the plan only, issued before measuring).
    then : callable or tuple of callables, optional
        ``then(k, outcome)``, a module-level function, run on the workers as one more stage
        of test ``k`` (1-based) as soon as its outcome is complete, while the other tests
        are still computed (the documents' figures of a test, say); its values, in test
        order, are the result's ``then``. A tuple: each function its own stage (so that a
        test's parts are drawn on several workers), the values a tuple per test.
    """
    from mtplan._parallel import effective_jobs
    from mtplan.plans import decisions

    procs = study.procedures
    # each sweep's grid here; each distinct set-up of a procedure's sweeps one stage, with
    # the estimators of every sweep that holds it (the base set-up is in most of them)
    grids = {(i, j): _sweep_grid(_model(ps.name), ps, study, sw)
             for i, ps in enumerate(procs) for j, sw in enumerate(ps.sweeps)}
    points = _points(grids)
    bar = _bar(progress, _count_steps(study, len(points)))
    partial = {}  # procedure index -> (results, key, recommended, its later stages)
    outcomes, payloads = {}, {}
    thens = tuple(then) if isinstance(then, (tuple, list)) else () if then is None else (then,)

    def unlocked(i, done):
        """The budget and readings stages of procedure ``i`` once its Monte Carlo is done;
        its ``then`` stage once all of its stages are."""
        ps = procs[i]
        if i not in partial:
            if any(("mc", i, est) not in done for est in ps.estimators):
                return []
            results = {est: done[("mc", i, est)] for est in ps.estimators}
            targeted = list((ps.plan or {}).get("targets", {}))
            key = decisions.key_measurands(results[ps.estimators[0]].measurands,
                                           [a["measurand"] for a in ps.acceptance], targeted)
            best = decisions.recommend_estimator(results, key)
            later = [(kind, i, best) for kind in ("readings", "as_left", "budget")
                     if kind == "budget" or (readings and ps.readings is not None
                                             and (kind == "readings" or ps.as_left is not None))]
            partial[i] = (results, key, best, later)
            return later
        if not thens or i in outcomes:
            return []
        mine = [t for (j, _), t in points.items() if j == i] + partial[i][3] + [("misc", i, None)]
        if any(t not in done for t in mine):
            return []
        outcomes[i] = _outcome(i, ps, partial[i], grids, points, done)
        for j, function in enumerate(thens):
            payloads[("then", i, j)] = (function, i + 1, outcomes[i])
        return [("then", i, j) for j in range(len(thens))]

    first = [("mc", i, est) for i, ps in enumerate(procs) for est in ps.estimators]
    first += list(points.values())
    first += [("misc", i, None) for i in range(len(procs))]
    done = _run_stages(first, unlocked, study, effective_jobs(n_jobs), bar, payloads)
    for i, ps in enumerate(procs):
        if i not in outcomes:
            outcomes[i] = _outcome(i, ps, partial[i], grids, points, done)
    if bar is not None:
        bar.close()
    return StudyResult(study=study, outcomes=[outcomes[i] for i in range(len(procs))],
                       provenance=_provenance(study, command),
                       then=None if not thens else [
                           tuple(done[("then", i, j)] for j in range(len(thens)))
                           if isinstance(then, (tuple, list)) else done[("then", i, 0)]
                           for i in range(len(procs))])


def _outcome(i, ps, partial, grids, points, done) -> ProcedureOutcome:
    """Test ``i``'s outcome from its stages' results: verdicts, advice and summary."""
    from mtplan.plans import decisions

    results, key, recommended, _ = partial
    budget, gum, budget_estimator = done[("budget", i, recommended)]
    plan, identifiability, extras = done[("misc", i, None)]
    outcome = ProcedureOutcome(
        spec=ps, title=_model(ps.name).title, results=results, gum=gum, budget=budget,
        sweeps=[_sweep_result(ps.sweeps[j], grids[(i, j)], i, points, done)
                for j in range(len(ps.sweeps))], plan=plan,
        measured=done.get(("readings", i, recommended)), identifiability=identifiability,
        extras=extras, recommended=recommended, key=key, budget_estimator=budget_estimator)
    decider = results.get(getattr(outcome.measured, "estimator", None), results[recommended])
    outcome.verdicts = decisions.conformity(ps.name, ps.label, ps.acceptance, decider,
                                            outcome.measured)
    outcome.as_left = done.get(("as_left", i, recommended))  # after an adjustment
    if outcome.as_left is not None:
        outcome.as_left_verdicts = decisions.conformity(ps.name, ps.label, ps.acceptance,
                                                        decider, outcome.as_left)
    _advise(outcome, _model(ps.name), i + 1)
    return outcome


def _model(name):
    from mtplan.models import get

    return get(name)


#: which ready stage a free worker takes first: the long ones a procedure waits on, then
#: what completes a procedure soonest (a procedure's ``then`` waits for its last sweep)
_PRIORITY = {"as_left": 0, "readings": 0, "budget": 1, "then": 1, "mc": 2, "misc": 2,
             "point": 3}


def _order(ready, cost) -> None:
    """Sort the ready stages in place: by :data:`_PRIORITY`, and the sweeps' set-ups of the
    procedures whose Monte Carlo took least time (``cost``: seconds per procedure index,
    those not yet timed last) first, so that those procedures complete, and their ``then``
    runs, while the costly ones' set-ups are still computed; otherwise in study order."""
    ready.sort(key=lambda t: (_PRIORITY[t[0]],
                              cost.get(t[1], math.inf) if t[0] == "point" else 0.0))


def _run_stages(tasks, unlocked, study, jobs, bar, payloads) -> dict:
    """Every stage's result, {(kind, procedure index, arg): result}: ``tasks`` and those
    ``unlocked(i, done)`` adds as they become ready, on ``jobs`` processes (one stage, on
    one core, per worker at a time) or, for one job, here. A stage in ``payloads`` is
    given its payload as its argument instead of its key's."""
    ready, cost, started = list(tasks), {}, {}
    _order(ready, cost)
    done = {}

    def finish(task, value):
        done[task] = value
        kind, i, arg = task
        if kind == "mc" and task in started:
            cost[i] = cost.get(i, 0.0) + time.perf_counter() - started.pop(task)
        name = study.procedures[i].name
        if kind in ("mc", "point", "budget", "readings", "as_left"):
            _tick(bar, f"{name} {arg if kind == 'mc' else 'sweep' if kind == 'point' else kind}")
        elif kind == "misc" and study.procedures[i].plan is not None:
            _tick(bar, f"{name} plan")
        ready.extend(unlocked(i, done))
        _order(ready, cost)  # stable: study order within a kind

    if jobs == 1:
        while ready:
            task = ready.pop(0)
            finish(task, _stage_work(task[0], study.procedures[task[1]], study,
                                     payloads.pop(task, task[2])))
        return done
    from concurrent.futures import FIRST_COMPLETED, wait

    from mtplan._parallel import stage_executor

    executor = stage_executor(jobs)  # forked: with the modules imported here (the models)
    running = {}
    while ready or running:
        while ready and len(running) < jobs:
            task = ready.pop(0)
            started[task] = time.perf_counter()
            running[executor.submit(_stage, task[0], study.procedures[task[1]], study,
                                    payloads.pop(task, task[2]))] = task
        finished, _ = wait(running, return_when=FIRST_COMPLETED)
        for future in finished:
            finish(running.pop(future), future.result())
    return done


def _stage(kind, ps, study, arg):
    """One stage of a procedure (see :func:`run_study`) in a worker: with one BLAS thread,
    as the workers share the cores."""
    from mtplan._parallel import one_blas_thread

    with one_blas_thread():  # scipy's own OpenBLAS too
        return _stage_work(kind, ps, study, arg)


def _stage_work(kind, ps, study, arg):
    """One stage of a procedure, in this process."""
    from mtplan.evaluation.simulation import simulate_uncertainty

    if kind == "then":
        function, k, outcome = arg
        return function(k, outcome)
    proc = _model(ps.name)
    if kind == "mc":
        # the procedure's own choice wins over the study's: trials (fixed) or digits
        if ps.trials is not None or ps.digits is not None:
            digits, trials = ps.digits, ps.trials
        else:
            digits, trials = study.digits, study.trials
        if digits is None and trials is None:
            trials = 10_000
        return simulate_uncertainty(
            proc, ps.setup, ps.truth, estimator=arg, trials=None if digits else trials,
            digits=digits, coverage=study.coverage, rng=study.seed, n_jobs=1,
            progress=False, max_trials=ps.max_trials or study.max_trials)
    if kind == "point":
        from mtplan.plans.sweep import point_rows

        return {est: point_rows(proc, arg.setup, ps.truth, est, None, dict(arg.options),
                                study.seed) for est in arg.estimators}
    if kind == "misc":
        plan = _run_plan(proc, ps, study) if ps.plan is not None else None
        return plan, _identifiability(proc, ps), _extras(proc, ps)
    if kind == "budget":
        return _run_budget(proc, ps, study, arg)
    if kind == "as_left":
        return _run_measured(proc, ps, study, arg, ps.as_left["file"])
    return _run_measured(proc, ps, study, arg)


def _run_budget(proc, ps, study, recommended):
    """(budget, GUM result or None, the estimator the budget is of)."""
    from mtplan.evaluation.simulation import linearize_procedure
    from mtplan.uncertainty.montecarlo import ModelError

    if ps.budget == "gum":
        gum = linearize_procedure(proc, ps.setup, ps.truth, estimator=recommended,
                                  coverage=study.coverage)
        return gum.budget(), gum, recommended
    try:
        return _mc_budget(proc, ps, study, 1, recommended), None, recommended
    except ModelError:  # one source alone can leave an estimator without a solution
        return _mc_budget(proc, ps, study, 1, ps.estimators[0]), None, ps.estimators[0]


@dataclass(frozen=True)
class _Point:
    """One set-up of a procedure's sweeps, with the Monte Carlo options of its sweep: a
    stage that evaluates every estimator any of those sweeps asks of it, one after the
    other in one process (they share the procedure's caches of the set-up), once for all
    the sweeps that hold it. ``fields``: its field values as text (the same text, the same
    seed and rows, :func:`~mtplan.plans.sweep.setup_seed`)."""

    fields: str
    options: tuple
    estimators: tuple
    setup: object = field(compare=False)


class _Grid:
    """A sweep's set-ups (grid order), estimators and options, and each set-up's key
    (field values as text, options) to its :class:`_Point`."""

    def __init__(self, setups, estimators, options):
        from mtplan.plans.sweep import _canonical  # the text the set-up's seed is made of

        self.setups, self.estimators = setups, list(estimators)
        opts = tuple(sorted(options.items()))
        self.keys = [(_canonical(s), opts) for s in setups]


def _points(grids) -> dict:
    """{(procedure index, set-up key): the point stage} over the study's sweeps
    ({(i, j): _Grid or the reason it cannot run}): one stage per distinct set-up and
    options of a procedure, with the estimators of every sweep that holds it."""
    wanted = {}
    for (i, _), g in grids.items():
        if isinstance(g, str):
            continue
        for setup, key in zip(g.setups, g.keys, strict=True):
            ests = wanted.setdefault((i, key), (setup, []))[1]
            ests += [e for e in g.estimators if e not in ests]
    return {(i, key): ("point", i, _Point(key[0], key[1], tuple(ests), setup))
            for (i, key), (setup, ests) in wanted.items()}


def _sweep_grid(proc, ps, study, sw):
    """The grid of a sweep of the study (:class:`_Grid`), or why it cannot run (a set-up
    the procedure refuses is a finding, shown in the report)."""
    from mtplan.plans.sweep import sweep_grid

    try:
        g = sweep_grid(proc, ps.setup, sw["vary"], truth=ps.truth,
                       estimators=sw.get("estimators", ps.estimators),
                       trials=sw.get("trials", 2000), seed=study.seed)
    except InvalidInput as exc:
        return " ".join(exc.problems)
    return _Grid(g.setups, g.estimators, g.options)


def _sweep_result(sw, grid, i, points, done):
    """(spec, table) of a sweep from its point stages: the table :func:`~mtplan.plans.sweep.
    sweep` gives for it (each set-up's rows are a function of the set-up alone)."""
    import pandas as pd

    from mtplan.plans.sweep import sweep_table

    if isinstance(grid, str):
        return sw, grid
    frames = []
    for p, key in enumerate(grid.keys):
        rows = done[points[(i, key)]]
        frames.append(pd.DataFrame([dict(row, point=p) for est in grid.estimators
                                    for row in rows[est]]))
    table = sweep_table(frames)
    table.attrs["notes"] = []
    return sw, table


def _advise(outcome, proc, k) -> None:
    """The summary rows, the levers ranked, the dominant sources and the targets."""
    from mtplan.models.protocol import fields_info
    from mtplan.plans import decisions

    ps = outcome.spec
    result = outcome.results[outcome.recommended]
    varied = {f for sw in ps.sweeps for f in sw["vary"]} | set((ps.plan or {}).get("vary", {}))
    outcome.setup_shown = decisions.shown_setup(ps.setup, proc.Setup(), proc.levers, varied)
    outcome.duration_s = float(proc.duration(ps.setup))
    outcome.summary = decisions.summary_rows(k, ps.name, ps.label, result, outcome.key,
                                             outcome.verdicts, outcome.measured,
                                             outcome.setup_shown, outcome.duration_s)
    outcome.levers = decisions.lever_effects(proc.levers, ps.setup, outcome.sweeps, outcome.key,
                                             outcome.recommended)
    outcome.dominant = decisions.dominant_sources(
        outcome.budget, proc.levers, [f["name"] for f in fields_info(proc.Setup)])
    outcome.comparison = decisions.estimator_comparison(outcome.results)
    outcome.targets = decisions.u_targets(ps.plan, outcome.verdicts)


def _mc_budget(proc, ps, study, n_jobs, estimator):
    """Budget by Monte Carlo: each active error source alone, ``budget_trials`` trials.

    For estimators that are not smooth in the readings (integer shifts, thresholds) the
    law of propagation's finite differences mean nothing; switching sources on one at a
    time shows each one's own effect. ``share`` is its variance over the sum of the
    single-source variances (interactions, if any, are left out).
    """
    import pandas as pd

    from mtplan.evaluation.simulation import source_budget

    df = source_budget(proc, ps.setup, ps.truth, estimator=estimator,
                       trials=ps.budget_trials, rng=study.seed, n_jobs=n_jobs)
    return pd.DataFrame({"output": df["measurand"], "input": df["source"], "u_input": math.nan,
                         "sensitivity": math.nan, "contribution": df["std"],
                         "share": df["share"]})


def _count_steps(study, points):
    n = points
    for ps in study.procedures:
        n += len(ps.estimators) + 1
        n += sum(x is not None for x in (ps.plan, ps.readings, ps.as_left))
    return n


class _Lines:
    """The progress where stderr is no terminal (a CI log, a pipe): one short line per
    finished stage, instead of a bar redrawn with carriage returns."""

    def __init__(self, total: int, file):
        self.total, self.n, self.file = total, 0, file
        self.text = ""

    def set_postfix_str(self, text: str) -> None:
        self.text = text

    def update(self, n: int = 1) -> None:
        self.n += n
        print(f"study {self.n}/{self.total}: {self.text}", file=self.file, flush=True)

    def close(self) -> None:
        pass


def _bar(progress, total):
    """A progress bar on a terminal; with ``progress`` True and stderr no terminal, a line
    per stage; None where there is nothing to show."""
    import sys

    if progress is False or (progress is None and not sys.stderr.isatty()):
        return None
    if not sys.stderr.isatty():
        return _Lines(total, sys.stderr)
    from tqdm.auto import tqdm

    tqdm.monitor_interval = 0  # no monitor thread: the stage workers are forked after it
    return tqdm(total=total, desc="study", unit="step", file=sys.stderr, leave=False)


def _tick(bar, text):
    if bar is not None:
        bar.set_postfix_str(text)
        bar.update(1)


def _run_plan(proc, ps, study):
    from mtplan.plans.planner import plan

    spec = ps.plan
    try:
        return plan(proc, ps.setup, spec.get("vary", {}), spec["targets"], k=spec.get("k", 1.0),
                    truth=ps.truth, estimator=spec.get("estimator", ps.estimators[0]),
                    trials=spec.get("trials", 4000), seed=study.seed)
    except InvalidInput as exc:  # an impossible target is a finding, not a crash
        return " ".join(exc.problems)


def _run_measured(proc, ps, study, recommended, file=None):
    """The readings (or those of ``file``, taken after an adjustment) evaluated, by default
    with the estimator the study recommends."""
    from mtplan.evaluation import measured

    spec = ps.readings
    readings = measured.read_readings(proc, ps.setup, file or spec["file"])
    return measured.estimate_measured(proc, ps.setup, readings,
                                      estimator=spec.get("estimator") or recommended,
                                      uncertainty=spec.get("uncertainty", "mc"),
                                      trials=spec.get("trials", 10_000), coverage=study.coverage,
                                      rng=study.seed,
                                      allow_unconverged=bool(spec.get("allow_unconverged", False)),
                                      posterior_options=spec.get("options"))


def _identifiability(proc, ps):
    """Rank, conditioning, O1-O5 and the inseparable combinations of the set-up's parameters.

    A procedure with its own ``identifiability_report`` (geometry21: the joint model of every
    error coefficient) is asked for it; otherwise the readings' sensitivities to the
    measurands (or truth fields) are analysed.
    """
    from types import SimpleNamespace

    from mtplan.plans.identifiability import identifiability, observability_indices
    from mtplan.plans.planner import readings_jacobian

    if proc.capabilities.identifiability_report is not None:
        rep = proc.capabilities.identifiability_report(ps.setup)
        sv = np.asarray(rep["singular_values"], dtype=float)
        nulls = [" ".join(f"{w:+.2f} {k}" for k, w in list(d.items())[:6])
                 + (" ..." if len(d) > 6 else "") for d in rep["null_space"]]
        return SimpleNamespace(
            names=[f"{rep['parameters']} coefficients and mounting parameters"],
            n_params=int(rep["parameters"]), rank=int(rep["rank"]),
            condition_number=float(rep["condition_number"]),
            observability=observability_indices(sv, int(rep["readings"])),
            null_combinations=nulls)
    J, names = readings_jacobian(proc, ps.setup, ps.truth)
    return identifiability(J, names=names)


def _extras(proc, ps):
    """Procedure-specific material for the report: the procedure's ``report_extras(setup,
    truth) -> dict`` (data only; the reports draw it), with its per-estimator
    ``identifiability`` and its ``observability`` where it declares them."""
    hook = proc.capabilities.report_extras
    extras = dict(hook(ps.setup, ps.truth)) if hook else {}
    # what the patent's method cannot see: per-estimator identifiability or observability
    if proc.capabilities.identifiability is not None and "identifiability" not in extras:
        extras["identifiability"] = {est: proc.capabilities.identifiability(ps.setup, est)
                                     for est in ps.estimators}
    if proc.capabilities.observability is not None and "observability" not in extras:
        extras["observability"] = proc.capabilities.observability(ps.setup)
    return extras


# ----------------------------------------------------------------------- the result cache
#: the packages whose versions a study's numbers depend on (besides mtplan's own code)
_NUMERIC_PACKAGES = ("numpy", "scipy", "pandas", "emcee", "joblib")


def study_cache_key(study: Study, readings: bool = True) -> str:
    """SHA-256 of everything a study's result depends on: the study file, its readings
    files, whether the readings are evaluated, every file of the installed mtplan package
    (its code, templates and examples), the Python version and the numeric packages'
    versions. Any change to one of them gives another key; ``n_jobs`` does not enter (the
    result does not depend on it)."""
    import importlib.metadata as md
    import platform

    digest = hashlib.sha256()
    digest.update(f"study {study.digest}\nreadings {bool(readings)}\n".encode())
    for ps in study.procedures:
        if ps.readings is not None and readings:
            digest.update(f"{ps.name} {_sha256(ps.readings['file'])}\n".encode())
            if ps.as_left is not None:
                digest.update(f"{ps.name} as left {_sha256(ps.as_left['file'])}\n".encode())
    package = Path(__file__).resolve().parent.parent
    for path in sorted(package.rglob("*")):
        if path.is_file() and "__pycache__" not in path.parts:
            digest.update(f"{path.relative_to(package).as_posix()} {_sha256(path)}\n".encode())
    digest.update(f"python {platform.python_version()} {platform.machine()}\n".encode())
    for pkg in _NUMERIC_PACKAGES:
        try:
            digest.update(f"{pkg} {md.version(pkg)}\n".encode())
        except md.PackageNotFoundError:
            digest.update(f"{pkg} -\n".encode())
    return digest.hexdigest()


def run_study_cached(study: Study, cache_dir, *, progress=None, n_jobs: int = 1,
                     command: str | None = None, readings: bool = True,
                     then=None) -> StudyResult:
    """:func:`run_study`, or its result stored in ``cache_dir`` by an earlier run with the
    same :func:`study_cache_key` (None: always computed). The provenance is this run's (its
    date and command) and names the cache file the numbers were read from. ``then`` as
    :func:`run_study` where the study is computed (a result read from the cache has none)."""
    import os
    import pickle

    if cache_dir is None:
        return run_study(study, progress=progress, n_jobs=n_jobs, command=command,
                         readings=readings, then=then)
    key = study_cache_key(study, readings)
    path = Path(cache_dir) / f"study-{key}.pickle"
    try:
        with open(path, "rb") as fh:
            outcomes = pickle.load(fh)
    except (OSError, EOFError, pickle.UnpicklingError, AttributeError, ImportError):
        outcomes = None  # none stored, or unreadable: computed again and stored anew
    if outcomes is not None:
        for outcome, ps in zip(outcomes, study.procedures, strict=True):
            outcome.spec = ps  # the same content (the key says so); this run's file paths
        provenance = _provenance(study, command)
        provenance["cached"] = str(path)
        return StudyResult(study=study, outcomes=outcomes, provenance=provenance)
    result = run_study(study, progress=progress, n_jobs=n_jobs, command=command,
                       readings=readings, then=then)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        with open(tmp, "wb") as fh:
            pickle.dump(result.outcomes, fh, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, path)
        _prune(path.parent)
    except OSError:  # a cache that cannot be written only costs the next run its time
        pass
    return result


#: how many study results the cache keeps (the newest; each code change makes a new key)
CACHE_KEEP = 4


def _prune(folder: Path) -> None:
    """Remove all but the CACHE_KEEP newest study results of the cache folder."""
    stored = sorted(folder.glob("study-*.pickle"), key=lambda p: p.stat().st_mtime,
                    reverse=True)
    for old in stored[CACHE_KEEP:]:
        old.unlink(missing_ok=True)
