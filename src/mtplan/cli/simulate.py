"""``mtplan simulate``: Monte Carlo uncertainty of one set-up."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from mtplan.cli._common import (
    UsageError,
    add_common,
    check_outputs,
    print_table,
    procedure_and_setup,
    run_options,
    parse_sources,
    write_out,
)


def register(sub) -> None:
    p = sub.add_parser("simulate", help="Monte Carlo uncertainty of one set-up")
    add_common(p)
    p.add_argument("--readings-out", metavar="FILE.csv",
                   help="write one simulated measurement in the readings format (with "
                        "--trials 1: only that, no Monte Carlo)")
    p.set_defaults(func=cmd_simulate)


def cmd_simulate(args):
    from mtplan.evaluation.simulation import simulate_readings, simulate_uncertainty

    check_outputs(out=args.out, readings_out=args.readings_out)
    if args.out and args.readings_out and _same_file(args.out, args.readings_out):
        raise UsageError(f"--out and --readings-out name the same file {args.out!r}")
    proc, setup, truth, config = procedure_and_setup(args)
    opts = run_options(args, config)
    estimator = args.estimator or config.get("estimator")
    sources = parse_sources(args, config)
    one = opts.trials == 1 and opts.digits is None
    if one and not args.readings_out:
        raise UsageError("--trials 1 gives no uncertainty; it is for writing one simulated "
                         "measurement with --readings-out (use at least 2 trials otherwise)")
    frame = None
    if args.readings_out:
        frame = simulate_readings(proc, setup, truth, rng=opts.rng, sources=sources)
    result = None
    if not one:
        result = simulate_uncertainty(proc, setup, truth, estimator=estimator, sources=sources,
                                      options=opts)
    if args.out and result is not None:  # first: a failure here leaves no readings file behind
        write_out(args.out, result.summary().to_csv())
    if frame is not None:
        _write_readings(frame, args.readings_out)
    if result is None:
        print(f"wrote one simulated {proc.name} measurement to {args.readings_out} (seed "
              f"{opts.rng}); 'mtplan estimate {proc.name} {args.readings_out}' gives its "
              "measurands with their uncertainty", file=sys.stderr)
        return 0
    if args.json:
        print(json.dumps(result.to_dict(), indent=1))
        return 0
    _print_result(result)
    return 0


def _write_readings(frame, path) -> None:
    from mtplan._io import atomic_write

    try:
        with atomic_write(path, "w", encoding="utf-8", newline="") as fh:
            frame.to_csv(fh, index=False)
    except OSError as exc:
        raise UsageError(f"--readings-out: cannot write {path!r}: {exc.strerror}") from None


def _print_result(result) -> None:
    """The table of :meth:`ProcedureResult.to_dict`, its not-determinable rows and notes."""
    from mtplan.reports.labels import fmt

    doc = result.to_dict()
    mc = result.mc
    print(f"{doc['procedure']} ({doc['estimator']}), {doc['trials']} trials, seed {doc['seed']}, "
          f"{100 * mc.coverage:g} % {doc['interval_kind']} intervals, "
          f"sources: {', '.join(doc['sources']) or 'none'}")
    if mc.digits is not None and not mc.converged:
        print(f"warning: not stable to {mc.digits} digits after {mc.trials} trials", file=sys.stderr)
    rows = []
    for m in doc["measurands"]:
        u = m["u"]
        if not m["determinable"]:
            rows.append([m["name"], m["unit"], fmt(m["true"]), "not determinable", "-", "-", "-"])
            continue
        rows.append([m["name"], m["unit"], fmt(m["true"], u), fmt(m["value"], u),
                     fmt(m["bias"], u), f"{u:.3g}",
                     f"[{fmt(m['interval'][0], u)}, {fmt(m['interval'][1], u)}]"])
    print_table(["measurand", "unit", "true", "mean", "bias", "u", "interval"], rows)
    for m in doc["measurands"]:
        if m["reason"]:
            print(f"{m['name']}: {m['reason']}")
    print(f"duration of the test: {doc['duration_s']:.0f} s")
    for note in doc["notes"]:
        print(f"note: {note}", file=sys.stderr)


def _same_file(a, b) -> bool:
    return Path(a).resolve() == Path(b).resolve()
