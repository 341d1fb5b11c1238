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
    # the default is NO_CORRECTION, a tag of the capabilities
    caps = type(models.get("rotary_axis").capabilities)
    assert [f.default for f in dataclasses.fields(caps)
            if f.name == "correction"] == [NO_CORRECTION]


def test_a_table_needs_positions_along_the_travel(capsys, tmp_path):
    doc = _doc("geometry21")
    doc["setup"].update(along_x_mm=[], along_y_mm=[], along_z_mm=[])
    doc["measurands"] = [m for m in doc["measurands"] if "@" not in m["name"]]
    path = tmp_path / "g.json"
    path.write_text(json.dumps(doc))
    code, out, err = run(capsys, "compensate", path, "--out", tmp_path / "c")
    assert code == 2 and "--along X=START:STOP:STEP" in err
    assert not (tmp_path / "c").exists()


# --------------------------------------------------------------------------- frames, offsets
def read_siemens_frames(text: str) -> tuple[int, np.ndarray, np.ndarray]:
    """(n, T [mm], R) of a '$P_UIFR[n]=CTRANS(X,..,Y,..,Z,..):CROT(Z,c,Y,b,X,a)' line: the
    frame approaches a programmed p at T + R p, R = Rz(c) Ry(b) Rx(a) (RPY, degrees)."""
    line = next(x for x in text.splitlines() if x.startswith("$P_UIFR"))
    n = int(re.search(r"\[(\d+)\]", line)[1])
    trans = dict(re.findall(r"([XYZ]),(-?[\d.]+)", line.split(":CROT")[0]))
    rot = dict(re.findall(r"([XYZ]),(-?[\d.]+)", line.split(":CROT")[1]))
    a, b, c = (np.radians(float(rot[k])) for k in "XYZ")
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return n, np.array([float(trans[k]) for k in "XYZ"]), rz @ ry @ rx


def test_siemens_frames_run_global_coordinates_on_each_sub_machine():
    """10^4 random global points: the written frame puts each where the measured pose of
    the sub-machine says it is in the sub-machine's coordinates, to 0.01 um."""
    doc = _doc("tracker_frame")
    files, corr, _ = compensate(doc, "siemens-frame", {"frame": "3"})
    value = {m["name"]: m["value"] for m in doc["measurands"]}
    setup = doc["setup"]
    rng = np.random.default_rng(7)
    points = rng.uniform(-4000, 4000, size=(10_000, 3))
    for k in range(1, setup["n_submachines"] + 1):
        n, T, R = read_siemens_frames(files[f"frame_submachine_{k}.spf"])
        assert n == 3
        y_k = (k - 1 - (setup["n_submachines"] - 1) / 2) * setup["submachine_spacing_mm"]
        t = np.array([0.0, y_k, setup["origin_height_mm"]]) + 1e-3 * np.array(
            [value[f"origin_{ax}_{k}"] for ax in "xyz"])
        a, b, c = (1e-6 * value[f"rot_{ax}_{k}"] for ax in "xyz")
        R_k = (np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
               @ np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
               @ np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]]))
        expected = (points - t) @ R_k  # R_k^T (p - t), row-wise
        written = T + points @ R.T
        assert np.max(np.abs(written - expected)) < 1e-5  # mm: 0.01 um


def test_fanuc_work_offset_adds_the_centre_rounded_to_the_increment():
    for increment, places in (("0.001", 3), ("0.0001", 4)):
        files, corr, res = compensate(EXAMPLES / "circle_centre_result.json", "fanuc-g10",
                                      {"offset": "2", "increment_mm": increment})
        text = files["work_offset_G55.nc"]
        p, values, incremental = read_fanuc_g10(text)
        assert p == 2 and incremental and text.startswith("%\nO9001")
        step = float(increment)
        for axis, name in (("X", "work_offset_x"), ("Y", "work_offset_y")):
            value = corr.value[corr.names.index(name)] * 1e-3
            assert abs(values[axis] - value) <= step / 2 + 1e-12
            # the rounding is known, and it shifts the residual's interval
            i = corr.names.index(name)
            assert res.shift[i] == pytest.approx((value - values[axis]) * 1e3, abs=1e-9)
        assert re.search(rf"X-?\d+\.\d{{{places}}} ", text)


# --------------------------------------------------------------------------- tables
def read_isg_tables(text: str) -> dict:
    """{function: (positions [mm], values [mm or rad])} of an ISG_CSV file's component-error
    blocks ('#' separates blocks; the first column of a block is its argument)."""
    out = {}
    for block in text.split("\n#\n"):
        rows = [line.split("//")[0].split() for line in block.splitlines()]
        rows = [r for r in rows if r]
        header, records = rows[0], np.array(rows[1:], dtype=float)
        if header[0] in "XYZ":
            for j, name in enumerate(header[1:], start=1):
                out[name] = (records[:, 0], records[:, j])
    return out


def test_isg_tables_read_back_with_linear_interpolation_to_the_estimated_functions():
    """The table of the estimate at every 1 mm, read back and interpolated linearly (the
    kernel's GRID mode) at 10^4 random positions inside the travel, equals the estimated
    polynomials to 0.01 um (0.01 urad for the angles)."""
    from mtplan.evaluation.readings import read_measurement
    from mtplan.models.geometry21 import coefficients

    proc = models.get("geometry21")
    grid = ",".join(str(u) for u in range(-50, 51))
    meas = read_measurement(proc, EXAMPLES.parent / "geometry21_readings.csv",
                            {"along_x_mm": grid, "along_y_mm": grid, "along_z_mm": grid})
    est = proc.estimate(meas.setup, meas.readings, "joint")
    ms = proc.measurands(meas.setup)
    doc = {"procedure": "geometry21", "estimator": "joint", "setup": meas.setup.as_dict(),
           "measurands": [{"name": m.name, "unit": m.unit, "value": float(est[m.name][0]) *
                           m.scale, "u": 1.0} for m in ms],
           "covariance": {"names": [m.name for m in ms], "units": [m.unit for m in ms],
                          "matrix": np.eye(len(ms)).tolist()}}
    files, corr, _ = compensate(doc, "isg-csv")
    tables = read_isg_tables(files["volcomp_tables.csv"])
    coefs = coefficients(meas.setup, meas.readings, estimator="joint")
    u = np.random.default_rng(3).uniform(-50, 50, 10_000)
    checked = 0
    for name, (pos, values) in tables.items():
        powers, c = coefs[name]
        exact = np.sum(c[0][None, :] * u[:, None] ** np.array(powers), axis=1)
        scale = 1e3 if name[1] in "XYZ" else 1e6  # mm -> um, rad -> urad
        assert np.max(np.abs(np.interp(u, pos, values) - exact)) * scale < 0.01, name
        checked += 1
    assert checked == 15 - 3  # the determined component errors (the squarenesses apart)
    assert "C0Y B0Z A0Z" in files["volcomp_tables.csv"]
