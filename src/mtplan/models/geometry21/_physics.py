"""geometry21's measurands, error sources and forward model (the exact kinematic chain
from the machine's errors to the plates' readings), true values and duration.
"""

from __future__ import annotations

import math

import numpy as np

from mtplan._cache import array_cache
from mtplan.models.geometry21._layout import (
    geometry,
    grid_basis,
    mount,
    plane_slices,
    truth_positions,
)
from mtplan.models.geometry21._model import joint_ident
from mtplan.models.geometry21._path import (
    FIELDS,
    MEDIUM_COHERENCE_MM,
    MEDIUM_WAVELENGTH_MM,
    field_elements,
    repeatability_filter,
    residual_basis,
    residual_knots,
)
from mtplan.models.geometry21._setup import (
    ALONG,
    AXIS,
    FUNCTIONS,
    GRID_POWERS,
    KIND,
    SERVO_MISMATCH,
    Setup,
    Truth,
    describe,
    sizeless,
    truth_coefficients,
    truth_rows,
)
from mtplan.models.protocol import Measurand, Readings, Source
from mtplan.uncertainty.distributions import Normal, Rectangular


# --------------------------------------------------------------------------- protocol
def measurands(setup: Setup) -> tuple[Measurand, ...]:
    """The measurands the data determine at this set-up (see :func:`identifiability`): each
    function at +line_length/2, then each component error at the set-up's positions along
    its axis (``along_x_mm`` ...), named ``EXX@-50`` (EXX at x = -50 mm)."""
    return measurand_map(setup)[0]


def along_positions(setup: Setup) -> list[tuple[str, float]]:
    """(function, position [mm]) of every measurand along the travel, in order: each axis's
    positions, and at each the axis's determined component errors in ISO 230-1 order. The
    machine coordinates' zero is left out: each error function is zero there by the
    definition of its reference (ISO 230-1), so it has no uncertainty to state."""
    ident = joint_ident(setup)
    out = []
    for axis, field in enumerate(ALONG):
        for u in getattr(setup, field):
            if u == 0:  # every function is zero there by its definition: nothing to state
                continue
            out += [(name, float(u)) for name, kind, ax, _ in FUNCTIONS
                    if ax == axis and kind != "sq" and ident["estimable"][name]]
    return out


def measurand_map(setup: Setup) -> tuple[tuple[Measurand, ...], np.ndarray]:
    """(measurands, g (q, n_par)): every measurand is ``g @ theta`` [mm, rad], theta the
    error coefficients and mountings of :func:`._layout.geometry`."""
    ident = joint_ident(setup)
    geo = geometry(setup)
    half = setup.line_length_mm / 2
    out, rows = [], []
    for i, (name, kind, axis, comp) in enumerate(FUNCTIONS):
        if not ident["estimable"][name]:
            continue
        unit = "urad" if kind in ("ang", "sq") else "um"
        text = describe(name)
        if kind != "sq":
            text += f", at {'xyz'[axis]} = +{half:g} mm"
        out.append(Measurand(name, unit, text))
        rows.append(ident["g"][i])
    for name, u in along_positions(setup):
        kind, axis = KIND[name], AXIS[name]
        text = describe(name) + f", at {'xyz'[axis]} = {u:+g} mm"
        if abs(u) > half * (1 + 1e-12):
            text += " (extrapolated: outside the measured travel)"
        out.append(Measurand(f"{name}@{u:g}", "urad" if kind == "ang" else "um", text))
        powers, sl = geo.layout[name]
        row = np.zeros(geo.n_par)
        row[sl] = [u**k for k in powers]
        rows.append(row)
    return tuple(out), np.array(rows).reshape(len(out), geo.n_par)


