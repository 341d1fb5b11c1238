"""``mtplan compensate``: corrections with their U, read back by independent readers.

Each controller format is parsed here from its documented layout alone (not with the
writer's code) and compared with the neutral table; the covariance of a correction is the
result's, mapped exactly through the correction model's linear terms.
"""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest

from mtplan import cli, models
from mtplan.compensation import compensate, correction, residual

EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "compensation"


def _doc(procedure: str) -> dict:
    return json.loads((EXAMPLES / f"{procedure}_result.json").read_text())


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


# --------------------------------------------------------------------------- readers
def read_isg_csv(text: str) -> dict:
    """ISG_CSV as the ISG kernel documents it: '//' comments, a header of names, records of
    white-space separated values; location errors named without the leading E [mm, rad]."""
    rows = [line.split("//")[0].split() for line in text.splitlines()]
    rows = [r for r in rows if r]
    header, records = rows[0], rows[1:]
    assert len(records) == 1, "location errors are constant: one record"
    return {f"E{name}": float(v) for name, v in zip(header, records[0])}


def read_fanuc_g10(text: str) -> tuple[int, dict, bool]:
    """(offset number, {axis: increment [mm]}, incremental) of a G10 L2 block."""
    block = next(line for line in text.splitlines() if "G10" in line and not
                 line.startswith("("))
    words = dict(re.findall(r"([A-Z])(-?\d+(?:\.\d*)?)", block))
    return int(words["P"]), {a: float(words[a]) for a in "XYZ" if a in words}, "G91" in block


def read_neutral_csv(text: str) -> dict:
    return {row["term"]: row for row in csv.DictReader(text.splitlines())}


# --------------------------------------------------------------------------- the correction
def test_terms_carry_the_results_values_and_covariance_exactly():
    doc = _doc("rotary_axis")
    corr = correction(models.get("rotary_axis").correction, doc, procedure="rotary_axis")
    values = {m["name"]: m["value"] for m in doc["measurands"]}
    names = doc["covariance"]["names"]
    C = np.array(doc["covariance"]["matrix"], dtype=float)
    idx = [names.index(n) for n in corr.names]
    assert corr.names == ("EX0C", "EY0C", "EA0C", "EB0C")
    np.testing.assert_array_equal(corr.value, [values[n] for n in corr.names])
    np.testing.assert_allclose(corr.covariance, C[np.ix_(idx, idx)], rtol=1e-15)
    np.testing.assert_allclose(corr.U, 2 * np.sqrt(np.diag(C))[idx], rtol=1e-15)


def test_a_combined_term_takes_the_covariance_through_its_weights():
    """A term that adds two measurands has u^2 = u1^2 + u2^2 + 2 cov: the map is A C A^T."""
    from mtplan.models.correction import CorrectionModel, CorrectionTerm

    doc = _doc("rotary_axis")
    model = CorrectionModel("kinematic location", "f", "s", lambda setup, names: (
        CorrectionTerm("sum", {"EX0C": 1.0, "EY0C": 1.0}, "um", "x + y"),
        CorrectionTerm("half", {"EA0C": 0.5}, "urad", "a / 2")))
    corr = correction(model, doc, procedure="rotary_axis")
    names = doc["covariance"]["names"]
    C = np.array(doc["covariance"]["matrix"], dtype=float)
    i, j, k = (names.index(n) for n in ("EX0C", "EY0C", "EA0C"))
    assert corr.covariance[0, 0] == pytest.approx(C[i, i] + C[j, j] + 2 * C[i, j], rel=1e-12)
    assert corr.covariance[1, 1] == pytest.approx(0.25 * C[k, k], rel=1e-12)
    assert corr.covariance[0, 1] == pytest.approx(0.5 * (C[i, k] + C[j, k]), rel=1e-12)
    # a sum has no interval of its own in the result: its residual is normal
    res = residual(corr)
    assert res.how[0] == "normal, 1.96 u" and np.isnan(corr.interval[0]).all()
    assert res.high[0] == pytest.approx(1.959963984540054 * np.sqrt(corr.covariance[0, 0]))
    # a scaled measurand keeps its interval, scaled
    a_low, a_high = next(m["interval"] for m in doc["measurands"] if m["name"] == "EA0C")
    np.testing.assert_allclose(corr.interval[1], [0.5 * a_low, 0.5 * a_high])


