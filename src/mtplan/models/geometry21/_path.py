"""geometry21's path: what the machine's path deviations share between readings.

The repeatability's AR(1) filter along each pass (in millimetres of path), the repeatable
short-wave residual beyond the polynomials (a random function of each axis's position, the
same in every pass), and the joint fit's whitening under both (a sparse whitening of the AR(1)
process, updated for the residual's low-rank covariance). See the package's docstring and
docs/geometry21.md.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from mtplan.fitting.linear import filter_whitening
from mtplan.models.geometry21._layout import Geometry, geometry
from mtplan.models.geometry21._setup import Setup, sizeless


@functools.lru_cache(maxsize=8)
def repeatability_filter(setup: Setup):
    """The AR(1) filter of the repeatability along each pass, a sparse lower-triangular
    matrix (M, M) from innovations to path deviations (None when the length is 0).

    Within a pass (one plane, head, test and pass: contiguous readings, equally spaced
    along the path by s mm) x_0 = e_0 and x_k = phi x_(k-1) + sqrt(1 - phi^2) e_k,
    phi = exp(-s / length): every x has the innovations' variance, and readings d mm
    apart correlate by exp(-d / length) whatever the spacing; passes are independent.
    """
    length = setup.repeatability_correlation_mm
    if length <= 0:
        return None
    return _ar1_filter(_pass_lengths(sizeless(setup)), length)


@functools.lru_cache(maxsize=16)
def _pass_lengths(key: Setup) -> tuple:
    """(number of readings, their spacing along the path [mm]) of each pass (contiguous
    readings of one plane, head, test and pass), in order: all the filter depends on
    besides the correlation length."""
    geo = geometry(key)
    keys = np.stack([geo.plane, geo.head, geo.test, geo.pass_], axis=1)
    start = np.ones(len(keys), dtype=bool)
    start[1:] = np.any(keys[1:] != keys[:-1], axis=1)
    first = np.flatnonzero(start)
    counts = np.diff(np.append(first, len(keys)))
    line = key.line_length_mm / (key.line_points - 1)
    full = key.circle_arc_deg >= 360.0
    arc = key.circle_radius_mm * math.radians(key.circle_arc_deg)
    circle = arc / (key.circle_points if full else key.circle_points - 1)
    return tuple((int(c), circle if geo.test[i] == 2 else line)
                 for i, c in zip(first.tolist(), counts.tolist()))


@functools.lru_cache(maxsize=8)
def _ar1_filter(passes: tuple, length: float):
    import scipy.sparse as sp

    rows, cols, vals = [], [], []
    a = 0
    for n, step in passes:
        phi = math.exp(-step / length)
        gain = math.sqrt(1.0 - phi * phi)
        k = np.arange(n)
        j, i = np.meshgrid(k, k)  # x_i from e_j, j <= i
        keep = j <= i
        w = phi ** (i - j) * np.where(j == 0, 1.0, gain)
        rows.append(a + i[keep])
        cols.append(a + j[keep])
        vals.append(w[keep])
        a += n
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(a, a))


#: knot spacing and correlation length of the machine's repeatable short-wave path residual
#: (source ``path_residual``) along each axis [mm]: ball-screw pitches and guideway waviness
#: are 5-20 mm long, shorter than the travels the polynomials describe
RESIDUAL_KNOT_MM = 2.5
RESIDUAL_CORRELATION_MM = 5.0


#: wavelength and coherence length of the machine's repeatable medium-wave deviation (source
#: ``medium_wave``) [mm]: guideway waviness and the accumulated pitch errors of a ball screw,
#: between the short-wave residual's few millimetres and the reach of the polynomials
MEDIUM_WAVELENGTH_MM = 40.0
MEDIUM_COHERENCE_MM = 40.0
#: the fields beyond the polynomials: source name -> how each is drawn on the knots
FIELDS = ("path_residual", "medium_wave")


def residual_knots(geo: Geometry) -> tuple[float, int]:
    """(first knot [mm], number of knots) of the residual's grid: every axis's commanded
    positions lie between the second and the last but one."""
    lo, hi = float(geo.cmd.min()), float(geo.cmd.max())
    first = math.floor(lo / RESIDUAL_KNOT_MM) * RESIDUAL_KNOT_MM - RESIDUAL_KNOT_MM
    return first, int(math.ceil((hi - first) / RESIDUAL_KNOT_MM)) + 2


def field_filter(k: int, field: str = "path_residual") -> np.ndarray:
    """(K, elements): the knots' values per unit element of a field beyond the polynomials,
    unit variance at every knot. ``path_residual``: the AR(1) filter of its innovations
    (correlation exp(-d / RESIDUAL_CORRELATION_MM), K elements). ``medium_wave``: a
    stationary field of covariance cos(2 pi d / MEDIUM_WAVELENGTH_MM)
    exp(-d^2 / (2 MEDIUM_COHERENCE_MM^2)) (waves of about that length, coherent over a few),
    its elements the eigen-modes of the knots' covariance that carry it (those above 1e-9 of
    the largest)."""
    if field == "path_residual":
        return _ar1_filter(((k, RESIDUAL_KNOT_MM),), RESIDUAL_CORRELATION_MM).toarray()
    if field == "medium_wave":
        return _medium_filter(k)
    raise ValueError(f"no field {field!r} (known: {', '.join(FIELDS)})")


@functools.lru_cache(maxsize=8)
def _medium_filter(k: int) -> np.ndarray:
    d = RESIDUAL_KNOT_MM * np.subtract.outer(np.arange(k), np.arange(k))
    c = np.cos(2 * math.pi * d / MEDIUM_WAVELENGTH_MM) * np.exp(
        -0.5 * (d / MEDIUM_COHERENCE_MM) ** 2)
    lam, vec = np.linalg.eigh(c)
    keep = lam > 1e-9 * lam[-1]
    return vec[:, keep][:, ::-1] * np.sqrt(lam[keep][::-1])


def field_elements(geo: Geometry, field: str = "path_residual") -> int:
    """Elements per axis and direction of a field beyond the polynomials (its source's last
    dimension)."""
    return field_filter(residual_knots(geo)[1], field).shape[1]


def _residual_factors(key: Setup, field: str = "path_residual") -> tuple:
    """A field's readings map in factors: (plate-frame rows (M, plate component,
    direction), the linear interpolation from the knots per axis (3 sparse (M, K), two
    knots a reading), the knots' values per element (K, elements), :func:`field_filter`)."""
    import scipy.sparse as sp

    geo = geometry(key)
    first, k = residual_knots(geo)
    f = field_filter(k, field)
    t = (geo.cmd - first) / RESIDUAL_KNOT_MM  # (M, axis) in knots
    i = np.floor(t).astype(int)
    frac = t - i
    m = t.shape[0]
    readings = np.arange(m).repeat(2)
    hats = tuple(sp.csc_matrix((np.column_stack([1.0 - frac[:, a], frac[:, a]]).ravel(),
                                (readings, np.column_stack([i[:, a], i[:, a] + 1]).ravel())),
                               shape=(m, k)) for a in range(3))
    return geo.basis[geo.plane][:, :, :2].transpose(0, 2, 1), hats, f


