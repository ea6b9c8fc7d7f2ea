"""The markerless search's facing cue (core.matching.markerless.feet_forward) on off-model scans
of core.synth.scanner_outputs: the feet tell front from back, whatever the facing and up sign."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest

pytest.importorskip("skimage")


@cache
def _case():
    """closed_lowres-2 (off-model, 20 k vertices) in canonical metres: points, faces, truth."""
    from core.synth.scanner_outputs import make_case

    c = make_case(2, "closed_lowres")
    A = c.to_file
    inv = np.linalg.inv(A[:3, :3])
    return (c.V - A[:3, 3]) @ inv.T, np.asarray(c.F), (c.truth - A[:3, 3]) @ inv.T


def _scan(R: np.ndarray):
    from core.io import detect_frame, prepare_scan
    from core.scan import RawMesh

    V, F, truth = _case()
    V, truth = V @ R.T, truth @ R.T
    return prepare_scan(RawMesh(V=V, F=F), detect_frame(V, units="m", up="+y")), truth


def _toes(truth: np.ndarray) -> np.ndarray:
    from core.template import load_template

    L = load_template().landmarks
    d = truth[[L["Toe_tip_L"], L["Toe_tip_R"]]].sum(0)
    d = d - truth[[L["Calcaneus_posterior_L"], L["Calcaneus_posterior_R"]]].sum(0)
    return d[[0, 2]] / np.linalg.norm(d[[0, 2]])


@pytest.mark.parametrize("deg, upside_down", [(0, False), (150, False), (250, True)])
def test_feet_show_which_way_the_body_faces(deg, upside_down):
    from core.matching.markerless import (
        FEET_CUE_ANGLE,
        _rot_y,
        _rot_z,
        _template_toes,
        candidate_alignments,
        feet_forward,
    )

    R = _rot_y(deg) @ (_rot_z(180.0) if upside_down else np.eye(3))
    scan, truth = _scan(R)
    toes = _toes(truth)
    cue = feet_forward(scan, top=upside_down)
    assert cue is not None and cue @ toes > np.cos(np.radians(15))
    # the candidates of the body's own up sign all face the feet's way (front and back of a
    # body match a scan almost equally well, so the other facing is not even tried)
    mine = [s for s in candidate_alignments(scan) if (s.R[1, 1] < 0) == upside_down]
    assert mine
    for s in mine:
        assert (s.R @ _template_toes())[[0, 2]] @ toes > np.cos(np.radians(FEET_CUE_ANGLE + 15))


def test_search_puts_a_flexed_head_on_the_scans_head(tmp_path):
    """raw-12 (a raw scan, written upside down in cm; neck and head flexed ~20° together): the
    articulated search tilted the head bone ~50° and its centroid started 72 mm off the truth's;
    the head step (:func:`core.matching.markerless._head_start`) puts it back."""
    from core.io import load_scan
    from core.matching.markerless import choose_alignment
    from core.registration.correspondence import ScanIndex
    from core.registration.shape_prior import fit_body_prior
    from core.synth.scanner_outputs import make_case
    from core.template import load_template
    from core.threads import single_blas_thread

    case = make_case(12, "raw")
    scan, _ = load_scan(case.write(tmp_path / "raw-12.ply"))
    truth = scan.frame.to_canonical(case.truth)
    index = ScanIndex(scan)
    start, scores = single_blas_thread(choose_alignment)(scan, index)
    assert "head" in start.label and any(s["stage"] == "head" for s in scores)
    tpl = load_template()
    F, none = np.asarray(tpl.F, np.int64), np.zeros(0, np.int64)
    X = fit_body_prior(
        index, tpl.V, F, none, np.zeros((0, 3)), start.similarity, iterations=0,
        initial_pose=start.pose, initial_coefficients=start.coefficients,
    ).X  # fmt: skip
    head = tpl.part_mask("head")
    off = np.linalg.norm(X[head].mean(0) - truth[head].mean(0)) * 1000
    assert off < 30.0, off  # measured 16 mm (72 mm with the search's own head)
