"""tracker_frame's rotations and vectors, batch-first, and the patent's frame: the longest
travel kept, the other two axes corrected by cross products.
"""

from __future__ import annotations

import numpy as np

from mtplan.models.tracker_frame._setup import Setup


# --------------------------------------------------------------------------- geometry
def rot(axis: np.ndarray, angle) -> np.ndarray:
    """Rotation matrices (..., 3, 3) about unit `axis` (..., 3) by `angle` (...) [rad]
    (Rodrigues, ``I + sin K + (1 - cos) K K``; axis and angle broadcast)."""
    angle = np.asarray(angle, dtype=float)
    axis = np.asarray(axis, dtype=float)
    if angle.ndim == 0 and axis.ndim == 1:  # one matrix: the same sums, without arrays
        x, y, z = (float(v) for v in axis)
        s, c = float(np.sin(angle)), 1.0 - float(np.cos(angle))
        return np.array([
            [1.0 + c * (-z * z - y * y), s * -z + c * (y * x), s * y + c * (z * x)],
            [s * z + c * (y * x), 1.0 + c * (-z * z - x * x), s * -x + c * (z * y)],
            [s * -y + c * (z * x), s * x + c * (z * y), 1.0 + c * (-y * y - x * x)]])
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    k = np.zeros((*x.shape, 3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -z, y, -x
    k[..., 1, 0], k[..., 2, 0], k[..., 2, 1] = z, -y, x
    kk = np.empty_like(k)  # K K, element by element (K is skew: K K = a a^T - |a|^2 I)
    kk[..., 0, 0], kk[..., 1, 1], kk[..., 2, 2] = -z * z - y * y, -z * z - x * x, -y * y - x * x
    kk[..., 0, 1] = kk[..., 1, 0] = y * x
    kk[..., 0, 2] = kk[..., 2, 0] = z * x
    kk[..., 1, 2] = kk[..., 2, 1] = z * y
    s, c = np.sin(angle)[..., None, None], np.cos(angle)[..., None, None]
    return np.eye(3) + s * k + (1 - c) * kk


def mv(r: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Matrices (..., 3, 3) times vectors (..., 3), broadcast."""
    return np.einsum("...ij,...j->...i", r, v)


def rxyz(rx: float, ry: float, rz: float) -> np.ndarray:
    """``Rz(rz) Ry(ry) Rx(rx)`` (fixed-axis X, then Y, then Z) [rad]."""
    e = np.eye(3)
    return rot(e[2], rz) @ rot(e[1], ry) @ rot(e[0], rx)


def angles(r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of :func:`rxyz` for matrices (..., 3, 3): (rx, ry, rz) [rad]."""
    rx = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    ry = np.arctan2(-r[..., 2, 0], np.hypot(r[..., 2, 1], r[..., 2, 2]))
    rz = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    return rx, ry, rz


def cyc(values: tuple, k: int) -> np.ndarray:
    """Element k (cycled) of a per-sub-machine tuple: a float, or an array (m,) when the
    truth is one per batch row (a posterior's walkers)."""
    return np.asarray(values[k % len(values)], dtype=float)


def cross(a, b):
    """Cross products of vectors (..., 3), broadcast: ``np.cross``'s sums without its
    axis handling (a few microseconds, where the geometry of one truth calls it often)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack(np.broadcast_arrays(a1 * b2 - a2 * b1, a2 * b0 - a0 * b2,
                                        a0 * b1 - a1 * b0), axis=-1)


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _frame_axes(setup: Setup) -> tuple[int, int, int]:
    """(kept, second, third) axis indices: longest travel kept, then the next longest."""
    travels = [setup.travel_x_mm, setup.travel_y_mm, setup.travel_z_mm]
    order = sorted(range(3), key=lambda i: (-travels[i], i))
    return order[0], order[1], order[2]


def orthonormal(setup: Setup, ux, uy, uz) -> np.ndarray:
    """The patent's frame: longest-travel axis kept, the others corrected by cross products.

    Returns rotation matrices (..., 3, 3) whose columns are the frame's X, Y, Z axes.
    """
    u = [ux, uy, uz]
    i, j, k = _frame_axes(setup)
    cyclic = (j - i) % 3 == 1
    cols = [None, None, None]
    cols[i] = unit(u[i])
    cols[k] = unit(cross(cols[i], u[j]) if cyclic else cross(u[j], cols[i]))
    cols[j] = cross(cols[k], cols[i]) if cyclic else cross(cols[i], cols[k])
    return np.stack(cols, axis=-1)
