"""The first-order service's chain rule in two parts held to the whole chain at once."""

import dataclasses

import numpy as np
import pytest

from mtplan.evaluation import first_order as fo


def assert_chain_rule_is_the_linearisation(proc, setup, estimator):
    """The chain rule in two parts (the readings' effects times the estimator's map, the
    service's way above ``WHOLE_MAX`` source elements) against the whole chain
    differentiated at once, source by source. Both are finite differences of the same
    first-order propagation: u agrees to its round-off (about 1e-7), each source's
    variance to about 1e-7 of the product of its effects on the readings and the
    estimator's map (more than its own size for a source the estimator cancels); 1e-5 of
    u and of u^2 are the bounds held."""
    generic = dataclasses.replace(proc, capabilities=proc.capabilities.generic(
        "first_order_sensitivities"))
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(fo, "WHOLE_MAX", 10**9)
        whole = fo.first_order(generic, setup, estimator=estimator)
        mp.setattr(fo, "WHOLE_MAX", 0)
        parts = fo.first_order(generic, setup, estimator=estimator)
    assert parts.sources == whole.sources and parts.inputs == whole.inputs
    var, want = parts.group_variance()[1], whole.group_variance()[1]
    for i in range(len(whole.names)):
        np.testing.assert_allclose(var[i], want[i], rtol=0, atol=1e-5 * whole.std[i] ** 2)
    np.testing.assert_allclose(parts.std, whole.std, rtol=1e-5)
    np.testing.assert_allclose(parts.value, whole.value, rtol=1e-9)  # (batched round-off)
