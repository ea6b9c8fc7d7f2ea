"""Readers for raw body scans: PLY, OBJ, STL, NPZ and XYZ/PTS point clouds.

All readers return a :class:`core.scan.RawMesh` in the file's own units and axes. Parsing is
vectorised (``np.frombuffer`` for binary data, one C-level float parse for text), so a 1 M-vertex
binary PLY reads in a fraction of a second.

Decisions
---------
- **Non-finite coordinates** (NaN/Inf) are rejected with :class:`InputFormatError` naming how
  many vertices are affected and the first one; nothing is silently dropped.
- **Confidence** must lie in [0, 1]; values outside by at most 1e-6 (round-off) are clipped,
  anything further out (or NaN) is an :class:`InputFormatError` asking to rescale the property.
  A PLY ``quality`` property (MeshLab's per-vertex scalar of any meaning: curvature, Poisson
  density, scanner intensity) is read as confidence only when it lies in [0, 1], else ignored.
- **Polygons** of any size are fan-triangulated ``(0, i, i+1)``; faces with < 3 corners are
  dropped. A PLY ``tristrips`` element (strips separated by -1) adds its triangles.
- **Limits** (``max_vertices``, ``max_faces``) are checked from the header (PLY, binary STL, NPZ)
  before the data are parsed, and from line counts for text formats.
- **NPZ** inflates nothing unchecked: only the scan's arrays (``vertices``, ``faces``,
  ``normals``, ``confidence``, ``colors`` and their aliases) are allowed, each member's ``.npy``
  header (shape x dtype) is checked against the limits and against the member's declared size
  before any data are read, and exactly that many bytes are inflated; any other member is refused.
- **Names**: ``name=`` says what messages call the file (an upload's filename, never a server
  path).
"""

from __future__ import annotations

import functools
import io
import os
import re
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from core.errors import InputFormatError
from core.io.images import MAX_TEXTURE_PIXELS
from core.scan import RawMesh, ScanTexture

Source = str | os.PathLike | bytes | bytearray | memoryview

FORMATS = ("ply", "obj", "stl", "npz", "xyz", "pts", "glb", "zip")
_EXT = {
    ".ply": "ply",
    ".obj": "obj",
    ".glb": "glb",
    ".zip": "zip",
    ".stl": "stl",
    ".npz": "npz",
    ".xyz": "xyz",
    ".pts": "pts",
    ".txt": "xyz",
    ".asc": "xyz",
}
_HEAD_BYTES = 1 << 16
_CONF_NAMES = ("confidence", "scalar_confidence", "quality")
_PLY_NORMALS = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))  # the latter: PCL
_CONF_TOL = 1e-6

# --------------------------------------------------------------------------------------------
# source handling


def _name(source: Source) -> str:
    if isinstance(source, bytes | bytearray | memoryview):
        return "uploaded scan"
    return str(source)


def _read_prefix(source: Source, n: int = _HEAD_BYTES) -> tuple[bytes, int]:
    """First ``n`` bytes of the source and its total size in bytes."""
    if isinstance(source, bytes | bytearray | memoryview):
        b = bytes(memoryview(source)[:n])
        return b, len(memoryview(source))
    p = Path(source)
    try:
        size = p.stat().st_size
        with p.open("rb") as f:
            return f.read(n), size
    except FileNotFoundError:
        raise InputFormatError(f"file not found: {p}", path=str(p)) from None
    except IsADirectoryError:
        raise InputFormatError(f"{p} is a directory, not a mesh file", path=str(p)) from None
    except OSError as e:
        raise InputFormatError(f"cannot read {p}: {e.strerror}", path=str(p)) from None


def _read_all(source: Source) -> bytes:
    if isinstance(source, bytes | bytearray | memoryview):
        return bytes(source)
    try:
        return Path(source).read_bytes()
    except OSError as e:
        raise InputFormatError(f"cannot read {source}: {e.strerror}", path=str(source)) from None


def _detect_format(
    source: Source, head: bytes, size: int, fmt: str | None, what: str | None = None
) -> str:
    what = _name(source) if what is None else what
    if fmt is not None:
        f = fmt.lower().lstrip(".")
        if f == "txt":
            f = "xyz"
        if f not in FORMATS:
            raise InputFormatError(
                f"unknown mesh format {fmt!r}; use one of {', '.join(FORMATS)}", fmt=fmt
            )
        return f
    if size == 0:
        raise InputFormatError(f"{what} is empty (0 bytes); upload a non-empty scan file")
    if not isinstance(source, bytes | bytearray | memoryview):
        ext = Path(source).suffix.lower()
        if ext in _EXT:
            return _EXT[ext]
    sniffed = _sniff(head, size)
    if sniffed is None:
        raise InputFormatError(
            f"{what}: unrecognised file format (first bytes {head[:16]!r}); "
            "supported formats are PLY, OBJ (alone or zipped with its MTL and textures), GLB, "
            "STL, NPZ and XYZ/PTS point clouds",
            first_bytes=repr(head[:16]),
        )
    return sniffed


def _sniff(head: bytes, size: int) -> str | None:
    if head.startswith(b"ply"):
        return "ply"
    if head.startswith(b"PK\x03\x04"):
        return "npz"  # or a textured-OBJ bundle: told apart by its members (_zip_kind)
    if head.startswith(b"glTF"):
        return "glb"
    if len(head) >= 84:
        n = int(np.frombuffer(head, "<u4", 1, 80)[0])
        if 84 + 50 * n == size:
            return "stl"
    stripped = head.lstrip()
    if stripped.startswith(b"solid") and b"facet" in head:
        return "stl"
    if re.search(rb"^[ \t]*v[ \t]+[-+.\d]", head, re.M) and b"\x00" not in head:
        return "obj"
    text = head[:4096]
    if b"\x00" not in text and re.match(rb"\s*[-+]?[\d.]", text):
        return "xyz"
    return None


def _check_limits(nv: int, nf: int, max_vertices: int | None, max_faces: int | None, what: str):
    if max_vertices is not None and nv > max_vertices:
        raise InputFormatError(
            f"{what} has {nv:,} vertices, above the limit of {max_vertices:,}; "
            "decimate the scan (e.g. to 1 M vertices) and upload again",
            n_vertices=nv,
            limit=max_vertices,
        )
    if max_faces is not None and nf > max_faces:
        raise InputFormatError(
            f"{what} has {nf:,} faces, above the limit of {max_faces:,}; "
            "decimate the scan and upload again",
            n_faces=nf,
            limit=max_faces,
        )


# --------------------------------------------------------------------------------------------
# text helpers


def _parse_floats(text: bytes, what: str) -> np.ndarray:
    """Parse whitespace-separated numbers (C speed); on failure, name the bad token."""
    if not text.strip():
        return np.zeros(0)
    try:
        return np.fromstring(text, sep=" ")
    except ValueError:
        pass
    for lineno, line in enumerate(text.splitlines(), 1):
        for tok in line.split():
            try:
                float(tok)
            except ValueError:
                raise InputFormatError(
                    f"{what}: non-numeric value {tok.decode('latin-1')!r} in data line "
                    f"{lineno} ({line.decode('latin-1').strip()[:80]!r}); fix or remove that line",
                    line=lineno,
                ) from None
    raise InputFormatError(f"{what}: could not parse the numeric data")


def _tokens_per_line(lines: list[bytes]) -> np.ndarray:
    """Number of whitespace-separated tokens on each line, vectorised."""
    if not lines:
        return np.zeros(0, dtype=np.int64)
    buf = np.frombuffer(b"\n".join(lines) + b"\n", dtype=np.uint8)
    nl = buf == 10
    space = (buf == 32) | (buf == 9) | (buf == 13) | (buf == 11) | (buf == 12) | nl
    start = ~space
    start[1:] &= space[:-1]
    line_id = np.cumsum(nl) - nl  # line index of each byte
    return np.bincount(line_id[start], minlength=len(lines))


# --------------------------------------------------------------------------------------------
# PLY

_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}


class _Prop:
    __slots__ = ("count_type", "name", "type")

    def __init__(self, name: str, type_: str, count_type: str | None = None):
        self.name = name
        self.type = type_
        self.count_type = count_type  # None for scalars


class _Element:
    __slots__ = ("count", "name", "props")

    def __init__(self, name: str, count: int):
        self.name = name
        self.count = count
        self.props: list[_Prop] = []

    @property
    def has_list(self) -> bool:
        return any(p.count_type is not None for p in self.props)


def _ply_header(head: bytes, what: str) -> tuple[str, list[_Element], int]:
    """Parse a PLY header -> (format, elements, byte offset of the data)."""
    m = re.search(rb"end_header[ \t]*\r?\n", head)
    if m is None:
        if b"end_header" in head and head.rstrip().endswith(b"end_header"):
            return _ply_header(head.rstrip() + b"\n", what)
        raise InputFormatError(
            f"{what}: PLY header has no 'end_header' line within the first "
            f"{_HEAD_BYTES // 1024} KiB; the file is truncated or not a PLY file"
        )
    # latin-1: comments may hold any bytes (UTF-8 author or software names); keywords and
    # names are checked below
    lines = head[: m.start()].decode("latin-1").splitlines()
    if not lines or lines[0].strip() != "ply":
        raise InputFormatError(f"{what}: a PLY file must start with the line 'ply'")
    fmt = None
    elements: list[_Element] = []
    for lineno, raw in enumerate(lines[1:], 2):
        parts = raw.split()
        if not parts or parts[0] in ("comment", "obj_info"):
            continue
        key = parts[0]
        bad = InputFormatError(
            f"{what}: malformed PLY header line {lineno}: {raw.strip()!r}", line=lineno
        )
        if key == "format":
            if len(parts) < 2 or parts[1] not in (
                "ascii",
                "binary_little_endian",
                "binary_big_endian",
            ):
                raise InputFormatError(
                    f"{what}: unsupported PLY format in header line {lineno}: {raw.strip()!r}; "
                    "expected ascii, binary_little_endian or binary_big_endian",
                    line=lineno,
                )
            fmt = parts[1]
        elif key == "element":
            if len(parts) != 3:
                raise bad
            try:
                count = int(parts[2])
            except ValueError:
                raise bad from None
            if count < 0:
                raise bad
            elements.append(_Element(parts[1], count))
        elif key == "property":
            if not elements:
                raise InputFormatError(
                    f"{what}: PLY header line {lineno} declares a property before any element",
                    line=lineno,
                )
            if len(parts) == 3 and parts[1] in _PLY_TYPES:
                elements[-1].props.append(_Prop(parts[2], _PLY_TYPES[parts[1]]))
            elif (
                len(parts) == 5
                and parts[1] == "list"
                and parts[2] in _PLY_TYPES
                and parts[3] in _PLY_TYPES
            ):
                elements[-1].props.append(
                    _Prop(parts[4], _PLY_TYPES[parts[3]], _PLY_TYPES[parts[2]])
                )
            else:
                raise InputFormatError(
                    f"{what}: unsupported PLY property in header line {lineno}: {raw.strip()!r}",
                    line=lineno,
                )
        else:
            raise bad
    if fmt is None:
        raise InputFormatError(f"{what}: PLY header has no 'format' line")
    return fmt, elements, m.end()


