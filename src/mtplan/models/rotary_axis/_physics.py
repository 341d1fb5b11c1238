"""rotary_axis's measurands, error sources, forward model, true values and the truth
of an estimate.
"""

from __future__ import annotations

import math

import numpy as np

from mtplan.models.protocol import Measurand, Readings, Source
from mtplan.models.rotary_axis._axes import AXIS_ROWS, POSITION_AXIS, axis_parts, combined
from mtplan.models.rotary_axis._layout import (
    FRAMES,
    influence_knots,
    NAMES,
    Plan,
    plan,
    rotate_about,
    rotate_by_vector,
    tilts,
)
from mtplan.models.rotary_axis._setup import ARCSEC, UM, URAD, Setup, Truth
from mtplan.models.protocol import file_content
from mtplan.uncertainty.distributions import Arcsine, MultivariateNormal, Normal, Rectangular


# --------------------------------------------------------------------------- protocol
_MEASURANDS = {
    "C": (
        Measurand("EX0C", "um", "X position of the C axis at the reference height"),
        Measurand("EY0C", "um", "Y position of the C axis at the reference height"),
        Measurand("EA0C", "urad", "orientation error of the C axis about X"),
        Measurand("EB0C", "urad", "orientation error of the C axis about Y"),
    ),
    "A": (
        Measurand("EY0A", "um", "Y position of the A axis at the reference X"),
        Measurand("EZ0A", "um", "Z position of the A axis at the reference X"),
        Measurand("EB0A", "urad", "orientation error of the A axis about Y"),
        Measurand("EC0A", "urad", "orientation error of the A axis about Z"),
    ),
    "CA": (
        Measurand("ac_offset", "um", "offset of the C axis from the A axis: signed length of "
                  "their common perpendicular, positive when C passes on the +Y side of A"),
        Measurand("ac_squareness", "urad", "squareness of C to A: 90 deg minus the angle "
                  "between them, asin(u_A . u_C) (about EB0C - EB0A)"),
        Measurand("pose_dx", "um", "X error of the workpiece point pose_point_mm at the pose "
                  "A = pose_a_deg, C = pose_c_deg, from the location errors of both axes"),
        Measurand("pose_dy", "um", "Y error of that point at that pose"),
        Measurand("pose_dz", "um", "Z error of that point at that pose"),
    ),
}


def measurands(setup: Setup) -> tuple[Measurand, ...]:
    """The ISO 230-7 location errors of each axis measured; for CA also the derived ones."""
    out = tuple(m for axis in setup.axes for m in _MEASURANDS[axis])
    return out + (_MEASURANDS["CA"] if setup.axis == "CA" else ())


def sources(setup: Setup) -> dict[str, Source]:
    """Every error source of the set-up, in internal units (mm, rad, 1).

    Shapes: P = positions, M = readings per position (the lattice's points, twice with
    sensor_reversal).
    """
    return {**_machine_sources(setup), **_sensor_and_setup_sources(setup)}


def zero_errors(setup: Setup, m: int) -> dict[str, np.ndarray]:
    """Every source's errors at zero for `m` trials, (m, *shape, *event_shape) each."""
    return {k: np.zeros((m, *v.shape, *v.distribution.event_shape))
            for k, v in sources(setup).items()}


