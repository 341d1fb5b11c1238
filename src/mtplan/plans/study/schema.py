"""A study's TOML file: its schema, read and validated.

:func:`load_study` reads a study file (or an already parsed dict), checks the whole of it
and lists every problem at once, each naming its place; it returns a :class:`Study` of
:class:`ProcedureStudy` records that :func:`~mtplan.plans.study.runner.run_study` computes.

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
from dataclasses import dataclass, field
from pathlib import Path

from mtplan._validate import InvalidInput
from mtplan.models.protocol import with_conditions

__all__ = ["Study", "ProcedureStudy", "HEADER_KEYS", "CONDITION_KEYS", "REQUIREMENT_KEYS",
           "CONDITION_CHECKS", "CONDITION_EFFECTS", "LARGER_U", "INSTRUMENT_KINDS",
           "UNHONOURED_STANDARDS", "load_study", "machine_serials"]

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


# --- what an accredited certificate states (ISO/IEC 17025 7.2.2, 7.8.2.1; ILAC-P8) --------
#: [laboratory] keys: whether the report is issued under an accreditation (``accredited``,
#: true or false; ``accreditation`` then names the body and number), who signs it and in
#: which function, and per procedure of the study (all are non-standard methods, ISO/IEC
#: 17025 7.2.2) the laboratory's procedure identifier and its validation reference
#: (``[laboratory.procedures] NAME = { id = "...", validation = "..." }``)
ACCREDITATION_KEYS = {"accredited", "signatory", "signatory_function", "procedures"}
_LAB_PROCEDURE_KEYS = {"id", "validation"}


def _accreditation(lab: dict, problems) -> dict:
    """The [laboratory] table with its accreditation keys checked: ``accredited`` a bool,
    ``signatory`` and ``signatory_function`` text, ``procedures`` a table of
    ``{id, validation}`` tables; every other key kept as text."""
    out = {k: str(v) for k, v in lab.items() if k not in ACCREDITATION_KEYS}
    accredited = lab.get("accredited")
    if accredited is not None and not isinstance(accredited, bool):
        problems.append("The study's laboratory 'accredited' must be true or false (the report "
                        f"issued under an accreditation or not). Got {accredited!r} instead.")
    elif accredited is not None:
        out["accredited"] = accredited
        if accredited and not str(lab.get("accreditation", "")).strip():
            problems.append("The study's laboratory 'accredited' is true: 'accreditation' must "
                            "name the accreditation body and number (ILAC-P8).")
    for key in ("signatory", "signatory_function"):
        if key in lab and not (isinstance(lab[key], str) and lab[key].strip()):
            problems.append(f"The study's laboratory {key!r} must be text. Got {lab[key]!r} "
                            "instead.")
        elif key in lab:
            out[key] = lab[key].strip()
    procedures = lab.get("procedures", {})
    if not isinstance(procedures, dict):
        problems.append("The study's laboratory 'procedures' must be a table of {id, "
                        f"validation}} tables per procedure. Got {procedures!r} instead.")
        procedures = {}
    out["procedures"] = {}
    for name, entry in procedures.items():
        where = f"The study's laboratory procedures {name!r}"
        if not isinstance(entry, dict):
            problems.append(f"{where} must be a table {{ id = \"...\", validation = \"...\" }}. "
                            f"Got {entry!r} instead.")
            continue
        _unknown(problems, where, entry, _LAB_PROCEDURE_KEYS)
        bad = [k for k in _LAB_PROCEDURE_KEYS if k in entry
               and not (isinstance(entry[k], str) and entry[k].strip())]
        for k in bad:
            problems.append(f"{where} {k!r} must be text. Got {entry[k]!r} instead.")
        out["procedures"][str(name)] = {k: entry[k].strip() for k in _LAB_PROCEDURE_KEYS
                                        if k in entry and k not in bad}
    return out
# --- end of the accreditation keys --------------------------------------------------------
#: the clause for an achieved U more than 10 % above the agreed one: the guard band widened
#: in proportion (w times U achieved / U agreed), or no decision on that measurand
LARGER_U = ("widen", "no decision")
#: what the plan requires and agrees before the test (the contract's clauses): key ->
#: (label, kind); kinds: band [low, high] in degC, number, bool, int, text
REQUIREMENT_KEYS = {
    "temperature_c": ("ambient temperature during the test [°C]", "band"),
    "gradient_c_per_h": ("largest temperature change [°C/h]", "number"),
    "warm_up": ("warm-up before the test", "text"),
    "warm_up_min": ("shortest warm-up [min]", "minutes"),
    "compensation": ("machine's error compensation", "per_machine_bool"),
    "controller": ("controller and its compensation tables' version", "per_machine_text"),
    "outside": ("outside a required condition", "text"),
    "outside_effect": ("effect of a condition outside the agreement, or not recorded, on "
                       "the statements of conformity", "effect"),
    "adjustment": ("on a fail or a conditional result: adjustment", "text"),
    "retests": ("re-tests allowed after an adjustment", "int"),
    "as_left": ("results after an adjustment", "text"),
    "larger_u": ("achieved U more than 10 % above the agreed U", "choice"),
    "schedule": ("schedule", "text"),
}
#: the test conditions (ISO 230-1 6, ISO 230-2 5.1): key -> (label, kind)
#: a measured temperature that a procedure's set-up field declares as its ``condition``
#: corrects that procedure's readings (models.protocol.with_conditions)
CONDITION_KEYS = {"ambient_temperature_c": ("ambient temperature", "temperature"),
                  "machine_temperature_c": ("machine temperature", "temperature"),
                  "part_temperature_c": ("part (artefact) temperature", "temperature"),
                  "air_gradient_k_per_m": ("vertical gradient of the air's temperature "
                                           "(K/m, warm air above positive)", "gradient"),
                  "air_gradient_x_k_per_m": ("horizontal gradient of the air's temperature "
                                             "along the tracker's x axis (K/m, towards warm "
                                             "air positive)", "gradient"),
                  "air_gradient_y_k_per_m": ("horizontal gradient of the air's temperature "
                                             "along the tracker's y axis (K/m, towards warm "
                                             "air positive)", "gradient"),
                  "temperature_min_c": ("lowest ambient temperature during the test",
                                        "temperature"),
                  "temperature_max_c": ("highest ambient temperature during the test",
                                        "temperature"),
                  "temperature_change_c_per_h": ("largest ambient temperature change [°C/h]",
                                                 "rate"),
                  "temperature_log": ("log of the ambient temperature", "text"),
                  "warm_up": ("warm-up before the test", "text"),
                  "warm_up_min": ("warm-up [min]", "minutes"),
                  "compensation": ("machine's error compensation", "per_machine_bool"),
                  "controller": ("controller and its compensation tables' version",
                                 "per_machine_text"),
                  "how": ("how each condition was measured", "how"),
                  "notes": ("other conditions", "text")}
#: the recorded conditions compared with the plan's (mtplan.plans.conditions), each named in
#: [conditions] how = {...} with how it was measured, and in [requirements] outside_effect
CONDITION_CHECKS = ("temperature", "temperature_change", "warm_up", "compensation",
                    "controller")
#: what a condition outside the agreement, or not recorded, does to the statements of
#: conformity of the tests run under it ([requirements] outside_effect): none is made (the
#: default), or the verdicts stand
CONDITION_EFFECTS = ("no statement", "verdicts stand")
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
              "notes", "standards", "machine", "time"}
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
_READ_KEYS = {"file", "uncertainty", "estimator", "trials", "options", "allow_unconverged",
              "along"}
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
    time: str = ""                     # time of the test on the test date ("08:30-09:40")

    @property
    def procedure(self):
        """The registered procedure this test runs (:func:`mtplan.models.get` of its name)."""
        from mtplan.models import get

        return get(self.name)


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
    laboratory: dict = field(default_factory=dict)    # name, address, ACCREDITATION_KEYS
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
    problems += [f"The study's laboratory procedures names {name!r}, which is no procedure of "
                 f"the study ({', '.join(sorted(names))})."
                 for name in certificate["laboratory"]["procedures"] if name not in names]
    _temperature_log(certificate["conditions"], path, problems)
    problems += _machine_problems(header, certificate, out)
    for i, ps in enumerate(out):  # the readings are evaluated at the recorded conditions
        if ps is not None and ps.setup is not None and ps.readings is not None:
            try:
                with_conditions(ps.setup, certificate["conditions"])
            except InvalidInput as exc:
                problems += [f"procedure #{i + 1} ({ps.name}) at the study's conditions: {p}"
                             for p in exc.problems]
    if problems:
        raise InvalidInput(problems)
    meta = {k: str(data[k]) for k in ("subtitle", "customer", "machine", "author") if k in data}
    return Study(title=str(data.get("title", "mtplan study")), path=path,
                 digest=hashlib.sha256(raw).hexdigest(), meta=meta, procedures=out,
                 header=header, **certificate, **top)


def machine_serials(header, procedures) -> list[str]:
    """The serial numbers of the machines a study tests: the header's ``machine_serial``
    (several separated by commas or semicolons) and each test's ``machine``, in order."""
    import re

    out = [s.strip() for s in re.split(r"[,;]", header.get("machine_serial", "")) if s.strip()]
    out += [ps.machine for ps in procedures if ps is not None and ps.machine]
    return list(dict.fromkeys(out))


