"""tracker_frame's set-up and truth: the gantry, its sub-machines, the tracker and the error
sources' sizes as planned (:class:`Setup`), the true geometry of every head and of the tracker's
pose (:class:`Truth`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mtplan._validate import Problems
from mtplan.models import _temperature as temperature
from mtplan.models.protocol import SetupBase, param


NAME = "tracker_frame"


AXES = ("X", "Y", "Z")


#: minimum angle between A and C accepted by the Truth check [deg]
MIN_AC_ANGLE_DEG = 5.0


#: the most sub-machines on a gantry (the truth's lists hold one value each, at most)
MAX_SUBMACHINES = 32

#: sine of the angle below which fitted A and C lines are called parallel
PARALLEL_SIN = 1e-6


# --------------------------------------------------------------------------- set-up
@dataclass(frozen=True)
class Setup(SetupBase):
    """Set-up of the tracker measurement of the sub-machine frames (mm, deg, s)."""

    _owner = NAME
    n_submachines: int = param(2, doc="Sub-machines on the gantry", low=1,
                               high=MAX_SUBMACHINES)
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
        10.0, doc="Tracker distance (ADM) MPE, constant part a", low=0, high=10000,
        owner="instrument")
    distance_per_length_um_per_m: float = param(
        0.3, doc="Tracker distance (ADM) MPE, length-proportional part b", low=0, high=1000,
        owner="instrument")
    transverse_fixed_um: float = param(
        15.0, doc="Tracker transverse MPE, constant part c", low=0, high=10000, owner="instrument")
    transverse_per_length_um_per_m: float = param(
        3.0, doc="Tracker transverse MPE, length-proportional part d: its per-point (random) "
        "share, the angular repeatability (see angular_systematic_um_per_m)", low=0, high=1000,
        owner="instrument")
    angular_systematic_um_per_m: float = param(
        5.0, doc="Tracker transverse MPE, length-proportional part d: its per-test systematic "
        "share (angle encoders' harmonics, collimation, trunnion tilt, vertical index: "
        "constant over the test). With the per-point 3 um/m it makes 5.8 um/m in "
        "quadrature, the Leica AT960's d = 6 um/m", low=0, high=1000, owner="instrument")
    smr_centring_um: float = param(
        2.5, doc="Centring tolerance of the SMR (optical centre to sphere centre), as an MPE "
        "per direction: +-2.5 um for a precision-grade 1.5 in SMR (standard grades +-12.7 "
        "um); beyond the MPE's own reflector", low=0, high=1000, owner="instrument")
    air_refraction_ppm: float = param(
        1.0, doc="Standard deviation of the distance scale error from the air's refractive "
        "index over the beam, one per test: weather station +-0.3 K and +-1 hPa (0.3 ppm "
        "each) and about 1 K between the station and the beam path in a hall (0.9 ppm)",
        low=0, high=1000, owner="environment")
    thermal_drift_um_per_s: float = param(
        0.003, doc="Standard deviation of each component (X, Y, Z) of the drift rate of the "
        "tracker against the machine over the test (tripod, floor, bed): 0.003 um/s = 11 "
        "um/h; a 1.5 m steel tripod grows 17 um per K", low=0, high=100, owner="machine")
    straightness_um: float = param(
        10.0, doc="Straightness tolerance of each linear travel measured, each direction "
        "across it (ISO 230-1, deviation from the least-squares reference line): 10 um, "
        "the order of the acceptance tolerances of large machining centres over 1 m",
        low=0, high=10000, owner="machine")
    mpe_model: str = param(
        "normal_k2", doc="How an MPE becomes a distribution: normal with std MPE/2 (k = 2) "
        "or rectangular with half-width MPE", choices=("normal_k2", "rectangular"))
    machine_repeatability_um: float = param(
        2.0, doc="Standard deviation of the machine's positioning at each point (each axis)",
        low=0, high=10000, owner="machine")
    reflector_fixture_um: float = param(
        50.0, doc="Half-width (rectangular) of the reflector's position on its fixture about "
        "the stated one (reflector_offset_mm from C at the tool tip), each direction: across "
        "C away from it, along C, and round it; one per mounting. Default 50 um for an "
        "uncalibrated fixture: the arm machined to +-50 um over 150 mm, the nest's height "
        "against the tool tip to +-50 um, the spindle's orientation stop (+-0.02 deg, 52 um "
        "at 150 mm). 0 takes the fixture as calibrated", low=0, high=10000, owner="method")
    rotary_positioning_arcsec: float = param(
        5.0, doc="Standard deviation of the A and C axes' angular positioning at each arc "
        "point (actual minus commanded angle)", low=0, high=36000, owner="machine")
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
        low=0, high=10, owner="instrument")
    structure_temperature_halfwidth_k: float = param(
        2.0, doc="Half-width (rectangular) of the structure's temperature minus 20 degC when "
        "it is not measured [K]: a machine hall held at 20 +- 2 degC", low=0, high=50,
        owner="environment")
    structure_expansion_ppm_per_k: float = param(
        11.5, doc="Linear thermal expansion coefficient of the bed and gantry [1e-6/K] (steel "
        "weldments 11.5; cast iron 10-11)", low=0, high=100)
    structure_expansion_u_ppm_per_k: float = param(
        1.0, doc="Standard uncertainty of the structure's expansion coefficient [1e-6/K] "
        "(steels and cast irons span 10-12.5e-6/K; ISO/TR 16015)", low=0, high=100, owner="machine")
    air_gradient_k_per_m: float | None = param(
        None, doc="Measured vertical gradient of the air's temperature along the beams [K/m], "
        "positive with warm air above (two thermometers at different heights): every "
        "estimator corrects the elevations for the beams' bending; empty: not measured, "
        "the gradient is taken uniform between 0 and air_gradient_range_k_per_m", low=-10,
        high=10, condition="air_gradient_k_per_m")
    air_gradient_u_k_per_m: float = param(
        0.2, doc="Standard uncertainty of the measured gradient as the mean along the beams "
        "[K/m] (two thermometers of 0.1 K a metre apart, 0.14 K/m, and the gradient's "
        "change along the hall); used when air_gradient_k_per_m is given", low=0, high=20,
        owner="instrument")
    air_gradient_range_k_per_m: float = param(
        1.0, doc="Upper end of the vertical gradient of the air's temperature when it is not "
        "measured [K/m]: uniform between 0 and it, warm air above (halls without displacement "
        "ventilation stratify by 0.5-1 K/m, Estler et al., CIRP Annals 51/2, 2002)", low=0,
        high=20, owner="environment")
    air_gradient_x_k_per_m: float | None = param(
        None, doc="Measured horizontal gradient of the air's temperature along the tracker's "
        "x axis (azimuth 0) [K/m], positive towards warm air (thermometers a metre apart "
        "across the hall); with air_gradient_y_k_per_m every estimator corrects the azimuths "
        "for the beams' swerve; empty: not measured, each component is taken uniform within "
        "+-air_gradient_horizontal_range_k_per_m", low=-10, high=10,
        condition="air_gradient_x_k_per_m")
    air_gradient_y_k_per_m: float | None = param(
        None, doc="Measured horizontal gradient of the air's temperature along the tracker's "
        "y axis (azimuth 90 deg) [K/m], positive towards warm air; given with "
        "air_gradient_x_k_per_m", low=-10, high=10, condition="air_gradient_y_k_per_m")
    air_gradient_horizontal_u_k_per_m: float = param(
        0.1, doc="Standard uncertainty of each measured horizontal gradient component as the "
        "mean along the beams [K/m] (0.1 K thermometers a metre apart give 0.14 K/m for one "
        "pair; averaged over the hall, 0.1); used when the horizontal gradient is given",
        low=0, high=20, owner="instrument")
    air_gradient_horizontal_range_k_per_m: float = param(
        0.1, doc="Half-width of each horizontal component of the air's temperature gradient "
        "when it is not measured [K/m]: uniform within +-it, either side warm (a hall without "
        "heaters, doors or sun on one side; near them 0.3 or more)", low=0, high=20,
        owner="environment")
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
        if (self.air_gradient_x_k_per_m is None) != (self.air_gradient_y_k_per_m is None):
            given = "x" if self.air_gradient_y_k_per_m is None else "y"
            p.add(f"air_gradient_{'y' if given == 'x' else 'x'}_k_per_m", None,
                  f"a number [K/m]: the horizontal gradient is measured as two components, "
                  f"and only air_gradient_{given}_k_per_m was given")
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
        if self.air_gradient_x_k_per_m is None:
            out.append(f"temperature: the air's horizontal gradient was assumed (each "
                       f"component within +-{self.air_gradient_horizontal_range_k_per_m:g} K/m), "
                       "not measured (state air_gradient_x_k_per_m and air_gradient_y_k_per_m)")
        return out


def _each(default: tuple, *, doc: str):
    """A truth field with one value per sub-machine (cycled when shorter than the count)."""
    return param(default, doc=doc, min_len=1, max_len=MAX_SUBMACHINES)


@dataclass(frozen=True)
class Truth(SetupBase):
    """True geometry. Tuples are per sub-machine, cycled when shorter than the count."""

    _owner = f"{NAME} truth"
    wrist_dx_um: tuple[float, ...] = _each((40.0, -25.0), doc="Wrist centre T off nominal, X")
    wrist_dy_um: tuple[float, ...] = _each((-30.0, 20.0), doc="Wrist centre T off nominal, Y")
    wrist_dz_um: tuple[float, ...] = _each((15.0, -10.0), doc="Wrist centre T off nominal, Z")
    frame_rx_urad: tuple[float, ...] = _each((20.0, -15.0), doc="Rotation of the sub-machine "
                                             "(axes and head) about X")
    frame_ry_urad: tuple[float, ...] = _each((-12.0, 25.0), doc="... about Y")
    frame_rz_urad: tuple[float, ...] = _each((35.0, -20.0), doc="... about Z")
    sq_xy_urad: tuple[float, ...] = _each((10.0, -8.0), doc="Squareness X-Y (90 deg minus "
                                          "the angle between X and Y)")
    sq_yz_urad: tuple[float, ...] = _each((-6.0, 12.0), doc="Squareness Y-Z")
    sq_zx_urad: tuple[float, ...] = _each((8.0, 5.0), doc="Squareness Z-X")
    c_tilt_x_urad: tuple[float, ...] = _each((15.0, -10.0), doc="Tilt of C against Z about X")
    c_tilt_y_urad: tuple[float, ...] = _each((-20.0, 12.0), doc="Tilt of C against Z about Y")
    a_tilt_y_urad: tuple[float, ...] = _each((25.0, -18.0), doc="Tilt of A about Y")
    a_tilt_z_urad: tuple[float, ...] = _each((-14.0, 30.0), doc="Tilt of A about Z")
    ac_offset_um: tuple[float, ...] = _each((30.0, -45.0), doc="Signed A-C offset (length of "
                                            "the common perpendicular)")
    pivot_length_error_um: tuple[float, ...] = _each(
        (0.0,), doc="True pivot length minus the stated one")
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
