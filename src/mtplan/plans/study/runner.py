"""A study computed: every result a report shows, in stages run in parallel.

:func:`run_study` cuts a :class:`~mtplan.plans.study.schema.Study` into stages (each
estimator's Monte Carlo, each distinct set-up of the sweeps, each procedure's budget, plan,
readings and extras), runs them on worker processes as they become ready, and joins them
into a :class:`StudyResult` of one :class:`ProcedureOutcome` per procedure, with the verdicts
and the advice; the reports render it without computing anything.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from mtplan._validate import InvalidInput
from mtplan.evaluation.reliability import reliability
from mtplan.models.protocol import with_conditions
from mtplan.plans.study.provenance import provenance
from mtplan.plans.study.schema import ProcedureStudy, Study

__all__ = ["ProcedureOutcome", "StudyResult", "run_study"]


@dataclass
class ProcedureOutcome:
    """Everything computed for one procedure of a study (display units).

    ``recommended`` is the estimator the study recommends (:func:`decisions.
    recommend_estimator`) over the measurands in ``key`` (toleranced and targeted ones);
    ``verdicts`` holds a :class:`~mtplan.plans.decisions.Verdict` per toleranced measurand,
    ``summary`` the procedure's rows of the summary page, ``levers`` the swept levers
    ranked by their effect, ``dominant`` the error sources that dominate, ``targets`` the
    target u per measurand for the figures, ``setup_shown`` the set-up fields a reader needs.
    """

    spec: ProcedureStudy
    title: str
    results: dict                      # estimator -> ProcedureResult
    gum: object                        # GUMResult of the recommended estimator, or None
    budget: object                     # DataFrame: measurand, source, contribution, share
    sweeps: list                       # (spec dict, DataFrame)
    plan: object | None = None         # PlanResult or an error message
    measured: object | None = None     # result of the readings evaluation
    identifiability: object | None = None
    extras: dict = field(default_factory=dict)
    recommended: str = ""
    key: list = field(default_factory=list)
    verdicts: list = field(default_factory=list)
    summary: list = field(default_factory=list)
    levers: list = field(default_factory=list)
    dominant: list = field(default_factory=list)
    comparison: dict = field(default_factory=dict)
    targets: dict = field(default_factory=dict)
    setup_shown: dict = field(default_factory=dict)
    duration_s: float = math.nan
    budget_estimator: str = ""
    as_left: object | None = None      # readings after adjustment, evaluated
    as_left_verdicts: list = field(default_factory=list)
    #: the readings' correction and the residual predicted after it
    #: (:class:`~mtplan.compensation.predicted.Predicted`), or why there is none
    compensation: object | None = None
    #: what one bad reading can do unseen at the agreed set-up, before the test
    #: (:class:`~mtplan.evaluation.reliability.Reliability`; after it: the readings
    #: evaluation's ``sections["reliability"]``)
    reliability: object | None = None


@dataclass
class StudyResult:
    study: Study
    outcomes: list
    provenance: dict
    #: what ``run_study``'s ``then`` gave for each test (in test order), or None
    then: list | None = None

    @property
    def verdicts(self) -> list:
        """Every toleranced measurand's verdict, in study order."""
        return [v for o in self.outcomes for v in o.verdicts]


