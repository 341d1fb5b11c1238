"""tracker_frame's physics: the true geometry of each head, the error sources, the forward
model from the machine's points to the tracker's readings, the measurands and their true
values, and the truths that reproduce an estimate.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import types
from dataclasses import dataclass

import numpy as np

from mtplan.models import _temperature as temperature
from mtplan.models.protocol import Measurand, Readings, Source
from mtplan.models.tracker_frame._geometry import (
    angles as _angles,
    cross as _cross,
    cyc as _cyc,
    mv as _mv,
    orthonormal as _orthonormal,
    rot as _rot,
    rxyz as _rxyz,
    unit as _unit,
)
from mtplan.models.tracker_frame._layout import (
    arc_angles as _arc_angles,
    bed_marks as _marks,
    linear_positions as _linear_positions,
    n_points as _n_points,
    nominal_origins as _nominal_origins,
    reading_times as _times,
    slices as _slices,
)
from mtplan.models.tracker_frame._setup import AXES, Setup, Truth
from mtplan.uncertainty.distributions import Normal, Rectangular


@dataclass(frozen=True)
class _Head:
    """True geometry of one sub-machine (global frame, mm)."""

    axes: np.ndarray  # (3, 3) rows: unit directions of the X, Y, Z travels
    c_dir: np.ndarray
    a_dir: np.ndarray
    wrist: np.ndarray  # T, the foot of the common perpendicular on C
    a_point: np.ndarray  # foot on A
    perp: np.ndarray  # unit C x A
    offset: float
    reflector: np.ndarray  # reflector at home
    origin: np.ndarray  # true origin (tool tip with the true pivot length)


def _travel_axes(sxy, syz, szx) -> np.ndarray:
    """Unit directions (..., 3, 3), rows X, Y, Z, of the linear travels of a sub-machine
    before its frame's rotation, for its squareness angles [rad]."""
    z0 = np.zeros(np.broadcast_shapes(np.shape(sxy), np.shape(syz), np.shape(szx)))
    ux = np.stack([z0 + 1.0, z0, z0], axis=-1)
    uy = np.stack([np.sin(sxy) + z0, np.cos(sxy) + z0, z0], axis=-1)
    alpha = np.sin(szx) + z0
    beta = (np.sin(syz) - alpha * np.sin(sxy)) / np.cos(sxy)
    uz = np.stack([alpha, beta, np.sqrt(1.0 - alpha**2 - beta**2)], axis=-1)
    return np.stack([ux, uy, uz], axis=-2)


#: the Truth fields of each sub-machine's head (tuples, one per sub-machine)
_HEAD_FIELDS = ("frame_rx_urad", "frame_ry_urad", "frame_rz_urad", "sq_xy_urad", "sq_yz_urad",
                "sq_zx_urad", "c_tilt_x_urad", "c_tilt_y_urad", "a_tilt_y_urad",
                "a_tilt_z_urad", "wrist_dx_um", "wrist_dy_um", "wrist_dz_um", "ac_offset_um",
                "pivot_length_error_um")


def _head(setup: Setup, truth: Truth, k: int) -> _Head:
    """True geometry of sub-machine k (0-based): vectors (3,), or (m, 3) for a truth whose
    fields are arrays (m,) (one truth per batch row). A truth of one value per field is
    looked up by those values (the same head comes back in many forward calls)."""
    values = tuple(_cyc(getattr(truth, f), k) for f in _HEAD_FIELDS)
    if any(v.ndim for v in values) or np.ndim(truth.ac_angle_deg):
        return _head_of(setup, truth, k)
    return _cached_head(setup, k, tuple(float(v) for v in values), float(truth.ac_angle_deg))


@functools.lru_cache(maxsize=256)
def _cached_head(setup: Setup, k: int, values: tuple, ac_angle_deg: float) -> _Head:
    fields = {f: (v,) for f, v in zip(_HEAD_FIELDS, values, strict=True)}
    head = _head_of(setup, types.SimpleNamespace(**fields, ac_angle_deg=ac_angle_deg), k)
    for f in dataclasses.fields(head):  # shared by every caller: read-only
        value = getattr(head, f.name)
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
    return head


