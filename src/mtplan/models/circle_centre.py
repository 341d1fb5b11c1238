"""Bore centre by three probed points in equilateral distribution (circle-centre patent).

A large two-axis stage carries a ring workpiece; a touch-trigger probe is lowered
into its bore of nominal radius ``r = bore_radius_mm`` at an arbitrary start point
and the centre is found from points probed on the wall. The machine frame has its
origin at the nominal bore centre; the measurands are the deviations of the bore's
centre (``centre_x``, ``centre_y``) and radius (``radius``) from nominal, in um.

Path planning (the patent's method, :func:`plan_path`)
----------------------------------------------------
1. From the start point probe along -y (p1), then along +y (p2). With the chord
   half-length ``h = |p2 - p1| / 2``, ``theta1 = angle p1-o-p2 = 2 asin(h / r)``.
2. At p2 the probe tries a small displacement ``free_test_mm`` in +x and in -x; the
   free direction (+1, -1, or 0 when neither is free, i.e. the start was on the
   centre's x) tells on which side of the chord the centre lies. The planner's
   centre estimate is ``o = ((x1 + x2)/2 + dir sqrt(r^2 - h^2), (y1 + y2)/2)``.
3. d1, d2, d3 are 120 deg apart with d3 on p1. The travel sense (sigma) is the long
   way round from p2 to p1 (away from p1); then d3 = p1, d2 = p1 - 120 deg and
   d1 = p1 - 240 deg along it, so the angle from o-p2 to o-d1 along the travel is
   ``theta2 = (360 - theta1) - 240 = 120 - theta1`` (the patent's formula is an image
   lost from the text; this is the value its figure and its two d1 cases imply:
   theta2 < 0 means d1 lies behind p2 and the travel reverses at d1).
4. Each leg from point A to point B of the bore is an arc of a helper circle tangent
   to the radius o-A at A and to the radius o-B at B, so the probe leaves and meets
   the wall along the radius (little tangential slip). For a leg of central angle
   theta its centre is the pole ``o + r / cos(theta/2) * u(mid-angle)`` and its
   radius ``r |tan(theta/2)|`` (r_o1 from theta2, r_o2 = r_o3 = r tan 60 deg).
   A leg turning ccw about o turns cw about its helper circle. The first rotation
   about o1 follows the patent's four cases: (1) theta2 >= 0 and free direction
   positive: ccw; (2) theta2 >= 0, negative: cw; (3) theta2 < 0, positive or 0: cw;
   (4) theta2 < 0, negative: ccw. At d1 the travel keeps its sense when
   theta2 >= 0 and reverses when theta2 < 0 (the patent's d1 rule). The planner
   derives these senses from geometry; the tests check them against the four cases.
5. Acceptance check: ``dx = |x_p1 - x_d3|``, ``dy = |y_p1 - y_d3|`` (the patent writes
   ``x_d3`` in dy: a typo); d3 is accepted when both are within
   ``miss_tolerance_mm`` (:func:`acceptance_check`). The check does not change the
   estimate, so the Monte Carlo reports it beside, not inside, the measurands.

Generalisation to ``n_points`` and ``spread_deg``: the n points are equally spaced,
``360/n`` apart when ``spread_deg == 360`` and ``spread/(n-1)`` apart (both ends
included) otherwise; the last one lands on p1 and the others precede it along the
travel, so ``theta2 = (360 - theta1) - (n - 1) * step`` (the patent's case is n = 3,
spread 360). A leg longer than 150 deg (only the first transfer of a short arc of
points) would need a helper circle through or beyond the centre; it is made as a
straight move to the planner's centre and out along the radius instead.

Forward model (:func:`forward`, batch-first)
--------------------------------------------
- Wall: ``rho(phi) = r + radius_dev + a cos(k phi) + b sin(k phi)`` about the true
  centre, ``k = lobes`` (>= 2, so the least-squares reference circle of the wall is
  the true circle and the measurands' true values are unaffected by form).
- Stage: the machine reads positions ``q_read``; the actual position is
  ``M q_read`` with ``M = [[1 + ex, s], [0, 1 + ey]]`` (scale errors and
  squareness, constant during the test), plus a per-reading repeatability. The
  probe is commanded in read coordinates, so every approach line is mapped through
  ``M`` exactly before it meets the wall.
- Start point: truth ``start_x_mm, start_y_mm`` plus a uniform scatter of
  half-width ``start_scatter_mm`` per axis (the operator lowers the probe by eye).
- Contacts: the exact intersection of each approach line with the wall (a circle
  intersection, then Newton on the form error; 4 iterations reach machine precision).
  The final approach to each d_k is taken along the helper arc's tangent at the
  target, i.e. the radius through the planned target. Over the distance ``delta``
  between the planned and the actual wall the arc leaves that line by its sagitta
  ``delta^2 / (2 r_o)``: the contact slides along the wall by that much (12 nm for
  delta = 0.1 mm and r_o = r tan 60 deg, r = 250 mm), which changes the recorded
  point's distance from the centre only through the wall's slope (< 1e-12 mm here),
  and the obliqueness by ``delta / r_o`` (4e-4 rad, i.e. < 5 nm of slip at the
  default). The recorded coordinates are those of a true wall point either way.
  Tested against the exact arc-circle intersection. For a first leg with a tiny
  theta2 (r_o1 -> 0) a real controller cannot follow the arc either; it re-probes
  radially, as modelled.
- Probe: trigger noise along the approach; pre-travel variation with approach
  direction beta, three-lobed as for kinematic probes (``A cos 3 beta + B sin 3 beta``);
  the error of the calibrated effective tip radius (one per test: the controller
  compensates the stylus centre by the calibrated radius along the approach, so every
  point lies that much beyond the wall; it moves the radius, and the centre only by
  about ``delta (e/r)^2`` for a planner's centre off by e); tangential slip along the
  wall ``c * gamma`` with gamma the signed angle between the approach and the wall
  normal.
- Temperature (ISO 1: dimensions at 20 degC). The part grows about its clamping point
  (``clamp_x_mm``, ``clamp_y_mm``) by ``alpha_part dT_part``; the stage's scales grow
  about their datum (``scale_datum_x_mm``, ``scale_datum_y_mm``, the fixed point about
  which real scales grow) by ``alpha_scale dT_scale`` and read lengths from the datum
  that much short; the stage's scale and squareness errors act about the same datum
  (``actual = D + M (read - D)``). A measured temperature (``part_temperature_c``,
  ``scale_temperature_c``) is corrected for by every estimator (:func:`_to_20c`, exact for
  a circle), leaving its thermometer's error (``*_temperature_u``) and the expansion
  coefficients' (``expansion_u``, ``scale_expansion_u``) as sources; one not measured is
  a zero-mean rectangular half-width (``*_temperature_halfwidth``), uncorrected, and the
  set-up's notes say so. Unmeasured scales follow the part's actual temperature within
  their half-width. The sources are the actual temperatures minus the reference ones the
  estimators correct with, so zero errors give the truth exactly.
- p1 and p2 are probed along -y and +y with the same probe model; the planner uses
  the read values, so their errors move the targets.

Estimators (internal units, mm)
-------------------------------
- ``three_point`` (the patent's method, listed first): the a..f formula. With
  ``n_points > 3`` it uses three of the points, the best-spread triple: indices
  ``0, n//3, 2n//3`` for a full circle (nearly equilateral), and the two ends and
  the middle ``0, (n-1)//2, n-1`` for a partial arc. It never refuses (the engine
  needs every estimator to answer); it just ignores the other points.
- ``kasa``: algebraic least-squares circle.
- ``geometric``: orthogonal-distance least-squares circle (Gauss-Newton /
  Levenberg-Marquardt on the batch, from Kasa).

Known behaviour (tested): with n equally spaced points and radial noise sigma the
centre's standard uncertainty per axis is ``sigma sqrt(2/n)``; three points bunched
into a short arc are worse by orders of magnitude. With three points 120 deg apart a
three-lobed pre-travel pattern (and a three-lobed form error) repeats at every
point and moves only the radius, never the centre. A **two-lobed** form error (an oval
bore, the default ``lobes``) is aliased into the centre: with points at
``phi_j = phi_0 + 120 j`` deg, ``cos 2 phi_j = cos(2 phi_0 - 120 j)`` is a one-lobed
(eccentricity) pattern over the three points, so an oval of amplitude ``A`` (peak to
valley ``2A``) moves the three-point centre by ``A`` (to first order), in the
direction ``3 phi_0 - psi`` (``psi`` the oval's orientation). In general n equally
spaced points alias a k-lobed form into the centre when ``k = +-1 (mod n)``. At the
default (RMS peak to valley 5 um, random orientation) that is ``5/(2 sqrt 2)`` =
1.8 um per axis, four times the 0.41 um of the probe noise; least-squares circles
through n >= 4 equally spaced points do not alias an oval (docs/circle_centre.md).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from mtplan._validate import InvalidInput, Problems
from mtplan.fitting import gls_step
from mtplan.fitting.circle import geometric_fit, kasa_fit, three_point_circle
from mtplan.models import _temperature as temperature
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
from mtplan.uncertainty import Normal, Rectangular

if TYPE_CHECKING:  # pandas only where a table is made or read: not in a Monte Carlo's workers
    import pandas as pd

__all__ = [
    "Setup",
    "Truth",
    "PathPlan",
    "Segment",
    "plan_path",
    "plan_for_bore",
    "acceptance_check",
    "miss",
    "fit_points",
    "PROCEDURE",
]

_DEG = math.pi / 180.0
_MAX_ARC = 150.0 * _DEG  # legs longer than this go through the centre (see docstring)


# --------------------------------------------------------------------------- set-up
@dataclass(frozen=True)
class Setup(SetupBase):
    """Set-up of the bore-centre measurement (see the module docstring)."""

    _owner = "circle_centre"
    bore_radius_mm: float = param(250.0, doc="Nominal radius of the bore", low=0, high=10_000,
                                  low_open=True)
    n_points: int = param(3, doc="Measuring points d1..dn (3: the patent's rule)", low=3, high=360)
    spread_deg: float = param(360.0, doc="Arc the points cover; 360 = full circle, equally "
                              "spaced; less: end points included", low=1, high=360)
    probe_noise_um: float = param(0.5, doc="Probe trigger noise along the approach (std)", low=0,
                                  high=1000)
    pretravel_variation_um: float = param(1.0, doc="RMS amplitude of the three-lobed pre-travel "
                                          "variation with approach direction", low=0, high=1000)
    tangential_slip_um_per_deg: float = param(0.2, doc="Mean tangential slip per degree between "
                                              "approach and wall normal", low=0, high=1000)
    roundness_um: float = param(5.0, doc="Form error of the bore (RMS peak-to-valley of one "
                                "lobed harmonic)", low=0, high=10_000)
    lobes: int = param(2, doc="Lobes of the form error (2 = oval)", low=2, high=100)
    scale_error_ppm: float = param(5.0, doc="Stage scale error per axis (rectangular half-width)",
                                   low=0, high=10_000)
    squareness_urad: float = param(10.0, doc="Stage X-Y squareness error (rectangular "
                                   "half-width)", low=0, high=100_000)
    stage_repeatability_um: float = param(0.5, doc="Stage positioning repeatability per axis "
                                          "and reading (std)", low=0, high=1000)
    tip_radius_um: float = param(0.5, doc="Standard deviation of the error of the probe's "
                                 "calibrated effective tip radius, one per test (the radius is "
                                 "calibrated on a setting ring whose diameter is known to about "
                                 "1 um, ISO 1938-1 / DIN 2250-1 setting rings)", low=0, high=1000)
    part_temperature_c: float | None = param(
        None, doc="Measured temperature of the part [degC] (ISO 1's reference is 20 degC): "
        "the estimates are corrected to 20 degC with it; empty: not measured, the part is "
        "assumed at 20 degC within +-part_temperature_halfwidth_k and nothing is corrected",
        low=10, high=40, condition="part_temperature_c")
    part_temperature_u_k: float = param(
        0.2, doc="Standard uncertainty of the measured part temperature (thermometer's "
        "calibration, its contact, one reading standing for the whole part; ISO/TR 16015 "
        "names these) [K]; used when part_temperature_c is given", low=0, high=10)
    part_temperature_halfwidth_k: float = param(
        2.0, doc="Half-width of the (rectangular) deviation of the part's temperature from "
        "20 degC when it is not measured [K] (a workshop held at 20 +- 2 degC)", low=0,
        high=50)
    expansion_ppm_per_k: float = param(11.5, doc="Linear thermal expansion coefficient of the "
                                       "workpiece [1e-6/K]; 11.5: steel", low=0, high=100)
    expansion_u_ppm_per_k: float = param(
        1.0, doc="Standard uncertainty of the workpiece's expansion coefficient [1e-6/K] "
        "(steels span 10.5-12.5e-6/K: ISO/TR 16015 advises about 1e-6/K for a material "
        "known by its kind only)", low=0, high=100)
    scale_temperature_c: float | None = param(
        None, doc="Measured temperature of the stage's scales (or of the machine structure "
        "that carries them) [degC]; empty: not measured, the scales are taken at the part's "
        "temperature within +-scale_temperature_halfwidth_k", low=10, high=40,
        condition="machine_temperature_c")
    scale_temperature_u_k: float = param(
        0.2, doc="Standard uncertainty of the measured scale temperature [K]; used when "
        "scale_temperature_c is given", low=0, high=10)
    scale_temperature_halfwidth_k: float = param(
        1.0, doc="Half-width of the (rectangular) difference of the scales' temperature from "
        "the part's when it is not measured [K] (0 when part and machine share one "
        "temperature; larger for a part that arrives warmer or colder)", low=0, high=50)
    scale_expansion_ppm_per_k: float = param(10.0, doc="Linear thermal expansion coefficient of "
                                             "the stage's scales [1e-6/K]; 10: steel-mounted "
                                             "glass or steel scales (about 0 for glass-ceramic "
                                             "scales)", low=0, high=100)
    scale_expansion_u_ppm_per_k: float = param(
        0.5, doc="Standard uncertainty of the scales' effective expansion coefficient "
        "[1e-6/K] (a scale mounted on steel follows its mounting, 10-11.5e-6/K)", low=0,
        high=100)
    scale_datum_x_mm: float = param(
        0.0, doc="x of the X scale's datum (its fixed point, about which it grows) from "
        "the nominal bore centre [mm]; state the machine's (e.g. -300: a bore in the middle of "
        "a 600 mm travel whose scale is fixed at its end); the default 0 puts it at the bore, "
        "where the scales' growth does not move the centre", low=-100_000, high=100_000)
    scale_datum_y_mm: float = param(
        0.0, doc="y of the Y scale's datum from the nominal bore centre [mm] (as "
        "scale_datum_x_mm)", low=-100_000, high=100_000)
    clamp_x_mm: float = param(
        0.0, doc="x of the point about which the part grows (where it is clamped or centred "
        "on the table) from the nominal bore centre [mm]; 0: a ring clamped concentrically",
        low=-100_000, high=100_000)
    clamp_y_mm: float = param(
        0.0, doc="y of the part's clamping point from the nominal bore centre [mm]",
        low=-100_000, high=100_000)
    start_scatter_mm: float = param(25.0, doc="Half-width per axis of the uniform scatter of "
                                    "the start point about the truth's start", low=0,
                                    high=10_000)
    free_test_mm: float = param(0.01, doc="Trial displacement at p2 that finds the free "
                                "direction", low=0, high=100, low_open=True)
    miss_tolerance_mm: float = param(0.05, doc="Accepted miss between d_n and p1 per axis",
                                     low=0, high=1000)
    feed_mm_min: float = param(2000.0, doc="Feed of the transfer moves", low=0, high=1e6,
                               low_open=True)
    probe_feed_mm_min: float = param(100.0, doc="Probing feed over the last clearance", low=0,
                                     high=1e5, low_open=True)
    clearance_mm: float = param(2.0, doc="Distance probed at the probing feed before each "
                                "contact", low=0, high=1000)
    dwell_s: float = param(0.5, doc="Dwell per contact (settling, skip signal, retract)", low=0,
                           high=3600)

    def _check(self, p: Problems) -> None:
        if self.start_scatter_mm * math.sqrt(2) > 0.5 * self.bore_radius_mm:
            p.add("start_scatter_mm", self.start_scatter_mm,
                  f"<= {0.5 * self.bore_radius_mm / math.sqrt(2):g} (the start must stay within "
                  f"half the bore radius bore_radius_mm={self.bore_radius_mm:g} of the truth's "
                  "start, or it may leave the bore)")
        if self.clearance_mm >= self.bore_radius_mm:
            p.add("clearance_mm", self.clearance_mm,
                  f"< bore_radius_mm ({self.bore_radius_mm:g})")
        if self.free_test_mm >= 0.1 * self.bore_radius_mm:
            p.add("free_test_mm", self.free_test_mm,
                  f"< a tenth of bore_radius_mm ({0.1 * self.bore_radius_mm:g})")
        roundness_mm = self.roundness_um * 1e-3
        if roundness_mm >= 0.05 * self.bore_radius_mm:
            p.add("roundness_um", self.roundness_um,
                  f"< 5 % of the bore radius ({50 * self.bore_radius_mm:g} um)")


    def notes(self) -> list[str]:
        """Which temperatures were assumed rather than measured, and what was corrected."""
        out = (temperature.assumed_note(self, "part_temperature", "the part's temperature")
               + temperature.assumed_note(self, "scale_temperature", "the scales' temperature",
                                          about="the part's"))
        if self.part_temperature_c is not None or self.scale_temperature_c is not None:
            dtp, dts = _reference_deviations(self)
            out.append(f"temperature: corrected to 20 degC from the part at {20 + dtp:g} degC "
                       f"and the scales at {20 + dts:g} degC (scales about their datum "
                       f"({self.scale_datum_x_mm:g}, {self.scale_datum_y_mm:g}) mm, the part "
                       f"about its clamping point ({self.clamp_x_mm:g}, {self.clamp_y_mm:g}) "
                       "mm)")
        return out


@dataclass(frozen=True)
class Truth(SetupBase):
    """True bore (relative to the nominal centre) and the nominal start point."""

    _owner = "circle_centre truth"
    centre_x_mm: float = param(0.35, doc="True centre, x, from the nominal centre")
    centre_y_mm: float = param(-0.2, doc="True centre, y, from the nominal centre")
    radius_deviation_mm: float = param(0.015, doc="True radius minus the nominal radius")
    start_x_mm: float = param(0.0, doc="Start point (machine reading), x, before the scatter")
    start_y_mm: float = param(0.0, doc="Start point (machine reading), y, before the scatter")


def measurands(setup: Setup) -> tuple[Measurand, ...]:
    return (
        Measurand("centre_x", "um", "x of the bore centre from its nominal position"),
        Measurand("centre_y", "um", "y of the bore centre from its nominal position"),
        Measurand("radius", "um", "bore radius minus the nominal radius"),
    )


def true_values(setup: Setup, truth: Truth) -> dict:
    return {"centre_x": truth.centre_x_mm, "centre_y": truth.centre_y_mm,
            "radius": truth.radius_deviation_mm}


def _n_contacts(setup: Setup) -> int:
    return setup.n_points + 2  # p1, p2, d1..dn


def sources(setup: Setup) -> dict[str, Source]:
    """Every error source, in internal units (mm, rad, 1)."""
    k = _n_contacts(setup)
    slip = setup.tangential_slip_um_per_deg * 1e-3 / _DEG  # mm per rad
    scale = setup.scale_error_ppm * 1e-6
    sq = setup.squareness_urad * 1e-6
    s = setup.start_scatter_mm
    return {
        "probe_noise": Source(
            Normal(0.0, setup.probe_noise_um * 1e-3), (k,),
            "Trigger noise of the touch probe along the approach, per contact; 0.5 um std is "
            "typical of a kinematic probe on a CNC skip input (makers quote 0.35-1 um 2 sigma "
            "unidirectional repeatability)."),
        "pretravel_variation": Source(
            Normal(0.0, setup.pretravel_variation_um * 1e-3 / math.sqrt(2)), (2,),
            "Coefficients (cos 3b, sin 3b) of the three-lobed pre-travel variation with the "
            "approach direction b, constant during the test (RMS amplitude 1 um: makers quote "
            "+-0.8 to +-2 um XY pre-travel variation for kinematic probes after calibration)."),
        "tangential_slip": Source(
            Rectangular(0.0, 2 * slip), (),
            "Slip of the stylus along the wall per radian of obliqueness of the approach, "
            "uniform between 0 and twice the set mean, constant during the test (assumed "
            "0.2 um/deg: no maker's figure; measure it for the probe in use)."),
        "roundness": Source(
            Normal(0.0, setup.roundness_um * 1e-3 / 2 / math.sqrt(2)), (2,),
            "Coefficients (cos k phi, sin k phi) of the bore's lobed form error, k = lobes; "
            "random orientation, RMS peak-to-valley = roundness_um (5 um: a large turned ring)."),
        "scale_error": Source(
            Rectangular(-scale, scale), (2,),
            "Residual scale (linear positioning) error of the stage's X and Y axes after "
            "compensation; +-5 um/m is typical of ISO 230-2 results of a large stage."),
        "squareness": Source(
            Rectangular(-sq, sq), (),
            "X-Y squareness error of the stage (ISO 230-1; +-10 urad typical)."),
        "stage_repeatability": Source(
            Normal(0.0, setup.stage_repeatability_um * 1e-3), (k, 2),
            "Positioning repeatability of the stage, per reading and axis (ISO 230-2 "
            "unidirectional repeatability of about 1 um = 2 sigma)."),
        "start_scatter": Source(
            Rectangular(-s, s), (2,),
            "Where the operator lowers the probe: uniform within +-25 mm per axis of the "
            "truth's start point (by eye, near the nominal centre)."),
        "tip_radius": Source(
            Normal(0.0, setup.tip_radius_um * 1e-3), (),
            "Error of the calibrated effective tip radius, one per test: every recorded point "
            "lies that far beyond the wall along its approach. 0.5 um std: the radius is "
            "calibrated on a setting ring (ISO 1938-1) known to about 1 um in diameter."),
        **_thermal_sources(setup),
    }


def _thermal_sources(setup: Setup) -> dict[str, Source]:
    """The temperatures' sources, measured or assumed (:mod:`mtplan.models._temperature`: each
    the actual value minus the one the estimators correct with, so zero-mean), and the
    expansion coefficients'."""
    return {
        **temperature.temperature_sources(
            setup, "part_temperature",
            measured="Error of the measured part temperature [K]: the part is at "
            "part_temperature_c plus this, and the estimates are corrected to 20 degC (ISO 1) "
            "with part_temperature_c. Default 0.2 K: a calibrated contact thermometer on a "
            "soaked part (ISO/TR 16015). The bore grows about the part's clamping point by "
            "expansion_ppm_per_k x dT; when the scales' temperature is not measured they "
            "follow the part's.",
            assumed="The part's temperature minus 20 degC [K] when it is not measured, uniform "
            "within +-part_temperature_halfwidth_k (default +-2 K: a workshop held at 20 +- 2 "
            "degC, ISO 1's reference temperature); nothing is corrected. The bore grows about "
            "the clamping point by expansion_ppm_per_k (11.5e-6/K: steel); the scales share "
            "this temperature (plus scale_temperature_halfwidth) and shrink their reading "
            "about their datum by scale_expansion_ppm_per_k (10e-6/K: the coefficient "
            "HEIDENHAIN states for its steel-mounted linear scales), so the radius reads r "
            "(alpha_part - alpha_scale) dT off and the centre alpha_scale dT times its offset "
            "from the scales' datum (a datum 300 mm away: 300 mm x 10e-6/K x 1.15 K = 3.5 "
            "um per axis at the default +-2 K; none with the default datum at the bore)."),
        **temperature.temperature_sources(
            setup, "scale_temperature",
            measured="Error of the measured scale temperature [K]; default 0.2 K. The scales "
            "read every length from their datum times 1 - scale_expansion_ppm_per_k x "
            "dT_scale.",
            assumed="The machine scales' temperature minus the part's [K] when it is not "
            "measured, uniform within +-scale_temperature_halfwidth_k. Default +-1 K: a part "
            "soaked on the machine for hours (ISO/TR 16015 advises soaking until part and "
            "machine agree within a kelvin); a part that arrives from a warmer hall needs "
            "more. The scales read lengths from their datum (scale_datum_x_mm, "
            "scale_datum_y_mm) times 1 - scale_expansion_ppm_per_k x dT_scale: the radius, "
            "and the centre by that strain times its offset from the datum (300 mm x "
            "10e-6/K x 0.58 K = 1.7 um)."),
        "expansion_u": Source(
            Normal(0.0, setup.expansion_u_ppm_per_k * 1e-6), (),
            "Error of the workpiece's expansion coefficient [1/K]: it moves the corrected "
            "result by u(alpha) x (T_part - 20 degC) x the length from the clamping point. "
            "Default 1e-6/K: steels span 10.5-12.5e-6/K (ISO/TR 16015)."),
        "scale_expansion_u": Source(
            Normal(0.0, setup.scale_expansion_u_ppm_per_k * 1e-6), (),
            "Error of the scales' effective expansion coefficient [1/K]: u(alpha) x "
            "(T_scale - 20 degC) x the length from the datum. Default 0.5e-6/K: a scale "
            "mounted on steel follows its mounting (10-11.5e-6/K)."),
    }


