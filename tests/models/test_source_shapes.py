"""A source's distribution chosen by the study: the set-up field ``distributions`` that every
procedure declares, applied where the Monte Carlo draws (the source's sampler), never in
the GUM's first order, which uses the standard uncertainty alone."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mtplan._validate import InvalidInput
from mtplan.evaluation.first_order import first_order
from mtplan.models import get, registry
from mtplan.models.protocol import fields_info
from mtplan.uncertainty.distributions import SHAPES, Normal, with_shape

#: kurtosis of each shape (normal 3; rectangular 9/5; symmetric triangular 12/5; arcsine 3/2)
KURTOSIS = {"normal": 3.0, "rectangular": 1.8, "triangular": 2.4, "arcsine": 1.5}


@pytest.mark.parametrize("shape", SHAPES)
def test_a_shape_keeps_the_mean_and_u_and_draws_its_own_kurtosis(shape):
    d = with_shape(Normal(0.1, 0.02), shape)
    assert d.mean == pytest.approx(0.1, rel=1e-12) and d.std == pytest.approx(0.02, rel=1e-12)
    x = d.draw(np.random.default_rng(11), 200_000)
    z = (x - 0.1) / 0.02
    # the sample kurtosis's standard error is at most sqrt(24 / n) = 0.011 (the normal's,
    # the widest of the four): 0.05 is 4.5 of them; the std's is u / sqrt(2 n), 0.16 %
    assert np.mean(z**4) == pytest.approx(KURTOSIS[shape], abs=0.05)
    assert x.std() == pytest.approx(0.02, rel=0.01)


def test_every_procedure_declares_distributions_last():
    for name, proc in registry().items():
        infos = fields_info(proc.Setup)
        assert infos[-1].name == "distributions" and infos[-1].pairs == SHAPES, name


def _first_scalar_source(proc, setup) -> str:
    return next(n for n, s in proc.active_sources(setup).items()
                if not s.distribution.event_shape and s.size > 0)


@pytest.mark.parametrize("name", sorted(registry()))
def test_the_monte_carlo_draws_the_chosen_shape_and_first_order_does_not_change(name):
    proc = get(name)
    source = _first_scalar_source(proc, proc.Setup())
    setup = proc.Setup(distributions=f"{source}=rectangular")
    u = float(np.asarray(proc.sources(setup)[source].distribution.std).max())
    seq = np.random.SeedSequence(5)
    plain = proc.draw_errors(proc.Setup(), 4000, seq, [source])[source]
    flat = proc.draw_errors(setup, 4000, seq, [source])[source]
    # a rectangular of this u never leaves +-sqrt(3) u; a normal does in 8.3 % of draws
    # (of 4000 or more draws, fewer than 250 would be a 6-sigma event)
    mean = float(proc.sources(setup)[source].distribution.mean)
    assert np.all(np.abs(flat - mean) <= math.sqrt(3) * u * (1 + 1e-12))
    assert np.mean(np.abs(plain - mean) > math.sqrt(3) * u) > 250 / plain.size
    if name == "circle_centre":  # one cheap first order: the GUM uses u alone
        assert first_order(proc, setup).u() == first_order(proc, proc.Setup()).u()


def test_a_bad_name_or_shape_is_refused_naming_the_field():
    proc = get("circle_centre")
    with pytest.raises(InvalidInput, match="'distributions'.*'nope' is none of them"):
        proc.check_setup(proc.Setup(distributions="nope=rectangular"))
    for text in ("probe_noise=cauchy", "probe_noise", "probe_noise=normal,probe_noise=normal"):
        with pytest.raises(InvalidInput, match="'distributions'.*normal, rectangular"):
            proc.Setup(distributions=text)


def test_a_study_keeps_the_choice_through_the_designer():
    from mtplan.explore import design as d

    design = d.normalise({"procedure": "circle_centre",
                          "setup": {"distributions": "probe_noise=arcsine"}})
    text = d.study_toml(design)
    assert 'distributions = "probe_noise=arcsine"' in text
    assert d.design_from_study(text)["setup"]["distributions"] == "probe_noise=arcsine"
    bad = d.evaluate({"procedure": "circle_centre", "setup": {"distributions": "nope=arcsine"}})
    assert not bad["ok"] and "nope" in bad["field_errors"]["distributions"]
