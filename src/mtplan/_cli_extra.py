"""Commands beyond the foundation: registered here so cli.py stays one thin file.

Each later command (plan, accept, estimate, report, demo) adds its parser in
:func:`register`; its code lives in the library, imported when it runs.
"""

from __future__ import annotations


def register(sub, common) -> None:
    p = sub.add_parser("plan", help="cheapest set-up meeting targets, Pareto front")
    common(p)
    p.add_argument("--target", action="append", metavar="NAME<=VALUE",
                   help="bound on a measurand's uncertainty in its unit (repeatable)")
    p.add_argument("--vary", action="append", metavar="FIELD=V1,V2,...",
                   help="candidate values of a set-up field (repeatable)")
    p.add_argument("--k", type=float, default=1.0,
                   help="coverage factor of the targets (default 1: standard uncertainty)")
    p.add_argument("--confirm", type=int, default=5,
                   help="most candidates checked by Monte Carlo (default 5)")
    p.set_defaults(func=cmd_plan)

    p = sub.add_parser("report", help="HTML and PDF report of a study")
    p.add_argument("study", metavar="STUDY.toml", help="the study file")
    p.add_argument("--out", metavar="DIR", required=True, help="output folder")
    p.add_argument("--jobs", type=int, default=1, metavar="J", help="parallel workers")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("demo", help="the built-in study, end to end")
    p.add_argument("--out", metavar="DIR", default="mtplan-report", help="output folder")
    p.add_argument("--jobs", type=int, default=1, metavar="J", help="parallel workers")
    p.set_defaults(func=cmd_demo)


def _report(study_path, out, jobs, progress):
    import sys
    import time

    from mtplan.plans.study import load_study, run_study
    from mtplan.reports import write_report

    start = time.perf_counter()
    study = load_study(study_path)
    result = run_study(study, progress=progress, n_jobs=jobs)
    written = write_report(result, out)
    print(f"report written in {time.perf_counter() - start:.1f} s:", file=sys.stderr)
    print(written["html"])
    print(written["pdf"])
    return 0


def cmd_report(args):
    return _report(args.study, args.out, args.jobs, progress=None)


def demo_study_path():
    """The built-in study shipped with mtplan (``examples/demo.toml``)."""
    from pathlib import Path

    return Path(__file__).resolve().parent / "examples" / "demo.toml"


def cmd_demo(args):
    """Run the default study end to end and say where the report is."""
    return _report(demo_study_path(), args.out, args.jobs, progress=True)


def cmd_plan(args):
    import json

    from mtplan.cli import UsageError, _procedure_and_setup, _sources, _vary
    from mtplan.plans.planner import parse_target, plan

    proc, setup, truth, config = _procedure_and_setup(args)
    targets = dict(parse_target(t) for t in (args.target or []))
    targets.update({k: float(v) for k, v in config.get("targets", {}).items()})
    if not targets:
        raise UsageError("plan needs at least one --target NAME<=VALUE")
    vary = dict(config.get("vary", {}))
    vary.update(_vary(args.vary))
    seed = args.seed if args.seed is not None else config.get("seed", 0)
    result = plan(proc, setup, vary, targets, k=args.k, truth=truth,
                  estimator=args.estimator or config.get("estimator"),
                  sources=_sources(args, config), confirm=args.confirm,
                  trials=args.trials or 5000, seed=seed, n_jobs=args.jobs, backend=args.backend)
    if args.out:
        from mtplan.cli import _write_out

        _write_out(args.out, result.table.to_csv(index=False))
    if args.json:
        print(json.dumps(result.to_dict(), indent=1, default=float))
        return 0
    best = result.best
    print(f"{proc.name}: cheapest set-up meeting " + ", ".join(
        f"{n} <= {v:g}" for n, v in targets.items()) + (f" (k = {args.k:g})" if args.k != 1 else ""))
    for f in vary:
        print(f"  {f} = {best['setup'][f]}")
    print(f"  duration {best['duration_s']:.0f} s")
    for n in targets:
        c = result.confirmation[-1]
        print(f"  {n}: predicted {best['predicted'][n]:.3g}, Monte Carlo {best['confirmed'][n]:.3g} "
              f"(ratio {c['ratio'][n]:.3f}, {c['trials']} trials)")
    print(f"Pareto front (duration against the worst target ratio): {len(result.pareto)} set-ups")
    for c in result.pareto:
        shown = ", ".join(f"{f}={c['setup'][f]}" for f in vary)
        print(f"  {c['duration_s']:8.0f} s  {c['worst']:.3f}  {shown}")
    return 0
