"""rotary_axis's measuring layout: the axes' frames, the lattice on the incline at each
position, the plan of the test (angles, points, times) and its schedule and duration.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np
import pandas as pd

from mtplan.models.protocol import file_content
from mtplan.models.rotary_axis._characteristic import bilinear
from mtplan.models.rotary_axis._setup import (
    Setup,
    incline_normal,
    lattice,
    nominal_rotations,
    TILT_TABLE,
    TILT_TABLE_DEG,
    sensor_tilts,
    serpentine,
    tilts,
)


# --------------------------------------------------------------------------- geometry
class _Frame(NamedTuple):
    ax: np.ndarray  # nominal axis direction (3,)
    p1: np.ndarray  # first perpendicular (3,): X for C, Y for A
    p2: np.ndarray  # second perpendicular (3,): Y for C, Z for A


FRAMES = {
    "C": _Frame(np.array([0.0, 0, 1]), np.array([1.0, 0, 0]), np.array([0.0, 1, 0])),
    "A": _Frame(np.array([1.0, 0, 0]), np.array([0.0, 1, 0]), np.array([0.0, 0, 1])),
}
NAMES = {  # (position 1, position 2, angle about p1, angle about p2)
    "C": ("EX0C", "EY0C", "EA0C", "EB0C"),
    "A": ("EY0A", "EZ0A", "EB0A", "EC0A"),
}


class Plan(NamedTuple):
    """Everything the forward model and estimators need that depends on the set-up only."""

    frame: _Frame
    theta: np.ndarray  # commanded angles (P,) [rad]
    n0: np.ndarray  # upward unit normal of the incline at the zero position (3,)
    q0: np.ndarray  # a point of the incline at the zero position (3,) [mm]
    centres: np.ndarray  # lattice centres (P, 2) [mm]
    xy: np.ndarray  # commanded point of each reading, every pass (P, R, 2) [mm]
    z_cmd: np.ndarray  # commanded Z: (P, R) following, (P, 1) otherwise [mm]
    local: np.ndarray  # [1; gx; gy] (3, M): plane in local coordinates -> heights
    read_local: np.ndarray  # the same for each reading, every pass (3, R)
    sensor_sign: np.ndarray  # +1 at the sensor's 0 deg pass, -1 at its 180 deg one (R,)
    fit: np.ndarray  # its pseudo-inverse, transposed (M, 3): heights -> (h, a, b)
    gram: np.ndarray  # local^T local summed over points: (3, 3)
    form: np.ndarray  # height per unit form coefficient, (K, P*R) [1]
    harmonics: np.ndarray  # [cos t, sin t, cos 2t, sin 2t] of the commanded angles (4, P)
    tilt_bound: np.ndarray  # range x the angle influence's bound at each position's tilt
    # relative to its bound at 30 deg (P,) [mm]
    tilt_direction: np.ndarray  # the tilt's direction from the triangulation plane (P,) [rad]
    influence: np.ndarray  # each reading's height per unit angle-influence element: the
    # tilt knots' hats x the four corner shapes x tilt_bound (K, 4, P, R) [mm]
    times: np.ndarray  # time of each reading from the start (P, R) [s]
    total_time: float  # [s]
    down: np.ndarray  # 1 where a position is approached against the first move, else 0 (P,)
    machine: np.ndarray  # the X/Y motion's Z error per unit term: x, y, bows (4, P, R) [mm]
    # with sensor_characteristic (else None and an empty index): the characteristic at each
    # reading's nominal tilt (P, R) [mm], the calibrated points it interpolates from (K,)
    # (flat indices into the file's grid) and each reading's weight on them (K, P, R)
    characteristic: np.ndarray | None = None
    calibration_index: np.ndarray = np.zeros(0, dtype=int)
    calibration: np.ndarray | None = None


def _form_basis(setup: Setup, axis: str, angles: np.ndarray, xy: np.ndarray,
                z: np.ndarray) -> np.ndarray:
    """Height change per unit coefficient of each form term at each reading, (P*M, 5).

    The terms, in coordinates (xi, eta) on the incline (along the fall line and across
    it, from the lattice centre, divided by half the lattice side): bowl
    (xi^2 + eta^2)/2, saddle (xi^2 - eta^2)/2, twist xi*eta/2 and two cubic waves
    xi^3/2, eta^3/2, each of peak-to-valley ~1 over the lattice. The deviation is along
    the normal; it changes the height read along Z by deviation / n_z.
    """
    theta = np.deg2rad(angles)
    rot = nominal_rotations(axis, theta)
    n0 = incline_normal(setup)
    az = math.radians(setup.incline_azimuth_deg)
    fall = np.array([math.cos(az), math.sin(az), 0.0])
    f1 = fall - (fall @ n0) * n0
    f1 /= np.linalg.norm(f1)
    f2 = np.cross(n0, f1)
    ox, oy = setup.lattice_offset_x_mm, setup.lattice_offset_y_mm
    c0 = np.array([ox, oy, setup.artifact_height_mm - (n0[0] * ox + n0[1] * oy) / n0[2]])
    pts = np.concatenate([xy, z[..., None]], axis=-1)  # (P, M, 3) nominal hit points
    back = np.einsum("pji,pmj->pmi", rot, pts) - c0  # R^T p - c0, in the zero position
    half = setup.lattice_size_mm / 2
    xi, eta = back @ f1 / half, back @ f2 / half
    basis = np.stack([(xi**2 + eta**2) / 2, (xi**2 - eta**2) / 2, xi * eta / 2,
                      xi**3 / 2, eta**3 / 2], axis=-1)
    nz = (rot @ n0)[:, 2]
    return (basis / nz[:, None, None]).reshape(-1, basis.shape[-1])


def _harmonics(angle: np.ndarray) -> np.ndarray:
    """First and second harmonics of `angle` (P,) [rad]: (4, P), cos, sin, cos 2, sin 2."""
    return np.stack([np.cos(angle), np.sin(angle), np.cos(2 * angle), np.sin(2 * angle)])


_TILT_TABLE_DEG, _TILT_TABLE = np.array(TILT_TABLE_DEG), np.array(TILT_TABLE)


def _calibration(setup: Setup):
    """(characteristic (P, R) [mm], calibrated points (K,), weights (K, P, R)) of the
    set-up's calibrated characteristic, bilinear at each reading's nominal tilt; (None,
    empty, None) without one."""
    ch = file_content(setup, "sensor_characteristic")
    if ch is None:
        return None, np.zeros(0, dtype=int), None
    index, weight = bilinear(ch, *sensor_tilts(setup))  # (P, passes, 4) each
    points = np.unique(index)
    P, passes = index.shape[:2]
    w = np.zeros((points.size, P, passes))
    p_i, k_i = np.meshgrid(np.arange(P), np.arange(passes), indexing="ij")
    for c in range(4):
        np.add.at(w, (np.searchsorted(points, index[..., c]), p_i, k_i), weight[..., c])
    w = np.repeat(w, setup.n_points, axis=2)  # (K, P, R): every point of a pass alike
    values = np.tensordot(ch.error.ravel()[points], w, axes=1)
    return values, points, w


def _tilt_bound(tau: np.ndarray) -> np.ndarray:
    """The angle influence's bound at tilts `tau` [deg] relative to its bound at 30 deg (P,)."""
    slope = (_TILT_TABLE[-1] - _TILT_TABLE[-2]) / (_TILT_TABLE_DEG[-1] - _TILT_TABLE_DEG[-2])
    inside = np.interp(tau, _TILT_TABLE_DEG, _TILT_TABLE)
    beyond = _TILT_TABLE[-1] + slope * (tau - _TILT_TABLE_DEG[-1])
    bound = np.where(tau > _TILT_TABLE_DEG[-1], beyond, inside)
    return bound / _TILT_TABLE[-1]


