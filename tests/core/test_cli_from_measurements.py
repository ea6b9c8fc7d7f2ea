"""``bodyspace from-measurements``: the most likely body from tape measurements, on the CLI."""

from __future__ import annotations

import json

import numpy as np

from core.io import read_mesh
from tests.core.test_cli import assert_one_line_error, run_cli


def test_from_measurements_file_and_pairs(tmp_path):
    m = tmp_path / "m.json"
    m.write_text(json.dumps({"stature": 1.70, "weightkg": 64.0, "waistcircumference": 0.76}))
    out, rep = tmp_path / "body.ply", tmp_path / "report.json"
    r = run_cli("from-measurements", m, "--measure", "stature=1.66", "--sex", "female",
                "--out", out, "--report", rep)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "waistcircumference" in r.stdout and "wrote" in r.stdout
    V = read_mesh(out).V
    assert V.shape == (13380, 3)
    assert abs(np.ptp(V[:, 1]) - 1.66) < 0.015  # the pair overrides the file
    report = json.loads(rep.read_text())
    assert report["given"] == {"stature": 1.66, "weightkg": 64.0, "waistcircumference": 0.76}
    assert report["calibrated"] is True and report["outputs"] == [str(out)]
    assert abs(report["matched"]["stature"]["residual"]) < 0.01


def test_from_measurements_errors(tmp_path):
    out = tmp_path / "body.glb"
    r = run_cli("from-measurements", "--sex", "male", "--measure", "height_m=1.8", "--out", out)
    assert_one_line_error(r, "unknown measurement", "did you mean 'stature'")
    r = run_cli("from-measurements", "--sex", "male", "--measure", "stature=1800", "--out", out)
    assert_one_line_error(r, "looks like millimetres")
    r = run_cli("from-measurements", "--sex", "male", "--measure", "stature", "--out", out)
    assert_one_line_error(r, "NAME=VALUE")
    r = run_cli("from-measurements", "--sex", "male", "--out", out)
    assert_one_line_error(r, "give measurements")
    bad = tmp_path / "bad.json"
    bad.write_text("[1, 2]")
    r = run_cli("from-measurements", bad, "--sex", "male", "--out", out)
    assert_one_line_error(r, "one JSON object")
    r = run_cli("from-measurements", "--sex", "male", "--measure", "stature=1.8",
                "--out", tmp_path / "body.stl")  # fmt: skip
    assert_one_line_error(r, "unsupported extension")
    assert not out.exists()


def test_from_measurements_accepts_the_synthesis_ranges(tmp_path):
    """The CLI takes what synthesis takes: the 141 kg soldier and a 1.40 m BMI 55 woman give a
    body and a warning (printed and in the report); a BMI of 90 is refused naming the range."""
    out, rep = tmp_path / "body.ply", tmp_path / "report.json"
    for sex, h, kg in (("male", 1.85, 141.0), ("female", 1.40, 107.8)):
        r = run_cli("from-measurements", "--sex", sex, "--measure", f"stature={h}",
                    "--measure", f"weightkg={kg}", "--out", out, "--report", rep)  # fmt: skip
        assert r.returncode == 0, r.stderr
        report = json.loads(rep.read_text())
        assert any("beyond the model's training range" in w for w in report["warnings"])
        assert "training range" in r.stdout + r.stderr
        assert abs(np.ptp(read_mesh(out).V[:, 1]) - h) < 0.005
    r = run_cli("from-measurements", "--sex", "male", "--measure", "stature=1.70",
                "--measure", "weightkg=260", "--out", out)  # fmt: skip
    assert_one_line_error(r, "body-mass index of 90.0", "10–80 kg/m²")
