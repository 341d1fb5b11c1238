"""The shared fitting machinery: readings' covariance, GLS gain and Gauss-Newton, fit check."""

from __future__ import annotations

import numpy as np
import pytest

from mtplan._validate import InvalidInput
from mtplan.fitting import (
    DENSE_MAX,
    Gaussian,
    SourceModel,
    central_jacobian,
    gauss_newton,
    gls_gain,
    gls_step,
    readings_covariance,
    source_effects,
    whitened_residuals,
)
from mtplan.fitting.effects import estimator_map
from mtplan.fitting.linear import truncated_pinv
from mtplan.models.protocol import Source
from mtplan.uncertainty.distributions import Normal, Rectangular


def _dense(D, U):
    return np.diag(D) + U @ U.T


def _random_budget(n, k, seed):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.5, 2.0, n) * 1e-6, rng.normal(size=(n, k)) * 1e-3


@pytest.mark.parametrize("n", [40, DENSE_MAX + 500])
def test_gls_gain_is_the_weighted_normal_equations(n):
    D, U = _random_budget(n, 6, 1)
    J = np.random.default_rng(2).normal(size=(n, 3))
    ci = np.linalg.inv(_dense(D, U))
    expect = np.linalg.solve(J.T @ ci @ J, J.T @ ci)
    got = gls_gain(J, (D, U))
    assert np.allclose(got, expect, rtol=1e-7, atol=1e-9 * np.abs(expect).max())


@pytest.mark.parametrize("n", [40, DENSE_MAX + 500])
def test_the_gaussian_is_the_dense_normal(n):
    D, U = _random_budget(n, 5, 3)
    U[:, -1] = 0.0  # a column without effect is dropped, not divided by
    g = Gaussian.known(D, U)
    C = _dense(D, U)
    R = np.random.default_rng(4).normal(size=(3, n)) * 1e-3
    quad = np.einsum("ij,ij->i", R @ np.linalg.inv(C), R)
    expect = -0.5 * (quad + np.linalg.slogdet(C)[1] + n * np.log(2 * np.pi))
    assert np.allclose(g.loglike(R), expect, rtol=1e-10, atol=1e-8)
    assert np.allclose(np.einsum("ij,ij->i", g.whiten(R), g.whiten(R)), quad, rtol=1e-10)
    assert np.allclose(g.inverse_times(R), R @ np.linalg.inv(C), rtol=1e-8,
                       atol=1e-10 * np.abs(R @ np.linalg.inv(C)).max())


def test_a_path_correlated_source_joins_the_gaussian_s_block_diagonal_base():
    """Elements confined to short passes of readings (an AR(1) scatter along a path), with
    a few that touch every reading: the base is block-diagonal, the rest low rank, and the
    log-likelihood, whitening, C^-1 and the fit check's pieces are the dense normal's."""
    from mtplan.evaluation.fitcheck import _cinv_diag, _wt

    n, rng = DENSE_MAX + 400, np.random.default_rng(7)
    D = rng.uniform(0.5, 2.0, n) * 1e-6
    cols = []
    for start in range(0, n, 40):  # passes of 40 readings, 10 innovations each
        for j in range(10):
            c = np.zeros(n)
            c[start + j: start + 40] = 0.8 ** np.arange(40 - j) * 1e-3
            cols.append(c)
    U = np.column_stack([*cols, rng.normal(size=(n, 4)) * 1e-3])
    g = Gaussian.known(D, U)
    assert g.wb is not None and g.q.shape[1] == 4
    C = _dense(D, U)
    Ci = np.linalg.inv(C)
    R = rng.normal(size=(3, n)) * 1e-3
    quad = np.einsum("ij,ij->i", R @ Ci, R)
    expect = -0.5 * (quad + np.linalg.slogdet(C)[1] + n * np.log(2 * np.pi))
    assert np.allclose(g.loglike(R), expect, rtol=1e-10, atol=1e-8)
    assert np.allclose(np.einsum("ij,ij->i", g.whiten(R), g.whiten(R)), quad, rtol=1e-10)
    assert np.allclose(g.inverse_times(R), R @ Ci, rtol=1e-8, atol=1e-10 * np.abs(R @ Ci).max())
    assert np.allclose(_cinv_diag(g), np.diag(Ci), rtol=1e-8)
    V = rng.normal(size=(n, 2))
    assert np.allclose(_wt(g, V), g.whiten(np.eye(n)) @ V, rtol=1e-8, atol=1e-12)


