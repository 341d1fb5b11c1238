"""The formats ``mtplan compensate`` can write: the built-in ones and those of installed
packages (entry point group ``mtplan.compensation_formats``, each a
:class:`~mtplan.compensation.formats.CompensationFormat`)."""

from __future__ import annotations

from importlib.metadata import entry_points

from mtplan._validate import InvalidInput
from mtplan.compensation import fanuc, isg, neutral, siemens
from mtplan.compensation.formats import CompensationFormat

__all__ = ["ENTRY_POINT_GROUP", "available_formats", "get_format"]

ENTRY_POINT_GROUP = "mtplan.compensation_formats"


def _built_in() -> dict:
    return {f.name: f for f in (neutral.FORMAT, isg.FORMAT, fanuc.FORMAT, siemens.FORMAT)}


def available_formats() -> dict:
    """Every format by name: the built-in ones, then those of installed packages
    (entry point group ``mtplan.compensation_formats``)."""
    out = _built_in()
    for point in entry_points(group=ENTRY_POINT_GROUP):
        if point.name in out:
            continue
        fmt = point.load()
        if not isinstance(fmt, CompensationFormat):
            raise InvalidInput([f"entry point {point.name!r} of {ENTRY_POINT_GROUP} is not a "
                                "CompensationFormat"])
        out[point.name] = fmt
    return out


def get_format(name: str) -> CompensationFormat:
    formats = available_formats()
    if name not in formats:
        raise InvalidInput([f"unknown format {name!r}: one of {', '.join(formats)}"])
    return formats[name]
