"""Rotary-axis location from an inclined plane (C and A axes; rotary-axis patent of 2020).

The test
--------
A flat inclined plane (incline 10-30 deg) is fastened to the C table of a table-tilting
five-axis machine. The rotary axis under test (C, or A with C held at zero) is turned to
``positions`` angles; at each, after the table is still, a point laser distance sensor on
the Z slide reads a rectangular lattice of heights on the incline. Each lattice gives a
plane; all planes are copies of one plane rotated about the true axis, so

- they share one point, where the axis pierces the incline (the least-squares solution
  of ``N P = -D``, ``N`` the stacked unit normals, ``D`` the offsets), and
- every normal makes the same angle alpha with the axis (``n_i . u = cos(alpha)``: the
  least-squares solution of ``N v = 1``, normalised, is the axis direction ``u``).

The axis is the line through ``P`` along ``u``. Neither step uses the angles the axis
was turned to, so the rotary axis's angular positioning error does not enter (the
``angles`` estimator below does use them: see Estimators).

Measuring order. C positions are taken in ascending order from 0 (the patent's six over
the full turn); A positions, by default, ascending (``a_order="ascending"``: -45 ... 45,
every position approached from one side, so the axis's reversal value is a common zero
that no estimator sees), or in the patent's order (S203: 0, 15, 30, 45, -15, -30, -45;
``a_order="patent"``: from 0 up, then from the first negative down), whose negative half
is approached from above and carries the reversal value (it moves ``angles``' EB0A; the
Monte Carlo draws it, so its u says so). The order also matters through the thermal
drift, which runs over the test's time line (:func:`schedule`).

Both axes (``axis="CA"``). The patent measures C (A held at 0) and then A (C held at 0)
and ends by computing the machining pose from both axis lines. A CA test is that
sequence on one time line: the C positions (``c_angles_deg``, default the six), then
the A positions (``positions``, ``range_deg``, ``angles_deg`` and ``a_order`` describe
the A part); the readings table says which axis turned at each position (``axis``
column). The per-test errors (sensor scale, flatness, the drift's rate) are shared by
both parts, since it is one artifact, one sensor and one test. Each part is estimated
as a single-axis test; the eight location errors are followed by the derived
measurands:

- ``ac_offset``: the offset of C from A, the signed length of their common
  perpendicular, positive when C passes on the +Y side of A (about EY0C - EY0A);
- ``ac_squareness``: 90 deg minus the angle between A and C, ``asin(u_A . u_C)``
  (about EB0C - EB0A);
- ``pose_dx``, ``pose_dy``, ``pose_dz``: the error of a workpiece point
  (``pose_point_mm``, on the table at A = C = 0) at the pose ``pose_a_deg``,
  ``pose_c_deg``: the point turned about the measured C line (C rides on A, and its line
  was measured at A = 0), then about the measured A line, minus the same on the nominal
  lines (Z and X through the origin). This is what the patent's last step, "calculate the
  machining attitude from the axes of A and C", needs from the test: the machine's
  actual kinematics in place of the nominal one. The axes' zero-angle errors (EA0A,
  EC0C) are not measured by the test (``angles`` takes a zero error of the encoder
  into its free common zero with the artifact's azimuth, the others use no angle) and
  are taken as zero.

Frame and conventions
---------------------
Machine frame X, Y, Z right-handed, Z up; the sensor reads along -Z. Lengths in mm and
angles in rad internally; results shown in um and urad.

- C axis: nominal axis = the Z line through the origin (the table centre); the table
  surface is at Z = 0. ``EX0C``, ``EY0C`` are where the axis line crosses the plane
  Z = ``reference_height_mm``; for the fitted direction scaled to u = (ux, uy, 1),
  ``EB0C = +ux`` and ``EA0C = -uy`` (ISO 230-7 location errors; a positive EA0C tips
  the axis towards -Y, a positive EB0C towards +X).
- A axis: nominal axis = the X line through the origin. ``EY0A``, ``EZ0A`` are where
  the axis crosses the plane X = ``reference_height_mm``; for u = (1, uy, uz),
  ``EC0A = +uy`` and ``EB0A = -uz``.
- The angles are the slope components above (tangents, not arcsines), in the truth as
  in the estimates, so noise-free recovery is exact.
- A positive angle turns the table right-handedly about +Z (C) or +X (A). The estimators
  do not use the sign, only the lattice placement does.

Set-up
------
At the zero position the incline passes through (0, 0, ``artifact_height_mm``) (above
the table centre; for the A axis this is its height above the nominal A axis) and falls
along the azimuth ``incline_azimuth_deg`` from +X: its upward unit normal is
``(sin i cos az, sin i sin az, cos i)``. The lattice is ``lattice_nx`` x ``lattice_ny``
points on a square of side ``lattice_size_mm``, aligned with X and Y (the slides place it)
and read in serpentine order. Its centre at the zero position is
(``lattice_offset_x_mm``, ``lattice_offset_y_mm``) relative to the nominal axis, and it
follows the artifact: at each position its centre is the vertical projection of that
surface point turned nominally with the table (for the A axis the artifact swings by
``artifact_height_mm * sin(A)`` in Y, so a fixed lattice would leave the artifact).

Measuring range. The lattice spans heights of ``lattice extent x tan(slope)`` (about
15 mm for 40 mm at 20 deg, more for the A axis, where the table's tilt adds to the
incline). With ``z_follows_surface`` (the default) the Z slide is sent to the nominal
surface height of each point, so the sensor only sees the deviation from the nominal
surface (tens of um); the reading is Z position + sensor value, and the Z axis's
positioning error enters in full, while the sensor's scale error acts on tens of um only.
Without it Z stays at the lattice centre's nominal height, and the set-up is refused
when a lattice's height span exceeds ``sensor_range_mm``; then the sensor's scale error
acts on the whole span.

Error sources (each a set-up field; 0 switches it off)
------------------------------------------------------
``probe_noise`` (per reading), ``sensor_scale`` (per test), ``xy_positioning`` and
``z_positioning`` (per reading: repeatability of the slides), ``flatness`` (form of the
incline, per test), ``thermal_drift`` (linear drift of sensor against table over the
test's time line from :func:`schedule`), ``radial_motion``, ``axial_motion`` and
``tilt_motion`` (error motions of the rotary axis, per position), ``angular_positioning``
(a smooth, repeatable function of the commanded angle: first and second harmonics per
axis, ISO 230-2's systematic positioning error) with ``angular_repeatability`` (its random
part, per position), ``angle_influence_halfwidth`` (the sensor's angle influence as a
function of the surface's local tilt in the sensor's frame: a height offset per position,
``range B(tau) (c0 + c1 cos phi + c2 cos 2 phi)``, B the data sheet's bound at the tilt's
magnitude tau, phi its direction from the triangulation plane; the even part c0 grows
with the tilt, the odd part c1 moves a C axis sideways by about ``e / tan(incline)``
along the triangulation plane, the anisotropy c2; a set-up tilting the surface beyond
``sensor_max_tilt_deg`` is refused), the artifact's real pose (``artifact_tilt``: normal, no hard bound, since the readings
determine it; ``artifact_height_error``), and the errors that act one to one: the laser
spot's lateral offset (``spot_offset_u``) and the sensor's zero (``sensor_zero_u``), the
X/Y motion's slope and bow in Z, machine-fixed (``xy_slope_halfwidth``,
``xy_straightness_halfwidth``), the rotary axis's reversal value (``reversal_halfwidth``:
a position approached against the first move is off by B) and the repeatable short-period
share of its positioning error (``angular_short_period_halfwidth``), and the sensor's
linearity curve about mid-range (``sensor_linearity_halfwidth``; ``sensor_scale`` is the
gain). A field named ``..._u_<unit>`` is a standard uncertainty, ``..._halfwidth_<unit>``
a half-width. :func:`sources` says where each default comes from.
A drift that is linear in time is the first-order model of ISO 230-3; it is the only
error whose effect depends on the measuring order. At the default rate the order hardly
matters (A axis, drift alone: u(EZ0A) 0.218 um ascending, 0.202 um in the patent's order;
the other three unchanged), so no further drift source (a random walk, a warm-up curve)
was added; docs/rotary_axis.md holds the budget tables.

The reversal (``sensor_reversal``): every lattice is read twice, with the sensor at 0
and at 180 deg about the spindle (M19, ``spindle_orient_s`` between the passes). The
spot's lateral offset and the angle influence's odd part change sign with the sensor;
the estimators fit each point's mean over the two passes, in which they cancel. The
readings are (n, P, 2 M), the second pass's points numbered on from M; ``duration``
counts the second pass.

Forward model
-------------
Exact rigid-body geometry: the artifact plane is turned about the *true* axis by the
commanded angle plus the angular positioning error (Rodrigues' formula), then moved by
the error motion (an exact rotation by the tilt vector about the true axis point at the
reference height, then the radial/axial translation); the vertical sensor ray at the
actual slide position meets that plane. Two first-order shortcuts, both far below a
nanometre: the form error (micrometres) is evaluated at the nominal hit point (the true
one is micrometres away; the form's slope is ~1e-4) and converted to height with the
nominal normal's Z component.

Estimators
----------
``patent``: the patent's three steps (the default of ``simulate``; ``estimate`` picks the
best exact estimator, ``angles`` at the defaults). Decisions where the patent is silent or its
formulas are lost:

1. Each plane is fitted by ordinary least squares of the heights on (x, y): the sensor
   errs along Z, so this is the plane the patent's "least-squares solution of
   X A + Y B + Z C + D = 0" means with C = -1. (A total-least-squares plane differs at
   second order in the noise and costs an eigen-decomposition per plane.) The design
   matrix is fixed by the set-up: one matrix product fits every plane of every trial.
2. Each plane is scaled to a unit normal (pointing up) before ``N P = -D``, so the
   residuals are distances.
3. ``N v = 1`` with the unit normals, then ``u = v / |v|``, as the patent.

``joint``: the least-squares fit of the whole model to all readings at once. The model
has the four axis parameters, the pierce point's position along the axis, the cone angle
alpha and one azimuth per position (the angles are *not* used: they are free, as in the
patent). Because every position's readings lie exactly on a plane for any parameter
values, the sum of squares over all readings equals the plane-fit residuals plus the
plane coefficients' misfit weighted by the lattice's normal matrix ``G^T G``; the fit is
therefore done on the plane coefficients, exactly, by Gauss-Newton on the whole batch
(started from ``patent``; the per-position azimuths eliminated by their Schur complement,
a 6 x 6 system per trial; Jacobian by central differences). It is the maximum-likelihood
estimate for independent Gaussian reading errors. With 3 positions both estimators are
the exact solution of the same equations and coincide.

``gls``: the same fit with each position's plane coefficients weighted by the inverse of
their covariance under every active error source of the set-up (computed once per set-up
by the law of propagation through forward model and plane fit; block-diagonal, so the
errors shared between positions, flatness, scale and drift, are left out of the weight).

What the Monte Carlo shows (4000 trials, default sizes; benchmarks and the tests hold
the figures): for the C axis the patent method is efficient, its standard deviations
equal the joint fit's to three digits, with every lattice geometry and angle set tried.
For the A axis the joint fit is 1-3 % better under reading noise alone (up to 11 % on
EZ0A with the incline's fall line at 60 deg to X), but with every default source it is
up to 13 % *worse* there: the per-position errors (error motions of the axis, Z
positioning) are not independent per reading, so the reading-count weighting that is
optimal for noise is not optimal for them. Weighted by the whole error budget (``gls``)
the joint fit recovers that loss and lands on the patent's uncertainty (within 2 %): the
patent's method is already efficient here. Beyond the estimator, the geometry decides:
the axial error motion of each position reads as a lateral offset of
``axial / tan(incline)`` (it dominates EX0C/EY0C by default), the direction of the A
axis along its arc is poorly determined (EB0A ~ 58 urad at +-45 deg, ~530 urad at
+-15 deg), and the angular positioning error has no effect at all on these three.

``angles`` (its figures below are those of per-position positioning errors; with the
smooth positioning error the tie cannot average the systematic part, and at its default
5 arcsec u(EB0A) is 35.7 urad against gls's 58.5, u(EA0C) 8.04 against 10.7, but A's
EC0A 14.0 against 13.8, and 27.8 against 23.6 with the fall line at 60 deg; the Monte
Carlo holds the smooth error, so its u stays honest as long as the stated bound is):
the ``gls`` fit with the azimuths tied to the commanded angles: position
p's azimuth is ``phi0 + theta_p``, ``theta_p`` the commanded angle, ``phi0`` one free
common zero (it takes up the artifact's azimuth and a zero error of the encoder), so the
fit has seven parameters per axis in place of 6 + positions: Gauss-Newton on the whole
batch, a 7 x 7 system per trial, Jacobian by central differences, started from the
patent's line. The angular positioning error moves each azimuth off ``phi0 + theta_p``
and enters through the weight (each position's plane-coefficient covariance). Exact
without noise (also with the artifact tilted and raised, every test case). What it
uses: the encoder's angles, which a careful engineer has (the control reads them), and
the posterior used from the start. What it gains (Monte Carlo, 20 000 trials, u of gls
-> angles): C axis EA0C 10.6 -> 8.06 urad, EB0C 10.7 -> 8.17 urad, EX0C/EY0C 1.27 ->
1.23 um; A axis EB0A 58.3 -> 36.0 urad (the short A arc gains most), EZ0A 3.31 -> 3.22
um, EY0A and EC0A unchanged (0.788 um, 14.0 urad: +0.5 %, the block weight leaves the
per-test errors out); CA ac_squareness 59.3 -> 36.8 urad, pose_dx 3.34 -> 2.69 um. It
is then the default, and its `mc` u matches the posterior's within 1-2 % (C, example
readings; A, simulated). Its price: it trusts the encoder. Its u grows with the stated
``angular_positioning_arcsec`` and meets gls's when the encoder says nothing (C EA0C
7.97, 8.06, 8.96, 10.2 urad at 0, 5, 20, 60 arcsec; A EB0A 28.4, 36.0, 53.1, 57.5 urad;
gls 10.6 and 58.3 throughout). An axis that really positions worse than the set-up
states makes its u an underestimate, where the other three do not care: an axis of
+-30 arcsec with the set-up's +-5 spreads C EA0C/EB0C by 11.0 urad (the Monte Carlo
says 8.1; gls 10.8) and A EB0A by 123 urad (the Monte Carlo says 36; gls 58). State
the axis's positioning error (ISO 230-2) truthfully, or use gls. About 1.5 times gls's
time (19 000 trials/s on the default C set-up, gls 25 000).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import pandas as pd

from mtplan._validate import Problems
from mtplan.fitting.fit3d import common_perpendicular
from mtplan.models.protocol import (
    Capabilities,
    Estimator,
    Measurand,
    Procedure,
    ReadingsFormat,
    SetupBase,
    Source,
    param,
)
from mtplan.uncertainty.distributions import Arcsine, Normal, Rectangular

__all__ = [
    "Setup",
    "Truth",
    "measurands",
    "sources",
    "forward",
    "estimate_patent",
    "estimate_joint",
    "estimate_gls",
    "estimate_angles",
    "axis_line",
    "true_values",
    "schedule",
    "duration",
    "readings_frame",
    "from_frame",
    "PROCEDURE",
]

NAME = "rotary_axis"
_UM = 1e-3  # mm per um
_URAD = 1e-6  # rad per urad
_ARCSEC = math.pi / 648000  # rad per arcsec
_DEFAULT_POSITIONS = {"C": 6, "A": 7}
_DEFAULT_RANGE = {"C": 360.0, "A": 90.0}
#: a point laser reading along -Z loses the spot on surfaces steeper than this
_MAX_SLOPE_DEG = 70.0
#: smallest |X component| of the incline's normal for the A axis (below: X unobservable)
_MIN_NORMAL_X = 0.01


# --------------------------------------------------------------------------- set-up
@dataclass(frozen=True)
class Setup(SetupBase):
    """Set-up of the inclined-plane rotary-axis test (fields carry their unit)."""

    _owner = NAME

    axis: str = param("C", doc="Rotary axis under test: C (about Z), A (about X), or CA: "
                      "both, C first at A = 0, then A with C at 0 (the patent's S102, S103), "
                      "with the location of C against A and the machining-pose error",
                      choices=("C", "A", "CA"))
    incline_deg: float = param(20.0, doc="Incline of the artifact plane [deg]; > 0, since a "
                               "level plane's normals all lie along the axis and locate nothing "
                               "(the patent uses 10-30)", low=0, high=60, low_open=True)
    incline_azimuth_deg: float = param(0.0, doc="Direction of the incline's fall line from +X "
                                       "at the zero position [deg]", low=-360, high=360)
    positions: int | None = param(None, doc="Number of axis positions, >= 3 (empty: 6 for C, "
                                  "7 for A); for CA, of the A part", low=3, high=360)
    range_deg: float | None = param(None, doc="Angular range [deg]: C positions equally spaced "
                                    "over it starting at 0 (360: the full turn), A positions "
                                    "spaced over -range/2..range/2 inclusive in a_order (empty: "
                                    "360 for C, 90 for A); for CA, of the A part", low=0,
                                    high=360, low_open=True)
    angles_deg: tuple[float, ...] | None = param(None, doc="Explicit axis angles in measuring "
                                                 "order [deg]; overrides positions and "
                                                 "range_deg; for CA, of the A part", low=-720,
                                                 high=720, min_len=3)
    a_order: str = param("ascending", doc="Measuring order of the A positions from positions "
                         "and range_deg: 'ascending' (-range/2 up to +range/2, every position "
                         "approached in one direction, so the reversal value B cannot bias the "
                         "result) or 'patent' (0 and up to +range/2, then from the first "
                         "negative down to -range/2: 0, 15, 30, 45, -15, -30, -45 as in the "
                         "patent's example; its down-approached positions carry B)",
                         choices=("patent", "ascending"))
    c_angles_deg: tuple[float, ...] | None = param(None, doc="C angles of the combined test "
                                                   "(axis CA) in measuring order [deg] "
                                                   "(empty: 6 over the full turn, as the "
                                                   "patent's example)", low=-720, high=720,
                                                   min_len=3)
    pose_a_deg: float = param(45.0, doc="CA: A angle of the machining pose whose error is "
                              "reported (pose_dx, pose_dy, pose_dz) [deg]", low=-360, high=360)
    pose_c_deg: float = param(90.0, doc="CA: C angle of that pose [deg]", low=-360, high=360)
    pose_point_mm: tuple[float, ...] = param((100.0, 50.0, 100.0), doc="CA: the workpiece "
                                             "point (X, Y, Z on the table at A = C = 0) whose "
                                             "position error at the pose is reported [mm]",
                                             low=-5000, high=5000, min_len=3)
    lattice_nx: int = param(5, doc="Lattice points along X, >= 2 (one column is a line: the "
                            "plane's tilt across it is undetermined)", low=2, high=101)
    lattice_ny: int = param(5, doc="Lattice points along Y, >= 2 (one row is a line)",
                            low=2, high=101)
    lattice_size_mm: float = param(40.0, doc="Side of the square lattice [mm]", low=0,
                                   high=1000, low_open=True)
    lattice_offset_x_mm: float = param(0.0, doc="Lattice centre at the zero position, X from "
                                       "the nominal axis [mm]", low=-1000, high=1000)
    lattice_offset_y_mm: float = param(0.0, doc="Lattice centre at the zero position, Y from "
                                       "the nominal axis [mm]", low=-1000, high=1000)
    artifact_height_mm: float = param(50.0, doc="Height of the incline above the table centre "
                                      "at the zero position (for A: above the nominal A axis) "
                                      "[mm]", low=-1000, high=1000)
    reference_height_mm: float = param(0.0, doc="C: height Z at which EX0C, EY0C are stated; "
                                       "A: position X at which EY0A, EZ0A are stated [mm]",
                                       low=-2000, high=2000)
    z_follows_surface: bool = param(True, doc="Z slide follows the nominal surface point by "
                                    "point (reading = Z position + sensor value); otherwise Z "
                                    "stays at the lattice centre's height for a whole lattice")
    sensor_range_mm: float = param(10.0, doc="Measuring range of the distance sensor [mm]",
                                   low=0, high=1000, low_open=True)
    probe_noise_um: float = param(1.0, doc="Standard deviation of one sensor reading [um]",
                                  low=0, high=1000)
    sensor_scale_ppm: float = param(500.0, doc="Half-width of the sensor's scale error "
                                    "(rectangular) [ppm]", low=0, high=1e5)
    xy_positioning_um: float = param(1.0, doc="Standard deviation of the X and Y slides' "
                                     "positioning at each lattice point [um]", low=0, high=1000)
    z_positioning_um: float = param(1.0, doc="Standard deviation of the Z slide's positioning "
                                    "at each reading [um]", low=0, high=1000)
    flatness_um: float = param(2.0, doc="Flatness of the incline over the lattice, peak to "
                               "valley [um]", low=0, high=1000)
    artifact_tilt_urad: float = param(5000.0, doc="Standard deviation (normal, no hard "
                                      "bound) of each of the two tilts of the artifact's real "
                                      "plane from its nominal incline and azimuth [urad]: the "
                                      "plane is clamped by eye, not calibrated; the patent's "
                                      "method does not need it", low=0, high=1e5)
    artifact_height_error_um: float = param(100.0, doc="Half-width (rectangular) of the "
                                            "artifact's real height from the nominal "
                                            "artifact_height_mm [um] (fixture drawing and "
                                            "clamping)", low=0, high=1e5)
    thermal_drift_um_per_s: float = param(0.001, doc="Standard deviation of each component "
                                          "(X, Y, Z) of the sensor-to-table drift rate "
                                          "[um/s]", low=0, high=10)
    radial_motion_um: float = param(3.0, doc="Radial error motion of the rotary axis, peak to "
                                    "valley per direction [um]", low=0, high=1000)
    axial_motion_um: float = param(2.0, doc="Axial error motion of the rotary axis, peak to "
                                   "valley [um]", low=0, high=1000)
    tilt_motion_urad: float = param(10.0, doc="Tilt error motion of the rotary axis, peak to "
                                    "valley per direction [urad]", low=0, high=1e4)
    angular_positioning_arcsec: float = param(5.0, doc="Bound of the rotary axis's "
                                              "systematic angular positioning error, a smooth "
                                              "and repeatable function of the commanded angle "
                                              "(first and second harmonics, each of amplitude "
                                              "up to half the bound) [arcsec]", low=0,
                                              high=3600)
    angular_repeatability_arcsec: float = param(1.0, doc="Standard deviation of the rotary "
                                                "axis's random positioning error at each "
                                                "position (ISO 230-2 repeatability R = 4 s) "
                                                "[arcsec]", low=0, high=3600)
    spot_offset_u_um: float = param(5.0, doc="Standard uncertainty of each component (X, "
                                    "Y) of the laser spot's lateral offset from the point the "
                                    "slides command, as located by scanning a sphere or an edge "
                                    "[um] (a 10 mm triangulation sensor's spot is 50-100 um "
                                    "across on its data sheet; located to about a tenth)",
                                    low=0, high=1000)
    sensor_zero_u_um: float = param(2.0, doc="Standard uncertainty of the sensor's zero (the "
                                    "reading at the commanded Z on the nominal surface), as set "
                                    "on a gauge block by the Z slide [um] (ISO 230-2 "
                                    "repeatability of Z)", low=0, high=1000)
    xy_slope_halfwidth_urad: float = param(20.0, doc="Half-width (rectangular) of each "
                                           "component of the slope of the X and Y motion "
                                           "against Z over the lattice, the same at every "
                                           "position [urad] (half the ISO 10791-2 squareness "
                                           "tolerance of 0.020 mm/500 mm)", low=0, high=1e4)
    xy_straightness_halfwidth_um: float = param(1.0, doc="Half-width (rectangular) of the bow "
                                                "of the X and of the Y motion in Z over +-50 "
                                                "mm about the table centre, the same at every "
                                                "position [um] (ISO 10791-2 straightness "
                                                "0.010 mm/500 mm, proportional to 100 mm)",
                                                low=0, high=1000)
    reversal_halfwidth_arcsec: float = param(5.0, doc="Half-width (rectangular, sign unknown) "
                                             "of the rotary axis's reversal value B (ISO 230-2) "
                                             "[arcsec]: a position approached in the other "
                                             "direction than the first is off by B (worm-driven "
                                             "tables: 2-10 arcsec)", low=0, high=3600)
    angular_short_period_halfwidth_arcsec: float = param(1.0, doc="Amplitude (arcsine: a "
                                                         "sinusoid of unknown phase) of the "
                                                         "rotary axis's short-period "
                                                         "positioning error at each position "
                                                         "(encoder interpolation, worm), "
                                                         "systematic: the same in every test "
                                                         "[arcsec] (angle encoders' error "
                                                         "within one signal period, about "
                                                         "+-1 % of a 30-80 arcsec period)",
                                                         low=0, high=3600)
    sensor_linearity_halfwidth_ppm: float = param(800.0, doc="Half-width of the sensor's "
                                                  "linearity deviation over its range, in ppm "
                                                  "of sensor_range_mm [ppm] (a curve about the "
                                                  "best straight line, zero at mid-range; "
                                                  "triangulation data sheets: +-0.08 % of the "
                                                  "range)", low=0, high=1e5)
    angle_influence_halfwidth_ppm: float = param(5000.0, doc="Bound of the sensor's angle "
                                                 "influence at a 30 deg tilt of the surface, "
                                                 "in ppm of sensor_range_mm; at other tilts "
                                                 "the bound follows the data sheet's table "
                                                 "(0.12 % at 5 deg, 0.2 % at 15, 0.5 % at "
                                                 "30 deg for diffuse surfaces) scaled to it "
                                                 "[ppm]", low=0, high=1e5)
    sensor_max_tilt_deg: float = param(50.0, doc="Largest tilt of the surface under the "
                                       "sensor the set-up may have [deg]; larger tilts are "
                                       "refused. Data sheets state the angle influence to 30 "
                                       "deg; beyond, the bound is extrapolated along the "
                                       "table's last row (the A axis's default +-45 deg tilts "
                                       "the 20 deg incline to 48.4 deg)", low=0, high=70,
                                       low_open=True)
    sensor_azimuth_deg: float = param(0.0, doc="Azimuth from +X of the sensor's triangulation "
                                      "plane (its laser and receiver) at spindle orientation 0 "
                                      "[deg]", low=-360, high=360)
    sensor_reversal: bool = param(False, doc="Read each lattice twice, with the sensor at 0 "
                                  "and at 180 deg about the spindle (M19): the mean cancels "
                                  "the odd part of the angle influence and the spot's lateral "
                                  "offset; costs a second pass and spindle_orient_s per "
                                  "position")
    spindle_orient_s: float = param(5.0, doc="Time to turn the spindle with the sensor by 180 "
                                    "deg (M19) and settle, once per position with "
                                    "sensor_reversal [s]", low=0, high=600)
    dwell_s: float = param(0.5, doc="Settling and reading time per lattice point [s]", low=0,
                           high=600)
    feed_mm_min: float = param(2000.0, doc="Feed of the X/Y moves between points [mm/min]",
                               low=0, high=1e5, low_open=True)
    index_time_s: float = param(5.0, doc="Time to turn, clamp and settle the rotary axis at "
                                "each position [s]", low=0, high=3600)

    # ----------------------------------------------------------------- derived
    @property
    def n_positions(self) -> int:
        """Number of axis positions (of both axes for CA)."""
        return len(self.angles())

    @property
    def n_points(self) -> int:
        """Lattice points per position."""
        return self.lattice_nx * self.lattice_ny

    @property
    def n_passes(self) -> int:
        """Passes over each lattice: 2 with sensor_reversal (sensor at 0 and 180 deg), else 1."""
        return 2 if self.sensor_reversal else 1

    @property
    def n_readings(self) -> int:
        """Readings per position: the lattice points of every pass."""
        return self.n_points * self.n_passes

    @property
    def axes(self) -> tuple[str, ...]:
        """The axes measured, in measuring order: ('C',), ('A',) or ('C', 'A')."""
        return ("C", "A") if self.axis == "CA" else (self.axis,)

    def axis_angles(self, axis: str) -> np.ndarray:
        """Commanded angles of `axis` ('C' or 'A') in measuring order, array [deg]."""
        if self.axis == "CA" and axis == "C":
            if self.c_angles_deg is not None:
                return np.asarray(self.c_angles_deg, dtype=float)
            return 360.0 * np.arange(6) / 6
        if self.angles_deg is not None:
            return np.asarray(self.angles_deg, dtype=float)
        n = self.positions if self.positions is not None else _DEFAULT_POSITIONS[axis]
        span = self.range_deg if self.range_deg is not None else _DEFAULT_RANGE[axis]
        if axis == "A":
            grid = np.linspace(-span / 2, span / 2, n)
            if self.a_order == "patent":
                grid = np.concatenate([grid[grid >= 0], grid[grid < 0][::-1]])
            return grid
        if span >= 360.0:
            return span * np.arange(n) / n
        return np.linspace(0.0, span, n)

    def angles(self) -> np.ndarray:
        """Commanded angles of every position in measuring order (C, then A for CA) [deg]."""
        return np.concatenate([self.axis_angles(a) for a in self.axes])

    def _check(self, p: Problems) -> None:
        if self.angles_deg is not None and self.positions is not None \
                and self.positions != len(self.angles_deg):
            p.add("positions", self.positions,
                  f"empty or equal to the number of angles_deg ({len(self.angles_deg)})")
        if self.c_angles_deg is not None and self.axis != "CA":
            p.add("c_angles_deg", self.c_angles_deg,
                  "empty unless axis is 'CA' (it sets the C part of the combined test)")
        if len(self.pose_point_mm) != 3:
            p.add("pose_point_mm", self.pose_point_mm, "three numbers: X, Y, Z")
        n0 = _incline_normal(self)
        if "A" in self.axes and abs(n0[0]) < _MIN_NORMAL_X:
            p.add_text(
                f"The 'incline_azimuth_deg' parameter of {NAME} must give the incline's normal "
                f"an X component of at least {_MIN_NORMAL_X} in magnitude for the A axis, or the "
                "axis direction along X is unobservable (all normals make the same angle with "
                f"any direction in the Y-Z plane). sin(incline_deg) * cos(incline_azimuth_deg) "
                f"= {n0[0]:.3g} with incline_deg={self.incline_deg!r}, "
                f"incline_azimuth_deg={self.incline_azimuth_deg!r}"
            )
        for axis in self.axes:
            self._check_axis(p, axis, n0)

    def _check_axis(self, p: Problems, axis: str, n0: np.ndarray) -> None:
        """Distinct positions, a readable surface and the sensor's range for one axis."""
        angles = self.axis_angles(axis)
        if self.axis == "CA" and axis == "C":
            field, value = "c_angles_deg", self.c_angles_deg
        elif self.angles_deg is not None:
            field, value = "angles_deg", self.angles_deg
        else:
            field, value = "range_deg", self.range_deg
        distinct = np.unique(np.round(np.mod(angles, 360.0), 9) % 360.0)
        if distinct.size < 3:
            p.add(field, value,
                  f"a set-up with at least 3 distinct {axis} positions (fewer planes do not "
                  f"determine the axis); these angles give {distinct.size}")
        rot = _nominal_rotations(axis, np.deg2rad(angles))
        nz = (rot @ n0)[:, 2]
        steep = nz < math.cos(math.radians(_MAX_SLOPE_DEG))
        if np.any(steep):
            bad = angles[steep]
            slope = np.degrees(np.arccos(np.clip(nz[steep], -1, 1)))
            p.add_text(
                f"The incline cannot be read at the {axis} angles {np.round(bad, 6).tolist()} "
                f"deg of {NAME}: the surface is {np.round(slope, 1).tolist()} deg steep there "
                f"(a sensor reading along -Z needs less than {_MAX_SLOPE_DEG:g} deg); reduce "
                f"incline_deg or the angles ({field})"
            )
        elif np.any((tilt := np.degrees(np.arccos(np.clip(nz, -1, 1))))
                    > self.sensor_max_tilt_deg):
            worst = int(np.argmax(tilt))
            p.add("sensor_max_tilt_deg", self.sensor_max_tilt_deg,
                  f">= the largest tilt of the surface under the sensor, {tilt[worst]:.1f} deg "
                  f"at {axis} = {angles[worst]:g} deg (the sensor's angle influence is not "
                  f"stated beyond its range: state a sensor whose data sheet covers the tilt, "
                  f"or reduce incline_deg or the angles ({field}))")
        if not np.any(steep) and not self.z_follows_surface:
            _, _, z_cmd = _lattice(self, axis, angles)
            span = float(np.max(np.ptp(z_cmd, axis=1)))
            if span > self.sensor_range_mm:
                p.add(
                    "sensor_range_mm", self.sensor_range_mm,
                    f">= the lattice's height span of {span:.4g} mm when z_follows_surface is "
                    "false (or let Z follow the surface, or shrink lattice_size_mm or "
                    "incline_deg)",
                )


