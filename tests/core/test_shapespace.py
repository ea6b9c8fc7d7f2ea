"""Shape space (core.shapespace): known truth recovered on a tiny model built in the test."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from core.errors import BodyspaceError
from core.shapespace import (
    OutOfRangeError,
    ShapeModel,
    body_height,
    body_volume,
    build_model,
    fit_pca,
    load_model,
    to_model_frame,
)
from core.synth.targets import load_targets
from core.template import load_template

TARGETS = (
    "torso/measure-waist-circ-incr", "torso/measure-hips-circ-incr", "legs/l-upperleg-fat-incr",
    "legs/r-upperleg-fat-incr", "stomach/stomach-pregnant-incr", "torso/measure-bust-circ-incr",
    "arms/measure-upperarm-circ-incr", "buttocks/buttocks-volume-incr",
)  # fmt: skip


def _bodies(n: int, seed: int) -> list[np.ndarray]:
    """Template scaled (stature) plus random positive mixes of a few MakeHuman targets."""
    rng = np.random.default_rng(seed)
    lib = load_targets()
    V0 = np.array(load_template().V)
    D = np.stack([lib.dense(t) for t in TARGETS])
    out = []
    for _ in range(n):
        V = (V0 + np.tensordot(rng.uniform(0, 1, len(TARGETS)), D, 1)) * rng.uniform(0.97, 1.03)
        V[:, 1] -= V[:, 1].min()
        out.append(V)
    return out


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> tuple[ShapeModel, list[np.ndarray], list[dict]]:
    d = tmp_path_factory.mktemp("fits")
    bodies = _bodies(24, 0)
    rows = []
    rng = np.random.default_rng(1)
    for i, V in enumerate(bodies):
        sex = "female" if i % 2 else "male"
        # a rigid placement like a fit in its scan's frame: the builder must undo it
        th = rng.uniform(-0.5, 0.5)
        R = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
        np.savez(d / f"b{i:02d}.npz", vertices=V @ R.T + rng.uniform(-1, 1, 3))
        rows.append({
            "id": f"b{i:02d}", "sex": sex, "height_m": body_height(V),
            "weight_kg": body_volume(V) * 1000.0, "age": rng.uniform(20, 60),
        })  # fmt: skip
    with open(d / "features.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    model = build_model(d, d / "features.csv", d / "model.npz", variance=0.99999)
    return model, bodies, rows


def test_pca_recovers_known_weights():
    X = np.stack([V.ravel() for V in _bodies(12, 3)])
    pca = fit_pca(X, variance=1.0)
    assert 8 <= pca.k <= 11  # 12 centred bodies: rank <= 11
    w = pca.sd * np.linspace(-1.5, 1.5, pca.k)
    V = pca.reconstruct(w)
    np.testing.assert_allclose(pca.project(V), w, atol=1e-6)
    assert np.abs(pca.residual(V)).max() < 1e-5
    # components are orthonormal
    C = pca.components.astype(np.float64)
    np.testing.assert_allclose(C @ C.T, np.eye(pca.k), atol=1e-5)


def test_model_projection_undoes_rigid_placement(tiny):
    model, _, _ = tiny
    s = model.space("female")
    w = s.pca.sd * 0.8
    V = model.reconstruct("female", w)
    th = 0.7
    R = np.array([[np.cos(th), 0, np.sin(th)], [0, 1, 0], [-np.sin(th), 0, np.cos(th)]])
    np.testing.assert_allclose(
        model.project("female", V @ R.T + [0.3, 0.2, -1.0]), w, rtol=1e-4, atol=1e-3
    )


def test_feature_map_reproduces_training_features(tiny):
    model, bodies, rows = tiny
    s = model.space("male")
    for V, r in zip(bodies, rows, strict=True):
        if r["sex"] != "male":
            continue
        f = s.features.features(model.project("male", V))
        # height and weight are determined by shape here: the map recovers them
        assert abs(f["height_m"] - r["height_m"]) < 0.003
        assert abs(f["weight_kg"] - r["weight_kg"]) < 0.6
    assert abs(s.density - 1000.0) < 1.0
    assert abs(model.weight_kg(bodies[0], "male") - rows[0]["weight_kg"]) < 1.0


def test_synthesis_honours_features_full_and_partial(tiny):
    model, _, rows = tiny
    fem = [r for r in rows if r["sex"] == "female"]
    h = float(np.mean([r["height_m"] for r in fem]))
    wkg = float(np.mean([r["weight_kg"] for r in fem]))
    age = 40.0
    V = model.synthesize("female", {"height_m": h + 0.03, "weight_kg": wkg + 4, "age": age})
    assert abs(body_height(V) - (h + 0.03)) < 1e-9  # exact (scaled about the floor)
    assert abs(model.weight_kg(V, "female") - (wkg + 4)) < 1.0
    assert V[:, 1].min() == pytest.approx(0.0, abs=1e-12)
    # partial: height only; weight takes its most likely value (plausible for that height)
    Vp = model.synthesize("female", {"height_m": h + 0.03}, exact_height=False)
    assert abs(body_height(Vp) - (h + 0.03)) < 0.003
    # a full vector gives the least-squares map, equal to the conditional mean
    s = model.space("female")
    full = {"height_m": h, "weight_kg": wkg, "age": age}
    sel = s.features
    idx = list(range(sel.f))
    f = np.array([h, np.cbrt(wkg), age])
    w_cond = sel.mean[sel.f :] + sel.cov[sel.f :, idx] @ np.linalg.solve(
        sel.cov[np.ix_(idx, idx)], f - sel.mean[idx]
    )
    np.testing.assert_allclose(
        sel.weights(full), w_cond, atol=1e-6 * max(1.0, np.abs(w_cond).max())
    )
    # seeded random bodies are reproducible
    np.testing.assert_array_equal(
        model.synthesize("male", seed=5), model.synthesize("male", seed=5)
    )


def test_edit_keeps_residual_and_hits_weight(tiny):
    model, bodies, rows = tiny
    i = next(j for j, r in enumerate(rows) if r["sex"] == "male")
    s = model.space("male")
    # a body with an individual detail outside the space (a bump on the back)
    V = bodies[i].copy()
    tpl = load_template()
    bump = np.exp(
        -np.sum((tpl.V - tpl.V[tpl.landmarks["Cervicale"]] + [0, 0.15, 0]) ** 2, 1) / 0.003
    )
    V[:, 2] -= 0.01 * bump
    Vm = to_model_frame(V, s.pca.mean.reshape(-1, 3))[0]
    res0 = s.pca.residual(Vm)
    E = model.edit("male", V, {"weight_kg": 5.0}, keep=())
    res1 = s.pca.residual(to_model_frame(E, s.pca.mean.reshape(-1, 3))[0])
    assert np.abs(res1 - res0).max() < 2e-3  # the individual residual is kept
    assert abs(model.weight_kg(E, "male") - model.weight_kg(V, "male") - 5.0) < 0.05
    # with the default keep: face and hands stay in place
    E2 = model.edit("male", V, {"weight_kg": 5.0})
    still = tpl.part_mask("head") | tpl.part_mask("hand_L") | tpl.part_mask("hand_R")
    assert np.linalg.norm(E2 - V, axis=1)[still].max() < 1e-9
    assert abs(model.weight_kg(E2, "male") - model.weight_kg(V, "male") - 5.0) < 0.05


def test_height_edit_moves_kept_parts_rigidly(tiny):
    model, bodies, rows = tiny
    i = next(j for j, r in enumerate(rows) if r["sex"] == "female")
    V = bodies[i]
    tpl = load_template()
    E = model.edit("female", V, {"height_m": 0.03})  # default keep: head and hands
    assert abs(body_height(E) - body_height(V) - 0.03) < 1e-4  # a pinned head would give ~0
    for part in ("head", "hand_L", "hand_R"):
        D = (E - V)[tpl.part_mask(part)]
        assert np.abs(D - D.mean(axis=0)).max() < 1e-9  # shape kept: a pure translation
    assert (E - V)[tpl.part_mask("head"), 1].mean() > 0.02  # the head follows the taller body


def test_save_load_round_trip(tiny, tmp_path):
    model, _, _ = tiny
    model.save(tmp_path / "m.npz")
    m2 = load_model(tmp_path / "m.npz")
    assert set(m2.spaces) == {"female", "male", "joint"}
    for key in m2.spaces:
        a, b = model.space(key), m2.space(key)
        assert a.pca.k == b.pca.k and a.features.names == b.features.names
        np.testing.assert_allclose(a.features.M, b.features.M)
    f = {"height_m": 1.7, "weight_kg": 60.0}
    np.testing.assert_allclose(model.synthesize("male", f), m2.synthesize("male", f), atol=1e-5)
    assert m2.describe()["spaces"]["female"]["features"]["height_m"]["unit"] == "m"


def test_out_of_range_is_a_clear_error(tiny):
    model, _, _ = tiny
    with pytest.raises(OutOfRangeError, match="height_m=3 m is outside the supported range") as e:
        model.synthesize("female", {"height_m": 3.0})
    assert isinstance(e.value, BodyspaceError) and e.value.code == "out_of_range"
    assert e.value.details["supported"][1] < 3.0
    with pytest.raises(OutOfRangeError, match="weight_kg"):
        model.synthesize("male", {"weight_kg": 1.0})
    with pytest.raises(OutOfRangeError, match="SD"):
        model.synthesize("male", pca=model.space("male").pca.sd * 10)
    with pytest.raises(OutOfRangeError, match="unknown feature"):
        model.synthesize("male", {"shoe_size": 44})
    with pytest.raises(OutOfRangeError, match="sex"):
        model.synthesize("other", {"height_m": 1.7})


def test_default_model_loads_and_synthesises():
    from core.shapespace import default_model

    m = default_model()
    assert {"female", "male", "joint"} <= set(m.spaces)
    V = m.synthesize("female", {"height_m": 1.65, "weight_kg": 65.0})
    assert abs(body_height(V) - 1.65) < 1e-9
    assert abs(m.weight_kg(V, "female") - 65.0) < 3.0
    with pytest.raises(OutOfRangeError, match="height_m=3 m"):
        m.synthesize("female", {"height_m": 3.0})


@pytest.mark.parametrize("sex", ["female", "male"])
def test_default_model_bodies_stand_on_both_feet(sex):
    """Bodies of the committed model stand level: both soles within 3 mm of the floor and the
    body left-right symmetric to a few millimetres (the fitted training bodies' mean once had
    one foot 23 mm up)."""
    from core.shapespace import default_model
    from core.shapespace.calibrate import symmetric_part
    from core.template import load_template

    tpl = load_template()
    m = default_model()
    for f in ({"height_m": 1.60, "weight_kg": 55.0}, {"height_m": 1.80, "weight_kg": 95.0}, {}):
        V = m.synthesize(sex, f)
        soles = [float(V[tpl.part_mask(p), 1].min()) for p in ("foot_L", "foot_R")]
        assert max(soles) < 0.003, soles
        assert float(np.abs(symmetric_part(V, tpl.mirror) - V).max()) < 0.01


def test_symmetric_part():
    from core.shapespace.calibrate import symmetric_part
    from core.template import load_template

    tpl = load_template()
    V = tpl.V.astype(np.float64)
    np.testing.assert_allclose(symmetric_part(V, tpl.mirror), V, atol=1e-12)  # symmetric
    D = np.zeros_like(V)
    D[tpl.part_mask("foot_L"), 1] = 0.02  # one foot up
    S = symmetric_part(V + D, tpl.mirror)
    np.testing.assert_allclose(S[tpl.part_mask("foot_L"), 1] - V[tpl.part_mask("foot_L"), 1], 0.01)
    np.testing.assert_allclose(S[tpl.part_mask("foot_R"), 1] - V[tpl.part_mask("foot_R"), 1], 0.01)
    assert symmetric_part(V.ravel(), tpl.mirror).shape == (V.size,)
