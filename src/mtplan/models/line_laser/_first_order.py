"""line_laser's closed-form sensitivities: each estimator's linear map times each source's
effect (the procedure's ``first_order_sensitivities``).

The generic chain rule of the first-order service (:mod:`mtplan.evaluation.first_order`)
differentiates forward model and estimator together, input by input: one input per
reading's noise, 15 600 at the default scan, each through the whole estimator. Here the
same first-order propagation is taken in two factors:

- the readings' derivative with respect to every element of every error source, at the
  sources' means (all zero), **exactly**: every error-free hit lies on one plane of the
  artifact, ``t = (c + g . O) / (-g . d)`` (``g = (gx, gy, -1)`` the plane's slopes), so a
  displacement ``delta`` of the sensor in a scan moves its heights by
  ``(g . q^T delta) / (-g . d)`` (``q`` the artifact's pose), a facet moved by ``e`` along
  its in-plane normal moves the heights on it by ``-tan(facet) e / (-g . d)``, the Z scale
  multiplies the heights, the linearity adds its Legendre curves, and the noise adds itself;
- the estimator's derivative with respect to the readings, its *linear map* ``L``
  (3, readings), from its own formulas at the error-free readings: the patent's
  alpha_y is a weighted mean of height differences (the row shift and the binarising
  thresholds are whole numbers and cut-offs, with derivative 0: its alpha_z, quantised
  in steps of ``dy/w``, has none at all), its alpha_x the arccos of a mean; the pattern
  fit's fixed point ``K (y - f(theta)) = 0`` (``K`` the gain it iterates with) moves by
  ``(K J)^-1 K dy``, ``J`` the readings' Jacobian at the truth.

The standard uncertainty of measurand i from a source is then the root sum of squares
of ``L_i . effect_e * u_e`` over the source's elements ``e``. The registration's map is
not written out (its masks and trims are cut-offs, its fit a Gauss-Newton on
interpolated, self-referenced scans): :func:`sensitivities` returns None for it, and the
generic chain rule is used. The two agree to the generic one's own finite-difference
error: at 16 profiles 0.25 mm apart (3 120 readings) every source's part of u to 3e-5 of
it for the patent and 5e-6 for the pattern fit, in 0.015 s and 0.3 s against 2 s and
7 s (``tests/models/test_line_laser.py`` holds the patent to the generic to 1e-4 and the
pattern fit's map to the estimator's own secants to 1e-5).
"""

from __future__ import annotations

import math

import numpy as np

from mtplan.models.line_laser._artifact import pitch as _pitch, x_shift as _shift
from mtplan.models.line_laser._estimators import (
    FIT_FIELDS,
    FIT_STEPS,
    fit_limits,
    interp_along_line,
    nearest_row,
    pattern_gain,
    predict_profiles,
    gain_reference,
    registration_check,
    row_search,
)
from mtplan.models.line_laser._physics import (
    FACET_OF as _FACET_OF,
    frames as _frames,
    forward,
    linearity_basis as _linearity_basis,
    measurands,
    nominal_trace as _nominal,
    scan_times as _scan_times,
    sources as _sources,
)
from mtplan.models.line_laser._setup import NAME, Truth
from mtplan.models.protocol import active_sources, zero_errors

#: estimators whose linear map is written out here (the registration's is not)
MAPPED = ("patent", "pattern")


def _effects(setup, truth) -> dict:
    """Derivative of the readings (flattened, 3 * lines * points) with respect to every
    element of every source at zero error: source -> (readings, elements) dense, except
    ``sensor_noise`` (the identity: None) and ``facet_position`` ((element of each
    reading, -1 for none), derivative of each reading)."""
    t0, _, _, _, gx, gy, _ = _nominal(setup, truth)
    _, d, q, _ = _frames(setup, truth)
    den = d[2] - gx * d[0] - gy * d[1]
    # heights per unit displacement of the sensor along machine axis j, (readings, 3)
    a = (gx[:, None] * q[:, 0] + gy[:, None] * q[:, 1] - q[:, 2]) / den[:, None]
    rays = t0.size
    scan = np.arange(rays) // (rays // 3)

    def moves(coef):
        """Effect of displacements coef (3 scans, 3 axes) per unit of the element."""
        return np.einsum("rj,rj->r", a, np.asarray(coef, dtype=float)[scan])

    w, h = _shift(setup), setup.raise_mm
    times = _scan_times(setup)[:3] - _scan_times(setup)[0]
    unit = np.zeros((3, 3))
    out = {"sensor_noise": None}
    out["shift_error"] = moves([[0, 0, 0], [1, 0, 0], [1, 0, 0]])[:, None]
    out["raise_error"] = moves([[0, 0, 0], [0, 0, 0], [0, 0, 1]])[:, None]
    trig = []
    for k in range(3):
        c = unit.copy()
        c[k, 1] = 1.0
        trig.append(moves(c))
    out["trigger_y"] = np.stack(trig, axis=1)
    out["squareness_xy"] = moves([[0, 0, 0], [0, w, 0], [0, w, 0]])[:, None]
    out["squareness_zy"] = moves([[0, 0, 0], [0, 0, 0], [0, h, 0]])[:, None]
    out["drift"] = np.stack([moves(np.outer(times, np.eye(3)[j])) for j in range(3)], axis=1)
    out["z_scale"] = t0[:, None]
    basis = _linearity_basis(setup)  # (degrees, points)
    out["linearity"] = np.tile(basis.T, (3 * setup.lines, 1))
    elem = _FACET_OF[(setup, truth)]
    out["facet_position"] = (elem, np.where(elem >= 0, -math.tan(math.radians(
        setup.facet_angle_deg)) / den, 0.0))
    return out


