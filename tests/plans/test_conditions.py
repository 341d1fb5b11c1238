"""A study's recorded test conditions feed the set-up fields that declare them: the measured
temperatures correct the readings' evaluation, never the plan made before the test."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

import mtplan
from mtplan._validate import InvalidInput
from mtplan.models import get
from mtplan.models.protocol import with_conditions
from mtplan.plans.study import load_study

CONDITIONS = {"part_temperature_c": 25.0, "machine_temperature_c": 24.0,
              "air_gradient_k_per_m": 0.4, "warm_up": "30 min"}


def test_measured_conditions_fill_the_fields_that_declare_them():
    circle = with_conditions(get("circle_centre").Setup(), CONDITIONS)
    assert (circle.part_temperature_c, circle.scale_temperature_c) == (25.0, 24.0)
    tracker = with_conditions(get("tracker_frame").Setup(), CONDITIONS)
    assert (tracker.structure_temperature_c, tracker.air_gradient_k_per_m) == (24.0, 0.4)
    # the notes no longer say "assumed, not measured" for what the study measured
    assert not any("part temperature" in n and "assumed" in n for n in circle.notes())


def test_the_set_ups_own_measurement_wins_and_others_are_untouched():
    own = get("circle_centre").Setup(part_temperature_c=22.0)
    assert with_conditions(own, CONDITIONS).part_temperature_c == 22.0
    rotary = get("rotary_axis").Setup()
    assert with_conditions(rotary, CONDITIONS) is rotary
    declared = {f.metadata.get("condition") for name in ("circle_centre", "tracker_frame")
                for f in dataclasses.fields(get(name).Setup)} - {None}
    assert declared == {"part_temperature_c", "machine_temperature_c", "air_gradient_k_per_m",
                        "air_gradient_x_k_per_m", "air_gradient_y_k_per_m"}


def _study(conditions: str) -> dict:
    import tomllib

    return tomllib.loads(f"""
title = "conditions"
trials = 100
[conditions]
{conditions}
[[procedure]]
name = "circle_centre"
  [procedure.readings]
  file = "circle_centre_readings.csv"
""")


def test_a_condition_the_set_up_cannot_take_is_refused_before_computing():
    with pytest.raises(InvalidInput) as err:
        load_study(_study("part_temperature_c = 45.0\nair_gradient_k_per_m = 12"))
    text = " ".join(err.value.problems)
    assert "procedure #1 (circle_centre) at the study's conditions" in text
    assert "part_temperature_c" in text and "45" in text
    assert "'air_gradient_k_per_m' must be a number from -10 to 10 [K/m]. Got 12" in text


WARM = """
title = "a bore in a warm hall"
trials = 100
seed = 1
{conditions}
[[procedure]]
name = "circle_centre"
estimators = ["gls"]
setup = {{ scale_datum_x_mm = -300.0, scale_datum_y_mm = -300.0, part_temperature_u_k = 0.2, scale_temperature_u_k = 0.2 }}
  [procedure.readings]
  file = "{readings}"
  trials = 2000
"""


@pytest.mark.parametrize("recorded", [True, False])
def test_a_study_corrects_its_readings_with_the_recorded_temperatures(tmp_path, recorded):
    """The warm example's readings (part and scales at 25 degC, datum 300 mm away): with the
    study's recorded temperatures the centre covers the truth; assumed at 20 degC it is
    about 15 um off, outside its interval."""
    from mtplan.plans.study import run_study

    csv = Path(mtplan.__file__).parent / "examples" / "circle_centre_warm_readings.csv"
    conditions = ("[conditions]\npart_temperature_c = 25.0\nmachine_temperature_c = 25.0"
                  if recorded else "")
    path = tmp_path / "warm.toml"
    path.write_text(WARM.format(conditions=conditions, readings=csv.as_posix()),
                    encoding="utf-8")
    m = run_study(load_study(path), progress=False, n_jobs=1).outcomes[0].measured
    truth = {"centre_x": 350.0, "centre_y": -200.0}
    names = [q.name for q in m.measurands]
    for name, true in truth.items():
        i = names.index(name)
        inside = m.low[i] <= true <= m.high[i]
        assert inside == recorded, (name, m.value[i], m.low[i], m.high[i])
