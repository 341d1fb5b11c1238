"""A study's errors along the travel: ``[procedure.readings] along`` or the procedure's
default grid (the measured travel at a step), for the readings' evaluation only."""

from __future__ import annotations

import pytest

from mtplan._validate import InvalidInput

EXAMPLES = __import__("pathlib").Path(__file__).resolve().parents[2] / "src" / "mtplan" / \
    "examples"

STUDY = """
title = "along"
[[procedure]]
name = "{name}"
  [procedure.readings]
  file = "{file}"
  {along}
"""


def _study(tmp_path, along="", name="geometry21", file="geometry21_readings.csv"):
    from mtplan.plans.study import load_study

    path = tmp_path / "study.toml"
    path.write_text(STUDY.format(name=name, file=(EXAMPLES / file).as_posix(), along=along),
                    encoding="utf-8")
    return load_study(path)


def _grid(ps):
    from mtplan.plans.study.runner import _along_setup

    setup = _along_setup(ps.procedure, ps.setup, ps.readings)
    return {f: getattr(setup, f) for f in ("along_x_mm", "along_y_mm", "along_z_mm")}


def test_the_default_grid_is_the_measured_travel_every_twentieth(tmp_path):
    (ps,) = _study(tmp_path).procedures
    grid = _grid(ps)
    assert grid["along_x_mm"] == tuple(float(x) for x in range(-50, 51, 5))
    assert grid["along_x_mm"] == grid["along_y_mm"] == grid["along_z_mm"]
    assert ps.setup.along_x_mm == ()  # the Monte Carlo, sweeps and plan: no curves


def test_the_study_names_the_grid_or_none(tmp_path):
    (ps,) = _study(tmp_path, 'along = { X = "-20:20:10" }').procedures
    assert _grid(ps) == {"along_x_mm": (-20, -10, 0, 10, 20), "along_y_mm": (),
                         "along_z_mm": ()}
    (ps,) = _study(tmp_path, "along = {}").procedures
    assert _grid(ps) == {"along_x_mm": (), "along_y_mm": (), "along_z_mm": ()}


def test_a_bad_grid_is_refused_naming_it(tmp_path):
    with pytest.raises(InvalidInput) as exc:
        _study(tmp_path, 'along = { Q = "-20:20:10", X = "20:-20:10" }')
    text = " ".join(exc.value.problems)
    assert "readings along 'Q': geometry21 states no errors along 'Q'" in text
    assert "readings along 'X': '20:-20:10': expected START:STOP:STEP" in text
    with pytest.raises(InvalidInput, match="circle_centre states no errors along 'X'"):
        _study(tmp_path, 'along = { X = "0:10:5" }', name="circle_centre",
               file="circle_centre_readings.csv")
