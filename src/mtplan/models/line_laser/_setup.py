"""line_laser's set-up and truth: the scans, the artifact and the sensor as planned
(:class:`Setup`), the mounting angles and the artifact's placement (:class:`Truth`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mtplan._validate import Problems
from mtplan.models.protocol import SetupBase, distributions_field, param

#: the procedure's name
NAME = "line_laser"
#: largest mounting angle the procedure is meant for [rad] (Truth limit, range margin)
ALPHA_MAX = 10e-3
#: largest tilt of the artifact on the table [rad] (Truth limit, range margin)
TILT_MAX = 5e-3
#: smallest mask tolerance of the registration [mm]: far above rounding, far below noise
TOL_FLOOR = 5e-5
SQ3 = math.sqrt(3.0)
#: Legendre degrees of the linearity curve along the line (0 and 1 belong to the data frame)
LIN_DEGREES = np.arange(2, 5)


# --------------------------------------------------------------------------- set-up
@dataclass(frozen=True)
class Setup(SetupBase):
    """Set-up of the line-laser mounting-angle test (units in the field names)."""

    _owner = "line_laser"
    # sensor
    line_width_mm: float = param(
        16.0, doc="Width of the laser line w0 (a 15-25 mm class profile sensor)",
        low=0, low_open=True)
    points_per_line: int = param(
        65, doc="Points reported along the line (decimated from the sensor's 800-3200)", low=5,
        high=3200, levels=(33, 65, 129))
    range_mm: float = param(
        8.0, doc="Measuring range of the sensor in height (e.g. +-4 mm)", low=0, low_open=True)
    sensor_noise_um: float = param(
        1.0, doc="Standard deviation of one height reading (single profile, matte metal)", low=0,
        owner="instrument")
    linearity_um: float = param(
        1.0, doc="RMS along the laser line of the sensor's height error after its best straight "
                 "line is removed (calibration linearity): a smooth curve, Legendre degrees 2-4 "
                 "with random amplitudes per test, the same in all three scans. Default 1 um: "
                 "Keyence LJ-X8000 heads quote a Z linearity of +-0.03 % of F.S. (+-2.4 um over "
                 "this 8 mm range), Micro-Epsilon scanCONTROL 30xx about +-0.1 % of FSO", low=0,
                 owner="instrument")
    z_scale_ppm: float = param(
        100.0, doc="Standard deviation of the scale (gain) error of the sensor's height reading. "
                   "Default 100 ppm: the Z gain as calibrated by the maker; Keyence LJ-X8000 "
                   "heads quote a temperature characteristic of 0.01 % of F.S. per K, so 1 K "
                   "from the calibration temperature gives this much", low=0, owner="instrument")
    # scans
    step_mm: float = param(
        0.05, doc="Scan step dy between profiles (encoder-pulse trigger interval)",
        low=0, low_open=True)
    lines: int = param(
        80, doc="Profiles per scan; the default 80 x 0.05 mm covers one pitch of the cells along "
                "Y, so every facet is seen whatever the artifact's position", low=5, high=20000)
    shift_fraction: float = param(
        0.625, doc="X shift of scan 2 per cell width (beta: the shift is w = beta * w0, "
                   "the patent: 0.5 to 0.75); beta >= 1 leaves no common part. The default "
                   "makes w (10 mm) a whole "
                   "number of point spacings, so the patent aligns the scans without "
                   "interpolating",
        low=0, high=1, low_open=True, high_open=True)
    raise_mm: float = param(2.0, doc="Raise h of scan 3 in +Z (within the range)",
                            low=0, low_open=True)
    max_shift_rows: int = param(5, doc="n_max: row shifts searched by the patent's overlap",
                                low=1, high=10000)
    # artifact
    cell_size_mm: float = param(4.0, doc="Pitch of the hexagonal cells (centre to centre)",
                                low=0, low_open=True)
    wall_mm: float = param(0.6, doc="Width of the land between neighbouring pockets", low=0)
    cell_depth_mm: float = param(
        0.4, doc="Depth of the pockets; 0 would be an artifact without a pattern",
        low=0, low_open=True)
    facet_angle_deg: float = param(
        25.0, doc="Inclination of the pocket walls to the plate (draft of the facets)",
        low=0, high=80, low_open=True)
    facet_position_um: float = param(
        2.0, doc="Standard deviation of the position of each facet of the pockets, along its "
                 "in-plane normal, independent from facet to facet: how well the artifact's "
                 "pattern is known. Default 2 um: an uncalibrated plate milled on a machining "
                 "centre (ISO 230-2 positioning and contouring deviations and tool deflection "
                 "of a few um; the drawing tolerance, tens of um, bounds it but is not its "
                 "size); a CMM calibration of every facet gives about 1 um. Only the "
                 "'pattern' estimator (and the posterior) use the pattern; the registration "
                 "compares the scans and does not see it", low=0, owner="artefact")
    # machine errors
    shift_error_um: float = param(
        1.0, doc="Standard deviation of the machine's positioning of the X shift w", low=0,
        owner="machine")
    raise_error_um: float = param(
        1.0, doc="Standard deviation of the machine's positioning of the raise h", low=0,
        owner="machine")
    trigger_y_um: float = param(
        0.3, doc="Standard deviation of each scan's Y trigger position", low=0, owner="instrument")
    squareness_xy_urad: float = param(
        20.0, doc="Half-width (rectangular) of the squareness error of the X motion to the Y "
                  "(scan) motion, positive toward +Y. ISO 230-1 defines it; acceptance "
                  "tolerances of machining centres (ISO 10791-2) are about 0.02 mm over 500 mm "
                  "(40 urad), a machine in order measures well inside that", low=0, owner="machine")
    squareness_zy_urad: float = param(
        20.0, doc="Half-width (rectangular) of the squareness error of the Z motion to the Y "
                  "(scan) motion, positive toward +Y (ISO 230-1; default as squareness_xy_urad)",
        low=0, owner="machine")
    drift_um_per_s: float = param(
        0.003, doc="Standard deviation, per axis, of the thermal drift rate of the sensor "
                   "relative to the artifact, constant during the test; the scans' start times "
                   "follow the duration model. Default 0.003 um/s (about 10 um/h): ISO 230-3 "
                   "thermal tests of machining centres show drifts of 5-30 um per hour while "
                   "warming up, and profile sensors need a 20 min run-in", low=0, owner="machine")
    # time
    scan_feed_mm_min: float = param(600.0, doc="Scanning feed along Y", low=0, low_open=True)
    frame_rate_per_s: float = param(1000.0, doc="Largest profile rate of the sensor",
                                    low=0, low_open=True)
    rapid_mm_min: float = param(10000.0, doc="Feed of the moves between scans",
                                low=0, low_open=True)
    settle_s: float = param(1.0, doc="Dwell before each scan", low=0)

    distributions: str = distributions_field()

    def _check(self, p: Problems) -> None:
        w = self.shift_fraction * self.line_width_mm
        common = self.line_width_mm - w
        if common < self.cell_size_mm:
            p.add_text(
                f"The common part of scans 1 and 2 of line_laser, (1 - shift_fraction) * "
                f"line_width_mm = {common:g} mm, must hold at least one cell "
                f"(cell_size_mm = {self.cell_size_mm:g} mm); lower shift_fraction or "
                f"cell_size_mm, or use a wider line"
            )
        margin = (ALPHA_MAX + TILT_MAX) * (self.line_width_mm + w)
        need = self.raise_mm + self.cell_depth_mm + margin
        if need > self.range_mm:
            p.add_text(
                f"The raise of line_laser is beyond the sensor's range: raise_mm + "
                f"cell_depth_mm + {margin:.3g} mm of tilt allowance = {need:.4g} mm must be "
                f"<= range_mm = {self.range_mm:g} mm, or scan 3 leaves the measuring range"
            )
        if self.wall_mm >= self.cell_size_mm:
            p.add("wall_mm", self.wall_mm, f"< cell_size_mm = {self.cell_size_mm:g} "
                  "(the land would cover the whole cell: no pattern)")
        else:
            floor = (self.cell_size_mm - self.wall_mm) / 2 - self.cell_depth_mm / math.tan(
                math.radians(self.facet_angle_deg))
            if floor <= 0:
                p.add_text(
                    f"The pockets of line_laser have no floor: (cell_size_mm - wall_mm)/2 - "
                    f"cell_depth_mm/tan(facet_angle_deg) = {floor:.4g} mm must be > 0; make "
                    f"the cells larger, shallower or the facets steeper"
                )
        if 2 * self.max_shift_rows > self.lines - 3:
            p.add("max_shift_rows", self.max_shift_rows,
                  f"an int <= (lines - 3)/2 = {(self.lines - 3) // 2} (the shifted rows must "
                  f"still overlap)")
        reach = w * math.tan(ALPHA_MAX)
        if self.max_shift_rows * self.step_mm < reach:
            p.add("max_shift_rows", self.max_shift_rows,
                  f"an int >= {math.ceil(reach / self.step_mm)}: the search must cover the "
                  f"row shift w*tan(alpha_z) = {reach * 1e3:.3g} um of a {ALPHA_MAX * 1e3:g} "
                  f"mrad mounting error (the patent: n_max larger than the expected shift)")


@dataclass(frozen=True)
class Truth(SetupBase):
    """True mounting angles and the artifact's (unknown) pose on the table."""

    _owner = "line_laser truth"
    alpha_z_mrad: float = param(1.5, doc="Mounting angle about Z", low=-10, high=10)
    alpha_y_mrad: float = param(-2.0, doc="Mounting angle about Y", low=-10, high=10)
    alpha_x_mrad: float = param(1.0, doc="Mounting angle about X", low=-10, high=10)
    artifact_x_mm: float = param(0.37, doc="X of a cell centre (lattice offset)",
                                 low=-100, high=100)
    artifact_y_mm: float = param(-0.21, doc="Y of a cell centre (lattice offset)",
                                 low=-100, high=100)
    artifact_rz_mrad: float = param(8.0, doc="Rotation of the artifact about Z",
                                    low=-100, high=100)
    artifact_tilt_x_mrad: float = param(0.3, doc="Tilt of the artifact about X",
                                        low=-5, high=5)
    artifact_tilt_y_mrad: float = param(-0.2, doc="Tilt of the artifact about Y",
                                        low=-5, high=5)