def run_study(study: Study, *, progress=None, n_jobs: int = 1,
              command: str | None = None, readings: bool = True, then=None) -> StudyResult:
    """Compute every result a study asks for (the reports only render them).

    The work is cut into stages, each computed on one core: each estimator's Monte Carlo,
    each distinct set-up of a procedure's sweeps (one stage for every sweep that holds it:
    the base set-up is in most), and each procedure's plan, identifiability and extras;
    then, as soon as a procedure's Monte Carlo stages are done and so its recommended
    estimator is known, its budget and its readings evaluation. ``n_jobs`` worker
    processes take the ready stages, the readings and budgets first (the longest, on which
    the procedure waits), the sweeps' set-ups last, those of the procedures whose Monte
    Carlo was quickest first (:func:`_order`). Every stage
    draws from the study's seed exactly as a serial run does, so the result does not depend
    on ``n_jobs`` nor on the order the stages ran in (beyond the last bits of floating-point
    sums, which numpy and BLAS may add in another order in another process).

    Parameters
    ----------
    study : Study
    progress : bool or None
        A progress bar on stderr: True, False, or None (only on a terminal).
    n_jobs : int
        Parallel worker processes (-1: all cores).
    command : str, optional
        The command line that asked for the study, for the provenance.
    readings : bool
        Evaluate the readings (False: the plan only, issued before measuring).
    then : callable or tuple of callables, optional
        ``then(k, outcome)``, a module-level function, run on the workers as one more stage
        of test ``k`` (1-based) as soon as its outcome is complete, while the other tests
        are still computed (the documents' figures of a test, say); its values, in test
        order, are the result's ``then``. A tuple: each function its own stage (so that a
        test's parts are drawn on several workers), the values a tuple per test.
    """
    from mtplan._parallel import effective_jobs
    from mtplan.plans import decisions

    procs = study.procedures
    # each sweep's grid here; each distinct set-up of a procedure's sweeps one stage, with
    # the estimators of every sweep that holds it (the base set-up is in most of them)
    grids = {(i, j): _sweep_grid(ps.procedure, ps, study, sw)
             for i, ps in enumerate(procs) for j, sw in enumerate(ps.sweeps)}
    points = _points(grids)
    bar = _bar(progress, _count_steps(study, len(points)))
    partial = {}  # procedure index -> (results, key, recommended, its later stages)
    outcomes, payloads = {}, {}
    thens = tuple(then) if isinstance(then, (tuple, list)) else () if then is None else (then,)

    def unlocked(i, done):
        """The budget and readings stages of procedure ``i`` once its Monte Carlo is done;
        its ``then`` stage once all of its stages are."""
        ps = procs[i]
        if i not in partial:
            if any(("mc", i, est) not in done for est in ps.estimators):
                return []
            results = {est: done[("mc", i, est)] for est in ps.estimators}
            targeted = list((ps.plan or {}).get("targets", {}))
            key = decisions.key_measurands(results[ps.estimators[0]].measurands,
                                           [a["measurand"] for a in ps.acceptance], targeted)
            best = decisions.recommend_estimator(results, key)
            later = [(kind, i, best) for kind in ("readings", "as_left", "budget")
                     if kind == "budget" or (readings and ps.readings is not None
                                             and (kind == "readings" or ps.as_left is not None))]
            partial[i] = (results, key, best, later)
            return later
        if not thens or i in outcomes:
            return []
        mine = [t for (j, _), t in points.items() if j == i] + partial[i][3] + [("misc", i, None)]
        if any(t not in done for t in mine):
            return []
        outcomes[i] = _outcome(i, ps, partial[i], grids, points, done)
        for j, function in enumerate(thens):
            payloads[("then", i, j)] = (function, i + 1, outcomes[i])
        return [("then", i, j) for j in range(len(thens))]

    first = [("mc", i, est) for i, ps in enumerate(procs) for est in ps.estimators]
    first += list(points.values())
    first += [("misc", i, None) for i in range(len(procs))]
    done = _run_stages(first, unlocked, study, effective_jobs(n_jobs), bar, payloads)
    for i, ps in enumerate(procs):
        if i not in outcomes:
            outcomes[i] = _outcome(i, ps, partial[i], grids, points, done)
    if bar is not None:
        bar.close()
    return StudyResult(study=study, outcomes=[outcomes[i] for i in range(len(procs))],
                       provenance=provenance(study, command),
                       then=None if not thens else [
                           tuple(done[("then", i, j)] for j in range(len(thens)))
                           if isinstance(then, (tuple, list)) else done[("then", i, 0)]
                           for i in range(len(procs))])


