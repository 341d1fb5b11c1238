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
  differences minimised in closed form) and rounded (:func:`._estimators.nearest_row`), which puts
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

from mtplan.models.line_laser._artifact import (
    facet_count,
    facet_layout,
    height_map,
    lattice_local,
    pitch,
    rot_x,
    rot_y,
    rot_z,
    sensor_rotation,
    x_shift,
)
from mtplan.models.line_laser._estimators import (
    estimate_patent,
    estimate_pattern,
    estimate_registration,
)
from mtplan.models.line_laser._first_order import sensitivities
from mtplan.models.line_laser._observability import Observability, observability, resolution
from mtplan.models.line_laser._physics import (
    FACET_OF,
    NOISE_SOURCE,
    NOMINAL,
    displacements,
    duration,
    forward,
    frames,
    measurands,
    newton,
    nominal_trace,
    origins,
    scan_times,
    source_structure,
    sources,
    trace,
    true_values,
    truth_from_estimate,
)
from mtplan.models.line_laser._readings import (
    from_frame,
    reading_limits,
    readings_frame,
    setup_from_frame,
)
from mtplan.models.line_laser._setup import NAME, Setup, Truth
from mtplan.models.protocol import (
    Capabilities,
    Estimator,
    Procedure,
    ReadingsFormat,
    SourceMethod,
)

from mtplan.models.line_laser._correction import CORRECTION

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



class _Capabilities(Capabilities):
    """line_laser beyond its model: the truth of an estimate, what each estimator can observe,
    the closed-form sensitivities and the facets' colouring (each facet moves a few
    readings)."""

    truth_from_estimate = staticmethod(truth_from_estimate)
    observability = staticmethod(observability)
    first_order_sensitivities = staticmethod(sensitivities)
    source_structure = staticmethod(source_structure)


PROCEDURE = Procedure(
    name=NAME,
    title="Mounting error angles of a line-laser profile sensor",
    Setup=Setup,
    Truth=Truth,
    measurands=measurands,
    sources=sources,
    forward=forward,
    true_values=true_values,
    duration=duration,
    readings=ReadingsFormat(readings_frame, from_frame, setup_from_frame=setup_from_frame,
                            limits=reading_limits, noise_source=NOISE_SOURCE),
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
    description=(
        "Three scans of a hexagonal-cell artifact (base, shifted by w in X, raised by h in Z) "
        "give the sensor's mounting angles about Z, Y and X. The patent's estimator quantises "
        "alpha_z to dy/w and cannot see the sign (nor, at realistic machine errors, the size) "
        "of alpha_x; the registration estimator fits sub-step translations between the scans "
        "and the rotation exactly."
    ),
    capabilities=_Capabilities(
        block_size=128,
        levers=tuple("points_per_line step_mm lines shift_fraction raise_mm max_shift_rows "
                     "scan_feed_mm_min rapid_mm_min settle_s".split()),
        source_method=SourceMethod(
            "patent", "Line laser mounting error angle determination method",
            who="Chinese patent application, Dong Zhigang, Kang Renke et al., filed 2019-09-03"),
        correction=CORRECTION),
)
