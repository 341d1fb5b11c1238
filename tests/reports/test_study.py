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


def test_header_and_acceptance_problems_at_once():
    data = {
        "header": {"customer": "C", "ambient_temperature_c": 95, "colour": "red",
                   "operator": ["a", "b"]},
        "procedure": [{"name": "circle_centre", "standards": "ISO 1101",
                       "acceptance": [
                           {"measurand": "centre_x", "lower": 5, "upper": -5},
                           {"measurand": "centre_x", "lower": -5, "upper": 5},
                           {"measurand": "centre_y", "upper": 5, "measured": "high"}]}],
    }
    text = "\n".join(problems_of(data))
    for needle in ("'colour'", "ambient_temperature_c", "'operator' must be text",
                   "'standards' must be a list", "'upper' must be > 'lower'",
                   "repeats measurand 'centre_x'", "'measured' must be a number"):
        assert needle in text, needle


def test_header_read_with_the_older_top_level_keys(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('customer = "Old"\nmachine = "Mill"\nauthor = "Me"\n'
                    '[header]\ndate = 2024-05-06\nambient_temperature_c = 19\n'
                    '[[procedure]]\nname = "circle_centre"\n'
                    'standards = ["ISO 10360-5:2020"]\n'
                    '[procedure.acceptance]\nmeasurand = "centre_x"\nupper = 10.0\n',
                    encoding="utf-8")
    study = load_study(path)
    assert study.header == {"customer": "Old", "machine_type": "Mill", "date": "2024-05-06",
                            "ambient_temperature_c": 19.0, "prepared_by": "Me"}
    ps = study.procedures[0]
    assert ps.standards == ["ISO 10360-5:2020"]
    assert ps.acceptance == [{"measurand": "centre_x", "upper": 10.0}]
    assert len(study.digest) == 64


def test_every_lever_is_a_setup_field_and_no_error_source():
    """Levers are what an engineer chooses; a field that sizes an error source is a
    property of the machine, the workpiece or the instrument."""
    from mtplan.models import registry
    from mtplan.models.protocol import fields_info

    for name, proc in registry().items():
        fields = {f.name for f in fields_info(proc.Setup)}
        assert proc.levers, name
        assert set(proc.levers) <= fields, (name, set(proc.levers) - fields)
        sources = proc.sources(proc.Setup())
        sized = {f for f in fields for s in sources if f.startswith(f"{s}_")}
        assert not sized & set(proc.levers), (name, sized & set(proc.levers))


@pytest.mark.parametrize("standard", ["ISO 230-2:2014", "ISO 1101:2017"])
def test_a_standard_the_procedure_does_not_honour_is_not_cited(standard):
    """ISO 230-2 asks for A, E, M, R, B per axis and ISO 1101 for a diameter position zone;
    no procedure evaluates them, so a study that cites them is refused, naming why."""
    problems = problems_of({"procedure": [{"name": "circle_centre",
                                           "standards": ["ISO 10360-5:2020", standard]}]})
    assert len(problems) == 1 and standard in problems[0] and "requires" in problems[0]


def test_agreement_keys_checked_at_once():
    """The plan's requirements, the instruments' certificates and a test's machine are
    validated with the rest of the study, every problem at once."""
    data = {
        "requirements": {"temperature_c": [22, 19], "retests": -1, "larger_u": "ignore",
                         "compensation": "yes", "humidity": 50},
        "instrument": [{"name": "P", "serial": "1", "certificate": "C", "kind": "guess",
                        "accredited": "maybe"}],
        "procedure": [{"name": "circle_centre", "machine": 42,
                       "acceptance": [{"measurand": "centre_x", "lower": -5, "upper": 5,
                                       "tolerance_source": 7}]}],
    }
    text = "\n".join(problems_of(data))
    for needle in ("'temperature_c' must be a band", "'retests' must be an integer >= 0",
                   "'larger_u' must be one of 'widen', 'no decision'",
                   "'compensation' must be true or false", "'humidity'",
                   "'kind' must be one of calibration, verification",
                   "'accredited' must be true or false", "'machine' must be the serial",
                   "'tolerance_source' must be text"):
        assert needle in text, needle
    good = load_study({**data, "requirements": {"temperature_c": [19, 22], "larger_u": "widen"},
                       "instrument": [{"name": "P", "serial": "1", "certificate": "C",
                                       "kind": "verification", "accredited": False}],
                       "procedure": [{"name": "circle_centre", "machine": "SN 1"}]})
    assert good.requirements == {"temperature_c": [19.0, 22.0], "larger_u": "widen"}
    assert good.instruments[0]["kind"] == "verification"
    assert good.instruments[0]["accredited"] is False
    assert good.procedures[0].machine == "SN 1"