def _head_of(setup: Setup, truth, k: int) -> _Head:
    u = 1e-6
    rf = _rxyz(_cyc(truth.frame_rx_urad, k) * u, _cyc(truth.frame_ry_urad, k) * u,
               _cyc(truth.frame_rz_urad, k) * u)
    sxy, syz, szx = (_cyc(truth.sq_xy_urad, k) * u, _cyc(truth.sq_yz_urad, k) * u,
                     _cyc(truth.sq_zx_urad, k) * u)
    axes = _travel_axes(sxy, syz, szx) @ np.swapaxes(rf, -1, -2)  # rows: rf @ u_i
    e = np.eye(3)
    c_loc = _mv(_rot(e[1], _cyc(truth.c_tilt_y_urad, k) * u)
                @ _rot(e[0], _cyc(truth.c_tilt_x_urad, k) * u), e[2])
    ac = np.radians(np.asarray(truth.ac_angle_deg, dtype=float))[..., None]
    a0 = np.sin(ac) * e[0] + np.cos(ac) * e[2]
    a_loc = _mv(_rot(e[2], _cyc(truth.a_tilt_z_urad, k) * u)
                @ _rot(e[1], _cyc(truth.a_tilt_y_urad, k) * u), a0)
    c_dir, a_dir = _mv(rf, c_loc), _mv(rf, a_loc)
    perp = _unit(_cross(c_dir, a_dir))
    nominal = _nominal_origins(setup)[k] + np.array([0.0, 0.0, setup.pivot_length_mm])
    wrist = nominal + 1e-3 * np.stack(np.broadcast_arrays(
        _cyc(truth.wrist_dx_um, k), _cyc(truth.wrist_dy_um, k), _cyc(truth.wrist_dz_um, k)), -1)
    offset = _cyc(truth.ac_offset_um, k) * 1e-3
    a_point = wrist + offset[..., None] * perp
    reflector = wrist - setup.pivot_length_mm * c_dir + setup.reflector_offset_mm * perp
    true_l = setup.pivot_length_mm + _cyc(truth.pivot_length_error_um, k) * 1e-3
    origin = wrist - true_l[..., None] * c_dir
    return _Head(axes, c_dir, a_dir, wrist, a_point, perp, offset, reflector, origin)


def _fixture_displacement(head: _Head, fixture: np.ndarray) -> np.ndarray:
    """Global displacement (n, 3) [mm] of the reflector for its fixture errors (n, 3) [mm]:
    across C away from it (``perp``), along C, and round C (``perp x C``)."""
    round_c = _cross(head.perp, head.c_dir)
    return (fixture[:, 0, None] * head.perp + fixture[:, 1, None] * head.c_dir
            + fixture[:, 2, None] * round_c)


def _machine_points(setup: Setup, truth: Truth, rotary_error=None,
                    fixture=None) -> np.ndarray:
    """True global positions [mm] of the reflector, layout order.

    Without `rotary_error`: shape (n_machine_points, 3) at the commanded angles. With
    `rotary_error` (batch, 2 N points_per_arc) [rad], the actual minus commanded angle
    of every arc point (C then A for each sub-machine): shape (batch, n_machine_points, 3).
    `fixture` (batch, N, 3) [mm]: the reflector's position on its fixture off the stated
    one, per sub-machine (see :func:`_fixture_displacement`); it needs `rotary_error`.
    """
    lin = _linear_positions(setup)
    q = setup.points_per_arc
    c_ang = np.radians(_arc_angles(setup.c_arc_deg, q))
    a_ang = np.radians(_arc_angles(setup.a_arc_deg, q))
    err = np.zeros((1, 2 * setup.n_submachines * q)) if rotary_error is None else rotary_error
    batch = err.shape[0]
    out = []
    for k in range(setup.n_submachines):
        h = _head(setup, truth, k)
        if fixture is not None and np.any(fixture[:, k]):
            h = dataclasses.replace(h, reflector=h.reflector
                                    + _fixture_displacement(h, fixture[:, k]))
        e_c = err[:, 2 * k * q:(2 * k + 1) * q]
        e_a = err[:, (2 * k + 1) * q:(2 * k + 2) * q]
        for i, ax in enumerate(AXES):
            out.append(np.broadcast_to(h.reflector[..., None, :]
                                       + lin[ax][:, None] * h.axes[..., i, None, :],
                                       (batch, len(lin[ax]), 3)))
        for point, axis, ang, e_k in ((h.wrist, h.c_dir, c_ang, e_c),
                                      (h.a_point, h.a_dir, a_ang, e_a)):
            arm = (h.reflector - point)[..., None, :]
            out.append(point[..., None, :] + _mv(_rot(axis[..., None, :], ang + e_k), arm))
    pts = np.concatenate(out, axis=1)
    return pts[0] if rotary_error is None else pts


