"""The default shape model beyond its training range (issue 12 item 4): every ANSUR II subject is
accepted, civilian extremes (stature 1.40–2.05 m, BMI 15–55) give plausible bodies with a
warning, physically meaningless values are refused naming the accepted range."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from core.shapespace import OutOfRangeError, body_height, default_model
from core.shapespace.features import MAX_MAHALANOBIS
from core.template import load_template

ANSUR_COPIES = [
    Path(__file__).resolve().parents[2] / "core" / "assets" / "ansur2",
    Path("/work/shared/data/ansur2"),
]


def _rows(folder: Path, sex: str) -> list[tuple[float, float, float]]:
    with open(folder / f"ansur2_{sex}_dev.csv", newline="") as f:
        return [
            (float(r["stature"]) / 1000, float(r["weightkg"]) / 10, float(r["Age"]))
            for r in csv.DictReader(f)
        ]


@pytest.mark.parametrize("folder", ANSUR_COPIES, ids=["assets", "shared"])
@pytest.mark.parametrize("sex", ["female", "male"])
def test_every_ansur_subject_is_accepted(folder, sex):
    """All rows (held in and held out) of both copies: stature, weight and age pass the feature
    map's checks (no body is made: that is the grid test's job)."""
    if not folder.exists():
        pytest.skip(f"{folder} not present")
    fm = default_model().space(sex).features
    rows = _rows(folder, sex)
    assert len(rows) > 1000
    for h, w, age in rows:
        fm.weights({"height_m": h, "weight_kg": w, "age": age})


def test_the_141_kg_soldier():
    """Issue 12's held-out soldier (male, 1.85 m, 141 kg; the model stopped at 136 kg)."""
    m = default_model()
    f = {"height_m": 1.85, "weight_kg": 141.0}
    V = m.synthesize("male", f)
    assert abs(body_height(V) - 1.85) < 1e-6
    assert abs(m.weight_kg(V, "male") - 141.0) < 0.02 * 141.0
    warnings = m.range_warnings("male", f)
    assert (
        len(warnings) == 1
        and "weight_kg=141 kg is beyond the model's training range" in (warnings[0])
    )


def _normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return np.cross(b - a, c - a)


@pytest.mark.parametrize("sex", ["female", "male"])
def test_civilian_extremes_give_plausible_bodies(sex):
    """Stature 1.40–2.05 m x BMI 15–55 (6 x 6): requested stature (± 5 mm) and weight (± 2 %,
    volume x the model's density), finite, both soles on the floor (≤ 6 mm: bodies inside the
    training range, which are the plain feature map's, reach 5.2 mm), and no sign of
    self-intersection: ≤ 1 % of the faces flipped against the mean body's normals, 99.8 % of
    the edges within 0.2–3x their mean-body length (measured: ≤ 0.52 %, 0.27–2.46x)."""
    m = default_model()
    tpl = load_template()
    F, E = tpl.F, tpl.edges
    V0 = m.synthesize(sex, {})
    n0 = _normals(V0, F)
    ok = np.linalg.norm(n0, axis=1) > 1e-7
    L0 = np.linalg.norm(V0[E[:, 0]] - V0[E[:, 1]], axis=1)
    long = L0 > 1e-3
    feet = [tpl.part_mask(p) for p in ("foot_L", "foot_R")]
    fm = m.space(sex).features
    (hlo, hhi), (wlo, whi) = fm.ranges["height_m"], fm.ranges["weight_kg"]
    n_warned = 0
    for h in np.linspace(1.40, 2.05, 6):
        for bmi in np.linspace(15.0, 55.0, 6):
            f = {"height_m": float(h), "weight_kg": float(bmi * h * h)}
            V = m.synthesize(sex, f)
            assert np.isfinite(V).all()
            assert abs(body_height(V) - h) < 0.005
            assert abs(m.weight_kg(V, sex) / f["weight_kg"] - 1.0) < 0.02, (h, bmi)
            assert abs(V[:, 1].min()) < 1e-12
            assert max(float(V[p, 1].min()) for p in feet) < 0.006, (h, bmi)
            flipped = ((np.einsum("ij,ij->i", _normals(V, F), n0) < 0) & ok).mean()
            assert flipped < 0.01, (h, bmi, flipped)
            r = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)[long] / L0[long]
            lo, hi = np.percentile(r, [0.1, 99.9])
            assert lo > 0.2 and hi < 3.0, (h, bmi, lo, hi)
            inside = hlo <= h <= hhi and wlo <= f["weight_kg"] <= whi
            inside = inside and fm.mahalanobis(f) <= MAX_MAHALANOBIS
            assert bool(m.range_warnings(sex, f)) == (not inside), (h, bmi)
            n_warned += not inside
    assert 10 < n_warned < 36  # the grid's middle is inside the training range


