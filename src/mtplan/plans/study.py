"""Studies: what a report covers, read from a TOML file and computed in one go.

A study names procedures, their base set-ups, sweeps, planning targets,
acceptance plans and optionally measured readings. :func:`load_study` validates
the whole file and lists every problem at once; :func:`run_study` computes every
result (Monte Carlo, GUM budget, sweeps, plan, acceptance, posterior) into a
:class:`StudyResult` that the reports render without computing anything.

Example::

    title = "Acceptance of machine 42"
    seed = 1
    digits = 2                      # adaptive Monte Carlo of each base set-up
    [[procedure]]
    name = "rotary_axis"
    label = "C axis"
    setup = { axis = "C", incline_deg = 20 }
    estimators = ["patent", "joint"]
      [[procedure.sweep]]
      vary = { incline_deg = [10, 20, 30] }
      trials = 2000
      [procedure.plan]
      targets = { EX0C = 1.0 }
      vary = { positions = [3, 6, 12] }
      [procedure.acceptance]
      measurand = "EX0C"
      lower = -10.0
      upper = 10.0
      prior = "normal:0,4"
      rule = "guard:0.5"
      [procedure.readings]
      file = "rotary_axis_readings.csv"   # relative to the study file
      uncertainty = "mc"                   # or "posterior"
"""

from __future__ import annotations

import hashlib
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mtplan._validate import InvalidInput

__all__ = ["Study", "ProcedureStudy", "StudyResult", "load_study", "run_study"]

_TOP_KEYS = {"title", "subtitle", "customer", "machine", "author", "seed", "digits", "trials",
             "max_trials", "coverage", "procedure"}
_PROC_KEYS = {"name", "label", "setup", "truth", "estimators", "sweep", "plan", "acceptance",
              "readings", "trials", "digits", "max_trials", "budget", "budget_trials", "notes"}
_SWEEP_KEYS = {"vary", "trials", "estimators"}
_PLAN_KEYS = {"targets", "vary", "k", "estimator", "trials"}
_ACCEPT_KEYS = {"measurand", "lower", "upper", "prior", "rule", "measured"}
_READ_KEYS = {"file", "uncertainty", "estimator", "trials", "options", "allow_unconverged"}


def _unknown(problems, where, table, allowed):
    if isinstance(table, dict):
        for key in sorted(set(table) - allowed):
            problems.append(f"{where} has an unknown key {key!r}; allowed: "
                            f"{', '.join(sorted(allowed))}.")


def _count(problems, where, value, low):
    if value is not None and not (isinstance(value, int) and not isinstance(value, bool)
                                  and value >= low):
        problems.append(f"{where} must be an int >= {low}. Got {value!r} instead.")


@dataclass
class ProcedureStudy:
    name: str
    label: str
    setup: object
    truth: object
    estimators: list
    sweeps: list = field(default_factory=list)        # dicts: vary, trials, estimators
    plan: dict | None = None
    acceptance: dict | None = None
    readings: dict | None = None
    trials: int | None = None
    digits: int | None = None
    max_trials: int | None = None
    budget: str = "gum"                # "gum" (law of propagation) or "mc" (one source at a time)
    budget_trials: int = 2000
    notes: str = ""


@dataclass
class Study:
    title: str
    path: Path | None
    digest: str
    seed: int
    digits: int | None
    trials: int | None
    coverage: float
    meta: dict
    procedures: list
    max_trials: int = 200_000


