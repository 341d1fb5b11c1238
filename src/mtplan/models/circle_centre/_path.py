"""circle_centre's path planner (the patent's method): the centre from the two y contacts, the
measuring points and the helper arcs between them, the acceptance check of the last point,
and the machine time and the report's figure of the planned path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from mtplan._validate import Problems
from mtplan.models.circle_centre._setup import DEG as _DEG, Setup, Truth


_MAX_ARC = 150.0 * _DEG  # legs longer than this go through the centre (see docstring)


def n_contacts(setup: Setup) -> int:
    return setup.n_points + 2  # p1, p2, d1..dn


def plan_core(p1, p2, radius, free_dir, n_points, spread_deg):
    """The patent's planning, batch-first.

    Parameters
    ----------
    p1, p2 : array (n, 2)
        Read coordinates of the -y and +y contacts [mm].
    radius : float
        Nominal bore radius [mm].
    free_dir : array (n,)
        Free direction of motion in x at p2: +1, -1 or 0.

    Returns
    -------
    dict with ``centre`` (n,2), ``theta1``, ``theta2`` (n,) [rad], ``sigma`` (n,)
    (+1 ccw about o, -1 cw: the travel sense from d1 on), ``alpha_p1``,
    ``alpha_p2`` (n,) and ``alpha`` (n, n_points) target angles about the planner's
    centre [rad], and ``step`` [rad].
    """
    h = 0.5 * np.hypot(p2[:, 0] - p1[:, 0], p2[:, 1] - p1[:, 1])
    ratio = np.minimum(h / radius, 1.0)
    theta1 = 2.0 * np.arcsin(ratio)
    off = radius * np.sqrt(np.maximum(1.0 - ratio * ratio, 0.0))
    mid = 0.5 * (p1 + p2)
    centre = np.stack([mid[:, 0] + free_dir * off, mid[:, 1]], axis=-1)
    alpha_p1 = np.arctan2(p1[:, 1] - centre[:, 1], p1[:, 0] - centre[:, 0])
    alpha_p2 = np.arctan2(p2[:, 1] - centre[:, 1], p2[:, 0] - centre[:, 0])
    # centre to the right (+1) or unknown (0): p1, p2 on the left, long way is clockwise
    sigma = np.where(free_dir < 0, 1.0, -1.0)
    if spread_deg >= 360.0:
        step = 2 * math.pi / n_points
    else:
        step = spread_deg * _DEG / (n_points - 1)
    k = np.arange(1, n_points + 1)
    alpha = alpha_p1[:, None] - sigma[:, None] * (n_points - k)[None, :] * step
    theta2 = (2 * math.pi - theta1) - (n_points - 1) * step
    return {"centre": centre, "theta1": theta1, "theta2": theta2, "sigma": sigma,
            "alpha_p1": alpha_p1, "alpha_p2": alpha_p2, "alpha": alpha, "step": step}


# --------------------------------------------------------------------------- path plan
@dataclass(frozen=True)
class Segment:
    """One move of the planned path, in read coordinates [mm].

    ``kind`` is ``'line'`` or ``'arc'``; for an arc, ``centre`` and ``radius`` are the
    helper circle's and ``ccw`` its turning sense about that centre.
    """

    kind: str
    start: tuple
    end: tuple
    centre: tuple | None = None
    radius: float | None = None
    ccw: bool | None = None
    probing: bool = False

    @property
    def length(self) -> float:
        if self.kind == "line":
            return math.dist(self.start, self.end)
        a0 = math.atan2(self.start[1] - self.centre[1], self.start[0] - self.centre[0])
        a1 = math.atan2(self.end[1] - self.centre[1], self.end[0] - self.centre[0])
        turn = (a1 - a0) % (2 * math.pi) if self.ccw else (a0 - a1) % (2 * math.pi)
        return self.radius * turn

    def polyline(self, samples: int = 64) -> np.ndarray:
        """Points along the segment, array (samples, 2), for drawing."""
        if self.kind == "line":
            t = np.linspace(0, 1, samples)[:, None]
            return (1 - t) * np.asarray(self.start) + t * np.asarray(self.end)
        a0 = math.atan2(self.start[1] - self.centre[1], self.start[0] - self.centre[0])
        turn = self.length / self.radius if self.radius > 0 else 0.0
        a = a0 + (1 if self.ccw else -1) * np.linspace(0, turn, samples)
        return np.column_stack([self.centre[0] + self.radius * np.cos(a),
                                self.centre[1] + self.radius * np.sin(a)])


@dataclass(frozen=True)
class PathPlan:
    """The planned probing path of one measurement (read coordinates, mm, degrees).

    Attributes
    ----------
    start, p1, p2 : tuple (x, y)
    centre : tuple (x, y)
        The planner's centre from p1, p2, the nominal radius and the free direction.
    bore_radius_mm : float
    free_direction : int
        +1, -1 or 0: which way (x) the probe could move at p2.
    theta1_deg, theta2_deg : float
        Angle p1-o-p2, and angle from o-p2 to o-d1 along the travel.
    case : int
        The patent's case 1..4 of the first rotation.
    first_rotation, later_rotation : str
        'ccw' or 'cw' about the helper circles o1 and o2, o3, ...
    targets : array (n_points, 2)
        Planned d1..dn on the nominal circle about the planner's centre.
    target_angles_deg : array (n_points,)
    helper_circles : tuple of (centre, radius)
        o1, o2, ... (a radial transfer has none).
    segments : tuple of Segment
        start -> p1 -> p2 -> d1 -> ... -> dn.
    miss_mm : tuple (dx, dy)
        The patent's |x_p1 - x_dn|, |y_p1 - y_dn| for the planned d_n.
    """

    start: tuple
    p1: tuple
    p2: tuple
    centre: tuple
    bore_radius_mm: float
    free_direction: int
    theta1_deg: float
    theta2_deg: float
    case: int
    first_rotation: str
    later_rotation: str
    targets: np.ndarray
    target_angles_deg: np.ndarray
    helper_circles: tuple
    segments: tuple = field(default=())
    miss_mm: tuple = (0.0, 0.0)

    @property
    def length_mm(self) -> float:
        """Total path length [mm]."""
        return float(sum(s.length for s in self.segments))

    def polyline(self, samples: int = 64) -> np.ndarray:
        """The whole path as points, array (m, 2), for drawing."""
        return np.concatenate([s.polyline(samples) for s in self.segments])


def _seed_case(theta2: float, free_dir: int) -> tuple[int, str]:
    """The patent's four cases of the first rotation about o1."""
    if theta2 >= 0:
        return (1, "ccw") if free_dir >= 0 else (2, "cw")
    return (3, "cw") if free_dir >= 0 else (4, "ccw")


