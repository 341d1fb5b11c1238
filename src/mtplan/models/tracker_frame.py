"""Zero point and frames of the sub-machines of a gantry machine by laser tracker (patent CN106078359A).

Machine and method (patent CN106078359A)
------------------------------------------------------------
A gantry drilling machine carries ``n_submachines`` five-axis sub-machines, each with
an AC swivel head. A laser tracker measures in a global frame set up from reference
marks at the four corners of the bed. With every axis homed, the tracker measures,
for each sub-machine, points along its X, Y and Z travels (a fitted line gives each
direction of motion) and points round its C and A axes (a fitted circle gives each
axis line: the circle's normal through its centre). The common perpendicular of the
A and C lines meets C in the wrist centre T; the sub-machine's origin is T moved by
the pivot length L along C toward the tool tip. The direction of the linear axis
with the longest travel is kept as it is; the other two are corrected by cross
products to an orthonormal triad; with the origin this is the homogeneous transform
from the sub-machine frame to the global frame.

Frames, units and conventions
-----------------------------
Global frame: origin at the bed centre, X along the bed (the gantry's travel), Y
across, Z up; the bed marks sit at ``(+-bed_length/2, +-bed_width/2, 0)``. The gantry
stands at X = 0; sub-machine k's nominal origin (the tool tip with every axis homed)
is at ``(0, y_k, origin_height)`` with the sub-machines ``submachine_spacing_mm``
apart along Y, centred on Y = 0; its nominal axes are the global ones. The tracker
stands at ``(-tracker_distance, 0, tracker_height)``, turned by a yaw and slightly
out of level (Truth); it reads spherical coordinates in its own frame: distance d,
azimuth ``atan2(y, x)`` and elevation ``atan2(z, hypot(x, y))``.

The head: C is oriented by the right-hand rule of its positive rotation (nominally
+Z, up); the tool points along -C from the wrist centre. A is nominally along +X.
The reflector rides on a fixture at the tool tip's height, ``reflector_offset_mm``
from the C axis along the common-perpendicular direction ``n = C x A / |C x A|``
(nominally +Y). Linear travels run from ``-travel/2`` to ``+travel/2`` about home
with ``points_per_axis`` points; arcs are centred on home (a 360 deg arc has no
repeated end point).

Measurands, for each sub-machine k = 1..N:

- ``origin_x_k``, ``origin_y_k``, ``origin_z_k`` [um]: the frame origin minus its
  nominal position, in the global frame.
- ``rot_x_k``, ``rot_y_k``, ``rot_z_k`` [urad]: the orientation of the frame against
  the nominal (global) axes as fixed-axis X-Y-Z angles, ``R = Rz(rot_z) Ry(rot_y)
  Rx(rot_x)``, extracted exactly (no small-angle shortcut).
- ``ac_offset_k`` [um]: the signed length of the common perpendicular of A and C,
  ``(P_A - T) . n`` with ``n = C x A / |C x A|``: positive when A passes on the +Y
  side of C (signed, so that it is unbiased near zero, unlike a distance).
- ``sq_xy_k``, ``sq_yz_k``, ``sq_zx_k`` [urad]: squareness of the measured (not yet
  corrected) linear-axis directions: ``asin(u_i . u_j)`` = 90 deg minus the angle
  between the positive directions of travel i and j (positive when they close in).

Estimators
----------
- ``patent``: the patent's method as above; the A and C circles are full 3D
  orthogonal-distance circles through the points, which do not use the angles at
  which the points were taken.
- ``angles``: the same construction, but each circle is fitted with the commanded
  rotary angles theta_i of its points (the machine's encoders; the ``angle_deg``
  column of the readings table): the least-squares fit of ``p_i = c + R (cos(theta_i
  + phi0) e1 + sin(theta_i + phi0) e2)`` over c, R and the orientation (normal ``n =
  e1 x e2``, phase phi0), solved exactly in closed form as a similarity transform of
  known planar points (``mtplan.fitting.fit3d.fit_circle_3d_angles``; no iteration, no start
  value). A circle through points on a short arc gets its radius, and so the
  position of the axis across the arc, only from the sagitta, second order in the
  arc; with known angle steps the spacing of the points gives it to first order
  (``R = chord / (2 sin(dtheta/2))``). For the A arc that direction is mostly Z (the
  reflector hangs below the A axis), so the height of the A line, of T and of the
  origin. The price: ``angles`` trusts the encoders, so the rotary axes' positioning
  error enters it (and only it). Everything after the axis lines is shared.
- ``home``: ``angles`` with one more point in each circle fit, the reflector at home
  (angle 0 of both arcs, the middle of every linear travel), estimated by the mean of
  the ``3 points_per_axis`` linear points (symmetric about home) and weighted by their
  number. The same reflector at the same home is on every group of points of a
  sub-machine; the separate fits leave that out, the forward model (and so the
  posterior) does not. On the example readings it narrows u(ac_offset_1) from 23.7 to
  18.4 um and u(origin_y_1) from 8.2 to 7.7 um (4000 trials).
- ``gls``: the generalised least-squares (maximum-likelihood) fit of the whole forward
  model to all readings. Parameters: the 14 head fields of each sub-machine
  (:data:`_GLS_HEAD`) and the tracker's position, yaw and tilts; the pivot-length
  error and the A-C angle are held (the readings do not determine them, the posterior
  holds them too). Weights: the inverse covariance of the readings under every active
  source, each source element's secant effect at +-1 sd (:func:`_gls_gain`).
  Gauss-Newton from the ``home`` estimate (first trial; tracker pose from the
  registration) with one gain for the whole batch, re-taken once at the batch median;
  the measurands are the construction applied to the fitted geometry. It uses what
  the posterior uses, so it is as efficient (u(posterior) / u(mc) 0.98-1.02 on the
  example readings, against 0.88-0.92 for ``home``'s origins) and the default by
  the smallest-geometric-mean rule. About 5 times slower than ``home`` (about 5 000
  trials/s).

Decisions where the patent is silent or leaves a choice
-------------------------------------------------------------------
- **The frame is defined by the construction.** The patent is a zero-point
  *definition* and calibration method: the true frame is the patent's construction
  applied to the true geometry (true axis directions, true A and C lines, the true
  pivot length). So the true rotation depends on which axis has the longest travel
  (a set-up choice), and the squareness of the linear axes ends up in the two
  corrected axes. Ties in travel are broken in the order X, Y, Z. The "other two
  axes corrected by cross products" is made definite thus: with i the kept
  (longest) axis and j the next longest, the third axis is the normalised cross
  product of i and j (in right-handed order) and j is then the cross product of
  the third and i.
- **Fits.** Lines: orthogonal-distance (total least squares). Circles: the full 3-D
  orthogonal-distance circle (README of the shared TraCIM data, section 3), not a
  plane fit followed by a circle in that plane; on short arcs the two differ. All
  fits are batch-first (:mod:`mtplan.fitting.fit3d`) and validated against the TraCIM gauss package
  to 1e-13 mm (``benchmarks/validate_fit3d_tracim.py``). Line directions are
  oriented by the order of travel (first to last point), circle normals by the
  right-hand rule of the positive rotation.
- **Global frame.** The patent sets it up from corner marks *and* faces; only the four
  corner marks are modelled, and the tracker-to-global transform is the
  least-squares rigid best fit (Kabsch/Umeyama without scale) of the measured marks
  to their stated coordinates. The registration's uncertainty therefore comes from
  the tracker's own errors on the marks and enters every sub-machine alike.
- **The error sources** (the tracker's MPE and how it becomes a distribution, the angle
  errors per test and per point, the reflector, air, drift, travels, the rotary
  positioning, the reflector's fixture, the tracker's position, the pivot length): the
  decisions and the sources of their defaults are in docs/tracker_frame.md, "Modelling
  decisions behind the sources".
- **Temperatures.** The structure stands expanded about the marks' centroid by its
  temperature minus 20 degC; the air's vertical gradient bends every beam (warm air above:
  a signed mean). Measured (``structure_temperature_c``, ``air_gradient_k_per_m``), every
  estimator corrects both (:func:`_corrected_readings`, the registered points shrunk back
  about the centroid; ``gls`` through its forward model), and the thermometers' and the
  expansion coefficient's errors are sources. Not measured, they are a zero-mean half-width
  and a range from 0 (signed mean), uncorrected; the set-up's notes say so.

Degenerate set-ups are refused by the Setup and Truth checks: a zero travel (no
direction), a zero arc (all arc points at one angle: no circle, no axis), fewer
than 3 points on an arc, and A and C (nearly) parallel (no unique common
perpendicular, no wrist centre). An estimate from measured data whose fitted A and
C lines are parallel is refused with the same reason, and so is one where a 3D circle
fit does not converge: an arc so short that its points lie on a straight line
within their noise (at the default noise, arcs of about 1 deg; 5 deg still converges,
with a standard uncertainty of origin_z above 10 mm) determines no axis. This refusal is ``patent``'s; ``angles`` has a closed-form fit that
always returns, with an uncertainty that grows as the arc shrinks.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import types
from dataclasses import dataclass

import numpy as np
import pandas as pd

from mtplan._validate import InvalidInput, Problems
from mtplan.fitting import (
    Gaussian,
    SourceModel,
    central_jacobian,
    gauss_newton,
    gls_gain,
)
from mtplan.fitting.fit3d import (
    common_perpendicular,
    fit_circle_3d,
    fit_circle_3d_angles,
    fit_line_3d,
)
from mtplan._parallel import one_blas_thread
from mtplan.fitting.effects import secant_effects
from mtplan.models import _temperature as temperature
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

__all__ = ["PROCEDURE", "Setup", "Truth"]

NAME = "tracker_frame"
AXES = ("X", "Y", "Z")
#: minimum angle between A and C accepted by the Truth check [deg]
MIN_AC_ANGLE_DEG = 5.0
#: sine of the angle below which fitted A and C lines are called parallel
PARALLEL_SIN = 1e-6


# --------------------------------------------------------------------------- set-up
@dataclass(frozen=True)
class Setup(SetupBase):
    """Set-up of the tracker measurement of the sub-machine frames (mm, deg, s)."""

    _owner = NAME
    n_submachines: int = param(2, doc="Sub-machines on the gantry", low=1, high=32)
    submachine_spacing_mm: float = param(
        2000.0, doc="Distance between neighbouring sub-machines along Y", low=0, low_open=True)
    origin_height_mm: float = param(
        800.0, doc="Height of the nominal origin (tool tip at home) above the bed", low=0)
    pivot_length_mm: float = param(
        300.0, doc="Stated pivot length L: wrist centre to tool tip along C", low=0, high=5000)
    reflector_offset_mm: float = param(
        150.0, doc="Distance of the reflector from the C axis (at tool-tip height)",
        low=0, low_open=True, high=2000)
    travel_x_mm: float = param(1000.0, doc="Travel of X used for the line", low=0, high=20000)
    travel_y_mm: float = param(600.0, doc="Travel of Y used for the line", low=0, high=20000)
    travel_z_mm: float = param(400.0, doc="Travel of Z used for the line", low=0, high=20000)
    points_per_axis: int = param(11, doc="Points along each linear travel", low=2, high=1000)
    c_arc_deg: float = param(180.0, doc="Arc of C covered by the points", low=0, high=360)
    a_arc_deg: float = param(60.0, doc="Arc of A covered by the points (often short)",
                             low=0, high=360)
    points_per_arc: int = param(7, doc="Points on each of the A and C arcs", low=3, high=1000)
    tracker_distance_mm: float = param(
        4000.0, doc="Horizontal distance from the tracker to the gantry (along X)",
        low=0, low_open=True, high=60000)
    tracker_height_mm: float = param(1500.0, doc="Height of the tracker head above the bed",
                                     low=-5000, high=20000)
    bed_length_mm: float = param(8000.0, doc="Distance of the bed's corner marks along X",
                                 low=0, low_open=True, high=100000)
    bed_width_mm: float = param(4000.0, doc="Distance of the bed's corner marks along Y",
                                low=0, low_open=True, high=100000)
    distance_fixed_um: float = param(
        10.0, doc="Tracker distance (ADM) MPE, constant part a", low=0, high=10000)
    distance_per_length_um_per_m: float = param(
        0.3, doc="Tracker distance (ADM) MPE, length-proportional part b", low=0, high=1000)
    transverse_fixed_um: float = param(
        15.0, doc="Tracker transverse MPE, constant part c", low=0, high=10000)
    transverse_per_length_um_per_m: float = param(
        3.0, doc="Tracker transverse MPE, length-proportional part d: its per-point (random) "
        "share, the angular repeatability (see angular_systematic_um_per_m)", low=0, high=1000)
    angular_systematic_um_per_m: float = param(
        5.0, doc="Tracker transverse MPE, length-proportional part d: its per-test systematic "
        "share (angle encoders' harmonics, collimation, trunnion tilt, vertical index: "
        "constant over the test). With the per-point 3 um/m it makes 5.8 um/m in "
        "quadrature, the Leica AT960's d = 6 um/m", low=0, high=1000)
    smr_centring_um: float = param(
        2.5, doc="Centring tolerance of the SMR (optical centre to sphere centre), as an MPE "
        "per direction: +-2.5 um for a precision-grade 1.5 in SMR (standard grades +-12.7 "
        "um); beyond the MPE's own reflector", low=0, high=1000)
    air_refraction_ppm: float = param(
        1.0, doc="Standard deviation of the distance scale error from the air's refractive "
        "index over the beam, one per test: weather station +-0.3 K and +-1 hPa (0.3 ppm "
        "each) and about 1 K between the station and the beam path in a hall (0.9 ppm)",
        low=0, high=1000)
    thermal_drift_um_per_s: float = param(
        0.003, doc="Standard deviation of each component (X, Y, Z) of the drift rate of the "
        "tracker against the machine over the test (tripod, floor, bed): 0.003 um/s = 11 "
        "um/h; a 1.5 m steel tripod grows 17 um per K", low=0, high=100)
    straightness_um: float = param(
        10.0, doc="Straightness tolerance of each linear travel measured, each direction "
        "across it (ISO 230-1, deviation from the least-squares reference line): 10 um, "
        "the order of the acceptance tolerances of large machining centres over 1 m",
        low=0, high=10000)
    mpe_model: str = param(
        "normal_k2", doc="How an MPE becomes a distribution: normal with std MPE/2 (k = 2) "
        "or rectangular with half-width MPE", choices=("normal_k2", "rectangular"))
    machine_repeatability_um: float = param(
        2.0, doc="Standard deviation of the machine's positioning at each point (each axis)",
        low=0, high=10000)
    reflector_fixture_um: float = param(
        50.0, doc="Half-width (rectangular) of the reflector's position on its fixture about "
        "the stated one (reflector_offset_mm from C at the tool tip), each direction: across "
        "C away from it, along C, and round it; one per mounting. Default 50 um for an "
        "uncalibrated fixture: the arm machined to +-50 um over 150 mm, the nest's height "
        "against the tool tip to +-50 um, the spindle's orientation stop (+-0.02 deg, 52 um "
        "at 150 mm). 0 takes the fixture as calibrated", low=0, high=10000)
    rotary_positioning_arcsec: float = param(
        5.0, doc="Standard deviation of the A and C axes' angular positioning at each arc "
        "point (actual minus commanded angle)", low=0, high=36000)
    structure_temperature_c: float | None = param(
        None, doc="Measured temperature of the bed and gantry [degC] (the mean of sensors on "
        "the structure): the frames are corrected to 20 degC, the marks' reference "
        "temperature (ISO 1); empty: not measured, the structure is assumed at 20 degC within "
        "+-structure_temperature_halfwidth_k and nothing is corrected", low=10, high=40,
        condition="machine_temperature_c")
    structure_temperature_u_k: float = param(
        0.3, doc="Standard uncertainty of the measured structure temperature as the mean "
        "temperature of the bed and gantry [K] (calibrated contact sensors 0.1 K; a weldment "
        "several metres long is not isothermal); used when structure_temperature_c is given",
        low=0, high=10)
    structure_temperature_halfwidth_k: float = param(
        2.0, doc="Half-width (rectangular) of the structure's temperature minus 20 degC when "
        "it is not measured [K]: a machine hall held at 20 +- 2 degC", low=0, high=50)
    structure_expansion_ppm_per_k: float = param(
        11.5, doc="Linear thermal expansion coefficient of the bed and gantry [1e-6/K] (steel "
        "weldments 11.5; cast iron 10-11)", low=0, high=100)
    structure_expansion_u_ppm_per_k: float = param(
        1.0, doc="Standard uncertainty of the structure's expansion coefficient [1e-6/K] "
        "(steels and cast irons span 10-12.5e-6/K; ISO/TR 16015)", low=0, high=100)
    air_gradient_k_per_m: float | None = param(
        None, doc="Measured vertical gradient of the air's temperature along the beams [K/m], "
        "positive with warm air above (two thermometers at different heights): every "
        "estimator corrects the elevations for the beams' bending; empty: not measured, "
        "the gradient is taken uniform between 0 and air_gradient_range_k_per_m", low=-10,
        high=10, condition="air_gradient_k_per_m")
    air_gradient_u_k_per_m: float = param(
        0.2, doc="Standard uncertainty of the measured gradient as the mean along the beams "
        "[K/m] (two thermometers of 0.1 K a metre apart, 0.14 K/m, and the gradient's "
        "change along the hall); used when air_gradient_k_per_m is given", low=0, high=20)
    air_gradient_range_k_per_m: float = param(
        1.0, doc="Upper end of the vertical gradient of the air's temperature when it is not "
        "measured [K/m]: uniform between 0 and it, warm air above (halls without displacement "
        "ventilation stratify by 0.5-1 K/m, Estler et al., CIRP Annals 51/2, 2002)", low=0,
        high=20)
    dwell_s: float = param(3.0, doc="Settling and tracker averaging per point", low=0)
    linear_feed_mm_min: float = param(3000.0, doc="Feed of the linear moves", low=0, low_open=True)
    rotary_move_s: float = param(3.0, doc="Time to index a rotary axis to the next arc point",
                                 low=0)
    changeover_s: float = param(300.0, doc="Mounting the reflector fixture on a sub-machine",
                                low=0)
    mark_s: float = param(60.0, doc="Measuring one bed mark (placing the reflector, reading)",
                          low=0)

    def _check(self, p: Problems) -> None:
        for ax in "xyz":
            field = f"travel_{ax}_mm"
            if getattr(self, field) <= 0:
                p.add(field, getattr(self, field),
                      f"> 0: a zero travel gives no direction of motion for the {ax.upper()} axis")
        for ax in "ca":
            field = f"{ax}_arc_deg"
            if getattr(self, field) <= 0:
                p.add(field, getattr(self, field),
                      f"> 0: with an arc of 0 all points of the {ax.upper()} arc lie at one "
                      "angle, so no circle and no axis line can be fitted")


    def notes(self) -> list[str]:
        """Which temperatures were assumed rather than measured."""
        out = temperature.assumed_note(self, "structure_temperature",
                                       "the structure's temperature")
        if self.air_gradient_k_per_m is None:
            out.append(f"temperature: the air's vertical gradient was assumed (0 to "
                       f"{self.air_gradient_range_k_per_m:g} K/m, warm air above), not measured: "
                       "its mean biases the simulated estimates; estimate's bias correction "
                       "removes it (state air_gradient_k_per_m)")
        return out


@dataclass(frozen=True)
class Truth(SetupBase):
    """True geometry. Tuples are per sub-machine, cycled when shorter than the count."""

    _owner = f"{NAME} truth"
    wrist_dx_um: tuple[float, ...] = param((40.0, -25.0), doc="Wrist centre T off nominal, X",
                                           min_len=1)
    wrist_dy_um: tuple[float, ...] = param((-30.0, 20.0), doc="Wrist centre T off nominal, Y",
                                           min_len=1)
    wrist_dz_um: tuple[float, ...] = param((15.0, -10.0), doc="Wrist centre T off nominal, Z",
                                           min_len=1)
    frame_rx_urad: tuple[float, ...] = param((20.0, -15.0), doc="Rotation of the sub-machine "
                                             "(axes and head) about X", min_len=1)
    frame_ry_urad: tuple[float, ...] = param((-12.0, 25.0), doc="... about Y", min_len=1)
    frame_rz_urad: tuple[float, ...] = param((35.0, -20.0), doc="... about Z", min_len=1)
    sq_xy_urad: tuple[float, ...] = param((10.0, -8.0), doc="Squareness X-Y (90 deg minus "
                                          "the angle between X and Y)", min_len=1)
    sq_yz_urad: tuple[float, ...] = param((-6.0, 12.0), doc="Squareness Y-Z", min_len=1)
    sq_zx_urad: tuple[float, ...] = param((8.0, 5.0), doc="Squareness Z-X", min_len=1)
    c_tilt_x_urad: tuple[float, ...] = param((15.0, -10.0), doc="Tilt of C against Z about X",
                                             min_len=1)
    c_tilt_y_urad: tuple[float, ...] = param((-20.0, 12.0), doc="Tilt of C against Z about Y",
                                             min_len=1)
    a_tilt_y_urad: tuple[float, ...] = param((25.0, -18.0), doc="Tilt of A about Y", min_len=1)
    a_tilt_z_urad: tuple[float, ...] = param((-14.0, 30.0), doc="Tilt of A about Z", min_len=1)
    ac_offset_um: tuple[float, ...] = param((30.0, -45.0), doc="Signed A-C offset (length of "
                                            "the common perpendicular)", min_len=1)
    pivot_length_error_um: tuple[float, ...] = param(
        (0.0,), doc="True pivot length minus the stated one", min_len=1)
    ac_angle_deg: float = param(90.0, doc="Angle between the A and C axes", low=0, high=180)
    tracker_yaw_deg: float = param(30.0, doc="Yaw of the tracker's frame", low=-360, high=360)
    tracker_tilt_x_urad: float = param(50.0, doc="Tracker out of level about X")
    tracker_tilt_y_urad: float = param(-30.0, doc="Tracker out of level about Y")
    tracker_dx_um: float = param(
        0.0, doc="Tracker's position off the set-up's (-tracker_distance, 0, tracker_height), "
        "X: a tripod is placed to centimetres, not micrometres; the registration on the "
        "marks finds where it stands, as it finds the yaw", low=-1e6, high=1e6)
    tracker_dy_um: float = param(0.0, doc="... Y", low=-1e6, high=1e6)
    tracker_dz_um: float = param(0.0, doc="... Z", low=-1e6, high=1e6)

    def _check(self, p: Problems) -> None:
        s = abs(math.sin(math.radians(self.ac_angle_deg)))
        if s < math.sin(math.radians(MIN_AC_ANGLE_DEG)):
            p.add("ac_angle_deg", self.ac_angle_deg,
                  f"between {MIN_AC_ANGLE_DEG:g} and {180 - MIN_AC_ANGLE_DEG:g}: with A and C "
                  "(nearly) parallel their common perpendicular, and so the wrist centre T, "
                  "is undefined")


# --------------------------------------------------------------------------- geometry
def _rot(axis: np.ndarray, angle) -> np.ndarray:
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


def _mv(r: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Matrices (..., 3, 3) times vectors (..., 3), broadcast."""
    return np.einsum("...ij,...j->...i", r, v)


