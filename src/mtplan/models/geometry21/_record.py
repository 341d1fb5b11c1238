"""geometry21's Procedure record without its capabilities: the model, the estimators and the
readings format, which the first-order analyses (:mod:`._first_order`) run on; the package
adds the capabilities those analyses provide."""

from __future__ import annotations

from mtplan.models.geometry21._estimators import DESCRIPTIONS, ESTIMATORS
from mtplan.models.geometry21._frames import from_frame, readings_frame, setup_from_frame
from mtplan.models.geometry21._physics import duration, forward, measurands, sources, true_values
from mtplan.models.geometry21._setup import Setup, Truth
from mtplan.models.protocol import Estimator, Procedure, ReadingsFormat

MODEL = Procedure(
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
    levers=tuple("poly_order line_length_mm line_repeats line_points circle_radius_mm "
                 "circle_points circle_arc_deg head_offset_mm head_lateral_mm "
                 "xy_plane_z_mm xz_plane_y_mm yz_plane_x_mm feed_mm_min xy_extra_heads_mm "
                 "xz_extra_heads_mm yz_extra_heads_mm extra_head_tests".split()),
    readings=ReadingsFormat(readings_frame, from_frame, setup_from_frame=setup_from_frame,
                            optional_columns=("head",)),
)
