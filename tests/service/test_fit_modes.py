"""Fit modes through a real server: markerless, markers-only (with and without a scan), bad input.

Bounds: the embedded server fits the small simulated scan of ``sim`` (seed 0) whose truth is
known; markerless with the fast schedule, markers-only from the 62 simulated markers.
"""

from __future__ import annotations

import numpy as np
import pytest

from core.io import read_markers
from core.io.frame import rotation_for_up
from core.template import load_template
from service.testing import glb_vertices, upload_scan, wait_state

FAST = {"schedule": "fast"}


def _markers(sim) -> dict[str, list[float]]:
    """The simulated markers (the sim files are in metres, +Y up, like the canonical frame)."""
    names = load_template().landmarks
    return {
        k: [float(x) for x in v] for k, v in read_markers(sim.markers, valid_names=names).items()
    }


def _error_mm(client, fit_id: str, truth: np.ndarray) -> np.ndarray:
    r = client.get(f"/v1/fits/{fit_id}/result", params={"format": "glb"})
    assert r.status_code == 200, r.text
    V = glb_vertices(r.content).astype(np.float64)
    assert V.shape == (13380, 3)
    return np.linalg.norm(V - truth, axis=1) * 1000


def _check(r, status: int, code: str) -> dict:
    assert r.status_code == status, r.text
    err = r.json()["error"]
    assert err["code"] == code, err
    assert err["message"]
    return err


def test_markerless_fit_recovers_truth(client, sim):
    scan = upload_scan(client, sim).json()
    r = client.post("/v1/fits", json={"scan_id": scan["id"], "mode": "markerless", "options": FAST})
    assert r.status_code == 202, r.text
    assert r.json()["mode"] == "markerless" and r.json()["scan_id"] == scan["id"]
    done = wait_state(client, r.json()["id"], timeout=180)
    assert done["state"] == "succeeded", done
    e = _error_mm(client, done["id"], sim.truth)
    assert e.mean() < 10.0, f"mean vertex error {e.mean():.1f} mm"
    rep = client.get(f"/v1/fits/{done['id']}/result", params={"format": "json"}).json()
    assert rep["markers_used"] == []  # the scan's uploaded markers are ignored
    assert any("markerless" in n for n in rep["notes"])


def test_markers_only_fit_without_scan(client, client_b, server, sim):
    r = client.post("/v1/fits", json={"mode": "markers_only", "markers": _markers(sim)})
    assert r.status_code == 202, r.text
    fit = r.json()
    assert fit["scan_id"] is None and fit["mode"] == "markers_only"
    assert fit["options"]["units"] == "m" and fit["options"]["up"] == "+y"
    done = wait_state(client, fit["id"])
    assert done["state"] == "succeeded", done
    assert done["result_formats"] == ["glb", "ply", "obj", "json"]
    e = _error_mm(client, fit["id"], sim.truth)
    assert e.mean() < 15.0, f"mean vertex error {e.mean():.1f} mm"
    rep = client.get(f"/v1/fits/{fit['id']}/result", params={"format": "json"}).json()
    assert len(rep["markers_used"]) == 62 and rep["units"] == "m"

    # it belongs to the tenant: listed, invisible to others, deleted with DELETE /v1/fits/{id}
    listed = client.get("/v1/fits", params={"mode": "markers_only", "limit": 200}).json()
    assert fit["id"] in [f["id"] for f in listed["items"]]
    assert all(f["mode"] == "markers_only" for f in listed["items"])
    assert client_b.get(f"/v1/fits/{fit['id']}").status_code == 404
    assert client_b.delete(f"/v1/fits/{fit['id']}").status_code == 404
    blobs = server["data"] / "blobs"
    assert list(blobs.glob(f"*/fits/{fit['id']}/*"))
    assert client.delete(f"/v1/fits/{fit['id']}").status_code == 204
    assert client.get(f"/v1/fits/{fit['id']}").status_code == 404
    assert client.get(f"/v1/fits/{fit['id']}/result").status_code == 404
    assert not list(blobs.glob(f"*/fits/{fit['id']}*"))


def test_marker_units_are_the_frames_options():
    from typing import get_args

    from core.io.frame import UNITS_OPTIONS
    from service.schemas import MarkerUnits

    assert set(get_args(MarkerUnits)) == set(UNITS_OPTIONS)


def _markers_only_in(client, sim, markers: dict, frames: tuple, want: tuple[str, str]) -> None:
    """Markers-only fits of ``markers`` (in some file frame) declared as each (units, up) of
    ``frames``: each job's frame is ``want`` and its fit lands on the truth."""
    for units, up in frames:
        body = {"mode": "markers_only", "markers": markers, "units": units, "up": up}
        r = client.post("/v1/fits", json=body)
        assert r.status_code == 202, r.text
        assert (r.json()["options"]["units"], r.json()["options"]["up"]) == want
        done = wait_state(client, r.json()["id"])
        assert done["state"] == "succeeded", done
        assert _error_mm(client, done["id"], sim.truth).mean() < 15.0