def _patent_map(setup, z) -> np.ndarray:
    """The patent's linear map (3, readings) [rad per mm] at readings ``z`` (3, lines,
    points): alpha_z none (a whole row shift), alpha_y ``arctan(l_y / w)`` with ``l_y`` the
    mean difference of scan 1 moved by ``w`` (interpolated along the line) and scan 2 at
    the row shift ``n1``, alpha_x ``arccos(h / h')`` with ``h'`` the mean of scan 2 minus
    scan 3 (derivative 0 where the ratio is clipped at 1)."""
    lines, pts = setup.lines, setup.points_per_line
    w, h = _shift(setup), setup.raise_mm
    nmax = setup.max_shift_rows
    a, cols = interp_along_line(setup, z[None, 0], w)
    b = z[None, 1]
    fracs, diffs = row_search(setup, a, b, cols)
    best = np.argmax(fracs, axis=1)
    n1 = int(nearest_row(setup, a, b, cols, best - nmax)[0])
    l_y = float(diffs[0, n1 + nmax])
    out = np.zeros((3, 3, lines, pts))
    jb = np.arange(max(0, n1), lines + min(0, n1))
    ja = jb - n1
    cols = np.flatnonzero(cols)
    p = w / _pitch(setup)  # as interp_along_line
    k = int(math.floor(p))
    f = p - k
    weight = 1.0 / (ja.size * cols.size) / (w * (1.0 + (l_y / w) ** 2))
    rows_a = ja[:, None]
    np.add.at(out[1, 0], (rows_a, np.clip(cols + k, 0, pts - 1)[None, :]), (1 - f) * weight)
    if f > 0:
        np.add.at(out[1, 0], (rows_a, np.clip(cols + k + 1, 0, pts - 1)[None, :]), f * weight)
    out[1, 1][np.ix_(jb, cols)] -= weight
    h_prime = float((z[1] - z[2]).mean())
    ratio = h / h_prime if h_prime else math.inf
    if -1.0 < ratio < 1.0:
        slope = h / (h_prime**2 * math.sqrt(1.0 - ratio**2)) / (lines * pts)
        out[2, 1] += slope
        out[2, 2] -= slope
    return out.reshape(3, -1)


def _pattern_map(setup, truth) -> np.ndarray:
    """The pattern fit's linear map (3, readings) [rad per mm]: ``(K J)^-1 K``, angle rows."""
    from mtplan.fitting import central_jacobian

    theta = np.array([getattr(truth, f) for f in FIT_FIELDS], dtype=float)
    low, high = fit_limits()
    # the tangent, not the secant of the fit's own gain: steps of 1 nrad and 0.1 nm move no
    # hit across a kink (its steps of 10 urad and 1 um move hundreds)
    jac = central_jacobian(lambda rows: predict_profiles(setup, rows), theta, FIT_STEPS * 1e-4,
                           low=low, high=high)
    gain = pattern_gain(setup, gain_reference(theta))
    return np.linalg.solve(gain @ jac, gain)[:3] * 1e-3  # mrad -> rad


def _check_pattern(setup) -> None:
    """Refuse, as the pattern estimator does, a set-up where the registration it starts from
    cannot work."""
    ok, why = registration_check(setup)
    if not ok:
        from mtplan._validate import InvalidInput

        raise InvalidInput([f"line_laser estimator 'pattern' cannot determine the angles "
                            f"at this set-up (it starts from the registration): {why}"])


def sensitivities(setup, truth=None, *, estimator: str = "patent", sources=None):
    """The measurands' sensitivity to every element of every active source [display unit
    per internal unit]: the jacobian (3, elements), the columns in the order of the
    first-order service (:func:`mtplan.evaluation.first_order.first_order`: the active
    sources in order, each one's elements flattened); the procedure's
    ``first_order_sensitivities``.

    The same first-order propagation as the generic chain rule, through the estimator's
    linear map at the truth and the sources' exact effects on the readings (the module's
    docstring) instead of a differentiation of the forward model and the estimator per
    element: a few seconds instead of half a minute at the default set-up. None for an
    estimator whose map is not written out (``registration``) or a source whose effect
    does not have one column per element: then the generic chain rule.
    """
    truth = Truth() if truth is None else truth
    if estimator not in MAPPED:
        return None
    if estimator == "patent":
        z = forward(setup, truth, zero_errors(_sources(setup), 1))["z_mm"][0]
        lmap = _patent_map(setup, z)
    else:
        _check_pattern(setup)
        lmap = _pattern_map(setup, truth)
    ms = measurands(setup)
    lmap = lmap * np.array([m.scale for m in ms])[:, None]
    effects = _effects(setup, truth)
    cols = []
    for name, src in active_sources(_sources(setup), sources, owner=NAME).items():
        shape = (*src.shape, *src.distribution.event_shape)
        size = int(np.prod(shape, dtype=np.int64))
        eff = effects[name]
        if eff is None:  # the readings' own noise
            col = lmap
        elif isinstance(eff, tuple):  # one element per reading
            elem, deriv = eff
            on = elem >= 0
            col = np.stack([np.bincount(elem[on], weights=row[on] * deriv[on], minlength=size)
                            for row in lmap])
        else:
            col = lmap @ eff
        if col.shape[1] != size:
            return None
        cols.append(col)
    return np.hstack(cols) if cols else np.zeros((len(ms), 0))
