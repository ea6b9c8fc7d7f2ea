"""``bodyspace morph``: a validator-clean GLB with morph targets from body files, one in-between
body with ``--t``, one-line errors; ``rig``, ``pose``, a coloured ``fit`` and ``texture``."""

from __future__ import annotations

import numpy as np

from core.io import read_mesh, write_ply
from core.synth import random_body
from core.template import load_template
from service.testing import glb_parts, validate_glb
from tests.core.test_cli import assert_one_line_error, run_cli


def _bodies(tmp_path, k: int) -> list:
    F = load_template().F
    out = []
    for i in range(k):
        V = random_body(np.random.default_rng(i), pose=False).V
        p = tmp_path / f"b{i}.ply"
        write_ply(p, V, F)
        out.append((p, V))
    return out


def test_morph_glb_and_in_between(tmp_path):
    (a, Va), (b, Vb), (c, Vc) = _bodies(tmp_path, 3)
    out = tmp_path / "m.glb"
    r = run_cli("morph", a, b, c, "--out", out)
    assert r.returncode == 0, r.stderr
    report = validate_glb(out)
    assert report["errors"] == 0 and report["warnings"] == 0, report
    doc, accessor = glb_parts(out.read_bytes())
    mesh = doc["meshes"][0]
    assert mesh["extras"]["targetNames"] == ["b1", "b2"]
    base = accessor(mesh["primitives"][0]["attributes"]["POSITION"]).astype(np.float64)
    for tg, V in zip(mesh["primitives"][0]["targets"], (Vb, Vc), strict=True):
        assert np.abs(base + accessor(tg["POSITION"]) - V).max() < 1e-4

    mid = tmp_path / "mid.ply"
    r = run_cli("morph", a, b, "--t", "0.25", "--out", mid)
    assert r.returncode == 0, r.stderr
    np.testing.assert_allclose(read_mesh(mid).V, 0.75 * Va + 0.25 * Vb, atol=1e-9)
    assert read_mesh(mid).colors is None  # no colours in, none out


def test_morph_keeps_colours(tmp_path):
    """Coloured body files: the in-between body's colours are the blend, the morph GLB has
    the first body's; with one uncoloured body the in-between body has none."""
    from core.transfer import morph_colors

    (a, Va), (b, Vb), (c, _) = _bodies(tmp_path, 3)
    F = load_template().F
    rng = np.random.default_rng(5)
    Ca, Cb = (rng.integers(0, 256, (len(Va), 3), dtype=np.uint8) for _ in range(2))
    write_ply(a, Va, F, colors=Ca)
    write_ply(b, Vb, F, colors=Cb)
    mid = tmp_path / "mid.ply"
    r = run_cli("morph", a, b, "--t", "0.25", "--out", mid)
    assert r.returncode == 0 and "colours blended" in r.stdout, r.stderr
    np.testing.assert_array_equal(read_mesh(mid).colors, morph_colors(Ca, Cb, 0.25))
    r = run_cli("morph", a, c, "--t", "0.25", "--out", mid)
    assert r.returncode == 0, r.stderr
    assert read_mesh(mid).colors is None
    out = tmp_path / "m.glb"
    r = run_cli("morph", a, b, c, "--out", out)
    assert r.returncode == 0, r.stderr
    assert validate_glb(out)["errors"] == 0
    doc, accessor = glb_parts(out.read_bytes())
    attrs = doc["meshes"][0]["primitives"][0]["attributes"]
    np.testing.assert_array_equal(accessor(attrs["COLOR_0"])[:, :3], Ca)


def test_morph_errors(tmp_path):
    (a, _), (b, _), (c, _) = _bodies(tmp_path, 3)
    assert_one_line_error(run_cli("morph", a, "--out", tmp_path / "m.glb"), "2 to 16")
    assert_one_line_error(run_cli("morph", a, b, "--out", tmp_path / "m.ply"), ".glb")
    assert_one_line_error(
        run_cli("morph", a, b, c, "--t", "0.5", "--out", tmp_path / "m.ply"), "exactly two"
    )
    assert_one_line_error(
        run_cli("morph", a, tmp_path / "nope.ply", "--out", tmp_path / "m.glb"), "not found"
    )
    bad = tmp_path / "small.ply"
    write_ply(bad, np.zeros((10, 3)), None)
    assert_one_line_error(run_cli("morph", a, bad, "--out", tmp_path / "m.glb"), "13380")


def test_rig_and_pose(tmp_path):
    import json

    from core.transfer.rig import JOINT_METHODS, POSTURES, pose, posture
    from service import cli

    assert JOINT_METHODS == cli.JOINT_METHODS
    assert tuple(POSTURES) == cli.POSTURE_NAMES
    ((a, _),) = _bodies(tmp_path, 1)
    out = tmp_path / "r.glb"
    r = run_cli("rig", a, "--out", out)
    assert r.returncode == 0, r.stderr
    report = validate_glb(out)
    assert report["errors"] == 0 and report["warnings"] == 0, report
    doc, _ = glb_parts(out.read_bytes())
    assert len(doc["skins"][0]["joints"]) == 163

    rot = tmp_path / "rot.json"
    rot.write_text(json.dumps({"lowerleg01.L": [0.5, 0, 0]}))
    p = tmp_path / "p.ply"
    r = run_cli("pose", a, "--posture", "seated", "--rotations", rot, "--out", p)
    assert r.returncode == 0, r.stderr
    want = posture("seated")
    from core.rig import axis_angle

    want["lowerleg01.L"] = axis_angle([1, 0, 0], 0.5)
    Va32 = read_mesh(a).V
    np.testing.assert_allclose(read_mesh(p).V, pose(Va32, want, seat_contact=True), atol=1e-9)
    r = run_cli("pose", a, "--posture", "seated", "--no-seat-contact", "--out", p)
    assert r.returncode == 0, r.stderr
    np.testing.assert_allclose(read_mesh(p).V, pose(Va32, posture("seated")), atol=1e-9)

    assert_one_line_error(run_cli("pose", a, "--out", p), "--posture")
    assert_one_line_error(
        run_cli("pose", a, "--posture", "standing", "--seat-contact", "--out", p), "no seat"
    )
    rot.write_text(json.dumps({"nosuchbone": [0, 0, 1]}))
    assert_one_line_error(run_cli("pose", a, "--rotations", rot, "--out", p), "nosuchbone")
    assert_one_line_error(run_cli("rig", a, "--out", tmp_path / "r.ply"), ".glb")