def load_study(source) -> Study:
    """Read and validate a study (a TOML path, or an already parsed dict)."""
    from mtplan.models import registry
    from mtplan.models._protocol import fields_info, make

    problems: list[str] = []
    path = None
    if isinstance(source, dict):
        data = source
        raw = repr(sorted(source.items())).encode()
    else:
        path = Path(source)
        try:
            raw = path.read_bytes()
        except FileNotFoundError:
            raise InvalidInput([f"No such study file {str(path)!r}."]) from None
        except OSError as exc:
            raise InvalidInput([f"Cannot read the study file {str(path)!r}: {exc.strerror}."]) from None
        try:
            data = tomllib.loads(raw.decode("utf-8"))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise InvalidInput([f"The study file {str(path)!r} is not valid TOML: {exc}."]) from None
    for key in sorted(set(data) - _TOP_KEYS):
        problems.append(f"The study has an unknown key {key!r}; allowed: {', '.join(sorted(_TOP_KEYS))}.")
    seed = data.get("seed", 0)
    if not (isinstance(seed, int) and seed >= 0):
        problems.append(f"The study's 'seed' must be an int >= 0. Got {seed!r} instead.")
    digits = data.get("digits")
    trials = data.get("trials")
    if digits is not None and not (isinstance(digits, int) and 1 <= digits <= 4):
        problems.append(f"The study's 'digits' must be an int from 1 to 4. Got {digits!r} instead.")
    if trials is not None and not (isinstance(trials, int) and trials >= 100):
        problems.append(f"The study's 'trials' must be an int >= 100. Got {trials!r} instead.")
    max_trials = data.get("max_trials", 200_000)
    _count(problems, "The study's 'max_trials'", max_trials, 1000)
    coverage = data.get("coverage", 0.95)
    if not (isinstance(coverage, float) and 0 < coverage < 1):
        problems.append(f"The study's 'coverage' must be a number in (0, 1). Got {coverage!r} instead.")
    entries = data.get("procedure", [])
    if not isinstance(entries, list) or not entries:
        problems.append("The study needs at least one [[procedure]] table.")
        entries = []
    procs = registry()
    out = []
    for i, entry in enumerate(entries):
        where = f"procedure #{i + 1}"
        if not isinstance(entry, dict):
            problems.append(f"{where} must be a table.")
            continue
        name = entry.get("name")
        where = f"procedure #{i + 1} ({name})"
        for key in sorted(set(entry) - _PROC_KEYS):
            problems.append(f"{where} has an unknown key {key!r}; allowed: {', '.join(sorted(_PROC_KEYS))}.")
        if name not in procs:
            problems.append(f"{where}: unknown procedure; the procedures are: {', '.join(procs)}.")
            continue
        proc = procs[name]
        _count(problems, f"{where} 'trials'", entry.get("trials"), 100)
        _count(problems, f"{where} 'max_trials'", entry.get("max_trials"), 1000)
        _count(problems, f"{where} 'budget_trials'", entry.get("budget_trials"), 100)
        pd_ = entry.get("digits")
        if pd_ is not None and not (isinstance(pd_, int) and 1 <= pd_ <= 4):
            problems.append(f"{where} 'digits' must be an int from 1 to 4. Got {pd_!r} instead.")
        if entry.get("budget", "gum") not in ("gum", "mc"):
            problems.append(f"{where} 'budget' must be 'gum' or 'mc'. Got {entry.get('budget')!r} "
                            "instead.")
        setup = truth = None
        try:
            setup = make(proc.Setup, entry.get("setup", {}), owner=f"{where} setup")
        except InvalidInput as exc:
            problems += exc.problems
        try:
            truth = make(proc.Truth, entry.get("truth", {}), owner=f"{where} truth")
        except InvalidInput as exc:
            problems += exc.problems
        estimators = entry.get("estimators", [proc.default_estimator])
        if estimators == "all":
            estimators = list(proc.estimators)
        if isinstance(estimators, str):
            estimators = [estimators]
        if not isinstance(estimators, list) or not estimators:
            problems.append(f"{where}: 'estimators' must be 'all', a name or a non-empty list.")
            estimators = [proc.default_estimator]
        for e in estimators:
            if e not in proc.estimators:
                problems.append(f"{where}: unknown estimator {e!r}; allowed: {', '.join(proc.estimators)}.")
        fields = {f["name"] for f in fields_info(proc.Setup)}
        sweeps = entry.get("sweep", [])
        sweeps = [sweeps] if isinstance(sweeps, dict) else sweeps
        for j, sw in enumerate(sweeps):
            _unknown(problems, f"{where} sweep #{j + 1}", sw, _SWEEP_KEYS)
            if isinstance(sw, dict):
                _count(problems, f"{where} sweep #{j + 1} 'trials'", sw.get("trials"), 2)
                for e in ([sw["estimators"]] if isinstance(sw.get("estimators"), str)
                          else sw.get("estimators", [])):
                    if e not in proc.estimators:
                        problems.append(f"{where} sweep #{j + 1}: unknown estimator {e!r}; "
                                        f"allowed: {', '.join(proc.estimators)}.")
            vary = sw.get("vary", {}) if isinstance(sw, dict) else None
            if not vary or not isinstance(vary, dict):
                problems.append(f"{where} sweep #{j + 1} needs a non-empty 'vary' table.")
                continue
            for f, values in vary.items():
                if f not in fields:
                    problems.append(f"{where} sweep #{j + 1} varies {f!r}, which is no set-up "
                                    f"field ({', '.join(sorted(fields))}).")
                elif not isinstance(values, list) or not values:
                    problems.append(f"{where} sweep #{j + 1}: the values of {f!r} must be a "
                                    "non-empty list.")
        if setup is not None:  # every set-up of every grid must be valid, said before computing
            grids = [(f"sweep #{j + 1}", sw.get("vary")) for j, sw in enumerate(sweeps)
                     if isinstance(sw, dict)]
            if isinstance(entry.get("plan"), dict):
                grids.append(("plan", entry["plan"].get("vary")))
            for what, vary in grids:
                problems += _grid_problems(proc, entry.get("setup", {}), vary, fields,
                                           f"{where} {what}")
        measurands = set()
        if setup is not None:
            measurands = {m.name for m in proc.measurands(setup)}
        plan = entry.get("plan")
        if plan is not None and not isinstance(plan, dict):
            problems.append(f"{where} 'plan' must be a table.")
            plan = None
        if plan is not None:
            _unknown(problems, f"{where} plan", plan, _PLAN_KEYS)
            for f in plan.get("vary", {}):
                if f not in fields:
                    problems.append(f"{where} plan varies {f!r}, which is no set-up field.")
            for m in plan.get("targets", {}):
                if m not in measurands:
                    problems.append(f"{where} plan targets {m!r}, which is no measurand "
                                    f"({', '.join(sorted(measurands))}).")
            if not plan.get("targets"):
                problems.append(f"{where} plan needs a 'targets' table.")
        acc = entry.get("acceptance")
        if acc is not None and not isinstance(acc, dict):
            problems.append(f"{where} 'acceptance' must be a table.")
            acc = None
        if acc is not None:
            _unknown(problems, f"{where} acceptance", acc, _ACCEPT_KEYS)
            from mtplan.plans import acceptance as _acc

            for key, parse in (("prior", _acc.parse_prior), ("rule", _acc.parse_rule)):
                if acc.get(key) is not None:
                    text = acc[key]
                    if key == "prior" and isinstance(text, str) and path is not None \
                            and not text.lower().startswith(("normal:", "gamma:")) \
                            and not Path(text).is_absolute():
                        text = str(path.parent / text)
                        acc = {**acc, "prior": text}
                    try:
                        parse(text)
                    except InvalidInput as exc:
                        problems += [f"{where} acceptance: {p}" for p in exc.problems]
            if acc.get("measurand") not in measurands:
                problems.append(f"{where} acceptance names measurand {acc.get('measurand')!r}, "
                                f"which is no measurand ({', '.join(sorted(measurands))}).")
            if acc.get("lower") is None and acc.get("upper") is None:
                problems.append(f"{where} acceptance needs 'lower' and/or 'upper' limits.")
        readings = entry.get("readings")
        if readings is not None and not isinstance(readings, dict):
            problems.append(f"{where} 'readings' must be a table.")
            readings = None
        if readings is not None:
            _unknown(problems, f"{where} readings", readings, _READ_KEYS)
            if readings.get("estimator", proc.default_estimator) not in proc.estimators:
                problems.append(f"{where} readings: unknown estimator "
                                f"{readings.get('estimator')!r}; allowed: {', '.join(proc.estimators)}.")
            f = readings.get("file")
            rp = Path(f) if f else None
            if rp is not None and not rp.is_absolute() and path is not None:
                rp = path.parent / rp
            if rp is None or not rp.exists():
                problems.append(f"{where} readings file {f!r} does not exist.")
            else:
                readings = {**readings, "file": rp}
            if readings.get("uncertainty", "mc") not in ("mc", "posterior"):
                problems.append(f"{where} readings 'uncertainty' must be 'mc' or 'posterior'.")
        label = str(entry.get("label", proc.title))
        out.append(ProcedureStudy(name=name, label=label, setup=setup, truth=truth,
                                  estimators=list(estimators), sweeps=list(sweeps), plan=plan,
                                  acceptance=acc, readings=readings, trials=entry.get("trials"),
                                  digits=entry.get("digits"), max_trials=entry.get("max_trials"),
                                  budget=entry.get("budget", "gum"),
                                  budget_trials=entry.get("budget_trials", 2000),
                                  notes=str(entry.get("notes", ""))))
    if problems:
        raise InvalidInput(problems)
    meta = {k: str(data[k]) for k in ("subtitle", "customer", "machine", "author") if k in data}
    return Study(title=str(data.get("title", "mtplan study")), path=path,
                 digest=hashlib.sha256(raw).hexdigest()[:16], seed=seed, digits=digits,
                 trials=trials, coverage=coverage, meta=meta, procedures=out,
                 max_trials=max_trials)