#: the angle influence's shapes in tilt are hats on knots spread evenly over the test's
#: tilts, about this far apart (the data sheet's own rows lie 5-15 deg apart): one knot
#: (a shape in tilt of B's own) where the tilts span less than half of it
INFLUENCE_KNOT_DEG = 15.0


def influence_knots(tau: np.ndarray) -> np.ndarray:
    """The tilt knots [deg] of the angle influence's shapes for a test whose surface tilts
    are `tau` (P,) [deg]: from the smallest to the largest, about
    :data:`INFLUENCE_KNOT_DEG` apart."""
    lo, hi = float(np.min(tau)), float(np.max(tau))
    return np.linspace(lo, hi, 1 + int(round((hi - lo) / INFLUENCE_KNOT_DEG)))


def influence_basis(setup: Setup) -> np.ndarray:
    """Each reading's height error per unit element of the angle influence (K, 4, P, R) [mm].

    The influence is ``range B(tau) s(tau, phi)`` with ``|s| <= 1`` wherever the data sheet
    bounds it, ``s = sum_k hat_k(tau) sum_i a_ki q_i(phi)``: hats on the tilt knots
    (:func:`influence_knots`; they are >= 0 and sum to 1) times the four corner shapes
    ``q = (1 + e cos phi)(1 + d cos 2 phi) / 4``, e, d = +-1 (>= 0, summing to 1), so any
    elements within +-1 keep the error within the bound at every tilt and direction, and
    the even part (all a alike), the odd part (a = +-1 by e) and the anisotropy (by d)
    each reach the whole bound. The sensor turned by 180 deg sees phi + pi: e changes sign.
    """
    tau, azimuth = tilts(setup)
    phi = azimuth - math.radians(setup.sensor_azimuth_deg)
    knots = influence_knots(tau)
    if knots.size == 1:
        hats = np.ones((1, tau.size))
    else:
        hats = np.clip(1.0 - np.abs(tau - knots[:, None]) / (knots[1] - knots[0]), 0.0, None)
    sign = np.array([1.0, -1.0][:setup.n_passes])
    c, v = np.cos(phi)[:, None] * sign, np.cos(2 * phi)[:, None]  # (P, passes), (P, 1)
    corners = np.stack([(1 + e * c) * (1 + d * v) / 4 for e in (1, -1) for d in (1, -1)])
    bound = setup.sensor_range_mm * _tilt_bound(tau)
    basis = hats[:, None, :, None] * corners[None] * bound[:, None]  # (K, 4, P, passes)
    return np.repeat(basis, setup.n_points, axis=-1)


