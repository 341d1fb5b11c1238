"""GUM law of propagation (linearize), budgets, Welch-Satterthwaite and JCGM 101 clause 8."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from mtplan._validate import InvalidInput
from mtplan.uncertainty import (
    MultivariateNormal,
    Normal,
    Rectangular,
    StudentT,
    Trapezoidal,
    linearize,
    propagate,
    validate,
)
from mtplan.uncertainty.gum import sensitivities, welch_satterthwaite


def test_linear_model_sensitivities_are_exact():
    inputs = {"a": Normal(1.0, 0.2), "b": Rectangular(-1.0, 3.0), "c": Trapezoidal(0.0, 4.0, 0.5)}
    g = linearize(lambda a, b, c: 3 * a - 2 * b + 0.5 * c + 7, inputs)
    np.testing.assert_allclose(g.sensitivity[0], [3.0, -2.0, 0.5], rtol=1e-9)
    u = np.array([d.std for d in inputs.values()])
    assert g.std[0] == pytest.approx(math.sqrt(np.sum((np.array([3, -2, 0.5]) * u) ** 2)), rel=1e-9)
    assert g.value[0] == pytest.approx(3 * 1.0 - 2 * 1.0 + 0.5 * 2.0 + 7)
    assert g.dof[0] == math.inf
    assert g.k[0] == pytest.approx(stats.norm.ppf(0.975))
    assert g.low[0] == pytest.approx(g.value[0] - g.k[0] * g.std[0])


def test_nonlinear_sensitivities():
    """Richardson central differences: error O(h^4) with h = 1e-3 u."""
    g = linearize(lambda a, b: a * np.exp(b), {"a": Normal(2.0, 0.1), "b": Normal(0.5, 0.05)})
    np.testing.assert_allclose(g.sensitivity[0], [math.exp(0.5), 2 * math.exp(0.5)], rtol=1e-10)
    value, jac = sensitivities(lambda p: np.sin(p), np.array([0.3, 1.1]), np.array([1e-3, 0.0]))
    np.testing.assert_allclose(jac[0], [math.cos(0.3), 0.0], atol=1e-10)  # p[:,0] -> out 0
    np.testing.assert_allclose(jac[1], [0.0, math.cos(1.1)], rtol=1e-8)  # zero u: fallback step


def test_student_t_uses_scale_and_dof_with_welch_satterthwaite():
    """GUF: StudentT(loc, scale, dof) contributes u = scale with dof degrees of freedom.

    Reference: u_a = 0.57 (9 dof), u_b = 0.25 (inf) -> nu_eff = 12.8 (sandialabs/suncal
    test_examples.py::test_DEGF, ENGR224 example); exact (0.57^2 + 0.25^2)^2 / (0.57^4 / 9).
    """
    nu_exact = (0.57**2 + 0.25**2) ** 2 / (0.57**4 / 9)
    g = linearize(lambda a, b: a + b, {"a": StudentT(1.0, 0.57, 9), "b": Normal(1.0, 0.25)})
    assert g.std[0] == pytest.approx(math.hypot(0.57, 0.25), rel=1e-10)
    assert g.dof[0] == pytest.approx(nu_exact, rel=1e-8)
    assert round(g.dof[0], 1) == 12.8
    assert g.k[0] == pytest.approx(stats.t.ppf(0.975, nu_exact), rel=1e-8)
    # the same through the dof override on a normal input
    g2 = linearize(lambda a, b: a + b, {"a": Normal(1.0, 0.57), "b": Normal(1.0, 0.25)}, dof={"a": 9})
    assert g2.dof[0] == pytest.approx(nu_exact, rel=1e-8)
    # Monte Carlo draws the full t: variance scale^2 nu / (nu - 2)
    mc = propagate(lambda a, b: a + b, {"a": StudentT(1.0, 0.57, 9), "b": Normal(1.0, 0.25)},
                   trials=400_000, rng=3, progress=False)
    u_mc = math.sqrt(0.57**2 * 9 / 7 + 0.25**2)
    assert abs(mc.std[0] / u_mc - 1) <= 4 * math.sqrt(1.2) / math.sqrt(2 * (400_000 - 1))


def test_welch_satterthwaite_function():
    nu = welch_satterthwaite(np.array([[1.0, 2.0]]), np.array([1.0, 1.0]), np.array([4.0, math.inf]))
    assert nu[0] == pytest.approx(25.0 / (1.0 / 4.0))
    assert welch_satterthwaite(np.array([[1.0]]), np.array([1.0]), np.array([math.inf]))[0] == math.inf


def test_budget_shares_sum_to_one_for_independent_inputs():
    inputs = {"a": Normal(1.0, 0.3), "b": Rectangular(0.0, 2.0), "c": StudentT(5.0, 0.1, 4)}
    g = linearize(lambda a, b, c: a * b + c**2, inputs)
    b = g.budget()
    assert list(b["input"]) == ["a", "b", "c"]
    assert b["share"].sum() == pytest.approx(1.0, rel=1e-12)
    np.testing.assert_allclose(b["contribution"], np.abs(b["sensitivity"]) * b["u_input"], rtol=1e-12)
    assert np.sqrt(np.sum(b["contribution"] ** 2)) == pytest.approx(g.std[0], rel=1e-12)


def test_correlated_vector_input():
    s1, s2, r = 0.3, 0.4, 0.6
    cov = [[s1 * s1, r * s1 * s2], [r * s1 * s2, s2 * s2]]
    g = linearize(lambda X: X[:, 0] + X[:, 1], {"X": MultivariateNormal([1.0, 2.0], cov)})
    assert g.std[0] == pytest.approx(math.sqrt(s1**2 + s2**2 + 2 * r * s1 * s2), rel=1e-9)
    assert g.inputs == ("X[0]", "X[1]") and g.groups == ("X", "X")
    b = g.budget()
    assert len(b) == 1 and b["share"].iloc[0] == pytest.approx(1.0)


def test_multiple_outputs_covariance():
    g = linearize(lambda a, b: {"s": a + b, "d": a - b}, {"a": Normal(0, 1.0), "b": Normal(0, 2.0)})
    assert g.names == ("s", "d")
    np.testing.assert_allclose(g.cov, [[5.0, -3.0], [-3.0, 5.0]], rtol=1e-9)


# ----------------------------------------------------------------- validation (clause 8)
ADD = lambda X1, X2, X3, X4: X1 + X2 + X3 + X4  # noqa: E731


def _additive(inputs, digits, seed=1):
    mc = propagate(ADD, inputs, trials=200_000, rng=seed, progress=False)
    return validate(mc, linearize(ADD, inputs), digits=digits)


def test_validation_passes_for_additive_normal():
    """JCGM 101 9.2.2: the GUF is validated (linear model, normal inputs)."""
    v = _additive({f"X{i}": Normal(0.0, 1.0) for i in range(1, 5)}, 2)
    assert v.valid
    t = v.table.iloc[0]
    assert t["delta"] == 0.05 and t["u_gum"] == pytest.approx(2.0)


def test_validation_fails_for_rectangular_at_three_digits():
    """JCGM 101 9.2.3: GUF [-3.92, 3.92] vs MCM [-3.88, 3.88]: valid to 2 digits, not 3."""
    inputs = {f"X{i}": Rectangular(-math.sqrt(3), math.sqrt(3)) for i in range(1, 5)}
    assert _additive(inputs, 2).valid
    v = _additive(inputs, 3)
    assert not v.valid
    assert v.table.iloc[0]["delta"] == pytest.approx(0.005)


def test_validation_fails_when_guf_u_is_zero():
    """JCGM 101 9.4 with x1 = 0: the GUF gives u = 0."""
    model = lambda X: X[:, 0] ** 2 + X[:, 1] ** 2  # noqa: E731
    inputs = {"X": MultivariateNormal([0.0, 0.0], np.eye(2) * 0.005**2)}
    mc = propagate(model, inputs, trials=50_000, rng=0, progress=False)
    g = linearize(model, inputs)
    assert g.std[0] == 0.0
    assert not validate(mc, g, digits=1).valid


# ----------------------------------------------------------------- bad arguments
def test_bad_arguments():
    inputs = {"a": Normal(0, 1)}
    f = lambda a: a  # noqa: E731
    with pytest.raises(InvalidInput, match="'coverage'"):
        linearize(f, inputs, coverage=1.5)
    with pytest.raises(InvalidInput, match="'dof'"):
        linearize(f, inputs, dof={"b": 3})
    with pytest.raises(InvalidInput, match="dof"):
        linearize(f, inputs, dof={"a": -1})
    with pytest.raises(InvalidInput, match="'model'"):
        linearize(None, inputs)
    with pytest.raises(InvalidInput, match="'inputs'"):
        linearize(f, [])
    mc = propagate(f, inputs, trials=1000, rng=0, progress=False)
    g = linearize(f, inputs)
    with pytest.raises(InvalidInput, match="'mc_result'"):
        validate(g, g)
    with pytest.raises(InvalidInput, match="'gum_result'"):
        validate(mc, mc)
    with pytest.raises(InvalidInput, match="'digits'"):
        validate(mc, g, digits=0)
    with pytest.raises(InvalidInput, match="'coverage'"):
        validate(mc, linearize(f, inputs, coverage=0.99))


def test_the_variance_without_the_covariance_is_its_diagonal():
    rng = np.random.default_rng(7)
    c, u = rng.normal(size=(40, 25)), rng.uniform(0.1, 2.0, 25)
    v = rng.normal(size=(25, 25))
    for cov in (None, v @ v.T):
        from mtplan.uncertainty.gum import GUMResult

        g = GUMResult(names=tuple(f"y{i}" for i in range(40)), inputs=tuple("x" * 25),
                      groups=tuple("ab"[j % 2] for j in range(25)), sensitivity=c,
                      input_std=u if cov is None else np.sqrt(np.diag(cov)),
                      dof=np.full(40, np.inf), input_cov=cov)
        variance = g.variance  # first: without the covariance formed (independent inputs)
        np.testing.assert_allclose(variance, np.diag(g.cov), rtol=1e-12)
        shares = {y: sum(p["share"] for p in parts.values()) for y, parts in g.by_source().items()}
        if cov is None:
            assert shares == pytest.approx({y: 1.0 for y in shares}, rel=1e-12)
