"""line_laser's observability: which estimator determines which angle at a
set-up, and in what steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mtplan.models.line_laser._artifact import pitch, x_shift
from mtplan.models.line_laser._estimators import registration_check
from mtplan.models.line_laser._setup import ALPHA_MAX


# --------------------------------------------------------------------------- observability
@dataclass(frozen=True)
class Observability:
    """Whether an estimator determines an angle at a set-up, and how finely.

    Attributes
    ----------
    observable : bool
        False where the estimator cannot tell the angle at this set-up (its value
        would be noise or a constant).
    signed : bool
        False where the estimator returns only the magnitude.
    quantum_urad : float
        Step of the estimate's possible values (0 when continuous) [urad].
    floor_urad : float
        Smallest magnitude the estimator tells from zero (standard-uncertainty level;
        0 where the estimate is linear in the angle) [urad].
    reason : str
        Plain-English explanation.
    """

    observable: bool
    signed: bool
    quantum_urad: float
    floor_urad: float
    reason: str


def observability(setup) -> dict:
    """Per estimator and angle: can it be determined at this set-up, with what limits.

    Returns
    -------
    dict
        ``{estimator: {"alpha_z"|"alpha_y"|"alpha_x": Observability}}``.
    """
    w, h = x_shift(setup), setup.raise_mm
    dy = setup.step_mm
    sigma = setup.sensor_noise_um * 1e-3
    n_all = setup.lines * setup.points_per_line
    quantum = math.atan(dy / w)
    u_h = math.sqrt((setup.raise_error_um * 1e-3) ** 2 + 2 * sigma**2 / n_all)
    floor_x = math.sqrt(2 * u_h / h)
    at_1mrad = h * 1e-6 / 2 * 1e6  # h' - h at 1 mrad [nm]
    patent = {
        "alpha_z": Observability(
            True, True, quantum * 1e6, 0.0,
            f"integer row shift: alpha_z comes in steps of arctan(dy/w) = {quantum * 1e6:.4g} "
            f"urad (dy = {dy:g} mm, w = {w:g} mm); values between steps are rounded"),
        "alpha_y": Observability(
            True, True, 0.0, 0.0,
            "mean height difference of the common part; biased by the sub-step "
            "misregistration left by the integer row shift, and by the sensor's linearity "
            "error through e(x_l + w) - e(x_l)"
            + ("" if abs(w / pitch(setup) - round(w / pitch(setup))) < 1e-9 else
               f"; w = {w / pitch(setup):.4g} point spacings is not a whole number, so the "
               f"alignment interpolates across the facets' kinks (a bias of some 10 urad: "
               f"choose shift_fraction so that w is a whole number of spacings)")
            + ("" if setup.lines * dy >= setup.cell_size_mm * (1 - 1e-9) else
               f"; the scan ({setup.lines} x {dy:g} mm) covers less than one cell pitch "
               f"({setup.cell_size_mm:g} mm) along Y, so which facets it holds, and the bias, "
               f"depend on where the artifact lies (tens of urad)")),
        "alpha_x": Observability(
            floor_x < ALPHA_MAX, False, 0.0, floor_x * 1e6,
            f"arccos(h/h') is even in alpha_x (returns |alpha_x|) and flat at small angles: "
            f"h' - h = h*alpha^2/2 = {at_1mrad:.3g} nm at 1 mrad, against a standard "
            f"uncertainty of h' of {u_h * 1e6:.3g} nm (raise positioning, sensor noise), so "
            f"|alpha_x| below about {floor_x * 1e3:.3g} mrad is indistinguishable from 0"
            + (f", more than the {ALPHA_MAX * 1e3:g} mrad this procedure is for: not "
               f"measurable at this set-up" if floor_x >= ALPHA_MAX else "")
            + "; even noise-free it does not estimate alpha_x (nor arccos(cos ax cos ay), "
              "which holds on the flat parts of a level artifact only): h' is weighted by "
              "the facets in the window, which change the height by up to h tan(facet) times "
              "the measuring direction's tilt, +-2 um at 2 mrad, and cancel only as far as "
              "the scan covers them in equal shares"),
    }
    ok, why = registration_check(setup)
    reg = {k: Observability(ok, True, 0.0, 0.0, why) for k in ("alpha_z", "alpha_y", "alpha_x")}
    why_pattern = (why if not ok else
                   "generalised least squares of the forward model on the stated pattern, "
                   "weighted by the error budget (started from the registration); as good as "
                   "the pattern is known (facet_position_um)")
    pattern = {k: Observability(ok, True, 0.0, 0.0, why_pattern)
               for k in ("alpha_z", "alpha_y", "alpha_x")}
    return {"patent": patent, "registration": reg, "pattern": pattern}


def resolution(setup, estimator: str) -> dict:
    """The steps [rad] in which `estimator`'s values come: the patent's alpha_z is a whole
    row shift, in steps of ``arctan(dy / w)``; the others are continuous (empty)."""
    return {"alpha_z": math.atan(setup.step_mm / x_shift(setup))} if estimator == "patent" else {}

