"""circle_centre's set-up and truth: the bore, the probe, the stage, the temperatures and the
path's parameters as planned (:class:`Setup`), the true bore and the start point (:class:`Truth`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mtplan._validate import Problems
from mtplan.models import _temperature as temperature
from mtplan.models.protocol import SetupBase, distributions_field, param


DEG = math.pi / 180.0


# --------------------------------------------------------------------------- set-up
@dataclass(frozen=True)
class Setup(SetupBase):
    """Set-up of the bore-centre measurement (see the module docstring)."""

    _owner = "circle_centre"
    bore_radius_mm: float = param(250.0, doc="Nominal radius of the bore", low=0, high=10_000,
                                  low_open=True)
    n_points: int = param(3, doc="Measuring points d1..dn (3: the patent's rule)", low=3, high=360,
                          levels=(3, 4, 6, 8, 12))
    spread_deg: float = param(360.0, doc="Arc the points cover; 360 = full circle, equally "
                              "spaced; less: end points included", low=1, high=360)
    probe_noise_um: float = param(0.5, doc="Probe trigger noise along the approach (std)", low=0,
                                  high=1000, owner="instrument")
    pretravel_variation_um: float = param(1.0, doc="RMS amplitude of the three-lobed pre-travel "
                                          "variation with approach direction", low=0, high=1000,
                                          owner="instrument")
    tangential_slip_um_per_deg: float = param(0.2, doc="Mean tangential slip per degree between "
                                              "approach and wall normal", low=0, high=1000,
                                              owner="instrument")
    roundness_um: float = param(5.0, doc="Form error of the bore (RMS peak-to-valley of one "
                                "lobed harmonic)", low=0, high=10_000, owner="workpiece")
    lobes: int = param(2, doc="Lobes of the form error (2 = oval)", low=2, high=100)
    scale_error_ppm: float = param(5.0, doc="Stage scale error per axis (rectangular half-width)",
                                   low=0, high=10_000, owner="machine")
    squareness_urad: float = param(10.0, doc="Stage X-Y squareness error (rectangular "
                                   "half-width)", low=0, high=100_000, owner="machine")
    stage_repeatability_um: float = param(0.5, doc="Stage positioning repeatability per axis "
                                          "and reading (std)", low=0, high=1000, owner="machine")
    tip_radius_um: float = param(0.5, doc="Standard deviation of the error of the probe's "
                                 "calibrated effective tip radius, one per test (the radius is "
                                 "calibrated on a setting ring whose diameter is known to about "
                                 "1 um, ISO 1938-1 / DIN 2250-1 setting rings)", low=0, high=1000,
                                 owner="instrument")
    part_temperature_c: float | None = param(
        None, doc="Measured temperature of the part [degC] (ISO 1's reference is 20 degC): "
        "the estimates are corrected to 20 degC with it; empty: not measured, the part is "
        "assumed at 20 degC within +-part_temperature_halfwidth_k and nothing is corrected",
        low=10, high=40, condition="part_temperature_c")
    part_temperature_u_k: float = param(
        0.2, doc="Standard uncertainty of the measured part temperature (thermometer's "
        "calibration, its contact, one reading standing for the whole part; ISO/TR 16015 "
        "names these) [K]; used when part_temperature_c is given", low=0, high=10,
        owner="instrument")
    part_temperature_halfwidth_k: float = param(
        2.0, doc="Half-width of the (rectangular) deviation of the part's temperature from "
        "20 degC when it is not measured [K] (a workshop held at 20 +- 2 degC)", low=0,
        high=50, owner="environment")
    expansion_ppm_per_k: float = param(11.5, doc="Linear thermal expansion coefficient of the "
                                       "workpiece [1e-6/K]; 11.5: steel", low=0, high=100)
    expansion_u_ppm_per_k: float = param(
        1.0, doc="Standard uncertainty of the workpiece's expansion coefficient [1e-6/K] "
        "(steels span 10.5-12.5e-6/K: ISO/TR 16015 advises about 1e-6/K for a material "
        "known by its kind only)", low=0, high=100, owner="workpiece")
    scale_temperature_c: float | None = param(
        None, doc="Measured temperature of the stage's scales (or of the machine structure "
        "that carries them) [degC]; empty: not measured, the scales are taken at the part's "
        "temperature within +-scale_temperature_halfwidth_k", low=10, high=40,
        condition="machine_temperature_c")
    scale_temperature_u_k: float = param(
        0.2, doc="Standard uncertainty of the measured scale temperature [K]; used when "
        "scale_temperature_c is given", low=0, high=10, owner="instrument")
    scale_temperature_halfwidth_k: float = param(
        1.0, doc="Half-width of the (rectangular) difference of the scales' temperature from "
        "the part's when it is not measured [K] (0 when part and machine share one "
        "temperature; larger for a part that arrives warmer or colder)", low=0, high=50,
        owner="environment")
    scale_expansion_ppm_per_k: float = param(10.0, doc="Linear thermal expansion coefficient of "
                                             "the stage's scales [1e-6/K]; 10: steel-mounted "
                                             "glass or steel scales (about 0 for glass-ceramic "
                                             "scales)", low=0, high=100)
    scale_expansion_u_ppm_per_k: float = param(
        0.5, doc="Standard uncertainty of the scales' effective expansion coefficient "
        "[1e-6/K] (a scale mounted on steel follows its mounting, 10-11.5e-6/K)", low=0,
        high=100, owner="machine")
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
                                    high=10_000, owner="method")
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

    distributions: str = distributions_field()

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


    def condition_notes(self) -> list[str]:
        """Which temperatures were assumed rather than measured, and what was corrected."""
        out = (temperature.assumed_note(self, "part_temperature", "the part's temperature")
               + temperature.assumed_note(self, "scale_temperature", "the scales' temperature",
                                          about="the part's"))
        if self.part_temperature_c is not None or self.scale_temperature_c is not None:
            dtp, dts = reference_deviations(self)
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


def reference_deviations(setup: Setup) -> tuple[float, float]:
    """The temperatures minus 20 degC [K] of the part and the scales that the estimators
    correct with: the measured ones, 0 where the part is not measured, and the part's
    where the scales are not."""
    dtp = temperature.deviation(setup, "part_temperature")
    return dtp, temperature.deviation(setup, "scale_temperature", default=dtp)