def _leg(o, radius, a0, a1) -> tuple[Segment, ...]:
    """Move along the wall from angle a0 to a1 (signed turn a1 - a0 about o)."""
    theta = a1 - a0
    s = (o[0] + radius * math.cos(a0), o[1] + radius * math.sin(a0))
    e = (o[0] + radius * math.cos(a1), o[1] + radius * math.sin(a1))
    if abs(theta) > _MAX_ARC:
        return (Segment("line", s, tuple(o)), Segment("line", tuple(o), e, probing=True))
    if theta == 0:
        return (Segment("line", s, e, probing=True),)
    mid = 0.5 * (a0 + a1)
    dist = radius / math.cos(theta / 2)
    c = (o[0] + dist * math.cos(mid), o[1] + dist * math.sin(mid))
    return (Segment("arc", s, e, c, radius * abs(math.tan(theta / 2)), ccw=theta < 0,
                    probing=True),)


def _check_plan_inputs(p: Problems, name, value, *, length=2):
    arr = np.asarray(value, dtype=float) if _numeric(value) else None
    if arr is None or arr.shape != (length,) or not np.all(np.isfinite(arr)):
        p.add(name, value, "a pair of finite numbers (x, y) [mm]")
        return None
    return arr


def _numeric(value) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True


def plan_path(p1, p2, bore_radius_mm: float, free_direction: int, *, n_points: int = 3,
              spread_deg: float = 360.0, start=None) -> PathPlan:
    """The patent's path from the two y contacts (one measurement).

    Parameters
    ----------
    p1, p2 : (x, y) [mm]
        Read contacts along -y and +y.
    bore_radius_mm : float
        Nominal bore radius [mm], > 0.
    free_direction : {1, -1, 0}
        Which way in x the probe is free to move at p2 (0: neither).
    n_points : int, >= 3
    spread_deg : float in [1, 360]
    start : (x, y), optional
        The start point, drawn as the first segment.

    Returns
    -------
    PathPlan
    """
    p = Problems("plan_path")
    a1 = _check_plan_inputs(p, "p1", p1)
    a2 = _check_plan_inputs(p, "p2", p2)
    p.number("bore_radius_mm", bore_radius_mm, low=0, low_open=True)
    p.choice("free_direction", free_direction, (1, -1, 0))
    p.number("n_points", n_points, integer=True, low=3)
    p.number("spread_deg", spread_deg, low=1, high=360)
    st = _check_plan_inputs(p, "start", start) if start is not None else None
    p.raise_if_any()
    if np.hypot(*(a2 - a1)) > 2 * bore_radius_mm * (1 + 1e-6):
        p.add_text(f"p1 and p2 of plan_path are {np.hypot(*(a2 - a1)):g} mm apart, more than the "
                   f"bore's diameter 2 x bore_radius_mm = {2 * bore_radius_mm:g} mm")
    p.raise_if_any()
    core = plan_core(a1[None], a2[None], float(bore_radius_mm),
                      np.array([float(free_direction)]), int(n_points), float(spread_deg))
    o = core["centre"][0]
    r = float(bore_radius_mm)
    sigma = float(core["sigma"][0])
    theta2 = float(core["theta2"][0])
    alpha = core["alpha"][0]
    targets = np.column_stack([o[0] + r * np.cos(alpha), o[1] + r * np.sin(alpha)])
    case, first = _seed_case(theta2, int(free_direction))
    segs = []
    if st is not None:
        segs.append(Segment("line", tuple(st), tuple(a1), probing=True))
    segs.append(Segment("line", tuple(a1), tuple(a2), probing=True))
    a_p2 = float(core["alpha_p2"][0])
    first_leg = _leg(o, r, a_p2, a_p2 + sigma * theta2)
    # the planner's circle passes through p2 only up to its noise: start from p2 itself
    s0 = first_leg[0]
    first_leg = (Segment(s0.kind, tuple(a2), s0.end, s0.centre, s0.radius, s0.ccw,
                         s0.probing),) + first_leg[1:]
    segs += first_leg
    helpers = [(s.centre, s.radius) for s in first_leg if s.kind == "arc"]
    a_prev = a_p2 + sigma * theta2  # d1, unwrapped so that each leg turns the right way
    step = sigma * float(core["step"])
    for _ in range(1, int(n_points)):
        leg = _leg(o, r, a_prev, a_prev + step)
        segs += leg
        helpers += [(s.centre, s.radius) for s in leg if s.kind == "arc"]
        a_prev += step
    later = "cw" if sigma > 0 else "ccw"
    miss = acceptance_check(a1, targets[-1], math.inf)
    return PathPlan(
        start=tuple(st) if st is not None else tuple(0.5 * (a1 + a2)),
        p1=tuple(a1), p2=tuple(a2), centre=tuple(o), bore_radius_mm=r,
        free_direction=int(free_direction),
        theta1_deg=float(core["theta1"][0]) / _DEG, theta2_deg=theta2 / _DEG,
        case=case, first_rotation=first, later_rotation=later,
        targets=targets, target_angles_deg=np.degrees(alpha),
        helper_circles=tuple(helpers), segments=tuple(segs),
        miss_mm=(miss["dx_mm"], miss["dy_mm"]),
    )


