"""``mtplan accept``: acceptance limits and risks of a decision rule (JCGM 106, ISO 14253-1)."""

from __future__ import annotations

import json


def register(sub) -> None:
    p = sub.add_parser("accept", help="acceptance decision rule and risks (JCGM 106, ISO 14253-1)")
    p.add_argument("--lower", type=float, metavar="L", help="lower tolerance limit")
    p.add_argument("--upper", type=float, metavar="U", help="upper tolerance limit")
    p.add_argument("--u", type=float, required=True, metavar="u", help="standard uncertainty")
    p.add_argument("--prior", metavar="SPEC",
                   help="process distribution: normal:MEAN,SD, gamma:SHAPE,SCALE or FILE.csv")
    p.add_argument("--rule", default="simple", metavar="RULE",
                   help="simple, guard:R, target-pfa:P, iso14253 or dobbert (default simple)")
    p.add_argument("--measured", type=float, metavar="Y", help="a measured value: its specific risk")
    p.add_argument("--json", action="store_true", help="print one JSON document on stdout")
    p.set_defaults(func=cmd_accept)


def cmd_accept(args):
    from mtplan.plans.acceptance import judgement, plan_acceptance

    r = plan_acceptance(args.lower, args.upper, args.u, prior=args.prior, rule=args.rule,
                        measured=args.measured)
    doc = r.to_dict()
    doc["judgement"] = judgement(r)
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0

    def show(x, pct=False):
        if x is None:
            return "-"
        return f"{100 * x:.4g} %" if pct else f"{x:.6g}"

    lo, hi = doc["acceptance_limits"]
    print(f"tolerance [{show(args.lower)}, {show(args.upper)}], u = {args.u:g}, rule {args.rule}")
    print(f"  acceptance limits        [{show(lo)}, {show(hi)}]")
    print(f"  TUR                      {show(doc['tur'])}    Cm {show(doc['cm'])}")
    print(f"  false accept (global)    {show(doc['pfa'], True)}")
    print(f"  false reject (global)    {show(doc['pfr'], True)}")
    print(f"  conditional false accept {show(doc['conditional_pfa'], True)}")
    print(f"  judgement                {doc['judgement']['text']}")
    if args.measured is not None:
        print(f"  measured {args.measured:g}: specific risk {show(doc['specific_risk'], True)}")
    return 0
