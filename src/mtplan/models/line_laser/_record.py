"""line_laser's Procedure record without its estimators and capabilities: the model and the
readings format, which the estimators (:mod:`._estimators`: the zero errors, the readings'
noise source) and the closed-form sensitivities run on; the package adds the estimators and
the capabilities."""

from __future__ import annotations

from mtplan.models.line_laser._physics import duration, forward, measurands, sources, true_values
from mtplan.models.line_laser._readings import (
    from_frame,
    reading_limits,
    readings_frame,
    setup_from_frame,
)
from mtplan.models.line_laser._setup import Setup, Truth
from mtplan.models.protocol import Procedure, ReadingsFormat

MODEL = Procedure(
    name="line_laser",
    title="Mounting error angles of a line-laser profile sensor",
    Setup=Setup,
    Truth=Truth,
    measurands=measurands,
    sources=sources,
    forward=forward,
    estimators={},
    true_values=true_values,
    duration=duration,
    readings=ReadingsFormat(readings_frame, from_frame, setup_from_frame=setup_from_frame,
                            limits=reading_limits, noise_source="sensor_noise"),
)
