"""The planner's default search: every lever a procedure declares, at its declared options,
and every calibration it offers, at its cost.

A lever's options come from its declaration (``Procedure.lever_options``: its ``levels``,
a bool's two values, a choice field's choices; a continuous lever is held at the set-up's
value). A calibration (``Capabilities.calibrations``) is one more option, taken or not, whose
cost adds to the test's duration. The search is bounded, not the whole product:

1. *Screen*: the base set-up, then each other option of each lever and each calibration,
   one at a time, by the first-order prediction (the caller's ``evaluate``).
2. *Prune*: a lever (or calibration) none of whose options moves a screened quantity (a
   target's predicted u over its bound) or the cost by more than :data:`RTOL` is held at
   the base; an option that is, alone, no cheaper than the base and better on no screened
   quantity (dominated) is not searched further.
3. *Combine*: the Cartesian product of the kept ones, those with the largest effect on the
   targets first (then on the cost), as many whole levers as keep it within
   ``max_candidates`` (default :data:`MAX_CANDIDATES`).
4. *Refine*: from the cheapest candidate that meets the targets (else the one nearest to
   them), each kept lever left out of the product tried at each of its options, one at a
   time (a coordinate step), repeated while it finds a better candidate, at most
   :data:`PASSES` times.

At most ``sum(options) + max_candidates + PASSES * sum(options)`` set-ups are evaluated.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.models.protocol import make
from mtplan.plans.sweep import canonical
from mtplan.uncertainty.montecarlo import ModelError

__all__ = ["RTOL", "MAX_CANDIDATES", "PASSES", "Score", "Search", "search", "calibration_of",
           "cost_of", "changes", "nearest"]

#: relative change of a screened quantity below which a lever is taken to have no effect
RTOL = 0.01
#: the most candidates of the product of the kept levers
MAX_CANDIDATES = 32
#: the most coordinate passes of the refinement
PASSES = 3


@dataclass(frozen=True)
class Score:
    """What the caller's ``evaluate(setup)`` says of a set-up.

    Attributes
    ----------
    values : array
        The screened quantities, smaller better (each target's predicted u over its bound);
        their relative changes decide which levers are searched.
    worst : float
        The largest ratio of a prediction to its target (inf: a target not determined).
    feasible : bool
        Every target (and criterion) met.
    """

    values: np.ndarray
    worst: float
    feasible: bool


@dataclass(frozen=True, eq=False)
class _Dim:
    """One searched choice: a lever (its options) or a calibration (not taken, taken)."""

    name: str
    options: tuple
    calibration: object = None


@dataclass
class Search:
    """What :func:`search` found.

    Attributes
    ----------
    setups : list
        The candidates evaluated that the procedure accepts, the base set-up first.
    scores : list of Score
        Each candidate's score.
    searched : dict
        Lever (or calibration name) -> the options tried.
    product : list of str
        The levers combined in full (step 3).
    refined : list of str
        The kept levers tried one at a time about the best (step 4).
    pruned : list of str
        The levers held at the base for want of an effect on the targets and the cost
        (step 2).
    refused : int
        Combinations the procedure refused (a set-up it does not allow).
    """

    setups: list = field(default_factory=list)
    scores: list = field(default_factory=list)
    searched: dict = field(default_factory=dict)
    product: list = field(default_factory=list)
    refined: list = field(default_factory=list)
    pruned: list = field(default_factory=list)
    refused: int = 0

    def summary(self) -> str:
        """One line: what was searched, combined, refined and held."""
        text = f"{len(self.setups)} set-ups over " + (", ".join(
            self.product + self.refined) or "no lever that moves the targets")
        if self.refined:
            text += f" ({', '.join(self.refined)} one at a time)"
        if self.pruned:
            text += f"; held (no effect on the targets or the cost): {', '.join(self.pruned)}"
        return text


def calibration_of(proc, base, setup):
    """The calibration of `proc` that `setup` takes and `base` does not (its fields set to
    the calibration's values), or None."""
    for cal in proc.capabilities.calibrations:
        if all(getattr(setup, f) == v for f, v in cal.values.items()) and not all(
                getattr(base, f) == v for f, v in cal.values.items()):
            return cal
    return None


def cost_of(proc, base, setup) -> float:
    """The planner's cost of a candidate [s]: the test's duration, plus the cost of the
    calibration it takes beyond `base` (:func:`calibration_of`)."""
    cal = calibration_of(proc, base, setup)
    return float(proc.duration(setup)) + (cal.cost_s if cal is not None else 0.0)


def changes(proc, base, setup, fields=None) -> dict:
    """What a candidate changes from `base`: lever (or `fields`) -> value, and
    ``calibration`` -> its name where it takes one; the calibration's own fields are not
    repeated."""
    cal = calibration_of(proc, base, setup)
    own = set(cal.values) if cal is not None else set()
    names = proc.levers if fields is None else fields
    out = {f: getattr(setup, f) for f in names
           if f not in own and getattr(setup, f) != getattr(base, f)}
    if cal is not None:
        out["calibration"] = cal.name
    return out


def _dims(proc, base) -> list:
    """The levers with more than one option and the calibrations `base` does not take."""
    dims = [_Dim(n, v) for n, v in proc.lever_options(base).items() if len(v) > 1]
    dims += [_Dim(c.name, (False, True), c) for c in proc.capabilities.calibrations
             if not all(getattr(base, f) == v for f, v in c.values.items())]
    return dims


def _setup(proc, base, choice: dict, dims: dict):
    """The set-up of a choice (dim name -> option; `dims`: name -> _Dim, whose first option
    is the base's): the levers' values and the fields of each calibration taken."""
    values = {}
    for name, value in choice.items():
        dim = dims[name]
        if dim.calibration is None:
            if value != dim.options[0]:
                values[name] = value
        elif value:
            values.update(dim.calibration.values)
    return make(proc.Setup, values, base=base, owner=proc.name) if values else base


def _dominated(base: Score, cost0: float, other: Score, cost: float) -> bool:
    """An option no cheaper than the base and better on no screened quantity."""
    a, b = np.asarray(base.values, float), np.asarray(other.values, float)
    a, b = np.where(np.isnan(a), np.inf, a), np.where(np.isnan(b), np.inf, b)
    return bool(cost >= cost0 and np.all(b >= a))


def _effect(base: Score, other: Score) -> float:
    """The largest relative change of a screened quantity (log ratio; inf where one is
    finite and the other not)."""
    a, b = np.asarray(base.values, float), np.asarray(other.values, float)
    fa, fb = np.isfinite(a), np.isfinite(b)
    if np.any(fa != fb):
        return math.inf
    both = fa & fb & (a > 0) & (b > 0)
    ratio = np.abs(np.log(b[both] / a[both])) if both.any() else np.zeros(0)
    moved = np.any((a[fa & fb] == 0) != (b[fa & fb] == 0))
    return math.inf if moved else float(ratio.max(initial=0.0))


def search(proc, base, evaluate: Callable, *, max_candidates: int = MAX_CANDIDATES) -> Search:
    """Search the declared levers and calibrations of `proc` about `base` (module notes).

    Parameters
    ----------
    proc : Procedure
    base : its Setup
    evaluate : callable
        ``evaluate(setup) -> Score``, or None for a set-up that cannot be evaluated.
    max_candidates : int
        The most candidates of the product of the kept levers (step 3).
    """
    found = Search()
    memo: dict = {}
    costs: dict = {}
    dims = {d.name: d for d in _dims(proc, base)}

    def setup_of(choice):
        try:
            return _setup(proc, base, choice, dims)
        except InvalidInput:
            return None

    def score(choice):
        setup = setup_of(choice)
        if setup is None:
            found.refused += 1
            return None, math.nan
        key = canonical(setup)
        if key not in memo:
            try:
                s = evaluate(setup)
            except (InvalidInput, ModelError, np.linalg.LinAlgError):
                s = None
            memo[key] = s
            costs[key] = cost_of(proc, base, setup)
            if s is not None:
                found.setups.append(setup)
                found.scores.append(s)
        return memo[key], costs[key]

    def best_of(choices):
        """The choice that meets the targets at least cost, else the nearest to them."""
        ranked = []
        for c in choices:
            setup = setup_of(c)
            s = memo.get(canonical(setup)) if setup is not None else None
            if s is not None:
                ranked.append(((not s.feasible, costs[canonical(setup)] if s.feasible
                                else s.worst), c))
        return min(ranked, key=lambda r: r[0])[1]

    start = {n: d.options[0] for n, d in dims.items()}
    first, cost0 = score(start)
    if first is None:
        raise InvalidInput([f"The base set-up of {proc.name} cannot be evaluated"])
    effect, saving, useful = {}, {}, {}
    for n, d in dims.items():  # 1. screen, one at a time
        found.searched[n] = d.options
        moved, useful[n] = [], [d.options[0]]
        for v in d.options[1:]:
            s, c = score({**start, n: v})
            if s is not None:
                moved.append((_effect(first, s), abs(math.log(max(c, 1e-9) / max(cost0, 1e-9)))))
                if not _dominated(first, cost0, s, c):
                    useful[n].append(v)
        effect[n] = max((m[0] for m in moved), default=0.0)
        saving[n] = max((m[1] for m in moved), default=0.0)
    tol = math.log1p(RTOL)
    kept = sorted((n for n in dims if (effect[n] > tol or saving[n] > tol)
                   and len(useful[n]) > 1), key=lambda n: (-min(effect[n], 1e300), -saving[n]))
    found.pruned = [n for n in dims if n not in kept]  # 2. prune
    product, size = [], 1
    for n in kept:  # 3. combine, largest effect first
        if size * len(useful[n]) > max_candidates:
            break
        product.append(n)
        size *= len(useful[n])
    combos = [{**start, **dict(zip(product, combo, strict=True))}
              for combo in itertools.product(*(useful[n] for n in product))]
    for c in combos:
        score(c)
    found.product = list(product)
    found.refined = [n for n in kept if n not in product]
    best = best_of(combos)
    for _ in range(PASSES if found.refined else 0):  # 4. refine about the best, coordinate-wise
        tried = [{**best, n: v} for n in found.refined for v in useful[n]]
        for c in tried:
            score(c)
        better = best_of([best, *tried])
        if better == best:
            break
        best = better
    return found


def nearest(proc, setup, evaluate: Callable, fields=()) -> tuple | None:
    """The one lever option or calibration, about `setup` and outside `fields` (those the
    user narrowed the search to), that meets the targets at least cost, else that comes
    nearest: (set-up, score), or None where no other option is evaluated."""
    tried = []
    dims = {d.name: d for d in _dims(proc, setup)}
    for name, d in dims.items():
        if name in fields:
            continue
        for v in d.options[1:]:
            try:
                other = _setup(proc, setup, {name: v}, dims)
                s = evaluate(other)
            except (InvalidInput, ModelError, np.linalg.LinAlgError):
                continue
            if s is not None:
                tried.append((other, s))
    if not tried:
        return None
    return min(tried, key=lambda t: (not t[1].feasible,
                                      cost_of(proc, setup, t[0]) if t[1].feasible
                                      else t[1].worst))
