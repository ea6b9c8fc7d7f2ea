"""Mesh writers: PLY (binary or ASCII), OBJ and binary glTF 2.0 (GLB).

Coordinates are written as given (bodyspace writes metres, +Y up, which are glTF's axes, so a
GLB needs no conversion). Every write is atomic: a temporary file in the destination folder is
written, flushed and then renamed over the target with ``os.replace``.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from core.errors import InputFormatError
from core.io._geometry import normalize, vertex_normals
from core.io.glb import (
    ARRAY_BUFFER,
    ELEMENT_ARRAY_BUFFER,
    GlbLayout,
    json_bytes,
    triangle_indices,
)

PathLike = str | os.PathLike


def atomic_write(path: PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temp file in the same folder, then os.replace)."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=folder)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _check(V, F, normals=None, confidence=None, colors=None):
    V = np.asarray(V, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3:
        raise InputFormatError(f"V must have shape (n, 3), got {V.shape}")
    if not np.isfinite(V).all():
        raise InputFormatError(
            f"V has {int((~np.isfinite(V).all(1)).sum())} non-finite vertices; cannot write"
        )
    n = len(V)
    if F is not None:
        F = np.asarray(F)
        if F.ndim != 2 or F.shape[1] != 3:
            raise InputFormatError(f"F must have shape (m, 3), got {F.shape}")
        F = F.astype(np.int64)
        if len(F) and (F.min() < 0 or F.max() >= n):
            raise InputFormatError(
                f"F indexes vertices {int(F.min())}..{int(F.max())} but V has {n} vertices"
            )
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float64)
        if normals.shape != (n, 3):
            raise InputFormatError(f"normals must have shape ({n}, 3), got {normals.shape}")
    if confidence is not None:
        confidence = np.asarray(confidence, dtype=np.float64)
        if confidence.shape != (n,):
            raise InputFormatError(f"confidence must have shape ({n},), got {confidence.shape}")
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != (n, 3):
            raise InputFormatError(f"colors must have shape ({n}, 3), got {colors.shape}")
        if colors.dtype.kind == "f":
            colors = np.round(np.clip(colors, 0, 1) * 255)
        colors = np.clip(colors, 0, 255).astype(np.uint8)
    return V, F, normals, confidence, colors


def write_ply(
    path: PathLike,
    V: np.ndarray,
    F: np.ndarray | None,
    *,
    normals: np.ndarray | None = None,
    confidence: np.ndarray | None = None,
    colors: np.ndarray | None = None,
    binary: bool = True,
) -> None:
    """Write a PLY file (binary little-endian by default, or ASCII).

    Parameters
    ----------
    path : output file.
    V : (n, 3) vertices (written as double).
    F : (m, 3) triangles, or None for a point cloud.
    normals : (n, 3) optional (float). confidence : (n,) optional (float, property
        ``confidence``). colors : (n, 3) optional uint8 RGB (or floats in [0, 1]).
    binary : bool, binary_little_endian when True, else ascii.
    """
    V, F, normals, confidence, colors = _check(V, F, normals, confidence, colors)
    n = len(V)
    fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    props = ["property double x", "property double y", "property double z"]
    if normals is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
        props += ["property float nx", "property float ny", "property float nz"]
    if confidence is not None:
        fields += [("confidence", "<f4")]
        props += ["property float confidence"]
    if colors is not None:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
        props += ["property uchar red", "property uchar green", "property uchar blue"]
    m = 0 if F is None else len(F)
    header = [
        "ply",
        f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
        "comment bodyspace",
        f"element vertex {n}",
        *props,
    ]
    if F is not None:
        header += [f"element face {m}", "property list uchar int vertex_indices"]
    header.append("end_header")
    head = ("\n".join(header) + "\n").encode("ascii")
    vrec = np.zeros(n, dtype=fields)
    vrec["x"], vrec["y"], vrec["z"] = V[:, 0], V[:, 1], V[:, 2]
    if normals is not None:
        vrec["nx"], vrec["ny"], vrec["nz"] = normals[:, 0], normals[:, 1], normals[:, 2]
    if confidence is not None:
        vrec["confidence"] = confidence
    if colors is not None:
        vrec["red"], vrec["green"], vrec["blue"] = colors[:, 0], colors[:, 1], colors[:, 2]
    if binary:
        parts = [head, vrec.tobytes()]
        if F is not None:
            frec = np.zeros(m, dtype=[("c", "u1"), ("i", "<i4", (3,))])
            frec["c"] = 3
            frec["i"] = F
            parts.append(frec.tobytes())
        atomic_write(path, b"".join(parts))
        return
    cols, fmts = [V], ["%.17g %.17g %.17g"]
    if normals is not None:
        cols.append(normals.astype(np.float32).astype(np.float64))
        fmts.append("%.9g %.9g %.9g")
    if confidence is not None:
        cols.append(confidence.astype(np.float32).astype(np.float64)[:, None])
        fmts.append("%.9g")
    if colors is not None:
        cols.append(colors.astype(np.float64))
        fmts.append("%d %d %d")
    table = np.concatenate(cols, axis=1)
    line = " ".join(fmts) + "\n"
    body = (line * n) % tuple(table.ravel()) if n else ""
    if F is not None and m:
        body += ("3 %d %d %d\n" * m) % tuple(F.ravel())
    atomic_write(path, head + body.encode("ascii"))


def write_obj(
    path: PathLike,
    V: np.ndarray,
    F: np.ndarray | None,
    *,
    normals: np.ndarray | None = None,
    uv: np.ndarray | None = None,
    FT: np.ndarray | None = None,
    mtllib: str | None = None,
    material: str = "skin",
) -> None:
    """Write a Wavefront OBJ (``v``, optional ``vn``/``vt``, ``f`` with 1-based indices).

    Parameters
    ----------
    path : output file. V : (n, 3) vertices. F : (m, 3) triangles or None.
    normals : (n, 3) optional per-vertex normals (faces then use ``v//vn``).
    uv, FT : (k, 2) texture coordinates in glTF's convention (written as OBJ ``vt``, v up) and
        (m, 3) their indices per face corner (faces then use ``v/vt``); not with ``normals``.
    mtllib, material : the material library and the material the faces use (``usemtl``).
    """
    V, F, normals, _, _ = _check(V, F, normals)
    n = len(V)
    out = ["# bodyspace\n"]
    if mtllib is not None:
        out.append(f"mtllib {mtllib}\n")
    if n:
        out.append(("v %.17g %.17g %.17g\n" * n) % tuple(V.ravel()))
    if normals is not None and n:
        out.append(("vn %.9g %.9g %.9g\n" * n) % tuple(normalize(normals).ravel()))
    if uv is not None:
        if normals is not None or F is None or FT is None or np.shape(FT) != F.shape:
            raise InputFormatError("uv needs F and FT of the same shape, and no normals")
        vt = np.asarray(uv, dtype=np.float64) * [1.0, -1.0] + [0.0, 1.0]  # OBJ: v up
        out.append(("vt %.9g %.9g\n" * len(vt)) % tuple(vt.ravel()))
    if mtllib is not None:
        out.append(f"usemtl {material}\n")
    if F is not None and len(F):
        F1 = F + 1
        if uv is not None:
            corners = np.stack([F1, np.asarray(FT, dtype=np.int64) + 1], axis=2).reshape(-1)
            out.append(("f %d/%d %d/%d %d/%d\n" * len(F)) % tuple(corners))
        elif normals is not None:
            out.append(("f %d//%d %d//%d %d//%d\n" * len(F)) % tuple(np.repeat(F1, 2, 1).ravel()))
        else:
            out.append(("f %d %d %d\n" * len(F)) % tuple(F1.ravel()))
    atomic_write(path, "".join(out).encode("ascii"))


@dataclass(frozen=True)
class GlbMorphTarget:
    """One glTF morph target: per-vertex displacements from the base mesh.

    Attributes
    ----------
    name : the target's name (written to ``mesh.extras.targetNames``).
    delta_positions : (n, 3) position deltas, metres.
    delta_normals : (n, 3) normal deltas (unit target normals minus unit base normals), or None.
    """

    name: str
    delta_positions: np.ndarray
    delta_normals: np.ndarray | None = None


@dataclass(frozen=True)
class GlbSkin:
    """A glTF skin: a joint hierarchy in its rest (bind) pose and per-vertex influences.

    Attributes
    ----------
    names : J joint names.
    parents : (J,) int parent index (``parents[j] < j``), -1 for a root.
    joints : (J, 3) rest joint positions (world = mesh frame), metres; joints carry no rotation
        in the bind pose, so inverse bind matrices are translations by ``-joints``.
    joint_index : (n, 4) int joint indices per vertex (``JOINTS_0``), < 65536.
    weights : (n, 4) float weights per vertex (``WEIGHTS_0``); rows sum to 1.
    """

    names: Sequence[str]
    parents: np.ndarray
    joints: np.ndarray
    joint_index: np.ndarray
    weights: np.ndarray


def _skin_weights_f32(w: np.ndarray) -> np.ndarray:
    """(n, 4) float32 weights summing to 1 in float32 (the residual goes to the largest)."""
    w = np.asarray(w, dtype=np.float64)
    w = w / w.sum(axis=1, keepdims=True)
    w32 = w.astype(np.float32)
    top = np.argmax(w32, axis=1)
    rows = np.arange(len(w32))
    others = w32.sum(axis=1, dtype=np.float32) - w32[rows, top]
    w32[rows, top] = np.float32(1.0) - others
    return w32


def _float_accessor(a32: np.ndarray, type_: str) -> dict:
    """The accessor (without view) of float32 rows ``a32`` with their ``min``/``max``."""
    return {
        "componentType": 5126,
        "count": len(a32),
        "type": type_,
        "min": [float(v) for v in a32.min(axis=0)],
        "max": [float(v) for v in a32.max(axis=0)],
    }


def write_glb(
    path_or_none: PathLike | None,
    V: np.ndarray,
    F: np.ndarray | None,
    *,
    normals: np.ndarray | None = None,
    colors: np.ndarray | None = None,
    targets: Sequence[GlbMorphTarget] = (),
    skin: GlbSkin | None = None,
    texcoords: np.ndarray | None = None,
    texture_png: bytes | None = None,
) -> bytes:
    """Encode (and optionally write) a binary glTF 2.0 file with one mesh and one primitive.

    Laid out by :class:`core.io.glb.GlbLayout`, as the cached encoder of bodies
    (:class:`core.io.glb.FixedTopologyGlb`): the same file for the same mesh.

    Parameters
    ----------
    path_or_none : output file, or None to only return the bytes.
    V : (n, 3) vertices, metres, +Y up (glTF's frame; no conversion is done).
    F : (m, 3) triangles, or None for a point primitive.
    normals : (n, 3) optional; computed (area-weighted) when not given; written unit length.
    colors : (n, 3) optional uint8 RGB (or floats in [0, 1]), written as normalised RGBA bytes.
    targets : morph targets (POSITION and, when given, NORMAL deltas); their names go to
        ``mesh.extras.targetNames``, their default weights are 0.
    skin : joints and per-vertex influences: the mesh node is skinned by a joint hierarchy
        (one node per joint, translations only) under the scene's root.
    texcoords : (n, 2) texture coordinates (``TEXCOORD_0``, glTF convention: origin at the
        image's top-left), given together with ``texture_png``.
    texture_png : PNG bytes embedded as the material's ``baseColorTexture`` (a matte,
        non-metallic, double-sided material; linear filtering, mipmaps, clamped edges). glTF
        multiplies the texture by ``COLOR_0``, so give ``colors`` or a texture, not both.

    Returns
    -------
    bytes
        The GLB file content.
    """
    V, F, normals, _, colors = _check(V, F, normals, None, colors)
    n = len(V)
    if n == 0:
        raise InputFormatError("cannot write a GLB without vertices")
    N = vertex_normals(V, F) if normals is None else normalize(normals)
    pos = V.astype(np.float32)
    layout = GlbLayout()
    blocks: list[tuple[int, np.ndarray]] = []  # (offset in the binary chunk, data)

    def add(data: np.ndarray, target: int, acc: dict) -> int:
        data = np.ascontiguousarray(data)
        index, offset = layout.add(data.nbytes, target, acc)
        blocks.append((offset, data))
        return index

    attrs = {
        "POSITION": add(pos, ARRAY_BUFFER, _float_accessor(pos, "VEC3")),
        "NORMAL": add(
            normalize(N.astype(np.float32).astype(np.float64)).astype(np.float32),
            ARRAY_BUFFER,
            {"componentType": 5126, "count": n, "type": "VEC3"},
        ),
    }
    if colors is not None:
        rgba = np.concatenate([colors, np.full((n, 1), 255, np.uint8)], axis=1)
        attrs["COLOR_0"] = add(
            rgba,
            ARRAY_BUFFER,
            {"componentType": 5121, "normalized": True, "count": n, "type": "VEC4"},
        )
    extra: dict = {}
    if (texcoords is None) != (texture_png is None):
        raise InputFormatError("give texcoords and texture_png together")
    if texture_png is not None:
        if colors is not None:
            raise InputFormatError("give colors or a texture, not both (glTF multiplies them)")
        uv = np.asarray(texcoords, dtype=np.float64)
        if uv.shape != (n, 2) or not np.isfinite(uv).all():
            raise InputFormatError(f"texcoords must be finite ({n}, 2), got {uv.shape}")
        uv32 = uv.astype(np.float32)
        attrs["TEXCOORD_0"] = add(uv32, ARRAY_BUFFER, _float_accessor(uv32, "VEC2"))
        png = np.frombuffer(bytes(texture_png), np.uint8)
        view, offset = layout.add_view(png.nbytes)
        blocks.append((offset, png))
        extra = {
            "materials": [
                {
                    "name": "skin",
                    "pbrMetallicRoughness": {
                        "baseColorTexture": {"index": 0},
                        "metallicFactor": 0.0,
                        "roughnessFactor": 1.0,
                    },
                    "doubleSided": True,
                }
            ],
            "textures": [{"sampler": 0, "source": 0}],
            "samplers": [{"magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071}],
            "images": [{"bufferView": view, "mimeType": "image/png"}],
        }
    prim: dict = {"attributes": attrs}
    if extra:
        prim["material"] = 0
    if F is not None and len(F):
        idx, index = triangle_indices(F, n)
        prim["indices"] = add(idx, ELEMENT_ARRAY_BUFFER, index)
        prim["mode"] = 4
    else:
        prim["mode"] = 0
    mesh: dict = {"name": "body", "primitives": [prim]}
    if targets:
        prim["targets"] = []
        for tg in targets:
            dV = np.asarray(tg.delta_positions, dtype=np.float64)
            if dV.shape != (n, 3) or not np.isfinite(dV).all():
                raise InputFormatError(
                    f"morph target {tg.name!r}: delta_positions must be finite ({n}, 3)"
                )
            d32 = dV.astype(np.float32)
            ta = {"POSITION": add(d32, ARRAY_BUFFER, _float_accessor(d32, "VEC3"))}
            if tg.delta_normals is not None:
                dN = np.asarray(tg.delta_normals, dtype=np.float64)
                if dN.shape != (n, 3) or not np.isfinite(dN).all():
                    raise InputFormatError(
                        f"morph target {tg.name!r}: delta_normals must be finite ({n}, 3)"
                    )
                ta["NORMAL"] = add(
                    dN.astype(np.float32),
                    ARRAY_BUFFER,
                    {"componentType": 5126, "count": n, "type": "VEC3"},
                )
            prim["targets"].append(ta)
        mesh["weights"] = [0.0] * len(targets)
        mesh["extras"] = {"targetNames": [str(tg.name) for tg in targets]}
    nodes: list[dict] = [{"mesh": 0, "name": "body"}]
    scene_nodes = [0]
    skins: list[dict] = []
    if skin is not None:
        J = len(skin.names)
        parents = np.asarray(skin.parents, dtype=np.int64)
        joints = np.asarray(skin.joints, dtype=np.float64)
        ji = np.asarray(skin.joint_index)
        if parents.shape != (J,) or joints.shape != (J, 3) or ji.shape != (n, 4):
            raise InputFormatError(
                f"skin: parents ({J},), joints ({J}, 3) and joint_index ({n}, 4) expected, got "
                f"{parents.shape}, {joints.shape}, {ji.shape}"
            )
        if (parents >= np.arange(J)).any() or (parents < -1).any():
            raise InputFormatError("skin: every parent must come before its child")
        if ji.min() < 0 or ji.max() >= J:
            raise InputFormatError(f"skin: joint_index must lie in [0, {J})")
        w32 = _skin_weights_f32(skin.weights)
        ji = np.where(w32 > 0, ji, 0)  # glTF: unused influences point at joint 0 with weight 0
        prim["attributes"]["JOINTS_0"] = add(
            ji.astype(np.uint16),
            ARRAY_BUFFER,
            {"componentType": 5123, "count": n, "type": "VEC4"},
        )
        prim["attributes"]["WEIGHTS_0"] = add(
            w32, ARRAY_BUFFER, {"componentType": 5126, "count": n, "type": "VEC4"}
        )
        ibm = np.zeros((J, 4, 4), np.float32)
        ibm[:, [0, 1, 2, 3], [0, 1, 2, 3]] = 1.0
        ibm[:, 3, :3] = -joints  # column-major: the translation is the last column
        ibm_acc = add(ibm.reshape(J, 16), 0, {"componentType": 5126, "count": J, "type": "MAT4"})
        first = len(nodes)
        for j in range(J):
            p = parents[j]
            local = joints[j] - (joints[p] if p >= 0 else 0.0)
            node: dict = {"name": str(skin.names[j]), "translation": [float(x) for x in local]}
            kids = (np.flatnonzero(parents == j) + first).tolist()
            if kids:
                node["children"] = kids
            nodes.append(node)
        roots = (np.flatnonzero(parents < 0) + first).tolist()
        nodes[0]["skin"] = 0
        scene_nodes += roots
        skins.append({"inverseBindMatrices": ibm_acc, "joints": list(range(first, first + J))})
        if len(roots) == 1:
            skins[0]["skeleton"] = roots[0]
    doc = layout.document(mesh, nodes=nodes, scene_nodes=scene_nodes, skins=skins, extra=extra)
    buf, o = layout.frame(json_bytes(doc))
    for offset, data in blocks:
        np.frombuffer(buf, np.uint8, data.nbytes, o + offset)[:] = data.reshape(-1).view(np.uint8)
    out = bytes(buf)
    if path_or_none is not None:
        atomic_write(path_or_none, out)
    return out


def write_mesh(path: PathLike, V: np.ndarray, F: np.ndarray | None, **kw) -> None:
    """Write by extension: ``.ply`` (:func:`write_ply`), ``.obj`` or ``.glb``.

    Keyword arguments are passed on (``normals``, ``confidence``, ``colors``, ``binary``);
    those a format cannot store are ignored.
    """
    ext = Path(path).suffix.lower()
    if ext == ".ply":
        allowed = {"normals", "confidence", "colors", "binary"}
        write_ply(path, V, F, **{k: v for k, v in kw.items() if k in allowed})
    elif ext == ".obj":
        write_obj(path, V, F, normals=kw.get("normals"))
    elif ext == ".glb":
        write_glb(path, V, F, normals=kw.get("normals"), colors=kw.get("colors"))
    else:
        raise InputFormatError(
            f"cannot write {Path(path).name!r}: unknown extension {ext!r}; use .ply, .obj or .glb"
        )