def _legendre(xi: np.ndarray) -> np.ndarray:
    """P2, P3, P4 at `xi` in [-1, 1]: array (3, len(xi)); each within [-1, 1]."""
    x2 = xi * xi
    return np.stack([(3 * x2 - 1) / 2, xi * (5 * x2 - 3) / 2, (35 * x2 * x2 - 30 * x2 + 3) / 8])


def _straightness(setup: Setup, truth: Truth, coef: np.ndarray) -> np.ndarray:
    """Straightness deviations of the linear-travel points (n, n_machine_points, 3) [mm].

    `coef` (n, N, 3, 2, 3): per sub-machine, axis and direction across the travel,
    the coefficients of P2, P3, P4 of the scaled position. The directions across
    the travel u are the next two nominal axes made orthogonal to u.
    """
    n = coef.shape[0]
    out = np.zeros((n, _n_points(setup) - 4, 3))
    if not np.any(coef):
        return out
    lin = _linear_positions(setup)
    sl = _slices(setup)
    e = np.eye(3)
    for k in range(setup.n_submachines):
        axes = _head(setup, truth, k).axes
        for i, ax in enumerate(AXES):
            u = axes[..., i, :]
            v1 = _unit(e[(i + 1) % 3] - np.sum(e[(i + 1) % 3] * u, axis=-1)[..., None] * u)
            across = np.broadcast_to(np.stack([v1, _cross(u, v1)], axis=-2), (n, 2, 3))
            t = lin[ax]
            shape = _legendre(t / t[-1])  # (3, P); travels are > 0
            dev = np.einsum("ndt,tp,ndj->npj", coef[:, k, i], shape, across)
            s = sl[(ax, k + 1)]
            out[:, s.start - 4:s.stop - 4] = dev
    return out


def _tracker_pose(setup: Setup, truth: Truth) -> tuple[np.ndarray, np.ndarray]:
    """(R (..., 3, 3), t (..., 3)): global = R @ tracker + t (arrays (m, ...) for a truth
    whose fields are arrays (m,))."""
    r = _rxyz(np.asarray(truth.tracker_tilt_x_urad) * 1e-6,
              np.asarray(truth.tracker_tilt_y_urad) * 1e-6, np.radians(truth.tracker_yaw_deg))
    d = np.stack(np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (
        truth.tracker_dx_um, truth.tracker_dy_um, truth.tracker_dz_um))), -1)
    t = np.array([-setup.tracker_distance_mm, 0.0, setup.tracker_height_mm]) + 1e-3 * d
    return r, t


# --------------------------------------------------------------------------- protocol
def measurands(setup: Setup) -> tuple[Measurand, ...]:
    """Ten measurands per sub-machine k = 1..N (see the module docstring)."""
    out = []
    for k in range(1, setup.n_submachines + 1):
        for ax in "xyz":
            out.append(Measurand(f"origin_{ax}_{k}", "um",
                                 f"Origin of sub-machine {k} minus nominal, global {ax.upper()}"))
        for ax in "xyz":
            out.append(Measurand(f"rot_{ax}_{k}", "urad",
                                 f"Orientation of sub-machine {k}'s frame about global "
                                 f"{ax.upper()} (R = Rz Ry Rx)"))
        out.append(Measurand(f"ac_offset_{k}", "um",
                             f"Signed A-C offset of sub-machine {k} (common perpendicular)"))
        for a, b in ("xy", "yz", "zx"):
            out.append(Measurand(f"sq_{a}{b}_{k}", "urad",
                                 f"Squareness {a.upper()}-{b.upper()} of sub-machine {k}: "
                                 f"90 deg minus the angle between the travels"))
    return tuple(out)


