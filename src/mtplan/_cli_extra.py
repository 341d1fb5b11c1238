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

    p = sub.add_parser("demo", help="the built-in study, end to end")
    p.add_argument("--out", metavar="DIR", default="mtplan-demo", help="output folder")
    p.add_argument("--trials", type=int, default=20000, metavar="N")
    p.set_defaults(func=cmd_demo)


def cmd_demo(args):
    """Until the demo study exists: Monte Carlo of every procedure's default set-up."""
    import sys

    from mtplan.models import registry
    from mtplan.uncertainty.procedures import simulate_uncertainty

    procs = registry()
    if not procs:
        print("no procedures are registered yet", file=sys.stderr)
        return 1
    for name, proc in procs.items():
        r = simulate_uncertainty(proc, trials=args.trials, rng=0, progress=None)
        print(f"\n== {name}: {proc.title} ({r.estimator}, {r.mc.trials} trials)")
        df = r.summary()
        print(df[["unit", "true", "mean", "bias", "std", "low", "high"]].to_string(
            float_format=lambda v: f"{v:.4g}"))
    return 0


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
