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
an unknown function within the data sheet's bound ``range B(tau)`` at the tilt's
magnitude tau, phi its direction from the triangulation plane: hats on tilt knots times
the four corner shapes ``(1 +- cos phi)(1 +- cos 2 phi) / 4``, each element arcsine
within the bound, so that every draw stays within it and the even part, the odd part
(which moves a C axis sideways by about ``e / tan(incline)`` along the triangulation
plane) and the anisotropy each reach the whole bound; the weights and the budget take
only the covariance of these draws (module ``_layout``, ``influence_basis``); a set-up
tilting the surface beyond
``sensor_max_tilt_deg`` is refused; with ``sensor_characteristic``, a calibrated
characteristic from a tilt table, it is that characteristic instead, which every estimator
removes at each reading's nominal tilt in the sensor's frame (bilinear between the
calibrated tilts), plus the calibration's error, ``angle_calibration_u``: one normal
error per calibrated point, independent between points, carried to the readings by the
same interpolation; module ``_characteristic``), the artifact's real pose (``artifact_tilt``: normal, no hard bound, since the readings
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

``gls``: the same fit with all plane coefficients weighted by the inverse of their
covariance under every active error source of the set-up (computed once per set-up by the
law of propagation through forward model and plane fit; the whole covariance, between
positions too, but for the sources the fit's parameters take up: see ``_gls_weights``).
The figures below are those of the block-diagonal weight of earlier versions.

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

from pathlib import Path

from mtplan.models.rotary_axis._axes import AXIS_ROWS, POSITION_AXIS, axis_part
from mtplan.models.rotary_axis._axis_line import DESCRIPTIONS, ESTIMATORS, axis_line
from mtplan.models.rotary_axis._estimators import (
    estimate_angles,
    estimate_gls,
    estimate_joint,
    estimate_patent,
)
from mtplan.models.rotary_axis._layout import FRAMES, duration, plan, schedule, tilts
from mtplan.models.rotary_axis._physics import (
    forward,
    measurands,
    sources,
    true_line,
    true_values,
    truth_from_estimate,
)
from mtplan.models.rotary_axis._readings import (
    from_frame,
    reading_limits,
    readings_frame,
    setup_from_frame,
)
from mtplan.models.rotary_axis._setup import NAME, Setup, Truth
from mtplan.models.protocol import (
    Calibration,
    Capabilities,
    Estimator,
    Procedure,
    ReadingsFormat,
    SourceMethod,
)

from mtplan.models.rotary_axis._correction import CORRECTION

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

#: the sensor's angle characteristic calibrated on a tilt table, as the packaged example
#: (a 5 deg grid of tilts from -50 to 50 deg, u = 0.5 um per point)
_EXAMPLE_CHARACTERISTIC = Path(__file__).resolve().parent.parent.parent / "examples" / \
    "angle_characteristic.csv"
_CALIBRATED_POINT_S = 10.0  # a tilt table's move, settling and reading per calibrated point

CHARACTERISTIC = Calibration(
    "sensor angle characteristic",
    {"sensor_characteristic": str(_EXAMPLE_CHARACTERISTIC)},
    cost_s=441 * _CALIBRATED_POINT_S,
    removes=("angle_influence_halfwidth",),
    description="the sensor calibrated on a tilt table as the packaged example "
                "angle_characteristic.csv: 21 x 21 tilts (a 5 deg grid from -50 to 50 deg), "
                "u = 0.5 um per point; its cost is the table's time, 10 s a point (move, "
                "settle, read): 4410 s",
)


class _Capabilities(Capabilities):
    """rotary_axis beyond its model: the truth of an estimate (the axis lines' errors)."""

    truth_from_estimate = staticmethod(truth_from_estimate)


PROCEDURE = Procedure(
    name=NAME,
    title="Rotary-axis location from an inclined plane (C and A axes)",
    Setup=Setup,
    Truth=Truth,
    measurands=measurands,
    sources=sources,
    forward=forward,
    estimators={name: Estimator(fn, description=DESCRIPTIONS[name], exact=True)
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
    readings=ReadingsFormat(readings_frame, from_frame, setup_from_frame=setup_from_frame,
                            limits=reading_limits, noise_source="probe_noise"),
    capabilities=_Capabilities(
        block_size=2000, calibrations=(CHARACTERISTIC,),
        levers=tuple("incline_deg incline_azimuth_deg positions range_deg angles_deg a_order "
                     "c_angles_deg lattice_nx lattice_ny lattice_size_mm lattice_offset_x_mm "
                     "lattice_offset_y_mm artifact_height_mm z_follows_surface sensor_reversal "
                     "dwell_s feed_mm_min".split()),
        source_method=SourceMethod(
            "patent", "Method for measuring direction and spatial position of rotation center of "
            "rotating shaft", who="Chinese patent application, Yang Xiaojun et al., filed "
            "2020-06-12"),
        correction=CORRECTION),
)
