"""line_laser's geometry: the sensor's rotation, the scan grid and the hexagonal-cell
artifact's height map and facets.
"""

from __future__ import annotations

import math

import numpy as np

from mtplan.models.line_laser._setup import SQ3


# --------------------------------------------------------------------------- geometry
def _rmat(rows):
    """Rotation matrices (..., 3, 3) from nested rows of scalars or arrays (...)."""
    return np.moveaxis(np.array([np.broadcast_arrays(*r) for r in rows], dtype=float), (0, 1),
                       (-2, -1))


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(c), np.zeros_like(c)
    return _rmat([[o, z, z], [z, c, -s], [z, s, c]])


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(c), np.zeros_like(c)
    return _rmat([[c, z, s], [z, o, z], [-s, z, c]])


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(c), np.zeros_like(c)
    return _rmat([[c, -s, z], [s, c, z], [z, z, o]])


def sensor_rotation(alpha_z: float, alpha_y: float, alpha_x: float) -> np.ndarray:
    """Sensor frame in the machine frame: ``Rx(alpha_x) @ Ry(alpha_y) @ Rz(alpha_z)``.

    Parameters
    ----------
    alpha_z, alpha_y, alpha_x : float
        Mounting angles [rad], applied about the machine's Z, then Y, then X.

    Returns
    -------
    array (3, 3)
        Columns: laser-line direction, sensor y, measuring direction (machine frame).
    """
    return rot_x(alpha_x) @ rot_y(alpha_y) @ rot_z(alpha_z)


def angles_from_rotation(r: np.ndarray):
    """(alpha_z, alpha_y, alpha_x) [rad] of rotations ``r`` (..., 3, 3)."""
    ay = np.arcsin(np.clip(r[..., 0, 2], -1.0, 1.0))
    ax = np.arctan2(-r[..., 1, 2], r[..., 2, 2])
    az = np.arctan2(-r[..., 0, 1], r[..., 0, 0])
    return az, ay, ax


def grid_u(setup) -> np.ndarray:
    """Positions of the points along the line x_l [mm], shape (points_per_line,)."""
    return np.linspace(-setup.line_width_mm / 2, setup.line_width_mm / 2, setup.points_per_line)


def grid_y(setup) -> np.ndarray:
    """Nominal machine Y of the triggers [mm], shape (lines,)."""
    return (np.arange(setup.lines) - (setup.lines - 1) / 2) * setup.step_mm


def pitch(setup) -> float:
    return setup.line_width_mm / (setup.points_per_line - 1)


def x_shift(setup) -> float:
    return setup.shift_fraction * setup.line_width_mm


#: outward in-plane normals of the six facets of a pocket (index k of an element)
_FACET_NORMALS = np.array([[SQ3 / 2, 0.5], [0.0, 1.0], [-SQ3 / 2, 0.5], [-SQ3 / 2, -0.5],
                           [0.0, -1.0], [SQ3 / 2, -0.5]])


def facet_layout(setup) -> tuple[int, int]:
    """Period (columns, rows) of the facets' position errors on the pocket lattice, in
    half lattice spacings (sx/2 = cell_size * sqrt(3)/2 along X, cell_size/2 along Y):
    wider than the scanned window (w0 + w by the scan's length) plus one pitch: the
    pockets the scans touch have their centres within the window widened by a pocket's
    circumradius (under half a pitch) on each side, so no two of them share an error
    (up to the Truth's +-100 mrad of rotation: the window then leans by at most
    0.1 (w0 + w) along Y)."""
    s = setup.cell_size_mm
    across = setup.line_width_mm + x_shift(setup)
    along = (setup.lines - 1) * setup.step_mm + 0.1 * across
    return 2 * math.ceil((across + s) / (s * SQ3)), 2 * math.ceil((along + s) / s)


def facet_count(setup) -> int:
    """Number of facet position errors (six per pocket of :func:`facet_layout`)."""
    cols, rows = facet_layout(setup)
    return 3 * cols * rows


