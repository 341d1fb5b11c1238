"""geometry21's correction: the component errors along each axis's travel as compensation
tables, the squareness errors as the linear axes' location errors."""

from __future__ import annotations

import math

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.models.correction import CorrectionModel, CorrectionTerm
from mtplan.models.geometry21._path import FIELDS, residual_at
from mtplan.models.geometry21._setup import FUNCTIONS, describe

_ALONG = ("along_x_mm", "along_y_mm", "along_z_mm")


def _terms(setup, names) -> tuple:
    if not any(setup.get(field) for field in _ALONG):
        raise InvalidInput(["the result states the component errors at no positions along "
                            "the travel: estimate with --along X=START:STOP:STEP (and Y, Z), "
                            "e.g. --along X=-50:50:5, to write their tables"])
    held = set(names)
    determined = {n.split("@")[0] for n in held if "@" in n}
    half = float(setup.get("line_length_mm", 100.0)) / 2
    out = []
    for axis, field in enumerate(_ALONG):
        for u in setup.get(field) or ():
            u = float(u)
            for name, kind, ax, _ in FUNCTIONS:
                if ax != axis or kind == "sq":
                    continue
                key = f"{name}@{u:g}"
                if name not in determined or (u != 0 and key not in held):
                    continue  # not determined by the test: not corrected
                length = kind in ("pos", "str")
                out.append(CorrectionTerm(
                    key, {key: 1.0} if u != 0 else {}, "um" if length else "urad",
                    f"{describe(name)} at {'xyz'[axis]} = {u:+g} mm"
                    + (" (zero by the definition of the reference)" if u == 0 else ""),
                    argument=("XYZ"[axis], u), extrapolated=abs(u) > half * (1 + 1e-12)))
    for name, kind, *_ in FUNCTIONS:
        if kind == "sq" and name in held:
            out.append(CorrectionTerm(name, {name: 1.0}, "urad", describe(name)))
    return tuple(out)


#: the default grid's step, as a fraction of the measured travel (100 mm: every 5 mm)
ALONG_STEPS = 20


def along_default(setup) -> dict:
    """The errors along each axis's measured travel (``+-line_length_mm / 2``) every
    ``line_length_mm / 20``, where the set-up states no positions of its own (then {})."""
    if any(getattr(setup, field) for field in _ALONG):
        return {}
    half = setup.line_length_mm / 2
    grid = tuple(round(-half + 2 * half * i / ALONG_STEPS, 9) for i in range(ALONG_STEPS + 1))
    return dict.fromkeys(_ALONG, grid)


def _unseen(setup) -> dict:
    """The path residual and the medium-wave deviation stay after any table of the
    translations' errors (their RMS in quadrature)."""
    short = float(setup.get("path_residual_um", 0.0))
    medium = float(setup.get("medium_wave_um", 0.0))
    u = math.hypot(short, medium)
    what = ("the machine's repeatable path deviation beyond the error polynomials, short-wave "
            "(path_residual_um, RMS) and medium-wave (medium_wave_um): a table through "
            "these points removes only the part of it the estimate took up")
    return {name: (u, what) for name, kind, *_ in FUNCTIONS if kind in ("pos", "str") and u}


def _restates(setup) -> dict:
    """Each function as a measurand (its value at +line_length_mm / 2) is its table's point
    there."""
    half = float(setup.get("line_length_mm", 100.0)) / 2
    return {name: f"{name}@{half:g}" for name, kind, *_ in FUNCTIONS if kind != "sq"}
def _realised(setup, errors) -> dict:
    """The path residual and the medium-wave deviation of `errors` at each translation's
    table point [um, batch rows]: the same fields the readings saw
    (:func:`._path.residual_at`)."""
    out = {}
    fields = [f for f in FIELDS if np.any(errors.get(f, 0.0))]
    if not fields:
        return out
    half = setup.line_length_mm / 2  # where the plain measurand (EXX) states its function
    for axis, along in enumerate(_ALONG):
        at = [half] + [float(u) for u in getattr(setup, along) if u != 0]
        values = sum(residual_at(setup, errors[f], axis, at, f) for f in fields) * 1e3
        for name, kind, ax, comp in FUNCTIONS:
            if ax == axis and kind in ("pos", "str"):
                out[name] = values[:, 0, comp]
                out.update({f"{name}@{u:g}": values[:, j, comp]
                            for j, u in enumerate(at) if j})
    return out


CORRECTION = CorrectionModel(
    kind="component errors",
    frame="machine coordinates, zero at the plate centre (the errors' reference point); the "
          "errors of the tool relative to the workpiece at the functional point "
          "(reference_tool_mm), ISO 230-1",
    sign="ISO 230-1 errors: actual minus nominal position or orientation; a volumetric "
         "compensation takes them as errors and removes them",
    terms=_terms,
    unseen=_unseen,
    restates=_restates,
    realised=_realised,
    grid=along_default,
)
