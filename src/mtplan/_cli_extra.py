"""Commands beyond the foundation: registered here so cli.py stays one thin file.

Each later command (plan, accept, estimate, report, demo) adds its parser in
:func:`register`; its code lives in the library, imported when it runs.
"""

from __future__ import annotations


def register(sub, common) -> None:
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
