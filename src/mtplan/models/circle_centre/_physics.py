"""circle_centre's physics: the error sources, the bore's wall at the test's temperature, the
probe's contacts and triggers, the stage's read and actual frames, and the forward model from
the start point along the planned path to the read points; the measurands, their true values
and the truths that reproduce an estimate or the readings' start.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from mtplan._validate import Problems
from mtplan.models import _temperature as temperature
from mtplan.models.circle_centre._path import n_contacts as _n_contacts, plan_core as _plan_core
from mtplan.models.circle_centre._setup import (
    DEG as _DEG,
    Setup,
    Truth,
    reference_deviations as _reference_deviations,
)
from mtplan.models.protocol import Measurand, Readings, Source
from mtplan.uncertainty import Normal, Rectangular


def measurands(setup: Setup) -> tuple[Measurand, ...]:
    return (
        Measurand("centre_x", "um", "x of the bore centre from its nominal position"),
        Measurand("centre_y", "um", "y of the bore centre from its nominal position"),
        Measurand("radius", "um", "bore radius minus the nominal radius"),
    )


def true_values(setup: Setup, truth: Truth) -> dict:
    return {"centre_x": truth.centre_x_mm, "centre_y": truth.centre_y_mm,
            "radius": truth.radius_deviation_mm}


def sources(setup: Setup) -> dict[str, Source]:
    """Every error source, in internal units (mm, rad, 1)."""
    k = _n_contacts(setup)
    slip = setup.tangential_slip_um_per_deg * 1e-3 / _DEG  # mm per rad
    scale = setup.scale_error_ppm * 1e-6
    sq = setup.squareness_urad * 1e-6
    s = setup.start_scatter_mm
    return {
        "probe_noise": Source(
            Normal(0.0, setup.probe_noise_um * 1e-3), (k,),
            "Trigger noise of the touch probe along the approach, per contact; 0.5 um std is "
            "typical of a kinematic probe on a CNC skip input (makers quote 0.35-1 um 2 sigma "
            "unidirectional repeatability).", field="probe_noise_um"),
        "pretravel_variation": Source(
            Normal(0.0, setup.pretravel_variation_um * 1e-3 / math.sqrt(2)), (2,),
            "Coefficients (cos 3b, sin 3b) of the three-lobed pre-travel variation with the "
            "approach direction b, constant during the test (RMS amplitude 1 um: makers quote "
            "+-0.8 to +-2 um XY pre-travel variation for kinematic probes after calibration).",
            field="pretravel_variation_um"),
        "tangential_slip": Source(
            Rectangular(0.0, 2 * slip), (),
            "Slip of the stylus along the wall per radian of obliqueness of the approach, "
            "uniform between 0 and twice the set mean, constant during the test (assumed "
            "0.2 um/deg: no maker's figure; measure it for the probe in use).",
            field="tangential_slip_um_per_deg"),
        "roundness": Source(
            Normal(0.0, setup.roundness_um * 1e-3 / 2 / math.sqrt(2)), (2,),
            "Coefficients (cos k phi, sin k phi) of the bore's lobed form error, k = lobes; "
            "random orientation, RMS peak-to-valley = roundness_um (5 um: a large turned ring).",
            field="roundness_um"),
        "scale_error": Source(
            Rectangular(-scale, scale), (2,),
            "Residual scale (linear positioning) error of the stage's X and Y axes after "
            "compensation; +-5 um/m is typical of ISO 230-2 results of a large stage.",
            field="scale_error_ppm"),
        "squareness": Source(
            Rectangular(-sq, sq), (),
            "X-Y squareness error of the stage (ISO 230-1; +-10 urad typical).",
            field="squareness_urad"),
        "stage_repeatability": Source(
            Normal(0.0, setup.stage_repeatability_um * 1e-3), (k, 2),
            "Positioning repeatability of the stage, per reading and axis (ISO 230-2 "
            "unidirectional repeatability of about 1 um = 2 sigma).",
            field="stage_repeatability_um"),
        "start_scatter": Source(
            Rectangular(-s, s), (2,),
            "Where the operator lowers the probe: uniform within +-25 mm per axis of the "
            "truth's start point (by eye, near the nominal centre).", field="start_scatter_mm"),
        "tip_radius": Source(
            Normal(0.0, setup.tip_radius_um * 1e-3), (),
            "Error of the calibrated effective tip radius, one per test: every recorded point "
            "lies that far beyond the wall along its approach. 0.5 um std: the radius is "
            "calibrated on a setting ring (ISO 1938-1) known to about 1 um in diameter.",
            field="tip_radius_um"),
        **_thermal_sources(setup),
    }


def _thermal_sources(setup: Setup) -> dict[str, Source]:
    """The temperatures' sources, measured or assumed (:mod:`mtplan.models._temperature`: each
    the actual value minus the one the estimators correct with, so zero-mean), and the
    expansion coefficients'."""
    return {
        **temperature.temperature_sources(
            setup, "part_temperature",
            measured="Error of the measured part temperature [K]: the part is at "
            "part_temperature_c plus this, and the estimates are corrected to 20 degC (ISO 1) "
            "with part_temperature_c. Default 0.2 K: a calibrated contact thermometer on a "
            "soaked part (ISO/TR 16015). The bore grows about the part's clamping point by "
            "expansion_ppm_per_k x dT; when the scales' temperature is not measured they "
            "follow the part's.",
            assumed="The part's temperature minus 20 degC [K] when it is not measured, uniform "
            "within +-part_temperature_halfwidth_k (default +-2 K: a workshop held at 20 +- 2 "
            "degC, ISO 1's reference temperature); nothing is corrected. The bore grows about "
            "the clamping point by expansion_ppm_per_k (11.5e-6/K: steel); the scales share "
            "this temperature (plus scale_temperature_halfwidth) and shrink their reading "
            "about their datum by scale_expansion_ppm_per_k (10e-6/K: the coefficient "
            "HEIDENHAIN states for its steel-mounted linear scales), so the radius reads r "
            "(alpha_part - alpha_scale) dT off and the centre alpha_scale dT times its offset "
            "from the scales' datum (a datum 300 mm away: 300 mm x 10e-6/K x 1.15 K = 3.5 "
            "um per axis at the default +-2 K; none with the default datum at the bore)."),
        **temperature.temperature_sources(
            setup, "scale_temperature",
            measured="Error of the measured scale temperature [K]; default 0.2 K. The scales "
            "read every length from their datum times 1 - scale_expansion_ppm_per_k x "
            "dT_scale.",
            assumed="The machine scales' temperature minus the part's [K] when it is not "
            "measured, uniform within +-scale_temperature_halfwidth_k. Default +-1 K: a part "
            "soaked on the machine for hours (ISO/TR 16015 advises soaking until part and "
            "machine agree within a kelvin); a part that arrives from a warmer hall needs "
            "more. The scales read lengths from their datum (scale_datum_x_mm, "
            "scale_datum_y_mm) times 1 - scale_expansion_ppm_per_k x dT_scale: the radius, "
            "and the centre by that strain times its offset from the datum (300 mm x "
            "10e-6/K x 0.58 K = 1.7 um)."),
        "expansion_u": Source(
            Normal(0.0, setup.expansion_u_ppm_per_k * 1e-6), (),
            "Error of the workpiece's expansion coefficient [1/K]: it moves the corrected "
            "result by u(alpha) x (T_part - 20 degC) x the length from the clamping point. "
            "Default 1e-6/K: steels span 10.5-12.5e-6/K (ISO/TR 16015).",
            field="expansion_u_ppm_per_k"),
        "scale_expansion_u": Source(
            Normal(0.0, setup.scale_expansion_u_ppm_per_k * 1e-6), (),
            "Error of the scales' effective expansion coefficient [1/K]: u(alpha) x "
            "(T_scale - 20 degC) x the length from the datum. Default 0.5e-6/K: a scale "
            "mounted on steel follows its mounting (10-11.5e-6/K).",
            field="scale_expansion_u_ppm_per_k"),
    }