def _machine_sources(setup: Setup) -> dict[str, Source]:
    """The readings' noise and gain, the slides, the artifact, the drift, the rotary axis."""
    P, M = setup.n_positions, setup.n_readings  # M: readings per position, every pass
    um = UM

    def rect(half):
        return Rectangular(-half, half)

    return {
        "probe_noise": Source(
            Normal(0.0, setup.probe_noise_um * um), (P, M),
            "Noise of one reading of the point laser sensor (standard deviation). Default 1 um: "
            "the repeatability of industrial laser triangulation sensors of 10-25 mm range on a "
            "ground metal surface (makers quote 0.5-2 um).", field="probe_noise_um"),
        "sensor_scale": Source(
            rect(setup.sensor_scale_ppm * 1e-6), (),
            "Scale (gain) error of the sensor, one per test, rectangular: its reading from "
            "mid-range is s (1 + kappa). Default +-500 ppm: the gain's share of a triangulation "
            "sensor's calibration (makers' certificates: +-0.03-0.1 % of the range); the "
            "curvature is sensor_linearity_halfwidth. With z_follows_surface it acts on the "
            "sensor's small residual only.", field="sensor_scale_ppm"),
        "xy_positioning": Source(
            Normal(0.0, setup.xy_positioning_um * um), (2, P, M),
            "X and Y positioning error of the slides at each lattice point (standard deviation; "
            "element [0] X, [1] Y). Default 1 um: ISO 230-2 unidirectional repeatability "
            "R = 4 s of about 4 um on a precision machining centre. A lateral error d changes "
            "the height by d tan(slope).", field="xy_positioning_um"),
        "z_positioning": Source(
            Normal(0.0, setup.z_positioning_um * um), (P, M) if setup.z_follows_surface else (P,),
            "Z positioning error (standard deviation): enters the reading in full, since "
            "reading = Z position + sensor value; per reading when Z follows the surface, per "
            "lattice otherwise. Default 1 um, as for X and Y (ISO 230-2 repeatability).",
            field="z_positioning_um"),
        "flatness": Source(
            rect(setup.flatness_um * um / 4), (5,),
            "Form error of the incline, one per test: bowl, saddle, twist and two cubic waves "
            "over the lattice, coefficients uniform in +-flatness/4, so the form's peak to "
            "valley is about flatness_um. Default 2 um: DIN 876 grade 00 / ISO 8512 for a "
            "face of 100-150 mm (2 (1 + L/1000) um); the diffuse face the sensor's table "
            "needs (artifact_surface) must be finished to it.", field="flatness_um"),
        "artifact_tilt": Source(
            Normal(0.0, setup.artifact_tilt_urad * 1e-6), (2,),
            "Tilts of the artifact's real plane from the nominal one, one pair per test: [0] "
            "about the line across the fall line (the incline angle), [1] about the fall line. "
            "Normal, standard deviation 10 mrad (0.6 deg) by default: an inclined plane "
            "clamped on the table by eye is easily 5-20 mrad off, so 20 mrad is twice the "
            "standard deviation (so that the fit check's prior term does not flag such a "
            "clamping). No hard bound: the readings "
            "determine the real plane, so a bounded prior would pull the axis when the plane "
            "lies beyond it. Every estimator fits each lattice's plane and never uses the "
            "nominal incline; a posterior must not take it as exact.", field="artifact_tilt_urad"),
        "artifact_height_error": Source(
            rect(setup.artifact_height_error_um * um), (),
            "Real height of the incline's reference point above its nominal, one per test. "
            "Default +-100 um: the fixture's drawing tolerance and its clamping.",
            field="artifact_height_error_um"),
        "thermal_drift": Source(
            Normal(0.0, setup.thermal_drift_um_per_s * um), (3,),
            "Drift rate (X, Y, Z) of the sensor against the table during the test, one per "
            "test (standard deviation per component), applied over the time line of the test. "
            "Default 0.001 um/s (3.6 um/h): ISO 230-3 environmental drift of a machining "
            "centre in a workshop without temperature control of the machine.",
            field="thermal_drift_um_per_s"),
        "radial_motion": Source(
            rect(setup.radial_motion_um * um / 2), (P, 2),
            "Radial error motion of the rotary axis at each position, two directions "
            "perpendicular to the axis, uniform within +-half the value. Default 3 um: ISO "
            "230-7 radial error motion of direct-drive rotary tables (makers quote 2-5 um).",
            field="radial_motion_um"),
        "axial_motion": Source(
            rect(setup.axial_motion_um * um / 2), (P,),
            "Axial error motion at each position, uniform within +-half the value. Default 2 "
            "um: ISO 230-7 axial error motion of direct-drive rotary tables (1-3 um).",
            field="axial_motion_um"),
        "tilt_motion": Source(
            rect(setup.tilt_motion_urad * URAD / 2), (P, 2),
            "Tilt error motion at each position about the two directions perpendicular to the "
            "axis (about the axis point at the reference height), uniform within +-half the "
            "value. Default 10 urad (2 arcsec): wobble specifications of precision rotary "
            "tables (1-5 arcsec).", field="tilt_motion_urad"),
        "angular_positioning": Source(
            rect(setup.angular_positioning_arcsec * ARCSEC / (2 * math.sqrt(2))),
            (len(setup.axes), 4),
            "Systematic angular positioning error of each rotary axis tested, a smooth and "
            "repeatable function of the commanded angle theta: a1 cos theta + b1 sin theta + "
            "a2 cos 2 theta + b2 sin 2 theta (per axis [a1, b1, a2, b2]), each coefficient "
            "uniform within +-bound / (2 sqrt 2), so each harmonic's amplitude is at most half "
            "the bound and the error at most the bound. ISO 230-2 finds positioning errors of "
            "rotary axes dominated by such low orders (eccentricity of the encoder: the first "
            "harmonic; its ellipticity: the second). Default 5 arcsec: the positioning "
            "accuracy of rotary tables with direct angle encoders (trunnion A axes are often "
            "10-30 arcsec: state yours). patent, joint and gls do not use the angles.",
            field="angular_positioning_arcsec"),
        "angular_repeatability": Source(
            Normal(0.0, setup.angular_repeatability_arcsec * ARCSEC), (P,),
            "Random part of the angular positioning error at each position (standard "
            "deviation). Default 1 arcsec: ISO 230-2 unidirectional repeatability R = 4 s of "
            "about 2-4 arcsec of rotary tables with direct angle encoders.",
            field="angular_repeatability_arcsec"),
    }