def _outcome(i, ps, partial, grids, points, done) -> ProcedureOutcome:
    """Test ``i``'s outcome from its stages' results: verdicts, advice and summary."""
    from mtplan.plans import decisions

    results, key, recommended, _ = partial
    budget, gum, budget_estimator, reliability = done[("budget", i, recommended)]
    plan, identifiability, extras = done[("misc", i, None)]
    outcome = ProcedureOutcome(
        spec=ps, title=ps.procedure.title, results=results, gum=gum, budget=budget,
        sweeps=[_sweep_result(ps.sweeps[j], grids[(i, j)], i, points, done)
                for j in range(len(ps.sweeps))], plan=plan,
        measured=done.get(("readings", i, recommended)), identifiability=identifiability,
        extras=extras, recommended=recommended, key=key, budget_estimator=budget_estimator,
        reliability=None if reliability is None else reliability.with_u(
            {m.name: float(u) for m, u in zip(results[recommended].measurands,
                                               results[recommended].mc.std, strict=True)}))
    decider = results.get(getattr(outcome.measured, "estimator", None), results[recommended])
    outcome.verdicts = decisions.conformity(ps.name, ps.label, ps.acceptance, decider,
                                            outcome.measured)
    outcome.as_left = done.get(("as_left", i, recommended))  # after an adjustment
    if outcome.measured is not None:
        from mtplan.compensation.predicted import predicted

        outcome.compensation = predicted(ps.procedure, outcome.measured.to_dict(),
                                         coverage=outcome.measured.coverage)
    if outcome.as_left is not None:
        outcome.as_left_verdicts = decisions.conformity(ps.name, ps.label, ps.acceptance,
                                                        decider, outcome.as_left)
    _advise(outcome, ps.procedure, i + 1)
    return outcome


#: which ready stage a free worker takes first: the long ones a procedure waits on, then
#: what completes a procedure soonest (a procedure's ``then`` waits for its last sweep)
_PRIORITY = {"as_left": 0, "readings": 0, "budget": 1, "then": 1, "mc": 2, "misc": 2,
             "point": 3}


def _order(ready, cost) -> None:
    """Sort the ready stages in place: by :data:`_PRIORITY`, and the sweeps' set-ups of the
    procedures whose Monte Carlo took least time (``cost``: seconds per procedure index,
    those not yet timed last) first, so that those procedures complete, and their ``then``
    runs, while the costly ones' set-ups are still computed; otherwise in study order."""
    ready.sort(key=lambda t: (_PRIORITY[t[0]],
                              cost.get(t[1], math.inf) if t[0] == "point" else 0.0))


def _run_stages(tasks, unlocked, study, jobs, bar, payloads) -> dict:
    """Every stage's result, {(kind, procedure index, arg): result}: ``tasks`` and those
    ``unlocked(i, done)`` adds as they become ready, on ``jobs`` processes (one stage, on
    one core, per worker at a time) or, for one job, here. A stage in ``payloads`` is
    given its payload as its argument instead of its key's."""
    ready, cost, started = list(tasks), {}, {}
    _order(ready, cost)
    done = {}

    def finish(task, value):
        done[task] = value
        kind, i, arg = task
        if kind == "mc" and task in started:
            cost[i] = cost.get(i, 0.0) + time.perf_counter() - started.pop(task)
        name = study.procedures[i].name
        if kind in ("mc", "point", "budget", "readings", "as_left"):
            _tick(bar, f"{name} {arg if kind == 'mc' else 'sweep' if kind == 'point' else kind}")
        elif kind == "misc" and study.procedures[i].plan is not None:
            _tick(bar, f"{name} plan")
        ready.extend(unlocked(i, done))
        _order(ready, cost)  # stable: study order within a kind

    if jobs == 1:
        while ready:
            task = ready.pop(0)
            finish(task, _stage_work(task[0], study.procedures[task[1]], study,
                                     payloads.pop(task, task[2])))
        return done
    from concurrent.futures import FIRST_COMPLETED, wait

    from mtplan._parallel import stage_executor

    executor = stage_executor(jobs)  # forked: with the modules imported here (the models)
    running = {}
    while ready or running:
        while ready and len(running) < jobs:
            task = ready.pop(0)
            started[task] = time.perf_counter()
            running[executor.submit(_stage, task[0], study.procedures[task[1]], study,
                                    payloads.pop(task, task[2]))] = task
        finished, _ = wait(running, return_when=FIRST_COMPLETED)
        for future in finished:
            finish(running.pop(future), future.result())
    return done


def _stage(kind, ps, study, arg):
    """One stage of a procedure (see :func:`run_study`) in a worker: with one BLAS thread,
    as the workers share the cores."""
    from mtplan._parallel import one_blas_thread

    with one_blas_thread():  # scipy's own OpenBLAS too
        return _stage_work(kind, ps, study, arg)


