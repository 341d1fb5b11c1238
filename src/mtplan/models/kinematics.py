"""Rigid-body kinematics of a vertical three-axis machine (cross table X on Y, head Z).

Helpers for :mod:`mtplan.models.geometry21`, batch-first and exact (no small-angle
shortcuts). The relative position of the tool point (the reading head) in the
workpiece (table) frame is the homogeneous-transform chain

.. math::

    p = f + T_X(x)\\, T_Y(y)\\, T_Z(z)\\, (h - f), \\qquad
    T_U(u) = \\mathrm{Trans}(u\\, d_U + \\delta_U(u))\\; R_U(u),

with :math:`\\delta_U = (E_{XU}, E_{YU}, E_{ZU})` the translational error motions,
:math:`R_U = R_x(E_{AU}) R_y(E_{BU}) R_z(E_{CU})` the exact rotation of the angular
error motions (this fixed order), :math:`d_X = e_x`, :math:`d_Y = R_z(E_{C0Y}) e_y`,
:math:`d_Z = R_y(E_{B0Z}) R_x(E_{A0Z}) e_z` the actual axis directions (squareness), and
:math:`h` the reading head's offset from the spindle reference point; the errors are defined
at the functional point f (ISO 230-1: the tool offset must be stated), about which
the angular error motions rotate. The order of
the chain gives the Abbe lever arms of a cross-table machine: X's angular errors act
on the lever (0, y, z) + h - f, Y's on (0, 0, z) + h - f, Z's on h - f (see
docs/geometry21.md).
"""

from __future__ import annotations

import numpy as np

__all__ = ["rotate", "rotate_inverse", "rotation_matrix", "chain", "polyval"]


def _cos_sin(angle):
    """(cos, sin) of an array of angles; exactly (1, 0) without the work when all are 0."""
    if not np.any(angle):
        return 1.0, 0.0
    return np.cos(angle), np.sin(angle)


def rotate(a, b, c, v, cs=(None, None, None)):
    """Apply R = Rx(a) Ry(b) Rz(c) to vectors `v`, exactly.

    Parameters
    ----------
    a, b, c : arrays broadcastable to each other, shape (...)
        Rotation angles about x, y, z [rad].
    v : array of shape (..., 3)
        Vectors.
    cs : three (cos, sin) pairs or None
        The angles' cosines and sines where already known (the same values).

    Returns
    -------
    array of shape (..., 3)
    """
    (ca, sa), (cb, sb), (cc, sc) = (_cos_sin(x) if t is None else t
                                    for x, t in zip((a, b, c), cs, strict=True))
    vx, vy, vz = v[..., 0], v[..., 1], v[..., 2]
    # Rz
    x1 = cc * vx - sc * vy
    y1 = sc * vx + cc * vy
    # Ry, Rx: written into the result (no stacked copy)
    out = np.empty((*np.broadcast_shapes(np.shape(x1), np.shape(vz), np.shape(ca),
                                         np.shape(cb)), 3))
    out[..., 0] = cb * x1 + sb * vz
    z2 = -sb * x1 + cb * vz
    out[..., 1] = ca * y1 - sa * z2
    out[..., 2] = sa * y1 + ca * z2
    return out


def rotate_inverse(a, b, c, v):
    """Apply the inverse of Rx(a) Ry(b) Rz(c), i.e. Rz(-c) Ry(-b) Rx(-a), to `v`, exactly.

    Shapes as for :func:`rotate`.
    """
    ca, sa = np.cos(a), np.sin(a)
    cb, sb = np.cos(b), np.sin(b)
    cc, sc = np.cos(c), np.sin(c)
    vx, vy, vz = v[..., 0], v[..., 1], v[..., 2]
    y1 = ca * vy + sa * vz
    z1 = -sa * vy + ca * vz
    x2 = cb * vx - sb * z1
    z2 = sb * vx + cb * z1
    x3 = cc * x2 + sc * y1
    y3 = -sc * x2 + cc * y1
    return np.stack(np.broadcast_arrays(x3, y3, z2), axis=-1)