def _sensor_and_setup_sources(setup: Setup) -> dict[str, Source]:
    """The errors that act one to one (spot, zero, the slides' slope and bow, reversal,
    short-period positioning, linearity) and the sensor's angle influence."""
    P = setup.n_positions
    um = UM

    def rect(half):
        return Rectangular(-half, half)

    return {
        "spot_offset_u": Source(
            Normal(0.0, setup.spot_offset_u_um * um), (2,),
            "Lateral offset [0] X, [1] Y of the laser spot from the point the slides command, "
            "one per test (the sensor is fixed on the spindle): every reading is the height "
            "d away, so every plane, and with it the axis, moves by -d in X and Y, one to one. "
            "Normal, default 5 um per component: the spot (50-100 um across on a 10 mm "
            "triangulation sensor's data sheet) located on the machine by scanning a sphere or "
            "an edge, to about a tenth of its diameter.", field="spot_offset_u_um"),
        "sensor_zero_u": Source(
            Normal(0.0, setup.sensor_zero_u_um * um), (),
            "Zero of the sensor (its reading at the commanded Z on the nominal surface), one "
            "per test: every reading is off by it, so the planes move along Z: one to one into "
            "the A axis's EZ0A, nothing on C. Normal, default 2 um: set on a gauge block by "
            "the Z slide, whose ISO 230-2 repeatability is a few micrometres.",
            field="sensor_zero_u_um"),
        "xy_slope_halfwidth": Source(
            rect(setup.xy_slope_halfwidth_urad * URAD), (2,),
            "Slope in Z of the X [0] and Y [1] motion over the lattice (the squareness of X "
            "and Y to Z), machine-fixed: the same at every position. Each plane's slope is "
            "off by it, so the normals and with them the axis's direction tilt (EA0C, EB0C; "
            "EB0A, EC0A). Rectangular, default +-20 urad: half of ISO 10791-2's squareness "
            "tolerance of 0.020 mm/500 mm (40 urad), for a machine measured and compensated "
            "to within half of it.", field="xy_slope_halfwidth_urad"),
        "xy_straightness_halfwidth": Source(
            rect(setup.xy_straightness_halfwidth_um * um), (2,),
            "Bow in Z of the X [0] and Y [1] motion, b (x / 50 mm)^2 and b (y / 50 mm)^2 "
            "about the table centre, machine-fixed. Rectangular, default +-1 um: ISO 10791-2's "
            "straightness tolerance 0.010 mm/500 mm, taken proportionally to 100 mm.",
            field="xy_straightness_halfwidth_um"),
        "reversal_halfwidth": Source(
            rect(setup.reversal_halfwidth_arcsec * ARCSEC), (len(setup.axes),),
            "Reversal value B (ISO 230-2) of each rotary axis tested, sign unknown: a position "
            "approached in the other direction than the test's first move is off by B (the "
            "first position is approached in the direction of the first move, after an "
            "overrun). Only the angles estimator uses the angles; in ascending order every "
            "position is approached one way and B is a common zero it absorbs; in the "
            "patent's A order (up, then down) it moves EB0A. Rectangular, default +-5 arcsec: "
            "ISO 230-2 reversal values of worm-driven rotary tables, 2-10 arcsec in makers' "
            "acceptance reports.", field="reversal_halfwidth_arcsec"),
        "angular_short_period_halfwidth": Source(
            Arcsine(-setup.angular_short_period_halfwidth_arcsec * ARCSEC,
                    setup.angular_short_period_halfwidth_arcsec * ARCSEC), (P,),
            "Short-period share of the rotary axis's positioning error at each position (the "
            "angle encoder's interpolation error within a signal period, the worm's error "
            "per turn): repeatable, so the same in every test, but of a period far shorter "
            "than the positions' spacing, so unrelated from one position to the next. "
            "Arcsine (a sinusoid of unknown phase), default amplitude 1 arcsec: angle "
            "encoders' position error within one signal period, about +-1 % of a 30-80 "
            "arcsec signal period (makers' catalogues). Only the angles estimator uses it.",
            field="angular_short_period_halfwidth_arcsec"),
        "sensor_linearity_halfwidth": Source(
            rect(0.4 * setup.sensor_linearity_halfwidth_ppm * 1e-6), (2,),
            "The sensor's linearity deviation over its range, one curve per test: with x = 2 "
            "s / range (s the sensor value from mid-range), range (c2 1.5 x^2 + c3 (5 x^3 - 3 "
            "x) / 2), the Legendre terms P2 - P2(0) and P3 (a deviation about the best "
            "straight line, zero at mid-range, where the zero is set), each coefficient "
            "uniform within +-0.4 bound, so the curve stays within +-bound. Default 800 ppm: "
            "+-0.08 % of the range, triangulation sensors' data sheets (e.g. Micro-Epsilon "
            "optoNCDT 1750). The gain is sensor_scale. With z_follows_surface the sensor "
            "works about mid-range and this acts on tens of micrometres only.",
            field="sensor_linearity_halfwidth_ppm"),
        "angle_influence_halfwidth": Source(
            _swing(0.0 if setup.sensor_characteristic is not None
                   else setup.angle_influence_halfwidth_ppm * 1e-6),
            (influence_knots(tilts(setup)[0]).size, 4),
            "The sensor's angle influence: a height error of every reading of a position that "
            "depends on the local tilt of the surface in the sensor's frame, magnitude tau "
            "and direction phi (the fall line's azimuth from the triangulation plane). The "
            "data sheet bounds it at each tilt, |e| <= range * B(tau), and states no shape "
            "and no split, so it is an unknown function within that bound, one per test (one "
            "sensor): e = range * B(tau) * sum_k hat_k(tau) sum_i a_ki q_i(phi), with hats "
            "on tilt knots spread over the test's tilts about 15 deg apart (smooth shapes in "
            "tilt, B's own among them but not assumed) and the four corner shapes q = (1 +- "
            "cos phi)(1 +- cos 2 phi) / 4; the hats and the q are >= 0 and each sum to 1, so "
            "every element within +-1 (of the bound at 30 deg, the field) keeps the error "
            "within the bound at every tilt and direction, and the even part, the odd part "
            "along the triangulation plane (it changes sign when the sensor turns by 180 "
            "deg) and the anisotropy across it each reach the whole bound. Each element is "
            "arcsine (JCGM 101 6.4.6: a characteristic that swings between its bounds), not "
            "uniform: the split being unknown, each part's variance must cover a sensor "
            "that puts most of the bound into that part (uniform elements give each part "
            "0.32 of the bound as standard deviation, a mostly-odd sensor 0.38; arcsine "
            "0.40). Estimators and the first-order budget take only the covariance of "
            "these draws. B: the "
            "angle influence tables of laser triangulation sensors on diffuse surfaces "
            "(Micro-Epsilon's operating instructions for optoNCDT 1700 and 2300: typ. "
            "0.12-0.2 % of the range at 5-15 deg, 0.5 % at 15-30 deg), taken as 0.12 % at 5 "
            "deg, 0.2 % at 15, 0.5 % at 30 (linear between, through 0 at 0 deg; beyond 30 "
            "deg along the last row's slope, an extrapolation), scaled so that B(30 deg) = "
            "angle_influence_halfwidth_ppm. Default 5000 ppm (0.5 %). On a C axis the odd "
            "part moves the axis sideways by about e / tan(incline); on an A axis the even "
            "part and the anisotropy move EZ0A. Off (0) when sensor_characteristic gives a "
            "calibrated characteristic: its u is angle_calibration_u.",
            field="angle_influence_halfwidth_ppm"),
        "angle_calibration_u": _calibration_source(setup),
    }


