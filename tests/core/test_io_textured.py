"""Textured scans in: OBJ + MTL + image (beside the OBJ or zipped with it) and GLB with an
embedded base colour texture give per-vertex colours sampled at the UVs; a textured scan fitted
carries its colours to the body within the issue's bounds; bombs and broken bundles are refused."""

from __future__ import annotations

import io
import json
import struct
import zipfile
import zlib

import numpy as np
import pytest

from core.errors import InputFormatError
from core.io import load_scan, read_mesh, write_markers_csv
from core.io.images import decode_image, encode_png
from core.io.writers import atomic_write
from core.registration.fit import fit
from core.registration.schedule import Schedule
from core.synth import ScanConfig, random_body, simulate_scan
from core.template import load_template
from core.transfer.colour import transfer_colours
from core.transfer.texture import bake_texture, load_uv_layout, textured_glb
from service.testing import glb_parts
from tests.core.test_transfer_colour import paint


def _obj_text(V, vt, F, FT, mtl: str | None = "scan.mtl", material: str = "skin") -> bytes:
    """OBJ with ``vt`` (OBJ convention, v up) and ``v/vt`` triangles."""
    out = [f"mtllib {mtl}\n"] if mtl else []
    out.append(("v %.6f %.6f %.6f\n" * len(V)) % tuple(np.ravel(V)))
    out.append(("vt %.7f %.7f\n" * len(vt)) % tuple(np.ravel(vt)))
    out.append(f"usemtl {material}\n")
    corners = np.stack([F + 1, FT + 1], axis=2).reshape(len(F), 6)
    out.append(("f %d/%d %d/%d %d/%d\n" * len(F)) % tuple(corners.ravel()))
    return "".join(out).encode()


MTL = b"newmtl skin\nKa 1 1 1\nKd 0.8 0.8 0.8\nmap_Kd -s 1 1 1 skin.png\n"


@pytest.fixture(scope="module")
def painted_template():
    """The template painted, its texture baked on the template UV layout, as an OBJ bundle."""
    tpl, L = load_template(), load_uv_layout()
    C = paint(tpl.V)
    img = bake_texture(C)
    vt = L.uv.astype(np.float64) * [1.0, -1.0] + [0.0, 1.0]  # glTF -> OBJ (v up)
    obj = _obj_text(tpl.V, vt, tpl.F, L.faces)
    return C, img, obj


def _zip(files: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for name, data in files.items():
            z.writestr(name, data)
    return buf.getvalue()


def test_obj_with_mtl_and_texture_beside_it(painted_template, tmp_path):
    C, img, obj = painted_template
    (tmp_path / "scan.obj").write_bytes(obj)
    (tmp_path / "scan.mtl").write_bytes(MTL)
    (tmp_path / "skin.png").write_bytes(encode_png(img))
    raw = read_mesh(tmp_path / "scan.obj")
    assert raw.colors is not None and raw.colors.shape == (len(C), 3)
    err = np.abs(raw.colors / 255.0 - C).mean(axis=1) / 0.8
    assert err.mean() < 0.005 and err.max() < 0.03, (err.mean(), err.max())
    # the same texture upside down (v read from the wrong side) gives other colours entirely
    (tmp_path / "skin.png").write_bytes(encode_png(img[::-1]))
    wrong = np.abs(read_mesh(tmp_path / "scan.obj").colors / 255.0 - C).mean(axis=1) / 0.8
    assert wrong.mean() > 10 * err.mean() and wrong.mean() > 0.05, wrong.mean()
    # the same OBJ from bytes (no folder) or with sidecars off: geometry only
    assert read_mesh(obj, "obj").colors is None
    assert read_mesh(tmp_path / "scan.obj", sidecar_files=False).colors is None
    # a JPEG texture reads too (lossy: within a few percent)
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="JPEG", quality=95)
    (tmp_path / "skin.png").write_bytes(buf.getvalue())  # named .png, is a JPEG: sniffed
    err = np.abs(read_mesh(tmp_path / "scan.obj").colors / 255.0 - C).mean(axis=1) / 0.8
    assert err.mean() < 0.02, err.mean()


