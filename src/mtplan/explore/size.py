"""The size of a set-up's work from its count fields alone, before any model runs.

The cost guard of :mod:`mtplan.explore.prediction` counts a set-up's error inputs and
readings by building its sources and running its forward model once: at a count field's
end-stop that alone took minutes and gigabytes (line_laser with 100 000 points a line:
71 s and 4.8 GB; geometry21 with 100 line repeats of 2001 points: a MemoryError). Here
the two numbers are estimated from the values of the fields that size the work (the
integer fields: points, lines, repeats, positions, lattice, sub-machines): each field
scales the share of the work it sizes in proportion, learnt once per procedure from the
default set-up and the set-up with that field doubled (both small)::

    n(x) = n0 * prod_i (1 + f_i (x_i / x0_i - 1)),   f_i = n(2 x0_i) / n0 - 1

(the same for the readings; a product, so that fields that multiply each other, line
repeats times line points, are costed together). A set-up estimated beyond
:data:`LIVE_SIZE` (a live answer) or :data:`JOB_SIZE` (a background job) is refused in
microseconds, naming the largest value the field that weighs most may take with the others
as they are. A field whose doubled set-up the procedure refuses (a rule between fields) or
that sizes nothing is given the share 0.
"""

from __future__ import annotations

import functools

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.models import get
from mtplan.models.protocol import fields_info

__all__ = ["LIVE_SIZE", "JOB_SIZE", "size_model", "estimated_size", "size_problem"]

#: the most error inputs or readings a set-up may be estimated to have for a live answer
LIVE_SIZE = 200_000
#: ... and for a background job (Monte Carlo, planner, check): one trial's arrays
JOB_SIZE = 2_000_000


def _count(proc, setup) -> tuple:
    """(error inputs, readings) of a set-up, counted by building it (small set-ups only)."""
    n = int(sum(src.size for src in proc.active_sources(setup).values()))
    out = proc.forward(setup, proc.Truth(), proc.zero_errors(setup, 1))
    return n, int(sum(np.size(v) for v in out.values()))


def _count_fields(proc) -> list:
    return [f.name for f in fields_info(proc.Setup) if f.kind is int]


@functools.lru_cache(maxsize=64)
def size_model(name: str) -> dict:
    """The size model of a procedure: ``{"base": (n0, r0), "at": {field: x0},
    "shares": {field: (f_n, f_r)}}``, learnt at the default set-up."""
    proc = get(name)
    setup = proc.Setup()
    n0, r0 = _count(proc, setup)
    at, shares = {}, {}
    for field in _count_fields(proc):
        x0 = getattr(setup, field)
        if not isinstance(x0, int) or x0 < 1:
            continue
        try:
            n1, r1 = _count(proc, setup.replace(**{field: 2 * x0}))
        except (InvalidInput, ValueError):
            continue  # the procedure refuses the doubled value alone: not costed by it
        at[field] = x0
        shares[field] = (max(n1 / max(n0, 1) - 1.0, 0.0), max(r1 / max(r0, 1) - 1.0, 0.0))
    return {"base": (n0, r0), "at": at, "shares": shares}


def _factor(share: float, ratio: float) -> float:
    return max(1.0 + share * (ratio - 1.0), 0.05)


def estimated_size(proc, values: dict) -> dict:
    """Estimated error inputs ``n`` and readings ``r`` of a set-up stated by `values`
    (field -> value; the defaults for the rest), and each count field's factor."""
    model = size_model(proc.name)
    n, r = (float(x) for x in model["base"])
    factors = {}
    for field, x0 in model["at"].items():
        x = values.get(field, x0)
        if not isinstance(x, int | float) or isinstance(x, bool) or x <= 0:
            continue
        f_n, f_r = model["shares"][field]
        factors[field] = max(_factor(f_n, x / x0), _factor(f_r, x / x0))
        n, r = n * _factor(f_n, x / x0), r * _factor(f_r, x / x0)
    return {"inputs": n, "readings": r, "factors": factors}


def size_problem(proc, values: dict, *, limit: float = LIVE_SIZE,
                 what: str = "a live answer") -> tuple:
    """(estimated size, message or None): the message, where the estimated error inputs or
    readings exceed `limit`, names the largest value the weightiest count field may take
    with the others as stated."""
    size = estimated_size(proc, values)
    worst = max(size["inputs"], size["readings"])
    if worst <= limit:
        return size, None
    model = size_model(proc.name)
    heavy = {f: v for f, v in size["factors"].items() if v > 1} or size["factors"]
    field = max(heavy, key=heavy.get) if heavy else None
    stated = ", ".join(f"{f} = {values.get(f, model['at'][f])}" for f in sorted(heavy)) \
        if heavy else "the defaults"
    where = ""
    if field is not None:
        x0, share = model["at"][field], max(model["shares"][field])
        # the factor this field may have, the others as they are: solved for its value
        room = size["factors"][field] * limit / worst
        largest = int(x0 * (1.0 + (room - 1.0) / share)) if share > 0 else 0
        where = (f" With the others as they are, {field} may be at most {largest}."
                 if largest >= 1 else f" Make {', '.join(sorted(heavy))} smaller.")
    kind = "readings" if size["readings"] >= size["inputs"] else "error inputs"
    return size, (f"This {proc.name} set-up ({stated}) would have about {worst:.3g} {kind}, "
                  f"more than the {limit:.3g} {what} may take.{where}")
