"""What the page draws for a procedure and the help it gives: the controls of every set-up
field, the measurands, and the glossary's words for every code and term shown."""

from __future__ import annotations

import functools
import math
import re
from pathlib import Path

from mtplan.explore.state import json_value, source_fields
from mtplan.models import get, registry
from mtplan.models.protocol import fields_info

__all__ = ["procedures_info", "procedure_info", "sliders", "GLOSSARY", "glossary", "explain",
           "help_text", "anchor", "measurand_rows"]


def procedure_info(name: str) -> dict:
    """Everything the page needs to draw one procedure's controls."""
    proc = get(name)
    setup = proc.Setup()
    by_field = {v: k for k, v in source_fields(proc).items()}
    sources = proc.sources(setup)
    fields = []
    for f in fields_info(proc.Setup):
        if f.file:  # a path on this machine: never a browser's (refuse_files)
            continue
        kind = f.kind
        kind = {float: "float", int: "int", bool: "bool", str: "str"}.get(kind, "tuple")
        fields.append({
            "name": f.name, "kind": kind, "unit": f.unit, "doc": f.doc or "",
            "default": json_value(f.default), "low": f.low, "high": f.high,
            "low_open": f.low_open, "high_open": f.high_open,
            "choices": list(f.choices) if f.choices else None,
            "optional": f.optional, "min_len": f.min_len, "max_len": f.max_len,
            "source": by_field.get(f.name),
            "source_doc": sources[by_field[f.name]].description if f.name in by_field
            else "",
            "lever": f.name in proc.levers,
        })
        fields[-1]["slider"] = _slider(fields[-1])
    return {
        "name": proc.name, "title": proc.title, "description": proc.description,
        "estimators": list(proc.estimators), "default_estimator": proc.default_estimator,
        "estimator_help": {k: e.description for k, e in proc.estimators.items()},
        "measurands": measurand_rows(proc, setup),
        "fields": fields,
    }


def _slider(f: dict) -> bool:
    """Whether the page draws a field as a slider: a bounded number whose range is of the
    order of its default (not 0 .. 100000 for a 1 um noise)."""
    if f["kind"] not in ("int", "float") or f["default"] is None:
        return False
    lo, hi = f["low"], f["high"]
    return lo is not None and hi is not None and math.isfinite(lo) and math.isfinite(hi) \
        and hi - lo <= 50 * max(abs(f["default"]), 1)


def sliders(name: str) -> list:
    """The fields of a procedure that the page draws as sliders."""
    return [f for f in procedure_info(name)["fields"] if f["slider"]]


#: the documentation's glossary (docs/glossary.md), packaged beside this module so that an
#: installed mtplan explains its codes as a checkout does
GLOSSARY = Path(__file__).with_name("glossary.md")


@functools.lru_cache(maxsize=1)
def glossary() -> list:
    """The rows of the documentation's glossary (``docs/glossary.md``, packaged with the
    designer): ``{"names": [...], "meaning": text, "section": heading}``. The page explains
    its codes and terms (EX0C, O1, TUR, PFR) with them."""
    text = GLOSSARY.read_text(encoding="utf-8")
    out, section = [], ""
    for line in text.splitlines():
        if line.startswith("## "):
            section = line[3:].strip()
        cells = [c.strip() for c in line.strip().strip("|").split("|")] if \
            line.startswith("|") else []
        if len(cells) != 2 or set(cells[0]) <= set("-") or cells[1] == "meaning":
            continue
        names = [n.strip(" `") for n in re.split(r",|\.\.\.|=", cells[0]) if n.strip(" `")]
        names += [n.split(": ", 1)[1] for n in names if ": " in n]  # "decision rule: simple"
        label = cells[0].replace("`", "")
        out.append({"names": names, "label": label, "meaning": cells[1].replace("`", ""),
                    "section": section, "anchor": "help-" + re.sub(r"[^A-Za-z0-9]+", "-",
                                                                   label).strip("-")})
    return out


@functools.lru_cache(maxsize=2048)
def explain(code: str) -> dict | None:
    """The glossary's row for a code or term shown on the page, or None.

    A row's name matches itself and its placeholders: ``_k`` any number (``origin_x_k``
    is ``origin_x_2``), and ``:R`` or ``:P`` after a colon any value (``guard:R`` is
    ``guard:1``).
    """
    rows, pattern = _patterns()
    found = pattern.fullmatch(code)
    return rows[found.lastindex - 1] if found else None


@functools.lru_cache(maxsize=1)
def _patterns() -> tuple:
    """(rows, one pattern): every glossary name's pattern as a group of one alternation,
    in the glossary's order, and the row of each group; compiled once (a page of thousands
    of measurands asks for each one's row)."""
    rows, parts = [], []
    for row in glossary():
        for name in row["names"]:
            pattern = re.escape(name)
            pattern = re.sub(r"_k$", r"_\\d+", pattern)
            pattern = re.sub(r":[A-Z]$", r":.+", pattern)
            rows.append(row)
            parts.append(f"({pattern})")
    return rows, re.compile("|".join(parts))


def help_text(code: str, description: str = "") -> str:
    """The page's help for a code: the glossary's words, then the procedure's own."""
    row = explain(code)
    words = f"{row['label']}: {row['meaning']}" if row else ""
    return ". ".join(t for t in (words, description) if t)


def procedures_info() -> list:
    """Name and title of every registered procedure."""
    return [{"name": p.name, "title": p.title} for p in registry().values()]


def measurand_rows(proc, setup) -> list:
    return [{"name": m.name, "unit": m.unit, "description": m.description,
             "help": help_text(m.name, m.description), "anchor": anchor(m.name)}
            for m in proc.measurands(setup)]


def anchor(code: str) -> str | None:
    row = explain(code)
    return row["anchor"] if row else None
