"""The ``mtplan`` command: parses, calls the library, prints.

Thin by design: every number comes from the library, which a Python user can
call directly. A user's mistake (unknown field, bad value, missing file) exits
with status 2 and one line on stderr, never a traceback. Heavy modules are
imported inside the commands so that ``mtplan --help`` starts fast.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

__all__ = ["main"]

EXIT_USAGE = 2


class UsageError(Exception):
    """A user's mistake on the command line: one line, exit status 2."""


# --------------------------------------------------------------------------- helpers
def _pairs(items, option):
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"{option} expects FIELD=VALUE, got {item!r}")
        out[key.strip()] = value.strip()
    return out


def _load_config(path):
    import tomllib

    if path is None:
        return {}
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        raise UsageError(f"--config: no such file {path!r}") from None
    except OSError as exc:
        raise UsageError(f"--config: cannot read {path!r}: {exc.strerror}") from None
    except tomllib.TOMLDecodeError as exc:
        raise UsageError(f"--config: {path} is not valid TOML: {exc}") from None
    return data


def _procedure_and_setup(args, config=None):
    from mtplan.models import get
    from mtplan.models._protocol import make

    config = _load_config(args.config) if config is None else config
    if config.get("procedure") not in (None, args.procedure):
        raise UsageError(
            f"--config {args.config} is for procedure {config['procedure']!r}, "
            f"not {args.procedure!r}"
        )
    proc = get(args.procedure)
    setup_values = dict(config.get("setup", {}))
    setup_values.update(_pairs(args.set, "--set"))
    truth_values = dict(config.get("truth", {}))
    truth_values.update(_pairs(getattr(args, "truth", None), "--truth"))
    problems = []
    setup = truth = None
    from mtplan._validate import InvalidInput

    try:
        setup = make(proc.Setup, setup_values, owner=proc.name)
    except InvalidInput as exc:
        problems += exc.problems
    try:
        truth = make(proc.Truth, truth_values, owner=f"{proc.name} truth")
    except InvalidInput as exc:
        problems += exc.problems
    if problems:
        raise InvalidInput(problems)
    return proc, setup, truth, config


def _sources(args, config):
    text = args.sources if args.sources is not None else config.get("sources")
    if text is None:
        return None
    if isinstance(text, list):
        return [str(s) for s in text]
    return [s.strip() for s in str(text).split(",") if s.strip()]


def _run_options(args, config):
    trials = args.trials if args.trials is not None else config.get("trials")
    digits = args.digits if args.digits is not None else config.get("digits")
    if trials is not None and digits is not None and args.trials is None and args.digits is not None:
        trials = None
    if trials is not None and digits is not None and args.digits is None and args.trials is not None:
        digits = None
    seed = args.seed if args.seed is not None else config.get("seed", 0)
    return {
        "trials": trials,
        "digits": digits,
        "coverage": args.coverage,
        "interval": args.interval,
        "rng": seed,
        "n_jobs": args.jobs,
        "backend": args.backend,
        "scheduler": args.scheduler,
    }


def _fmt(value, u):
    """Round `value` to the resolution its uncertainty `u` supports (two digits of u)."""
    if not math.isfinite(value):
        return str(value)
    if not (u > 0 and math.isfinite(u)):
        return f"{value:.6g}"
    decimals = max(0, 1 - math.floor(math.log10(u)))
    return f"{value:.{min(decimals, 9)}f}"


def _print_table(header, rows, file=None):
    file = file or sys.stdout
    widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) if rows else len(h)
              for i, h in enumerate(header)]
    print("  ".join(str(h).ljust(w) for h, w in zip(header, widths, strict=True)), file=file)
    for r in rows:
        print("  ".join(str(c).rjust(w) if i else str(c).ljust(w)
                        for i, (c, w) in enumerate(zip(r, widths, strict=True))), file=file)


def _write_out(path, text):
    from mtplan._io import atomic_write_text

    try:
        atomic_write_text(path, text)
    except OSError as exc:
        raise UsageError(f"--out: cannot write {path!r}: {exc.strerror}") from None


