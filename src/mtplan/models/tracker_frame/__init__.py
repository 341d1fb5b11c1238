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
  (:data:`._estimators._GLS_HEAD`) and the tracker's position, yaw and tilts; the
  pivot-length error and the A-C angle are held (the readings do not determine them, the
  posterior holds them too). Weights: the inverse covariance of the readings under every
  active source, each source element's secant effect at +-1 sd
  (:func:`._estimators._gls_gain`). Gauss-Newton from the ``home`` estimate (first trial;
  tracker pose from the registration) with one gain for the whole batch, re-taken once at
  the batch median; the measurands are the construction applied to the fitted geometry. It
  uses what the posterior uses, so it is as efficient (u(posterior) / u(mc) 0.98-1.02 on
  the example readings, against 0.88-0.92 for ``home``'s origins) and the default by the
  smallest-geometric-mean rule. About 5 times slower than ``home`` (about 5 000 trials/s).

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
  estimator corrects both (:func:`._estimators._corrected_readings`, the registered points
  shrunk back about the centroid; ``gls`` through its forward model), and the
  thermometers' and the expansion coefficient's errors are sources. Not measured, they are
  a zero-mean half-width and a range from 0 (signed mean), uncorrected; the set-up's notes
  say so.

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

from mtplan.models.protocol import (
    Capabilities,
    Estimator,
    Procedure,
    ReadingsFormat,
    SourceMethod,
)
from mtplan.models.tracker_frame._estimators import (
    estimate_angles,
    estimate_gls,
    estimate_home,
    estimate_patent,
)
from mtplan.models.tracker_frame._layout import duration
from mtplan.models.tracker_frame._physics import (
    forward,
    measurands,
    sources,
    true_values,
    truth_from_estimate,
    truths_from_estimates,
)
from mtplan.models.tracker_frame._readings import (
    KEY_COLUMNS,
    READING_COLUMNS,
    from_frame,
    readings_frame,
    setup_from_frame,
)
from mtplan.models.tracker_frame._setup import (
    AXES,
    MIN_AC_ANGLE_DEG,
    NAME,
    PARALLEL_SIN,
    Setup,
    Truth,
)

from mtplan.models.tracker_frame._correction import CORRECTION

__all__ = [
    "PROCEDURE",
    "Setup",
    "Truth",
    "NAME",
    "AXES",
    "MIN_AC_ANGLE_DEG",
    "PARALLEL_SIN",
    "measurands",
    "sources",
    "forward",
    "estimate_patent",
    "estimate_angles",
    "estimate_home",
    "estimate_gls",
    "true_values",
    "truth_from_estimate",
    "truths_from_estimates",
    "duration",
    "READING_COLUMNS",
    "KEY_COLUMNS",
    "readings_frame",
    "from_frame",
    "setup_from_frame",
]


class _Capabilities(Capabilities):
    """tracker_frame beyond its model: the truth of an estimate, and of many estimates as one
    batch (the designer's sensitivities in one forward run)."""

    truth_from_estimate = staticmethod(truth_from_estimate)
    truths_from_estimates = staticmethod(truths_from_estimates)


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
    readings=ReadingsFormat(readings_frame, from_frame, setup_from_frame=setup_from_frame),
    capabilities=_Capabilities(
        block_size=4000,
        levers=tuple("reflector_offset_mm travel_x_mm travel_y_mm travel_z_mm "
                     "points_per_axis c_arc_deg a_arc_deg points_per_arc tracker_distance_mm "
                     "tracker_height_mm dwell_s linear_feed_mm_min".split()),
        source_method=SourceMethod(
            "patent", "Zero point definition and calibration method for a gantry-type "
            "multi-spindle drilling combined machine tool", "patent CN106078359A"),
        correction=CORRECTION),
)
