"""``mtplan compensate``: the correction a controller takes, from a measured result."""

from __future__ import annotations

from mtplan.cli._common import UsageError, parse_pairs


def register(sub) -> None:
    """Add the ``compensate`` sub-command to the parser's sub-parsers `sub`."""
    p = sub.add_parser(
        "compensate", help="corrections for the controller from a measured result, with U "
                           "and the predicted residual",
        description="Write the correction that the procedure's users apply (a rotary axis's "
                    "location errors, a work offset, a sensor's rotation, ...) from an "
                    "'mtplan estimate --json' result: each value with its U (k = 2), its "
                    "sign convention and the residual predicted after compensation, as the "
                    "neutral table (CSV and JSON) and, with --format, a controller's format. "
                    "See docs/compensation.md.")
    p.add_argument("result", nargs="?", metavar="RESULT.json",
                   help="an 'mtplan estimate --json' output")
    p.add_argument("--format", default="neutral", metavar="NAME",
                   help="the format to write besides the neutral table (default: neutral "
                        "only); 'mtplan compensate --list' names them")
    p.add_argument("--option", action="append", default=[], metavar="NAME=VALUE",
                   help="an option of the format (e.g. offset=2 for fanuc-g10); repeatable")
    p.add_argument("--out", default="compensation", metavar="FOLDER",
                   help="folder to write into (default: compensation)")
    p.add_argument("--json", action="store_true",
                   help="print the neutral table's JSON document on stdout (the files are "
                        "written all the same)")
    p.add_argument("--list", action="store_true",
                   help="list the formats, what each holds and its source, and exit")
    p.set_defaults(func=cmd_compensate)


def cmd_compensate(args) -> int:
    """Read the result, build the correction, write every file or none."""
    from mtplan._io import atomic_write_text, output_problem
    from mtplan.compensation import available_formats, compensate

    if args.list:
        for fmt in available_formats().values():
            print(f"{fmt.name}: {fmt.title} (holds: {', '.join(fmt.kinds)}; after {fmt.source})")
        return 0
    if args.result is None:
        raise UsageError("compensate needs RESULT.json (an 'mtplan estimate --json' output), "
                         "or --list")
    problem = output_problem(args.out, folder=True)
    if problem:
        raise UsageError(f"--out: {problem}")
    options = parse_pairs(args.option, "--option")
    files, correction, res = compensate(args.result, args.format, options)
    for name, text in files.items():  # all rendered before any is written
        atomic_write_text(f"{args.out}/{name}", text)
    if args.json:
        print(files["correction.json"], end="")
        return 0
    width = max(len(n) for n in correction.names)
    print(f"{correction.procedure}: {correction.kind} correction ({correction.sign})")
    for n, unit, v, U, lo, hi in zip(correction.names, correction.units, correction.value,
                                     correction.U, res.low, res.high):
        print(f"  {n:<{width}}  {v:+10.4g} {unit:<4}  U {U:<8.3g}  residual after it (95 %): "
              f"{lo:+.3g} to {hi:+.3g} {unit}")
    print("wrote " + ", ".join(f"{args.out}/{name}" for name in files))
    return 0