def _swing(half: float) -> Arcsine:
    """Arcsine within +-half: an element of the angle influence (see its description)."""
    return Arcsine(-half, half)


def _calibration_source(setup: Setup) -> Source:
    """The calibrated characteristic's error at each calibrated point the set-up's tilts
    interpolate from: normal, independent between points, std the file's u_um (or
    angle_calibration_u_um); without a characteristic, off."""
    text = (
        "Error of the calibrated angle characteristic (sensor_characteristic) at each "
        "calibrated tilt the set-up's readings interpolate from, one set per test (one "
        "calibration): every reading is corrected by the characteristic interpolated "
        "bilinearly at its nominal tilt, so it carries the same interpolation of these "
        "errors; readings at one tilt share their error, readings at neighbouring tilts "
        "share calibrated points. Normal, independent between calibrated points, standard "
        "deviation each point's u_um from the file (its tilt-table calibration's "
        "certificate), or angle_calibration_u_um for every point. A share common to every "
        "point is a zero offset, which sensor_zero_u covers (the zero is set on the machine).")
    g = plan(setup)
    points = g.calibration_index
    if points.size == 0:
        return Source(Normal(0.0, 0.0), (1,), text, field="angle_calibration_u_um")
    if setup.angle_calibration_u_um is not None:
        u = np.full(points.size, setup.angle_calibration_u_um * UM)
    else:
        u = file_content(setup, "sensor_characteristic").u.ravel()[points]
    return Source(MultivariateNormal(np.zeros(points.size), np.diag(u * u)), (), text,
                  field="angle_calibration_u_um")