@pytest.mark.parametrize("sex", ["female", "male"])
def test_warnings_exactly_outside_the_training_range(sex):
    """No warning inside the training range (each feature inside ``ranges``, the combination
    within MAX_MAHALANOBIS), one naming the feature beyond it."""
    m = default_model()
    fm = m.space(sex).features
    (hlo, hhi), (wlo, whi) = fm.ranges["height_m"], fm.ranges["weight_kg"]
    h0, w0 = fm.conditional({})["height_m"], fm.conditional({})["weight_kg"]
    assert m.range_warnings(sex, {"height_m": h0, "weight_kg": w0}) == []
    assert m.range_warnings(sex, {"age": 30}) == []
    for f, name in (
        ({"height_m": hhi + 0.01}, "height_m"),
        ({"height_m": hlo - 0.01}, "height_m"),
        ({"weight_kg": whi + 1}, "weight_kg"),
        ({"age": 70}, "age"),
    ):
        (w,) = [x for x in m.range_warnings(sex, f) if x.startswith(name)]
        assert "training range" in w and "extrapolated" in w
        m.synthesize(sex, f)  # accepted
    # inside each range but an unusual combination
    f = {"height_m": hhi - 0.01, "weight_kg": wlo + 1}
    assert fm.mahalanobis(f) > MAX_MAHALANOBIS
    (w,) = m.range_warnings(sex, f)
    assert "unlike the model's training bodies" in w


@pytest.mark.parametrize(
    ("features", "match"),
    [
        ({"height_m": 0.9}, r"height_m=0\.9 m is outside the supported range 1–2\.5 m"),
        ({"height_m": 2.6}, r"height_m=2\.6 m is outside the supported range 1–2\.5 m"),
        ({"height_m": 1.7, "weight_kg": 27.0}, r"body-mass index of 9\.3.*10–80"),
        ({"height_m": 1.7, "weight_kg": 240.0}, r"body-mass index of 83\.0.*10–80"),
        ({"weight_kg": 5.0}, r"weight_kg=5 kg is outside the supported range 10–500 kg"),
        ({"age": 12}, r"age=12 years is outside the supported range 17–90 years"),
        ({"age": 95}, r"age=95 years is outside the supported range 17–90 years"),
        ({"height_m": float("nan")}, "finite"),
    ],
)
def test_meaningless_values_are_refused(features, match):
    with pytest.raises(OutOfRangeError, match=match):
        default_model().synthesize("male", features)


def test_the_whole_accepted_range_gives_finite_bodies():
    """Beyond the civilian extremes, up to the limits: finite bodies of the requested stature
    and weight (not checked for plausibility: the warnings say they are extrapolated)."""
    m = default_model()
    for sex in ("female", "male"):
        for h, bmi in ((1.0, 10.0), (1.0, 80.0), (2.5, 10.0), (2.5, 80.0)):
            f = {"height_m": h, "weight_kg": bmi * h * h, "age": 90.0}
            V = m.synthesize(sex, f)
            assert np.isfinite(V).all()
            assert abs(body_height(V) - h) < 0.005
            assert m.range_warnings(sex, f)


def test_age_range_is_adult():
    m = default_model()
    for sex in ("female", "male"):
        fm = m.space(sex).features
        assert fm.limits("age") == (17.0, 90.0)
        assert fm.training_range("age") == (17.0, 58.0)
        assert m.describe()["spaces"][sex]["features"]["age"]["range"][0] >= 17.0


@pytest.mark.parametrize("sex", ["female", "male"])
def test_bodies_from_measurements_at_the_extremes(sex):
    """``body_from_measurements`` (CLI and the measurements fit mode) at the grid's corners: the
    given stature (5 mm) and weight (2 %), both soles on the floor (it symmetrises as synthesis
    does: without, one foot was up to 16.8 mm off the floor), the extrapolation warned about."""
    from core.matching.from_measurements import body_from_measurements

    m = default_model()
    feet = [load_template().part_mask(p) for p in ("foot_L", "foot_R")]
    for h, bmi in ((1.40, 15.0), (1.40, 55.0), (2.05, 15.0), (2.05, 55.0)):
        r = body_from_measurements(sex, {"stature": h, "weightkg": bmi * h * h})
        V = r.vertices
        assert np.isfinite(V).all()
        assert abs(body_height(V) - h) < 0.005
        assert abs(m.weight_kg(V, sex) / (bmi * h * h) - 1.0) < 0.02
        assert max(float(V[p, 1].min()) for p in feet) < 0.003, (h, bmi)
        assert any("training range" in w for w in r.report.warnings)
