"""``mtplan simulate``: Monte Carlo uncertainty of one set-up."""

from __future__ import annotations

import json
import sys

from mtplan.cli._common import (
    UsageError,
    add_common,
    check_outputs,
    fmt,
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
                   help="write one simulated measurement in the readings format")
    p.set_defaults(func=cmd_simulate)


def cmd_simulate(args):
    from mtplan.evaluation.simulation import simulate_uncertainty

    check_outputs(out=args.out, readings_out=args.readings_out)
    if args.out and args.readings_out and _same_file(args.out, args.readings_out):
        raise UsageError(f"--out and --readings-out name the same file {args.out!r}")
    proc, setup, truth, config = procedure_and_setup(args)
    opts = run_options(args, config)
    estimator = args.estimator or config.get("estimator")
    sources = parse_sources(args, config)
    result = simulate_uncertainty(proc, setup, truth, estimator=estimator, sources=sources,
                                  progress=None, **opts)
    doc = result.to_dict()
    frame = None
    if args.readings_out:
        readings = proc.simulate(setup, truth, 1, rng=opts["rng"], sources=sources)
        frame = proc.readings_frame(setup, readings)
    if args.out:  # first: a failure here leaves no readings file behind
        write_out(args.out, result.summary().to_csv())
    if frame is not None:
        from mtplan._io import atomic_write

        try:
            with atomic_write(args.readings_out, "w", encoding="utf-8", newline="") as fh:
                frame.to_csv(fh, index=False)
        except OSError as exc:
            raise UsageError(f"--readings-out: cannot write {args.readings_out!r}: "
                             f"{exc.strerror}") from None
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    mc = result.mc
    print(f"{proc.name} ({result.estimator}), {mc.trials} trials, seed {doc['seed']}, "
          f"{100 * mc.coverage:g} % {mc.interval} intervals, "
          f"sources: {', '.join(result.sources) or 'none'}")
    if mc.digits is not None and not mc.converged:
        print(f"warning: not stable to {mc.digits} digits after {mc.trials} trials", file=sys.stderr)
    rows = []
    for m in doc["measurands"]:
        u = m["std"]
        rows.append([m["name"], m["unit"], fmt(m["true"], u), fmt(m["mean"], u),
                     fmt(m["bias"], u), f"{u:.3g}",
                     f"[{fmt(m['interval'][0], u)}, {fmt(m['interval'][1], u)}]"])
    print_table(["measurand", "unit", "true", "mean", "bias", "u", "interval"], rows)
    print(f"duration of the test: {result.duration_s:.0f} s")
    for note in result.findings():
        print(f"note: {note}", file=sys.stderr)
    return 0


def _same_file(a, b) -> bool:
    from pathlib import Path

    return Path(a).resolve() == Path(b).resolve()