def test_obj_bundle_zip(painted_template, tmp_path, monkeypatch):
    C, img, obj = painted_template
    data = _zip({"scan/scan.obj": obj, "scan/scan.mtl": MTL, "scan/skin.png": encode_png(img)})
    raw = read_mesh(data)  # sniffed: a ZIP holding an OBJ, not an NPZ
    err = np.abs(raw.colors / 255.0 - C).mean(axis=1) / 0.8
    assert err.mean() < 0.005, err.mean()
    (tmp_path / "bundle.zip").write_bytes(data)
    from core.io import inspect_mesh_header

    head = inspect_mesh_header(tmp_path / "bundle.zip")
    assert head["format"] == "zip" and head["n_vertices"] == len(C)
    # the OBJ is counted while it inflates chunk by chunk: lines across chunks count once
    import core.io.readers as readers

    monkeypatch.setattr(readers, "_INSPECT_CHUNK", 4099)
    small = inspect_mesh_header(tmp_path / "bundle.zip")
    plain = inspect_mesh_header(obj, "obj")
    assert (small["n_vertices"], small["n_faces"]) == (plain["n_vertices"], plain["n_faces"])
    assert small["inflated_bytes"] > len(data)
    # a named file missing from the archive is an error naming it
    with pytest.raises(InputFormatError, match=r"skin\.png"):
        read_mesh(_zip({"scan.obj": obj, "scan.mtl": MTL}), "zip")
    with pytest.raises(InputFormatError, match=r"scan\.mtl"):
        read_mesh(_zip({"scan.obj": obj}), "zip")
    with pytest.raises(InputFormatError, match=r"exactly one \.obj"):
        read_mesh(_zip({"a.obj": obj, "b.obj": obj}), "zip")
    # a bundle inflating to far more than its size (a zip bomb) is refused before inflating
    bomb = _zip({"scan.obj": obj, "scan.mtl": MTL, "pad.txt": b"\0" * (64 << 20)})
    assert len(bomb) < 2 << 20
    with pytest.raises(InputFormatError, match="inflated"):
        read_mesh(bomb, "zip")


def test_kd_colours_without_texture(tmp_path):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)
    text = (
        b"mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nusemtl red\nf 1 2 3\n"
        b"usemtl blue\nf 2 4 3\n"
    )
    mtl = b"newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\n"
    raw = read_mesh(_zip({"s.obj": text, "m.mtl": mtl}), "zip")
    assert len(raw.V) == len(V)
    # vertex 0 only red faces, vertex 3 only blue, 1 and 2 both
    np.testing.assert_array_equal(raw.colors[0], [255, 0, 0])
    np.testing.assert_array_equal(raw.colors[3], [0, 0, 255])
    np.testing.assert_array_equal(raw.colors[1], [128, 0, 128])


def test_glb_with_base_colour_texture(painted_template, tmp_path):
    C, img, _ = painted_template
    tpl, L = load_template(), load_uv_layout()
    data = textured_glb(None, tpl.V, img)
    raw = read_mesh(data)  # sniffed from the magic
    assert len(raw.V) == len(L.uv) and raw.F is not None and len(raw.F) == len(tpl.F)
    np.testing.assert_allclose(raw.V, tpl.V[L.vertex], atol=1e-6)
    err = np.abs(raw.colors[: len(C)] / 255.0 - C).mean(axis=1) / 0.8
    assert err.mean() < 0.005, err.mean()
    # node transforms apply: the same GLB under a node scaled by 1000 (millimetres)
    from core.io.glb import read_glb_primitives

    (p,) = read_glb_primitives(data)
    assert p.image is not None and p.uv.shape == (len(L.uv), 2)
    doc, _ = glb_parts(data)
    doc["nodes"][0]["scale"] = [1000.0, 1000.0, 1000.0]
    raw_mm = read_mesh(with_document(data, doc), "glb")
    np.testing.assert_allclose(raw_mm.V, raw.V * 1000.0, rtol=1e-6)
    # a required extension we do not read is named
    doc["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    with pytest.raises(InputFormatError, match="KHR_draco_mesh_compression"):
        read_mesh(with_document(data, doc), "glb")
    # hostile accessors: a data-less TEXCOORD of 10^12 elements, a view past the data
    bad, _ = glb_parts(data)
    attrs = bad["meshes"][0]["primitives"][0]["attributes"]
    acc = bad["accessors"][attrs["TEXCOORD_0"]]
    del acc["bufferView"]
    acc["count"] = 10**12
    with pytest.raises(InputFormatError, match="elements"):
        read_mesh(with_document(data, bad), "glb")
    bad, _ = glb_parts(data)
    bad["bufferViews"][0]["byteLength"] += 1 << 30
    with pytest.raises(InputFormatError, match="runs past"):
        read_mesh(with_document(data, bad), "glb")
    # KHR_texture_transform: UVs stored through the inverse of the extension's matrix (built
    # here from its GLSL text: column-major mat3s, translation * rotation * scale)
    from core.io.images import encode_png
    from core.io.writers import write_glb

    r, (ox, oy), (sx, sy) = 0.3, (0.1, 0.2), (0.8, 0.9)
    T = np.array([[1, 0, 0], [0, 1, 0], [ox, oy, 1]], float).T
    R = np.array([[np.cos(r), np.sin(r), 0], [-np.sin(r), np.cos(r), 0], [0, 0, 1]]).T
    S = np.array([[sx, 0, 0], [0, sy, 0], [0, 0, 1]], float).T
    Minv = np.linalg.inv(T @ R @ S)
    stored = L.uv @ Minv[:2, :2].T + Minv[:2, 2]
    moved = write_glb(None, raw.V, raw.F, texcoords=stored, texture_png=encode_png(img))
    doc, _ = glb_parts(moved)
    info = doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]
    ext = {"offset": [ox, oy], "rotation": r, "scale": [sx, sy]}
    info["extensions"] = {"KHR_texture_transform": ext}
    doc["extensionsUsed"] = doc["extensionsRequired"] = ["KHR_texture_transform"]
    got = read_mesh(with_document(moved, doc), "glb").colors
    assert np.abs(got.astype(int) - raw.colors).max() <= 1  # float32 UVs
    assert np.abs(read_mesh(moved, "glb").colors.astype(int) - raw.colors).mean() > 10


