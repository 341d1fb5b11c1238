"""The ``mtplan`` command: parses, calls the library, prints.

Thin by design: every number comes from the library, which a Python user can
call directly. One module per command (:data:`COMMANDS`), each with a
``register(subparsers)`` that adds its parser; what they share is in
:mod:`mtplan.cli._common`, which imports none of them. A user's mistake (unknown
field, bad value, missing file) exits with status 2 and one line on stderr, never
a traceback; a reader that leaves early (``| head``) ends the command quietly with status
141. Every number a command prints comes from the library's result object (its ``to_dict``
is the ``--json`` document, its ``summary`` the ``--out`` CSV). Imports: the standard
library at module level; the library (numpy and above) inside the commands, so that
``mtplan --help`` and a usage error start fast.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from mtplan.cli._common import EXIT_USAGE, ArgumentParser, UsageError

__all__ = ["main", "build_parser", "COMMANDS"]

#: The command modules, in the order ``mtplan --help`` lists them.
COMMANDS = ("procedures", "simulate", "linearize", "sweep", "estimate", "plan", "accept",
            "report", "validate", "compensate", "explore")


def build_parser() -> argparse.ArgumentParser:
    from mtplan import __version__

    parser = ArgumentParser(
        prog="mtplan",
        description="Monte Carlo uncertainty and test-plan designer for machine-tool metrology.",
        epilog="Lengths in um, angles in urad on output; 'mtplan COMMAND --help' for details.",
    )
    parser.add_argument("--version", action="version", version=f"mtplan {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=ArgumentParser)

    for module in COMMANDS:
        importlib.import_module(f"mtplan.cli.{module}").register(sub)
    return parser


def _one_line(text: str) -> str:
    """A message on one line: control characters a user typed (or a file held) escaped."""
    return "".join(c if c.isprintable() or c == " " else repr(c)[1:-1] for c in str(text))


def _error(text: str) -> None:
    print("mtplan: error: " + _one_line(text), file=sys.stderr)


#: exit status when the reader of stdout left (128 + SIGPIPE, as a shell reports it)
EXIT_PIPE = 141


def _silence_stdout() -> None:
    """Point stdout at the null device, so that the interpreter's last flush of a closed
    pipe raises nothing either."""
    import os

    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # a replaced stdout (tests): nothing to do
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
    finally:
        os.close(devnull)


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
        _error(str(exc))
        return EXIT_USAGE
    except InvalidInput as exc:
        _error(" ".join(exc.problems))
        return EXIT_USAGE
    except FileNotFoundError as exc:
        _error(f"no such file {exc.filename!r}")
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("mtplan: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader left (| head): stop quietly, as a shell tool does
        _silence_stdout()
        return EXIT_PIPE
    except Exception as exc:  # a model that cannot be evaluated: one line, status 1
        from mtplan.uncertainty.montecarlo import ModelError

        if isinstance(exc, ModelError):
            _error(str(exc))
            return 1
        raise


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