def _grid_problems(proc, base, vary, fields, where) -> list[str]:
    import itertools

    from mtplan.models._protocol import make

    if not isinstance(vary, dict) or not vary:
        return []
    vary = {f: v for f, v in vary.items() if f in fields and isinstance(v, list) and v}
    found = []
    for combo in itertools.product(*vary.values()):
        at = dict(zip(vary, combo, strict=True))
        try:
            make(proc.Setup, {**base, **at}, owner="")
        except InvalidInput as exc:
            shown = ", ".join(f"{k}={v}" for k, v in at.items())
            found += [f"{where} at {shown}: {p.lstrip(': ')}" for p in exc.problems]
        if len(found) >= 5:
            found.append(f"{where}: (further problems in this grid left out)")
            break
    return found


@dataclass
class ProcedureOutcome:
    """Everything computed for one procedure of a study (display units)."""

    spec: ProcedureStudy
    title: str
    results: dict                      # estimator -> ProcedureResult
    gum: object                        # GUMResult of the default estimator
    budget: object                     # DataFrame: measurand, source, contribution, share
    sweeps: list                       # (spec dict, DataFrame)
    plan: object | None = None         # PlanResult or an error message
    acceptance: object | None = None   # dict with the acceptance result
    measured: object | None = None     # result of the readings evaluation
    identifiability: object | None = None
    extras: dict = field(default_factory=dict)


