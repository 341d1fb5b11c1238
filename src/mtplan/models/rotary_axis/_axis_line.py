"""rotary_axis's estimator table and the fitted axis as a line.
"""

from __future__ import annotations

from mtplan._validate import Problems
from mtplan.models.rotary_axis._axes import measurand_line
from mtplan.models.rotary_axis._estimators import (
    estimate_angles,
    estimate_gls,
    estimate_joint,
    estimate_patent,
)
from mtplan.models.rotary_axis._setup import NAME, Setup


ESTIMATORS = {"patent": estimate_patent, "joint": estimate_joint, "gls": estimate_gls,
              "angles": estimate_angles}
#: each estimator as the documents describe it (plain words, jargon spelled out)
DESCRIPTIONS = {
    "patent": "The source method: a plane fitted to each lattice, the planes' least-squares "
              "intersection point on the axis, and the axis direction from the plane normals.",
    "joint": "Least squares of the axis model to all readings at once (maximum likelihood).",
    "gls": "The joint fit weighted by the set-up's whole error budget (generalised least "
           "squares, GLS).",
    "angles": "The weighted joint fit with the planes' directions tied to the commanded "
              "angles.",
}


def axis_line(setup: Setup, readings: dict, *, estimator: str = "patent", axis: str | None = None):
    """The fitted axis as a line: point at the reference (n, 3) [mm], unit direction (n, 3).

    The point is where the axis crosses Z = ``reference_height_mm`` (C) or
    X = ``reference_height_mm`` (A); the direction points along +Z (C) or +X (A).
    `axis` ('C' or 'A') picks one of a CA test's two lines (default: the axis tested).
    """
    p = Problems(f"{NAME}.axis_line")
    p.choice("estimator", estimator, ESTIMATORS)
    axis = setup.axis if axis is None else axis
    p.choice("axis", axis, setup.axes)
    p.raise_if_any()
    m = ESTIMATORS[estimator](setup, readings)
    return measurand_line(axis, setup.reference_height_mm, m)