def sources(setup: Setup) -> dict:
    """Every error source of the test (switched off by a size of 0)."""
    geo = geometry(setup)
    m = geo.plane.size
    k = len(GRID_POWERS)
    lag = setup.servo_lag_ms * 1e-3
    return {
        "encoder_noise": Source(
            Normal(0.0, setup.encoder_noise_um * 1e-3), (m, 2),
            "Reading noise of the 2D grid encoder, each component of each reading. Default "
            "0.05 um: assumed for a KGM 182 read on the fly at 500 mm/min (signal period "
            "4 um, interpolated to nm resolution; the maker states no dynamic noise).",
            field="encoder_noise_um"),
        "grid_error": Source(
            Normal(0.0, setup.grid_error_um * 1e-3 / math.sqrt(k)), (3, 2, k),
            "The grid plate's own error: per set-up, a smooth field cubic in the plate "
            "coordinates (u/70 mm, v/70 mm), each component with random coefficients whose "
            "root-sum-square is grid_error_um (1 um: the KGM 182 accuracy grade is +-2 um, "
            "read as a bound). Its linear part (scale, shear) biases positioning and "
            "squareness as a real plate's does.", field="grid_error_um"),
        "plate_offset": Source(
            Normal(0.0, setup.plate_offset_mm), (3, 2),
            "Plate mounting: in-plane offset of the plate centre from the test centre in "
            "each of the three set-ups (0.05 mm: centring by dial indicator, assumed). A "
            "nuisance the estimators remove.", field="plate_offset_mm"),
        "plate_tilt": Source(
            Normal(0.0, setup.plate_tilt_urad * 1e-6), (3, 3),
            "Plate mounting: tilt about the plate's two axes and rotation about its normal "
            "in each set-up (100 urad = 0.1 mm/m alignment, assumed). The rotation is a "
            "nuisance the estimators remove; the tilts act at second order (cosine error).",
            field="plate_tilt_urad"),
        "head_setting": Source(
            Normal(0.0, setup.head_setting_um * 1e-3 if geo.n_extra else 0.0), (geo.n_extra, 2),
            "In-plane position of each extra head position after the change (tool length "
            "from a presetter, lateral offset of the bracket): 10 um each component, assumed "
            "(presetters read tool length to 2-5 um; a bracket's offset is known to ~10 um). "
            "A nuisance the estimators remove; off without extra heads.", field="head_setting_um"),
        "repeatability": Source(
            Normal(0.0, setup.repeatability_um * 1e-3), (m, 2),
            "The machine's non-repeatable path deviation at each reading point, each "
            "in-plane component, independent between passes and correlated along each pass: "
            "the source's elements are the innovations of an AR(1) process in the path "
            "length, readings s mm apart correlating by exp(-s / repeatability_correlation_mm) "
            "(standard deviation repeatability_um at every reading), so reading a pass more "
            "densely adds readings, not independent information. Default 0.3 um: "
            "ISO 230-2 unidirectional repeatability R = 4 s of about 1.2 um, typical of a "
            "machining centre with linear scales (data sheets: R 1-3 um). Default correlation "
            "length 50 mm: the path deviations of a contouring machine are low-frequency "
            "(ISO 230-4: the servo's and the guideways' deviations span tens of millimetres, "
            "several ball-screw pitches of 10-20 mm), not white from one reading to the next; "
            "0 gives independent readings.", field="repeatability_um"),
        "path_residual": Source(
            Normal(0.0, setup.path_residual_um * 1e-3), (3, 3, residual_knots(geo)[1]),
            "The machine's repeatable path deviation beyond the fitted polynomials: for each "
            "axis (X, Y, Z) and each direction of the tool's deviation (x, y, z), a random "
            "function of the axis's commanded position, correlated over 5 mm (AR(1) over "
            "knots 2.5 mm apart, linearly interpolated; the elements are its innovations), "
            "RMS path_residual_um. A function of position, so every pass (repeat, direction, "
            "head) sees the same; the polynomials cannot follow it, so the error of "
            "truncating the model enters u. The measurands are the smooth (polynomial) part "
            "of each error function. Default 0.3 um: the short-wave part of ISO 230-1 "
            "straightness and ISO 230-2 positioning records of a machining centre with linear "
            "scales (periodic deviations of ball-screw drives and guideway waviness of "
            "0.2-1 um over 5-20 mm), assumed.", field="path_residual_um"),
        "medium_wave": Source(
            Normal(0.0, setup.medium_wave_um * 1e-3),
            (3, 3, field_elements(geo, "medium_wave")),
            "The machine's repeatable medium-wave path deviation: for each axis and direction "
            "of the tool's deviation, a stationary random function of the axis's commanded "
            f"position made of waves of about {MEDIUM_WAVELENGTH_MM:g} mm (covariance "
            f"cos(2 pi d / {MEDIUM_WAVELENGTH_MM:g} mm) "
            f"exp(-d^2 / (2 ({MEDIUM_COHERENCE_MM:g} mm)^2)); the elements are the modes of "
            "that covariance on the path residual's knots), RMS "
            "medium_wave_um: the errors between the short-wave residual (5 mm) and the "
            "polynomials' reach (a cubic over 100 mm follows waves of 200 mm and more), "
            "which truncating the model at poly_order leaves. The same in every pass; the "
            "joint fit does not weigh it (an unknown function, its shape not stated), the "
            "budget takes its covariance. Default 0.3 um: guideway waviness and the "
            "accumulated pitch error of a ball screw over 20-100 mm, a fraction of the "
            "2-4 um per 100-300 mm straightness and positioning deviations that ISO 230-1 "
            "and ISO 230-2 records of a machining centre show beyond their smooth trend, "
            "assumed.", field="medium_wave_um"),
        "reversal": Source(
            Rectangular(0.0, 2e-3 * setup.reversal_um), (3,),
            "Reversal value (lost motion) B of each axis, drawn uniform on [0, 2 reversal_um] "
            "(mean reversal_um, never negative): moving in +U the axis lags by B/2, moving in "
            "-U it leads by B/2, so the back-and-forth lines and the quadrants of the "
            "circles see it. Default 2 um: ISO 230-2 reversal value of a machining centre "
            "with linear scales (data sheets 1-3 um; with rotary encoders 3-10 um).",
            field="reversal_um"),
        "servo_lag": Source(
            Normal(lag, SERVO_MISMATCH * lag), (3,),
            "Following time T = 1/Kv of each axis's position loop, drawn with 10 % spread "
            "about servo_lag_ms (the mismatch of tuned gains): the contouring error of the "
            "circles, a radius reduction v^2 T^2 / (2 R) and a 45-deg ellipse of amplitude "
            "v (T_b - T_a) / 2 that changes sign with the direction (ISO 230-4 Annex). "
            "Default 2 ms: the effective following time with velocity feed-forward, assumed "
            "(without it Kv = 1-3 (m/min)/mm, T = 20-60 ms); at 500 mm/min the ellipse is "
            "about 1 um.", field="servo_lag_ms"),
        "thermal_growth": Source(
            Normal(0.0, setup.thermal_growth_ppm_per_h * 1e-6), (3,),
            "Rate of change of each axis's scale during the test (thermal expansion of the "
            "scale or ball screw), linear in the test's time: the positioning error grows "
            "by g t u. Default 2 ppm/h: a workshop's temperature change of ~0.2 K/h on "
            "steel/cast iron (11.5 ppm/K), the order of ISO 230-3 environmental drift "
            "tests of machining centres.", field="thermal_growth_ppm_per_h"),
        "thermal_drift": Source(
            Normal(0.0, setup.thermal_drift_um_per_h * 1e-3), (3,),
            "Rate of the head's drift relative to the plate during the test (spindle and "
            "column growth), each component, linear in the test's time. Default 2 um/h: the "
            "order of ISO 230-3 drift of a warmed-up machining centre at rest (2-10 um over "
            "several hours, most in Z).", field="thermal_drift_um_per_h"),
    }


