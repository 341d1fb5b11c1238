"""A first-order result crosses processes (the study's workers, its cache) with its value."""

import pickle

import numpy as np

from mtplan import models
from mtplan.evaluation.first_order import first_order


def test_a_first_order_result_pickles_with_its_value():
    proc = models.get("circle_centre")
    result = first_order(proc, proc.setup())
    back = pickle.loads(pickle.dumps(result))
    np.testing.assert_array_equal(back.value, result.value)
    np.testing.assert_array_equal(back.sensitivity, result.sensitivity)
    assert back.value_of is None and back.u() == result.u()
