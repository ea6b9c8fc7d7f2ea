"""Mesh readers: every format, every bad input the product must handle."""

from __future__ import annotations

import contextlib
import io
import time

import numpy as np
import pytest
import trimesh

from core.errors import InputFormatError
from core.io.readers import inspect_mesh_header, read_mesh
from core.template import load_template


@pytest.fixture(scope="module")
def tpl():
    t = load_template()
    return np.array(t.V), np.array(t.F, dtype=np.int64)


def ply_bytes(V, F=None, *, fmt="binary_little_endian", extra=None, face_type="int"):
    """A minimal PLY writer for fixtures (independent of core.io.writers)."""
    n = len(V)
    end = ">" if fmt == "binary_big_endian" else "<"
    fields = [("x", end + "f4"), ("y", end + "f4"), ("z", end + "f4")]
    extra = extra or {}
    for name, arr in extra.items():
        fields.append((name, end + ("f4" if arr.dtype.kind == "f" else "u1")))
    h = [f"ply\nformat {fmt} 1.0\nelement vertex {n}"]
    for name, t in fields:
        h.append(f"property {'float' if t[1:] == 'f4' else 'uchar'} {name}")
    if F is not None:
        h.append(f"element face {len(F)}\nproperty list uchar {face_type} vertex_indices")
    h.append("end_header\n")
    head = "\n".join(h).encode()
    rec = np.zeros(n, dtype=fields)
    rec["x"], rec["y"], rec["z"] = V.T
    for name, arr in extra.items():
        rec[name] = arr
    if fmt == "ascii":
        lines = [
            " ".join(repr(float(v)) if isinstance(v, np.floating) else str(v) for v in r)
            for r in rec.tolist()
        ]
        if F is not None:
            lines += [" ".join(map(str, [len(f), *f])) for f in F]
        return head + ("\n".join(lines) + "\n").encode()
    body = rec.tobytes()
    if F is not None:
        it = {"int": "i4", "uint": "u4", "short": "i2"}[face_type]
        fr = np.zeros(len(F), dtype=[("c", "u1"), ("i", end + it, (3,))])
        fr["c"] = 3
        fr["i"] = F
        body += fr.tobytes()
    return head + body


SQUARE_V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1]], float)


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian", "binary_big_endian"])
def test_ply_formats_roundtrip(tpl, fmt):
    V, F = tpl
    r = read_mesh(ply_bytes(V, F, fmt=fmt), "ply")
    np.testing.assert_allclose(r.V, V.astype(np.float32), atol=1e-7)
    np.testing.assert_array_equal(r.F, F)
    assert r.F.dtype == np.int64 and r.V.dtype == np.float64


def test_ply_from_path_with_normals_confidence_colors(tmp_path, tpl):
    V, F = tpl
    n = len(V)
    N = np.tile([0.0, 0.0, 1.0], (n, 1)).astype(np.float32)
    c = np.linspace(0, 1, n).astype(np.float32)
    rgb = np.random.default_rng(0).integers(0, 256, (n, 3)).astype(np.uint8)
    extra = {
        "nx": N[:, 0],
        "ny": N[:, 1],
        "nz": N[:, 2],
        "quality": c,
        "red": rgb[:, 0],
        "green": rgb[:, 1],
        "blue": rgb[:, 2],
    }
    p = tmp_path / "scan.ply"
    p.write_bytes(ply_bytes(V, F, extra=extra))
    r = read_mesh(p)
    np.testing.assert_allclose(r.normals, N)
    np.testing.assert_allclose(r.confidence, c, atol=1e-7)
    np.testing.assert_array_equal(r.colors, rgb)


def test_ply_polygons_fan_triangulated_and_unknown_elements_skipped():
    # quad + pentagon, an unknown element with a list between vertex and face, binary
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], "<f4")
    head = (
        b"ply\nformat binary_little_endian 1.0\ncomment test\n"
        b"element vertex 6\nproperty float x\nproperty float y\nproperty float z\n"
        b"element junk 2\nproperty short a\nproperty list uchar float vals\n"
        b"element face 3\nproperty list uchar uint vertex_index\nproperty uchar flags\n"
        b"end_header\n"
    )
    junk = (
        np.array([7], "<i2").tobytes()
        + bytes([2])
        + np.array([1, 2], "<f4").tobytes()
        + np.array([8], "<i2").tobytes()
        + bytes([0])
    )
    faces = b""
    for poly in ([0, 1, 2, 3], [1, 4, 5, 2, 3], [0, 1, 3]):
        faces += bytes([len(poly)]) + np.array(poly, "<u4").tobytes() + bytes([9])
    r = read_mesh(head + V.tobytes() + junk + faces, "ply")
    assert r.F.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2], [1, 2, 3], [0, 1, 3]]