def _features(errors: dict) -> np.ndarray | None:
    """The 15 per-trial features of :func:`._layout._feature_patterns`, or None when all are zero."""
    t = errors["servo_lag"]
    f = np.concatenate([errors["thermal_growth"], errors["thermal_drift"], errors["reversal"],
                        t, t * t], axis=1)
    return f if np.any(f) else None


def forward(setup: Setup, truth: Truth, errors: dict) -> Readings:
    """Readings of the plates in the three set-ups, exact rigid-body model.

    Returns
    -------
    dict with ``plate_mm``: array (n, M, 2), the head's in-plane position in each plate's
    frame, relative to the plate's nominal origin [mm]; the point order is that of
    :func:`readings_frame`.
    """
    geo = geometry(setup)
    n = errors["encoder_noise"].shape[0]
    feat = _features(errors)
    if truth_rows(truth) is not None:  # one truth per batch row (a posterior's walkers)
        loc = truth_positions(geo, truth_coefficients(truth)).reshape(n, -1)
        if feat is not None:
            loc = loc + feat @ geo.pattern.reshape(15, -1)
        loc = loc.reshape(n, -1, 3)
    elif feat is None:
        loc = forward_matrix(setup, truth)[:1].reshape(1, -1, 3)
    else:  # drift, reversal and servo: one product for the batch
        base = forward_matrix(setup, truth)  # (16, 3M): the truth's positions, then patterns
        loc = (np.column_stack([np.ones(n), feat]) @ base).reshape(n, -1, 3)
    r = mount(geo, loc, errors["plate_offset"], errors["head_setting"], errors["plate_tilt"])
    g = errors["grid_error"]  # (n, 3, 2, K)
    if np.any(g):
        basis = grid_basis(geo)
        for k, sl in enumerate(plane_slices(geo)):
            r[:, sl, :] += np.swapaxes(g[:, k] @ basis[sl].T, 1, 2)
    for field in FIELDS:
        res = errors[field]
        if np.any(res):  # the same function of position in every pass: one product
            r += (res.reshape(n, -1) @ residual_basis(sizeless(setup), field).T).reshape(
                n, -1, 2)
    r += errors["encoder_noise"]
    e = errors["repeatability"]
    if np.any(e):
        f = repeatability_filter(setup)
        if f is None:
            r += e
        else:  # the AR(1) process along each pass: one sparse product for the batch
            n_, m_, _ = e.shape
            r += (f @ np.moveaxis(e, 1, 0).reshape(m_, -1)).reshape(m_, n_, 2).swapaxes(0, 1)
    return Readings({"plate_mm": r})