def _ply_counts(elements: list[_Element]) -> tuple[int, int]:
    nv = nf = 0
    for e in elements:
        if e.name == "vertex":
            nv = e.count
        elif e.name == "face":
            nf = e.count
    return nv, nf


def _binary_element(
    data: memoryview, off: int, el: _Element, end: str, what: str
) -> tuple[dict[str, Any], int]:
    """Read one binary element -> ({prop: array or list-of-(k, (r,k) array) runs}, new offset)."""
    n = el.count
    if not el.has_list:
        dt = np.dtype([(f"p{i}", end + p.type) for i, p in enumerate(el.props)])
        need = dt.itemsize * n
        if off + need > len(data):
            raise InputFormatError(
                f"{what}: binary PLY is truncated: element '{el.name}' needs {need:,} bytes "
                f"for {n:,} rows but only {max(len(data) - off, 0):,} remain; "
                "the upload was cut short or the header count is wrong",
                element=el.name,
            )
        arr = np.frombuffer(data, dt, n, off) if n else np.zeros(0, dt)
        return {p.name: arr[f"p{i}"] for i, p in enumerate(el.props)}, off + need
    # Elements with list properties: find every row's start (vectorised when all rows share the
    # first row's list lengths, else one pass over the count bytes), then gather each property.
    props = [
        (np.dtype(end + p.type), None if p.count_type is None else np.dtype(end + p.count_type))
        for p in el.props
    ]
    rec = _uniform_rows(data, off, n, props)
    if rec is not None:  # every row has the first row's list lengths: one structured view
        out: dict[str, Any] = {}
        for i, p in enumerate(el.props):
            if props[i][1] is None:
                out[p.name] = rec[f"p{i}"]
            else:  # (n, c) values: a ragged array of equal rows
                vals = rec[f"p{i}"] if f"p{i}" in rec.dtype.names else np.zeros((n, 0))
                out[p.name] = (np.full(n, vals.shape[1], dtype=np.int64), vals)
        return out, off + n * rec.dtype.itemsize
    starts = _row_starts(data, off, n, props, el.name, what)
    buf = np.frombuffer(data, np.uint8)
    out = {}
    pos = starts
    for p, (vt, ct) in zip(el.props, props, strict=True):
        if ct is None:
            out[p.name] = _gather(buf, pos, vt)
            pos = pos + vt.itemsize
            continue
        counts = _gather(buf, pos, ct).astype(np.int64)
        first = pos + ct.itemsize
        flat_pos = np.repeat(first, counts) + vt.itemsize * _ranks(counts)
        out[p.name] = (counts, _gather(buf, flat_pos, vt))
        pos = first + counts * vt.itemsize
    end_off = int(pos[-1]) if n else off
    return out, end_off


def _gather(buf: np.ndarray, pos: np.ndarray, dt: np.dtype) -> np.ndarray:
    """Values of type ``dt`` at byte offsets ``pos`` of ``buf`` (uint8) -> (len(pos),)."""
    if dt.itemsize == 1:
        return buf[pos].view(dt)
    idx = pos[:, None] + np.arange(dt.itemsize)
    return np.ascontiguousarray(buf[idx]).view(dt).reshape(-1)


def _ranks(counts: np.ndarray) -> np.ndarray:
    """0..c-1 for each row of a ragged array with row lengths ``counts``, concatenated."""
    total = int(counts.sum())
    first = np.cumsum(counts) - counts
    return np.arange(total, dtype=np.int64) - np.repeat(first, counts)


_MAX_LIST = 1_000_000


def _row_layout(data, off: int, props) -> tuple[list[int], int] | None:
    """List lengths and byte size of the row at ``off`` (None when past the end)."""
    counts = []
    pos = off
    for vt, ct in props:
        if ct is None:
            pos += vt.itemsize
            continue
        if pos + ct.itemsize > len(data):
            return None
        c = int(np.frombuffer(data, ct, 1, pos)[0])
        counts.append(c)
        pos += ct.itemsize + max(c, 0) * vt.itemsize
    return counts, pos - off


def _uniform_rows(data, off: int, n: int, props) -> np.ndarray | None:
    """The rows as one structured array if every row has the first row's list lengths
    (checked), else None."""
    if n == 0:
        return None
    first = _row_layout(data, off, props)
    if first is None or any(c < 0 or c > _MAX_LIST for c in first[0]):
        return None
    counts, size = first
    if off + n * size > len(data):
        return None
    fields, li = [], 0
    for i, (vt, ct) in enumerate(props):
        if ct is None:
            fields.append((f"p{i}", vt))
        else:
            fields.append((f"c{i}", ct))
            if counts[li]:
                fields.append((f"p{i}", vt, (counts[li],)))
            li += 1
    rec = np.frombuffer(data, np.dtype(fields), n, off)
    li = 0
    for i, (_, ct) in enumerate(props):
        if ct is not None:
            if not np.all(rec[f"c{i}"] == counts[li]):
                return None
            li += 1
    return rec


def _row_starts(data, off: int, n: int, props, name: str, what: str) -> np.ndarray:
    """Row starts of an element whose rows differ in list lengths: one pass over the counts
    (the one sequential dependency of the format; ~0.1 us a row for the usual faces)."""
    starts = np.empty(n, dtype=np.int64)
    size = len(data)
    lists = [i for i, (_, ct) in enumerate(props) if ct is not None]
    pre = sum(vt.itemsize for vt, _ in props[: lists[0]])
    post = sum(vt.itemsize for vt, _ in props[lists[0] + 1 :])
    vt0, ct0 = props[lists[0]]
    pos = off
    if len(lists) == 1 and ct0.itemsize == 1 and ct0.kind == "u":  # the usual: uchar counts
        mv = memoryview(data).cast("B") if isinstance(data, memoryview) else memoryview(data)
        fixed, isz = pre + 1 + post, vt0.itemsize
        found = []
        add = found.append
        try:
            for _ in range(n):
                add(pos)
                pos += fixed + mv[pos + pre] * isz
        except IndexError:
            pos = size + 1
        if pos <= size:
            starts = np.array(found, dtype=np.int64)
    else:
        for i in range(n):
            starts[i] = pos
            lay = _row_layout(data, pos, props)
            if lay is None:
                pos = size + 1
                break
            if any(c < 0 or c > _MAX_LIST for c in lay[0]):
                raise InputFormatError(
                    f"{what}: invalid list length in element '{name}' row {i:,}; "
                    "the file is corrupt",
                    element=name,
                )
            pos += lay[1]
    if pos > size:
        raise InputFormatError(
            f"{what}: binary PLY is truncated inside element '{name}' ({n:,} rows declared); "
            "the upload was cut short or the header count is wrong",
            element=name,
        )
    return starts


def _ascii_element(
    lines: list[bytes], start: int, el: _Element, what: str
) -> tuple[dict[str, Any], int]:
    """Read one ASCII element of ``el.count`` lines starting at line ``start``."""
    n = el.count
    chunk = lines[start : start + n]
    if len(chunk) < n:
        raise InputFormatError(
            f"{what}: PLY header declares {n:,} '{el.name}' rows but the file has only "
            f"{len(chunk):,}; the file is truncated or the header count is wrong",
            element=el.name,
        )
    ntok = _tokens_per_line(chunk)
    vals = _parse_floats(b"\n".join(chunk), f"{what} (element '{el.name}')")
    out: dict[str, Any] = {}
    if not el.has_list:
        w = len(el.props)
        bad = np.flatnonzero(ntok != w)
        if len(bad):
            i = int(bad[0])
            raise InputFormatError(
                f"{what}: '{el.name}' row {i + 1} has {ntok[i]} values, expected {w}: "
                f"{chunk[i].decode('latin-1').strip()[:80]!r}",
                element=el.name,
            )
        tab = vals.reshape(n, w) if n else np.zeros((0, w))
        for j, p in enumerate(el.props):
            out[p.name] = _as_type(tab[:, j], p.type)
        return out, start + n
    # list elements: each row's list lengths from its tokens, then one gather per property
    offs = np.concatenate([[0], np.cumsum(ntok)])
    per_prop_counts: dict[int, np.ndarray] = {}
    pos = offs[:-1].copy()
    for i, p in enumerate(el.props):
        if p.count_type is None:
            pos += 1
            continue
        valid = pos < offs[1:]
        c = np.where(valid, vals[np.minimum(pos, len(vals) - 1)], -1) if len(vals) else pos * 0
        if np.any(c < 0) or np.any(c != np.round(c)):
            i_bad = int(np.flatnonzero((c < 0) | (c != np.round(c)))[0])
            raise InputFormatError(
                f"{what}: malformed '{el.name}' row {i_bad + 1}: "
                f"{chunk[i_bad].decode('latin-1').strip()[:80]!r}",
                element=el.name,
            )
        c = c.astype(np.int64)
        per_prop_counts[i] = c
        pos = pos + 1 + c
    bad = np.flatnonzero(pos != offs[1:])
    if len(bad):
        i = int(bad[0])
        raise InputFormatError(
            f"{what}: '{el.name}' row {i + 1} has {ntok[i]} values, which does not match its "
            f"list lengths: {chunk[i].decode('latin-1').strip()[:80]!r}",
            element=el.name,
        )
    col = offs[:-1].copy()
    for i, p in enumerate(el.props):
        if p.count_type is None:
            out[p.name] = vals[col]
            col = col + 1
        else:
            c = per_prop_counts[i]
            flat = vals[np.repeat(col + 1, c) + _ranks(c)]
            out[p.name] = (c, _as_type(flat, p.type))
            col = col + 1 + c
    return out, start + n


