"""The demo's report draws geometry21's errors along the travel with their bands and the
residual after compensation, prints the residual beside each corrected toleranced
measurand, and writes both to results/measured.csv (the demo is built once per run:
conftest's ``demo_report``)."""

from __future__ import annotations

import math
import subprocess

import numpy as np
import pandas as pd

from tests.reports.conftest import need


def test_the_demo_report_draws_the_errors_along_the_travel(demo_report):
    folder, _ = demo_report
    html = (folder / "report.html").read_text(encoding="utf-8")
    assert "Errors along the travel and after compensation (predicted)" in html
    assert "Test 2: errors along the travel (blue: measured, pointwise and simultaneous" in html
    assert "after compensation (predicted)</th>" in html.replace("\n", "")
    need("pdftotext")
    text = " ".join(subprocess.run(["pdftotext", str(folder / "report.pdf"), "-"], check=True,
                                   capture_output=True, text=True).stdout.split())
    assert "Errors along the travel and after compensation (predicted)" in text
    assert "The 240 values of the errors along the travel" in text


def test_measured_csv_holds_the_bands_and_the_residual(demo_report):
    folder, _ = demo_report
    m = pd.read_csv(folder / "results" / "measured.csv").set_index("measurand")
    g = m[m["procedure"] == "geometry21"]
    points = g[g.index.str.contains("@")]
    assert len(points) == 240  # 12 determined functions, 20 positions each (0 left out)
    assert (points["simultaneous_low"] < points["low"]).all()
    assert (points["simultaneous_high"] > points["high"]).all()
    assert g.loc[["EXX", "EC0Y"], "simultaneous_low"].isna().all()  # no curve
    # EXX (at +50 mm) is its table's point there: the same residual
    np.testing.assert_array_equal(
        g.loc["EXX", ["after_compensation_low", "after_compensation_high"]].to_numpy(float),
        g.loc["EXX@50", ["after_compensation_low", "after_compensation_high"]].to_numpy(float))
    lo, hi = g.loc["EXX", ["after_compensation_low", "after_compensation_high"]]
    # what the test cannot see (0.3 um short-wave and 0.3 um medium-wave) less what the
    # estimate took up of it: at the travel's end narrower than the quadrature of u and the
    # unseen part (the polynomial follows the deviation there)
    quadrature = 2 * 1.96 * math.hypot(g.loc["EXX", "u"], 0.3, 0.3)
    assert lo < 0 < hi and hi - lo < 0.8 * quadrature
    # every toleranced measurand of the demo has a correction, so a residual
    verdicts = pd.read_csv(folder / "results" / "verdicts.csv")
    for proc, name in zip(verdicts["procedure"], verdicts["measurand"], strict=True):
        row = m[(m["procedure"] == proc) & (m.index == name)]
        assert row["after_compensation_low"].notna().all(), (proc, name)