def with_document(glb: bytes, doc: dict) -> bytes:
    """The GLB ``glb`` with its JSON chunk replaced by ``doc`` (the binary chunk kept)."""
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    jlen = struct.unpack_from("<I", glb, 12)[0]
    rest = glb[20 + jlen :]
    head = struct.pack("<IIIII", 0x46546C67, 2, 20 + len(js) + len(rest), len(js), 0x4E4F534A)
    return head + js + rest


def _png_header_only(w: int, h: int) -> bytes:
    """A tiny PNG declaring a w x h RGB image (a decompression bomb's header)."""

    def chunk(kind: bytes, body: bytes) -> bytes:
        crc = zlib.crc32(kind + body) & 0xFFFFFFFF
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)

    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(b"\x00" * 1024))
        + chunk(b"IEND", b"")
    )


def test_bomb_and_bad_images_refused(painted_template):
    _, _, obj = painted_template
    bomb = _png_header_only(50_000, 50_000)  # 2.5 G pixels in a few hundred bytes
    assert len(bomb) < 1000
    with pytest.raises(InputFormatError, match="limit"):
        decode_image(bomb)
    with pytest.raises(InputFormatError, match="limit"):
        read_mesh(_zip({"scan.obj": obj, "scan.mtl": MTL, "skin.png": bomb}), "zip")
    with pytest.raises(InputFormatError, match="PNG or JPEG"):
        decode_image(b"GIF89a" + b"\x00" * 64)
    with pytest.raises(InputFormatError, match="truncated or corrupt"):
        decode_image(encode_png(np.zeros((64, 64, 3), np.uint8))[:-40])


