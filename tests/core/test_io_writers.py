"""Writers: PLY/OBJ round trips through read_mesh, GLB structure and trimesh cross-check."""

from __future__ import annotations

import json
import os
import struct

import numpy as np
import pytest
import trimesh

from core.errors import InputFormatError
from core.io.readers import read_mesh
from core.io.writers import write_glb, write_mesh, write_obj, write_ply
from core.template import load_template

TPL = load_template()
V0 = np.array(TPL.V)
F0 = np.array(TPL.F, dtype=np.int64)


def read_glb(data: bytes) -> tuple[dict, bytes]:
    """A small GLB reader: header, JSON chunk, BIN chunk."""
    magic, version, total = struct.unpack_from("<III", data, 0)
    assert magic == 0x46546C67 and version == 2 and total == len(data)
    jlen, jtype = struct.unpack_from("<II", data, 12)
    assert jtype == 0x4E4F534A and jlen % 4 == 0
    gltf = json.loads(data[20 : 20 + jlen])
    blen, btype = struct.unpack_from("<II", data, 20 + jlen)
    assert btype == 0x004E4942 and blen % 4 == 0
    return gltf, data[28 + jlen : 28 + jlen + blen]


def accessor(gltf, binary, i):
    acc = gltf["accessors"][i]
    view = gltf["bufferViews"][acc["bufferView"]]
    assert view["byteOffset"] % 4 == 0 and "byteStride" not in view
    dt = {5126: "<f4", 5125: "<u4", 5123: "<u2", 5121: "u1"}[acc["componentType"]]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[acc["type"]]
    a = np.frombuffer(
        binary, dt, acc["count"] * width, view["byteOffset"] + acc.get("byteOffset", 0)
    )
    return a.reshape(acc["count"], width) if width > 1 else a


@pytest.mark.parametrize("binary", [True, False])
def test_ply_roundtrip(tmp_path, binary):
    n = len(V0)
    rng = np.random.default_rng(0)
    N = trimesh.Trimesh(V0, F0, process=False).vertex_normals
    conf = rng.random(n)
    rgb = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    p = tmp_path / "o.ply"
    write_ply(p, V0, F0, normals=N, confidence=conf, colors=rgb, binary=binary)
    r = read_mesh(p)
    np.testing.assert_array_equal(r.V, V0)
    np.testing.assert_array_equal(r.F, F0)
    np.testing.assert_allclose(r.normals, N, atol=1e-6)
    np.testing.assert_allclose(r.confidence, conf, atol=1e-6)
    np.testing.assert_array_equal(r.colors, rgb)
    assert trimesh.load(p, process=False).vertices.shape == V0.shape


def test_ply_point_cloud(tmp_path):
    p = tmp_path / "c.ply"
    write_ply(p, V0[:100], None)
    r = read_mesh(p)
    assert r.F is None and np.array_equal(r.V, V0[:100])


def test_obj_roundtrip(tmp_path):
    p = tmp_path / "o.obj"
    N = trimesh.Trimesh(V0, F0, process=False).vertex_normals
    write_obj(p, V0, F0, normals=N)
    r = read_mesh(p)
    np.testing.assert_array_equal(r.V, V0)
    np.testing.assert_array_equal(r.F, F0)
    np.testing.assert_allclose(r.normals, N, atol=1e-6)
    write_obj(p, V0, F0)
    assert read_mesh(p).normals is None


def test_glb_structure_and_trimesh(tmp_path):
    p = tmp_path / "o.glb"
    rgb = np.full((len(V0), 3), 200, np.uint8)
    data = write_glb(p, V0, F0, colors=rgb)
    assert p.read_bytes() == data
    gltf, binary = read_glb(data)
    assert gltf["asset"] == {"version": "2.0", "generator": "bodyspace"}
    assert len(gltf["meshes"]) == 1 and len(gltf["meshes"][0]["primitives"]) == 1
    prim = gltf["meshes"][0]["primitives"][0]
    pos = accessor(gltf, binary, prim["attributes"]["POSITION"])
    np.testing.assert_allclose(pos, V0, atol=1e-6)
    acc = gltf["accessors"][prim["attributes"]["POSITION"]]
    np.testing.assert_allclose(acc["min"], pos.min(axis=0))
    np.testing.assert_allclose(acc["max"], pos.max(axis=0))
    nrm = accessor(gltf, binary, prim["attributes"]["NORMAL"])
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-6)
    ref = trimesh.Trimesh(V0, F0, process=False).vertex_normals
    assert np.mean(np.sum(nrm * ref, axis=1) > 0.8) > 0.97
    idx = accessor(gltf, binary, prim["indices"])
    assert gltf["accessors"][prim["indices"]]["componentType"] == 5123  # small: uint16
    np.testing.assert_array_equal(idx.reshape(-1, 3), F0)
    col = accessor(gltf, binary, prim["attributes"]["COLOR_0"])
    assert col.shape == (len(V0), 4) and np.all(col[:, :3] == 200)
    scene = trimesh.load(p)
    mesh = next(iter(scene.geometry.values()))
    assert mesh.vertices.shape == V0.shape and mesh.faces.shape == F0.shape


def test_glb_large_uses_uint32_and_bytes_only():
    V, F = trimesh.remesh.subdivide(V0, F0)
    V, F = trimesh.remesh.subdivide(V, F)
    data = write_glb(None, V, F)
    gltf, binary = read_glb(data)
    prim = gltf["meshes"][0]["primitives"][0]
    assert gltf["accessors"][prim["indices"]]["componentType"] == 5125
    np.testing.assert_array_equal(accessor(gltf, binary, prim["indices"]).reshape(-1, 3), F)


def test_write_mesh_dispatch_and_atomic(tmp_path):
    for ext in ("ply", "obj", "glb"):
        p = tmp_path / f"m.{ext}"
        write_mesh(p, V0, F0, normals=None)
        assert p.stat().st_size > 0
    assert sorted(os.listdir(tmp_path)) == ["m.glb", "m.obj", "m.ply"]  # no temp files left
    with pytest.raises(InputFormatError, match="unknown extension"):
        write_mesh(tmp_path / "m.fbx", V0, F0)


def test_failed_write_leaves_target_untouched(tmp_path):
    p = tmp_path / "keep.ply"
    p.write_bytes(b"old")
    with pytest.raises(InputFormatError):
        write_ply(p, V0, F0 + len(V0))  # out-of-range faces are refused before writing
    assert p.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["keep.ply"]
