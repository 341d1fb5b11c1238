"""Generalised least squares through a filter's whitening (mtplan.fitting.linear)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from mtplan.fitting.linear import filter_whitening, gls_pinv, truncated_pinv


def _ar1(lengths, phi):
    """AR(1) filter with unit marginal variance, independent passes of the given lengths."""
    blocks = []
    for m in lengths:
        k = np.arange(m)
        f = np.tril(phi ** (k[:, None] - k[None, :]).clip(0)) * np.sqrt(1 - phi**2)
        f[:, 0] = phi ** k
        blocks.append(f)
    return sp.block_diag(blocks, format="csr")


def test_filter_whitening_inverts_the_covariance_and_keeps_passes_apart():
    f = _ar1([5, 8], 0.9)
    w = filter_whitening(f, 0.2, components=2)
    fd = f.toarray()
    cov = np.kron(fd @ fd.T + 0.04 * np.eye(13), np.eye(2))
    np.testing.assert_allclose(w.toarray() @ cov @ w.toarray().T, np.eye(26), atol=1e-10)
    assert np.all(w.toarray()[10:, :10] == 0)  # the second pass never sees the first


def test_gls_pinv_is_unbiased_and_beats_ordinary_least_squares():
    """On AR(1) readings the GLS map reproduces the parameters exactly (J) and its
    variance is the Gauss-Markov bound (J^T C^-1 J)^-1, below the OLS map's."""
    f = _ar1([40, 40], 0.9)
    n = 80
    x = np.linspace(-1, 1, n)
    jac = np.column_stack([np.ones(n), x, x**2 * 1e3, np.sin(7 * x)])  # mixed scales
    s = np.array([1.0, 1.0, 1e-3, 1.0])
    ols, rank, _, vt = truncated_pinv(jac, s)
    g = gls_pinv(jac, s, vt, rank, None, filter_whitening(f, 0.1))
    np.testing.assert_allclose(g @ jac, np.eye(4), atol=1e-9)
    fd = f.toarray()
    cov = fd @ fd.T + 0.01 * np.eye(n)
    bound = np.linalg.inv(jac.T @ np.linalg.solve(cov, jac))
    np.testing.assert_allclose(g @ cov @ g.T, bound, rtol=1e-8, atol=1e-14)
    assert np.all(np.diag(ols @ cov @ ols.T) > np.diag(bound))
