"""rotary_axis's correction: the measured location errors as the kinematic model's offsets."""

from __future__ import annotations

from mtplan.models.correction import CorrectionModel, CorrectionTerm

#: location errors by axis, with what each says of the axis's average line
_TERMS = {
    "C": (("EX0C", "um", "X position of the C axis's average line at the reference height"),
          ("EY0C", "um", "Y position of the C axis's average line at the reference height"),
          ("EA0C", "urad", "tilt of the C axis about X"),
          ("EB0C", "urad", "tilt of the C axis about Y")),
    "A": (("EY0A", "um", "Y position of the A axis's average line at the reference X"),
          ("EZ0A", "um", "Z position of the A axis's average line at the reference X"),
          ("EB0A", "urad", "tilt of the A axis about Y"),
          ("EC0A", "urad", "tilt of the A axis about Z")),
}


def _terms(setup, names) -> tuple:
    axes = "CA" if setup.get("axis") == "CA" else str(setup.get("axis", "C"))
    return tuple(CorrectionTerm(name, {name: 1.0}, unit, text)
                 for axis in axes for name, unit, text in _TERMS.get(axis, ()))


CORRECTION = CorrectionModel(
    kind="kinematic location",
    frame="machine coordinates, the axis's average line at the set-up's reference height "
          "(C) or reference X (A): the pivot of the control's kinematic model must be there",
    sign="ISO 230-7 location errors: the actual axis minus the nominal one. A kinematic "
         "model takes them as the axis's place (add them to the nominal offsets); a "
         "volumetric compensation takes them as errors and removes them",
    terms=_terms,
)