def _reference_deviations(setup: Setup) -> tuple[float, float]:
    """The temperatures minus 20 degC [K] of the part and the scales that the estimators
    correct with: the measured ones, 0 where the part is not measured, and the part's
    where the scales are not."""
    dtp = temperature.deviation(setup, "part_temperature")
    return dtp, temperature.deviation(setup, "scale_temperature", default=dtp)


def _thermal(setup: Setup, errors: dict, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The actual thermal strains (n,) of the part (about its clamping point) and of the
    scales (about their datum): alpha (T - 20 degC) with the actual alphas and temperatures."""
    def e(name):
        return np.asarray(errors[name], dtype=float).reshape(n)

    dtp_ref, dts_ref = _reference_deviations(setup)
    dtp = dtp_ref + e("part_temperature_u") + e("part_temperature_halfwidth")
    if setup.scale_temperature_c is None:  # the scales follow the part's actual temperature
        dts = dtp + e("scale_temperature_halfwidth") + e("scale_temperature_u")
    else:
        dts = dts_ref + e("scale_temperature_u") + e("scale_temperature_halfwidth")
    part = (setup.expansion_ppm_per_k * 1e-6 + e("expansion_u")) * dtp
    scale = (setup.scale_expansion_ppm_per_k * 1e-6 + e("scale_expansion_u")) * dts
    return part, scale


def _datum(setup: Setup) -> np.ndarray:
    return np.array([setup.scale_datum_x_mm, setup.scale_datum_y_mm])


def _clamp(setup: Setup) -> np.ndarray:
    return np.array([setup.clamp_x_mm, setup.clamp_y_mm])


def _to_20c(setup: Setup, cx, cy, r) -> tuple:
    """A circle read at the test's temperatures, corrected to 20 degC (ISO 1): the read
    coordinates scaled back about the scales' datum by 1 + alpha_scale dT_scale, then the
    part shrunk about its clamping point by 1 + alpha_part dT_part, with the reference
    temperatures (:func:`_reference_deviations`) and the stated alphas. Exact for a circle
    (both are similarities); the identity where nothing was measured."""
    dtp, dts = _reference_deviations(setup)
    if dtp == 0.0 and dts == 0.0:
        return cx, cy, r
    s = 1.0 + setup.scale_expansion_ppm_per_k * 1e-6 * dts
    g = 1.0 + setup.expansion_ppm_per_k * 1e-6 * dtp
    (dx, dy), (kx, ky) = _datum(setup), _clamp(setup)
    ax, ay = dx + s * (np.asarray(cx) - dx), dy + s * (np.asarray(cy) - dy)
    return kx + (ax - kx) / g, ky + (ay - ky) / g, s * np.asarray(r) / g


# --------------------------------------------------------------------------- geometry
def _wall(setup, truth, errors, n, part_strain):
    """True centre (n,2), radius (n,), form coefficients (n,2), lobes.

    The bore at the test's temperature: the 20 degC bore scaled by ``1 + part_strain``
    about the part's clamping point (its form error is left at its 20 degC size, a
    change of 1e-5 of a few micrometres). Truth fields may be arrays (n,): one truth per
    batch row (a posterior's walkers).
    """
    grow = 1.0 + np.reshape(part_strain, (n, 1))
    k = _clamp(setup)
    centre = k + (np.broadcast_to(_xy_of(truth.centre_x_mm, truth.centre_y_mm), (n, 2)) - k) * grow
    radius = (setup.bore_radius_mm + np.asarray(truth.radius_deviation_mm)) * grow[:, 0]
    form = np.asarray(errors["roundness"], dtype=float).reshape(n, 2)
    return centre, radius, form, setup.lobes


def _contact(origin, direction, centre, radius, form, lobes, iterations: int = 4):
    """Where lines from `origin` along unit `direction` meet the wall (t > 0).

    Parameters
    ----------
    origin, direction : array (n, k, 2)
        Actual (not read) start points and unit directions of the approach lines.
    centre : array (n, 2); radius : array (n,); form : array (n, 2); lobes : int

    Returns
    -------
    contact : array (n, k, 2)
    normal : array (n, k, 2)
        Outward unit normal of the wall at the contact.

    Notes
    -----
    The line meets the circle of the mean radius first (closed form); Newton's method
    on ``g(t) = |q(t) - c| - rho(phi(q(t)))`` then adds the form error, with
    ``g' = e_r . u - rho'(phi) (e_r x u) / |q - c|``. The start is off by at most the
    form amplitude, so four iterations reach machine precision.
    """
    wx = origin[..., 0] - centre[:, None, 0]
    wy = origin[..., 1] - centre[:, None, 1]
    ux, uy = direction[..., 0], direction[..., 1]
    a, b = form[:, 0:1], form[:, 1:2]
    r0 = radius[:, None]
    wu = wx * ux + wy * uy
    t = -wu + np.sqrt(np.maximum(wu * wu - (wx * wx + wy * wy - r0 * r0), 0.0))
    has_form = bool(np.any(form))
    for _ in range(iterations if has_form else 0):
        qx, qy = wx + t * ux, wy + t * uy
        dist = np.hypot(qx, qy)
        phi = np.arctan2(qy, qx)
        ck, sk = np.cos(lobes * phi), np.sin(lobes * phi)
        rho = r0 + a * ck + b * sk
        drho = lobes * (b * ck - a * sk)
        dg = (qx * ux + qy * uy) / dist - drho * (qx * uy - qy * ux) / (dist * dist)
        t = t - (dist - rho) / dg
    qx, qy = wx + t * ux, wy + t * uy
    dist = np.hypot(qx, qy)
    erx, ery = qx / dist, qy / dist
    if has_form:
        phi = np.arctan2(qy, qx)
        ck, sk = np.cos(lobes * phi), np.sin(lobes * phi)
        rho = r0 + a * ck + b * sk
        drho = lobes * (b * ck - a * sk)
        nx, ny = rho * erx + drho * ery, rho * ery - drho * erx  # rho e_r - rho' e_phi
        norm = np.hypot(nx, ny)
        nx, ny = nx / norm, ny / norm
    else:
        nx, ny = erx, ery
    contact = np.stack([qx + centre[:, None, 0], qy + centre[:, None, 1]], axis=-1)
    return contact, np.stack([nx, ny], axis=-1)


def _inside(point, centre, radius, form, lobes):
    """Whether actual points (n, 2) lie strictly inside the wall."""
    q = point - centre
    phi = np.arctan2(q[:, 1], q[:, 0])
    rho = radius + form[:, 0] * np.cos(lobes * phi) + form[:, 1] * np.sin(lobes * phi)
    return np.hypot(q[:, 0], q[:, 1]) < rho


def _plan_core(p1, p2, radius, free_dir, n_points, spread_deg):
    """The patent's planning, batch-first.

    Parameters
    ----------
    p1, p2 : array (n, 2)
        Read coordinates of the -y and +y contacts [mm].
    radius : float
        Nominal bore radius [mm].
    free_dir : array (n,)
        Free direction of motion in x at p2: +1, -1 or 0.

    Returns
    -------
    dict with ``centre`` (n,2), ``theta1``, ``theta2`` (n,) [rad], ``sigma`` (n,)
    (+1 ccw about o, -1 cw: the travel sense from d1 on), ``alpha_p1``,
    ``alpha_p2`` (n,) and ``alpha`` (n, n_points) target angles about the planner's
    centre [rad], and ``step`` [rad].
    """
    h = 0.5 * np.hypot(p2[:, 0] - p1[:, 0], p2[:, 1] - p1[:, 1])
    ratio = np.minimum(h / radius, 1.0)
    theta1 = 2.0 * np.arcsin(ratio)
    off = radius * np.sqrt(np.maximum(1.0 - ratio * ratio, 0.0))
    mid = 0.5 * (p1 + p2)
    centre = np.stack([mid[:, 0] + free_dir * off, mid[:, 1]], axis=-1)
    alpha_p1 = np.arctan2(p1[:, 1] - centre[:, 1], p1[:, 0] - centre[:, 0])
    alpha_p2 = np.arctan2(p2[:, 1] - centre[:, 1], p2[:, 0] - centre[:, 0])
    # centre to the right (+1) or unknown (0): p1, p2 on the left, long way is clockwise
    sigma = np.where(free_dir < 0, 1.0, -1.0)
    if spread_deg >= 360.0:
        step = 2 * math.pi / n_points
    else:
        step = spread_deg * _DEG / (n_points - 1)
    k = np.arange(1, n_points + 1)
    alpha = alpha_p1[:, None] - sigma[:, None] * (n_points - k)[None, :] * step
    theta2 = (2 * math.pi - theta1) - (n_points - 1) * step
    return {"centre": centre, "theta1": theta1, "theta2": theta2, "sigma": sigma,
            "alpha_p1": alpha_p1, "alpha_p2": alpha_p2, "alpha": alpha, "step": step}


def _free_direction(contact_p2, centre, radius, form, lobes, test_mm, mx):
    """+1 / -1 / 0: which of the trial moves +-test_mm (read x) from p2 stays inside."""
    ex = mx / np.linalg.norm(mx, axis=-1, keepdims=True)  # actual direction of read +x
    plus = _inside(contact_p2 + test_mm * ex, centre, radius, form, lobes)
    minus = _inside(contact_p2 - test_mm * ex, centre, radius, form, lobes)
    return np.where(plus & ~minus, 1.0, np.where(minus & ~plus, -1.0, 0.0))


def _probe(setup, errors, contact, normal, direction, idx):
    """Stylus position at trigger (actual frame): contact + (pre-travel + noise + tip-radius
    error) along the approach + slip along the wall."""
    n = contact.shape[0]
    noise = np.asarray(errors["probe_noise"], dtype=float).reshape(n, -1)[:, idx]
    pre = np.asarray(errors["pretravel_variation"], dtype=float).reshape(n, 2)
    tip = np.asarray(errors["tip_radius"], dtype=float).reshape(n, 1)
    ux, uy = direction[..., 0], direction[..., 1]
    nx, ny = normal[..., 0], normal[..., 1]
    # cos 3b, sin 3b of the approach angle b from the unit vector (triple-angle formulas)
    c3 = ux * (4 * ux * ux - 3)
    s3 = uy * (3 - 4 * uy * uy)
    # the controller compensates the stylus centre by the calibrated tip radius along
    # the approach: a radius calibrated too large by `tip` records the point beyond the wall
    along = noise + pre[:, 0:1] * c3 + pre[:, 1:2] * s3 + tip
    # signed angle from the outward normal to the approach; slip along the tangent (-ny, nx)
    slip_c = np.asarray(errors["tangential_slip"], dtype=float).reshape(n, 1)
    slip = slip_c * np.arctan2(nx * uy - ny * ux, nx * ux + ny * uy) if np.any(slip_c) else 0.0
    return np.stack([contact[..., 0] + along * ux - slip * ny,
                     contact[..., 1] + along * uy + slip * nx], axis=-1)


def _stage(errors, n, thermal=0.0):
    """M (n,2,2): actual = M @ read, and its inverse; `thermal` (n,) is the scales' thermal
    strain, added to both axes' scale errors."""
    sc = np.asarray(errors["scale_error"], dtype=float).reshape(n, 2) + np.reshape(thermal,
                                                                                  (-1, 1))
    sq = np.asarray(errors["squareness"], dtype=float).reshape(n)
    m = np.zeros((n, 2, 2))
    m[:, 0, 0] = 1 + sc[:, 0]
    m[:, 0, 1] = sq
    m[:, 1, 1] = 1 + sc[:, 1]
    minv = np.zeros_like(m)
    minv[:, 0, 0] = 1 / m[:, 0, 0]
    minv[:, 1, 1] = 1 / m[:, 1, 1]
    minv[:, 0, 1] = -m[:, 0, 1] / (m[:, 0, 0] * m[:, 1, 1])
    return m, minv


def _xy_of(x, y) -> np.ndarray:
    """Points (2,) or, for arrays (n,) of one truth per batch row, (n, 2)."""
    return np.stack(np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float)),
                    axis=-1)