def true_line(setup: Setup, truth: Truth) -> tuple[np.ndarray, np.ndarray]:
    """Point at the reference (3,) [mm] and unit direction (3,) of the true axis."""
    f = FRAMES[setup.axis]
    # truth fields may be arrays (one truth per batch row, e.g. posterior walkers):
    # each value becomes shape (m, 1) so that point and direction are (m, 3)
    tv = {k: (np.reshape(v, (-1, 1)) if np.ndim(v) else v)
          for k, v in true_values(setup, truth).items()}
    n1, n2, a1, a2 = NAMES[setup.axis]
    # slope components along p1 and p2 (see the sign convention in the module docstring)
    t1, t2 = tv[a2], -tv[a1]
    point = setup.reference_height_mm * f.ax + tv[n1] * f.p1 + tv[n2] * f.p2
    w = f.ax + t1 * f.p1 + t2 * f.p2
    return point, w / np.linalg.norm(w, axis=-1, keepdims=True)


def true_values(setup: Setup, truth: Truth) -> dict[str, float]:
    """True measurands of the axes under test [mm, rad] (for CA with the derived ones)."""
    out = {}
    if "C" in setup.axes:
        out.update({"EX0C": truth.EX0C_um * UM, "EY0C": truth.EY0C_um * UM,
                    "EA0C": truth.EA0C_urad * URAD, "EB0C": truth.EB0C_urad * URAD})
    if "A" in setup.axes:
        out.update({"EY0A": truth.EY0A_um * UM, "EZ0A": truth.EZ0A_um * UM,
                    "EB0A": truth.EB0A_urad * URAD, "EC0A": truth.EC0A_urad * URAD})
    if setup.axis == "CA":
        derived = combined(setup, {k: np.array([v]) for k, v in out.items()})
        out.update({k: float(v[0]) for k, v in derived.items()})
    return out


def truth_from_estimate(setup: Setup, estimate: dict) -> Truth:
    """The Truth whose measurands equal `estimate` [mm, rad] (the other axis at its defaults).

    For CA the derived measurands follow from the eight location errors and are not
    Truth fields.
    """
    fields = {"EX0C": "EX0C_um", "EY0C": "EY0C_um", "EY0A": "EY0A_um", "EZ0A": "EZ0A_um",
              "EA0C": "EA0C_urad", "EB0C": "EB0C_urad", "EB0A": "EB0A_urad", "EC0A": "EC0A_urad"}
    values = {}
    for name, value in estimate.items():
        if name not in fields:
            continue
        field = fields[name]
        values[field] = float(np.asarray(value).ravel()[0]) / (UM if field.endswith("_um") else URAD)
    return Truth(**values)



