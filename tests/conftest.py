"""Suite-wide settings.

Hypothesis runs derandomized (a fixed seed per test, no example database), like every other
stochastic test here: the same commit gives the same verdict on every machine, CI included.
Set ``HYPOTHESIS_PROFILE=explore`` to search with fresh random examples instead.
"""

import os

import pytest
from hypothesis import settings

settings.register_profile("mtplan", derandomize=True, database=None, print_blob=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "mtplan"))


# --- scheduling on the workers (`make test`: pytest -n 2 --dist loadfile) --------------------
#
# Each file is one unit of work, as --dist loadfile makes it, except the files below, whose
# tests share no expensive fixture and are split: one unit per test (SPLIT), or per procedure
# where the tests of one procedure share its module-scoped posterior (BY_PROCEDURE); the tests
# of several files that estimate one heavy procedure's example readings are one unit
# (EXAMPLE_READINGS), so that its cached least-squares start is computed once. The units
# start longest first (the ranking of a --durations profile), so that no long unit is left for
# the end while the other worker idles; the demo the report tests share starts at once.
# (pytest-xdist's own loadgroup cannot do this under pytest 9: its xdist_group marks no longer
# reach the scheduler, so the units are made here, from the test ids.)
SPLIT = {
    "tests/evaluation/test_no_zero_uncertainty.py",
    "tests/evaluation/test_readings.py",
    "tests/evaluation/test_measured.py",
    "tests/test_cli_schema.py",
    "tests/plans/test_accept_cli.py",
    "tests/models/test_line_laser.py",
}
BY_PROCEDURE = {"tests/evaluation/test_posterior_procedures.py"}
#: files whose tests of one procedure estimate its shipped example readings: those of one heavy
#: procedure are one unit, so that they run in one process and share the readings' least-squares
#: start and the estimator's gain, computed on the first estimate and cached (line_laser's first
#: estimate takes 14 s of CPU, the next ones 1-4 s; geometry21 and tracker_frame some seconds)
EXAMPLE_READINGS = {
    "tests/evaluation/test_posterior_procedures.py",
    "tests/evaluation/test_readings.py",
    "tests/evaluation/test_no_zero_uncertainty.py",
    "tests/test_cli_schema.py",
}
SHARED_START = ("line_laser", "geometry21", "tracker_frame")
#: units that start first, longest first: (file, text in the test's name or ""), from the
#: --durations of each file run alone (seconds of CPU, the imports left out). The demo (about
#: 100 s, two processes) starts at once on one worker, line_laser's example readings (50 s) on
#: the other, which then takes the documented commands (about 70 s over the two processes it
#: forks: they inherit line_laser's cached start, which `mtplan estimate line_laser` needs);
#: every other unit is 30 s or less, so the two workers end within the last small units of
#: each other.
LONGEST_FIRST = [
    ("tests/reports/test_certificate.py", "demo"),  # builds the demo test_report.py reads
    ("tests/reports/test_certificate.py", ""),
    ("tests/evaluation/test_posterior_procedures.py", "line_laser"),  # its example readings: 50 s
    ("tests/test_documented_commands.py", ""),
    ("tests/evaluation/test_posterior_procedures.py", "geometry21"),  # its example readings: 30 s
    ("tests/explore/test_explore_browser.py", ""),  # 22 s
    ("tests/evaluation/test_posterior_procedures.py", "tracker_frame"),  # 20 s
    ("tests/plans/test_accept_cli.py", "optimize"),  # 12 s
    ("tests/evaluation/test_posterior.py", ""),  # 11 s
    ("tests/evaluation/test_measured.py", "line_laser"),  # 9 s
    ("tests/models/test_tracker_frame.py", ""),  # 8 s
    ("tests/models/test_line_laser.py", "small_setup"),  # 7 s
    ("tests/test_cli_fuzz.py", ""),  # 7 s
    ("tests/reference/test_ggs_circle.py", ""),  # 7 s
    ("tests/evaluation/test_readings.py", ""),  # 6 s (the published points, 2000 trials), 4 s
    ("tests/models/test_line_laser.py", "pattern"),  # 5 s each (five poses)
    ("tests/evaluation/test_measured.py", "geometry21"),  # 5 s
    ("tests/models/test_geometry21.py", ""),  # 5 s
]


def unit_of_work(nodeid: str) -> str:
    """The unit of work a test belongs to: its file, its own id or its procedure."""
    path = nodeid.split("::")[0]
    if path in EXAMPLE_READINGS:
        proc = next((p for p in SHARED_START if p in nodeid.split("::", 1)[-1]), None)
        if proc is not None:
            return f"the example readings of {proc}"
    if path in SPLIT:
        return nodeid
    if path in BY_PROCEDURE and nodeid.endswith("]"):
        return f"{path}[{nodeid.rsplit('[', 1)[1]}"
    return path


def pytest_configure(config):
    """With workers (``-n``), each computes on one core, its BLAS too: set before the
    workers start, so that they load their BLAS libraries with one thread. (Two workers with
    two BLAS threads each on two cores: a thread that waits for the core the other worker
    holds spins; the suite ran 4 % longer.) An explicit setting in the environment wins."""
    if getattr(config.option, "numprocesses", None) and not os.environ.get("PYTEST_XDIST_WORKER"):
        for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(name, "1")
    # every process of the suite (workers, pools, the commands it runs) with the allocator
    # settings `mtplan` takes (mtplan._parallel.keep_freed_memory): set before they start
    from mtplan._parallel import MALLOC_SETTINGS

    for name, value in MALLOC_SETTINGS.items():
        os.environ.setdefault(name, str(value))


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """The units of work longest first (the same order on every worker)."""
    root = config.rootpath
    ranked = []
    for index, item in enumerate(items):
        path = item.path.relative_to(root).as_posix()
        rank = next((i for i, (file, text) in enumerate(LONGEST_FIRST)
                     if path == file and text in item.name), len(LONGEST_FIRST))
        ranked.append((rank, index, item))
    items[:] = [item for _, _, item in sorted(ranked, key=lambda r: r[:2])]


def pytest_xdist_make_scheduler(config, log):
    """--dist loadfile with the units above, taken in the order collected."""
    if config.getvalue("dist") != "loadfile":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class Units(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return unit_of_work(nodeid)

    config.option.loadscopereorder = False  # keep the longest-first order
    return Units(config, log)
