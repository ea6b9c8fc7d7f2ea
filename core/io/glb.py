"""GLB (binary glTF 2.0) encoding: the one layout of bodyspace's GLB files.

:class:`GlbLayout` lays out the JSON document and the binary chunk of a one-mesh GLB (buffer
views, accessors, the file header): :func:`core.io.write_glb` builds one per call for any mesh
(normals, colours, morph targets, skins); :class:`FixedTopologyGlb` builds one once for the many
meshes that share one triangle list (bodies in template order) and keeps, besides it, the index
buffer bytes, a sparse vertex <- face matrix that sums face normals into vertex normals and the
JSON chunk around the only per-body values (the POSITION ``min``/``max``). Its output is what
``write_glb(None, V, F)`` writes for the same ``V`` and ``F`` -- the same JSON chunk, positions
and indices byte for byte -- except that the area-weighted vertex normals are summed in float32
from float64 edge vectors (they are stored as float32 anyway): within 1e-5 (0.0006°) of
write_glb's float64 normals, unit length to float32 precision. About a fifth of write_glb's time
per body.

:func:`read_glb_primitives` reads the other way, for scans delivered as GLB: the triangle and
point primitives of the default scene in world coordinates, with ``COLOR_0``, the base colour
texture and its ``TEXCOORD``; every reference and byte range is checked.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import sparse

from core.errors import InputFormatError

_GLTF_MAGIC, _JSON, _BIN = 0x46546C67, 0x4E4F534A, 0x004E4942
_MIN, _MAX = "@@POSITION_MIN@@", "@@POSITION_MAX@@"


def _pad4(b: bytes, fill: bytes = b"\x00") -> bytes:
    return b + fill * (-len(b) % 4)


ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963  # buffer view targets


class GlbLayout:
    """The JSON document and binary-chunk layout of a GLB with one mesh and one primitive.

    Data blocks are added in buffer order (:meth:`add`: each starts on a 4-byte boundary); the
    caller writes each block's bytes at its offset in the buffer of :meth:`frame`.
    """

    def __init__(self) -> None:
        self.views: list[dict] = []
        self.accessors: list[dict] = []
        self.bin_len = 0  # bytes of the binary chunk's data (blocks padded to 4)

    def add(self, nbytes: int, target: int, accessor: dict) -> tuple[int, int]:
        """Reserve ``nbytes`` for ``accessor`` (its ``bufferView`` is set here) in a buffer
        view with ``target`` (0: none). Returns (accessor index, byte offset in the chunk)."""
        offset = self.bin_len
        view = {"buffer": 0, "byteOffset": offset, "byteLength": int(nbytes)}
        if target:
            view["target"] = target
        self.views.append(view)
        accessor["bufferView"] = len(self.views) - 1
        self.accessors.append(accessor)
        self.bin_len += int(nbytes) + (-int(nbytes) % 4)
        return len(self.accessors) - 1, offset

    def add_view(self, nbytes: int) -> tuple[int, int]:
        """Reserve ``nbytes`` in a buffer view without accessor or target (e.g. an embedded
        image). Returns (buffer view index, byte offset in the chunk)."""
        offset = self.bin_len
        self.views.append({"buffer": 0, "byteOffset": offset, "byteLength": int(nbytes)})
        self.bin_len += int(nbytes) + (-int(nbytes) % 4)
        return len(self.views) - 1, offset

    def document(
        self,
        mesh: dict,
        nodes: list[dict] | None = None,
        scene_nodes: list[int] | None = None,
        skins: list[dict] | None = None,
        extra: dict | None = None,
    ) -> dict:
        """The glTF JSON document: ``mesh`` on node 0 (``nodes``: all nodes, default the mesh
        node alone; ``scene_nodes``: the scene's roots, default ``[0]``; ``extra``: further
        top-level entries such as ``materials``, ``textures``, ``images``, ``samplers``)."""
        gltf = {
            "asset": {"version": "2.0", "generator": "bodyspace"},
            "scene": 0,
            "scenes": [{"nodes": [0] if scene_nodes is None else scene_nodes}],
            "nodes": [{"mesh": 0, "name": "body"}] if nodes is None else nodes,
            "meshes": [mesh],
            "buffers": [{"byteLength": self.bin_len}],
            "bufferViews": self.views,
            "accessors": self.accessors,
        }
        if skins:
            gltf["skins"] = skins
        if extra:
            gltf.update(extra)
        return gltf

    def frame(self, js: bytes) -> tuple[bytearray, int]:
        """A zeroed GLB buffer with its headers and the JSON chunk ``js`` (compact JSON, padded
        here with spaces) written; returns it and the offset of the binary chunk's data."""
        js = js + b" " * (-len(js) % 4)
        o = 28 + len(js)  # 12 (file header) + 8 (JSON chunk header) + JSON + 8 (BIN header)
        total = o + self.bin_len
        buf = bytearray(total)
        struct.pack_into("<IIIII", buf, 0, _GLTF_MAGIC, 2, total, len(js), _JSON)
        buf[20 : 20 + len(js)] = js
        struct.pack_into("<II", buf, o - 8, self.bin_len, _BIN)
        return buf, o