@functools.lru_cache(maxsize=8)
def residual_basis(key: Setup, field: str = "path_residual") -> np.ndarray:
    """(2M, 3 x 3 x K): each reading's plate-frame (u, v) per unit innovation of the path
    residual (axis, direction of the deviation, knot), in the source's order.

    Per axis and direction the residual is a stationary AR(1) field over knots
    ``RESIDUAL_KNOT_MM`` apart (correlation exp(-d / RESIDUAL_CORRELATION_MM), unit variance,
    :func:`_ar1_filter` of the innovations), linearly interpolated at the axis's commanded
    position; the deviation's direction is taken into the plate's frame. `field`
    ``medium_wave``: the same for that source (:func:`field_filter`)."""
    rows, hats, f = _residual_factors(key, field)
    # (M, axis, K): the field per innovation (the interpolation as a dense product)
    field = np.stack([hat.toarray() @ f for hat in hats], axis=1)
    # (M, plate component, axis, direction, knot): one product of broadcast factors, laid
    # out in that order so the reshape is a view
    out = np.multiply(rows[:, :, None, :, None], field[:, None, :, None, :], order="C")
    return out.reshape(2 * rows.shape[0], -1)


def residual_at(setup: Setup, innovations: np.ndarray, axis: int,
                positions, field: str = "path_residual") -> np.ndarray:
    """The path residual's value [mm] (n, positions, direction x, y, z) along `axis` (0, 1,
    2 for X, Y, Z) at `positions` [mm], for the source's draws `innovations` (n, 3, 3, K):
    the same field the readings see (:func:`residual_basis`), so a simulated machine's true
    error at a position is its polynomial plus this (the function ``E<direction><axis>``,
    e.g. X's deviation along y adds to EYX). Positions must lie on the field's knot grid's
    span (every commanded position of the test and a knot beyond). `field` ``medium_wave``:
    that source's field (:func:`field_filter`)."""
    geo = geometry(sizeless(setup))
    first, k = residual_knots(geo)
    u = np.asarray(positions, dtype=float).ravel()
    t = (u - first) / RESIDUAL_KNOT_MM
    outside = (t < 0) | (t > k - 1)
    if np.any(outside):
        raise ValueError(f"positions {u[outside].tolist()} along {'XYZ'[axis]} lie outside the "
                         f"path residual's field [{first:g}, "
                         f"{first + (k - 1) * RESIDUAL_KNOT_MM:g}] mm")
    f = field_filter(k, field)
    knots = np.asarray(innovations, dtype=float)[:, axis] @ f.T  # (n, direction, K)
    i = np.minimum(np.floor(t).astype(int), k - 2)
    frac = t - i
    out = knots[:, :, i] * (1.0 - frac) + knots[:, :, i + 1] * frac  # (n, direction, P)
    return np.swapaxes(out, 1, 2)