def _rxyz(rx: float, ry: float, rz: float) -> np.ndarray:
    """``Rz(rz) Ry(ry) Rx(rx)`` (fixed-axis X, then Y, then Z) [rad]."""
    e = np.eye(3)
    return _rot(e[2], rz) @ _rot(e[1], ry) @ _rot(e[0], rx)


def _angles(r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of :func:`_rxyz` for matrices (..., 3, 3): (rx, ry, rz) [rad]."""
    rx = np.arctan2(r[..., 2, 1], r[..., 2, 2])
    ry = np.arctan2(-r[..., 2, 0], np.hypot(r[..., 2, 1], r[..., 2, 2]))
    rz = np.arctan2(r[..., 1, 0], r[..., 0, 0])
    return rx, ry, rz


def _cyc(values: tuple, k: int) -> np.ndarray:
    """Element k (cycled) of a per-sub-machine tuple: a float, or an array (m,) when the
    truth is one per batch row (a posterior's walkers)."""
    return np.asarray(values[k % len(values)], dtype=float)


def _cross(a, b):
    """Cross products of vectors (..., 3), broadcast: ``np.cross``'s sums without its
    axis handling (a few microseconds, where the geometry of one truth calls it often)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack(np.broadcast_arrays(a1 * b2 - a2 * b1, a2 * b0 - a0 * b2,
                                        a0 * b1 - a1 * b0), axis=-1)


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _frame_axes(setup: Setup) -> tuple[int, int, int]:
    """(kept, second, third) axis indices: longest travel kept, then the next longest."""
    travels = [setup.travel_x_mm, setup.travel_y_mm, setup.travel_z_mm]
    order = sorted(range(3), key=lambda i: (-travels[i], i))
    return order[0], order[1], order[2]


def _orthonormal(setup: Setup, ux, uy, uz) -> np.ndarray:
    """The patent's frame: longest-travel axis kept, the others corrected by cross products.

    Returns rotation matrices (..., 3, 3) whose columns are the frame's X, Y, Z axes.
    """
    u = [ux, uy, uz]
    i, j, k = _frame_axes(setup)
    cyclic = (j - i) % 3 == 1
    cols = [None, None, None]
    cols[i] = _unit(u[i])
    cols[k] = _unit(_cross(cols[i], u[j]) if cyclic else _cross(u[j], cols[i]))
    cols[j] = _cross(cols[k], cols[i]) if cyclic else _cross(cols[i], cols[k])
    return np.stack(cols, axis=-1)


def _nominal_origins(setup: Setup) -> np.ndarray:
    """Nominal origins (N, 3) [mm] of the sub-machine frames."""
    n = setup.n_submachines
    y = (np.arange(n) - (n - 1) / 2) * setup.submachine_spacing_mm
    return np.column_stack([np.zeros(n), y, np.full(n, setup.origin_height_mm)])


def _marks(setup: Setup) -> np.ndarray:
    """Stated global coordinates (4, 3) [mm] of the bed's corner marks."""
    a, b = setup.bed_length_mm / 2, setup.bed_width_mm / 2
    return np.array([[-a, -b, 0.0], [a, -b, 0.0], [a, b, 0.0], [-a, b, 0.0]])


def _linear_positions(setup: Setup) -> dict[str, np.ndarray]:
    travel = {"X": setup.travel_x_mm, "Y": setup.travel_y_mm, "Z": setup.travel_z_mm}
    return {ax: np.linspace(-t / 2, t / 2, setup.points_per_axis) for ax, t in travel.items()}


def _arc_angles(arc_deg: float, m: int) -> np.ndarray:
    """Arc angles [deg] centred on home; a full turn leaves out the repeated end point."""
    if arc_deg >= 360.0:
        return np.linspace(-180.0, 180.0, m, endpoint=False)
    return np.linspace(-arc_deg / 2, arc_deg / 2, m)


def _layout(setup: Setup) -> list[tuple[str, int, int, float, float]]:
    """Every reading in order: (group, submachine, index, position_mm, angle_deg)."""
    rows = [("mark", 0, i, 0.0, 0.0) for i in range(4)]
    lin = _linear_positions(setup)
    c_ang = _arc_angles(setup.c_arc_deg, setup.points_per_arc)
    a_ang = _arc_angles(setup.a_arc_deg, setup.points_per_arc)
    for k in range(1, setup.n_submachines + 1):
        for ax in AXES:
            rows += [(ax, k, i, float(s), 0.0) for i, s in enumerate(lin[ax])]
        rows += [("C", k, i, 0.0, float(a)) for i, a in enumerate(c_ang)]
        rows += [("A", k, i, 0.0, float(a)) for i, a in enumerate(a_ang)]
    return rows


def _slices(setup: Setup) -> dict:
    """Index ranges of each group of readings: {(group, k): slice} (marks: ('mark', 0))."""
    out = {("mark", 0): slice(0, 4)}
    pos = 4
    P, Q = setup.points_per_axis, setup.points_per_arc
    for k in range(1, setup.n_submachines + 1):
        for g, m in (("X", P), ("Y", P), ("Z", P), ("C", Q), ("A", Q)):
            out[(g, k)] = slice(pos, pos + m)
            pos += m
    return out


def _n_points(setup: Setup) -> int:
    return 4 + setup.n_submachines * (3 * setup.points_per_axis + 2 * setup.points_per_arc)


@dataclass(frozen=True)
class _Head:
    """True geometry of one sub-machine (global frame, mm)."""

    axes: np.ndarray  # (3, 3) rows: unit directions of the X, Y, Z travels
    c_dir: np.ndarray
    a_dir: np.ndarray
    wrist: np.ndarray  # T, the foot of the common perpendicular on C
    a_point: np.ndarray  # foot on A
    perp: np.ndarray  # unit C x A
    offset: float
    reflector: np.ndarray  # reflector at home
    origin: np.ndarray  # true origin (tool tip with the true pivot length)


def _travel_axes(sxy, syz, szx) -> np.ndarray:
    """Unit directions (..., 3, 3), rows X, Y, Z, of the linear travels of a sub-machine
    before its frame's rotation, for its squareness angles [rad]."""
    z0 = np.zeros(np.broadcast_shapes(np.shape(sxy), np.shape(syz), np.shape(szx)))
    ux = np.stack([z0 + 1.0, z0, z0], axis=-1)
    uy = np.stack([np.sin(sxy) + z0, np.cos(sxy) + z0, z0], axis=-1)
    alpha = np.sin(szx) + z0
    beta = (np.sin(syz) - alpha * np.sin(sxy)) / np.cos(sxy)
    uz = np.stack([alpha, beta, np.sqrt(1.0 - alpha**2 - beta**2)], axis=-1)
    return np.stack([ux, uy, uz], axis=-2)


#: the Truth fields of each sub-machine's head (tuples, one per sub-machine)
_HEAD_FIELDS = ("frame_rx_urad", "frame_ry_urad", "frame_rz_urad", "sq_xy_urad", "sq_yz_urad",
                "sq_zx_urad", "c_tilt_x_urad", "c_tilt_y_urad", "a_tilt_y_urad",
                "a_tilt_z_urad", "wrist_dx_um", "wrist_dy_um", "wrist_dz_um", "ac_offset_um",
                "pivot_length_error_um")


def _head(setup: Setup, truth: Truth, k: int) -> _Head:
    """True geometry of sub-machine k (0-based): vectors (3,), or (m, 3) for a truth whose
    fields are arrays (m,) (one truth per batch row). A truth of one value per field is
    looked up by those values (the same head comes back in many forward calls)."""
    values = tuple(_cyc(getattr(truth, f), k) for f in _HEAD_FIELDS)
    if any(v.ndim for v in values) or np.ndim(truth.ac_angle_deg):
        return _head_of(setup, truth, k)
    return _cached_head(setup, k, tuple(float(v) for v in values), float(truth.ac_angle_deg))


@functools.lru_cache(maxsize=256)
def _cached_head(setup: Setup, k: int, values: tuple, ac_angle_deg: float) -> _Head:
    fields = {f: (v,) for f, v in zip(_HEAD_FIELDS, values, strict=True)}
    head = _head_of(setup, types.SimpleNamespace(**fields, ac_angle_deg=ac_angle_deg), k)
    for f in dataclasses.fields(head):  # shared by every caller: read-only
        value = getattr(head, f.name)
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
    return head


def _head_of(setup: Setup, truth, k: int) -> _Head:
    u = 1e-6
    rf = _rxyz(_cyc(truth.frame_rx_urad, k) * u, _cyc(truth.frame_ry_urad, k) * u,
               _cyc(truth.frame_rz_urad, k) * u)
    sxy, syz, szx = (_cyc(truth.sq_xy_urad, k) * u, _cyc(truth.sq_yz_urad, k) * u,
                     _cyc(truth.sq_zx_urad, k) * u)
    axes = _travel_axes(sxy, syz, szx) @ np.swapaxes(rf, -1, -2)  # rows: rf @ u_i
    e = np.eye(3)
    c_loc = _mv(_rot(e[1], _cyc(truth.c_tilt_y_urad, k) * u)
                @ _rot(e[0], _cyc(truth.c_tilt_x_urad, k) * u), e[2])
    ac = np.radians(np.asarray(truth.ac_angle_deg, dtype=float))[..., None]
    a0 = np.sin(ac) * e[0] + np.cos(ac) * e[2]
    a_loc = _mv(_rot(e[2], _cyc(truth.a_tilt_z_urad, k) * u)
                @ _rot(e[1], _cyc(truth.a_tilt_y_urad, k) * u), a0)
    c_dir, a_dir = _mv(rf, c_loc), _mv(rf, a_loc)
    perp = _unit(_cross(c_dir, a_dir))
    nominal = _nominal_origins(setup)[k] + np.array([0.0, 0.0, setup.pivot_length_mm])
    wrist = nominal + 1e-3 * np.stack(np.broadcast_arrays(
        _cyc(truth.wrist_dx_um, k), _cyc(truth.wrist_dy_um, k), _cyc(truth.wrist_dz_um, k)), -1)
    offset = _cyc(truth.ac_offset_um, k) * 1e-3
    a_point = wrist + offset[..., None] * perp
    reflector = wrist - setup.pivot_length_mm * c_dir + setup.reflector_offset_mm * perp
    true_l = setup.pivot_length_mm + _cyc(truth.pivot_length_error_um, k) * 1e-3
    origin = wrist - true_l[..., None] * c_dir
    return _Head(axes, c_dir, a_dir, wrist, a_point, perp, offset, reflector, origin)


def _fixture_displacement(head: _Head, fixture: np.ndarray) -> np.ndarray:
    """Global displacement (n, 3) [mm] of the reflector for its fixture errors (n, 3) [mm]:
    across C away from it (``perp``), along C, and round C (``perp x C``)."""
    round_c = _cross(head.perp, head.c_dir)
    return (fixture[:, 0, None] * head.perp + fixture[:, 1, None] * head.c_dir
            + fixture[:, 2, None] * round_c)


def _machine_points(setup: Setup, truth: Truth, rotary_error=None,
                    fixture=None) -> np.ndarray:
    """True global positions [mm] of the reflector, layout order.

    Without `rotary_error`: shape (n_machine_points, 3) at the commanded angles. With
    `rotary_error` (batch, 2 N points_per_arc) [rad], the actual minus commanded angle
    of every arc point (C then A for each sub-machine): shape (batch, n_machine_points, 3).
    `fixture` (batch, N, 3) [mm]: the reflector's position on its fixture off the stated
    one, per sub-machine (see :func:`_fixture_displacement`); it needs `rotary_error`.
    """
    lin = _linear_positions(setup)
    q = setup.points_per_arc
    c_ang = np.radians(_arc_angles(setup.c_arc_deg, q))
    a_ang = np.radians(_arc_angles(setup.a_arc_deg, q))
    err = np.zeros((1, 2 * setup.n_submachines * q)) if rotary_error is None else rotary_error
    batch = err.shape[0]
    out = []
    for k in range(setup.n_submachines):
        h = _head(setup, truth, k)
        if fixture is not None and np.any(fixture[:, k]):
            h = dataclasses.replace(h, reflector=h.reflector
                                    + _fixture_displacement(h, fixture[:, k]))
        e_c = err[:, 2 * k * q:(2 * k + 1) * q]
        e_a = err[:, (2 * k + 1) * q:(2 * k + 2) * q]
        for i, ax in enumerate(AXES):
            out.append(np.broadcast_to(h.reflector[..., None, :]
                                       + lin[ax][:, None] * h.axes[..., i, None, :],
                                       (batch, len(lin[ax]), 3)))
        for point, axis, ang, e_k in ((h.wrist, h.c_dir, c_ang, e_c),
                                      (h.a_point, h.a_dir, a_ang, e_a)):
            arm = (h.reflector - point)[..., None, :]
            out.append(point[..., None, :] + _mv(_rot(axis[..., None, :], ang + e_k), arm))
    pts = np.concatenate(out, axis=1)
    return pts[0] if rotary_error is None else pts


def _legendre(xi: np.ndarray) -> np.ndarray:
    """P2, P3, P4 at `xi` in [-1, 1]: array (3, len(xi)); each within [-1, 1]."""
    x2 = xi * xi
    return np.stack([(3 * x2 - 1) / 2, xi * (5 * x2 - 3) / 2, (35 * x2 * x2 - 30 * x2 + 3) / 8])


def _straightness(setup: Setup, truth: Truth, coef: np.ndarray) -> np.ndarray:
    """Straightness deviations of the linear-travel points (n, n_machine_points, 3) [mm].

    `coef` (n, N, 3, 2, 3): per sub-machine, axis and direction across the travel,
    the coefficients of P2, P3, P4 of the scaled position. The directions across
    the travel u are the next two nominal axes made orthogonal to u.
    """
    n = coef.shape[0]
    out = np.zeros((n, _n_points(setup) - 4, 3))
    if not np.any(coef):
        return out
    lin = _linear_positions(setup)
    sl = _slices(setup)
    e = np.eye(3)
    for k in range(setup.n_submachines):
        axes = _head(setup, truth, k).axes
        for i, ax in enumerate(AXES):
            u = axes[..., i, :]
            v1 = _unit(e[(i + 1) % 3] - np.sum(e[(i + 1) % 3] * u, axis=-1)[..., None] * u)
            across = np.broadcast_to(np.stack([v1, _cross(u, v1)], axis=-2), (n, 2, 3))
            t = lin[ax]
            shape = _legendre(t / t[-1])  # (3, P); travels are > 0
            dev = np.einsum("ndt,tp,ndj->npj", coef[:, k, i], shape, across)
            s = sl[(ax, k + 1)]
            out[:, s.start - 4:s.stop - 4] = dev
    return out


def _tracker_pose(setup: Setup, truth: Truth) -> tuple[np.ndarray, np.ndarray]:
    """(R (..., 3, 3), t (..., 3)): global = R @ tracker + t (arrays (m, ...) for a truth
    whose fields are arrays (m,))."""
    r = _rxyz(np.asarray(truth.tracker_tilt_x_urad) * 1e-6,
              np.asarray(truth.tracker_tilt_y_urad) * 1e-6, np.radians(truth.tracker_yaw_deg))
    d = np.stack(np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (
        truth.tracker_dx_um, truth.tracker_dy_um, truth.tracker_dz_um))), -1)
    t = np.array([-setup.tracker_distance_mm, 0.0, setup.tracker_height_mm]) + 1e-3 * d
    return r, t