def _linear_model(n=12):
    """Readings A e of a scale error (1 element), a shared offset (2) and noise (n)."""
    x = np.linspace(-1.0, 1.0, n)
    srcs = {"noise": Source(Normal(0.0, 2e-3), (n,)), "scale": Source(Normal(0.0, 1e-4), ()),
            "offset": Source(Rectangular(0.0, 3e-3), (2,)), "off": Source(Normal(0.0, 0.0), ())}

    def readings(err):
        return (err["noise"] + err["scale"][:, None] * 100 * x
                + err["offset"][:, :1] + err["offset"][:, 1:] * x)

    def zero(m):
        return {k: np.zeros((m, *s.shape)) for k, s in srcs.items()}

    return SourceModel("toy", srcs, readings, zero), x, srcs


def test_the_readings_covariance_of_a_linear_model_is_exact():
    model, x, srcs = _linear_model()
    D, U = source_effects(model)
    sd_o = float(srcs["offset"].distribution.std)
    A = np.column_stack([100 * x * 1e-4, np.ones_like(x) * sd_o, x * sd_o])
    expect = np.diag(np.full(x.size, 2e-3**2)) + A @ A.T
    assert np.allclose(_dense(D, U), expect, rtol=1e-10, atol=1e-16)
    g = readings_covariance(model, floor=1e-9)
    assert g.mode == "dense" and np.isclose(g.logdet, np.linalg.slogdet(expect)[1], rtol=1e-6)


def _patches(structure=None, rows=None):
    """Readings in 8 patches of 5; element (p, k) of a 'patch' source moves reading k and
    k + 1 of patch p (non-linearly: a square beside the linear term), so that the readings
    of a patch depend on two elements. Colouring: k even / odd never share a reading, and
    patches never share one either (the colour of an element is k % 2)."""
    n_p, per = 8, 5
    srcs = {"patch": Source(Normal(0.0, 1e-3), (n_p, per - 1), "patch errors"),
            "noise": Source(Normal(0.0, 1e-4), (n_p * per,), "reading noise")}

    def readings(errors):
        e = np.asarray(errors["patch"], dtype=float)
        m = e.shape[0]
        if rows is not None and np.any(e != 0):
            rows.append(m)
        y = np.zeros((m, n_p, per))
        y[:, :, :-1] += e + 50.0 * e**2
        y[:, :, 1:] += 0.5 * e
        return y.reshape(m, -1) + errors["noise"]

    def zero(m):
        return {k: np.zeros((m, *s.shape)) for k, s in srcs.items()}

    return SourceModel("patches", srcs, readings, zero, structure)


def test_coloured_source_effects_equal_the_element_by_element_ones():
    n_p, per = 8, 5
    elem = np.arange(n_p * (per - 1)).reshape(n_p, per - 1)
    colours = (elem % 2).reshape(-1)
    owners = np.full((2, n_p * per), -1)
    for p in range(n_p):
        for k in range(per - 1):
            for r in (k, k + 1):
                owners[k % 2, p * per + r] = elem[p, k]
    calls = []

    def structure(name):
        calls.append(name)
        return (colours, owners) if name == "patch" else None

    plain, coloured = [], []
    D0, U0 = source_effects(_patches(rows=plain))
    D1, U1 = source_effects(_patches(structure, coloured))
    assert calls == ["patch", "noise"]
    assert sum(coloured) == 4 and sum(plain) >= 2 * n_p * (per - 1)  # 2 per colour, not element
    assert U1.shape == U0.shape == (n_p * per, n_p * (per - 1))
    assert np.array_equal(D1, D0) and np.array_equal(U1, U0)
    # a colouring that does not hold (an element left out of its readings' owners: they
    # move in a row that, by the colouring, touches none of them) is not used
    wrong = owners.copy()
    wrong[0, 0] = -1
    fallback = []
    D2, U2 = source_effects(_patches(lambda name: (colours, wrong) if name == "patch" else None,
                                     fallback))
    assert np.array_equal(D2, D0) and np.array_equal(U2, U0)
    assert sum(fallback) == 4 + sum(plain)


