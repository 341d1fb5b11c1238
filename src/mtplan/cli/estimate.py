"""``mtplan estimate``: measurands with their uncertainty from a measured readings file."""

from __future__ import annotations

import json
import math
import os
import sys
import warnings

from mtplan.cli._common import (
    UsageError,
    capped_trials,
    check_outputs,
    count,
    load_config,
    print_table,
    procedure_of,
    setup_values,
    trials_cap,
    workers,
    write_out,
)


def register(sub) -> None:
    """Add the ``estimate`` sub-command to the parser's sub-parsers `sub`."""
    p = sub.add_parser("estimate", help="measurands from measured readings, with uncertainty")
    p.add_argument("procedure", help="procedure name (see 'mtplan procedures')")
    p.add_argument("readings", metavar="READINGS.csv",
                   help="readings in the procedure's format ('mtplan simulate --readings-out')")
    p.add_argument("--config", metavar="FILE.toml", help="set-up file: [setup] table")
    p.add_argument("--set", action="append", metavar="FIELD=VALUE",
                   help="set-up field (repeatable); fields the readings determine (counts, "
                        "positions, angles, radius) need not be given, and must agree")
    p.add_argument("--along", action="append", metavar="AXIS=START:STOP:STEP",
                   help="also state the errors that are functions of position at these "
                        "positions along AXIS [mm], each a measurand with its uncertainty "
                        "(geometry21: --along X=-50:50:5; repeatable; for a compensation table)")
    p.add_argument("--estimator", metavar="NAME",
                   help="estimator (default: the best one that observes every measurand; the "
                        "patent's method by its name)")
    p.add_argument("--uncertainty", choices=["mc", "posterior"], default=None,
                   help="mc: Monte Carlo around the estimate (default); posterior: emcee")
    p.add_argument("--trials", type=count, metavar="N",
                   help="Monte Carlo trials (default: the first-order u and interval where a "
                        "Monte Carlo of 256 to 2048 trials validates them, else 10000 trials)")
    p.add_argument("--seed", type=int, metavar="S", help="random seed (default 0)")
    p.add_argument("--jobs", type=workers, default=min(os.cpu_count() or 1, 4), metavar="J",
                   help="mc: parallel workers of the Monte Carlo (default: the machine's "
                        "cores, at most 4; the numbers do not depend on it)")
    p.add_argument("--coverage", type=float, default=0.95, metavar="P",
                   help="coverage probability (default 0.95)")
    p.add_argument("--noise", metavar="SIGMA|free|setup", default="setup",
                   help="posterior: the noise source's standard deviation in the readings' unit "
                        "(mm or rad), 'free' (estimated from the readings) or 'setup' (default: "
                        "the set-up's; every other error source always is)")
    p.add_argument("--max-steps", type=count, default=20000, metavar="N",
                   help="posterior: step budget per ensemble (default 20000)")
    p.add_argument("--max-seconds", type=float, metavar="S",
                   help="posterior: time budget of the sampling (default: none)")
    p.add_argument("--allow-unconverged", action="store_true",
                   help="posterior: report an unconverged posterior (flagged) instead of failing")
    p.add_argument("--fit-alpha", type=float, default=None, metavar="ALPHA",
                   help="significance level of the fit check, split between its chi-square "
                        "test (a fifth) and the largest |w| (four fifths, Bonferroni over the "
                        "readings): the readings do not fit the model when either fails "
                        "(default 0.05)")
    p.add_argument("--json", action="store_true", help="print one JSON document on stdout")
    p.add_argument("--out", metavar="FILE", help="also write the table to FILE (CSV)")
    p.set_defaults(func=cmd_estimate, truth=None)


