"""The ``bodyspace`` command line, run as a real subprocess.

Error cases must exit 2 with one ``bodyspace: error: …`` line and no traceback. The real fits use
``--fast`` and check the result against the simulator's truth.

Bounds (measured, fast schedule, per-vertex error to the truth): the small simulated scan below
(``ScanConfig.small``, seed 0, mm, +Z up, ~26 k points) measured mean 2.2-3.0 mm / p95 4.5-6.2 mm
while the registration was being tuned (seeds 0-7: mean 2.0-4.8 mm, p95 4.2-10.5 mm); the test
asserts mean < 6 mm and p95 < 12 mm. The bundled example (``bodyspace demo --fast``) measured
mean 2.8 mm / p95 5.2 mm; asserted mean < 6 mm and p95 < 12 mm.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from core.io import detect_frame, read_mesh, write_markers_csv, write_ply
from core.registration.schedule import Schedule
from core.synth import ScanConfig, random_body, simulate_scan
from core.template import load_template

REPO = Path(__file__).resolve().parents[2]
N_TEMPLATE = 13380
REPORT_KEYS = {
    "stages",
    "seconds",
    "scan_to_fit_mean_m",
    "scan_to_fit_p95_m",
    "no_data_fraction",
    "markers_used",
    "markers_dropped",
    "warnings",
    "units",
    "up",
    "inputs",
    "frame",
    "schedule",
    "timing_s",
    "outputs",
}


def run_cli(*args: str | Path, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "service.cli", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=cwd or REPO,
        timeout=600,
    )


def assert_one_line_error(r: subprocess.CompletedProcess, *needles: str) -> str:
    """Exit 2, exactly one error line (progress lines aside), no traceback."""
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert "Traceback" not in r.stderr
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("bodyspace: error: ")]
    others = [ln for ln in r.stderr.splitlines() if ln and not ln.startswith("fit")]
    assert len(errors) == 1, r.stderr
    assert others == errors, r.stderr  # nothing but progress and the one error line
    for n in needles:
        assert n in errors[0], errors[0]
    return errors[0]


@pytest.fixture(scope="module")
def small_case(tmp_path_factory) -> dict:
    """A small simulated scan (mm, +Z up) with markers and its truth (canonical metres)."""
    d = tmp_path_factory.mktemp("cli")
    rng = np.random.default_rng(0)
    tpl = load_template()
    body = random_body(rng, pose=True)
    sim = simulate_scan(
        body.V,
        tpl.F,
        rng,
        config=ScanConfig.small(units="mm", up="+z"),
        landmarks=tpl.landmarks,
    )
    scan = d / "scan.ply"
    markers = d / "markers.csv"
    write_ply(scan, sim.V_scan, sim.F_scan, confidence=sim.confidence)
    write_markers_csv(markers, sim.markers)
    frame = detect_frame(sim.V_scan, markers=sim.markers)
    truth = frame.to_canonical(sim.V_truth)
    return {"dir": d, "scan": scan, "markers": markers, "truth": truth, "sim": sim}


# ----------------------------------------------------------------------------- errors


def test_missing_scan_file(tmp_path, small_case):
    r = run_cli(
        "fit",
        tmp_path / "nope.ply",
        "--markers",
        small_case["markers"],
        "--out",
        tmp_path / "f.ply",
    )
    assert_one_line_error(r, "not found", "nope.ply")
    assert r.stderr.count("\n") == 1


def test_garbage_scan(tmp_path, small_case):
    bad = tmp_path / "garbage.ply"
    bad.write_bytes(b"this is not a mesh\n" * 20)
    r = run_cli("fit", bad, "--markers", small_case["markers"], "--out", tmp_path / "f.ply")
    assert_one_line_error(r, "garbage.ply")
    assert not (tmp_path / "f.ply").exists()


def test_unknown_marker_name(tmp_path, small_case):
    m = tmp_path / "m.csv"
    m.write_text(small_case["markers"].read_text() + "Belly_button,1,2,3\n")
    r = run_cli("fit", small_case["scan"], "--markers", m, "--out", tmp_path / "f.ply")
    assert_one_line_error(r, "Belly_button", "valid names")


def test_fewer_than_three_markers(tmp_path, small_case):
    lines = small_case["markers"].read_text().splitlines()
    m = tmp_path / "m.csv"
    m.write_text("\n".join(lines[:3]) + "\n")  # header + 2 markers
    r = run_cli("fit", small_case["scan"], "--markers", m, "--out", tmp_path / "f.ply")
    assert_one_line_error(r, "at least 3")
    assert not (tmp_path / "f.ply").exists()


@pytest.mark.parametrize("name", ["fit.stl", "fit", "fit.json"])
def test_bad_out_extension(tmp_path, small_case, name):
    r = run_cli("fit", small_case["scan"], "--markers", small_case["markers"], "--out", name)
    assert_one_line_error(r, "--out", ".ply, .obj, .glb")
    assert r.stderr.count("\n") == 1  # fails before any work


def test_unwritable_out_folder(tmp_path, small_case):
    out = tmp_path / "no" / "such" / "dir" / "f.glb"
    r = run_cli("fit", small_case["scan"], "--markers", small_case["markers"], "--out", out)
    assert_one_line_error(r, "does not exist")


def test_no_markers_with_paper_schedule_is_an_error(tmp_path, small_case):
    r = run_cli("fit", small_case["scan"], "--out", tmp_path / "f.ply", "--schedule", "paper")
    assert_one_line_error(r, "body prior", "--markers")
    assert r.stderr.count("\n") == 1


def test_no_markers_runs_markerless(tmp_path, small_case):
    out = tmp_path / "f.ply"
    r = run_cli("fit", small_case["scan"], "--out", out, "--fast", "--quiet")
    assert r.returncode == 0, r.stderr
    V = read_mesh(out).V
    assert V.shape == (N_TEMPLATE, 3)
    err = np.linalg.norm(V - small_case["truth"], axis=1) * 1000
    assert err.mean() < 10.0  # measured 4-6.3 mm on small scans (tests/core/test_matching.py)


def test_help_and_usage():
    r = run_cli("--help")
    assert r.returncode == 0
    assert "fit" in r.stdout and "demo" in r.stdout
    r = run_cli()
    assert r.returncode == 2
    r = run_cli("fit", "--help")
    assert r.returncode == 0
    for opt in ("--markers", "--out", "--report", "--units", "--up", "--fast", "--quiet"):
        assert opt in r.stdout


# ----------------------------------------------------------------------------- real fits


@pytest.mark.slow
def test_fit_small_scan_recovers_truth(small_case):
    d = small_case["dir"]
    out, rep = d / "fit.ply", d / "report.json"  # read_mesh reads PLY/OBJ, not GLB
    r = run_cli(
        "fit",
        small_case["scan"],
        "--markers",
        small_case["markers"],
        "--out",
        out,
        "--report",
        rep,
        "--fast",
    )
    assert r.returncode == 0, r.stderr
    assert "scan->fit distance" in r.stdout and "markers:" in r.stdout

    mesh = read_mesh(out)
    assert mesh.V.shape == (N_TEMPLATE, 3)
    assert mesh.F is not None and len(mesh.F) == len(load_template().F)

    report = json.loads(rep.read_text())
    assert not REPORT_KEYS - set(report), REPORT_KEYS - set(report)
    assert report["frame"]["units"] == "mm" and report["frame"]["up"] == "+z"
    assert report["frame"]["detected"] is True
    assert report["schedule"] == "fast"
    assert len(report["stages"]) == len(Schedule.fast().stages)
    assert len(report["markers_used"]) >= 50
    assert report["scan_to_fit_mean_m"] < 0.005

    err = np.linalg.norm(mesh.V - small_case["truth"], axis=1)
    assert err.mean() < 0.006, err.mean()
    assert np.percentile(err, 95) < 0.012, np.percentile(err, 95)


@pytest.mark.slow
def test_demo_fast(tmp_path):
    out_dir = tmp_path / "demo"
    r = run_cli("demo", "--out-dir", out_dir, "--fast", "--quiet")
    assert r.returncode == 0, r.stderr
    assert r.stdout == ""  # --quiet
    for name in ("fit.glb", "fit.ply", "report.json"):
        assert (out_dir / name).stat().st_size > 0
    assert read_mesh(out_dir / "fit.ply").V.shape == (N_TEMPLATE, 3)
    report = json.loads((out_dir / "report.json").read_text())
    te = report["truth_error_m"]
    assert te["mean_m"] < 0.006, te
    assert te["p95_m"] < 0.012, te
    assert report["frame"] == {"units": "mm", "up": "+z", "detected": True, "scale_to_m": 0.001}