def _machine_problems(header, certificate, procedures) -> list[str]:
    """A test's machine that the cover does not name, conditions or requirements stated per
    machine for a serial no test is run on, and a lowest temperature above the highest."""
    problems = []
    named = machine_serials(header, [])
    for i, ps in enumerate(procedures):
        if ps is not None and named and ps.machine and ps.machine not in named:
            problems.append(f"procedure #{i + 1} ({ps.name}) 'machine' {ps.machine!r} is not "
                            f"among the header's 'machine_serial' ({', '.join(named)}): the "
                            "cover names the items tested.")
        elif ps is not None and len(named) > 1 and not ps.machine:
            problems.append(f"procedure #{i + 1} ({ps.name}) needs 'machine': the header names "
                            f"several machines ({', '.join(named)}).")
    serials = machine_serials(header, procedures)
    for table in ("conditions", "requirements"):
        for key in ("compensation", "controller"):
            value = certificate[table].get(key)
            if isinstance(value, dict):
                for serial in sorted(set(value) - set(serials)):
                    problems.append(f"The study's {table} {key!r} names machine {serial!r}, "
                                    f"which no test is run on ({', '.join(serials) or 'none'}).")
    low = certificate["conditions"].get("temperature_min_c")
    high = certificate["conditions"].get("temperature_max_c")
    if low is not None and high is not None and low > high:
        problems.append(f"The study's conditions 'temperature_min_c' ({low:g}) must not exceed "
                        f"'temperature_max_c' ({high:g}).")
    return problems