def _check_start(setup: Setup, truth: Truth) -> None:
    r_true = setup.bore_radius_mm + np.asarray(truth.radius_deviation_mm)
    reach = np.hypot(np.asarray(truth.start_x_mm) - truth.centre_x_mm,
                     np.asarray(truth.start_y_mm) - truth.centre_y_mm)
    reach = reach + setup.start_scatter_mm * math.sqrt(2) + setup.roundness_um * 1e-3 * 4
    bad = ~(reach < r_true - setup.free_test_mm)
    if np.any(bad):
        i = int(np.flatnonzero(np.ravel(bad))[0])

        def first(v):
            return float(np.ravel(v)[i % np.size(v)])

        p = Problems("circle_centre truth")
        p.add_text(
            f"The start point (start_x_mm={first(truth.start_x_mm):g}, start_y_mm="
            f"{first(truth.start_y_mm):g}) with its scatter start_scatter_mm="
            f"{setup.start_scatter_mm:g} reaches {first(reach):g} mm from the true centre, "
            f"outside the bore of radius {first(r_true):g} mm: the probe must start inside the "
            "bore")
        p.raise_if_any()


def forward(setup: Setup, truth: Truth, errors: dict) -> dict:
    """Simulated readings, batch-first (see the module docstring).

    Returns
    -------
    dict
        ``x_mm``, ``y_mm``: arrays (n, n_points), the read coordinates of d1..dn;
        ``p_x_mm``, ``p_y_mm``: arrays (n, 2), the read coordinates of p1 and p2.
    """
    _check_start(setup, truth)
    n = np.asarray(errors["probe_noise"]).shape[0]
    part_strain, scale_strain = _thermal(setup, errors, n)
    centre, radius, form, lobes = _wall(setup, truth, errors, n, part_strain)
    m, minv = _stage(errors, n, scale_strain)
    datum = _datum(setup)
    rep = np.asarray(errors["stage_repeatability"], dtype=float).reshape(n, -1, 2)

    def apply(mat, q):  # (n, 2, 2) @ (n, k, 2), written out: faster than einsum
        x, y = q[..., 0], q[..., 1]
        return np.stack([mat[:, 0, 0, None] * x + mat[:, 0, 1, None] * y,
                         mat[:, 1, 0, None] * x + mat[:, 1, 1, None] * y], axis=-1)

    def to_actual(q):  # read -> actual: the scales grow (and err) about their datum
        return datum + apply(m, q - datum)

    def to_read(q):
        return datum + apply(minv, q - datum)

    start = _xy_of(truth.start_x_mm, truth.start_y_mm) + np.asarray(
        errors["start_scatter"], dtype=float).reshape(n, 2)
    # p1 along -y, p2 along +y (read frame), from the start
    dirs_read = np.broadcast_to(np.array([[0.0, -1.0], [0.0, 1.0]]), (n, 2, 2))
    origin = to_actual(np.broadcast_to(start[:, None, :], (n, 2, 2)))
    dirs = apply(m, dirs_read)  # a direction: no datum
    dirs = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    cp, nrm = _contact(origin, dirs, centre, radius, form, lobes)
    stylus = _probe(setup, errors, cp, nrm, dirs, slice(0, 2))
    p_read = to_read(stylus) + rep[:, 0:2]
    free = _free_direction(cp[:, 1], centre, radius, form, lobes, setup.free_test_mm, m[:, :, 0])
    plan = _plan_core(p_read[:, 0], p_read[:, 1], setup.bore_radius_mm, free,
                      setup.n_points, setup.spread_deg)
    u_read = np.stack([np.cos(plan["alpha"]), np.sin(plan["alpha"])], axis=-1)
    o_read = np.broadcast_to(plan["centre"][:, None, :], u_read.shape)
    origin = to_actual(o_read)
    dirs = apply(m, u_read)
    dirs = dirs / np.linalg.norm(dirs, axis=-1, keepdims=True)
    cd, nrm = _contact(origin, dirs, centre, radius, form, lobes)
    stylus = _probe(setup, errors, cd, nrm, dirs, slice(2, None))
    d_read = to_read(stylus) + rep[:, 2:]
    return {"x_mm": d_read[..., 0], "y_mm": d_read[..., 1],
            "p_x_mm": p_read[..., 0], "p_y_mm": p_read[..., 1]}


