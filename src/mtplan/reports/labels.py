"""Plain words for the document: units as printed (µm, µrad), set-up fields as labels
(``incline_deg`` -> "incline of the artifact plane [deg]") and
numbers formatted to their uncertainty. Formatting only: nothing here computes a result.
"""

from __future__ import annotations

import math
import re

from mtplan._numbers import fmt, fmt_u, unit
from mtplan.models.protocol import split_unit

__all__ = ["unit", "split_field", "field_label", "field_value", "plain_fields", "value_text", "fmt",
           "fmt_u", "tolerance_text", "duration_text", "percent", "prior_text"]

def split_field(name: str) -> tuple[str, str]:
    """(base, unit suffix) of a set-up field name; the suffix is "" when it has none."""
    return split_unit(name)


def field_label(name: str, doc: str = "") -> str:
    """An axis or table label for a set-up field: the first clause of its documentation
    when short, else its name in words, with the unit in brackets."""
    base, suffix = split_field(name)
    words = base.replace("_", " ")
    first = re.split(r";|, | \(| \[|: ", doc.strip(), maxsplit=1)[0].strip().rstrip(".")
    if first and len(first) <= 48:
        words = first[0].lower() + first[1:] if first[1:2].islower() else first
    return f"{words} [{unit(suffix)}]" if suffix else words


def plain_fields(text: str, setup_cls) -> str:
    """``text`` with every set-up field name of ``setup_cls`` (``air_gradient_k_per_m``)
    and every error source named after one (``start_scatter``) in plain words, by the
    field's declared label (:func:`field_label`, without its unit): a document never
    prints an identifier."""
    from mtplan.models.protocol import fields_info

    names = {}
    for f in fields_info(setup_cls):
        label = field_label(f.name, f.doc or "").split(" [")[0]
        names[f.name] = label
        names.setdefault(split_field(f.name)[0], label)
    for name in sorted(names, key=len, reverse=True):
        if "_" in name:
            text = re.sub(rf"(?<![A-Za-z0-9_]){re.escape(name)}(?![A-Za-z0-9_])",
                          names[name], text)
    return text


def value_text(value) -> str:
    """A set-up value as a document prints it: yes/no for a switch, 20 for 20.0, lists
    joined by commas."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, list | tuple):
        return ", ".join(value_text(x) for x in value)
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def field_value(name: str, value) -> str:
    """``incline_deg = 20`` -> "incline 20 deg"; lists joined by commas."""
    base, suffix = split_field(name)
    shown = value_text(value)
    return f"{base.replace('_', ' ')} {shown}" + (f" {unit(suffix)}" if suffix else "")


def tolerance_text(lower, upper, unit_name: str = "", zone=None) -> str:
    """±10 µm, [-5, 10] µm, <= 10 µm or >= -5 µm; a position zone (``zone``: its
    ``diameter`` and ``nominal``) as "Ø 800 µm at (0, 0)"."""
    u = f" {unit(unit_name)}" if unit_name else ""
    if zone is not None:
        x, y = zone["nominal"]
        return f"Ø {zone['diameter']:g}{u} at ({x:g}, {y:g})"
    if lower is None and upper is None:
        return "-"
    if lower is None:
        return f"≤ {upper:g}{u}"
    if upper is None:
        return f"≥ {lower:g}{u}"
    if math.isclose(-lower, upper):
        return f"±{upper:g}{u}"
    return f"[{lower:g}, {upper:g}]{u}"


def duration_text(seconds: float) -> str:
    """Machine time: s below 2 min, min below 2 h, else h."""
    if seconds is None or not math.isfinite(seconds):
        return "-"
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


def percent(p) -> str:
    """A probability in per cent to two significant digits."""
    if p is None or not math.isfinite(p):
        return "-"
    x = 100 * float(p)
    if x == 0:
        return "0 %"
    if x >= 10:
        return f"{x:.0f} %"
    return f"{x:.2g} %"


def prior_text(prior, unit_name: str) -> str:
    """The population of items (the prior) in words: N(0, 4 µm), gamma(k, θ), the n values
    of a file."""
    if prior is None:
        return ""
    u = unit(unit_name)
    name = type(prior).__name__
    if name == "NormalPrior":
        return f"N({prior.mean:g}, {prior.sd:g} {u})"
    if name == "GammaPrior":
        return f"gamma(shape {prior.shape:g}, scale {prior.scale:g} {u})"
    if name == "EmpiricalPrior":
        return f"the {len(prior.values)} measured values given"
    return str(prior)
