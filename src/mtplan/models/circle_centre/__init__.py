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
  which real scales grow) by ``alpha_scale dT_scale`` and read lengths from the datum that
  much short; the stage's scale and squareness errors act about the same datum (``actual =
  D + M (read - D)``). A measured temperature (``part_temperature_c``,
  ``scale_temperature_c``) is corrected for by every estimator
  (:func:`._estimators._to_20c`, exact for a circle), leaving its thermometer's error
  (``*_temperature_u``) and the expansion coefficients' (``expansion_u``,
  ``scale_expansion_u``) as sources; one not measured is a zero-mean rectangular
  half-width (``*_temperature_halfwidth``), uncorrected, and the set-up's notes say so.
  Unmeasured scales follow the part's actual temperature within their half-width. The
  sources are the actual temperatures minus the reference ones the estimators correct
  with, so zero errors give the truth exactly.
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

from mtplan.models.circle_centre._estimators import (
    gross_errors,
    DESCRIPTIONS,
    ESTIMATORS,
    estimate_geometric,
    estimate_gls,
    estimate_kasa,
    estimate_three_point,
    fit_points,
)
from mtplan.models.circle_centre._path import (
    PathPlan,
    Segment,
    acceptance_check,
    duration,
    miss,
    plan_for_bore,
    plan_path,
    report_extras,
)
from mtplan.models.circle_centre._physics import (
    forward,
    measurands,
    sources,
    start_from_readings,
    true_values,
    truth_from_estimate,
)
from mtplan.models.circle_centre._readings import from_frame, readings_frame, setup_from_frame
from mtplan.models.circle_centre._setup import Setup, Truth
from mtplan.models.protocol import (
    Capabilities,
    Estimator,
    Procedure,
    ReadingsFormat,
    SourceMethod,
)

from mtplan.models.circle_centre._correction import CORRECTION

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
    "estimate_three_point",
    "estimate_kasa",
    "estimate_geometric",
    "estimate_gls",
    "PROCEDURE",
]


class _Capabilities(Capabilities):
    """circle_centre beyond its model: the truth of an estimate, the least squares' start on
    the readings' branch of the planned path, the planned path for the report, and a bad
    contact as the gross error the fit check must see."""

    truth_from_estimate = staticmethod(truth_from_estimate)
    start_from_readings = staticmethod(start_from_readings)
    report_extras = staticmethod(report_extras)
    gross_errors = staticmethod(gross_errors)


PROCEDURE = Procedure(
    name="circle_centre",
    title="Bore centre by three probed points in equilateral distribution",
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
        "A touch probe, lowered anywhere into a bore of known nominal radius, probes -y and "
        "+y, plans three points 120 deg apart reached on helper arcs tangent to the radii, "
        "and computes the centre from them (circle-centre patent). Compares the three-point formula with "
        "algebraic and geometric least-squares circles through n points over any spread."
    ),
    readings=ReadingsFormat(readings_frame, from_frame, setup_from_frame=setup_from_frame,
                            optional_columns=("point",), noise_source="probe_noise"),
    capabilities=_Capabilities(
        block_size=2000,
        levers=tuple("n_points spread_deg free_test_mm miss_tolerance_mm feed_mm_min "
                     "probe_feed_mm_min clearance_mm dwell_s".split()),
        source_method=SourceMethod(
            "three_point", "Circle centre measuring and calculating method and device for "
            "high-precision circular fitting", who="Chinese patent"),
        correction=CORRECTION),
)
