"""``mtplan report`` and ``mtplan demo``: a study computed and written as HTML and PDF."""

from __future__ import annotations

import sys
import time
from pathlib import Path


def register(sub) -> None:
    p = sub.add_parser("report", help="HTML and PDF report of a study")
    p.add_argument("study", metavar="STUDY.toml", help="the study file")
    p.add_argument("--out", metavar="DIR", required=True, help="output folder")
    p.add_argument("--jobs", type=int, default=1, metavar="J", help="parallel workers")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("demo", help="the built-in study, end to end")
    p.add_argument("--out", metavar="DIR", default="mtplan-report", help="output folder")
    p.add_argument("--jobs", type=int, default=1, metavar="J", help="parallel workers")
    p.set_defaults(func=cmd_demo)


def _report(study_path, out, jobs, progress, command):
    from mtplan._io import output_problem
    from mtplan.cli._common import UsageError
    from mtplan.plans.study import load_study, run_study
    from mtplan.reports import write_report

    problem = output_problem(out, folder=True)
    if problem:
        raise UsageError(f"--out: {problem}")
    start = time.perf_counter()
    study = load_study(study_path)
    result = run_study(study, progress=progress, n_jobs=jobs, command=command)
    written = write_report(result, out)
    print(f"report written in {time.perf_counter() - start:.1f} s:", file=sys.stderr)
    print(written["html"])
    print(written["pdf"])
    return 0


def _command(*words) -> str:
    """The command line as a shell would take it again (for the provenance)."""
    import shlex

    return shlex.join(["mtplan", *(str(w) for w in words)])


def cmd_report(args):
    command = _command("report", args.study, "--out", args.out, "--jobs", args.jobs)
    return _report(args.study, args.out, args.jobs, progress=None, command=command)


def demo_study_path():
    """The built-in study shipped with mtplan (``examples/demo.toml``)."""
    return Path(__file__).resolve().parent.parent / "examples" / "demo.toml"


def cmd_demo(args):
    """Run the default study end to end and say where the report is."""
    command = _command("demo", "--out", args.out, "--jobs", args.jobs)
    return _report(demo_study_path(), args.out, args.jobs, progress=True, command=command)
