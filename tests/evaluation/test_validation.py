"""mtplan validate: measured results against calibrated references (E_n, generalised chi-square).

The statistical checks draw synthetic results (one seed each) and bound the count of
wrong verdicts by the binomial quantile of its nominal rate; the benchmark
``benchmarks/bench_validate.py`` measures the rates with more replicates."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mtplan._validate import InvalidInput
from mtplan.cli import main
from mtplan.evaluation.validation import (CONSISTENT, GENERALISED, LEVEL, SHARE_AND_DISPERSION,
                                          TOO_LARGE, TOO_SMALL, read_references, read_results,
                                          validate)

ROOT = Path(__file__).resolve().parents[2]
RESULTS = sorted((ROOT / "examples" / "validate_results").glob("*.json"))
REFS = ROOT / "examples" / "validate_references.csv"


def test_shipped_example_prints_the_en_table_and_verdict(tmp_path, capsys):
    assert len(RESULTS) >= 5
    figure = tmp_path / "en.png"
    assert main(["validate", *map(str, RESULTS), "--references", str(REFS),
                 "--figure", str(figure)]) == 0
    out = capsys.readouterr().out
    assert "E_n" in out and "ring_gauge_1" in out and "verdict: consistent" in out
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the positional form, and --json
    assert main(["validate", *map(str, RESULTS), str(REFS), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["overall"]["verdict"] == "consistent" and len(doc["comparisons"]) == 3 * len(RESULTS)
    row = doc["comparisons"][0]
    assert row["E_n"] == pytest.approx((row["value"] - row["reference"])
                                       / np.hypot(row["U"], row["U_reference_at_coverage"]))
    # U: the result's own interval on the side facing the reference, not 2 u
    m = json.loads(RESULTS[0].read_text())["measurands"][0]
    side = m["interval"][1] - m["value"] if row["reference"] > m["value"] else \
        m["value"] - m["interval"][0]
    assert row["U"] == pytest.approx(side) and row["coverage"] == m["coverage"]
    # one reference value for every ring gauge: the comparisons share its error
    assert doc["overall"]["method"] == GENERALISED
    assert "a shared reference value" in doc["overall"]["correlated_by"]
    print(out)  # the E_n table and the verdict, shown with pytest -s


def _scaled(tmp_path, factor):
    paths = []
    for p in RESULTS:
        doc = json.loads(p.read_text())
        for m in doc["measurands"]:
            m["u"] *= factor
            m["interval"] = [m["value"] + factor * (e - m["value"]) for e in m["interval"]]
        cov = doc.get("covariance")
        if cov:
            cov["matrix"] = (factor**2 * np.asarray(cov["matrix"])).tolist()
        out = tmp_path / p.name
        out.write_text(json.dumps(doc))
        paths.append(str(out))
    return paths


def test_halved_u_is_too_small_and_doubled_too_large(tmp_path, capsys):
    assert main(["validate", *_scaled(tmp_path, 0.5), str(REFS)]) == 0
    assert f"verdict: {TOO_SMALL}" in capsys.readouterr().out
    v = validate(read_results(_scaled(tmp_path, 3.0)), read_references(REFS))
    assert v.overall.verdict == TOO_LARGE


def test_bad_inputs_are_one_line_errors(tmp_path, capsys):
    bad = tmp_path / "refs.csv"
    bad.write_text("procedure,measurand,value,unit\ncircle_centre,radius,15,um\n")
    assert main(["validate", str(RESULTS[0]), str(bad)]) == 2
    assert "lacks the column(s) U" in capsys.readouterr().err
    bad.write_text("procedure,measurand,value,U,unit\ncircle_centre,radius,15,-1,um\n")
    with pytest.raises(InvalidInput, match="U must be a finite number >= 0"):
        read_references(bad)
    bad.write_text("procedure,measurand,value,U,unit\ncircle_centre,radius,15,0.5,mm\n")
    with pytest.raises(InvalidInput, match="state the reference in the result's unit"):
        validate(read_results(RESULTS[:1]), read_references(bad))
    assert main(["validate", str(RESULTS[0])]) == 2
    assert "REFERENCES.csv" in capsys.readouterr().err
    notjson = tmp_path / "x.json"
    notjson.write_text("{}")
    assert main(["validate", str(notjson), str(REFS)]) == 2


# ------------------------------------------------------------------ the example is the model's
DOC = ROOT / "docs" / "validate.md"


def _quoted(name):
    """The number the doc's section on the shipped example quotes as `name = <number>`
    (e.g. "u(radius) = 1.83 um")."""
    import re

    text = DOC.read_text(encoding="utf-8").split("## The shipped example", 1)[1]
    found = re.search(r"\b" + re.escape(name) + r" = (-?[0-9.]+[0-9])", text)
    assert found, f"docs/validate.md no longer quotes {name}"
    return found.group(1)


def test_the_docs_numbers_are_the_shipped_examples():
    """The numbers docs/validate.md quotes, to the digits it prints them with."""
    docs = [json.loads(p.read_text()) for p in RESULTS]
    u = {m["name"]: np.mean([[x["u"] for x in d["measurands"] if x["name"] == m["name"]][0]
                             for d in docs]) for m in docs[0]["measurands"]}
    for name, value in u.items():
        text = _quoted(f"u({name})")
        digits = len(text.split(".")[1]) if "." in text else 0
        assert float(text) == pytest.approx(value, abs=0.5 * 10**-digits), name
    v = validate(read_results(RESULTS), read_references(REFS))
    assert _quoted("T") == f"{v.overall.dispersion:.3g}"
    assert int(_quoted("inside")) == v.overall.inside and int(_quoted("n")) == v.overall.n


def test_the_shipped_example_is_from_the_current_model(tmp_path, capsys):
    """Its readings are what 'mtplan simulate' gives now, and its first result is what
    'mtplan estimate' gives for them now; else run sh examples/validate_results/regenerate.sh."""
    import pandas as pd

    folder = ROOT / "examples" / "validate_results"
    out = tmp_path / "r.csv"
    assert main(["simulate", "circle_centre", "--trials", "1", "--seed", "101",
                 "--readings-out", str(out)]) == 0
    new, old = pd.read_csv(out), pd.read_csv(folder / "readings" / "ring_gauge_1.csv")
    hint = "the model has changed: run sh examples/validate_results/regenerate.sh"
    assert new.shape == old.shape and np.allclose(new[["x_mm", "y_mm"]], old[["x_mm", "y_mm"]],
                                                  rtol=0, atol=1e-9), hint
    capsys.readouterr()
    assert main(["estimate", "circle_centre", str(folder / "readings" / "ring_gauge_1.csv"),
                 "--json"]) == 0
    now = json.loads(capsys.readouterr().out)
    shipped = json.loads((folder / "ring_gauge_1.json").read_text())
    for a, b in zip(now["measurands"], shipped["measurands"], strict=True):
        assert a["u"] == pytest.approx(b["u"], rel=1e-6), hint
        assert a["value"] == pytest.approx(b["value"], rel=1e-6, abs=1e-9), hint


# ------------------------------------------------------------------ synthetic results
def _doc(name, values, us, *, intervals=None, coverage=0.95, cov=None):
    """An 'estimate --json' document of measurands a, b, ... (um)."""
    names = [chr(ord("a") + i) for i in range(len(values))]
    ms = []
    for i, (n, y, u) in enumerate(zip(names, values, us, strict=True)):
        lo, hi = intervals[i] if intervals else (y - 1.959964 * u, y + 1.959964 * u)
        ms.append({"name": n, "unit": "um", "value": y, "u": u, "interval": [lo, hi],
                   "coverage": coverage})
    doc = {"procedure": "p", "measurands": ms}
    if cov is not None:
        doc["covariance"] = {"names": names, "units": ["um"] * len(names), "matrix": cov}
    return name, doc


def _ref(value, U, measurand="a", result=""):
    return {"procedure": "p", "measurand": measurand, "value": value, "U": U, "unit": "um",
            "result": result}


def test_one_shared_reference_correlates_and_result_specific_ones_do_not():
    results = [_doc(f"r{i}", [0.1 * i], [1.0]) for i in range(3)]
    shared = validate(results, [_ref(0.0, 2.0)])
    assert shared.overall.method == GENERALISED
    V = shared.covariance
    assert V[0, 1] == pytest.approx(1.0) and V[0, 0] == pytest.approx(2.0)  # u_ref^2 = 1
    d = np.array([0.0, 0.1, 0.2])
    assert shared.overall.dispersion == pytest.approx(d @ np.linalg.solve(V, d))
    own = validate(results, [_ref(0.0, 2.0, result=f"r{i}") for i in range(3)])
    assert own.overall.method == SHARE_AND_DISPERSION
    assert own.overall.dispersion == pytest.approx(np.sum(d**2 / 2.0))


def test_an_asymmetric_interval_is_used_on_the_side_facing_the_reference():
    results = [_doc("r", [10.0], [1.0], intervals=[(9.0, 14.0)])]
    above, below = (validate(results, [_ref(v, 0.0)]).comparisons[0] for v in (12.0, 8.0))
    assert above.U == pytest.approx(4.0) and above.en == pytest.approx(-0.5)
    assert below.U == pytest.approx(1.0) and below.en == pytest.approx(2.0)


def test_what_cannot_be_tested_is_refused_with_the_reason():
    with pytest.raises(InvalidInput, match="different coverages"):
        validate([_doc("r1", [0.0], [1.0]), _doc("r2", [0.0], [1.0], coverage=0.99)],
                 [_ref(0.0, 0.1)])
    with pytest.raises(InvalidInput, match="singular"):
        validate([_doc("r1", [0.0], [0.0], intervals=[(0.0, 0.0)])], [_ref(0.0, 0.0)])


def _false_verdicts(draw, n_results, replicates, seed, *, shared=True, U_ref=2.0):
    """Verdicts over `replicates` validations of `n_results` results of measurand a with
    u = 1, errors from `draw(rng, size)` and their own 95 % interval, against one
    reference shared by all, or one per result (normal, its U = `U_ref` at k = 2)."""
    from scipy import stats

    rng = np.random.default_rng(seed)
    half = {_normal: stats.norm.isf(0.025), _uniform: 0.95 * np.sqrt(3)}.get(draw, 1.959964)
    verdicts = []
    for _ in range(replicates):
        ref_error = U_ref / 2 * rng.standard_normal(None if shared else n_results)
        e = draw(rng, n_results)
        results = [_doc(f"r{i}", [float(e[i])], [1.0],
                        intervals=[(e[i] - half, e[i] + half)]) for i in range(n_results)]
        refs = [_ref(float(-ref_error), U_ref)] if shared else \
            [_ref(float(-ref_error[i]), U_ref, result=f"r{i}") for i in range(n_results)]
        verdicts.append(validate(results, refs).overall.verdict)
    return verdicts


def _normal(rng, n):
    return rng.standard_normal(n)


def _uniform(rng, n):
    return rng.uniform(-np.sqrt(3), np.sqrt(3), n)


@pytest.mark.parametrize("draw, n, shared, U_ref", [(_normal, 24, True, 2.0),
                                                    (_uniform, 100, False, 0.1)],
                         ids=["shared_reference_U_ref_equal_U", "rectangular_own_interval"])
def test_right_uncertainties_are_called_wrong_within_the_nominal_rate(draw, n, shared, U_ref):
    """Results with right uncertainties: n = 24 against one shared reference with
    U_ref = U (the 2u test: 36 % wrong verdicts), and n = 100 with rectangular errors and
    their own 95 % interval (the 2u test: "too large" in 99.9 %). Wrong verdicts stay
    below the 99.9 % binomial quantile of 1 - LEVEL over 200 validations."""
    from scipy import stats

    verdicts = _false_verdicts(draw, n, 200, 5, shared=shared, U_ref=U_ref)
    wrong = sum(v != CONSISTENT for v in verdicts)
    assert wrong <= stats.binom.ppf(0.999, 200, 1 - LEVEL), wrong


def test_halved_uncertainties_are_still_too_small_on_a_shared_reference():
    """Errors twice the stated u (u halved), 24 results, one shared reference with
    U_ref = 2 u: T = sum d^2 - (sum d)^2 / 25 is about 4 chi-square(23), mean 92 against the
    upper limit 39.4; it falls short when chi-square(23) < 9.85, probability 0.008. Misses
    over 50 validations stay below the 99.9 % binomial quantile of 0.01."""
    from scipy import stats

    assert stats.chi2.cdf(39.4 / 4, 23) < 0.01
    verdicts = _false_verdicts(lambda rng, n: 2 * rng.standard_normal(n), 24, 50, 6)
    assert sum(v != TOO_SMALL for v in verdicts) <= stats.binom.ppf(0.999, 50, 0.01)