def test_ply_point_cloud_without_faces():
    r = read_mesh(ply_bytes(SQUARE_V), "ply")
    assert r.F is None and r.V.shape == (5, 3)


def test_ply_binary_1m_vertices_is_fast():
    n = 1_000_000
    rng = np.random.default_rng(0)
    V = rng.random((n, 3))
    F = rng.integers(0, n, (2 * n, 3))
    b = ply_bytes(V, F)
    read_mesh(b, "ply")  # warm-up
    t0 = time.process_time()
    r = read_mesh(b, "ply")
    assert time.process_time() - t0 < 1.0  # CPU time (all threads): ~0.1 s here
    assert r.V.shape == (n, 3) and r.F.shape == (2 * n, 3)


def test_obj_forms_negative_indices_polygons(tmp_path):
    text = (
        "# comment\nmtllib x.mtl\no body\n"
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n"
        "vt 0 0\nvn 0 0 1\n"
        "f 1/1/1 2/1/1 3/1/1 4/1/1\n"
        "v 2 0 0\n"
        "f -1//1 -4//1 -3//1\n"
        "f 1 2 4\n"
    )
    p = tmp_path / "a.obj"
    p.write_text(text)
    r = read_mesh(p)
    assert r.V.shape == (5, 3)
    assert r.F.tolist() == [[0, 1, 2], [0, 2, 3], [4, 1, 2], [0, 1, 3]]


def test_obj_and_stl_of_template(tpl):
    V, F = tpl
    m = trimesh.Trimesh(V, F, process=False)
    r = read_mesh(m.export(file_type="obj").encode(), "obj")
    np.testing.assert_allclose(r.V, V, atol=1e-9)
    np.testing.assert_array_equal(r.F, F)
    for ft in ("stl", "stl_ascii"):
        data = m.export(file_type=ft)
        data = data.encode() if isinstance(data, str) else data
        r = read_mesh(data, "stl")
        # duplicates merged into an indexed mesh with shared vertices
        assert r.V.shape == V.shape and r.F.shape == F.shape
        np.testing.assert_allclose(r.V[r.F], V[F], atol=1e-6)


def test_stl_sniffed_without_fmt(tpl):
    V, F = tpl
    data = trimesh.Trimesh(V, F, process=False).export(file_type="stl")
    assert read_mesh(data).F.shape == F.shape


def test_npz_keys(tpl):
    V, F = tpl
    for kv, kf in (("vertices", "faces"), ("V", "F")):
        buf = io.BytesIO()
        np.savez(buf, **{kv: V, kf: F, "confidence": np.full(len(V), 0.5)})
        r = read_mesh(buf.getvalue(), "npz")
        np.testing.assert_array_equal(r.V, V)
        np.testing.assert_array_equal(r.F, F)
        assert np.all(r.confidence == 0.5)


@pytest.mark.parametrize("ext", ["xyz", "pts"])
def test_point_cloud_text(tmp_path, ext):
    p = tmp_path / f"c.{ext}"
    if ext == "pts":
        p.write_text("3\n0 0 0 10 255 0 0\n1,0,0,10,0,255,0\n0 1 0 10 0 0 255\n")
        r = read_mesh(p)
        assert r.colors.tolist() == [[255, 0, 0], [0, 255, 0], [0, 0, 255]]
    else:
        p.write_text("# x y z nx ny nz\n0 0 0 0 0 1\n1 0 0 0 0 1\r\n0 1 0 0 0 1\n")
        r = read_mesh(p)
        np.testing.assert_allclose(r.normals, [[0, 0, 1]] * 3)
    assert r.F is None and r.V.shape == (3, 3)


