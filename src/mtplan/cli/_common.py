"""What every ``mtplan`` command shares: option parsing, set-up loading and output.

Every command module of :mod:`mtplan.cli` imports this one; this one imports none
of them. Heavy modules are imported inside the functions so that ``mtplan --help``
starts fast.
"""

from __future__ import annotations

import argparse
import os
import sys
import tomllib
from pathlib import Path

__all__ = [
    "EXIT_USAGE",
    "ArgumentParser",
    "UsageError",
    "add_common",
    "load_config",
    "parse_pairs",
    "print_table",
    "procedure_and_setup",
    "procedure_of",
    "setup_values",
    "check_config",
    "check_outputs",
    "CONFIG_KEYS",
    "run_options",
    "parse_sources",
    "parse_vary",
    "write_out",
    "MAX_TRIALS_ENV",
    "capped_trials",
    "count",
    "workers",
    "trials_cap",
]

EXIT_USAGE = 2


class UsageError(Exception):
    """A user's mistake on the command line: one line, exit status 2."""


# --------------------------------------------------------------------------- options
def parse_pairs(items, option):
    """``FIELD=VALUE`` options -> {field: value}; an empty field or value is refused."""
    out = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"{option} expects FIELD=VALUE, got {item!r}")
        if not value.strip():
            raise UsageError(f"{option} {item} gives {key.strip()} no value; state one "
                             "('default' for a field whose default depends on others)")
        out[key.strip()] = value.strip()
    return out


#: What a ``--config`` file may hold: top-level keys, their kind and what they are.
CONFIG_KEYS = {
    "procedure": (str, "the procedure the file is for"),
    "seed": (int, "random seed"),
    "trials": (int, "Monte Carlo trials"),
    "digits": (int, "adaptive Monte Carlo digits"),
    "estimator": (str, "estimator name"),
    "sources": ((str, list), "error sources to simulate"),
    "uncertainty": (str, "estimate: mc or posterior"),
    "setup": (dict, "set-up fields"),
    "truth": (dict, "true values for the simulation"),
    "vary": (dict, "sweep and plan: field = [values]"),
    "targets": (dict, "plan: measurand = bound"),
    "determine": ((str, list), "plan: 'all' or the measurands the set-up must determine"),
}


def load_config(path):
    """A ``--config`` TOML file as a dict, every key and kind checked; {} without a file."""
    if path is None:
        return {}
    try:
        with open(path, "rb") as fh:
            raw = fh.read()
    except FileNotFoundError:
        raise UsageError(f"--config: no such file {path!r}") from None
    except IsADirectoryError:
        raise UsageError(f"--config: {path!r} is a folder, not a TOML file") from None
    except OSError as exc:
        raise UsageError(f"--config: cannot read {path!r}: {exc.strerror}") from None
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError:
        raise UsageError(f"--config: {path} is not a TOML file (not UTF-8 text)") from None
    except tomllib.TOMLDecodeError as exc:
        raise UsageError(f"--config: {path} is not valid TOML: {exc}") from None
    check_config(data, path)
    return data


def check_config(data, path) -> None:
    """Refuse unknown keys and keys of the wrong kind, naming the file and the known keys."""
    problems = []
    for key, value in data.items():
        if key not in CONFIG_KEYS:
            problems.append(f"unknown key {key!r}")
            continue
        kind, what = CONFIG_KEYS[key]
        ok = isinstance(value, kind) and not (kind is int and isinstance(value, bool))
        if ok and key in ("sources", "determine") and isinstance(value, list):
            ok = all(isinstance(v, str) for v in value)
        if ok and kind is dict and key in ("setup", "truth"):
            empty = [k for k, v in value.items() if isinstance(v, str) and not v.strip()]
            if empty:
                problems.append(f"[{key}] gives {', '.join(empty)} no value (state one, or "
                                "'default')")
        if not ok:
            shown = repr(value) if not isinstance(value, dict) else "a table"
            want = {str: "a string", int: "an integer", dict: "a table [" + key + "]"}.get(
                kind, "a string or a list of strings")
            problems.append(f"{key} ({what}) must be {want}, got {shown[:40]}")
    if problems:
        known = ", ".join(k if CONFIG_KEYS[k][0] is not dict else f"[{k}]" for k in CONFIG_KEYS)
        raise UsageError(f"--config {path}: " + "; ".join(problems) + f" (known: {known})")


