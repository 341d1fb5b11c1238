"""The designer's state: a design, its set-up and the fields that size its sources.

A *design* is a plain JSON-ready dict, the whole state of one browser tab (it travels in
the tab's URL, so two tabs never share it and a link reopens it)::

    {"procedure": "rotary_axis",
     "setup": {"positions": "8", "incline_deg": "25"},     # fields as typed (strings)
     "off": ["flatness"],                                  # error sources switched off
     "estimator": "patent",
     "tolerances": {"EX0C": {"lower": -10, "upper": 10, "prior": "normal:0,4",
                             "rule": "iso14253"}},
     "targets": {"EX0C": 2.0},                             # U (k = 2) targets
     "vary": {"positions": "4,6,8,12"},                    # ranges for the planner
     "lever": "incline_deg",                               # the field last moved
     "seed": 0, "trials": 10000}

An error source is sized by its set-up field (``probe_noise`` by ``probe_noise_um``); a
source switched off is that field at 0, so the exported study states it the same way.
:func:`normalise` fills a design's defaults, :func:`setup_of` makes its set-up and
:func:`field_problems` gives the procedure's message for each field it refuses.
"""

from __future__ import annotations

import functools
import json
import math

from mtplan._validate import InvalidInput
from mtplan.models import get
from mtplan.models.protocol import fields_info, file_fields, make, parse_fields

__all__ = ["K", "source_fields", "json_value", "setup_key", "json_setup", "whole", "normalise",
           "refuse_files", "field_problems", "setup_of", "design_problems"]


#: coverage factor of the U the designer shows and its targets are stated in
K = 2.0


def source_fields(proc) -> dict:
    """Error source name -> the set-up field that sizes it (``probe_noise`` ->
    ``probe_noise_um``), as each source declares it (``Source(field=...)``)."""
    return dict(_source_fields(proc.name))


@functools.lru_cache(maxsize=64)
def _source_fields(name: str) -> tuple:  # asked several times a change: once per procedure
    proc = get(name)
    return tuple((s, src.field) for s, src in proc.sources(proc.Setup()).items())


def json_value(v):
    if isinstance(v, tuple):
        return list(v)
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def setup_key(setup) -> str:
    return json.dumps(setup.as_dict(), sort_keys=True)


def json_setup(setup) -> dict:
    return {k: json_value(v) for k, v in setup.as_dict().items()}


def whole(value, name: str, *, low: int = 0, high: int | None = None) -> int:
    """An integer from a number or its text, scientific notation included ('1e6'), in
    [low, high]; InvalidInput naming `name` otherwise."""
    allowed = f"a whole number >= {low}" + (f" and <= {high}" if high is not None else "")
    try:
        x = float(str(value).strip()) if not isinstance(value, bool) else math.nan
    except ValueError:
        x = math.nan
    if not math.isfinite(x) or x != int(x) or x < low or (high is not None and x > high):
        raise InvalidInput([f"The '{name}' must be {allowed}. Got {str(value)[:40]!r} instead."])
    return int(x)


#: what each key of a design may hold, by JSON type: a refusal names the key and this
_KEY_KINDS = {
    "procedure": ((str,), "a procedure's name (text)"),
    "setup": ((dict,), "an object of set-up field: value"),
    "off": ((list,), "a list of error source names"),
    "estimator": ((str,), "an estimator's name (text)"),
    "tolerances": ((dict,), "an object of measurand: {lower, upper, prior, rule}"),
    "targets": ((dict,), "an object of measurand: target U (a number)"),
    "vary": ((dict,), "an object of set-up field: values to try (text such as '4,6,8')"),
    "lever": ((str,), "a set-up field's name (text)"),
    "seed": ((int, float, str), "a whole number"),
    "trials": ((int, float, str), "a whole number"),
}
_SCALAR = (str, int, float)
_TOLERANCE_KEYS = ("lower", "upper", "measured", "prior", "rule", "prior_csv", "prior_name")


def _kind(v) -> str:
    return {dict: "an object", list: "a list", str: "text", bool: "true/false"}.get(
        type(v), "a number" if isinstance(v, int | float) else type(v).__name__)


def _shown(v) -> str:
    return json.dumps(v)[:40] if isinstance(v, dict | list | str | int | float) else repr(v)


