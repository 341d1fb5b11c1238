"""The ISG kernel's volumetric compensation parameter file (ISG_CSV), as Beckhoff's TwinCAT 3
CNC (TF5280) and other ISG-based controls read it.

Layout, from the ISG kernel documentation of the volumetric compensation ("ISG CSV format",
"List of parameters supported", "Units of measure", "Interpolation mode"): a header line
naming the columns (an argument, then parameters), records below it, fields separated by
white space, row comments after ``//``, and ``#`` for a file break after which a new header
and its records follow. Position (location) errors are named after ISO 230-7 without the
leading E (``X0C`` for EX0C, ``C0Y`` for the squareness EC0Y) and are constant: one record.
Component errors keep their ISO 230-1 names (EXX, EYX, ...) as functions of their axis's
position. Values in mm and rad; arguments in mm. Between records the kernel interpolates
linearly (interpolation mode GRID, its default).
"""

from __future__ import annotations

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.compensation.formats import CompensationFormat, FormatOption

__all__ = ["FORMAT", "isg_name"]

#: the ISG kernel's position errors: six per axis X Y Z A B C (ISO 230-7 without the E)
POSITION_ERRORS = {f"{e}0{a}" for a in "XYZABC" for e in "XYZABC"}
#: component errors of the linear axes (ISO 230-1)
COMPONENT_ERRORS = {f"E{e}{a}" for a in "XYZ" for e in "XYZABC"}


def isg_name(iso: str) -> str:
    """The ISG parameter name of an ISO 230-7 location error (``EX0C`` -> ``X0C``)."""
    return iso[1:] if iso.startswith("E") and len(iso) == 4 and iso[2] == "0" else iso


def _value_text(value: float) -> str:
    return f"{value:.10g}"


def _yes_no(text: str) -> bool:
    if text not in ("yes", "no"):
        raise ValueError(f"must be yes or no. Got {text!r} instead.")
    return text == "yes"


def _records(text: str) -> int:
    n = int(text) if text.isdigit() else 0
    if n < 1:
        raise ValueError(f"must be a whole number >= 1. Got {text!r} instead.")
    return n


def _render(correction, options) -> dict:
    problems, constants, tables = [], [], {}
    for i, (name, arg) in enumerate(zip(correction.names, correction.arguments)):
        value, _ = correction.internal(name)
        if arg:
            function = name.split("@")[0]
            if function not in COMPONENT_ERRORS:
                problems.append(f"format 'isg-csv' has no component error {function!r}")
            tables.setdefault(arg[0], {}).setdefault(float(arg[1]), {})[function] = value
        elif isg_name(name) in POSITION_ERRORS:
            constants.append((isg_name(name), value))
        else:
            problems.append(f"format 'isg-csv' has no parameter for {name!r} (its position "
                            "errors: X0X ... C0C, ISO 230-7 without the E)")
    outside = [f"{n} at {a[0]} = {a[1]:g} mm" for n, a, ex in
               zip(correction.names, correction.arguments, correction.extrapolated) if ex]
    if outside and not options["extrapolate"]:
        problems.append(f"{len(outside)} table points lie outside the measured travel (first: "
                        f"{outside[0]}): a table is written inside the travel only, unless "
                        "--option extrapolate=yes")
    records = int(bool(constants)) + sum(len(points) for points in tables.values())
    if records > options["max_records"]:
        problems.append(f"{records} records exceed the compensation list's bound "
                        f"vol_comp[i].max_records = {options['max_records']} (--option "
                        "max_records=N to match the control's configuration)")
    if problems:
        raise InvalidInput(problems)
    src = correction.source
    lines = [
        f"// mtplan correction of {correction.procedure} (estimator {src.get('estimator')}, "
        f"result {src.get('file')})",
        "// ISG_CSV volumetric compensation parameters: ISO 230 names (position errors "
        "without the E); values mm and rad, arguments mm",
        f"// sign: {correction.sign}",
        "// U (k = 2) and the predicted residual of every value: correction.csv beside this "
        "file",
    ]
    blocks = []
    if constants:
        blocks.append([" ".join(n for n, _ in constants),
                       " ".join(_value_text(v) for _, v in constants)])
    for axis in sorted(tables, key="XYZ".index):
        points = tables[axis]
        functions = [f for f in sorted(COMPONENT_ERRORS, key=_order) if
                     any(f in row for row in points.values())]
        rows = [" ".join([axis, *functions])]
        for u in sorted(points):
            rows.append(" ".join([_value_text(u)] + [_value_text(points[u].get(f, 0.0))
                                                    for f in functions]))
        blocks.append(rows)
    text = lines + [line for k, block in enumerate(blocks)
                    for line in (["#"] if k else []) + block]
    name = "volcomp_tables.csv" if tables else "volcomp_location.csv"
    return {name: "\n".join(text) + "\n"}


def _order(name: str) -> tuple:
    return "XYZ".index(name[2]), "XYZABC".index(name[1])


def _step(correction, options) -> np.ndarray:
    return np.zeros(len(correction.names))


FORMAT = CompensationFormat(
    name="isg-csv",
    title="ISG kernel / Beckhoff TF5280 volumetric compensation, ISG_CSV parameter file",
    source="ISG kernel documentation, Volumetric Compensation: 'ISG CSV format', 'List of "
           "parameters supported', 'Units of measure' (mm, rad; arguments mm), "
           "'Interpolation mode' (GRID: linear, the default), compensation list bound "
           "vol_comp[i].max_records",
    kinds=("kinematic location", "component errors"),
    render=_render,
    options=(FormatOption("extrapolate", False, "write table points outside the measured "
                          "travel too: yes or no (default no)", _yes_no),
             FormatOption("max_records", 2000, "the compensation list's vol_comp[i]."
                          "max_records (default 2000, the documentation's example)",
                          _records)),
    resolution=_step,
)
