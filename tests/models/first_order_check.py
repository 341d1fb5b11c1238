"""The first-order hooks of mtplan.models.first_order held to the GUM linearisation."""

import numpy as np
import pytest

from mtplan.evaluation.simulation import linearize_procedure


def assert_chain_rule_is_the_linearisation(proc, setup, estimator):
    """The designer's and planner's first-order hooks (the chain rule of
    mtplan.models.first_order) against the whole-chain GUM linearisation, source by
    source. Both are finite differences of the same first-order propagation: u agrees to
    its round-off (about 1e-7), each source's variance to about 1e-7 of the product of
    its effects on the readings and the estimator's map (more than its own size for a
    source the estimator cancels); 1e-5 of u and of u^2 are the bounds held."""
    gum = linearize_procedure(proc, setup, estimator=estimator)
    groups, var = gum.group_variance()
    table = proc.first_order_budget(setup, estimator=estimator)
    std = proc.first_order_std(setup, estimator=estimator)
    for i, name in enumerate(gum.names):
        part = table[table.measurand == name].set_index("source")["std"]
        assert sorted(part.index) == sorted(groups)
        np.testing.assert_allclose(part[list(groups)].to_numpy() ** 2, var[i], rtol=0,
                                   atol=1e-5 * gum.std[i] ** 2)
        assert std[name] == pytest.approx(gum.std[i], rel=1e-5)