def test_inspect_header(tpl, tmp_path):
    V, F = tpl
    p = tmp_path / "s.ply"
    p.write_bytes(ply_bytes(V, F, extra={"confidence": np.ones(len(V), np.float32)}))
    info = inspect_mesh_header(p)
    assert info == dict(
        format="ply", n_vertices=len(V), n_faces=len(F), has_normals=False, has_confidence=True
    )
    with pytest.raises(InputFormatError, match="limit"):
        inspect_mesh_header(p, max_vertices=1000)
    data = trimesh.Trimesh(V, F, process=False).export(file_type="stl")
    assert inspect_mesh_header(data)["n_faces"] == len(F)
    obj = trimesh.Trimesh(V, F, process=False).export(file_type="obj").encode()
    assert inspect_mesh_header(obj, "obj")["n_vertices"] == len(V)


def test_inspect_header_detects_truncated_binary(tpl):
    V, F = tpl
    b = ply_bytes(V, F)
    with pytest.raises(InputFormatError, match="truncated"):
        inspect_mesh_header(b[: len(b) // 2])


# --- bad inputs -------------------------------------------------------------------------------


def test_empty_file(tmp_path):
    p = tmp_path / "empty.ply"
    p.write_bytes(b"")
    with pytest.raises(InputFormatError, match="empty"):
        read_mesh(p)
    with pytest.raises(InputFormatError, match="empty"):
        read_mesh(b"")
    with pytest.raises(InputFormatError, match="empty"):
        inspect_mesh_header(p)


def test_missing_file(tmp_path):
    with pytest.raises(InputFormatError, match="not found"):
        read_mesh(tmp_path / "nope.ply")


def test_truncated_binary_ply(tpl):
    V, F = tpl
    b = ply_bytes(V, F)
    for cut in (len(b) - 7, len(b) // 2, 300):
        with pytest.raises(InputFormatError, match="truncated"):
            read_mesh(b[:cut], "ply")


def test_header_claims_more_vertices_than_present():
    b = ply_bytes(SQUARE_V).replace(b"element vertex 5", b"element vertex 50")
    with pytest.raises(InputFormatError, match="truncated"):
        read_mesh(b, "ply")
    a = ply_bytes(SQUARE_V, fmt="ascii").replace(b"element vertex 5", b"element vertex 50")
    with pytest.raises(InputFormatError, match="declares 50"):
        read_mesh(a, "ply")


@pytest.mark.parametrize(
    "data",
    [
        b"\x00\x01garbage\xff\xfe" * 20,
        b"ply\nformat binary_little_endian 1.0\nelement vertex abc\nend_header\n",
        b"ply\nformat weird 1.0\nend_header\n",
        b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
        b"property float z\nend_header\n0 0 0\n1 zz 0\n",
        b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
        b"property float z\nend_header\n0 0 0\n1 0\n",
        b"ply\nno end header",
        b"\xff\xfe\xfa\xfb" * 100,
    ],
)
def test_garbage(data):
    with pytest.raises(InputFormatError):
        read_mesh(data)


def test_garbage_obj_and_stl(tmp_path):
    p = tmp_path / "x.obj"
    p.write_bytes(b"v 1 2 three\nf 1 2 3\n")
    with pytest.raises(InputFormatError, match="three"):
        read_mesh(p)
    p = tmp_path / "x.stl"
    p.write_bytes(b"\x00" * 80 + np.array([1000], "<u4").tobytes() + b"\x00" * 100)
    with pytest.raises(InputFormatError, match="truncated"):
        read_mesh(p)
    p = tmp_path / "x.npz"
    p.write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(InputFormatError, match="NPZ"):
        read_mesh(p)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nonfinite_coordinates_rejected(bad):
    V = SQUARE_V.copy()
    V[2, 1] = bad
    V[4, 0] = bad
    with pytest.raises(InputFormatError, match="2 of 5 vertices have non-finite") as e:
        read_mesh(ply_bytes(V), "ply")
    assert e.value.details["first_index"] == 2


def test_face_index_out_of_range():
    F = np.array([[0, 1, 2], [2, 3, 7]])
    with pytest.raises(InputFormatError, match="face index 7") as e:
        read_mesh(ply_bytes(SQUARE_V, F), "ply")
    assert e.value.details["face"] == 1
    with pytest.raises(InputFormatError, match="out of range"):
        read_mesh(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "obj")


def test_limits_checked_from_header():
    V = np.zeros((100, 3))
    b = ply_bytes(V, np.zeros((10, 3), int))
    with pytest.raises(InputFormatError, match="above the limit of 50"):
        read_mesh(b, "ply", max_vertices=50)
    with pytest.raises(InputFormatError, match="faces, above the limit of 5"):
        read_mesh(b, "ply", max_faces=5)
    # a huge header count is refused before any allocation or parsing
    huge = b.replace(b"element vertex 100", b"element vertex 999999999")
    with pytest.raises(InputFormatError, match="limit"):
        read_mesh(huge, "ply")
    with pytest.raises(InputFormatError, match="limit"):
        read_mesh(b"v 0 0 0\n" * 20, "obj", max_vertices=10)


def test_confidence_out_of_range_is_an_error():
    c = np.array([0.1, 0.5, 1.5, 0.2, 0.3], np.float32)
    with pytest.raises(InputFormatError, match=r"\[0, 1\]"):
        read_mesh(ply_bytes(SQUARE_V, extra={"confidence": c}), "ply")
    ok = np.array([0.0, 0.5, 1.0 + 1e-7, 0.2, 0.3], np.float32)
    r = read_mesh(ply_bytes(SQUARE_V, extra={"confidence": ok}), "ply")
    assert r.confidence.max() <= 1.0


def test_unknown_format_name():
    with pytest.raises(InputFormatError, match="unknown mesh format"):
        read_mesh(b"abc", "fbx")


def test_corrupted_files_only_raise_input_format_error(tpl):
    """Random truncations and byte flips never leak IndexError, struct.error and the like."""
    V, F = tpl
    V, F = V[:200], F[F.max(axis=1) < 200][:50]
    m = trimesh.Trimesh(V, F, process=False)
    buf = io.BytesIO()
    np.savez(buf, vertices=V, faces=F)
    seeds = [
        (ply_bytes(V, F), "ply"),
        (ply_bytes(V, F, fmt="ascii"), "ply"),
        (m.export(file_type="obj").encode(), "obj"),
        (m.export(file_type="stl"), "stl"),
        (buf.getvalue(), "npz"),
    ]
    rng = np.random.default_rng(0)
    for i in range(400):
        data, fmt = seeds[i % len(seeds)]
        b = bytearray(data)
        if i % 2:
            b = b[: int(rng.integers(0, len(b)))]
        else:
            for j in rng.integers(0, len(b), 5):
                b[j] = int(rng.integers(0, 256))
        for f in (fmt, None):
            with contextlib.suppress(InputFormatError):
                read_mesh(bytes(b), f)


def test_mixed_polygons_fan_triangulated_in_file_order_in_every_format():
    """Faces alternating triangles / quads / pentagons (issue 11: parsed face by face before)."""
    import time

    from bench.mixed_faces import mixed_polygons, obj, ply_ascii, ply_binary

    V = np.random.default_rng(1).normal(size=(5_000, 3)).astype(np.float32).astype(np.float64)
    polys = mixed_polygons(20_000, len(V))
    want = np.array([(p[0], p[j], p[j + 1]) for p in polys for j in range(1, len(p) - 1)])
    for data, fmt in ((ply_binary(V, polys), "ply"), (ply_ascii(V, polys), "ply"),
                      (obj(V, polys), "obj")):  # fmt: skip
        t = time.process_time()
        r = read_mesh(data, fmt)
        assert time.process_time() - t < 1.0  # was 0.4-0.45 s per 20,000 faces
        np.testing.assert_array_equal(r.F, want)
        np.testing.assert_allclose(r.V, V, atol=1e-5)


def test_binary_ply_list_rows_truncated_midway():
    from bench.mixed_faces import mixed_polygons, ply_binary

    V = np.zeros((10, 3))
    data = ply_binary(V, mixed_polygons(50, 10))
    for cut in (1, 7, 30):
        with pytest.raises(InputFormatError, match="truncated"):
            read_mesh(data[:-cut], "ply")


def test_binary_ply_faces_with_two_lists_and_a_scalar():
    """Rows whose sizes depend on two list lengths (the general, non-uchar path)."""
    head = (
        b"ply\nformat binary_big_endian 1.0\nelement vertex 6\n"
        b"property double x\nproperty double y\nproperty double z\n"
        b"element face 3\nproperty ushort flags\nproperty list int uint vertex_indices\n"
        b"property list uchar float texcoord\nend_header\n"
    )
    V = np.arange(18, dtype=float).reshape(6, 3)
    rows = b""
    for k, idx in ((3, [0, 1, 2]), (4, [2, 3, 4, 5]), (5, [0, 1, 2, 3, 4])):
        rows += np.array([7], ">u2").tobytes() + np.array([k], ">i4").tobytes()
        rows += np.array(idx, ">u4").tobytes() + bytes([2 * k]) + np.zeros(2 * k, ">f4").tobytes()
    r = read_mesh(head + V.astype(">f8").tobytes() + rows, "ply")
    np.testing.assert_array_equal(
        r.F, [[0, 1, 2], [2, 3, 4], [2, 4, 5], [0, 1, 2], [0, 2, 3], [0, 3, 4]]
    )


@pytest.mark.parametrize("enc", ["utf-8", "latin-1"])
def test_ply_header_comments_with_non_ascii_characters(enc):
    """Scanner software writes author and product names in comments (Artec, MeshLab users)."""
    F = np.array([[0, 1, 2], [0, 2, 3], [0, 1, 4]])
    for fmt in ("ascii", "binary_little_endian"):
        data = ply_bytes(SQUARE_V, F, fmt=fmt)
        comment = "comment Créé par Müller, Artec Studio © 2024\n".encode(enc)
        data = data.replace(b"ply\n", b"ply\n" + comment, 1)
        r = read_mesh(data, "ply")
        np.testing.assert_allclose(r.V, SQUARE_V)
        np.testing.assert_array_equal(r.F, F)
        assert inspect_mesh_header(data, "ply")["n_faces"] == 3


def test_ply_quality_outside_the_unit_interval_is_not_confidence():
    """MeshLab writes a per-vertex ``quality`` of any meaning (curvature, density): outside
    [0, 1] it is ignored, not refused; ``confidence`` itself stays strict."""
    q = np.array([0.0, 3.5, 17.0, 250.0, 1.0], np.float32)
    r = read_mesh(ply_bytes(SQUARE_V, extra={"quality": q}), "ply")
    assert r.confidence is None
    np.testing.assert_allclose(r.V, SQUARE_V)
    q01 = np.array([0.0, 0.25, 0.5, 0.75, 1.0], np.float32)
    r = read_mesh(ply_bytes(SQUARE_V, extra={"quality": q01}), "ply")
    np.testing.assert_allclose(r.confidence, q01)
    with pytest.raises(InputFormatError, match=r"\[0, 1\]"):
        read_mesh(ply_bytes(SQUARE_V, extra={"confidence": q}), "ply")


@pytest.mark.parametrize("fmt", ["ascii", "binary_big_endian"])
def test_ply_16_bit_colours_scaled_to_8_bit(fmt):
    """LAS/E57 point clouds converted to PLY (PDAL, CloudCompare) carry ushort colours."""
    head = (
        f"ply\nformat {fmt} 1.0\nelement vertex 5\nproperty float x\nproperty float y\n"
        "property float z\nproperty ushort red\nproperty ushort green\nproperty ushort blue\n"
        "end_header\n"
    ).encode()

    def ply(rgb):
        if fmt == "ascii":
            rows = [" ".join(map(str, [*v, *c])) for v, c in zip(SQUARE_V, rgb, strict=True)]
            return head + ("\n".join(rows) + "\n").encode()
        rec = np.zeros(5, dtype=[("v", ">f4", 3), ("c", ">u2", 3)])
        rec["v"], rec["c"] = SQUARE_V, rgb
        return head + rec.tobytes()

    rgb8 = np.random.default_rng(3).integers(0, 256, (5, 3))
    rgb8[0] = 255
    np.testing.assert_array_equal(read_mesh(ply(rgb8 * 257), "ply").colors, rgb8)  # 16-bit
    np.testing.assert_array_equal(read_mesh(ply(rgb8), "ply").colors, rgb8)  # 8-bit values


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian"])
def test_ply_tristrips_give_triangles_with_one_winding(fmt):
    """A ``tristrips`` element (older Cyberware/VRIP scans, some exporters): strips separated
    by -1, joined by degenerate triangles; it was read as a point cloud."""
    # a ribbon of 2 x 5 vertices in the z = 0 plane: bottom row 0..4, top row 5..9
    V = np.array([[x, y, 0.0] for y in (0, 1) for x in range(5)])
    ribbon = [0, 5, 1, 6, 2, 7, -1, 2, 2, 2, 7, 3, 8, 4, 9]  # two strips, degenerate lead-in
    head = (
        f"ply\nformat {fmt} 1.0\nelement vertex 10\nproperty float x\nproperty float y\n"
        "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
        "element tristrips 1\nproperty list int int vertex_indices\nend_header\n"
    ).encode()
    face = [4, 0, 1, 2, 3]  # a (degenerate, collinear) quad: faces and strips together
    if fmt == "ascii":
        rows = [" ".join(map(str, v)) for v in V] + [" ".join(map(str, face))]
        body = ("\n".join([*rows, " ".join(map(str, [len(ribbon), *ribbon]))]) + "\n").encode()
    else:
        body = V.astype("<f4").tobytes() + bytes([4]) + np.array(face[1:], "<i4").tobytes()
        body += np.array([len(ribbon), *ribbon], "<i4").tobytes()
    r = read_mesh(head + body, "ply")
    strips = r.F[2:]
    assert len(strips) == 8  # one triangle per quad cell's half: 4 cells x 2
    assert {tuple(sorted(t)) for t in strips} == {
        tuple(sorted(t)) for i in range(4) for t in ((i, i + 1, i + 5), (i + 1, i + 5, i + 6))
    }
    e1, e2 = V[strips[:, 1]] - V[strips[:, 0]], V[strips[:, 2]] - V[strips[:, 0]]
    normal_z = np.cross(e1, e2)[:, 2]
    assert np.all(normal_z < 0) or np.all(normal_z > 0)  # one winding
    np.testing.assert_array_equal(r.F[:2], [[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize("eol", ["\n", "\r\n"])
def test_obj_backslash_line_continuations(eol):
    """The OBJ spec lets a line ending in a backslash continue on the next (long polygons)."""
    lines = ["v 0 0 0", "v 1 0 \\", "  0", "v 1 1 0", "v 0 1 0",
             "f 1 2 \\", "  3 4", "f 1 2\\", " 4"]  # fmt: skip
    r = read_mesh(eol.join(lines).encode() + eol.encode(), "obj")
    np.testing.assert_allclose(r.V, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    np.testing.assert_array_equal(r.F, [[0, 1, 2], [0, 2, 3], [0, 1, 3]])


def test_obj_vertex_colours_kept_over_a_flat_material_colour(tmp_path):
    """MeshLab/Blender write per-vertex colours and name a default material beside them
    (``Kd 0.8 0.8 0.8``): the material's flat grey replaced every vertex's colour."""
    rgb = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 255, 0]])
    V = SQUARE_V[:4]
    vs = "".join(f"v {x} {y} {z} {r / 255} {g / 255} {b / 255}\n" for (x, y, z), (r, g, b)
                 in zip(V, rgb, strict=True))  # fmt: skip
    (tmp_path / "scan.mtl").write_text("newmtl Material\nKa 1 1 1\nKd 0.8 0.8 0.8\nd 1\n")
    p = tmp_path / "scan.obj"
    p.write_text(f"mtllib scan.mtl\n{vs}usemtl Material\nf 1 2 3\nf 1 3 4\n")
    np.testing.assert_array_equal(read_mesh(p).colors, rgb)
    # without vertex colours the material's colour is still the scan's
    p.write_text("mtllib scan.mtl\n" + "".join(f"v {x} {y} {z}\n" for x, y, z in V)
                 + "usemtl Material\nf 1 2 3\nf 1 3 4\n")  # fmt: skip
    np.testing.assert_array_equal(read_mesh(p).colors, [[204, 204, 204]] * 4)


def _stl_binary(tri: np.ndarray, header: bytes, count: int) -> bytes:
    rec = np.zeros(len(tri), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["v"] = tri
    return header.ljust(80, b" ") + np.array([count], "<u4").tobytes() + rec.tobytes()


def test_binary_stl_with_a_solid_header_padding_or_no_count(tpl):
    """Binary STLs whose header starts with "solid" (SolidWorks and others) and that carry
    bytes past the declared triangles, or a count of 0 (a streaming writer), are read; a
    truncated one is refused as truncated (it was 'no triangles', read as ASCII)."""
    V, F = tpl
    tri = V[F[:500]].astype(np.float32)
    for header in (b"solid part exported by SolidWorks", b"Artec binary STL"):
        for data in (
            _stl_binary(tri, header, len(tri)) + b"\x00\x00",  # padding
            _stl_binary(tri, header, len(tri)) + b"\n",
            _stl_binary(tri, header, 0),  # count never written
        ):
            r = read_mesh(data, "stl")
            np.testing.assert_allclose(r.V[r.F], tri, atol=1e-6)
            assert inspect_mesh_header(data, "stl")["n_faces"] == len(tri)
        with pytest.raises(InputFormatError, match="truncated"):
            read_mesh(_stl_binary(tri, header, len(tri))[:-30], "stl")
        with pytest.raises(InputFormatError, match="truncated"):
            inspect_mesh_header(_stl_binary(tri, header, len(tri))[:-30], "stl")


def test_ascii_stl_keywords_in_upper_case(tpl):
    V, F = tpl
    m = trimesh.Trimesh(V, F[:300], process=False)
    text = m.export(file_type="stl_ascii")
    r = read_mesh(text.upper().encode(), "stl")
    np.testing.assert_allclose(r.V[r.F], V[F[:300]], atol=1e-5)
    assert inspect_mesh_header(text.upper().encode(), "stl")["n_faces"] == 300


def test_ply_normals_named_normal_x_as_pcl_writes_them():
    """PCL (and tools built on it) name PLY normals normal_x/normal_y/normal_z."""
    N = np.random.default_rng(2).normal(size=(5, 3)).astype(np.float32)
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    extra = {"normal_x": N[:, 0], "normal_y": N[:, 1], "normal_z": N[:, 2]}
    data = ply_bytes(SQUARE_V, extra=extra)
    np.testing.assert_allclose(read_mesh(data, "ply").normals, N)
    assert inspect_mesh_header(data, "ply")["has_normals"]


def test_ply_confidence_name_in_any_case():
    """CloudCompare writes a scalar field "Confidence" as ``scalar_Confidence``."""
    c = np.array([0.1, 0.5, 0.9, 0.2, 1.0], np.float32)
    data = ply_bytes(SQUARE_V, extra={"scalar_Confidence": c})
    np.testing.assert_allclose(read_mesh(data, "ply").confidence, c)
    assert inspect_mesh_header(data, "ply")["has_confidence"]


@pytest.mark.parametrize("header", [True, False])
def test_point_cloud_text_columns_in_cloudcompare_order(header):
    """CloudCompare's ASCII export writes x y z, colours, scalar fields, normals (the colours
    were read as normals and the normals as colours); float colours (0-1) were dropped."""
    rng = np.random.default_rng(4)
    V = rng.normal(size=(6, 3))
    N = rng.normal(size=(6, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    rgb = rng.integers(0, 256, (6, 3))
    rows = [f"{v[0]},{v[1]},{v[2]},{c[0]},{c[1]},{c[2]},{n[0]},{n[1]},{n[2]}"
            for v, c, n in zip(V, rgb, N, strict=True)]  # fmt: skip
    text = "\n".join((["//X,Y,Z,R,G,B,Nx,Ny,Nz"] if header else []) + rows) + "\n"
    r = read_mesh(text.encode(), "xyz")
    np.testing.assert_allclose(r.V, V)
    np.testing.assert_allclose(r.normals, N)
    np.testing.assert_array_equal(r.colors, rgb)
    # colours saved as floats in [0, 1], then a scalar field
    rows = [f"{v[0]} {v[1]} {v[2]} {c[0] / 255} {c[1] / 255} {c[2] / 255} 0.5"
            for v, c in zip(V, rgb, strict=True)]  # fmt: skip
    text = "\n".join((["//X Y Z Rf Gf Bf Intensity"] if header else []) + rows) + "\n"
    r = read_mesh(text.encode(), "xyz")
    np.testing.assert_array_equal(r.colors, rgb)
    assert r.normals is None


def test_obj_point_cloud_keeps_its_vertex_normals():
    """A point cloud saved as OBJ (MeshLab, CloudCompare) has one ``vn`` per ``v`` and no faces
    to pair them: the normals were dropped (and estimated again)."""
    N = np.random.default_rng(5).normal(size=(5, 3))
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    text = "".join(f"vn {n[0]!r} {n[1]!r} {n[2]!r}\nv {v[0]} {v[1]} {v[2]}\n"
                   for v, n in zip(SQUARE_V, N.tolist(), strict=True))  # fmt: skip
    r = read_mesh(text.encode(), "obj")
    assert r.F is None
    np.testing.assert_allclose(r.V, SQUARE_V)
    np.testing.assert_allclose(r.normals, N)
    # a count that does not match says nothing about which normal is whose
    assert read_mesh(text.encode() + b"vn 0 0 1\n", "obj").normals is None
