"""Texture baking on the template's one UV layout: the layout covers every triangle once (no
overlap), a baked texture gives the painted colours back at the vertices, and a texture baked on
body A dresses body B (validator-clean GLB, the same UVs)."""

from __future__ import annotations

import numpy as np
import pytest

from core.io.images import decode_image, encode_png, sample_image
from core.synth import random_body
from core.template import load_template
from core.transfer.texture import (
    _rasterise,
    bake_texture,
    load_uv_layout,
    texture_colours,
    textured_glb,
)
from service.testing import glb_parts, validate_glb
from tests.core.test_transfer_colour import paint


def test_layout_maps_onto_the_template():
    tpl, L = load_template(), load_uv_layout()
    np.testing.assert_array_equal(L.vertex[L.faces], tpl.F)
    np.testing.assert_array_equal(L.vertex[: len(tpl.V)], np.arange(len(tpl.V)))
    assert len(L.uv) > len(tpl.V)  # seams are split
    assert L.uv.min() >= 0.0 and L.uv.max() <= 1.0
    # every seam copy carries a UV its body vertex's primary copy does not
    seam = np.arange(len(tpl.V), len(L.uv))
    assert (np.abs(L.uv[seam] - L.uv[L.vertex[seam]]).max(axis=1) > 1e-6).all()
    # islands do not overlap: the UV triangles' areas add up to what they cover
    T = L.uv[L.faces].astype(np.float64)
    e1, e2 = T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]
    area = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    assert (area < 0).all()  # one winding (v points down in glTF): no mirrored island
    _, covered = _rasterise(L.uv * 1024.0, L.faces.astype(np.int64), np.ones((len(L.uv), 1)), 1024)
    assert abs(covered.mean() - np.abs(area).sum()) < 1e-3, (covered.mean(), np.abs(area).sum())


def test_bake_gives_the_colours_back():
    tpl = load_template()
    C = paint(tpl.V)
    img = bake_texture(C)
    back = texture_colours(img)
    err = np.abs(back - C).mean(axis=1) / 0.8  # fraction of the painted range
    assert err.mean() < 0.005 and err.max() < 0.02, (err.mean(), err.max())
    # through PNG: lossless
    np.testing.assert_array_equal(decode_image(encode_png(img)), img)


def test_texture_moves_from_one_body_to_another(tmp_path):
    tpl, L = load_template(), load_uv_layout()
    rng = np.random.default_rng(3)
    A = random_body(rng, sex="female").V
    B = random_body(rng, sex="male").V
    img = bake_texture(paint(A))  # colours follow body A's own shape
    ga = textured_glb(tmp_path / "a.glb", A, img)
    gb = textured_glb(tmp_path / "b.glb", B, encode_png(img))
    for name in ("a.glb", "b.glb"):
        report = validate_glb(tmp_path / name)
        assert report["errors"] == 0 and report["warnings"] == 0, report
    (da, acc_a), (db, acc_b) = glb_parts(ga), glb_parts(gb)
    pa, pb = (d["meshes"][0]["primitives"][0] for d in (da, db))
    uv_a, uv_b = acc_a(pa["attributes"]["TEXCOORD_0"]), acc_b(pb["attributes"]["TEXCOORD_0"])
    np.testing.assert_array_equal(uv_a, uv_b)
    np.testing.assert_array_equal(uv_a, L.uv)
    assert "COLOR_0" not in pb["attributes"]  # glTF would multiply it into the texture
    # body B's vertices: the first 13380 are B in template order, the rest seam copies
    pos = acc_b(pb["attributes"]["POSITION"])
    np.testing.assert_allclose(pos[: len(tpl.V)], B, atol=1e-6)
    np.testing.assert_allclose(pos, B[L.vertex], atol=1e-6)
    # the embedded image is body A's texture, so B wears A's colours vertex for vertex
    view = db["bufferViews"][db["images"][0]["bufferView"]]
    jlen = int.from_bytes(gb[12:16], "little")
    start = 20 + jlen + 8 + view["byteOffset"]
    png = gb[start : start + view["byteLength"]]
    np.testing.assert_array_equal(decode_image(png), img)
    rgb_b = sample_image(decode_image(png), uv_b[: len(tpl.V)])
    assert np.abs(rgb_b - paint(A)).mean() / 0.8 < 0.005
    # seam copies share their vertex's normal (no lighting seam)
    nrm = acc_b(pb["attributes"]["NORMAL"])
    np.testing.assert_allclose(nrm, nrm[L.vertex], atol=1e-6)


def test_bake_refuses_wrong_shapes():
    with pytest.raises(ValueError, match="shape"):
        bake_texture(np.zeros((10, 3)))
