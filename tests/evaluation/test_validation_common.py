"""validate with a common share of the results' u²: repeated tests of one machine."""

from __future__ import annotations

import numpy as np
import pytest

from mtplan import cli
from mtplan._validate import InvalidInput
from mtplan.evaluation.validation import CONSISTENT, TOO_LARGE, validate


def _results(errors, setup=None):
    return [(f"r{i}", {"procedure": "p", "setup": setup, "measurands": [
        {"name": "a", "unit": "um", "value": float(e), "u": 1.0,
         "interval": [float(e) - 1.96, float(e) + 1.96], "coverage": 0.95}]})
        for i, e in enumerate(errors)]


def _refs(n):
    return [{"procedure": "p", "measurand": "a", "value": 0.0, "U": 0.2, "unit": "um",
             "result": f"r{i}"} for i in range(n)]


def test_the_common_share_correlates_every_pair_of_results():
    v = validate(_results([0.5, 0.6, 0.4]), _refs(3), common=0.9)
    u_ref2 = 0.1 ** 2
    np.testing.assert_allclose(v.covariance, 0.9 * np.ones((3, 3)) + np.diag([0.1 + u_ref2] * 3),
                               rtol=1e-12)
    assert "the results' common share" in v.overall.correlated_by[0]


def test_results_that_moved_together_are_consistent_only_with_their_common_share():
    """24 repeated tests whose errors are one common error (90 % of u²) plus their own: as independent results their spread is far too small ("too large"); with
    the common share stated the generalised chi-square finds them consistent."""
    rng = np.random.default_rng(5)
    errors = np.sqrt(0.9) * 0.5 + np.sqrt(0.1) * rng.standard_normal(24)
    alone = validate(_results(errors, {"x": 1}), _refs(24))
    assert alone.overall.verdict == TOO_LARGE
    assert any("compared as independent" in n and "--common" in n for n in alone.notes)
    together = validate(_results(errors, {"x": 1}), _refs(24), common=0.9)
    assert together.overall.verdict == CONSISTENT
    assert not any("compared as independent" in n for n in together.notes)


@pytest.mark.parametrize("common", [-0.1, 1.5, float("nan")])
def test_a_common_share_outside_0_to_1_is_refused(common):
    with pytest.raises(InvalidInput, match="share from 0 to 1"):
        validate(_results([0.1]), _refs(1), common=common)


def test_the_command_refuses_it_in_one_line(capsys, tmp_path):
    code = cli.main(["validate", "--common", "2", "--references", "r.csv", "x.json"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and "--common" in err