def _stage_work(kind, ps, study, arg):
    """One stage of a procedure, in this process."""
    from mtplan.evaluation.simulation import simulate_uncertainty

    if kind == "then":
        function, k, outcome = arg
        return function(k, outcome)
    proc = ps.procedure
    if kind == "mc":
        # the procedure's own choice wins over the study's: trials (fixed) or digits
        if ps.trials is not None or ps.digits is not None:
            digits, trials = ps.digits, ps.trials
        else:
            digits, trials = study.digits, study.trials
        if digits is None and trials is None:
            trials = 10_000
        result = simulate_uncertainty(
            proc, ps.setup, ps.truth, estimator=arg, trials=None if digits else trials,
            digits=digits, coverage=study.coverage, rng=study.seed, n_jobs=1,
            progress=False, max_trials=ps.max_trials or study.max_trials)
        result.coverage_of_U()  # counted here, on the stage's core, not later in the main one
        return result
    if kind == "point":
        from mtplan.plans.sweep import point_rows

        return {est: point_rows(proc, arg.setup, ps.truth, est, None, dict(arg.options),
                                study.seed) for est in arg.estimators}
    if kind == "misc":
        plan = _run_plan(proc, ps, study) if ps.plan is not None else None
        return plan, _identifiability(proc, ps), _extras(proc, ps)
    if kind == "budget":  # with what one bad reading can do unseen, before the test
        return (*_run_budget(proc, ps, study, arg),
                reliability(proc, ps.setup, ps.truth, estimator=arg))
    if kind == "as_left":
        return _run_measured(proc, ps, study, arg, ps.as_left["file"])
    return _run_measured(proc, ps, study, arg)


def _run_budget(proc, ps, study, recommended):
    """(budget, GUM result or None, the estimator the budget is of)."""
    from mtplan.evaluation.simulation import linearize_procedure
    from mtplan.uncertainty.montecarlo import ModelError

    if ps.budget == "gum":
        gum = linearize_procedure(proc, ps.setup, ps.truth, estimator=recommended,
                                  coverage=study.coverage)
        return gum.budget(), gum, recommended
    try:
        return _mc_budget(proc, ps, study, 1, recommended), None, recommended
    except ModelError:  # one source alone can leave an estimator without a solution
        return _mc_budget(proc, ps, study, 1, ps.estimators[0]), None, ps.estimators[0]


@dataclass(frozen=True)
class _Point:
    """One set-up of a procedure's sweeps, with the Monte Carlo options of its sweep: a
    stage that evaluates every estimator any of those sweeps asks of it, one after the
    other in one process (they share the procedure's caches of the set-up), once for all
    the sweeps that hold it. ``fields``: its field values as text (the same text, the same
    seed and rows, :func:`~mtplan.plans.sweep.setup_seed`)."""

    fields: str
    options: tuple
    estimators: tuple
    setup: object = field(compare=False)


class _Grid:
    """A sweep's set-ups (grid order), estimators and options, and each set-up's key
    (field values as text, options) to its :class:`_Point`."""

    def __init__(self, setups, estimators, options):
        from mtplan.plans.sweep import canonical  # the text the set-up's seed is made of

        self.setups, self.estimators = setups, list(estimators)
        opts = tuple(sorted(options.items()))
        self.keys = [(canonical(s), opts) for s in setups]


def _points(grids) -> dict:
    """{(procedure index, set-up key): the point stage} over the study's sweeps
    ({(i, j): _Grid or the reason it cannot run}): one stage per distinct set-up and
    options of a procedure, with the estimators of every sweep that holds it."""
    wanted = {}
    for (i, _), g in grids.items():
        if isinstance(g, str):
            continue
        for setup, key in zip(g.setups, g.keys, strict=True):
            ests = wanted.setdefault((i, key), (setup, []))[1]
            ests += [e for e in g.estimators if e not in ests]
    return {(i, key): ("point", i, _Point(key[0], key[1], tuple(ests), setup))
            for (i, key), (setup, ests) in wanted.items()}