def cmd_estimate(args) -> int:
    """Read the readings, estimate, print; exit status 2 with one line on bad input."""
    from mtplan.evaluation.fitcheck import FIT_ALPHA
    from mtplan.evaluation.measured import FULL_TRIALS, MeasuredOptions, estimate_measured, \
        read_measurement
    from mtplan.evaluation.posterior import NotConvergedError, PosteriorOptions, \
        UnconvergedWarning

    check_outputs(out=args.out)
    noise = _noise(args.noise)
    if args.max_seconds is not None and not args.max_seconds > 0:
        raise UsageError(f"--max-seconds must be a number > 0, got {args.max_seconds!r}")
    fit_alpha = FIT_ALPHA if args.fit_alpha is None else args.fit_alpha
    if not 0 < fit_alpha < 1:
        raise UsageError(f"--fit-alpha must be a number between 0 and 1, got {fit_alpha!r}")
    config = load_config(args.config)
    proc = procedure_of(args, config)
    if config.get("truth"):
        raise UsageError(f"--config {args.config}: [truth] is for simulations; estimate takes "
                         "the truth from the readings")
    measurement = read_measurement(proc, args.readings, setup_values(args, config, proc))
    method = args.uncertainty or config.get("uncertainty", "mc")
    if method not in ("mc", "posterior"):
        raise UsageError(f"--uncertainty must be mc or posterior, got {method!r}")
    # no count stated: first order where a short Monte Carlo validates it (the library's
    # default); under MTPLAN_MAX_TRIALS a Monte Carlo of at most that many trials
    trials = capped_trials(args.trials if args.trials is not None else config.get("trials"),
                           None if trials_cap() is None else FULL_TRIALS)
    seed = args.seed if args.seed is not None else config.get("seed", 0)
    try:
        with warnings.catch_warnings():
            # --allow-unconverged: the result says NOT CONVERGED itself, no Python warning
            warnings.simplefilter("ignore", UnconvergedWarning)
            sampling = PosteriorOptions(noise=noise, max_seconds=args.max_seconds,
                                        allow_unconverged=args.allow_unconverged,
                                        max_steps=args.max_steps)
            options = MeasuredOptions(trials=trials, coverage=args.coverage, rng=seed,
                                      progress=None, n_jobs=args.jobs, fit_alpha=fit_alpha,
                                      origin=measurement.origin, posterior=sampling)
            result = estimate_measured(
                proc, None, measurement, estimator=args.estimator or config.get("estimator"),
                uncertainty=method, options=options)
    except NotConvergedError as exc:
        print(f"mtplan: error: {exc}", file=sys.stderr)
        return 1
    if args.out:
        write_out(args.out, result.summary().to_csv())
    if args.json:
        print(json.dumps(result.to_dict(), indent=1))
        return 0
    _print_result(result, args.readings)
    return 0


def _noise(text):
    """--noise: 'setup', 'free' or a standard deviation > 0."""
    if text in ("setup", "free"):
        return text
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not value > 0 or not math.isfinite(value):
        raise UsageError(f"--noise must be a number > 0, 'free' or 'setup', got {text!r}")
    return value


def _print_result(result, source) -> None:
    """The table of :meth:`MeasuredResult.to_dict` (value, u, interval; the estimate and its
    correction as provenance), the not-determinable rows' reasons, the posterior's state and
    the notes."""
    from mtplan.reports.labels import fmt

    doc = result.to_dict()
    method = doc["uncertainty"]
    print(f"{doc['procedure']} ({doc['estimator']}) from {source}: {method} uncertainty, "
          f"{100 * result.coverage:g} % intervals, seed {doc['seed']}")
    rows = []
    for m in doc["measurands"]:
        u, est = m["u"], m["estimate"]
        if not m["determinable"]:
            rows.append([m["name"], m["unit"], "not determinable", "-", "-",
                         "-" if est is None else fmt(est, abs(est) * 1e-3 or 1.0), "-", "-"])
            continue
        mc = method == "mc"
        corr = fmt(m["bias_correction"], m["bias_correction_u"] or u) if mc else "-"
        u_corr = f"{m['bias_correction_u']:.2g}" if mc else "-"
        rows.append([m["name"], m["unit"], fmt(m["value"], u), f"{u:.2g}",
                     f"[{fmt(m['interval'][0], u)}, {fmt(m['interval'][1], u)}]",
                     fmt(est, u), corr, u_corr])
    print_table(["measurand", "unit", "value", "u", "interval", "estimate", "correction",
                 "u(correction)"], rows)
    for m in doc["measurands"]:
        if m["reason"]:
            print(f"{m['name']}: {m['reason']}")
    if result.fit is not None:  # the worst reading and its row, passed or not
        print(result.fit.warning() or result.fit.summary())
    if method == "posterior":
        post = result.details
        print(f"posterior: {post.chains.shape[0]} ensembles x {post.n_walkers} walkers x "
              f"{post.n_steps} steps, max tau {max(post.tau.values()):.1f}, max R-hat "
              f"{max(post.rhat.values()):.4f}, min ESS {min(post.ess.values()):.0f}, "
              f"{'converged' if post.converged else 'NOT CONVERGED'}, {post.wall_s:.1f} s")
        print("error sources: " + "; ".join(f"{k}: {', '.join(v)}"
                                            for k, v in doc["source_kinds"].items()))
    for note in doc["notes"]:
        print(f"note: {note}", file=sys.stderr)
