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

import dataclasses
import functools
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from mtplan._validate import InvalidInput, Problems
from mtplan.fitting import central_jacobian
from mtplan.fitting.linear import gls_pinv, restricted_pinv, \
    truncated_pinv
from mtplan.models.kinematics import chain, polyval, rotate_inverse
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
from mtplan.uncertainty.distributions import Normal, Rectangular

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
    "budget",
    "first_order_std",
    "noise_free_table",
]

#: (name, kind, axis index, component index) of the 21 error functions, ISO 230-1 names.
FUNCTIONS = (
    ("EXX", "pos", 0, 0), ("EYY", "pos", 1, 1), ("EZZ", "pos", 2, 2),
    ("EYX", "str", 0, 1), ("EZX", "str", 0, 2), ("EXY", "str", 1, 0),
    ("EZY", "str", 1, 2), ("EXZ", "str", 2, 0), ("EYZ", "str", 2, 1),
    ("EAX", "ang", 0, 0), ("EBX", "ang", 0, 1), ("ECX", "ang", 0, 2),
    ("EAY", "ang", 1, 0), ("EBY", "ang", 1, 1), ("ECY", "ang", 1, 2),
    ("EAZ", "ang", 2, 0), ("EBZ", "ang", 2, 1), ("ECZ", "ang", 2, 2),
    ("EC0Y", "sq", 1, 2), ("EB0Z", "sq", 2, 1), ("EA0Z", "sq", 2, 0),
)
NAMES = tuple(f[0] for f in FUNCTIONS)
_KIND = {f[0]: f[1] for f in FUNCTIONS}
_AXIS = {f[0]: f[2] for f in FUNCTIONS}
_DESCR = {
    "pos": "positioning error of the {ax} axis",
    "str": "straightness error of the {ax} axis in {comp}",
    "ang": "{rot} of the {ax} axis",
    "sq": "squareness error",
}
_ROT = ("rotation about X", "rotation about Y", "rotation about Z")
#: plate planes: name, in-plane axes (a, b), the fixed axis
PLANES = (("XY", 0, 1, 2), ("XZ", 0, 2, 1), ("YZ", 1, 2, 0))
#: the patent's assignment of step-1 errors (lines) to planes; _STEP2 documents the patent's
#: assignment of the angular errors to the circles (step 2 stacks them, module docstring)
_STEP1 = {"XY": ("EXX", "EYY", "EYX", "EXY", "EC0Y"), "XZ": ("EZZ", "EZX", "EXZ", "EB0Z"),
          "YZ": ("EZY", "EYZ", "EA0Z")}
_STEP2 = {"XY": ("EAY", "EBY", "ECY", "ECX"), "XZ": ("EBX", "EBZ"), "YZ": ("EAZ", "EAX", "ECZ")}
#: radius of the grid plate's measuring range (KGM 182: 140 mm diameter) [mm]
PLATE_RADIUS_MM = 70.0
_TEST_NAMES = ("line_a", "line_b", "circle")
_GRID_POWERS = tuple((i, j) for d in (1, 2, 3) for i in range(d + 1) for j in (d - i,))
#: relative spread of the axes' following times about servo_lag_ms (gain mismatch)
SERVO_MISMATCH = 0.1
#: error sources that add white noise to each reading component (first order: sigma^2 I)
_WHITE = ("encoder_noise", "repeatability")


def _powers(name: str, order: int) -> tuple[int, ...]:
    kind = _KIND[name]
    if kind == "sq":
        return (0,)
    return tuple(range(2 if kind == "str" else 1, order + 1))


# --------------------------------------------------------------------------- set-up
def _heads_field(plane: str, doc_extra: str):
    return param((), doc=f"Extra head positions of the {plane} plate's tests: triples of tool "
                 "length, lateral X and lateral Y offset from the spindle axis [mm] (e.g. "
                 f"200,0,0,100,60,0); each repeats the plane's tests there. {doc_extra}",
                 low=-1000, high=1000)


@dataclass(frozen=True)
class Setup(SetupBase):
    """Set-up of the 2D grid-encoder test of the 21 geometric errors."""

    _owner = "geometry21"
    poly_order: int = param(3, doc="Order of the error polynomials (the patent: 3)", low=2, high=6)
    line_length_mm: float = param(100.0, doc="Length of each line test (the patent: 100 mm)",
                                  low=0, high=2 * PLATE_RADIUS_MM, low_open=True)
    line_repeats: int = param(5, doc="Back-and-forth repeats of each line (the patent: 5)",
                              low=1, high=100)
    line_points: int = param(21, doc="Readings per line pass", low=3, high=2001)
    circle_radius_mm: float = param(50.0, doc="Radius of the circle tests (the patent: 30-70 mm)",
                                    low=0, high=PLATE_RADIUS_MM, low_open=True)
    circle_points: int = param(72, doc="Readings per circle pass (two passes: CCW, CW)",
                               low=8, high=20001)
    circle_arc_deg: float = param(360.0, doc="Arc of each circle pass (the patent's program: 45)",
                                  low=0, high=360, low_open=True)
    head_offset_mm: float = param(100.0, doc="Reading head below the spindle reference point "
                                  "(tool length L) of the first head position", low=0, high=1000)
    reference_tool_mm: float = param(100.0, doc="Tool offset of the functional point at which "
                                     "the errors are defined (ISO 230-1); default the head's",
                                     low=0, high=1000)
    head_lateral_mm: float = param(0.0, doc="First head position's offset from the spindle axis "
                                   "along X", low=-200, high=200)
    xy_extra_heads_mm: tuple[float, ...] = _heads_field("XY", "A lateral X offset shows ECY.")
    xz_extra_heads_mm: tuple[float, ...] = _heads_field(
        "XZ", "Another tool length shows EBZ; a lateral Y arm (the plate's normal) ECZ and EAZ.")
    yz_extra_heads_mm: tuple[float, ...] = _heads_field(
        "YZ", "A lateral X arm (the plate's normal) shows EBY, ECY, EBZ, ECZ and, at "
        "poly_order + 1 distinct arms, EAX; another tool length shows EAZ.")
    extra_head_tests: str = param("all", doc="Tests repeated at the extra head positions: "
                                  "'all' (lines and circle) or 'lines'", choices=("all", "lines"))
    xy_plane_z_mm: float = param(0.0, doc="Z of the XY plate set-up", low=-1000, high=1000)
    xz_plane_y_mm: float = param(0.0, doc="Y of the XZ plate set-up", low=-1000, high=1000)
    yz_plane_x_mm: float = param(120.0, doc="X of the YZ plate set-up (the patent: 120 mm)",
                                 low=-1000, high=1000)
    encoder_noise_um: float = param(0.05, doc="Reading noise of the 2D encoder (std, each "
                                    "component)", low=0, high=100)
    grid_error_um: float = param(1.0, doc="Grid plate's own error (std of its smooth field)",
                                 low=0, high=100)
    plate_offset_mm: float = param(0.05, doc="Plate mounting offset in its plane (std)",
                                   low=0, high=10)
    plate_tilt_urad: float = param(100.0, doc="Plate mounting rotation and tilts (std)",
                                   low=0, high=20000)
    head_setting_um: float = param(10.0, doc="In-plane position error of an extra head after "
                                   "the change (std, each component; estimated as a nuisance)",
                                   low=0, high=1000)
    repeatability_um: float = param(0.3, doc="Machine repeatability at each reading point (std, "
                                    "each in-plane component; ISO 230-2 R = 4 s)", low=0, high=100)
    repeatability_correlation_mm: float = param(
        50.0, doc="Correlation length of the repeatability along the path of each pass [mm]: "
        "AR(1) in the path length, readings s mm apart correlate by exp(-s / length), however "
        "densely the pass is read; 0: independent", low=0, high=1e5)
    path_residual_um: float = param(
        0.3, doc="RMS of the machine's repeatable short-wave path deviation beyond the "
        "polynomials, each axis and direction (harmonics of 10-40 mm wavelength of the "
        "axis's position: ball-screw pitch, guideway waviness); the same in every pass",
        low=0, high=100)
    reversal_um: float = param(2.0, doc="Reversal value of each axis (mean; drawn uniform on "
                               "[0, 2x]; ISO 230-2 B, 1-3 um with linear scales)", low=0, high=100)
    servo_lag_ms: float = param(2.0, doc="Following time 1/Kv of each axis's position loop "
                                "(mean; 10 % spread per axis for the gain mismatch)", low=0,
                                high=200)
    thermal_growth_ppm_per_h: float = param(2.0, doc="Growth of each axis's scale during the test "
                                            "(std of the rate; ISO 230-3 drift)", low=0, high=100)
    thermal_drift_um_per_h: float = param(2.0, doc="Drift of the head relative to the plate "
                                          "during the test (std of the rate, each component)",
                                          low=0, high=1000)
    feed_mm_min: float = param(500.0, doc="Feed of the test moves (the patent: 500 mm/min)",
                               low=0, high=100000, low_open=True)
    setup_change_s: float = param(1200.0, doc="Time to mount and align the plate in one plane",
                                  low=0, high=36000)
    head_change_s: float = param(300.0, doc="Time to change the reading head (tool length or "
                                 "bracket) and set it, per extra head position", low=0, high=36000)

    def _check(self, p: Problems) -> None:
        if self.line_points < self.poly_order + 2:
            p.add("line_points", self.line_points,
                  f"an int >= poly_order + 2 = {self.poly_order + 2} (a line record must "
                  "determine its trend line and polynomial)")
        if self.circle_points < 2 * self.poly_order + 4:
            p.add("circle_points", self.circle_points,
                  f"an int >= 2 * poly_order + 4 = {2 * self.poly_order + 4} (the circle's "
                  "least-squares fit needs more readings than unknowns)")
        for pl in ("xy", "xz", "yz"):
            name = f"{pl}_extra_heads_mm"
            v = np.asarray(getattr(self, name), dtype=float)
            if v.size % 3:
                p.add(name, getattr(self, name), "a list of triples (tool length, lateral X, "
                      "lateral Y) [mm]: its length must be a multiple of 3")
                continue
            t = v.reshape(-1, 3)
            if np.any(t[:, 0] < 0) or np.any(np.abs(t[:, 1:]) > 200):
                p.add(name, getattr(self, name), "triples with tool length in [0, 1000] and "
                      "lateral offsets in [-200, 200] mm")


