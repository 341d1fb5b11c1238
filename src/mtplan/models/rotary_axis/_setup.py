"""rotary_axis's set-up and truth: the axis tested, the incline, the lattice, the
sensor and the machine's errors as planned (:class:`Setup`), the axis's location errors
(:class:`Truth`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mtplan._validate import Problems
from mtplan.models.protocol import SetupBase, file_content, param
from mtplan.models.rotary_axis._characteristic import outside, read_characteristic


NAME = "rotary_axis"
UM = 1e-3  # mm per um
URAD = 1e-6  # rad per urad
ARCSEC = math.pi / 648000  # rad per arcsec
_DEFAULT_POSITIONS = {"C": 6, "A": 7}
_DEFAULT_RANGE = {"C": 360.0, "A": 90.0}
#: a point laser reading along -Z loses the spot on surfaces steeper than this
_MAX_SLOPE_DEG = 70.0
#: smallest |X component| of the incline's normal for the A axis (below: X unobservable)
_MIN_NORMAL_X = 0.01
#: the angle influence's bound [fraction of the range] against the surface's tilt [deg]:
#: laser triangulation on diffuse surfaces (Micro-Epsilon optoNCDT 1700/2300 operating
#: instructions: typ. 0.12-0.2 % at 5-15 deg, 0.5 % at 15-30 deg); beyond the last row the
#: bound runs on along its slope (an extrapolation, stated in the field's doc and in the
#: set-up's notes)
TILT_TABLE_DEG = (0.0, 5.0, 15.0, 30.0)
TILT_TABLE = (0.0, 0.0012, 0.002, 0.005)
#: the most axis positions of one axis (positions, angles_deg, c_angles_deg)
MAX_POSITIONS = 360


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
                                  "7 for A); for CA, of the A part", low=3,
                                  high=MAX_POSITIONS)
    range_deg: float | None = param(None, doc="Angular range [deg]: C positions equally spaced "
                                    "over it starting at 0 (360: the full turn), A positions "
                                    "spaced over -range/2..range/2 inclusive in a_order (empty: "
                                    "360 for C, 90 for A); for CA, of the A part", low=0,
                                    high=360, low_open=True)
    angles_deg: tuple[float, ...] | None = param(None, doc="Explicit axis angles in measuring "
                                                 "order [deg]; overrides positions and "
                                                 "range_deg; for CA, of the A part", low=-720,
                                                 high=720, min_len=3, max_len=MAX_POSITIONS)
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
                                                   min_len=3, max_len=MAX_POSITIONS)
    pose_a_deg: float = param(45.0, doc="CA: A angle of the machining pose whose error is "
                              "reported (pose_dx, pose_dy, pose_dz) [deg]", low=-360, high=360)
    pose_c_deg: float = param(90.0, doc="CA: C angle of that pose [deg]", low=-360, high=360)
    pose_point_mm: tuple[float, ...] = param((100.0, 50.0, 100.0), doc="CA: the workpiece "
                                             "point (X, Y, Z on the table at A = C = 0) whose "
                                             "position error at the pose is reported [mm]",
                                             low=-5000, high=5000, min_len=3, max_len=3)
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
                                  low=0, high=1000, owner="instrument")
    sensor_scale_ppm: float = param(500.0, doc="Half-width of the sensor's scale error "
                                    "(rectangular) [ppm]", low=0, high=1e5, owner="instrument")
    xy_positioning_um: float = param(1.0, doc="Standard deviation of the X and Y slides' "
                                     "positioning at each lattice point [um]", low=0, high=1000,
                                     owner="machine")
    z_positioning_um: float = param(1.0, doc="Standard deviation of the Z slide's positioning "
                                    "at each reading [um]", low=0, high=1000, owner="machine")
    flatness_um: float = param(2.0, doc="Flatness of the incline over the lattice, peak to "
                               "valley [um]", low=0, high=1000, owner="artefact")
    artifact_tilt_urad: float = param(5000.0, doc="Standard deviation (normal, no hard "
                                      "bound) of each of the two tilts of the artifact's real "
                                      "plane from its nominal incline and azimuth [urad]: the "
                                      "plane is clamped by eye, not calibrated; the patent's "
                                      "method does not need it", low=0, high=1e5, owner="artefact")
    artifact_height_error_um: float = param(100.0, doc="Half-width (rectangular) of the "
                                            "artifact's real height from the nominal "
                                            "artifact_height_mm [um] (fixture drawing and "
                                            "clamping)", low=0, high=1e5, owner="artefact")
    thermal_drift_um_per_s: float = param(0.001, doc="Standard deviation of each component "
                                          "(X, Y, Z) of the sensor-to-table drift rate "
                                          "[um/s]", low=0, high=10, owner="machine")
    radial_motion_um: float = param(3.0, doc="Radial error motion of the rotary axis, peak to "
                                    "valley per direction [um]", low=0, high=1000, owner="machine")
    axial_motion_um: float = param(2.0, doc="Axial error motion of the rotary axis, peak to "
                                   "valley [um]", low=0, high=1000, owner="machine")
    tilt_motion_urad: float = param(10.0, doc="Tilt error motion of the rotary axis, peak to "
                                    "valley per direction [urad]", low=0, high=1e4, owner="machine")
    angular_positioning_arcsec: float = param(5.0, doc="Bound of the rotary axis's "
                                              "systematic angular positioning error, a smooth "
                                              "and repeatable function of the commanded angle "
                                              "(first and second harmonics, each of amplitude "
                                              "up to half the bound) [arcsec]", low=0,
                                              high=3600, owner="machine")
    angular_repeatability_arcsec: float = param(1.0, doc="Standard deviation of the rotary "
                                                "axis's random positioning error at each "
                                                "position (ISO 230-2 repeatability R = 4 s) "
                                                "[arcsec]", low=0, high=3600, owner="machine")
    spot_offset_u_um: float = param(5.0, doc="Standard uncertainty of each component (X, "
                                    "Y) of the laser spot's lateral offset from the point the "
                                    "slides command, as located by scanning a sphere or an edge "
                                    "[um] (a 10 mm triangulation sensor's spot is 50-100 um "
                                    "across on its data sheet; located to about a tenth)",
                                    low=0, high=1000, owner="instrument")
    sensor_zero_u_um: float = param(2.0, doc="Standard uncertainty of the sensor's zero (the "
                                    "reading at the commanded Z on the nominal surface), as set "
                                    "on a gauge block by the Z slide [um] (ISO 230-2 "
                                    "repeatability of Z)", low=0, high=1000, owner="instrument")
    xy_slope_halfwidth_urad: float = param(20.0, doc="Half-width (rectangular) of each "
                                           "component of the slope of the X and Y motion "
                                           "against Z over the lattice, the same at every "
                                           "position [urad] (half the ISO 10791-2 squareness "
                                           "tolerance of 0.020 mm/500 mm)", low=0, high=1e4,
                                           owner="machine")
    xy_straightness_halfwidth_um: float = param(1.0, doc="Half-width (rectangular) of the bow "
                                                "of the X and of the Y motion in Z over +-50 "
                                                "mm about the table centre, the same at every "
                                                "position [um] (ISO 10791-2 straightness "
                                                "0.010 mm/500 mm, proportional to 100 mm)",
                                                low=0, high=1000, owner="machine")
    reversal_halfwidth_arcsec: float = param(5.0, doc="Half-width (rectangular, sign unknown) "
                                             "of the rotary axis's reversal value B (ISO 230-2) "
                                             "[arcsec]: a position approached in the other "
                                             "direction than the first is off by B (worm-driven "
                                             "tables: 2-10 arcsec)", low=0, high=3600,
                                             owner="machine")
    angular_short_period_halfwidth_arcsec: float = param(1.0, doc="Amplitude (arcsine: a "
                                                         "sinusoid of unknown phase) of the "
                                                         "rotary axis's short-period "
                                                         "positioning error at each position "
                                                         "(encoder interpolation, worm), "
                                                         "systematic: the same in every test "
                                                         "[arcsec] (angle encoders' error "
                                                         "within one signal period, about "
                                                         "+-1 % of a 30-80 arcsec period)",
                                                         low=0, high=3600, owner="machine")
    sensor_linearity_halfwidth_ppm: float = param(800.0, doc="Half-width of the sensor's "
                                                  "linearity deviation over its range, in ppm "
                                                  "of sensor_range_mm [ppm] (a curve about the "
                                                  "best straight line, zero at mid-range; "
                                                  "triangulation data sheets: +-0.08 % of the "
                                                  "range)", low=0, high=1e5, owner="instrument")
    angle_influence_halfwidth_ppm: float = param(5000.0, doc="Bound of the sensor's angle "
                                                 "influence at a 30 deg tilt of the surface, "
                                                 "in ppm of sensor_range_mm; at other tilts "
                                                 "the bound follows the data sheet's table "
                                                 "(0.12 % at 5 deg, 0.2 % at 15, 0.5 % at "
                                                 "30 deg for diffuse surfaces) scaled to it "
                                                 "[ppm]", low=0, high=1e5, owner="instrument")
    sensor_max_tilt_deg: float = param(50.0, doc="Largest tilt of the surface under the "
                                       "sensor the set-up may have [deg]; larger tilts are "
                                       "refused. Data sheets state the angle influence to 30 "
                                       "deg; beyond, the bound is extrapolated along the "
                                       "table's last row (the A axis's default +-45 deg tilts "
                                       "the 20 deg incline to 48.4 deg)", low=0, high=70,
                                       low_open=True)
    sensor_characteristic: str | None = param(None, doc="A calibrated angle characteristic "
                                              "of the sensor (CSV: tilt_x_deg, tilt_y_deg, "
                                              "error_um, u_um on a full grid of tilts in the "
                                              "sensor's frame, as a tilt-table calibration "
                                              "gives it; docs/readings.md). Given, it replaces "
                                              "the data sheet's bound "
                                              "(angle_influence_halfwidth_ppm is then unused): "
                                              "every estimator corrects each reading by it, "
                                              "interpolated bilinearly at the reading's "
                                              "nominal tilt, and the budget carries the "
                                              "calibration's u (angle_calibration_u_um). "
                                              "Empty: none", reader=read_characteristic)
    angle_calibration_u_um: float | None = param(None, doc="Standard uncertainty of the "
                                                 "calibrated characteristic at each of its "
                                                 "points [um] (empty: each point's u_um from "
                                                 "the file; 0: taken as exact); used only with "
                                                 "sensor_characteristic", low=0, high=1000,
                                                 owner="instrument")
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

    def notes(self) -> list[str]:
        """That the sensor's angle influence is a calibrated characteristic, when it is; or
        that the set-up tilts the surface beyond the data sheet's last row, where its bound
        is extrapolated."""
        if self.sensor_characteristic is None:
            return self._extrapolation_note()
        return [f"sensor: the angle influence is the calibrated characteristic "
                f"{self.sensor_characteristic!r} (its u in the budget as angle_calibration_u); "
                "the data sheet's bound angle_influence_halfwidth_ppm is not used"]

    def _extrapolation_note(self) -> list[str]:
        """The steepest tilt beyond the data sheet's table, and the rule that bounds it."""
        tau = tilts(self)[0]
        i = int(np.argmax(tau))
        if tau[i] <= TILT_TABLE_DEG[-1] or self.angle_influence_halfwidth_ppm == 0:
            return []
        slope = (TILT_TABLE[-1] - TILT_TABLE[-2]) / (TILT_TABLE_DEG[-1] - TILT_TABLE_DEG[-2])
        bound = (TILT_TABLE[-1] + slope * (tau[i] - TILT_TABLE_DEG[-1])) / TILT_TABLE[-1]
        ppm = self.angle_influence_halfwidth_ppm
        return [f"sensor: the surface tilts to {tau[i]:.1f} deg under the sensor at "
                f"{self.position_axis(i)} = {self.angles()[i]:g} deg, beyond the data sheet's "
                f"last row ({TILT_TABLE_DEG[-1]:g} deg): the angle influence's bound there is "
                f"extrapolated along the last row's slope, {ppm * bound:.0f} ppm of the range "
                f"against {ppm:g} ppm at {TILT_TABLE_DEG[-1]:g} deg"]

    def _check(self, p: Problems) -> None:
        if self.angles_deg is not None and self.positions is not None \
                and self.positions != len(self.angles_deg):
            p.add("positions", self.positions,
                  f"empty or equal to the number of angles_deg ({len(self.angles_deg)})")
        if self.c_angles_deg is not None and self.axis != "CA":
            p.add("c_angles_deg", self.c_angles_deg,
                  "empty unless axis is 'CA' (it sets the C part of the combined test)")
        n0 = incline_normal(self)
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
        if self.sensor_characteristic is not None and not p:
            self._check_characteristic(p)

    def _check_characteristic(self, p: Problems) -> None:
        """Every reading's nominal tilt lies inside the calibrated grid."""
        ch = file_content(self, "sensor_characteristic")
        tx, ty = sensor_tilts(self)
        bad = outside(ch, tx, ty)
        if np.any(bad):
            p_i, k = np.argwhere(bad)[0]
            angle = self.angles()[p_i]
            p.add("sensor_characteristic", self.sensor_characteristic,
                  f"a characteristic that covers the set-up's tilts: it is calibrated for "
                  f"tilt_x from {ch.tilt_x[0]:g} to {ch.tilt_x[-1]:g} deg and tilt_y from "
                  f"{ch.tilt_y[0]:g} to {ch.tilt_y[-1]:g} deg, and the set-up tilts the "
                  f"surface to ({tx[p_i, k]:.2f}, {ty[p_i, k]:.2f}) deg at "
                  f"{self.position_axis(p_i)} = {angle:g} deg"
                  + (" (sensor at 180 deg)" if k else "") + f"; {int(bad.sum())} of "
                  f"{bad.size} tilts are outside (reduce incline_deg or the angles, or "
                  "calibrate further)")

    def position_axis(self, index: int) -> str:
        """The axis ('C' or 'A') turned at position `index` of the test."""
        return "C" if self.axis == "CA" and index < len(self.axis_angles("C")) else \
            self.axes[-1]

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
        rot = nominal_rotations(axis, np.deg2rad(angles))
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
            _, _, z_cmd = lattice(self, axis, angles)
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


