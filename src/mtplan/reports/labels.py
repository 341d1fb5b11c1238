"""Plain words for the document: units as printed (µm, µrad), set-up fields as labels
(``incline_deg`` -> "incline of the artifact plane [deg]"), estimators explained, and
numbers formatted to their uncertainty. Formatting only: nothing here computes a result.
"""

from __future__ import annotations

import math
import re

from mtplan.models.protocol import split_unit

__all__ = ["unit", "split_field", "field_label", "field_value", "estimator_text", "fmt",
           "fmt_u", "tolerance_text", "duration_text", "percent", "prior_text"]

_UNIT_TEXT = {"um": "µm", "urad": "µrad", "nm": "nm", "mm": "mm", "rad": "rad",
              "mrad": "mrad", "deg": "deg", "arcsec": "arcsec", "ppm": "ppm", "s": "s",
              "c": "°C", "1": "", "m": "m", "min": "min", "per": "/", "ms": "ms", "h": "h"}


def unit(name: str) -> str:
    """A unit as printed: ``um`` -> µm, ``um_per_m`` -> µm/m, ``mm_min`` -> mm/min."""
    if name in _UNIT_TEXT:
        return _UNIT_TEXT[name]
    if name == "per_s":
        return "1/s"
    if "_per_" in name:
        a, b = name.split("_per_", 1)
        return f"{unit(a)}/{unit(b)}"
    if name == "mm_min":
        return "mm/min"
    return name


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


def field_value(name: str, value) -> str:
    """``incline_deg = 20`` -> "incline 20 deg"; lists joined by commas."""
    base, suffix = split_field(name)
    if isinstance(value, list | tuple):
        shown = ", ".join(f"{x:g}" if isinstance(x, float) else str(x) for x in value)
    elif isinstance(value, float):
        shown = f"{value:g}"
    else:
        shown = str(value)
    return f"{base.replace('_', ' ')} {shown}" + (f" {unit(suffix)}" if suffix else "")


def estimator_text(function) -> str:
    """The first sentence of an estimator's docstring, without reST markup or units."""
    doc = (getattr(function, "__doc__", None) or "").strip().split("\n\n")[0]
    doc = " ".join(doc.split())
    doc = re.sub(r":\w+:`~?([^`]+)`", r"\1", doc).replace("``", "")
    doc = re.sub(r";?\s*(measurands\s*)?\[mm, rad\],?\s*\(n,\)\.?", ".", doc)
    return doc.rstrip(" .;") + "."


def fmt(value, u=None) -> str:
    """`value` rounded to the resolution its uncertainty `u` supports (two significant
    digits of u); four significant digits without one; "n/d" for NaN (not determined).
    The one number format of the reports and the command line."""
    if value is None:
        return "-"
    try:
        value = float(value)
    except (TypeError, ValueError):
        return str(value)
    if not math.isfinite(value):
        return "n/d" if math.isnan(value) else str(value)
    if u is None or not (math.isfinite(u) and u > 0):
        return _no_minus_zero(f"{value:.4g}")
    decimals = max(0, 1 - math.floor(math.log10(u)))
    return _no_minus_zero(f"{value:.{min(decimals, 9)}f}")


def _no_minus_zero(text: str) -> str:
    """"-0.00" -> "0.00": a value that rounds to zero has no sign."""
    return text[1:] if text.startswith("-") and not text.strip("-0.") else text


def fmt_u(u) -> str:
    """An uncertainty to two significant digits ("n/d" when not determinable)."""
    if u is None:
        return "-"
    if not math.isfinite(u):
        return "n/d"
    if u == 0:
        return "0"
    decimals = max(0, 1 - math.floor(math.log10(abs(u))))
    return f"{u:.{min(decimals, 9)}f}"


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
