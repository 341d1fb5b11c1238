"""A FANUC work-offset correction: a program that adds the measured deviation to a work
offset (``G91 G10 L2 Pn``).

``G10 L2 Pp`` sets the workpiece zero-point offset p (1-6: G54-G59); in incremental mode
(G91) the values are added to the offset's present contents, so the program corrects
whatever the offset held when the bore was measured. Values in mm at the control's input
increment (IS-B: 0.001 mm, IS-C: 0.0001 mm); the rounding is part of the predicted residual.
"""

from __future__ import annotations

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.compensation.formats import CompensationFormat, FormatOption, decimals, rounded

__all__ = ["FORMAT"]

_AXIS = {"work_offset_x": "X", "work_offset_y": "Y", "work_offset_z": "Z"}


def _whole(low: int, high: int, what: str):
    """A parser of a whole number low..high, refusing others with `what` they stand for."""
    def parse(text: str) -> int:
        n = int(text) if text.strip().lstrip("+").isdigit() else low - 1
        if not low <= n <= high:
            raise ValueError(f"must be a whole number {low} to {high} ({what}). Got {text!r} "
                             "instead.")
        return n
    return parse


def _increment(text: str) -> float:
    steps = {"0.001": 0.001, "0.0001": 0.0001}
    if text not in steps:
        raise ValueError(f"must be 0.001 (IS-B) or 0.0001 (IS-C) mm. Got {text!r} instead.")
    return steps[text]


def _step(correction, options) -> np.ndarray:
    return np.array([options["increment_mm"] * 1e3 if u == "um" else 0.0
                     for u in correction.units])


def _render(correction, options) -> dict:
    unknown = [n for n in correction.names if n not in _AXIS]
    if unknown:
        raise InvalidInput([f"format 'fanuc-g10' writes work offsets along X, Y and Z; it has "
                            f"no entry for {', '.join(unknown)}"])
    step = _step(correction, options)
    written = rounded(correction.value, step) * 1e-3  # um -> mm
    places = decimals(options["increment_mm"])
    words = " ".join(f"{_AXIS[n]}{v:.{places}f}" for n, v in zip(correction.names, written))
    p = options["offset"]
    src = correction.source
    lines = [
        "%",
        f"O{options['program']:04d} (MTPLAN WORK OFFSET CORRECTION G{53 + p})",
        f"({correction.procedure.upper()} ESTIMATOR {str(src.get('estimator')).upper()})",
        "(ADDS THE MEASURED CENTRE DEVIATION TO THE OFFSET, MM)",
        "(U K=2 UM: " + " ".join(f"{_AXIS[n]}{U:.2g}" for n, U in
                                 zip(correction.names, correction.U)) + ")",
        f"G91 G10 L2 P{p} {words}",
        "G90",
        "M30",
        "%",
    ]
    return {f"work_offset_G{53 + p}.nc": "\n".join(lines) + "\n"}


FORMAT = CompensationFormat(
    name="fanuc-g10",
    title="FANUC work offset (G54-G59) corrected by G91 G10 L2 Pn",
    source="FANUC Series 30i/31i/32i-MODEL B Operator's Manual, programmable data "
           "input G10: workpiece zero-point offset G10 L2 Pp, absolute (G90) or incremental "
           "(G91) input",
    kinds=("work offset",),
    render=_render,
    options=(FormatOption("offset", 1, "work offset 1-6 (G54-G59)",
                          _whole(1, 6, "G54 to G59")),
             FormatOption("increment_mm", 0.001, "the control's input increment: 0.001 (IS-B) "
                          "or 0.0001 (IS-C)", _increment),
             FormatOption("program", 9001, "program number O1-O9999",
                          _whole(1, 9999, "a program number"))),
    resolution=_step,
)