@dataclass(frozen=True)
class Truth(SetupBase):
    """True location errors of the axis under test (only the tested axis's four are used)."""

    _owner = f"{NAME} truth"

    EX0C_um: float = param(12.0, doc="C axis: X position at the reference height [um]")
    EY0C_um: float = param(-8.0, doc="C axis: Y position at the reference height [um]")
    EA0C_urad: float = param(25.0, doc="C axis: orientation error about X [urad]")
    EB0C_urad: float = param(-15.0, doc="C axis: orientation error about Y [urad]")
    EY0A_um: float = param(10.0, doc="A axis: Y position at the reference X [um]")
    EZ0A_um: float = param(-5.0, doc="A axis: Z position at the reference X [um]")
    EB0A_urad: float = param(20.0, doc="A axis: orientation error about Y [urad]")
    EC0A_urad: float = param(-30.0, doc="A axis: orientation error about Z [urad]")


# --------------------------------------------------------------------------- geometry
class _Frame(NamedTuple):
    ax: np.ndarray  # nominal axis direction (3,)
    p1: np.ndarray  # first perpendicular (3,): X for C, Y for A
    p2: np.ndarray  # second perpendicular (3,): Y for C, Z for A


_FRAMES = {
    "C": _Frame(np.array([0.0, 0, 1]), np.array([1.0, 0, 0]), np.array([0.0, 1, 0])),
    "A": _Frame(np.array([1.0, 0, 0]), np.array([0.0, 1, 0]), np.array([0.0, 0, 1])),
}
_NAMES = {  # (position 1, position 2, angle about p1, angle about p2)
    "C": ("EX0C", "EY0C", "EA0C", "EB0C"),
    "A": ("EY0A", "EZ0A", "EB0A", "EC0A"),
}