@dataclass
class StudyResult:
    study: Study
    outcomes: list
    provenance: dict


def _provenance(study: Study) -> dict:
    import datetime
    import importlib.metadata as md
    import platform

    versions = {}
    for pkg in ("mtplan", "numpy", "scipy", "pandas", "matplotlib", "joblib", "emcee", "jinja2",
                "reportlab"):
        try:
            versions[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            versions[pkg] = "not installed"
    return {
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
        "study_file": str(study.path) if study.path else "(in memory)",
        "study_sha256": study.digest,
        "seed": study.seed,
        "python": platform.python_version(),
        "versions": versions,
    }


def run_study(study: Study, *, progress=None, n_jobs: int = 1) -> StudyResult:
    """Compute every result a study asks for (the reports only render them)."""
    from mtplan.models import get
    from mtplan.plans.sweep import sweep
    from mtplan.evaluation.simulation import linearize_procedure, simulate_uncertainty

    outcomes = []
    steps = _count_steps(study)
    bar = _bar(progress, steps)
    for ps in study.procedures:
        proc = get(ps.name)
        # the procedure's own choice wins over the study's: trials (fixed) or digits (adaptive)
        if ps.trials is not None or ps.digits is not None:
            digits, trials = ps.digits, ps.trials
        else:
            digits, trials = study.digits, study.trials
        if digits is None and trials is None:
            trials = 10_000
        max_trials = ps.max_trials or study.max_trials
        results = {}
        for est in ps.estimators:
            results[est] = simulate_uncertainty(
                proc, ps.setup, ps.truth, estimator=est, trials=None if digits else trials,
                digits=digits, coverage=study.coverage, rng=study.seed, n_jobs=n_jobs,
                progress=False, max_trials=max_trials)
            _tick(bar, f"{ps.name} {est}")
        gum = None
        if ps.budget == "gum":
            gum = linearize_procedure(proc, ps.setup, ps.truth, estimator=ps.estimators[0],
                                      coverage=study.coverage)
            budget = gum.budget()
        else:
            budget = _mc_budget(proc, ps, study, n_jobs)
        _tick(bar, f"{ps.name} budget")
        sweeps = []
        for sw in ps.sweeps:
            try:
                table = sweep(proc, ps.setup, sw["vary"], truth=ps.truth,
                              estimators=sw.get("estimators", ps.estimators),
                              trials=sw.get("trials", 2000), seed=study.seed, n_jobs=n_jobs,
                              progress=False)
            except InvalidInput as exc:  # a set-up the estimators refuse is a finding
                table = " ".join(exc.problems)
            sweeps.append((sw, table))
            _tick(bar, f"{ps.name} sweep")
        outcome = ProcedureOutcome(spec=ps, title=proc.title, results=results, gum=gum,
                                   budget=budget, sweeps=sweeps)
        if ps.plan is not None:
            outcome.plan = _run_plan(proc, ps, study)
            _tick(bar, f"{ps.name} plan")
        if ps.acceptance is not None:
            outcome.acceptance = _run_acceptance(ps, results[ps.estimators[0]])
            _tick(bar, f"{ps.name} acceptance")
        if ps.readings is not None:
            outcome.measured = _run_measured(proc, ps, study)
            _tick(bar, f"{ps.name} readings")
        outcome.identifiability = _identifiability(proc, ps)
        outcome.extras = _extras(proc, ps)
        outcomes.append(outcome)
    if bar is not None:
        bar.close()
    return StudyResult(study=study, outcomes=outcomes, provenance=_provenance(study))


def _mc_budget(proc, ps, study, n_jobs):
    """Budget by Monte Carlo: each active error source alone, ``budget_trials`` trials.

    For estimators that are not smooth in the readings (integer shifts, thresholds) the
    law of propagation's finite differences mean nothing; switching sources on one at a
    time shows each one's own effect. ``share`` is its variance over the sum of the
    single-source variances (interactions, if any, are left out).
    """
    import pandas as pd

    from mtplan.evaluation.simulation import source_budget

    df = source_budget(proc, ps.setup, ps.truth, estimator=ps.estimators[0],
                       trials=ps.budget_trials, rng=study.seed, n_jobs=n_jobs)
    return pd.DataFrame({"output": df["measurand"], "input": df["source"], "u_input": math.nan,
                         "sensitivity": math.nan, "contribution": df["std"],
                         "share": df["share"]})


def _count_steps(study):
    n = 0
    for ps in study.procedures:
        n += len(ps.estimators) + 1 + len(ps.sweeps)
        n += sum(x is not None for x in (ps.plan, ps.acceptance, ps.readings))
    return n


def _bar(progress, total):
    import sys

    if progress is False:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, desc="study", unit="step", file=sys.stderr, leave=False,
                disable=progress is None and not sys.stderr.isatty())


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


