"""The 21 geometric errors of a three-axis machine from a 2D grid encoder (patent CN101982726).

Machine and model
-----------------
A vertical three-axis machine with a cross table (X on top of Y) and a head moving in
Z. The rigid-body model (:mod:`mtplan.models.kinematics`) chains exact homogeneous
transforms ``p = f + T_X(x) T_Y(y) T_Z(z) (h - f)`` with the 21 error functions in ISO
230-1 names, all taken in the sense *tool (reading head) relative to workpiece (plate)*:
positioning EXX, EYY, EZZ; straightness EYX, EZX, EXY, EZY, EXZ, EYZ; angular EAX, EBX,
ECX, EAY, EBY, ECY, EAZ, EBZ, ECZ; squareness EC0Y, EB0Z, EA0Z. Rotations are exact,
``R = Rx(EA) Ry(EB) Rz(EC)``; axis directions ``d_Y = Rz(EC0Y) e_y``,
``d_Z = Ry(EB0Z) Rx(EA0Z) e_z``. The errors are defined at the functional point
``f = (0, 0, -reference_tool_mm)``; the order of the chain gives the Abbe lever arms of a
cross-table machine: X's angular errors act on (0, y, z) + h - f, Y's on (0, 0, z) + h - f,
Z's on h - f, with h the reading head's offset from the spindle reference point.

Each error function is a polynomial in its axis's machine coordinate without constant
term (zero at the plate centre, the machine's reference point):
positioning and angular errors have powers 1..``poly_order``; **straightness errors
have powers 2..``poly_order``** and squareness is a constant. Decision (differs from the
brief's "every function a polynomial without constant term"): ISO 230-1 defines
straightness relative to the axis's reference straight line, whose direction *is* the
squareness; a linear straightness term would be the same parameter as the squareness
(or the plate's rotation) and the model would be rank deficient by definition. The patent
does the same (straightness = record minus its trend line). The error functions are
functions of position: :func:`error_functions` gives each one's estimate, truth and
first-order band over its travel; a measurand is the value at one stated position.

Instrument and tests
--------------------
A 2D grid plate (HEIDENHAIN KGM 182 in the patent, measuring range 140 mm diameter) is
fixed on the table in the XY, XZ and YZ planes in turn (plane offsets
``xy_plane_z_mm``, ``xz_plane_y_mm``, ``yz_plane_x_mm``: the machine coordinate of the
spindle reference during that plane's tests with the first head; the patent's YZ plane is
at x = 120 mm), and reads the head's position in the plate's plane. In each plane:
back-and-forth lines along both axes through the plate centre (``line_length_mm``,
``line_repeats``, ``line_points`` per pass) and a circle of radius ``circle_radius_mm``
about the centre, counter-clockwise then clockwise back along the same arc
(``circle_points`` per pass, ``circle_arc_deg``; the patent's example program uses 45 deg
arcs, the brief a full circle, which is the default).

*Several head positions.* The first head sits at (``head_lateral_mm``, 0,
-``head_offset_mm``) in every plane (the patent's single head). Each plane may repeat its
tests with extra head positions (``xy_extra_heads_mm``, ``xz_extra_heads_mm``,
``yz_extra_heads_mm``: triples of tool length, lateral X and lateral Y offset from the
spindle axis; for the vertical plates an angle bracket puts the head sideways, its arm
along the plate's normal). The plate stays mounted and the CNC's tool offset makes the
head follow the same path on the plate, so the commanded machine positions move by the
change of head offset, ``h0 - h``. Consequences for what the data can see: Z's angular
errors see the new lever ``h - f`` directly (tool length: EAZ at the YZ plate, EBZ at
the XZ plate; lateral offsets: ECZ); X's and Y's angular errors see only the head's
lateral offset (their lever in the plate's directions is fixed by where the plate is:
EBY and ECY need a lateral X offset); and an arm along the YZ plate's normal moves the
machine in x while the plate stays, so the X roll EAX turns the YZ pattern by EAX(x)
at each machine x against the plate's one rotation: ``poly_order`` + 1 distinct x
(3 extra arms at the default order) determine EAX. ``extra_head_tests`` says whether an
extra head repeats the circle too or the lines only. Each extra head's in-plane position
after the change is not known to a micrometre (``head_setting_um``); every estimator
estimates it, as it does the plates' mounting. The plate reads in its own grid's frame,
so the head's rotation does not matter.

Error sources
-------------
Reading noise, the plate's own grid error (a smooth random field per plane, cubic in
the plate coordinates), the plate's mounting in each set-up (in-plane offset, in-plane
rotation and two tilts), the extra heads' setting, and those of a real 1-2 h test:
machine repeatability per reading point (correlated along each pass: AR(1) in the path
length with ``repeatability_correlation_mm``, since a contouring machine's path deviations
are low-frequency), the machine's repeatable short-wave path deviation beyond the
polynomials (``path_residual_um``: the same in every pass, so the error of truncating the
model enters u), reversal (lost motion) between directions of
travel of each axis, the servo contouring error of the circles (first-order position
loops, radius- and feed-dependent), and thermal drift over the test's duration (a
growth of each axis's scale and a drift of the head relative to the plate, both
linear in time). Every reading has a time in the test's schedule (:func:`duration`
sums it): plate changes, head changes, then the moves at ``feed_mm_min``. See
:func:`sources` for each default and where it comes from.

Estimators
----------
``patent`` (the patent's stepwise method): step 1 fits each plane's two line records read
with the first head (trend line + polynomial; the patent's "record minus trend line" as
one least-squares fit) for 3 positioning, 6 straightness and 3 squareness errors and the
plate's offset and rotation; step 2 brings every other reading back to the nominal plate
frame (step-1 mounting removed exactly), subtracts the step-1 errors' first-order effect
and solves ``E = Q P`` by least squares for the angular coefficients (and the extra
heads' settings) from **all three circles stacked**, each circle's radial deviation
``|r| - R``, together with the 2D line records of the extra heads. The patent assigns the
angular errors to planes (XY: EAY, EBY, ECY, ECX; XZ: EBX, EBZ; YZ: EAZ, EAX, ECZ),
which the lever arms do not support (the XY circle has no lever for EAY, the YZ circle
sees EAY through z): stacking is what makes step 2 work; the patent's single head has no
line records beyond step 1, so with it step 2 is the patent's circles alone. Q is the
forward model's first-order expansion (its Jacobian at zero error), not the patent's
damaged formulas. Where the derivation differs from the patent: the patent's lever arms
include each axis's own coordinate (terms ``x^2 sin(theta)``), which ISO 230-1 absorbs
in the straightness; the X roll column of the patent's Q_YOZ is ``x^n (z cos + y sin)``
whereas a rotation about x seen at fixed x = 120 mm is a rigid rotation of the YZ
pattern, whose radial component about the centre vanishes, and its three columns (n = 1,
2, 3) are proportional: Q_YOZ is rank deficient. The patent also ignores the tool-length
lever arm in step 1, so its positioning errors are those at the reading head (EXX - L EBX
at first order), not at the spindle reference point.

``joint``: all coefficients and the nuisance mounting parameters at once, generalised
least squares (weights: the covariance of the encoder noise, the AR(1) repeatability and the
repeatable path residual: a sparse whitening with a low-rank update, :mod:`._path`) with the model's Jacobian (rank-truncated pseudo-inverse, one product per batch),
then Gauss-Newton on the exact model with **one linearisation for the whole batch**: the
trials of a Monte Carlo block differ by the noise only, so the exact model is evaluated
at the batch's (componentwise) median estimate and every trial is moved by the same
correction of the model's non-linear part (chord iterations, the Jacobian at a coarse
grid point near the median, shared by every block near it). The neglected term is
second order in a trial's distance from the median; it is checked on the trials
farthest from it (their exact residual's correction must be below 1e-3 of a typical
error, 1 nm / 0.01 urad) and the batch falls back to per-trial chord iterations on the
exact model where it is not. A batch of one (a measurement) is plain chord Gauss-Newton.
``joint_linear``: the first, linearised, step only.

Identifiability (the point of the study)
----------------------------------------
From 2D plate readings the model is rank deficient: see :func:`identifiability` and
docs/geometry21.md. At the default set-up (the patent's one head, errors defined at the
reading head) the joint Jacobian has rank 42 of 60: the X roll EAX only rotates the YZ
pattern (confounded with the plate's rotation), and EBY, ECY, EAZ, EBZ, ECZ have no
lever arm between the functional point and any plate plane (no effect). Decision:
:func:`measurands` lists only the measurands that the data determine (estimable functions
of the joint model at the given set-up: 15 at the default, all 21 with the head
positions of ``examples/geometry21_all21.toml``); the others are never reported as
numbers, and :func:`identifiability` gives every one of the 21 with its status and the
errors it is confounded with. The patent estimator reports the same list; where it is
biased at first order (e.g. ``reference_tool_mm=0``: EXX - L EBX) :func:`identifiability`
with ``estimator="patent"`` says so and names the errors that bias it.

Units: mm and rad internally; measurands in um (positioning, straightness) and urad
(angular, squareness), each the value of the function at the positive end of the
line travel, u = +``line_length_mm``/2.
"""

