"""``mtplan plan``: the cheapest set-up meeting targets, its Pareto front, design search."""

from __future__ import annotations

import json

from mtplan.cli._common import (
    UsageError,
    add_common,
    capped_trials,
    check_outputs,
    count,
    parse_sources,
    parse_vary,
    procedure_and_setup,
    write_out,
)


def register(sub) -> None:
    p = sub.add_parser("plan", help="cheapest set-up meeting targets, Pareto front")
    add_common(p)
    p.add_argument("--target", action="append", metavar="NAME<=VALUE",
                   help="bound on a measurand's uncertainty in its unit (repeatable); "
                        "reliability:NAME<=VALUE bounds the largest shift of NAME one bad "
                        "reading the fit check misses can cause")
    p.add_argument("--determine", metavar="all|NAME,...",
                   help="measurands the set-up must determine at all (all: every one the "
                        "procedure can report, e.g. geometry21's 21 errors)")
    p.add_argument("--vary", action="append", metavar="FIELD=V1,V2,...",
                   help="candidate values of a set-up field (repeatable)")
    p.add_argument("--k", type=float, default=1.0,
                   help="coverage factor of the targets (default 1: standard uncertainty)")
    p.add_argument("--confirm", type=count, default=5,
                   help="most candidates checked by Monte Carlo (default 5)")
    p.add_argument("--tolerance", metavar="NAME=LO,HI",
                   help="tolerance of a measurand (empty LO or HI: one-sided), with --prior and "
                        "--max-pfa: cheapest set-up keeping the false-accept probability below it")
    p.add_argument("--prior", metavar="SPEC",
                   help="population of machines: normal:MEAN,SD, gamma:SHAPE,SCALE or FILE.csv")
    p.add_argument("--max-pfa", type=float, metavar="P", help="largest global false-accept probability")
    p.add_argument("--rule", default="simple", metavar="RULE",
                   help="decision rule for --tolerance (simple, guard:R, target-pfa:P, iso14253, dobbert)")
    p.add_argument("--optimize", action="append", metavar="FIELD=LO:HI",
                   help="search a continuous field (or every element of a list field such as "
                        "angles_deg) within [LO, HI] for the best --criterion (repeatable)")
    p.add_argument("--criterion", default="D", metavar="C",
                   help="design criterion of --optimize: u:MEASURAND, D, A or E (default D)")
    p.set_defaults(func=cmd_plan)


def cmd_plan(args):
    from mtplan.plans.planner import RELIABILITY, parse_target, plan

    check_outputs(out=args.out)
    proc, setup, truth, config = procedure_and_setup(args)
    targets = dict(parse_target(t) for t in (args.target or []))
    targets.update({k: float(v) for k, v in config.get("targets", {}).items()})
    criterion = None
    if args.tolerance or args.prior or args.max_pfa is not None:
        criterion = _pfa_criterion(args, [m.name for m in proc.measurands(setup)])
    if args.optimize and not targets and criterion is None:
        return _design_search(args, proc, setup, truth)
    determine = args.determine if args.determine is not None else config.get("determine")
    if isinstance(determine, str):
        determine = ("all" if determine.strip().lower() == "all"
                     else [d.strip() for d in determine.split(",") if d.strip()])
    if not targets and criterion is None and not determine:
        raise UsageError("plan needs at least one --target NAME<=VALUE, --determine, or "
                         "--tolerance with --prior and --max-pfa")
    vary = dict(config.get("vary", {}))
    vary.update(parse_vary(args.vary))
    seed = args.seed if args.seed is not None else config.get("seed", 0)
    result = plan(proc, setup, vary, targets, k=args.k, truth=truth,
                  estimator=args.estimator or config.get("estimator"),
                  sources=parse_sources(args, config), confirm=args.confirm,
                  trials=capped_trials(args.trials if args.trials is not None
                                       else config.get("trials"), 5000), seed=seed,
                  n_jobs=args.jobs, backend=args.backend, criterion=criterion,
                  determine=determine or None)
    if args.out:
        write_out(args.out, result.table.to_csv(index=False))
    if args.json:
        print(json.dumps(result.to_dict(), indent=1, default=float))
        return 0
    from mtplan.uncertainty.coverage import coverage_text

    best = result.best
    goals = [f"{n} <= {v:g}" for n, v in targets.items()]
    if criterion is not None:
        goals.append(f"false accept <= {args.max_pfa:g} for {args.tolerance}")
    if determine:
        goals.insert(0, "every measurand determined" if isinstance(determine, str)
                     else f"{', '.join(determine)} determined")
    print(f"{proc.name}: cheapest set-up meeting " + ", ".join(goals)
          + (f" (k = {args.k:g})" if args.k != 1 else ""))
    if result.search:
        print(f"  searched: {result.search}")
    for f, v in best["changes"].items():
        print(f"  {f} = {v}")
    if not vary and not best["changes"]:
        print("  the set-up as given")
    print(f"  duration {best['duration_s']:.0f} s" + (
        f", cost {best['cost_s']:.0f} s with the calibration" if best["calibration"] else ""))
    if determine:
        print(f"  determines {len(best['predicted'])} measurands: {', '.join(best['predicted'])}")
    if criterion is not None:
        print(f"  false accept at the confirmed uncertainty: {criterion.pfa(best['confirmed']):.4g}")
    for n in targets:
        c = result.confirmation[-1]
        if n.startswith(RELIABILITY):  # the design's own figure: no Monte Carlo of it
            print(f"  {n}: largest shift one undetected bad reading causes "
                  f"{best['predicted'][n]:.3g} (the fit check's MDB through the estimator)")
            continue
        covers = c.get("monte_carlo_coverage", {}).get(n)
        covers = (f", ±{args.k:g}u covers "
                  f"{coverage_text(covers, se=c['monte_carlo_coverage_se'].get(n))} of its values"
                  if covers is not None and args.k != 1 else "")
        print(f"  {n}: predicted {best['predicted'][n]:.3g}, Monte Carlo {best['confirmed'][n]:.3g} "
              f"(ratio {c['ratio'][n]:.3f}, {c['trials']} trials{covers})")
    print(f"Pareto front (cost against the worst target ratio): {len(result.pareto)} set-ups")
    for c in result.pareto:
        shown = ", ".join(f"{f}={v}" for f, v in c["changes"].items()) or "the set-up as given"
        print(f"  {c['cost_s']:8.0f} s  {c['worst']:.3f}  {shown}")
    return 0