def plan_for_bore(start, *, bore_radius_mm: float, centre=(0.0, 0.0), n_points: int = 3,
                  spread_deg: float = 360.0, free_test_mm: float = 0.01) -> PathPlan:
    """The planned path for a round bore without errors, from a start point.

    Parameters
    ----------
    start : (x, y) [mm]
        Where the probe is lowered; must lie inside the bore.
    bore_radius_mm : float
        Radius of the (round) bore [mm], > 0; the planner uses it as nominal.
    centre : (x, y) [mm]
        The bore's true centre.
    n_points, spread_deg : as for :func:`plan_path`
    free_test_mm : float
        Trial displacement at p2 [mm].

    Returns
    -------
    PathPlan
    """
    p = Problems("plan_for_bore")
    st = _check_plan_inputs(p, "start", start)
    c = _check_plan_inputs(p, "centre", centre)
    ok_r = p.number("bore_radius_mm", bore_radius_mm, low=0, low_open=True)
    p.number("free_test_mm", free_test_mm, low=0, low_open=True)
    p.raise_if_any()
    if ok_r and np.hypot(*(st - c)) >= bore_radius_mm:
        p.add("start", tuple(st), f"a point inside the bore (less than bore_radius_mm="
              f"{bore_radius_mm:g} mm from its centre {tuple(c)}; it is "
              f"{np.hypot(*(st - c)):g} mm away)")
    p.raise_if_any()
    dx = st[0] - c[0]
    h = math.sqrt(bore_radius_mm**2 - dx * dx)
    p1 = (st[0], c[1] - h)
    p2 = (st[0], c[1] + h)
    # free when the displaced p2 stays inside: 2 d (x2 - xc) + d^2 < 0 for d = +-test
    plus = 2 * free_test_mm * dx + free_test_mm**2 < 0
    minus = -2 * free_test_mm * dx + free_test_mm**2 < 0
    free = 1 if plus and not minus else (-1 if minus and not plus else 0)
    return plan_path(p1, p2, bore_radius_mm, free, n_points=n_points, spread_deg=spread_deg,
                     start=tuple(st))