# --------------------------------------------------------------------------- protocol
def measurands(setup: Setup) -> tuple[Measurand, ...]:
    """Ten measurands per sub-machine k = 1..N (see the module docstring)."""
    out = []
    for k in range(1, setup.n_submachines + 1):
        for ax in "xyz":
            out.append(Measurand(f"origin_{ax}_{k}", "um",
                                 f"Origin of sub-machine {k} minus nominal, global {ax.upper()}"))
        for ax in "xyz":
            out.append(Measurand(f"rot_{ax}_{k}", "urad",
                                 f"Orientation of sub-machine {k}'s frame about global "
                                 f"{ax.upper()} (R = Rz Ry Rx)"))
        out.append(Measurand(f"ac_offset_{k}", "um",
                             f"Signed A-C offset of sub-machine {k} (common perpendicular)"))
        for a, b in ("xy", "yz", "zx"):
            out.append(Measurand(f"sq_{a}{b}_{k}", "urad",
                                 f"Squareness {a.upper()}-{b.upper()} of sub-machine {k}: "
                                 f"90 deg minus the angle between the travels"))
    return tuple(out)


def _mpe(setup: Setup, mpe: float) -> Normal | Rectangular:
    if setup.mpe_model == "rectangular":
        return Rectangular(-mpe, mpe)
    return Normal(0.0, mpe / 2.0)


