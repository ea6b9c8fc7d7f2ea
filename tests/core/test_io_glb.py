"""FixedTopologyGlb: write_glb's bytes (normals to float32 precision), unit normals matching the
float64 computation."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from core.errors import InputFormatError
from core.io._geometry import vertex_normals
from core.io.glb import FixedTopologyGlb
from core.io.writers import write_glb
from core.template import load_template


@pytest.fixture(scope="module")
def template():
    return load_template()


@pytest.fixture(scope="module")
def encoder(template):
    return FixedTopologyGlb(template.F, template.n_vertices)


def _bodies(template, n=6):
    """Varied template-order bodies: shape-space syntheses and randomly deformed templates."""
    from core.shapespace import default_model

    m = default_model()
    rng = np.random.default_rng(3)
    out = [
        m.synthesize("female", {"height_m": 1.58, "weight_kg": 52}),
        m.synthesize("male", {"height_m": 1.90, "weight_kg": 105, "age": 40}),
        m.synthesize("male", {"height_m": 1.75}, seed=11),
    ]
    for _ in range(n - len(out)):
        out.append(template.V * rng.uniform(0.9, 1.1) + rng.normal(0, 0.002, template.V.shape))
    return out


def _chunks(data: bytes) -> tuple[dict, bytes]:
    magic, version, total = struct.unpack_from("<III", data, 0)
    assert (magic, version, total) == (0x46546C67, 2, len(data))
    jlen, jtype = struct.unpack_from("<II", data, 12)
    assert jtype == 0x4E4F534A and jlen % 4 == 0
    blen, btype = struct.unpack_from("<II", data, 20 + jlen)
    assert btype == 0x004E4942 and blen % 4 == 0
    return json.loads(data[20 : 20 + jlen]), data[28 + jlen : 28 + jlen + blen]


def _normals(data: bytes) -> np.ndarray:
    gltf, binary = _chunks(data)
    acc = gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["NORMAL"]]
    view = gltf["bufferViews"][acc["bufferView"]]
    N = np.frombuffer(binary, np.float32, 3 * acc["count"], view["byteOffset"])
    return N.reshape(-1, 3).astype(np.float64)


def _same_as_write_glb(data: bytes, ref: bytes) -> None:
    """Same length, header, JSON chunk, positions and indices; normals within 1e-5."""
    assert len(data) == len(ref)
    gltf, binary = _chunks(data)
    gltf_ref, binary_ref = _chunks(ref)
    assert gltf == gltf_ref
    head = len(data) - len(binary)  # GLB header, JSON chunk, BIN chunk header
    assert data[:head] == ref[:head]
    view = gltf["bufferViews"][gltf["accessors"][1]["bufferView"]]
    lo, hi = view["byteOffset"], view["byteOffset"] + view["byteLength"]
    assert binary[:lo] == binary_ref[:lo] and binary[hi:] == binary_ref[hi:]
    assert np.abs(_normals(data) - _normals(ref)).max() < 1e-5


def test_same_as_write_glb(template, encoder):
    for V in _bodies(template):
        _same_as_write_glb(encoder.encode(V), write_glb(None, V, template.F))


def test_normals_unit_and_match_vertex_normals(template, encoder):
    for V in _bodies(template):
        N = encoder.normals(V)
        assert N.dtype == np.float32
        np.testing.assert_allclose(np.linalg.norm(N.astype(np.float64), axis=1), 1.0, atol=1e-6)
        assert np.abs(N - vertex_normals(V, template.F)).max() < 1e-5
        np.testing.assert_array_equal(_normals(encoder.encode(V)), N)


def test_positions_bounds_and_indices(template, encoder):
    V = _bodies(template, 3)[1]
    gltf, binary = _chunks(encoder.encode(V))
    prim = gltf["meshes"][0]["primitives"][0]
    pos = gltf["accessors"][prim["attributes"]["POSITION"]]
    P = np.frombuffer(binary, np.float32, 3 * pos["count"], 0).reshape(-1, 3)
    np.testing.assert_array_equal(P, V.astype(np.float32))
    assert pos["min"] == [float(x) for x in P.min(0)] and pos["max"] == [float(x) for x in P.max(0)]
    idx = gltf["accessors"][prim["indices"]]
    view = gltf["bufferViews"][idx["bufferView"]]
    assert idx["componentType"] == 5123  # uint16: 13380 vertices
    Fi = np.frombuffer(binary, np.uint16, idx["count"], view["byteOffset"]).reshape(-1, 3)
    np.testing.assert_array_equal(Fi, template.F)


def test_uint32_indices_and_unused_vertices_match_write_glb():
    rng = np.random.default_rng(0)
    n = 70_000  # > 65535: uint32 indices; most vertices in no face -> fallback normal (0, 1, 0)
    V = rng.normal(size=(n, 3))
    F = rng.integers(0, n, size=(500, 3))
    F[0] = [5, 5, 6]  # a degenerate face (zero area)
    enc = FixedTopologyGlb(F, n)
    data = enc.encode(V)
    _same_as_write_glb(data, write_glb(None, V, F))
    gltf, _ = _chunks(data)
    assert gltf["accessors"][2]["componentType"] == 5125
    N = enc.normals(V)
    unused = np.setdiff1d(np.arange(n), F.ravel())
    np.testing.assert_array_equal(N[unused], np.tile([0.0, 1.0, 0.0], (len(unused), 1)))
    used = np.unique(F[1:])
    assert np.abs(N[used] - vertex_normals(V, F)[used]).max() < 1e-5


def test_bad_input(template, encoder):
    with pytest.raises(InputFormatError, match="shape"):
        encoder.encode(template.V[:-1])
    V = template.V.copy()
    V[7, 1] = np.nan
    with pytest.raises(InputFormatError, match="non-finite"):
        encoder.encode(V)
    for bad in (np.inf, -np.inf):  # caught through the bounds: either end
        V = template.V.copy()
        V[3, 2] = bad
        with pytest.raises(InputFormatError, match="1 non-finite vertices"):
            encoder.encode_buffer(V)
    with pytest.raises(ValueError, match="F must have shape"):
        FixedTopologyGlb(np.zeros((0, 3), int), 3)
    with pytest.raises(ValueError, match="indexes vertices"):
        FixedTopologyGlb(np.array([[0, 1, 3]]), 3)


def test_encode_buffer_is_encode_without_the_copy(template, encoder):
    V = _bodies(template, 2)[1]
    buf = encoder.encode_buffer(V)
    assert isinstance(buf, bytearray)
    assert bytes(buf) == encoder.encode(V)
