"""Parse time of meshes whose faces mix triangles, quads and n-gons vs uniform triangles.

``python -m bench.mixed_faces [--faces N]``: binary and ASCII PLY and OBJ, each written with
faces alternating triangle / quad (and a pentagon every 7th face) and with triangles only, read by
``core.io.read_mesh`` and by trimesh (the library one would otherwise use); best of 3, CPU s.
"""

from __future__ import annotations

import argparse
import io
import time

import numpy as np


def mixed_polygons(n_faces: int, n_vertices: int, seed: int = 0) -> list[np.ndarray]:
    """Polygons alternating 3, 4 corners, every 7th a pentagon (random vertex indices)."""
    rng = np.random.default_rng(seed)
    ks = np.where(np.arange(n_faces) % 2 == 0, 3, 4)
    ks[::7] = 5
    flat = rng.integers(0, n_vertices, int(ks.sum()))
    return np.split(flat, np.cumsum(ks)[:-1])


def ply_binary(V: np.ndarray, polys: list[np.ndarray]) -> bytes:
    head = (
        f"ply\nformat binary_little_endian 1.0\nelement vertex {len(V)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        f"element face {len(polys)}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode()
    out = io.BytesIO()
    out.write(head)
    out.write(V.astype("<f4").tobytes())
    rows = bytearray()
    for p in polys:
        rows += bytes([len(p)]) + p.astype("<i4").tobytes()
    out.write(bytes(rows))
    return out.getvalue()


def ply_ascii(V: np.ndarray, polys: list[np.ndarray]) -> bytes:
    head = (
        f"ply\nformat ascii 1.0\nelement vertex {len(V)}\n"
        "property float x\nproperty float y\nproperty float z\n"
        f"element face {len(polys)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    vs = "\n".join(f"{x:.5f} {y:.5f} {z:.5f}" for x, y, z in V)
    fs = "\n".join(f"{len(p)} " + " ".join(map(str, p)) for p in polys)
    return (head + vs + "\n" + fs + "\n").encode()


def obj(V: np.ndarray, polys: list[np.ndarray]) -> bytes:
    vs = "\n".join(f"v {x:.5f} {y:.5f} {z:.5f}" for x, y, z in V)
    fs = "\n".join("f " + " ".join(str(i + 1) for i in p) for p in polys)
    return (vs + "\n" + fs + "\n").encode()


def cpu(fn, reps: int = 3) -> float:
    best = np.inf
    for _ in range(reps):
        t = time.process_time()
        fn()
        best = min(best, time.process_time() - t)
    return best


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--faces", type=int, default=200_000)
    args = ap.parse_args()
    from core.io import read_mesh

    nv = args.faces // 2
    V = np.random.default_rng(1).normal(size=(nv, 3))
    mixed = mixed_polygons(args.faces, nv)
    tris = list(np.random.default_rng(2).integers(0, nv, (args.faces, 3)))
    print(f"{args.faces:,} faces, {nv:,} vertices; best of 3 CPU seconds")
    print(f"{'file':28s} {'MB':>6s} {'bodyspace':>10s} {'trimesh':>8s}")
    for name, writer, ext in (("binary PLY", ply_binary, "ply"), ("ASCII PLY", ply_ascii, "ply"),
                              ("OBJ", obj, "obj")):  # fmt: skip
        for label, polys in (("triangles", tris), ("mixed 3/4/5", mixed)):
            data = writer(V, polys)
            ours = cpu(lambda d=data, e=ext: read_mesh(d, e))
            try:
                theirs = f"{cpu(lambda d=data, e=ext: _trimesh(d, e)):8.3f}"
            except Exception as err:  # reported in the table
                theirs = f"  fails ({type(err).__name__}: {str(err)[:40]})"
            print(f"{name + ', ' + label:28s} {len(data) / 1e6:6.1f} {ours:10.3f} {theirs}")


def _trimesh(data: bytes, ext: str):
    import trimesh

    return trimesh.load(io.BytesIO(data), file_type=ext, process=False)


if __name__ == "__main__":
    main()