def _tolerance(text):

    name, sep, rest = (text or "").partition("=")
    lo, comma, hi = rest.partition(",")
    try:
        lo = float(lo) if lo.strip() else None
        hi = float(hi) if hi.strip() else None
    except ValueError:
        lo = hi = None
        comma = ""
    if not sep or not comma or not name.strip() or (lo is None and hi is None):
        raise UsageError(f"--tolerance expects NAME=LO,HI (one of them may be empty), got {text!r}")
    return name.strip(), lo, hi


def _pfa_criterion(args, measurands):
    from mtplan.plans.acceptance import parse_prior, parse_rule
    from mtplan.plans.planner import PfaCriterion

    if not (args.tolerance and args.prior and args.max_pfa is not None):
        raise UsageError("--tolerance, --prior and --max-pfa go together")
    name, lo, hi = _tolerance(args.tolerance)
    if name not in measurands:
        raise UsageError(f"--tolerance names {name!r}, which is no measurand ({', '.join(measurands)})")
    if not 0 < args.max_pfa < 1:
        raise UsageError(f"--max-pfa must lie between 0 and 1, got {args.max_pfa:g}")
    return PfaCriterion(name, lo, hi, parse_prior(args.prior), parse_rule(args.rule), args.max_pfa)


def _design_search(args, proc, setup, truth):
    """`mtplan plan PROC --optimize FIELD=LO:HI`: continuous search against the grid's best."""
    from mtplan.plans.planner import criterion_value, optimize_design
    from mtplan.evaluation.simulation import linearize_procedure

    free = {}
    for item in args.optimize:
        name, sep, rng = item.partition("=")
        lo, colon, hi = rng.partition(":")
        try:
            free[name.strip()] = (float(lo), float(hi))
        except ValueError:
            colon = ""
        if not sep or not colon:
            raise UsageError(f"--optimize expects FIELD=LO:HI, got {item!r}")
    found = optimize_design(proc, setup, free, criterion=args.criterion, truth=truth,
                            estimator=args.estimator)
    doc = {"criterion": args.criterion, "start_value": found["start_value"],
           "value": found["value"], "evaluations": found["evaluations"],
           "setup": found["setup"].as_dict()}
    vary = parse_vary(args.vary)
    if vary:  # the best grid point, for comparison
        from mtplan.plans.sweep import setup_grid

        values = [(criterion_value(linearize_procedure(proc, s, truth, estimator=args.estimator),
                                   args.criterion), s) for s in setup_grid(proc, setup, vary)]
        best_value, best = min(values, key=lambda v: v[0])
        doc["grid_best"] = {"value": best_value, "setup": best.as_dict()}
    if args.json:
        print(json.dumps({"design_search": doc}, indent=1))
        return 0
    print(f"{proc.name}: continuous search for the best {args.criterion} (linearised)")
    print(f"  at the base set-up: {doc['start_value']:.4g}")
    if "grid_best" in doc:
        shown = ", ".join(f"{f}={doc['grid_best']['setup'][f]}" for f in vary)
        print(f"  best grid point:    {doc['grid_best']['value']:.4g} ({shown})")
    shown = ", ".join(f"{f}={doc['setup'][f]}" for f in free)
    print(f"  search optimum:     {doc['value']:.4g} ({shown}; {doc['evaluations']} evaluations)")
    return 0