def test_fit_of_a_coloured_scan_is_coloured(tmp_path):
    """``bodyspace fit`` of a coloured PLY: the colours baked into a texture on the template UV
    layout in the GLB (validator-clean) and beside the OBJ (MTL + PNG), colours in the PLY,
    close to the paint (the core test bounds the error; here: the plumbing)."""
    from core.io import write_markers_csv
    from core.synth import ScanConfig, simulate_scan
    from tests.core.test_transfer_colour import paint

    tpl = load_template()
    rng = np.random.default_rng(11)
    body = random_body(rng, sex="male")
    C = paint(tpl.V)
    sim = simulate_scan(body.V, tpl.F, rng, config=ScanConfig.small(), colors=C)
    write_ply(tmp_path / "scan.ply", sim.V_scan, sim.F_scan, colors=sim.colors)
    write_markers_csv(tmp_path / "m.csv", sim.markers)
    glb, ply, obj = tmp_path / "fit.glb", tmp_path / "fit.ply", tmp_path / "fit.obj"
    for out in (glb, ply, obj):
        r = run_cli(
            "fit", tmp_path / "scan.ply", "--markers", tmp_path / "m.csv", "--fast", "--quiet",
            "--out", out,
        )  # fmt: skip
        assert r.returncode == 0, r.stderr
    report = validate_glb(glb)
    assert report["errors"] == 0 and report["warnings"] == 0, report
    doc, accessor = glb_parts(glb.read_bytes())
    attrs = doc["meshes"][0]["primitives"][0]["attributes"]
    assert "COLOR_0" not in attrs and doc["materials"][0]["pbrMetallicRoughness"]
    from core.io.images import decode_image, sample_image
    from core.transfer.texture import load_uv_layout

    uv = accessor(attrs["TEXCOORD_0"])
    np.testing.assert_array_equal(uv, load_uv_layout().uv)
    png = (tmp_path / "fit.png").read_bytes()  # the OBJ's texture: the same image
    rgb = sample_image(decode_image(png), uv[: len(tpl.V)])
    assert np.abs(rgb - C).mean() / 0.8 < 0.05
    m = read_mesh(ply)
    assert m.colors is not None
    d = np.abs(m.colors / 255.0 - rgb)
    assert d.mean() < 0.005, d.mean()  # baking at 1024 px: tiny UV triangles blend a little
    assert "map_Kd fit.png" in (tmp_path / "fit.mtl").read_text()
    o = read_mesh(obj)  # OBJ + MTL + PNG read back: the vertices and their colours
    np.testing.assert_allclose(o.V, m.V, atol=1e-9)
    do = np.abs(o.colors.astype(int) - m.colors.astype(int))
    assert do.mean() < 2, do.mean()


def test_texture_baked_on_one_body_dresses_another(tmp_path):
    """``bodyspace texture``: body A's colours baked into a PNG, that PNG on body B as a
    validator-clean GLB and as OBJ + MTL + PNG (B's colours at its vertices = A's); a body
    without colours and no --texture is a one-line error."""
    from core.io.images import decode_image, sample_image
    from core.transfer.texture import load_uv_layout
    from tests.core.test_transfer_colour import paint

    tpl, L = load_template(), load_uv_layout()
    (a, Va), (b, Vb) = _bodies(tmp_path, 2)
    C = paint(Va)  # colours that follow body A's own shape
    write_ply(a, Va, tpl.F, colors=C)
    png = tmp_path / "a.png"
    r = run_cli("texture", a, "--size", "512", "--out", png)
    assert r.returncode == 0, r.stderr
    img = decode_image(png.read_bytes())
    assert img.shape == (512, 512, 3)
    glb = tmp_path / "b.glb"
    r = run_cli("texture", b, "--texture", png, "--out", glb)
    assert r.returncode == 0, r.stderr
    report = validate_glb(glb)
    assert report["errors"] == 0 and report["warnings"] == 0, report
    doc, accessor = glb_parts(glb.read_bytes())
    attrs = doc["meshes"][0]["primitives"][0]["attributes"]
    np.testing.assert_allclose(accessor(attrs["POSITION"])[: len(Vb)], Vb, atol=1e-6)
    rgb = sample_image(img, accessor(attrs["TEXCOORD_0"])[: len(Vb)])
    assert np.abs(rgb - C).mean() / 0.8 < 0.01
    obj = tmp_path / "b.obj"
    r = run_cli("texture", b, "--texture", png, "--out", obj)
    assert r.returncode == 0, r.stderr
    m = read_mesh(obj)  # with b.mtl and b.png beside it
    np.testing.assert_allclose(m.V, Vb, atol=1e-9)
    assert np.abs(m.colors / 255.0 - C).mean() / 0.8 < 0.01
    assert_one_line_error(run_cli("texture", b, "--out", tmp_path / "x.glb"), "no vertex colours")
    assert_one_line_error(run_cli("texture", b, "--texture", a, "--out", glb), "PNG or JPEG")
    assert len(L.uv) == len(accessor(attrs["TEXCOORD_0"]))