def _temperature_log(conditions, path, problems) -> None:
    """``[conditions] temperature_log``: a CSV log of the ambient temperature (relative to
    the study file) read into the lowest and highest temperature and the largest change
    per hour (:func:`~mtplan.plans.study.temperature_log.read_temperature_log`), which the
    study then may not state as well."""
    from mtplan.plans.study.temperature_log import read_temperature_log

    name = conditions.get("temperature_log")
    if name is None:
        return
    stated = [k for k in ("temperature_min_c", "temperature_max_c",
                          "temperature_change_c_per_h") if k in conditions]
    if stated:
        problems.append(f"The study's conditions state {', '.join(stated)} and a "
                        "'temperature_log': give one or the other.")
        return
    log = Path(name)
    if not log.is_absolute() and path is not None:
        log = path.parent / log
    try:
        conditions.update(read_temperature_log(log))
    except InvalidInput as exc:
        problems += exc.problems


def _time(problems, where, value) -> str:
    """A test's time on the test date: a TOML time (08:30:00) or text "08:30" or
    "08:30-09:40"; "" when not given."""
    import re

    if value is None:
        return ""
    if isinstance(value, datetime.time):
        return value.strftime("%H:%M")
    clock = r"([01]\d|2[0-3]):[0-5]\d"
    if isinstance(value, str) and re.fullmatch(rf"{clock}(-{clock})?", value.strip()):
        return value.strip()
    problems.append(f"{where} 'time' must be the time of the test on the test date, "
                    f"\"08:30\" or \"08:30-09:40\" (24 h). Got {value!r} instead.")
    return ""


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
    _unknown(problems, "The study's laboratory", lab, _LAB_KEYS | ACCREDITATION_KEYS)
    conditions = {}
    if "ambient_temperature_c" in header:
        conditions["ambient_temperature_c"] = header["ambient_temperature_c"]
    conditions.update(_typed_table(data, "conditions", CONDITION_KEYS, problems))
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
    requirements = _typed_table(data, "requirements", REQUIREMENT_KEYS, problems)
    simulated = data.get("simulated", False)
    if not isinstance(simulated, bool):
        problems.append(f"The study's 'simulated' must be true or false. Got {simulated!r} "
                        "instead.")
        simulated = False
    return {"laboratory": _accreditation(lab, problems), "conditions": conditions,
            "instruments": shown, "simulated": simulated, "requirements": requirements}


def _is_number(value) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


