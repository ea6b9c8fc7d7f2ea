"""Body measurements: shapes of known measure, scaling, symmetry, plausibility, targets."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from core.measure import (
    MEASUREMENTS,
    convex_perimeter,
    measure,
    mesh_volume,
    plane_section,
    section_circumference,
)
from core.synth import load_targets, random_body
from core.template import load_template

TPL = load_template()
ANSUR = Path(__file__).resolve().parents[3] / "shared" / "data" / "ansur2"
LENGTH_KINDS = ("height", "length", "breadth", "depth", "circumference")
REQUIRED = (
    "stature",
    "cervicaleheight",
    "acromialheight",
    "waistheightomphalion",
    "crotchheight",
    "kneeheightmidpatella",
    "chestcircumference",
    "waistcircumference",
    "buttockcircumference",
    "neckcircumference",
    "thighcircumference",
    "calfcircumference",
    "bicepscircumferenceflexed",
    "forearmcircumferenceflexed",
    "wristcircumference",
    "headcircumference",
    "biacromialbreadth",
    "hipbreadth",
    "acromionradialelength",
    "radialestylionlength",
    "footlength",
    "weightkg",
)


# ---------------------------------------------------------------------- synthetic meshes
def cylinder(r: float, h: float, n: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """Closed cylinder along +Y (outward-wound triangles), ``n`` segments, 4 rings."""
    a = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    ring = np.stack([r * np.cos(a), np.zeros(n), r * np.sin(a)], axis=1)
    ys = np.linspace(0.0, h, 4)
    rings = [ring + np.array([0.0, y, 0.0]) for y in ys]
    V = np.concatenate([*rings, np.array([[0.0, 0.0, 0.0], [0.0, h, 0.0]])])
    F = []
    for k in range(len(ys) - 1):
        for i in range(n):
            j = (i + 1) % n
            a0, a1, b0, b1 = k * n + i, k * n + j, (k + 1) * n + i, (k + 1) * n + j
            F += [[a0, b0, a1], [a1, b0, b1]]
    bot, top, last = len(V) - 2, len(V) - 1, (len(ys) - 1) * n
    for i in range(n):
        j = (i + 1) % n
        F += [[bot, i, j], [top, last + j, last + i]]
    return V.astype(np.float64), np.array(F)


def box(a: float, b: float, c: float) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned closed box [0,a] x [0,b] x [0,c] (12 triangles)."""
    V = np.array([[x, y, z] for x in (0, a) for y in (0, b) for z in (0, c)], dtype=np.float64)
    F = np.array(
        [
            [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
            [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],
        ]
    )  # fmt: skip
    return V, F


def test_cylinder_section_perimeter_is_two_pi_r():
    r = 0.17
    V, F = cylinder(r, 1.0)
    per = section_circumference(V, F, [0.0, 0.41, 0.0], [0.0, 1.0, 0.0])
    polygon = 2 * 256 * r * np.sin(np.pi / 256)  # the mesh is a 256-gon
    assert per == pytest.approx(polygon, rel=1e-9)
    assert per == pytest.approx(2 * np.pi * r, rel=1e-4)
    # an oblique plane through the axis cuts an ellipse with semi-axes r and r / cos(30 deg)
    n = [np.sin(np.radians(30)), np.cos(np.radians(30)), 0.0]
    per = section_circumference(V, F, [0.0, 0.5, 0.0], n)
    a, b = r / np.cos(np.radians(30)), r
    ramanujan = np.pi * (3 * (a + b) - np.sqrt((3 * a + b) * (a + 3 * b)))
    assert per == pytest.approx(ramanujan, rel=1e-3)


def test_box_section_perimeter_and_volume():
    V, F = box(0.3, 1.2, 0.2)
    assert section_circumference(V, F, [0, 0.6, 0], [0, 1, 0]) == pytest.approx(2 * (0.3 + 0.2))
    assert section_circumference(V, F, [0.1, 0, 0], [1, 0, 0]) == pytest.approx(2 * (1.2 + 0.2))
    assert mesh_volume(V, F) == pytest.approx(0.3 * 1.2 * 0.2)
    assert mesh_volume(V, F[:, ::-1]) == pytest.approx(0.3 * 1.2 * 0.2)  # either winding
    assert section_circumference(V, F, [0, 2.0, 0], [0, 1, 0]) == 0.0  # plane misses the box


def test_cylinder_volume_and_section_loops():
    V, F = cylinder(0.1, 0.5, n=512)
    area = 0.5 * 512 * 0.1**2 * np.sin(2 * np.pi / 512)
    assert mesh_volume(V, F) == pytest.approx(area * 0.5, rel=1e-9)
    # two cylinders side by side: two loops; `near` keeps the one asked for
    V2 = np.concatenate([V, V + np.array([0.5, 0.0, 0.0])])
    F2 = np.concatenate([F, F + len(V)])
    s = plane_section(V2, F2, [0, 0.25, 0], [0, 1, 0])
    assert s.n_components == 2
    both = convex_perimeter(s.to_2d())
    one = convex_perimeter(s.to_2d(s.piece(np.array([0.5, 0.25, 0.0]))))
    assert one == pytest.approx(2 * 512 * 0.1 * np.sin(np.pi / 512), rel=1e-9)
    assert both == pytest.approx(2 * np.pi * 0.1 + 2 * 0.5, rel=1e-4)  # a taut band round both


def test_convex_perimeter_degenerate_inputs():
    assert convex_perimeter(np.zeros((1, 2))) == 0.0
    assert convex_perimeter(np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]])) == pytest.approx(6.0)
    with pytest.raises(ValueError, match=r"\(k, 2\)"):
        convex_perimeter(np.zeros((4, 3)))


