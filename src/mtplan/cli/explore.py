"""``mtplan explore``: the live set-up designer in the browser (optional extra)."""

from __future__ import annotations

INSTALL = "pip install 'mtplan[explore]'"


def register(sub) -> None:
    p = sub.add_parser("explore", help="live set-up designer in the browser (extra: explore)")
    p.add_argument("procedure", nargs="?", help="procedure to open (default rotary_axis)")
    p.add_argument("--config", metavar="FILE.toml",
                   help="start from a set-up file ([setup] table) or a study file")
    p.add_argument("--port", type=int, default=8050, metavar="P", help="port (default 8050)")
    p.add_argument("--no-browser", action="store_true", help="do not open a browser")
    p.set_defaults(func=cmd_explore)


def cmd_explore(args):
    from mtplan.cli._common import UsageError
    from mtplan.explore import missing_extra, serve

    missing = missing_extra()
    if missing:
        raise UsageError(f"explore needs the optional packages {', '.join(missing)}: {INSTALL}")
    if not 0 < args.port < 65536:
        raise UsageError(f"--port must be from 1 to 65535, got {args.port}")
    from mtplan.explore.state import normalise
    from mtplan.explore.studies import design_from_study
    from mtplan.models import get

    initial = {"procedure": get(args.procedure).name} if args.procedure else {}
    if args.config:
        try:
            with open(args.config, encoding="utf-8") as fh:
                text = fh.read()
        except OSError as exc:
            raise UsageError(f"--config: cannot read {args.config!r}: {exc.strerror}") from None
        initial = design_from_study(text, args.procedure)
    serve(normalise(initial), port=args.port, open_browser=not args.no_browser)
    return 0