def sources(setup: Setup) -> dict[str, Source]:
    """Error sources (internal units: mm, or mm per mm for the length-proportional parts)."""
    n = _n_points(setup)
    m = n - 4
    q = 2 * setup.n_submachines * setup.points_per_arc
    spec = ("Default from a current tracker's ISO 10360-10 subsystem MPE (ADM 10 um + 0.3 um/m, "
            "transverse 15 um + 6 um/m); MPE converted by mpe_model.")
    return {
        "distance_fixed": Source(
            _mpe(setup, setup.distance_fixed_um * 1e-3), (n,),
            "Tracker distance error, constant part a of the MPE a + b L, per point [mm]. " + spec),
        "distance_per_length": Source(
            _mpe(setup, setup.distance_per_length_um_per_m * 1e-6), (n,),
            "Tracker distance error, part b of the MPE proportional to the distance, per point "
            "[mm/mm]. " + spec),
        "transverse_fixed": Source(
            _mpe(setup, setup.transverse_fixed_um * 1e-3), (n, 2),
            "Tracker error across the beam (horizontal, vertical), constant part c of the MPE "
            "c + d L, per point [mm]. " + spec),
        "transverse_per_length": Source(
            _mpe(setup, setup.transverse_per_length_um_per_m * 1e-6), (n, 2),
            "Tracker error across the beam proportional to the distance (an angle error), "
            "its per-point share (angular repeatability: pointing, encoder interpolation, "
            "air turbulence), independent from point to point [rad]. Default 3 um/m, with "
            "angular_systematic's 5 um/m the AT960's d = 6 um/m in quadrature; "
            "converted by mpe_model."),
        "angular_systematic": Source(
            _mpe(setup, setup.angular_systematic_um_per_m * 1e-6), (len(_SYSTEMATIC_WEIGHTS),),
            "Tracker angle error constant over the test (ASME B89.4.19 / ISO 10360-10 "
            "geometric model after Muralikrishnan et al., J. Res. NIST 114 (2009)): first and "
            "second harmonics of the horizontal encoder, collimation (beam tilt), trunnion "
            "tilt, vertical index and vertical encoder eccentricity, one coefficient each "
            "per test [rad], weighted so that the transverse error has this standard "
            "deviation in each direction across the beam (at level sight). A constant "
            "azimuth offset is left out: the registration on the marks absorbs it. Nearby "
            "points (a short arc) are displaced together. Default 5 um/m of the AT960's "
            "d = 6 um/m; converted by mpe_model."),
        "smr_centring": Source(
            _mpe(setup, setup.smr_centring_um * 1e-3), (n, 3),
            "Offset of the SMR's optical centre from its sphere's centre, along the beam and "
            "across it (horizontal, vertical), per point [mm]: the SMR is turned in its nest "
            "toward the tracker at each point (and reseated on every mark), so its centring "
            "error shows in a new direction each time. Default +-2.5 um, a precision-grade "
            "1.5 in SMR; converted by mpe_model."),
        "air_refraction": Source(
            Normal(0.0, setup.air_refraction_ppm * 1e-6), (),
            "Scale error of every distance from the air's refractive index, one per test "
            "[1]: -0.93 ppm/K, +0.27 ppm/hPa (Edlen); default 1 ppm from the weather "
            "station's +-0.3 K, +-1 hPa and about 1 K between the station and the beam path."),
        "thermal_drift": Source(
            Normal(0.0, setup.thermal_drift_um_per_s * 1e-3), (3,),
            "Drift rate (global X, Y, Z) of the tracker against the machine during the test, "
            "one per test [mm/s]: every point moves by rate x its time from the start "
            "(_times: marks first, then each sub-machine). Default 0.003 um/s (11 um/h): a "
            "1.5 m steel tripod grows 17 um per K, a hall changes 0.5-1 K/h."),
        "straightness": Source(
            Rectangular(-setup.straightness_um * 1e-3 / 4, setup.straightness_um * 1e-3 / 4),
            (setup.n_submachines, 3, 2, 3),
            "Straightness deviation of each linear travel (sub-machine, axis X/Y/Z, two "
            "directions across it), one per test [mm]: coefficients of the Legendre "
            "polynomials P2, P3, P4 of the position scaled to -1..1 (orthogonal to the "
            "reference straight line, whose direction is the measurand), each uniform in "
            "+-straightness/4, so the deviation stays within about the tolerance. Only the "
            "sampling of the travel at points_per_axis points lets it tilt the fitted line "
            "(P3 at the ends). Default 10 um."),
        "machine_repeatability": Source(
            Normal(0.0, setup.machine_repeatability_um * 1e-3), (m, 3),
            "Scatter of the machine's positioning at each measured point, each global axis "
            "[mm]. Default 2 um: an ISO 230-2 unidirectional repeatability of about 8 um "
            "(4 s) for large gantry axes."),
        "reflector_fixture": Source(
            Rectangular(-setup.reflector_fixture_um * 1e-3, setup.reflector_fixture_um * 1e-3),
            (setup.n_submachines, 3),
            "Position of the reflector on its fixture off the stated one (reflector_offset_mm "
            "from the C axis, at the tool tip), one per sub-machine (the fixture is mounted "
            "on each), in the head's directions: across C away from it, along C, round C "
            "[mm]. The circle fits leave the radius free, so the estimators are blind to it; "
            "a model that took the offset as exact would know the radii of the C and A "
            "circles and so where their axes lie across a short arc. Default +-50 um "
            "(rectangular) for an uncalibrated fixture: arm machined to +-50 um, the nest's "
            "height to +-50 um, the spindle's orientation stop +-0.02 deg at 150 mm."),
        **_thermal_sources(setup),
        "rotary_positioning": Source(
            Normal(0.0, setup.rotary_positioning_arcsec * math.pi / 648000), (q,),
            "Angular positioning error of the A and C axes at each arc point (actual minus "
            "commanded angle), independent from point to point [rad]: the reflector stands "
            "at the actual angle, the readings report the commanded one. Default 5 arcsec "
            "(standard deviation): an ISO 230-2 bidirectional positioning accuracy of about "
            "20 arcsec (+-2 s) for the rotary axes of the swivel heads of such gantries."),
    }


