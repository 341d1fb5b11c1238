"""``mtplan procedures``: procedures, set-up fields, defaults, measurands, error sources."""

from __future__ import annotations

import json
import sys


def register(sub) -> None:
    p = sub.add_parser("procedures", help="list procedures, set-up fields, defaults, measurands")
    p.add_argument("procedure", nargs="?", help="show only this procedure")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_procedures)


def cmd_procedures(args):
    from mtplan.models import broken, registry
    from mtplan.models.protocol import fields_info

    procs = registry()
    if args.procedure:
        from mtplan.models import get

        procs = {args.procedure: get(args.procedure)}
    else:  # the installed plug-ins that gave no procedure, each named with why
        for why in broken():
            print(f"mtplan: warning: {why}", file=sys.stderr)
    doc = []
    for name, proc in procs.items():
        setup = proc.Setup()
        doc.append({
            "name": name,
            "title": proc.title,
            "estimators": list(proc.estimators),
            "measurands": [{"name": m.name, "unit": m.unit, "description": m.description}
                           for m in proc.measurands(setup)],
            "sources": {k: s.description for k, s in proc.sources(setup).items()},
            "setup": [{k: (list(v) if isinstance(v, tuple) else v)
                       for k in ("name", "default", "unit", "doc", "low", "high", "choices",
                                 "condition") for v in (getattr(f, k),)}
                      for f in fields_info(proc.Setup)],
        })
    if args.json:
        print(json.dumps(doc, indent=1, default=str))
        return 0
    for d in doc:
        print(f"{d['name']}: {d['title']}")
        print(f"  estimators: {', '.join(d['estimators'])}")
        print("  measurands: " + ", ".join(f"{m['name']} [{m['unit']}]" for m in d["measurands"]))
        print("  error sources: " + ", ".join(d["sources"]))
        print("  set-up fields (default):")
        for f in d["setup"]:
            default = f["default"]
            default = "empty" if default is None else default  # the doc says what it means
            also = (f"; in a study, [conditions] {f['condition']} fills it when the readings "
                    "are evaluated" if f.get("condition") else "")
            print(f"    {f['name']} = {default}    {f['doc']}{also}")
        print()
    return 0
