"""mtplan validate: measured results against calibrated references (E_n)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from mtplan._validate import InvalidInput
from mtplan.cli import main
from mtplan.evaluation.validation import (TOO_LARGE, TOO_SMALL, read_references, read_results,
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
                                       / np.hypot(row["U"], row["U_reference"]))
    print(out)  # the E_n table and the verdict, shown with pytest -s


def _scaled(tmp_path, factor):
    paths = []
    for p in RESULTS:
        doc = json.loads(p.read_text())
        for m in doc["measurands"]:
            m["u"] *= factor
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