def setup_values(args, config, proc) -> dict:
    """The set-up fields of `proc` stated by ``--config`` [setup] and ``--set`` (which wins);
    a file field's relative path in the config is taken from the config file's folder."""
    from mtplan.models.protocol import resolve_file_fields

    values = dict(config.get("setup", {}))
    if values and getattr(args, "config", None):
        values = resolve_file_fields(proc.Setup, values, Path(args.config).parent)
    values.update(parse_pairs(args.set, "--set"))
    values.update(along_values(getattr(args, "along", None), proc))
    return values


def along_values(items, proc) -> dict:
    """``--along AXIS=START:STOP:STEP`` -> {``along_<axis>_mm``: "p1,p2,..."}: the positions
    [mm] at which a procedure whose set-up has that field states its errors along AXIS
    (START to STOP inclusive, every STEP)."""
    from mtplan.evaluation.along import parse_grid
    from mtplan.models.protocol import fields_info

    out = {}
    for axis, text in parse_pairs(items, "--along").items():
        field = f"along_{axis.lower()}_mm"
        if field not in getattr(proc.Setup, "__dataclass_fields__", {}):
            raise UsageError(f"--along {axis}: {proc.name} states no errors along {axis!r} "
                             f"(its set-up has no field {field})")
        most = next(f.max_len for f in fields_info(proc.Setup) if f.name == field)
        try:
            positions = parse_grid(text, most)
        except ValueError:
            raise UsageError(f"--along {axis}={text}: expected START:STOP:STEP [mm] with STEP "
                             "> 0, STOP >= START" + (f" and at most {most} positions"
                                                     if most is not None else "")) from None
        out[field] = ",".join(f"{p:g}" for p in positions)
    return out


def procedure_of(args, config):
    """The procedure named on the command line, checked against the config file's."""
    from mtplan.models import get

    if config.get("procedure") not in (None, args.procedure):
        raise UsageError(
            f"--config {args.config} is for procedure {config['procedure']!r}, "
            f"not {args.procedure!r}"
        )
    return get(args.procedure)


def procedure_and_setup(args, config=None):
    from mtplan._validate import InvalidInput
    from mtplan.models.protocol import make

    config = load_config(args.config) if config is None else config
    proc = procedure_of(args, config)
    truth_values = dict(config.get("truth", {}))
    truth_values.update(parse_pairs(getattr(args, "truth", None), "--truth"))
    problems = []
    setup = truth = None
    try:
        setup = make(proc.Setup, setup_values(args, config, proc), owner=proc.name)
    except InvalidInput as exc:
        problems += exc.problems
    try:
        truth = make(proc.Truth, truth_values, owner=f"{proc.name} truth")
    except InvalidInput as exc:
        problems += exc.problems
    if problems:
        raise InvalidInput(problems)
    return proc, setup, truth, config


def check_outputs(**paths) -> None:
    """Refuse output files that cannot be written, before any work: ``option=path`` pairs."""
    from mtplan._io import output_problem

    for option, path in paths.items():
        if path is None:
            continue
        problem = output_problem(path)
        if problem:
            raise UsageError(f"--{option.replace('_', '-')}: {problem}")


def parse_sources(args, config):
    """``--sources`` (or the config's ``sources``) as a list; None: every source."""
    text = args.sources if args.sources is not None else config.get("sources")
    if text is None:
        return None
    names = ([str(s).strip() for s in text] if isinstance(text, list)
             else [s.strip() for s in str(text).split(",")])
    names = [s for s in names if s]
    if not names:
        raise UsageError("--sources names no error source; name at least one (a source is its "
                         "set-up field without the unit: 'mtplan procedures PROC' lists them)")
    return names


#: The environment variable that caps every Monte Carlo trial count a command asks for
#: (``--trials``, a config's ``trials``, the defaults, the adaptive runs' limit): quick
#: runs of documented commands, as the test of the examples does.
MAX_TRIALS_ENV = "MTPLAN_MAX_TRIALS"


def trials_cap():
    """The ``MTPLAN_MAX_TRIALS`` cap on every Monte Carlo run, None when it is unset."""
    text = os.environ.get(MAX_TRIALS_ENV, "").strip()
    if not text:
        return None
    try:
        cap = int(text)
    except ValueError:
        cap = 0
    if cap < 2:
        raise UsageError(f"{MAX_TRIALS_ENV}={text!r} must be an integer >= 2 (or unset)")
    return cap