#: the angle influence's elements (K, 4) for the three parts (0 even, 1 odd, 2 anisotropic)
#: of the bound, ``s = c0 + c1 cos phi + c2 cos 2 phi`` at every tilt knot
INFLUENCE_PARTS = np.array([[1.0, 1.0, 1.0, 1.0], [1.0, 1.0, -1.0, -1.0], [1.0, -1.0, 1.0, -1.0]])


#: the length over which the X and Y motion's bow is stated (+-50 mm about the table centre)
_BOW_HALF_MM = 50.0


def _approached_down(angles: np.ndarray) -> np.ndarray:
    """1 where a position is approached in the other direction than the axis's first move
    (the first position in the first move's direction, after an overrun), else 0 (P,)."""
    step = np.sign(np.diff(angles))
    first = step[np.flatnonzero(step)[0]] if np.any(step) else 1.0
    direction = np.concatenate([[first], np.where(step == 0, first, step)])
    return (direction != first).astype(float)


def _machine_basis(xy: np.ndarray) -> np.ndarray:
    """The X/Y motion's Z error per unit slope (x, y) [mm/rad] and per unit bow [1] at the
    commanded points `xy` (P, M, 2): (4, P, M)."""
    x, y = xy[..., 0], xy[..., 1]
    return np.stack([x, y, (x / _BOW_HALF_MM) ** 2, (y / _BOW_HALF_MM) ** 2])