def _thermal(setup: Setup, errors: dict, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The actual thermal strains (n,) of the part (about its clamping point) and of the
    scales (about their datum): alpha (T - 20 degC) with the actual alphas and temperatures."""
    def e(name):
        return np.asarray(errors[name], dtype=float).reshape(n)

    dtp_ref, dts_ref = _reference_deviations(setup)
    dtp = dtp_ref + e("part_temperature_u") + e("part_temperature_halfwidth")
    if setup.scale_temperature_c is None:  # the scales follow the part's actual temperature
        dts = dtp + e("scale_temperature_halfwidth") + e("scale_temperature_u")
    else:
        dts = dts_ref + e("scale_temperature_u") + e("scale_temperature_halfwidth")
    part = (setup.expansion_ppm_per_k * 1e-6 + e("expansion_u")) * dtp
    scale = (setup.scale_expansion_ppm_per_k * 1e-6 + e("scale_expansion_u")) * dts
    return part, scale


def scale_datum(setup: Setup) -> np.ndarray:
    return np.array([setup.scale_datum_x_mm, setup.scale_datum_y_mm])


def clamp_point(setup: Setup) -> np.ndarray:
    return np.array([setup.clamp_x_mm, setup.clamp_y_mm])


# --------------------------------------------------------------------------- geometry
def _wall(setup, truth, errors, n, part_strain):
    """True centre (n,2), radius (n,), form coefficients (n,2), lobes.

    The bore at the test's temperature: the 20 degC bore scaled by ``1 + part_strain``
    about the part's clamping point (its form error is left at its 20 degC size, a
    change of 1e-5 of a few micrometres). Truth fields may be arrays (n,): one truth per
    batch row (a posterior's walkers).
    """
    grow = 1.0 + np.reshape(part_strain, (n, 1))
    k = clamp_point(setup)
    centre = k + (np.broadcast_to(_xy_of(truth.centre_x_mm, truth.centre_y_mm), (n, 2)) - k) * grow
    radius = (setup.bore_radius_mm + np.asarray(truth.radius_deviation_mm)) * grow[:, 0]
    form = np.asarray(errors["roundness"], dtype=float).reshape(n, 2)
    return centre, radius, form, setup.lobes


def _contact(origin, direction, centre, radius, form, lobes, iterations: int = 4):
    """Where lines from `origin` along unit `direction` meet the wall (t > 0).

    Parameters
    ----------
    origin, direction : array (n, k, 2)
        Actual (not read) start points and unit directions of the approach lines.
    centre : array (n, 2); radius : array (n,); form : array (n, 2); lobes : int

    Returns
    -------
    contact : array (n, k, 2)
    normal : array (n, k, 2)
        Outward unit normal of the wall at the contact.

    Notes
    -----
    The line meets the circle of the mean radius first (closed form); Newton's method
    on ``g(t) = |q(t) - c| - rho(phi(q(t)))`` then adds the form error, with
    ``g' = e_r . u - rho'(phi) (e_r x u) / |q - c|``. The start is off by at most the
    form amplitude, so four iterations reach machine precision.
    """
    wx = origin[..., 0] - centre[:, None, 0]
    wy = origin[..., 1] - centre[:, None, 1]
    ux, uy = direction[..., 0], direction[..., 1]
    a, b = form[:, 0:1], form[:, 1:2]
    r0 = radius[:, None]
    wu = wx * ux + wy * uy
    t = -wu + np.sqrt(np.maximum(wu * wu - (wx * wx + wy * wy - r0 * r0), 0.0))
    has_form = bool(np.any(form))
    for _ in range(iterations if has_form else 0):
        qx, qy = wx + t * ux, wy + t * uy
        dist = np.hypot(qx, qy)
        phi = np.arctan2(qy, qx)
        ck, sk = np.cos(lobes * phi), np.sin(lobes * phi)
        rho = r0 + a * ck + b * sk
        drho = lobes * (b * ck - a * sk)
        dg = (qx * ux + qy * uy) / dist - drho * (qx * uy - qy * ux) / (dist * dist)
        t = t - (dist - rho) / dg
    qx, qy = wx + t * ux, wy + t * uy
    dist = np.hypot(qx, qy)
    erx, ery = qx / dist, qy / dist
    if has_form:
        phi = np.arctan2(qy, qx)
        ck, sk = np.cos(lobes * phi), np.sin(lobes * phi)
        rho = r0 + a * ck + b * sk
        drho = lobes * (b * ck - a * sk)
        nx, ny = rho * erx + drho * ery, rho * ery - drho * erx  # rho e_r - rho' e_phi
        norm = np.hypot(nx, ny)
        nx, ny = nx / norm, ny / norm
    else:
        nx, ny = erx, ery
    contact = np.stack([qx + centre[:, None, 0], qy + centre[:, None, 1]], axis=-1)
    return contact, np.stack([nx, ny], axis=-1)


def _inside(point, centre, radius, form, lobes):
    """Whether actual points (n, 2) lie strictly inside the wall."""
    q = point - centre
    phi = np.arctan2(q[:, 1], q[:, 0])
    rho = radius + form[:, 0] * np.cos(lobes * phi) + form[:, 1] * np.sin(lobes * phi)
    return np.hypot(q[:, 0], q[:, 1]) < rho


def _free_direction(contact_p2, centre, radius, form, lobes, test_mm, mx):
    """+1 / -1 / 0: which of the trial moves +-test_mm (read x) from p2 stays inside."""
    ex = mx / np.linalg.norm(mx, axis=-1, keepdims=True)  # actual direction of read +x
    plus = _inside(contact_p2 + test_mm * ex, centre, radius, form, lobes)
    minus = _inside(contact_p2 - test_mm * ex, centre, radius, form, lobes)
    return np.where(plus & ~minus, 1.0, np.where(minus & ~plus, -1.0, 0.0))


def _probe(setup, errors, contact, normal, direction, idx):
    """Stylus position at trigger (actual frame): contact + (pre-travel + noise + tip-radius
    error) along the approach + slip along the wall."""
    n = contact.shape[0]
    noise = np.asarray(errors["probe_noise"], dtype=float).reshape(n, -1)[:, idx]
    pre = np.asarray(errors["pretravel_variation"], dtype=float).reshape(n, 2)
    tip = np.asarray(errors["tip_radius"], dtype=float).reshape(n, 1)
    ux, uy = direction[..., 0], direction[..., 1]
    nx, ny = normal[..., 0], normal[..., 1]
    # cos 3b, sin 3b of the approach angle b from the unit vector (triple-angle formulas)
    c3 = ux * (4 * ux * ux - 3)
    s3 = uy * (3 - 4 * uy * uy)
    # the controller compensates the stylus centre by the calibrated tip radius along
    # the approach: a radius calibrated too large by `tip` records the point beyond the wall
    along = noise + pre[:, 0:1] * c3 + pre[:, 1:2] * s3 + tip
    # signed angle from the outward normal to the approach; slip along the tangent (-ny, nx)
    slip_c = np.asarray(errors["tangential_slip"], dtype=float).reshape(n, 1)
    slip = slip_c * np.arctan2(nx * uy - ny * ux, nx * ux + ny * uy) if np.any(slip_c) else 0.0
    return np.stack([contact[..., 0] + along * ux - slip * ny,
                     contact[..., 1] + along * uy + slip * nx], axis=-1)


def _stage(errors, n, thermal=0.0):
    """M (n,2,2): actual = M @ read, and its inverse; `thermal` (n,) is the scales' thermal
    strain, added to both axes' scale errors."""
    sc = np.asarray(errors["scale_error"], dtype=float).reshape(n, 2) + np.reshape(thermal,
                                                                                  (-1, 1))
    sq = np.asarray(errors["squareness"], dtype=float).reshape(n)
    m = np.zeros((n, 2, 2))
    m[:, 0, 0] = 1 + sc[:, 0]
    m[:, 0, 1] = sq
    m[:, 1, 1] = 1 + sc[:, 1]
    minv = np.zeros_like(m)
    minv[:, 0, 0] = 1 / m[:, 0, 0]
    minv[:, 1, 1] = 1 / m[:, 1, 1]
    minv[:, 0, 1] = -m[:, 0, 1] / (m[:, 0, 0] * m[:, 1, 1])
    return m, minv


def _xy_of(x, y) -> np.ndarray:
    """Points (2,) or, for arrays (n,) of one truth per batch row, (n, 2)."""
    return np.stack(np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float)),
                    axis=-1)