def rotation_matrix(a: float, b: float, c: float) -> np.ndarray:
    """The matrix Rx(a) Ry(b) Rz(c) (for tests and documentation), shape (3, 3)."""
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    return rx @ ry @ rz


def polyval(coef: np.ndarray, powers, u: np.ndarray) -> np.ndarray:
    """Sum_k coef[..., k] u**powers[k] for a batch of coefficient vectors.

    Parameters
    ----------
    coef : array of shape (n, K)
    powers : sequence of K ints
    u : array of shape (m,)

    Returns
    -------
    array of shape (n, m)
    """
    if len(powers) == 0:
        return np.zeros((coef.shape[0], u.shape[0]))
    basis = np.stack([u ** int(k) for k in powers])  # (K, m)
    return coef @ basis


def _known(trig: dict, axis: str) -> tuple:
    """The (cos, sin) pairs of axis `axis`'s three angular errors the caller gave (or None)."""
    return tuple(trig.get(f"E{r}{axis}") for r in "ABC")


def chain(values: dict, x: np.ndarray, y: np.ndarray, z: np.ndarray, head: np.ndarray,
          ref: np.ndarray | None = None, trig: dict | None = None):
    """Relative position of the head in the workpiece frame, exact.

    Parameters
    ----------
    values : dict of str to array of shape (n, m) or (n, 1)
        The 21 error functions evaluated at the points (ISO names, mm and rad);
        the squareness errors EC0Y, EB0Z, EA0Z have shape (n, 1).
    x, y, z : arrays of shape (m,)
        Commanded axis positions [mm].
    head : array of shape (3,) or (m, 3)
        Head offset from the spindle reference point [mm], one for all points or one per
        point (tests repeated with several head positions).
    ref : array of shape (3,), optional
        Offset of the functional point at which the errors are defined (the angular
        error motions rotate about it); default the spindle reference point (0, 0, 0).
    trig : dict of str to (cos, sin), optional
        The angular errors' cosines and sines where the caller has them (the same values).

    Returns
    -------
    array of shape (n, m, 3)
        Position of the head relative to the workpiece frame [mm].
    """
    v, t = values, trig or {}
    n = next(iter(v.values())).shape[0]
    m = x.shape[0]
    # axis directions (squareness), exact
    cy = v["EC0Y"]
    d_y = np.stack([-np.sin(cy), np.cos(cy), np.zeros_like(cy)], axis=-1)  # (n,1,3)
    bz, az = v["EB0Z"], v["EA0Z"]
    d_z = np.stack([np.sin(bz) * np.cos(az), -np.sin(az), np.cos(bz) * np.cos(az)], axis=-1)
    ref = np.zeros(3) if ref is None else np.asarray(ref, dtype=float)
    hv = np.broadcast_to(np.asarray(head, dtype=float) - ref, (n, m, 3))  # (3,) or (m, 3)
    # Z (vectors relative to the functional point; rotations about it)
    # (in place, in the same order of operations: (p + u d) + delta)
    p = rotate(v["EAZ"], v["EBZ"], v["ECZ"], hv, _known(t, "Z"))
    p += z[None, :, None] * d_z
    for i, c in enumerate("XYZ"):
        p[..., i] += v[f"E{c}Z"]
    # Y
    p = rotate(v["EAY"], v["EBY"], v["ECY"], p, _known(t, "Y"))
    p += y[None, :, None] * d_y
    for i, c in enumerate("XYZ"):
        p[..., i] += v[f"E{c}Y"]
    # X
    p = rotate(v["EAX"], v["EBX"], v["ECX"], p, _known(t, "X"))
    p = p + ref
    p[..., 0] += x[None, :] + v["EXX"]
    p[..., 1] += v["EYX"]
    p[..., 2] += v["EZX"]
    return p