def design_problems(d) -> list:
    """What is malformed in a design as sent, each naming its key ('setup', 'tolerances
    EX0C rule'), all at once: a type that no value of that key has."""
    if not isinstance(d, dict):
        return [f"The design must be a JSON object. Got {_kind(d)} ({_shown(d)}) instead."]
    out = []

    def bad(key, v, allowed):
        out.append(f"The design's {key!r} must be {allowed}. Got {_kind(v)} ({_shown(v)}) "
                   "instead.")

    for key, (kinds, allowed) in _KEY_KINDS.items():
        v = d.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, kinds)):
            bad(key, v, allowed)
    if isinstance(d.get("setup"), dict):
        for k, v in d["setup"].items():
            if v is not None and not isinstance(v, _SCALAR):
                bad(f"setup {k}", v, "a value as typed (text, a number or true/false)")
    if isinstance(d.get("off"), list):
        for v in d["off"]:
            if not isinstance(v, str):
                bad("off", v, "a list of error source names (text)")
    for key in ("targets", "vary"):
        for k, v in (d.get(key) if isinstance(d.get(key), dict) else {}).items():
            if v is not None and (isinstance(v, bool) or not isinstance(v, _SCALAR)):
                bad(f"{key} {k}", v, "a number or its text")
    for name, row in (d.get("tolerances") if isinstance(d.get("tolerances"), dict)
                      else {}).items():
        if not isinstance(row, dict):
            bad(f"tolerances {name}", row, "an object of lower, upper, prior and rule")
            continue
        for k in _TOLERANCE_KEYS:
            v = row.get(k)
            text_only = k not in ("lower", "upper", "measured")
            if v is not None and (isinstance(v, bool) or not isinstance(
                    v, str if text_only else _SCALAR)):
                bad(f"tolerances {name} {k}", v, "text" if text_only else "a number or its text")
    return out


def normalise(design: dict | None) -> dict:
    """A design with every key present (defaults filled), unknown keys dropped;
    InvalidInput naming each key whose value has a type no design has
    (:func:`design_problems`)."""
    problems = design_problems(design if design is not None else {})
    if problems:
        raise InvalidInput(problems)
    d = dict(design or {})
    name = d.get("procedure") or "rotary_axis"
    proc = get(name)
    seed = d.get("seed", 0)
    trials = d.get("trials", 10_000)
    return {
        "procedure": proc.name,
        "setup": {str(k): ("" if v is None else str(v)) for k, v in (d.get("setup") or {}).items()},
        "off": [str(s) for s in d.get("off") or []],
        "estimator": d.get("estimator") or proc.estimator(None)[0],  # the command line's
        "tolerances": {str(k): dict(v) for k, v in (d.get("tolerances") or {}).items()
                       if isinstance(v, dict)},
        "targets": {str(k): v for k, v in (d.get("targets") or {}).items()
                    if v not in (None, "")},
        "vary": {str(k): str(v) for k, v in (d.get("vary") or {}).items() if str(v).strip()},
        "lever": d.get("lever") or default_lever(proc),
        "seed": seed,
        "trials": trials,
    }


def default_lever(proc) -> str | None:
    """The lever the page draws first: the first of the procedure's levers whose default is
    a number (an empty default, resolved by the set-up, has no range to draw a curve over
    until the user gives it a value); None where none is."""
    numeric = {f.name for f in fields_info(proc.Setup)
               if f.kind in (int, float) and isinstance(f.default, int | float)
               and not isinstance(f.default, bool)}
    return next((f for f in proc.levers if f in numeric), None)


def refuse_files(proc, setup: dict) -> None:
    """Refuse a design that states a file field: the page never names a path on this
    machine (such a field is set in a set-up file, for the command line)."""
    named = [f for f in file_fields(proc.Setup) if str(setup.get(f) or "").strip()]
    if named:
        raise InvalidInput([f"The designer does not read files: {', '.join(named)} of "
                            f"{proc.name} names one; set it in the set-up file (mtplan simulate "
                            "--config FILE.toml) and leave it out here."])


def _values(proc, design) -> dict:
    """The set-up values the design states, with switched-off sources at 0."""
    refuse_files(proc, design["setup"])
    values = {k: v for k, v in design["setup"].items() if str(v).strip() != ""}
    fields = source_fields(proc)
    for s in design["off"]:
        if s in fields:
            values[fields[s]] = "0"
    return values


def field_problems(proc, design) -> dict:
    """Field name -> the procedure's own message for each value it refuses alone."""
    infos = {f.name for f in fields_info(proc.Setup)}
    try:
        values = _values(proc, design)
    except InvalidInput as exc:  # a file field: named beside itself
        return {f: " ".join(exc.problems) for f in file_fields(proc.Setup)
                if str(design["setup"].get(f) or "").strip()}
    out = {}
    for key, value in values.items():
        if key not in infos:
            out[key] = f"{proc.name} has no field {key!r}"
            continue
        try:
            parse_fields(proc.Setup, {key: value}, owner=proc.name)
        except InvalidInput as exc:
            out[key] = " ".join(exc.problems)
    return out


def setup_of(design):
    """(procedure, Setup) of a design; InvalidInput with the procedure's messages."""
    proc = get(design["procedure"])
    setup = make(proc.Setup, _values(proc, design), owner=proc.name)
    proc.check_setup(setup)  # what the procedure checks of a set-up beyond its fields
    return proc, setup
