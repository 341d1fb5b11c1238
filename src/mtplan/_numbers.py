"""Numbers and units as the documents and the command line print them: a value rounded to
its uncertainty, an uncertainty to two significant digits, ``um`` as µm. Shared by every
layer that phrases a number for a reader (the plan's deviations as well as the reports)."""

from __future__ import annotations

import math

__all__ = ["unit", "fmt", "fmt_u"]

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
