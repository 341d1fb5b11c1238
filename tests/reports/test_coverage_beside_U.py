"""The coverage printed beside every U of the demo is the Monte Carlo's coverage of ± U.

The demo (conftest's ``demo_report``, rendered once for the whole run) prints in each
test's section of the plan a table of every measurand's U with "±U covers": the fraction of
the set-up's Monte Carlo values within ± U, which ``results/PROC_k_uncertainty.csv`` holds
(``U_coverage``, its standard error ``U_coverage_se`` and the ``trials`` it rests on), and
the report the coverage of every measured U (``results/measured.csv``). For every demo
measurand:

- the printed coverage is the CSV's, to its printed 0.1 %;
- it is counted to :data:`~mtplan.uncertainty.coverage.RESOLUTION` (0.3 %) or better, so it
  is within 1 % of the Monte Carlo's coverage of that ± U with 99.9 % confidence: a plain
  count where the demo runs 10**4 trials or more, else with the first-order model as the
  count's control variate (geometry21's 400 trials: the estimators are linear to 1e-3 of u;
  line_laser's pattern fit, 14 % of u off first order, from 2500 trials);
- a Monte Carlo from another seed, its coverage of the printed value ± U counted the same
  way, agrees with it within four standard errors of the two and the printed rounding.

``benchmarks/bench_coverage_demo.py`` counts the same intervals plainly in 10**5 trials of
each test's set-up (not in the suite: minutes).
"""

from __future__ import annotations

import math
import re
import subprocess

import pandas as pd
import pytest

from tests.reports.conftest import need

#: the independent Monte Carlo's trials, at most (seconds per procedure)
MAX_TRIALS = 1_000
_NUM = r"-?\d+(?:\.\d+)?"


def _printed_tables(folder) -> list:
    """[(estimator, trials, {measurand: printed coverage [%]})], one per test, from the plan's
    tables "Results with the E estimator: U of the study's set-up (...)"."""
    need("pdftotext")
    text = subprocess.run(["pdftotext", "-layout", str(folder / "plan.pdf"), "-"], check=True,
                          capture_output=True, text=True).stdout
    head = re.compile(r"Results with the (\w+) estimator: U of the study's set-up "
                      r"\((?:adaptive Monte Carlo, )?(\d+)(?: Monte Carlo)? trials")
    row = re.compile(rf"^\s*(\w+) \[[^\]]+\]\s.*?\s({_NUM})\s+({_NUM}) %\s*$")
    out = []
    for m in head.finditer(text):
        printed = {}
        for line in text[m.end():].splitlines()[2:]:
            found = row.match(line)
            if found is None:
                if printed:
                    break
                continue
            printed[found[1]] = float(found[3])
        out.append((m[1], int(m[2]), printed))
    return out


@pytest.fixture(scope="module")
def demo_tests(demo_report):
    """The demo study and per test: (its procedure's study, the recommended estimator, the
    plan's printed coverages, the estimator's rows of the uncertainty CSV)."""
    from mtplan.cli.report import demo_study_path
    from mtplan.plans.study import load_study

    folder, _ = demo_report
    study = load_study(demo_study_path())
    tables = _printed_tables(folder)
    assert len(tables) == len(study.procedures)
    out = []
    for k, (ps, (est, trials, printed)) in enumerate(zip(study.procedures, tables, strict=True),
                                                     start=1):
        csv = pd.read_csv(folder / "results" / f"{ps.name}_{k}_uncertainty.csv")
        csv = csv[csv["estimator"] == est].set_index("measurand")
        assert (csv["trials"] == trials).all(), (ps.name, trials)
        out.append((ps, est, printed, csv))
    return study, out


def test_every_U_is_printed_with_the_coverage_of_its_results(demo_tests):
    """The plan prints every determinable measurand's coverage, the CSV's to 0.1 %, from
    the Monte Carlo (not assumed), counted to RESOLUTION."""
    from mtplan.uncertainty.coverage import RESOLUTION

    _, tests = demo_tests
    for ps, _, printed, csv in tests:
        shown = csv[csv["u"] > 0]
        assert set(printed) == set(shown.index), ps.name
        assert (shown["U_coverage_from"] == "monte carlo").all()
        for name, p in shown["U_coverage"].items():
            assert printed[name] == pytest.approx(100 * p, abs=0.05 + 1e-9), (ps.name, name)
        assert (shown["U_coverage_se"] <= RESOLUTION + 1e-12).all(), (ps.name, shown)


def test_every_measured_U_is_printed_with_a_resolved_coverage(demo_report):
    """The report's measured U (results/measured.csv, as the certificate prints them): each
    determinable one with its coverage counted to RESOLUTION, from the Monte Carlo around
    the estimate or the posterior's samples."""
    from mtplan.uncertainty.coverage import RESOLUTION

    folder, _ = demo_report
    m = pd.read_csv(folder / "results" / "measured.csv")
    m = m[m["determinable"]]
    assert set(m["U_coverage_from"]) <= {"monte carlo", "posterior samples"}
    assert m["U_coverage"].between(0, 1).all()
    assert (m["U_coverage_se"] <= RESOLUTION + 1e-12).all(), \
        m.loc[m["U_coverage_se"] > RESOLUTION, ["procedure", "measurand", "U_coverage_se"]]


def test_an_independent_monte_carlo_agrees_within_its_error(demo_tests):
    """Another seed's coverage of the printed value ± U agrees with the printed one within
    four standard errors of the two (and the printing's 0.05 %)."""
    from mtplan.evaluation.simulation import simulate_uncertainty

    study, tests = demo_tests
    for ps, est, printed, csv in tests:
        trials = int(csv["trials"].iloc[0])
        r = simulate_uncertainty(ps.procedure, ps.setup, ps.truth, estimator=est,
                                 trials=min(trials, MAX_TRIALS), rng=study.seed + 1,
                                 progress=False)
        rows = csv.reindex([m.name for m in r.measurands])
        other, other_se = r.coverage_within(rows["value"].to_numpy(), rows["U"].to_numpy())
        for i, m in enumerate(r.measurands):
            if m.name not in printed:
                continue
            shown, se = printed[m.name] / 100, float(rows["U_coverage_se"].iloc[i])
            tol = 4.0 * math.hypot(se, other_se[i]) + 5e-4
            assert abs(shown - other[i]) <= tol, (ps.name, m.name, shown, other[i], tol)