from __future__ import annotations

from mtplan.models.geometry21._estimators import (
    DESCRIPTIONS,
    ESTIMATORS,
    SHARED_SPREAD,
    SHARED_TOL,
    coefficients,
    measure,
    theta_joint,
    theta_joint_per_trial,
)
from mtplan.models.geometry21._first_order import (
    coefficient_covariance,
    error_bands,
    error_functions,
    identifiability,
    identifiability_report,
    noise_free_table,
    report_extras,
    sensitivities,
)
from mtplan.models.geometry21._layout import geometry
from mtplan.models.geometry21._model import (
    RANK_TOL,
    joint_ident,
    model_jacobian,
    mounting_mask,
    parameter_scales,
)
from mtplan.models.geometry21._patent import patent_design, theta_patent
from mtplan.models.geometry21._path import repeatability_filter, residual_at, residual_basis
from mtplan.models.geometry21._correction import CORRECTION
from mtplan.models.geometry21._physics import (
    duration,
    forward,
    measurands,
    sources,
    true_values,
)
from mtplan.models.geometry21._frames import from_frame, readings_frame, setup_from_frame
from mtplan.models.geometry21._setup import (
    AXIS,
    HIDDEN_ANGULAR,
    KIND,
    NAMES,
    PLANES,
    WHITE,
    Setup,
    Truth,
    sizeless,
)
from mtplan.models.protocol import (
    Capabilities,
    Estimator,
    Procedure,
    ReadingsFormat,
    SourceMethod,
)