def forward(setup: Setup, truth: Truth, errors: dict) -> Readings:
    """Simulated readings of the lattices: ``{"z_mm": array (n, positions, points)}``.

    Parameters
    ----------
    setup : Setup
    truth : Truth
    errors : dict of str to array
        Every source of :func:`sources`, each of shape ``(n, *shape)`` [mm, rad, 1].

    Returns
    -------
    dict
        ``z_mm``: the reading of each lattice point, Z position + sensor value [mm], in
        measuring order (for CA: the C positions, then the A positions). The per-test
        errors (scale, flatness, drift) are shared by both axes of a CA test; the drift
        runs on over the whole test's time line.
    """
    g = plan(setup)
    z = []
    for i, (part, sl) in enumerate(axis_parts(setup)):
        errs = {k: (v[(slice(None),) * POSITION_AXIS[k] + (sl,)] if k in POSITION_AXIS
                    else v[:, i] if k in AXIS_ROWS else v) for k, v in errors.items()}
        z.append(_forward_axis(part, truth, errs, g.times[sl]))
    z = z[0] if len(z) == 1 else np.concatenate(z, axis=1)
    influence = errors["angle_influence_halfwidth"]  # (n, K, 4): one function of the tilt
    if np.any(influence):  # over the whole test (one sensor), at each reading's tilt
        z = z + np.tensordot(influence.reshape(len(influence), -1),
                             g.influence.reshape(-1, *z.shape[1:]), axes=1)
    if g.characteristic is not None:  # the sensor's calibrated characteristic, its error
        z = z + g.characteristic
        cal = errors["angle_calibration_u"]  # (n, K) at the calibrated points
        if np.any(cal):
            z = z + np.tensordot(cal, g.calibration, axes=1)
    return Readings({"z_mm": z})


def _artifact_pose(g: Plan, tilt, height) -> tuple[np.ndarray, np.ndarray]:
    """The artifact's real upward normal and reference point at the zero position: the
    nominal ones (3,), or (n, 3) turned by the per-test tilts (n, 2) [rad] about the line
    across the fall line and about the fall line, and raised by `height` (n,) [mm]."""
    n0, q0 = g.n0, g.q0
    if tilt is not None and np.any(tilt):
        fall = np.array([-n0[0], -n0[1], 0.0])  # downhill in the table plane
        fall = fall - (fall @ n0) * n0
        norm = np.linalg.norm(fall)
        f1 = fall / norm if norm > 1e-12 else np.array([1.0, 0.0, 0.0]) - n0[0] * n0
        f1 = f1 / np.linalg.norm(f1)
        f2 = np.cross(n0, f1)
        n0 = rotate_by_vector(n0, tilt[:, :1] * f2 + tilt[:, 1:] * f1)
    if height is not None and np.any(height):
        q0 = q0 + height[:, None] * np.array([0.0, 0.0, 1.0])
    return n0, q0


