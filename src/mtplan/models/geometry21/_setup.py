"""geometry21's set-up and truth: the 21 error functions' names and kinds, the planes,
the :class:`Setup` of the test and the :class:`Truth` of the machine's errors.
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass

import numpy as np

from mtplan._validate import Problems
from mtplan.models.protocol import SetupBase, param


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
KIND = {f[0]: f[1] for f in FUNCTIONS}
AXIS = {f[0]: f[2] for f in FUNCTIONS}
DESCR = {
    "pos": "positioning error of the {ax} axis",
    "str": "straightness error of the {ax} axis in {comp}",
    "ang": "{rot} of the {ax} axis",
    "sq": "squareness error",
}
ROT = ("rotation about X", "rotation about Y", "rotation about Z")
#: plate planes: name, in-plane axes (a, b), the fixed axis
PLANES = (("XY", 0, 1, 2), ("XZ", 0, 2, 1), ("YZ", 1, 2, 0))
#: the patent's assignment of step-1 errors (lines) to planes; _STEP2 documents the patent's
#: assignment of the angular errors to the circles (step 2 stacks them, module docstring)
STEP1 = {"XY": ("EXX", "EYY", "EYX", "EXY", "EC0Y"), "XZ": ("EZZ", "EZX", "EXZ", "EB0Z"),
          "YZ": ("EZY", "EYZ", "EA0Z")}
_STEP2 = {"XY": ("EAY", "EBY", "ECY", "ECX"), "XZ": ("EBX", "EBZ"), "YZ": ("EAZ", "EAX", "ECZ")}
#: radius of the grid plate's measuring range (KGM 182: 140 mm diameter) [mm]
PLATE_RADIUS_MM = 70.0
TEST_NAMES = ("line_a", "line_b", "circle")
GRID_POWERS = tuple((i, j) for d in (1, 2, 3) for i in range(d + 1) for j in (d - i,))
#: relative spread of the axes' following times about servo_lag_ms (gain mismatch)
SERVO_MISMATCH = 0.1
#: error sources that add white noise to each reading component (first order: sigma^2 I)
WHITE = ("encoder_noise", "repeatability")


def function_powers(name: str, order: int) -> tuple[int, ...]:
    kind = KIND[name]
    if kind == "sq":
        return (0,)
    return tuple(range(2 if kind == "str" else 1, order + 1))


# --------------------------------------------------------------------------- set-up
#: the most extra head positions of one plate's tests (each repeats them all)
MAX_EXTRA_HEADS = 10
#: the most positions along one axis (:data:`ALONG`): 1 mm steps over 2 m
MAX_ALONG = 2001
#: the most coefficients of a true error function
MAX_TRUE_COEFFICIENTS = 20


def _heads_field(plane: str, doc_extra: str):
    return param((), doc=f"Extra head positions of the {plane} plate's tests: triples of tool "
                 "length, lateral X and lateral Y offset from the spindle axis [mm] (e.g. "
                 f"200,0,0,100,60,0); each repeats the plane's tests there. {doc_extra}",
                 low=-1000, high=1000, max_len=3 * MAX_EXTRA_HEADS)


def describe(name: str) -> str:
    """What error function `name` is, in words ("positioning error of the X axis")."""
    _, kind, axis, comp = FUNCTIONS[NAMES.index(name)]
    return DESCR[kind].format(ax="XYZ"[axis], comp="XYZ"[comp], rot=ROT[comp])


def _along_field(axis: str):
    return param((), doc=f"Positions along {axis} [mm] at which {axis}'s component errors are "
                 "also stated, each a measurand of its own (EXX@-50 is EXX at x = -50 mm): the "
                 "errors along the travel, with their uncertainty and covariance, for a "
                 "compensation table; outside the measured travel (+-line_length_mm / 2) "
                 "they are extrapolated, and marked so", low=-5000, high=5000,
                 max_len=MAX_ALONG)


#: the set-up fields that state the functions at more positions (:func:`along_positions`)
ALONG = ("along_x_mm", "along_y_mm", "along_z_mm")


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
    along_x_mm: tuple[float, ...] = _along_field("X")
    along_y_mm: tuple[float, ...] = _along_field("Y")
    along_z_mm: tuple[float, ...] = _along_field("Z")
    extra_head_tests: str = param("all", doc="Tests repeated at the extra head positions: "
                                  "'all' (lines and circle) or 'lines'", choices=("all", "lines"))
    xy_plane_z_mm: float = param(0.0, doc="Z of the XY plate set-up", low=-1000, high=1000)
    xz_plane_y_mm: float = param(0.0, doc="Y of the XZ plate set-up", low=-1000, high=1000)
    yz_plane_x_mm: float = param(120.0, doc="X of the YZ plate set-up (the patent: 120 mm)",
                                 low=-1000, high=1000)
    encoder_noise_um: float = param(0.05, doc="Reading noise of the 2D encoder (std, each "
                                    "component)", low=0, high=100, owner="instrument")
    grid_error_um: float = param(1.0, doc="Grid plate's own error (std of its smooth field)",
                                 low=0, high=100, owner="instrument")
    plate_offset_mm: float = param(0.05, doc="Plate mounting offset in its plane (std)",
                                   low=0, high=10, owner="method")
    plate_tilt_urad: float = param(100.0, doc="Plate mounting rotation and tilts (std)",
                                   low=0, high=20000, owner="method")
    head_setting_um: float = param(10.0, doc="In-plane position error of an extra head after "
                                   "the change (std, each component; estimated as a nuisance)",
                                   low=0, high=1000, owner="method")
    repeatability_um: float = param(0.3, doc="Machine repeatability at each reading point (std, "
                                    "each in-plane component; ISO 230-2 R = 4 s)", low=0, high=100,
                                    owner="machine")
    repeatability_correlation_mm: float = param(
        50.0, doc="Correlation length of the repeatability along the path of each pass [mm]: "
        "AR(1) in the path length, readings s mm apart correlate by exp(-s / length), however "
        "densely the pass is read; 0: independent", low=0, high=1e5)
    path_residual_um: float = param(
        0.3, doc="RMS of the machine's repeatable short-wave path deviation beyond the "
        "polynomials, each axis and direction (harmonics of 10-40 mm wavelength of the "
        "axis's position: ball-screw pitch, guideway waviness); the same in every pass",
        low=0, high=100, owner="machine")
    medium_wave_um: float = param(
        0.3, doc="RMS of the machine's repeatable medium-wave path deviation, each axis and "
        "direction: waves of about 40 mm of the axis's position (guideway waviness, the "
        "accumulated pitch error of a ball screw), longer than the short-wave residual and "
        "shorter than what the polynomials follow; the same in every pass",
        low=0, high=100, owner="machine")
    reversal_um: float = param(2.0, doc="Reversal value of each axis (mean; drawn uniform on "
                               "[0, 2x]; ISO 230-2 B, 1-3 um with linear scales)", low=0, high=100,
                               owner="machine")
    servo_lag_ms: float = param(2.0, doc="Following time 1/Kv of each axis's position loop "
                                "(mean; 10 % spread per axis for the gain mismatch)", low=0,
                                high=200, owner="machine")
    thermal_growth_ppm_per_h: float = param(2.0, doc="Growth of each axis's scale during the test "
                                            "(std of the rate; ISO 230-3 drift)", low=0, high=100,
                                            owner="machine")
    thermal_drift_um_per_h: float = param(2.0, doc="Drift of the head relative to the plate "
                                          "during the test (std of the rate, each component)",
                                          low=0, high=1000, owner="machine")
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
        for name in ALONG:
            v = getattr(self, name)
            if len(set(v)) != len(v):
                p.add(name, v, "distinct positions")
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
#: design do not depend on them and are computed once for every size (:func:`sizeless`)
_SIZES = ("encoder_noise_um", "grid_error_um", "plate_offset_mm", "plate_tilt_urad",
          "head_setting_um", "repeatability_um", "path_residual_um", "medium_wave_um",
          "reversal_um",
          "servo_lag_ms",
          "thermal_growth_ppm_per_h", "thermal_drift_um_per_h")


@functools.lru_cache(maxsize=64)
def sizeless(setup: Setup) -> Setup:
    """The set-up with every error source at its default size and no positions along the
    travel (neither changes the test's geometry)."""
    return setup.replace(**{f: Setup.__dataclass_fields__[f].default for f in _SIZES + ALONG})


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
    unit = "urad" if KIND[name] == "ang" else "um"
    first = 2 if KIND[name] == "str" else 1
    return param(_DEFAULT_TRUTH[name],
                 doc=f"{name}: coefficients of (u/100 mm)^n, n = {first}, {first + 1}, ... "
                 f"[{unit}]", max_len=MAX_TRUE_COEFFICIENTS)


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


def truth_rows(truth: Truth) -> int | None:
    """None for one truth; m for a truth whose fields are arrays (m,) (one per batch row)."""
    values = []
    for f in dataclasses.fields(truth):
        v = getattr(truth, f.name)
        values += list(v) if isinstance(v, tuple) else [v]
    if not any(np.ndim(v) for v in values):
        return None
    return max(int(np.size(v)) for v in values)


def truth_coefficients(truth: Truth) -> dict:
    """name -> (powers, internal coefficients) of the true functions (any length): arrays
    (L,), or (m, L) for a truth whose fields are arrays (m,) (one per batch row)."""
    m = truth_rows(truth)
    out = {}
    for name in NAMES:
        kind = KIND[name]
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