@array_cache(maxsize=8)
def forward_matrix(setup: Setup, truth: Truth) -> np.ndarray:
    """The truth's head positions in the plates' frames and the 15 feature patterns of
    :func:`._layout._feature_patterns`, stacked (16, 3M): ``[1, features] @ it`` is every reading's
    plate-frame position."""
    geo = geometry(setup)
    coefs = {k: (pw, c[None, :]) for k, (pw, c) in truth_coefficients(truth).items()}
    return np.concatenate([truth_positions(geo, coefs).reshape(1, -1),
                           geo.pattern.reshape(15, -1)])


def true_values(setup: Setup, truth: Truth) -> dict:
    """Each listed measurand's true value (function at u = +line_length/2, and at the
    positions along the travel) [mm or rad]."""
    u = setup.line_length_mm / 2
    coefs = truth_coefficients(truth)
    listed = {m.name for m in measurands(setup)}
    out = {name: (np.sum(c * u ** np.array(pw), axis=-1) if KIND[name] != "sq" else c[..., 0])
           for name, (pw, c) in coefs.items() if name in listed}
    for name, at in along_positions(setup):
        pw, c = coefs[name]
        out[f"{name}@{at:g}"] = np.sum(c * at ** np.array(pw), axis=-1)
    return {k: float(v) if np.ndim(v) == 0 else v for k, v in out.items()}  # arrays: batch rows


def duration(setup: Setup) -> float:
    """Machine time [s]: three plate set-ups, the head changes, the line and circle passes
    of every head position at ``feed_mm_min`` (the schedule that times each reading)."""
    return geometry(setup).duration_s

