"""What the test cannot see, with its share in the estimate: geometry21's residual after
compensation at each table point (true + the unseen fields - estimate) has the variance the
unseen covariance predicts, point by point, against a seeded Monte Carlo of the same fields;
the quadrature of the estimate's u and the unseen u is off both ways (too wide at the ends of
the travel, too narrow in between)."""

from __future__ import annotations

import math

import numpy as np

from mtplan import models
from mtplan.compensation.unseen import unseen_covariance
from mtplan.evaluation.first_order import first_order
from mtplan.uncertainty.streams import as_seed_sequence, block_sequence

ALONG = {f"along_{a}_mm": "-50,-25,25,50" for a in "xyz"}
FIELDS = ("path_residual", "medium_wave")


def test_unseen_covariance_gives_each_points_residual_variance():
    proc = models.get("geometry21")
    setup = proc.setup(ALONG)
    doc = {"procedure": "geometry21", "setup": setup.as_dict(), "estimator": "patent"}
    names, d = unseen_covariance(proc, doc)
    # the estimate's share of the fields alone (the other sources add their covariance to
    # both sides alike): first order over the same sources
    gum = first_order(proc, setup, estimator="patent", sources=FIELDS)
    jac = gum.sensitivity * gum.input_std
    at = [gum.names.index(n) for n in names]
    predicted = np.diag(jac @ jac.T)[at] + np.diag(d)

    n = 2000
    errors = proc.draw_errors(setup, n, block_sequence(as_seed_sequence(11), 0), only=FIELDS)
    truth = proc.Truth()
    est = proc.estimators["patent"](setup, proc.forward(setup, truth, errors))
    true = proc.display_truth(setup, truth)
    realised = proc.correction.realised(setup, errors)
    scale = {m.name: m.scale for m in proc.measurands(setup)}
    points = [i for i, m in enumerate(names) if m in realised]
    assert len(points) == 9 * 5  # 9 translation functions: EXX and its 4 table points
    residual = np.column_stack([true[names[i]] + realised[names[i]]
                                - np.asarray(est[names[i]]).ravel() * scale[names[i]]
                                for i in points])
    ratio = residual.var(axis=0, ddof=1) / predicted[points]
    # the sample variance's relative standard error (normal fields, linear estimate at their
    # size): sqrt(2 / (n - 1)), 3.2 % here; 4.5 of them over 45 points
    tol = 4.5 * math.sqrt(2 / (n - 1))
    assert np.all(np.abs(ratio - 1) < tol), dict(zip(np.array(names)[points], ratio.round(3)))
    # the quadrature (estimate's u and the unseen u independent) misses by far more, both
    # ways (half the variance at the ends of the travel, a sixth more in between): beyond
    # the tolerance, so the test tells the two apart
    unseen = math.hypot(setup.path_residual_um, setup.medium_wave_um)
    quad = np.diag(jac @ jac.T)[at][points] + unseen ** 2
    off = residual.var(axis=0, ddof=1) / quad - 1
    assert off.min() < -3 * tol and off.max() > tol


def test_no_unseen_part_no_covariance():
    proc = models.get("rotary_axis")
    doc = {"procedure": "rotary_axis", "setup": {}, "estimator": None}
    assert unseen_covariance(proc, doc) is None
    g21 = models.get("geometry21")
    assert unseen_covariance(g21, {"procedure": "geometry21", "setup": {
        "path_residual_um": 0.0, "medium_wave_um": 0.0}}) is None
    assert unseen_covariance(g21, doc) is None  # another procedure's result