# --------------------------------------------------------------------------- commands
def cmd_procedures(args):
    from mtplan.models import registry
    from mtplan.models._protocol import fields_info

    procs = registry()
    if args.procedure:
        from mtplan.models import get

        procs = {args.procedure: get(args.procedure)}
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
            "setup": [{k: (list(v) if isinstance(v, tuple) else v) for k, v in f.items()
                       if k in ("name", "default", "unit", "doc", "low", "high", "choices")}
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
            default = "axis default" if default is None else default
            print(f"    {f['name']} = {default}    {f['doc']}")
        print()
    return 0


def cmd_simulate(args):
    from mtplan.uncertainty.procedures import simulate_uncertainty

    proc, setup, truth, config = _procedure_and_setup(args)
    opts = _run_options(args, config)
    estimator = args.estimator or config.get("estimator")
    result = simulate_uncertainty(proc, setup, truth, estimator=estimator,
                                  sources=_sources(args, config), progress=None, **opts)
    doc = result.to_dict()
    if args.readings_out:
        from mtplan._io import atomic_write

        readings = proc.simulate(setup, truth, 1, rng=opts["rng"], sources=_sources(args, config))
        frame = proc.readings_frame(setup, readings)
        try:
            with atomic_write(args.readings_out, "w", encoding="utf-8", newline="") as fh:
                frame.to_csv(fh, index=False)
        except OSError as exc:
            raise UsageError(f"--readings-out: cannot write {args.readings_out!r}: {exc.strerror}") from None
    if args.out:
        _write_out(args.out, result.summary().to_csv())
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
        rows.append([m["name"], m["unit"], _fmt(m["true"], u), _fmt(m["mean"], u),
                     _fmt(m["bias"], u), f"{u:.3g}",
                     f"[{_fmt(m['interval'][0], u)}, {_fmt(m['interval'][1], u)}]"])
    _print_table(["measurand", "unit", "true", "mean", "bias", "u", "interval"], rows)
    print(f"duration of the test: {result.duration_s:.0f} s")
    return 0


def cmd_linearize(args):
    from mtplan.uncertainty.procedures import linearize_procedure

    proc, setup, truth, config = _procedure_and_setup(args)
    estimator = args.estimator or config.get("estimator")
    g = linearize_procedure(proc, setup, truth, estimator=estimator,
                            sources=_sources(args, config), coverage=args.coverage)
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
        _write_out(args.out, g.budget().to_csv(index=False))
    if args.json:
        print(json.dumps(doc, indent=1))
        return 0
    print(f"{proc.name} ({doc['estimator']}): GUM law of propagation, k = {g.k[0]:.3f}")
    rows = []
    for m in doc["measurands"]:
        u = m["std"]
        shares = sorted(m["budget"].items(), key=lambda kv: -kv[1]["share"])
        top = ", ".join(f"{k} {100 * v['share']:.0f} %" for k, v in shares[:3] if v["share"] > 0.005)
        rows.append([m["name"], m["unit"], _fmt(m["value"], u), f"{u:.3g}",
                     f"[{_fmt(m['interval'][0], u)}, {_fmt(m['interval'][1], u)}]", top])
    _print_table(["measurand", "unit", "value", "u", "interval", "largest sources"], rows)
    return 0


def _vary(items):
    vary = {}
    for item in items or []:
        key, sep, values = item.partition("=")
        if not sep or not key.strip() or not values.strip():
            raise UsageError(f"--vary expects FIELD=V1,V2,..., got {item!r}")
        if "|" in values:  # list-valued fields: --vary angles_deg="0,90|0,45,90"
            vary[key.strip()] = [v.strip() for v in values.split("|")]
        else:
            vary[key.strip()] = [v.strip() for v in values.split(",") if v.strip()]
    return vary


def cmd_sweep(args):
    from mtplan.plans.sweep import sweep

    proc, setup, truth, config = _procedure_and_setup(args)
    vary = dict(config.get("vary", {}))
    vary.update(_vary(args.vary))
    if not vary:
        raise UsageError("sweep needs at least one --vary FIELD=V1,V2,...")
    opts = _run_options(args, config)
    est = args.estimator or config.get("estimator")
    estimators = None if est is None else ("all" if est == "all" else est.split(","))
    table = sweep(proc, setup, vary, truth=truth, estimators=estimators,
                  sources=_sources(args, config), trials=opts["trials"], digits=opts["digits"],
                  coverage=opts["coverage"], interval=opts["interval"], seed=opts["rng"],
                  n_jobs=opts["n_jobs"], backend=opts["backend"], scheduler=opts["scheduler"],
                  out=args.out, progress=None)
    if args.json:
        print(table.to_json(orient="records"))
        return 0
    show = list(vary) + ["estimator", "measurand", "unit", "bias", "std", "duration_s"]
    wide = table[show]
    import pandas as pd

    with pd.option_context("display.max_rows", 200, "display.width", 160):
        print(wide.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    errors = table["error"]
    failed = table[errors.notna() & (errors.astype(str) != "")]
    for (est, point), group in failed.groupby(["estimator", "point"], sort=False):
        shown = ", ".join(f"{f}={group[f].iloc[0]}" for f in vary)
        print(f"note: {est} cannot evaluate {shown}: {group['error'].iloc[0]}", file=sys.stderr)
    if args.out:
        print(f"wrote {args.out}", file=sys.stderr)
    return 0


# --------------------------------------------------------------------------- parser
def _common(p, *, mc=True):
    p.add_argument("procedure", help="procedure name (see 'mtplan procedures')")
    p.add_argument("--config", metavar="FILE.toml", help="set-up file: [setup] and [truth] tables")
    p.add_argument("--set", action="append", metavar="FIELD=VALUE", help="set-up field (repeatable)")
    p.add_argument("--truth", action="append", metavar="FIELD=VALUE",
                   help="true value for the simulation (repeatable)")
    p.add_argument("--estimator", metavar="NAME", help="estimator (default: the seed's method)")
    p.add_argument("--sources", metavar="NAME[,NAME...]",
                   help="simulate with only these error sources (field name without its unit)")
    p.add_argument("--coverage", type=float, default=0.95, metavar="P",
                   help="coverage probability (default 0.95)")
    p.add_argument("--json", action="store_true", help="print one JSON document on stdout")
    p.add_argument("--out", metavar="FILE", help="also write the table to FILE")
    if mc:
        g = p.add_mutually_exclusive_group()
        g.add_argument("--trials", type=int, metavar="N", help="Monte Carlo trials (default 10000)")
        g.add_argument("--digits", type=int, metavar="D",
                       help="adaptive Monte Carlo to D significant digits (JCGM 101 7.9)")
        p.add_argument("--seed", type=int, metavar="S", help="random seed (default 0)")
        p.add_argument("--jobs", type=int, default=1, metavar="J", help="parallel workers (-1: all)")
        p.add_argument("--backend", choices=["loky", "threading", "dask"],
                       help="joblib backend (dask: --scheduler or a local cluster)")
        p.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler address")
        p.add_argument("--interval", choices=["symmetric", "shortest"], default="symmetric",
                       help="coverage interval (default: probabilistically symmetric)")


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise UsageError(message)


def build_parser() -> argparse.ArgumentParser:
    from mtplan import __version__

    parser = _Parser(
        prog="mtplan",
        description="Monte Carlo uncertainty and test-plan designer for machine-tool metrology.",
        epilog="Lengths in um, angles in urad on output; 'mtplan COMMAND --help' for details.",
    )
    parser.add_argument("--version", action="version", version=f"mtplan {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    p = sub.add_parser("procedures", help="list procedures, set-up fields, defaults, measurands")
    p.add_argument("procedure", nargs="?", help="show only this procedure")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_procedures)

    p = sub.add_parser("simulate", help="Monte Carlo uncertainty of one set-up")
    _common(p)
    p.add_argument("--readings-out", metavar="FILE.csv",
                   help="write one simulated measurement in the readings format")
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("linearize", help="GUM law of propagation for one set-up, with budget")
    _common(p, mc=False)
    p.set_defaults(func=cmd_linearize)

    p = sub.add_parser("sweep", help="grid of set-ups -> table (CSV or Parquet)")
    _common(p)
    p.add_argument("--vary", action="append", metavar="FIELD=V1,V2,...",
                   help="values of a set-up field (repeatable; the grid is their product)")
    p.set_defaults(func=cmd_sweep)

    _extra_commands(sub)
    return parser


def _extra_commands(sub):
    """Commands contributed by later modules (plan, accept, estimate, report, demo)."""
    from mtplan import _cli_extra

    _cli_extra.register(sub, _common)


def main(argv=None) -> int:
    """Entry point of the ``mtplan`` console script."""
    from mtplan._validate import InvalidInput

    try:
        parser = build_parser()
        args = parser.parse_args(argv)
        if not getattr(args, "command", None):
            parser.print_help()
            return 0
        return int(args.func(args) or 0)
    except UsageError as exc:
        print(f"mtplan: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except InvalidInput as exc:
        print("mtplan: error: " + " ".join(exc.problems), file=sys.stderr)
        return EXIT_USAGE
    except FileNotFoundError as exc:
        print(f"mtplan: error: no such file {exc.filename!r}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("mtplan: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # a model that cannot be evaluated: one line, status 1
        from mtplan.uncertainty.montecarlo import ModelError

        if isinstance(exc, ModelError):
            print(f"mtplan: error: {exc}", file=sys.stderr)
            return 1
        raise


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
