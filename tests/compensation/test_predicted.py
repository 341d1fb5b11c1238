"""The machine after compensation as the documents show it: the residual the report prints
is the compensation package's, for the measurand a term corrects and for one the model
says is the same quantity (geometry21's EXX is its table's point at +50 mm); the residual's
simultaneous band over a table holds its pointwise band."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from mtplan import models
from mtplan.compensation import compensate
from mtplan.compensation.predicted import Predicted, predicted

EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "compensation"


def _doc(procedure: str) -> dict:
    return json.loads((EXAMPLES / f"{procedure}_result.json").read_text())


def test_printed_residual_is_the_compensation_packages():
    from mtplan.reports.along import residual_text
    from mtplan.reports.labels import fmt

    doc = _doc("geometry21")
    proc = models.get("geometry21")
    got = predicted(proc, doc)
    assert isinstance(got, Predicted)
    _files, corr, res = compensate(doc)
    for measurand, term in (("EXX@-30", "EXX@-30"), ("EXX", "EXX@50"), ("EC0Y", "EC0Y")):
        i = corr.names.index(term)
        assert got.of(measurand) == (res.low[i], res.high[i], res.units[i])
        m = next(m for m in doc["measurands"] if m["name"] == measurand)
        v = SimpleNamespace(measurand=measurand, measured_u=m["u"])
        U = 2 * m["u"]
        assert residual_text(SimpleNamespace(compensation=got), v) == \
            f"[{fmt(res.low[i], U)}, {fmt(res.high[i], U)}]"
    # the translations' residual holds what the test cannot see less what the estimate took
    # up of it: at the travel's end narrower than the measurement's own interval (the
    # polynomial follows the fields there), not the quadrature of the two
    m = next(m for m in doc["measurands"] if m["name"] == "EXX")
    lo, hi, _ = got.of("EXX")
    i = corr.names.index("EXX@50")
    assert hi - lo == pytest.approx(2 * 1.959963984540054 * math.sqrt(
        corr.covariance[i, i] + corr.unseen_covariance[i, i]))
    assert hi - lo < m["interval"][1] - m["interval"][0] < 2 * 1.96 * math.hypot(
        m["u"], corr.unseen_u[i])
    assert got.of("EAX") is None  # not determined: not corrected, no residual
    assert residual_text(SimpleNamespace(compensation="no correction"),
                         SimpleNamespace(measurand="EXX", measured_u=0.4)) == "-"


def test_residual_simultaneous_band_holds_the_pointwise_one():
    doc = _doc("geometry21")
    got = predicted(models.get("geometry21"), doc)
    names = got.correction.names
    table = [i for i, arg in enumerate(got.correction.arguments) if arg]
    assert set(got.simultaneous) == {names[i] for i in table}
    lo = np.array([got.simultaneous[names[i]][0] for i in table])
    hi = np.array([got.simultaneous[names[i]][1] for i in table])
    low, high = got.residual.low[table], got.residual.high[table]
    wide = high > low  # at the coordinates' zero every function is 0 by definition
    assert np.all(lo[wide] < low[wide]) and np.all(hi[wide] > high[wide])
    assert np.all(lo[~wide] == low[~wide]) and np.all(hi[~wide] == high[~wide])
    zero = np.array([got.correction.arguments[i][1] == 0 for i in table])
    np.testing.assert_array_equal(wide, ~zero)
    assert all(1.96 < c < 4 for c in got.factor.values())


@pytest.mark.parametrize("procedure", ["rotary_axis", "circle_centre", "tracker_frame",
                                       "line_laser"])
def test_every_procedures_toleranced_measurand_has_its_residual(procedure):
    doc = _doc(procedure)
    got = predicted(models.get(procedure), doc)
    assert isinstance(got, Predicted) and got.corrects
    for name, i in got.corrects.items():
        assert got.of(name) == (got.residual.low[i], got.residual.high[i],
                                got.residual.units[i])
    assert not got.simultaneous  # no table along an axis


def test_a_result_without_a_correction_says_why():
    doc = _doc("geometry21")
    doc = {**doc, "setup": {k: v for k, v in doc["setup"].items()
                            if not k.startswith("along_")}}
    why = predicted(models.get("geometry21"), doc)
    assert isinstance(why, str) and "--along" in why
