"""U of every measurand over a lever's range: the page's sensitivity curve."""

from __future__ import annotations

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.explore.prediction import CURVE_SECONDS, guard_cost, predict
from mtplan.explore.state import K, json_value, normalise, setup_of
from mtplan.explore.trust import known_spot, resolution_steps, trust
from mtplan.models.protocol import fields_info

__all__ = ["lever_values", "sensitivity"]


def lever_values(proc, setup, field: str, n: int = 9) -> list:
    """Values of a numeric field over its range around the current value (n at most)."""
    info = next(f for f in fields_info(proc.Setup) if f.name == field)
    v = getattr(setup, field)
    kind = info.kind
    if kind not in (int, float) or v is None:
        raise InvalidInput([f"The lever {field!r} of {proc.name} is not a number; a "
                            "sensitivity needs a numeric field."])
    lo, hi = info.low, info.high
    v = float(v)
    a = lo if lo is not None else (0.0 if v >= 0 else 4 * v)
    b = hi if hi is not None else max(4 * abs(v), 1.0)
    # keep the plot around the current value: at most x0.25 .. x4 on ratio-scale fields
    if lo is not None and lo >= 0 and v > 0:
        a, b = max(a, v / 4), min(b, v * 4)
    if info.low_open and a == lo:
        a = a + (b - a) / (4 * n)
    if info.high_open and b == hi:
        b = b - (b - a) / (4 * n)
    if kind is int:
        vals = sorted(set(int(round(x)) for x in np.linspace(a, b, n)) | {int(v)})
    else:
        vals = sorted(set(float(x) for x in np.linspace(a, b, n)) | {v})
    return vals


def _num(v):
    return float(v) if isinstance(v, float) else v


def sensitivity(design: dict, field: str | None = None, n: int = 9, *, stop=None) -> dict:
    """U (k = 2) of every measurand over a lever's range, the current value marked.

    `stop`, a callable, is asked before each point: when it says True (a newer change has
    come from the same page) the curve is given up, ``superseded`` True, so that it never
    holds up the numbers of that change.
    """
    design = normalise(design)
    if field is not None and not isinstance(field, str):
        raise InvalidInput([f"The 'field' of a sensitivity must be a set-up field's name (text). "
                            f"Got {str(field)[:40]!r} instead."])
    proc, setup = setup_of(design)
    field = field or design["lever"]
    if field not in {f.name for f in fields_info(proc.Setup)}:
        raise InvalidInput([f"The lever {str(field)[:40]!r} is no set-up field of {proc.name}."])
    est, _ = proc.estimator(design["estimator"])
    guard_cost(proc, setup, est)
    spot = known_spot(proc, setup, est)
    untrusted = sorted(k for k, v in trust(predict(proc, setup, est)["u"], spot,
                                           resolution_steps(proc, setup, est)).items()
                       if v["trust"] == "no")
    now = _num(getattr(setup, field))
    budget, points = CURVE_SECONDS, {}
    # nearest the current value first: where the budget runs out, the far ends are left
    for x in sorted(lever_values(proc, setup, field, n), key=lambda v: abs(v - now)):
        if stop is not None and stop():
            return {"field": field, "superseded": True}
        try:
            s = setup.replace(**{field: x})
            cost = guard_cost(proc, s, est)
        except InvalidInput:
            continue  # a value the procedure refuses, or beyond the live budget: no point
        if not proc.measurands(s):
            continue  # nothing to draw (and nothing for a first-order budget to give)
        if cost["seconds"] > budget and x != now:
            continue
        budget -= cost["seconds"]
        points[x] = predict(proc, s, est)["u"]
    xs, curves = sorted(points), {}
    for x in xs:
        for name, u in points[x].items():
            curves.setdefault(name, []).append(K * u)
    info = next(f for f in fields_info(proc.Setup) if f.name == field)
    return {"field": field, "unit": info.unit, "x": xs, "U": curves, "untrusted": untrusted,
            "current": json_value(getattr(setup, field)),
            "units": {m.name: m.unit for m in proc.measurands(setup)},
            "targets": {k: v for k, v in design["targets"].items()}}
