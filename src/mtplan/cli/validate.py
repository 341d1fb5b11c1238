"""``mtplan validate``: measured results against calibrated references (E_n numbers)."""

from __future__ import annotations

import json

from mtplan.cli._common import UsageError, check_outputs, print_table


def register(sub) -> None:
    """Add the ``validate`` sub-command to the parser's sub-parsers `sub`."""
    p = sub.add_parser(
        "validate", help="measured results against reference values: E_n, coverage, verdict",
        description="Compare 'mtplan estimate --json' results with calibrated reference values: "
                    "E_n = (y - y_ref) / sqrt(U^2 + U_ref^2) with U from each result's own "
                    "coverage interval, the share with |E_n| <= 1 against that coverage, and "
                    "the generalised chi-square of the comparisons with their covariance "
                    "(shared reference values, correlated measurands); a verdict: consistent, "
                    "uncertainty too small or too large, each at 95 %% confidence. See "
                    "docs/validate.md.")
    p.add_argument("files", nargs="+", metavar="FILE",
                   help="RESULTS.json ... (estimate --json outputs), then REFERENCES.csv unless "
                        "--references is given")
    p.add_argument("--references", metavar="REFS.csv",
                   help="reference values: columns procedure, measurand, value, U (k = 2), unit "
                        "and optionally result (the results file's name without .json; without "
                        "it the value is shared by every result of the procedure)")
    p.add_argument("--common", type=float, default=0.0, metavar="F",
                   help="share (0 to 1) of each result's u² that the results have in common: "
                        "repeated tests with one sensor, set-up or machine (default 0: "
                        "independent results); see docs/validate.md")
    p.add_argument("--figure", metavar="FILE.png", help="write the E_n figure (PNG)")
    p.add_argument("--json", action="store_true", help="print one JSON document on stdout")
    p.set_defaults(func=cmd_validate)


def cmd_validate(args) -> int:
    """Read, compare, print; exit status 2 with one line on bad input."""
    from mtplan._io import atomic_write
    from mtplan.evaluation.validation import (read_references, read_results, validate,
                                              validation_figure)

    check_outputs(figure=args.figure)
    if not 0.0 <= args.common <= 1.0:
        raise UsageError(f"--common must be a share from 0 to 1 of the results' u² they have "
                         f"in common, got {args.common!r}")
    files = list(args.files)
    refs = args.references
    if refs is None:
        if len(files) < 2 or not files[-1].lower().endswith(".csv"):
            raise UsageError("validate needs RESULTS.json ... and the references: a last "
                             "REFERENCES.csv or --references REFS.csv")
        refs = files.pop()
    v = validate(read_results(files), read_references(refs), common=args.common)
    if args.figure:
        with atomic_write(args.figure, "wb") as fh:
            fh.write(validation_figure(v))
    if args.json:
        print(json.dumps(v.to_dict(), indent=1))
        return 0
    rows = [[c.result, f"{c.procedure} {c.measurand}", c.unit, f"{c.value:.4g}",
             f"{c.U:.2g} ({100 * c.coverage:.4g} %)", f"{c.reference:.4g}",
             f"{c.U_reference:.2g}", f"{c.en:+.2f}"] for c in v.comparisons]
    print_table(["result", "measurand", "unit", "value", "U (its interval)", "reference",
                 "U_ref (k=2)", "E_n"], rows)
    print()
    for name, g in [*v.by_measurand.items(), ("all", v.overall)]:
        print(f"{name}: {g.text()}")
    print(f"verdict: {v.overall.verdict}")
    for note in v.notes:
        print(f"note: {note}")
    return 0