@pytest.mark.parametrize("procedure", ["rotary_axis", "line_laser"])
def test_neutral_table_round_trips(procedure):
    files, corr, res = compensate(EXAMPLES / f"{procedure}_result.json")
    table = read_neutral_csv(files["correction.csv"])
    doc = json.loads(files["correction.json"])
    assert list(table) == list(corr.names) == [t["term"] for t in doc["terms"]]
    for i, name in enumerate(corr.names):
        assert float(table[name]["value"]) == corr.value[i]
        assert float(table[name]["U"]) == pytest.approx(2 * np.sqrt(corr.covariance[i, i]))
        assert table[name]["sign"] == corr.sign and table[name]["frame"] == corr.frame
    np.testing.assert_array_equal(doc["covariance"]["matrix"], corr.covariance)
    # written at full precision: the residual's interval is the result's own, less the value
    measured = {m["name"]: m for m in json.loads(
        (EXAMPLES / f"{procedure}_result.json").read_text())["measurands"]}
    for i, name in enumerate(corr.names):
        low, high = measured[name]["interval"]
        assert res.low[i] == pytest.approx(low - corr.value[i], abs=1e-12)
        assert res.high[i] == pytest.approx(high - corr.value[i], abs=1e-12)
        assert float(table[name]["residual_low"]) == res.low[i]
    assert set(res.how) == {"the result's 95 % interval"}


def test_isg_csv_reads_back_to_the_location_errors():
    files, corr, _ = compensate(EXAMPLES / "rotary_axis_result.json", "isg-csv")
    read = read_isg_csv(files["volcomp_location.csv"])
    assert list(read) == list(corr.names)
    for name in corr.names:
        value, _U = corr.internal(name)
        scale = 1e3 if name[1] in "XYZ" else 1e6  # mm -> um, rad -> urad
        assert abs(read[name] - value) * scale < 0.01  # 0.01 um, 0.01 urad


# --------------------------------------------------------------------------- refusals
def test_an_unknown_format_is_refused_in_one_line(capsys, tmp_path):
    code, out, err = run(capsys, "compensate", EXAMPLES / "rotary_axis_result.json",
                         "--format", "heidenhain-com", "--out", tmp_path / "c")
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1
    assert "unknown format 'heidenhain-com'" in err and "isg-csv" in err
    assert not (tmp_path / "c").exists()


def test_a_format_that_cannot_hold_the_correction_is_refused(capsys, tmp_path):
    code, out, err = run(capsys, "compensate", EXAMPLES / "rotary_axis_result.json",
                         "--format", "fanuc-g10", "--out", tmp_path / "c")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "holds work offset corrections" in err and "kinematic location" in err
    assert not (tmp_path / "c").exists()


def test_a_result_without_covariance_is_refused(capsys, tmp_path):
    doc = _doc("rotary_axis")
    del doc["covariance"]
    path = tmp_path / "r.json"
    path.write_text(json.dumps(doc))
    code, out, err = run(capsys, "compensate", path, "--out", tmp_path / "c")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "no covariance" in err
    assert not (tmp_path / "c").exists()


def test_a_bad_option_names_the_option_and_the_allowed_values(capsys, tmp_path):
    code, out, err = run(capsys, "compensate", EXAMPLES / "rotary_axis_result.json",
                         "--format", "isg-csv", "--option", "offset=9", "--out", tmp_path / "c")
    assert code == 2 and "has no option 'offset'" in err
    assert not (tmp_path / "c").exists()


def test_a_procedure_without_a_correction_model_is_refused():
    import dataclasses

    from mtplan._validate import InvalidInput
    from mtplan.models.correction import NO_CORRECTION

    with pytest.raises(InvalidInput, match="states no correction"):
        correction(NO_CORRECTION, _doc("rotary_axis"), procedure="rotary_axis")
    assert dataclasses.fields(models.get("rotary_axis"))  # the default is NO_CORRECTION:
    assert [f.default for f in dataclasses.fields(type(models.get("rotary_axis")))
            if f.name == "correction"] == [NO_CORRECTION]


def test_a_table_needs_positions_along_the_travel(capsys, tmp_path):
    code, out, err = run(capsys, "compensate", EXAMPLES / "geometry21_result.json",
                         "--out", tmp_path / "c")
    assert code == 2 and "--along X=START:STOP:STEP" in err
    assert not (tmp_path / "c").exists()
