"""tracker_frame's measuring layout: where each reading is taken (the bed marks, the points
along the travels and round the arcs of every sub-machine, in order) and when (the test's
time line and its duration).
"""

from __future__ import annotations

import numpy as np

from mtplan.models.tracker_frame._setup import AXES, Setup


def nominal_origins(setup: Setup) -> np.ndarray:
    """Nominal origins (N, 3) [mm] of the sub-machine frames."""
    n = setup.n_submachines
    y = (np.arange(n) - (n - 1) / 2) * setup.submachine_spacing_mm
    return np.column_stack([np.zeros(n), y, np.full(n, setup.origin_height_mm)])


def bed_marks(setup: Setup) -> np.ndarray:
    """Stated global coordinates (4, 3) [mm] of the bed's corner marks."""
    a, b = setup.bed_length_mm / 2, setup.bed_width_mm / 2
    return np.array([[-a, -b, 0.0], [a, -b, 0.0], [a, b, 0.0], [-a, b, 0.0]])


def linear_positions(setup: Setup) -> dict[str, np.ndarray]:
    travel = {"X": setup.travel_x_mm, "Y": setup.travel_y_mm, "Z": setup.travel_z_mm}
    return {ax: np.linspace(-t / 2, t / 2, setup.points_per_axis) for ax, t in travel.items()}


def arc_angles(arc_deg: float, m: int) -> np.ndarray:
    """Arc angles [deg] centred on home; a full turn leaves out the repeated end point."""
    if arc_deg >= 360.0:
        return np.linspace(-180.0, 180.0, m, endpoint=False)
    return np.linspace(-arc_deg / 2, arc_deg / 2, m)


def layout(setup: Setup) -> list[tuple[str, int, int, float, float]]:
    """Every reading in order: (group, submachine, index, position_mm, angle_deg)."""
    rows = [("mark", 0, i, 0.0, 0.0) for i in range(4)]
    lin = linear_positions(setup)
    c_ang = arc_angles(setup.c_arc_deg, setup.points_per_arc)
    a_ang = arc_angles(setup.a_arc_deg, setup.points_per_arc)
    for k in range(1, setup.n_submachines + 1):
        for ax in AXES:
            rows += [(ax, k, i, float(s), 0.0) for i, s in enumerate(lin[ax])]
        rows += [("C", k, i, 0.0, float(a)) for i, a in enumerate(c_ang)]
        rows += [("A", k, i, 0.0, float(a)) for i, a in enumerate(a_ang)]
    return rows


def slices(setup: Setup) -> dict:
    """Index ranges of each group of readings: {(group, k): slice} (marks: ('mark', 0))."""
    out = {("mark", 0): slice(0, 4)}
    pos = 4
    P, Q = setup.points_per_axis, setup.points_per_arc
    for k in range(1, setup.n_submachines + 1):
        for g, m in (("X", P), ("Y", P), ("Z", P), ("C", Q), ("A", Q)):
            out[(g, k)] = slice(pos, pos + m)
            pos += m
    return out


def n_points(setup: Setup) -> int:
    return 4 + setup.n_submachines * (3 * setup.points_per_axis + 2 * setup.points_per_arc)


def reading_times(setup: Setup) -> tuple[np.ndarray, float]:
    """Time of each reading from the start (n_points,) in layout order, and the total [s].

    The marks first (``mark_s`` each); then per sub-machine the fixture
    (``changeover_s``); each linear travel out from home to its start, along it point
    by point (``dwell_s`` at each) and back home at ``linear_feed_mm_min``; each arc
    point ``rotary_move_s`` + ``dwell_s``. A reading is taken at the end of its dwell.
    """
    feed = setup.linear_feed_mm_min / 60.0
    P, Q = setup.points_per_axis, setup.points_per_arc
    travels = (setup.travel_x_mm, setup.travel_y_mm, setup.travel_z_mm)
    marks = setup.mark_s * np.arange(1, 5)
    # one sub-machine, from its start: three travels, then the C and A arcs
    lin = [(np.arange(P) * (t / (P - 1)) + t / 2) / feed + setup.dwell_s * np.arange(1, P + 1)
           for t in travels]
    starts = np.cumsum([0.0] + [2 * t / feed + P * setup.dwell_s for t in travels])
    arc = (setup.rotary_move_s + setup.dwell_s) * np.arange(1, 2 * Q + 1)
    one = np.concatenate([*(s + t for s, t in zip(starts, lin, strict=False)), starts[3] + arc])
    per_sub = setup.changeover_s + starts[3] + arc[-1]
    subs = marks[-1] + setup.changeover_s + per_sub * np.arange(setup.n_submachines)
    times = np.concatenate([marks, (subs[:, None] + one).ravel()])
    return times, float(marks[-1] + setup.n_submachines * per_sub)


def duration(setup: Setup) -> float:
    """Machine time [s]: marks, and per sub-machine the fixture, travels and arcs."""
    return reading_times(setup)[1]
