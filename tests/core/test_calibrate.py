"""Anthropometric calibration of a space's mean (core.shapespace.calibrate): known truth."""

from __future__ import annotations

import numpy as np
import pytest

from core.measure import measure
from core.registration.shape_prior import load_shape_basis
from core.shapespace import load_model
from core.shapespace.calibrate import calibrate_mean
from core.shapespace.model import DEFAULT_MODEL

NAMES = ["stature", "waistcircumference", "buttockcircumference", "chestcircumference"]
FEATS = [
    {"height_m": 1.60, "weight_kg": 55.0},
    {"height_m": 1.66, "weight_kg": 70.0},
    {"height_m": 1.72, "weight_kg": 82.0},
]


def _measured(model, feats):
    return np.array(
        [[measure(model.synthesize("female", f, exact_height=False), names=NAMES)[n]
          for n in NAMES] for f in feats]
    )  # fmt: skip


def test_recovers_a_known_mean_shift():
    """Targets measured on a model whose mean was shifted by a known basis combination: the
    calibration of the unshifted model removes the measurement bias and recovers the shift."""
    B = load_shape_basis(5)
    U, sd = B.U.reshape(-1, B.k)[:, 2:], B.sigma[2:]  # 3 directions, 4 measurements: identifiable
    truth = load_model(DEFAULT_MODEL)
    c_true = np.array([0.8, -0.6, 0.5]) * sd
    truth.space("female").pca.mean = truth.space("female").pca.mean + U @ c_true
    T = _measured(truth, FEATS)

    model = load_model(DEFAULT_MODEL)
    before = _measured(model, FEATS)
    sigma = np.array([0.01, 0.02, 0.02, 0.02])
    assert np.abs((before - T).mean(0) / sigma).max() > 0.5  # the shift is visible
    cal = calibrate_mean(model, "female", FEATS, T, NAMES, sigma, U, sd, mu=1e-4, iterations=3)
    after = _measured(model, FEATS)
    np.testing.assert_allclose(cal.bias_after, (after - T).mean(0), atol=1e-9)
    assert np.abs(cal.bias_after / sigma).max() < 0.1
    assert np.abs(cal.bias_after).max() < 0.25 * np.abs(cal.bias_before).max()
    # the mean moved by the calibration's delta and nothing else
    d = model.space("female").pca.mean - load_model(DEFAULT_MODEL).space("female").pca.mean
    np.testing.assert_allclose(d.reshape(-1, 3), cal.delta, atol=1e-12)
    # the recovered displacement points the way of the true one
    D_true = (U @ c_true).reshape(-1, 3)
    cos = float(np.sum(cal.delta * D_true) / np.linalg.norm(cal.delta) / np.linalg.norm(D_true))
    assert cos > 0.9, cos
    np.testing.assert_allclose(cal.coefficients, c_true, rtol=0.3, atol=0.1 * sd.max())


def test_bad_inputs():
    model = load_model(DEFAULT_MODEL)
    B = load_shape_basis(2)
    U = B.U.reshape(-1, B.k)
    T = np.zeros((len(FEATS), len(NAMES)))
    with pytest.raises(ValueError, match="targets"):
        calibrate_mean(model, "female", FEATS, T[:, :2], NAMES, np.ones(4), U, B.sigma)
    with pytest.raises(ValueError, match="sigma"):
        calibrate_mean(model, "female", FEATS, T, NAMES, np.zeros(4), U, B.sigma)
    with pytest.raises(ValueError, match="basis"):
        calibrate_mean(model, "female", FEATS, T, NAMES, np.ones(4), U[:10], B.sigma)