# --------------------------------------------------------------------------- estimators
def _xy(readings) -> tuple[np.ndarray, np.ndarray]:
    return (np.asarray(readings["x_mm"], dtype=float), np.asarray(readings["y_mm"], dtype=float))


def _three_indices(n: int, spread_deg: float) -> list[int]:
    if spread_deg >= 360.0:
        return [0, n // 3, (2 * n) // 3]
    return [0, (n - 1) // 2, n - 1]


def _result(circle, setup: Setup) -> dict:
    """The measurands of a circle fitted to read points, corrected to 20 degC."""
    cx, cy, r = _to_20c(setup, circle.xc, circle.yc, circle.r)
    return {"centre_x": np.asarray(cx), "centre_y": np.asarray(cy),
            "radius": np.asarray(r) - setup.bore_radius_mm}


def estimate_three_point(setup: Setup, readings: dict) -> dict:
    """The patent's a..f formula on d1, d2, d3 (or the best-spread triple of n points)."""
    x, y = _xy(readings)
    idx = _three_indices(x.shape[-1], setup.spread_deg)
    return _result(three_point_circle(x[..., idx], y[..., idx]), setup)


def estimate_kasa(setup: Setup, readings: dict) -> dict:
    """Algebraic (Kasa) least-squares circle through all measuring points."""
    x, y = _xy(readings)
    return _result(kasa_fit(x, y), setup)


def estimate_geometric(setup: Setup, readings: dict) -> dict:
    """Orthogonal-distance least-squares circle through all measuring points."""
    x, y = _xy(readings)
    return _result(geometric_fit(x, y), setup)


def _contacts(readings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every contact (..., m, 2) with its approach direction (..., m, 2) (NaN: radial): p1
    (along -y) and p2 (along +y) where the readings hold them, then d1..dn; and a mask (...)
    of the rows that hold p1, p2."""
    x, y = _xy(readings)
    d = np.stack([x, y], axis=-1)
    p = np.stack(np.broadcast_arrays(np.asarray(readings["p_x_mm"], dtype=float),
                                     np.asarray(readings["p_y_mm"], dtype=float)), axis=-1)
    p = np.broadcast_to(p, d.shape[:-2] + (2, 2))
    has_p = np.all(np.isfinite(p), axis=(-2, -1))
    pts = np.concatenate([p, d], axis=-2)
    approach = np.full(pts.shape, np.nan)
    approach[..., 0, :] = (0.0, -1.0)
    approach[..., 1, :] = (0.0, 1.0)
    return pts, approach, has_p


def _radial_covariance(setup: Setup, u, approach, radius, centre) -> np.ndarray:
    """Covariance (..., m, m) of the contacts' radial errors under the set-up's error budget.

    The linearised physics of :func:`forward` along each contact's outward unit radial
    `u` (..., m, 2), for a contact approached along `approach` (the radial where NaN), on
    the circle of `radius` (...) about `centre` (..., 2): probe noise and tip-radius error
    along the approach, the pre-travel's three lobes of the approach direction, the stage's
    repeatability (isotropic), scale and squareness errors (read = M^-1 actual, about the
    scales' datum), the bore's lobed form, and the temperatures and expansion coefficients
    (the part grows about its clamping point, the scales about their datum). Tangential
    slip moves contacts along the wall and start scatter moves the path: neither changes a
    contact's distance from the centre to first order.
    """
    src = sources(setup)
    sd = {k: np.asarray(v.distribution.std, dtype=float).reshape(-1)[0] for k, v in src.items()}
    a = np.where(np.isnan(approach), u, approach)
    cos_au = np.sum(a * u, axis=-1)
    c3, s3 = a[..., 0] * (4 * a[..., 0] ** 2 - 3), a[..., 1] * (3 - 4 * a[..., 1] ** 2)
    phi = np.arctan2(u[..., 1], u[..., 0])
    k = setup.lobes
    pts = np.asarray(centre)[..., None, :] + radius[..., None, None] * u
    from_datum = pts - _datum(setup)
    from_clamp = np.sum((pts - _clamp(setup)) * u, axis=-1)  # radial growth per unit strain
    along_datum = np.sum(from_datum * u, axis=-1)
    alpha_p = setup.expansion_ppm_per_k * 1e-6
    alpha_s = setup.scale_expansion_ppm_per_k * 1e-6
    dtp, dts = _reference_deviations(setup)
    sd_p = math.hypot(sd["part_temperature_u"], sd["part_temperature_halfwidth"])
    sd_s = math.hypot(sd["scale_temperature_u"], sd["scale_temperature_halfwidth"])
    follow = 1.0 if setup.scale_temperature_c is None else 0.0  # scales follow the part
    cols = [sd["pretravel_variation"] * c3 * cos_au, sd["pretravel_variation"] * s3 * cos_au,
            sd["tip_radius"] * cos_au,
            sd["roundness"] * np.cos(k * phi), sd["roundness"] * np.sin(k * phi),
            sd["scale_error"] * from_datum[..., 0] * u[..., 0],
            sd["scale_error"] * from_datum[..., 1] * u[..., 1],
            sd["squareness"] * from_datum[..., 1] * u[..., 0],
            sd_p * (alpha_p * from_clamp - follow * alpha_s * along_datum),
            sd_s * alpha_s * along_datum,
            sd["expansion_u"] * dtp * from_clamp,
            sd["scale_expansion_u"] * dts * along_datum]
    v = np.stack(cols, axis=-1)
    diag = (sd["probe_noise"] * cos_au) ** 2 + sd["stage_repeatability"] ** 2
    cov = v @ np.swapaxes(v, -1, -2)
    idx = np.arange(u.shape[-2])
    cov[..., idx, idx] += diag
    return cov


def estimate_gls(setup: Setup, readings: dict, iterations: int = 4) -> dict:
    """Circle through every contact, weighted by the set-up's error budget (generalised
    least squares of the radial residuals).

    Uses the path planner's p1 and p2 too where the readings hold them (a bare point file
    has d1..dn only): they are wall points, probed along -y and +y, and their chord's
    midpoint lies on the bore's centre line; the patent uses them only to plan the path.
    The residuals ``e_i = |p_i - c| - r`` are weighted by the inverse of their covariance
    under every error source of the set-up (:func:`_radial_covariance`, per trial, since
    the contacts' angles follow the start point): the bore's lobed form, the pre-travel
    lobes, the stage's scale and squareness act on several contacts at once, so an
    unweighted fit is not the best one. Gauss-Newton on the whole batch from the
    orthogonal-distance fit (:func:`mtplan.fitting.gls_step`); the weights are taken at
    each iterate.
    """
    pts, approach, has_p = _contacts(readings)
    if not np.all(has_p):  # rows without p1, p2: their measuring points alone
        pts = np.where(has_p[..., None, None], pts, np.concatenate(
            [pts[..., 2:3, :], pts[..., 2:3, :], pts[..., 2:, :]], axis=-2))
        approach = np.where(has_p[..., None, None], approach, np.nan)
    circle = geometric_fit(pts[..., 0], pts[..., 1])
    c = np.stack([circle.xc, circle.yc], axis=-1)
    r = np.asarray(circle.r, dtype=float)
    # a row without p1, p2 repeats d1 in their place: weight them out (no information)
    dup = np.broadcast_to(~has_p[..., None], r.shape + (2,))
    for _ in range(iterations):
        diff = pts - c[..., None, :]
        dist = np.linalg.norm(diff, axis=-1)
        u = diff / dist[..., None]
        e = dist - r[..., None]
        cov = _radial_covariance(setup, u, approach, r, c)
        big = 1e6 * np.max(np.diagonal(cov, axis1=-2, axis2=-1), axis=-1)
        cov[..., 0, 0] += np.where(dup[..., 0], big, 0.0)
        cov[..., 1, 1] += np.where(dup[..., 1], big, 0.0)
        jac = np.concatenate([-u, -np.ones(e.shape + (1,))], axis=-1)  # d e / d(xc, yc, r)
        step, _ = gls_step(jac, -e, cov)
        c = c + step[..., :2]
        r = r + step[..., 2]
    cx, cy, r = _to_20c(setup, c[..., 0], c[..., 1], r)
    return {"centre_x": cx, "centre_y": cy, "radius": r - setup.bore_radius_mm}


ESTIMATORS = {"three_point": estimate_three_point, "kasa": estimate_kasa,
              "geometric": estimate_geometric, "gls": estimate_gls}
#: each estimator as the documents describe it (plain words, jargon spelled out)
_DESCRIPTIONS = {
    "three_point": "The source method's three-point formula on the three probed distances (with "
                   "more points, the triple spread best).",
    "kasa": "Algebraic least-squares circle (Kasa fit) through all measuring points.",
    "geometric": "Geometric least-squares circle (orthogonal distances) through all measuring "
                 "points.",
    "gls": "Circle through every contact, weighted by the set-up's error budget (generalised "
           "least squares, GLS, of the radial residuals).",
}


def fit_points(x_mm, y_mm, estimator: str = "geometric") -> dict:
    """Centre and radius of measured points, for ``mtplan estimate circle_centre``.

    Parameters
    ----------
    x_mm, y_mm : array_like (m,)
        Coordinates of the points on the bore wall [mm], at least 3 (exactly the three
        used points for ``three_point``: with more, the best-spread triple of a full
        circle, indices 0, m//3, 2m//3, is used, as in the simulation).
    estimator : {'geometric', 'kasa', 'three_point'}

    Returns
    -------
    dict
        ``centre_x_mm``, ``centre_y_mm``, ``radius_mm`` (floats).
    """
    p = Problems("fit_points")
    p.choice("estimator", estimator, ("geometric", "kasa", "three_point"))
    x = np.asarray(x_mm, dtype=float)
    y = np.asarray(y_mm, dtype=float)
    if x.ndim != 1 or x.shape != y.shape:
        p.add("x_mm", x.shape, f"a 1-D array of the same length as y_mm {y.shape}")
    elif x.size < 3:
        p.add("x_mm", x.size, "at least 3 points")
    elif not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        bad = np.flatnonzero(~(np.isfinite(x) & np.isfinite(y)))
        p.add_text(f"The points of fit_points must be finite numbers; rows {bad.tolist()} are not")
    p.raise_if_any()
    if estimator == "three_point":
        c = three_point_circle(x[None, _three_indices(x.size, 360.0)],
                               y[None, _three_indices(x.size, 360.0)])
    elif estimator == "kasa":
        c = kasa_fit(x[None], y[None])
    else:
        c = geometric_fit(x[None], y[None])
    out = {"centre_x_mm": float(c.xc[0]), "centre_y_mm": float(c.yc[0]),
           "radius_mm": float(c.r[0])}
    if not all(math.isfinite(v) for v in out.values()):
        raise InvalidInput(["The points of fit_points are collinear: no circle passes through "
                            "them."])
    return out


# --------------------------------------------------------------------------- path plan
@dataclass(frozen=True)
class Segment:
    """One move of the planned path, in read coordinates [mm].

    ``kind`` is ``'line'`` or ``'arc'``; for an arc, ``centre`` and ``radius`` are the
    helper circle's and ``ccw`` its turning sense about that centre.
    """

    kind: str
    start: tuple
    end: tuple
    centre: tuple | None = None
    radius: float | None = None
    ccw: bool | None = None
    probing: bool = False

    @property
    def length(self) -> float:
        if self.kind == "line":
            return math.dist(self.start, self.end)
        a0 = math.atan2(self.start[1] - self.centre[1], self.start[0] - self.centre[0])
        a1 = math.atan2(self.end[1] - self.centre[1], self.end[0] - self.centre[0])
        turn = (a1 - a0) % (2 * math.pi) if self.ccw else (a0 - a1) % (2 * math.pi)
        return self.radius * turn

    def polyline(self, samples: int = 64) -> np.ndarray:
        """Points along the segment, array (samples, 2), for drawing."""
        if self.kind == "line":
            t = np.linspace(0, 1, samples)[:, None]
            return (1 - t) * np.asarray(self.start) + t * np.asarray(self.end)
        a0 = math.atan2(self.start[1] - self.centre[1], self.start[0] - self.centre[0])
        turn = self.length / self.radius if self.radius > 0 else 0.0
        a = a0 + (1 if self.ccw else -1) * np.linspace(0, turn, samples)
        return np.column_stack([self.centre[0] + self.radius * np.cos(a),
                                self.centre[1] + self.radius * np.sin(a)])


@dataclass(frozen=True)
class PathPlan:
    """The planned probing path of one measurement (read coordinates, mm, degrees).

    Attributes
    ----------
    start, p1, p2 : tuple (x, y)
    centre : tuple (x, y)
        The planner's centre from p1, p2, the nominal radius and the free direction.
    bore_radius_mm : float
    free_direction : int
        +1, -1 or 0: which way (x) the probe could move at p2.
    theta1_deg, theta2_deg : float
        Angle p1-o-p2, and angle from o-p2 to o-d1 along the travel.
    case : int
        The patent's case 1..4 of the first rotation.
    first_rotation, later_rotation : str
        'ccw' or 'cw' about the helper circles o1 and o2, o3, ...
    targets : array (n_points, 2)
        Planned d1..dn on the nominal circle about the planner's centre.
    target_angles_deg : array (n_points,)
    helper_circles : tuple of (centre, radius)
        o1, o2, ... (a radial transfer has none).
    segments : tuple of Segment
        start -> p1 -> p2 -> d1 -> ... -> dn.
    miss_mm : tuple (dx, dy)
        The patent's |x_p1 - x_dn|, |y_p1 - y_dn| for the planned d_n.
    """

    start: tuple
    p1: tuple
    p2: tuple
    centre: tuple
    bore_radius_mm: float
    free_direction: int
    theta1_deg: float
    theta2_deg: float
    case: int
    first_rotation: str
    later_rotation: str
    targets: np.ndarray
    target_angles_deg: np.ndarray
    helper_circles: tuple
    segments: tuple = field(default=())
    miss_mm: tuple = (0.0, 0.0)

    @property
    def length_mm(self) -> float:
        """Total path length [mm]."""
        return float(sum(s.length for s in self.segments))

    def polyline(self, samples: int = 64) -> np.ndarray:
        """The whole path as points, array (m, 2), for drawing."""
        return np.concatenate([s.polyline(samples) for s in self.segments])


def _seed_case(theta2: float, free_dir: int) -> tuple[int, str]:
    """The patent's four cases of the first rotation about o1."""
    if theta2 >= 0:
        return (1, "ccw") if free_dir >= 0 else (2, "cw")
    return (3, "cw") if free_dir >= 0 else (4, "ccw")


def _leg(o, radius, a0, a1) -> tuple[Segment, ...]:
    """Move along the wall from angle a0 to a1 (signed turn a1 - a0 about o)."""
    theta = a1 - a0
    s = (o[0] + radius * math.cos(a0), o[1] + radius * math.sin(a0))
    e = (o[0] + radius * math.cos(a1), o[1] + radius * math.sin(a1))
    if abs(theta) > _MAX_ARC:
        return (Segment("line", s, tuple(o)), Segment("line", tuple(o), e, probing=True))
    if theta == 0:
        return (Segment("line", s, e, probing=True),)
    mid = 0.5 * (a0 + a1)
    dist = radius / math.cos(theta / 2)
    c = (o[0] + dist * math.cos(mid), o[1] + dist * math.sin(mid))
    return (Segment("arc", s, e, c, radius * abs(math.tan(theta / 2)), ccw=theta < 0,
                    probing=True),)


def _check_plan_inputs(p: Problems, name, value, *, length=2):
    arr = np.asarray(value, dtype=float) if _numeric(value) else None
    if arr is None or arr.shape != (length,) or not np.all(np.isfinite(arr)):
        p.add(name, value, "a pair of finite numbers (x, y) [mm]")
        return None
    return arr


def _numeric(value) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def plan_path(p1, p2, bore_radius_mm: float, free_direction: int, *, n_points: int = 3,
              spread_deg: float = 360.0, start=None) -> PathPlan:
    """The patent's path from the two y contacts (one measurement).

    Parameters
    ----------
    p1, p2 : (x, y) [mm]
        Read contacts along -y and +y.
    bore_radius_mm : float
        Nominal bore radius [mm], > 0.
    free_direction : {1, -1, 0}
        Which way in x the probe is free to move at p2 (0: neither).
    n_points : int, >= 3
    spread_deg : float in [1, 360]
    start : (x, y), optional
        The start point, drawn as the first segment.

    Returns
    -------
    PathPlan
    """
    p = Problems("plan_path")
    a1 = _check_plan_inputs(p, "p1", p1)
    a2 = _check_plan_inputs(p, "p2", p2)
    p.number("bore_radius_mm", bore_radius_mm, low=0, low_open=True)
    p.choice("free_direction", free_direction, (1, -1, 0))
    p.number("n_points", n_points, integer=True, low=3)
    p.number("spread_deg", spread_deg, low=1, high=360)
    st = _check_plan_inputs(p, "start", start) if start is not None else None
    p.raise_if_any()
    if np.hypot(*(a2 - a1)) > 2 * bore_radius_mm * (1 + 1e-6):
        p.add_text(f"p1 and p2 of plan_path are {np.hypot(*(a2 - a1)):g} mm apart, more than the "
                   f"bore's diameter 2 x bore_radius_mm = {2 * bore_radius_mm:g} mm")
    p.raise_if_any()
    core = _plan_core(a1[None], a2[None], float(bore_radius_mm),
                      np.array([float(free_direction)]), int(n_points), float(spread_deg))
    o = core["centre"][0]
    r = float(bore_radius_mm)
    sigma = float(core["sigma"][0])
    theta2 = float(core["theta2"][0])
    alpha = core["alpha"][0]
    targets = np.column_stack([o[0] + r * np.cos(alpha), o[1] + r * np.sin(alpha)])
    case, first = _seed_case(theta2, int(free_direction))
    segs = []
    if st is not None:
        segs.append(Segment("line", tuple(st), tuple(a1), probing=True))
    segs.append(Segment("line", tuple(a1), tuple(a2), probing=True))
    a_p2 = float(core["alpha_p2"][0])
    first_leg = _leg(o, r, a_p2, a_p2 + sigma * theta2)
    # the planner's circle passes through p2 only up to its noise: start from p2 itself
    s0 = first_leg[0]
    first_leg = (Segment(s0.kind, tuple(a2), s0.end, s0.centre, s0.radius, s0.ccw,
                         s0.probing),) + first_leg[1:]
    segs += first_leg
    helpers = [(s.centre, s.radius) for s in first_leg if s.kind == "arc"]
    a_prev = a_p2 + sigma * theta2  # d1, unwrapped so that each leg turns the right way
    step = sigma * float(core["step"])
    for _ in range(1, int(n_points)):
        leg = _leg(o, r, a_prev, a_prev + step)
        segs += leg
        helpers += [(s.centre, s.radius) for s in leg if s.kind == "arc"]
        a_prev += step
    later = "cw" if sigma > 0 else "ccw"
    miss = acceptance_check(a1, targets[-1], math.inf)
    return PathPlan(
        start=tuple(st) if st is not None else tuple(0.5 * (a1 + a2)),
        p1=tuple(a1), p2=tuple(a2), centre=tuple(o), bore_radius_mm=r,
        free_direction=int(free_direction),
        theta1_deg=float(core["theta1"][0]) / _DEG, theta2_deg=theta2 / _DEG,
        case=case, first_rotation=first, later_rotation=later,
        targets=targets, target_angles_deg=np.degrees(alpha),
        helper_circles=tuple(helpers), segments=tuple(segs),
        miss_mm=(miss["dx_mm"], miss["dy_mm"]),
    )


def plan_for_bore(start, *, bore_radius_mm: float, centre=(0.0, 0.0), n_points: int = 3,
                  spread_deg: float = 360.0, free_test_mm: float = 0.01) -> PathPlan:
    """The planned path for a round bore without errors, from a start point.

    Parameters
    ----------
    start : (x, y) [mm]
        Where the probe is lowered; must lie inside the bore.
    bore_radius_mm : float
        Radius of the (round) bore [mm], > 0; the planner uses it as nominal.
    centre : (x, y) [mm]
        The bore's true centre.
    n_points, spread_deg : as for :func:`plan_path`
    free_test_mm : float
        Trial displacement at p2 [mm].

    Returns
    -------
    PathPlan
    """
    p = Problems("plan_for_bore")
    st = _check_plan_inputs(p, "start", start)
    c = _check_plan_inputs(p, "centre", centre)
    ok_r = p.number("bore_radius_mm", bore_radius_mm, low=0, low_open=True)
    p.number("free_test_mm", free_test_mm, low=0, low_open=True)
    p.raise_if_any()
    if ok_r and np.hypot(*(st - c)) >= bore_radius_mm:
        p.add("start", tuple(st), f"a point inside the bore (less than bore_radius_mm="
              f"{bore_radius_mm:g} mm from its centre {tuple(c)}; it is "
              f"{np.hypot(*(st - c)):g} mm away)")
    p.raise_if_any()
    dx = st[0] - c[0]
    h = math.sqrt(bore_radius_mm**2 - dx * dx)
    p1 = (st[0], c[1] - h)
    p2 = (st[0], c[1] + h)
    # free when the displaced p2 stays inside: 2 d (x2 - xc) + d^2 < 0 for d = +-test
    plus = 2 * free_test_mm * dx + free_test_mm**2 < 0
    minus = -2 * free_test_mm * dx + free_test_mm**2 < 0
    free = 1 if plus and not minus else (-1 if minus and not plus else 0)
    return plan_path(p1, p2, bore_radius_mm, free, n_points=n_points, spread_deg=spread_deg,
                     start=tuple(st))


def acceptance_check(p1, d_last, tolerance_mm: float) -> dict:
    """The patent's acceptance of the last point: ``|x_p1 - x_dn|``, ``|y_p1 - y_dn|``.

    Parameters
    ----------
    p1, d_last : array (..., 2) [mm]
        The first -y contact and the last measuring point (batch-first allowed).
    tolerance_mm : float
        Largest accepted miss per axis [mm].

    Returns
    -------
    dict
        ``dx_mm``, ``dy_mm`` (arrays or floats) and ``accepted`` (bool array or bool).
        The patent's second difference reads ``|y_p1 - x_d3|``, a typo for
        ``|y_p1 - y_d3|``, which is used here.
    """
    a = np.asarray(p1, dtype=float)
    b = np.asarray(d_last, dtype=float)
    dx = np.abs(a[..., 0] - b[..., 0])
    dy = np.abs(a[..., 1] - b[..., 1])
    acc = (dx <= tolerance_mm) & (dy <= tolerance_mm)
    if dx.ndim == 0:
        return {"dx_mm": float(dx), "dy_mm": float(dy), "accepted": bool(acc)}
    return {"dx_mm": dx, "dy_mm": dy, "accepted": acc}


def miss(setup: Setup, readings: dict) -> dict:
    """The acceptance check of simulated or measured readings (batch-first)."""
    p1 = np.stack([np.asarray(readings["p_x_mm"])[:, 0], np.asarray(readings["p_y_mm"])[:, 0]],
                  axis=-1)
    dn = np.stack([np.asarray(readings["x_mm"])[:, -1], np.asarray(readings["y_mm"])[:, -1]],
                  axis=-1)
    return acceptance_check(p1, dn, setup.miss_tolerance_mm)


# --------------------------------------------------------------------------- duration, I/O
def duration(setup: Setup) -> float:
    """Machine time [s]: path length at the feed, the last clearance of each contact at the
    probing feed, a dwell per contact. The path is averaged over nine start points
    (the centre of the scatter square, its corners and edge mid-points) about the
    nominal centre of a nominal bore.
    """
    s = setup.start_scatter_mm
    r = setup.bore_radius_mm
    lengths = []
    for fx in (-1, 0, 1):
        for fy in (-1, 0, 1):
            plan = plan_for_bore((fx * s, fy * s), bore_radius_mm=r, n_points=setup.n_points,
                                 spread_deg=setup.spread_deg, free_test_mm=setup.free_test_mm)
            lengths.append(plan.length_mm)
    contacts = _n_contacts(setup)
    move = float(np.mean(lengths)) - contacts * setup.clearance_mm
    t = max(move, 0.0) / (setup.feed_mm_min / 60.0)
    t += contacts * (setup.clearance_mm / (setup.probe_feed_mm_min / 60.0) + setup.dwell_s)
    return float(t)


def _labels(n_points: int) -> list[str]:
    return ["p1", "p2"] + [f"d{k}" for k in range(1, n_points + 1)]


def readings_frame(setup: Setup, readings: dict) -> pd.DataFrame:
    """One measurement as a tidy frame: columns ``point`` (p1, p2, d1..dn), ``x_mm``, ``y_mm``."""
    import pandas as pd

    px = np.asarray(readings["p_x_mm"], dtype=float)[0]
    py = np.asarray(readings["p_y_mm"], dtype=float)[0]
    x = np.asarray(readings["x_mm"], dtype=float)[0]
    y = np.asarray(readings["y_mm"], dtype=float)[0]
    return pd.DataFrame({"point": _labels(x.size), "x_mm": np.concatenate([px, x]),
                         "y_mm": np.concatenate([py, y])})


def from_frame(setup: Setup, df: pd.DataFrame) -> dict:
    """Readings (batch of one) from a frame with columns ``point``, ``x_mm``, ``y_mm``.

    ``point`` names p1, p2 and d1..dn (n = ``n_points``) in any order. Without a
    ``point`` column every row is a measuring point d1..dn in order, and p1, p2 (which
    only the acceptance check uses) are taken as unknown (NaN).
    """
    import pandas as pd

    p = Problems("circle_centre data")
    for col in ("x_mm", "y_mm"):
        if col not in df.columns:
            p.add_text(f"The circle_centre data must have a column {col!r}; its columns are "
                       f"{', '.join(map(str, df.columns))}")
    p.raise_if_any()
    xs = pd.to_numeric(df["x_mm"], errors="coerce").to_numpy(dtype=float)
    ys = pd.to_numeric(df["y_mm"], errors="coerce").to_numpy(dtype=float)
    bad = np.flatnonzero(~(np.isfinite(xs) & np.isfinite(ys)))
    if bad.size:
        p.add_text(f"The columns 'x_mm' and 'y_mm' of the circle_centre data must hold finite "
                   f"numbers; rows {bad.tolist()} do not")
    n = setup.n_points
    if "point" in df.columns:
        names = df["point"].astype(str).str.strip().tolist()
        want = _labels(n)
        missing = [w for w in want if w not in names]
        extra = [w for w in names if w not in want]
        dup = sorted({w for w in names if names.count(w) > 1})
        if missing or extra or dup:
            p.add_text(f"The 'point' column of the circle_centre data must name p1, p2 and d1..d{n} "
                       f"once each (n_points={n}); missing {missing}, unknown {extra}, "
                       f"repeated {dup}")
        p.raise_if_any()
        order = [names.index(w) for w in want]
        px, py = xs[order[:2]], ys[order[:2]]
        x, y = xs[order[2:]], ys[order[2:]]
    else:
        if len(xs) != n:
            p.add_text(f"The circle_centre data must have n_points={n} rows of measuring points "
                       f"(or a 'point' column naming p1, p2, d1..d{n}); it has {len(xs)}")
        p.raise_if_any()
        px = py = np.full(2, np.nan)
        x, y = xs, ys
    return {"x_mm": x[None, :], "y_mm": y[None, :], "p_x_mm": px[None, :],
            "p_y_mm": py[None, :]}


def truth_from_estimate(setup: Setup, estimate: dict) -> Truth:
    """The Truth whose centre and radius equal `estimate` [mm]; the nominal start point is
    put at that centre (where an operator lowers the probe), so it lies inside the bore."""
    def first(v):
        return float(np.asarray(v).ravel()[0])

    cx, cy = first(estimate["centre_x"]), first(estimate["centre_y"])
    return Truth(centre_x_mm=cx, centre_y_mm=cy, radius_deviation_mm=first(estimate["radius"]),
                 start_x_mm=cx, start_y_mm=cy)


def start_from_readings(setup: Setup, readings: dict, truth: Truth) -> Truth:
    """`truth` with its start point's x where the readings put it: p1 and p2 are probed
    along -y and +y from the start, so their read x is the start's (the start's y moves no
    reading and stays). A least squares started from the bore's centre instead starts
    where the planner's free direction is undefined (p2 at the top of the bore), on another
    branch of the planned path than the readings', and can run away from there."""
    px = np.asarray(readings.get("p_x_mm", np.nan), dtype=float).reshape(-1)
    px = px[np.isfinite(px)]
    if px.size == 0:
        return truth
    return dataclasses.replace(truth, start_x_mm=float(np.mean(px)))


def report_extras(setup: Setup, truth: Truth) -> dict:
    """The planned probing path of the nominal measurement, as data for the report's figure.

    Start point at the truth's start, a round bore at the truth's centre; the figure draws
    the bore, the helper circles, the path and the points p1, p2, d1..dn.
    """
    plan = plan_for_bore((truth.start_x_mm, truth.start_y_mm), bore_radius_mm=setup.bore_radius_mm,
                         centre=(truth.centre_x_mm, truth.centre_y_mm), n_points=setup.n_points,
                         spread_deg=setup.spread_deg, free_test_mm=setup.free_test_mm)
    points = {"start": plan.start, "p1": plan.p1, "p2": plan.p2}
    points.update({f"d{i + 1}": tuple(map(float, t)) for i, t in enumerate(plan.targets)})
    circles = [(truth.centre_x_mm, truth.centre_y_mm, setup.bore_radius_mm, "")]
    circles += [(float(c[0]), float(c[1]), float(r), f"o{i + 1}")
                for i, (c, r) in enumerate(plan.helper_circles)]
    return {"path": {
        "caption": (f"Planned probing path (patent's case {plan.case}, first rotation "
                    f"{plan.first_rotation}, path length {plan.length_mm:.0f} mm): start, the "
                    "two y contacts p1 and p2, then the measuring points d1..dn reached on "
                    "helper arcs tangent to the radii (dashed: bore and helper circles)."),
        "polylines": [plan.polyline()],
        "points": points,
        "circles": circles,
        "view": (truth.centre_x_mm, truth.centre_y_mm, 1.25 * setup.bore_radius_mm),
    }}


# --------------------------------------------------------------------------- set-up from a file
#: the random sources besides the probe's noise; a user who states any of them has set up
#: the noise budget, and the points' scatter no longer raises the probe noise's default
_SCATTER_FIELDS = ("probe_noise_um", "pretravel_variation_um", "roundness_um",
                   "stage_repeatability_um")


def setup_from_frame(df: pd.DataFrame) -> dict:
    """The set-up fields a measured table of bore points determines (see ``Implied``).

    From the measuring points (the ``d`` rows, or every row of a bare point file): their
    number (``n_points``); the nominal radius as the radius of their geometric
    (ISO 12181) circle, agreeing within 5 % of it plus three times the points' scatter
    about it (the ``radius`` measurand is then relative to it: state the drawing's
    radius to measure the deviation from that); the arc they cover (``spread_deg``, 360
    when no gap between neighbours exceeds 1.25 times the even spacing), within 10 %
    plus 2 deg. The bore bounds the fields the set-up requires to fit in it (start
    scatter, clearance, trial displacement, form error; taken at the low end of the
    radius's tolerance). With more than three points, their scatter about the circle
    ``s = sqrt(SSR / (n - 3))`` bounds the probe's noise from below, softly: a default
    whose random sources are too small to give that scatter at 99.9 % confidence is
    raised so that they give ``s``.
    """
    import pandas as pd

    from scipy import special

    from mtplan.models.protocol import Implied

    x = pd.to_numeric(df["x_mm"], errors="coerce").to_numpy(dtype=float)
    y = pd.to_numeric(df["y_mm"], errors="coerce").to_numpy(dtype=float)
    if "point" in df.columns:
        labels = df["point"].astype(str).str.strip()
        keep = labels.str.fullmatch(r"d[1-9][0-9]*").to_numpy()
        x, y = x[keep], y[keep]
    n = x.size
    out = {"n_points": Implied(n, why=f"the file's {n} measuring points")}
    if n < 3 or not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        return out  # from_frame names what is wrong
    try:
        c = geometric_fit(x[None], y[None])
        r = float(c.r[0])
    except np.linalg.LinAlgError:  # collinear points: Kasa's start is singular
        r = math.inf
    span = max(float(np.ptp(x)), float(np.ptp(y)))
    if not (math.isfinite(r) and 0 < r < 1e4 * span):
        raise InvalidInput(["The measuring points lie on a straight line (their circle's "
                            "radius is over 10^4 times their extent): no bore passes through "
                            "them."])
    resid = np.hypot(x - float(c.xc[0]), y - float(c.yc[0])) - r
    s = math.sqrt(float(resid @ resid) / (n - 3)) if n > 3 else 0.0
    tol = 0.05 * r + 3 * s
    out["bore_radius_mm"] = Implied(r, tol, why=f"the geometric circle through the {n} points")
    phi = np.sort(np.mod(np.degrees(np.arctan2(y - float(c.yc[0]), x - float(c.xc[0]))), 360))
    gap = float(np.max(np.diff(np.concatenate([phi, phi[:1] + 360]))))
    spread = 360.0 if gap <= 1.25 * 360.0 / n else 360.0 - gap
    out["spread_deg"] = Implied(spread, 0.1 * spread + 2.0, why="the arc the points cover")
    r_low = max(r - tol, 0.5 * r)
    bounds = (("start_scatter_mm", 0.999 * 0.5 * r_low / math.sqrt(2), "the start within half "
               "the bore radius"), ("clearance_mm", 0.5 * r_low, "within the bore"),
              ("free_test_mm", 0.05 * r_low, "a small part of the bore radius"),
              ("roundness_um", 25.0 * r_low, "a small part of the bore radius"))
    for name, value, why in bounds:
        out[name] = Implied(value, bound="max", why=f"{why}, r >= {r_low:.4g} mm")
    if n > 3:
        d = Setup()
        other = ((d.stage_repeatability_um * 1e-3) ** 2 + (d.pretravel_variation_um * 1e-3) ** 2 / 2
                 + (d.roundness_um * 1e-3 / (2 * math.sqrt(2))) ** 2)
        s_low = s * math.sqrt((n - 3) / (2 * special.gammaincinv((n - 3) / 2, 0.999)))
        need = math.sqrt(max(s * s - other, 0.0)) * 1e3
        need_low = math.sqrt(max(s_low * s_low - other, 0.0)) * 1e3
        high = next(f.metadata["high"] for f in dataclasses.fields(Setup)
                    if f.name == "probe_noise_um")
        out["probe_noise_um"] = Implied(
            min(need, high), need - need_low, bound="min", soft=True,
            unless_given=_SCATTER_FIELDS,
            why=f"the points scatter by {s * 1e3:.3g} um rms about their circle")
    return out


PROCEDURE = Procedure(
    name="circle_centre",
    title="Bore centre by three probed points in equilateral distribution",
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
        "A touch probe, lowered anywhere into a bore of known nominal radius, probes -y and "
        "+y, plans three points 120 deg apart reached on helper arcs tangent to the radii, "
        "and computes the centre from them (circle-centre patent). Compares the three-point formula with "
        "algebraic and geometric least-squares circles through n points over any spread."
    ),
    levers=tuple("n_points spread_deg free_test_mm miss_tolerance_mm feed_mm_min "
                 "probe_feed_mm_min clearance_mm dwell_s".split()),
    readings=ReadingsFormat(readings_frame, from_frame, setup_from_frame=setup_from_frame,
                            optional_columns=("point",), noise_source="probe_noise"),
    capabilities=Capabilities(block_size=2000, truth_from_estimate=truth_from_estimate,
                              start_from_readings=start_from_readings,
                              report_extras=report_extras),
)
