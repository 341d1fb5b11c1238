"""``mtplan linearize``: the GUM law of propagation for one set-up, with its budget."""

from __future__ import annotations

import json
import math
import sys

from mtplan.cli._common import (
    add_common,
    check_outputs,
    fmt,
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
    from mtplan.evaluation.simulation import linearize_procedure

    check_outputs(out=args.out)
    proc, setup, truth, config = procedure_and_setup(args)
    estimator = args.estimator or config.get("estimator")
    g = linearize_procedure(proc, setup, truth, estimator=estimator,
                            sources=parse_sources(args, config), coverage=args.coverage)
    measurands = proc.measurands(setup)
    groups, var = g.group_variance()
    doc = {
        "procedure": proc.name,
        "estimator": estimator or proc.default_estimator,
        "setup": setup.as_dict(),
        "measurands": [
            {
                "name": m.name,
                "unit": m.unit,
                "value": float(g.value[i]),
                "std": float(g.std[i]),
                "interval": [float(g.low[i]), float(g.high[i])],
                "coverage": args.coverage,
                "budget": {src: {"std": float(math.sqrt(var[i, j])),
                                 "share": float(var[i, j] / g.cov[i, i]) if g.cov[i, i] > 0 else 0.0}
                           for j, src in enumerate(groups)},
            }
            for i, m in enumerate(measurands)
        ],
    }
    if args.out:
        write_out(args.out, g.budget().to_csv(index=False))
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    print(f"{proc.name} ({doc['estimator']}): GUM law of propagation, k = {g.k[0]:.3f}")
    rows = []
    for m in doc["measurands"]:
        u = m["std"]
        shares = sorted(m["budget"].items(), key=lambda kv: -kv[1]["share"])
        top = ", ".join(f"{k} {100 * v['share']:.0f} %" for k, v in shares[:3] if v["share"] > 0.005)
        rows.append([m["name"], m["unit"], fmt(m["value"], u), f"{u:.3g}",
                     f"[{fmt(m['interval'][0], u)}, {fmt(m['interval'][1], u)}]", top])
    print_table(["measurand", "unit", "value", "u", "interval", "largest sources"], rows)
    for m in doc["measurands"]:
        if not m["std"] > 0:
            print(f"note: {m['name']}: u = 0: the {doc['estimator']} estimator does not move "
                  "with any error source at first order (it is quantised or blind to this "
                  "measurand), so the law of propagation cannot give its uncertainty",
                  file=sys.stderr)
    return 0
