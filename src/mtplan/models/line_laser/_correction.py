"""line_laser's correction: the mounting angles, as the rotation that corrects the profiles."""

from __future__ import annotations

from mtplan.models.correction import CorrectionModel, CorrectionTerm

_TERMS = (("alpha_z", "mounting angle about Z (applied first)"),
          ("alpha_y", "mounting angle about Y (applied second)"),
          ("alpha_x", "mounting angle about X (applied last)"))


def _terms(setup, names) -> tuple:
    return tuple(CorrectionTerm(name, {name: 1.0}, "urad", text) for name, text in _TERMS)


CORRECTION = CorrectionModel(
    kind="sensor rotation",
    frame="the scan's frame: Y along the Y motion, X in the plane of the X and Y motions, Z "
          "normal to both; the sensor's frame in it is R = Rx(alpha_x) Ry(alpha_y) "
          "Rz(alpha_z), rotations about the fixed axes",
    sign="coordinate compensation: a profile point (x, 0, z) in the sensor's frame is at "
         "R (x, 0, z) in the scan's, so apply R to every profile; mechanical adjustment: turn "
         "the sensor by R transposed (alpha_x back first, then alpha_y, then alpha_z)",
    terms=_terms,
)