@pytest.fixture(scope="module")
def textured_scan_fit(tmp_path_factory):
    """A painted body scanned with colour by the simulator, written as OBJ + MTL + PNG: every
    scan vertex's colour is the texture's pixel at its ``vt`` (the texture made here)."""
    tpl = load_template()
    rng = np.random.default_rng(7)
    body = random_body(rng, sex="female")
    C = paint(tpl.V)
    sim = simulate_scan(body.V, tpl.F, rng, config=ScanConfig.small(), colors=C)
    n = len(sim.V_scan)
    W = 512
    H = -(-n // W)
    img = np.zeros((H, W, 3), np.uint8)
    k = np.arange(n)
    cols = np.asarray(sim.colors)
    cols = cols if cols.dtype == np.uint8 else np.round(np.clip(cols, 0, 1) * 255).astype(np.uint8)
    img[k // W, k % W] = cols
    img = img[::-1]  # OBJ's v points up: row 0 of the image is v = 1
    vt = np.stack([(k % W + 0.5) / W, (k // W + 0.5) / H], axis=1)
    d = tmp_path_factory.mktemp("textured")
    atomic_write(d / "scan.obj", _obj_text(sim.V_scan, vt, sim.F_scan, sim.F_scan))
    (d / "scan.mtl").write_bytes(MTL)
    (d / "skin.png").write_bytes(encode_png(img))
    write_markers_csv(d / "markers.csv", sim.markers)
    scan, markers = load_scan(d / "scan.obj", markers_path=d / "markers.csv")
    res = fit(scan, markers, schedule=Schedule.fast())
    from scipy.spatial import cKDTree

    unseen = cKDTree(sim.V_scan).query(body.V)[0] > 0.01
    return C, sim, cols, scan, res, unseen


def test_textured_obj_scan_colours_reach_the_fitted_body(textured_scan_fit):
    C, sim, cols, scan, res, unseen = textured_scan_fit
    assert scan.colors is not None
    from scipy.spatial import cKDTree

    d, j = cKDTree(sim.V_scan).query(scan.V)  # the scan's points keep their texture colour
    assert d.max() < 1e-5
    np.testing.assert_array_equal(scan.colors, cols[j])
    got, observed = transfer_colours(res.vertices, scan)
    err = np.abs(got - C).mean(axis=1) / 0.8
    assert unseen.sum() > 200 and (~observed[unseen]).mean() > 0.5
    assert err[~unseen].mean() < 0.05, err[~unseen].mean()
    assert err[unseen].mean() < 0.15, err[unseen].mean()


def _stripes(size: int, period_m: float) -> np.ndarray:
    """(size, size, 3) uint8: red stripes across image rows, for the cylindrical atlas below
    (row -> height y = 2 (1 - v) m): red = 0.5 + 0.4 sin(2 pi y / period), green/blue 0.5."""
    v = (np.arange(size) + 0.5) / size
    red = 0.5 + 0.4 * np.sin(2 * np.pi * (1 - v) * 2.0 / period_m)
    img = np.full((size, size, 3), 0.5)
    img[..., 0] = red[:, None]
    return np.round(img * 255).astype(np.uint8)


def test_texture_at_full_resolution_from_a_textured_scan(tmp_path):
    """A scan whose texture holds stripes finer than the body's vertex spacing (1.2-4 cm): the
    body's texture taken texel by texel from the scan's texture keeps them; the per-vertex
    colours baked cannot."""
    from core.scan import FrameInfo
    from core.transfer.texture import _rasterise, textured_surface, transfer_texture

    tpl, L = load_template(), load_uv_layout()
    # 1. the scan is the template itself (UVs of the layout, a 2048 px texture of stripes in
    #    UV space): the transfer must reproduce the scan's texture texel for texel
    S = 2048
    yy, xx = np.mgrid[0:S, 0:S]
    img = np.full((S, S, 3), 128, np.uint8)
    img[..., 0] = np.where((xx // 6) % 2 == 0, 220, 40)
    img[..., 1] = np.where((yy // 6) % 2 == 0, 200, 60)
    vt = L.uv.astype(np.float64) * [1.0, -1.0] + [0.0, 1.0]
    raw = read_mesh(
        _zip({"s.obj": _obj_text(tpl.V, vt, tpl.F, L.faces), "scan.mtl": MTL,
              "skin.png": encode_png(img)}), "zip",
    )  # fmt: skip
    assert raw.texture is not None and raw.texture.uv.shape == (len(tpl.F), 3, 2)
    frame = FrameInfo(units="m", up="+y", scale=1.0, R=np.eye(3), detected=False)
    fallback = bake_texture(raw.colors[: len(tpl.V)])
    out, share = transfer_texture(tpl.V, textured_surface(raw, frame), fallback)
    size = out.shape[0]
    i, j = np.mgrid[0:size, 0:size]
    uv = np.stack([(j + 0.5) / size, (i + 0.5) / size], axis=-1).reshape(-1, 2)
    _, covered = _rasterise(L.uv * float(size), L.faces.astype(np.int64),
                            np.ones((len(L.uv), 1)), size)  # fmt: skip
    from core.io.images import sample_image

    truth = sample_image(img, uv).reshape(size, size, 3)[covered]
    err = np.abs(out[covered] / 255.0 - truth).mean()
    err_vertex = np.abs(fallback[covered] / 255.0 - truth).mean()
    assert share > 0.999 and err < 0.005 and err_vertex > 0.15, (share, err, err_vertex)
    # 2. a simulated scan of a body (holes, noise) with a cylindrical atlas (v = 1 - y / 2)
    #    and 4 cm stripes, fitted: per texel against the true body's stripes
    rng = np.random.default_rng(7)
    body = random_body(rng, sex="female")
    sim = simulate_scan(body.V, tpl.F, rng, config=ScanConfig.small())
    x, y, z = sim.V_scan.T
    uv_scan = np.stack([np.arctan2(x, z) / (2 * np.pi) + 0.5, 1 - y / 2.0], axis=1)
    from core.io.writers import write_obj

    write_obj(tmp_path / "scan.obj", sim.V_scan, sim.F_scan, uv=uv_scan, FT=sim.F_scan,
              mtllib="scan.mtl")  # fmt: skip
    (tmp_path / "scan.mtl").write_bytes(MTL)
    (tmp_path / "skin.png").write_bytes(encode_png(_stripes(2048, 0.04)))
    write_markers_csv(tmp_path / "m.csv", sim.markers)
    scan, markers = load_scan(tmp_path / "scan.obj", markers_path=tmp_path / "m.csv")
    res = fit(scan, markers, schedule=Schedule.fast())
    colours, _ = transfer_colours(res.vertices, scan)
    fallback = bake_texture(colours)
    surface = textured_surface(read_mesh(tmp_path / "scan.obj"), scan.frame)
    out, share = transfer_texture(res.vertices, surface, fallback)
    body_at, covered = _rasterise(L.uv * 1024.0, L.faces.astype(np.int64), body.V[L.vertex], 1024)
    fit_at, _ = _rasterise(L.uv * 1024.0, L.faces.astype(np.int64), res.vertices[L.vertex], 1024)
    from scipy.spatial import cKDTree

    seen = cKDTree(sim.V_scan).query(fit_at[covered])[0] < 0.005
    truth = 0.5 + 0.4 * np.sin(2 * np.pi * body_at[covered][:, 1] / 0.04)
    err = np.abs(out[covered][:, 0] / 255.0 - truth)[seen].mean() / 0.8
    err_vertex = np.abs(fallback[covered][:, 0] / 255.0 - truth)[seen].mean() / 0.8
    assert share > 0.85 and err < 0.11 and err < 0.6 * err_vertex, (share, err, err_vertex)


@pytest.mark.parametrize("layout", ["face_texcoord", "vertex_uv"])
def test_textured_ply_beside_its_image_keeps_colours(tmp_path, layout):
    """MeshLab / Metashape textured PLY: ``comment TextureFile`` and per-corner ``texcoord``
    (or per-vertex ``texture_u``/``texture_v``); its colours were dropped."""
    img = np.array([[[255, 0, 0], [0, 255, 0]], [[0, 0, 255], [255, 255, 255]]], np.uint8)
    (tmp_path / "skin.png").write_bytes(encode_png(img))
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float32)
    uv = np.array([[0.25, 0.75], [0.75, 0.75], [0.75, 0.25], [0.25, 0.25]], np.float32)  # v up
    want = [[255, 0, 0], [0, 255, 0], [255, 255, 255], [0, 0, 255]]  # the pixels they hit
    F = np.array([[0, 1, 2], [0, 2, 3]])
    vprops = "property float x\nproperty float y\nproperty float z\n"
    fprops = "property list uchar int vertex_indices\n"
    if layout == "vertex_uv":
        vprops += "property float texture_u\nproperty float texture_v\n"
        verts = np.hstack([V, uv]).astype("<f4").tobytes()
    else:
        fprops += "property list uchar float texcoord\n"
        verts = V.astype("<f4").tobytes()
    faces = b"".join(
        bytes([3]) + f.astype("<i4").tobytes()
        + (b"" if layout == "vertex_uv" else bytes([6]) + uv[f].astype("<f4").tobytes())
        for f in F
    )  # fmt: skip
    head = (
        "ply\nformat binary_little_endian 1.0\ncomment TextureFile skin.png\n"
        f"element vertex 4\n{vprops}element face 2\n{fprops}end_header\n"
    ).encode()
    p = tmp_path / "scan.ply"
    p.write_bytes(head + verts + faces)
    r = read_mesh(p)
    np.testing.assert_array_equal(r.F, F)
    np.testing.assert_array_equal(r.colors, want)
    np.testing.assert_allclose(r.texture.uv, (uv * [1, -1] + [0, 1])[F], atol=1e-6)  # glTF
    assert r.texture.image.tolist() == [0, 0] and len(r.texture.images) == 1
    # bytes (an upload) or no image beside it: geometry only, as before
    assert read_mesh(p.read_bytes(), "ply").colors is None
    (tmp_path / "skin.png").unlink()
    assert read_mesh(p).colors is None
