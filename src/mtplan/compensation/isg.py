"""The ISG kernel's volumetric compensation parameter file (ISG_CSV), as Beckhoff's TwinCAT 3
CNC (TF5280) and other ISG-based controls read it.

Layout, from the ISG kernel documentation ("ISG CSV format" of the volumetric compensation):
a header line naming the columns (arguments and parameters), records below it, white space
between fields, row comments after ``//``. Location errors are named after ISO 230-7 without
the leading E (``X0C`` for EX0C) and are constant: one record. Values in mm and rad.
"""

from __future__ import annotations

from mtplan._validate import InvalidInput
from mtplan.compensation.formats import CompensationFormat

__all__ = ["FORMAT", "LOCATION_NAMES", "isg_name"]

#: the location errors the ISG parameter list names, by axis (ISO 230-7 without the E)
LOCATION_NAMES = {"C": ("X0C", "Y0C", "A0C", "B0C"), "A": ("Y0A", "Z0A", "B0A", "C0A"),
                  "B": ("X0B", "Z0B", "A0B", "C0B")}


def isg_name(iso: str) -> str:
    """The ISG parameter name of an ISO 230-7 location error (``EX0C`` -> ``X0C``)."""
    return iso[1:] if iso.startswith("E") and len(iso) == 4 and iso[2] == "0" else iso


def _value_text(value: float) -> str:
    return f"{value:.10g}"


def _render(correction, options) -> dict:
    names = [isg_name(n) for n in correction.names]
    known = {n for group in LOCATION_NAMES.values() for n in group}
    unknown = [n for n in names if n not in known]
    if unknown:
        raise InvalidInput([f"format 'isg-csv' has no parameter for {', '.join(unknown)} (its "
                            f"location errors: {', '.join(sorted(known))})"])
    values = [correction.internal(n)[0] for n in correction.names]
    src = correction.source
    lines = [
        f"// mtplan correction of {correction.procedure} (estimator {src.get('estimator')}, "
        f"result {src.get('file')})",
        "// ISG_CSV volumetric compensation parameters: location errors after ISO 230-7 "
        "without the leading E; mm and rad",
        f"// sign: {correction.sign}",
        "// U (k = 2) of each value: " + ", ".join(
            f"{isg_name(n)} {correction.internal(n)[1]:.3g}" for n in correction.names),
        " ".join(names),
        " ".join(_value_text(v) for v in values),
    ]
    return {"volcomp_location.csv": "\n".join(lines) + "\n"}


FORMAT = CompensationFormat(
    name="isg-csv",
    title="ISG kernel / Beckhoff TF5280 volumetric compensation, ISG_CSV parameter file",
    source="ISG kernel documentation, Volumetric Compensation (FCT-C26): 'ISG CSV format' and "
           "the parameter list (location errors X0C ... without the leading E, mm and rad)",
    kinds=("kinematic location",),
    render=_render,
)
