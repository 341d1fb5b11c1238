"""What every ``mtplan`` command shares: option parsing, set-up loading and output.

Every command module of :mod:`mtplan.cli` imports this one; this one imports none
of them. Heavy modules are imported inside the functions so that ``mtplan --help``
starts fast.
"""

from __future__ import annotations

import argparse
import math
import sys

__all__ = [
    "EXIT_USAGE",
    "ArgumentParser",
    "UsageError",
    "add_common",
    "fmt",
    "load_config",
    "parse_pairs",
    "print_table",
    "procedure_and_setup",
    "run_options",
    "parse_sources",
    "parse_vary",
    "write_out",
]

EXIT_USAGE = 2


class UsageError(Exception):
    """A user's mistake on the command line: one line, exit status 2."""


# --------------------------------------------------------------------------- options
def parse_pairs(items, option):
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"{option} expects FIELD=VALUE, got {item!r}")
        out[key.strip()] = value.strip()
    return out


def load_config(path):
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


def procedure_and_setup(args, config=None):
    from mtplan.models import get
    from mtplan.models._protocol import make

    config = load_config(args.config) if config is None else config
    if config.get("procedure") not in (None, args.procedure):
        raise UsageError(
            f"--config {args.config} is for procedure {config['procedure']!r}, "
            f"not {args.procedure!r}"
        )
    proc = get(args.procedure)
    setup_values = dict(config.get("setup", {}))
    setup_values.update(parse_pairs(args.set, "--set"))
    truth_values = dict(config.get("truth", {}))
    truth_values.update(parse_pairs(getattr(args, "truth", None), "--truth"))
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


def parse_sources(args, config):
    text = args.sources if args.sources is not None else config.get("sources")
    if text is None:
        return None
    if isinstance(text, list):
        return [str(s) for s in text]
    return [s.strip() for s in str(text).split(",") if s.strip()]


def run_options(args, config):
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


def fmt(value, u):
    """Round `value` to the resolution its uncertainty `u` supports (two digits of u)."""
    if not math.isfinite(value):
        return str(value)
    if not (u > 0 and math.isfinite(u)):
        return f"{value:.6g}"
    decimals = max(0, 1 - math.floor(math.log10(u)))
    return f"{value:.{min(decimals, 9)}f}"


def print_table(header, rows, file=None):
    file = file or sys.stdout
    widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) if rows else len(h)
              for i, h in enumerate(header)]
    print("  ".join(str(h).ljust(w) for h, w in zip(header, widths, strict=True)), file=file)
    for r in rows:
        print("  ".join(str(c).rjust(w) if i else str(c).ljust(w)
                        for i, (c, w) in enumerate(zip(r, widths, strict=True))), file=file)


def write_out(path, text):
    from mtplan._io import atomic_write_text

    try:
        atomic_write_text(path, text)
    except OSError as exc:
        raise UsageError(f"--out: cannot write {path!r}: {exc.strerror}") from None


def parse_vary(items):
    """--vary FIELD=V1,V2 (or V1|V2 for list fields) -> {field: [values]}."""
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


# --------------------------------------------------------------------------- parser
def add_common(p, *, mc=True):
    """The options of the commands that evaluate one procedure's set-up."""
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


class ArgumentParser(argparse.ArgumentParser):
    """argparse that raises UsageError (one line, exit 2) instead of exiting."""

    def error(self, message):
        raise UsageError(message)
