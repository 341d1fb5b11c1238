"""circle_centre's correction: the bore's centre as a work offset."""

from __future__ import annotations

from mtplan.models.correction import CorrectionModel, CorrectionTerm


def _terms(setup, names) -> tuple:
    return (CorrectionTerm("work_offset_x", {"centre_x": 1.0}, "um",
                           "the work offset's X: the bore centre's x minus its nominal"),
            CorrectionTerm("work_offset_y", {"centre_y": 1.0}, "um",
                           "the work offset's Y: the bore centre's y minus its nominal"))


CORRECTION = CorrectionModel(
    kind="work offset",
    frame="machine coordinates, from the bore's nominal centre (where the work offset "
          "pointed when the bore was probed)",
    sign="add to the work offset: it then points at the measured centre (G91 G10 L2 adds; "
         "an absolute entry is the nominal centre plus these values)",
    terms=_terms,
)