# --------------------------------------------------------------------------- nominal geometry
def incline_normal(setup: Setup) -> np.ndarray:
    i, az = math.radians(setup.incline_deg), math.radians(setup.incline_azimuth_deg)
    return np.array([math.sin(i) * math.cos(az), math.sin(i) * math.sin(az), math.cos(i)])


def tilts(setup: Setup) -> tuple[np.ndarray, np.ndarray]:
    """Magnitude [deg] and direction from +X [rad] of the nominal surface's tilt under the
    sensor at every position: the angle of the normal from Z, the fall line's azimuth (P,)."""
    n0 = incline_normal(setup)
    normals = np.concatenate([nominal_rotations(a, np.deg2rad(setup.axis_angles(a))) @ n0
                              for a in setup.axes])
    tau = np.degrees(np.arccos(np.clip(normals[:, 2], -1.0, 1.0)))
    return tau, np.arctan2(normals[:, 1], normals[:, 0])


def sensor_tilts(setup: Setup) -> tuple[np.ndarray, np.ndarray]:
    """The nominal surface's tilt in the sensor's frame at every position and pass, its
    components along the triangulation plane and across it, tau cos phi and tau sin phi
    (P, passes) [deg]: the sensor turned by 180 deg (the second pass of sensor_reversal)
    sees both components reversed."""
    tau, azimuth = tilts(setup)
    phi = azimuth - math.radians(setup.sensor_azimuth_deg)
    sign = np.array([1.0, -1.0][:setup.n_passes])
    return (tau * np.cos(phi))[:, None] * sign, (tau * np.sin(phi))[:, None] * sign