def _mpe(setup: Setup, mpe: float) -> Normal | Rectangular:
    if setup.mpe_model == "rectangular":
        return Rectangular(-mpe, mpe)
    return Normal(0.0, mpe / 2.0)


def sources(setup: Setup) -> dict[str, Source]:
    """Error sources (internal units: mm, or mm per mm for the length-proportional parts)."""
    n = _n_points(setup)
    m = n - 4
    q = 2 * setup.n_submachines * setup.points_per_arc
    spec = ("Default from a current tracker's ISO 10360-10 subsystem MPE (ADM 10 um + 0.3 um/m, "
            "transverse 15 um + 6 um/m); MPE converted by mpe_model.")
    return {
        "distance_fixed": Source(
            _mpe(setup, setup.distance_fixed_um * 1e-3), (n,),
            "Tracker distance error, constant part a of the MPE a + b L, per point [mm]. " + spec,
            field="distance_fixed_um"),
        "distance_per_length": Source(
            _mpe(setup, setup.distance_per_length_um_per_m * 1e-6), (n,),
            "Tracker distance error, part b of the MPE proportional to the distance, per point "
            "[mm/mm]. " + spec, field="distance_per_length_um_per_m"),
        "transverse_fixed": Source(
            _mpe(setup, setup.transverse_fixed_um * 1e-3), (n, 2),
            "Tracker error across the beam (horizontal, vertical), constant part c of the MPE "
            "c + d L, per point [mm]. " + spec, field="transverse_fixed_um"),
        "transverse_per_length": Source(
            _mpe(setup, setup.transverse_per_length_um_per_m * 1e-6), (n, 2),
            "Tracker error across the beam proportional to the distance (an angle error), "
            "its per-point share (angular repeatability: pointing, encoder interpolation, "
            "air turbulence), independent from point to point [rad]. Default 3 um/m, with "
            "angular_systematic's 5 um/m the AT960's d = 6 um/m in quadrature; "
            "converted by mpe_model.", field="transverse_per_length_um_per_m"),
        "angular_systematic": Source(
            _mpe(setup, setup.angular_systematic_um_per_m * 1e-6), (len(_SYSTEMATIC_WEIGHTS),),
            "Tracker angle error constant over the test (ASME B89.4.19 / ISO 10360-10 "
            "geometric model after Muralikrishnan et al., J. Res. NIST 114 (2009)): first and "
            "second harmonics of the horizontal encoder, collimation (beam tilt), trunnion "
            "tilt, vertical index and vertical encoder eccentricity, one coefficient each "
            "per test [rad], weighted so that the transverse error has this standard "
            "deviation in each direction across the beam (at level sight). A constant "
            "azimuth offset is left out: the registration on the marks absorbs it. Nearby "
            "points (a short arc) are displaced together. Default 5 um/m of the AT960's "
            "d = 6 um/m; converted by mpe_model.", field="angular_systematic_um_per_m"),
        "smr_centring": Source(
            _mpe(setup, setup.smr_centring_um * 1e-3), (n, 3),
            "Offset of the SMR's optical centre from its sphere's centre, along the beam and "
            "across it (horizontal, vertical), per point [mm]: the SMR is turned in its nest "
            "toward the tracker at each point (and reseated on every mark), so its centring "
            "error shows in a new direction each time. Default +-2.5 um, a precision-grade "
            "1.5 in SMR; converted by mpe_model.", field="smr_centring_um"),
        "air_refraction": Source(
            Normal(0.0, setup.air_refraction_ppm * 1e-6), (),
            "Scale error of every distance from the air's refractive index, one per test "
            "[1]: -0.93 ppm/K, +0.27 ppm/hPa (Edlen); default 1 ppm from the weather "
            "station's +-0.3 K, +-1 hPa and about 1 K between the station and the beam path.",
            field="air_refraction_ppm"),
        "thermal_drift": Source(
            Normal(0.0, setup.thermal_drift_um_per_s * 1e-3), (3,),
            "Drift rate (global X, Y, Z) of the tracker against the machine during the test, "
            "one per test [mm/s]: every point moves by rate x its time from the start "
            "(_times: marks first, then each sub-machine). Default 0.003 um/s (11 um/h): a "
            "1.5 m steel tripod grows 17 um per K, a hall changes 0.5-1 K/h.",
            field="thermal_drift_um_per_s"),
        "straightness": Source(
            Rectangular(-setup.straightness_um * 1e-3 / 4, setup.straightness_um * 1e-3 / 4),
            (setup.n_submachines, 3, 2, 3),
            "Straightness deviation of each linear travel (sub-machine, axis X/Y/Z, two "
            "directions across it), one per test [mm]: coefficients of the Legendre "
            "polynomials P2, P3, P4 of the position scaled to -1..1 (orthogonal to the "
            "reference straight line, whose direction is the measurand), each uniform in "
            "+-straightness/4, so the deviation stays within about the tolerance. Only the "
            "sampling of the travel at points_per_axis points lets it tilt the fitted line "
            "(P3 at the ends). Default 10 um.", field="straightness_um"),
        "machine_repeatability": Source(
            Normal(0.0, setup.machine_repeatability_um * 1e-3), (m, 3),
            "Scatter of the machine's positioning at each measured point, each global axis "
            "[mm]. Default 2 um: an ISO 230-2 unidirectional repeatability of about 8 um "
            "(4 s) for large gantry axes.", field="machine_repeatability_um"),
        "reflector_fixture": Source(
            Rectangular(-setup.reflector_fixture_um * 1e-3, setup.reflector_fixture_um * 1e-3),
            (setup.n_submachines, 3),
            "Position of the reflector on its fixture off the stated one (reflector_offset_mm "
            "from the C axis, at the tool tip), one per sub-machine (the fixture is mounted "
            "on each), in the head's directions: across C away from it, along C, round C "
            "[mm]. The circle fits leave the radius free, so the estimators are blind to it; "
            "a model that took the offset as exact would know the radii of the C and A "
            "circles and so where their axes lie across a short arc. Default +-50 um "
            "(rectangular) for an uncalibrated fixture: arm machined to +-50 um, the nest's "
            "height to +-50 um, the spindle's orientation stop +-0.02 deg at 150 mm.",
            field="reflector_fixture_um"),
        **_thermal_sources(setup),
        "rotary_positioning": Source(
            Normal(0.0, setup.rotary_positioning_arcsec * math.pi / 648000), (q,),
            "Angular positioning error of the A and C axes at each arc point (actual minus "
            "commanded angle), independent from point to point [rad]: the reflector stands "
            "at the actual angle, the readings report the commanded one. Default 5 arcsec "
            "(standard deviation): an ISO 230-2 bidirectional positioning accuracy of about "
            "20 arcsec (+-2 s) for the rotary axes of the swivel heads of such gantries.",
            field="rotary_positioning_arcsec"),
    }