def _thermal_sources(setup: Setup) -> dict[str, Source]:
    """The structure's temperature and the air's gradient, measured or assumed
    (:mod:`mtplan.models._temperature`), and the structure's expansion coefficient."""
    return {
        **temperature.temperature_sources(
            setup, "structure_temperature",
            measured="Error of the measured structure temperature as the mean temperature of "
            "the bed and gantry [K]; the frames are corrected to 20 degC with "
            "structure_temperature_c. Default 0.3 K: calibrated sensors (0.1 K) on a structure "
            "that is not isothermal (ISO/TR 16015).",
            assumed="Temperature of the bed and gantry minus 20 degC when it is not measured, "
            "one per test [K], uniform within +-structure_temperature_halfwidth_k: the marks' "
            "coordinates are stated at 20 degC (ISO 1), the structure and everything on it "
            "stand expanded by structure_expansion_ppm_per_k x dT about the marks' centroid, "
            "and the registration on the stated marks keeps that scale: a sub-machine 1 m from "
            "the centroid moves by 13 um at the default (11.5e-6/K x 1 m x 1.15 K). Default "
            "+-2 K: a machine hall held at 20 +- 2 degC; nothing is corrected."),
        "structure_expansion_u": Source(
            Normal(0.0, setup.structure_expansion_u_ppm_per_k * 1e-6), (),
            "Error of the structure's expansion coefficient [1/K]: it acts times the "
            "measured T - 20 degC, by the distance from the marks' centroid. Default 1e-6/K: "
            "steels and cast irons span 10-12.5e-6/K (ISO/TR 16015)."),
        **temperature.gradient_sources(
            setup, "air_gradient",
            measured="Error of the measured vertical gradient of the air's temperature as its "
            "mean along the beams [K/m]; the elevations are corrected with "
            "air_gradient_k_per_m. Default 0.2 K/m: two thermometers of 0.1 K a metre apart "
            "and the gradient's change along the hall.",
            assumed="Vertical gradient G of the air's temperature when it is not measured, one "
            "per test [K/m], uniform between 0 and air_gradient_range_k_per_m: warm air lies "
            "above, so its mean is signed (+0.5 K/m at the default) and biases the simulated "
            "estimates (estimate's bias correction removes the mean). The refractive index "
            "falls by 0.93 ppm/K (Edlen), so a beam bends with curvature 0.93e-6 G per metre "
            "and the tracker sees a target at horizontal distance D raised by 0.93e-6 G D^2 / "
            "2 (7.4 um at 4 m for 1 K/m). Default 1 K/m: halls without displacement "
            "ventilation stratify by 0.5-1 K/m (Estler et al., Large-scale metrology - an "
            "update, CIRP Annals 51/2, 2002)."),
    }


#: weights of the per-test angle-error terms (horizontal: encoder 1st and 2nd harmonic,
#: collimation, trunnion tilt; vertical: index, encoder eccentricity) so that the
#: transverse error has the source's standard deviation in each direction at level sight
_SYSTEMATIC_WEIGHTS = np.array([3**-0.5] * 5 + [1.0] + [2**-0.5] * 3)


def _systematic_angles(coef: np.ndarray, az: np.ndarray, el: np.ndarray):
    """Azimuth and elevation errors (n, points) [rad] of the per-test terms `coef` (n, 9).

    Horizontal: ``c0 cos az + c1 sin az + c2 cos 2az + c3 sin 2az`` (encoder
    harmonics), ``c4 / cos el`` (collimation: the beam off square to the trunnion
    axis), ``c5 tan el`` (trunnion axis out of square to the standing axis).
    Vertical: ``c6 + c7 cos el + c8 sin el`` (index offset, encoder eccentricity).
    """
    c = (coef * _SYSTEMATIC_WEIGHTS)[:, :, None]
    cos_el = np.cos(el)
    daz = (c[:, 0] * np.cos(az) + c[:, 1] * np.sin(az) + c[:, 2] * np.cos(2 * az)
           + c[:, 3] * np.sin(2 * az) + c[:, 4] / cos_el + c[:, 5] * np.tan(el))
    d_el = c[:, 6] + c[:, 7] * cos_el + c[:, 8] * np.sin(el)
    return daz, d_el


def forward(setup: Setup, truth: Truth, errors: dict) -> dict:
    """Tracker readings (distance [mm], azimuth [rad], elevation [rad]), shape (n, points)."""
    marks = _marks(setup)
    rep = np.asarray(errors["machine_repeatability"])
    batch = rep.shape[0]
    mach = _machine_points(setup, truth, np.asarray(errors["rotary_positioning"]),
                           np.asarray(errors["reflector_fixture"]))
    mach = mach + rep + _straightness(setup, truth, np.asarray(errors["straightness"]))
    pts = np.concatenate([np.broadcast_to(marks, (batch, 4, 3)), mach], axis=1)
    rate = np.asarray(errors["thermal_drift"])
    if np.any(rate):
        pts = pts + rate[:, None, :] * _times(setup)[0][:, None]
    dt_ref = temperature.deviation(setup, "structure_temperature")

    def e(name):
        return np.asarray(errors[name], dtype=float).reshape(-1, 1, 1)

    grow = ((setup.structure_expansion_ppm_per_k * 1e-6 + e("structure_expansion_u"))
            * (dt_ref + e("structure_temperature_u") + e("structure_temperature_halfwidth")))
    if np.any(grow):  # the structure at 20 degC + dT, about the marks' centroid
        pts = pts + grow * (pts - marks.mean(axis=0))
    r, t = _tracker_pose(setup, truth)
    v = (pts - t[..., None, :]) @ r  # tracker-frame coordinates: R^T (p - t), row vectors
    horiz = np.hypot(v[..., 0], v[..., 1])
    d = np.linalg.norm(v, axis=-1)
    az = np.arctan2(v[..., 1], v[..., 0])
    el = np.arctan2(v[..., 2], horiz)
    tf = np.asarray(errors["transverse_fixed"])
    tl = np.asarray(errors["transverse_per_length"])
    smr = np.asarray(errors["smr_centring"])
    scale = 1.0 + np.asarray(errors["air_refraction"])[..., None]
    dist = (d + errors["distance_fixed"] + errors["distance_per_length"] * d) * scale
    dist = dist + smr[..., 0]
    daz = (tf[..., 0] / d + tl[..., 0] + smr[..., 1] / d) * d / horiz
    d_el = tf[..., 1] / d + tl[..., 1] + smr[..., 2] / d
    grad = (temperature.gradient(setup, "air_gradient") + e("air_gradient_u")
            + e("air_gradient_range")).reshape(-1, 1)
    if np.any(grad):  # beam bending: the target seen raised by 0.93e-6 G D^2 / 2
        d_el = d_el + temperature.bending(grad, horiz)
    sys = np.asarray(errors["angular_systematic"])
    if np.any(sys):
        s_az, s_el = _systematic_angles(sys, az, el)
        daz, d_el = daz + s_az, d_el + s_el
    return {"distance_mm": dist, "azimuth_rad": az + daz, "elevation_rad": el + d_el}