def nominal_rotations(axis: str, angles: np.ndarray) -> np.ndarray:
    """Right-handed rotations about the nominal axis, array (positions, 3, 3)."""
    c, s = np.cos(angles), np.sin(angles)
    one, zero = np.ones_like(c), np.zeros_like(c)
    if axis == "C":
        rows = [[c, -s, zero], [s, c, zero], [zero, zero, one]]
    else:
        rows = [[one, zero, zero], [zero, c, -s], [zero, s, c]]
    return np.moveaxis(np.array(rows), (0, 1), (-2, -1))


def serpentine(nx: int, ny: int, size: float) -> tuple[np.ndarray, np.ndarray]:
    """Lattice offsets from its centre in measuring order, arrays (nx*ny,) [mm]."""
    xs = np.linspace(-size / 2, size / 2, nx)
    ys = np.linspace(-size / 2, size / 2, ny)
    gx = np.concatenate([xs if r % 2 == 0 else xs[::-1] for r in range(ny)])
    gy = np.repeat(ys, nx)
    return gx, gy


def lattice(setup: Setup, axis: str, angles: np.ndarray):
    """Lattice centres (P, 3) on the nominal surface, points (P, M, 2), heights (P, M) [mm].

    For the positions `angles` [deg] of `axis` ('C' or 'A').
    """
    theta = np.deg2rad(angles)
    rot = nominal_rotations(axis, theta)
    n0 = incline_normal(setup)
    q0 = np.array([0.0, 0.0, setup.artifact_height_mm])
    ox, oy = setup.lattice_offset_x_mm, setup.lattice_offset_y_mm
    c0 = np.array([ox, oy, q0[2] - (n0[0] * ox + n0[1] * oy) / n0[2]])  # surface point
    centres = rot @ c0
    normals = rot @ n0  # (P, 3)
    points = rot @ q0  # a point of each nominal plane (P, 3)
    gx, gy = serpentine(setup.lattice_nx, setup.lattice_ny, setup.lattice_size_mm)
    xy = np.stack([centres[:, None, 0] + gx, centres[:, None, 1] + gy], axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = points[:, None, 2] - (
            normals[:, None, 0] * (xy[..., 0] - points[:, None, 0])
            + normals[:, None, 1] * (xy[..., 1] - points[:, None, 1])
        ) / normals[:, None, 2]
    return centres, xy, z
