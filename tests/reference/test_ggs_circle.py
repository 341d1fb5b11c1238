"""The Gander-Golub-Strebel (1994) six-point circle: geometric and Kasa fits.

Data: W. Gander, G. H. Golub and R. Strebel, "Least-squares fitting of circles and
ellipses", BIT 34 (1994) 558-578; the six points (1,7) (2,6) (5,8) (7,7) (9,5) (3,7),
in ``ggs1994_circle.csv`` beside this file (copied from the project's reference-data
folder ``circle_ggs1994/points.csv``; its README, section 2, gives the provenance).

- Geometric (orthogonal-distance) fit: centre (4.739782, 2.983533), radius 4.714226,
  sigma = sqrt(SSR/n) = 0.4523271, as printed in N. Chernov's circle-fitting test
  program ("Test One: benchmark example from Gander, Golub, Strebel"); reproduced to
  the printed digits (half a unit of the last printed digit).
- Kasa fit: Chernov's printed "correct answer" (4.921166, 3.835123, r 4.123176) is
  WRONG (a back-substitution bug in his CircleFitByKasa.cpp); the exact rational
  solution of the normal equations is xc = 773/163, yc = 5001/1304 and
  r = 4.108761522345449, which is tested here instead.
"""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mtplan.fitting.circle import geometric_fit, kasa_fit
from mtplan.models.circle_centre import fit_points

DATA = Path(__file__).parent / "ggs1994_circle.csv"


@pytest.fixture(scope="module")
def points():
    df = pd.read_csv(DATA, comment="#")
    return df["x"].to_numpy(float), df["y"].to_numpy(float)


def test_geometric_fit_reproduces_the_published_digits(points):
    x, y = points
    c = geometric_fit(x, y)
    assert bool(c.converged)
    assert abs(c.xc - 4.739782) <= 0.5e-6
    assert abs(c.yc - 2.983533) <= 0.5e-6
    assert abs(c.r - 4.714226) <= 0.5e-6
    sigma = np.sqrt(np.mean((np.hypot(x - c.xc, y - c.yc) - c.r) ** 2))
    assert abs(sigma - 0.4523271) <= 0.5e-7


def test_geometric_fit_matches_the_high_precision_recomputation(points):
    c = geometric_fit(*points)
    np.testing.assert_allclose([c.xc, c.yc, c.r],
                               [4.739782410906074, 2.983532699292475, 4.714226037792110],
                               rtol=0, atol=1e-12)


def test_kasa_fit_is_the_exact_rational_solution(points):
    x, y = points
    # the exact solution of the normal equations, in rational arithmetic
    xs = [Fraction(int(v)) for v in x]
    ys = [Fraction(int(v)) for v in y]
    rows = [(a, b, Fraction(1)) for a, b in zip(xs, ys)]
    rhs = [-(a * a + b * b) for a, b in zip(xs, ys)]
    n = [[sum(r[i] * r[j] for r in rows) for j in range(3)] for i in range(3)]
    g = [sum(r[i] * v for r, v in zip(rows, rhs)) for i in range(3)]
    for i in range(3):  # Gauss-Jordan, exact
        piv = n[i][i]
        n[i] = [v / piv for v in n[i]]
        g[i] /= piv
        for k in range(3):
            if k != i:
                f = n[k][i]
                n[k] = [a - f * b for a, b in zip(n[k], n[i])]
                g[k] -= f * g[i]
    d, e, f = g
    assert (-d / 2, -e / 2) == (Fraction(773, 163), Fraction(5001, 1304))
    c = kasa_fit(x, y)
    np.testing.assert_allclose([c.xc, c.yc, c.r], [773 / 163, 5001 / 1304, 4.108761522345449],
                               rtol=0, atol=1e-13)
    # and not Chernov's published (buggy) Kasa values
    assert abs(c.xc - 4.921166) > 0.1


@pytest.mark.parametrize("estimator, expected", [
    ("geometric", (4.739782, 2.983533, 4.714226)),
    ("kasa", (773 / 163, 5001 / 1304, 4.108761522345449)),
])
def test_fit_points_for_the_command_line(points, estimator, expected):
    out = fit_points(*points, estimator)
    got = (out["centre_x_mm"], out["centre_y_mm"], out["radius_mm"])
    np.testing.assert_allclose(got, expected, rtol=0, atol=0.5e-6)


def test_estimate_command_reproduces_the_published_geometric_fit(tmp_path, capsys):
    """`mtplan estimate circle_centre POINTS.csv` on bare x_mm, y_mm points (GGS 1994)."""
    import json

    from mtplan import cli

    df = pd.read_csv(DATA, comment="#")
    points = tmp_path / "ggs.csv"
    pd.DataFrame({"x_mm": df["x"], "y_mm": df["y"]}).to_csv(points, index=False)
    nominal = 4.7  # nominal radius [mm]; the radius measurand is the deviation from it
    argv = ["estimate", "circle_centre", str(points), "--set", "n_points=6",
            "--set", f"bore_radius_mm={nominal}", "--set", "start_scatter_mm=0.5",
            "--trials", "300", "--json"]
    expected = {"geometric": (4.739782, 2.983533, 4.714226),
                "kasa": (773 / 163, 5001 / 1304, 4.108761522345449)}
    for estimator, (xc, yc, r) in expected.items():
        assert cli.main([*argv, "--estimator", estimator]) == 0
        doc = json.loads(capsys.readouterr().out)
        got = {m["name"]: m["estimate"] for m in doc["measurands"]}
        assert got["centre_x"] / 1e3 == pytest.approx(xc, abs=5e-7)
        assert got["centre_y"] / 1e3 == pytest.approx(yc, abs=5e-7)
        assert nominal + got["radius"] / 1e3 == pytest.approx(r, abs=5e-7)
