"""``mtplan report`` and ``mtplan demo``: a study computed and written as HTML and PDF."""

from __future__ import annotations

import datetime
import os
import sys
import time
from pathlib import Path

from mtplan.cli._common import workers


def register(sub) -> None:
    p = sub.add_parser("report", help="test plan and test report (HTML and PDF) of a study")
    p.add_argument("study", metavar="STUDY.toml", help="the study file")
    p.add_argument("--out", metavar="DIR", required=True, help="output folder")
    p.add_argument("--jobs", type=workers, default=1, metavar="J", help="parallel workers")
    p.add_argument("--cache", metavar="DIR", default=None,
                   help="reuse the study's result stored in DIR by an earlier run of the same "
                        "study, readings, mtplan code and numeric packages (default: none)")
    how = p.add_mutually_exclusive_group()
    how.add_argument("--plan-only", action="store_true",
                     help="issue the test plan only (plan.pdf, plan.html, plan.json), before "
                          "measuring: the readings are not used")
    how.add_argument("--plan", metavar="PLAN.json",
                     help="the agreed plan (plan.json of --plan-only): the study must state "
                          "exactly its rules; writes the test report decided with them")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("demo", help="the built-in study, end to end")
    p.add_argument("--out", metavar="DIR", default="mtplan-report", help="output folder")
    p.add_argument("--jobs", type=workers, default=min(os.cpu_count() or 1, 4), metavar="J",
                   help="parallel workers (default: the machine's cores, at most 4)")
    cache = p.add_mutually_exclusive_group()
    cache.add_argument("--cache", metavar="DIR", default=None,
                       help="where the study's result is kept for the next run of the same "
                            "study, readings, mtplan code and numeric packages (default: "
                            "$XDG_CACHE_HOME/mtplan or ~/.cache/mtplan)")
    cache.add_argument("--no-cache", action="store_true",
                       help="compute the study anew and store nothing")
    p.set_defaults(func=cmd_demo)


def _report(study_path, out, jobs, progress, command, plan_path=None, plan_only=False,
            cache=None):
    from mtplan._io import output_problem
    from mtplan.cli._common import UsageError
    from mtplan.plans import agreement
    from mtplan.plans.study import load_study, run_study_cached
    from mtplan.reports import write_report
    from mtplan.reports.certificate import PLAN_PARTS

    problem = output_problem(out, folder=True)
    if problem:
        raise UsageError(f"--out: {problem}")
    start = time.perf_counter()
    study = load_study(study_path)
    plan = None
    if plan_path is not None:  # refused before anything is computed
        agreement.require_dates(study)
        plan = agreement.read_plan(plan_path)
        agreement.check_study(study, plan)
        agreement.check_dates(study, plan)
    elif plan_only or study.header.get("plan_date"):  # the plan of this run, dated
        agreement.check_dates(study, {"issued": study.header.get("plan_date")
                                      or datetime.date.today().isoformat(),
                                      "document": study.header.get("plan_document", "")})
    # with workers and both documents to write, each test's figures of the plan are drawn
    # as soon as the test is complete, beside the other tests' stages
    early = PLAN_PARTS if jobs != 1 and plan is None and not plan_only else None
    result = run_study_cached(study, cache, progress=progress, n_jobs=jobs, command=command,
                              readings=not plan_only, then=early)
    computed = time.perf_counter()
    written = write_report(result, out, plan, plan_only=plan_only, n_jobs=jobs)
    end = time.perf_counter()
    how = "read from the cache" if "cached" in result.provenance else "computed"
    print(f"written in {end - start:.1f} s (study {computed - start:.1f} s, {how}; documents "
          f"{end - computed:.1f} s, {jobs} workers):", file=sys.stderr)
    for key in ("plan_pdf", "plan_html", "plan_json", "report_pdf", "report_html"):
        if key in written:
            print(written[key])
    return 0


def _command(*words) -> str:
    """The command line as a shell would take it again from the working folder (for the
    provenance): an absolute path relative to that folder, or by its name where it lies
    outside it, so that the documents name no local folders."""
    import shlex

    def shown(word) -> str:
        text = str(word)
        if not os.path.isabs(text):
            return text
        try:
            relative = os.path.relpath(text)
        except ValueError:  # another drive
            return Path(text).name
        return Path(text).name if relative.startswith("..") else relative

    return shlex.join(["mtplan", *(shown(w) for w in words)])


def cmd_report(args):
    extra = ["--plan-only"] if args.plan_only else (["--plan", args.plan] if args.plan else [])
    command = _command("report", args.study, "--out", args.out, "--jobs", args.jobs, *extra)
    return _report(args.study, args.out, args.jobs, progress=None, command=command,
                   plan_path=args.plan, plan_only=args.plan_only, cache=args.cache)


def demo_study_path():
    """The built-in study shipped with mtplan (``examples/demo.toml``)."""
    return Path(__file__).resolve().parent.parent / "examples" / "demo.toml"


def default_cache_dir() -> Path:
    """Where ``mtplan demo`` keeps the study's result: ``$XDG_CACHE_HOME/mtplan``, else
    ``~/.cache/mtplan``."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "mtplan"


def cmd_demo(args):
    """Run the default study end to end: the test plan issued, then the test report decided
    with it (both from this one run; the report says so among its deviations). The study's
    result is kept in the cache folder and reused while the study, its readings, mtplan's
    code and the numeric packages stay the same."""
    command = _command("demo", "--out", args.out, "--jobs", args.jobs)
    cache = None if args.no_cache else (args.cache or default_cache_dir())
    return _report(demo_study_path(), args.out, args.jobs, progress=True, command=command,
                   cache=cache)
