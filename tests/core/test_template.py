"""The template asset: shapes, symmetry, segmentation, masks, skin weights."""

from __future__ import annotations

import numpy as np
import pytest

from core.template import MASK_NAMES, load_template

N = 13380


@pytest.fixture(scope="module", name="T")
def template_fixture():
    return load_template()


def test_asset_shapes_and_dtypes(T):
    x = T.extras
    assert T.V.shape == (N, 3) and T.V.dtype == np.float64
    assert T.F.shape == (26756, 3) and T.F.dtype == np.int32
    assert x["mirror"].shape == (N,) and x["mirror"].dtype == np.int32
    assert x["part"].shape == (N,) and x["part"].dtype == np.int8
    for m in MASK_NAMES:
        assert x[f"mask_{m}"].shape == (N,) and x[f"mask_{m}"].dtype == bool
    J = len(x["joint_names"])
    assert J == 163
    assert x["joint_parents"].dtype == np.int16 and x["joint_parents"].shape == (J,)
    assert x["joint_heads"].shape == (J, 3) and x["joint_heads"].dtype == np.float32
    assert x["joint_tails"].shape == (J, 3) and x["joint_tails"].dtype == np.float32
    assert x["skin_rows"].shape == x["skin_cols"].shape == x["skin_vals"].shape
    assert x["skin_vals"].dtype == np.float32


def test_floor_and_height(T):
    assert T.V[:, 1].min() == pytest.approx(0.0, abs=1e-12)
    assert 1.5 < T.V[:, 1].max() < 2.0


def test_mirror_symmetry(T):
    m = T.mirror
    assert np.array_equal(m[m], np.arange(N))
    err = np.linalg.norm(T.V[m] * [-1, 1, 1] - T.V, axis=1)
    assert np.mean(err < 1e-3) > 0.99
    mid = m == np.arange(N)
    assert 50 < mid.sum() < 500
    assert np.abs(T.V[mid, 0]).max() < 1e-3


def test_landmark_pairs_mirror(T):
    pairs = [n[:-2] for n in T.landmarks if n.endswith("_L")]
    assert len(pairs) == 25
    for base in pairs:
        left, right = T.landmarks[base + "_L"], T.landmarks[base + "_R"]
        assert T.mirror[left] == right, base
        assert T.V[left, 0] > 0 > T.V[right, 0], base


def test_parts_nonempty_and_sided(T):
    assert len(T.part_names) == 16
    assert set(np.unique(T.part)) == set(range(16))
    for name in T.part_names:
        m = T.part_mask(name)
        assert m.sum() > 100, name
        if name.endswith("_L"):
            assert (T.V[m, 0] > 0).all(), name
            other = T.part_mask(name[:-2] + "_R")
            assert np.array_equal(m[T.mirror], other), name
    # anatomical order along y
    y = {n: T.V[T.part_mask(n), 1].mean() for n in T.part_names}
    assert y["head"] > y["neck"] > y["torso"] > y["pelvis"] > y["thigh_L"] > y["shin_L"]
    assert y["shin_L"] > y["foot_L"]
    assert y["upper_arm_L"] > y["forearm_L"] > y["hand_L"]


def test_masks_reasonable(T):
    sizes = {m: int(T.mask(m).sum()) for m in MASK_NAMES}
    for m in ("ears", "fingers", "toes", "eyes_mouth"):
        assert 200 < sizes[m] < 3500, (m, sizes[m])
        assert np.array_equal(T.mask(m), T.mask(m)[T.mirror]), m  # symmetric
    union = T.mask("ears") | T.mask("fingers") | T.mask("toes") | T.mask("eyes_mouth")
    assert np.array_equal(T.bad_scan_mask, union)
    assert union.mean() < 0.5
    head = T.part_mask("head")
    assert head[T.mask("ears")].all() and head[T.mask("eyes_mouth")].all()
    hands = T.part_mask("hand_L") | T.part_mask("hand_R")
    feet = T.part_mask("foot_L") | T.part_mask("foot_R")
    assert hands[T.mask("fingers")].all() and feet[T.mask("toes")].all()
    # fingers are the far end of the hand: farther from the wrist joint than the palm
    names = [str(n) for n in T.extras["joint_names"]]
    wrist = T.extras["joint_heads"][names.index("wrist.L")]
    dist = np.linalg.norm(T.V - wrist, axis=1)
    fingers_l = T.mask("fingers") & T.part_mask("hand_L")
    palm_l = ~T.mask("fingers") & T.part_mask("hand_L")
    assert np.median(dist[fingers_l]) > 1.5 * np.median(dist[palm_l])
    with pytest.raises(ValueError, match="valid"):
        T.mask("nose")


def test_skin_weights_sum_to_one(T):
    x = T.extras
    s = np.bincount(x["skin_rows"], weights=x["skin_vals"].astype(np.float64), minlength=N)
    np.testing.assert_allclose(s, 1.0, atol=1e-5)
    assert (x["skin_vals"] > 0).all()
    assert x["skin_cols"].max() < len(x["joint_names"])


def test_joint_tree(T):
    p = T.extras["joint_parents"].astype(int)
    assert (p == -1).sum() == 1
    assert (p < np.arange(len(p))).all()  # parents before children


def test_edges_and_normals(T):
    E = T.edges
    assert E.shape == (40134, 2) and (E[:, 0] < E[:, 1]).all()
    assert len(T.V) - len(E) + len(T.F) == 2  # closed genus-0 surface
    N_ = T.vertex_normals()
    np.testing.assert_allclose(np.linalg.norm(N_, axis=1), 1.0, atol=1e-9)
    # outward: the nose tip's normal points to the front (+Z)
    assert N_[T.landmarks["Pronasale"], 2] > 0.8
    with pytest.raises(ValueError):
        T.vertex_normals(T.V[:10])