def lattice_local(setup, x, y):
    """Offset (dx, dy) [mm] of points from the nearest pocket centre, and that pocket's
    index in the period of the facet errors (:func:`facet_layout`)."""
    s = setup.cell_size_mm
    sx, sy = s * SQ3, s
    # nearest centre of the hexagonal lattice = nearest of its two rectangular sub-lattices
    i1, j1 = np.round(x / sx), np.round(y / sy)
    i2, j2 = np.round(x / sx - 0.5), np.round(y / sy - 0.5)
    dx1, dy1 = x - i1 * sx, y - j1 * sy
    dx2, dy2 = x - (i2 + 0.5) * sx, y - (j2 + 0.5) * sy
    first = dx1 * dx1 + dy1 * dy1 <= dx2 * dx2 + dy2 * dy2
    cols, rows = facet_layout(setup)
    ci = np.where(first, 2 * i1, 2 * i2 + 1).astype(np.int64) % cols
    cj = np.where(first, 2 * j1, 2 * j2 + 1).astype(np.int64) % rows
    return np.where(first, dx1, dx2), np.where(first, dy1, dy2), ci * (rows // 2) + cj // 2


def height_map(setup, x, y, *, margin: bool = False, offsets=None, rows=None):
    """Height of the artifact and its slope, in the artifact's own frame.

    Parameters
    ----------
    setup : Setup
    x, y : arrays of the same shape
        Coordinates on the artifact [mm].
    margin : bool
        Also return the distance to the nearest edge of the plane the point lies on.
    offsets : array (m, facet_count(setup)), optional
        Position errors of the facets [mm], outward along their in-plane normal
        (source ``facet_position``), one row per error row; ``rows`` (same shape as
        ``x``) says which row each point uses.

    Returns
    -------
    z, dz_dx, dz_dy : arrays of that shape
        Height [mm] (0 on the land, ``-cell_depth_mm`` on the floors) and its gradient.
    margin : array of that shape, only when asked
        Distance [mm] in the plate's plane from the point to the nearest kink of the
        height map (edge of its facet, of the floor or of the land).
    """
    s = setup.cell_size_mm
    dx, dy, pocket = lattice_local(setup, x, y)
    tan_phi = math.tan(math.radians(setup.facet_angle_deg))
    opening = (s - setup.wall_mm) / 2
    depth = setup.cell_depth_mm
    if offsets is None:
        # hexagonal norm over the neighbour directions 30, 90, 150 deg:
        # max(|dy|, |c30 dx + dy/2|, |-c30 dx + dy/2|) = max(|dy|, c30 |dx| + |dy|/2)
        c30 = SQ3 / 2
        adx, ady = np.abs(dx), np.abs(dy)
        slant = c30 * adx + 0.5 * ady
        vertical = ady >= slant  # the facet whose normal is along Y
        rho = np.maximum(ady, slant)
        sdy = np.sign(dy)
        nx = np.where(vertical, 0.0, c30 * np.sign(dx))
        ny = np.where(vertical, sdy, 0.5 * sdy)
        corner = np.abs(0.5 * ady - c30 * adx)
        corner = np.where(vertical, corner, np.minimum(corner, ady))
    else:
        # each facet moved outward by its error: rho = max_k (n_k . d - offset_k)
        off = np.asarray(offsets)[np.asarray(rows)[..., None], 6 * pocket[..., None] + np.arange(6)]
        proj = dx[..., None] * _FACET_NORMALS[:, 0] + dy[..., None] * _FACET_NORMALS[:, 1] - off
        top = np.argmax(proj, axis=-1)
        two = np.sort(proj, axis=-1)[..., -2:]
        rho, corner = two[..., 1], two[..., 1] - two[..., 0]  # neighbours: |n_i - n_j| = 1
        nx, ny = _FACET_NORMALS[top, 0], _FACET_NORMALS[top, 1]
    z = np.clip((rho - opening) * tan_phi, -depth, 0.0)
    on_facet = (z < 0) & (z > -depth)
    g = tan_phi * on_facet
    gx, gy = nx * g, ny * g
    if not margin:
        return z, gx, gy
    floor = opening - depth / tan_phi
    edge = np.minimum(np.abs(rho - opening), np.abs(rho - floor))
    out = np.where(on_facet, np.minimum(edge, corner), edge)
    return z, gx, gy, out


def facet_element(setup, x, y, z) -> np.ndarray:
    """Index of the facet error a point on a facet depends on; -1 on land and floor."""
    dx, dy, pocket = lattice_local(setup, x, y)
    k = np.argmax(dx[..., None] * _FACET_NORMALS[:, 0] + dy[..., None] * _FACET_NORMALS[:, 1],
                  axis=-1)
    elem = 6 * pocket + k
    return np.where((z < 0) & (z > -setup.cell_depth_mm), elem, -1)


def standoff(setup) -> float:
    """Machine Z of the middle of the measuring range in scans 1 and 2 [mm]."""
    return -(setup.raise_mm + setup.cell_depth_mm) / 2

