"""Choosing a set-up: the cheapest one meeting uncertainty targets, Pareto fronts,
continuous optimal-design search and identifiability.

Two speeds, as a metrologist would work:

1. *Screen* every candidate set-up with the linearised prediction (the GUM law of
   propagation through forward model and estimator; for an efficient estimator and
   Gaussian sources this is the Cramer-Rao bound from the Fisher information).
2. *Confirm* the shortlist, cheapest first, by Monte Carlo, and report the ratio of
   the two. A candidate is recommended only once its Monte Carlo uncertainty meets
   every target: never an unconfirmed winner.

The candidates are the user's grid (``vary``) where one is given; without one, every lever
the procedure declares at its declared options and every calibration it offers
(:mod:`mtplan.plans.levers`: a bounded search by the same linearised prediction). A
candidate's cost is the test's duration plus the cost of a calibration it takes.

Targets bound the standard uncertainty (``k=1``) or the expanded uncertainty
``k u`` of named measurands, in their display units (um, urad).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from mtplan._parallel import check_parallel, ordered_map, parallel_session
from mtplan._validate import InvalidInput, Problems
from mtplan.compensation.unseen import unseen_covariance
from mtplan.evaluation.first_order import first_order
from mtplan.evaluation.reliability import reliability
from mtplan.evaluation.simulation import linearize_procedure, simulate_uncertainty
from mtplan.models import get
from mtplan.models.protocol import fields_info, make
from mtplan.plans import levers as _levers
from mtplan.plans.identifiability import identifiability, observability_indices
from mtplan.plans.sweep import canonical, setup_grid
from mtplan.uncertainty.montecarlo import ModelError
from mtplan.uncertainty.options import Options

__all__ = ["PlanResult", "PlanOptions", "plan", "pareto_front", "optimize_design",
           "readings_jacobian", "design_identifiability", "parse_target", "PfaCriterion",
           "RESIDUAL", "RELIABILITY", "target_u", "target_value", "target_measurand"]


#: a target on the residual after compensation: ``residual:EXX<=2``
RESIDUAL = "residual:"
#: a target on what one bad reading can do unseen: ``reliability:centre_x<=4`` bounds the
#: largest shift of centre_x that an error of one reading the fit check misses (its
#: minimal detectable bias, :mod:`mtplan.evaluation.reliability`) can cause
RELIABILITY = "reliability:"


def target_measurand(name: str) -> str:
    """The measurand a target names: ``residual:EX0C`` and ``reliability:EX0C`` name EX0C."""
    for prefix in (RESIDUAL, RELIABILITY):
        if name.startswith(prefix):
            return name[len(prefix):]
    return name


def target_u(proc, setup, name: str, u: Mapping[str, float], estimator: str | None = None
             ) -> float:
    """The standard uncertainty a target bounds: the measurand's (`u`: its standard
    uncertainty by name [display unit], at `setup`), or for ``residual:M`` that of the error
    left after the machine is compensated with M's estimate by `estimator`, as ``mtplan
    compensate`` predicts it: M's u with what the test cannot see of it, less what that
    unseen part moved in the estimate (``u^2 + D_MM``,
    :func:`mtplan.compensation.unseen.unseen_covariance`); where the correction model
    realises nothing, M's u and its ``unseen_of`` in quadrature. NaN where the set-up does
    not determine the measurand."""
    measurand = name.removeprefix(RESIDUAL)
    if measurand not in u:
        return math.nan
    if name == measurand:
        return float(u[measurand])
    joint = _unseen_part(proc, setup, estimator)
    if joint is not None and measurand in joint[0]:
        i = joint[0].index(measurand)
        # u^2 + D >= 0 where u holds the unseen sources' own share, as the set-up's does
        return math.sqrt(max(float(u[measurand]) ** 2 + float(joint[1][i, i]), 0.0))
    unseen = proc.correction.unseen_of(setup.as_dict(), measurand)[0]
    return math.hypot(float(u[measurand]), unseen)


#: (procedure, set-up, estimator) -> its unseen covariance, the last 64 (a plan's search
#: asks each candidate's residual several times)
_UNSEEN: dict = {}


def _unseen_part(proc, setup, estimator):
    """:func:`~mtplan.compensation.unseen.unseen_covariance` at the set-up, once per
    procedure, set-up and estimator."""
    key = (proc.name, canonical(setup), estimator)
    if key not in _UNSEEN:
        if len(_UNSEEN) >= 64:
            _UNSEEN.pop(next(iter(_UNSEEN)))
        _UNSEEN[key] = unseen_covariance(proc, {"procedure": proc.name,
                                                "setup": setup.as_dict(),
                                                "estimator": estimator})
    return _UNSEEN[key]


def target_value(proc, setup, name: str, u: Mapping[str, float], k: float,
                 shifts: Mapping[str, float] | None = None, estimator: str | None = None
                 ) -> float:
    """What a target bounds, in the measurand's display unit: ``k`` times :func:`target_u`,
    or for ``reliability:M`` the largest shift of M that one reading's error the fit check
    misses can cause (`shifts`, :meth:`Reliability.shift`; not scaled by ``k``: it is a
    shift, not an uncertainty). NaN where the set-up does not determine M."""
    if name.startswith(RELIABILITY):
        return float((shifts or {}).get(target_measurand(name), math.nan))
    return k * target_u(proc, setup, name, u, estimator)


def parse_target(text: str) -> tuple[str, float]:
    """Parse ``NAME<=VALUE`` (or ``NAME=VALUE``) into (name, value); NAME may be
    ``residual:M`` (the error left after compensating M, :func:`target_u`) or
    ``reliability:M`` (the largest shift of M one undetected bad reading can cause,
    :func:`target_value`)."""
    for sep in ("<=", "="):
        name, found, value = text.partition(sep)
        if found:
            try:
                v = float(value)
            except ValueError:
                break
            if name.strip() and math.isfinite(v) and v > 0:
                return name.strip(), v
            break
    raise InvalidInput([f"A target must read NAME<=VALUE with a value > 0 in the measurand's "
                        f"unit (e.g. EX0C<=2, residual:EX0C<=2 for the error left after "
                        f"compensation, or reliability:EX0C<=2 for the largest shift one "
                        f"undetected bad reading can cause). Got {text!r} instead."])


def pareto_front(cost: np.ndarray, value: np.ndarray) -> np.ndarray:
    """Indices of the non-dominated points (lower cost and lower value both better),
    sorted by cost."""
    cost = np.asarray(cost, dtype=float)
    value = np.asarray(value, dtype=float)
    order = np.lexsort((value, cost))
    front, best = [], math.inf
    for i in order:
        if value[i] < best:
            front.append(int(i))
            best = value[i]
    return np.array(front, dtype=int)


@dataclass
class PlanResult:
    """What :func:`plan` found.

    Attributes
    ----------
    table : pandas.DataFrame
        One row per candidate: set-up fields, ``duration_s``, ``cost_s`` (the duration plus
        the cost of the ``calibration`` it takes, named there), predicted ``u_<name>``
        (k times the linearised standard uncertainty) per target, ``worst`` (largest
        ratio of prediction to target) and ``feasible``.
    best : dict or None
        The recommended set-up: ``setup`` (fields), ``duration_s``, ``predicted`` and
        ``confirmed`` uncertainties per target measurand.
    pareto : list of dict
        Non-dominated candidates (cost against ``worst``), cheapest first.
    confirmation : list of dict
        The Monte Carlo checks made, in order: set-up, predicted and Monte Carlo
        uncertainty per target, their ratio, and whether the targets were met.
    targets : dict
    k : float
    runners_up : list of dict
    search : str
        Without a grid, what the default search over the levers tried (one line;
        :meth:`mtplan.plans.levers.Search.summary`); "" for a grid.
    """

    table: object
    best: dict | None
    pareto: list
    confirmation: list
    targets: dict
    k: float
    runners_up: list = field(default_factory=list)
    search: str = ""

    def to_dict(self) -> dict:
        return {
            "targets": self.targets,
            "k": self.k,
            "search": self.search,
            "best": self.best,
            "runners_up": self.runners_up,
            "pareto": self.pareto,
            "confirmation": self.confirmation,
        }


def _setup_fields(setup) -> dict:
    return setup.as_dict()


@dataclass(frozen=True)
class PlanOptions(Options):
    """How :func:`plan` judges and confirms its candidates (frozen: change one with
    :meth:`replace`).

    Attributes
    ----------
    k : float
        Coverage factor of the targets (1: standard uncertainty).
    confirm : int
        Largest number of candidates checked by Monte Carlo before giving up.
    trials : int
        Monte Carlo trials of each confirmation.
    seed : int
        The confirmations' seed.
    n_jobs, backend
        Parallel screening of the candidates.
    criterion : callable, optional
        Extra feasibility rule ``criterion(u: dict) -> bool`` on the k-scaled
        uncertainties (used by the acceptance-driven plan).
    identify : bool
        Add the identifiability columns (``rank``, ``n_params``, ``condition``,
        ``O1`` ... ``O5``, see :func:`design_identifiability`) to the table: for every
        candidate of a grid, for the recommended one of the search over the levers (NaN
        in the other rows).
    determine : "all" or iterable of str, optional
        Measurands the set-up must determine at all (procedures whose measurands depend
        on the set-up, such as geometry21's error functions): a candidate is feasible
        only if it lists every one; ``"all"`` means every measurand the procedure can
        report (geometry21: the 21 errors). Targets may name measurands that only some
        candidates determine.
    levers : bool
        Without a grid (``vary``), search every declared lever at its options and every
        calibration the procedure offers (:mod:`mtplan.plans.levers`); False: the base
        set-up alone.
    max_candidates : int
        The most candidates of the search's product of levers.
    """

    k: float = 1.0
    confirm: int = 5
    trials: int = 5000
    seed: int = 0
    n_jobs: int = 1
    backend: str | None = None
    criterion: object = None
    identify: bool = True
    determine: object = None
    levers: bool = True
    max_candidates: int = _levers.MAX_CANDIDATES

    WHAT = "plan option"


def plan(
    procedure,
    base_setup=None,
    vary: Mapping[str, Sequence] | None = None,
    targets: Mapping[str, float] | None = None,
    *,
    truth=None,
    estimator: str | None = None,
    sources=None,
    **options,
) -> PlanResult:
    """The set-up of least duration whose uncertainty meets every target.

    Parameters
    ----------
    procedure : str or Procedure
    base_setup : Setup, optional
    vary : mapping of field to values
        Candidate grid (the Cartesian product), which narrows the search to it; empty means
        every declared lever and calibration (:mod:`mtplan.plans.levers`; the option
        ``levers=False``: the base set-up alone).
    targets : mapping of measurand name to value
        Upper bounds for ``k u`` [display unit of each measurand].
    truth, estimator, sources
        As for :func:`mtplan.evaluation.simulation.simulate_uncertainty`.
    **options
        ``options=`` a :class:`PlanOptions` (the coverage factor ``k``, ``confirm``,
        ``trials``, ``seed``, ``n_jobs``, ``backend``, ``criterion``, ``identify``,
        ``determine``, ``levers``, ``max_candidates``), and any of its fields as keywords,
        which replace the record's.

    Raises
    ------
    InvalidInput
        For targets naming unknown measurands, and when no candidate can meet a
        target (the message gives the best reachable value of each, where it is reached and
        at what cost, and the lever or calibration outside a grid that would meet it or
        comes nearest).
    """
    o = PlanOptions.of(options.pop("options", None), **options)
    k, confirm, trials, seed, criterion = o.k, o.confirm, o.trials, o.seed, o.criterion
    n_jobs, backend, identify, determine = o.n_jobs, o.backend, o.identify, o.determine
    proc = get(procedure)
    base_setup = proc.Setup() if base_setup is None else base_setup
    proc.check_setup(base_setup)
    truth = proc.Truth() if truth is None else truth
    targets = dict(targets or {})
    vary = dict(vary or {})
    setups = setup_grid(proc, base_setup, vary) if vary else [base_setup]
    units, listed = _possible_measurands(proc, setups)
    names = list(units)
    required = _required(proc, names, determine)
    _check_plan(proc, names, targets, criterion, k, confirm, trials, n_jobs, backend, required,
                o.max_candidates)
    proc.estimator(estimator)
    judge = _Judge(proc, truth, estimator, sources, targets, k, criterion, required)
    done = found = None
    if not vary and o.levers:
        found = _levers.search(proc, base_setup, judge.score, max_candidates=o.max_candidates)
        setups = found.setups
        units, listed = _possible_measurands(proc, setups, judge.measurands)
        names = list(units)
        done = [judge.assess(s) for s in setups]
    table = _screen(proc, setups, truth, estimator, sources, targets, k, criterion,
                    identify and found is None, n_jobs, backend, names, required, listed,
                    done=done, base=base_setup)
    front = pareto_front(table["cost_s"].to_numpy(), table["worst"].to_numpy())
    feasible = table[table["feasible"]].sort_values(["cost_s", "worst"], kind="stable")
    pareto = [_candidate(table.iloc[i], setups[i], names, targets) for i in front]
    if feasible.empty:
        raise InvalidInput(_unreachable(units, table, targets, vary, criterion, required,
                                        _Where(proc, base_setup, setups, vary, judge)))
    best, confirmation = _confirm(proc, setups, table, feasible.index[:confirm], truth,
                                  estimator, sources, targets, k, criterion, trials, seed)
    if identify and found is not None:  # of the search's candidates, the recommended one's
        j = best["candidate"]
        _identify_rows(proc, setups, truth, table, [j])
        best["identifiability"] = _candidate(table.loc[j], setups[j], names,
                                             targets)["identifiability"]
    runners = [_candidate(table.loc[j], setups[j], names, targets)
               for j in feasible.index if j != best["candidate"]][:3]
    for c in [best, *runners, *pareto]:  # what each changes from the base set-up
        c["changes"] = _levers.changes(proc, base_setup, setups[c["candidate"]],
                                       tuple(vary) if vary else None)
    return PlanResult(table=table, best=best, pareto=pareto, confirmation=confirmation,
                      targets=targets, k=k, runners_up=runners,
                      search=found.summary() if found is not None else "")


class _Judge:
    """The linearised u of a candidate (once per set-up) and its score for the lever
    search: each target's k u over its bound, the measurands left undetermined."""

    def __init__(self, proc, truth, estimator, sources, targets, k, criterion, required):
        self.proc, self.truth, self.estimator, self.sources = proc, truth, estimator, sources
        self.targets, self.k, self.criterion, self.required = targets, k, criterion, required
        self.memo, self.listed = {}, {}

    def assess(self, setup) -> tuple:
        """(u, {}, shifts) of :func:`_assess`, once per set-up."""
        key = canonical(setup)
        if key not in self.memo:
            reliable = any(n.startswith(RELIABILITY) for n in self.targets)
            self.memo[key] = _assess(self.proc, setup, self.truth, self.estimator,
                                     self.sources, True, False, reliable)
        return self.memo[key]

    def u(self, setup) -> dict:
        return self.assess(setup)[0]

    def measurands(self, setup) -> tuple:
        """The procedure's measurands at `setup`, once per set-up (geometry21's take a
        rank analysis)."""
        key = canonical(setup)
        if key not in self.listed:
            self.listed[key] = self.proc.measurands(setup)
        return self.listed[key]

    def score(self, setup) -> _levers.Score:
        u, _, shifts = self.assess(setup)
        ratios = [target_value(self.proc, setup, n, u, self.k, shifts, self.estimator) / v
                  for n, v in self.targets.items()]
        ratios = [r if math.isfinite(r) else math.inf for r in ratios]
        listed = {m.name for m in self.measurands(setup)}
        missing = [n for n in self.required if n not in listed]
        values = list(ratios)
        if missing or self.required:
            values.append(1.0 + len(missing))
        if self.criterion is not None:  # the criterion's measurand, else every measurand
            values += [self.k * u[n] for n in ([self.criterion.name]
                       if getattr(self.criterion, "name", None) in u else u)]
        worst = max(ratios + ([math.inf] if missing else []), default=0.0)
        feasible = worst <= 1 and (self.criterion is None or bool(
            self.criterion({n: self.k * x for n, x in u.items()})))
        return _levers.Score(np.array(values, dtype=float), worst, feasible)


class _Where:
    """How a message names a candidate: what it changes from the base set-up (the grid's
    fields, or the levers and the calibration searched) and its cost; and, for a grid, the
    lever or calibration outside it that would meet the targets or comes nearest."""

    def __init__(self, proc, base, setups, vary, judge):
        self.proc, self.base, self.setups, self.vary, self.judge = proc, base, setups, vary, judge

    def __call__(self, j) -> str:
        s = self.setups[j]
        if self.vary:
            shown = {f: getattr(s, f) for f in self.vary}
        else:
            shown = _levers.changes(self.proc, self.base, s)
        text = ", ".join(f"{f}={v}" if f != "calibration" else f"with the calibration {v!r}"
                         for f, v in shown.items())
        if not self.vary:
            text = (text or "the base set-up") + \
                f"; cost {_levers.cost_of(self.proc, self.base, s):.0f} s"
        return text

    def outside(self, j) -> str:
        """For a grid: the one lever option or calibration about candidate `j` that meets
        the targets, or comes nearest, with its cost; "" without a grid."""
        if not self.vary:
            return ""
        s = self.setups[j]
        near = _levers.nearest(self.proc, s, self.judge.score, fields=tuple(self.vary))
        if near is None:
            return ""
        other, score = near
        change = ", ".join(f"{f}={v}" if f != "calibration" else f"the calibration {v!r}"
                           for f, v in _levers.changes(self.proc, s, other).items())
        cost = _levers.cost_of(self.proc, self.base, other)
        what = "would meet the targets" if score.feasible else \
            f"comes nearest (worst ratio {score.worst:.3g})"
        return f"; outside the grid, {change} {what} at a cost of {cost:.0f} s"


def _possible_measurands(proc, setups, measurands=None) -> tuple[dict, list]:
    """Every measurand a candidate may report, name -> unit: those listed at any candidate
    and, where the procedure's identifiability report names them (geometry21: the 21 error
    functions), those the procedure could report at some set-up; in the procedure's order.
    Also each candidate's own list. `measurands`: the procedure's, or a memo of it."""
    names = dict.fromkeys(proc.capabilities.identifiability_report(setups[0]).get(
        "functions", {}), "")
    listed = []
    for s in setups:
        ms = (measurands or proc.measurands)(s)
        names.update({m.name: m.unit for m in ms})
        listed.append([m.name for m in ms])
    return names, listed


def _required(proc, names, determine) -> tuple:
    """The measurands a candidate must determine (``determine``: None, "all" or names)."""
    if determine is None:
        return ()
    if isinstance(determine, str) and determine.strip().lower() == "all":
        return tuple(names)
    wanted = [determine] if isinstance(determine, str) else list(determine)
    unknown = [n for n in wanted if n not in names]
    if unknown:
        raise InvalidInput([f"The 'determine' parameter of plan {proc.name} must name its "
                            f"measurands ({', '.join(names)}) or be 'all'. Got "
                            f"{', '.join(map(repr, unknown))} instead."])
    return tuple(wanted)


def _check_plan(proc, names, targets, criterion, k, confirm, trials, n_jobs, backend,
                required=(), max_candidates=1):
    """Every problem of the plan's arguments at once."""
    p = Problems(f"plan {proc.name}")
    if not targets and criterion is None and not required:
        p.add_text("plan needs at least one target NAME<=VALUE")
    for name, value in targets.items():
        measurand = target_measurand(name)
        if measurand not in names:
            p.add_text(f"The target {name!r} names no measurand of {proc.name}; its measurands "
                       f"are: {', '.join(names)}")
        elif name.startswith(RESIDUAL) and not proc.correction.kind:
            p.add_text(f"The target {name!r} bounds a residual after compensation, but "
                       f"{proc.name} states no correction a controller takes")
        p.number(f"targets[{name!r}]", value, low=0, low_open=True)
    p.number("k", k, low=0, low_open=True)
    p.number("confirm", confirm, integer=True, low=1)
    p.number("trials", trials, integer=True, low=100)
    p.number("max_candidates", max_candidates, integer=True, low=1)
    check_parallel(p, n_jobs, backend)
    p.raise_if_any()


def _screen(proc, setups, truth, estimator, sources, targets, k, criterion, identify, n_jobs,
            backend, names=None, required=(), listed=None, done=None, base=None):
    """The candidates' table: linearised (k-scaled) uncertainties (NaN for measurands a
    candidate does not determine), worst target ratio, identifiability and feasibility,
    one row per set-up. A candidate that misses a required measurand is not linearised.
    `done`: each set-up's (u, identifiability) where already known; `base`: the set-up whose
    calibrations a candidate's cost leaves out (default: the first)."""
    import pandas as pd

    names = [m.name for m in proc.measurands(setups[0])] if names is None else names
    if listed is None:
        listed = [[m.name for m in proc.measurands(s)] for s in setups]
    missing = [[n for n in required if n not in ls] for ls in listed]
    base = setups[0] if base is None else base
    if done is None:
        with parallel_session(n_jobs, backend) as session:  # one task per candidate, so that
            # a procedure's per-set-up precomputation serves both
            reliable = [target_measurand(n) for n in targets if n.startswith(RELIABILITY)]
            tasks = ((proc, s, truth, estimator, sources, not miss, identify,
                      bool(reliable) and not miss) for s, miss in zip(setups, missing))
            done = list(ordered_map(_assess, tasks, n_jobs=session["n_jobs"], backend=backend))
    rows = []
    for i, (s, (u, ident, shifts)) in enumerate(zip(setups, done, strict=True)):
        cal = _levers.calibration_of(proc, base, s)
        row = {"candidate": i, **_flat(_setup_fields(s)), "duration_s": float(proc.duration(s)),
               "cost_s": _levers.cost_of(proc, base, s),
               "calibration": cal.name if cal is not None else ""}
        for name in names:
            row[f"u_{name}"] = k * u[name] if name in u else math.nan
        for name in targets:
            row[f"u_{name}"] = target_value(proc, s, name, u, k, shifts, estimator)
        ratios = [row[f"u_{n}"] / v if math.isfinite(row[f"u_{n}"]) else math.inf
                  for n, v in targets.items()]
        if missing[i]:
            ratios.append(math.inf)
        row["worst"] = max(ratios) if ratios else 0.0
        row.update(ident)
        if required:
            row["determined"] = len(listed[i])
            row["undetermined"] = ",".join(missing[i])
        row["feasible"] = bool(all(r <= 1 for r in ratios)) and (
            criterion is None or bool(criterion({n: k * u[n] for n in u})))
        rows.append(row)
    return pd.DataFrame(rows)


def _unreachable(units, table, targets, vary, criterion, required=(), where=None) -> list[str]:
    """Why no candidate is feasible: the measurands no candidate determines, the best
    reachable value of each target missed (`where(j)`: how candidate j is named, and
    ``where.outside(j)`` the lever beyond a grid that would meet the targets)."""
    names = list(units)
    msgs = []
    if where is None:
        def where(j):
            return ", ".join(f"{f}={table.loc[j, f]}" for f in (vary or {}))
        where.outside = lambda j: ""
    if required:
        full = table[table["undetermined"] == ""]
        if full.empty:
            j = int(table["determined"].idxmax())
            at = where(j)
            msgs.append(f"No candidate determines every measurand asked for: the best "
                        f"determines {table.loc[j, 'determined']} and leaves "
                        f"{table.loc[j, 'undetermined']} undetermined"
                        + (f" (at {at})" if at else "") + where.outside(j))
            return msgs
        table = full
    for n, v in targets.items():
        if table[f"u_{n}"].isna().all():
            msgs.append(f"The target {n}<={v:g} cannot be met: no candidate determines {n}")
            continue
        j = int(table[f"u_{n}"].idxmin())
        reach = table.loc[j, f"u_{n}"]
        if reach > v:
            at = where(j)
            unit = units[target_measurand(n)]
            msgs.append(f"The target {n}<={v:g} {unit} cannot be met: the best reachable "
                        f"value is {reach:.3g} {unit}" + (f" (at {at})" if at else "")
                        + where.outside(j))
    if not msgs and criterion is not None and hasattr(criterion, "explain"):
        us = [{n: float(table.loc[j, f"u_{n}"]) for n in names
               if math.isfinite(table.loc[j, f"u_{n}"])} for j in table.index]
        msgs.append(criterion.explain(us, [dict(zip(vary or {}, (table.loc[j, f] for f in
                                                                 (vary or {})), strict=True))
                                           for j in table.index]))
    if not msgs:
        j = int(table["worst"].idxmin())
        msgs.append(("No candidate meets every target at once (each can be met alone)"
                     if targets else "No candidate meets the acceptance criterion")
                    + where.outside(j))
    return msgs


def _confirm(proc, setups, table, candidates, truth, estimator, sources, targets, k, criterion,
             trials, seed):
    """Monte Carlo of the cheapest feasible candidates until one meets every target:
    (best candidate, the confirmation record of each tried)."""
    confirmation = []
    for j in candidates:
        s = setups[j]
        names = [m.name for m in proc.measurands(s)]
        names += [n for n in targets if n not in names]  # residual targets
        try:
            r = simulate_uncertainty(proc, s, truth, estimator=estimator, sources=sources,
                                     trials=trials, rng=seed, progress=False)
        except ModelError as exc:  # the estimator fails on some trials: not confirmed
            confirmation.append({"candidate": int(j), "setup": _setup_fields(s),
                                 "duration_s": float(table.loc[j, "duration_s"]),
                                 "met": False, "error": str(exc)})
            continue
        mc_std = {m.name: float(r.mc.std[i]) for i, m in enumerate(r.measurands)}
        mc_u = {m: k * v for m, v in mc_std.items()}
        # a reliability target is the design's own (the estimator's response to one
        # reading, the fit check's MDB): the Monte Carlo has nothing to add to it
        mc_u.update({n: float(table.loc[j, f"u_{n}"]) if n.startswith(RELIABILITY)
                     else k * target_u(proc, s, n, mc_std, estimator) for n in targets if n not in mc_u})
        met = all(mc_u[n] <= v for n, v in targets.items()) and (
            criterion is None or bool(criterion(mc_u)))
        within, within_se = r.coverage_within(r.mc.mean, k * r.mc.std)
        confirmation.append({
            "candidate": int(j),
            "setup": _setup_fields(s),
            "duration_s": float(table.loc[j, "duration_s"]),
            "predicted": {n: float(table.loc[j, f"u_{n}"]) for n in names},
            "monte_carlo": mc_u,
            # the fraction of the Monte Carlo values within +- k u: the coverage each
            # confirmed value really has (mtplan.uncertainty.coverage)
            "monte_carlo_coverage": dict(zip([m.name for m in r.measurands],
                                             map(float, within), strict=True)),
            "monte_carlo_coverage_se": dict(zip([m.name for m in r.measurands],
                                                map(float, within_se), strict=True)),
            "ratio": {n: float(mc_u[n] / table.loc[j, f"u_{n}"]) if table.loc[j, f"u_{n}"] > 0
                      else math.nan for n in names},
            "trials": int(r.mc.trials),
            "met": bool(met),
        })
        if met:
            return {**_candidate(table.loc[j], s, names, targets), "confirmed": mc_u}, confirmation
    raise InvalidInput([
        f"None of the {len(confirmation)} cheapest candidates predicted to meet the targets "
        "was confirmed by Monte Carlo (the linearised prediction is optimistic here); widen "
        "the grid or relax the targets"])


class PfaCriterion:
    """Feasibility rule of :func:`plan`: the global false-accept probability under a limit.

    Parameters
    ----------
    name : str
        The toleranced measurand.
    lo, hi : float or None
        Tolerance limits [display unit]; None for a one-sided tolerance.
    prior : prior of :mod:`mtplan.plans.acceptance`
        The population of machines.
    rule : decision rule of :mod:`mtplan.plans.acceptance`
    max_pfa : float
        Largest allowed global false-accept probability.
    """

    def __init__(self, name, lo, hi, prior, rule, max_pfa):
        self.name, self.lo, self.hi = name, lo, hi
        self.prior, self.rule, self.max_pfa = prior, rule, max_pfa

    def pfa(self, u: dict) -> float:
        from mtplan.plans.acceptance import plan_acceptance

        return plan_acceptance(self.lo, self.hi, u[self.name], prior=self.prior,
                               rule=self.rule).pfa

    def __call__(self, u: dict) -> bool:
        return u[self.name] > 0 and self.pfa(u) <= self.max_pfa

    def explain(self, us: list, where: list) -> str:
        pfas = [self.pfa(u) for u in us]
        j = min(range(len(pfas)), key=pfas.__getitem__)
        at = ", ".join(f"{k}={v}" for k, v in where[j].items())
        return (f"No candidate keeps the false-accept probability for {self.name} at or below "
                f"{self.max_pfa:g}: the lowest reachable is {pfas[j]:.4g}" + (f" (at {at})" if at else ""))


def _flat(fields: dict) -> dict:
    return {k: (",".join(f"{x:g}" for x in v) if isinstance(v, list) else v) for k, v in fields.items()}


_IDENT = ("rank", "n_params", "condition", "O1", "O2", "O3", "O4", "O5")


def _candidate(row, setup, names, targets) -> dict:
    names = [*names, *(n for n in targets if n not in names)]  # residual targets
    out = {
        "candidate": int(row["candidate"]),
        "setup": setup.as_dict(),
        "duration_s": float(row["duration_s"]),
        "cost_s": float(row["cost_s"]),
        "calibration": str(row["calibration"]),
        "predicted": {n: float(row[f"u_{n}"]) for n in names if math.isfinite(row[f"u_{n}"])},
        "worst": float(row["worst"]),
    }
    if "rank" in row and not math.isnan(row["rank"]):
        out["identifiability"] = {k: (int(row[k]) if k in ("rank", "n_params") else float(row[k]))
                                  for k in _IDENT}
    return out


def _identify_rows(proc, setups, truth, table, rows) -> None:
    """The identifiability columns of the rows `rows` of `table` (the others NaN): the
    recommended set-up of the search, without the analysis of every set-up it screened."""
    for j in dict.fromkeys(int(r) for r in rows):
        for key, value in design_identifiability(proc, setups[j], truth).items():
            if key not in table.columns:
                table[key] = math.nan
            table.loc[j, key] = value


def _assess(proc, setup, truth, estimator, sources, predict, identify,
            reliable=False) -> tuple[dict, dict, dict]:
    """One candidate's linearised uncertainties (when `predict`), identifiability (when
    `identify`) and the largest undetected shift of each measurand (when `reliable`)."""
    u = first_order(proc, setup, truth, estimator=estimator, sources=sources).u() if predict \
        else {}
    shifts = {}
    if reliable:
        rel = reliability(proc, setup, truth, estimator=estimator)
        shifts = {m: rel.shift(m) for m in rel.measurands}
    return u, design_identifiability(proc, setup, truth) if identify else {}, shifts


# --------------------------------------------------------------------------- design search
def criterion_value(g, criterion: str) -> float:
    cov = g.cov
    if criterion.startswith("u:"):
        return float(g.std[g.index(criterion[2:])])
    if criterion == "D":  # geometric mean of the covariance ellipsoid's axes
        sign, logdet = np.linalg.slogdet(cov)
        return float(math.exp(logdet / (2 * cov.shape[0]))) if sign > 0 else math.inf
    if criterion == "A":
        return float(math.sqrt(np.trace(cov) / cov.shape[0]))
    if criterion == "E":
        return float(math.sqrt(max(np.linalg.eigvalsh(cov).max(), 0.0)))
    raise InvalidInput([f"The 'criterion' parameter must be 'u:MEASURAND', 'D', 'A' or 'E'. "
                        f"Got {criterion!r} instead."])


def optimize_design(
    procedure,
    base_setup=None,
    free: Mapping[str, tuple[float, float]] | None = None,
    *,
    criterion: str = "D",
    truth=None,
    estimator: str | None = None,
    maxiter: int = 200,
):
    """Search continuous set-up choices for the best linearised criterion.

    Parameters
    ----------
    free : mapping of field to (low, high)
        Float fields, or a tuple field (every element free within the bounds, for
        example the rotation angles of an axis within its range).
    criterion : str
        ``"u:NAME"`` (a measurand's standard uncertainty), ``"D"`` (geometric mean
        of the covariance's principal standard deviations, i.e. D-optimality),
        ``"A"`` (root mean variance) or ``"E"`` (largest principal standard deviation),
        over the measurands in display units.

    Returns
    -------
    dict with ``setup`` (the optimum), ``value`` (criterion there), ``start_value``
    (at the base set-up) and ``evaluations``.
    """
    from scipy.optimize import minimize

    proc = get(procedure)
    base_setup = proc.Setup() if base_setup is None else base_setup
    infos = {i.name: i for i in fields_info(proc.Setup)}
    p = Problems(f"optimize_design {proc.name}")
    if not free:
        p.add_text("optimize_design needs at least one free field")
    layout, x0, bounds = [], [], []
    for name, lim in (free or {}).items():
        if name not in infos or infos[name].kind not in (float, "tuple"):
            p.add("free", name, "float or list-of-number set-up fields")
            continue
        if not (isinstance(lim, Sequence) and len(lim) == 2 and lim[0] < lim[1]):
            p.add(f"free[{name!r}]", lim, "a pair (low, high) with low < high")
            continue
        value = getattr(base_setup, name)
        if infos[name].kind == "tuple":
            if value is None:
                p.add(f"free[{name!r}]", value, "a list field that is set in the base set-up")
                continue
            layout.append((name, len(value)))
            x0 += list(value)
            bounds += [tuple(lim)] * len(value)
        else:
            layout.append((name, 0))
            x0.append(value)
            bounds.append(tuple(lim))
    p.raise_if_any()
    evaluations = [0]

    def setup_at(x):
        vals, pos = {}, 0
        for name, n in layout:
            if n:
                vals[name] = tuple(float(v) for v in x[pos : pos + n])
                pos += n
            else:
                vals[name] = float(x[pos])
                pos += 1
        return make(proc.Setup, vals, base=base_setup, owner=proc.name)

    def objective(x):
        evaluations[0] += 1
        x = np.clip(x, [b[0] for b in bounds], [b[1] for b in bounds])
        try:
            g = linearize_procedure(proc, setup_at(x), truth, estimator=estimator)
        except InvalidInput:
            return 1e300
        return criterion_value(g, criterion)

    start = objective(np.array(x0, dtype=float))
    res = minimize(objective, np.array(x0, dtype=float), method="Nelder-Mead", bounds=bounds,
                   options={"maxiter": maxiter, "xatol": 1e-3, "fatol": 1e-6 * max(start, 1e-300)})
    x = np.clip(res.x, [b[0] for b in bounds], [b[1] for b in bounds])
    return {"setup": setup_at(x), "value": float(res.fun), "start_value": float(start),
            "evaluations": evaluations[0]}


def readings_jacobian(procedure, setup=None, truth=None, *, wrt: str | None = None):
    """Sensitivity of the noise-free readings to the measurands (or truth fields).

    Parameters
    ----------
    wrt : {"measurands", "truth"}, optional
        ``"measurands"`` (the default when the procedure builds a truth from an estimate,
        ``Capabilities.builds_truths``):
        columns are the measurands [reading unit per mm or rad]. ``"truth"``: every
        float Truth field that moves the readings at all (fields without effect, such
        as the other axis's errors, are left out).

    Returns
    -------
    (J, names): J of shape (n_readings, n_params), central differences with steps of
    1e-6 of each value's magnitude (at least 1e-9); every step of every measurand in one
    forward run where the procedure batches truths (``Capabilities.batches_truths``).
    """
    proc = get(procedure)
    setup = proc.Setup() if setup is None else setup
    truth = proc.Truth() if truth is None else truth
    zero = proc.zero_errors(setup, 1)
    if wrt is None:
        wrt = "measurands" if proc.capabilities.builds_truths else "truth"

    def flat(t):
        r = proc.forward(setup, t, zero)
        return np.concatenate([np.asarray(v, dtype=float).ravel() for v in r.values()])

    cols, names = [], []
    if wrt == "measurands" and proc.capabilities.batches_truths:
        # every step of every measurand as one batch row: one truth per row, one forward run
        base = proc.true_values(setup, truth)
        names = list(base)
        h = np.array([max(abs(v) * 1e-6, 1e-9) for v in base.values()])
        step = np.concatenate([np.diag(h), -np.diag(h)])  # (2 p, p): up rows, then down
        rows = np.array(list(base.values()), dtype=float)[None, :] + step
        r = proc.forward(setup, proc.capabilities.truths_from_estimates(
            setup, {n: rows[:, j] for j, n in enumerate(names)}),
            proc.zero_errors(setup, rows.shape[0]))
        f = np.concatenate([np.asarray(v, dtype=float).reshape(rows.shape[0], -1)
                            for v in r.values()], axis=1)
        p = len(names)
        return ((f[:p] - f[p:]) / (2 * h[:, None])).T, names
    if wrt == "measurands":
        base = proc.true_values(setup, truth)
        for name, v in base.items():
            h = max(abs(v) * 1e-6, 1e-9)
            up = proc.capabilities.truth_from_estimate(setup, {**base, name: v + h})
            down = proc.capabilities.truth_from_estimate(setup, {**base, name: v - h})
            cols.append((flat(up) - flat(down)) / (2 * h))
            names.append(name)
    else:
        for f in fields_info(proc.Truth):
            if f.kind is not float:
                continue
            v = getattr(truth, f.name)
            h = max(abs(v) * 1e-6, 1e-9)
            col = (flat(dataclasses.replace(truth, **{f.name: v + h}))
                   - flat(dataclasses.replace(truth, **{f.name: v - h}))) / (2 * h)
            if np.any(col):
                cols.append(col)
                names.append(f.name)
    return np.column_stack(cols), names


def design_identifiability(procedure, setup=None, truth=None) -> dict:
    """Rank, condition number and observability indices O1-O5 of a set-up.

    Uses the procedure's own ``identifiability_report(setup)`` where it declares one
    (geometry21: the joint model of all error coefficients), else the column-scaled
    sensitivities of :func:`readings_jacobian`.

    Returns
    -------
    dict with ``rank``, ``n_params``, ``condition`` (of the identified part where the
    module's report says so), ``O1`` ... ``O5``; and ``determined`` (how many measurands
    the readings determine) where the module's report gives its Jacobian and the
    measurands as functions of its parameters.
    """
    proc = get(procedure)
    setup = proc.Setup() if setup is None else setup
    rep = proc.capabilities.identifiability_report(setup)
    if rep:
        if "jacobian" in rep:  # the model's own Jacobian: the generic analysis, with the
            # measurands as functions of its parameters (geometry21's 21 error functions)
            gen = identifiability(rep["jacobian"], scale=rep["scale"], names=rep["names"],
                                  tol=rep["rank_tol"], n_poses=int(rep["readings"]),
                                  functions=rep["functions"])
            return {"rank": int(gen.rank), "n_params": int(gen.n_params),
                    "condition": float(rep["condition_number"]), **gen.observability,
                    "determined": int(sum(gen.determined.values()))}
        sv = np.asarray(rep["singular_values"], dtype=float)
        return {"rank": int(rep["rank"]), "n_params": int(rep["parameters"]),
                "condition": float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf,
                **observability_indices(sv, int(rep["readings"]))}
    J, names = readings_jacobian(proc, setup, truth)
    rep = identifiability(J, names=names)
    return {"rank": int(rep.rank), "n_params": int(rep.n_params),
            "condition": float(rep.condition_number), **rep.observability}