def acceptance_check(p1, d_last, tolerance_mm: float) -> dict:
    """The patent's acceptance of the last point: ``|x_p1 - x_dn|``, ``|y_p1 - y_dn|``.

    Parameters
    ----------
    p1, d_last : array (..., 2) [mm]
        The first -y contact and the last measuring point (batch-first allowed).
    tolerance_mm : float
        Largest accepted miss per axis [mm].

    Returns
    -------
    dict
        ``dx_mm``, ``dy_mm`` (arrays or floats) and ``accepted`` (bool array or bool).
        The patent's second difference reads ``|y_p1 - x_d3|``, a typo for
        ``|y_p1 - y_d3|``, which is used here.
    """
    a = np.asarray(p1, dtype=float)
    b = np.asarray(d_last, dtype=float)
    dx = np.abs(a[..., 0] - b[..., 0])
    dy = np.abs(a[..., 1] - b[..., 1])
    acc = (dx <= tolerance_mm) & (dy <= tolerance_mm)
    if dx.ndim == 0:
        return {"dx_mm": float(dx), "dy_mm": float(dy), "accepted": bool(acc)}
    return {"dx_mm": dx, "dy_mm": dy, "accepted": acc}


def miss(setup: Setup, readings: dict) -> dict:
    """The acceptance check of simulated or measured readings (batch-first)."""
    p1 = np.stack([np.asarray(readings["p_x_mm"])[:, 0], np.asarray(readings["p_y_mm"])[:, 0]],
                  axis=-1)
    dn = np.stack([np.asarray(readings["x_mm"])[:, -1], np.asarray(readings["y_mm"])[:, -1]],
                  axis=-1)
    return acceptance_check(p1, dn, setup.miss_tolerance_mm)


# --------------------------------------------------------------------------- duration, figure
def duration(setup: Setup) -> float:
    """Machine time [s]: path length at the feed, the last clearance of each contact at the
    probing feed, a dwell per contact. The path is averaged over nine start points
    (the centre of the scatter square, its corners and edge mid-points) about the
    nominal centre of a nominal bore.
    """
    s = setup.start_scatter_mm
    r = setup.bore_radius_mm
    lengths = []
    for fx in (-1, 0, 1):
        for fy in (-1, 0, 1):
            plan = plan_for_bore((fx * s, fy * s), bore_radius_mm=r, n_points=setup.n_points,
                                 spread_deg=setup.spread_deg, free_test_mm=setup.free_test_mm)
            lengths.append(plan.length_mm)
    contacts = n_contacts(setup)
    move = float(np.mean(lengths)) - contacts * setup.clearance_mm
    t = max(move, 0.0) / (setup.feed_mm_min / 60.0)
    t += contacts * (setup.clearance_mm / (setup.probe_feed_mm_min / 60.0) + setup.dwell_s)
    return float(t)


def report_extras(setup: Setup, truth: Truth) -> dict:
    """The planned probing path of the nominal measurement, as data for the report's figure.

    Start point at the truth's start, a round bore at the truth's centre; the figure draws
    the bore, the helper circles, the path and the points p1, p2, d1..dn.
    """
    plan = plan_for_bore((truth.start_x_mm, truth.start_y_mm), bore_radius_mm=setup.bore_radius_mm,
                         centre=(truth.centre_x_mm, truth.centre_y_mm), n_points=setup.n_points,
                         spread_deg=setup.spread_deg, free_test_mm=setup.free_test_mm)
    points = {"start": plan.start, "p1": plan.p1, "p2": plan.p2}
    points.update({f"d{i + 1}": tuple(map(float, t)) for i, t in enumerate(plan.targets)})
    circles = [(truth.centre_x_mm, truth.centre_y_mm, setup.bore_radius_mm, "")]
    circles += [(float(c[0]), float(c[1]), float(r), f"o{i + 1}")
                for i, (c, r) in enumerate(plan.helper_circles)]
    return {"path": {
        "caption": (f"Planned probing path (patent's case {plan.case}, first rotation "
                    f"{plan.first_rotation}, path length {plan.length_mm:.0f} mm): start, the "
                    "two y contacts p1 and p2, then the measuring points d1..dn reached on "
                    "helper arcs tangent to the radii (dashed: bore and helper circles)."),
        "polylines": [plan.polyline()],
        "points": points,
        "circles": circles,
        "view": (truth.centre_x_mm, truth.centre_y_mm, 1.25 * setup.bore_radius_mm),
    }}