def _incline_normal(setup: Setup) -> np.ndarray:
    i, az = math.radians(setup.incline_deg), math.radians(setup.incline_azimuth_deg)
    return np.array([math.sin(i) * math.cos(az), math.sin(i) * math.sin(az), math.cos(i)])


def _nominal_rotations(axis: str, angles: np.ndarray) -> np.ndarray:
    """Right-handed rotations about the nominal axis, array (positions, 3, 3)."""
    c, s = np.cos(angles), np.sin(angles)
    one, zero = np.ones_like(c), np.zeros_like(c)
    if axis == "C":
        rows = [[c, -s, zero], [s, c, zero], [zero, zero, one]]
    else:
        rows = [[one, zero, zero], [zero, c, -s], [zero, s, c]]
    return np.moveaxis(np.array(rows), (0, 1), (-2, -1))


def _serpentine(nx: int, ny: int, size: float) -> tuple[np.ndarray, np.ndarray]:
    """Lattice offsets from its centre in measuring order, arrays (nx*ny,) [mm]."""
    xs = np.linspace(-size / 2, size / 2, nx)
    ys = np.linspace(-size / 2, size / 2, ny)
    gx = np.concatenate([xs if r % 2 == 0 else xs[::-1] for r in range(ny)])
    gy = np.repeat(ys, nx)
    return gx, gy


