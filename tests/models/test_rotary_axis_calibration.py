"""rotary_axis's calibrated angle characteristic (``sensor_characteristic``): the file is
read and checked, every estimator corrects by it, the budget carries its u
(``angle_calibration_u``) in place of the data sheet's bound, and what that source moves.

The example characteristic (``examples/angle_characteristic.csv``, written by
``benchmarks/make_angle_characteristic.py``) is a simulated tilt-table calibration of the
data-sheet model: c0 = 0.20, c1 = 0.25, c2 = -0.10 of the bound, 0.5 um per point.
"""

from __future__ import annotations

import contextlib
import io
import math
from pathlib import Path

import numpy as np
import pytest

from mtplan._validate import InvalidInput
from mtplan.models import get
from mtplan.models.protocol import file_content
from mtplan.models.rotary_axis._layout import plan, sensor_tilts

PROC = get("rotary_axis")
ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = str(ROOT / "examples" / "angle_characteristic.csv")
HEADER = "tilt_x_deg,tilt_y_deg,error_um,u_um\n"


def _grid_csv(path, error, u=0.5, step=5.0, span=50.0):
    """A full grid characteristic with error_um = error(tx, ty) [um] at every point."""
    grid = np.arange(-span, span + step / 2, step)
    tx, ty = (a.ravel() for a in np.meshgrid(grid, grid, indexing="ij"))
    rows = [f"{x:g},{y:g},{float(e)!r},{u:g}" for x, y, e in zip(tx, ty, error(tx, ty), strict=True)]
    Path(path).write_text(HEADER + "\n".join(rows) + "\n")
    return str(path)


def _estimate(setup, estimator, **errors):
    err = PROC.zero_errors(setup, 1)
    for name, value in errors.items():
        err[name] = np.asarray(value, dtype=float).reshape(err[name].shape)
    return PROC.display_estimate(setup, PROC.forward(setup, PROC.Truth(), err), estimator)


# --------------------------------------------------------------------------- the set-up
@pytest.mark.parametrize("values", [dict(axis="C"), dict(axis="A", sensor_reversal=True),
                                    dict(axis="CA")])
def test_noise_free_readings_are_corrected_exactly_by_every_estimator(values):
    setup = PROC.setup(**values, sensor_characteristic=EXAMPLE)
    readings = PROC.forward(setup, PROC.Truth(), PROC.zero_errors(setup, 1))
    truth = PROC.display_truth(setup)
    for name in PROC.estimators:
        est = PROC.display_estimate(setup, readings, name)
        assert max(abs(float(est[k][0]) - v) for k, v in truth.items()) < 1e-6, name


def test_the_characteristic_replaces_the_data_sheet_bound_and_its_u_switches_off_at_0():
    setup = PROC.setup(sensor_characteristic=EXAMPLE)
    active = PROC.active_sources(setup)
    assert "angle_influence_halfwidth" not in active and "angle_calibration_u" in active
    # one element per calibrated point the six tilts (20 deg about the circle) interpolate from
    assert active["angle_calibration_u"].size == 24
    assert np.allclose(active["angle_calibration_u"].distribution.std, 0.5e-3)
    assert np.allclose(PROC.active_sources(setup.replace(angle_calibration_u_um=2.0))[
        "angle_calibration_u"].distribution.std, 2e-3)
    assert "angle_calibration_u" not in PROC.active_sources(setup.replace(angle_calibration_u_um=0))
    assert "angle_calibration_u" not in PROC.active_sources(PROC.Setup())
    assert any("calibrated characteristic" in n for n in setup.notes())


