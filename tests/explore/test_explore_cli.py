"""``mtplan explore`` without a browser: the missing extra, the state functions."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from mtplan.cli import main


def test_without_the_extra_it_exits_2_with_the_install_line(monkeypatch, capsys):
    import mtplan.explore

    monkeypatch.setattr(mtplan.explore, "missing_extra", lambda: ["starlette"])
    assert main(["explore", "rotary_axis", "--no-browser"]) == 2
    err = capsys.readouterr().err
    assert "pip install 'mtplan[explore]'" in err and len(err.strip().splitlines()) == 1


def test_binds_to_loopback_only():
    from mtplan.explore import HOST

    assert HOST == "127.0.0.1"


def test_study_round_trip_keeps_the_design():
    from mtplan.explore.design import design_from_study, evaluate, study_toml

    design = {"procedure": "circle_centre", "setup": {"n_points": "5", "spread_deg": "270"},
              "off": ["roundness"], "targets": {"centre_x": "4"},
              "vary": {"n_points": "3,4,6"},
              "tolerances": {"centre_x": {"lower": "-20", "upper": "20",
                                          "prior": "normal:0,8", "rule": "iso14253"}},
              "seed": 3, "trials": 500}
    text = study_toml(design)
    data = tomllib.loads(text)
    assert data["procedure"][0]["setup"]["roundness_um"] == 0.0
    assert data["procedure"][0]["plan"]["targets"] == {"centre_x": 4.0}
    back = design_from_study(text)
    assert back["off"] == ["roundness"]
    assert back["setup"]["n_points"] == "5" and back["setup"]["spread_deg"] == "270"
    assert back["targets"] == {"centre_x": 4.0} and back["seed"] == 3
    a, b = evaluate(design), evaluate(back)
    assert [m["U"] for m in a["measurands"]] == [m["U"] for m in b["measurands"]]
    assert a["measurands"][0]["acceptance"] == b["measurands"][0]["acceptance"]


@pytest.mark.parametrize("setup, field", [({"n_points": "2"}, "n_points"),
                                          ({"spread_deg": "x"}, "spread_deg"),
                                          ({"nope": "1"}, "nope")])
def test_a_refused_value_is_named_beside_its_field(setup, field):
    from mtplan.explore.design import evaluate

    r = evaluate({"procedure": "circle_centre", "setup": setup})
    assert not r["ok"] and field in r["field_errors"] and field in r["field_errors"][field]


@pytest.mark.parametrize("name", ["circle_centre", "geometry21", "line_laser", "rotary_axis",
                                  "tracker_frame"])
def test_every_error_source_has_the_field_that_sizes_it(name):
    from mtplan.explore.design import source_fields
    from mtplan.models import get

    proc = get(name)
    assert set(source_fields(proc)) == set(proc.sources(proc.Setup()))


@pytest.mark.parametrize("name, change", [("rotary_axis", {"probe_noise_um": 0.0,
                                                           "flatness_um": 7.0}),
                                          ("circle_centre", {"roundness_um": 0.0})])
def test_identifiability_reused_across_source_sizes_is_the_fresh_one(name, change):
    from mtplan.explore import design as d
    from mtplan.models import get

    proc = get(name)
    setup = proc.Setup().replace(**change)
    d.identify_cached(proc, proc.Setup())  # cached at the defaults
    assert d.identify_cached(proc, setup) == d.identify(proc, setup)


def test_cheapest_set_up_is_the_planners_answer_over_the_marked_ranges():
    from mtplan.explore.jobs import cheapest
    from mtplan.models import get
    from mtplan.plans.planner import plan

    design = {"procedure": "circle_centre", "estimator": "kasa", "trials": 400, "seed": 2,
              "targets": {"centre_x": "6"}, "vary": {"n_points": "3,4,6,8"}}
    r = cheapest(design)
    proc = get("circle_centre")
    direct = plan(proc, proc.Setup(), {"n_points": [3, 4, 6, 8]}, {"centre_x": 6.0}, k=2.0,
                  estimator="kasa", seed=2, trials=400)
    assert r["best"]["setup"] == direct.best["setup"]
    assert r["best"]["confirmed"]["centre_x"] <= 6.0
    with pytest.raises(Exception, match="range"):
        cheapest({**design, "vary": {}})


def test_monte_carlo_reports_its_progress_to_a_callable():
    from mtplan.evaluation.simulation import simulate_uncertainty

    seen = []
    r = simulate_uncertainty("circle_centre", trials=300, rng=1, block_size=100,
                             progress=lambda done, total: seen.append((done, total)))
    assert seen == [(100, 300), (200, 300), (300, 300)] and r.mc.trials == 300


GLOSSARY = Path(__file__).resolve().parents[2] / "docs" / "glossary.md"
#: set-ups that show every measurand code a procedure has (the axes, a third sub-machine)
VARIANTS = [("rotary_axis", {"axis": "CA"}), ("rotary_axis", {"axis": "A"}),
            ("tracker_frame", {"n_submachines": 3}), ("geometry21", {}), ("line_laser", {}),
            ("circle_centre", {})]


def test_an_installed_mtplan_explains_its_codes_as_a_checkout_does(tmp_path):
    """Built and installed from its sources (pip, into a folder of its own), the designer
    reads the glossary that docs/glossary.md is: an install without the checkout beside it
    still explains EX0C, TUR and the rest."""
    import shutil

    from tests.packaging import pip_install

    root = GLOSSARY.parents[1]
    tree = tmp_path / "mtplan-src"  # what a source distribution holds, the links as links
    (tree / "docs").mkdir(parents=True)
    for name in ("pyproject.toml", "README.md", "docs/glossary.md"):
        shutil.copy2(root / name, tree / name)
    shutil.copytree(root / "src", tree / "src", symlinks=True,
                    ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
    site = tmp_path / "site"
    pip_install(site, tree, setuptools=(77, 0))  # pyproject.toml's build requirement
    code = ("from mtplan.explore import design as d; import json; "
            "print(json.dumps([d.__file__, len(d.glossary()), d.explain('EX0C')['meaning']]))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(site)}, cwd=tmp_path, timeout=120)
    assert done.returncode == 0, done.stderr
    where, rows, meaning = json.loads(done.stdout)
    assert Path(where).is_relative_to(site)
    assert not (site / "mtplan" / "explore" / "glossary.md").is_symlink()
    from mtplan.explore import design as d
    assert rows == len(d.glossary()) > 20 and meaning == d.explain("EX0C")["meaning"]


@pytest.mark.parametrize("name, change", VARIANTS)
def test_every_measurand_code_has_the_glossarys_words(name, change):
    from mtplan.explore import design as d
    from mtplan.models import get

    text = GLOSSARY.read_text(encoding="utf-8").replace("`", "")
    proc = get(name)
    for m in proc.measurands(proc.Setup(**change)):
        row = d.explain(m.name)
        assert row is not None, m.name
        assert f"| {row['label']} | {row['meaning']} |" in text, m.name
        assert d.help_text(m.name, m.description).startswith(f"{row['label']}: {row['meaning']}")


@pytest.mark.parametrize("code", ["TUR", "PFA", "PFR", "w", "A_L", "prior", "O1", "rank",
                                  "c_i", "share", "target", "u", "U", "simple", "iso14253",
                                  "dobbert", "guard:1", "target-pfa:0.02", "conditional PFA"])
def test_every_term_of_the_page_is_in_the_glossary(code):
    from mtplan.explore import design as d

    assert d.explain(code) is not None


def test_a_file_field_is_never_offered_nor_read():
    """The page never names a path on the server: a file field (rotary_axis's calibrated
    characteristic) is left out of the controls, refused in a design beside its name, and
    refused in a study the page loads."""
    from mtplan._validate import InvalidInput
    from mtplan.explore.design import design_from_study, evaluate, procedure_info

    names = [f["name"] for f in procedure_info("rotary_axis")["fields"]]
    assert "sensor_characteristic" not in names and "angle_calibration_u_um" in names
    r = evaluate({"procedure": "rotary_axis", "setup": {"sensor_characteristic": "/etc/passwd"}})
    assert not r["ok"] and "set it in the set-up file" in r["field_errors"]["sensor_characteristic"]
    text = ('[[procedure]]\nname = "rotary_axis"\n'
            'setup = { sensor_characteristic = "/etc/passwd" }\n')
    with pytest.raises(InvalidInput, match="does not read files"):
        design_from_study(text)