def _sweep_grid(proc, ps, study, sw):
    """The grid of a sweep of the study (:class:`_Grid`), or why it cannot run (a set-up
    the procedure refuses is a finding, shown in the report)."""
    from mtplan.plans.sweep import sweep_grid

    try:
        g = sweep_grid(proc, ps.setup, sw["vary"], truth=ps.truth,
                       estimators=sw.get("estimators", ps.estimators),
                       trials=sw.get("trials", 2000), rng=study.seed)
    except InvalidInput as exc:
        return " ".join(exc.problems)
    return _Grid(g.setups, g.estimators, g.options)


def _sweep_result(sw, grid, i, points, done):
    """(spec, table) of a sweep from its point stages: the table :func:`~mtplan.plans.sweep.
    sweep` gives for it (each set-up's rows are a function of the set-up alone)."""
    import pandas as pd

    from mtplan.plans.sweep import sweep_table

    if isinstance(grid, str):
        return sw, grid
    frames = []
    for p, key in enumerate(grid.keys):
        rows = done[points[(i, key)]]
        frames.append(pd.DataFrame([dict(row, point=p) for est in grid.estimators
                                    for row in rows[est]]))
    table = sweep_table(frames)
    table.attrs["notes"] = []
    return sw, table


def _advise(outcome, proc, k) -> None:
    """The summary rows, the levers ranked, the dominant sources and the targets."""
    from mtplan.plans import decisions

    ps = outcome.spec
    result = outcome.results[outcome.recommended]
    varied = {f for sw in ps.sweeps for f in sw["vary"]} | set((ps.plan or {}).get("vary", {}))
    outcome.setup_shown = decisions.shown_setup(ps.setup, proc.Setup(), proc.levers, varied)
    outcome.duration_s = float(proc.duration(ps.setup))
    outcome.summary = decisions.summary_rows(k, ps.name, ps.label, result, outcome.key,
                                             outcome.verdicts, outcome.measured,
                                             outcome.setup_shown, outcome.duration_s)
    outcome.levers = decisions.lever_effects(proc.levers, ps.setup, outcome.sweeps, outcome.key,
                                             outcome.recommended)
    outcome.dominant = decisions.dominant_sources(
        outcome.budget, proc.levers,
        {name: src.field for name, src in proc.sources(ps.setup).items()})
    outcome.comparison = decisions.estimator_comparison(outcome.results)
    outcome.targets = decisions.u_targets(ps.plan, outcome.verdicts)


def _mc_budget(proc, ps, study, n_jobs, estimator):
    """Budget by Monte Carlo: each active error source alone, ``budget_trials`` trials.

    For estimators that are not smooth in the readings (integer shifts, thresholds) the
    law of propagation's finite differences mean nothing; switching sources on one at a
    time shows each one's own effect. ``share`` is its variance over the sum of the
    single-source variances (interactions, if any, are left out).
    """
    from mtplan.evaluation.simulation import source_budget

    return source_budget(proc, ps.setup, ps.truth, estimator=estimator,
                         trials=ps.budget_trials, rng=study.seed, n_jobs=n_jobs)


def _count_steps(study, points):
    n = points
    for ps in study.procedures:
        n += len(ps.estimators) + 1
        n += sum(x is not None for x in (ps.plan, ps.readings, ps.as_left))
    return n


class _Lines:
    """The progress where stderr is no terminal (a CI log, a pipe): one short line per
    finished stage, instead of a bar redrawn with carriage returns."""

    def __init__(self, total: int, file):
        self.total, self.n, self.file = total, 0, file
        self.text = ""

    def set_postfix_str(self, text: str) -> None:
        self.text = text

    def update(self, n: int = 1) -> None:
        self.n += n
        print(f"study {self.n}/{self.total}: {self.text}", file=self.file, flush=True)

    def close(self) -> None:
        pass


def _bar(progress, total):
    """A progress bar on a terminal; with ``progress`` True and stderr no terminal, a line
    per stage; None where there is nothing to show."""
    import sys

    if progress is False or (progress is None and not sys.stderr.isatty()):
        return None
    if not sys.stderr.isatty():
        return _Lines(total, sys.stderr)
    from tqdm.auto import tqdm

    tqdm.monitor_interval = 0  # no monitor thread: the stage workers are forked after it
    return tqdm(total=total, desc="study", unit="step", file=sys.stderr, leave=False)


def _tick(bar, text):
    if bar is not None:
        bar.set_postfix_str(text)
        bar.update(1)


