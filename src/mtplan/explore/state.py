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
           "refuse_files", "field_problems", "setup_of"]


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


def normalise(design: dict | None) -> dict:
    """A design with every key present (defaults filled), unknown keys dropped."""
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
        "lever": d.get("lever") or (proc.levers[0] if proc.levers else None),
        "seed": seed,
        "trials": trials,
    }


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
    return proc, make(proc.Setup, _values(proc, design), owner=proc.name)