def residual_response(key: Setup, left: np.ndarray, field: str = "path_residual") -> np.ndarray:
    """``left @ residual_basis(key)`` for a map `left` (n, 2M) of the readings, from the
    basis's factors, never forming it (2M x 9K, 17 MB at the defaults): the map is taken
    into each reading's deviation directions, gathered onto the knots by the interpolation
    (its transpose), then through the knots' filter. Equal to the product to rounding
    (tested). `field` ``medium_wave``: that source's (:func:`field_filter`)."""
    rows, hats, f = _residual_factors(key, field)
    n, m, k = left.shape[0], rows.shape[0], f.shape[0]
    u, v = left[:, 0::2], left[:, 1::2]  # (n, M) each: the map of each plate component
    q = np.stack([u * rows[:, 0, d] + v * rows[:, 1, d] for d in range(3)], axis=1)
    q = q.reshape(n * 3, m)  # (n x direction, M): the map along each deviation direction
    knots = np.stack([(q @ hat).reshape(n, 3, k) for hat in hats], axis=1)
    return (knots @ f).reshape(n, -1)  # (n, axis x direction x element)


def reading_whitener(setup: Setup):
    """Whitening (2M, 2M) of the readings' scatter that the joint fit weighs: encoder noise,
    the AR(1) repeatability (:func:`mtplan.fitting.linear.filter_whitening`) and the path
    residual that every pass repeats (a low-rank term, :class:`_LowRank`); None where all is
    white (equal weights are then the efficient ones). A full circle's CW pass starts where
    the CCW one does, so the two are not weighted as mirror images: the reversal and a growth
    linear in time no longer cancel exactly (0.03 um in EXX, 0.08 urad in EAY at the
    defaults); weighting the CW pass as the CCW one reversed would, at 13 % more u in EBX,
    ECX, EAY."""
    ratios = weight_ratios(setup)
    return None if ratios is None else whitening(sizeless(setup), *ratios)


def weight_ratios(setup: Setup) -> tuple | None:
    """What the joint fit's weights depend on besides the geometry: (the encoder noise over
    the repeatability, or None where the repeatability is white; the path residual's
    coefficients' standard deviation over the same unit); None for equal weights."""
    correlated = repeatability_filter(setup) is not None and setup.repeatability_um > 0
    unit = setup.repeatability_um if correlated else math.hypot(setup.encoder_noise_um,
                                                                setup.repeatability_um)
    residual = setup.path_residual_um
    if unit <= 0 or not (correlated or residual > 0):
        return None
    return (setup.encoder_noise_um / unit if correlated else None, residual / unit)


@functools.lru_cache(maxsize=8)
def whitening(key: Setup, noise_ratio: float | None, residual_ratio: float):
    """The whitening of :func:`reading_whitener` for the geometry of `key` (in units of the
    repeatability's variance, or of the white scatter's where it is white)."""
    import scipy.sparse as sp

    if noise_ratio is None:
        w = sp.identity(2 * geometry(key).plane.size, format="csr")
    else:
        w = _whitener(_pass_lengths(key), key.repeatability_correlation_mm, noise_ratio)
    if residual_ratio > 0:
        w = _LowRank(w, residual_ratio * residual_basis(key))
    return w


class _LowRank:
    """The whitening ``W' = (I - Q diag(k) Q^T) W`` of ``C + U U^T`` from the whitening W of
    C (``W^T W = C^-1``): with ``W U = Q S R^T`` (thin SVD), ``k = 1 - 1 / sqrt(1 + s^2)``,
    so that ``W'^T W' = W^T (I + W U U^T W^T)^-1 W = (C + U U^T)^-1`` (Woodbury). Supports
    ``w @ x`` and ``w.T @ y``, all :func:`mtplan.fitting.linear.gls_pinv` asks."""

    def __init__(self, w, u: np.ndarray, *, _transposed: bool = False, _parts=None):
        if _parts is None:
            q, sv, _ = np.linalg.svd(np.asarray(w @ u), full_matrices=False)
            keep = sv > 1e-12 * (sv[0] if sv.size else 1.0)
            _parts = (w, q[:, keep], 1.0 - 1.0 / np.sqrt(1.0 + sv[keep] ** 2))
        self._parts, self._transposed = _parts, _transposed

    @property
    def T(self):
        return _LowRank(None, None, _transposed=not self._transposed, _parts=self._parts)

    def __matmul__(self, x):
        w, q, k = self._parts
        if self._transposed:  # W^T (I - Q K Q^T) y
            y = np.asarray(x)
            return np.asarray(w.T @ (y - q @ (k[:, None] * (q.T @ y))))
        y = np.asarray(w @ x)
        return y - q @ (k[:, None] * (q.T @ y))


@functools.lru_cache(maxsize=8)
def _whitener(passes: tuple, length: float, ratio: float):
    return filter_whitening(_ar1_filter(passes, length), ratio, 2)


