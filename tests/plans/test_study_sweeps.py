"""A study's sweeps: each distinct set-up of a procedure's sweeps is one stage, computed once
for every sweep that holds it, and every sweep's table is the one :func:`sweep` gives alone."""

from __future__ import annotations

import pandas as pd

from mtplan.plans.study import runner
from mtplan.plans.study import load_study, run_study
from mtplan.plans.sweep import sweep

STUDY = """
title = "Sweeps that share set-ups"
seed = 11
trials = 200
[[procedure]]
name = "circle_centre"
setup = { n_points = 4, bore_radius_mm = 175 }
estimators = ["three_point", "kasa", "geometric"]
  [[procedure.sweep]]          # the base set-up is in all three sweeps
  vary = { bore_radius_mm = [100, 175, 250] }
  trials = 150
  [[procedure.sweep]]
  vary = { n_points = [3, 4, 6] }
  trials = 150
  estimators = ["kasa"]
  [[procedure.sweep]]          # another trial count: its own stages
  vary = { n_points = [4, 8] }
  trials = 120
  estimators = ["geometric", "kasa"]
"""


def test_shared_set_ups_run_once_and_give_the_tables_of_sweep_alone(tmp_path, monkeypatch):
    path = tmp_path / "s.toml"
    path.write_text(STUDY, encoding="utf-8")
    study = load_study(path)
    ran = []
    work = runner._stage_work

    def counted(kind, ps, st, arg):
        if kind == "point":
            ran.append((arg.fields, arg.options, arg.estimators))
        return work(kind, ps, st, arg)

    monkeypatch.setattr(runner, "_stage_work", counted)
    result = run_study(study, progress=False, readings=False)
    # 3 + 3 + 2 set-ups, the base set-up in the first two at 150 trials: 7 stages, each once;
    # the base set-up's stage evaluates the estimators of both sweeps
    assert len(ran) == len(set(ran)) == 7
    base = [r for r in ran if '"bore_radius_mm": 175.0' in r[0] and '"n_points": 4' in r[0]
            and ("trials", 150) in r[1]]
    assert len(base) == 1 and base[0][2] == ("three_point", "kasa", "geometric")
    ps = study.procedures[0]
    for sw, table in result.outcomes[0].sweeps:
        alone = sweep(ps.name, ps.setup, sw["vary"], truth=ps.truth,
                      estimators=sw.get("estimators", ps.estimators), trials=sw["trials"],
                      rng=study.seed, progress=False)
        pd.testing.assert_frame_equal(table, alone, check_exact=True)
        assert table.attrs["notes"] == []
