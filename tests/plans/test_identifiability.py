"""Identifiability (rank, null space, observability indices O1-O5) and design criteria."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from mtplan._validate import InvalidInput
from mtplan.plans.identifiability import (
    a_optimality,
    d_optimality,
    e_optimality,
    identifiability,
    information_matrix,
    observability_indices,
)

# issue 8: singular values [4, 2, 1] of a 5-pose design
ISSUE_REFERENCE = {"O1": "0.8944", "O2": "0.25", "O3": "1", "O4": "0.25", "O5": "0.5714"}


def with_singular_values(s, n_rows, seed=0):
    """A matrix of shape (n_rows, len(s)) with the given singular values."""
    rng = np.random.default_rng(seed)
    u, _ = np.linalg.qr(rng.normal(size=(n_rows, len(s))))
    v, _ = np.linalg.qr(rng.normal(size=(len(s), len(s))))
    return u @ np.diag(s) @ v.T


@pytest.mark.parametrize("name, published", ISSUE_REFERENCE.items())
def test_issue_reference_indices(name, published):
    decimals = len(published.split(".")[1]) if "." in published else 0
    value = observability_indices([4, 2, 1], 5)[name]
    assert value == pytest.approx(float(published), abs=0.5 * 10.0**-decimals)


def test_index_definitions_exactly():
    o = observability_indices([1, 4, 2], 5)  # order does not matter
    assert o["O1"] == pytest.approx(2 / math.sqrt(5), rel=1e-15)  # (4*2*1)^(1/3) / sqrt(5)
    assert o["O2"] == 0.25 and o["O3"] == 1.0 and o["O4"] == 0.25
    assert o["O5"] == pytest.approx(1 / (1 / 4 + 1 / 2 + 1), rel=1e-15)
    assert observability_indices([3, 0], 4) == {"O1": 0, "O2": 0, "O3": 0, "O4": 0, "O5": 0}


def test_identifiability_of_a_matrix_with_known_singular_values():
    j = with_singular_values([4.0, 2.0, 1.0], 5)
    r = identifiability(j, scale=np.ones(3), names=["EX0C", "EB0C", "EC0C"])
    np.testing.assert_allclose(r.singular_values, [4, 2, 1], rtol=1e-12)
    assert r.rank == 3 and r.identifiable
    assert r.condition_number == pytest.approx(4)
    assert r.null_combinations == [] and r.null_space.shape == (3, 0)
    expected = observability_indices([4, 2, 1], 5)
    for k, v in expected.items():
        assert r.observability[k] == pytest.approx(v, rel=1e-12)
    json.dumps(r.to_dict(), allow_nan=False)


def test_null_space_names_the_inseparable_combination():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(12, 3))
    # fourth parameter acts exactly like p0 - 2 p1 (in its own units)
    j = np.column_stack([a, a[:, 0] - 2.0 * a[:, 1]])
    r = identifiability(j, names=["EX0C", "EB0C", "EC0C", "EXX"])
    assert r.rank == 3 and not r.identifiable
    assert math.isinf(r.condition_number) and r.to_dict()["condition_number"] is None
    assert all(v == 0 for v in r.observability.values())
    v = r.null_space[:, 0]
    np.testing.assert_allclose(j @ v, 0, atol=1e-12)
    np.testing.assert_allclose(v / v[1], [-0.5, 1, 0, 0.5], atol=1e-12)
    assert r.null_combinations == ["-0.5*EX0C + EB0C + 0.5*EXX"]
    # parameter scales change the indices but not the physical null direction
    r2 = identifiability(j, scale=[1, 10, 1, 0.1], names=["EX0C", "EB0C", "EC0C", "EXX"])
    np.testing.assert_allclose(r2.null_space, r.null_space, atol=1e-12)


def test_zero_column_and_short_matrix():
    j = np.array([[1.0, 0.0, 2.0], [3.0, 0.0, -1.0], [0.5, 0.0, 0.0]])
    r = identifiability(j, names=["a", "b", "c"])
    assert r.rank == 2 and r.null_combinations == ["b"]
    short = identifiability(np.array([[1.0, 2.0, 3.0]]))
    assert short.rank == 1 and len(short.null_combinations) == 2
    assert short.singular_values.shape == (1,)


def test_rank_tolerance_is_relative():
    j = with_singular_values([1.0, 1e-3, 1e-9], 6)
    assert identifiability(j, scale=np.ones(3)).rank == 3
    r = identifiability(j, scale=np.ones(3), tol=1e-6)
    assert r.rank == 2 and r.tol == 1e-6 and len(r.null_combinations) == 1


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    exponents=st.lists(st.integers(-6, 6), min_size=3, max_size=3),
)
def test_default_scaling_makes_indices_unit_free(seed, exponents):
    j = np.random.default_rng(seed).normal(size=(8, 3))
    units = 10.0 ** np.array(exponents)  # re-express each parameter in other units
    a = identifiability(j)
    b = identifiability(j / units)
    np.testing.assert_allclose(b.singular_values, a.singular_values, rtol=1e-9)
    for k in a.observability:
        assert b.observability[k] == pytest.approx(a.observability[k], rel=1e-9)


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"J": [1.0, 2.0]}, "'J'"),
        ({"J": [[1.0, float("nan")]]}, "'J'"),
        ({"J": [[1.0, 2.0]], "scale": [1.0, -1.0]}, "'scale'"),
        ({"J": [[1.0, 2.0]], "scale": [1.0]}, "'scale'"),
        ({"J": [[1.0, 2.0]], "names": ["a"]}, "'names'"),
        ({"J": [[1.0, 2.0]], "tol": 1.0}, "'tol'"),
        ({"J": [[1.0, 2.0]], "n_poses": 0}, "'n_poses'"),
    ],
)
def test_bad_input(kwargs, field):
    j = kwargs.pop("J")
    with pytest.raises(InvalidInput, match=field):
        identifiability(j, **kwargs)


def test_all_problems_at_once():
    with pytest.raises(InvalidInput) as err:
        identifiability([[1.0, 2.0]], scale=[0, 1], names=["a"], tol=-1)
    assert len(err.value.problems) == 3


@pytest.mark.parametrize("s, n", [([], 3), ([1.0, -1.0], 3), ([1.0, float("inf")], 3), ([1.0], 0), ([1.0], 2.5)])
def test_bad_singular_values(s, n):
    with pytest.raises(InvalidInput):
        observability_indices(s, n)


def test_design_criteria():
    m = np.diag([4.0, 2.0, 0.5])
    assert d_optimality(m) == pytest.approx(math.log(4.0))
    assert a_optimality(m) == pytest.approx(0.25 + 0.5 + 2.0)
    assert e_optimality(m) == pytest.approx(0.5)
    singular = np.diag([1.0, 0.0])
    assert d_optimality(singular) == -math.inf
    assert a_optimality(singular) == math.inf
    assert e_optimality(singular) == 0.0
    with pytest.raises(InvalidInput, match="symmetric"):
        d_optimality([[1.0, 2.0], [0.0, 1.0]])
    with pytest.raises(InvalidInput, match="square"):
        e_optimality([[1.0, 2.0]])


def test_information_matrix_and_criteria_agree_with_indices():
    j = with_singular_values([4.0, 2.0, 1.0], 5, seed=3)
    m = information_matrix(j, sigma=0.5)
    np.testing.assert_allclose(m, j.T @ j / 0.25, rtol=1e-12)
    m1 = information_matrix(j)
    o = observability_indices([4, 2, 1], 5)
    assert e_optimality(m1) == pytest.approx(o["O3"] ** 2)
    assert d_optimality(m1) == pytest.approx(2 * math.log(8.0))
    assert a_optimality(m1) == pytest.approx(1 / 16 + 1 / 4 + 1)
    np.testing.assert_allclose(information_matrix(j, sigma=[1, 2, 1, 1, 1]), j.T @ np.diag([1, 0.25, 1, 1, 1]) @ j)
    with pytest.raises(InvalidInput, match="'sigma'"):
        information_matrix(j, sigma=[1.0, 0.0, 1.0, 1.0, 1.0])


def test_functions_the_observations_determine():
    """p2 acts like p0 + p1 (null direction (1, 1, -1)): a function is determined exactly
    when it is orthogonal to it, whatever the columns' scale."""
    a = np.random.default_rng(2).normal(size=(10, 2))
    j = np.column_stack([a, a[:, 0] + a[:, 1]])
    funcs = {"p0 + p2": [1, 0, 1], "p0": [1, 0, 0], "p0 - p1": [1, -1, 0], "zero": [0, 0, 0]}
    expect = {"p0 + p2": True, "p0": False, "p0 - p1": True, "zero": True}
    for scale in (None, [1.0, 1e3, 1e-2]):
        r = identifiability(j, scale=scale, functions=funcs)
        assert r.rank == 2 and r.determined == expect
    d = r.to_dict()
    assert d["determined"] == ["p0 + p2", "p0 - p1", "zero"] and d["undetermined"] == ["p0"]
    json.dumps(d, allow_nan=False)
    assert identifiability(j).determined == {}


def test_functions_must_have_one_weight_per_parameter():
    with pytest.raises(InvalidInput, match=r"functions\['f'\]"):
        identifiability([[1.0, 2.0]], functions={"f": [1.0, 2.0, 3.0]})


def test_tall_matrix_null_space_and_singular_values():
    """A tall matrix goes through its QR's R: same singular values and null space."""
    j = with_singular_values([5.0, 2.0, 0.0], 400, seed=4)
    r = identifiability(j, scale=np.ones(3))
    np.testing.assert_allclose(r.singular_values, np.linalg.svd(j, compute_uv=False), atol=1e-12)
    assert r.rank == 2
    np.testing.assert_allclose(j @ r.null_space, 0, atol=1e-12)