def triangle_indices(F: np.ndarray, n_vertices: int) -> tuple[np.ndarray, dict]:
    """The index block of triangles ``F`` ((m, 3), m >= 1) of a mesh of ``n_vertices``: the
    flat uint16 (uint32 from 65535 vertices) indices and their accessor (without view)."""
    if n_vertices < 65535:
        idx, ctype = np.ascontiguousarray(F, dtype=np.uint16).ravel(), 5123
    else:
        idx, ctype = np.ascontiguousarray(F, dtype=np.uint32).ravel(), 5125
    accessor = {
        "componentType": ctype,
        "count": int(idx.size),
        "type": "SCALAR",
        "min": [int(idx.min())],
        "max": [int(idx.max())],
    }
    return idx, accessor


def json_bytes(gltf: dict) -> bytes:
    """Compact UTF-8 JSON of a glTF document (unpadded)."""
    return json.dumps(gltf, separators=(",", ":")).encode("utf-8")


class FixedTopologyGlb:
    """GLB 2.0 encoder for meshes with ``n_vertices`` vertices and the triangles ``F``.

    Parameters
    ----------
    F : (m, 3) int triangles, indices in ``[0, n_vertices)``; m >= 1.
    n_vertices : number of vertices of every mesh to encode.

    Examples
    --------
    >>> enc = FixedTopologyGlb(template.F, 13380)      # once
    >>> data = enc.encode(V)                           # per body, (13380, 3) metres
    """

    def __init__(self, F: np.ndarray, n_vertices: int) -> None:
        F = np.asarray(F)
        n = int(n_vertices)
        if F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
            raise ValueError(f"F must have shape (m, 3) with m >= 1, got {F.shape}")
        if n <= 0:
            raise ValueError(f"n_vertices must be positive, got {n}")
        F = F.astype(np.int64)
        if F.min() < 0 or F.max() >= n:
            raise ValueError(f"F indexes vertices {int(F.min())}..{int(F.max())}, n_vertices {n}")
        m = len(F)
        self.n_vertices, self.n_faces = n, m
        self._f0, self._f1, self._f2 = (np.ascontiguousarray(F[:, c]) for c in range(3))
        # vertex normal = sum of the area-weighted normals of its faces, in face order (the CSR
        # columns are sorted, so each row sums in the same order as write_glb's bincount)
        ones = np.ones(3 * m)
        acc = sparse.csr_matrix((ones, (F.ravel(), np.repeat(np.arange(m), 3))), (n, m))
        acc.sum_duplicates()
        acc.sort_indices()
        self._acc = acc.astype(np.float32)
        idx, index = triangle_indices(F, n)
        self._idx = _pad4(idx.tobytes())
        vec = 12 * n  # float32 VEC3, a multiple of 4
        layout = GlbLayout()
        position = {"componentType": 5126, "count": n, "type": "VEC3", "min": _MIN, "max": _MAX}
        normal = {"componentType": 5126, "count": n, "type": "VEC3"}
        self._offsets = tuple(
            layout.add(nbytes, target, accessor)[1]
            for nbytes, target, accessor in (
                (vec, ARRAY_BUFFER, position),
                (vec, ARRAY_BUFFER, normal),
                (idx.nbytes, ELEMENT_ARRAY_BUFFER, index),
            )
        )
        prim = {"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2, "mode": 4}
        js = json_bytes(layout.document({"name": "body", "primitives": [prim]}))
        head, rest = js.split(f'"{_MIN}"'.encode())
        mid, tail = rest.split(f'"{_MAX}"'.encode())
        self._js = (head, mid, tail)
        self._layout = layout

    def normals(self, V: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(n, 3) float32 area-weighted unit vertex normals (``(0, 1, 0)`` where no area).

        Edge vectors are taken in float64 (coordinates of ~1 m, edges of a few mm: float32
        differences would lose 1e-3 of the direction), cross products and per-vertex sums in
        float32 (half the memory traffic), one coordinate at a time (contiguous arrays). Within
        1e-5 (measured ≤ 3.1e-6 on 200 bodies) of :func:`core.io._geometry.vertex_normals`.

        Parameters
        ----------
        V : (n, 3) vertices.
        out : optional (n, 3) float32 array to write into (e.g. a view of the GLB buffer).
        """
        VT = np.ascontiguousarray(np.asarray(V, dtype=np.float64).T)
        return self._normals(VT, out)

    def _normals(self, VT: np.ndarray, out: np.ndarray | None) -> np.ndarray:
        """:meth:`normals` of the (3, n) contiguous float64 transpose of ``V``."""
        if out is None:
            out = np.empty((self.n_vertices, 3), np.float32)
        f0, f1, f2 = self._f0, self._f1, self._f2
        e1, e2 = [], []
        for x in VT:  # x, y, z rows
            x0 = x.take(f0)
            e1.append((x.take(f1) - x0).astype(np.float32))
            e2.append((x.take(f2) - x0).astype(np.float32))
        (bx, by, bz), (cx, cy, cz) = e1, e2
        nx = self._acc @ (by * cz - bz * cy)
        ny = self._acc @ (bz * cx - bx * cz)
        nz = self._acc @ (bx * cy - by * cx)
        L = np.sqrt(nx * nx + ny * ny + nz * nz)
        ok = L > 1e-30  # False for NaN too
        if ok.all():
            out[:, 0], out[:, 1], out[:, 2] = nx / L, ny / L, nz / L
            return out
        N = np.stack([nx, ny, nz], axis=1)
        out[ok] = N[ok] / L[ok, None]
        out[~ok] = (0.0, 1.0, 0.0)
        return out

    def encode(self, V: np.ndarray) -> bytes:
        """The GLB of the mesh with vertices ``V`` ((n, 3), metres, +Y up) and normals.

        Raises
        ------
        InputFormatError
            ``V`` has the wrong shape or non-finite values.
        """
        return bytes(self.encode_buffer(V))

    def encode_buffer(self, V: np.ndarray) -> bytearray:
        """:meth:`encode` into a new ``bytearray``, without the final copy into ``bytes`` (a
        server can send ``memoryview(buffer)`` as it is)."""
        V = np.asarray(V, dtype=np.float64)
        n = self.n_vertices
        if V.shape != (n, 3):
            raise InputFormatError(f"V must have shape ({n}, 3), got {V.shape}")
        # one (3, n) copy serves min/max (a reduction over axis 0 of an (n, 3) array is ~10x
        # slower than over contiguous rows) and the edge vectors of the normals
        VT = np.ascontiguousarray(V.T)
        lo, hi = VT.min(axis=1), VT.max(axis=1)
        if not (np.isfinite(lo).all() and np.isfinite(hi).all()):  # NaN/inf reach min or max
            raise InputFormatError(
                f"V has {int((~np.isfinite(V).all(1)).sum())} non-finite vertices; cannot write"
            )
        # float32 rounding is monotonic, so the float32 of the min is the min of the float32s
        lo_s = json.dumps([float(np.float32(x)) for x in lo], separators=(",", ":"))
        hi_s = json.dumps([float(np.float32(x)) for x in hi], separators=(",", ":"))
        head, mid, tail = self._js
        buf, o = self._layout.frame(head + lo_s.encode() + mid + hi_s.encode() + tail)
        # positions and normals are written straight into the buffer (no temporaries)
        at_v, at_n, at_i = (o + x for x in self._offsets)
        np.frombuffer(buf, np.float32, 3 * n, at_v).reshape(n, 3)[:] = V
        self._normals(VT, np.frombuffer(buf, np.float32, 3 * n, at_n).reshape(n, 3))
        buf[at_i:] = self._idx
        return buf


# --------------------------------------------------------------------------------------------
# reading (scans delivered as GLB)

_COMPONENTS = {5120: "i1", 5121: "u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_NORM = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0}
# required extensions we read (quantized accessors, texture transforms) or may ignore (looks)
_SUPPORTED = {
    "KHR_mesh_quantization",
    "KHR_texture_transform",
    "KHR_materials_unlit",
    "KHR_materials_emissive_strength",
    "KHR_materials_ior",
}
MAX_JSON_BYTES = 64 << 20
MAX_ZERO_ELEMENTS = 50_000_000  # elements of an accessor without data (all zeros)


@dataclass
class GlbPrimitive:
    """One triangle (or point) primitive of a GLB in world coordinates.

    Attributes
    ----------
    V : (n, 3) float64 positions (node transforms applied). F : (m, 3) int64 or None (points).
    normals : (n, 3) or None. colors : (n, 3) float64 in [0, 1] (``COLOR_0`` times the
    material's ``baseColorFactor``) or None. uv : (n, 2) float64 texture coordinates of the base
    colour texture (glTF convention) or None. image : the base colour texture's encoded bytes
    (PNG/JPEG) or None.
    """

    V: np.ndarray
    F: np.ndarray | None
    normals: np.ndarray | None = None
    colors: np.ndarray | None = None
    uv: np.ndarray | None = None
    image: bytes | None = None
    factor: np.ndarray | None = None  # (3,) baseColorFactor RGB


class _Glb:
    """A parsed GLB container: its JSON document and binary chunk, with bounds-checked
    accessor reads. Every failure is an :class:`InputFormatError` naming ``what``."""

    def __init__(self, data: bytes, what: str) -> None:
        self.what = what
        bad = f"{what}: not a valid GLB file"
        if len(data) < 20 or data[:4] != b"glTF":
            raise InputFormatError(f"{bad} (no 'glTF' magic)")
        _, version, length = struct.unpack_from("<III", data, 0)
        if version != 2:
            raise InputFormatError(f"{what}: GLB version {version}; only glTF 2.0 is supported")
        if length > len(data):
            raise InputFormatError(f"{bad}: header says {length:,} bytes, file has {len(data):,}")
        jlen, jtype = struct.unpack_from("<II", data, 12)
        if jtype != _JSON or 20 + jlen > length or jlen > MAX_JSON_BYTES:
            raise InputFormatError(f"{bad}: the first chunk must be a JSON chunk within the file")
        try:
            self.doc = json.loads(bytes(data[20 : 20 + jlen]))
        except (ValueError, UnicodeDecodeError):
            raise InputFormatError(f"{bad}: its JSON chunk does not parse") from None
        if not isinstance(self.doc, dict):
            raise InputFormatError(f"{bad}: its JSON chunk is not an object")
        self.bin = memoryview(b"")
        o = 20 + jlen + (-jlen % 4)
        if o + 8 <= length:
            blen, btype = struct.unpack_from("<II", data, o)
            if btype == _BIN:
                if o + 8 + blen > length:
                    raise InputFormatError(f"{bad}: its binary chunk runs past the end")
                self.bin = memoryview(data)[o + 8 : o + 8 + blen]
        required = set(self.doc.get("extensionsRequired") or ()) - _SUPPORTED
        if required:
            raise InputFormatError(
                f"{what}: the GLB requires the extension(s) {', '.join(sorted(required))}, "
                "which bodyspace does not read (e.g. Draco or meshopt compression); export it "
                "without compression",
                extensions=sorted(required),
            )

    def _get(self, key: str, i: Any) -> dict:
        items = self.doc.get(key)
        if not isinstance(i, int) or not isinstance(items, list) or not 0 <= i < len(items):
            raise InputFormatError(f"{self.what}: GLB refers to {key}[{i!r}], which is missing")
        item = items[i]
        if not isinstance(item, dict):
            raise InputFormatError(f"{self.what}: GLB {key}[{i}] is not an object")
        return item

    def view_bytes(self, i: int) -> memoryview:
        view = self._get("bufferViews", i)
        if view.get("buffer", 0) != 0 or "uri" in self._get("buffers", view.get("buffer", 0)):
            raise InputFormatError(
                f"{self.what}: GLB data in external buffers is not supported; embed them "
                "(export as a single .glb)"
            )
        off, n = view.get("byteOffset", 0), view.get("byteLength")
        if not isinstance(off, int) or not isinstance(n, int) or off < 0 or n < 0:
            raise InputFormatError(f"{self.what}: GLB bufferViews[{i}] is malformed")
        if off + n > len(self.bin):
            raise InputFormatError(f"{self.what}: GLB bufferViews[{i}] runs past the data")
        return self.bin[off : off + n]

    def count(self, i: int) -> int:
        n = self._get("accessors", i).get("count")
        if not isinstance(n, int) or n < 0:
            raise InputFormatError(f"{self.what}: GLB accessors[{i}] has no valid count")
        return n

    def accessor(self, i: int, types: tuple[str, ...], count: int | None = None) -> np.ndarray:
        """(count, width) float64 (normalised integers scaled) or int64 values of accessor i
        (``count``: the number of elements it must have, checked before reading)."""
        acc = self._get("accessors", i)
        ctype, typ, n = acc.get("componentType"), acc.get("type"), self.count(i)
        if ctype not in _COMPONENTS or typ not in types:
            raise InputFormatError(
                f"{self.what}: GLB accessors[{i}] has type {typ!r}/{ctype!r}; expected {types}"
            )
        if count is not None and n != count:
            raise InputFormatError(
                f"{self.what}: GLB accessors[{i}] has {n:,} elements; the primitive has {count:,}"
            )
        if "bufferView" not in acc and n > MAX_ZERO_ELEMENTS:
            raise InputFormatError(f"{self.what}: GLB accessors[{i}] is too large")
        if "sparse" in acc:
            raise InputFormatError(f"{self.what}: GLB sparse accessors are not supported")
        dt = np.dtype(_COMPONENTS[ctype])
        k = _WIDTH[typ]
        if "bufferView" not in acc:
            out = np.zeros((n, k))
        else:
            raw = self.view_bytes(acc["bufferView"])
            view = self._get("bufferViews", acc["bufferView"])
            off = acc.get("byteOffset", 0)
            stride = view.get("byteStride") or dt.itemsize * k
            if not isinstance(off, int) or not isinstance(stride, int) or off < 0 or stride <= 0:
                raise InputFormatError(f"{self.what}: GLB accessors[{i}] is malformed")
            if n and off + stride * (n - 1) + dt.itemsize * k > len(raw):
                raise InputFormatError(f"{self.what}: GLB accessors[{i}] runs past its view")
            if n == 0:
                return np.zeros((0, k))
            out = np.ndarray((n, k), dt, raw, off, (stride, dt.itemsize)).copy()
        if dt.kind == "f":
            return out.astype(np.float64)
        if acc.get("normalized"):
            return np.maximum(out / _NORM[ctype], -1.0)
        return out.astype(np.int64)


def _node_matrix(node: dict) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    if "matrix" in node:
        M = np.asarray(node["matrix"], dtype=np.float64)
        if M.shape != (16,) or not np.isfinite(M).all():
            raise InputFormatError("GLB node matrix must be 16 finite numbers")
        return M.reshape(4, 4).T  # column-major
    M = np.eye(4)
    t = np.asarray(node.get("translation", (0, 0, 0)), dtype=np.float64)
    q = np.asarray(node.get("rotation", (0, 0, 0, 1)), dtype=np.float64)
    s = np.asarray(node.get("scale", (1, 1, 1)), dtype=np.float64)
    if t.shape != (3,) or q.shape != (4,) or s.shape != (3,) or not np.isfinite([*t, *q, *s]).all():
        raise InputFormatError("GLB node translation/rotation/scale are malformed")
    R = Rotation.from_quat(q).as_matrix() if np.linalg.norm(q) > 0 else np.eye(3)
    M[:3, :3] = R * s
    M[:3, 3] = t
    return M


def _instances(g: _Glb) -> list[tuple[int, np.ndarray]]:
    """(mesh index, world matrix) of every mesh instance of the default scene."""
    doc = g.doc
    nodes = doc.get("nodes") or []
    scenes = doc.get("scenes") or []
    if scenes:
        roots = g._get("scenes", doc.get("scene", 0)).get("nodes") or []
    else:  # no scene: every node that is nobody's child
        kids = {c for n in nodes if isinstance(n, dict) for c in n.get("children") or ()}
        roots = [i for i in range(len(nodes)) if i not in kids]
    out: list[tuple[int, np.ndarray]] = []
    stack = [(r, np.eye(4)) for r in roots]
    seen = 0
    while stack:
        i, parent = stack.pop()
        seen += 1
        if seen > 100_000:
            raise InputFormatError(f"{g.what}: GLB node hierarchy is cyclic or too large")
        node = g._get("nodes", i)
        M = parent @ _node_matrix(node)
        if "mesh" in node:
            out.append((node["mesh"], M))
        stack.extend((c, M) for c in node.get("children") or ())
    if not out and not scenes and doc.get("meshes"):
        out = [(m, np.eye(4)) for m in range(len(doc["meshes"]))]
    return out


def _uv_transform(info: dict) -> np.ndarray | None:
    """The (3, 3) UV matrix of a texture info's ``KHR_texture_transform`` (None without one):
    ``T(offset) R(rotation) S(scale)`` as the extension defines it."""
    ext = (info.get("extensions") or {}).get("KHR_texture_transform")
    if not isinstance(ext, dict):
        return None
    try:
        ox, oy = (float(x) for x in ext.get("offset", (0.0, 0.0)))
        sx, sy = (float(x) for x in ext.get("scale", (1.0, 1.0)))
        r = float(ext.get("rotation", 0.0))
    except (TypeError, ValueError):
        raise InputFormatError("GLB KHR_texture_transform is malformed") from None
    c, s = np.cos(r), np.sin(r)
    T = np.array([[1.0, 0.0, ox], [0.0, 1.0, oy], [0.0, 0.0, 1.0]])
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])  # counter-clockwise
    return T @ R @ np.diag([sx, sy, 1.0])


def _image_bytes(g: _Glb, material: dict) -> tuple[bytes | None, int, np.ndarray | None]:
    """The base colour texture's encoded bytes, its texCoord set and its UV transform (None,
    0, None when untextured)."""
    import base64

    tex = (material.get("pbrMetallicRoughness") or {}).get("baseColorTexture")
    if not isinstance(tex, dict):
        return None, 0, None
    texture = g._get("textures", tex.get("index"))
    source = texture.get("source")
    if source is None:
        return None, 0, None
    img = g._get("images", source)
    M = _uv_transform(tex)
    tc = (tex.get("extensions") or {}).get("KHR_texture_transform", {}).get("texCoord")
    tc = int(tex.get("texCoord", 0) if tc is None else tc)
    if "bufferView" in img:
        return bytes(g.view_bytes(img["bufferView"])), tc, M
    uri = img.get("uri", "")
    if isinstance(uri, str) and uri.startswith("data:") and ";base64," in uri:
        try:
            return base64.b64decode(uri.split(",", 1)[1], validate=True), tc, M
        except ValueError:
            raise InputFormatError(f"{g.what}: GLB image data URI is not valid base64") from None
    raise InputFormatError(
        f"{g.what}: the GLB's base colour texture is an external file ({str(uri)[:80]!r}); "
        "embed the texture in the GLB"
    )


def read_glb_primitives(
    data: bytes,
    what: str = "uploaded scan",
    *,
    max_vertices: int | None = None,
    max_faces: int | None = None,
) -> list[GlbPrimitive]:
    """The triangle and point primitives of a GLB's default scene, in world coordinates.

    Counts are checked against the limits from the accessors' declared counts before any data
    are read. Triangle strips and fans are refused (exporters write lists).

    Raises
    ------
    InputFormatError
        Not a GLB, malformed or out-of-range references, required extensions (e.g. Draco),
        external buffers or images, counts above the limits, no mesh.
    """
    g = _Glb(data, what)
    inst = _instances(g)
    prims = [(g._get("meshes", m).get("primitives") or [], M) for m, M in inst]
    nv = nf = 0
    for ps, _ in prims:
        for p in ps:
            attrs = p.get("attributes") or {}
            if "POSITION" not in attrs:
                continue
            nv += g.count(attrs["POSITION"])
            nf += g.count(p["indices"]) // 3 if "indices" in p else 0
    if max_vertices is not None and nv > max_vertices:
        raise InputFormatError(
            f"{what} has {nv:,} vertices, above the limit of {max_vertices:,}; decimate the scan",
            n_vertices=nv,
            limit=max_vertices,
        )
    if max_faces is not None and nf > max_faces:
        raise InputFormatError(
            f"{what} has {nf:,} faces, above the limit of {max_faces:,}; decimate the scan",
            n_faces=nf,
            limit=max_faces,
        )
    out: list[GlbPrimitive] = []
    for ps, M in prims:
        for p in ps:
            attrs = p.get("attributes") or {}
            mode = p.get("mode", 4)
            if "POSITION" not in attrs or mode not in (0, 4):
                if "POSITION" in attrs and mode not in (1, 2, 3):  # lines are not surfaces
                    raise InputFormatError(
                        f"{what}: GLB primitive mode {mode!r} (triangle strips/fans) is not "
                        "supported; export triangle lists"
                    )
                continue
            V = g.accessor(attrs["POSITION"], ("VEC3",))
            n = len(V)
            V = V @ M[:3, :3].T + M[:3, 3]
            F = None
            if mode == 4:
                idx = (
                    g.accessor(p["indices"], ("SCALAR",)).ravel()
                    if "indices" in p
                    else np.arange(n - n % 3)
                )
                if idx.dtype.kind == "f" or len(idx) % 3:
                    raise InputFormatError(f"{what}: GLB triangle indices are malformed")
                if len(idx) and (idx.min() < 0 or idx.max() >= n):
                    raise InputFormatError(f"{what}: GLB triangle index out of range")
                F = idx.reshape(-1, 3).astype(np.int64)
            normals = None
            if "NORMAL" in attrs:
                Minv = np.linalg.inv(M[:3, :3]).T if abs(np.linalg.det(M[:3, :3])) > 1e-30 else None
                if Minv is not None:
                    normals = g.accessor(attrs["NORMAL"], ("VEC3",), n) @ Minv.T
            material = g._get("materials", p["material"]) if "material" in p else {}
            pbr = material.get("pbrMetallicRoughness") or {}
            factor = np.asarray(pbr.get("baseColorFactor", (1, 1, 1, 1)), dtype=np.float64)
            if factor.shape != (4,) or not np.isfinite(factor).all():
                raise InputFormatError(f"{what}: GLB baseColorFactor is malformed")
            colors = None
            if "COLOR_0" in attrs:
                colors = g.accessor(attrs["COLOR_0"], ("VEC3", "VEC4"), n)[:, :3].clip(0, 1)
            image, tc, uvm = _image_bytes(g, material)
            uv = None
            if image is not None:
                key = f"TEXCOORD_{tc}"
                if key not in attrs:
                    raise InputFormatError(f"{what}: GLB textured primitive has no {key}")
                uv = g.accessor(attrs[key], ("VEC2",), n)
                if uvm is not None:
                    uv = uv @ uvm[:2, :2].T + uvm[:2, 2]
            out.append(GlbPrimitive(V, F, normals, colors, uv, image, factor[:3]))
    if not out:
        raise InputFormatError(f"{what}: the GLB has no triangle or point mesh")
    return out


def glb_counts(data: bytes, what: str = "uploaded scan") -> tuple[int, int, bool]:
    """(vertices, triangles, has normals) of a GLB's default scene from its accessors' counts
    (no data read): for cheap upload checks."""
    g = _Glb(data, what)
    nv = nf = 0
    normals = False
    for m, _ in _instances(g):
        for p in g._get("meshes", m).get("primitives") or []:
            attrs = p.get("attributes") or {}
            if "POSITION" in attrs:
                nv += g.count(attrs["POSITION"])
                nf += g.count(p["indices"]) // 3 if "indices" in p else 0
                normals = normals or "NORMAL" in attrs
    return nv, nf, normals
