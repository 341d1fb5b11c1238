"""The template procedure to copy (docs/adding_a_procedure.md): a straight edge probed at
`n_points` heights, ``z = offset + slope x + noise``, with a scale error of the probe, and one
least-squares estimator.

:func:`mtplan.testing.template_source` gives this module's text with ``toy_line`` renamed,
ready to become a procedure's own module. mtplan's tests also run the engine on it,
independently of the real procedures. It is not registered: it becomes a procedure where an
entry point of the group ``mtplan.procedures`` names its copy.

Readings: heights z_i = a + b x_i + noise at `n_points` x positions over `length_mm`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from mtplan.models import (
    Capabilities,
    Estimator,
    Measurand,
    Procedure,
    Readings,
    ReadingsFormat,
    SetupBase,
    Source,
    SourceMethod,
    distributions_field,
    param,
)
from mtplan.uncertainty import Normal, Rectangular


@dataclass(frozen=True)
class Setup(SetupBase):
    _owner = "toy_line"
    n_points: int = param(11, doc="Points along the edge", low=2, high=1000)
    length_mm: float = param(100.0, doc="Length probed", low=0, low_open=True)
    probe_noise_um: float = param(1.0, doc="Probe noise (std)", low=0)
    scale_error_ppm: float = param(0.0, doc="Probe scale error (rectangular half-width)", low=0)
    distributions: str = distributions_field()

    def _check(self, p):
        if self.n_points < 2:
            p.add("n_points", self.n_points, "an int >= 2")


@dataclass(frozen=True)
class Truth(SetupBase):
    _owner = "toy_line truth"
    offset_mm: float = param(0.012, doc="Height at x = 0")
    slope_rad: float = param(20e-6, doc="Slope")


def measurands(setup):
    return (Measurand("offset", "um", "height at x = 0"), Measurand("slope", "urad", "slope"))


def sources(setup):
    return {
        "probe_noise": Source(Normal(0.0, setup.probe_noise_um * 1e-3), (setup.n_points,),
                              "noise", field="probe_noise_um"),
        "scale_error": Source(Rectangular(-setup.scale_error_ppm * 1e-6,
                                          setup.scale_error_ppm * 1e-6),
                              (), "scale", field="scale_error_ppm"),
    }


def _x(setup):
    return np.linspace(-setup.length_mm / 2, setup.length_mm / 2, setup.n_points)


def forward(setup, truth, errors):
    x = _x(setup)
    # one truth per batch row: fields may be arrays (n,) (the protocol's convention)
    offset, slope = (np.reshape(v, (-1, 1)) for v in (truth.offset_mm, truth.slope_rad))
    z = offset + slope * x
    z = z * (1 + errors["scale_error"][:, None]) + errors["probe_noise"]
    return Readings({"z_mm": z})


def estimate_ls(setup, readings):
    x = _x(setup)
    design = np.column_stack([np.ones_like(x), x])
    coef = np.linalg.pinv(design) @ readings["z_mm"].T  # one product for the batch
    return {"offset": coef[0], "slope": coef[1]}


def true_values(setup, truth):
    return {"offset": truth.offset_mm, "slope": truth.slope_rad}


def duration(setup):
    return 2.0 * setup.n_points + setup.length_mm / 10


def readings_frame(setup, readings):
    z = np.asarray(readings["z_mm"])[0]
    return pd.DataFrame({"x_mm": _x(setup), "z_mm": z})


def from_frame(setup, df):
    return Readings({"z_mm": df["z_mm"].to_numpy(dtype=float)[None, :]})


PROCEDURE = Procedure(
    name="toy_line",
    title="Straight edge (test procedure)",
    Setup=Setup,
    Truth=Truth,
    measurands=measurands,
    sources=sources,
    forward=forward,
    estimators={"least_squares": Estimator(estimate_ls, exact=True)},
    true_values=true_values,
    duration=duration,
    readings=ReadingsFormat(readings_frame, from_frame, noise_source="probe_noise"),
    capabilities=Capabilities(
        block_size=2000,
        levers=("n_points", "length_mm"),
        # the least-squares reference straight line of ISO 230-1
        source_method=SourceMethod(
            "least_squares", "Test code for machine tools - Part 1: Geometric accuracy of "
            "machines operating under no-load or quasi-static conditions", "ISO 230-1:2012")),
)
