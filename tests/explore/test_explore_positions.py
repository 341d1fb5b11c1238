"""The picture of the measuring positions: the points of the set-up's readings table
without errors, as the table states them, checked against that table."""

from __future__ import annotations

import numpy as np
import pytest

from mtplan.explore.positions import (MAX_POINTS, _positions, measuring_positions,
                                     positions_of_frame)
from mtplan.explore.state import source_fields
from mtplan.models import get


def _frame(name: str, **values):
    proc = get(name)
    setup = proc.setup(values)
    return proc.readings.frame(setup, proc.forward(setup, proc.Truth(),
                                                   proc.zero_errors(setup, 1)))


def test_a_rotary_axis_turns_each_point_by_its_positions_angle():
    f = _frame("rotary_axis", positions=8)
    p = positions_of_frame(f)
    x, y, z = (np.asarray(p[k]) for k in "xyz")
    assert p["group_by"] == "position" and len(x) == len(f)
    # turned about z (axis C): the radius and height stay, the angle grows by the position's
    r0, a0 = np.hypot(f.x_mm, f.y_mm), np.arctan2(f.y_mm, f.x_mm)
    np.testing.assert_allclose(np.hypot(x, y), r0, atol=1e-9)
    np.testing.assert_allclose(z, f.z_mm, atol=1e-12)
    moved = r0 > 1e-9
    turn = np.angle(np.exp(1j * (np.arctan2(y, x) - a0 - np.radians(f.angle_deg))))
    np.testing.assert_allclose(turn[moved], 0, atol=1e-9)


def test_a_trackers_readings_become_points_about_it_and_a_plane_stays_a_plane():
    f = _frame("tracker_frame")
    p = positions_of_frame(f)
    d = np.sqrt(np.square(p["x"]) + np.square(p["y"]) + np.square(p["z"]))
    np.testing.assert_allclose(d, f.distance_mm, rtol=1e-12)
    np.testing.assert_allclose(np.arcsin(np.asarray(p["z"]) / d), f.elevation_rad, atol=1e-12)
    c = positions_of_frame(_frame("circle_centre"))
    assert c["z"] is None and c["group_by"] is None and len(c["x"]) == c["n"]


def test_a_large_table_is_drawn_evenly_thinned_and_a_table_without_coordinates_refused():
    p = measuring_positions({"procedure": "line_laser"})  # 15 600 readings
    assert p["n"] > MAX_POINTS and len(p["x"]) == MAX_POINTS and set(p["group"]) == {"1", "2", "3"}
    # a source resized: the same noise-free readings, not computed again
    hits = _positions.cache_info().hits
    field = next(iter(source_fields(get("line_laser")).values()))
    assert measuring_positions({"procedure": "line_laser", "setup": {field: "0.5"}}) == p
    assert _positions.cache_info().hits == hits + 1
    with pytest.raises(ValueError, match="no coordinates"):
        positions_of_frame(_frame("tracker_frame")[["point", "group"]])