#: the fields that size an error source: the geometry, the Jacobian and the patent's
#: design do not depend on them and are computed once for every size (:func:`_sizeless`)
_SIZES = ("encoder_noise_um", "grid_error_um", "plate_offset_mm", "plate_tilt_urad",
          "head_setting_um", "repeatability_um", "path_residual_um", "reversal_um",
          "servo_lag_ms",
          "thermal_growth_ppm_per_h", "thermal_drift_um_per_h")


@functools.lru_cache(maxsize=64)
def _sizeless(setup: Setup) -> Setup:
    """The set-up with every error source at its default size."""
    return setup.replace(**{f: Setup.__dataclass_fields__[f].default for f in _SIZES})


def extra_heads(setup: Setup) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The head offsets h = (lateral X, lateral Y, -tool length) of each plane [mm].

    Returns
    -------
    tuple of three arrays of shape (1 + n_extra, 3), XY, XZ, YZ: the first head, then
    that plane's extra heads.
    """
    h0 = np.array([setup.head_lateral_mm, 0.0, -setup.head_offset_mm])
    out = []
    for pl in ("xy", "xz", "yz"):
        t = np.asarray(getattr(setup, f"{pl}_extra_heads_mm"), dtype=float).reshape(-1, 3)
        out.append(np.vstack([h0, np.column_stack([t[:, 1], t[:, 2], -t[:, 0]])]))
    return tuple(out)


_DEFAULT_TRUTH = {
    # coefficients of (u / 100 mm)^n, n = 1.. (straightness n = 2..) in um or urad
    "EXX": (10.0, 3.0, -4.0), "EYY": (-8.0, 2.0, 3.0), "EZZ": (6.0, -3.0, 2.0),
    "EYX": (4.0, -3.0), "EZX": (-3.0, 2.0), "EXY": (3.0, 2.5), "EZY": (-4.0, -2.0),
    "EXZ": (2.0, 3.0), "EYZ": (-2.5, 1.5),
    "EAX": (), "EBX": (20.0, 8.0, -6.0), "ECX": (-15.0, 6.0, 5.0),
    "EAY": (-18.0, 5.0, 4.0), "EBY": (), "ECY": (),
    "EAZ": (), "EBZ": (), "ECZ": (),
}
#: Realistic values of the six angular errors the default test cannot see (they are
#: zero in the default Truth, see the Truth docstring): ``Truth(**HIDDEN_ANGULAR)``.
HIDDEN_ANGULAR = {
    "EAX_urad": (12.0, -6.0, 4.0), "EBY_urad": (10.0, -4.0, 3.0), "ECY_urad": (14.0, 6.0, -5.0),
    "EAZ_urad": (16.0, -5.0, 3.0), "EBZ_urad": (-12.0, 7.0, 4.0), "ECZ_urad": (8.0, 3.0, -2.0),
}
_DEFAULT_SQ = {"EC0Y": 20.0, "EB0Z": -15.0, "EA0Z": 12.0}


def _tfield(name):
    unit = "urad" if _KIND[name] == "ang" else "um"
    first = 2 if _KIND[name] == "str" else 1
    return param(_DEFAULT_TRUTH[name],
                 doc=f"{name}: coefficients of (u/100 mm)^n, n = {first}, {first + 1}, ... [{unit}]")


@dataclass(frozen=True)
class Truth(SetupBase):
    """True error functions of the simulated machine (realistic for a small machining centre).

    Positioning about 10 um per 100 mm, straightness a few um, angular 10-30 urad per
    100 mm, squareness 10-20 urad. ``error_scale`` multiplies every error and
    ``angular_scale`` the angular and squareness errors only (large-error studies).

    The six angular errors that the default (the patent's one-head) test cannot see at first
    order (EAX: only a rotation of the YZ pattern, taken up by the plate's rotation; EBY,
    ECY, EAZ, EBZ, ECZ: no lever arm between the functional point and the plates' planes)
    are zero by default: with realistic values (:data:`HIDDEN_ANGULAR`) their second-order
    effect on the readings (at most ~1e-8 mm) makes every estimator inexact by up to
    ~1e-4 urad / 2e-6 um at that set-up, and the conformance check of noise-free recovery
    is at 1e-6. A set-up with head positions that determine all 21
    (``examples/geometry21_all21.toml``) is simulated with them set.
    """

    _owner = "geometry21 truth"
    EXX_um: tuple[float, ...] = _tfield("EXX")
    EYY_um: tuple[float, ...] = _tfield("EYY")
    EZZ_um: tuple[float, ...] = _tfield("EZZ")
    EYX_um: tuple[float, ...] = _tfield("EYX")
    EZX_um: tuple[float, ...] = _tfield("EZX")
    EXY_um: tuple[float, ...] = _tfield("EXY")
    EZY_um: tuple[float, ...] = _tfield("EZY")
    EXZ_um: tuple[float, ...] = _tfield("EXZ")
    EYZ_um: tuple[float, ...] = _tfield("EYZ")
    EAX_urad: tuple[float, ...] = _tfield("EAX")
    EBX_urad: tuple[float, ...] = _tfield("EBX")
    ECX_urad: tuple[float, ...] = _tfield("ECX")
    EAY_urad: tuple[float, ...] = _tfield("EAY")
    EBY_urad: tuple[float, ...] = _tfield("EBY")
    ECY_urad: tuple[float, ...] = _tfield("ECY")
    EAZ_urad: tuple[float, ...] = _tfield("EAZ")
    EBZ_urad: tuple[float, ...] = _tfield("EBZ")
    ECZ_urad: tuple[float, ...] = _tfield("ECZ")
    EC0Y_urad: float = param(_DEFAULT_SQ["EC0Y"], doc="Squareness of Y to X [urad]")
    EB0Z_urad: float = param(_DEFAULT_SQ["EB0Z"], doc="Squareness of Z to X [urad]")
    EA0Z_urad: float = param(_DEFAULT_SQ["EA0Z"], doc="Squareness of Z to Y [urad]")
    error_scale: float = param(1.0, doc="Factor on every error", low=0)
    angular_scale: float = param(1.0, doc="Extra factor on angular and squareness errors", low=0)


def _rows(truth: Truth) -> int | None:
    """None for one truth; m for a truth whose fields are arrays (m,) (one per batch row)."""
    values = []
    for f in dataclasses.fields(truth):
        v = getattr(truth, f.name)
        values += list(v) if isinstance(v, tuple) else [v]
    if not any(np.ndim(v) for v in values):
        return None
    return max(int(np.size(v)) for v in values)


def _truth_coefficients(truth: Truth) -> dict:
    """name -> (powers, internal coefficients) of the true functions (any length): arrays
    (L,), or (m, L) for a truth whose fields are arrays (m,) (one per batch row)."""
    m = _rows(truth)
    out = {}
    for name in NAMES:
        kind = _KIND[name]
        unit = 1e-6 if kind in ("ang", "sq") else 1e-3
        scale = np.asarray(truth.error_scale) * (np.asarray(truth.angular_scale)
                                                 if kind in ("ang", "sq") else 1.0)
        if kind == "sq":
            c = np.asarray(getattr(truth, name + "_urad"), dtype=float) * unit * scale
            out[name] = ((0,), c.reshape(1) if m is None else np.broadcast_to(c, (m,))[:, None])
            continue
        vals = getattr(truth, name + ("_urad" if kind == "ang" else "_um"))
        first = 2 if kind == "str" else 1
        powers = tuple(range(first, first + len(vals)))
        coef = [np.asarray(v, dtype=float) * unit * scale / 100.0**k for v, k in zip(vals, powers)]
        if m is None:
            out[name] = (powers, np.array(coef, dtype=float).reshape(len(powers)))
        else:
            out[name] = (powers, np.stack([np.broadcast_to(c, (m,)) for c in coef], axis=-1)
                         if coef else np.zeros((m, 0)))
    return out


# --------------------------------------------------------------------------- geometry
@dataclass(frozen=True)
class _Geometry:
    plane: np.ndarray      # (M,) plane index
    head: np.ndarray       # (M,) head index within its plane (0: the first head)
    xhead: np.ndarray      # (M,) global index of an extra head, -1 for the first head
    test: np.ndarray       # (M,) 0 line along a, 1 line along b, 2 circle
    pass_: np.ndarray      # (M,)
    point: np.ndarray      # (M,)
    cmd: np.ndarray        # (M, 3) commanded x, y, z [mm]
    local: np.ndarray      # (M, 2) nominal in-plane position relative to the centre [mm]
    hvec: np.ndarray       # (M, 3) head offset of each reading [mm]
    time_s: np.ndarray     # (M,) time of each reading from the test's start [s]
    basis: np.ndarray      # (3, 3, 3) plate axes (columns u, v, n) per plane
    centre: np.ndarray     # (3, 3) commanded centre of each plane's tests, first head [mm]
    origin: np.ndarray     # (3, 3) the plates' nominal origins (centre + first head) [mm]
    ref: np.ndarray        # (3,) functional point
    pattern: np.ndarray    # (15, M, 3) plate-frame effect of the drift/reversal/servo features
    powers: np.ndarray     # (3, poly_order + 1, M) powers of each axis's commanded position
    distinct: tuple        # per axis: (index (M,) into its distinct positions, their powers)
    layout: dict           # function -> (powers, slice into coefficients)
    n_coef: int
    n_extra: int           # extra head positions, all planes
    xslices: tuple         # (plane, slice of its readings) of each extra head position
    n_par: int             # coefficients + 3 per plane + 2 per extra head
    u_end: float
    duration_s: float
    # the readings' distinct points (plane, commanded position, head offset) as a geometry
    # of their own (its per-reading arrays only), and the point of every reading: the rigid-
    # body chain is evaluated once per point and spread (repeated passes, forward and back)
    points: tuple | None = None


def _plane_centre(setup, k):
    c = np.zeros(3)
    c[PLANES[k][3]] = (setup.xy_plane_z_mm, setup.xz_plane_y_mm, setup.yz_plane_x_mm)[k]
    return c


def _passes(setup):
    """The passes of one plane's program: (test, pass, local a, local b, path length to
    each point [mm], pass length [mm], velocity sign (a, b) per point, circle angle, sense)."""
    half = setup.line_length_mm / 2
    u = np.linspace(-half, half, setup.line_points)
    R = setup.circle_radius_mm
    arc = math.radians(setup.circle_arc_deg)
    full = setup.circle_arc_deg >= 360.0
    th = np.linspace(0.0, arc, setup.circle_points, endpoint=not full)
    out = []
    for t in (0, 1):
        for rep in range(setup.line_repeats):
            for d, uu in enumerate((u, u[::-1])):
                z = np.zeros(uu.size)
                sign = np.full(uu.size, 1.0 if d == 0 else -1.0)
                vel = (sign, z) if t == 0 else (z, sign)
                out.append((t, 2 * rep + d, uu if t == 0 else z, uu if t == 1 else z,
                            np.abs(uu - uu[0]), setup.line_length_mm, vel, z, 0.0))
    for d, s in enumerate((1.0, -1.0)):  # CCW, then CW back along the same arc (the patent)
        phi = th if s > 0 else arc - th
        va, vb = -s * np.sin(phi), s * np.cos(phi)
        vel = tuple(np.where(np.abs(v) > 1e-12, np.sign(v), 0.0) for v in (va, vb))
        out.append((2, d, R * np.cos(phi), R * np.sin(phi), R + R * th, 2 * R + R * arc, vel,
                    phi, s))
    return out


@functools.lru_cache(maxsize=16)
def _geometry(setup: Setup) -> _Geometry:
    if (key := _sizeless(setup)) != setup:  # one geometry for every size of the sources
        return _geometry(key)
    heads = extra_heads(setup)
    passes = _passes(setup)
    v = setup.feed_mm_min / 60.0  # [mm/s]
    cols = {k: [] for k in ("plane", "head", "xhead", "test", "pass", "point", "la", "lb", "time",
                            "va", "vb", "phi", "sense", "h")}
    clock, xh = 0.0, 0
    for k in range(3):
        clock += setup.setup_change_s
        for j, h in enumerate(heads[k]):
            if j:
                clock += setup.head_change_s
            for test, pss, la, lb, dist, length, vel, phi, sense in passes:
                if j and test == 2 and setup.extra_head_tests == "lines":
                    continue
                n = la.size
                for key, val in (("plane", k), ("head", j), ("xhead", xh if j else -1),
                                 ("test", test), ("pass", pss), ("sense", sense)):
                    cols[key].append(np.full(n, val))
                cols["point"].append(np.arange(n))
                cols["la"].append(la)
                cols["lb"].append(lb)
                cols["time"].append(clock + dist / v)
                cols["va"].append(vel[0])
                cols["vb"].append(vel[1])
                cols["phi"].append(phi)
                cols["h"].append(np.broadcast_to(h, (n, 3)))
                clock += length / v
            xh += 1 if j else 0
    c = {key: np.concatenate(val) for key, val in cols.items()}
    plane = c["plane"].astype(int)
    local = np.column_stack([c["la"], c["lb"]])
    cmd = np.zeros((plane.size, 3))
    vdir = np.zeros((plane.size, 3))
    hvec = np.asarray(c["h"], dtype=float)
    basis = np.zeros((3, 3, 3))
    centre = np.stack([_plane_centre(setup, k) for k in range(3)])
    for k, (_, a, b, _c) in enumerate(PLANES):
        sel = plane == k
        # the head follows the plate's path: the machine moves by the head's change of offset
        cmd[sel] = centre[k] + heads[k][0] - hvec[sel]
        cmd[sel, a] += local[sel, 0]
        cmd[sel, b] += local[sel, 1]
        vdir[sel, a] = c["va"][sel]
        vdir[sel, b] = c["vb"][sel]
        ea, eb = np.eye(3)[a], np.eye(3)[b]
        basis[k] = np.column_stack([ea, eb, np.cross(ea, eb)])
    layout, pos = {}, 0
    for name in NAMES:
        pw = _powers(name, setup.poly_order)
        layout[name] = (pw, slice(pos, pos + len(pw)))
        pos += len(pw)
    n_extra = int(c["xhead"].max()) + 1 if c["xhead"].size else 0
    xslices = []
    for e in range(n_extra):
        idx = np.flatnonzero(c["xhead"] == e)
        xslices.append((int(plane[idx[0]]), slice(int(idx[0]), int(idx[-1]) + 1)))
    geo = dict(plane=plane, head=c["head"].astype(int), xhead=c["xhead"].astype(int),
               test=c["test"].astype(int), pass_=c["pass"].astype(int),
               point=c["point"].astype(int), cmd=cmd, local=local, hvec=hvec,
               time_s=c["time"], basis=basis, centre=centre,
               origin=centre + np.stack([h[0] for h in heads]),
               ref=np.array([0.0, 0.0, -setup.reference_tool_mm]), layout=layout, n_coef=pos,
               n_extra=n_extra, xslices=tuple(xslices), n_par=pos + 9 + 2 * n_extra, u_end=setup.line_length_mm / 2,
               duration_s=float(clock))
    pat = _feature_patterns(setup, plane, cmd, local, vdir, c["time"], c["phi"], c["sense"],
                            c["test"])
    geo["pattern"] = _to_plate_frame(plane, basis, pat)
    geo["powers"] = cmd.T[:, None, :] ** np.arange(setup.poly_order + 1)[None, :, None]
    geo["distinct"] = tuple((inv, u[None, :] ** np.arange(setup.poly_order + 1)[:, None])
                            for u, inv in (np.unique(x, return_inverse=True) for x in cmd.T))
    geo["points"] = _points(geo)
    return _Geometry(**geo)


def _points(geo: dict) -> tuple:
    """(geometry of the distinct points, index (M,) of each reading's point).

    A reading's position in its plate's nominal frame (:func:`_truth_positions`) depends on
    its plane, commanded position and head offset only; the line passes repeat their points
    (``line_repeats``, forward and back), so about a quarter of the readings are distinct.
    The points keep the planes' order (plane first), so each plane's are contiguous, as
    :func:`_local3` needs; only the per-reading arrays are taken (no extra-head slices).
    """
    key = np.column_stack([geo["plane"], geo["cmd"], geo["hvec"]])
    _, rep, spread = np.unique(key, axis=0, return_index=True, return_inverse=True)
    sub = {k: v for k, v in geo.items() if k != "points"}
    for k in ("plane", "head", "xhead", "test", "pass_", "point", "cmd", "local", "hvec",
              "time_s"):
        sub[k] = geo[k][rep]
    sub["pattern"] = geo["pattern"][:, rep]
    sub["powers"] = geo["powers"][..., rep]
    sub["distinct"] = tuple((inv[rep], at) for inv, at in geo["distinct"])
    sub["xslices"], sub["n_extra"] = (), 0
    return _Geometry(**sub), np.asarray(spread).reshape(-1)


def _feature_patterns(setup, plane, cmd, local, vdir, time_s, phi, sense, test):
    """Machine-frame displacement of each reading per unit of the 15 drift/reversal/servo
    features (g_x, g_y, g_z [1/h], d_x, d_y, d_z [mm/h], B_x, B_y, B_z [mm],
    T_x, T_y, T_z [s], T_x^2, T_y^2, T_z^2 [s^2]), shape (15, M, 3).

    Thermal growth of axis U: ``g_U (t / 1 h) u_U`` along U; drift: ``d (t / 1 h)``;
    reversal (lost motion) of axis U: ``-B_U / 2 * sign(velocity_U)`` (an axis at rest
    or at a turning point of a circle: 0, the mean of its two states); servo contouring
    error of a circle in the plane of axes (a, b), radial, from first-order position loops
    with following times T (steady state, to second order in omega T, omega = s v / R,
    s = +1 counter-clockwise):
    ``dR = -v^2 / (2 R) (T_a^2 cos^2 phi + T_b^2 sin^2 phi) - s v / 2 (T_b - T_a) sin 2 phi``:
    a radius reduction growing with v^2 / R and the 45-deg ellipse of a gain mismatch
    growing with v. Lines (one axis at constant speed) have no contouring error.
    """
    m = plane.size
    pat = np.zeros((15, m, 3))
    hours = time_s / 3600.0
    eye = np.eye(3)
    for u in range(3):
        pat[u] = (hours * cmd[:, u])[:, None] * eye[u]
        pat[3 + u] = hours[:, None] * eye[u]
        pat[6 + u] = (-0.5 * vdir[:, u])[:, None] * eye[u]
    v = setup.feed_mm_min / 60.0
    R = setup.circle_radius_mm
    circ = test == 2
    for k, (_, a, b, _c) in enumerate(PLANES):
        sel = circ & (plane == k)
        p, s = phi[sel], sense[sel]
        er = np.cos(p)[:, None] * eye[a] + np.sin(p)[:, None] * eye[b]  # radial, machine frame
        quad = -v * v / (2 * R)
        pat[12 + a][sel] += (quad * np.cos(p) ** 2)[:, None] * er
        pat[12 + b][sel] += (quad * np.sin(p) ** 2)[:, None] * er
        pat[9 + a][sel] += (s * v / 2 * np.sin(2 * p))[:, None] * er
        pat[9 + b][sel] += (-s * v / 2 * np.sin(2 * p))[:, None] * er
    return pat


def _to_plate_frame(plane, basis, vec):
    """Machine-frame vectors (..., M, 3) in the plate coordinates of each reading's plane."""
    out = np.empty_like(vec)
    for k in range(3):
        sel = plane == k
        out[..., sel, :] = vec[..., sel, :] @ basis[k]
    return out


def _values(geo: _Geometry, coefs: dict, trig: dict | None = None) -> dict:
    """Function values at the points: name -> (n, M) ((n, 1) for squareness); into `trig`
    the angular ones' (cos, sin): each at its axis's distinct positions, then spread."""
    out = {}
    for name in NAMES:
        powers, coef = coefs[name]
        if _KIND[name] == "sq":
            out[name] = coef[:, :1] * np.ones((1, 1))
        elif powers and max(powers) < geo.powers.shape[1]:
            inv, at = geo.distinct[_AXIS[name]]
            vals = coef @ at[list(powers)]
            out[name] = vals[:, inv]
            if trig is not None and _KIND[name] == "ang" and np.any(vals):
                trig[name] = (np.cos(vals)[:, inv], np.sin(vals)[:, inv])
        else:
            out[name] = polyval(coef, powers, geo.cmd[:, _AXIS[name]])
    return out


def _plane_slices(geo: _Geometry) -> list[slice]:
    bounds = [0, *np.searchsorted(geo.plane, [1, 2]).tolist(), geo.plane.size]
    return [slice(bounds[k], bounds[k + 1]) for k in range(3)]


def _local3(geo: _Geometry, p: np.ndarray) -> np.ndarray:
    """Head positions (n, M, 3) [machine frame] in each plate's nominal frame (n, M, 3)."""
    out = np.empty(p.shape)
    for k, sl in enumerate(_plane_slices(geo)):  # the planes' readings are contiguous
        np.matmul(p[..., sl, :] - geo.origin[k], geo.basis[k], out=out[..., sl, :])
    return out


def _rotation_rows(rot: np.ndarray) -> np.ndarray:
    """First two rows of ``Rinv = (Rx(a) Ry(b) Rz(c))^-1`` per trial: (n, 2, 3) for rot (n, 3)."""
    cols = rotate_inverse(rot[:, None, 0], rot[:, None, 1], rot[:, None, 2], np.eye(3)[None])
    return np.swapaxes(cols, 1, 2)[:, :2, :]


def _mount(geo: _Geometry, loc: np.ndarray, offset: np.ndarray, head: np.ndarray,
           rot: np.ndarray) -> np.ndarray:
    """Plate readings from plate-frame positions, exactly: ``Rinv(rot) (loc - (shift, 0))``
    with the shift the plate's offset less an extra head's setting error, (n, M, 2).

    Parameters
    ----------
    loc : array (n or 1, M, 3)
        Head position in the plate's nominal frame [mm].
    offset : array (n, 3, 2)
        In-plane offset of each plate [mm].
    head : array (n, n_extra, 2)
        In-plane setting error of each extra head position [mm].
    rot : array (n, 3, 3)
        Rotation of each plate [rad]: tilt about its u axis, tilt about its v axis,
        rotation about its normal (applied as Rx Ry Rz in plate coordinates).
    """
    n = max(loc.shape[0], rot.shape[0])
    if not np.any(rot):  # Rinv's rows are exactly (1, 0, 0), (0, 1, 0): the shifts alone
        out = np.array(np.broadcast_to(loc[:, :, :2], (n, loc.shape[1], 2)))
        for k, sl in enumerate(_plane_slices(geo)):
            out[:, sl, :] -= offset[:, None, k, :]
        for e, (_k, sl) in enumerate(geo.xslices):
            out[:, sl, :] += head[:, None, e, :]
        return out
    out = np.empty((n, loc.shape[1], 2))
    rows = []
    for k, sl in enumerate(_plane_slices(geo)):
        m = _rotation_rows(rot[:, k])  # (n, 2, 3)
        rows.append(m)
        np.matmul(loc[:, sl, :], np.swapaxes(m, 1, 2), out=out[:, sl, :])
        out[:, sl, :] -= (m[:, :, :2] @ offset[:, k, :, None])[:, None, :, 0]
    for e, (k, sl) in enumerate(geo.xslices):
        out[:, sl, :] += (rows[k][:, :, :2] @ head[:, e, :, None])[:, None, :, 0]
    return out


def _grid_basis(geo: _Geometry) -> np.ndarray:
    """Basis of the plates' grid-error field at the nominal readings, shape (M, K)."""
    u, v = geo.local[:, 0] / PLATE_RADIUS_MM, geo.local[:, 1] / PLATE_RADIUS_MM
    return np.column_stack([u**i * v**j for i, j in _GRID_POWERS])


# --------------------------------------------------------------------------- protocol
def measurands(setup: Setup) -> tuple[Measurand, ...]:
    """The measurands the data determine at this set-up (see :func:`identifiability`)."""
    ident = _joint_ident(setup)
    out = []
    for name, kind, axis, comp in FUNCTIONS:
        if not ident["estimable"][name]:
            continue
        unit = "urad" if kind in ("ang", "sq") else "um"
        text = _DESCR[kind].format(ax="XYZ"[axis], comp="XYZ"[comp], rot=_ROT[comp])
        if kind != "sq":
            text += f", at {'xyz'[axis]} = +{setup.line_length_mm / 2:g} mm"
        out.append(Measurand(name, unit, text))
    return tuple(out)


def sources(setup: Setup) -> dict:
    """Every error source of the test (switched off by a size of 0)."""
    geo = _geometry(setup)
    m = geo.plane.size
    k = len(_GRID_POWERS)
    lag = setup.servo_lag_ms * 1e-3
    return {
        "encoder_noise": Source(
            Normal(0.0, setup.encoder_noise_um * 1e-3), (m, 2),
            "Reading noise of the 2D grid encoder, each component of each reading. Default "
            "0.05 um: assumed for a KGM 182 read on the fly at 500 mm/min (signal period "
            "4 um, interpolated to nm resolution; the maker states no dynamic noise)."),
        "grid_error": Source(
            Normal(0.0, setup.grid_error_um * 1e-3 / math.sqrt(k)), (3, 2, k),
            "The grid plate's own error: per set-up, a smooth field cubic in the plate "
            "coordinates (u/70 mm, v/70 mm), each component with random coefficients whose "
            "root-sum-square is grid_error_um (1 um: the KGM 182 accuracy grade is +-2 um, "
            "read as a bound). Its linear part (scale, shear) biases positioning and "
            "squareness as a real plate's does."),
        "plate_offset": Source(
            Normal(0.0, setup.plate_offset_mm), (3, 2),
            "Plate mounting: in-plane offset of the plate centre from the test centre in "
            "each of the three set-ups (0.05 mm: centring by dial indicator, assumed). A "
            "nuisance the estimators remove."),
        "plate_tilt": Source(
            Normal(0.0, setup.plate_tilt_urad * 1e-6), (3, 3),
            "Plate mounting: tilt about the plate's two axes and rotation about its normal "
            "in each set-up (100 urad = 0.1 mm/m alignment, assumed). The rotation is a "
            "nuisance the estimators remove; the tilts act at second order (cosine error)."),
        "head_setting": Source(
            Normal(0.0, setup.head_setting_um * 1e-3 if geo.n_extra else 0.0), (geo.n_extra, 2),
            "In-plane position of each extra head position after the change (tool length "
            "from a presetter, lateral offset of the bracket): 10 um each component, assumed "
            "(presetters read tool length to 2-5 um; a bracket's offset is known to ~10 um). "
            "A nuisance the estimators remove; off without extra heads."),
        "repeatability": Source(
            Normal(0.0, setup.repeatability_um * 1e-3), (m, 2),
            "The machine's non-repeatable path deviation at each reading point, each "
            "in-plane component, independent between passes and correlated along each pass: "
            "the source's elements are the innovations of an AR(1) process in the path "
            "length, readings s mm apart correlating by exp(-s / repeatability_correlation_mm) "
            "(standard deviation repeatability_um at every reading), so reading a pass more "
            "densely adds readings, not independent information. Default 0.3 um: "
            "ISO 230-2 unidirectional repeatability R = 4 s of about 1.2 um, typical of a "
            "machining centre with linear scales (data sheets: R 1-3 um). Default correlation "
            "length 50 mm: the path deviations of a contouring machine are low-frequency "
            "(ISO 230-4: the servo's and the guideways' deviations span tens of millimetres, "
            "several ball-screw pitches of 10-20 mm), not white from one reading to the next; "
            "0 gives independent readings."),
        "path_residual": Source(
            Normal(0.0, setup.path_residual_um * 1e-3), (3, 3, _residual_knots(geo)[1]),
            "The machine's repeatable path deviation beyond the fitted polynomials: for each "
            "axis (X, Y, Z) and each direction of the tool's deviation (x, y, z), a random "
            "function of the axis's commanded position, correlated over 5 mm (AR(1) over "
            "knots 2.5 mm apart, linearly interpolated; the elements are its innovations), "
            "RMS path_residual_um. A function of position, so every pass (repeat, direction, "
            "head) sees the same; the polynomials cannot follow it, so the error of "
            "truncating the model enters u. The measurands are the smooth (polynomial) part "
            "of each error function. Default 0.3 um: the short-wave part of ISO 230-1 "
            "straightness and ISO 230-2 positioning records of a machining centre with linear "
            "scales (periodic deviations of ball-screw drives and guideway waviness of "
            "0.2-1 um over 5-20 mm), assumed."),
        "reversal": Source(
            Rectangular(0.0, 2e-3 * setup.reversal_um), (3,),
            "Reversal value (lost motion) B of each axis, drawn uniform on [0, 2 reversal_um] "
            "(mean reversal_um, never negative): moving in +U the axis lags by B/2, moving in "
            "-U it leads by B/2, so the back-and-forth lines and the quadrants of the "
            "circles see it. Default 2 um: ISO 230-2 reversal value of a machining centre "
            "with linear scales (data sheets 1-3 um; with rotary encoders 3-10 um)."),
        "servo_lag": Source(
            Normal(lag, SERVO_MISMATCH * lag), (3,),
            "Following time T = 1/Kv of each axis's position loop, drawn with 10 % spread "
            "about servo_lag_ms (the mismatch of tuned gains): the contouring error of the "
            "circles, a radius reduction v^2 T^2 / (2 R) and a 45-deg ellipse of amplitude "
            "v (T_b - T_a) / 2 that changes sign with the direction (ISO 230-4 Annex). "
            "Default 2 ms: the effective following time with velocity feed-forward, assumed "
            "(without it Kv = 1-3 (m/min)/mm, T = 20-60 ms); at 500 mm/min the ellipse is "
            "about 1 um."),
        "thermal_growth": Source(
            Normal(0.0, setup.thermal_growth_ppm_per_h * 1e-6), (3,),
            "Rate of change of each axis's scale during the test (thermal expansion of the "
            "scale or ball screw), linear in the test's time: the positioning error grows "
            "by g t u. Default 2 ppm/h: a workshop's temperature change of ~0.2 K/h on "
            "steel/cast iron (11.5 ppm/K), the order of ISO 230-3 environmental drift "
            "tests of machining centres."),
        "thermal_drift": Source(
            Normal(0.0, setup.thermal_drift_um_per_h * 1e-3), (3,),
            "Rate of the head's drift relative to the plate during the test (spindle and "
            "column growth), each component, linear in the test's time. Default 2 um/h: the "
            "order of ISO 230-3 drift of a warmed-up machining centre at rest (2-10 um over "
            "several hours, most in Z)."),
    }


def _features(errors: dict) -> np.ndarray | None:
    """The 15 per-trial features of :func:`_feature_patterns`, or None when all are zero."""
    t = errors["servo_lag"]
    f = np.concatenate([errors["thermal_growth"], errors["thermal_drift"], errors["reversal"],
                        t, t * t], axis=1)
    return f if np.any(f) else None


def forward(setup: Setup, truth: Truth, errors: dict) -> dict:
    """Readings of the plates in the three set-ups, exact rigid-body model.

    Returns
    -------
    dict with ``plate_mm``: array (n, M, 2), the head's in-plane position in each plate's
    frame, relative to the plate's nominal origin [mm]; the point order is that of
    :func:`readings_frame`.
    """
    geo = _geometry(setup)
    n = errors["encoder_noise"].shape[0]
    feat = _features(errors)
    if _rows(truth) is not None:  # one truth per batch row (a posterior's walkers)
        loc = _truth_positions(geo, _truth_coefficients(truth)).reshape(n, -1)
        if feat is not None:
            loc = loc + feat @ geo.pattern.reshape(15, -1)
        loc = loc.reshape(n, -1, 3)
    elif feat is None:
        loc = _forward_matrix(setup, truth)[:1].reshape(1, -1, 3)
    else:  # drift, reversal and servo: one product for the batch
        base = _forward_matrix(setup, truth)  # (16, 3M): the truth's positions, then patterns
        loc = (np.column_stack([np.ones(n), feat]) @ base).reshape(n, -1, 3)
    r = _mount(geo, loc, errors["plate_offset"], errors["head_setting"], errors["plate_tilt"])
    g = errors["grid_error"]  # (n, 3, 2, K)
    if np.any(g):
        basis = _grid_basis(geo)
        for k, sl in enumerate(_plane_slices(geo)):
            r[:, sl, :] += np.swapaxes(g[:, k] @ basis[sl].T, 1, 2)
    res = errors["path_residual"]
    if np.any(res):  # the same function of position in every pass: one product
        r += (res.reshape(n, -1) @ _residual_basis(_sizeless(setup)).T).reshape(n, -1, 2)
    r += errors["encoder_noise"]
    e = errors["repeatability"]
    if np.any(e):
        f = _repeatability_filter(setup)
        if f is None:
            r += e
        else:  # the AR(1) process along each pass: one sparse product for the batch
            n_, m_, _ = e.shape
            r += (f @ np.moveaxis(e, 1, 0).reshape(m_, -1)).reshape(m_, n_, 2).swapaxes(0, 1)
    return {"plate_mm": r}


@functools.lru_cache(maxsize=8)
def _forward_matrix(setup: Setup, truth: Truth) -> np.ndarray:
    """The truth's head positions in the plates' frames and the 15 feature patterns of
    :func:`_feature_patterns`, stacked (16, 3M): ``[1, features] @ it`` is every reading's
    plate-frame position."""
    geo = _geometry(setup)
    coefs = {k: (pw, c[None, :]) for k, (pw, c) in _truth_coefficients(truth).items()}
    return np.concatenate([_truth_positions(geo, coefs).reshape(1, -1),
                           geo.pattern.reshape(15, -1)])


def _truth_positions(geo: _Geometry, coefs: dict) -> np.ndarray:
    """Head positions (n, M, 3) in the plates' frames for coefficients (n, L) per function,
    exact: the chain evaluated once per distinct point (:func:`_points`), the same numbers
    spread to every reading."""
    sub, spread = geo.points
    trig: dict = {}
    p = chain(_values(sub, coefs, trig), *sub.cmd.T, sub.hvec, sub.ref, trig)
    return np.take(_local3(sub, p), spread, axis=1)


def true_values(setup: Setup, truth: Truth) -> dict:
    """Each listed measurand's true value (function at u = +line_length/2) [mm or rad]."""
    u = setup.line_length_mm / 2
    coefs = _truth_coefficients(truth)
    listed = {m.name for m in measurands(setup)}
    out = {name: (np.sum(c * u ** np.array(pw), axis=-1) if _KIND[name] != "sq" else c[..., 0])
           for name, (pw, c) in coefs.items() if name in listed}
    return {k: float(v) if np.ndim(v) == 0 else v for k, v in out.items()}  # arrays: batch rows


def duration(setup: Setup) -> float:
    """Machine time [s]: three plate set-ups, the head changes, the line and circle passes
    of every head position at ``feed_mm_min`` (the schedule that times each reading)."""
    return _geometry(setup).duration_s


def readings_frame(setup: Setup, readings: dict) -> pd.DataFrame:
    """One measurement (the first trial) as a tidy table, one reading point per row.

    Columns: ``plane`` (XY, XZ, YZ), ``head`` (0: the first head position, 1, 2, ...: the
    plane's extra head positions in the order of the set-up's list), ``test`` (line_a,
    line_b: along the plane's first or second axis; circle), ``pass`` (line: 2*repeat +
    direction; circle: 0 CCW, 1 CW), ``point``, the commanded ``x_mm``, ``y_mm``,
    ``z_mm``, and the plate readings ``u_mm``, ``v_mm`` (head position along the plate's
    first and second axis, relative to the plate's nominal origin). Tables without the
    ``head`` column (written before head positions existed) are read as all head 0.
    """
    geo = _geometry(setup)
    r = np.asarray(readings["plate_mm"])[0]
    return pd.DataFrame({
        "plane": np.array([p[0] for p in PLANES])[geo.plane],
        "head": geo.head,
        "test": np.array(_TEST_NAMES)[geo.test],
        "pass": geo.pass_,
        "point": geo.point,
        "x_mm": geo.cmd[:, 0], "y_mm": geo.cmd[:, 1], "z_mm": geo.cmd[:, 2],
        "u_mm": r[:, 0], "v_mm": r[:, 1],
    })


def from_frame(setup: Setup, df: pd.DataFrame) -> dict:
    """Readings (a batch of one) from a table in the format of :func:`readings_frame`."""
    geo = _geometry(setup)
    need = ["plane", "test", "pass", "point", "x_mm", "y_mm", "z_mm", "u_mm", "v_mm"]
    missing = [c for c in need if c not in df.columns]
    if missing:
        raise InvalidInput([f"The geometry21 readings table lacks the column(s) "
                            f"{', '.join(missing)}; it needs {', '.join(need)} (and head)."])
    if len(df) != geo.plane.size:
        raise InvalidInput([f"The geometry21 readings table must have {geo.plane.size} rows "
                            f"for this set-up. Got {len(df)} instead."])
    problems = []
    if "head" not in df.columns and geo.n_extra:
        problems.append("The geometry21 readings table needs a 'head' column: this set-up "
                        f"has {geo.n_extra} extra head position(s).")
    for col in need[4:]:
        vals = pd.to_numeric(df[col], errors="coerce").to_numpy(dtype=float)
        bad = np.flatnonzero(~np.isfinite(vals))
        if bad.size:
            problems.append(f"The '{col}' column of the geometry21 readings must be finite "
                            f"numbers. Got {df[col].iloc[bad[0]]!r} in row {int(bad[0])} instead.")
    order = [("plane", np.array([p[0] for p in PLANES])[geo.plane]),
             ("test", np.array(_TEST_NAMES)[geo.test])]
    if "head" in df.columns:
        order.append(("head", geo.head.astype(str)))
    for col, expect in order:
        got = df[col].astype(str).to_numpy()
        if col == "head":
            got = np.array([g[:-2] if g.endswith(".0") else g for g in got])
        bad = np.flatnonzero(got != expect)
        if bad.size:
            problems.append(f"The '{col}' column of the geometry21 readings must follow the "
                            f"set-up's order; row {int(bad[0])} has {df[col].iloc[bad[0]]!r}, "
                            f"expected {expect[bad[0]]!r}.")
    if problems:
        raise InvalidInput(problems)
    cmd = df[["x_mm", "y_mm", "z_mm"]].to_numpy(dtype=float)
    bad = np.flatnonzero(np.any(np.abs(cmd - geo.cmd) > 1e-6, axis=1))
    if bad.size:
        raise InvalidInput([f"The commanded positions of the geometry21 readings do not match "
                            f"the set-up; row {int(bad[0])} has {cmd[bad[0]].tolist()}, "
                            f"expected {geo.cmd[bad[0]].tolist()}."])
    r = df[["u_mm", "v_mm"]].to_numpy(dtype=float)
    return {"plate_mm": r[None, :, :]}


# --------------------------------------------------------------------------- linear model
_GN_ITERATIONS = 8
_GN_TOL = 1e-5  # step below 1e-5 of a typical error (1 um / 10 urad): 0.01 pm
_RANK_TOL = 1e-7
#: the shared linearisation's neglected term may move a trial by 1e-3 of a typical error,
#: or by 1 % of the batch's spread of that parameter (its Monte Carlo uncertainty), at most
_SHARED_TOL = 1e-3
_SHARED_SPREAD = 0.01
#: smaller batches (a measurement is a batch of one) are solved trial by trial
_SHARED_MIN = 8
#: grid of the shared linearisation point of the coefficients [typical errors]
_GRID_STEP = 10.0


def _scales(geo: _Geometry) -> np.ndarray:
    """Typical size of each parameter: 1 um or 10 urad at the end of the travel;
    1 um and 10 urad for the plates' offsets and rotations, 1 um for the heads' settings."""
    s = np.empty(geo.n_par)
    t = geo.u_end
    for name in NAMES:
        powers, sl = geo.layout[name]
        typ = 1e-5 if _KIND[name] in ("ang", "sq") else 1e-3
        s[sl] = [typ / t**k for k in powers]
    s[geo.n_coef: geo.n_coef + 9] = np.tile([1e-3, 1e-3, 1e-5], 3)
    s[geo.n_coef + 9:] = 1e-3
    return s


def _nuisance(geo: _Geometry, theta: np.ndarray):
    """(plate offsets (n, 3, 2), plate rotations (n, 3), head settings (n, n_extra, 2))."""
    n = theta.shape[0]
    plate = theta[:, geo.n_coef: geo.n_coef + 9].reshape(n, 3, 3)
    return plate[:, :, :2], plate[:, :, 2], theta[:, geo.n_coef + 9:].reshape(n, -1, 2)


def _predict(geo: _Geometry, theta: np.ndarray) -> np.ndarray:
    """Noise-free readings (n, M, 2) for parameters theta (n, n_par), exact model."""
    n = theta.shape[0]
    coefs = {name: (pw, theta[:, sl]) for name, (pw, sl) in geo.layout.items()}
    offset, turn, head = _nuisance(geo, theta)
    rot = np.zeros((n, 3, 3))
    rot[:, :, 2] = turn
    return _mount(geo, _truth_positions(geo, coefs), offset, head, rot)


def _measurand_map(geo: _Geometry) -> np.ndarray:
    """g (21, n_par): measurand = g @ theta (function at u = +line_length/2)."""
    g = np.zeros((len(NAMES), geo.n_par))
    for i, name in enumerate(NAMES):
        powers, sl = geo.layout[name]
        g[i, sl] = [geo.u_end**k for k in powers]
    return g


def _param_names(geo: _Geometry) -> list[str]:
    names = [None] * geo.n_par
    for name, (powers, sl) in geo.layout.items():
        for j, k in zip(range(sl.start, sl.stop), powers):
            names[j] = f"{name}[{k}]"
    for k, (pl, *_rest) in enumerate(PLANES):
        for j, what in enumerate(("offset_u", "offset_v", "rotation")):
            names[geo.n_coef + 3 * k + j] = f"{pl}.{what}"
    for e in range(geo.n_extra):
        sel = np.flatnonzero(geo.xhead == e)[0]
        pl, j = PLANES[geo.plane[sel]][0], geo.head[sel]
        names[geo.n_coef + 9 + 2 * e] = f"{pl}.head{j}.offset_u"
        names[geo.n_coef + 10 + 2 * e] = f"{pl}.head{j}.offset_v"
    return names


def _tpinv(a: np.ndarray, scale: np.ndarray, free: np.ndarray | None = None):
    """:func:`mtplan.fitting.linear.truncated_pinv` at this module's rank tolerance: the
    mounting (`free`) takes what it can absorb, which keeps unseen errors (the X roll EAX,
    seen only as a rotation of the YZ pattern) from growing to the size of the mounting
    errors in the exact, non-linear model."""
    return truncated_pinv(a, scale, free, rank_tol=_RANK_TOL)


def _free(geo: _Geometry) -> np.ndarray:
    """Mask of the nuisance (mounting) parameters."""
    return np.arange(geo.n_par) >= geo.n_coef


def _jacobian(geo: _Geometry, theta0: np.ndarray, s: np.ndarray):
    """(f(theta0) (2M,), J (2M, P)) by central differences of the exact model, steps 0.1 s."""
    def predict(rows):
        return _predict(geo, rows).reshape(rows.shape[0], -1)

    return predict(theta0[None, :])[0], central_jacobian(predict, theta0, 0.1 * s)


@functools.lru_cache(maxsize=16)
def _joint_ident(setup: Setup) -> dict:
    """Jacobian of the readings at zero error, its SVD, pseudo-inverse and estimability:
    the geometry's (:func:`_joint_geometry`) with the fit's weights (``pinv``)."""
    return _Ident(_joint_geometry(_sizeless(setup)), setup)


class _Ident(dict):
    """:func:`_joint_geometry`'s dict; the pseudo-inverses ``pinv0`` (unweighted) and
    ``pinv`` (the joint fit's: generalised least squares where the readings correlate along
    each pass) are computed when first asked for (the patent's first order needs neither)."""

    def __init__(self, base: dict, setup: Setup):
        super().__init__(base)
        self.setup = setup

    def __missing__(self, key):
        s = self.setup
        if key == "pinv0":
            self[key] = _tpinv(self["jac"], self["scale"], _free(self["geo"]))[0]
        elif key == "pinv" and _reading_whitener(s) is None:
            self[key] = self["pinv0"]
        elif key == "pinv":
            self[key] = _gls(_sizeless(s), _weight_ratios(s))
        else:
            raise KeyError(key)
        return self[key]


@functools.lru_cache(maxsize=8)
def _joint_geometry(key: Setup) -> dict:
    """What does not depend on the sources' sizes: the Jacobian (closed form,
    :func:`._maps.zero_jacobian`), its SVD, null space and the measurands' estimability."""
    from mtplan.models.geometry21._maps import zero_jacobian

    geo = _geometry(key)
    s = _scales(geo)
    r0, jac = _predict(geo, np.zeros((1, geo.n_par))).reshape(-1), zero_jacobian(geo)
    a_s = jac * s  # the SVD as truncated_pinv's (tall: of the QR's R)
    _, sv, vt = np.linalg.svd(np.linalg.qr(a_s, mode="r")) if a_s.shape[0] > a_s.shape[1] \
        else np.linalg.svd(a_s, full_matrices=False)
    rank = int(np.sum(sv > _RANK_TOL * sv[0])) if sv.size and sv[0] > 0 else 0
    null = vt[rank:]  # scaled null space (k, P)
    colnorm = np.linalg.norm(a_s, axis=0)
    dead = colnorm <= _RANK_TOL * sv[0]
    if null.size and np.any(dead):  # the null space's basis: each parameter without effect
        rest = np.where(dead, 0.0, null)  # alone (its column is exactly 0), then the others
        _, sv_r, vt_r = np.linalg.svd(rest, full_matrices=False)
        null = np.concatenate([vt_r[sv_r > 1e-8], np.eye(geo.n_par)[dead]])
    g = _measurand_map(geo)
    gs = g * s
    resid = np.linalg.norm(gs @ null.T, axis=1) / np.linalg.norm(gs, axis=1) if null.size else \
        np.zeros(len(NAMES))
    no_effect = {name: bool(np.all(colnorm[sl] <= _RANK_TOL * sv[0]))
                 for name, (_, sl) in geo.layout.items()}
    return {"geo": geo, "jac": jac, "scale": s, "rank": rank, "sv": sv,
            "null": null, "vt": vt, "g": g, "no_effect": no_effect, "r0": r0,
            "estimable": {n: bool(r < 1e-6) for n, r in zip(NAMES, resid)}}


@functools.lru_cache(maxsize=16)
def _gls(key: Setup, ratios: tuple) -> np.ndarray:
    ji = _joint_geometry(key)
    return gls_pinv(ji["jac"], ji["scale"], ji["vt"], ji["rank"], _free(ji["geo"]),
                    _whitening(key, *ratios))


def _readings_matrix(setup: Setup, readings: dict) -> np.ndarray:
    geo = _geometry(setup)
    r = np.asarray(readings["plate_mm"], dtype=float)
    if r.ndim != 3 or r.shape[1:] != (geo.plane.size, 2):
        raise InvalidInput([f"The 'plate_mm' readings of geometry21 must have shape "
                            f"(trials, {geo.plane.size}, 2) for this set-up. Got {r.shape} instead."])
    return r.reshape(r.shape[0], -1)


def _grid_step(geo: _Geometry) -> np.ndarray:
    """Grid of the shared linearisation points of the coefficients [their units]."""
    return _GRID_STEP * _scales(geo)[: geo.n_coef]


@functools.lru_cache(maxsize=8)
def _linearisation(setup: Setup, key: tuple) -> dict:
    """The Jacobian ``jac`` (2M, P), its pseudo-inverse ``pinv`` and the pieces of
    :class:`_Unmounted` at the coefficients of the grid point `key` (ints, one per
    coefficient) with no mounting error.

    A pure function of the set-up and the grid point, so that a batch's result never
    depends on which batches ran before (the cache only saves time).
    """
    ji = _joint_ident(setup)
    geo, s = ji["geo"], ji["scale"]
    if any(key):
        c = np.asarray(key, dtype=float) * _grid_step(geo)
        _, jac = _jacobian(geo, np.concatenate([c, np.zeros(geo.n_par - geo.n_coef)]), s)
        w = _reading_whitener(setup)
        pinv = restricted_pinv(jac, s, ji["vt"], ji["rank"], _free(geo)) if w is None else \
            gls_pinv(jac, s, ji["vt"], ji["rank"], _free(geo), w)
    else:
        jac, pinv = ji["jac"], ji["pinv"]
    npar = geo.n_par
    p3 = pinv.reshape(npar, -1, 2)
    split, plate = [], np.empty((npar, 3, 2))
    for k, sl in enumerate(_plane_slices(geo)):
        pk = p3[:, sl, :]
        quarter = np.stack([pk[..., 1], -pk[..., 0]], axis=-1)  # P G: G (u, v) = (-v, u)
        split.append(np.ascontiguousarray(np.concatenate([pk, quarter]).reshape(2 * npar, -1)))
        plate[:, k] = pk.sum(axis=1)
    head = np.stack([p3[:, sl, :].sum(axis=1) for _, sl in geo.xslices], axis=1) \
        if geo.n_extra else np.zeros((npar, 0, 2))
    return {"jac": jac, "pinv": pinv, "split": split, "plate": plate.reshape(npar, -1),
            "head": head.reshape(npar, -1), "coef_response": pinv @ jac[:, : geo.n_coef]}


def _plate_model(geo: _Geometry, coef: np.ndarray) -> np.ndarray:
    """Exact readings (n, 2M) of coefficients (n, n_coef) with the plates and heads as set."""
    theta = np.zeros((coef.shape[0], geo.n_par))
    theta[:, : geo.n_coef] = coef
    return _predict(geo, theta).reshape(coef.shape[0], -1)


class _Unmounted:
    """``pinv @ (R(rotation) r + shift)``: the readings brought back to the nominal plate
    frame with each trial's own mounting estimate and projected on the parameters, for any
    mounting. The rotation is per plane, so ``P R(phi) r = cos(phi) P r + sin(phi) P G r``
    (G the quarter turn): one product for the batch per plane serves every iteration."""

    def __init__(self, geo: _Geometry, r: np.ndarray, lin: dict):
        n, npar = r.shape[0], lin["pinv"].shape[0]
        self.geo, self.lin = geo, lin
        self.y = np.empty((n, 3, npar))
        self.z = np.empty((n, 3, npar))
        for k, sl in enumerate(_plane_slices(geo)):
            yz = r[:, 2 * sl.start: 2 * sl.stop] @ lin["split"][k].T
            self.y[:, k], self.z[:, k] = yz[:, :npar], yz[:, npar:]

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        offset, turn, head = _nuisance(self.geo, theta)
        n = theta.shape[0]
        out = np.einsum("nk,nkp->np", np.cos(turn), self.y)
        out += np.einsum("nk,nkp->np", np.sin(turn), self.z)
        out += offset.reshape(n, -1) @ self.lin["plate"].T
        out -= head.reshape(n, -1) @ self.lin["head"].T
        return out


def _theta_joint_per_trial(setup: Setup, readings: dict) -> np.ndarray:
    """The former joint estimate (chord Gauss-Newton with the exact model evaluated for every
    trial in every iteration), kept as the reference of :func:`_theta_joint`'s speed-up."""
    ji = _joint_ident(setup)
    geo, pinv, s = ji["geo"], ji["pinv"], ji["scale"]
    r = _readings_matrix(setup, readings)
    theta = (r - ji["r0"]) @ pinv.T
    for _ in range(_GN_ITERATIONS):
        step = (r - _predict(geo, theta).reshape(r.shape)) @ pinv.T
        theta = theta + step
        if np.max(np.abs(step) / s) < _GN_TOL:  # whole batch converged
            break
    return theta


def _theta_joint(setup: Setup, readings: dict, iterations: int) -> np.ndarray:
    """Joint least squares; Gauss-Newton with one linearisation for the batch.

    The model is ``r = R(-rotation) (L(c) - shift)`` per plate: a rigid plate transform,
    which each trial undoes exactly with its own estimate (:class:`_Unmounted`), after the
    machine's error model L of the coefficients c, whose non-linearity is weak and is
    shared: L is evaluated exactly at the batch's median coefficients c_m and expanded to
    first order about it (``L(c) = L(c_m) + J_c (c - c_m)``). Chord iterations (the
    Jacobian at the grid point next to c_m towards zero, see :func:`_linearisation`) until every
    trial's step is below 1e-5 of a typical error; then the neglected second-order term
    is evaluated exactly for the trials farthest from c_m, and if its correction exceeds
    both 1e-3 of a typical error and 1 % of the batch's spread of that parameter (or the
    iterations did not converge), the batch is solved again with L evaluated exactly for
    every trial, as are batches of fewer than 8 trials.
    """
    ji = _joint_ident(setup)
    geo, s = ji["geo"], ji["scale"]
    nc = geo.n_coef
    r = _readings_matrix(setup, readings)
    lin = _linearisation(setup, (0,) * nc)
    unmounted = _Unmounted(geo, r, lin)
    # the linear estimate, (r - r0) @ pinv.T, from the same products
    theta = unmounted.y.sum(axis=1) - ji["pinv"] @ ji["r0"]
    if iterations == 0:
        return theta
    key = tuple(int(k) for k in np.trunc(np.median(theta[:, :nc], axis=0) / _grid_step(geo)))
    if any(key):
        lin = _linearisation(setup, key)
        unmounted = _Unmounted(geo, r, lin)
    jac, pinv, b = lin["jac"], lin["pinv"], lin["coef_response"]

    def solve(theta, shared):
        for _ in range(iterations):
            if shared:  # the exact model once, at the median; first order about it
                c_m = np.median(theta[:, :nc], axis=0)
                model = _plate_model(geo, c_m[None, :])
                step = unmounted(theta) - model @ pinv.T - (theta[:, :nc] - c_m) @ b.T
            else:
                step = unmounted(theta) - _plate_model(geo, theta[:, :nc]) @ pinv.T
            theta = theta + step
            if np.max(np.abs(step) / s) < _GN_TOL:
                return theta, (c_m, model) if shared else None
        return theta, None

    if r.shape[0] < _SHARED_MIN:
        return solve(theta, False)[0]
    out, at = solve(theta, True)
    if at is not None:  # the term left out, exactly, where it is largest
        c_m, model = at
        dev = np.abs(out[:, :nc] - c_m) / s[:nc]
        far = np.unique([*np.argsort(dev.max(axis=1))[-3:],
                         int(np.argmax(np.linalg.norm(dev, axis=1)))])
        lin = model + (out[far, :nc] - c_m) @ jac[:, :nc].T
        left = (_plate_model(geo, out[far, :nc]) - lin) @ pinv.T
        allowed = np.maximum(_SHARED_TOL * s, _SHARED_SPREAD * np.std(out, axis=0))
        if np.all(np.abs(left) <= allowed):
            return out
    return solve(out, False)[0]


def _estimate_theta(setup: Setup, readings: dict, estimator: str) -> np.ndarray:
    if estimator == "patent":
        return _theta_patent(setup, readings)
    if estimator == "joint":
        return _theta_joint(setup, readings, _GN_ITERATIONS)
    if estimator == "joint_linear":
        return _theta_joint(setup, readings, 0)
    raise InvalidInput([f"The 'estimator' parameter of geometry21 must be one of 'patent', "
                        f"'joint', 'joint_linear'. Got {estimator!r} instead."])


def _measure(setup: Setup, theta: np.ndarray) -> dict:
    ji = _joint_ident(setup)
    listed = {m.name for m in measurands(setup)}
    vals = theta @ ji["g"].T
    return {name: vals[:, i] for i, name in enumerate(NAMES) if name in listed}


def estimate_patent(setup: Setup, readings: dict) -> dict:
    """The patent's stepwise estimator (lines, then circles); measurands [mm, rad], (n,)."""
    return _measure(setup, _theta_patent(setup, readings))


def estimate_joint(setup: Setup, readings: dict) -> dict:
    """Joint least squares of all coefficients, Gauss-Newton refined; [mm, rad], (n,)."""
    return _measure(setup, _theta_joint(setup, readings, _GN_ITERATIONS))


def estimate_joint_linear(setup: Setup, readings: dict) -> dict:
    """Joint linearised least squares (one matrix product); [mm, rad], (n,)."""
    return _measure(setup, _theta_joint(setup, readings, 0))


ESTIMATORS = {"patent": estimate_patent, "joint": estimate_joint,
              "joint_linear": estimate_joint_linear}
#: each estimator as the documents describe it (plain words, jargon spelled out)
_DESCRIPTIONS = {
    "patent": "The source method's stepwise evaluation: straight lines first, then circles.",
    "joint": "Least squares of all error coefficients at once, refined by Gauss-Newton "
             "iteration.",
    "joint_linear": "Least squares of all error coefficients at once, linearised (one matrix "
                    "product).",
}


# --------------------------------------------------------------------------- reports
def _check_estimator(estimator: str) -> None:
    if estimator not in ESTIMATORS:
        raise InvalidInput([f"The 'estimator' parameter of geometry21 must be one of "
                            f"{', '.join(map(repr, ESTIMATORS))}. Got {estimator!r} instead."])


def coefficients(setup: Setup, readings: dict, *, estimator: str = "joint") -> dict:
    """Estimated coefficients of every error function.

    Returns
    -------
    dict of name -> (powers, array (n, K)) [mm/mm^k or rad/mm^k]; unidentifiable
    functions are present with the value the estimator's null-space convention gives them
    (the joint fits: the error coefficients' smallest norm, the mounting taking what it can)
    and must be read with :func:`identifiability` (the data do not determine them).
    """
    _check_estimator(estimator)
    theta = _estimate_theta(setup, readings, estimator)
    geo = _geometry(setup)
    return {name: (pw, theta[:, sl]) for name, (pw, sl) in geo.layout.items()}


# the patent's stepwise estimator, then the first-order uncertainty, identifiability and
# report extras (on the shared fitting machinery); below what they use, re-exported here
from mtplan.models.geometry21._patent import _patent_design, _theta_patent  # noqa: E402
from mtplan.models.geometry21._path import (  # noqa: E402
    RESIDUAL_CORRELATION_MM,
    RESIDUAL_KNOT_MM,
    _pass_lengths,
    _reading_whitener,
    _repeatability_filter,
    _residual_basis,
    _residual_knots,
    _weight_ratios,
    _whitening,
)
from mtplan.models.geometry21._first_order import (  # noqa: E402
    budget,
    coefficient_covariance,
    error_bands,
    error_functions,
    first_order_std,
    identifiability,
    identifiability_report,
    noise_free_table,
    report_extras,
    sensitivities,
)
from mtplan.models.geometry21._frames import setup_from_frame  # noqa: E402


PROCEDURE = Procedure(
    name="geometry21",
    title="21 geometric errors of a three-axis machine from a 2D grid encoder",
    Setup=Setup,
    Truth=Truth,
    measurands=measurands,
    sources=sources,
    forward=forward,
    estimators={name: Estimator(fn, description=_DESCRIPTIONS[name], exact=name == "joint")
                for name, fn in ESTIMATORS.items()},
    true_values=true_values,
    duration=duration,
    description=__doc__.split("\n\n")[0] if __doc__ else "",
    levers=tuple("poly_order line_length_mm line_repeats line_points circle_radius_mm "
                 "circle_points circle_arc_deg head_offset_mm head_lateral_mm "
                 "xy_plane_z_mm xz_plane_y_mm yz_plane_x_mm feed_mm_min xy_extra_heads_mm "
                 "xz_extra_heads_mm yz_extra_heads_mm extra_head_tests".split()),
    readings=ReadingsFormat(readings_frame, from_frame, setup_from_frame=setup_from_frame,
                            optional_columns=("head",)),
    capabilities=Capabilities(block_size=128, identifiability_report=identifiability_report,
                              report_extras=report_extras, identifiability=identifiability,
                              first_order_sensitivities=sensitivities),
)