def _cartesian(readings: dict) -> np.ndarray:
    d = np.asarray(readings["distance_mm"], dtype=float)
    az = np.asarray(readings["azimuth_rad"], dtype=float)
    el = np.asarray(readings["elevation_rad"], dtype=float)
    ce = np.cos(el)
    return np.stack([d * ce * np.cos(az), d * ce * np.sin(az), d * np.sin(el)], axis=-1)


def _corrected_readings(setup: Setup, readings: dict) -> dict:
    """The readings with the elevations corrected for the measured air gradient (unchanged
    where it was not measured)."""
    g = temperature.gradient(setup, "air_gradient")
    if not g:
        return readings
    return {**readings, "elevation_rad": temperature.unbend(
        readings["elevation_rad"], np.asarray(readings["distance_mm"], dtype=float), g)}


def _register(setup: Setup, tracker_marks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rigid transform (R (n,3,3), t (n,3)) with global = R v + t (Kabsch)."""
    stated = _marks(setup)
    sc = stated.mean(axis=0)
    mc = tracker_marks.mean(axis=-2)
    h = np.einsum("nmi,mj->nij", tracker_marks - mc[:, None, :], stated - sc)
    u, _, vt = np.linalg.svd(h)
    det = np.linalg.det(vt.transpose(0, 2, 1) @ u.transpose(0, 2, 1))
    dm = np.broadcast_to(np.eye(3), h.shape).copy()
    dm[:, 2, 2] = np.sign(det)
    rot = vt.transpose(0, 2, 1) @ dm @ u.transpose(0, 2, 1)
    return rot, sc - np.einsum("nij,nj->ni", rot, mc)


def _on_distinct(fit, points: np.ndarray):
    """``fit(points)`` for points (n, m, 3), each distinct row of points fitted once.

    The rows of a linearisation (the estimator map of the first-order prediction) differ
    from the error-free readings in one reading each, so most rows of a group of points are the same
    points: a circle of 7 points sees 42 of 588 rows moved, plus those of the bed marks
    (which move every point through the registration). Rows are matched by a weighted sum
    of their coordinates and then checked equal number for number, so a fit is only ever
    shared by identical points (each row is fitted on its own: the same numbers). A
    Monte Carlo batch, with no two rows alike, is fitted as it is.
    """
    n = points.shape[0]
    flat = points.reshape(n, -1)
    _, first, inverse = np.unique(flat @ np.linspace(1.0, 2.0, flat.shape[1]),
                                  return_index=True, return_inverse=True)
    if 2 * first.size > n or not np.array_equal(flat[first][inverse], flat):
        return fit(points)
    out = fit(points[first])
    return type(out)(*(v[inverse] if np.ndim(v) and np.shape(v)[0] == first.size else v
                       for v in out))


def _fit_arcs_patent(setup: Setup, pts: dict, k: int) -> dict:
    """The patent's 3D circles (no angles); refuses arcs whose fit does not converge."""
    fits = {}
    for g, arc in (("C", setup.c_arc_deg), ("A", setup.a_arc_deg)):
        fit = _on_distinct(fit_circle_3d, pts[g])
        fail = ~np.asarray(fit.converged)
        if np.any(fail):
            raise InvalidInput([
                f"The 3D circle fit of the {g} arc of sub-machine {k} did not converge in "
                f"{int(fail.sum())} of {fail.size} measurement(s): over {arc:g} deg the "
                "points lie nearly on a straight line for their noise, so the circle and "
                f"the {g} axis are not determined. Use a longer arc ({g.lower()}_arc_deg) "
                "or more points."])
        fits[g] = fit
    return fits


def _fit_arcs_angles(setup: Setup, pts: dict, k: int) -> dict:
    """Circles fitted with the commanded angles of the arc points (closed form)."""
    q = setup.points_per_arc
    return {g: _on_distinct(functools.partial(
        fit_circle_3d_angles, angles=np.radians(_arc_angles(arc, q))), pts[g])
            for g, arc in (("C", setup.c_arc_deg), ("A", setup.a_arc_deg))}


def _fit_arcs_home(setup: Setup, pts: dict, k: int) -> dict:
    """Circles with the commanded angles through the arc points and the home position.

    The linear travels run symmetrically about home, so the mean of their points is the
    reflector at home, the point at angle 0 of both arcs: it joins each arc's fit with
    the weight of the number of linear points it averages.
    """
    q = setup.points_per_arc
    home = np.concatenate([pts[ax] for ax in AXES], axis=1)
    weights = np.r_[np.ones(q), home.shape[1]]
    home = home.mean(axis=1, keepdims=True)
    return {g: _on_distinct(functools.partial(
        fit_circle_3d_angles, angles=np.r_[np.radians(_arc_angles(arc, q)), 0.0],
        weights=weights), np.concatenate([pts[g], home], axis=1))
            for g, arc in (("C", setup.c_arc_deg), ("A", setup.a_arc_deg))}


def _estimate(setup: Setup, readings: dict, fit_arcs) -> dict[str, np.ndarray]:
    """Registration, lines, the arcs by `fit_arcs`, then the patent's construction."""
    xyz = _cartesian(_corrected_readings(setup, readings))
    rot, t = _register(setup, xyz[:, :4])
    glob = xyz @ np.swapaxes(rot, -1, -2) + t[:, None, :]  # R v + t (a product: einsum's
    # loop over the batch took 20 times as long)
    dt_ref = temperature.deviation(setup, "structure_temperature")
    if dt_ref:  # to 20 degC: the structure shrunk back about the marks' centroid
        centroid = _marks(setup).mean(axis=0)
        glob = centroid + (glob - centroid) / (1.0 + setup.structure_expansion_ppm_per_k
                                               * 1e-6 * dt_ref)
    sl = _slices(setup)
    nominal = _nominal_origins(setup)
    dot = lambda a, b: np.einsum("ni,ni->n", a, b)  # noqa: E731
    out = {}
    for k in range(1, setup.n_submachines + 1):
        pts = {g: glob[:, sl[(g, k)]] for g in ("X", "Y", "Z", "C", "A")}
        ux, uy, uz = (_on_distinct(lambda p: fit_line_3d(p, orient=p[:, -1] - p[:, 0]),
                                   pts[ax]).direction for ax in AXES)
        arcs = fit_arcs(setup, pts, k)
        c_fit, a_fit = arcs["C"], arcs["A"]
        _, wrist, offset, sin_ac = common_perpendicular(a_fit.centre, a_fit.normal,
                                                        c_fit.centre, c_fit.normal)
        bad = sin_ac < PARALLEL_SIN
        if np.any(bad):
            raise InvalidInput([
                f"The fitted A and C axes of sub-machine {k} are parallel (angle "
                f"{np.min(sin_ac) * 1e6:.3g} urad) in {int(bad.sum())} of {bad.size} "
                "measurement(s): their common perpendicular, and so the wrist centre, is "
                "undefined."])
        origin = wrist - setup.pivot_length_mm * c_fit.normal - nominal[k - 1]
        rx, ry, rz = _angles(_orthonormal(setup, ux, uy, uz))
        out.update({
            f"origin_x_{k}": origin[:, 0], f"origin_y_{k}": origin[:, 1],
            f"origin_z_{k}": origin[:, 2],
            f"rot_x_{k}": rx, f"rot_y_{k}": ry, f"rot_z_{k}": rz,
            f"ac_offset_{k}": offset,
            f"sq_xy_{k}": np.arcsin(dot(ux, uy)), f"sq_yz_{k}": np.arcsin(dot(uy, uz)),
            f"sq_zx_{k}": np.arcsin(dot(uz, ux)),
        })
    return out


def estimate_patent(setup: Setup, readings: dict) -> dict[str, np.ndarray]:
    """The source method: lines, 3D circles, common perpendicular, cross-product frame.

    Parameters
    ----------
    setup : Setup
    readings : dict
        ``distance_mm``, ``azimuth_rad``, ``elevation_rad``, each (n, points).

    Returns
    -------
    dict of measurand name -> array (n,) in mm and rad.
    """
    return _estimate(setup, readings, _fit_arcs_patent)


def estimate_angles(setup: Setup, readings: dict) -> dict[str, np.ndarray]:
    """The source method, with the A and C circles fitted at the commanded angles.

    Each arc is fitted as ``p_i = c + R (cos(theta_i + phi0) e1 + sin(theta_i + phi0)
    e2)`` with the commanded angles theta_i of the set-up (the ``angle_deg`` column of
    the readings table), in closed form (:func:`fit_circle_3d_angles`); the axis line
    is the normal ``e1 x e2`` through c. Everything after the axis lines is the patent's.
    """
    return _estimate(setup, readings, _fit_arcs_angles)


def estimate_home(setup: Setup, readings: dict) -> dict[str, np.ndarray]:
    """The source method, with the circles fitted at the commanded angles and through the
    home position that every group of points shares.

    The reflector at home is on every group of points: the middle of each linear
    travel and angle 0 of each arc. The mean of the linear points (symmetric about
    home) estimates it from 3 ``points_per_axis`` readings; it joins each arc's fit as
    a point at angle 0 of that weight (:func:`_fit_arcs_home`).
    """
    return _estimate(setup, readings, _fit_arcs_home)


def true_values(setup: Setup, truth: Truth) -> dict[str, float]:
    """The patent's construction applied to the true geometry [mm, rad]."""
    nominal = _nominal_origins(setup)
    out = {}
    for k in range(setup.n_submachines):
        h = _head(setup, truth, k)
        o = h.origin - nominal[k]
        ux, uy, uz = (h.axes[..., i, :] for i in range(3))
        rx, ry, rz = _angles(_orthonormal(setup, ux, uy, uz))
        name = k + 1
        out.update({
            f"origin_x_{name}": o[..., 0], f"origin_y_{name}": o[..., 1],
            f"origin_z_{name}": o[..., 2],
            f"rot_x_{name}": rx, f"rot_y_{name}": ry, f"rot_z_{name}": rz,
            f"ac_offset_{name}": h.offset,
            f"sq_xy_{name}": np.arcsin(np.sum(ux * uy, axis=-1)),
            f"sq_yz_{name}": np.arcsin(np.sum(uy * uz, axis=-1)),
            f"sq_zx_{name}": np.arcsin(np.sum(uz * ux, axis=-1)),
        })
    # floats for one truth; arrays (m,) for one truth per batch row
    return {k: (float(v) if np.ndim(v) == 0 else v) for k, v in out.items()}


def truth_from_estimate(setup: Setup, estimate: dict) -> Truth:
    """A Truth whose measurands equal `estimate` (first trial; internal units mm, rad).

    The head's tilts are set to zero (A and C then lie along the frame's X and Z
    axes), the pivot-length error to zero and the tracker at its defaults; the
    squareness, A-C offset, frame rotation and wrist centre follow from the estimate
    exactly: the frame is the construction applied to the local axes, rotated.
    """
    first = {k: np.asarray(v, dtype=float).ravel()[:1] for k, v in estimate.items()}
    fields = _head_rows(setup, first)
    return Truth(**{**_ZERO_HEAD, **{k: tuple(float(x[0]) for x in v)
                                     for k, v in fields.items()}})


def truths_from_estimates(setup: Setup, estimates: dict) -> Truth:
    """:func:`truth_from_estimate` of every row of `estimates` (measurand -> array (m,)):
    a Truth whose head fields are tuples of arrays (m,), one truth per batch row of
    :func:`forward` (not validated: the values are those of valid estimates)."""
    fields = _head_rows(setup, {k: np.asarray(v, dtype=float).ravel()
                                for k, v in estimates.items()})
    t = Truth(**_ZERO_HEAD)
    for k, v in fields.items():
        object.__setattr__(t, k, tuple(v))
    return t


#: the head fields :func:`truth_from_estimate` holds at zero (tilts, pivot-length error)
_ZERO_HEAD = {f: (0.0,) for f in ("c_tilt_x_urad", "c_tilt_y_urad", "a_tilt_y_urad",
                                   "a_tilt_z_urad", "pivot_length_error_um")}


def _head_rows(setup: Setup, est: dict) -> dict[str, list]:
    """The head fields of :func:`truth_from_estimate` for estimates (m,) per measurand:
    field -> one array (m,) per sub-machine."""
    fields: dict[str, list] = {name: [] for name in (
        "wrist_dx_um", "wrist_dy_um", "wrist_dz_um", "frame_rx_urad", "frame_ry_urad",
        "frame_rz_urad", "sq_xy_urad", "sq_yz_urad", "sq_zx_urad", "ac_offset_um")}
    for k in range(1, setup.n_submachines + 1):
        sq = {ab: est[f"sq_{ab}_{k}"] for ab in ("xy", "yz", "zx")}
        # the frame of the local axes (the head untilted, the frame unrotated)
        r_loc = _orthonormal(setup, *np.moveaxis(_travel_axes(
            *(sq[ab] * 1e6 * 1e-6 for ab in ("xy", "yz", "zx"))), -2, 0))
        r_est = _rxyz(est[f"rot_x_{k}"], est[f"rot_y_{k}"], est[f"rot_z_{k}"])
        rx, ry, rz = _angles(r_est @ np.swapaxes(r_loc, -1, -2))
        c_dir = _rxyz(rx, ry, rz)[..., :, 2]
        o = np.stack([est[f"origin_{a}_{k}"] for a in "xyz"], axis=-1)
        wrist = o + setup.pivot_length_mm * (c_dir - np.array([0.0, 0.0, 1.0]))
        for name, value in (("wrist_dx_um", wrist[..., 0] * 1e3),
                            ("wrist_dy_um", wrist[..., 1] * 1e3),
                            ("wrist_dz_um", wrist[..., 2] * 1e3), ("frame_rx_urad", rx * 1e6),
                            ("frame_ry_urad", ry * 1e6), ("frame_rz_urad", rz * 1e6),
                            ("sq_xy_urad", sq["xy"] * 1e6), ("sq_yz_urad", sq["yz"] * 1e6),
                            ("sq_zx_urad", sq["zx"] * 1e6),
                            ("ac_offset_um", est[f"ac_offset_{k}"] * 1e3)):
            fields[name].append(value)
    return fields


# --------------------------------------------------------------------------- gls
#: Truth fields of each sub-machine that the ``gls`` fit estimates (tuples, one per head)
_GLS_HEAD = ("wrist_dx_um", "wrist_dy_um", "wrist_dz_um", "frame_rx_urad", "frame_ry_urad",
             "frame_rz_urad", "sq_xy_urad", "sq_yz_urad", "sq_zx_urad", "c_tilt_x_urad",
             "c_tilt_y_urad", "a_tilt_y_urad", "a_tilt_z_urad", "ac_offset_um")
#: the tracker's pose fields it estimates
_GLS_TRACKER = ("tracker_dx_um", "tracker_dy_um", "tracker_dz_um", "tracker_tilt_x_urad",
                "tracker_tilt_y_urad", "tracker_yaw_deg")
#: central-difference steps [um, urad, deg]: 0.1 um, 0.1 urad, 0.1 urad of yaw
_GLS_STEP = {"deg": math.degrees(1e-7), "um": 0.1, "urad": 0.1}


def _gls_names(setup: Setup) -> list[tuple[str, int | None]]:
    """The fitted parameters in order: (field, sub-machine index or None)."""
    return ([(f, k) for k in range(setup.n_submachines) for f in _GLS_HEAD]
            + [(f, None) for f in _GLS_TRACKER])


def _gls_truth(setup: Setup, base: Truth, theta: np.ndarray) -> Truth:
    """``base`` with the fitted fields set from parameter rows ``theta`` (m, p) (arrays (m,),
    one truth per row; no validation)."""
    t = dataclasses.replace(base)
    n = setup.n_submachines
    heads: dict[str, list] = {f: [None] * n for f in _GLS_HEAD}
    for j, (f, k) in enumerate(_gls_names(setup)):
        if k is None:
            object.__setattr__(t, f, np.ascontiguousarray(theta[:, j]))
        else:
            heads[f][k] = np.ascontiguousarray(theta[:, j])
    for f, v in heads.items():
        object.__setattr__(t, f, tuple(v))
    return t


def _gls_vector(readings: dict) -> np.ndarray:
    """Readings as rows (n, 3 points): distance [mm], azimuth, elevation [rad]."""
    return np.concatenate([np.asarray(readings[k], dtype=float)
                           for k in ("distance_mm", "azimuth_rad", "elevation_rad")], axis=-1)


def _gls_predict(setup: Setup, base: Truth, theta: np.ndarray) -> np.ndarray:
    """Error-free readings (m, 3 points) for parameter rows ``theta`` (m, p)."""
    errors = PROCEDURE.zero_errors(setup, theta.shape[0])
    return _gls_vector(forward(setup, _gls_truth(setup, base, theta), errors))


def _gls_residual(setup: Setup, y: np.ndarray, pred: np.ndarray) -> np.ndarray:
    r = y - pred
    p = _n_points(setup)
    r[:, p:] = (r[:, p:] + np.pi) % (2 * np.pi) - np.pi  # angles: wrap
    return r


@functools.lru_cache(maxsize=16)
def _gls_gain(setup: Setup, base: Truth, ref: tuple) -> np.ndarray:
    """Gain K (p, 3 points) of the generalised least squares at the parameters ``ref``.

    ``K = (J^T C^-1 J)^-1 J^T C^-1`` (:func:`mtplan.fitting.gls_gain`) with ``J`` the
    readings' Jacobian (central differences) and ``C`` (plus a floor of 1 nm and
    0.1 nrad) their covariance under every active error source of the set-up, by the
    secant effect of each element of a source at the same parameters
    (:func:`mtplan.fitting.readings_covariance`'s numbers, from grouped rows:
    :func:`mtplan.fitting.effects.secant_effects`). The readings are few (3 per point), so
    ``C`` is formed and factorised, scaled to unit diagonal.
    """
    theta = np.asarray(ref, dtype=float)[None, :]
    steps = np.array([_GLS_STEP[f.rsplit("_", 1)[1]] for f, _ in _gls_names(setup)])
    jac = central_jacobian(lambda rows: _gls_predict(setup, base, rows), theta[0], steps)
    model = SourceModel(
        PROCEDURE.name, sources(setup),
        lambda errors: _gls_vector(forward(setup, _gls_truth(setup, base, np.repeat(
            theta, next(iter(errors.values())).shape[0], axis=0)), errors)),
        lambda m: PROCEDURE.zero_errors(setup, m))
    # a floor far below any source's effect (1 nm, 0.1 nrad), so that readings no source
    # moves (or a set-up without sources) keep a weight and C stays regular
    floor = np.repeat([1e-6, 1e-10, 1e-10], _n_points(setup))
    D, U = secant_effects(model, key=(NAME, setup))  # readings_covariance's numbers
    return gls_gain(jac, Gaussian.known(D + floor**2, U))


def _gls_start(setup: Setup, readings: dict) -> tuple[Truth, np.ndarray]:
    """The start of the fit: the ``home`` estimate of the first trial as a Truth (head
    tilts zero), the tracker's pose from the registration on the marks; (truth, theta (p,))."""
    home = estimate_home(setup, {k: np.asarray(v)[:1] for k, v in readings.items()})
    base = truth_from_estimate(setup, home)
    rot, t = _register(setup, _cartesian({k: np.asarray(v)[:1] for k, v in
                                          readings.items()})[:, :4])
    tx, ty, yaw = _angles(rot[0])
    d = (t[0] - np.array([-setup.tracker_distance_mm, 0.0, setup.tracker_height_mm])) * 1e3
    base = dataclasses.replace(base, tracker_dx_um=float(d[0]), tracker_dy_um=float(d[1]),
                               tracker_dz_um=float(d[2]), tracker_tilt_x_urad=float(tx) * 1e6,
                               tracker_tilt_y_urad=float(ty) * 1e6,
                               tracker_yaw_deg=float(np.degrees(yaw)))
    theta = np.array([float(_cyc(getattr(base, f), k)) if k is not None
                      else float(getattr(base, f)) for f, k in _gls_names(setup)])
    return base, theta


def _gls_key(setup: Setup, theta: np.ndarray) -> tuple:
    """Parameters rounded to 10 um, 10 urad and 1e-3 deg (17 urad): where the gain is
    taken (its cache key, so that a Monte Carlo's blocks, whose starts scatter by a few
    micrometres, share it). Noise-free the fit's fixed point does not depend on where
    the gain was taken; with noise the weighting changes by second-order amounts."""
    grid = np.array([1e-3 if f.endswith("_deg") else 10.0 for f, _ in _gls_names(setup)])
    return tuple(float(f"{v:.10g}") for v in np.round(np.asarray(theta) / grid) * grid)


def estimate_gls(setup: Setup, readings: dict, *, iterations: int = 30) -> dict[str, np.ndarray]:
    """Generalised least squares (GLS) of the whole forward model to all readings.

    The parameters are the head's geometry of every sub-machine (:data:`_GLS_HEAD`) and
    the tracker's pose; the pivot-length error and the A-C angle are held. The weights
    are the inverse covariance of the readings under every active error source
    (:func:`_gls_gain`). Gauss-Newton with one gain for the whole batch
    (:func:`mtplan.fitting.gauss_newton`), taken at the start (:func:`_gls_start`) and
    re-taken once at the batch's median; the measurands
    are the construction applied to the fitted geometry (:func:`true_values`).
    """
    # matrices of a few hundred rows: a team of BLAS threads costs more than it gains
    # (3 times, on a busy machine), so the fit runs on one
    with one_blas_thread():
        return _estimate_gls(setup, readings, iterations)


def _estimate_gls(setup: Setup, readings: dict, iterations: int) -> dict[str, np.ndarray]:
    y = _gls_vector(readings)
    start_truth, start = _gls_start(setup, readings)
    # the gain depends on the held fields only (the fitted ones come from theta)
    base = Truth(pivot_length_error_um=start_truth.pivot_length_error_um,
                 ac_angle_deg=start_truth.ac_angle_deg)
    fit = gauss_newton(lambda th: _gls_residual(setup, y, _gls_predict(setup, base, th)),
                       np.repeat(start[None, :], y.shape[0], axis=0),
                       _gls_gain(setup, base, _gls_key(setup, start)),
                       iterations=iterations, tol=1e-7,  # [um, urad]
                       regain_after=(2,), regain=lambda th: _gls_gain(
                           setup, base, _gls_key(setup, np.median(th, axis=0))))
    theta = np.where(fit.ok[:, None], fit.theta, np.nan)
    return true_values(setup, _gls_truth(setup, base, theta))


def _times(setup: Setup) -> tuple[np.ndarray, float]:
    """Time of each reading from the start (n_points,) in layout order, and the total [s].

    The marks first (``mark_s`` each); then per sub-machine the fixture
    (``changeover_s``); each linear travel out from home to its start, along it point
    by point (``dwell_s`` at each) and back home at ``linear_feed_mm_min``; each arc
    point ``rotary_move_s`` + ``dwell_s``. A reading is taken at the end of its dwell.
    """
    feed = setup.linear_feed_mm_min / 60.0
    P, Q = setup.points_per_axis, setup.points_per_arc
    travels = (setup.travel_x_mm, setup.travel_y_mm, setup.travel_z_mm)
    marks = setup.mark_s * np.arange(1, 5)
    # one sub-machine, from its start: three travels, then the C and A arcs
    lin = [(np.arange(P) * (t / (P - 1)) + t / 2) / feed + setup.dwell_s * np.arange(1, P + 1)
           for t in travels]
    starts = np.cumsum([0.0] + [2 * t / feed + P * setup.dwell_s for t in travels])
    arc = (setup.rotary_move_s + setup.dwell_s) * np.arange(1, 2 * Q + 1)
    one = np.concatenate([*(s + t for s, t in zip(starts, lin, strict=False)), starts[3] + arc])
    per_sub = setup.changeover_s + starts[3] + arc[-1]
    subs = marks[-1] + setup.changeover_s + per_sub * np.arange(setup.n_submachines)
    times = np.concatenate([marks, (subs[:, None] + one).ravel()])
    return times, float(marks[-1] + setup.n_submachines * per_sub)


def duration(setup: Setup) -> float:
    """Machine time [s]: marks, and per sub-machine the fixture, travels and arcs."""
    return _times(setup)[1]


READING_COLUMNS = ("distance_mm", "azimuth_rad", "elevation_rad")
KEY_COLUMNS = ("group", "submachine", "index")


def readings_frame(setup: Setup, readings: dict) -> pd.DataFrame:
    """Tidy table of one measurement (the first trial): one tracker reading per row.

    Columns: ``point`` (0..), ``group`` (``mark``, ``X``, ``Y``, ``Z``, ``C``, ``A``),
    ``submachine`` (0 for the bed marks), ``index`` (within the group), the commanded
    ``position_mm`` (linear travels) and ``angle_deg`` (arcs), and the readings
    ``distance_mm``, ``azimuth_rad``, ``elevation_rad``.
    """
    rows = _layout(setup)
    df = pd.DataFrame(rows, columns=["group", "submachine", "index", "position_mm", "angle_deg"])
    df.insert(0, "point", np.arange(len(rows)))
    for col in READING_COLUMNS:
        df[col] = np.asarray(readings[col], dtype=float)[0]
    return df


def from_frame(setup: Setup, df: pd.DataFrame) -> dict:
    """Readings (batch of one) from a table in the format of :func:`readings_frame`.

    Rows are matched to the set-up's layout by (group, submachine, index); their
    order in the table does not matter. The commanded positions are not used (the
    estimators orient lines by the order of the points along each travel). The
    commanded angles of the arcs, which the ``angles`` estimator uses, come from the
    set-up; an ``angle_deg`` column, when present, must agree with them (1e-6 deg).
    """
    p = Problems(f"{NAME} readings")
    values = frame_columns(df, (*KEY_COLUMNS, *READING_COLUMNS), f"{NAME} readings",
                           numeric=READING_COLUMNS, problems=p)
    layout = _layout(setup)
    if len(df) != len(layout):
        p.add_text(f"The readings of {NAME} must have {len(layout)} rows for this set-up "
                   f"(4 marks + {setup.n_submachines} x (3 x {setup.points_per_axis} + 2 x "
                   f"{setup.points_per_arc})). Got {len(df)} instead")
    p.raise_if_any()
    try:
        keys = list(zip(df["group"].astype(str),
                        pd.to_numeric(df["submachine"]).astype(int),
                        pd.to_numeric(df["index"]).astype(int), strict=True))
    except (ValueError, TypeError):
        raise InvalidInput([f"Columns 'submachine' and 'index' of the {NAME} readings must "
                            "hold integers."]) from None
    where = {}
    for row, key in enumerate(keys):
        if key in where:
            p.add_text(f"Row {row} of the {NAME} readings repeats {key} (first at row "
                       f"{where[key]})")
        where[key] = row
    expected = [r[:3] for r in layout]
    absent = [key for key in expected if key not in where]
    if absent:
        p.add_text(f"The {NAME} readings lack the point(s) (group, submachine, index) "
                   f"{', '.join(map(str, absent[:5]))}" + (" ..." if len(absent) > 5 else ""))
    extra = sorted(set(where) - set(expected))
    if extra:
        p.add_text(f"The {NAME} readings hold point(s) this set-up does not have: "
                   f"{', '.join(map(str, extra[:5]))}")
    p.raise_if_any()
    order = np.array([where[key] for key in expected])
    if "angle_deg" in df.columns:
        # the angles estimator takes the commanded angles from the set-up: a table whose
        # arcs were run at other angles would be fitted against the wrong ones
        got = pd.to_numeric(df["angle_deg"], errors="coerce").to_numpy(dtype=float)[order]
        want = np.array([r[4] for r in layout])
        arc = np.array([r[0] in ("C", "A") for r in layout])
        off = np.flatnonzero(arc & ~(np.abs(got - want) <= 1e-6))
        if off.size:
            rows = ", ".join(f"{layout[i][:3]} {got[i]:g} deg, set-up {want[i]:g} deg"
                             for i in off[:3])
            raise InvalidInput([
                f"The 'angle_deg' of {off.size} arc point(s) of the {NAME} readings differ "
                f"from the set-up's commanded angles ({rows}"
                f"{' ...' if off.size > 3 else ''}); arcs are centred on home with "
                "c_arc_deg / a_arc_deg and points_per_arc: set these to match the data."])
    return {col: values[col][order][None, :] for col in READING_COLUMNS}


def setup_from_frame(df: pd.DataFrame) -> dict:
    """The set-up fields a measured tracker table determines (see ``Implied``).

    The number of sub-machines (the largest ``submachine``), of points per linear travel
    (the X rows of the first sub-machine) and per arc (its C rows), the travels (the
    span of ``position_mm`` of its X, Y and Z rows, within 1e-6 mm) and the arcs of C
    and A (from ``angle_deg``: the span, or 360 when the points are evenly spaced over a
    full turn without its repeated end, within 1e-6 deg). Where the table is not regular
    enough to tell, the field is left out and the design check names the offending row.
    """
    from mtplan.models.protocol import Implied

    group = df["group"].astype(str).str.strip().to_numpy()
    sub = pd.to_numeric(df["submachine"], errors="coerce").to_numpy(dtype=float)
    pos = pd.to_numeric(df["position_mm"], errors="coerce").to_numpy(dtype=float)
    ang = pd.to_numeric(df["angle_deg"], errors="coerce").to_numpy(dtype=float)
    if not all(np.all(np.isfinite(a)) for a in (sub, pos, ang)) or not np.any(sub >= 1):
        return {}
    n_sub = int(sub.max())
    out = {"n_submachines": Implied(n_sub, why=f"the file's sub-machines 1..{n_sub}")}
    first = sub == 1
    for g, field, what in (("X", "points_per_axis", "X"), ("C", "points_per_arc", "C")):
        m = int(np.sum(first & (group == g)))
        if m:
            out[field] = Implied(m, why=f"the {what} rows of sub-machine 1")
    for g in AXES:
        p = pos[first & (group == g)]
        if p.size >= 2:
            out[f"travel_{g.lower()}_mm"] = Implied(float(np.ptp(p)), 1e-6,
                                                  why=f"the {g} positions of sub-machine 1")
    for g in ("C", "A"):
        a = np.sort(ang[first & (group == g)])
        if a.size >= 2:
            full = np.allclose(_arc_angles(360.0, a.size), a, rtol=0, atol=1e-6)
            out[f"{g.lower()}_arc_deg"] = Implied(360.0 if full else float(np.ptp(a)), 1e-6,
                                                  why=f"the {g} angles of sub-machine 1")
    return out


PROCEDURE = Procedure(
    name=NAME,
    title="Zero point and frames of gantry sub-machines by laser tracker",
    Setup=Setup,
    Truth=Truth,
    measurands=measurands,
    sources=sources,
    forward=forward,
    estimators={"patent": Estimator(estimate_patent, exact=True),
                "angles": Estimator(estimate_angles, exact=True),
                "home": Estimator(estimate_home, exact=True),
                "gls": Estimator(estimate_gls, exact=True)},
    true_values=true_values,
    duration=duration,
    description=(
        "Laser-tracker calibration of the frames of the AC-head sub-machines of a gantry "
        "(CN106078359A): lines along the travels, 3D circles round A and C, the common "
        "perpendicular of A and C, origin at the pivot length along C, longest travel kept."),
    levers=tuple("reflector_offset_mm travel_x_mm travel_y_mm travel_z_mm "
                 "points_per_axis c_arc_deg a_arc_deg points_per_arc tracker_distance_mm "
                 "tracker_height_mm dwell_s linear_feed_mm_min".split()),
    readings=ReadingsFormat(readings_frame, from_frame, setup_from_frame=setup_from_frame),
    capabilities=Capabilities(block_size=4000, truth_from_estimate=truth_from_estimate,
                              truths_from_estimates=truths_from_estimates),
)
