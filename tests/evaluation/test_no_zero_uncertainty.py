"""No `simulate` or `estimate` output states u = 0 or an interval of zero width.

An estimator that gives the same value in every trial is quantised or blind to the
measurand: its uncertainty is its resolution (u = step / sqrt(12), where the procedure
states the step; `simulate`) or not determinable (NaN; `estimate`), never 0. Every procedure,
every estimator, at the defaults: `simulate` (few trials: a zero spread shows at once)
and `estimate` on the shipped example readings (its `mc` evaluation).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

import mtplan
from mtplan.evaluation.measured import estimate_measured, read_readings
from mtplan.evaluation.simulation import simulate_uncertainty
from mtplan.models import registry

EXAMPLES = Path(mtplan.__file__).parent / "examples"
HEAVY = {"line_laser", "geometry21", "tracker_frame"}
CASES = [pytest.param(p, e, marks=[pytest.mark.slow] if p in HEAVY else [], id=f"{p}-{e}")
         for p in sorted(registry()) for e in registry()[p].estimators]


def _nonzero(u, low, high):
    """u and the interval: both finite with u > 0 and low < high, or not determinable."""
    if u is None or (isinstance(u, float) and math.isnan(u)):
        return low is None or math.isnan(low)
    return u > 0 and high > low


@pytest.mark.parametrize("proc_name,estimator", CASES)
def test_simulate_and_estimate_never_state_u_zero(proc_name, estimator):
    proc = registry()[proc_name]
    setup = proc.Setup()
    res = simulate_uncertainty(proc, setup, estimator=estimator, trials=24, rng=2,
                               progress=False)
    doc = json.loads(json.dumps(res.to_dict()))
    for m in doc["measurands"]:
        assert _nonzero(m["u"], *m["interval"]), (estimator, m)
    readings = read_readings(proc, setup, EXAMPLES / f"{proc_name}_readings.csv")
    out = estimate_measured(proc, setup, readings, estimator=estimator, uncertainty="mc",
                            trials=24, rng=3)
    for i, m in enumerate(out.measurands):
        assert _nonzero(float(out.std[i]), float(out.low[i]), float(out.high[i])), \
            (estimator, m.name, out.std[i], out.low[i], out.high[i])
    assert np.all(np.isnan(out.std[~out.determinable]))


def test_the_quantised_patent_alpha_z_states_its_step():
    proc = registry()["line_laser"]
    setup = proc.Setup()
    res = simulate_uncertainty(proc, setup, estimator="patent", trials=24, rng=2,
                               progress=False)
    step = proc.estimators["patent"].steps(setup)["alpha_z"] * 1e6  # urad
    i = [m.name for m in res.measurands].index("alpha_z")
    assert res.mc.std[i] == pytest.approx(step / math.sqrt(12), rel=1e-12)
    assert res.mc.high[i] - res.mc.low[i] == pytest.approx(0.95 * step, rel=1e-12)
