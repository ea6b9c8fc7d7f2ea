"""Morphing: exact end points, base + delta = the other body, in-between measurements, a
validator-clean GLB with morph targets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from core.io._geometry import vertex_normals
from core.measure import measure
from core.synth import random_body
from core.template import load_template
from core.transfer import morph, morph_glb, morph_targets
from service.testing import glb_parts, validate_glb


@pytest.fixture(scope="module")
def pair() -> tuple[np.ndarray, np.ndarray]:
    a = random_body(np.random.default_rng(1), sex="female").V
    b = random_body(np.random.default_rng(2), sex="male").V
    return a, b


def test_end_points_are_exact(pair):
    a, b = pair
    assert np.array_equal(morph(a, b, 0.0), a)
    assert np.array_equal(morph(a, b, 1.0), b)
    mid = morph(a, b, 0.5)
    np.testing.assert_allclose(mid, (a + b) / 2, atol=1e-15)


def test_bad_input(pair):
    a, b = pair
    with pytest.raises(ValueError, match="t must lie in"):
        morph(a, b, 1.5)
    with pytest.raises(ValueError, match="template order"):
        morph(a, b[:100], 0.5)
    with pytest.raises(ValueError, match="2 to 16"):
        morph_targets([a])
    with pytest.raises(ValueError, match="2 to 16"):
        morph_targets([a] * 17)


@pytest.mark.parametrize(
    "fa, fb",
    [
        (("female", 1.55, 52.0), ("male", 1.88, 100.0)),
        (("female", 1.60, 80.0), ("female", 1.75, 60.0)),  # shorter but heavier
    ],
)
def test_in_between_measurements_lie_between(fa, fb):
    """Bodies of the default shape model (their measurement definitions are min/max searches,
    so between two bodies that hardly differ in one measurement -- or differ in posture -- a
    blend can fall a few mm outside; these pairs differ in shape, the use case)."""
    from core.shapespace.model import load_model

    m = load_model()
    a = m.synthesize(fa[0], {"height_m": fa[1], "weight_kg": fa[2]})
    b = m.synthesize(fb[0], {"height_m": fb[1], "weight_kg": fb[2]})
    ma, mb = measure(a), measure(b)
    for t in (0.3, 0.5, 0.7):
        mt = measure(morph(a, b, t))
        checked = 0
        for k, v in mt.items():
            lo, hi = sorted((ma[k], mb[k]))
            if not (math.isfinite(v) and math.isfinite(lo) and math.isfinite(hi)):
                continue
            checked += 1
            assert lo - 1e-9 <= v <= hi + 1e-9, (k, t, lo, v, hi)
        assert checked >= 30


def test_glb_targets_reproduce_the_bodies(pair, tmp_path):
    a, b = pair
    c = random_body(np.random.default_rng(3), sex="female").V
    data = morph_glb([a, b, c], names=["a", "b", "c"])
    path = tmp_path / "morph.glb"
    path.write_bytes(data)
    report = validate_glb(path)
    assert report["errors"] == 0 and report["warnings"] == 0, report

    doc, accessor = glb_parts(data)
    mesh = doc["meshes"][0]
    assert mesh["extras"]["targetNames"] == ["b", "c"]
    assert mesh["weights"] == [0.0, 0.0]
    prim = mesh["primitives"][0]
    base = accessor(prim["attributes"]["POSITION"]).astype(np.float64)
    np.testing.assert_array_equal(base, a.astype(np.float32))
    F = load_template().F
    for tg, V in zip(prim["targets"], (b, c), strict=True):
        dV = accessor(tg["POSITION"]).astype(np.float64)
        assert np.abs(base + dV - V).max() < 1e-4
        acc = doc["accessors"][tg["POSITION"]]
        np.testing.assert_allclose(acc["min"], dV.min(axis=0))
        np.testing.assert_allclose(acc["max"], dV.max(axis=0))
        N0 = accessor(prim["attributes"]["NORMAL"]).astype(np.float64)
        N = N0 + accessor(tg["NORMAL"])
        assert np.abs(N - vertex_normals(V, F)).max() < 1e-5


def test_targets_names_default():
    a = load_template().V
    _, targets = morph_targets([a, a * 1.01])
    assert [t.name for t in targets] == ["body1"]
    np.testing.assert_allclose(targets[0].delta_positions, a * 0.01, atol=1e-12)


def test_colours_blend_and_ride_on_the_glb(pair, tmp_path):
    """An in-between body's colours are the blend of the two bodies' (t = 0 and 1 exact); the
    morph GLB carries the first body's colours as COLOR_0 and still validates."""
    from core.transfer import morph_colors

    n = len(pair[0])
    rng = np.random.default_rng(7)
    C0 = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    C1 = rng.integers(0, 256, (n, 3), dtype=np.uint8)
    assert np.array_equal(morph_colors(C0, C1, 0.0), C0)
    assert np.array_equal(morph_colors(C0, C1, 1.0), C1)
    mid = morph_colors(C0, C1, 0.3).astype(np.int64)
    want = 0.7 * C0.astype(np.float64) + 0.3 * C1
    assert np.abs(mid - want).max() <= 0.5 + 1e-9
    lo, hi = np.minimum(C0, C1), np.maximum(C0, C1)
    assert np.all((mid >= lo) & (mid <= hi))
    with pytest.raises(ValueError, match="t must"):
        morph_colors(C0, C1, 1.5)
    with pytest.raises(ValueError, match="colours"):
        morph_colors(C0, C1[:10], 0.5)

    data = morph_glb(list(pair), names=["a", "b"], colors=C0)
    path = tmp_path / "coloured.glb"
    path.write_bytes(data)
    report = validate_glb(path)
    assert report["errors"] == 0 and report["warnings"] == 0, report
    doc, accessor = glb_parts(data)
    prim = doc["meshes"][0]["primitives"][0]
    np.testing.assert_array_equal(accessor(prim["attributes"]["COLOR_0"])[:, :3], C0)
    assert len(prim["targets"]) == 1