def _thermal_sources(setup: Setup) -> dict[str, Source]:
    """The structure's temperature and the air's gradient, measured or assumed
    (:mod:`mtplan.models._temperature`), and the structure's expansion coefficient."""
    return {
        **temperature.temperature_sources(
            setup, "structure_temperature",
            measured="Error of the measured structure temperature as the mean temperature of "
            "the bed and gantry [K]; the frames are corrected to 20 degC with "
            "structure_temperature_c. Default 0.3 K: calibrated sensors (0.1 K) on a structure "
            "that is not isothermal (ISO/TR 16015).",
            assumed="Temperature of the bed and gantry minus 20 degC when it is not measured, "
            "one per test [K], uniform within +-structure_temperature_halfwidth_k: the marks' "
            "coordinates are stated at 20 degC (ISO 1), the structure and everything on it "
            "stand expanded by structure_expansion_ppm_per_k x dT about the marks' centroid, "
            "and the registration on the stated marks keeps that scale: a sub-machine 1 m from "
            "the centroid moves by 13 um at the default (11.5e-6/K x 1 m x 1.15 K). Default "
            "+-2 K: a machine hall held at 20 +- 2 degC; nothing is corrected."),
        "structure_expansion_u": Source(
            Normal(0.0, setup.structure_expansion_u_ppm_per_k * 1e-6), (),
            "Error of the structure's expansion coefficient [1/K]: it acts times the "
            "measured T - 20 degC, by the distance from the marks' centroid. Default 1e-6/K: "
            "steels and cast irons span 10-12.5e-6/K (ISO/TR 16015).",
            field="structure_expansion_u_ppm_per_k"),
        **temperature.gradient_sources(
            setup, "air_gradient",
            measured="Error of the measured vertical gradient of the air's temperature as its "
            "mean along the beams [K/m]; the elevations are corrected with "
            "air_gradient_k_per_m. Default 0.2 K/m: two thermometers of 0.1 K a metre apart "
            "and the gradient's change along the hall.",
            assumed="Vertical gradient G of the air's temperature when it is not measured, one "
            "per test [K/m], uniform between 0 and air_gradient_range_k_per_m: warm air lies "
            "above, so its mean is signed (+0.5 K/m at the default) and biases the simulated "
            "estimates (estimate's bias correction removes the mean). The refractive index "
            "falls by 0.93 ppm/K (Edlen), so a beam bends with curvature 0.93e-6 G per metre "
            "and the tracker sees a target at horizontal distance D raised by 0.93e-6 G D^2 / "
            "2 (7.4 um at 4 m for 1 K/m). Default 1 K/m: halls without displacement "
            "ventilation stratify by 0.5-1 K/m (Estler et al., Large-scale metrology - an "
            "update, CIRP Annals 51/2, 2002)."),
        **temperature.horizontal_gradient_sources(
            setup, "air_gradient",
            measured="Error of the measured horizontal gradient of the air's temperature "
            "along the tracker's {axis} axis, as its mean along the beams [K/m]; the azimuths "
            "are corrected with air_gradient_x_k_per_m and air_gradient_y_k_per_m. Default "
            "0.1 K/m.",
            assumed="Horizontal gradient of the air's temperature along the tracker's {axis} "
            "axis when it is not measured, one per test [K/m], uniform within "
            "+-air_gradient_horizontal_range_k_per_m: nothing says which side is warm. The "
            "component G across a beam swerves it sideways as the vertical gradient bends it: "
            "the target at distance D is seen moved towards the warm side by 0.93e-6 G D^2 / 2 "
            "(0.74 um at 4 m for 0.1 K/m). Default 0.1 K/m: a hall without heaters, open doors "
            "or sun on one side."),
    }


