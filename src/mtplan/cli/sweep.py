"""``mtplan sweep``: a grid of set-ups -> one tidy table (CSV or Parquet), resumable."""

from __future__ import annotations

import sys

from mtplan.cli._common import (
    UsageError,
    add_common,
    procedure_and_setup,
    run_options,
    parse_sources,
    parse_vary,
)


def register(sub) -> None:
    p = sub.add_parser("sweep", help="grid of set-ups -> table (CSV or Parquet)")
    add_common(p)
    p.add_argument("--vary", action="append", metavar="FIELD=V1,V2,...",
                   help="values of a set-up field (repeatable; the grid is their product)")
    p.set_defaults(func=cmd_sweep)


def cmd_sweep(args):
    from mtplan.plans.sweep import sweep

    proc, setup, truth, config = procedure_and_setup(args)
    vary = dict(config.get("vary", {}))
    vary.update(parse_vary(args.vary))
    if not vary:
        raise UsageError("sweep needs at least one --vary FIELD=V1,V2,...")
    opts = run_options(args, config)
    est = args.estimator or config.get("estimator")
    estimators = None if est is None else ("all" if est == "all" else est.split(","))
    table = sweep(proc, setup, vary, truth=truth, estimators=estimators,
                  sources=parse_sources(args, config), out=args.out, options=opts)
    if args.json:
        print(table.to_json(orient="records"))
        return 0
    show = list(vary) + ["estimator", "measurand", "unit", "bias", "u", "duration_s"]
    wide = table[show]
    import pandas as pd

    with pd.option_context("display.max_rows", 200, "display.width", 160):
        print(wide.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    errors = table["error"]
    failed = table[errors.notna() & (errors.astype(str) != "")]
    for (est, point), group in failed.groupby(["estimator", "point"], sort=False):
        shown = ", ".join(f"{f}={group[f].iloc[0]}" for f in vary)
        print(f"note: {est} cannot evaluate {shown}: {group['error'].iloc[0]}", file=sys.stderr)
    for note in table.attrs.get("notes", []):
        print(f"note: {note}", file=sys.stderr)
    if args.out:
        print(f"wrote {args.out}", file=sys.stderr)
    return 0
