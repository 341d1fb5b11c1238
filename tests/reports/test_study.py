"""Study files: every problem said at once, in words that name the place."""

from __future__ import annotations

import pytest

from mtplan._validate import InvalidInput
from mtplan.plans.study import load_study


def problems_of(data) -> list[str]:
    with pytest.raises(InvalidInput) as info:
        load_study(data)
    return info.value.problems


def test_every_problem_at_once():
    data = {
        "seed": -1,
        "colour": "red",
        "procedure": [
            {"name": "no_such_procedure"},
            {"name": "circle_centre", "setup": {"n_points": 2, "wibble": 1},
             "estimators": ["kasa", "magic"], "extra": 1,
             "sweep": [{"vary": {"nonsense_mm": [1, 2]}, "color": 1}],
             "plan": {"targets": {"EX0C": 1.0}},
             "acceptance": {"measurand": "nope", "lower": -1, "upper": 1, "rule": "wild"},
             "readings": {"file": "/no/such/readings.csv"}},
        ],
    }
    text = "\n".join(problems_of(data))
    for needle in ("'colour'", "'seed'", "no_such_procedure", "'extra'", "'wibble'",
                   "n_points", "'magic'", "nonsense_mm", "'color'", "EX0C", "'nope'",
                   "wild", "readings file"):
        assert needle in text, needle


def test_missing_readings_file_relative_to_study(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('[[procedure]]\nname = "circle_centre"\n'
                    '[procedure.readings]\nfile = "missing.csv"\n', encoding="utf-8")
    with pytest.raises(InvalidInput) as info:
        load_study(path)
    assert any("missing.csv" in p for p in info.value.problems)


def test_invalid_grid_setups_are_found_before_computing():
    data = {"procedure": [{"name": "circle_centre",
                           "sweep": [{"vary": {"bore_radius_mm": [50, 250]}}]}]}
    text = " ".join(problems_of(data))
    assert "bore_radius_mm=50" in text and "start_scatter_mm" in text


@pytest.mark.parametrize("text, needle", [
    ("not toml [", "not valid TOML"),
    ("title = 'x'\n", "at least one [[procedure]]"),
])
def test_bad_files(tmp_path, text, needle):
    path = tmp_path / "s.toml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(InvalidInput) as info:
        load_study(path)
    assert needle in " ".join(info.value.problems)


def test_no_such_study_file(tmp_path):
    with pytest.raises(InvalidInput, match="No such study file"):
        load_study(tmp_path / "absent.toml")


def test_cli_reports_bad_study_in_one_line(tmp_path, capsys):
    from mtplan.cli import main

    path = tmp_path / "s.toml"
    path.write_text('[[procedure]]\nname = "nope"\n', encoding="utf-8")
    code = main(["report", str(path), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "nope" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()
