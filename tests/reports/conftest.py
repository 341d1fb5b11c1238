"""Shared fixtures: one small study computed once per session (seconds, not the demo)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

def need(*binaries: str) -> str:
    """The first of `binaries` on the PATH; skip the test where none is.

    Only the tests that look at the report through an outside viewer (poppler's pdftotext,
    pdftoppm, pdffonts, pdftohtml; headless Chromium) skip, with the reason and the package
    to install; CI installs both (.ci/run). What the issues ask of the PDF itself (embedded
    fonts, bookmarks) is also checked without them (test_document.py)."""
    for binary in binaries:
        if shutil.which(binary):
            return shutil.which(binary)
    pytest.skip(f"{' or '.join(binaries)} is not installed (Debian: apt-get install "
                "poppler-utils chromium): this check looks at the report through it")


EXAMPLES = Path(__file__).resolve().parents[2] / "src" / "mtplan" / "examples"

SMALL = f"""
title = "Small study <script>alert('title')</script>"
subtitle = "A & B <b>bold?</b>"
seed = 3
trials = 300
simulated = true
[laboratory]
name = "Lab <b>One</b>"
address = "1 Gauge Street, Metrotown"
[conditions]
temperature_min_c = 20.2
temperature_max_c = 20.8
machine_temperature_c = 21.0
part_temperature_c = 20.7
warm_up = "45 min axis cycling"
compensation = false
[requirements]
temperature_c = [19.5, 21.5]
compensation = false
adjustment = "the builder may adjust once"
retests = 1
[[instrument]]
name = "Touch probe"
serial = "TP-0042"
certificate = "CAL-2024-0815"
calibration_due = 2025-08-15
traceability = "PTB via DAkkS D-K-99999"
[header]
document = "DOC-<b>1</b>"
revision = "B"
plan_date = 2023-12-20
customer = "Customer & <i>Co</i>"
machine_serial = "SN-42"
date = 2024-01-02
ambient_temperature_c = 20.5
prepared_by = "P. Preparer"
checked_by = "C. Checker"
[[procedure]]
name = "circle_centre"
label = "Bore <script>alert(1)</script> & co"
time = "09:00-10:30"
standards = ["ISO 10360-5:2020"]
estimators = ["three_point", "kasa"]
notes = "Notes with <img src=x onerror=alert(2)>"
  [[procedure.sweep]]
  vary = {{ n_points = [3, 6] }}
  trials = 200
  estimators = ["kasa"]
  [procedure.plan]
  targets = {{ centre_x = 5.0 }}
  vary = {{ n_points = [3, 4, 6] }}
  estimator = "kasa"
  trials = 300
  [[procedure.acceptance]]          # the readings' centre_x (about 350 um) lies far outside
  measurand = "centre_x"
  lower = -20.0
  upper = 20.0
  prior = "normal:0,8"
  population_source = "bores of 12 earlier parts"
  rule = "guard:0.5"
  [[procedure.acceptance]]          # centre_y (about -200 um) lies well inside
  measurand = "centre_y"
  lower = -400.0
  upper = 400.0
  rule = "iso14253"
  [procedure.readings]
  file = "{(EXAMPLES / 'circle_centre_readings.csv').as_posix()}"
  uncertainty = "mc"
  trials = 300
"""


@pytest.fixture(scope="session")
def small_study_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("study") / "small.toml"
    path.write_text(SMALL, encoding="utf-8")
    return path


@pytest.fixture(scope="session")
def small_result(small_study_file):
    from mtplan.plans.study import load_study, run_study

    return run_study(load_study(small_study_file), progress=False,
                     command="mtplan report small.toml --out report")


@pytest.fixture(scope="session")
def small_report(small_result, tmp_path_factory) -> Path:
    """The plan and the report of the small study (plan.*, report.*, results/)."""
    from mtplan.reports import write_report

    out = tmp_path_factory.mktemp("report")
    write_report(small_result, out)
    return out


@pytest.fixture(scope="session")
def demo_report(tmp_path_factory):
    """`mtplan demo` run once for every test that looks at it: (folder, stdout).

    Once for the whole run, also with pytest-xdist: the first worker to get the lock builds
    the demo in the workers' common temporary folder, the others wait for it and read it."""
    import contextlib
    import fcntl
    import io

    from mtplan.cli import main

    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent  # shared by the workers of this run
    out, log = root / "demo-shared" / "demo", root / "demo-shared" / "stdout.txt"
    out.parent.mkdir(parents=True, exist_ok=True)
    with open(root / "demo-shared.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not log.exists():
                buf = io.StringIO()
                with contextlib.redirect_stdout(buf):
                    code = main(["demo", "--out", str(out), "--jobs", "2", "--no-cache"])
                assert code == 0
                log.write_text(buf.getvalue(), encoding="utf-8")
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    return out, log.read_text(encoding="utf-8")
