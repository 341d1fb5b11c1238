"""``mtplan linearize``: the GUM law of propagation for one set-up, with its budget."""

from __future__ import annotations

import json
import sys

from mtplan.cli._common import (
    add_common,
    check_outputs,
    print_table,
    procedure_and_setup,
    parse_sources,
    write_out,
)


def register(sub) -> None:
    p = sub.add_parser("linearize", help="GUM law of propagation for one set-up, with budget")
    add_common(p, mc=False)
    p.set_defaults(func=cmd_linearize)


def cmd_linearize(args):
    from mtplan.evaluation.simulation import linearize_result

    check_outputs(out=args.out)
    proc, setup, truth, config = procedure_and_setup(args)
    result = linearize_result(proc, setup, truth, estimator=args.estimator or
                              config.get("estimator"), sources=parse_sources(args, config),
                              coverage=args.coverage)
    if args.out:
        write_out(args.out, result.gum.budget().to_csv(index=False))
    doc = result.to_dict()
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    _print_result(doc, result.sections.get("reliability"))
    return 0


def _print_result(doc, rel=None) -> None:
    """The table of :meth:`LinearizedResult.to_dict`, its largest sources, what one bad
    reading can do unseen (`rel`, a :class:`~mtplan.evaluation.reliability.Reliability`)
    and the notes."""
    from mtplan.reports.labels import fmt

    k = f", k = {doc['k']:.3f}" if doc["k"] is not None else ""
    print(f"{doc['procedure']} ({doc['estimator']}): GUM law of propagation{k}")
    rows = []
    for m in doc["measurands"]:
        u = m["u"]
        if not m["determinable"]:
            rows.append([m["name"], m["unit"], "not determinable", "-", "-", "-"])
            continue
        shares = sorted(m["budget"].items(), key=lambda kv: -kv[1]["share"])
        top = ", ".join(f"{k} {100 * v['share']:.0f} %" for k, v in shares[:3] if v["share"] > 0.005)
        rows.append([m["name"], m["unit"], fmt(m["value"], u), f"{u:.3g}",
                     f"[{fmt(m['interval'][0], u)}, {fmt(m['interval'][1], u)}]", top])
    print_table(["measurand", "unit", "value", "u", "interval", "largest sources"], rows)
    for m in doc["measurands"]:
        if m["reason"]:
            print(f"{m['name']}: {m['reason']}")
    if rel is not None:
        for line in rel.lines():
            print(line)
    for note in doc["notes"]:
        print(f"note: {note}", file=sys.stderr)
