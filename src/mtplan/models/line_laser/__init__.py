"""Mounting error angles of a line-laser profile sensor (line-laser patent application of 2019).

A line-laser profile sensor on a three-axis machine reports, at each trigger, a
profile: heights ``z_l`` at fixed points ``x_l`` along its laser line. The machine
moves it along Y and triggers a profile every ``step_mm`` (dy). Its mounting is off
by small rotations ``alpha_z`` about Z, then ``alpha_y`` about Y, then ``alpha_x``
about X (rotations about the fixed machine axes, applied in that order, so the
sensor's frame is ``R = Rx(alpha_x) Ry(alpha_y) Rz(alpha_z)``; its laser line runs
along ``R e_x`` and it measures along ``R e_z``). The machine frame is the scan's:
Y along the Y motion (which builds the data's third coordinate), X in the plane of the
X and Y motions, Z normal to both; the X and Z motions deviate from those axes by the
machine's squareness errors. The method scans a standard artifact with a periodic
pattern three times (the patent's claim 3):

1. along Y;
2. shifted by ``w = shift_fraction * line_width_mm`` in +X, same Y path;
3. raised by ``h = raise_mm`` in +Z, same path as scan 2.

Forward model
-------------
- **Artifact**: a plate with a honeycomb of hexagonal pockets (the patent's figure 3),
  pitch ``cell_size_mm`` between neighbouring cells, land ``wall_mm`` between
  pockets, depth ``cell_depth_mm``; the pocket walls are plane facets inclined at
  ``facet_angle_deg`` to the plate (a machined pocket with drafted walls). The
  height map is exactly piecewise planar (top land, six facets, floor). The lattice's
  neighbour directions are at 30, 90 and 150 deg, so every facet slopes partly along Y.
  The artifact lies on the table with an unknown pose (Truth: lattice offset,
  rotation about Z, two small tilts); no estimator uses that pose.
- **Sensor**: the laser line has ``points_per_line`` points spread evenly over
  ``line_width_mm`` (w0); each point is a ray through ``P + x_l R e_x`` along
  ``R e_z`` (a telecentric model: the reported ``x_l`` does not depend on the height;
  a real fan-beam sensor's ``x_l`` would, which changes nothing in the method). The
  reported height is the ray parameter ``t`` of the first intersection with the
  artifact, solved **exactly** on the whole batch by Newton's method on the
  piecewise-planar height map (the ray's drift across the facets is a few
  micrometres, so each step contracts the error by ~1e-2 and the iteration ends at
  machine precision; inside one facet one step is exact). ``z_l = 0`` is the middle
  of the measuring range ``range_mm``; the stand-off is set before scanning so that
  all three scans fit in the range (the patent's claim 5), and set-ups where they
  cannot are refused.
- **Error sources** (each sized by its set-up field; the field's doc names the data
  sheet or standard its default comes from):

  - sensor noise on every height;
  - the sensor's *linearity*: a height error ``e(x_l)`` along the line, the same in
    all three scans (a calibration error of the sensor), modelled as
    ``e = sum_k c_k sqrt(2k+1) P_k(2 x_l / w0)`` over the Legendre degrees k = 2, 3, 4,
    the ``c_k`` normal with standard deviation ``linearity_um / sqrt(3)`` and drawn once
    per test, so the expected RMS of ``e`` along the line is ``linearity_um``. Degrees 0
    and 1 are left out: an offset cancels in every difference, and a tilt of the
    calibration along the line is, to the data, the same thing as ``alpha_y`` (it is
    part of the sensor's data frame that the method determines). Scans 1 and 2 see the
    same artifact point at ``x_l + w`` and ``x_l``, so ``e(x_l + w) - e(x_l)`` enters
    ``alpha_y`` with lever ``1/w`` (averaged over the mirror-symmetric common part, only
    the odd degree survives in the patent's mean: u(alpha_y) = 0.27 linearity_um / w at
    the default); scans 2 and 3 see it at the same ``x_l``, where it cancels;
  - the *Z scale* (gain) error of the height reading, ``z = (1 + s) t``, about the
    middle of the range: it scales every height difference, hence ``h'`` by ``s h``;
  - the machine's positioning error of the X shift ``w`` (scans 2 and 3 share it:
    scan 3 does not move in X) and of the raise ``h``;
  - the *squareness* of the X motion to Y (the shift runs along
    ``(cos g, sin g, 0)``: scan 2 moves by ``w g`` along Y, which is ``alpha_z`` to
    the data) and of the Z motion to Y (the raise runs along ``(0, sin e, cos e)``:
    scan 3 moves by ``h e`` along Y, which is ``alpha_x`` to the registration);
  - the Y position of each scan's trigger train (one offset per scan: the
    encoder/scale triggers restart for each scan);
  - *drift*: a thermal drift velocity of the sensor relative to the artifact, constant
    during the test, which displaces scan k by ``v (t_k - t_1)`` (start times from the
    duration model, :func:`duration`). The drift within a scan is the same in all
    three scans and left out. At the default timing (scans 1.5 s apart) a drift of
    10 um/h moves the scans by nanometres; it matters when the scans are minutes apart.
  - the *position of each facet* of the artifact's pockets (``facet_position_um``), along
    its in-plane normal, independent from facet to facet: the artifact is machined, and
    its pattern is known to the machining's few micrometres, not exactly. The
    registration compares the scans of one and the same artifact and does not see it;
    the ``pattern`` estimator and the posterior, which use the stated pattern, do. Of the
    artifact's geometry this is what matters: the pattern's *shape* (where its facets
    lie relative to each other) carries the single-scan information on ``alpha_z``
    (the line's skew to the Y motion shears the sampled lattice). Errors common to the
    whole pattern (pitch, depth, facet angle, land width: tens of micrometres or a
    fraction of a degree) move the angles by nothing the linearised information can
    see (docs/line_laser.md has the figures).

Estimators
----------
``patent`` (the patent, claims 7 to 9):

- the heights are binarised (pocket / land, threshold halfway between the extremes of
  the scan); scan 1 is moved by ``w`` along the line (linear interpolation, ``w`` is a
  known distance) and shifted against scan 2 by whole rows ``n = -n_max..n_max``; the
  overlap is the *fraction* of agreeing points of the common part (the patent says the
  amount of coinciding data; a raw count favours ``n = 0`` because the common part
  shrinks with ``|n|``, so we normalise). ``l_z = n1 dy``, ``alpha_z = arctan(l_z/w)``:
  **quantised** in steps of about ``dy/w``. ``n1`` is the whole shift *nearest* the true
  one, as the patent means: the binarised overlap is a staircase whose steps sit where the
  facets' edges cross the rows, so its argmax alone switched up to 0.64 step off the
  half-way points, wherever the artifact lay; the overlap's best shift is refined within
  the two row intervals beside it (rows interpolated linearly, the centred sum of squared
  differences minimised in closed form) and rounded (:func:`_nearest_row`), which puts
  the switch points at +-1/2 step wherever the artifact lies (tested to 0.05 step).
  ``simulate`` states its u as ``step / sqrt(12)`` (:func:`resolution`), never 0.
- ``l_y`` is the mean height difference (scan 1 minus scan 2) over the common part
  aligned by ``w`` and ``n1``, ``alpha_y = arctan(l_y/w)``. The patent fixes no sign
  convention; the signs here make both formulas right to first order in this
  module's conventions.
- ``h'`` is the mean height difference of scans 2 and 3 at the same points,
  ``alpha_x = arccos(h/h')``. **Sign-blind**: the estimator returns ``|alpha_x|``
  (0 when ``h' <= h``, where the arccos has no real value). What ``h'`` is, exactly:
  on a plane with unit normal ``n``, raising the sensor by ``h`` along ``a`` (the Z
  motion) changes the reading by ``h (n . a) / (n . d)`` (``d`` the measuring
  direction), and ``h'`` is the mean of that over the points, weighted by how many
  fall on each plane (plus the few rays whose hit crosses a kink between the scans).
  On the land and floors of a *level* artifact that is ``h / (cos alpha_x cos
  alpha_y)``, the patent's relation, whose arccos is ``arccos(cos alpha_x cos alpha_y)
  ~ sqrt(alpha_x^2 + alpha_y^2)``: even there it absorbs ``alpha_y``, and with the
  artifact's tilt it gives the angle between ``d`` and the plate's normal (1.90 mrad
  at the default truth, against 2.24 mrad for a level plate). On a facet inclined
  by ``phi`` the change differs from ``h`` by about ``h tan(phi) (d_h . e_f)``
  (``d_h`` the horizontal part of ``d``, ``e_f`` the facet's downhill direction):
  -2.1 to +2.1 um per facet at the default truth, several hundred times the
  ``h alpha^2 / 2`` = 5 nm that carry the angles; the six facet orientations cancel
  only as far as the scan covers them in equal shares. So, noise-free, ``h' - h`` is
  +57 nm at the default set-up (flat parts +1.7 nm of it, facets +55.8 nm) and the
  estimate 7.58 mrad; at the former default (40 lines, beta = 0.6) it was -14 nm
  (flat +1.6, facets -15.7) and the estimate 0. **The patent's alpha_x estimates
  neither alpha_x nor arccos(cos alpha_x cos alpha_y)**, but the balance of the
  facets in the scanned window; and any ``h'`` error of a nanometre moves it by
  ``1/(h alpha)`` ~ 70 urad. Restricting the mean to the flat parts would give the
  tilt-corrected angle between ``d`` and the plate's normal, still sign-blind and
  still drowned by the machine's positioning error of ``h`` (:func:`observability`
  says so, with the numbers). The Z scale error adds ``s h`` to ``h'``: 100 ppm
  alone reads as 14 mrad.

``registration`` (improved, self-referencing like the patent, no artifact dimensions
used): each scan is a sampled surface ``z_l = F_k(x_l, y)`` in the sensor's data
coordinates. Because the machine moves the sensor rigidly, the scans are exact
translates of one another in those coordinates:
``F_2(x, y) = F_1(x - du, y - dy_) + dt`` with ``du e_xl + dy_ e_y + dt e_zl = -(w, 0, 0)``
(and likewise scans 3/2 with ``(0, 0, h)``). The translations are estimated to
sub-step precision by Gauss-Newton (Lucas-Kanade) on bilinear interpolation of the
reference scan, using only cells whose corners lie on one plane (bilinear
interpolation is exact there, so on noise-free data the fit is exact), with a robust
trim of the residuals. The two translations give two vector pairs ``R b = a``,
``a = (w, dy_, 0)`` and ``(0, dy_', h)`` in the machine frame, ``b = -(du, 0, dt)`` in
the sensor frame, with ``w`` and ``h`` taken from the vector lengths (so the machine's
positioning errors of w and h drop out exactly); the rotation is their least-squares
fit (Kabsch, one batched 3x3 SVD) and the angles are read off it **with sign**. The raise
is what gives ``alpha_x`` its sign: it shifts the pattern along Y by ``-h tan(alpha_x)``
(first order), where the patent only looks at the height change (second order).
It needs the facets to be resolved by the sampling (three samples across a facet);
where they are not, it refuses with the reason (see :func:`observability`).

``pattern`` (uses the artifact's stated pattern and the error model): the generalised least
squares of the whole forward model over the three angles and the artifact's pose (lattice
offset, rotation about Z, two tilts), every reading of the three scans at once, weighted by
the inverse of the readings' covariance under every active error source
(``C = sigma^2 I + U U^T``, one column of ``U`` per element of a source other than the
noise: its effect at one standard deviation). Gauss-Newton, each trial with its own gains
(taken at its start and its fit, rounded to a grid, so trials that round alike share one
matrix product per step), started from the trial's registration angles and the default
truth's pose, or a grid search of the lattice offset and rotation where that misses: a
trial's estimate does not depend on the other trials of its batch. What it uses that the registration does not: a height error that is
fixed along the line (the sensor's *linearity*) is not a rotation of the line on a known
pattern, so it separates from ``alpha_y`` (the registration reads its mean over the cells,
40 of its 41 urad; the pattern fit 2.8 urad); the pattern's shape gives ``alpha_z`` from
each scan alone, as far as the facets' positions are known (``facet_position``: 25 urad
with an exact pattern, 39 with facets known to 2 um, against the registration's 48);
``alpha_x`` gains from the parallax of the pockets' floors (rays tilted by ``alpha_x`` meet
the floor displaced along Y by the depth times the angle). It is the estimator whose
Monte Carlo agrees with the posterior, which uses the same information.

Decisions where the patent is silent or loose: the patent's ``cos(alpha_x) = h/h'`` ignores
``alpha_y``; we implement it as written and show the contamination. The patent aligns
along ``x_l`` by ``w``; we interpolate linearly along the line for that (``w`` need not
be a whole number of points). Rows are compared at the nominal trigger positions
(the data know no better).

Default scan: 80 profiles 0.05 mm apart cover one pitch of the cells along Y (4 mm),
so every facet orientation is in the window wherever the artifact lies; 40 profiles
covered half a pitch, and the patent's noise-free alpha_y error then ranged from -68
to +17 urad with the artifact's (unknown) Y position, against -18 to -15 urad with
80. The remaining -17 urad came from the linear interpolation along the line across
the facets' kinks (w = 9.6 mm = 38.4 point spacings at beta = 0.6); the default
beta = 0.625 makes w = 10 mm a whole number of spacings, and the error is below
1 urad for every position. :func:`observability` flags a ``w`` that is not.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from mtplan._validate import InvalidInput, Problems
from mtplan.models.protocol import (
    Capabilities,
    Estimator,
    Measurand,
    Procedure,
    ReadingsFormat,
    SetupBase,
    Source,
    frame_columns,
    param,
)
from mtplan.uncertainty.distributions import Normal, Rectangular

__all__ = [
    "Setup",
    "Truth",
    "Observability",
    "observability",
    "sensor_rotation",
    "height_map",
    "facet_count",
    "estimate_patent",
    "estimate_registration",
    "estimate_pattern",
    "PROCEDURE",
]

#: largest mounting angle the procedure is meant for [rad] (Truth limit, range margin)
ALPHA_MAX = 10e-3
#: largest tilt of the artifact on the table [rad] (Truth limit, range margin)
TILT_MAX = 5e-3
#: smallest mask tolerance of the registration [mm]: far above rounding, far below noise
_TOL_FLOOR = 5e-5
_SQ3 = math.sqrt(3.0)
#: Legendre degrees of the linearity curve along the line (0 and 1 belong to the data frame)
_LIN_DEGREES = np.arange(2, 5)


# --------------------------------------------------------------------------- set-up
@dataclass(frozen=True)
class Setup(SetupBase):
    """Set-up of the line-laser mounting-angle test (units in the field names)."""

    _owner = "line_laser"
    # sensor
    line_width_mm: float = param(
        16.0, doc="Width of the laser line w0 (a 15-25 mm class profile sensor)",
        low=0, low_open=True)
    points_per_line: int = param(
        65, doc="Points reported along the line (decimated from the sensor's 800-3200)", low=5)
    range_mm: float = param(
        8.0, doc="Measuring range of the sensor in height (e.g. +-4 mm)", low=0, low_open=True)
    sensor_noise_um: float = param(
        1.0, doc="Standard deviation of one height reading (single profile, matte metal)", low=0)
    linearity_um: float = param(
        1.0, doc="RMS along the laser line of the sensor's height error after its best straight "
                 "line is removed (calibration linearity): a smooth curve, Legendre degrees 2-4 "
                 "with random amplitudes per test, the same in all three scans. Default 1 um: "
                 "Keyence LJ-X8000 heads quote a Z linearity of +-0.03 % of F.S. (+-2.4 um over "
                 "this 8 mm range), Micro-Epsilon scanCONTROL 30xx about +-0.1 % of FSO", low=0)
    z_scale_ppm: float = param(
        100.0, doc="Standard deviation of the scale (gain) error of the sensor's height reading. "
                   "Default 100 ppm: the Z gain as calibrated by the maker; Keyence LJ-X8000 "
                   "heads quote a temperature characteristic of 0.01 % of F.S. per K, so 1 K "
                   "from the calibration temperature gives this much", low=0)
    # scans
    step_mm: float = param(
        0.05, doc="Scan step dy between profiles (encoder-pulse trigger interval)",
        low=0, low_open=True)
    lines: int = param(
        80, doc="Profiles per scan; the default 80 x 0.05 mm covers one pitch of the cells along "
                "Y, so every facet is seen whatever the artifact's position", low=5)
    shift_fraction: float = param(
        0.625, doc="X shift of scan 2 per cell width (beta: the shift is w = beta * w0, "
                   "the patent: 0.5 to 0.75); beta >= 1 leaves no common part. The default "
                   "makes w (10 mm) a whole "
                   "number of point spacings, so the patent aligns the scans without "
                   "interpolating",
        low=0, high=1, low_open=True, high_open=True)
    raise_mm: float = param(2.0, doc="Raise h of scan 3 in +Z (within the range)",
                            low=0, low_open=True)
    max_shift_rows: int = param(5, doc="n_max: row shifts searched by the patent's overlap",
                                low=1)
    # artifact
    cell_size_mm: float = param(4.0, doc="Pitch of the hexagonal cells (centre to centre)",
                                low=0, low_open=True)
    wall_mm: float = param(0.6, doc="Width of the land between neighbouring pockets", low=0)
    cell_depth_mm: float = param(
        0.4, doc="Depth of the pockets; 0 would be an artifact without a pattern",
        low=0, low_open=True)
    facet_angle_deg: float = param(
        25.0, doc="Inclination of the pocket walls to the plate (draft of the facets)",
        low=0, high=80, low_open=True)
    facet_position_um: float = param(
        2.0, doc="Standard deviation of the position of each facet of the pockets, along its "
                 "in-plane normal, independent from facet to facet: how well the artifact's "
                 "pattern is known. Default 2 um: an uncalibrated plate milled on a machining "
                 "centre (ISO 230-2 positioning and contouring deviations and tool deflection "
                 "of a few um; the drawing tolerance, tens of um, bounds it but is not its "
                 "size); a CMM calibration of every facet gives about 1 um. Only the "
                 "'pattern' estimator (and the posterior) use the pattern; the registration "
                 "compares the scans and does not see it", low=0)
    # machine errors
    shift_error_um: float = param(
        1.0, doc="Standard deviation of the machine's positioning of the X shift w", low=0)
    raise_error_um: float = param(
        1.0, doc="Standard deviation of the machine's positioning of the raise h", low=0)
    trigger_y_um: float = param(
        0.3, doc="Standard deviation of each scan's Y trigger position", low=0)
    squareness_xy_urad: float = param(
        20.0, doc="Half-width (rectangular) of the squareness error of the X motion to the Y "
                  "(scan) motion, positive toward +Y. ISO 230-1 defines it; acceptance "
                  "tolerances of machining centres (ISO 10791-2) are about 0.02 mm over 500 mm "
                  "(40 urad), a machine in order measures well inside that", low=0)
    squareness_zy_urad: float = param(
        20.0, doc="Half-width (rectangular) of the squareness error of the Z motion to the Y "
                  "(scan) motion, positive toward +Y (ISO 230-1; default as squareness_xy_urad)",
        low=0)
    drift_um_per_s: float = param(
        0.003, doc="Standard deviation, per axis, of the thermal drift rate of the sensor "
                   "relative to the artifact, constant during the test; the scans' start times "
                   "follow the duration model. Default 0.003 um/s (about 10 um/h): ISO 230-3 "
                   "thermal tests of machining centres show drifts of 5-30 um per hour while "
                   "warming up, and profile sensors need a 20 min run-in", low=0)
    # time
    scan_feed_mm_min: float = param(600.0, doc="Scanning feed along Y", low=0, low_open=True)
    frame_rate_per_s: float = param(1000.0, doc="Largest profile rate of the sensor",
                                    low=0, low_open=True)
    rapid_mm_min: float = param(10000.0, doc="Feed of the moves between scans",
                                low=0, low_open=True)
    settle_s: float = param(1.0, doc="Dwell before each scan", low=0)

    def _check(self, p: Problems) -> None:
        w = self.shift_fraction * self.line_width_mm
        common = self.line_width_mm - w
        if common < self.cell_size_mm:
            p.add_text(
                f"The common part of scans 1 and 2 of line_laser, (1 - shift_fraction) * "
                f"line_width_mm = {common:g} mm, must hold at least one cell "
                f"(cell_size_mm = {self.cell_size_mm:g} mm); lower shift_fraction or "
                f"cell_size_mm, or use a wider line"
            )
        margin = (ALPHA_MAX + TILT_MAX) * (self.line_width_mm + w)
        need = self.raise_mm + self.cell_depth_mm + margin
        if need > self.range_mm:
            p.add_text(
                f"The raise of line_laser is beyond the sensor's range: raise_mm + "
                f"cell_depth_mm + {margin:.3g} mm of tilt allowance = {need:.4g} mm must be "
                f"<= range_mm = {self.range_mm:g} mm, or scan 3 leaves the measuring range"
            )
        if self.wall_mm >= self.cell_size_mm:
            p.add("wall_mm", self.wall_mm, f"< cell_size_mm = {self.cell_size_mm:g} "
                  "(the land would cover the whole cell: no pattern)")
        else:
            floor = (self.cell_size_mm - self.wall_mm) / 2 - self.cell_depth_mm / math.tan(
                math.radians(self.facet_angle_deg))
            if floor <= 0:
                p.add_text(
                    f"The pockets of line_laser have no floor: (cell_size_mm - wall_mm)/2 - "
                    f"cell_depth_mm/tan(facet_angle_deg) = {floor:.4g} mm must be > 0; make "
                    f"the cells larger, shallower or the facets steeper"
                )
        if 2 * self.max_shift_rows > self.lines - 3:
            p.add("max_shift_rows", self.max_shift_rows,
                  f"an int <= (lines - 3)/2 = {(self.lines - 3) // 2} (the shifted rows must "
                  f"still overlap)")
        reach = w * math.tan(ALPHA_MAX)
        if self.max_shift_rows * self.step_mm < reach:
            p.add("max_shift_rows", self.max_shift_rows,
                  f"an int >= {math.ceil(reach / self.step_mm)}: the search must cover the "
                  f"row shift w*tan(alpha_z) = {reach * 1e3:.3g} um of a {ALPHA_MAX * 1e3:g} "
                  f"mrad mounting error (the patent: n_max larger than the expected shift)")


@dataclass(frozen=True)
class Truth(SetupBase):
    """True mounting angles and the artifact's (unknown) pose on the table."""

    _owner = "line_laser truth"
    alpha_z_mrad: float = param(1.5, doc="Mounting angle about Z", low=-10, high=10)
    alpha_y_mrad: float = param(-2.0, doc="Mounting angle about Y", low=-10, high=10)
    alpha_x_mrad: float = param(1.0, doc="Mounting angle about X", low=-10, high=10)
    artifact_x_mm: float = param(0.37, doc="X of a cell centre (lattice offset)",
                                 low=-100, high=100)
    artifact_y_mm: float = param(-0.21, doc="Y of a cell centre (lattice offset)",
                                 low=-100, high=100)
    artifact_rz_mrad: float = param(8.0, doc="Rotation of the artifact about Z",
                                    low=-100, high=100)
    artifact_tilt_x_mrad: float = param(0.3, doc="Tilt of the artifact about X",
                                        low=-5, high=5)
    artifact_tilt_y_mrad: float = param(-0.2, doc="Tilt of the artifact about Y",
                                        low=-5, high=5)