def _times(setup: Setup, xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Time of each reading (P, R) and of the whole test [s]: index, moves, dwell, and the
    spindle's turn before each second pass."""
    speed = setup.feed_mm_min / 60.0
    flat = xy.reshape(-1, 2)
    steps = np.zeros(len(flat))
    steps[1:] = np.hypot(*(np.diff(flat, axis=0).T)) / speed
    steps += setup.dwell_s
    steps = steps.reshape(xy.shape[:2])
    steps[:, 0] += setup.index_time_s  # turn, clamp and settle before each lattice
    for k in range(1, setup.n_passes):
        steps[:, k * setup.n_points] += setup.spindle_orient_s  # M19 by 180 deg
    times = np.cumsum(steps.ravel()).reshape(steps.shape)
    return times, float(times[-1, -1])


@functools.lru_cache(maxsize=64)
def plan(setup: Setup) -> Plan:
    parts = []  # per axis measured: centres (P, 3), points, heights, form (P*M, K)
    for axis in setup.axes:
        angles = setup.axis_angles(axis)
        centres3, xy, z = lattice(setup, axis, angles)
        parts.append((centres3, xy, z, _form_basis(setup, axis, angles, xy, z)))
    centres3, xy, z, form = (np.concatenate(arrays) for arrays in zip(*parts, strict=True))
    gx, gy = serpentine(setup.lattice_nx, setup.lattice_ny, setup.lattice_size_mm)
    local = np.stack([np.ones_like(gx), gx, gy])
    fit = np.linalg.pinv(local.T).T  # (M, 3): coef = heights @ fit
    # every pass reads the lattice in the same order: readings (P, R), R = passes x M
    passes, P = setup.n_passes, xy.shape[0]
    xy, z = np.tile(xy, (1, passes, 1)), np.tile(z, (1, passes))
    form = np.tile(form.reshape(P, -1, form.shape[-1]), (1, passes, 1)).reshape(-1, form.shape[-1])
    times, total = _times(setup, xy)  # one time line through every axis's positions
    z_cmd = z if setup.z_follows_surface else centres3[:, 2:]
    out = Plan(
        frame=FRAMES.get(setup.axis),  # None for CA: each part has its own
        theta=np.deg2rad(setup.angles()),
        n0=incline_normal(setup),
        q0=np.array([0.0, 0.0, setup.artifact_height_mm]),
        centres=centres3[:, :2],
        xy=xy,
        z_cmd=np.ascontiguousarray(z_cmd),
        local=local,
        read_local=np.ascontiguousarray(np.tile(local, (1, passes))),
        sensor_sign=np.repeat([1.0, -1.0][:passes], setup.n_points),
        fit=np.ascontiguousarray(fit),
        gram=local @ local.T,
        form=np.ascontiguousarray(form.T),  # (K, P*M)
        harmonics=_harmonics(np.deg2rad(setup.angles())),
        tilt_bound=setup.sensor_range_mm * _tilt_bound(tilts(setup)[0]),
        tilt_direction=tilts(setup)[1] - math.radians(setup.sensor_azimuth_deg),
        influence=np.ascontiguousarray(influence_basis(setup)),
        times=times,
        total_time=total,
        down=np.concatenate([_approached_down(setup.axis_angles(a)) for a in setup.axes]),
        machine=_machine_basis(xy),
        **dict(zip(("characteristic", "calibration_index", "calibration"),
                   _calibration(setup), strict=True)),
    )
    for arr in out:
        if isinstance(arr, np.ndarray):
            arr.setflags(write=False)
    return out


def rotate_about(v: np.ndarray, u: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotate vectors `v` (..., 3) about the unit vector(s) `u` (..., 3) by `angle` (...).

    Rodrigues' formula, exact; `u` and `angle` broadcast against `v`.
    """
    c, s = np.cos(angle)[..., None], np.sin(angle)[..., None]
    return v * c + _cross(u, v) * s + u * (np.sum(v * u, axis=-1)[..., None] * (1.0 - c))


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last axis (..., 3), without np.cross's axis juggling."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def rotate_by_vector(v: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Rotate vectors `v` (..., 3) by rotation vectors `w` (..., 3) [rad], exactly.

    Rodrigues' formula with sin(t)/t and (1 - cos t)/t^2 taken from their series below
    t = 1e-3 (error < 1e-21), so a zero rotation is exact.
    """
    t2 = (w * w).sum(axis=-1)
    t = np.sqrt(t2)
    small = t < 1e-3
    safe = np.where(small, 1.0, t)
    k1 = np.where(small, 1 - t2 / 6 + t2 * t2 / 120, np.sin(safe) / safe)
    k2 = np.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, (1 - np.cos(safe)) / (safe * safe))
    wv = (w * v).sum(axis=-1)
    return v * np.cos(t)[..., None] + _cross(w, v) * k1[..., None] + w * (k2 * wv)[..., None]



# --------------------------------------------------------------------------- time, data
def schedule(setup: Setup) -> pd.DataFrame:
    """The test's time line: one row per reading (axis, position, point, x_mm, y_mm, time_s).

    Each position starts with ``index_time_s``; each point costs the X/Y move from the
    previous one at ``feed_mm_min`` plus ``dwell_s``; the reading is taken at its end.
    """
    g = plan(setup)
    P, M = setup.n_positions, setup.n_readings
    return pd.DataFrame({
        "axis": np.repeat(position_axes(setup), M),
        "position": np.repeat(np.arange(P), M),
        "point": np.tile(np.arange(M), P),
        "x_mm": g.xy[..., 0].ravel(),
        "y_mm": g.xy[..., 1].ravel(),
        **_sensor_column(setup),
        "time_s": g.times.ravel(),
    })


def _sensor_column(setup: Setup) -> dict:
    """``sensor_deg`` (0 or 180, the spindle's orientation of each reading) with
    sensor_reversal, else nothing: {} or {"sensor_deg": array (P*R,)}."""
    if not setup.sensor_reversal:
        return {}
    sign = np.tile(plan(setup).sensor_sign, setup.n_positions)
    return {"sensor_deg": np.where(sign > 0, 0.0, 180.0)}


def duration(setup: Setup) -> float:
    """Machine time of the test [s]: indexing, X/Y moves and dwell at every point."""
    return plan(setup).total_time


def position_axes(setup: Setup) -> np.ndarray:
    """The axis ('C' or 'A') turned at each position, array (positions,) of str."""
    return np.concatenate([np.full(len(setup.axis_angles(a)), a) for a in setup.axes])