def test_gauss_newton_with_one_gain_solves_a_linear_model_in_one_step():
    model, x, _ = _linear_model()
    rng = np.random.default_rng(5)
    g = readings_covariance(model)
    J = central_jacobian(lambda th: th[:, :1] + th[:, 1:] * x, np.zeros(2), 1e-3)
    assert np.allclose(J, np.column_stack([np.ones_like(x), x]))
    truth = np.array([0.1, -0.2])
    y = truth[0] + truth[1] * x + rng.normal(size=(50, x.size)) * 2e-3
    fit = gauss_newton(lambda th: y - (th[:, :1] + th[:, 1:] * x), np.zeros((50, 2)),
                       gls_gain(J, g), tol=1e-12)
    direct = y @ gls_gain(J, g).T
    assert fit.converged and fit.ok.all() and fit.iterations <= 3
    assert np.allclose(fit.theta, direct, atol=1e-12)
    step, inv = gls_step(np.broadcast_to(J, (50, *J.shape)), y, np.broadcast_to(
        _dense(*source_effects(model)), (50, x.size, x.size)))
    assert np.allclose(step, direct, atol=1e-10) and inv.shape == (50, 2, 2)


def test_gauss_newton_stops_rows_it_cannot_evaluate_and_clips_to_bounds():
    x = np.linspace(0, 1, 5)
    y = np.array([np.exp(0.5 * x), np.full(5, np.nan)])
    fit = gauss_newton(lambda th: y - np.exp(th * x), np.zeros((2, 1)),
                       np.linalg.pinv(x[:, None]), tol=1e-12, bounds=(np.array([-1.0]),
                                                                       np.array([0.4])))
    assert fit.ok.tolist() == [True, False]
    assert fit.theta[0, 0] == pytest.approx(0.4)  # clipped at the bound
    assert fit.theta[1, 0] == 0.0  # never moved


def test_whitened_residuals_of_a_gls_fit_are_chi_square_with_n_minus_p_dof():
    """Mean chi-square n - p within 4 Monte Carlo standard errors (seeded)."""
    model, x, _ = _linear_model(30)
    g = readings_covariance(model)
    C = _dense(*source_effects(model))
    m = 4000
    rng = np.random.default_rng(6)
    y = rng.standard_normal((m, x.size)) @ np.linalg.cholesky(C).T
    J = np.column_stack([np.ones_like(x), x, x**2])
    theta = y @ gls_gain(J, g).T
    out = whitened_residuals(y - theta @ J.T, g, n_params=3)
    assert out.dof == 27 and out.whitened.shape == (m, 30)
    assert abs(out.chi2.mean() - 27) < 4 * np.sqrt(2 * 27 / m)
    # without a fit: n dof, and the same from a dense covariance or (D, U)
    raw = whitened_residuals(y[:5], C)
    assert raw.dof == 30
    assert np.allclose(raw.chi2, whitened_residuals(y[:5], source_effects(model)).chi2)
    assert np.allclose(raw.chi2, np.einsum("ij,ij->i", y[:5] @ np.linalg.inv(C), y[:5]))


def test_whitened_residuals_refuse_what_does_not_fit():
    model, x, _ = _linear_model()
    g = readings_covariance(model)
    with pytest.raises(InvalidInput, match="12"):
        whitened_residuals(np.zeros(5), g)
    with pytest.raises(InvalidInput, match="n_params"):
        whitened_residuals(np.zeros(12), g, n_params=13)


def test_truncated_pinv_and_response_of_a_linear_estimator():
    rng = np.random.default_rng(7)
    a = rng.normal(size=(20, 4))
    a[:, 3] = a[:, 2]  # rank 3
    pinv, rank, sv, vt = truncated_pinv(a, np.ones(4))
    assert rank == 3 and np.allclose(pinv, np.linalg.pinv(a), atol=1e-10)
    m = rng.normal(size=(3, 20))
    x0 = rng.normal(size=20)
    assert np.allclose(estimator_map(lambda r: r @ m.T, x0, np.full(20, 1e-3)), m)
