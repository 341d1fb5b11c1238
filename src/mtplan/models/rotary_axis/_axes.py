"""rotary_axis's two axes of a CA test: each axis's part of the set-up and of the
positions, the error sources' position axes, and CA's derived measurands.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from mtplan.fitting.fit3d import common_perpendicular
from mtplan.models.rotary_axis._layout import FRAMES, NAMES, rotate_about
from mtplan.models.rotary_axis._setup import Setup, nominal_rotations


# --------------------------------------------------------------------------- both axes (CA)
#: axis of each per-position source's errors (after the batch axis) that runs over positions
POSITION_AXIS = {"probe_noise": 1, "xy_positioning": 2, "z_positioning": 1,
                  "radial_motion": 1, "axial_motion": 1, "tilt_motion": 1,
                  "angular_repeatability": 1, "angular_short_period_halfwidth": 1}
#: sources with one row of errors per axis tested (after the batch axis)
AXIS_ROWS = ("angular_positioning", "reversal_halfwidth")


@functools.lru_cache(maxsize=64)
def axis_part(setup: Setup, axis: str) -> Setup:
    """The single-axis set-up of one part of a CA test (its angles and its incline,
    everything else shared)."""
    return Setup(**{**setup.as_dict(), "axis": axis, "incline_deg": setup.incline,
                    "angles_deg": tuple(setup.axis_angles(axis).tolist()),
                    "positions": None, "range_deg": None, "c_angles_deg": None})


def axis_parts(setup: Setup) -> list[tuple[Setup, slice]]:
    """(single-axis set-up, its positions' slice of the whole test) for each axis measured."""
    if setup.axis != "CA":
        return [(setup, slice(0, setup.n_positions))]
    out, start = [], 0
    for axis in setup.axes:
        n = len(setup.axis_angles(axis))
        out.append((axis_part(setup, axis), slice(start, start + n)))
        start += n
    return out


def measurand_line(axis: str, reference: float, m: dict) -> tuple[np.ndarray, np.ndarray]:
    """Point at the reference (n, 3) [mm] and unit direction (n, 3) from location errors."""
    f = FRAMES[axis]
    n1, n2, a1, a2 = NAMES[axis]
    point = reference * f.ax + m[n1][:, None] * f.p1 + m[n2][:, None] * f.p2
    w = f.ax + m[a2][:, None] * f.p1 - m[a1][:, None] * f.p2
    return point, w / np.linalg.norm(w, axis=-1, keepdims=True)


def combined(setup: Setup, m: dict) -> dict[str, np.ndarray]:
    """The derived measurands of CA from the eight location errors (arrays (n,)) [mm, rad].

    The kinematics of a table-tilting machine whose C table rides on A: a workpiece
    point p (table coordinates at A = C = 0) is turned about the C line (as measured at
    A = 0) by the pose's C angle, then about the A line by its A angle; the nominal
    lines are the Z and X axes through the origin. The pose error is the actual point
    minus the nominal one.
    """
    pc, uc = measurand_line("C", setup.reference_height_mm, m)
    pa, ua = measurand_line("A", setup.reference_height_mm, m)
    _, _, dist, _ = common_perpendicular(pc, uc, pa, ua)  # (foot_C - foot_A) . (A x C) / |.|
    n = len(pc)
    a, c = math.radians(setup.pose_a_deg), math.radians(setup.pose_c_deg)
    p = np.asarray(setup.pose_point_mm, dtype=float)
    q = pc + rotate_about(p - pc, uc, np.full(n, c))
    actual = pa + rotate_about(q - pa, ua, np.full(n, a))
    nominal = (nominal_rotations("A", np.array(a)) @ nominal_rotations("C", np.array(c))) @ p
    err = actual - nominal
    return {"ac_offset": -dist, "ac_squareness": np.arcsin(np.sum(ua * uc, axis=-1)),
            "pose_dx": err[:, 0], "pose_dy": err[:, 1], "pose_dz": err[:, 2]}
