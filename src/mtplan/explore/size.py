"""The size of a set-up's work from its count fields alone, before any model runs.

Building a set-up's sources and running its forward model once to count its error inputs
and readings took, at a count field's end-stop, minutes and gigabytes (line_laser with
100 000 points a line: 71 s and 4.8 GB; geometry21 with 100 line repeats of 2001 points: a
MemoryError). Here the two numbers that size the work, error inputs ``n`` and readings
``r``, are estimated from the sizes its count fields state
(:attr:`~mtplan.models.fields.FieldInfo.count`: an int field's value, a list field's
length). Each count field scales each number along a line, learnt once per procedure
from the default set-up and one or two small set-ups that change that field alone::

    n(x) = n0 * prod_i F_i(x_i),   F_i(x) = a_i + s_i x   (F_i = 1 where x_i is empty)

(the same for ``r``; a product, so that fields that multiply each other, line
repeats times line points, are costed together). A field with a value at its default
(an int ``x0``) is learnt from ``x0`` and ``2 x0``, or the next size the procedure
accepts; one whose default is empty (``positions`` of rotary_axis, an empty list of
positions) from the two smallest sizes it accepts. Probe lists hold evenly spaced values
in the field's range (:func:`probe_value`). A probe the procedure refuses (a rule between
fields: C angles only for the combined axis) is tried again with each other choice of the
set-up's choice fields, the field's line then learnt relative to that set-up.

The measurands are not counted here: the procedure's own list of them may need an
analysis of the set-up (geometry21's identifiability, a second a set-up); the prediction's
own estimate costs them (:func:`mtplan.explore.prediction.prediction_cost`).

A set-up estimated beyond :data:`LIVE_SIZE` (a live answer) or :data:`JOB_SIZE` (a
background job's trial) is refused in microseconds, naming the largest value the field
that weighs most may take with the others as they are. Learning a procedure's model takes
10-300 ms once it is imported; the server learns every one at start, in the background
(:func:`mtplan.explore.prediction.learn_costs`).
"""

from __future__ import annotations

import functools

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.models import get
from mtplan.models.protocol import fields_info

__all__ = ["LIVE_SIZE", "JOB_SIZE", "size_model", "estimated_size",
           "size_problem", "probe_value"]

#: the most error inputs or readings a set-up may be estimated to have for a live answer
LIVE_SIZE = 200_000
#: ... and for a background job (Monte Carlo, planner, check): one trial's arrays
JOB_SIZE = 2_000_000
#: the two numbers, in the order of a size model's tuples
_WHAT = ("error inputs", "readings")


def _count(proc, setup) -> tuple:
    """(error inputs, readings) of a set-up, counted by building it (small set-ups only)."""
    n = int(sum(src.size for src in proc.active_sources(setup).values()))
    out = proc.forward(setup, proc.Truth(), proc.zero_errors(setup, 1))
    return n, int(sum(np.size(v) for v in out.values()))


def probe_value(info, size: int):
    """A value of the count field `info` of that size: the int itself, or `size` evenly
    spaced numbers after the field's lower end (0 where it allows it) up to at most 100 of
    its units beyond it (distinct positions, angles or offsets, such as a set-up takes; the
    end itself left out: a position at 0 may be a reference that states nothing)."""
    if info.kind is int:
        return size
    low = -np.inf if info.low is None else float(info.low) + (1.0 if info.low_open else 0.0)
    high = np.inf if info.high is None else float(info.high) - (1.0 if info.high_open else 0.0)
    start = min(max(0.0, low), high)
    end = min(start + 100.0, high)
    return tuple(float(v) for v in np.round(np.linspace(start, end, size + 1)[1:], 6))


def _probes(info, x0) -> list:
    """The sizes to try, smallest change first, within the field's range."""
    largest = info.largest if info.largest is not None else 10**9
    if x0 is None:
        start = max(int(info.low or 1) if info.kind is int else (info.min_len or 1), 1)
        sizes = [start, 2 * start, start + 1, start + 2, start + 3, 3 * start]
    else:
        sizes = [2 * x0, x0 + 1, x0 + 2, x0 + 3] if x0 >= 1 else [1, 2, 3, 4, 6]
    return [x for x in dict.fromkeys(sizes) if x <= largest and x != x0]