#: weights of the per-test angle-error terms (horizontal: encoder 1st and 2nd harmonic,
#: collimation, trunnion tilt; vertical: index, encoder eccentricity) so that the
#: transverse error has the source's standard deviation in each direction at level sight
_SYSTEMATIC_WEIGHTS = np.array([3**-0.5] * 5 + [1.0] + [2**-0.5] * 3)


def _systematic_angles(coef: np.ndarray, az: np.ndarray, el: np.ndarray):
    """Azimuth and elevation errors (n, points) [rad] of the per-test terms `coef` (n, 9).

    Horizontal: ``c0 cos az + c1 sin az + c2 cos 2az + c3 sin 2az`` (encoder
    harmonics), ``c4 / cos el`` (collimation: the beam off square to the trunnion
    axis), ``c5 tan el`` (trunnion axis out of square to the standing axis).
    Vertical: ``c6 + c7 cos el + c8 sin el`` (index offset, encoder eccentricity).
    """
    c = (coef * _SYSTEMATIC_WEIGHTS)[:, :, None]
    cos_el = np.cos(el)
    daz = (c[:, 0] * np.cos(az) + c[:, 1] * np.sin(az) + c[:, 2] * np.cos(2 * az)
           + c[:, 3] * np.sin(2 * az) + c[:, 4] / cos_el + c[:, 5] * np.tan(el))
    d_el = c[:, 6] + c[:, 7] * cos_el + c[:, 8] * np.sin(el)
    return daz, d_el


