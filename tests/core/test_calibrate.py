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


def test_feature_map_with_slopes_is_the_map_of_shifted_training_weights():
    """with_slopes(B) equals the map learned from training weights w + B (f - mean f)."""
    from core.shapespace.features import encode, fit_feature_map

    rng = np.random.default_rng(3)
    n, k = 400, 5
    h = rng.normal(1.65, 0.07, n)
    wt = 20 * h**2 * rng.normal(1.0, 0.12, n)
    age = rng.uniform(18, 60, n)
    F = np.stack([h, wt, age], 1)
    W = rng.normal(size=(n, k)) * np.array([0.05, 0.03, 0.02, 0.01, 0.005])
    W[:, 0] += 0.6 * (h - 1.65)
    names = ("height_m", "weight_kg", "age")
    base = fit_feature_map(names, F, W, W.var(0, ddof=1))
    E = np.stack([encode(nm, F[:, j]) for j, nm in enumerate(names)], 1)
    B = np.zeros((k, 3))
    B[:, 0] = rng.normal(size=k) * 0.2
    B[:, 1] = rng.normal(size=k) * 0.01
    shifted = fit_feature_map(names, F, W + (E - E.mean(0)) @ B.T, W.var(0, ddof=1))
    mapped = base.with_slopes(B)
    np.testing.assert_allclose(mapped.M, shifted.M, atol=1e-10)
    np.testing.assert_allclose(mapped.cov[:3], shifted.cov[:3], rtol=1e-9, atol=1e-12)
    for feats in ({"height_m": 1.72}, {"height_m": 1.58, "weight_kg": 70.0}, {"age": 30.0}):
        np.testing.assert_allclose(
            mapped.weights(feats, check=False), shifted.weights(feats, check=False), atol=1e-10
        )
    # the original map is untouched and slopes of zero change nothing
    np.testing.assert_allclose(base.with_slopes(np.zeros((k, 3))).M, base.M)
    with pytest.raises(ValueError, match="slopes"):
        base.with_slopes(np.zeros((k, 2)))


def test_calibration_recovers_known_slopes():
    """Targets measured on a model whose height/weight slopes were changed by a known B: the
    slope calibration of the unchanged model finds the slopes back (measurement error of the
    rows drops to a fraction, B points the same way)."""
    from core.measure import MEASUREMENTS
    from core.shapespace.calibrate import calibrate_space

    # all 39 measurements: enough equations to tell the 11 components' slopes apart
    names = [n for n in MEASUREMENTS if n != "weightkg"] + ["weightkg"]
    feats = [{"height_m": h, "weight_kg": w} for h in (1.56, 1.64, 1.72)
             for w in (55.0, 70.0, 88.0)]  # fmt: skip
    truth = load_model(DEFAULT_MODEL)
    sp = truth.space("female")
    k = sp.pca.k
    cols = [sp.features.names.index("height_m"), sp.features.names.index("weight_kg")]
    g_sd = np.sqrt(np.diag(sp.features.cov)[cols])
    B_true = np.zeros((k, sp.features.f))
    B_true[1, cols[1]] = 0.5 * sp.pca.sd[1] / g_sd[1]  # half an SD of PC 2 per SD of weight
    B_true[2, cols[0]] = -0.4 * sp.pca.sd[2] / g_sd[0]
    sp.features = sp.features.with_slopes(B_true)

    def measured(model):
        out = []
        for f in feats:
            V = model.synthesize("female", f, exact_height=False)
            r = measure(V, names=names[:-1])
            out.append([r[n] for n in names[:-1]] + [model.weight_kg(V, "female")])
        return np.array(out)

    T = measured(truth)
    model = load_model(DEFAULT_MODEL)
    before = measured(model)
    sigma = np.append(np.full(len(names) - 1, 0.01), 1.0)
    U = np.zeros((model.space("female").pca.mean.size, 1))
    U[1::3, 0] = 1.0 / np.sqrt(U.shape[0] / 3)  # a vertical shift: harmless to every measure
    cal = calibrate_space(model, "female", feats, T, names, sigma, U, np.array([1.0]),
                          slope_sd=1.0, mu=1e-6, iterations=3)  # fmt: skip
    after = measured(model)
    rms0 = np.sqrt((((before - T) / sigma) ** 2).mean())
    rms1 = np.sqrt((((after - T) / sigma) ** 2).mean())
    assert rms0 > 0.3 and rms1 < 0.1 * rms0, (rms0, rms1)
    np.testing.assert_allclose(cal.rmse_after, np.sqrt(((after - T) ** 2).mean(0)), atol=1e-9)
    assert cal.slopes is not None and cal.slope_features == ("height_m", "weight_kg")
    b, bt = cal.slopes[:, cols].ravel(), B_true[:, cols].ravel()
    assert float(b @ bt / np.linalg.norm(b) / np.linalg.norm(bt)) > 0.9