def _as_type(a: np.ndarray, t: str) -> np.ndarray:
    """Cast parsed ASCII values to the declared PLY type (integers must be integral)."""
    dt = np.dtype(t)
    if dt.kind == "f":
        return a.astype(dt) if dt.itemsize == 4 else a
    if len(a) and np.any(a != np.round(a)):
        bad = a[a != np.round(a)][0]
        raise InputFormatError(f"PLY: non-integer value {bad!r} in an integer property")
    return a.astype(np.int64)


def _fan(counts: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """Fan-triangulate polygons given as a ragged array -> (m, 3) int64, in file order.

    ``counts`` (r,) corners per polygon, ``flat`` (sum(counts),) their vertex indices (or
    (r, k) when every polygon has k corners); polygon
    ``(v0, ..., vk-1)`` gives ``(v0, vj, vj+1)`` for j = 1..k-2; polygons with < 3 corners are
    dropped. Vectorised: mixed triangles, quads and n-gons cost what uniform ones do.
    """
    counts = np.asarray(counts, dtype=np.int64)
    flat = np.asarray(flat)
    if flat.ndim == 2:  # equal rows (n, k), e.g. a structured view of a binary PLY
        if flat.shape[1] == 3:
            return flat.astype(np.int64)  # one copy, contiguous
        flat = flat.reshape(-1)
    if len(counts) and np.all(counts == 3):
        return flat.astype(np.int64, copy=False).reshape(-1, 3)
    first = np.cumsum(counts) - counts
    ntri = np.maximum(counts - 2, 0)
    base = np.repeat(first, ntri)
    j = _ranks(ntri) + 1
    F = np.empty((len(base), 3), dtype=np.int64)
    F[:, 0] = flat[base]
    F[:, 1] = flat[base + j]
    F[:, 2] = flat[base + j + 1]
    return F


def _read_ply(
    data: bytes,
    what: str,
    max_vertices: int | None,
    max_faces: int | None,
    files: Files | None = None,
    max_pixels: int = MAX_TEXTURE_PIXELS,
) -> RawMesh:
    """PLY (ASCII or binary); with ``files`` (the images beside it) a texture named by a
    ``comment TextureFile`` line gives the vertex colours (:func:`_ply_texture`)."""
    fmt, elements, off = _ply_header(data[:_HEAD_BYTES], what)
    nv, nf = _ply_counts(elements)
    _check_limits(nv, nf, max_vertices, max_faces, what)
    if not any(e.name == "vertex" for e in elements):
        raise InputFormatError(f"{what}: PLY file has no 'vertex' element")
    parsed: dict[str, dict[str, Any]] = {}
    if fmt == "ascii":
        body = data[off:]
        lines = [ln for ln in body.splitlines() if ln.strip()]
        pos = 0
        for el in elements:
            vals, pos = _ascii_element(lines, pos, el, what)
            if el.name in ("vertex", "face", "tristrips"):
                parsed[el.name] = vals
    else:
        end = "<" if fmt == "binary_little_endian" else ">"
        mv = memoryview(data)
        for el in elements:
            vals, off = _binary_element(mv, off, el, end, what)
            if el.name in ("vertex", "face", "tristrips"):
                parsed[el.name] = vals
    vert = parsed["vertex"]
    missing = [c for c in "xyz" if c not in vert]
    if missing:
        raise InputFormatError(
            f"{what}: PLY vertex element lacks the coordinate properties {missing}; "
            "vertices need x, y and z"
        )
    V = np.stack([np.asarray(vert[c], dtype=np.float64) for c in "xyz"], axis=1)
    normals = None
    nnames = next((ns for ns in _PLY_NORMALS if all(c in vert for c in ns)), None)
    if nnames is not None:
        normals = np.stack([np.asarray(vert[c], dtype=np.float64) for c in nnames], 1)
    conf = None
    lower = {k.lower(): k for k in vert}  # CloudCompare keeps a scalar field's case
    for cname in _CONF_NAMES:
        if cname in lower:
            conf = np.asarray(vert[lower[cname]], dtype=np.float64)
            if cname == "quality" and not _unit_interval(conf):
                conf = None  # not a confidence (module docstring)
            break
    colors = None
    for names in (
        ("red", "green", "blue"),
        ("r", "g", "b"),
        ("diffuse_red", "diffuse_green", "diffuse_blue"),
    ):
        if all(c in vert for c in names):
            declared = next(np.dtype(p.type) for e in elements if e.name == "vertex"
                            for p in e.props if p.name == names[0])  # fmt: skip
            colors = _ply_colors(np.stack([vert[c] for c in names], 1), declared)
            break
    tris, faces = [], None
    for el, triangulate in (("face", _fan), ("tristrips", _strips)):
        if parsed.get(el) is not None and any(e.name == el and e.count for e in elements):
            ragged = _ply_indices(parsed[el], el, what)
            tris.append(triangulate(*ragged))
            faces = ragged if el == "face" else None
    F = np.concatenate(tris) if tris else None
    texture = None
    names = _PLY_TEXTURE_FILE.findall(data[:off])
    if files is not None and names and faces is not None and len(tris) == 1:
        got = _ply_texture(vert, parsed["face"], faces, names, files, what, max_pixels)
        if got is not None:
            colors, texture = got
    raw = RawMesh(V=V, F=F, normals=normals, confidence=conf, colors=colors, texture=texture)
    return _finish(raw, what)


_PLY_TEXTURE_FILE = re.compile(rb"^comment[ \t]+TextureFile[ \t]+([^\r\n]*?)[ \t]*\r?$", re.M)
_PLY_VERTEX_UV = (("texture_u", "texture_v"), ("texture_s", "texture_t"), ("s", "t"), ("u", "v"))


def _ply_texture(
    vert: dict[str, Any],
    face: dict[str, Any],
    ragged: tuple[np.ndarray, np.ndarray],
    names: list[bytes],
    files: Files,
    what: str,
    max_pixels: int,
) -> tuple[np.ndarray, ScanTexture] | None:
    """Vertex colours (n, 3) uint8 and the texture mapping of a textured PLY (MeshLab,
    Metashape), or None (no texture coordinates, or no image found).

    The images are the ``comment TextureFile`` names (a face's ``texnumber`` picks one, else
    the first); texture coordinates are the faces' ``texcoord`` lists (u v per corner) or the
    vertices' ``texture_u``/``texture_v`` (or ``s``/``t``, ``u``/``v``), OBJ convention (v up).
    A vertex takes the mean of its corners' bilinear samples.
    """
    from core.io.images import decode_image, sample_image

    counts, flat = ragged
    flat = np.asarray(flat).reshape(-1).astype(np.int64)
    nv = len(next(iter(vert.values())))
    if len(flat) and (flat.min() < 0 or flat.max() >= nv):
        return None  # _finish names the bad index
    tc = face.get("texcoord")
    uvn = next((ns for ns in _PLY_VERTEX_UV if all(c in vert for c in ns)), None)
    if isinstance(tc, tuple) and np.array_equal(tc[0], 2 * np.asarray(counts)):
        uv = np.asarray(tc[1], dtype=np.float64).reshape(-1, 2)
    elif uvn is not None:
        uv = np.stack([np.asarray(vert[c], dtype=np.float64) for c in uvn], 1)[flat]
    else:
        return None
    if not np.isfinite(uv).all():
        raise InputFormatError(f"{what}: PLY texture coordinates must be finite")
    uv = uv * [1.0, -1.0] + [0.0, 1.0]  # v up -> glTF v down
    tex = face.get("texnumber")
    corner = np.repeat(np.zeros(len(counts), np.int64) if tex is None else tex, counts)
    images: list[np.ndarray] = []
    slot = np.full(len(names) + 1, -1)  # image of each name; the extra -1: no valid texnumber
    for i, name in enumerate(n.decode("utf-8", "replace") for n in names):
        img = files(name) if np.any(corner == i) else None
        if img is not None:
            slot[i] = len(images)
            images.append(
                decode_image(img, name=f"{what}: texture {name!r}", max_pixels=max_pixels)
            )
            max_pixels -= images[-1].shape[0] * images[-1].shape[1]
    if not images:
        return None
    corner_img = slot[np.where((corner >= 0) & (corner < len(names)), corner, -1)]
    acc, cnt = np.zeros((nv, 3)), np.zeros(nv)
    for k, img in enumerate(images):
        c = np.flatnonzero(corner_img == k)
        rgb = sample_image(img, uv[c])
        for j in range(3):
            acc[:, j] += np.bincount(flat[c], weights=rgb[:, j], minlength=nv)
        cnt += np.bincount(flat[c], minlength=nv)
    has = cnt > 0
    acc[has] /= cnt[has, None]
    acc[~has] = acc[has].mean(axis=0)
    tri = _fan(counts, np.arange(len(flat)))
    image = corner_img[tri[:, 0]].astype(np.int16)
    texture = ScanTexture(uv=uv[tri].astype(np.float32), image=image, images=images)
    return np.clip(np.round(acc * 255.0), 0, 255).astype(np.uint8), texture


def _ply_indices(vals: dict[str, Any], el: str, what: str) -> tuple[np.ndarray, np.ndarray]:
    """The ``vertex_indices`` (or ``vertex_index``) list of a PLY ``face`` or ``tristrips``
    element as a ragged array (counts, flat)."""
    key = next((k for k in ("vertex_indices", "vertex_index") if k in vals), None)
    if key is None or not isinstance(vals[key], tuple):
        raise InputFormatError(
            f"{what}: PLY {el} element has no list property 'vertex_indices' (or 'vertex_index')"
        )
    counts, flat = vals[key]
    if flat.dtype.kind == "f" and np.any(flat != np.round(flat)):
        raise InputFormatError(f"{what}: PLY {el} indices must be integers")
    return counts, flat


def _strips(counts: np.ndarray, flat: np.ndarray) -> np.ndarray:
    """Triangles (m, 3) int64 of triangle strips given as a ragged array (PLY ``tristrips``).

    Each row holds strips separated by -1; strip ``(v0, v1, v2, v3, ...)`` gives ``(v0, v1,
    v2)``, ``(v2, v1, v3)``, ... (every second triangle reversed, so all keep the first's
    winding). The degenerate triangles that join strips are dropped.
    """
    flat = np.asarray(flat).reshape(-1)
    seq = flat.astype(np.int64)
    if flat.dtype.kind == "u":  # -1 stored in an unsigned type
        seq[seq == np.iinfo(flat.dtype).max] = -1
    seq = np.insert(seq, np.cumsum(counts), -1)  # a row's end ends its strip
    sep = seq < 0
    idx = np.arange(len(seq))
    rank = idx - np.maximum.accumulate(np.where(sep, idx, -1)) - 1  # place in its strip
    j = np.flatnonzero(~(sep[:-2] | sep[1:-1] | sep[2:]))
    a, b, c = seq[j], seq[j + 1], seq[j + 2]
    odd = rank[j] % 2 == 1
    T = np.stack([np.where(odd, b, a), np.where(odd, a, b), c], axis=1)
    return T[(a != b) & (b != c) & (a != c)]


def _ply_colors(rgb: np.ndarray, declared: np.dtype) -> np.ndarray:
    """(n, 3) uint8 colours from PLY colour properties of the ``declared`` type: floats in
    [0, 1]; 8-bit integers; wider integers holding values above 255 are 16-bit colours
    (0-65535, as LAS/E57 point clouds converted by PDAL or CloudCompare carry them)."""
    rgb = np.asarray(rgb, dtype=np.float64)
    if declared.kind == "f":
        rgb = rgb * 255.0
    elif declared.itemsize > 1 and rgb.max(initial=0.0) > 255.0:
        rgb = rgb * (255.0 / 65535.0)
    return np.clip(np.round(rgb), 0, 255).astype(np.uint8)


# --------------------------------------------------------------------------------------------
# OBJ

_OBJ_V = re.compile(rb"^[ \t]*v[ \t]+([^\r\n]*)", re.M)
_OBJ_VN = re.compile(rb"^[ \t]*vn[ \t]+([^\r\n]*)", re.M)
_OBJ_F = re.compile(rb"^[ \t]*f[ \t]+([^\r\n]*)", re.M)
_OBJ_CONTINUATION = re.compile(rb"\\[ \t]*\r?\n")


def _read_obj(
    data: bytes,
    what: str,
    max_vertices: int | None,
    max_faces: int | None,
    files: Files | None = None,
    strict: bool = False,
    max_pixels: int = MAX_TEXTURE_PIXELS,
) -> RawMesh:
    """OBJ; with ``files`` (the MTL and images beside it) a ``map_Kd`` texture or ``Kd``
    colour gives the vertex colours (``strict``: a named file that is missing is an error).
    Per-vertex colours (``v x y z r g b``) give way to a texture only, never to a flat ``Kd``
    (exporters name a default material, e.g. Blender's grey ``Kd 0.8 0.8 0.8``)."""
    if b"\\" in data:  # a line ending in a backslash continues on the next
        data = _OBJ_CONTINUATION.sub(b" ", data)
    v_lines = _OBJ_V.findall(data)
    f_lines = _OBJ_F.findall(data)
    _check_limits(len(v_lines), len(f_lines), max_vertices, max_faces, what)
    if not v_lines:
        raise InputFormatError(f"{what}: OBJ file has no vertex ('v x y z') lines")
    ntok = _tokens_per_line(v_lines)
    vals = _parse_floats(b"\n".join(v_lines), f"{what} (OBJ vertices)")
    colors = None
    if np.all(ntok == 3):
        V = vals.reshape(-1, 3)
    elif np.all(ntok == 4):
        V = vals.reshape(-1, 4)[:, :3]
    elif np.all(ntok == 6) or np.all(ntok == 7):
        tab = vals.reshape(len(v_lines), -1)
        V = tab[:, :3]
        c = tab[:, -3:]
        scale = 255.0 if c.max(initial=0) <= 1.0 else 1.0
        colors = np.clip(np.round(c * scale), 0, 255).astype(np.uint8)
    else:
        bad = np.flatnonzero(ntok < 3)
        if len(bad):
            i = int(bad[0])
            raise InputFormatError(
                f"{what}: OBJ vertex line {i + 1} ('v {v_lines[i].decode('latin-1')[:60]}') has "
                f"{ntok[i]} values, expected 3"
            )
        offs = np.concatenate([[0], np.cumsum(ntok)[:-1]])
        V = vals[offs[:, None] + np.arange(3)[None, :]]
    V = np.ascontiguousarray(V, dtype=np.float64)
    nv = len(V)

    F = None
    normals = None
    texture = None
    if f_lines:
        ftok = _tokens_per_line(f_lines)
        block = b"\n".join(f_lines)
        vi_text = re.sub(rb"/[^\s]*", b"", block)
        vi = _parse_floats(vi_text, f"{what} (OBJ faces)")
        if len(vi) != int(ftok.sum()):
            raise InputFormatError(f"{what}: malformed OBJ face lines")
        if np.any(vi != np.round(vi)):
            raise InputFormatError(f"{what}: OBJ face indices must be integers")
        vi = vi.astype(np.int64)
        if np.any(vi == 0):
            raise InputFormatError(
                f"{what}: OBJ face index 0 found; OBJ indices start at 1 (or are negative)"
            )
        if np.any(vi < 0):
            # negative indices are relative to the vertices defined so far
            v_pos = np.array([m.start() for m in _OBJ_V.finditer(data)])
            f_pos = np.array([m.start() for m in _OBJ_F.finditer(data)])
            n_before = np.searchsorted(v_pos, f_pos)
            per_tok = np.repeat(n_before, ftok)
            vi = np.where(vi < 0, per_tok + vi, vi - 1)
        else:
            vi = vi - 1
        ni = None
        vn_lines = _OBJ_VN.findall(data)
        if vn_lines and re.search(rb"\S+/\S*/\S+", block):
            parts = re.findall(rb"(\S+)", block)
            if all(p.count(b"/") == 2 and not p.endswith(b"/") for p in parts):
                ni_text = re.sub(rb"(\S*?)/(\S*?)/(\S+)", rb"\3", block)
                ni = _parse_floats(ni_text, f"{what} (OBJ normal indices)").astype(np.int64)
                nvn = len(vn_lines)
                ni = np.where(ni < 0, nvn + ni, ni - 1)
                if np.any((ni < 0) | (ni >= nvn)):
                    ni = None
                else:
                    vn = _parse_floats(b"\n".join(vn_lines), f"{what} (OBJ normals)")
                    if len(vn) != 3 * nvn:
                        raise InputFormatError(f"{what}: OBJ 'vn' lines must have 3 values each")
                    vn = vn.reshape(-1, 3)
                    if np.all((vi >= 0) & (vi < nv)):
                        normals = np.zeros((nv, 3))
                        normals[vi] = vn[ni]
                        # only keep normals when every vertex has a single consistent one
                        chk = normals[vi]
                        if not np.allclose(chk, vn[ni]) or len(np.unique(vi)) != nv:
                            normals = None
        if files is not None and np.all((vi >= 0) & (vi < nv)):
            tex, texture = _obj_material_colours(
                data, block, ftok, vi, nv, files, strict, what, max_pixels
            )
            if tex is not None and (colors is None or texture is not None):
                colors = tex
            if texture is not None:  # per triangle of the fan, as F below
                tri = _fan(ftok, np.arange(len(vi)))
                corner_uv, corner_img, texture_images = texture
                img_idx = corner_img[tri[:, 0]].astype(np.int16)
                uv = corner_uv[tri].astype(np.float32)
                img_idx[~np.isfinite(uv).all(axis=(1, 2))] = -1
                texture = ScanTexture(uv=uv, image=img_idx, images=texture_images)
        F = _fan(ftok, vi)
    else:  # a point cloud: one vn per v, in order (MeshLab, CloudCompare)
        vn_lines = _OBJ_VN.findall(data)
        if len(vn_lines) == nv:
            vn = _parse_floats(b"\n".join(vn_lines), f"{what} (OBJ normals)")
            if len(vn) == 3 * nv:
                normals = vn.reshape(-1, 3)
    return _finish(RawMesh(V=V, F=F, normals=normals, colors=colors, texture=texture), what)


# --------------------------------------------------------------------------------------------
# OBJ materials and textures (MTL + map_Kd images), OBJ bundles (ZIP) and GLB

Files = Callable[[str], bytes | None]  # a file named by the OBJ/MTL -> its bytes, None if absent
_OBJ_VT = re.compile(rb"^[ \t]*vt[ \t]+([^\r\n]*)", re.M)
_OBJ_USEMTL = re.compile(rb"^[ \t]*usemtl[ \t]+([^\r\n]*)", re.M)
_OBJ_MTLLIB = re.compile(rb"^[ \t]*mtllib[ \t]+([^\r\n]*)", re.M)
MAX_SIDECAR_BYTES = 256 << 20  # one MTL or texture file
MAX_BUNDLE_MEMBERS = 64
MAX_BUNDLE_BYTES = 2 << 30  # inflated bytes read from one ZIP bundle
_INSPECT_CHUNK = 1 << 24  # bytes of a bundle's OBJ inflated at a time by inspect_mesh_header
MAX_BUNDLE_RATIO = 20  # ... and at most this many times the archive's own size (zip bombs)


def _corner_vt(data: bytes, block: bytes, ftok: np.ndarray, what: str) -> np.ndarray | None:
    """0-based ``vt`` index of every face corner (-1 where a corner has none), or None when
    the faces carry no ``v/vt`` corners (or mix layouts: then the texture is not used)."""
    n = int(ftok.sum())
    slashes = block.count(b"/")
    for k, extra in ((1, rb"/[^\s/]*/"), (2, rb"/[^\s/]*/[^\s/]*/")):
        if slashes != k * n or re.search(extra, block):
            continue
        vals = _parse_floats(
            block.replace(b"//", b"/0/").replace(b"/", b" "), f"{what} (OBJ faces)"
        )
        if len(vals) != n * (k + 1):
            return None
        vt = vals.reshape(n, k + 1)[:, 1].astype(np.int64)
        if np.any(vt < 0):  # relative to the vt lines so far
            vt_pos = np.array([m.start() for m in _OBJ_VT.finditer(data)])
            f_pos = np.array([m.start() for m in _OBJ_F.finditer(data)])
            before = np.repeat(np.searchsorted(vt_pos, f_pos), ftok)
            vt = np.where(vt < 0, before + vt + 1, vt)
        return vt - 1
    return None


def _obj_vt(vt_lines: list[bytes], what: str) -> np.ndarray:
    """(T, 2) ``u v`` of the ``vt`` lines (a missing ``v`` is 0, a ``w`` ignored)."""
    ntok = _tokens_per_line(vt_lines)
    w = int(ntok[0])
    if w in (2, 3) and np.all(ntok == w):
        return _parse_floats(b"\n".join(vt_lines), f"{what} (OBJ vt)").reshape(-1, w)[:, :2]
    rows = [[*ln.split(), b"0", b"0"][:2] for ln in vt_lines]
    return _parse_floats(b"\n".join(b" ".join(r) for r in rows), f"{what} (OBJ vt)").reshape(-1, 2)


def _mtl_materials(text: bytes) -> dict[str, tuple[np.ndarray | None, str | None]]:
    """MTL ``newmtl`` name -> (``Kd`` RGB in [0, 1] or None, ``map_Kd`` file name or None)."""
    out: dict[str, tuple[np.ndarray | None, str | None]] = {}
    name = None
    for raw in text.decode("utf-8", "replace").splitlines():
        parts = raw.split()
        if not parts:
            continue
        key = parts[0]
        if key == "newmtl" and len(parts) > 1:
            name = raw.split(None, 1)[1].strip()
            out[name] = (None, None)
        elif name is None:
            continue
        elif key == "Kd" and len(parts) >= 4:
            try:
                kd = np.clip([float(x) for x in parts[1:4]], 0.0, 1.0)
            except ValueError:
                continue
            out[name] = (kd, out[name][1])
        elif key == "map_Kd" and len(parts) > 1:
            # options (-s 1 1 1, -bm 2, ...) come first; the file name is the rest
            fname = parts[-1] if parts[1].startswith("-") else raw.split(None, 1)[1].strip()
            out[name] = (out[name][0], fname)
    return out


def _obj_material_colours(
    data: bytes,
    block: bytes,
    ftok: np.ndarray,
    vi: np.ndarray,
    nv: int,
    files: Files,
    strict: bool,
    what: str,
    max_pixels: int,
) -> tuple[np.ndarray | None, tuple | None]:
    """(nv, 3) uint8 vertex colours from the OBJ's materials, or None (no usable material),
    and the corners' texture mapping ((c, 2) glTF UVs, NaN where none; (c,) image index, -1
    where none; the images), or None without a texture.

    Each face corner takes its material's ``map_Kd`` texture at the corner's ``vt`` (bilinear;
    ``Kd`` is not multiplied in, as most viewers do) or, without a texture, its ``Kd``; a vertex
    takes the mean over its corners (a scan's texture detail finer than its vertex spacing is
    averaged away). Vertices with no coloured corner take the mean colour.
    """
    from core.io.images import decode_image, sample_image

    libs = [m.strip().decode("utf-8", "replace") for m in _OBJ_MTLLIB.findall(data)]
    if not libs:
        return None, None
    materials: dict[str, tuple[np.ndarray | None, str | None]] = {}
    for lib in libs:
        text = files(lib)
        if text is None:
            if strict:
                raise InputFormatError(f"{what}: the material file {lib!r} named by the OBJ "
                                       "is missing; add it to the archive")  # fmt: skip
            continue
        materials.update(_mtl_materials(text))
    use = _OBJ_USEMTL.findall(data)
    if not materials or not use:
        return None, None
    names = [u.strip().decode("utf-8", "replace") for u in use]
    u_pos = np.array([m.start() for m in _OBJ_USEMTL.finditer(data)])
    f_pos = np.array([m.start() for m in _OBJ_F.finditer(data)])
    corner_mat = np.repeat(np.searchsorted(u_pos, f_pos) - 1, ftok)  # -1: before any usemtl
    vt_lines = _OBJ_VT.findall(data)
    corner_vt = _corner_vt(data, block, ftok, what) if vt_lines else None
    uvs = None
    if corner_vt is not None:
        uvs = _obj_vt(vt_lines, what)
        if not np.isfinite(uvs).all():
            raise InputFormatError(f"{what}: OBJ texture coordinates must be finite")
    acc = np.zeros((nv, 3))
    cnt = np.zeros(nv)
    budget = max_pixels
    corner_uv = np.full((len(vi), 2), np.nan)
    corner_img = np.full(len(vi), -1, dtype=np.int64)
    images: list[np.ndarray] = []
    for m, mname in enumerate(names):
        corners = np.flatnonzero(corner_mat == m)
        if mname not in materials or not len(corners):
            continue
        kd, image = materials[mname]
        rgb = None
        if image is not None and uvs is not None:
            img_bytes = files(image)
            if img_bytes is None:
                if strict:
                    raise InputFormatError(
                        f"{what}: the texture {image!r} named by material {mname!r} is "
                        "missing; add it to the archive"
                    )
            else:
                img = decode_image(img_bytes, name=f"{what}: texture {image!r}", max_pixels=budget)
                budget -= img.shape[0] * img.shape[1]
                t = corner_vt[corners]
                ok = (t >= 0) & (t < len(uvs))
                corners = corners[ok]
                uv = uvs[t[ok]] * [1.0, -1.0] + [0.0, 1.0]  # OBJ v up -> glTF v down
                rgb = sample_image(img, uv)
                corner_uv[corners] = uv
                corner_img[corners] = len(images)
                images.append(img)
        if rgb is None and kd is not None:
            rgb = np.broadcast_to(kd, (len(corners), 3))
        if rgb is None:
            continue
        v = vi[corners]
        for c in range(3):
            acc[:, c] += np.bincount(v, weights=rgb[:, c], minlength=nv)
        cnt += np.bincount(v, minlength=nv)
    if not cnt.any():
        return None, None
    has = cnt > 0
    acc[has] /= cnt[has, None]
    acc[~has] = acc[has].mean(axis=0)
    texture = (corner_uv, corner_img, images) if images else None
    return np.clip(np.round(acc * 255.0), 0, 255).astype(np.uint8), texture


def _folder_files(folder: Path) -> Files:
    """Files beside an OBJ on disk: looked up by base name in its folder only (never a path
    named in the file, so an OBJ cannot read outside its folder)."""

    def get(name: str) -> bytes | None:
        base = Path(name.strip().strip('"').replace("\\", "/")).name
        p = folder / base
        if not base or not p.is_file():
            return None
        if p.stat().st_size > MAX_SIDECAR_BYTES:
            raise InputFormatError(f"{base} is larger than {MAX_SIDECAR_BYTES:,} bytes")
        return p.read_bytes()

    return get


def _zip_kind(data: bytes) -> str:
    """``zip`` for an archive holding an OBJ (a textured-OBJ bundle), else ``npz``."""
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as z:
            names = z.namelist()
    except Exception:
        return "npz"  # the NPZ reader explains what is wrong
    return "zip" if any(n.lower().endswith(".obj") for n in names) else "npz"


def _bundle(data: bytes, what: str) -> tuple[zipfile.ZipFile, zipfile.ZipInfo, Files]:
    """The archive, its one OBJ member and a reader of the other members (by path or by base
    name, case-insensitive), each inflated with its declared size as a hard cap."""
    try:
        z = zipfile.ZipFile(io.BytesIO(data))
        infos = [i for i in z.infolist() if not i.is_dir()]
    except Exception as e:
        raise InputFormatError(f"{what}: not a valid ZIP archive ({type(e).__name__})") from None
    if len(infos) > MAX_BUNDLE_MEMBERS:
        raise InputFormatError(
            f"{what}: the archive has {len(infos)} files; at most {MAX_BUNDLE_MEMBERS} (one OBJ, "
            "its MTL and its textures)"
        )
    objs = [i for i in infos if i.filename.lower().endswith(".obj")]
    if len(objs) != 1:
        raise InputFormatError(
            f"{what}: the archive must hold exactly one .obj file (with its .mtl and texture "
            f"images), found {len(objs)}"
        )
    inflated = sum(i.file_size for i in infos)
    limit = min(MAX_BUNDLE_BYTES, MAX_BUNDLE_RATIO * len(data))
    if inflated > limit:
        raise InputFormatError(
            f"{what}: the archive declares {inflated:,} bytes inflated, more than {limit:,} "
            f"({MAX_BUNDLE_RATIO}x its size, at most {MAX_BUNDLE_BYTES:,}); a textured scan's "
            "OBJ, MTL and images do not compress that much",
            inflated_bytes=inflated,
            limit_bytes=limit,
        )
    by_path = {i.filename.replace("\\", "/").lower(): i for i in infos}
    by_base: dict[str, zipfile.ZipInfo] = {}
    for i in infos:
        by_base.setdefault(i.filename.replace("\\", "/").rsplit("/", 1)[-1].lower(), i)
    folder = objs[0].filename.replace("\\", "/").rpartition("/")[0]

    def get(name: str) -> bytes | None:
        n = name.strip().strip('"').replace("\\", "/").lower()
        info = by_path.get(f"{folder.lower()}/{n}" if folder else n) or by_path.get(n)
        info = info or by_base.get(n.rsplit("/", 1)[-1])
        if info is None:
            return None
        if info.file_size > MAX_SIDECAR_BYTES:
            raise InputFormatError(f"{what}: {info.filename!r} is larger than "
                                   f"{MAX_SIDECAR_BYTES:,} bytes")  # fmt: skip
        return _member(z, info, what)

    return z, objs[0], get


def _member(z: zipfile.ZipFile, info: zipfile.ZipInfo, what: str) -> bytes:
    """A member's bytes, never more than its declared size."""
    try:
        with z.open(info) as f:
            out = f.read(info.file_size + 1)
    except Exception as e:
        raise InputFormatError(
            f"{what}: cannot inflate {info.filename!r} ({type(e).__name__})"
        ) from None
    if len(out) != info.file_size:
        raise InputFormatError(f"{what}: {info.filename!r} is not the size its header declares")
    return out


def _inspect_bundle(data: bytes, what: str) -> dict[str, Any]:
    """:func:`inspect_mesh_header` of a ZIP bundle: the OBJ's lines counted while it inflates
    in 16 MiB chunks (never held whole); ``inflated_bytes``: the members' declared total."""
    z, obj, _ = _bundle(data, what)
    nv = nf = 0
    normals = False
    with z, z.open(obj) as fh:
        tail = b""
        got = 0
        while True:
            chunk = fh.read(_INSPECT_CHUNK)
            got += len(chunk)
            if got > obj.file_size:
                raise InputFormatError(f"{what}: {obj.filename!r} is larger than declared")
            block = tail + chunk
            if chunk:
                cut = block.rfind(b"\n") + 1
                block, tail = block[:cut], block[cut:]
            nv += len(_OBJ_V.findall(block))
            nf += len(_OBJ_F.findall(block))
            normals = normals or bool(_OBJ_VN.search(block))
            if not chunk:
                break
        inflated = sum(i.file_size for i in z.infolist())
    return dict(format="zip", n_vertices=nv, n_faces=nf, has_normals=normals,
                has_confidence=False, inflated_bytes=inflated)  # fmt: skip


def _read_zip(
    data: bytes,
    what: str,
    max_vertices: int | None,
    max_faces: int | None,
    max_pixels: int = MAX_TEXTURE_PIXELS,
) -> RawMesh:
    """A ZIP bundle: one OBJ with its MTL and texture images (every file it names must be in
    the archive)."""
    z, obj, files = _bundle(data, what)
    with z:
        text = _member(z, obj, what)
        return _read_obj(
            text, f"{what} ({obj.filename})", max_vertices, max_faces, files, True, max_pixels
        )


def _read_glb(
    data: bytes,
    what: str,
    max_vertices: int | None,
    max_faces: int | None,
    max_pixels: int = MAX_TEXTURE_PIXELS,
) -> RawMesh:
    """GLB: the default scene's triangle/point primitives merged, in world coordinates;
    colours from the base colour texture at ``TEXCOORD`` (times ``COLOR_0`` and the material's
    factor, applied to the stored values), else ``COLOR_0``."""
    from core.io.glb import read_glb_primitives
    from core.io.images import decode_image, sample_image

    prims = read_glb_primitives(data, what, max_vertices=max_vertices, max_faces=max_faces)
    coloured = any(p.image is not None or p.colors is not None for p in prims)
    Vs, Fs, Ns, Cs, UVs, Is = [], [], [], [], [], []
    off = 0
    budget = max_pixels
    images: dict[bytes, np.ndarray] = {}
    for p in prims:
        n = len(p.V)
        Vs.append(p.V)
        Ns.append(p.normals)
        k = -1  # the primitive's image in the texture mapping (plain textures only)
        if coloured:
            c = np.ones((n, 3)) if p.colors is None else p.colors
            if p.image is not None:
                if p.image not in images:
                    images[p.image] = decode_image(p.image, name=f"{what}: base colour texture",
                                                   max_pixels=budget)  # fmt: skip
                    budget -= images[p.image].shape[0] * images[p.image].shape[1]
                c = c * sample_image(images[p.image], p.uv)
                if p.colors is None and np.all(p.factor == 1.0):
                    k = list(images).index(p.image)
            Cs.append(c * p.factor)
        if p.F is not None:
            Fs.append(p.F + off)
            UVs.append(p.uv[p.F] if k >= 0 else np.zeros((len(p.F), 3, 2)))
            Is.append(np.full(len(p.F), k, dtype=np.int16))
        off += n
    V = np.concatenate(Vs)
    F = np.concatenate(Fs) if Fs else None
    normals = np.concatenate(Ns) if all(x is not None for x in Ns) else None
    colors = texture = None
    if coloured:
        colors = np.clip(np.round(np.concatenate(Cs) * 255.0), 0, 255).astype(np.uint8)
    if F is not None and any((i >= 0).any() for i in Is):
        uv = np.concatenate(UVs).astype(np.float32)
        texture = ScanTexture(uv=uv, image=np.concatenate(Is), images=list(images.values()))
    return _finish(RawMesh(V=V, F=F, normals=normals, colors=colors, texture=texture), what)


# --------------------------------------------------------------------------------------------
# STL


def _merge_vertices(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge exactly coincident points (first-appearance order) -> (V, inverse)."""
    P = np.ascontiguousarray(P + 0.0)  # -0.0 -> +0.0
    void = P.view(np.dtype((np.void, P.dtype.itemsize * 3))).ravel()
    _, first, inv = np.unique(void, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return P[first[order]], rank[inv.ravel()]


def _stl_triangles(head: bytes, size: int, what: str) -> int | None:
    """Triangles of a binary STL (from its first bytes ``head`` and size), None for ASCII.

    Binary when the size matches the declared count. Else ASCII when the file starts with
    ``solid`` and its first 4 KiB are text (a binary count below 2^24 holds a NUL byte; many
    binary headers start with "solid" too). Else binary all the same: with bytes beyond the
    declared triangles (padding some exporters add: ignored), or with a count of 0 over whole
    50-byte records (a streaming writer that never wrote the count: the records are read).
    """
    text = head[:4096]
    ascii_ = b"\0" not in text and text.lstrip()[:5].lower() == b"solid"
    if size < 84:
        if ascii_:
            return None
        raise InputFormatError(f"{what}: not an STL file ({size} bytes, no 'solid' keyword)")
    n = int(np.frombuffer(head, "<u4", 1, 80)[0])
    if 84 + 50 * n == size:
        return n
    if ascii_:
        return None
    if n == 0 and (size - 84) % 50 == 0:
        return (size - 84) // 50
    if 84 + 50 * n < size:
        return n
    raise InputFormatError(
        f"{what}: binary STL declares {n:,} triangles ({84 + 50 * n:,} bytes) but the "
        f"file has {size:,} bytes; the upload is truncated or corrupt",
        n_faces=n,
    )


_STL_VERTEX = re.compile(rb"^[ \t]*vertex[ \t]+(\S+)[ \t]+(\S+)[ \t]+(\S+)", re.M | re.I)


def _read_stl(data: bytes, what: str, max_vertices: int | None, max_faces: int | None) -> RawMesh:
    """Binary or ASCII STL (keywords in any case); coincident corners are merged."""
    n = _stl_triangles(data[:4096], len(data), what)
    if n is not None:
        _check_limits(0, n, None, max_faces, what)
        _check_limits(3 * n, 0, max_vertices, None, what + " (before merging duplicates)")
        dt = np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
        rec = np.frombuffer(data, dt, n, 84)
        P = rec["v"].reshape(-1, 3).astype(np.float64)
    else:
        found = _STL_VERTEX.findall(data)
        if len(found) % 3:
            raise InputFormatError(
                f"{what}: ASCII STL has {len(found)} 'vertex' lines, not a multiple of 3; "
                "the file is truncated or corrupt"
            )
        _check_limits(len(found), len(found) // 3, max_vertices, max_faces, what)
        P = _parse_floats(b" ".join(b" ".join(t) for t in found), f"{what} (STL vertices)")
        P = P.reshape(-1, 3)
    if len(P) == 0:
        raise InputFormatError(f"{what}: STL file contains no triangles")
    _check_nonfinite(P, what)
    V, inv = _merge_vertices(P)
    return _finish(RawMesh(V=V, F=inv.reshape(-1, 3).astype(np.int64)), what)


# --------------------------------------------------------------------------------------------
# NPZ

_NPZ_KEYS = {
    "V": ("vertices", "V", "points"),
    "F": ("faces", "F", "triangles"),
    "normals": ("normals", "N"),
    "confidence": ("confidence",),
    "colors": ("colors",),
}
_NPZ_NAMES = tuple(k for keys in _NPZ_KEYS.values() for k in keys)


class _NpyMember:
    """One ``.npy`` member of an NPZ: its header, read without inflating the data."""

    __slots__ = ("dtype", "fortran", "info", "offset", "shape")

    def __init__(self, info: zipfile.ZipInfo, shape, fortran: bool, dtype, offset: int):
        self.info, self.shape, self.fortran, self.dtype, self.offset = (
            info, tuple(int(s) for s in shape), fortran, dtype, offset
        )  # fmt: skip

    @property
    def nbytes(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64)) * self.dtype.itemsize


def _npz_members(
    z: zipfile.ZipFile, what: str, max_vertices: int | None, max_faces: int | None
) -> dict[str, _NpyMember]:
    """Headers of an NPZ's arrays, checked before any data are inflated.

    Only the arrays a scan can use (``_NPZ_NAMES``) are allowed; each must be a plain numeric
    array whose shape fits the limits, and the member's declared size must match its header
    (so reading it can inflate at most that many bytes).
    """
    out: dict[str, _NpyMember] = {}
    for info in z.infolist():
        if info.is_dir():
            continue
        key = info.filename[:-4] if info.filename.endswith(".npy") else None
        if key not in _NPZ_NAMES:
            raise InputFormatError(
                f"{what}: NPZ member {info.filename[:80]!r} is not a scan array; an NPZ scan may "
                f"hold only {', '.join(k + '.npy' for k in _NPZ_NAMES)}",
                member=info.filename[:80],
            )
        with z.open(info) as f:
            ver = np.lib.format.read_magic(f)
            if ver == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
            elif ver == (2, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
            else:
                raise InputFormatError(
                    f"{what}: NPZ member '{info.filename}' uses .npy format {ver}; "
                    "save it with numpy's default format (1.0 or 2.0)"
                )
            offset = f.tell()
        m = _NpyMember(info, shape, fortran, dtype, offset)
        if dtype.kind not in "biuf" or dtype.itemsize > 8 or dtype.hasobject:
            raise InputFormatError(
                f"{what}: NPZ array '{key}' must be numeric (bool, int or float up to 64 bits), "
                f"got {dtype}"
            )
        if info.file_size != offset + m.nbytes:
            raise InputFormatError(
                f"{what}: NPZ member '{info.filename}' is {info.file_size:,} bytes uncompressed "
                f"but its header describes {offset + m.nbytes:,}; the archive is corrupt"
            )
        out[key] = m
    kv = _npz_pick(out, "V")
    if kv is None:
        raise InputFormatError(
            f"{what}: NPZ has no vertex array; store it under 'vertices' (or 'V'); "
            f"found keys {sorted(out)}"
        )
    for keys in _NPZ_KEYS.values():
        if sum(k in out for k in keys) > 1:
            raise InputFormatError(f"{what}: NPZ holds more than one of {keys}; keep one")
    nv = out[kv].shape[0] if out[kv].shape else 0
    kf = _npz_pick(out, "F")
    nf = out[kf].shape[0] if kf and out[kf].shape else 0
    _check_limits(nv, nf, max_vertices, max_faces, what)
    for field, want in (("V", (nv, 3)), ("normals", (nv, 3)), ("confidence", (nv,)),
                        ("colors", (nv, 3)), ("F", (nf, 3))):  # fmt: skip
        k = _npz_pick(out, field)
        if k is not None and out[k].shape != want:
            raise InputFormatError(
                f"{what}: NPZ array '{k}' must have shape "
                f"{'(n, 3)' if field == 'V' else '(m, 3)' if field == 'F' else want}, "
                f"got {out[k].shape}"
            )
    return out


def _npz_array(z: zipfile.ZipFile, m: _NpyMember, what: str) -> np.ndarray:
    """Inflate exactly one member's ``m.nbytes`` data bytes (never more)."""
    buf = bytearray(m.nbytes)
    view = memoryview(buf)
    with z.open(m.info) as f:
        f.seek(m.offset)
        got = 0
        while got < m.nbytes:
            chunk = f.read(min(m.nbytes - got, 1 << 22))
            if not chunk:
                raise InputFormatError(f"{what}: NPZ member '{m.info.filename}' is truncated")
            view[got : got + len(chunk)] = chunk
            got += len(chunk)
    a = np.frombuffer(buf, m.dtype)
    return a.reshape(m.shape, order="F" if m.fortran else "C")


def _npz_open(data: bytes, what: str) -> zipfile.ZipFile:
    try:
        return zipfile.ZipFile(io.BytesIO(data))
    except Exception as e:  # zipfile raises many types on corrupt input
        raise InputFormatError(f"{what}: not a valid NPZ archive ({type(e).__name__})") from None


def _npz_pick(arrays: dict, field: str) -> str | None:
    return next((k for k in _NPZ_KEYS[field] if k in arrays), None)


def _read_npz(data: bytes, what: str, max_vertices: int | None, max_faces: int | None) -> RawMesh:
    with _npz_open(data, what) as z:
        try:
            members = _npz_members(z, what, max_vertices, max_faces)
            arr = {k: _npz_array(z, m, what) for k, m in members.items()}
        except InputFormatError:
            raise
        except Exception as e:  # corrupt headers or members
            raise InputFormatError(
                f"{what}: cannot load the NPZ arrays ({type(e).__name__}: {str(e)[:200]})"
            ) from None

    def get(field: str, dtype) -> np.ndarray | None:
        k = _npz_pick(arr, field)
        if k is None:
            return None
        a = arr[k]
        if (
            field == "F"
            and a.dtype.kind == "f"
            and (not np.all(np.isfinite(a)) or np.any(a != np.round(a)))
        ):
            raise InputFormatError(f"{what}: NPZ face indices must be integers")
        if field == "colors" and a.dtype.kind == "f":
            a = np.clip(np.round(a * 255.0), 0, 255)
        return a.astype(dtype)

    raw = RawMesh(
        V=get("V", np.float64),
        F=get("F", np.int64),
        normals=get("normals", np.float64),
        confidence=get("confidence", np.float64),
        colors=get("colors", np.uint8),
    )
    if raw.F is not None and len(raw.F) == 0:
        raw.F = None
    return _finish(raw, what)


# --------------------------------------------------------------------------------------------
# XYZ / PTS


_XYZ_NORMALS = (("nx", "ny", "nz"), ("normal_x", "normal_y", "normal_z"))
_XYZ_COLORS = (("r", "g", "b"), ("red", "green", "blue"), ("rf", "gf", "bf"))  # rf: floats


def _xyz_columns(tab: np.ndarray, names: list[str] | None) -> tuple[int | None, int | None]:
    """First columns of the normals and of the colours (None: absent) of a text point cloud's
    table (n, w), from its header's column names when they name every column, else from the
    values: normals are a unit-length triple (or 0 0 0), colours a triple of integers in
    0-255 or of values in [0, 1]; of 7 columns, integers after a 4th (PTS: x y z intensity r g
    b) come first."""
    w = tab.shape[1]
    if names is not None and len(names) == w:
        named = {tuple(names[i : i + 3]): i for i in range(w - 3, 2, -1)}  # the first wins
        ni = next((named[t] for t in _XYZ_NORMALS if t in named), None)
        return ni, next((named[t] for t in _XYZ_COLORS if t in named), None)

    def unit(c: np.ndarray) -> bool:
        r = np.linalg.norm(c, axis=1)
        return bool(np.all((np.abs(r - 1.0) < 1e-2) | (r == 0.0)) and np.any(r > 0.0))

    def colour(c: np.ndarray, floats: bool) -> bool:
        return bool(np.all((c >= 0) & (c <= 255) & (c == np.round(c)))) or (
            floats and bool(np.all((c >= 0) & (c <= 1)))
        )

    normals = next((i for i in range(3, w - 2) if unit(tab[:, i : i + 3])), None)
    # (first column, floats allowed); PTS colours are 8-bit integers
    tries = [(4, False), (3, True), (4, True)] if w == 7 else [(i, True) for i in range(3, w - 2)]
    colors = next((i for i, floats in tries if (normals is None or abs(i - normals) >= 3)
                   and colour(tab[:, i : i + 3], floats)), None)  # fmt: skip
    return normals, colors


def _read_xyz(data: bytes, what: str, max_vertices: int | None, max_faces: int | None) -> RawMesh:
    """Text point cloud: ``x y z`` then, by the header's column names (CloudCompare's
    ``//X,Y,Z,R,G,B,Nx,Ny,Nz``) or else by their values, normals and colours in any order."""
    text = data.replace(b",", b" ").replace(b";", b" ")
    lines = [ln for ln in text.splitlines() if ln.strip()]
    names = None  # the last comment or header row before the first point
    while lines and (lines[0].lstrip()[:1].isalpha() or lines[0].lstrip()[:1] in (b"#", b"/")):
        names = lines.pop(0).decode("latin-1").lstrip("#/ \t").lower().split()
    lines = [ln for ln in lines if not ln.lstrip().startswith((b"#", b"//"))]
    if lines and len(lines[0].split()) == 1:  # PTS point count line
        lines = lines[1:]
    _check_limits(len(lines), 0, max_vertices, None, what)
    if not lines:
        raise InputFormatError(f"{what}: point cloud file has no points")
    if lines[0].lstrip()[:1].isalpha():  # header row such as "x y z" after the count
        names = lines.pop(0).decode("latin-1").lower().split()
    ntok = _tokens_per_line(lines)
    w = int(ntok[0]) if len(ntok) else 0
    bad = np.flatnonzero(ntok != w)
    if len(bad):
        i = int(bad[0])
        raise InputFormatError(
            f"{what}: point line {i + 1} has {ntok[i]} values but the first has {w}: "
            f"{lines[i].decode('latin-1').strip()[:80]!r}"
        )
    if w < 3:
        raise InputFormatError(f"{what}: point lines need at least 3 values (x y z), got {w}")
    tab = _parse_floats(b"\n".join(lines), what).reshape(len(lines), w)
    V = tab[:, :3].copy()
    ni, ci = _xyz_columns(tab, names)
    normals = None if ni is None else tab[:, ni : ni + 3].copy()
    colors = None
    if ci is not None:
        c = tab[:, ci : ci + 3]
        float01 = np.all(c <= 1.0) and np.any(c != np.round(c))
        colors = np.clip(np.round(c * 255.0 if float01 else c), 0, 255).astype(np.uint8)
    return _finish(RawMesh(V=V, normals=normals, colors=colors), what)


# --------------------------------------------------------------------------------------------
# validation


def _check_nonfinite(V: np.ndarray, what: str) -> None:
    if np.isfinite(V.sum()):  # one reduction; NaN/Inf propagate (overflow to Inf: checked below)
        return
    bad = ~np.isfinite(V).all(axis=1)
    if bad.any():
        nb = int(bad.sum())
        first = int(np.flatnonzero(bad)[0])
        raise InputFormatError(
            f"{what}: {nb:,} of {len(V):,} vertices have non-finite coordinates (NaN or Inf), "
            f"the first is vertex {first}; remove those points (and faces using them) from "
            "the scan and upload again",
            n_nonfinite=nb,
            first_index=first,
        )


def _unit_interval(c: np.ndarray) -> bool:
    """Whether every value lies in [0, 1] (up to round-off), none NaN."""
    return bool(np.all((c >= -_CONF_TOL) & (c <= 1 + _CONF_TOL)))


def _finish(raw: RawMesh, what: str) -> RawMesh:
    """Common validation of a freshly read mesh."""
    V = raw.V
    if len(V) == 0:
        raise InputFormatError(f"{what}: the file contains no vertices")
    _check_nonfinite(V, what)
    if raw.F is not None:
        F = raw.F
        if len(F) == 0:
            raw.F = None
        else:
            nv = len(V)
            if F.min() < 0 or F.max() >= nv:
                bad = (F < 0) | (nv <= F)
                row = int(np.flatnonzero(bad.any(axis=1))[0])
                val = int(F[row][bad[row]][0])
                raise InputFormatError(
                    f"{what}: face index {val} (triangle {row}) is out of range; the mesh has "
                    f"{len(V):,} vertices (valid indices 0..{len(V) - 1}); "
                    "the file is corrupt or vertices were removed without updating the faces",
                    face=row,
                    index=val,
                )
            raw.F = np.ascontiguousarray(F, dtype=np.int64)
    if raw.normals is not None:
        n = raw.normals
        ok = np.isfinite(n).all(axis=1)
        if not ok.all():
            n = np.where(ok[:, None], n, 0.0)
        raw.normals = np.ascontiguousarray(n, dtype=np.float64)
    if raw.confidence is not None:
        c = raw.confidence
        if not np.isfinite(c).all():
            raise InputFormatError(
                f"{what}: {int((~np.isfinite(c)).sum()):,} confidence values are NaN or Inf; "
                "confidence must be in [0, 1]; fix or remove the confidence property"
            )
        lo, hi = float(c.min()), float(c.max())
        if lo < -_CONF_TOL or hi > 1 + _CONF_TOL:
            raise InputFormatError(
                f"{what}: per-vertex confidence must be in [0, 1] but ranges {lo:g}..{hi:g}; "
                "rescale it to [0, 1] or remove the property (it will then be estimated)",
                min=lo,
                max=hi,
            )
        raw.confidence = np.clip(c, 0.0, 1.0)
    return raw


# --------------------------------------------------------------------------------------------
# public API

_READERS = {
    "ply": _read_ply,
    "obj": _read_obj,
    "stl": _read_stl,
    "npz": _read_npz,
    "xyz": _read_xyz,
    "pts": _read_xyz,
    "glb": _read_glb,
    "zip": _read_zip,
}


def read_mesh(
    source: Source,
    fmt: str | None = None,
    *,
    max_vertices: int = 5_000_000,
    max_faces: int = 10_000_000,
    name: str | None = None,
    sidecar_files: bool = True,
    max_texture_pixels: int = MAX_TEXTURE_PIXELS,
) -> RawMesh:
    """Read a scan mesh or point cloud in the file's units and axes.

    Parameters
    ----------
    source : path or bytes
        The file, or its content (then give ``fmt`` or rely on magic-byte sniffing).
    fmt : {"ply", "obj", "stl", "npz", "xyz", "pts"}, optional
        Format; by default from the extension, else from the content.
    max_vertices, max_faces : int
        Limits checked before the data are parsed (faces after fan triangulation may be more).
    name : str, optional
        What error messages call the file (e.g. an upload's filename); default its path.
    sidecar_files : bool
        For an OBJ or PLY read from a path: read the MTL and texture images it names from its
        own folder (by base name only). A service reading stored uploads passes False.
    max_texture_pixels : int
        Limit on the summed width x height of a scan's texture images (checked from their
        headers before decoding).

    Returns
    -------
    RawMesh
        ``V`` (n, 3) float64, ``F`` (m, 3) int64 or None (point cloud), optional normals,
        confidence in [0, 1] and colours (per vertex; from a texture: sampled at the vertex's
        UVs, see :func:`_obj_material_colours`).

    Textured scans: an OBJ with ``mtllib``/``usemtl``, ``vt`` and ``v/vt`` faces whose material
    has a ``map_Kd`` image (PNG/JPEG) -- beside the OBJ on disk, or zipped with it (format
    ``zip``: one ``.obj``, its ``.mtl`` and images) --, a PLY with ``comment TextureFile``
    images beside it and face ``texcoord`` lists or vertex ``texture_u``/``texture_v``
    (MeshLab, Metashape), or a GLB whose material has a ``baseColorTexture`` (embedded
    PNG/JPEG) over ``TEXCOORD_0``.

    Raises
    ------
    InputFormatError
        Empty, truncated, corrupt or unknown files, out-of-range face indices, non-finite
        coordinates, confidence outside [0, 1], counts above the limits.
    """
    head, size = _read_prefix(source)
    what = _name(source) if name is None else name
    if size == 0:
        raise InputFormatError(f"{what} is empty (0 bytes); upload a non-empty scan file")
    f = _detect_format(source, head, size, fmt, what)
    if f == "ply":  # check limits from the header before reading the body
        _, elements, _ = _ply_header(head, what)
        _check_limits(*_ply_counts(elements), max_vertices, max_faces, what)
    data = _read_all(source)
    if f == "npz" and fmt is None:
        f = _zip_kind(data)
    reader = _READERS[f]
    if f in ("obj", "ply"):
        folder = None
        if sidecar_files and not isinstance(source, bytes | bytearray | memoryview):
            folder = _folder_files(Path(source).resolve().parent)
        reader = functools.partial(reader, files=folder, max_pixels=max_texture_pixels)
    elif f in ("zip", "glb"):
        reader = functools.partial(reader, max_pixels=max_texture_pixels)
    try:
        with np.errstate(all="ignore"):
            return reader(data, what, max_vertices, max_faces)
    except InputFormatError:
        raise
    except Exception as e:  # last resort: corrupt data must never crash the caller
        raise InputFormatError(
            f"{what}: cannot parse the {f.upper()} data ({type(e).__name__}: {e}); the file is "
            "corrupt or not in the format its name says",
            fmt=f,
        ) from None


def inspect_mesh_header(
    path_or_bytes: Source,
    fmt: str | None = None,
    *,
    max_vertices: int | None = None,
    max_faces: int | None = None,
    name: str | None = None,
) -> dict[str, Any]:
    """Validate a scan's header cheaply, e.g. before a web service accepts an upload.

    PLY, binary STL and NPZ are inspected from their headers only (a binary PLY's size is
    checked against what the header promises). OBJ, ASCII STL and XYZ have no header, so their
    lines are counted (no float parsing). For STL, ``n_vertices`` is ``3 * n_faces``, an upper
    bound before duplicate vertices are merged.

    Returns
    -------
    dict
        ``format`` (str), ``n_vertices`` (int), ``n_faces`` (int, triangles before fan
        triangulation for polygon formats), ``has_normals`` (bool), ``has_confidence`` (bool);
        for a ZIP bundle also ``inflated_bytes`` (int, what reading it inflates).

    Raises
    ------
    InputFormatError
        Empty, unknown or malformed files, truncated binary PLY/STL, counts above the limits.
    """
    head, size = _read_prefix(path_or_bytes)
    what = _name(path_or_bytes) if name is None else name
    if size == 0:
        raise InputFormatError(f"{what} is empty (0 bytes); upload a non-empty scan file")
    f = _detect_format(path_or_bytes, head, size, fmt, what)
    if f == "npz" and fmt is None:
        f = _zip_kind(_read_all(path_or_bytes))
    out: dict[str, Any]
    if f == "ply":
        pfmt, elements, off = _ply_header(head, what)
        nv, nf = _ply_counts(elements)
        vprops = next((e for e in elements if e.name == "vertex"), None)
        if vprops is None:
            raise InputFormatError(f"{what}: PLY file has no 'vertex' element")
        names = {p.name for p in vprops.props}
        if pfmt != "ascii":
            need = 0
            for e in elements:
                for p in e.props:
                    if p.count_type is None:
                        need += e.count * np.dtype(p.type).itemsize
                    else:  # a polygon has at least 3 corners; other lists may be empty
                        k = 3 if p.name in ("vertex_indices", "vertex_index") else 0
                        need += e.count * (
                            np.dtype(p.count_type).itemsize + k * np.dtype(p.type).itemsize
                        )
            if off + need > size:
                raise InputFormatError(
                    f"{what}: binary PLY header promises at least {off + need:,} bytes but the "
                    f"file has {size:,}; the upload is truncated or the header count is wrong"
                )
        out = dict(
            format="ply",
            n_vertices=nv,
            n_faces=nf,
            has_normals=any(set(ns) <= names for ns in _PLY_NORMALS),
            has_confidence=any(c.lower() in _CONF_NAMES for c in names),
        )
    elif f == "stl":
        nf = _stl_triangles(head, size, what)
        if nf is None:
            nf = len(re.findall(rb"\bfacet\b", _read_all(path_or_bytes), re.I))
        out = dict(
            format="stl", n_vertices=3 * nf, n_faces=nf, has_normals=False, has_confidence=False
        )
    elif f == "npz":
        with _npz_open(_read_all(path_or_bytes), what) as z:
            try:
                members = _npz_members(z, what, max_vertices, max_faces)
            except InputFormatError:
                raise
            except Exception as e:  # corrupt npy headers
                raise InputFormatError(
                    f"{what}: not a valid NPZ archive ({type(e).__name__})"
                ) from None
        shapes = {k: m.shape for k, m in members.items()}
        kv, kf = _npz_pick(shapes, "V"), _npz_pick(shapes, "F")
        out = dict(
            format="npz",
            n_vertices=int(shapes[kv][0]) if shapes[kv] else 0,
            n_faces=int(shapes[kf][0]) if kf and shapes[kf] else 0,
            has_normals=_npz_pick(shapes, "normals") is not None,
            has_confidence="confidence" in shapes,
        )
    elif f == "glb":
        from core.io.glb import glb_counts

        nv, nf, normals = glb_counts(_read_all(path_or_bytes), what)
        out = dict(
            format="glb", n_vertices=nv, n_faces=nf, has_normals=normals, has_confidence=False
        )
    elif f == "zip":
        out = _inspect_bundle(_read_all(path_or_bytes), what)
    elif f == "obj":
        data = _read_all(path_or_bytes)
        out = dict(
            format=f,
            n_vertices=len(_OBJ_V.findall(data)),
            n_faces=len(_OBJ_F.findall(data)),
            has_normals=bool(_OBJ_VN.search(data)),
            has_confidence=False,
        )
    else:
        data = _read_all(path_or_bytes)
        n = sum(
            1
            for ln in data.splitlines()
            if ln.strip() and not ln.lstrip().startswith((b"#", b"//"))
        )
        out = dict(format=f, n_vertices=n, n_faces=0, has_normals=False, has_confidence=False)
    if out["n_vertices"] == 0:
        raise InputFormatError(f"{what}: the file declares no vertices")
    _check_limits(out["n_vertices"], out["n_faces"], max_vertices, max_faces, what)
    return out