def forward(setup: Setup, truth: Truth, errors: dict) -> Readings:
    """Tracker readings (distance [mm], azimuth [rad], elevation [rad]), shape (n, points)."""
    marks = _marks(setup)
    rep = np.asarray(errors["machine_repeatability"])
    batch = rep.shape[0]
    mach = _machine_points(setup, truth, np.asarray(errors["rotary_positioning"]),
                           np.asarray(errors["reflector_fixture"]))
    mach = mach + rep + _straightness(setup, truth, np.asarray(errors["straightness"]))
    pts = np.concatenate([np.broadcast_to(marks, (batch, 4, 3)), mach], axis=1)
    rate = np.asarray(errors["thermal_drift"])
    if np.any(rate):
        pts = pts + rate[:, None, :] * _times(setup)[0][:, None]
    dt_ref = temperature.deviation(setup, "structure_temperature")

    def e(name):
        return np.asarray(errors[name], dtype=float).reshape(-1, 1, 1)

    grow = ((setup.structure_expansion_ppm_per_k * 1e-6 + e("structure_expansion_u"))
            * (dt_ref + e("structure_temperature_u") + e("structure_temperature_halfwidth")))
    if np.any(grow):  # the structure at 20 degC + dT, about the marks' centroid
        pts = pts + grow * (pts - marks.mean(axis=0))
    r, t = _tracker_pose(setup, truth)
    v = (pts - t[..., None, :]) @ r  # tracker-frame coordinates: R^T (p - t), row vectors
    horiz = np.hypot(v[..., 0], v[..., 1])
    d = np.linalg.norm(v, axis=-1)
    az = np.arctan2(v[..., 1], v[..., 0])
    el = np.arctan2(v[..., 2], horiz)
    tf = np.asarray(errors["transverse_fixed"])
    tl = np.asarray(errors["transverse_per_length"])
    smr = np.asarray(errors["smr_centring"])
    scale = 1.0 + np.asarray(errors["air_refraction"])[..., None]
    dist = (d + errors["distance_fixed"] + errors["distance_per_length"] * d) * scale
    dist = dist + smr[..., 0]
    daz = (tf[..., 0] / d + tl[..., 0] + smr[..., 1] / d) * d / horiz
    d_el = tf[..., 1] / d + tl[..., 1] + smr[..., 2] / d
    grad = (temperature.gradient(setup, "air_gradient") + e("air_gradient_u")
            + e("air_gradient_range")).reshape(-1, 1)
    if np.any(grad):  # beam bending: the target seen raised by 0.93e-6 G D^2 / 2
        d_el = d_el + temperature.bending(grad, horiz)
    gx0, gy0 = temperature.horizontal_gradient(setup, "air_gradient")
    gx = (gx0 + e("air_gradient_x_u") + e("air_gradient_x_range")).reshape(-1, 1)
    gy = (gy0 + e("air_gradient_y_u") + e("air_gradient_y_range")).reshape(-1, 1)
    if np.any(gx) or np.any(gy):  # sideways: towards the warm side, by the same law
        daz = daz + temperature.swerve(gx, gy, az, d, horiz)
    sys = np.asarray(errors["angular_systematic"])
    if np.any(sys):
        s_az, s_el = _systematic_angles(sys, az, el)
        daz, d_el = daz + s_az, d_el + s_el
    return Readings({"distance_mm": dist, "azimuth_rad": az + daz, "elevation_rad": el + d_el})


def true_values(setup: Setup, truth: Truth) -> dict[str, float]:
    """The patent's construction applied to the true geometry [mm, rad]."""
    nominal = _nominal_origins(setup)
    out = {}
    for k in range(setup.n_submachines):
        h = _head(setup, truth, k)
        o = h.origin - nominal[k]
        ux, uy, uz = (h.axes[..., i, :] for i in range(3))
        rx, ry, rz = _angles(_orthonormal(setup, ux, uy, uz))
        name = k + 1
        out.update({
            f"origin_x_{name}": o[..., 0], f"origin_y_{name}": o[..., 1],
            f"origin_z_{name}": o[..., 2],
            f"rot_x_{name}": rx, f"rot_y_{name}": ry, f"rot_z_{name}": rz,
            f"ac_offset_{name}": h.offset,
            f"sq_xy_{name}": np.arcsin(np.sum(ux * uy, axis=-1)),
            f"sq_yz_{name}": np.arcsin(np.sum(uy * uz, axis=-1)),
            f"sq_zx_{name}": np.arcsin(np.sum(uz * ux, axis=-1)),
        })
    # floats for one truth; arrays (m,) for one truth per batch row
    return {k: (float(v) if np.ndim(v) == 0 else v) for k, v in out.items()}