def _check_start(setup: Setup, truth: Truth) -> None:
    r_true = setup.bore_radius_mm + np.asarray(truth.radius_deviation_mm)
    reach = np.hypot(np.asarray(truth.start_x_mm) - truth.centre_x_mm,
                     np.asarray(truth.start_y_mm) - truth.centre_y_mm)
    reach = reach + setup.start_scatter_mm * math.sqrt(2) + setup.roundness_um * 1e-3 * 4
    bad = ~(reach < r_true - setup.free_test_mm)
    if np.any(bad):
        i = int(np.flatnonzero(np.ravel(bad))[0])

        def first(v):
            return float(np.ravel(v)[i % np.size(v)])

        p = Problems("circle_centre truth")
        p.add_text(
            f"The start point (start_x_mm={first(truth.start_x_mm):g}, start_y_mm="
            f"{first(truth.start_y_mm):g}) with its scatter start_scatter_mm="
            f"{setup.start_scatter_mm:g} reaches {first(reach):g} mm from the true centre, "
            f"outside the bore of radius {first(r_true):g} mm: the probe must start inside the "
            "bore")
        p.raise_if_any()


def forward(setup: Setup, truth: Truth, errors: dict) -> Readings:
    """Simulated readings, batch-first (see the module docstring).

    Returns
    -------
    dict
        ``x_mm``, ``y_mm``: arrays (n, n_points), the read coordinates of d1..dn;
        ``p_x_mm``, ``p_y_mm``: arrays (n, 2), the read coordinates of p1 and p2.
    """
    _check_start(setup, truth)
    n = np.asarray(errors["probe_noise"]).shape[0]
    part_strain, scale_strain = _thermal(setup, errors, n)
    centre, radius, form, lobes = _wall(setup, truth, errors, n, part_strain)
    m, minv = _stage(errors, n, scale_strain)
    datum = scale_datum(setup)
    rep = np.asarray(errors["stage_repeatability"], dtype=float).reshape(n, -1, 2)

    def apply(mat, q):  # (n, 2, 2) @ (n, k, 2), written out: faster than einsum
        x, y = q[..., 0], q[..., 1]
        return np.stack([mat[:, 0, 0, None] * x + mat[:, 0, 1, None] * y,
                         mat[:, 1, 0, None] * x + mat[:, 1, 1, None] * y], axis=-1)

    def to_actual(q):  # read -> actual: the scales grow (and err) about their datum
        return datum + apply(m, q - datum)

    def to_read(q):
        return datum + apply(minv, q - datum)

    start = _xy_of(truth.start_x_mm, truth.start_y_mm) + np.asarray(
        errors["start_scatter"], dtype=float).reshape(n, 2)
    # p1 along -y, p2 along +y (read frame), from the start
    dirs_read = np.broadcast_to(np.array([[0.0, -1.0], [0.0, 1.0]]), (n, 2, 2))
    origin = to_actual(np.broadcast_to(start[:, None, :], (n, 2, 2)))
    dirs = apply(m, dirs_read)  # a direction: no datum
    dirs = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    cp, nrm = _contact(origin, dirs, centre, radius, form, lobes)
    stylus = _probe(setup, errors, cp, nrm, dirs, slice(0, 2))
    p_read = to_read(stylus) + rep[:, 0:2]
    free = _free_direction(cp[:, 1], centre, radius, form, lobes, setup.free_test_mm, m[:, :, 0])
    plan = _plan_core(p_read[:, 0], p_read[:, 1], setup.bore_radius_mm, free,
                      setup.n_points, setup.spread_deg)
    u_read = np.stack([np.cos(plan["alpha"]), np.sin(plan["alpha"])], axis=-1)
    o_read = np.broadcast_to(plan["centre"][:, None, :], u_read.shape)
    origin = to_actual(o_read)
    dirs = apply(m, u_read)
    dirs = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    cd, nrm = _contact(origin, dirs, centre, radius, form, lobes)
    stylus = _probe(setup, errors, cd, nrm, dirs, slice(2, None))
    d_read = to_read(stylus) + rep[:, 2:]
    return Readings({"x_mm": d_read[..., 0], "y_mm": d_read[..., 1],
                     "p_x_mm": p_read[..., 0], "p_y_mm": p_read[..., 1]})


def truth_from_estimate(setup: Setup, estimate: dict) -> Truth:
    """The Truth whose centre and radius equal `estimate` [mm]; the nominal start point is
    put at that centre (where an operator lowers the probe), so it lies inside the bore."""
    def first(v):
        return float(np.asarray(v).ravel()[0])

    cx, cy = first(estimate["centre_x"]), first(estimate["centre_y"])
    return Truth(centre_x_mm=cx, centre_y_mm=cy, radius_deviation_mm=first(estimate["radius"]),
                 start_x_mm=cx, start_y_mm=cy)


def start_from_readings(setup: Setup, readings: dict, truth: Truth) -> Truth:
    """`truth` with its start point's x where the readings put it: p1 and p2 are probed
    along -y and +y from the start, so their read x is the start's (the start's y moves no
    reading and stays). A least squares started from the bore's centre instead starts
    where the planner's free direction is undefined (p2 at the top of the bore), on another
    branch of the planned path than the readings', and can run away from there."""
    px = np.asarray(readings.get("p_x_mm", np.nan), dtype=float).reshape(-1)
    px = px[np.isfinite(px)]
    if px.size == 0:
        return truth
    return dataclasses.replace(truth, start_x_mm=float(np.mean(px)))