def _forward_axis(setup: Setup, truth: Truth, errors: dict, times: np.ndarray) -> np.ndarray:
    """Readings (n, P, M) of one axis's positions; `times` (P, M) [s] for the drift."""
    g = plan(setup)
    f = g.frame
    noise = errors["probe_noise"]
    n, P, M = noise.shape
    a, u = true_line(setup, truth)  # (3,), or (n, 3) for one truth per trial
    ub = u[:, None, None, :] if u.ndim == 2 else u

    # rigid motion of the artifact at each position: exact rotation about the true axis by
    # the commanded angle, then by the angular positioning error, then the error motion
    # (tilt about the axis point, radial and axial translation). The normal and the lever
    # arm from the axis point to the incline's reference point turn together: (.., 2, 3).
    n0, q0 = _artifact_pose(g, errors.get("artifact_tilt"), errors.get("artifact_height_error"))
    lever = np.stack(np.broadcast_arrays(n0, q0 - a), axis=-2)  # (2, 3) or (n, 2, 3)
    if lever.ndim == 3:
        lever = lever[:, None]
    vec = rotate_about(lever, ub, g.theta[:, None])  # (P, 2, 3) or (n, P, 2, 3)
    # angular positioning: the smooth systematic part (harmonics of the commanded angle)
    # plus the random part per position, (n, P) [rad]
    dpsi = (errors["angular_positioning"] @ g.harmonics + errors["angular_repeatability"]
            + errors["angular_short_period_halfwidth"]
            + errors["reversal_halfwidth"][:, None] * g.down)
    if np.any(dpsi):
        vec = rotate_about(vec, ub, dpsi[..., None])  # (n, P, 2, 3)
    tilt = errors["tilt_motion"]
    if np.any(tilt):
        w = tilt[..., :1] * f.p1 + tilt[..., 1:] * f.p2
        vec = rotate_by_vector(vec, w[..., None, :])
    vec = np.broadcast_to(vec, (n, P, 2, 3))
    normal = vec[..., 0, :]
    q = (a[:, None, :] if a.ndim == 2 else a) + vec[..., 1, :]
    rad, axial = errors["radial_motion"], errors["axial_motion"]
    if np.any(rad):
        q = q + rad[..., :1] * f.p1 + rad[..., 1:] * f.p2
    if np.any(axial):
        q = q + axial[..., None] * f.ax

    # the plane z = h + c1 (x - cx) + c2 (y - cy) about each lattice centre
    coef = np.empty((n, P, 3))
    c1, c2 = coef[..., 1], coef[..., 2]
    np.divide(normal[..., 0], normal[..., 2], out=c1)
    np.divide(normal[..., 1], normal[..., 2], out=c2)
    np.negative(coef[..., 1:], out=coef[..., 1:])
    coef[..., 0] = q[..., 2] + c1 * (g.centres[:, 0] - q[..., 0]) + c2 * (g.centres[:, 1] - q[..., 1])
    # thermal drift moves the sensor by rate * t: height change (c1 rx + c2 ry - rz) t
    rate = errors["thermal_drift"]  # (n, 3)
    drift = c1 * rate[:, :1] + c2 * rate[:, 1:2] - rate[:, 2:] if np.any(rate) else None

    # per reading (n, P, M): one matrix product for the planes, then each active source
    # added in place (a source switched off is all zeros and skipped)
    z = np.matmul(coef.reshape(n * P, 3), g.read_local).reshape(n, P, M)
    z += noise
    tmp = np.empty_like(z)
    if drift is not None:
        z += np.multiply(drift[..., None], times, out=tmp)
    xy_err = errors["xy_positioning"]  # (n, 2, P, M): the ray is where the slides really are
    if np.any(xy_err):
        z += np.multiply(c1[..., None], xy_err[:, 0], out=tmp)
        z += np.multiply(c2[..., None], xy_err[:, 1], out=tmp)
    spot = errors["spot_offset_u"]  # (n, 2): the spot reads the height d away (-d at 180)
    if np.any(spot):
        z += (c1 * spot[:, :1] + c2 * spot[:, 1:])[..., None] * g.sensor_sign
    zero = errors["sensor_zero_u"]  # (n,)
    if np.any(zero):
        z += zero[:, None, None]
    motion = np.concatenate([errors["xy_slope_halfwidth"], errors["xy_straightness_halfwidth"]],
                            axis=-1)  # (n, 4): the slides' Z error, the same at every position
    if np.any(motion):
        z -= np.tensordot(motion, g.machine, axes=1)
    form = errors["flatness"]  # (n, K)
    if np.any(form):
        z += np.matmul(form, g.form).reshape(n, P, M)
    ez = errors["z_positioning"]  # gap = surface - actual Z position
    if np.any(ez):
        z -= ez if ez.ndim == 3 else ez[..., None]
    kappa = errors["sensor_scale"]  # reading = Z_cmd + (gap - Z_cmd) (1 + kappa) + noise
    lin = errors["sensor_linearity_halfwidth"]  # (n, 2): + range (c2 1.5 x^2 + c3 P3(x))
    if np.any(kappa) or np.any(lin):
        s = z - noise - g.z_cmd  # the sensor value from mid-range
        if np.any(lin):
            half = setup.sensor_range_mm / 2
            x = s / half
            z += 2 * half * (lin[:, :1, None] * 1.5 * x * x
                             + lin[:, 1:, None] * 0.5 * x * (5 * x * x - 3))
        if np.any(kappa):
            z += s * kappa[:, None, None]
    return z
