"""geometry21's readings' Jacobian at zero error in closed form: the chain rule of the
kinematic chain (it was central differences, 2 evaluations of the chain per parameter);
the tests hold it to the central differences (relative 1e-6 of its largest entry).
"""

from __future__ import annotations

import numpy as np

from mtplan.models.geometry21._layout import Geometry
from mtplan.models.geometry21._setup import AXIS, KIND, NAMES


def _cross(axis: int, v: np.ndarray) -> np.ndarray:
    """e_axis x v for vectors v (M, 3): the first-order motion of v under a small rotation
    about that axis."""
    out = np.zeros_like(v)
    b, c = (axis + 1) % 3, (axis + 2) % 3
    out[:, c] = v[:, b]
    out[:, b] = -v[:, c]
    return out


def _value_effects(geo: Geometry) -> dict:
    """Function name -> (M, 3) machine-frame first-order motion of each reading's head
    position per unit of the function's value there (:func:`mtplan.models.kinematics.chain`
    at zero error: translations add; angular errors of Z act on the head's lever (h - f),
    of Y on it plus z e_z, of X on that plus y e_y; the squareness tilts the axis directions)."""
    m = geo.plane.size
    x, y, z = geo.cmd.T
    hv = geo.hvec - geo.ref
    p_z = hv.copy()
    p_z[:, 2] += z
    p_y = p_z.copy()
    p_y[:, 1] += y
    lever = {"Z": hv, "Y": p_z, "X": p_y}
    eye = np.eye(3)
    out = {}
    for name in NAMES:
        kind = KIND[name]
        if kind == "sq":
            e = np.zeros((m, 3))
            if name == "EC0Y":  # d_y = (-sin c, cos c, 0)
                e[:, 0] = -y
            elif name == "EB0Z":  # d_z = (sin b cos a, -sin a, cos b cos a)
                e[:, 0] = z
            else:  # EA0Z
                e[:, 1] = -z
        elif kind == "ang":  # E[ABC]U: rotation about x, y, z of axis U
            e = _cross("ABC".index(name[1]), lever[name[2]])
        else:  # E[XYZ]U: translation along x, y, z
            e = np.broadcast_to(eye["XYZ".index(name[1])], (m, 3))
        out[name] = e
    return out


def zero_jacobian(geo: Geometry) -> np.ndarray:
    """J (2M, P): the readings' first-order response to every parameter at zero error
    (coefficients, then each plate's offset u, v and rotation, then the extra heads'
    settings), the same layout as ``predict_readings``'s readings flattened."""
    m = geo.plane.size
    loc = np.empty((m, 3))
    for k in range(3):  # the nominal head positions in each plate's frame
        sel = geo.plane == k
        loc[sel] = (geo.cmd[sel] + geo.hvec[sel] - geo.origin[k]) @ geo.basis[k]
    jac = np.zeros((m, 2, geo.n_par))
    effects = _value_effects(geo)
    for name in NAMES:
        powers, sl = geo.layout[name]
        e = effects[name]
        uv = np.empty((m, 2))
        for k in range(3):
            sel = geo.plane == k
            uv[sel] = e[sel] @ geo.basis[k][:, :2]
        u = geo.cmd[:, AXIS[name]]
        for j, pw in zip(range(sl.start, sl.stop), powers, strict=True):
            jac[:, :, j] = uv * (u**pw)[:, None] if pw else uv
    nc = geo.n_coef
    for k in range(3):
        sel = geo.plane == k
        jac[sel, 0, nc + 3 * k] = -1.0  # offset: the reading is loc - offset
        jac[sel, 1, nc + 3 * k + 1] = -1.0
        jac[sel, 0, nc + 3 * k + 2] = loc[sel, 1]  # rotation c: Rz(-c) loc
        jac[sel, 1, nc + 3 * k + 2] = -loc[sel, 0]
    for e, (_k, sl) in enumerate(geo.xslices):  # an extra head's setting adds
        jac[sl, 0, nc + 9 + 2 * e] = 1.0
        jac[sl, 1, nc + 10 + 2 * e] = 1.0
    return jac.reshape(2 * m, geo.n_par)