def capped_trials(trials, default=None):
    """`trials` (None: `default`) under the ``MTPLAN_MAX_TRIALS`` cap when that is set."""
    trials = default if trials is None else trials
    cap = trials_cap()
    return trials if cap is None or trials is None else min(trials, cap)


def run_options(args, config):
    """The run options of a command (:class:`~mtplan.uncertainty.options.RunOptions`): the
    command line's over the configuration file's; a trials cap (``MTPLAN_MAX_TRIALS``)
    turns an adaptive run into a fixed one at the cap."""
    from mtplan.uncertainty.options import RunOptions

    trials = args.trials if args.trials is not None else config.get("trials")
    digits = args.digits if args.digits is not None else config.get("digits")
    if trials is not None and digits is not None and args.trials is None and args.digits is not None:
        trials = None
    if trials is not None and digits is not None and args.digits is None and args.trials is not None:
        digits = None
    seed = args.seed if args.seed is not None else config.get("seed", 0)
    if trials_cap() is not None and digits is not None:  # adaptive runs stop at the cap
        trials, digits = trials_cap(), None
    return RunOptions(trials=capped_trials(trials, None if digits is not None else 10_000),
                      digits=digits, coverage=args.coverage, interval=args.interval, rng=seed,
                      n_jobs=args.jobs, backend=args.backend, scheduler=args.scheduler)


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


# --------------------------------------------------------------------------- counts
# Every option that counts something takes one of these as its argparse ``type``, so that a
# count of zero (or a negative one) is refused while the command line is read, before any
# work starts, with one line naming the option (tests/test_cli_inputs.py finds every such
# option in the parsers).
def _whole_number(text: str) -> int | None:
    try:
        return int(text)
    except ValueError:
        return None


def count(text: str) -> int:
    """A count option's value (trials, digits, steps, candidates): a whole number >= 1."""
    value = _whole_number(text)
    if value is None or value < 1:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 1, got {text!r}")
    return value


def workers(text: str) -> int:
    """A ``--jobs`` value: a whole number of parallel workers other than 0 (negative ones
    count back from the machine's cores, joblib's convention: -1 is every core)."""
    value = _whole_number(text)
    if value is None or value == 0:
        raise argparse.ArgumentTypeError(
            f"must be a whole number of workers >= 1 (or -1: every core), got {text!r}")
    return value


# --------------------------------------------------------------------------- parser
def add_common(p, *, mc=True):
    """The options of the commands that evaluate one procedure's set-up."""
    p.add_argument("procedure", help="procedure name (see 'mtplan procedures')")
    p.add_argument("--config", metavar="FILE.toml", help="set-up file: [setup] and [truth] tables")
    p.add_argument("--set", action="append", metavar="FIELD=VALUE", help="set-up field (repeatable)")
    p.add_argument("--truth", action="append", metavar="FIELD=VALUE",
                   help="true value for the simulation (repeatable)")
    p.add_argument("--estimator", metavar="NAME", help="estimator (default: the patent's method)")
    p.add_argument("--sources", metavar="NAME[,NAME...]",
                   help="simulate with only these error sources (field name without its unit)")
    p.add_argument("--coverage", type=float, default=0.95, metavar="P",
                   help="coverage probability (default 0.95)")
    p.add_argument("--json", action="store_true", help="print one JSON document on stdout")
    p.add_argument("--out", metavar="FILE", help="also write the table to FILE")
    if mc:
        g = p.add_mutually_exclusive_group()
        g.add_argument("--trials", type=count, metavar="N",
                       help="Monte Carlo trials (default 10000)")
        g.add_argument("--digits", type=count, metavar="D",
                       help="adaptive Monte Carlo to D significant digits (JCGM 101 7.9)")
        p.add_argument("--seed", type=int, metavar="S", help="random seed (default 0)")
        p.add_argument("--jobs", type=workers, default=1, metavar="J",
                       help="parallel workers (-1: all)")
        p.add_argument("--backend", choices=["loky", "threading", "dask"],
                       help="joblib backend (dask: --scheduler or a local cluster)")
        p.add_argument("--scheduler", metavar="ADDRESS", help="Dask scheduler address")
        p.add_argument("--interval", choices=["symmetric", "shortest"], default="symmetric",
                       help="coverage interval (default: probabilistically symmetric)")


class ArgumentParser(argparse.ArgumentParser):
    """argparse that raises UsageError (one line, exit 2) instead of exiting."""

    def error(self, message):
        raise UsageError(message)