# ---------------------------------------------------------------------- bodies
@pytest.fixture(scope="module")
def tpl_m() -> dict[str, float]:
    return measure(TPL.V)


@pytest.fixture(scope="module")
def randoms() -> list:
    return [random_body(np.random.default_rng(100 + s)) for s in range(6)]


def test_metadata_and_names(tpl_m):
    assert len(MEASUREMENTS) >= 20
    assert set(REQUIRED) <= set(MEASUREMENTS)
    assert set(tpl_m) == set(MEASUREMENTS)
    csv_path = ANSUR / "ansur2_female_dev.csv"
    header = csv_path.open().readline().strip().split(",") if csv_path.exists() else []
    for name, meta in MEASUREMENTS.items():
        assert meta.ansur == name
        if header:
            assert name in header, name
        assert meta.kind in (*LENGTH_KINDS, "mass")
        assert meta.unit == ("kg" if meta.kind == "mass" else "m")
        assert len(meta.definition) > 20
    assert all(np.isfinite(v) and v > 0 for v in tpl_m.values())


def test_names_subset_and_bad_input():
    m = measure(TPL.V, names=["stature", "waistcircumference"])
    assert list(m) == ["stature", "waistcircumference"]
    with pytest.raises(ValueError, match="unknown measurement"):
        measure(TPL.V, names=["waist"])
    with pytest.raises(ValueError, match="template order"):
        measure(TPL.V[:100])
    with pytest.raises(ValueError, match="side"):
        measure(TPL.V, side="middle")
    with pytest.raises(ValueError, match="density"):
        measure(TPL.V, density=-1.0)
    bad = np.array(TPL.V)
    bad[5, 1] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        measure(bad)


def test_template_stature_equals_its_height(tpl_m):
    assert tpl_m["stature"] == pytest.approx(TPL.V[:, 1].max() - TPL.V[:, 1].min(), abs=1e-12)


def test_scaling_scales_lengths_by_s_and_weight_by_s_cubed(tpl_m):
    s = 1.07
    V = np.array(TPL.V) * s + [0.3, 0.2, -0.1]  # scaled about the origin, then moved
    m = measure(V)
    for name, meta in MEASUREMENTS.items():
        want = tpl_m[name] * (s**3 if meta.kind == "mass" else s)
        assert m[name] == pytest.approx(want, rel=2e-3), name


def test_density_scales_weight():
    assert measure(TPL.V, names=["weightkg"], density=1000.0)["weightkg"] == pytest.approx(
        mesh_volume(TPL.V, TPL.F) * 1000.0
    )


def test_left_and_right_agree_on_the_symmetric_template(tpl_m):
    left = measure(TPL.V, side="left")
    for name in MEASUREMENTS:
        assert left[name] == pytest.approx(tpl_m[name], rel=1e-6, abs=1e-9), name