# --------------------------------------------------------------------------- geometry
def _rmat(rows):
    """Rotation matrices (..., 3, 3) from nested rows of scalars or arrays (...)."""
    return np.moveaxis(np.array([np.broadcast_arrays(*r) for r in rows], dtype=float), (0, 1),
                       (-2, -1))


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(c), np.zeros_like(c)
    return _rmat([[o, z, z], [z, c, -s], [z, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(c), np.zeros_like(c)
    return _rmat([[c, z, s], [z, o, z], [-s, z, c]])


def _rz(a):
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
    return _rx(alpha_x) @ _ry(alpha_y) @ _rz(alpha_z)


def _angles_from_rotation(r: np.ndarray):
    """(alpha_z, alpha_y, alpha_x) [rad] of rotations ``r`` (..., 3, 3)."""
    ay = np.arcsin(np.clip(r[..., 0, 2], -1.0, 1.0))
    ax = np.arctan2(-r[..., 1, 2], r[..., 2, 2])
    az = np.arctan2(-r[..., 0, 1], r[..., 0, 0])
    return az, ay, ax


def _grid_u(setup) -> np.ndarray:
    """Positions of the points along the line x_l [mm], shape (points_per_line,)."""
    return np.linspace(-setup.line_width_mm / 2, setup.line_width_mm / 2, setup.points_per_line)


def _grid_y(setup) -> np.ndarray:
    """Nominal machine Y of the triggers [mm], shape (lines,)."""
    return (np.arange(setup.lines) - (setup.lines - 1) / 2) * setup.step_mm


def _pitch(setup) -> float:
    return setup.line_width_mm / (setup.points_per_line - 1)


def _shift(setup) -> float:
    return setup.shift_fraction * setup.line_width_mm


#: outward in-plane normals of the six facets of a pocket (index k of an element)
_FACET_NORMALS = np.array([[_SQ3 / 2, 0.5], [0.0, 1.0], [-_SQ3 / 2, 0.5], [-_SQ3 / 2, -0.5],
                           [0.0, -1.0], [_SQ3 / 2, -0.5]])


def _facet_layout(setup) -> tuple[int, int]:
    """Period (columns, rows) of the facets' position errors on the pocket lattice, in
    half lattice spacings (sx/2 = cell_size * sqrt(3)/2 along X, cell_size/2 along Y):
    wider than the scanned window (w0 + w by the scan's length) plus one pitch: the
    pockets the scans touch have their centres within the window widened by a pocket's
    circumradius (under half a pitch) on each side, so no two of them share an error
    (up to the Truth's +-100 mrad of rotation: the window then leans by at most
    0.1 (w0 + w) along Y)."""
    s = setup.cell_size_mm
    across = setup.line_width_mm + _shift(setup)
    along = (setup.lines - 1) * setup.step_mm + 0.1 * across
    return 2 * math.ceil((across + s) / (s * _SQ3)), 2 * math.ceil((along + s) / s)


def facet_count(setup) -> int:
    """Number of facet position errors (six per pocket of :func:`_facet_layout`)."""
    cols, rows = _facet_layout(setup)
    return 3 * cols * rows


def _lattice_local(setup, x, y):
    """Offset (dx, dy) [mm] of points from the nearest pocket centre, and that pocket's
    index in the period of the facet errors (:func:`_facet_layout`)."""
    s = setup.cell_size_mm
    sx, sy = s * _SQ3, s
    # nearest centre of the hexagonal lattice = nearest of its two rectangular sub-lattices
    i1, j1 = np.round(x / sx), np.round(y / sy)
    i2, j2 = np.round(x / sx - 0.5), np.round(y / sy - 0.5)
    dx1, dy1 = x - i1 * sx, y - j1 * sy
    dx2, dy2 = x - (i2 + 0.5) * sx, y - (j2 + 0.5) * sy
    first = dx1 * dx1 + dy1 * dy1 <= dx2 * dx2 + dy2 * dy2
    cols, rows = _facet_layout(setup)
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
    dx, dy, pocket = _lattice_local(setup, x, y)
    tan_phi = math.tan(math.radians(setup.facet_angle_deg))
    opening = (s - setup.wall_mm) / 2
    depth = setup.cell_depth_mm
    if offsets is None:
        # hexagonal norm over the neighbour directions 30, 90, 150 deg:
        # max(|dy|, |c30 dx + dy/2|, |-c30 dx + dy/2|) = max(|dy|, c30 |dx| + |dy|/2)
        c30 = _SQ3 / 2
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


def _facet_element(setup, x, y, z) -> np.ndarray:
    """Index of the facet error a point on a facet depends on; -1 on land and floor."""
    dx, dy, pocket = _lattice_local(setup, x, y)
    k = np.argmax(dx[..., None] * _FACET_NORMALS[:, 0] + dy[..., None] * _FACET_NORMALS[:, 1],
                  axis=-1)
    elem = 6 * pocket + k
    return np.where((z < 0) & (z > -setup.cell_depth_mm), elem, -1)


def _standoff(setup) -> float:
    """Machine Z of the middle of the measuring range in scans 1 and 2 [mm]."""
    return -(setup.raise_mm + setup.cell_depth_mm) / 2


# --------------------------------------------------------------------------- sources
def measurands(setup) -> tuple:
    return (
        Measurand("alpha_z", "urad", "mounting error angle of the sensor about Z"),
        Measurand("alpha_y", "urad", "mounting error angle of the sensor about Y"),
        Measurand("alpha_x", "urad", "mounting error angle of the sensor about X"),
    )


def sources(setup) -> dict:
    """Every error source (inactive ones with zero spread)."""
    shape = (3, setup.lines, setup.points_per_line)
    return {
        "sensor_noise": Source(
            Normal(0.0, setup.sensor_noise_um * 1e-3), shape,
            "Noise of each height reading; default 1 um: single-profile point noise of a "
            "15-25 mm class laser profiler on matte metal (makers quote 0.2-0.5 um "
            "repeatability for averaged profiles)."),
        "shift_error": Source(
            Normal(0.0, setup.shift_error_um * 1e-3), (),
            "Machine's positioning error of the X shift w (shared by scans 2 and 3); default "
            "1 um: ISO 230-2 short-travel repeatability of a machining-centre axis."),
        "raise_error": Source(
            Normal(0.0, setup.raise_error_um * 1e-3), (),
            "Machine's positioning error of the raise h of scan 3; default 1 um: ISO 230-2 "
            "short-travel repeatability of a Z axis."),
        "trigger_y": Source(
            Normal(0.0, setup.trigger_y_um * 1e-3), (3,),
            "Y position of each scan's trigger train; default 0.3 um: interpolation error "
            "of the linear scale plus trigger latency at the scanning feed."),
        "linearity": Source(
            Normal(0.0, setup.linearity_um * 1e-3 / math.sqrt(_LIN_DEGREES.size)),
            (_LIN_DEGREES.size,),
            "Coefficients of the sensor's height error along the line on the orthonormal "
            "Legendre polynomials of degrees 2, 3, 4 (sqrt(2k+1) P_k of 2 x_l / w0), one set "
            "per test, equal shares, so the expected RMS along the line is linearity_um; "
            "degrees 0 and 1 (offset, tilt) are part of the sensor's data frame, not errors. "
            "Default 1 um: Keyence LJ-X8000 +-0.03 % of F.S., Micro-Epsilon scanCONTROL "
            "about +-0.1 % of FSO."),
        "z_scale": Source(
            Normal(0.0, setup.z_scale_ppm * 1e-6), (),
            "Scale (gain) error of the height reading about the middle of the range, one per "
            "test; default 100 ppm (Keyence LJ-X8000: 0.01 % of F.S. per K)."),
        "squareness_xy": Source(
            Rectangular(-setup.squareness_xy_urad * 1e-6, setup.squareness_xy_urad * 1e-6), (),
            "Squareness of the X motion (the shift w) to the Y scan motion, toward +Y; "
            "rectangular +-20 urad (ISO 230-1; ISO 10791-2 tolerances are 0.02 mm/500 mm)."),
        "squareness_zy": Source(
            Rectangular(-setup.squareness_zy_urad * 1e-6, setup.squareness_zy_urad * 1e-6), (),
            "Squareness of the Z motion (the raise h) to the Y scan motion, toward +Y; "
            "rectangular +-20 urad (ISO 230-1)."),
        "facet_position": Source(
            Normal(0.0, setup.facet_position_um * 1e-3), (facet_count(setup),),
            "Position error of each facet of the artifact's pockets, along its in-plane "
            "normal (outward positive), independent from facet to facet; the errors repeat "
            "with a period wider than the scanned window (:func:`_facet_layout`). Default "
            "2 um: an uncalibrated pocket milled on a machining centre (ISO 230-2 "
            "positioning, contouring and tool deflection of a few micrometres)."),
        "drift": Source(
            Normal(0.0, setup.drift_um_per_s * 1e-3), (3,),
            "Thermal drift velocity (X, Y, Z) of the sensor relative to the artifact, one per "
            "test; scan k is displaced by it times its start time after scan 1. Default "
            "0.003 um/s, about 10 um/h (ISO 230-3 warm-up drifts of 5-30 um/h)."),
    }


def source_structure(setup, truth, name: str):
    """The facets' colouring (:attr:`mtplan.models.protocol.Capabilities.source_structure`):
    colour k holds facet k of every pocket. A reading depends only on the facets of the
    pocket its hit lies in (:func:`height_map`: ``offsets`` of that pocket alone; pockets
    are 0.6 mm of land apart, a facet error moves micrometres), and no two scanned
    pockets share an error (:func:`_facet_layout`), so facets of one colour never move a
    common reading. The owners are taken at the error-free hits of the truth's traced
    neighbour (:func:`_row`, as :func:`_trace` does); `truth` scalar or batched (its
    first row). None for every other source."""
    if name != "facet_position":
        return None
    _, x, y, _, _, _, _ = _nominal(setup, _row(truth, 0))
    pocket = _lattice_local(setup, x, y)[2]
    colours = np.tile(np.arange(6), facet_count(setup) // 6)
    return colours, 6 * pocket[None, :] + np.arange(6)[:, None]


def _linearity_basis(setup) -> np.ndarray:
    """Orthonormal Legendre polynomials along the line, shape (degrees, points_per_line).

    ``sqrt(2k + 1) P_k(xi)`` with ``xi = 2 x_l / w0`` in [-1, 1], k in ``_LIN_DEGREES``:
    each has unit mean square over the line, so coefficients of standard deviation
    ``L / sqrt(degrees)`` give an error curve of expected RMS ``L``.
    """
    xi = 2.0 * _grid_u(setup) / setup.line_width_mm
    return np.stack([math.sqrt(2 * k + 1) * np.polynomial.legendre.Legendre.basis(k)(xi)
                     for k in _LIN_DEGREES])


def _scan_times(setup) -> np.ndarray:
    """Start time of scans 1, 2, 3 and the end of the test [s], shape (4,).

    Each scan is preceded by a dwell ``settle_s``; between scans the machine returns
    along Y at rapid feed and makes the X shift (before scan 2) or the raise (before
    scan 3). The last entry is :func:`duration`.
    """
    length = (setup.lines - 1) * setup.step_mm
    scan = length / min(setup.scan_feed_mm_min / 60, setup.step_mm * setup.frame_rate_per_s)
    rapid = setup.rapid_mm_min / 60
    t1 = setup.settle_s
    t2 = t1 + scan + (length + _shift(setup)) / rapid + setup.settle_s
    t3 = t2 + scan + (length + setup.raise_mm) / rapid + setup.settle_s
    return np.array([t1, t2, t3, t3 + scan])


def _displacements(setup, errors) -> np.ndarray:
    """Actual minus nominal position of the sensor in each scan, (n, 3, 3) [mm].

    Axis 1 is the scan, axis 2 the machine coordinate. The frame is the scan's: Y along
    the Y motion, X in the plane of the X and Y motions, Z normal to both. The X shift
    ``w + e_w`` runs along ``(cos g, sin g, 0)`` (g the X-Y squareness) and the raise
    ``h + e_h`` along ``(0, sin e, cos e)`` (e the Z-Y squareness), both exactly; each scan's
    trigger train is offset along Y; the drift velocity moves scan k by ``v (t_k - t_1)``.
    All zero when every source is zero (exactly: ``(w + 0) cos 0 - w == 0``).
    """
    e_w = np.asarray(errors["shift_error"], dtype=float).reshape(-1)
    n = e_w.shape[0]
    e_h = np.asarray(errors["raise_error"], dtype=float).reshape(n)
    e_y = np.asarray(errors["trigger_y"], dtype=float).reshape(n, 3)
    g = np.asarray(errors["squareness_xy"], dtype=float).reshape(n)
    e = np.asarray(errors["squareness_zy"], dtype=float).reshape(n)
    v = np.asarray(errors["drift"], dtype=float).reshape(n, 3)
    w, h = _shift(setup), setup.raise_mm
    disp = np.zeros((n, 3, 3))
    sx = w + e_w
    disp[:, 1:, 0] = (sx * np.cos(g) - w)[:, None]
    disp[:, 1:, 1] = (sx * np.sin(g))[:, None]
    rz = h + e_h
    disp[:, 2, 1] += rz * np.sin(e)
    disp[:, 2, 2] = rz * np.cos(e) - h
    disp[:, :, 1] += e_y
    times = _scan_times(setup)[:3]
    disp += v[:, None, :] * (times - times[0])[None, :, None]
    return disp


# --------------------------------------------------------------------------- forward
def _newton(setup, ox, oy, oz, d, t, idx, rays=None, offsets=None, *, rows=None):
    """Solve ``oz + t d_z = height(ox + t d_x, oy + t d_y)`` in place for ``t[idx]``.

    Newton's method on the piecewise-planar height map: inside one plane a step is
    exact; across a kink each step contracts the error by ``tan(facet) |d_xy|``
    (about 1e-2), so it ends at machine precision in a few steps. ``offsets`` (m,
    facets): the facets' position errors of each row of ``rays`` rays (:func:`height_map`);
    ``rows`` (like ``ox``), instead of ``rays``: the batch row of each ray.
    """
    for _ in range(60):
        if idx.size == 0:
            break
        tt = t[idx]
        # one direction (3,), or one per batch row (m, 3)
        row = rows[idx] if rows is not None else (idx // rays if rays else None)
        dx, dy, dz = (d[row].T if row is not None and np.ndim(d) == 2 else d)
        z, gx, gy = height_map(setup, ox[idx] + tt * dx, oy[idx] + tt * dy, offsets=offsets,
                               rows=None if offsets is None else row)
        step = (oz[idx] + tt * dz - z) / (dz - gx * dx - gy * dy)
        t[idx] = tt - step
        idx = idx[np.abs(step) > 1e-15 * (1.0 + np.abs(tt))]
    return t


def _frames(setup, truth):
    """Laser-line and measuring directions and artifact pose: (ex, d, q, c0).

    Shapes (3,), (3,), (3, 3), (3,); with a leading axis (m,) for a truth whose fields
    are arrays (m,) (one truth per batch row, a posterior's walkers).
    """
    r = sensor_rotation(np.asarray(truth.alpha_z_mrad) * 1e-3,
                        np.asarray(truth.alpha_y_mrad) * 1e-3,
                        np.asarray(truth.alpha_x_mrad) * 1e-3)
    q = _rz(np.asarray(truth.artifact_rz_mrad) * 1e-3) @ _ry(
        np.asarray(truth.artifact_tilt_y_mrad) * 1e-3) @ _rx(
        np.asarray(truth.artifact_tilt_x_mrad) * 1e-3)
    x, y = np.broadcast_arrays(np.asarray(truth.artifact_x_mm, dtype=float),
                               np.asarray(truth.artifact_y_mm, dtype=float))
    c0 = np.stack([x, y, np.zeros_like(x)], axis=-1)
    qt = np.swapaxes(q, -1, -2)
    return (np.einsum("...ij,...j->...i", qt, r[..., :, 0]),
            np.einsum("...ij,...j->...i", qt, r[..., :, 2]), q, c0)


def _batched(truth) -> bool:
    """Whether the truth holds one set of values per batch row (array fields)."""
    return bool(np.ndim(truth.alpha_z_mrad) or np.ndim(truth.artifact_x_mm))


def _base(setup, disp, q, c0):
    """The rays' origins at ``x_l = 0`` in the artifact frame, (m, 3, lines, 3): the
    sensor's nominal positions moved by ``disp`` (m, 3, 3) [mm]; ``q``, ``c0`` the pose
    (:func:`_frames`, one per row or one for all)."""
    m = disp.shape[0]
    pos = np.zeros((m, 3, setup.lines, 3))
    pos[:, 1:, :, 0] = _shift(setup)
    pos[:, :, :, 1] = _grid_y(setup)[None, None, :]
    pos[:, :, :, 2] = _standoff(setup)
    pos[:, 2, :, 2] += setup.raise_mm
    pos += disp[:, :, None, :]
    # one pose per row (a batched truth): (m, 3) and (m, 3, 3), the scan axes added
    c0 = c0[:, None, None, :] if c0.ndim == 2 else c0
    q = q[:, None] if q.ndim == 3 else q
    return (pos - c0) @ q  # rows: q.T @ (p - c0)


def _origins(setup, truth, disp):
    """Ray origins in the artifact frame, three arrays (m, 3, lines, points) flattened.

    ``disp`` (m, 3, 3): each scan's displacement from its nominal position [mm]
    (:func:`_displacements`).
    """
    ex, _, q, c0 = _frames(setup, truth)
    m = disp.shape[0]
    ex = ex[:, None, None, None, :] if ex.ndim == 2 else ex
    base = _base(setup, disp, q, c0)
    u = _grid_u(setup)
    return tuple((base[..., k : k + 1] + u * ex[..., k]).reshape(m, -1) for k in range(3))


_NOMINAL: dict = {}
#: error-free traces kept (about 2 MB each at the default scan)
_CACHED = 48


#: grid [mrad, mm] of the batched truths whose error-free traces are cached (:func:`_row`),
#: so that half a step moves a hit by about a micrometre at most: coarse for the tilts of
#: the measuring direction (0.25 mrad over the 4 mm range), finer for the rotations about
#: Z (0.05 mrad over the line's 8 mm and the scans' 20 mm reach) and the lattice offset
#: (1:1); the plate's tilts, which the walkers hardly move, on the default truth's grid
_KEY_GRID = {"alpha_z_mrad": 0.1, "alpha_y_mrad": 0.5, "alpha_x_mrad": 0.5,
             "artifact_x_mm": 0.002, "artifact_y_mm": 0.002, "artifact_rz_mrad": 0.1,
             "artifact_tilt_x_mrad": 0.1, "artifact_tilt_y_mrad": 0.1}


def _row(truth, i: int, *, own: bool = False):
    """A scalar Truth near row i of a batched one (or near a scalar one): its values rounded
    to :data:`_KEY_GRID`, so that nearby truths (a posterior's walkers, a fit's iterates, a
    Jacobian's steps) share the cached error-free trace; which rays stay on their plane is
    checked ray by ray (:func:`_trace`), so the rounding costs no accuracy. A scalar truth
    on that grid, or any with `own`, is returned itself (:func:`_trace` asks for its own
    trace where facet errors are NaN: which facet a ray at a kink belongs to, the one whose
    NaN error makes it NaN as the error budget's probes ask, is then the truth's own)."""
    import dataclasses

    if own and not _batched(truth):
        return truth
    values = {}
    for f in dataclasses.fields(truth):
        g = _KEY_GRID.get(f.name, 0.01)
        values[f.name] = float(f"{round(float(np.ravel(getattr(truth, f.name))[i]) / g) * g:.10g}")
    if not _batched(truth) and all(values[k] == getattr(truth, k) for k in values):
        return truth
    return dataclasses.replace(truth, **values)


def _nominal(setup, truth):
    """Error-free trace, cached: hit parameter, plane of the hit and its edge margin."""
    key = (setup, truth)
    if key not in _NOMINAL:
        _, d, _, _ = _frames(setup, truth)
        ox, oy, oz = (a[0] for a in _origins(setup, truth, np.zeros((1, 3, 3))))
        t = -oz / d[2]  # hit of the land plane
        t = _newton(setup, ox, oy, oz, d, t, np.arange(t.size))
        x, y = ox + t * d[0], oy + t * d[1]
        z, gx, gy, margin = height_map(setup, x, y, margin=True)
        while len(_NOMINAL) >= _CACHED:  # the oldest out
            old = next(iter(_NOMINAL))
            del _NOMINAL[old]
            _FACET_OF.pop(old, None)
            _PLANS.pop(old, None)
        _NOMINAL[key] = (t, x, y, z, gx, gy, margin)
        _FACET_OF[key] = _facet_element(setup, x, y, z)
    return _NOMINAL[key]


_FACET_OF: dict = {}


def _trace(setup, truth, disp, offsets=None):
    """Exact heights t [mm] of the rays, shape (m, 3, lines, points), for m error rows.

    ``disp`` (m, 3, 3): each scan's displacement of the sensor [mm]; ``offsets`` (m,
    facets): the facets' position errors [mm] (:func:`height_map`), None for none. The
    errors move the sensor and the facets by micrometres. A ray whose error-free hit
    lies farther from any kink than that move (bounded generously: twice the sum of the
    components' magnitudes, plus twice the largest facet error) stays on the same
    plane, and its hit is the exact ray-plane intersection (on a facet, the plane moved
    by its error: the height changes by ``-offset tan(facet)``); the others (near
    kinks) are solved by :func:`_newton`.

    The ray-plane intersection ``t = (c + g . O) / (-g . d)`` (``g = (gx, gy, -1)`` the
    plane's slopes, ``O`` the ray's origin, ``c`` the plane's height at the artifact's
    origin) is assembled from small tables (:func:`_plan`): the origin is
    ``B[row, scan, line] + x_l e_x[row]``, so ``g . O`` is a table over (row, scan, line,
    plane) plus one over (row, point, plane), the denominator one over (row, plane), and
    each ray looks its entries up. The rays near a kink are found among the prefix of the
    rays sorted by margin that a bound of the move allows (:func:`_move_bound`).
    """
    ex, d, q, c0 = _frames(setup, truth)
    m = disp.shape[0]
    # the planes of a nearby truth's error-free hits, checked ray by ray
    key = _row(truth, 0, own=offsets is not None and bool(np.isnan(offsets).any()))
    moved_truth = key is not truth
    _, x0, y0, _, _, _, margin = _nominal(setup, key)
    plan = _plan(setup, key)
    pts = setup.points_per_line
    g = np.column_stack([plan["grads"], -np.ones(len(plan["grads"]))])  # (P, 3)
    base = _base(setup, disp, q, c0)  # (m, 3, lines, 3)
    exr, dr = np.atleast_2d(ex), np.atleast_2d(d)  # (1 or m, 3)
    tab_v = (_grid_u(setup)[None, :, None] * (exr @ g.T)[:, None, :]).reshape(len(exr), -1)
    den = -(dr @ g.T)  # (1 or m, P)
    t = np.take((base @ g.T).reshape(m, -1), plan["i_t"], axis=1)
    t += np.take(tab_v, plan["i_v"], axis=1)
    t += plan["c"]
    extra = np.zeros(m)
    if offsets is not None and np.any(offsets != 0):
        offsets = np.asarray(offsets, dtype=float).reshape(m, -1)
        elem = _FACET_OF[(setup, key)]
        on = np.flatnonzero(elem >= 0)
        t[:, on] -= offsets[:, elem[on]] * math.tan(math.radians(setup.facet_angle_deg))
        extra = 2.0 * np.abs(offsets).max(axis=1)
    else:
        offsets = None
    t /= np.take(den, plan["cls"], axis=1)
    top = np.maximum(t.max(axis=1), -t.min(axis=1))  # |t| per row
    if moved_truth:  # on the same plane while the hit stays within its margin
        bound = _move_bound(setup, key, base, exr, dr, den, top, extra)
        rows, ray = _prefix_rays(plan, 2.0 * bound + extra + 1e-9)
        ox, oy, oz = _ray_origins(setup, base, exr, rows, ray)
        tt = t[rows, ray]
        dxy = dr[rows % len(dr)]
        moved = np.hypot(ox + tt * dxy[:, 0] - x0[ray], oy + tt * dxy[:, 1] - y0[ray])
        sel = np.flatnonzero(2.0 * moved + extra[rows] + 1e-9 >= margin[ray])
    else:
        move = 2.0 * np.abs(disp).sum(axis=2).max(axis=1) + 1e-9
        rows, ray = _prefix_rays(plan, move + extra)
        ox, oy, oz = _ray_origins(setup, base, exr, rows, ray)
        tt = t[rows, ray]
        sel = np.arange(rows.size)
    if sel.size:
        tn = _newton(setup, ox[sel], oy[sel], oz[sel], d, tt[sel], np.arange(sel.size),
                     offsets=offsets, rows=rows[sel])
        t[rows[sel], ray[sel]] = tn
        top = max(float(top.max(initial=0.0)), float(np.abs(tn).max()))
    else:
        top = float(top.max(initial=0.0))
    if top > setup.range_mm / 2:
        raise InvalidInput([
            f"line_laser: the profiles leave the sensor's range (|z_l| up to "
            f"{top:.4g} mm > range_mm/2 = {setup.range_mm / 2:g} mm) with these "
            f"truth angles and artifact tilts; enlarge range_mm or lower raise_mm"
        ])
    return t.reshape(m, 3, setup.lines, pts)


_PLANS: dict = {}


def _plan(setup, key):
    """What :func:`_trace` needs of the error-free trace of the truth `key`, cached.

    Every error-free hit lies on one of a few planes (land and floor, the six facet
    orientations): ``cls`` (rays,) names it in ``grads`` (P, 2), the planes' slopes;
    ``c`` (rays,) is ``z0 - gx0 x0 - gy0 y0``, the plane's height at the artifact's
    origin; ``i_t`` and ``i_v`` index the tables of :func:`_trace`; ``order`` sorts the
    rays by their margin to a kink (``sorted_margin``), so the rays within a distance of
    a kink are a prefix of it; ``base``, ``ex``, ``d`` and ``top`` are the error-free
    origins, directions and largest ``|t|`` that :func:`_move_bound` compares with.
    """
    nominal = _nominal(setup, key)
    if _PLANS.get((setup, key), {}).get("nominal") is not nominal:
        t0, x0, y0, z0, gx0, gy0, margin = nominal
        # the planes' slopes (a few distinct pairs), without a sort of the pairs
        ux, ix = np.unique(gx0, return_inverse=True)
        uy, iy = np.unique(gy0, return_inverse=True)
        codes, cls = np.unique(ix.reshape(-1) * len(uy) + iy.reshape(-1), return_inverse=True)
        grads = np.stack([ux[codes // len(uy)], uy[codes % len(uy)]], axis=1)
        cls = np.asarray(cls).reshape(-1)
        pts, n_planes = setup.points_per_line, len(grads)
        ray = np.arange(t0.size)
        order = np.argsort(margin, kind="stable")
        ex, d, q, c0 = _frames(setup, key)
        _PLANS[(setup, key)] = {
            "nominal": nominal, "cls": cls, "grads": grads, "c": z0 - gx0 * x0 - gy0 * y0,
            "i_t": (ray // pts) * n_planes + cls, "i_v": (ray % pts) * n_planes + cls,
            "order": order, "sorted_margin": margin[order],
            "base": _base(setup, np.zeros((1, 3, 3)), q, c0)[0], "ex": ex, "d": d,
            "top": float(np.abs(t0).max()),
            "tan": float(np.abs(grads).max(initial=0.0)),
        }
    return _PLANS[(setup, key)]


def _prefix_rays(plan, thr):
    """(row, ray) of every ray whose margin is at most ``thr`` (m,) of its row (none where
    ``thr`` is NaN: a row of NaN errors, whose rays are not solved again)."""
    k = np.searchsorted(plan["sorted_margin"], np.where(np.isnan(thr), -np.inf, thr),
                        side="right")
    rows = np.repeat(np.arange(k.size), k)
    pos = np.arange(int(k.sum())) - np.repeat(np.cumsum(k) - k, k)
    return rows, plan["order"][pos]


def _ray_origins(setup, base, exr, rows, ray):
    """Origins (ox, oy, oz) of the rays ``ray`` of batch rows ``rows`` (:func:`_base`)."""
    pts, lines = setup.points_per_line, setup.lines
    u = _grid_u(setup)[ray % pts]
    b = base[rows, ray // (pts * lines), (ray // pts) % lines]
    e = exr[rows % len(exr)]
    return tuple(b[:, k] + u * e[:, k] for k in range(3))


def _move_bound(setup, key, base, exr, dr, den, top, extra):
    """Per row, a bound (m,) of how far any ray's hit moves in the plate's plane from the
    error-free hit of the truth `key` (:func:`_plan`): the origin's move, ``|t|`` times the
    direction's change, and ``|t - t0|`` times the error-free direction's slope, with
    ``t - t0 = (g . dO - t0 (den - den0)) / den`` bounded plane by plane's largest slope."""
    plan = _plan(setup, key)
    dxy0 = abs(plan["d"][0]) + abs(plan["d"][1])
    half = setup.line_width_mm / 2
    d_base = np.abs(base - plan["base"]).max(axis=(1, 2))  # (m, 3)
    d_o = d_base + half * np.abs(exr - plan["ex"])  # (m, 3): the origins' move
    d_d = np.abs(dr - plan["d"])  # (1 or m, 3)
    tan = plan["tan"]
    d_den = d_d[:, 2] + tan * (d_d[:, 0] + d_d[:, 1])
    d_t = (tan * (d_o[:, 0] + d_o[:, 1]) + d_o[:, 2] + plan["top"] * d_den
           + 0.5 * extra * tan) / den.min(axis=1)
    return d_o[:, 0] + d_o[:, 1] + top * (d_d[:, 0] + d_d[:, 1]) + d_t * dxy0


def forward(setup, truth, errors) -> dict:
    """Simulated profiles: ``{"z_mm": array (n, 3, lines, points_per_line)}``.

    The reported height is ``(1 + z_scale) t + e(x_l) + noise``: ``t`` the exact ray
    parameter of the displaced sensor (:func:`_displacements`, :func:`_trace`), ``e``
    the linearity curve along the line (:func:`_linearity_basis`), the same in the
    three scans.

    Parameters
    ----------
    setup : Setup
    truth : Truth
    errors : dict
        ``sensor_noise`` (n, 3, lines, points) [mm], ``shift_error`` (n,) [mm],
        ``raise_error`` (n,) [mm], ``trigger_y`` (n, 3) [mm], ``linearity`` (n, 3) [mm],
        ``z_scale`` (n,) [1], ``squareness_xy`` and ``squareness_zy`` (n,) [rad],
        ``drift`` (n, 3) [mm/s], ``facet_position`` (n, facets) [mm].
    """
    disp = _displacements(setup, errors)
    n = disp.shape[0]
    facets = np.asarray(errors["facet_position"], dtype=float).reshape(n, -1)
    if np.all(disp == disp[:1]) and np.all(facets == facets[:1]) and not _batched(truth):
        # identical trials: trace once
        t = np.broadcast_to(_trace(setup, truth, disp[:1], facets[:1]),
                            (n, 3, setup.lines, setup.points_per_line))
    else:
        t = _trace(setup, truth, disp, facets)  # a new array: the errors are added in place
    scale = np.asarray(errors["z_scale"], dtype=float).reshape(n)
    coef = np.asarray(errors["linearity"], dtype=float).reshape(n, -1)
    noise = np.asarray(errors["sensor_noise"], dtype=float)
    z = t if t.flags.writeable else np.array(t)
    if not _all_zero(scale):
        z *= (1.0 + scale)[:, None, None, None]
    if not _all_zero(coef):
        z += (coef @ _linearity_basis(setup))[:, None, None, :]
    if not _all_zero(noise):
        z += noise
    return {"z_mm": z}


def _all_zero(a: np.ndarray) -> bool:
    """Whether `a` is all zero, reading each broadcast (zero-stride) axis once."""
    return not np.any(a[tuple(slice(None) if st else slice(0, 1) for st in a.strides)])


def true_values(setup, truth) -> dict:
    return {
        "alpha_z": truth.alpha_z_mrad * 1e-3,
        "alpha_y": truth.alpha_y_mrad * 1e-3,
        "alpha_x": truth.alpha_x_mrad * 1e-3,
    }


def truth_from_estimate(setup, estimate) -> Truth:
    """The default Truth with the estimated angles [rad] put in."""
    return Truth().replace(
        **{f"{k}_mrad": float(np.clip(np.asarray(estimate[k]).ravel()[0] * 1e3, -10, 10))
           for k in ("alpha_z", "alpha_y", "alpha_x")})


# --------------------------------------------------------------------------- observability
@dataclass(frozen=True)
class Observability:
    """Whether an estimator determines an angle at a set-up, and how finely.

    Attributes
    ----------
    observable : bool
        False where the estimator cannot tell the angle at this set-up (its value
        would be noise or a constant).
    signed : bool
        False where the estimator returns only the magnitude.
    quantum_urad : float
        Step of the estimate's possible values (0 when continuous) [urad].
    floor_urad : float
        Smallest magnitude the estimator tells from zero (standard-uncertainty level;
        0 where the estimate is linear in the angle) [urad].
    reason : str
        Plain-English explanation.
    """

    observable: bool
    signed: bool
    quantum_urad: float
    floor_urad: float
    reason: str


def observability(setup) -> dict:
    """Per estimator and angle: can it be determined at this set-up, with what limits.

    Returns
    -------
    dict
        ``{estimator: {"alpha_z"|"alpha_y"|"alpha_x": Observability}}``.
    """
    w, h = _shift(setup), setup.raise_mm
    dy = setup.step_mm
    sigma = setup.sensor_noise_um * 1e-3
    n_all = setup.lines * setup.points_per_line
    quantum = math.atan(dy / w)
    u_h = math.sqrt((setup.raise_error_um * 1e-3) ** 2 + 2 * sigma**2 / n_all)
    floor_x = math.sqrt(2 * u_h / h)
    at_1mrad = h * 1e-6 / 2 * 1e6  # h' - h at 1 mrad [nm]
    patent = {
        "alpha_z": Observability(
            True, True, quantum * 1e6, 0.0,
            f"integer row shift: alpha_z comes in steps of arctan(dy/w) = {quantum * 1e6:.4g} "
            f"urad (dy = {dy:g} mm, w = {w:g} mm); values between steps are rounded"),
        "alpha_y": Observability(
            True, True, 0.0, 0.0,
            "mean height difference of the common part; biased by the sub-step "
            "misregistration left by the integer row shift, and by the sensor's linearity "
            "error through e(x_l + w) - e(x_l)"
            + ("" if abs(w / _pitch(setup) - round(w / _pitch(setup))) < 1e-9 else
               f"; w = {w / _pitch(setup):.4g} point spacings is not a whole number, so the "
               f"alignment interpolates across the facets' kinks (a bias of some 10 urad: "
               f"choose shift_fraction so that w is a whole number of spacings)")
            + ("" if setup.lines * dy >= setup.cell_size_mm * (1 - 1e-9) else
               f"; the scan ({setup.lines} x {dy:g} mm) covers less than one cell pitch "
               f"({setup.cell_size_mm:g} mm) along Y, so which facets it holds, and the bias, "
               f"depend on where the artifact lies (tens of urad)")),
        "alpha_x": Observability(
            floor_x < ALPHA_MAX, False, 0.0, floor_x * 1e6,
            f"arccos(h/h') is even in alpha_x (returns |alpha_x|) and flat at small angles: "
            f"h' - h = h*alpha^2/2 = {at_1mrad:.3g} nm at 1 mrad, against a standard "
            f"uncertainty of h' of {u_h * 1e6:.3g} nm (raise positioning, sensor noise), so "
            f"|alpha_x| below about {floor_x * 1e3:.3g} mrad is indistinguishable from 0"
            + (f", more than the {ALPHA_MAX * 1e3:g} mrad this procedure is for: not "
               f"measurable at this set-up" if floor_x >= ALPHA_MAX else "")
            + "; even noise-free it does not estimate alpha_x (nor arccos(cos ax cos ay), "
              "which holds on the flat parts of a level artifact only): h' is weighted by "
              "the facets in the window, which change the height by up to h tan(facet) times "
              "the measuring direction's tilt, +-2 um at 2 mrad, and cancel only as far as "
              "the scan covers them in equal shares"),
    }
    ok, why = _registration_check(setup)
    reg = {k: Observability(ok, True, 0.0, 0.0, why) for k in ("alpha_z", "alpha_y", "alpha_x")}
    why_pattern = (why if not ok else
                   "generalised least squares of the forward model on the stated pattern, "
                   "weighted by the error budget (started from the registration); as good as "
                   "the pattern is known (facet_position_um)")
    pattern = {k: Observability(ok, True, 0.0, 0.0, why_pattern)
               for k in ("alpha_z", "alpha_y", "alpha_x")}
    return {"patent": patent, "registration": reg, "pattern": pattern}


def resolution(setup, estimator: str) -> dict:
    """The steps [rad] in which `estimator`'s values come: the patent's alpha_z is a whole
    row shift, in steps of ``arctan(dy / w)``; the others are continuous (empty)."""
    return {"alpha_z": math.atan(setup.step_mm / _shift(setup))} if estimator == "patent" else {}


@functools.lru_cache(maxsize=64)
def _registration_check(setup) -> tuple[bool, str]:
    """Whether the registration works at `setup`: the facets must be resolved (three
    samples across), and on the noise-free data of the default truth the fit must be
    well conditioned and recover the angles."""
    p, dy = _pitch(setup), setup.step_mm
    facet = setup.cell_depth_mm / math.tan(math.radians(setup.facet_angle_deg))
    if facet < 3 * max(p, dy):
        return False, (
            f"the facets ({facet:.3g} mm wide) are narrower than three samples "
            f"(3 x {max(p, dy):.3g} mm): the registration has no sloped surface to work on; "
            f"use more points per line, a finer step or shallower facets")
    truth = Truth()
    try:
        z = forward(setup, truth, PROCEDURE.zero_errors(setup, 1))["z_mm"]
    except InvalidInput as exc:
        return False, f"the default truth cannot be scanned at this set-up ({exc})"
    est = _registration_core(setup, z)
    err = max(abs(float(est[k][0]) - v) for k, v in true_values(setup, truth).items())
    if not err < 1e-9:
        return False, (
            "too few planar samples on the facets (a narrow scan, few points per line or "
            "few lines): on noise-free data of the default truth the registration's normal "
            "equations are singular or it misses the angles; scan more lines or use more "
            "points per line")
    return True, ("sub-step least-squares registration of the sloped facets, exact rotation "
                  "fit; the raise shifts the pattern by -h*tan(alpha_x) along Y, which gives "
                  "the sign")


# the estimators (a submodule of their own: the physics above is what they fit)
from mtplan.models.line_laser._estimators import (  # noqa: E402
    _FIT_FIELDS,
    _FIT_STEPS,
    _registration_core,
    _truth_rows,
    estimate_patent,
    estimate_pattern,
    estimate_registration,
)


# --------------------------------------------------------------------------- time, frames
def duration(setup) -> float:
    """Machine time of the three scans [s]: scans at the feed the frame rate allows,
    the moves between them at rapid feed, a dwell before each scan."""
    return float(_scan_times(setup)[-1])


_COLUMNS = ("scan", "line", "point", "x_mm", "y_mm", "z_mm")


def readings_frame(setup, readings) -> pd.DataFrame:
    """One measurement (the first trial) as a tidy table, one height per row.

    Columns: ``scan`` (1, 2, 3), ``line`` (0..lines-1), ``point``
    (0..points_per_line-1), ``x_mm`` (position along the laser line), ``y_mm``
    (nominal machine Y of the trigger), ``z_mm`` (reported height).
    """
    z = np.asarray(readings["z_mm"], dtype=float)[0]
    k, j, i = np.meshgrid(np.arange(3), np.arange(setup.lines), np.arange(setup.points_per_line),
                          indexing="ij")
    return pd.DataFrame({
        "scan": k.ravel() + 1,
        "line": j.ravel(),
        "point": i.ravel(),
        "x_mm": _grid_u(setup)[i.ravel()],
        "y_mm": _grid_y(setup)[j.ravel()],
        "z_mm": z.ravel(),
    })


def from_frame(setup, df) -> dict:
    """Readings (a batch of one) from a table in the format of :func:`readings_frame`.

    Raises
    ------
    InvalidInput
        Missing columns, non-numeric or missing values, indices out of range or
        repeated, or positions that do not match the set-up's line and step.
    """
    vals = frame_columns(df, _COLUMNS, "line_laser data")
    p = Problems("line_laser data")
    expected = 3 * setup.lines * setup.points_per_line
    if len(df) != expected:
        p.add_text(f"The line_laser data have {len(df)} rows; the set-up (3 scans x {setup.lines} "
                   f"lines x {setup.points_per_line} points) needs {expected}")
        p.raise_if_any()
    for c, hi in (("scan", 3), ("line", setup.lines - 1), ("point", setup.points_per_line - 1)):
        lo = 1 if c == "scan" else 0
        col = vals[c]
        bad = np.flatnonzero((col != np.round(col)) | (col < lo) | (col > hi))
        if bad.size:
            p.add_text(f"Column {c!r} of the line_laser data must hold whole numbers {lo}..{hi}; "
                       f"row {int(bad[0])} has {col[bad[0]]:g}")
    p.raise_if_any()
    k = vals["scan"].astype(int) - 1
    j = vals["line"].astype(int)
    i = vals["point"].astype(int)
    flat = (k * setup.lines + j) * setup.points_per_line + i
    counts = np.bincount(flat, minlength=expected)
    if np.any(counts != 1):
        first = int(np.flatnonzero(counts != 1)[0])
        kk, rest = divmod(first, setup.lines * setup.points_per_line)
        jj, ii = divmod(rest, setup.points_per_line)
        p.add_text(f"The line_laser data must hold each (scan, line, point) once; "
                   f"({kk + 1}, {jj}, {ii}) occurs {int(counts[first])} times")
        p.raise_if_any()
    for c, grid, idx in (("x_mm", _grid_u(setup), i), ("y_mm", _grid_y(setup), j)):
        dev = np.abs(vals[c] - grid[idx])
        bad = np.flatnonzero(dev > 1e-6 * (1 + np.abs(grid[idx])))
        if bad.size:
            p.add_text(f"Column {c!r} of the line_laser data does not match the set-up's grid "
                       f"(line_width_mm, points_per_line, step_mm, lines): row {int(bad[0])} "
                       f"has {vals[c][bad[0]]:g}, expected {grid[idx[bad[0]]]:g}")
    p.raise_if_any()
    z = np.empty(expected)
    z[flat] = vals["z_mm"]
    return {"z_mm": z.reshape(1, 3, setup.lines, setup.points_per_line)}


def reading_limits(setup: Setup) -> dict:
    """Heights the sensor can report: its measuring range about the middle (z_l = 0) [mm]."""
    half = setup.range_mm / 2
    return {"z_mm": (-half, half, f"the sensor's measuring range (range_mm = {setup.range_mm:g})")}


def setup_from_frame(df: pd.DataFrame) -> dict:
    """The set-up fields a measured table of scans determines (see ``Implied``).

    The number of profiles per scan (``lines``, the distinct ``line`` indices) and of
    points per profile (``points_per_line``), the line's width (the span of ``x_mm``)
    and the scan step (the spacing of the trigger positions ``y_mm``, which must be even),
    each within 1e-6 mm. Where the table is not regular enough to tell, the field is left
    out and the design check names the offending row.
    """
    from mtplan.models.protocol import Implied

    tol = 1e-6
    line = pd.to_numeric(df["line"], errors="coerce").to_numpy(dtype=float)
    point = pd.to_numeric(df["point"], errors="coerce").to_numpy(dtype=float)
    x = pd.to_numeric(df["x_mm"], errors="coerce").to_numpy(dtype=float)
    y = pd.to_numeric(df["y_mm"], errors="coerce").to_numpy(dtype=float)
    if not all(np.all(np.isfinite(a)) for a in (line, point, x, y)):
        return {}
    lines, points = np.unique(line).size, np.unique(point).size
    out = {"lines": Implied(lines, why=f"the file's {lines} profiles per scan"),
           "points_per_line": Implied(points, why=f"the file's {points} points per profile")}
    xs = np.unique(np.round(x / tol)) * tol
    if xs.size == points:
        out["line_width_mm"] = Implied(float(f"{xs[-1] - xs[0]:.12g}"), tol,
                                       why="the span of x_mm")
    ys = np.unique(np.round(y / tol)) * tol
    steps = np.diff(ys)
    if ys.size == lines and lines > 1 and np.ptp(steps) <= 2 * tol:
        step = float(f"{(ys[-1] - ys[0]) / (lines - 1):.12g}")  # as written, not as summed
        out["step_mm"] = Implied(step, tol, why="the spacing of y_mm")
    return out


# the closed-form sensitivities (a submodule: each estimator's linear map times the sources'
# effects)
from mtplan.models.line_laser._first_order import sensitivities  # noqa: E402

PROCEDURE = Procedure(
    name="line_laser",
    title="Mounting error angles of a line-laser profile sensor",
    Setup=Setup,
    Truth=Truth,
    measurands=measurands,
    sources=sources,
    forward=forward,
    estimators={"patent": Estimator(
                    estimate_patent, description="The source method: whole-row shifts between "
                    "the scans, mean height differences and arccos(h/h').",
                    resolution=functools.partial(resolution, estimator="patent")),
                "registration": Estimator(
                    estimate_registration, exact=True, description="Least-squares "
                    "registration of the three scans to each other, then an exact rotation "
                    "fit."),
                "pattern": Estimator(
                    estimate_pattern, exact=True, description="Generalised least squares of "
                    "the forward model to the artefact's known pattern: angles and artefact "
                    "pose.")},
    true_values=true_values,
    duration=duration,
    description=(
        "Three scans of a hexagonal-cell artifact (base, shifted by w in X, raised by h in Z) "
        "give the sensor's mounting angles about Z, Y and X. The patent's estimator quantises "
        "alpha_z to dy/w and cannot see the sign (nor, at realistic machine errors, the size) "
        "of alpha_x; the registration estimator fits sub-step translations between the scans "
        "and the rotation exactly."
    ),
    levers=tuple("points_per_line step_mm lines shift_fraction raise_mm max_shift_rows "
                 "scan_feed_mm_min rapid_mm_min settle_s".split()),
    readings=ReadingsFormat(readings_frame, from_frame, setup_from_frame=setup_from_frame,
                            limits=reading_limits, noise_source="sensor_noise"),
    capabilities=Capabilities(block_size=128, truth_from_estimate=truth_from_estimate,
                              observability=observability,
                              first_order_sensitivities=sensitivities,
                              source_structure=source_structure),
)