def test_markers_only_in_mm_z_up(client, sim):
    R = rotation_for_up("+z")  # file -> canonical
    mm = {k: (1000.0 * (R.T @ np.asarray(v))).tolist() for k, v in _markers(sim).items()}
    # in mm but declared metres (the default): refused before the job exists
    _check(client.post("/v1/fits", json={"mode": "markers_only", "markers": mm}), 422,
           "ambiguous_units")  # fmt: skip
    _markers_only_in(client, sim, mm, (("mm", "+z"), ("auto", "auto")), ("mm", "+z"))


def test_markers_only_in_inches(client, sim):
    """US scanners' inches: declared or detected from the markers' height, the fit in metres."""
    inch = {k: (np.asarray(v) / 0.0254).tolist() for k, v in _markers(sim).items()}
    _markers_only_in(client, sim, inch, (("in", "auto"), ("auto", "auto")), ("in", "+y"))


def test_markers_only_from_the_scans_marker_file(client, sim):
    scan = upload_scan(client, sim).json()
    r = client.post("/v1/fits", json={"scan_id": scan["id"], "mode": "markers_only"})
    assert r.status_code == 202, r.text
    done = wait_state(client, r.json()["id"])
    assert done["state"] == "succeeded", done
    assert _error_mm(client, done["id"], sim.truth).mean() < 15.0
    # deleting the scan deletes the fits made from its markers
    assert client.delete(f"/v1/scans/{scan['id']}").status_code == 204
    assert client.get(f"/v1/fits/{done['id']}").status_code == 404


@pytest.mark.parametrize(
    ("body", "status", "code"),
    [
        ({"mode": "markers_only"}, 422, "markers_required"),
        ({"mode": "markers_only", "markers": {}}, 422, "markers_required"),
        ({"mode": "markerless"}, 422, "missing_field"),
        ({"mode": "full"}, 422, "missing_field"),
        ({"mode": "full", "scan_id": None}, 422, "validation_error"),
        (
            {"mode": "markerless", "scan_id": "scn_x", "options": {"calibrate": True}},
            422,
            "validation_error",
        ),
        ({"mode": "sideways", "scan_id": "scn_x"}, 422, "validation_error"),
        ({"mode": "markers_only", "units": "furlong", "markers": {}}, 422, "validation_error"),
    ],
    ids=[
        "no-markers",
        "empty-markers",
        "markerless-no-scan",
        "full-no-scan",
        "full-null-scan",
        "calibrate-markerless",
        "unknown-mode",
        "bad-units",
    ],
)
def test_bad_mode_requests(client, body, status, code):
    _check(client.post("/v1/fits", json=body), status, code)


def test_markers_only_bad_markers(client, sim):
    m = _markers(sim)
    two = {k: m[k] for k in ("Vertex", "Crotch")}
    err = _check(client.post("/v1/fits", json={"mode": "markers_only", "markers": two}), 422,
                 "invalid_markers")  # fmt: skip
    assert "at least 3" in err["message"]
    bad = {**m, "Elbow_tip": [0.0, 1.0, 0.0]}
    err = _check(client.post("/v1/fits", json={"mode": "markers_only", "markers": bad}), 422,
                 "invalid_markers")  # fmt: skip
    assert "Elbow_tip" in err["message"]
    line = {"Vertex": [0.0, 1.7, 0.0], "Menton": [0.0, 1.48, 0.0], "Crotch": [0.0, 0.8, 0.0]}
    _check(client.post("/v1/fits", json={"mode": "markers_only", "markers": line}), 422,
           "invalid_markers")  # fmt: skip


def test_mode_option_conflicts(client, sim):
    scan = upload_scan(client, sim).json()
    sid = scan["id"]
    cases = [
        {"scan_id": sid, "mode": "markerless", "options": {"schedule": "paper"}},
        {"scan_id": sid, "mode": "full", "options": {"refine": False}},
        {"scan_id": sid, "mode": "full", "units": "mm"},
        {"scan_id": sid, "mode": "markers_only", "up": "+z"},
    ]
    for body in cases:
        _check(client.post("/v1/fits", json=body), 422, "validation_error")
    # the default mode is 'full' (today's requests unchanged)
    r = client.post("/v1/fits", json={"scan_id": sid, "options": FAST})
    assert r.status_code == 202 and r.json()["mode"] == "full"
    assert wait_state(client, r.json()["id"])["state"] == "succeeded"
