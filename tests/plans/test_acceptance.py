"""Conformity assessment (JCGM 106, ISO 14253-1): published cases, cross-checks, bad input."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy import integrate, special, stats

from mtplan._validate import InvalidInput
from mtplan.plans.acceptance import (
    AcceptanceResult,
    DecisionRule,
    EmpiricalPrior,
    GammaPrior,
    NormalPrior,
    _bvn_cdf,
    acceptance_limits,
    cm,
    global_risks,
    guard_band,
    parse_prior,
    parse_rule,
    plan_acceptance,
    specific_risk,
    tur,
)


def printed(value: str) -> tuple[float, float]:
    """A published number and half a unit in its last printed digit."""
    decimals = len(value.split(".")[1]) if "." in value else 0
    return float(value), 0.5 * 10.0**-decimals


SQRT2PI = math.sqrt(2 * math.pi)
BEARING = GammaPrior(4, 0.25)  # JCGM 106 example: shape 4, scale 0.25 um
ITP95 = NormalPrior.from_in_tolerance(0.95, -1, 1)

# (label, function returning the computed value, published value as printed)
REFERENCE = [
    ("N(9.5,0.3) pfa", lambda: plan_acceptance(9, 10, 0.1, prior=NormalPrior(9.5, 0.3)).pfa, "0.0189422"),
    ("N(9.5,0.3) pfr", lambda: plan_acceptance(9, 10, 0.1, prior=NormalPrior(9.5, 0.3)).pfr, "0.0372078"),
    (
        "N(9.5,0.3) guard band for 0.5 % pfa",
        lambda: guard_band("target-pfa:0.005", 9, 10, 0.1, prior=NormalPrior(9.5, 0.3)),
        "0.0920660",
    ),
    ("bearing P(nonconforming)", lambda: 1 - plan_acceptance(None, 2, 0.25, prior=BEARING).p_conform_prior, "0.042380"),
    ("bearing pfa", lambda: plan_acceptance(None, 2, 0.25, prior=BEARING).pfa, "0.0080191"),
    ("bearing pfa, lower 0", lambda: plan_acceptance(0, 2, 0.25, prior=BEARING).pfa, "0.0080191"),
    (
        "bearing upper acceptance limit for 0.1 % pfa",
        lambda: acceptance_limits("target-pfa:0.001", None, 2, 0.25, prior=BEARING)[1],
        "1.67183",
    ),
    (
        "bearing upper acceptance limit for 0.1 % pfa, lower 0",
        lambda: acceptance_limits("target-pfa:0.001", 0, 2, 0.25, prior=BEARING)[1],
        "1.67183",
    ),
    ("ITP 0.95, TUR 4 pfa", lambda: plan_acceptance(-1, 1, 1 / 8, prior=ITP95).pfa, "0.0085827"),
    ("ITP 0.95, TUR 4 pfr", lambda: plan_acceptance(-1, 1, 1 / 8, prior=ITP95).pfr, "0.0155365"),
    ("ITP 0.95, TUR 4: tur", lambda: plan_acceptance(-1, 1, 1 / 8, prior=ITP95).tur, "4"),
    ("specific risk y = 9.8", lambda: plan_acceptance(9, 10, 0.1, measured=9.8).specific_risk, "0.022750"),
]


@pytest.mark.parametrize("label, compute, published", REFERENCE, ids=[r[0] for r in REFERENCE])
def test_published_cases(label, compute, published):
    value, tol = printed(published)
    assert compute() == pytest.approx(value, abs=tol)


def test_from_in_tolerance_prior():
    assert ITP95.prob_within(-1, 1) == pytest.approx(0.95, abs=1e-14)
    assert ITP95.mean == 0


# ------------------------------------------------------------------ exact versus quadrature


@pytest.mark.parametrize("seed", range(3))
def test_owens_t_bivariate_cdf_matches_quadrature(seed):
    rng = np.random.default_rng(seed)
    h, k = rng.normal(0, 2, (2, 40))
    h[:3] = 0.0
    k[1:5] = 0.0
    r = rng.uniform(-0.99, 0.99, 40)
    q = np.sqrt(1 - r**2)
    ours = _bvn_cdf(h, k, r, q)
    # P(X < h, Y < k) = int_{-inf}^{h} phi(x) Phi((k - r x) / q) dx
    ref = [
        integrate.quad(lambda x: math.exp(-0.5 * x * x) / SQRT2PI * special.ndtr((ki - ri * x) / qi), -np.inf, hi,
                       epsabs=1e-14, epsrel=1e-12)[0]
        for hi, ki, ri, qi in zip(h, k, r, q)
    ]
    np.testing.assert_allclose(ours, ref, atol=1e-12)
    # h k underflows to 0 for tiny h, k of the same sign (found by hypothesis)
    assert _bvn_cdf(-1e-190, -1e-190, 0.5, math.sqrt(0.75)) == pytest.approx(1 / 3)
    np.testing.assert_allclose(_bvn_cdf(h, np.inf, r, q), stats.norm.cdf(h), atol=1e-15)
    assert np.all(_bvn_cdf(-np.inf, k, r, q) == 0)


def quad_risks(prior_pdf, lo, hi, a_lo, a_hi, u, support=(-np.inf, np.inf)):
    """PFA and PFR by direct quadrature of pdf(x) * P(accept | x): an independent path."""

    def accept(x):
        return stats.norm.cdf(a_hi, x, u) - stats.norm.cdf(a_lo, x, u)

    def q(f, a, b):
        a, b = max(a, support[0]), min(b, support[1])
        return integrate.quad(f, a, b, epsabs=1e-14, limit=200)[0] if b > a else 0.0

    pfa = q(lambda x: prior_pdf(x) * accept(x), -np.inf, lo) + q(lambda x: prior_pdf(x) * accept(x), hi, np.inf)
    pfr = q(lambda x: prior_pdf(x) * (1 - accept(x)), lo, hi)
    return pfa, pfr


CASES = [
    # prior, lower, upper, u, acceptance limits
    (NormalPrior(9.5, 0.3), 9, 10, 0.1, (9.05, 9.95)),
    (NormalPrior(0.2, 0.5), -1, 1, 0.3, (-0.8, 1.1)),
    (NormalPrior(1.0, 0.05), None, 1.1, 0.02, (None, 1.08)),
    (NormalPrior(1.0, 2.0), 0.0, None, 0.5, (0.5, None)),
    (GammaPrior(4, 0.25), None, 2, 0.25, (None, 1.8)),
    (GammaPrior(1.5, 2.0), 0.5, 6, 0.7, (1.0, 5.0)),
]


@pytest.mark.parametrize("prior, lower, upper, u, acc", CASES)
def test_risks_match_direct_quadrature(prior, lower, upper, u, acc):
    g = global_risks(lower, upper, u, prior, acceptance=acc)
    lo, hi = (-np.inf if lower is None else lower), (np.inf if upper is None else upper)
    a_lo, a_hi = (-np.inf if acc[0] is None else acc[0]), (np.inf if acc[1] is None else acc[1])
    support = (0, np.inf) if isinstance(prior, GammaPrior) else (-np.inf, np.inf)
    pfa, pfr = quad_risks(prior.pdf, lo, hi, a_lo, a_hi, u, support)
    assert g.pfa == pytest.approx(pfa, rel=1e-7, abs=1e-13)
    assert g.pfr == pytest.approx(pfr, rel=1e-7, abs=1e-13)
    assert g.p_accept == pytest.approx(g.pfa + g.p_conform - g.pfr, abs=1e-12)


@pytest.mark.parametrize("prior, lower, upper, u, acc", CASES)
def test_risks_match_monte_carlo(prior, lower, upper, u, acc):
    n = 400_000
    rng = np.random.default_rng(20240)
    x = prior.sample(n, rng)
    y = x + u * rng.standard_normal(n)
    lo, hi = (-np.inf if lower is None else lower), (np.inf if upper is None else upper)
    a_lo, a_hi = (-np.inf if acc[0] is None else acc[0]), (np.inf if acc[1] is None else acc[1])
    conform = (x >= lo) & (x <= hi)
    accept = (y >= a_lo) & (y <= a_hi)
    g = global_risks(lower, upper, u, prior, acceptance=acc)
    for exact, hits in ((g.pfa, ~conform & accept), (g.pfr, conform & ~accept)):
        sd = math.sqrt(max(exact * (1 - exact), 1e-12) / n)
        assert abs(hits.mean() - exact) < 5 * sd


def test_empirical_prior_is_a_kernel_mixture():
    values = np.random.default_rng(3).normal(9.5, 0.3, 200)
    prior = EmpiricalPrior(values)
    h = np.std(values, ddof=1) * values.size ** -0.2
    kde = stats.gaussian_kde(values)
    xs = np.linspace(8.5, 10.5, 9)
    np.testing.assert_allclose(prior.pdf(xs), kde(xs), rtol=1e-10)
    assert integrate.quad(prior.pdf, 7, 12)[0] == pytest.approx(1, abs=1e-9)
    g = global_risks(9, 10, 0.1, prior, acceptance=(9.05, 9.95))
    pfa, pfr = quad_risks(prior.pdf, 9, 10, 9.05, 9.95, 0.1)
    assert g.pfa == pytest.approx(pfa, rel=1e-7)
    assert g.pfr == pytest.approx(pfr, rel=1e-7)
    assert prior.cdf(9.5) == pytest.approx(np.mean(stats.norm.cdf(9.5, values, h)))


def test_empirical_prior_with_zero_bandwidth_is_the_sample():
    values = np.array([8.9, 9.2, 9.5, 9.7, 10.0, 10.2])
    prior = EmpiricalPrior(values, bandwidth=0)
    u = 0.1
    g = global_risks(9, 10, u, prior)
    p_acc = stats.norm.cdf(10, values, u) - stats.norm.cdf(9, values, u)
    conform = (values >= 9) & (values <= 10)  # 10.0 sits on the limit and conforms
    assert g.pfa == pytest.approx(np.mean(np.where(~conform, p_acc, 0)), rel=1e-12)
    assert g.pfr == pytest.approx(np.mean(np.where(conform, 1 - p_acc, 0)), rel=1e-12)
    assert g.p_conform == pytest.approx(4 / 6)
    w = stats.norm.pdf(9.95, values, u)
    assert specific_risk(9.95, 9, 10, u, prior=prior) == pytest.approx(w[~conform].sum() / w.sum())


def test_specific_risk_with_priors():
    # normal prior: the posterior is normal
    m, s, u, y = 9.5, 0.3, 0.1, 9.95
    pm = (m * u**2 + y * s**2) / (s**2 + u**2)
    ps = s * u / math.hypot(s, u)
    exact = stats.norm.cdf(9, pm, ps) + stats.norm.sf(10, pm, ps)
    assert specific_risk(y, 9, 10, u, prior=NormalPrior(m, s)) == pytest.approx(exact, rel=1e-10)
    # gamma prior: direct quadrature of prior x likelihood
    for y in (0.3, 1.8, 2.2, 3.0):
        f = lambda x: BEARING.pdf(x) * stats.norm.pdf(y, x, 0.25)  # noqa: E731
        num = integrate.quad(f, 2, 20, epsabs=1e-15)[0]
        den = integrate.quad(f, 0, 2, epsabs=1e-15)[0] + num
        r = plan_acceptance(None, 2, 0.25, prior=BEARING, measured=y)
        assert r.specific_risk == pytest.approx(num / den, rel=1e-7)
        assert r.p_conform == pytest.approx(1 - num / den, rel=1e-7)


def test_specific_risk_without_prior_is_the_likelihood():
    assert specific_risk(9.8, 9, 10, 0.1) == pytest.approx(stats.norm.sf(2), rel=1e-12)
    assert specific_risk(1.9, None, 2, 0.1) == pytest.approx(stats.norm.sf(1), rel=1e-12)
    assert specific_risk(10.3, 9, 10, 0.1) == pytest.approx(stats.norm.cdf(3), rel=1e-12)


# ------------------------------------------------------------------ decision rules


def test_rule_guard_bands():
    u = 0.1
    assert guard_band("simple", 9, 10, u) == 0
    assert guard_band("guard:0.5", 9, 10, u) == pytest.approx(0.1)
    assert guard_band("iso14253", 9, 10, u) == pytest.approx(0.2)
    assert acceptance_limits("iso14253", 9, 10, u) == pytest.approx((9.2, 9.8))
    assert acceptance_limits("guard:1", None, 2, 0.25) == (None, pytest.approx(1.5))
    assert acceptance_limits("guard:1", 0.3, None, 0.1) == (pytest.approx(0.5), None)


@pytest.mark.parametrize("t", [1.0, 2.0, 3.0, 4.0, 4.5, 6.0])
def test_dobbert_managed_guard_band(t):
    u = 1 / (2 * t)  # tolerance +-1, TUR = 2 / (4 u)
    assert tur(-1, 1, u) == pytest.approx(t)
    multiplier = max(1.04 - math.exp(0.38 * math.log(t) - 0.54), 0.0)
    assert guard_band("dobbert", -1, 1, u) == pytest.approx(multiplier * 2 * u)
    # Dobbert's claim: pfa <= 2 % whatever the in-tolerance probability (centred normal)
    worst = max(
        plan_acceptance(-1, 1, u, prior=NormalPrior.from_in_tolerance(p, -1, 1), rule="dobbert").pfa
        for p in np.linspace(0.3, 0.999, 60)
    )
    assert worst <= 0.0200


def test_target_pfa_reaches_target_and_never_relaxes():
    prior = NormalPrior(9.5, 0.3)
    for target in (0.001, 0.005, 0.015):
        r = plan_acceptance(9, 10, 0.1, prior=prior, rule=f"target-pfa:{target}")
        assert r.pfa == pytest.approx(target, rel=1e-9)
        assert r.acceptance_limits[0] - 9 == pytest.approx(10 - r.acceptance_limits[1])
    r = plan_acceptance(9, 10, 0.1, prior=prior, rule="target-pfa:0.05")  # simple gives 0.0189
    assert r.guard_band == 0 and r.acceptance_limits == (9, 10)
    r = plan_acceptance(0.0, None, 0.5, prior=NormalPrior(3, 1.0), rule="target-pfa:1e-6")
    assert r.pfa == pytest.approx(1e-6, rel=1e-7)
    assert r.acceptance_limits[1] is None


def test_capability_and_result_dict():
    assert cm(9, 10, 0.1) == pytest.approx(2.5)
    assert tur(9, 10, 0.1) == pytest.approx(2.5)
    assert tur(None, 2, 0.25) is None and cm(None, 2, 0.25) is None
    r = plan_acceptance(None, 2, 0.25, prior=BEARING, rule="guard:0.5", measured=1.9)
    assert isinstance(r, AcceptanceResult)
    d = r.to_dict()
    assert list(d) == ["acceptance_limits", "specific_risk", "pfa", "pfr", "conditional_pfa", "tur", "cm"]
    assert d["acceptance_limits"] == [None, pytest.approx(1.75)]
    assert d["tur"] is None
    assert r.decision == "reject"
    assert r.conditional_pfa == pytest.approx(r.pfa / r.p_accept)
    json.dumps(d, allow_nan=False)
    no_prior = plan_acceptance(9, 10, 0.1).to_dict()
    assert no_prior["pfa"] is None and no_prior["specific_risk"] is None
    json.dumps(no_prior, allow_nan=False)


# ------------------------------------------------------------------ parsing


def test_parse_prior_text_and_csv(tmp_path):
    assert parse_prior("normal:9.5,0.3") == NormalPrior(9.5, 0.3)
    assert parse_prior(" Gamma: 4 , 2.5e-1 ") == GammaPrior(4, 0.25)
    values = [9.4, 9.6, 9.5, 9.55, 9.45]
    (tmp_path / "named.csv").write_text("machine,value\n" + "".join(f"m{i},{v}\n" for i, v in enumerate(values)))
    (tmp_path / "one.csv").write_text("EXX_um\n" + "\n".join(map(str, values)) + "\n")
    (tmp_path / "bare.csv").write_text("\n".join(map(str, values)) + "\n")
    for name in ("named.csv", "one.csv", "bare.csv"):
        prior = parse_prior(str(tmp_path / name))
        assert isinstance(prior, EmpiricalPrior)
        np.testing.assert_allclose(np.sort(prior.values), np.sort(values))


@pytest.mark.parametrize(
    "text",
    ["", "normal:9.5", "normal:9.5,-0.3", "gamma:0,1", "lognormal:1,2", "normal:a,b", "missing.csv", 3.0],
)
def test_parse_prior_bad_text(text):
    with pytest.raises(InvalidInput) as err:
        parse_prior(text)
    assert "\n" not in str(err.value) and "prior" in str(err.value)


def test_parse_prior_bad_csv(tmp_path):
    (tmp_path / "two.csv").write_text("a,b\n1,2\n3,4\n")
    (tmp_path / "text.csv").write_text("value\n1.0\nabc\n2.0\n")
    (tmp_path / "const.csv").write_text("value\n1.0\n1.0\n")
    for name in ("two.csv", "text.csv", "const.csv"):
        with pytest.raises(InvalidInput) as err:
            parse_prior(str(tmp_path / name))
        assert "\n" not in str(err.value) and name in str(err.value)


def test_parse_rule():
    assert parse_rule("simple") == DecisionRule("simple")
    assert parse_rule(" Guard:0.5 ") == DecisionRule("guard", 0.5)
    assert parse_rule("target-pfa:0.02") == DecisionRule("target-pfa", 0.02)
    assert parse_rule("ISO14253") == DecisionRule("iso14253")
    assert parse_rule("dobbert") == DecisionRule("dobbert")
    for bad in ("", "guard", "guard:-1", "target-pfa:0", "target-pfa:1.5", "shared", "guard:x", None):
        with pytest.raises(InvalidInput) as err:
            parse_rule(bad)
        assert "\n" not in str(err.value) and "'rule'" in str(err.value)


# ------------------------------------------------------------------ bad input


def test_every_problem_is_reported_at_once():
    with pytest.raises(InvalidInput) as err:
        plan_acceptance(2, 1, -0.1, measured=float("nan"))
    names = " ".join(err.value.problems)
    assert len(err.value.problems) == 3
    assert "'upper'" in names and "'u'" in names and "'measured'" in names


def test_rule_specific_errors():
    with pytest.raises(InvalidInput, match="prior"):
        plan_acceptance(9, 10, 0.1, rule="target-pfa:0.01")
    with pytest.raises(InvalidInput, match="two-sided"):
        plan_acceptance(None, 2, 0.25, rule="dobbert")
    with pytest.raises(InvalidInput, match="no acceptance interval"):
        plan_acceptance(9, 10, 0.2, rule="guard:2")
    with pytest.raises(InvalidInput, match="lower"):
        plan_acceptance(None, None, 0.1)
    with pytest.raises(InvalidInput, match="prior"):
        plan_acceptance(9, 10, 0.1, prior=object())



def test_specific_risk_far_outside_the_prior_stays_finite():
    # posterior of a gamma prior for measured values far in its tails (log-space scaling)
    assert specific_risk(-50.0, None, 2, 0.25, prior=BEARING) == pytest.approx(0, abs=1e-12)
    assert specific_risk(50.0, None, 2, 0.25, prior=BEARING) == pytest.approx(1, abs=1e-12)


finite = st.floats(-1e3, 1e3, allow_nan=False)
bad_number = st.one_of(st.just(float("nan")), st.just(float("inf")), st.just("1"), st.none(), st.booleans())


@settings(max_examples=40, deadline=None)
@given(lower=finite, width=st.floats(-10, 0), u=st.floats(0.01, 1))
def test_reversed_limits_raise(lower, width, u):
    with pytest.raises(InvalidInput):
        plan_acceptance(lower, lower + width, u)


@settings(max_examples=40, deadline=None)
@given(u=st.one_of(st.floats(max_value=0, allow_nan=False), bad_number))
def test_bad_uncertainty_raises(u):
    with pytest.raises(InvalidInput, match="'u'"):
        plan_acceptance(9, 10, u)


@settings(max_examples=40, deadline=None)
@given(mean=st.one_of(finite, bad_number), sd=st.one_of(st.floats(-5, 0), bad_number))
def test_bad_normal_prior_raises(mean, sd):
    with pytest.raises(InvalidInput):
        NormalPrior(mean, sd)


@settings(max_examples=40, deadline=None)
@given(shape=st.one_of(st.floats(-5, 0), bad_number), scale=st.floats(0.1, 5))
def test_bad_gamma_prior_raises(shape, scale):
    with pytest.raises(InvalidInput, match="'shape'"):
        GammaPrior(shape, scale)


priors = st.one_of(
    st.builds(NormalPrior, st.floats(-2, 2), st.floats(0.05, 3)),
    st.builds(GammaPrior, st.floats(0.5, 8), st.floats(0.05, 1)),
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    prior=priors,
    lower=st.floats(-1.5, 0.5),
    width=st.floats(0.5, 3),
    u=st.floats(0.01, 0.5),
    one_sided=st.booleans(),
)
def test_risks_are_probabilities_and_guard_bands_are_monotone(prior, lower, width, u, one_sided):
    upper = lower + width
    lo = None if one_sided else lower
    half = width / 2 if not one_sided else 4 * width
    pfa, pfr = [], []
    for w in np.linspace(0, 0.95 * half, 6):
        acc = (None if lo is None else lower + w, upper - w)
        g = global_risks(lo, upper, u, prior, acceptance=acc)
        assert 0 <= g.pfa <= 1 - g.p_conform + 1e-12
        assert 0 <= g.pfr <= g.p_conform + 1e-12
        assert 0 <= g.p_accept <= 1
        pfa.append(g.pfa)
        pfr.append(g.pfr)
    assert np.all(np.diff(pfa) <= 1e-12), pfa  # wider guard band: fewer false accepts
    assert np.all(np.diff(pfr) >= -1e-12), pfr  # ... and more false rejects


def test_prior_sampling_is_seeded():
    for prior in (NormalPrior(1, 2), GammaPrior(4, 0.25), EmpiricalPrior([1.0, 2.0, 4.0])):
        a = prior.sample(50_000, 7)
        np.testing.assert_array_equal(a, prior.sample(50_000, np.random.default_rng(7)))
        assert a.shape == (50_000,)
    x = GammaPrior(4, 0.25).sample(100_000, 1)
    assert x.mean() == pytest.approx(1.0, abs=4 * 0.5 / math.sqrt(1e5))


def test_a_subnormal_prior_mean_is_the_limit_of_zero():
    # found by hypothesis: Owen's a = (k - r h) / (h q) overflowed for h ~ 1e-311
    near = global_risks(0.0, 0.5, 0.01, NormalPrior(2.2e-311, 1), acceptance=(0.0, 0.5))
    zero = global_risks(0.0, 0.5, 0.01, NormalPrior(0.0, 1), acceptance=(0.0, 0.5))
    assert near.pfa == pytest.approx(zero.pfa, rel=1e-9)
    assert near.pfr == pytest.approx(zero.pfr, rel=1e-9)


def test_an_agreed_guard_band_is_the_printed_one_rounded_up():
    """A plan states w to the digits its U supports; the decision uses that w, rounded up so
    the acceptance zone is never wider than the rule's (and the consumer's risk no higher)."""
    from mtplan.plans.acceptance import agreed_resolution

    assert agreed_resolution(3.4167, 10_000) == pytest.approx(0.1)   # U 6.8: two digits
    assert agreed_resolution(3.4167, 3) == pytest.approx(1.0)        # U's MC error 3.4
    assert agreed_resolution(0.0493, 2_000) == pytest.approx(0.001)
    prior = NormalPrior(0.0, 4.0)
    exact = plan_acceptance(-12, 12, 3.4167, prior=prior, rule="iso14253")
    step = agreed_resolution(3.4167, 10_000)
    agreed = plan_acceptance(-12, 12, 3.4167, prior=prior, rule="iso14253", resolution=step)
    assert agreed.guard_band == 6.9 and exact.guard_band == pytest.approx(6.8334)
    assert agreed.acceptance_limits == pytest.approx((-5.1, 5.1), abs=1e-12)
    assert f"{agreed.acceptance_limits[1]:.1f}" == "5.1"
    assert agreed.pfa < exact.pfa and agreed.pfr > exact.pfr
    # a w already on the step stays; the simple rule's zero stays zero
    assert plan_acceptance(-12, 12, 3.4, rule="iso14253", resolution=0.1).guard_band == 6.8
    assert plan_acceptance(-12, 12, 3.4167, rule="simple", resolution=0.1).guard_band == 0.0
    # a w the rounding takes to half the tolerance leaves no zone: refused, in plain numbers
    with pytest.raises(InvalidInput, match=r"guard band 400 that leaves no acceptance"):
        plan_acceptance(-400, 400, 199.19, rule="iso14253", resolution=10.0)