def truth_from_estimate(setup: Setup, estimate: dict) -> Truth:
    """A Truth whose measurands equal `estimate` (first trial; internal units mm, rad).

    The head's tilts are set to zero (A and C then lie along the frame's X and Z
    axes), the pivot-length error to zero and the tracker at its defaults; the
    squareness, A-C offset, frame rotation and wrist centre follow from the estimate
    exactly: the frame is the construction applied to the local axes, rotated.
    """
    first = {k: np.asarray(v, dtype=float).ravel()[:1] for k, v in estimate.items()}
    fields = _head_rows(setup, first)
    return Truth(**{**_ZERO_HEAD, **{k: tuple(float(x[0]) for x in v)
                                     for k, v in fields.items()}})


def truths_from_estimates(setup: Setup, estimates: dict) -> Truth:
    """:func:`truth_from_estimate` of every row of `estimates` (measurand -> array (m,)):
    a batch of truths (``Truth.batch``) whose head fields are tuples of arrays (m,), one
    truth per batch row of :func:`forward` (not validated: the values are those of valid
    estimates)."""
    fields = _head_rows(setup, {k: np.asarray(v, dtype=float).ravel()
                                for k, v in estimates.items()})
    return Truth.batch(Truth(**_ZERO_HEAD), **{k: tuple(v) for k, v in fields.items()})


#: the head fields :func:`truth_from_estimate` holds at zero (tilts, pivot-length error)
_ZERO_HEAD = {f: (0.0,) for f in ("c_tilt_x_urad", "c_tilt_y_urad", "a_tilt_y_urad",
                                   "a_tilt_z_urad", "pivot_length_error_um")}


def _head_rows(setup: Setup, est: dict) -> dict[str, list]:
    """The head fields of :func:`truth_from_estimate` for estimates (m,) per measurand:
    field -> one array (m,) per sub-machine."""
    fields: dict[str, list] = {name: [] for name in (
        "wrist_dx_um", "wrist_dy_um", "wrist_dz_um", "frame_rx_urad", "frame_ry_urad",
        "frame_rz_urad", "sq_xy_urad", "sq_yz_urad", "sq_zx_urad", "ac_offset_um")}
    for k in range(1, setup.n_submachines + 1):
        sq = {ab: est[f"sq_{ab}_{k}"] for ab in ("xy", "yz", "zx")}
        # the frame of the local axes (the head untilted, the frame unrotated)
        r_loc = _orthonormal(setup, *np.moveaxis(_travel_axes(
            *(sq[ab] * 1e6 * 1e-6 for ab in ("xy", "yz", "zx"))), -2, 0))
        r_est = _rxyz(est[f"rot_x_{k}"], est[f"rot_y_{k}"], est[f"rot_z_{k}"])
        rx, ry, rz = _angles(r_est @ np.swapaxes(r_loc, -1, -2))
        c_dir = _rxyz(rx, ry, rz)[..., :, 2]
        o = np.stack([est[f"origin_{a}_{k}"] for a in "xyz"], axis=-1)
        wrist = o + setup.pivot_length_mm * (c_dir - np.array([0.0, 0.0, 1.0]))
        for name, value in (("wrist_dx_um", wrist[..., 0] * 1e3),
                            ("wrist_dy_um", wrist[..., 1] * 1e3),
                            ("wrist_dz_um", wrist[..., 2] * 1e3), ("frame_rx_urad", rx * 1e6),
                            ("frame_ry_urad", ry * 1e6), ("frame_rz_urad", rz * 1e6),
                            ("sq_xy_urad", sq["xy"] * 1e6), ("sq_yz_urad", sq["yz"] * 1e6),
                            ("sq_zx_urad", sq["zx"] * 1e6),
                            ("ac_offset_um", est[f"ac_offset_{k}"] * 1e3)):
            fields[name].append(value)
    return fields