@functools.lru_cache(maxsize=64)
def size_model(name: str) -> dict:
    """The size model of a procedure: ``{"base": (n0, r0), "lines": {field: ((a_n, s_n),
    (a_r, s_r))}, "unlearnt": {field: why}}``, learnt at the default set-up (or at the one
    with another choice where the procedure refuses the field's sizes there). A count field
    that cannot grow within its range (a list of exactly three) is in neither."""
    proc = get(name)
    default = proc.Setup()
    counts = {(): _count(proc, default)}
    lines, unlearnt = {}, {}
    for info in fields_info(proc.Setup):
        if not info.count or info.file or not _probes(info, info.size(info.default)):
            continue
        refused = ""
        for change in _bases(proc):
            line, why = _line(proc, default.replace(**dict(change)), info, counts, change)
            if line is not None:
                lines[info.name] = line
                break
            refused = refused or why
        else:
            unlearnt[info.name] = refused
    return {"base": counts[()], "lines": lines, "unlearnt": unlearnt}


def _bases(proc) -> list:
    """The changes of the default set-up a field's sizes are tried at: none, then each
    other choice of each choice field (the combined axis for its C angles)."""
    setup = proc.Setup()
    return [()] + [((f.name, c),) for f in fields_info(proc.Setup) if f.choices
                   for c in f.choices if c != getattr(setup, f.name)]


def _line(proc, base, info, counts: dict, change: tuple) -> tuple:
    """(((a_n, s_n), (a_r, s_r)) or None, why): the field's factor line at `base` (its
    counts kept in `counts` under `change`), from its size there and one more, or from
    two sizes where it is empty."""
    try:
        if change not in counts:
            counts[change] = _count(proc, base)
    except (InvalidInput, ValueError) as exc:
        return None, str(exc).splitlines()[0][:200]
    x0 = info.size(getattr(base, info.name))
    points = [] if x0 is None else [(x0, (1.0, 1.0))]
    why = "no size of it was accepted"
    for x in _probes(info, x0):
        if len(points) == 2:
            break
        try:
            n = _count(proc, base.replace(**{info.name: probe_value(info, x)}))
        except (InvalidInput, ValueError) as exc:
            why = str(exc).splitlines()[0][:200]
            continue
        points.append((x, tuple(c / max(b, 1) for c, b in zip(n, counts[change], strict=True))))
    if len(points) < 2:
        return None, why
    (xa, fa), (xb, fb) = points
    return tuple((a - (b - a) / (xb - xa) * xa, (b - a) / (xb - xa))
                 for a, b in zip(fa, fb, strict=True)), ""


def _factor(line: tuple, x: float) -> float:
    a, s = line
    return max(a + s * x, 0.05)


def estimated_size(proc, values: dict) -> dict:
    """Estimated error inputs ``inputs`` and readings ``readings`` of a set-up stated by
    `values` (field -> value; the defaults for the rest), and each count field's
    ``factors`` on the two."""
    model = size_model(proc.name)
    size = [float(x) for x in model["base"]]
    infos = {f.name: f for f in fields_info(proc.Setup)}
    factors = {}
    for field, lines in model["lines"].items():
        x = infos[field].size(values.get(field))
        if x is None:
            continue
        each = [_factor(line, x) for line in lines]
        factors[field] = each
        size = [s * f for s, f in zip(size, each, strict=True)]
    return {"inputs": size[0], "readings": size[1], "factors": factors}


def size_problem(proc, values: dict, *, limit: float = LIVE_SIZE,
                 what: str = "a live answer") -> tuple:
    """(estimated size, message or None): the message, where the estimated error inputs
    or readings exceed `limit`, names the largest value the weightiest count field may take
    with the others as stated."""
    size = estimated_size(proc, values)
    numbers = (size["inputs"], size["readings"])
    over = int(numbers[1] >= numbers[0])
    if numbers[over] <= limit:
        return size, None
    model = size_model(proc.name)
    infos = {f.name: f for f in fields_info(proc.Setup)}
    weights = {f: v[over] for f, v in size["factors"].items()}
    heavy = {f: v for f, v in weights.items() if v > 1} or weights
    field = max(heavy, key=heavy.get) if heavy else None
    stated = ", ".join(f"{f} = {_shown(values.get(f))}" for f in sorted(heavy)) \
        if heavy else "the defaults"
    where = ""
    if field is not None:
        # the factor this field may have, the others as they are: solved for its size
        room = weights[field] * limit / numbers[over]
        a, s = model["lines"][field][over]
        largest = int((room - a) / s) if s > 0 else 0
        count = "may be at most" if infos[field].kind is int else "may hold at most"
        where = (f" With the others as they are, {field} {count} {largest}"
                 f"{'' if infos[field].kind is int else ' values'}."
                 if largest >= 1 else f" Make {', '.join(sorted(heavy))} smaller.")
    return size, (f"This {proc.name} set-up ({stated}) would have about "
                  f"{numbers[over]:.3g} {_WHAT[over]}, more than the {limit:.3g} {what} "
                  f"may take.{where}")


def _shown(value) -> str:
    """A count field's value as a refusal quotes it: a list by its length."""
    return f"{len(value)} values" if isinstance(value, list | tuple) else str(value)
