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
