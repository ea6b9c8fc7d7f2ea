"""Cheap body-shape checks of scans (``core.matching.body_check``): simulated body scans pass,
boxes, poles, sheets, floors and bodies read in the wrong units do not."""

from __future__ import annotations

import numpy as np
import pytest

from bench.cases import make_case
from core.errors import FitError, NotABodyError
from core.matching.body_check import MAX_PROFILE_RATIO, body_shape, check_body_shape


@pytest.mark.parametrize("seed", [0, 1, 3])
def test_simulated_body_scans_pass(seed):
    c = make_case(seed, small=True)
    s = check_body_shape(c.scan.V, c.scan.F)
    assert 1.4 < s["height_m"] < 2.0
    assert s["profile_ratio"] < 0.5 * MAX_PROFILE_RATIO  # measured 0.16-0.22


def test_a_body_without_faces_and_turned_passes():
    c = make_case(3, small=True)
    a = np.radians(37.0)
    R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    check_body_shape(c.scan.V @ R.T)


def _box(w, h, d, n=30):
    g = np.linspace(0.0, 1.0, n)
    u, v = (x.ravel() for x in np.meshgrid(g, g))
    faces = []
    for ax in range(3):
        o = [i for i in range(3) if i != ax]
        for side in (0.0, 1.0):
            p = np.zeros((len(u), 3))
            p[:, ax], p[:, o[0]], p[:, o[1]] = side, u, v
            faces.append(p)
    return np.concatenate(faces) * [w, h, d] - [w / 2, 0, d / 2]


@pytest.mark.parametrize(
    ("V", "check", "match"),
    [
        (_box(0.5, 1.7, 0.3), "profile", "box or a column"),
        (_box(0.6, 1.7, 0.001), "depth", "flat"),
        (_box(0.1, 1.7, 0.1), "width", "too narrow"),
        (_box(0.5, 1.7, 0.3) * 1000, "height", "units or up axis"),  # mm read as metres
        (_box(0.5, 1.7, 0.3) / 100, "height", "units or up axis"),  # cm read as mm... as m
        (np.concatenate([_box(3.0, 0.01, 3.0), make_case(1, small=True).scan.V]), "width",
         "floor"),
    ],
    ids=["box", "sheet", "pole", "mm-as-m", "tiny", "floor"],
)  # fmt: skip
def test_not_a_body(V, check, match):
    with pytest.raises(NotABodyError, match=match) as e:
        check_body_shape(V, frame="units m, up +y")
    assert e.value.details["check"] == check
    assert "read as units m, up +y" in e.value.message
    assert isinstance(e.value, FitError) and e.value.code == "not_a_body"


def test_coarse_mesh_is_sampled_and_few_points_refused():
    # a box of 8 vertices and 12 triangles: the faces are sampled, the profile is still a box
    import trimesh

    b = trimesh.creation.box(extents=(0.5, 1.7, 0.3))
    s = body_shape(np.asarray(b.vertices), np.asarray(b.faces))
    assert s["profile_ratio"] > 0.9 and abs(s["height_m"] - 1.7) < 0.01
    with pytest.raises(NotABodyError, match="too few"):
        body_shape(np.zeros((5, 3)))