def _lattice(setup: Setup, axis: str, angles: np.ndarray):
    """Lattice centres (P, 3) on the nominal surface, points (P, M, 2), heights (P, M) [mm].

    For the positions `angles` [deg] of `axis` ('C' or 'A').
    """
    theta = np.deg2rad(angles)
    rot = _nominal_rotations(axis, theta)
    n0 = _incline_normal(setup)
    q0 = np.array([0.0, 0.0, setup.artifact_height_mm])
    ox, oy = setup.lattice_offset_x_mm, setup.lattice_offset_y_mm
    c0 = np.array([ox, oy, q0[2] - (n0[0] * ox + n0[1] * oy) / n0[2]])  # surface point
    centres = rot @ c0
    normals = rot @ n0  # (P, 3)
    points = rot @ q0  # a point of each nominal plane (P, 3)
    gx, gy = _serpentine(setup.lattice_nx, setup.lattice_ny, setup.lattice_size_mm)
    xy = np.stack([centres[:, None, 0] + gx, centres[:, None, 1] + gy], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = points[:, None, 2] - (
            normals[:, None, 0] * (xy[..., 0] - points[:, None, 0])
            + normals[:, None, 1] * (xy[..., 1] - points[:, None, 1])
        ) / normals[:, None, 2]
    return centres, xy, z


class _Plan(NamedTuple):
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
    times: np.ndarray  # time of each reading from the start (P, R) [s]
    total_time: float  # [s]
    down: np.ndarray  # 1 where a position is approached against the first move, else 0 (P,)
    machine: np.ndarray  # the X/Y motion's Z error per unit term: x, y, bows (4, P, R) [mm]


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
    rot = _nominal_rotations(axis, theta)
    n0 = _incline_normal(setup)
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


#: the angle influence's bound [fraction of the range] against the surface's tilt [deg]:
#: laser triangulation on diffuse surfaces (Micro-Epsilon optoNCDT 1700/2300 operating
#: instructions: typ. 0.12-0.2 % at 5-15 deg, 0.5 % at 15-30 deg); beyond the last row the
#: bound runs on along its slope (an extrapolation, stated in the field's doc)
_TILT_TABLE_DEG = np.array([0.0, 5.0, 15.0, 30.0])
_TILT_TABLE = np.array([0.0, 0.0012, 0.002, 0.005])


def _tilts(setup: Setup) -> tuple[np.ndarray, np.ndarray]:
    """Magnitude [deg] and direction from +X [rad] of the nominal surface's tilt under the
    sensor at every position: the angle of the normal from Z, the fall line's azimuth (P,)."""
    n0 = _incline_normal(setup)
    normals = np.concatenate([_nominal_rotations(a, np.deg2rad(setup.axis_angles(a))) @ n0
                              for a in setup.axes])
    tau = np.degrees(np.arccos(np.clip(normals[:, 2], -1.0, 1.0)))
    return tau, np.arctan2(normals[:, 1], normals[:, 0])


def _tilt_bound(tau: np.ndarray) -> np.ndarray:
    """The angle influence's bound at tilts `tau` [deg] relative to its bound at 30 deg (P,)."""
    slope = (_TILT_TABLE[-1] - _TILT_TABLE[-2]) / (_TILT_TABLE_DEG[-1] - _TILT_TABLE_DEG[-2])
    inside = np.interp(tau, _TILT_TABLE_DEG, _TILT_TABLE)
    beyond = _TILT_TABLE[-1] + slope * (tau - _TILT_TABLE_DEG[-1])
    bound = np.where(tau > _TILT_TABLE_DEG[-1], beyond, inside)
    return bound / _TILT_TABLE[-1]


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
def _plan(setup: Setup) -> _Plan:
    parts = []  # per axis measured: centres (P, 3), points, heights, form (P*M, K)
    for axis in setup.axes:
        angles = setup.axis_angles(axis)
        centres3, xy, z = _lattice(setup, axis, angles)
        parts.append((centres3, xy, z, _form_basis(setup, axis, angles, xy, z)))
    centres3, xy, z, form = (np.concatenate(arrays) for arrays in zip(*parts, strict=True))
    gx, gy = _serpentine(setup.lattice_nx, setup.lattice_ny, setup.lattice_size_mm)
    local = np.stack([np.ones_like(gx), gx, gy])
    fit = np.linalg.pinv(local.T).T  # (M, 3): coef = heights @ fit
    # every pass reads the lattice in the same order: readings (P, R), R = passes x M
    passes, P = setup.n_passes, xy.shape[0]
    xy, z = np.tile(xy, (1, passes, 1)), np.tile(z, (1, passes))
    form = np.tile(form.reshape(P, -1, form.shape[-1]), (1, passes, 1)).reshape(-1, form.shape[-1])
    times, total = _times(setup, xy)  # one time line through every axis's positions
    z_cmd = z if setup.z_follows_surface else centres3[:, 2:]
    out = _Plan(
        frame=_FRAMES.get(setup.axis),  # None for CA: each part has its own
        theta=np.deg2rad(setup.angles()),
        n0=_incline_normal(setup),
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
        tilt_bound=setup.sensor_range_mm * _tilt_bound(_tilts(setup)[0]),
        tilt_direction=_tilts(setup)[1] - math.radians(setup.sensor_azimuth_deg),
        times=times,
        total_time=total,
        down=np.concatenate([_approached_down(setup.axis_angles(a)) for a in setup.axes]),
        machine=_machine_basis(xy),
    )
    for arr in out:
        if isinstance(arr, np.ndarray):
            arr.setflags(write=False)
    return out


def _true_line(setup: Setup, truth: Truth) -> tuple[np.ndarray, np.ndarray]:
    """Point at the reference (3,) [mm] and unit direction (3,) of the true axis."""
    f = _FRAMES[setup.axis]
    # truth fields may be arrays (one truth per batch row, e.g. posterior walkers):
    # each value becomes shape (m, 1) so that point and direction are (m, 3)
    tv = {k: (np.reshape(v, (-1, 1)) if np.ndim(v) else v)
          for k, v in true_values(setup, truth).items()}
    n1, n2, a1, a2 = _NAMES[setup.axis]
    # slope components along p1 and p2 (see the sign convention in the module docstring)
    t1, t2 = tv[a2], -tv[a1]
    point = setup.reference_height_mm * f.ax + tv[n1] * f.p1 + tv[n2] * f.p2
    w = f.ax + t1 * f.p1 + t2 * f.p2
    return point, w / np.linalg.norm(w, axis=-1, keepdims=True)


def _rotate_about(v: np.ndarray, u: np.ndarray, angle: np.ndarray) -> np.ndarray:
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


def _rotate_by_vector(v: np.ndarray, w: np.ndarray) -> np.ndarray:
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


# --------------------------------------------------------------------------- protocol
_MEASURANDS = {
    "C": (
        Measurand("EX0C", "um", "X position of the C axis at the reference height"),
        Measurand("EY0C", "um", "Y position of the C axis at the reference height"),
        Measurand("EA0C", "urad", "orientation error of the C axis about X"),
        Measurand("EB0C", "urad", "orientation error of the C axis about Y"),
    ),
    "A": (
        Measurand("EY0A", "um", "Y position of the A axis at the reference X"),
        Measurand("EZ0A", "um", "Z position of the A axis at the reference X"),
        Measurand("EB0A", "urad", "orientation error of the A axis about Y"),
        Measurand("EC0A", "urad", "orientation error of the A axis about Z"),
    ),
    "CA": (
        Measurand("ac_offset", "um", "offset of the C axis from the A axis: signed length of "
                  "their common perpendicular, positive when C passes on the +Y side of A"),
        Measurand("ac_squareness", "urad", "squareness of C to A: 90 deg minus the angle "
                  "between them, asin(u_A . u_C) (about EB0C - EB0A)"),
        Measurand("pose_dx", "um", "X error of the workpiece point pose_point_mm at the pose "
                  "A = pose_a_deg, C = pose_c_deg, from the location errors of both axes"),
        Measurand("pose_dy", "um", "Y error of that point at that pose"),
        Measurand("pose_dz", "um", "Z error of that point at that pose"),
    ),
}


def measurands(setup: Setup) -> tuple[Measurand, ...]:
    """The ISO 230-7 location errors of each axis measured; for CA also the derived ones."""
    out = tuple(m for axis in setup.axes for m in _MEASURANDS[axis])
    return out + (_MEASURANDS["CA"] if setup.axis == "CA" else ())


def sources(setup: Setup) -> dict[str, Source]:
    """Every error source of the set-up, in internal units (mm, rad, 1).

    Shapes: P = positions, M = readings per position (the lattice's points, twice with
    sensor_reversal).
    """
    return {**_machine_sources(setup), **_sensor_and_setup_sources(setup)}


def _machine_sources(setup: Setup) -> dict[str, Source]:
    """The readings' noise and gain, the slides, the artifact, the drift, the rotary axis."""
    P, M = setup.n_positions, setup.n_readings  # M: readings per position, every pass
    um = _UM

    def rect(half):
        return Rectangular(-half, half)

    return {
        "probe_noise": Source(
            Normal(0.0, setup.probe_noise_um * um), (P, M),
            "Noise of one reading of the point laser sensor (standard deviation). Default 1 um: "
            "the repeatability of industrial laser triangulation sensors of 10-25 mm range on a "
            "ground metal surface (makers quote 0.5-2 um)."),
        "sensor_scale": Source(
            rect(setup.sensor_scale_ppm * 1e-6), (),
            "Scale (gain) error of the sensor, one per test, rectangular: its reading from "
            "mid-range is s (1 + kappa). Default +-500 ppm: the gain's share of a triangulation "
            "sensor's calibration (makers' certificates: +-0.03-0.1 % of the range); the "
            "curvature is sensor_linearity_halfwidth. With z_follows_surface it acts on the "
            "sensor's small residual only."),
        "xy_positioning": Source(
            Normal(0.0, setup.xy_positioning_um * um), (2, P, M),
            "X and Y positioning error of the slides at each lattice point (standard deviation; "
            "element [0] X, [1] Y). Default 1 um: ISO 230-2 unidirectional repeatability "
            "R = 4 s of about 4 um on a precision machining centre. A lateral error d changes "
            "the height by d tan(slope)."),
        "z_positioning": Source(
            Normal(0.0, setup.z_positioning_um * um), (P, M) if setup.z_follows_surface else (P,),
            "Z positioning error (standard deviation): enters the reading in full, since "
            "reading = Z position + sensor value; per reading when Z follows the surface, per "
            "lattice otherwise. Default 1 um, as for X and Y (ISO 230-2 repeatability)."),
        "flatness": Source(
            rect(setup.flatness_um * um / 4), (5,),
            "Form error of the incline, one per test: bowl, saddle, twist and two cubic waves "
            "over the lattice, coefficients uniform in +-flatness/4, so the form's peak to "
            "valley is about flatness_um. Default 2 um: DIN 876 grade 00 / ISO 8512 for a "
            "lapped face of 100-150 mm (2 (1 + L/1000) um)."),
        "artifact_tilt": Source(
            Normal(0.0, setup.artifact_tilt_urad * 1e-6), (2,),
            "Tilts of the artifact's real plane from the nominal one, one pair per test: [0] "
            "about the line across the fall line (the incline angle), [1] about the fall line. "
            "Normal, standard deviation 5 mrad (0.3 deg) by default: an inclined plane clamped "
            "on the table by eye is easily 5-20 mrad off. No hard bound: the readings "
            "determine the real plane, so a bounded prior would pull the axis when the plane "
            "lies beyond it. Every estimator fits each lattice's plane and never uses the "
            "nominal incline; a posterior must not take it as exact."),
        "artifact_height_error": Source(
            rect(setup.artifact_height_error_um * um), (),
            "Real height of the incline's reference point above its nominal, one per test. "
            "Default +-100 um: the fixture's drawing tolerance and its clamping."),
        "thermal_drift": Source(
            Normal(0.0, setup.thermal_drift_um_per_s * um), (3,),
            "Drift rate (X, Y, Z) of the sensor against the table during the test, one per "
            "test (standard deviation per component), applied over the time line of the test. "
            "Default 0.001 um/s (3.6 um/h): ISO 230-3 environmental drift of a machining "
            "centre in a workshop without temperature control of the machine."),
        "radial_motion": Source(
            rect(setup.radial_motion_um * um / 2), (P, 2),
            "Radial error motion of the rotary axis at each position, two directions "
            "perpendicular to the axis, uniform within +-half the value. Default 3 um: ISO "
            "230-7 radial error motion of direct-drive rotary tables (makers quote 2-5 um)."),
        "axial_motion": Source(
            rect(setup.axial_motion_um * um / 2), (P,),
            "Axial error motion at each position, uniform within +-half the value. Default 2 "
            "um: ISO 230-7 axial error motion of direct-drive rotary tables (1-3 um)."),
        "tilt_motion": Source(
            rect(setup.tilt_motion_urad * _URAD / 2), (P, 2),
            "Tilt error motion at each position about the two directions perpendicular to the "
            "axis (about the axis point at the reference height), uniform within +-half the "
            "value. Default 10 urad (2 arcsec): wobble specifications of precision rotary "
            "tables (1-5 arcsec)."),
        "angular_positioning": Source(
            rect(setup.angular_positioning_arcsec * _ARCSEC / (2 * math.sqrt(2))),
            (len(setup.axes), 4),
            "Systematic angular positioning error of each rotary axis tested, a smooth and "
            "repeatable function of the commanded angle theta: a1 cos theta + b1 sin theta + "
            "a2 cos 2 theta + b2 sin 2 theta (per axis [a1, b1, a2, b2]), each coefficient "
            "uniform within +-bound / (2 sqrt 2), so each harmonic's amplitude is at most half "
            "the bound and the error at most the bound. ISO 230-2 finds positioning errors of "
            "rotary axes dominated by such low orders (eccentricity of the encoder: the first "
            "harmonic; its ellipticity: the second). Default 5 arcsec: the positioning "
            "accuracy of rotary tables with direct angle encoders (trunnion A axes are often "
            "10-30 arcsec: state yours). patent, joint and gls do not use the angles."),
        "angular_repeatability": Source(
            Normal(0.0, setup.angular_repeatability_arcsec * _ARCSEC), (P,),
            "Random part of the angular positioning error at each position (standard "
            "deviation). Default 1 arcsec: ISO 230-2 unidirectional repeatability R = 4 s of "
            "about 2-4 arcsec of rotary tables with direct angle encoders."),
    }


def _sensor_and_setup_sources(setup: Setup) -> dict[str, Source]:
    """The errors that act one to one (spot, zero, the slides' slope and bow, reversal,
    short-period positioning, linearity) and the sensor's angle influence."""
    P = setup.n_positions
    um = _UM

    def rect(half):
        return Rectangular(-half, half)

    return {
        "spot_offset_u": Source(
            Normal(0.0, setup.spot_offset_u_um * um), (2,),
            "Lateral offset [0] X, [1] Y of the laser spot from the point the slides command, "
            "one per test (the sensor is fixed on the spindle): every reading is the height "
            "d away, so every plane, and with it the axis, moves by -d in X and Y, one to one. "
            "Normal, default 5 um per component: the spot (50-100 um across on a 10 mm "
            "triangulation sensor's data sheet) located on the machine by scanning a sphere or "
            "an edge, to about a tenth of its diameter."),
        "sensor_zero_u": Source(
            Normal(0.0, setup.sensor_zero_u_um * um), (),
            "Zero of the sensor (its reading at the commanded Z on the nominal surface), one "
            "per test: every reading is off by it, so the planes move along Z: one to one into "
            "the A axis's EZ0A, nothing on C. Normal, default 2 um: set on a gauge block by "
            "the Z slide, whose ISO 230-2 repeatability is a few micrometres."),
        "xy_slope_halfwidth": Source(
            rect(setup.xy_slope_halfwidth_urad * _URAD), (2,),
            "Slope in Z of the X [0] and Y [1] motion over the lattice (the squareness of X "
            "and Y to Z), machine-fixed: the same at every position. Each plane's slope is "
            "off by it, so the normals and with them the axis's direction tilt (EA0C, EB0C; "
            "EB0A, EC0A). Rectangular, default +-20 urad: half of ISO 10791-2's squareness "
            "tolerance of 0.020 mm/500 mm (40 urad), for a machine measured and compensated "
            "to within half of it."),
        "xy_straightness_halfwidth": Source(
            rect(setup.xy_straightness_halfwidth_um * um), (2,),
            "Bow in Z of the X [0] and Y [1] motion, b (x / 50 mm)^2 and b (y / 50 mm)^2 "
            "about the table centre, machine-fixed. Rectangular, default +-1 um: ISO 10791-2's "
            "straightness tolerance 0.010 mm/500 mm, taken proportionally to 100 mm."),
        "reversal_halfwidth": Source(
            rect(setup.reversal_halfwidth_arcsec * _ARCSEC), (len(setup.axes),),
            "Reversal value B (ISO 230-2) of each rotary axis tested, sign unknown: a position "
            "approached in the other direction than the test's first move is off by B (the "
            "first position is approached in the direction of the first move, after an "
            "overrun). Only the angles estimator uses the angles; in ascending order every "
            "position is approached one way and B is a common zero it absorbs; in the "
            "patent's A order (up, then down) it moves EB0A. Rectangular, default +-5 arcsec: "
            "ISO 230-2 reversal values of worm-driven rotary tables, 2-10 arcsec in makers' "
            "acceptance reports."),
        "angular_short_period_halfwidth": Source(
            Arcsine(-setup.angular_short_period_halfwidth_arcsec * _ARCSEC,
                    setup.angular_short_period_halfwidth_arcsec * _ARCSEC), (P,),
            "Short-period share of the rotary axis's positioning error at each position (the "
            "angle encoder's interpolation error within a signal period, the worm's error "
            "per turn): repeatable, so the same in every test, but of a period far shorter "
            "than the positions' spacing, so unrelated from one position to the next. "
            "Arcsine (a sinusoid of unknown phase), default amplitude 1 arcsec: angle "
            "encoders' position error within one signal period, about +-1 % of a 30-80 "
            "arcsec signal period (makers' catalogues). Only the angles estimator uses it."),
        "sensor_linearity_halfwidth": Source(
            rect(0.4 * setup.sensor_linearity_halfwidth_ppm * 1e-6), (2,),
            "The sensor's linearity deviation over its range, one curve per test: with x = 2 "
            "s / range (s the sensor value from mid-range), range (c2 1.5 x^2 + c3 (5 x^3 - 3 "
            "x) / 2), the Legendre terms P2 - P2(0) and P3 (a deviation about the best "
            "straight line, zero at mid-range, where the zero is set), each coefficient "
            "uniform within +-0.4 bound, so the curve stays within +-bound. Default 800 ppm: "
            "+-0.08 % of the range, triangulation sensors' data sheets (e.g. Micro-Epsilon "
            "optoNCDT 1750). The gain is sensor_scale. With z_follows_surface the sensor "
            "works about mid-range and this acts on tens of micrometres only."),
        "angle_influence_halfwidth": Source(
            rect(setup.angle_influence_halfwidth_ppm * 1e-6 / 3), (3,),
            "The sensor's angle influence: a height error of every reading of a position that "
            "depends on the local tilt of the surface in the sensor's frame, magnitude tau "
            "and direction phi (the fall line's azimuth from the triangulation plane), "
            "range * B(tau) * (c0 + c1 cos phi + c2 cos 2 phi): an even part c0 that grows "
            "with the tilt's magnitude, an odd part c1 along the triangulation plane (it "
            "changes sign when the sensor turns by 180 deg) and the anisotropy across it c2 "
            "(a sensor is symmetric about its triangulation plane: no sin phi terms). Each "
            "coefficient uniform within +-1/3 of the bound at 30 deg (the field), one set per "
            "test (one sensor), B(tau) the table relative to 30 deg, so the error stays "
            "within the data sheet's bound at the actual tilt. B: the angle "
            "influence tables of laser triangulation sensors on diffuse surfaces (Micro-"
            "Epsilon's operating instructions for optoNCDT 1700 and 2300: typ. 0.12-0.2 % "
            "of the range at 5-15 deg, 0.5 % at 15-30 deg), taken as 0.12 % at 5 deg, 0.2 % "
            "at 15, 0.5 % at 30 (linear between, through 0 at 0 deg; beyond 30 deg along "
            "the last row's slope, an extrapolation), scaled so that B(30 deg) = "
            "angle_influence_halfwidth_ppm. Default 5000 ppm (0.5 %). On a C axis the tilt "
            "is the incline at every position and the odd part moves the axis sideways by "
            "about e / tan(incline); on an A axis the tilt grows with |A| and the even part "
            "moves EZ0A."),
    }


def true_values(setup: Setup, truth: Truth) -> dict[str, float]:
    """True measurands of the axes under test [mm, rad] (for CA with the derived ones)."""
    out = {}
    if "C" in setup.axes:
        out.update({"EX0C": truth.EX0C_um * _UM, "EY0C": truth.EY0C_um * _UM,
                    "EA0C": truth.EA0C_urad * _URAD, "EB0C": truth.EB0C_urad * _URAD})
    if "A" in setup.axes:
        out.update({"EY0A": truth.EY0A_um * _UM, "EZ0A": truth.EZ0A_um * _UM,
                    "EB0A": truth.EB0A_urad * _URAD, "EC0A": truth.EC0A_urad * _URAD})
    if setup.axis == "CA":
        derived = _combined(setup, {k: np.array([v]) for k, v in out.items()})
        out.update({k: float(v[0]) for k, v in derived.items()})
    return out


def truth_from_estimate(setup: Setup, estimate: dict) -> Truth:
    """The Truth whose measurands equal `estimate` [mm, rad] (the other axis at its defaults).

    For CA the derived measurands follow from the eight location errors and are not
    Truth fields.
    """
    fields = {"EX0C": "EX0C_um", "EY0C": "EY0C_um", "EY0A": "EY0A_um", "EZ0A": "EZ0A_um",
              "EA0C": "EA0C_urad", "EB0C": "EB0C_urad", "EB0A": "EB0A_urad", "EC0A": "EC0A_urad"}
    values = {}
    for name, value in estimate.items():
        if name not in fields:
            continue
        field = fields[name]
        values[field] = float(np.asarray(value).ravel()[0]) / (_UM if field.endswith("_um") else _URAD)
    return Truth(**values)


# --------------------------------------------------------------------------- both axes (CA)
#: axis of each per-position source's errors (after the batch axis) that runs over positions
_POSITION_AXIS = {"probe_noise": 1, "xy_positioning": 2, "z_positioning": 1,
                  "radial_motion": 1, "axial_motion": 1, "tilt_motion": 1,
                  "angular_repeatability": 1, "angular_short_period_halfwidth": 1}
#: sources with one row of errors per axis tested (after the batch axis)
_AXIS_ROWS = ("angular_positioning", "reversal_halfwidth")


@functools.lru_cache(maxsize=64)
def _part(setup: Setup, axis: str) -> Setup:
    """The single-axis set-up of one part of a CA test (its angles, everything else shared)."""
    return Setup(**{**setup.as_dict(), "axis": axis,
                    "angles_deg": tuple(setup.axis_angles(axis).tolist()),
                    "positions": None, "range_deg": None, "c_angles_deg": None})


def _parts(setup: Setup) -> list[tuple[Setup, slice]]:
    """(single-axis set-up, its positions' slice of the whole test) for each axis measured."""
    if setup.axis != "CA":
        return [(setup, slice(0, setup.n_positions))]
    out, start = [], 0
    for axis in setup.axes:
        n = len(setup.axis_angles(axis))
        out.append((_part(setup, axis), slice(start, start + n)))
        start += n
    return out


def _measurand_line(axis: str, reference: float, m: dict) -> tuple[np.ndarray, np.ndarray]:
    """Point at the reference (n, 3) [mm] and unit direction (n, 3) from location errors."""
    f = _FRAMES[axis]
    n1, n2, a1, a2 = _NAMES[axis]
    point = reference * f.ax + m[n1][:, None] * f.p1 + m[n2][:, None] * f.p2
    w = f.ax + m[a2][:, None] * f.p1 - m[a1][:, None] * f.p2
    return point, w / np.linalg.norm(w, axis=-1, keepdims=True)


def _combined(setup: Setup, m: dict) -> dict[str, np.ndarray]:
    """The derived measurands of CA from the eight location errors (arrays (n,)) [mm, rad].

    The kinematics of a table-tilting machine whose C table rides on A: a workpiece
    point p (table coordinates at A = C = 0) is turned about the C line (as measured at
    A = 0) by the pose's C angle, then about the A line by its A angle; the nominal
    lines are the Z and X axes through the origin. The pose error is the actual point
    minus the nominal one.
    """
    pc, uc = _measurand_line("C", setup.reference_height_mm, m)
    pa, ua = _measurand_line("A", setup.reference_height_mm, m)
    _, _, dist, _ = common_perpendicular(pc, uc, pa, ua)  # (foot_C - foot_A) . (A x C) / |.|
    n = len(pc)
    a, c = math.radians(setup.pose_a_deg), math.radians(setup.pose_c_deg)
    p = np.asarray(setup.pose_point_mm, dtype=float)
    q = pc + _rotate_about(p - pc, uc, np.full(n, c))
    actual = pa + _rotate_about(q - pa, ua, np.full(n, a))
    nominal = (_nominal_rotations("A", np.array(a)) @ _nominal_rotations("C", np.array(c))) @ p
    err = actual - nominal
    return {"ac_offset": -dist, "ac_squareness": np.arcsin(np.sum(ua * uc, axis=-1)),
            "pose_dx": err[:, 0], "pose_dy": err[:, 1], "pose_dz": err[:, 2]}


def _each_axis(setup: Setup, readings: dict, estimate_axis) -> dict[str, np.ndarray]:
    """Run a single-axis estimator on each axis's positions; add CA's derived measurands."""
    z = _check_readings(setup, readings)
    out = {}
    for part, sl in _parts(setup):
        out.update(estimate_axis(part, z[:, sl]))
    if setup.axis == "CA":
        out.update(_combined(setup, out))
    return out


def forward(setup: Setup, truth: Truth, errors: dict) -> dict[str, np.ndarray]:
    """Simulated readings of the lattices: ``{"z_mm": array (n, positions, points)}``.

    Parameters
    ----------
    setup : Setup
    truth : Truth
    errors : dict of str to array
        Every source of :func:`sources`, each of shape ``(n, *shape)`` [mm, rad, 1].

    Returns
    -------
    dict
        ``z_mm``: the reading of each lattice point, Z position + sensor value [mm], in
        measuring order (for CA: the C positions, then the A positions). The per-test
        errors (scale, flatness, drift) are shared by both axes of a CA test; the drift
        runs on over the whole test's time line.
    """
    times = _plan(setup).times
    z = []
    for i, (part, sl) in enumerate(_parts(setup)):
        errs = {k: (v[(slice(None),) * _POSITION_AXIS[k] + (sl,)] if k in _POSITION_AXIS
                    else v[:, i] if k in _AXIS_ROWS else v) for k, v in errors.items()}
        z.append(_forward_axis(part, truth, errs, times[sl]))
    return {"z_mm": z[0] if len(z) == 1 else np.concatenate(z, axis=1)}


def _artifact_pose(g: _Plan, tilt, height) -> tuple[np.ndarray, np.ndarray]:
    """The artifact's real upward normal and reference point at the zero position: the
    nominal ones (3,), or (n, 3) turned by the per-test tilts (n, 2) [rad] about the line
    across the fall line and about the fall line, and raised by `height` (n,) [mm]."""
    n0, q0 = g.n0, g.q0
    if tilt is not None and np.any(tilt):
        fall = np.array([-n0[0], -n0[1], 0.0])  # downhill in the table plane
        fall = fall - (fall @ n0) * n0
        norm = np.linalg.norm(fall)
        f1 = fall / norm if norm > 1e-12 else np.array([1.0, 0.0, 0.0]) - n0[0] * n0
        f1 = f1 / np.linalg.norm(f1)
        f2 = np.cross(n0, f1)
        n0 = _rotate_by_vector(n0, tilt[:, :1] * f2 + tilt[:, 1:] * f1)
    if height is not None and np.any(height):
        q0 = q0 + height[:, None] * np.array([0.0, 0.0, 1.0])
    return n0, q0


def _forward_axis(setup: Setup, truth: Truth, errors: dict, times: np.ndarray) -> np.ndarray:
    """Readings (n, P, M) of one axis's positions; `times` (P, M) [s] for the drift."""
    g = _plan(setup)
    f = g.frame
    noise = errors["probe_noise"]
    n, P, M = noise.shape
    a, u = _true_line(setup, truth)  # (3,), or (n, 3) for one truth per trial
    ub = u[:, None, None, :] if u.ndim == 2 else u

    # rigid motion of the artifact at each position: exact rotation about the true axis by
    # the commanded angle, then by the angular positioning error, then the error motion
    # (tilt about the axis point, radial and axial translation). The normal and the lever
    # arm from the axis point to the incline's reference point turn together: (.., 2, 3).
    n0, q0 = _artifact_pose(g, errors.get("artifact_tilt"), errors.get("artifact_height_error"))
    lever = np.stack(np.broadcast_arrays(n0, q0 - a), axis=-2)  # (2, 3) or (n, 2, 3)
    if lever.ndim == 3:
        lever = lever[:, None]
    vec = _rotate_about(lever, ub, g.theta[:, None])  # (P, 2, 3) or (n, P, 2, 3)
    # angular positioning: the smooth systematic part (harmonics of the commanded angle)
    # plus the random part per position, (n, P) [rad]
    dpsi = (errors["angular_positioning"] @ g.harmonics + errors["angular_repeatability"]
            + errors["angular_short_period_halfwidth"]
            + errors["reversal_halfwidth"][:, None] * g.down)
    if np.any(dpsi):
        vec = _rotate_about(vec, ub, dpsi[..., None])  # (n, P, 2, 3)
    tilt = errors["tilt_motion"]
    if np.any(tilt):
        w = tilt[..., :1] * f.p1 + tilt[..., 1:] * f.p2
        vec = _rotate_by_vector(vec, w[..., None, :])
    vec = np.broadcast_to(vec, (n, P, 2, 3))
    normal = vec[..., 0, :]
    q = (a[:, None, :] if a.ndim == 2 else a) + vec[..., 1, :]
    rad, axial = errors["radial_motion"], errors["axial_motion"]
    if np.any(rad):
        q = q + rad[..., :1] * f.p1 + rad[..., 1:] * f.p2
    if np.any(axial):
        q = q + axial[..., None] * f.ax

    # the plane z = h + c1 (x - cx) + c2 (y - cy) about each lattice centre
    coef = np.empty((n, P, 3))
    c1, c2 = coef[..., 1], coef[..., 2]
    np.divide(normal[..., 0], normal[..., 2], out=c1)
    np.divide(normal[..., 1], normal[..., 2], out=c2)
    np.negative(coef[..., 1:], out=coef[..., 1:])
    coef[..., 0] = q[..., 2] + c1 * (g.centres[:, 0] - q[..., 0]) + c2 * (g.centres[:, 1] - q[..., 1])
    # thermal drift moves the sensor by rate * t: height change (c1 rx + c2 ry - rz) t
    rate = errors["thermal_drift"]  # (n, 3)
    drift = c1 * rate[:, :1] + c2 * rate[:, 1:2] - rate[:, 2:] if np.any(rate) else None

    # per reading (n, P, M): one matrix product for the planes, then each active source
    # added in place (a source switched off is all zeros and skipped)
    z = np.matmul(coef.reshape(n * P, 3), g.read_local).reshape(n, P, M)
    z += noise
    tmp = np.empty_like(z)
    if drift is not None:
        z += np.multiply(drift[..., None], times, out=tmp)
    xy_err = errors["xy_positioning"]  # (n, 2, P, M): the ray is where the slides really are
    if np.any(xy_err):
        z += np.multiply(c1[..., None], xy_err[:, 0], out=tmp)
        z += np.multiply(c2[..., None], xy_err[:, 1], out=tmp)
    spot = errors["spot_offset_u"]  # (n, 2): the spot reads the height d away (-d at 180)
    if np.any(spot):
        z += (c1 * spot[:, :1] + c2 * spot[:, 1:])[..., None] * g.sensor_sign
    zero = errors["sensor_zero_u"]  # (n,)
    if np.any(zero):
        z += zero[:, None, None]
    motion = np.concatenate([errors["xy_slope_halfwidth"], errors["xy_straightness_halfwidth"]],
                            axis=-1)  # (n, 4): the slides' Z error, the same at every position
    if np.any(motion):
        z -= np.tensordot(motion, g.machine, axes=1)
    form = errors["flatness"]  # (n, K)
    if np.any(form):
        z += np.matmul(form, g.form).reshape(n, P, M)
    influence = errors["angle_influence_halfwidth"]  # (n, 3): a height error per position
    if np.any(influence):  # even, odd (its sign turns with the sensor), anisotropic
        phi = g.tilt_direction
        even = influence[:, ::2] @ (np.stack([np.ones_like(phi), np.cos(2 * phi)]) * g.tilt_bound)
        odd = influence[:, 1:2] * (np.cos(phi) * g.tilt_bound)
        z += even[..., None] + odd[..., None] * g.sensor_sign
    ez = errors["z_positioning"]  # gap = surface - actual Z position
    if np.any(ez):
        z -= ez if ez.ndim == 3 else ez[..., None]
    kappa = errors["sensor_scale"]  # reading = Z_cmd + (gap - Z_cmd) (1 + kappa) + noise
    lin = errors["sensor_linearity_halfwidth"]  # (n, 2): + range (c2 1.5 x^2 + c3 P3(x))
    if np.any(kappa) or np.any(lin):
        s = z - noise - g.z_cmd  # the sensor value from mid-range
        if np.any(lin):
            half = setup.sensor_range_mm / 2
            x = s / half
            z += 2 * half * (lin[:, :1, None] * 1.5 * x * x
                             + lin[:, 1:, None] * 0.5 * x * (5 * x * x - 3))
        if np.any(kappa):
            z += s * kappa[:, None, None]
    return z


# the estimators (a submodule of their own: the physics above is what they fit)
from mtplan.models.rotary_axis._estimators import (  # noqa: E402
    _check_readings,
    estimate_angles,
    estimate_gls,
    estimate_joint,
    estimate_patent,
)


ESTIMATORS = {"patent": estimate_patent, "joint": estimate_joint, "gls": estimate_gls,
              "angles": estimate_angles}
#: each estimator as the documents describe it (plain words, jargon spelled out)
_DESCRIPTIONS = {
    "patent": "The source method: a plane fitted to each lattice, the planes' least-squares "
              "intersection point on the axis, and the axis direction from the plane normals.",
    "joint": "Least squares of the axis model to all readings at once (maximum likelihood).",
    "gls": "The joint fit weighted by the set-up's whole error budget (generalised least "
           "squares, GLS).",
    "angles": "The weighted joint fit with the planes' directions tied to the commanded "
              "angles.",
}


def axis_line(setup: Setup, readings: dict, *, estimator: str = "patent", axis: str | None = None):
    """The fitted axis as a line: point at the reference (n, 3) [mm], unit direction (n, 3).

    The point is where the axis crosses Z = ``reference_height_mm`` (C) or
    X = ``reference_height_mm`` (A); the direction points along +Z (C) or +X (A).
    `axis` ('C' or 'A') picks one of a CA test's two lines (default: the axis tested).
    """
    p = Problems(f"{NAME}.axis_line")
    p.choice("estimator", estimator, ESTIMATORS)
    axis = setup.axis if axis is None else axis
    p.choice("axis", axis, setup.axes)
    p.raise_if_any()
    m = ESTIMATORS[estimator](setup, readings)
    return _measurand_line(axis, setup.reference_height_mm, m)


# --------------------------------------------------------------------------- time, data
def schedule(setup: Setup) -> pd.DataFrame:
    """The test's time line: one row per reading (axis, position, point, x_mm, y_mm, time_s).

    Each position starts with ``index_time_s``; each point costs the X/Y move from the
    previous one at ``feed_mm_min`` plus ``dwell_s``; the reading is taken at its end.
    """
    g = _plan(setup)
    P, M = setup.n_positions, setup.n_readings
    return pd.DataFrame({
        "axis": np.repeat(_position_axes(setup), M),
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
    sign = np.tile(_plan(setup).sensor_sign, setup.n_positions)
    return {"sensor_deg": np.where(sign > 0, 0.0, 180.0)}


def duration(setup: Setup) -> float:
    """Machine time of the test [s]: indexing, X/Y moves and dwell at every point."""
    return _plan(setup).total_time


def _position_axes(setup: Setup) -> np.ndarray:
    """The axis ('C' or 'A') turned at each position, array (positions,) of str."""
    return np.concatenate([np.full(len(setup.axis_angles(a)), a) for a in setup.axes])


# the readings as a table (a submodule of their own: the CSV format and what it determines)
from mtplan.models.rotary_axis._readings import (  # noqa: E402
    from_frame,
    reading_limits,
    readings_frame,
    setup_from_frame,
)


PROCEDURE = Procedure(
    name=NAME,
    title="Rotary-axis location from an inclined plane (C and A axes)",
    Setup=Setup,
    Truth=Truth,
    measurands=measurands,
    sources=sources,
    forward=forward,
    estimators={name: Estimator(fn, description=_DESCRIPTIONS[name], exact=True)
                for name, fn in ESTIMATORS.items()},
    true_values=true_values,
    duration=duration,
    description=(
        "A point laser on the Z slide reads a lattice on an inclined plane at n >= 3 positions "
        "of the rotary axis; the planes' least-squares intersection is a point on the axis and "
        "N v = 1 gives its direction (rotary-axis patent application of 2020). Measurands: ISO 230-7 location errors of the "
        "C axis (EX0C, EY0C, EA0C, EB0C) or the A axis (EY0A, EZ0A, EB0A, EC0A); with axis "
        "CA both, the offset and squareness of C to A and the error of a machining pose."
    ),
    levers=tuple("incline_deg incline_azimuth_deg positions range_deg angles_deg a_order "
                 "c_angles_deg lattice_nx lattice_ny lattice_size_mm lattice_offset_x_mm "
                 "lattice_offset_y_mm artifact_height_mm z_follows_surface sensor_reversal "
                 "dwell_s feed_mm_min".split()),
    readings=ReadingsFormat(readings_frame, from_frame, setup_from_frame=setup_from_frame,
                            limits=reading_limits, noise_source="probe_noise"),
    capabilities=Capabilities(block_size=2000, truth_from_estimate=truth_from_estimate),
)