__all__ = [
    "Setup",
    "Truth",
    "NAMES",
    "PROCEDURE",
    "HIDDEN_ANGULAR",
    "identifiability",
    "identifiability_report",
    "coefficients",
    "coefficient_covariance",
    "error_bands",
    "error_functions",
    "noise_free_table",
]



class _Capabilities(Capabilities):
    """geometry21 beyond its model: the joint model's own rank analysis, which error functions
    each estimator determines, the error functions' bands for the report, and the
    closed-form sensitivities."""

    identifiability_report = staticmethod(identifiability_report)
    report_extras = staticmethod(report_extras)
    identifiability = staticmethod(identifiability)
    first_order_sensitivities = staticmethod(sensitivities)


PROCEDURE = Procedure(
    name="geometry21",
    title="21 geometric errors of a three-axis machine from a 2D grid encoder",
    Setup=Setup,
    Truth=Truth,
    measurands=measurands,
    sources=sources,
    forward=forward,
    estimators={name: Estimator(fn, description=DESCRIPTIONS[name], exact=name == "joint")
                for name, fn in ESTIMATORS.items()},
    true_values=true_values,
    duration=duration,
    readings=ReadingsFormat(readings_frame, from_frame, setup_from_frame=setup_from_frame,
                            optional_columns=("head",)),
    description=__doc__.split("\n\n")[0] if __doc__ else "",
    capabilities=_Capabilities(
        block_size=128,
        levers=tuple("poly_order line_length_mm line_repeats line_points circle_radius_mm "
                     "circle_points circle_arc_deg head_offset_mm head_lateral_mm "
                     "xy_plane_z_mm xz_plane_y_mm yz_plane_x_mm feed_mm_min xy_extra_heads_mm "
                     "xz_extra_heads_mm yz_extra_heads_mm extra_head_tests".split()),
        source_method=SourceMethod(
            "patent", "Detection method for geometric motion errors of three-axis numerical "
            "control equipment", "patent CN101982726",
            "Shanghai Jiao Tong University, filed 2010-09-27"),
        correction=CORRECTION),
)
