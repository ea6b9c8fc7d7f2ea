"""``bodyspace build-model``: a lab builds its own shape space from a folder of fits."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from core.shapespace import load_model
from core.shapespace.model import body_volume
from core.synth import random_body
from tests.core.test_cli import assert_one_line_error, run_cli


@pytest.fixture(scope="module")
def fits_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("fits")
    rows = []
    for i in range(16):
        sex = "female" if i % 2 else "male"
        b = random_body(np.random.default_rng(500 + i), sex=sex, pose=False)
        np.savez(d / f"s{i:02d}.npz", vertices=b.V)
        height = float(np.ptp(b.V[:, 1]))
        rows.append({"id": f"s{i:02d}", "sex": sex, "height_m": height,
                     "weight_kg": body_volume(b.V) * 1010.0})  # fmt: skip
    with open(d / "features.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["id", "sex", "height_m", "weight_kg"])
        w.writeheader()
        w.writerows(rows)
    return d


def test_build_model_from_a_folder(fits_dir, tmp_path):
    out = tmp_path / "model.npz"
    r = run_cli("build-model", fits_dir, "--out", out, "--variance", "0.99")
    assert r.returncode == 0, r.stderr
    model = load_model(out)
    V = np.load(fits_dir / "s03.npz")["vertices"]  # a training body (female)
    back = model.reconstruct("female", model.project("female", V))
    # the body is rotated/centred into the model frame: compare shapes, not placement
    Vc, Bc = V - V.mean(axis=0), back - back.mean(axis=0)
    assert np.sqrt(np.mean(np.sum((Vc - Bc) ** 2, axis=1))) < 0.01


def test_build_model_errors(tmp_path, fits_dir):
    r = run_cli("build-model", tmp_path / "nope", "--out", tmp_path / "m.npz")
    assert_one_line_error(r, "not found")
    r = run_cli("build-model", fits_dir, "--out", tmp_path / "m.txt")
    assert_one_line_error(r, ".npz")
    bad = tmp_path / "bad.csv"
    bad.write_text("id,height_m\nx,1.7\n")
    r = run_cli("build-model", fits_dir, "--features", bad, "--out", tmp_path / "m.npz")
    assert_one_line_error(r, "sex")