def test_mirrored_body_swaps_sides(randoms):
    V = randoms[0].V
    mirrored = np.array(V) * [-1.0, 1.0, 1.0]
    mirrored = mirrored[TPL.mirror]  # back into template order: left vertex <-> right vertex
    a, b = measure(V, side="right"), measure(mirrored, side="left")
    for name, meta in MEASUREMENTS.items():
        # landmark measures agree exactly; sections differ slightly, as the quads' diagonals
        # (the triangulation) are not mirror images of each other
        rel = 5e-3 if meta.kind in ("circumference", "breadth", "depth", "mass") else 1e-9
        assert b[name] == pytest.approx(a[name], rel=rel), name


def test_template_is_plausible(tpl_m):
    assert 45.0 < tpl_m["weightkg"] < 80.0
    assert 1.60 < tpl_m["stature"] < 1.75
    assert 0.5 < tpl_m["headcircumference"] < 0.62
    assert tpl_m["stature"] > tpl_m["cervicaleheight"] > tpl_m["acromialheight"]
    assert tpl_m["acromialheight"] > tpl_m["waistheightomphalion"] > tpl_m["crotchheight"]
    assert tpl_m["crotchheight"] > tpl_m["kneeheightmidpatella"]
    assert tpl_m["buttockcircumference"] > tpl_m["thighcircumference"]
    assert tpl_m["thighcircumference"] > tpl_m["calfcircumference"]
    assert tpl_m["calfcircumference"] > tpl_m["anklecircumference"]
    assert tpl_m["bicepscircumferenceflexed"] > tpl_m["forearmcircumferenceflexed"]
    assert tpl_m["forearmcircumferenceflexed"] > tpl_m["wristcircumference"]


#: Generous plausible ranges for adult bodies, metres (kg for weight).
RANGES = {
    "stature": (1.45, 2.0),
    "chestcircumference": (0.7, 1.4),
    "waistcircumference": (0.55, 1.3),
    "buttockcircumference": (0.75, 1.35),
    "neckcircumference": (0.26, 0.5),
    "thighcircumference": (0.42, 0.8),
    "calfcircumference": (0.28, 0.5),
    "bicepscircumferenceflexed": (0.2, 0.45),
    "forearmcircumferenceflexed": (0.18, 0.36),
    "wristcircumference": (0.11, 0.21),
    "headcircumference": (0.45, 0.65),
    "biacromialbreadth": (0.28, 0.48),
    "hipbreadth": (0.28, 0.46),
    "acromionradialelength": (0.22, 0.4),
    "radialestylionlength": (0.18, 0.32),
    "footlength": (0.2, 0.31),
    "weightkg": (35.0, 130.0),
}


def test_random_bodies_are_plausible(randoms):
    for b in randoms:
        m = measure(b.V)
        for name, (lo, hi) in RANGES.items():
            assert lo < m[name] < hi, (name, m[name], b.sex)
        assert m["stature"] == pytest.approx(b.stature_m, abs=0.01)  # head top is the top
        assert m["crotchheight"] < m["waistheightomphalion"] < m["acromialheight"]


def test_waist_target_increases_waist_circumference():
    lib = load_targets()
    name = "torso/measure-waist-circ-incr"
    assert name in lib.names
    V = np.array(TPL.V)
    before = measure(V, names=["waistcircumference", "stature"])
    after = measure(V + lib.dense(name), names=["waistcircumference", "stature"])
    assert after["waistcircumference"] > before["waistcircumference"] + 0.02
    assert after["stature"] == pytest.approx(before["stature"], abs=0.005)
    thin = measure(V + lib.dense("torso/measure-waist-circ-decr"), names=["waistcircumference"])
    assert thin["waistcircumference"] < before["waistcircumference"] - 0.02


@pytest.mark.parametrize(
    ("target", "name"),
    [
        ("legs/measure-thigh-circ-incr", "thighcircumference"),
        ("neck/measure-neck-circ-incr", "neckcircumference"),
        ("torso/measure-hips-circ-incr", "buttockcircumference"),
    ],
)
def test_regional_targets_increase_their_measurement(target, name):
    lib = load_targets()
    V = np.array(TPL.V)
    assert measure(V + lib.dense(target), names=[name])[name] > measure(V, names=[name])[name]


def test_measure_is_fast(randoms):
    V = randoms[1].V
    measure(V)
    times = []
    for _ in range(5):
        t0 = time.process_time()
        measure(V)
        times.append(time.process_time() - t0)
    ms = 1e3 * float(np.median(times))
    print(f"\nmeasure(): {ms:.1f} ms CPU for {len(MEASUREMENTS)} measurements")
    assert ms < 100.0  # ~30 ms on an idle core; generous for loaded CI machines