def _run_plan(proc, ps, study):
    from mtplan.plans.planner import plan

    spec = ps.plan
    try:
        return plan(proc, ps.setup, spec.get("vary", {}), spec["targets"], k=spec.get("k", 1.0),
                    truth=ps.truth, estimator=spec.get("estimator", ps.estimators[0]),
                    trials=spec.get("trials", 4000), seed=study.seed)
    except InvalidInput as exc:  # an impossible target is a finding, not a crash
        return " ".join(exc.problems)


def _run_measured(proc, ps, study, recommended, file=None):
    """The readings (or those of ``file``, taken after an adjustment) evaluated, by default
    with the estimator the study recommends."""
    from mtplan.evaluation import measured
    from mtplan.evaluation.posterior import PosteriorOptions

    spec = ps.readings
    setup = with_conditions(_along_setup(proc, ps.setup, spec), study.conditions)
    readings = measured.read_readings(proc, setup, file or spec["file"])
    sampling = PosteriorOptions.of(None, **(spec.get("options") or {})).replace(
        allow_unconverged=bool(spec.get("allow_unconverged", False)))
    options = measured.MeasuredOptions(trials=spec.get("trials", 10_000),
                                       coverage=study.coverage, rng=study.seed,
                                       posterior=sampling)
    result = measured.estimate_measured(proc, setup, readings,
                                        estimator=spec.get("estimator") or recommended,
                                        uncertainty=spec.get("uncertainty", "mc"),
                                        options=options)
    # what one bad reading could have done unseen, at these readings, after the test
    result.sections["reliability"] = reliability(
        proc, setup, readings=readings, estimator=result.estimator, check=result.fit,
        u={m.name: float(u) for m, u in zip(result.measurands, result.std, strict=True)})
    return result


def _along_setup(proc, setup, spec):
    """`setup` with the positions at which the readings' evaluation states the errors
    along the travel: ``[procedure.readings] along``, else the procedure's default
    (the correction model's ``grid``: none where the set-up states its own)."""
    import dataclasses

    grid = spec.get("along")
    grid = proc.correction.grid(setup) if grid is None else grid
    return dataclasses.replace(setup, **grid) if grid else setup


def _identifiability(proc, ps):
    """Rank, conditioning, O1-O5 and the inseparable combinations of the set-up's parameters.

    A procedure with its own ``identifiability_report`` (geometry21: the joint model of every
    error coefficient) is asked for it; otherwise the readings' sensitivities to the
    measurands (or truth fields) are analysed.
    """
    from types import SimpleNamespace

    from mtplan.plans.identifiability import identifiability, observability_indices
    from mtplan.plans.planner import readings_jacobian

    rep = proc.capabilities.identifiability_report(ps.setup)
    if rep:
        sv = np.asarray(rep["singular_values"], dtype=float)
        nulls = [" ".join(f"{w:+.2f} {k}" for k, w in list(d.items())[:6])
                 + (" ..." if len(d) > 6 else "") for d in rep["null_space"]]
        return SimpleNamespace(
            names=[f"{rep['parameters']} coefficients and mounting parameters"],
            n_params=int(rep["parameters"]), rank=int(rep["rank"]),
            condition_number=float(rep["condition_number"]),
            observability=observability_indices(sv, int(rep["readings"])),
            null_combinations=nulls)
    J, names = readings_jacobian(proc, ps.setup, ps.truth)
    return identifiability(J, names=names)


def _extras(proc, ps):
    """Procedure-specific material for the report: the procedure's ``report_extras(setup,
    truth) -> dict`` (data only; the reports draw it), with its per-estimator
    ``identifiability`` and its ``observability`` where they say anything (the generic
    defaults are empty)."""
    caps = proc.capabilities
    extras = dict(caps.report_extras(ps.setup, ps.truth))
    # what the patent's method cannot see: per-estimator identifiability or observability
    if "identifiability" not in extras:
        tables = {est: caps.identifiability(ps.setup, est) for est in ps.estimators}
        if any(len(table) for table in tables.values()):
            extras["identifiability"] = tables
    if "observability" not in extras:
        observability = caps.observability(ps.setup)
        if observability:
            extras["observability"] = observability
    return extras