#: the kinds of a study's typed tables ([conditions], [requirements]): kind -> (test, what is
#: allowed, the value kept)
_KINDS = {
    "temperature": (lambda v: _is_number(v) and -30 <= v <= 60, "a number from -30 to 60 [degC]",
                    float),
    "gradient": (lambda v: _is_number(v) and -10 <= v <= 10, "a number from -10 to 10 [K/m]",
                 float),
    "band": (lambda v: isinstance(v, list) and len(v) == 2 and all(map(_is_number, v))
             and v[0] < v[1], "a band [low, high] of two numbers, low < high",
             lambda v: [float(x) for x in v]),
    "number": (lambda v: _is_number(v) and v > 0, "a number > 0", float),
    "int": (lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 0,
            "an integer >= 0", int),
    "bool": (lambda v: isinstance(v, bool), "true or false", bool),
    "text": (lambda v: isinstance(v, str), "text", str),
    "choice": (lambda v: v in LARGER_U, f"one of {', '.join(map(repr, LARGER_U))}", str),
    "rate": (lambda v: _is_number(v) and 0 <= v <= 100, "a number from 0 to 100 [°C/h]",
             float),
    "minutes": (lambda v: _is_number(v) and 0 <= v <= 10_000, "a number of minutes from 0 "
                "to 10000", float),
    "per_machine_bool": (lambda v: isinstance(v, bool) or _per_machine(v, bool),
                         "true or false, or a table of them by machine serial number",
                         lambda v: v if isinstance(v, bool) else dict(v)),
    "per_machine_text": (lambda v: _text(v) or _per_machine(v, str),
                         "text, or a table of texts by machine serial number",
                         lambda v: v.strip() if isinstance(v, str) else
                         {k: x.strip() for k, x in v.items()}),
    "how": (lambda v: isinstance(v, dict) and set(v) <= set(CONDITION_CHECKS)
            and all(map(_text, v.values())),
            f"a table of texts naming some of {', '.join(CONDITION_CHECKS)}", dict),
    "effect": (lambda v: isinstance(v, dict) and set(v) <= set(CONDITION_CHECKS)
               and all(x in CONDITION_EFFECTS for x in v.values()),
               f"a table naming some of {', '.join(CONDITION_CHECKS)}, each one of "
               f"{', '.join(map(repr, CONDITION_EFFECTS))}", dict),
}


def _text(value) -> bool:
    return isinstance(value, str) and bool(value.strip())


def _per_machine(value, kind) -> bool:
    """A table of values of ``kind`` by machine serial number."""
    return (isinstance(value, dict) and bool(value)
            and all(isinstance(x, kind) and (kind is not str or x.strip())
                    for x in value.values()))


def _typed_table(data, name: str, keys: dict, problems) -> dict:
    """The study's table `name`, each key of `keys` (key -> (label, kind)) checked against
    its kind (:data:`_KINDS`); every problem at once, unknown keys included."""
    table = data.get(name, {})
    if not isinstance(table, dict):
        problems.append(f"The study's {name!r} must be a table.")
        return {}
    _unknown(problems, f"The study's {name}", table, set(keys))
    out = {}
    for key, value in table.items():
        if key not in keys:
            continue
        test, allowed, keep = _KINDS[keys[key][1]]
        if test(value):
            out[key] = keep(value)
        else:
            problems.append(f"The study's {name} {key!r} must be {allowed}. Got {value!r} "
                            "instead.")
    return out


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
    fields = {f.name for f in fields_info(proc.Setup)}
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
                          machine=machine.strip(),
                          time=_time(problems, where, entry.get("time")))


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
    from mtplan.plans.planner import target_measurand

    if _subtable(problems, where, "plan", plan, _PLAN_KEYS) is None:
        return None
    for f in plan.get("vary", {}):
        if f not in fields:
            problems.append(f"{where} plan varies {f!r}, which is no set-up field.")
    for m in plan.get("targets", {}):
        if target_measurand(m) not in measurands:  # residual:, reliability: of one
            problems.append(f"{where} plan targets {m!r}, which is no measurand "
                            f"({', '.join(sorted(measurands))}), nor a residual: or "
                            "reliability: one.")
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
    if "along" in readings:
        readings = {**readings, "along": _along(proc, readings["along"], where, problems)}
    return readings


def _along(proc, table, where, problems) -> dict:
    """``along = { X = "-50:50:5" }``: the positions at which the readings' evaluation states
    the errors along each axis's travel (``{}``: none; left out: the procedure's default,
    the correction model's ``grid``), as {set-up field: positions}."""
    from mtplan.evaluation.along import parse_grid
    from mtplan.models.protocol import fields_info

    fields = {f.name: f for f in fields_info(proc.Setup)}
    if not isinstance(table, dict):
        problems.append(f"{where} readings 'along' must be a table of AXIS = "
                        f"\"START:STOP:STEP\" [mm]. Got {table!r} instead.")
        return {}
    out = {}
    for axis, text in table.items():
        field = f"along_{str(axis).lower()}_mm"
        if field not in fields:
            problems.append(f"{where} readings along {axis!r}: {proc.name} states no errors "
                            f"along {axis!r} (its set-up has no field {field}).")
            continue
        try:
            out[field] = parse_grid(text, fields[field].max_len)
        except ValueError as exc:
            problems.append(f"{where} readings along {axis!r}: {exc}.")
    return out


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
