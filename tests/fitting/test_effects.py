"""How each source element moves each reading (mtplan.fitting.effects): the NaN probes and the
grouped rows give the element-by-element numbers."""

from __future__ import annotations

import numpy as np
import pytest

from mtplan.fitting import SourceModel, effects, source_effects
from mtplan.models.protocol import Source
from mtplan.uncertainty.distributions import Normal


def _model(n=48):
    """Readings of n points: their own noise (one reading each), a scale error (all of them)
    and a pair of offsets, each moving its half of the readings."""
    x = np.linspace(-1.0, 1.0, n)
    srcs = {"noise": Source(Normal(0.0, 2e-3), (n,)),
            "scale": Source(Normal(0.0, 1e-4)),
            "pair": Source(Normal(0.0, 5e-3), (2,))}

    def readings(err):
        half = np.where(x < 0, err["pair"][:, :1], err["pair"][:, 1:])
        return err["noise"] + (1.0 + err["scale"][:, None]) * x ** 3 + half

    def zero(m):
        return {k: np.zeros((m, *s.shape)) for k, s in srcs.items()}

    return SourceModel("toy", srcs, readings, zero)


def test_probed_and_grouped_effects_are_the_element_by_element_ones(monkeypatch):
    model = _model()
    probed = source_effects(model)  # the noise (48 elements) by NaN probes
    grouped = effects.secant_effects(model)  # every source from grouped rows
    monkeypatch.setattr(effects, "PROBE", 10**9)
    plain = source_effects(model)  # element by element
    for got in (probed, grouped):
        for a, b in zip(got, plain, strict=True):
            assert a.shape == b.shape
            np.testing.assert_allclose(a, b, rtol=1e-12, atol=0)
    D, U = plain
    np.testing.assert_allclose(D, 2e-3**2, rtol=1e-12)
    assert U.shape == (48, 3)  # the scale error and the two offsets: several readings each


def test_probes_name_the_element_of_every_reading():
    grouping = effects.Grouping(np.zeros(11, dtype=np.int64))
    bits, rows = effects.probe_rows(np.zeros(11), grouping)
    owner = np.array([3, 3, 10, -1, 0])  # readings 0-4 depend on these elements

    def reading(row):
        return np.array([row[3], 2 * row[3], row[10], 1.0, row[0]])

    pred = np.array([reading(r) for r in rows.reshape(-1, 11)])
    np.testing.assert_array_equal(effects.element_of(pred, 1, bits, 11)[0], owner)
    both = np.array([[r[3] + r[4]] for r in rows.reshape(-1, 11)])  # one reading, two elements
    assert effects.element_of(both, 1, bits, 11) is None


@pytest.mark.parametrize("rtol", [0.0, 1e-12])
def test_a_grouping_whose_readings_mix_elements_fails_the_check(rtol):
    f0 = np.zeros((1, 3))
    plus, minus = np.array([[1.0, 2.0, 0.0]]), np.array([[-1.0, -2.0, 0.0]])
    owner, sign = np.array([[0, 1, -1]]), np.array([1.0, -1.0])
    assert effects.grouped_ok(plus, minus, np.array([[1.0, -2.0, 0.0]]), f0, owner, sign,
                              rtol=rtol, rtol_free=0.0)
    assert not effects.grouped_ok(plus, minus, np.array([[1.0, -1.5, 0.0]]), f0, owner, sign,
                                  rtol=rtol, rtol_free=0.0)
