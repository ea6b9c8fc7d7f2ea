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
"""

from __future__ import annotations

import json
import struct

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