def _run_acceptance(ps, result):
    try:
        from mtplan.plans import acceptance as acc
    except ImportError:  # pragma: no cover - until the acceptance module lands
        return None
    spec = ps.acceptance
    i = [m.name for m in result.measurands].index(spec["measurand"])
    u = float(result.mc.std[i])
    prior = acc.parse_prior(spec["prior"]) if spec.get("prior") else None
    rule = spec.get("rule", "simple")
    res = acc.plan_acceptance(spec.get("lower"), spec.get("upper"), u, prior=prior,
                              rule=acc.parse_rule(rule) if hasattr(acc, "parse_rule") else rule,
                              measured=spec.get("measured"))
    return {"measurand": spec["measurand"], "unit": result.measurands[i].unit, "u": u,
            "lower": spec.get("lower"), "upper": spec.get("upper"), "prior": spec.get("prior"),
            "rule": rule, **res.to_dict()}


def _run_measured(proc, ps, study):
    try:
        from mtplan.evaluation import measured
    except ImportError:  # pragma: no cover - until the measured-data module lands
        return None
    spec = ps.readings
    readings = measured.read_readings(proc, ps.setup, spec["file"])
    return measured.estimate_measured(proc, ps.setup, readings,
                                      estimator=spec.get("estimator"),
                                      uncertainty=spec.get("uncertainty", "mc"),
                                      trials=spec.get("trials", 10_000), coverage=study.coverage,
                                      rng=study.seed,
                                      allow_unconverged=bool(spec.get("allow_unconverged", False)),
                                      posterior_options=spec.get("options"))


def _identifiability(proc, ps):
    """Rank, conditioning, O1-O5 and the inseparable combinations of the set-up's parameters.

    A procedure module with its own ``identifiability_report(setup)`` (geometry21: the joint
    model of every error coefficient) is asked for it; otherwise the readings' sensitivities
    to the measurands (or truth fields) are analysed.
    """
    import importlib
    from types import SimpleNamespace

    from mtplan.plans.identifiability import identifiability, observability_indices
    from mtplan.plans.planner import readings_jacobian

    module = importlib.import_module(proc.forward.__module__)
    own = getattr(module, "identifiability_report", None)
    if callable(own):
        rep = own(ps.setup)
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
    """Procedure-specific material for the report: a module-level ``report_extras(setup,
    truth) -> dict`` in the procedure's module (data only; the reports draw it)."""
    import importlib

    module = importlib.import_module(proc.forward.__module__)
    hook = getattr(module, "report_extras", None)
    extras = dict(hook(ps.setup, ps.truth)) if callable(hook) else {}
    # what the seed's method cannot see: per-estimator identifiability or observability
    ident = getattr(module, "identifiability", None)
    if callable(ident) and "identifiability" not in extras:
        extras["identifiability"] = {est: ident(ps.setup, est) for est in ps.estimators}
    obs = getattr(module, "observability", None)
    if callable(obs) and "observability" not in extras:
        extras["observability"] = obs(ps.setup)
    return extras