# --------------------------------------------------------------------------- what it moves
def test_calibration_error_moves_what_the_geometry_says(tmp_path):
    # an error of the calibration linear in the tilt along the triangulation plane, 1 um at
    # the C test's 20 deg, is an odd part: EX0C by 1 / tan(20 deg) = 2.747 um (as the
    # angle influence's odd part), nothing else; a common 1 um is a zero offset: A's EZ0A by
    # 1 um, nothing of C. Bilinear interpolation reproduces a linear error exactly.
    for values, pattern, expected in (
            (dict(axis="C"), lambda tx, ty: tx / 20.0, {"EX0C": 2.7473}),
            (dict(axis="C"), lambda tx, ty: np.ones_like(tx), {}),
            (dict(axis="A"), lambda tx, ty: np.ones_like(tx), {"EZ0A": 1.0})):
        setup = PROC.setup(**values, sensor_characteristic=EXAMPLE)
        ch = file_content(setup, "sensor_characteristic")
        points = plan(setup).calibration_index
        tx = ch.tilt_x[points // ch.tilt_y.size]
        ty = ch.tilt_y[points % ch.tilt_y.size]
        base = _estimate(setup, "angles")
        moved = _estimate(setup, "angles", angle_calibration_u=pattern(tx, ty) * 1e-3)
        for name in base:
            change = float(moved[name][0] - base[name][0])
            assert change == pytest.approx(expected.get(name, 0.0), abs=0.01), (values, name)


@pytest.mark.parametrize("axis, measurand", [("C", "EX0C"), ("A", "EZ0A")])
def test_calibrated_estimate_covers_the_truth_with_a_smaller_u_than_the_data_sheet(axis,
                                                                                  measurand):
    # readings of a sensor whose angle influence is the characteristic plus an error of its
    # calibration (0.5 um per point), every other default source on: the error of the
    # corrected estimate has the GUM's u (rms of error / u within its Monte Carlo error,
    # 4 / sqrt(2 (N - 1)) relative; every trial converges), and u of the measurand the
    # angle influence dominated is less than a third of the data sheet's (C: EX0C 16.7 ->
    # 5.2 um, A: EZ0A 13.0 -> 4.0 um)
    from mtplan.evaluation.first_order import first_order

    n = 400
    setup = PROC.setup(axis=axis, sensor_characteristic=EXAMPLE)
    u = first_order(PROC, setup, estimator="angles").u()
    u_sheet = first_order(PROC, PROC.setup(axis=axis), estimator="angles").u()
    assert u[measurand] < u_sheet[measurand] / 3
    est = PROC.display_estimate(setup, PROC.simulate(setup, draws=n, rng=32), "angles")
    truth = PROC.display_truth(setup)
    for name, value in truth.items():
        ratio = math.sqrt(np.mean(((est[name] - value) / u[name]) ** 2))
        assert abs(ratio - 1) < 4 / math.sqrt(2 * (n - 1)), (name, ratio)


def test_a_characteristic_of_the_wrong_sign_biases_the_result(tmp_path):
    # the laboratory's sign turned (reading minus true taken the other way): the correction
    # doubles the angle influence, whose odd part (0.25 x 0.3 % of 10 mm = 7.5 um at 20 deg)
    # then moves EX0C by about 2 x 7.5 / tan(20 deg) = 41 um, 8 of its u
    lines = Path(EXAMPLE).read_text().splitlines()
    flipped = [lines[0]] + [",".join([*r.split(",")[:2], str(-float(r.split(",")[2])),
                                      r.split(",")[3]]) for r in lines[1:]]
    wrong = tmp_path / "flipped.csv"
    wrong.write_text("\n".join(flipped) + "\n")
    n = 200
    setup = PROC.setup(sensor_characteristic=EXAMPLE)
    flipped = setup.replace(sensor_characteristic=str(wrong))
    true = PROC.display_truth(setup)["EX0C"]
    noise_free = PROC.display_estimate(
        flipped, PROC.forward(setup, PROC.Truth(), PROC.zero_errors(setup, 1)), "patent")
    bias = float(noise_free["EX0C"][0]) - true  # the file's points, interpolated: 39.3 um
    assert bias == pytest.approx(41, abs=2.5)
    est = PROC.display_estimate(flipped, PROC.simulate(setup, draws=n, rng=5), "patent")["EX0C"]
    assert abs(float(np.mean(est)) - true - bias) < 4 * np.std(est) / math.sqrt(n)
    assert bias > 5 * np.std(est)


# --------------------------------------------------------------------------- refusals
@pytest.mark.parametrize("text, words", [
    ("", ["is empty"]),
    ("a,b\n1,2\n", ["lacks the column(s) tilt_x_deg, tilt_y_deg, error_um, u_um"]),
    (HEADER + "0,0,1,0.5\n0,5,x,0.5\n5,0,1,-1\n5,5,1,0.5\n5,5,1,0.5\n",
     ["row 3, column error_um", "got 'x'", "row 4, column u_um", ">= 0",
      "(5, 5) deg more than once (rows 5, 6)"]),
    (HEADER + "0,0,1,0.5\n0,5,1,0.5\n5,0,1,0.5\n", ["full grid", "1 tilt(s) are missing: (5, 5)"]),
    (HEADER + "0,0,1,0.5\n0,5,1,0.5\n", ["at least two values of tilt_x_deg"]),
])
def test_a_bad_characteristic_is_refused_naming_file_row_and_column(tmp_path, text, words):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(InvalidInput) as caught:
        PROC.setup(sensor_characteristic=str(path))
    message = " ".join(caught.value.problems)
    assert str(path) in message
    for word in words:
        assert word in message, (word, message)


def test_tilts_outside_the_calibrated_range_are_refused_naming_field_value_and_range(tmp_path):
    small = _grid_csv(tmp_path / "small.csv", lambda tx, ty: 0 * tx, span=10.0)
    with pytest.raises(InvalidInput, match=r"'sensor_characteristic'.*tilt_x from -10 to 10 "
                       r"deg and tilt_y from -10 to 10 deg.*\(20.00, 0.00\) deg at C = 0 deg"):
        PROC.setup(sensor_characteristic=small)
    with pytest.raises(InvalidInput, match="'sensor_characteristic'.*readable file"):
        PROC.setup(sensor_characteristic=str(tmp_path / "absent.csv"))


def test_the_sensor_frame_tilts_turn_with_the_sensor():
    tx, ty = sensor_tilts(PROC.setup(sensor_reversal=True))
    assert np.allclose(np.hypot(tx, ty), 20.0) and np.allclose(tx[:, 1], -tx[:, 0])
    assert tx[0, 0] == pytest.approx(20.0) and ty[1, 0] == pytest.approx(20 * math.sin(math.pi / 3))


# --------------------------------------------------------------------------- command line
def _cli(*argv):
    from mtplan.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(list(argv))
        except SystemExit as exc:
            code = exc.code
    return code, out.getvalue(), err.getvalue()


def test_procedures_lists_the_fields_and_the_source():
    code, out, _ = _cli("procedures", "rotary_axis")
    assert code == 0
    assert "sensor_characteristic = empty" in out and "angle_calibration_u_um = empty" in out
    assert "angle_calibration_u" in out.split("error sources:")[1].splitlines()[0]


def test_a_path_in_a_config_file_is_taken_from_the_config_files_folder(tmp_path, monkeypatch):
    folder = tmp_path / "setups"
    folder.mkdir()
    _grid_csv(folder / "char.csv", lambda tx, ty: 0.01 * tx)
    (folder / "s.toml").write_text('[setup]\nsensor_characteristic = "char.csv"\n')
    monkeypatch.chdir(tmp_path)
    code, out, err = _cli("linearize", "rotary_axis", "--config", "setups/s.toml", "--json")
    assert code == 0, err
    assert "angle_calibration_u" in out
    code, _, err = _cli("linearize", "rotary_axis", "--set", "sensor_characteristic=char.csv")
    assert code == 2 and len(err.strip().splitlines()) == 1 and "char.csv" in err


def test_a_path_in_a_study_is_taken_from_the_study_files_folder(tmp_path, monkeypatch):
    from mtplan.plans.study import load_study

    folder = tmp_path / "study"
    folder.mkdir()
    _grid_csv(folder / "char.csv", lambda tx, ty: 0.01 * tx)
    (folder / "s.toml").write_text('title = "t"\n[[procedure]]\nname = "rotary_axis"\n'
                                   'setup = { sensor_characteristic = "char.csv" }\n')
    monkeypatch.chdir(tmp_path)
    setup = load_study(folder / "s.toml").procedures[0].setup
    assert Path(setup.sensor_characteristic) == folder / "char.csv"
