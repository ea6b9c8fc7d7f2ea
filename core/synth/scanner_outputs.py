"""What scanner software delivers, made from a known body (seeded test material).

Real booth and handheld scanners do not hand over our simulated raw range images: their software
closes holes, fuses fingers and arms touching the torso, smooths, decimates, adds hair, cuts the
soles flat or leaves a floor plate, and writes any units, up axis and facing. This module turns a
template-order body (see :mod:`core.synth.realworld`) into such outputs; :func:`make_case` and
:func:`benchmark_cases` assemble whole test cases with their truth.

Decisions
---------
- **Closed meshes** (:func:`closed_mesh`): the body is voxelised by its winding number (rays along
  +Z, union of overlapping parts, so LBS self-intersections become one solid), hands are inflated by
  max(4 mm, 0.4 voxel) (a mitten: sub-voxel fingers stay solid) and closed morphologically with a
  ball of 10–14 mm, at least two voxels (mitten hands, fused fingers), hair is added as solid
  volume, the soles are cut flat (3–8 mm above the floor) or a floor plate (10 mm, at least two
  voxels thick; a disc reaching 8–15 cm beyond the feet) is added, cavities are filled, and the
  surface is extracted by marching cubes (scikit-image, BSD) on a signed distance field that is
  exact near the original surface (distances to 1.5 mm surface samples) and an EDT distance where
  the volume was edited, truncated at ±1.5 voxels and smoothed by a Gaussian of 0.5 voxel. Only the
  largest component is kept (scanner software does), the winding is outward. Voxel 5–7 mm → 40–90 k
  vertices; 10–14 mm → the 8–20 k of decimated booth-scanner meshes. Every edge is shared by exactly
  two faces (tested).
- **Decimated meshes** (``closed_decimated``, :func:`decimated_cases`): what most scanner
  software writes at 10-20 k vertices: a fine closed mesh (5-7 mm grid, as above) decimated by
  quadric edge collapse (:func:`decimate`, fast-simplification, MIT) to a drawn 10-20 k vertices:
  the vertices stay on the fine surface, few on the flat torso (edges to 25 mm), many where it
  bends, spread evenly (nearest-neighbour distances' 90th/10th percentile 2.7-3.0 against
  marching cubes' 5-9). Its sampling (8 mm) says nothing of its detail: its fingertips and toes lie
  0-3 and 1-8 mm short of the truth's, a 12 mm grid's 4-14 and 5-10. mm, +Y up, floor 0, flat
  cut soles. Only in :func:`decimated_cases` (seeds 700 on), each with a ``raw`` twin; and
  ``closed_booth_decimated``: a booth subject (below; the same hair, arms, plate and vertex
  count as its ``closed_booth`` case) meshed on a 5-7 mm grid and decimated so
  (``bench.realworld --booth --decimated``); where an arm lay a voxel from the flank a collapse
  can join the two sheets along an edge: 0-6 edges in four faces, none open.
- **Hair** (:func:`hair_volume`): ``bun`` (sphere r 3.5–5.5 cm behind and above the
  opisthocranion), ``ponytail`` (capsule r 2.5–3.5 cm from the back of the head, 12–25 cm down and
  back), ``cap`` (the scalp above the tragion level thickened by 1–3 cm), or ``cap+bun``; and,
  only when asked for (``make_case(..., hair="long")``, not in the drawn styles, so every drawn
  case stays as it was), ``long``: loose hair to the shoulders — a layer of 1–2.5 cm over the
  crown and the back of the head, then a curtain hanging straight down from the back of the head
  to 3–20 cm below the cervicale, bridging the nape and lying on the upper back, as wide as the
  head at the ears and up to 11 cm each side of the midline at its ends (:func:`_long_hair`).
- **Booth meshes** (``closed_booth``, :func:`booth_cases`): issue 12's real subjects all at once:
  a closed mesh regridded once to a drawn 10–15 k vertices, mm, +Y up, hair drawn from none and
  :data:`HAIR_STYLES`, arms fused to the torso in 40 %, a floor plate in 20 %, any BMI (heavy
  bodies included). Seeds 300 on; the kind's randomness has its own stream (the other kinds'
  cases are unchanged by it).
- **Raw scans** come from :func:`core.synth.scanner.simulate_scan` of the off-model body
  (6 views, 4 mm pitch, 1 mm noise); ``make_case(..., hair=style)`` scans it with a hair solid's
  surface (:func:`hair_mesh`, 4 mm marching cubes) on the head, the scalp under it hidden.
  ``inward``: the faces (and normals) of both arms are wound inward. ``clutter``: 2–5 stray
  blobs (spheres r 2–6 cm, 0.3–1.2 m from the body) and a ring of floor points/triangles around
  the feet (r 0.25–0.6 m).
- **Scans without feet** (``raw_feetless`` / ``cloud_feetless`` / ``closed_feetless`` /
  ``capped_feetless``, :func:`feetless_cases`): scanners whose views miss the feet, or a floor
  cropped away with them, deliver a body that ends at the ankles: everything below a drawn
  6-12 cm over the soles is removed (points, and faces with them; a closed mesh is left open
  there, or closed by the software's cap, flat or domed: :func:`cap_cut`), random frame; the
  body stands leaned as a whole by −3 to +4° at the ankles (:data:`FEETLESS_LEAN_RANGE_DEG`).
- **Scans cut at the head** (``raw_headcut`` / ``cloud_headcut`` / ``closed_headcut`` /
  ``capped_headcut``, :func:`headcut_cases`): a tall subject in a short scan volume: everything
  above a drawn 3-9 cm below the crown is removed (a closed mesh is left open there, or closed
  by the software's cap, flat or domed 5-20 mm: :func:`cap_cut` mirrored), random frame.
- **Subjects who moved between views** (``raw_swayed`` / ``cloud_swayed``,
  :func:`swayed_cases`): a sequential capture (handheld sweeps, a turntable, booth heads firing
  in turn) sees the body once per view, each time swayed, the arms drifted and the chest
  breathing differently (:func:`core.synth.realworld.moved_views`; the motions' mean over the
  views taken out: the truth is where the subject stood on average); the skin then lies in
  layers a few millimetres apart. Random frame.
- **Point clouds** carry no normals: the raw scan's points (``cloud``), or 1.0–3.0 M points drawn
  uniformly by area on the true body surface with 0.5 mm noise and the soles removed
  (``dense``).
- **Frames**: units mm / cm / m, up axis any of ±X, ±Y, ±Z, facing any angle about the up axis, a
  translation up to 0.3 m; the booth-like ``closed_lowres`` family stays mm, +Y up, floor 0.
- **Markers** (:func:`other_convention_markers`): the 62 CAESAR landmarks or a 33-marker subset
  (:data:`SUBSET_33`); each is moved 2–5 cm along the surface from our definition in a direction
  fixed per convention (another team's habit, the same on every subject), plus 3 mm placement
  noise; 0–2 left/right pairs swapped and 0–4 markers missing per case.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy import ndimage
from scipy.spatial import Delaunay, cKDTree
from scipy.spatial.transform import Rotation

from core.geometry import MeshDistance, kept_faces
from core.io.frame import rotation_for_up
from core.synth.realworld import (
    PALM_TWIST_RANGE,
    WIDE_ARM_RANGE,
    mesh_volume,
    moved_views,
    off_model_body,
    posture,
    stand_leaned,
)
from core.synth.scanner import ScanConfig, simulate_scan, vertex_normals
from core.template import load_template

UNITS = {"m": 1.0, "cm": 100.0, "mm": 1000.0}
UPS = ("+x", "-x", "+y", "-y", "+z", "-z")
HAIR_STYLES = ("bun", "ponytail", "cap", "cap+bun")
#: Hair styles made only when asked for by name (``make_case(hair=)``): never drawn, so adding
#: them left every drawn case as it was.
EXTRA_HAIR_STYLES = ("long",)
#: Every hair style :func:`hair_volume` and ``make_case(hair=)`` take.
ALL_HAIR_STYLES = HAIR_STYLES + EXTRA_HAIR_STYLES

#: Case kinds: family name -> what it is.
KINDS = {
    "closed_lowres": "closed hole-filled mesh from booth software, 8-20 k vertices, mm, +Y up",
    "closed_hair": "closed mesh with hair volume, 40-90 k vertices",
    "closed_touching": "closed mesh, arms touching the torso (fused, mostly genus > 0)",
    "closed_plate": "closed mesh standing on a floor plate",
    "raw": "raw multi-view range scan (holes, duplicated overlaps)",
    "raw_inward": "raw multi-view scan, both arms' faces wound inward",
    "raw_clutter": "raw scan with stray blobs and floor points",
    "cloud": "point cloud of a raw scan, no normals",
    "dense": "dense point cloud, 1-3 M points, no normals",
    "closed_booth": "closed booth-software mesh (as issue 12's subjects), 10-15 k vertices, "
    "mm, +Y up, hair drawn (none, bun, ponytail, cap), arms touching the torso in 40 %",
    "raw_wide": "raw multi-view range scan, arms 60-90° from the body (T-pose capture)",
    "closed_wide": "closed mesh (5-7 mm grid), arms 60-90° from the body (T-pose capture)",
    "cloud_wide": "point cloud of a raw scan, no normals, arms 60-90° from the body",
    "raw_palms": "raw multi-view range scan, palms turned 45-100° forwards or backwards",
    "closed_palms": "closed hole-filled mesh, 8-20 k vertices, palms turned 45-100°",
    "closed_decimated": "closed mesh decimated by quadric edge collapse to 10-20 k vertices "
    "(from a 5-7 mm grid), mm, +Y up",
    "closed_booth_decimated": "closed_booth's subject (hair, touching arms, plate) meshed on a "
    "5-7 mm grid and decimated by quadric edge collapse to its 10-15 k vertices",
    "raw_tilted": "raw multi-view range scan in a handheld scanner's frame: the body 5-45° off "
    "every file axis",
    "cloud_tilted": "point cloud without normals in a handheld scanner's frame: the body 5-45° "
    "off every file axis",
    "closed_tilted": "closed mesh (5-7 mm grid) in a handheld scanner's frame: the body 5-45° "
    "off every file axis",
    "closed_filled": "closed mesh hole-filled from a raw scan (what the scanner missed bridged by "
    "a smooth membrane: armpits, crotch, crown, soles), decimated to 10-15 k vertices, mm, +Y up",
    "closed_booth_filled": "closed mesh hole-filled from a booth subject's raw scan (its hair, "
    "and arms touching the body, fused to it), decimated to 10-15 k vertices, mm, +Y up",
    "raw_feetless": "raw multi-view range scan that ends 6-12 cm above the soles (the feet "
    "missed or cropped with the floor)",
    "cloud_feetless": "point cloud without normals that ends 6-12 cm above the soles",
    "closed_feetless": "closed mesh (5-7 mm grid) that ends 6-12 cm above the soles, open there",
    "capped_feetless": "closed mesh (5-7 mm grid) that ends 6-12 cm above the soles, the cut "
    "closed by the scanner software (a flat or domed cap)",
    "raw_headcut": "raw multi-view range scan that ends 3-9 cm below the crown (a tall subject "
    "in a short scan volume)",
    "cloud_headcut": "point cloud without normals that ends 3-9 cm below the crown",
    "closed_headcut": "closed mesh (5-7 mm grid) that ends 3-9 cm below the crown, open there",
    "capped_headcut": "closed mesh (5-7 mm grid) that ends 3-9 cm below the crown, the cut "
    "closed by the scanner software (a flat or domed cap)",
    "raw_swayed": "raw multi-view range scan of a subject who moved between the views (sway, "
    "arms drifting, breathing)",
    "cloud_swayed": "point cloud without normals of a subject who moved between the views",
}
#: The wide-arms kinds (:data:`core.synth.realworld.WIDE_ARM_RANGE`: T-pose and near it) and the
#: kind each is delivered as; only in :func:`wide_cases` (``bench.realworld --wide``).
WIDE_KINDS = {"raw_wide": "raw", "closed_wide": "closed", "cloud_wide": "cloud"}
#: The turned-palms kinds (both forearms turned about their axes,
#: :data:`core.synth.realworld.PALM_TWIST_RANGE`) and the kind each is delivered as; only in
#: :func:`palm_cases` (``bench.realworld --palms``).
PALM_KINDS = {"raw_palms": "raw", "closed_palms": "closed_lowres"}
#: The tilted kinds (a handheld scanner's or an unlevelled rig's frame: the body turned
#: :data:`TILT_RANGE_DEG` about a random horizontal axis before the file's axes, units and
#: facing are drawn) and the kind each is delivered as; only in :func:`tilted_cases`
#: (``bench.realworld --tilted``).
TILTED_KINDS = {"raw_tilted": "raw", "cloud_tilted": "cloud", "closed_tilted": "closed"}
#: Tilts (degrees) of :data:`TILTED_KINDS`.
TILT_RANGE_DEG = (5.0, 45.0)
#: The feetless kinds (scans that end above the soles: a scanner whose views miss the feet, or
#: a floor cropped away with them; everything below :data:`FEETLESS_CUT_RANGE_M` over the soles
#: removed, faces with it) and the kind each is delivered as; only in :func:`feetless_cases`
#: (``bench.realworld --feetless``).
FEETLESS_KINDS = {
    "raw_feetless": "raw", "cloud_feetless": "cloud", "closed_feetless": "closed",
    "capped_feetless": "closed",
}  # fmt: skip
#: Heights (metres above the soles) below which a feetless kind holds nothing: the ankles
#: (lateral malleolus 6-8 cm up) to the lower shins.
FEETLESS_CUT_RANGE_M = (0.06, 0.12)
#: Whole-body lean (degrees, + forwards, about the floor under the body) of the feetless
#: kinds: their facing cue reads the legs' profile, which a lean tilts (:func:`make_case`).
FEETLESS_LEAN_RANGE_DEG = (-3.0, 4.0)
#: The head-cut kinds (scans that end below the crown: a tall subject in a short scan volume,
#: the top of the head cropped; everything above :data:`HEADCUT_RANGE_M` below the crown
#: removed, faces with it) and the kind each is delivered as; only in :func:`headcut_cases`
#: (``bench.realworld --headcut``).
HEADCUT_KINDS = {
    "raw_headcut": "raw", "cloud_headcut": "cloud", "closed_headcut": "closed",
    "capped_headcut": "closed",
}  # fmt: skip
#: Depths (metres below the crown) above which a head-cut kind holds nothing (a raw scan's
#: crown dropout, :class:`core.synth.scanner.ScanConfig`'s ``crown_cap_m``, is 1-4 cm).
HEADCUT_RANGE_M = (0.03, 0.09)
#: The swayed kinds (a subject scanned view after view, who moved between the views:
#: :func:`core.synth.realworld.moved_views`; the truth is where the subject stood on average)
#: and the kind each is delivered as; only in :func:`swayed_cases` (``bench.realworld
#: --swayed``).
SWAYED_KINDS = {"raw_swayed": "raw", "cloud_swayed": "cloud"}
#: How far (metres) ``capped_feetless``'s cap bulges below the cut: flat in half the cases,
#: else drawn from this range (:func:`cap_cut`).
CAP_DOME_RANGE_M = (0.005, 0.02)

#: The kinds in the order that seeds their randomness and :func:`make_case`'s draw (kind None):
#: fixed, so that a kind added later leaves every earlier case as it was.
_SEED_ORDER = (
    "closed_hair", "closed_lowres", "closed_plate", "closed_touching", "cloud", "dense", "raw",
    "raw_clutter", "raw_inward", "closed_booth", "raw_wide", "closed_wide", "cloud_wide",
    "raw_palms", "closed_palms", "closed_decimated", "closed_booth_decimated", "raw_tilted",
    "cloud_tilted", "closed_tilted", "closed_filled", "closed_booth_filled", "raw_feetless",
    "cloud_feetless", "closed_feetless", "capped_feetless", "raw_headcut", "cloud_headcut",
    "closed_headcut", "raw_swayed", "cloud_swayed", "capped_headcut",
)  # fmt: skip

#: A 33-marker subset of the CAESAR landmarks, as used by teams with shorter protocols.
SUBSET_33 = (
    "Sellion", "Tragion_L", "Tragion_R", "Cervicale", "Suprasternale", "Substernale",
    "Acromion_L", "Acromion_R", "Radiale_L", "Radiale_R", "Olecranon_L", "Olecranon_R",
    "Radial_styloid_L", "Radial_styloid_R", "Ulnar_styloid_L", "Ulnar_styloid_R",
    "Thelion_L", "Thelion_R", "ASIS_L", "ASIS_R", "PSIS_L", "PSIS_R",
    "Trochanterion_L", "Trochanterion_R", "Femoral_lateral_epicondyle_L",
    "Femoral_lateral_epicondyle_R", "Lateral_malleolus_L", "Lateral_malleolus_R",
    "Medial_malleolus_L", "Medial_malleolus_R", "Calcaneus_posterior_L",
    "Calcaneus_posterior_R", "Omphalion",
)  # fmt: skip


# ----------------------------------------------------------------------------- closed meshes


def _surface_samples(V: np.ndarray, F: np.ndarray, spacing: float, rng: np.random.Generator):
    """Points drawn uniformly by area, about one per ``spacing``² (k, 3), and their face index."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    n = int(area.sum() / spacing**2) + 1
    fi = rng.choice(len(F), size=n, p=area / area.sum())
    r1, r2 = rng.random(n), rng.random(n)
    s = np.sqrt(r1)
    P = (1 - s)[:, None] * a[fi] + (s * (1 - r2))[:, None] * b[fi] + (s * r2)[:, None] * c[fi]
    return P, fi


def winding_occupancy(V: np.ndarray, F: np.ndarray, origin: np.ndarray, h: float, shape):
    """Voxels (shape (nx, ny, nz) bool) whose centre has winding number ≥ 1 w.r.t. the closed,
    outward-wound triangle mesh (V, F): the union of overlapping parts counts as inside.

    Voxel ``(i, j, k)`` has centre ``origin + h * (i, j, k)``. Rays run along +Z: each crossing
    adds the sign of its triangle's normal z to every voxel before it.
    """
    nx, ny, nz = shape
    uv = (V[:, :2] - origin[:2]) / h
    a, b, c = uv[F[:, 0]], uv[F[:, 1]], uv[F[:, 2]]
    lo = np.ceil(np.minimum(np.minimum(a, b), c)).astype(np.int64)
    hi = np.floor(np.maximum(np.maximum(a, b), c)).astype(np.int64)
    wh = hi - lo + 1
    den = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    ok = (wh[:, 0] > 0) & (wh[:, 1] > 0) & (np.abs(den) > 1e-14)
    ti = np.flatnonzero(ok)
    cnt = wh[ti, 0] * wh[ti, 1]
    rep = np.repeat(np.arange(len(ti)), cnt)
    local = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    t = ti[rep]
    px = lo[t, 0] + local % wh[ti, 0][rep]
    py = lo[t, 1] + local // wh[ti, 0][rep]
    ax, ay = a[t, 0], a[t, 1]
    l1 = ((px - ax) * (c[t, 1] - ay) - (c[t, 0] - ax) * (py - ay)) / den[t]
    l2 = ((b[t, 0] - ax) * (py - ay) - (px - ax) * (b[t, 1] - ay)) / den[t]
    l0 = 1.0 - l1 - l2
    inside = (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
    px, py, t = px[inside], py[inside], t[inside]
    z = l0[inside] * V[F[t, 0], 2] + l1[inside] * V[F[t, 1], 2] + l2[inside] * V[F[t, 2], 2]
    sgn = np.sign(den[t])  # projected orientation = sign of the normal's z
    k = np.clip(np.ceil((z - origin[2]) / h).astype(np.int64), 0, nz)  # first voxel at/after z
    keep = (k >= 1) & (px >= 0) & (px < nx) & (py >= 0) & (py < ny)
    flat = (px[keep] * ny + py[keep]) * nz + (k[keep] - 1)
    A = np.bincount(flat, weights=sgn[keep], minlength=nx * ny * nz).reshape(nx, ny, nz)
    W = np.cumsum(A[:, :, ::-1], axis=2)[:, :, ::-1]
    return W >= 0.5


def hair_volume(V: np.ndarray, style: str, rng: np.random.Generator):
    """A hair solid for a body ``V`` (13380, 3) in template order: an inside-test function of
    points (k, 3) -> (k,) bool, and the drawn parameters (metres)."""
    tpl = load_template()
    lm = {k: V[i] for k, i in tpl.landmarks.items()}
    back = lm["Opisthocranion"]
    top = lm["Vertex"]
    front = lm["Sellion"]
    fwd = front - back
    fwd[1] = 0.0
    fwd /= np.linalg.norm(fwd)
    up = np.array([0.0, 1.0, 0.0])
    tests = []
    params: dict = {"style": style}
    if "bun" in style:
        r = float(rng.uniform(0.035, 0.055))
        c = back - fwd * (0.6 * r) + up * float(rng.uniform(0.0, 0.06))
        params["bun"] = {"radius": r, "centre": c.tolist()}
        tests.append(lambda P, c=c, r=r: np.linalg.norm(P - c, axis=1) < r)
    if style == "ponytail":
        r = float(rng.uniform(0.025, 0.035))
        L = float(rng.uniform(0.12, 0.25))
        p0 = back - fwd * 0.01 + up * 0.02
        p1 = p0 - up * L - fwd * 0.08

        def tail(P: np.ndarray, p0=p0, p1=p1, r=r) -> np.ndarray:
            d = p1 - p0
            t = np.clip((P - p0) @ d / (d @ d), 0.0, 1.0)
            return np.linalg.norm(P - p0 - t[:, None] * d, axis=1) < r * (1.0 - 0.4 * t)

        params["ponytail"] = {"radius": r, "length": L}
        tests.append(tail)
    if "cap" in style:
        th = float(rng.uniform(0.01, 0.03))
        y0 = 0.5 * (lm["Tragion_L"][1] + lm["Tragion_R"][1])
        head = tpl.part_mask("head")
        face_cut = (V - back) @ fwd < 0.8 * np.linalg.norm((front - back)[[0, 2]])
        scalp = V[head & (V[:, 1] > y0) & (face_cut | (V[:, 1] > front[1] + 0.03))]
        tree = cKDTree(scalp)
        params["cap"] = {"thickness": th}
        tests.append(lambda P, tree=tree, th=th, y0=y0: (tree.query(P)[0] < th) & (P[:, 1] > y0))
    if style == "long":
        long_test, params["long"] = _long_hair(V, rng)
        tests.append(long_test)
    if not tests:
        raise ValueError(f"hair style must be one of {ALL_HAIR_STYLES}, got {style!r}")
    params["top_m"] = float(top[1])

    def inside(P: np.ndarray) -> np.ndarray:
        out = np.zeros(len(P), dtype=bool)
        for f in tests:
            out |= f(P)
        return out

    return inside, params


def _long_hair(V: np.ndarray, rng: np.random.Generator):
    """Loose shoulder-length hair for a body ``V`` (13380, 3; metres, +Y up, facing +Z): an
    inside test (k, 3) -> (k,) bool and its parameters. A layer of thickness ``th`` over the
    scalp above the ears' level, and a curtain that hangs straight down from the back of the head
    (its back-most depth in each 5 mm column across) to ``length`` below the cervicale: where the
    neck curves in under the occiput the curtain bridges it, where the upper back reaches farther
    back the hair lies on it (``th`` thick, thinning to half at the ends); never in front of the
    ears."""
    tpl = load_template()
    lm = {k: V[i] for k, i in tpl.landmarks.items()}
    th = float(rng.uniform(0.01, 0.025))
    length = float(rng.uniform(0.03, 0.20))
    half_end = float(rng.uniform(0.08, 0.11))
    y_top = 0.5 * (lm["Tragion_L"][1] + lm["Tragion_R"][1])
    y_end = float(lm["Cervicale"][1]) - length
    head = tpl.part_mask("head")
    H = V[head & (V[:, 1] > lm["Cervicale"][1] + 0.03)]
    cx = float(0.5 * (lm["Tragion_L"][0] + lm["Tragion_R"][0]))
    half_top = float(0.5 * abs(lm["Tragion_L"][0] - lm["Tragion_R"][0]))
    z_ears = float(0.5 * (lm["Tragion_L"][2] + lm["Tragion_R"][2]))  # the curtain hangs behind
    cell = 0.005
    x0 = cx - 0.15
    nx = int(0.30 / cell) + 1
    # the back of the head's depth per column across (the curtain hangs from it)
    ixh = np.clip(((H[:, 0] - x0) / cell).astype(int), 0, nx - 1)
    zc = np.full(nx, np.inf)
    np.minimum.at(zc, ixh, H[:, 2])
    ok = np.isfinite(zc)
    zc = np.interp(np.arange(nx), np.flatnonzero(ok), zc[ok])
    # the body's back surface per (x, y) cell over the curtain's span (torso, neck, head)
    S, _ = _surface_samples(V, np.asarray(tpl.F, np.int64), 0.004, rng)
    y0 = y_end - 0.03
    ny = int((y_top - y0) / cell) + 2
    sel = (np.abs(S[:, 0] - cx) < 0.15) & (S[:, 1] > y0) & (S[:, 1] < y_top + cell)
    sel &= S[:, 2] < np.median(V[:, 2])  # the back half (arms hang beside, not behind)
    Q = S[sel]
    zb = np.full((nx, ny), np.inf)
    np.minimum.at(
        zb,
        (np.clip(((Q[:, 0] - x0) / cell).astype(int), 0, nx - 1),
         np.clip(((Q[:, 1] - y0) / cell).astype(int), 0, ny - 1)),
        Q[:, 2],
    )  # fmt: skip
    zb = ndimage.minimum_filter(zb, size=3)  # close the sampling's gaps

    def inside(P: np.ndarray) -> np.ndarray:
        ix = np.clip(((P[:, 0] - x0) / cell).astype(int), 0, nx - 1)
        iy = np.clip(((P[:, 1] - y0) / cell).astype(int), 0, ny - 1)
        t = np.clip((y_top - P[:, 1]) / (y_top - y_end), 0.0, 1.0)
        w = half_top + (half_end - half_top) * t
        thick = th * (1.0 - 0.5 * t)
        back = zb[ix, iy]
        outer = np.minimum(zc[ix], back) - thick
        inner = np.where(np.isfinite(back), back + 0.005, outer + thick)
        return (
            (P[:, 1] > y_end) & (P[:, 1] < y_top) & (np.abs(P[:, 0] - cx) < w)
            & (P[:, 2] >= outer) & (P[:, 2] <= np.minimum(inner, z_ears))
        )  # fmt: skip

    back_of_head = (V[:, 2] < lm["Tragion_L"][2]) | (V[:, 1] > lm["Glabella"][1] + 0.04)
    scalp = V[head & (V[:, 1] > y_top) & back_of_head]
    tree = cKDTree(scalp)

    def test(P: np.ndarray) -> np.ndarray:
        return ((tree.query(P)[0] < th) & (P[:, 1] > y_top)) | inside(P)

    params = {"thickness": th, "length_below_cervicale": length, "half_width_end": half_end,
              "bottom_m": y_end}  # fmt: skip
    return test, params


def hair_box(V: np.ndarray, params: dict) -> tuple[np.ndarray, np.ndarray]:
    """The box (lo, hi; metres) that holds the hair drawn with ``params`` on body ``V``: around
    the head, and down to the ends of long hair."""
    head = V[load_template().part_mask("head")]
    lo = head.min(axis=0) - 0.1
    hi = head.max(axis=0) + np.array([0.1, 0.08, 0.1])
    if "long" in params:
        lo = np.minimum(lo, [lo[0] - 0.05, params["long"]["bottom_m"] - 0.02, lo[2] - 0.05])
        hi = hi + np.array([0.05, 0.0, 0.0])
    return lo, hi


def _largest_component(F: np.ndarray, n: int) -> np.ndarray:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    E = np.vstack([F[:, [0, 1]], F[:, [1, 2]]])
    G = coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n))
    _, lab = connected_components(G, directed=False)
    big = np.argmax(np.bincount(lab[F[:, 0]]))
    return F[lab[F[:, 0]] == big]


def outward_largest_component(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The largest connected component of a marching-cubes mesh (V (n, 3), F (m, 3)), its
    unused vertices dropped, wound outward (positive volume), as scanner software keeps it."""
    F = _largest_component(np.asarray(F, dtype=np.int64), len(V))
    used = np.unique(F)
    remap = -np.ones(len(V), dtype=np.int64)
    remap[used] = np.arange(len(used))
    V, F = V[used], remap[F]
    if mesh_volume(V, F) < 0:
        F = F[:, [0, 2, 1]]
    return V, F


def decimate(V: np.ndarray, F: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Quadric edge-collapse decimation (fast-simplification, MIT; a dev dependency) of a closed
    mesh to about ``n_vertices`` vertices, as scanner software decimates its output.

    V (n, 3) metres, F (m, 3) outward-wound triangles → (V', F'): the largest component, unused
    vertices and doubled triangles dropped, wound outward; every edge in exactly two faces when
    the input's were (tested on the cases).
    """
    import fast_simplification

    V = np.asarray(V, np.float64)
    F = np.asarray(F, np.int64)
    if n_vertices >= len(V):
        return V, F
    Vd, Fd = fast_simplification.simplify(
        V.astype(np.float32), F.astype(np.int32), target_reduction=1.0 - n_vertices / len(V)
    )
    Vd, Fd = np.asarray(Vd, np.float64), np.asarray(Fd, np.int64)
    # a collapse now and then leaves a triangle twice (a fin over an edge shared by four faces):
    # every copy goes, which leaves its edges to the two faces around them
    _, inv, cnt = np.unique(np.sort(Fd, axis=1), axis=0, return_inverse=True, return_counts=True)
    return outward_largest_component(Vd, Fd[cnt[inv.ravel()] == 1])


def mouth_pocket_mask(rings: int = 3) -> np.ndarray:
    """(13380,) bool: the template's mouth cavity (``eyes_mouth`` without the eyes' rims) and
    the lips around its opening: ``rings`` passes over the template's edges, each growing the
    mask along both edge directions in turn (so up to two edges far in one pass; 3 passes reach
    about as far as 5 exact rings, ``core.assets.build.dilate``)."""
    tpl = load_template()
    em = np.asarray(tpl.mask("eyes_mouth"), bool)
    m = em & (tpl.V[:, 1] < tpl.V[tpl.landmarks["Sellion"], 1])
    E = np.asarray(tpl.edges, np.int64)
    for _ in range(rings):
        m = m | np.bincount(E[:, 0], m[E[:, 1]], len(m)).astype(bool)
        m = m | np.bincount(E[:, 1], m[E[:, 0]], len(m)).astype(bool)
    return m


def closed_mesh(
    V: np.ndarray,
    F: np.ndarray,
    rng: np.random.Generator,
    *,
    voxel_m: float = 0.006,
    mitten_m: float | None = 0.012,
    hair: str | None = None,
    floor: str = "cut",
) -> tuple[np.ndarray, np.ndarray, dict]:
    """A closed, hole-filled, watertight mesh of a body, as booth-scanner software writes it.

    Parameters
    ----------
    V : (13380, 3) body, metres, +Y up, floor y = 0, template order. F : its triangles.
    rng : randomness (hair, floor cut height, surface samples).
    voxel_m : voxel edge (metres): 5–7 mm for 40–90 k vertices, 10–14 mm for 8–20 k.
    mitten_m : radius of the ball closing the hands (fused fingers); None keeps the fingers.
    hair : None or one of :data:`HAIR_STYLES`.
    floor : ``"cut"`` (flat soles 3–8 mm up), ``"plate"`` (10 mm floor plate under the feet) or
        ``"none"``.

    Returns
    -------
    Vc (n, 3) float64 metres, Fc (m, 3) int64 outward-wound triangles (every edge in exactly two
    faces), info (parameters drawn; with a plate ``floor_shift_m``: the mesh was raised by this
    so that the plate's underside is at y = 0 and the body stands on its top).
    """
    from skimage.measure import marching_cubes  # dev dependency (BSD-3)

    tpl = load_template()
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    h = float(voxel_m)
    info: dict = {"voxel_m": h, "floor": floor}
    hair_in = None
    lo, hi = V.min(axis=0), V.max(axis=0)
    if hair is not None:
        hair_in, info["hair"] = hair_volume(V, hair, rng)
        lo, hi = lo - 0.1, hi + np.array([0.1, 0.08, 0.1])  # holds hair_box's too
    if floor == "plate":
        reach = float(rng.uniform(0.08, 0.15))
        lo = np.minimum(lo, [lo[0] - reach, -0.012, lo[2] - reach])
        hi = np.maximum(hi, [hi[0] + reach, hi[1], hi[2] + reach])
    pad = 4
    origin = lo - pad * h + h * np.array([0.137, 0.291, 0.413])  # off-grid: no exact ray hits
    shape = tuple(int(s) for s in np.ceil((hi - origin) / h).astype(int) + pad)
    occ0 = winding_occupancy(V, F, origin, h, shape)
    axes = [origin[k] + h * np.arange(shape[k]) for k in range(3)]

    def box(lo_b: np.ndarray, hi_b: np.ndarray) -> tuple[tuple[slice, ...], np.ndarray]:
        """Index slices of the voxels in a box and their centres (a, b, c, 3)."""
        i0 = np.clip(np.floor((lo_b - origin) / h).astype(int), 0, shape)
        i1 = np.clip(np.ceil((hi_b - origin) / h).astype(int) + 1, 0, shape)
        sl = tuple(slice(int(a), int(b)) for a, b in zip(i0, i1, strict=True))
        C = np.stack(np.meshgrid(*[axes[k][sl[k]] for k in range(3)], indexing="ij"), -1)
        return sl, C

    # the true signed distance g near the surface (sign from the winding occupancy), minus an
    # inflation of the hands (mittens): there g < 0 makes even sub-voxel fingers solid
    near0 = ndimage.binary_dilation(occ0 ^ ndimage.binary_erosion(occ0), iterations=3)
    offset = np.zeros(shape, dtype=np.float32)
    hand_boxes = []
    if mitten_m:
        inflate = max(0.004, 0.4 * h)
        for side in ("hand_L", "hand_R"):
            H = V[tpl.part_mask(side)]
            sl, C = box(H.min(axis=0) - 0.04, H.max(axis=0) + 0.04)
            near = np.isfinite(
                cKDTree(H).query(C.reshape(-1, 3), distance_upper_bound=0.03)[0]
            ).reshape(C.shape[:3])
            offset[sl][near] = inflate
            near0[sl] |= near
            hand_boxes.append((sl, near))
        info["mitten_inflate_m"] = inflate
    P, _ = _surface_samples(V, F, 0.0015, rng)
    ib = np.nonzero(near0)
    d = cKDTree(P).query(np.stack([axes[k][ib[k]] for k in range(3)], axis=1))[0]
    g = np.where(occ0[ib], -d, d) - offset[ib]
    occ_g = occ0.copy()
    occ_g[ib] = g < 0
    occ = occ_g.copy()
    if mitten_m:
        rad = max(mitten_m, 2.0 * h)  # a ball of at least two voxels, or thin gaps survive
        r = int(np.ceil(rad / h))
        ball = np.linalg.norm(np.mgrid[-r : r + 1, -r : r + 1, -r : r + 1], axis=0) * h <= rad
        for sl, near in hand_boxes:
            closed = ndimage.binary_closing(occ[sl], structure=ball, border_value=0)
            occ[sl] |= closed & near
        info["mitten_m"] = mitten_m
    # the template's mouth is an open pocket reaching 9 cm back into the throat: a scanner sees
    # closed lips, and booth software never opens a tunnel there (at 10-14 mm voxels the thin
    # lips vanished and left a 6 cm gap across the face at the mouth): the pocket is solid
    pocket = V[mouth_pocket_mask()]
    sl, C = box(pocket.min(axis=0), pocket.max(axis=0))
    occ[sl] |= (Delaunay(pocket).find_simplex(C.reshape(-1, 3)) >= 0).reshape(C.shape[:3])
    if hair_in is not None:
        sl, C = box(*hair_box(V, info["hair"]))
        occ[sl] |= hair_in(C.reshape(-1, 3)).reshape(C.shape[:3])
    yy = axes[1][None, :, None]
    if floor == "cut":
        cut = float(rng.uniform(0.003, 0.008))
        occ &= yy > cut
        info["sole_cut_m"] = cut
    elif floor == "plate":
        feet = V[V[:, 1] < 0.03]
        j0, j1 = np.searchsorted(axes[1], [-max(0.01, 2.0 * h), 0.0])
        XZ = np.stack(np.meshgrid(axes[0], axes[2], indexing="ij"), -1).reshape(-1, 2)
        c = feet[:, [0, 2]].mean(axis=0)
        radius = np.linalg.norm(feet[:, [0, 2]] - c, axis=1).max() + reach
        d = np.linalg.norm(XZ - c, axis=1).reshape(shape[0], shape[2])
        occ[:, j0:j1, :] |= (d < radius)[:, None, :]
        info["plate_reach_m"] = reach
    occ = ndimage.binary_fill_holes(occ)
    # signed distance: exact near the untouched surface, EDT where the volume was edited
    f = np.where(occ, -(ndimage.distance_transform_edt(occ) - 0.5),
                 ndimage.distance_transform_edt(~occ) - 0.5) * h  # fmt: skip
    gf = np.full(shape, np.nan, dtype=np.float64)
    gf[ib] = g
    band = np.isfinite(gf) & (occ == occ_g)
    if floor == "cut":
        band &= yy > info["sole_cut_m"] + 2 * h
    f[band] = gf[band]
    f = ndimage.gaussian_filter(np.clip(f, -1.5 * h, 1.5 * h), 0.5)  # truncated, then smoothed
    f = np.pad(f, 1, constant_values=h)
    Vc, Fc, _, _ = marching_cubes(f, level=0.0, spacing=(h, h, h))
    Vc = Vc + origin - h
    Vc, Fc = outward_largest_component(Vc, Fc)
    if floor == "plate":  # the plate's underside is the floor: the body stands on its top
        info["floor_shift_m"] = float(-Vc[:, 1].min())
        Vc[:, 1] += info["floor_shift_m"]
    return Vc, Fc, info


# ----------------------------------------------------------------------------- raw outputs


def _kept(
    keep: np.ndarray, X: np.ndarray, F: np.ndarray | None, normals: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The points X (n, 3) ``keep`` ((n,) bool) selects, the triangles F among them (renumbered)
    and their normals (either may be None)."""
    return (
        X[keep],
        None if F is None else kept_faces(F, keep),
        None if normals is None else normals[keep],
    )


def cap_cut(
    V: np.ndarray,
    F: np.ndarray,
    cut_y: float,
    dome_m: float,
    band_m: float = 0.02,
    *,
    top: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Close the holes a horizontal cut at ``cut_y`` (metres) left in a mesh, as scanner software
    does: each boundary loop within ``band_m`` above the cut is filled by rings shrinking to its
    centre at about the loop's edge length, bulging ``dome_m`` below it at the centre (0: flat).
    ``top``: the mesh lies below the cut (loops within ``band_m`` under it, the cap bulging up).
    Returns the vertices (n', 3) and triangles (m', 3), wound as the mesh's."""
    if top:  # mirrored through the horizontal plane (the winding reversed with it) and back
        M = np.array([1.0, -1.0, 1.0])
        X, T = cap_cut(V * M, F[:, ::-1], -cut_y, dome_m, band_m)
        return X * M, T[:, ::-1].copy()
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    code = E[:, 0] * len(V) + E[:, 1]
    rev = np.isin(E[:, 1] * len(V) + E[:, 0], code)
    nxt = dict(E[~rev].tolist())  # directed boundary edges a -> b (one per vertex on a hole)
    Vs, Fs, n = [V], [F], len(V)
    seen: set[int] = set()
    for a0 in list(nxt):
        if a0 in seen:
            continue
        loop, a = [], a0
        while a not in seen:
            seen.add(a)
            loop.append(a)
            a = nxt.get(a, a0)
        ring = np.asarray(loop)
        if len(ring) < 3 or V[ring, 1].max() > cut_y + band_m:
            continue
        P = V[ring]
        c = P.mean(axis=0)
        edge = float(np.linalg.norm(P - np.roll(P, -1, axis=0), axis=1).mean())
        k = max(1, round(np.linalg.norm(P - c, axis=1).mean() / max(edge, 1e-9)))
        outer = ring
        for i in range(1, k + 1):
            t = 1.0 - i / k
            if i == k:  # the centre, a fan
                Vs.append((c - [0.0, dome_m, 0.0])[None])
                centre = np.full(len(outer), n)
                Fs.append(np.stack([np.roll(outer, -1), outer, centre], axis=1))
                n += 1
                break
            Q = c + t * (P - c)
            Q[:, 1] -= dome_m * (1.0 - t * t)
            inner = np.arange(n, n + len(Q))
            Vs.append(Q)
            n += len(Q)
            o1, i1 = np.roll(outer, -1), np.roll(inner, -1)
            Fs += [np.stack([o1, outer, inner], axis=1), np.stack([o1, inner, i1], axis=1)]
            outer = inner
    return np.vstack(Vs), np.vstack(Fs).astype(np.int64)


def _cap_dome(rng: np.random.Generator) -> float:
    """A software cap's bulge (metres): flat in half the cases, else :data:`CAP_DOME_RANGE_M`."""
    return float(rng.uniform(*CAP_DOME_RANGE_M)) if rng.random() < 0.5 else 0.0


def _sphere(c: np.ndarray, r: float, n: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Icosphere-like triangulated sphere (octahedron subdivided ``n`` times)."""
    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4],
                  [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])  # fmt: skip
    for _ in range(n):
        E = np.sort(np.vstack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
        u, inv = np.unique(E, axis=0, return_inverse=True)
        inv = inv.ravel()
        mid = V[u].mean(axis=1)
        m = len(V) + inv.reshape(3, -1).T  # midpoints of edges 01, 12, 20
        V = np.vstack([V, mid])
        a, b, cc = F[:, 0], F[:, 1], F[:, 2]
        F = np.vstack([np.c_[a, m[:, 0], m[:, 2]], np.c_[m[:, 0], b, m[:, 1]],
                       np.c_[m[:, 2], m[:, 1], cc], np.c_[m[:, 0], m[:, 1], m[:, 2]]])  # fmt: skip
        V /= np.linalg.norm(V, axis=1, keepdims=True)
    return c + r * V, F


def clutter(body: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict]:
    """Stray blobs and a floor ring around a body (metres, +Y up): (V, F, info)."""
    centre = np.array([body[:, 0].mean(), 0.0, body[:, 2].mean()])
    Vs, Fs, n0 = [], [], 0
    nb = int(rng.integers(2, 6))
    for _ in range(nb):
        th = rng.uniform(0, 2 * np.pi)
        dist = rng.uniform(0.3, 1.2)
        c = centre + np.array([dist * np.cos(th), rng.uniform(0.1, 1.8), dist * np.sin(th)])
        v, f = _sphere(c, float(rng.uniform(0.02, 0.06)))
        Vs.append(v)
        Fs.append(f + n0)
        n0 += len(v)
    r0, r1 = 0.25, float(rng.uniform(0.35, 0.6))
    step = 0.01
    g = np.arange(-r1, r1 + step, step)
    X, Z = np.meshgrid(g, g, indexing="ij")
    rr = np.hypot(X, Z)
    idx = -np.ones(X.shape, dtype=np.int64)
    ring = (rr >= r0) & (rr <= r1)
    idx[ring] = np.arange(ring.sum()) + n0
    P = np.c_[X[ring] + centre[0], rng.normal(0, 0.001, ring.sum()), Z[ring] + centre[2]]
    a, b = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel()
    c, d = idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()
    T = np.vstack([np.c_[a, c, b], np.c_[b, c, d]])
    T = T[(T >= 0).all(axis=1)]
    Vs.append(P)
    Fs.append(T)
    return np.vstack(Vs), np.vstack(Fs), {"blobs": nb, "floor_ring_m": (r0, r1)}


def _booth_hair(brng: np.random.Generator) -> str | None:
    """A booth subject's hair: none or one of :data:`HAIR_STYLES`, drawn from its protocol's
    generator ``brng``."""
    return [None, *HAIR_STYLES][int(brng.integers(len(HAIR_STYLES) + 1))]


def _scanned_hair(
    P: np.ndarray, style: str | None, seed: int, out: dict
) -> tuple[np.ndarray, np.ndarray] | None:
    """The hair surface (vertices, triangles; :func:`hair_mesh`) of ``style`` on the body P
    (n, 3) for :func:`raw_scan`, its parameters put in ``out["hair"]``; None without hair."""
    if style is None:
        return None
    Vh, Fh, out["hair"] = hair_mesh(P, style, np.random.default_rng([seed, 104]))
    return Vh, Fh


def hair_mesh(
    V: np.ndarray, style: str, rng: np.random.Generator, voxel_m: float = 0.004
) -> tuple[np.ndarray, np.ndarray, dict]:
    """The surface of a hair solid (:func:`hair_volume`) for a body ``V`` (13380, 3), metres:
    outward-wound triangles by marching cubes on a ``voxel_m`` grid (its inner side lies inside
    the head, where a scanner does not see it). Returns (vertices, triangles, parameters)."""
    from skimage.measure import marching_cubes  # dev dependency (BSD-3)

    inside, params = hair_volume(V, style, rng)
    lo, hi = hair_box(V, params)
    axes = [np.arange(lo[k], hi[k] + voxel_m, voxel_m) for k in range(3)]
    C = np.stack(np.meshgrid(*axes, indexing="ij"), -1)
    occ = inside(C.reshape(-1, 3)).reshape(C.shape[:3]).astype(np.float64)
    f = ndimage.gaussian_filter(np.pad(occ, 1), 0.7)
    Vh, Fh, _, _ = marching_cubes(f, level=0.5, spacing=(voxel_m,) * 3)
    Vh = Vh + lo - voxel_m
    Fh = Fh.astype(np.int64)
    if mesh_volume(Vh, Fh) < 0:
        Fh = Fh[:, [0, 2, 1]]
    return Vh, Fh, params


def raw_scan(
    V: np.ndarray,
    rng: np.random.Generator,
    hair: tuple[np.ndarray, np.ndarray] | None = None,
    views: list[tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A raw multi-view scan (6 views, 4 mm pitch, 1 mm noise) in metres: points, faces, normals.

    ``hair``: a hair surface (vertices, triangles; :func:`hair_mesh`) scanned with the body: the
    scanner sees the hair and not the scalp under it. ``views``: the body as each of the 6
    views saw it, with the sway that moves the hair (:func:`core.synth.realworld.moved_views`).
    """
    tpl = load_template()
    F = np.asarray(tpl.F, dtype=np.int64)
    bodies = None
    if views is not None:
        bodies = [b for b, _, _ in views]
    if hair is not None:
        if bodies is not None:
            bodies = [np.vstack([b, hair[0] @ R.T + t]) for b, R, t in views]  # type: ignore[union-attr]
        V, F = np.vstack([V, hair[0]]), np.vstack([F, hair[1] + len(V)])
    sim = simulate_scan(
        V, F, rng, config=ScanConfig(n_views=6, pitch_m=0.004, noise_m=0.001), view_bodies=bodies
    )
    return sim.V_scan, sim.F_scan, sim.normals


def wind_arms_inward(
    P: np.ndarray, T: np.ndarray, N: np.ndarray, body: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flip the faces (and vertex normals) of a raw scan that lie on the arms of ``body``."""
    tpl = load_template()
    arm = np.isin(tpl.part, [tpl.part_names.index(n) for n in tpl.part_names
                             if n.startswith(("upper_arm", "forearm", "hand"))])  # fmt: skip
    on_arm = arm[cKDTree(body).query(P)[1]]
    flip = on_arm[T].all(axis=1)
    T = T.copy()
    T[flip] = T[flip][:, [0, 2, 1]]
    N = N.copy()
    N[on_arm] *= -1.0
    return T, N, flip


# ----------------------------------------------------------------------------- markers


def _convention_direction(name: str, convention: str, seed_extra: int = 0) -> tuple[float, float]:
    """A fixed (angle rad, distance m) per marker and convention: the convention's habit."""
    r = np.random.default_rng(zlib.crc32(f"{convention}:{name}:{seed_extra}".encode()))
    return float(r.uniform(0, 2 * np.pi)), float(r.uniform(0.02, 0.05))


def other_convention_markers(
    body: np.ndarray,
    rng: np.random.Generator,
    *,
    convention: str = "caesar62-teamB",
) -> tuple[dict[str, np.ndarray], dict]:
    """Markers placed by another team's convention on a body (13380, 3) in template order.

    ``convention`` starting with ``subset33`` uses :data:`SUBSET_33`, else all 62 landmarks.
    Returns name -> (3,) position (metres, body frame) and what was done (offsets mm, swapped
    pairs, missing names).
    """
    tpl = load_template()
    F = np.asarray(tpl.F, dtype=np.int64)
    names = list(SUBSET_33) if convention.startswith("subset33") else list(tpl.landmarks)
    N = tpl.vertex_normals(body)
    md = MeshDistance(body, F)
    out: dict[str, np.ndarray] = {}
    offsets = {}
    for n in names:
        i = tpl.landmarks[n]
        p, nrm = body[i], N[i]
        e1 = np.cross(nrm, [0.0, 1.0, 0.0] if abs(nrm[1]) < 0.9 else [1.0, 0.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(nrm, e1)
        th, dist = _convention_direction(n, convention)
        q = p.copy()
        step = (np.cos(th) * e1 + np.sin(th) * e2) * dist / 4
        for _ in range(4):  # walk along the surface in four steps
            q = _project(md, q + step)
        q = q + rng.normal(0.0, 0.003, 3)
        out[n] = q
        offsets[n] = float(np.linalg.norm(q - p) * 1000)
    swapped = []
    pairs = sorted({n[:-2] for n in out if n.endswith("_L") and n[:-2] + "_R" in out})
    for base in rng.choice(pairs, size=int(rng.integers(0, 3)), replace=False):
        a, b = base + "_L", base + "_R"
        out[a], out[b] = out[b], out[a]
        swapped.append(str(base))
    missing = [str(n) for n in rng.choice(sorted(out), size=int(rng.integers(0, 5)), replace=False)]
    for n in missing:
        del out[n]
    return out, {"convention": convention, "offset_mm": offsets, "swapped": swapped,
                 "missing": missing}  # fmt: skip


def _project(md: MeshDistance, q: np.ndarray) -> np.ndarray:
    """Closest point on the mesh of ``md`` to q (3,)."""
    from core.geometry import closest_point_on_triangles

    _, nn = md.tree.query(q, k=8)
    faces = np.unique(md.inc[nn].indices)
    tri = md.F[faces]
    Q = np.repeat(q[None], len(faces), axis=0)
    cp = closest_point_on_triangles(Q, md.V[tri[:, 0]], md.V[tri[:, 1]], md.V[tri[:, 2]])
    return cp[np.argmin(np.linalg.norm(cp - q, axis=1))]


# ----------------------------------------------------------------------------- frames and cases


def file_transform(units: str, up: str, facing_deg: float, shift_m: np.ndarray) -> np.ndarray:
    """(4, 4) map from canonical metres (+Y up, +Z front) to a file's frame: turn the body by
    ``facing_deg`` about +Y, shift by ``shift_m`` (metres), turn +Y to ``up``, scale to units."""
    a = np.radians(facing_deg)
    c, s = np.cos(a), np.sin(a)
    Rf = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
    A = np.eye(4)
    A[:3, :3] = UNITS[units] * rotation_for_up(up).T @ Rf
    A[:3, 3] = UNITS[units] * rotation_for_up(up).T @ np.asarray(shift_m, dtype=np.float64)
    return A


@dataclass
class RealWorldCase:
    """One real-world-like case; everything in the **file's** frame and units.

    Attributes
    ----------
    seed, kind : what made it (``make_case(seed, kind)`` reproduces it).
    V : (n, 3) float64 scan points. F : (m, 3) int64 triangles or None (point cloud).
    normals : (n, 3) or None. colors : (n, 3) uint8 or None.
    units, up : the file's units (``m``/``cm``/``mm``) and up axis (e.g. ``-z``).
    facing_deg : rotation of the subject about the up axis.
    to_file : (4, 4) canonical metres -> file frame.
    truth : (13380, 3) the body (without hair), template order, file frame.
    markers : name -> (3,) in the file frame, another team's convention (see ``marker_info``).
    family : the case's kind; description : what it is, in words.
    body_key : cases with the same key show the same body in the same posture.
    params : everything drawn (body, posture, output).
    """

    seed: int
    kind: str
    V: np.ndarray
    F: np.ndarray | None
    normals: np.ndarray | None
    colors: np.ndarray | None
    units: str
    up: str
    facing_deg: float
    to_file: np.ndarray
    truth: np.ndarray
    markers: dict[str, np.ndarray]
    marker_info: dict
    family: str
    description: str
    body_key: str
    params: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"{self.kind}-{self.seed}"

    def write(self, path: str | Path) -> Path:
        """Write the scan to ``path`` (.ply binary, .obj or .xyz by extension); returns it."""
        from core.io import write_mesh

        path = Path(path)
        if path.suffix.lower() == ".xyz":
            np.savetxt(path, self.V, fmt="%.6f")
        elif path.suffix.lower() == ".obj":
            write_mesh(path, self.V, self.F, normals=self.normals)
        else:
            write_mesh(path, self.V, self.F, normals=self.normals, colors=self.colors)
        return path

    def write_markers(self, path: str | Path) -> Path:
        """Write the markers as CSV ``name,x,y,z`` (file units) to ``path``; returns it."""
        from core.io.markers import write_markers_csv

        write_markers_csv(path, self.markers)
        return Path(path)


def _tf(A: np.ndarray, X: np.ndarray) -> np.ndarray:
    return X @ A[:3, :3].T + A[:3, 3]


def make_case(
    seed: int, kind: str | None = None, *, hair: str | None = None, voxel_m: float | None = None
) -> RealWorldCase:
    """Build a real-world-like case (deterministic in ``seed``, ``kind`` and ``hair``).

    The body and its posture depend on ``seed`` only (``closed_touching`` lowers the arms until
    they touch), so ``make_case(s, "closed_lowres")`` and ``make_case(s, "raw")`` show the same
    body. ``kind`` None draws one of :data:`KINDS` from the seed. ``hair`` (one of
    :data:`HAIR_STYLES` or :data:`EXTRA_HAIR_STYLES`; any kind but dense) puts that hair on the
    head instead of the kind's own (none, or closed_hair's and closed_booth's drawn style;
    default None: the cases as they always were). ``voxel_m``
    (closed kinds only): mesh on this grid (metres) instead of the kind's drawn one (e.g. 0.017:
    ~8 k vertices, where close feet fuse).
    """
    kinds = list(_SEED_ORDER)
    if kind is None:
        n_draw = kinds.index("closed_booth")  # the kinds before it, as always drawn
        kind = kinds[int(np.random.default_rng([seed, 100]).integers(n_draw))]
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(sorted(kinds))}, got {kind!r}")
    if hair is not None and kind == "dense":
        raise ValueError("hair= is not for the dense kind (points drawn on the true skin)")
    if voxel_m is not None and not (kind.startswith("closed") and 0.002 <= voxel_m <= 0.03):
        raise ValueError(f"voxel_m is for the closed kinds, 0.002-0.03 m; got {voxel_m} ({kind})")
    if hair is not None and hair not in ALL_HAIR_STYLES:
        raise ValueError(f"hair must be one of {ALL_HAIR_STYLES}, got {hair!r}")
    hair_asked = hair
    tpl = load_template()
    F_t = np.asarray(tpl.F, dtype=np.int64)
    body = off_model_body(np.random.default_rng([seed, 101]))
    booth = kind in ("closed_booth", "closed_booth_decimated", "closed_booth_filled")
    brng = np.random.default_rng([seed, 105])  # the booth subject's protocol
    touching = kind == "closed_touching" or (booth and brng.random() < 0.4)
    wide = kind in WIDE_KINDS
    arm_range = WIDE_ARM_RANGE if wide else None
    twist = (0.0, 0.0)
    if kind in PALM_KINDS:  # the same turn for both twins of a body
        trng = np.random.default_rng([seed, 107])
        t = float(trng.choice([-1.0, 1.0]) * trng.uniform(*PALM_TWIST_RANGE))
        a = float(trng.uniform(-10.0, 10.0))
        twist = (t + a, t - a)
    P, pose = posture(
        body.V, np.random.default_rng([seed, 102]), touching=touching, arm_range=arm_range,
        forearm_twist=twist,
    )  # fmt: skip
    kind_drawn = kind  # a wide or turned-palms kind is delivered as its base
    if kind in FEETLESS_KINDS:  # the whole body leaned at the ankles, as people stand
        lean = float(np.random.default_rng([seed, 113]).uniform(*FEETLESS_LEAN_RANGE_DEG))
        P = stand_leaned(P, lean)
        pose["stance_lean_deg"] = lean
    views = None
    if kind in SWAYED_KINDS:  # the body as each sequential view saw it
        views, out_views = moved_views(P, np.random.default_rng([seed, 112]), 6)
    for delivered in (WIDE_KINDS, PALM_KINDS, TILTED_KINDS, FEETLESS_KINDS, HEADCUT_KINDS,
                      SWAYED_KINDS):  # fmt: skip
        kind = delivered.get(kind, kind)
    rng = np.random.default_rng([seed, 103, kinds.index(kind_drawn)])
    out: dict = {}
    normals = None
    F: np.ndarray | None
    if kind in ("closed_filled", "closed_booth_filled"):  # booth software's watertight mesh
        from core.synth.hole_filling import filled_mesh  # of its own raw scan

        if booth:  # the booth subject's hair, scanned with the body (drawn as closed_booth's)
            hair = _booth_hair(brng) if hair_asked is None else hair_asked
        surface = _scanned_hair(P, hair if booth else None, seed, out)
        Xr, _, Nr = raw_scan(P, rng, hair=surface)
        h = float(rng.uniform(0.006, 0.008))
        want = int(rng.uniform(10_000, 15_000))
        X, F = filled_mesh(Xr, Nr, h, want)
        out.update(voxel_m=h, raw_points=len(Xr), fill="membrane")
        normals = vertex_normals(X, F) if rng.random() < 0.5 else None
    elif kind.startswith("closed"):
        lowres = kind in ("closed_lowres", "closed_booth")
        h = float(rng.uniform(0.010, 0.014) if lowres else rng.uniform(0.005, 0.007))
        n_decimated = int(rng.uniform(10_000, 20_000)) if kind == "closed_decimated" else 0
        h = h if voxel_m is None else float(voxel_m)
        hair = str(rng.choice(HAIR_STYLES)) if kind == "closed_hair" else None
        if booth:
            hair = _booth_hair(brng)
        if hair_asked is not None:  # drawn above all the same: the rest of the case is as always
            hair = hair_asked
        floor = "plate" if kind == "closed_plate" or (booth and brng.random() < 0.2) else "cut"
        mitten = float(rng.uniform(0.010, 0.014))
        X, F, out = closed_mesh(P, F_t, rng, voxel_m=h, mitten_m=mitten, hair=hair, floor=floor)
        if booth and voxel_m is None:  # decimated to the drawn 10-15 k vertices: regrid once
            want = float(brng.uniform(10_000, 15_000))
            if kind == "closed_booth_decimated":  # or by edge collapse from the fine mesh
                n_decimated = int(want)
            elif not 0.9 * want < len(X) < 1.1 * want:
                h = float(np.clip(h * np.sqrt(len(X) / want), 0.008, 0.02))
                X, F, out = closed_mesh(P, F_t, np.random.default_rng([seed, 106]), voxel_m=h,
                                        mitten_m=mitten, hair=hair, floor=floor)  # fmt: skip
        if n_decimated:
            out["fine_vertices"] = len(X)
            X, F = decimate(X, F, n_decimated)
        P = P + np.array([0.0, out.get("floor_shift_m", 0.0), 0.0])  # the truth stands on a plate
        normals = vertex_normals(X, F) if rng.random() < 0.5 else None
    elif kind == "dense":
        n = int(rng.uniform(1.0e6, 3.0e6))
        a, b, c = P[F_t[:, 0]], P[F_t[:, 1]], P[F_t[:, 2]]
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
        X, _ = _surface_samples(P, F_t, float(np.sqrt(area.sum() / n)), rng)
        X = X + rng.normal(0.0, 0.0005, X.shape)
        X = X[X[:, 1] > 0.004]
        F = None
        out["points"] = len(X)
    else:
        X, F, normals = raw_scan(P, rng, hair=_scanned_hair(P, hair, seed, out), views=views)
        if views is not None:
            out["moved"] = out_views
        if kind == "raw_inward":
            F, normals, flip = wind_arms_inward(X, F, normals, P)
            out["flipped_faces"] = int(flip.sum())
        elif kind == "raw_clutter":
            Vc, Fc, out = clutter(P, rng)
            F = np.vstack([F, Fc + len(X)])
            X = np.vstack([X, Vc])
            normals = vertex_normals(X, F)
        elif kind == "cloud":
            F, normals = None, None
    if kind_drawn in FEETLESS_KINDS:  # nothing below the cut: points, and faces with them
        cut = float(np.random.default_rng([seed, 109]).uniform(*FEETLESS_CUT_RANGE_M))
        X, F, normals = _kept(X[:, 1] > P[:, 1].min() + cut, X, F, normals)
        out["cut_m"] = cut
        if kind_drawn == "capped_feetless":
            assert F is not None
            dome = _cap_dome(np.random.default_rng([seed, 110]))
            X, F = cap_cut(X, F, P[:, 1].min() + cut, dome)
            normals = None if normals is None else vertex_normals(X, F)
            out["cap_dome_m"] = dome
    if kind_drawn in HEADCUT_KINDS:  # nothing above the cut: points, and faces with them
        cut = float(np.random.default_rng([seed, 111]).uniform(*HEADCUT_RANGE_M))
        X, F, normals = _kept(X[:, 1] < P[:, 1].max() - cut, X, F, normals)
        out["head_cut_m"] = cut
        if kind_drawn == "capped_headcut":
            assert F is not None
            dome = _cap_dome(np.random.default_rng([seed, 114]))
            X, F = cap_cut(X, F, P[:, 1].max() - cut, dome, top=True)
            normals = None if normals is None else vertex_normals(X, F)
            out["cap_dome_m"] = dome
    # frame
    if kind in ("closed_lowres", "closed_booth", "closed_decimated", "closed_booth_decimated",
                "closed_filled", "closed_booth_filled"):  # fmt: skip
        units, up, facing, shift = "mm", "+y", 0.0, np.zeros(3)
    else:
        units = str(rng.choice(list(UNITS)))
        up = str(rng.choice(UPS))
        facing = float(rng.uniform(0.0, 360.0))
        shift = rng.uniform(-0.3, 0.3, 3)
    A = file_transform(units, up, facing, shift)
    if kind_drawn in TILTED_KINDS:  # turned about a horizontal axis through the feet first
        trng = np.random.default_rng([seed, 108])
        tilt = float(trng.uniform(*TILT_RANGE_DEG))
        az = float(trng.uniform(0.0, 2.0 * np.pi))
        out["tilt_deg"] = tilt
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec(
            np.radians(tilt) * np.array([np.cos(az), 0.0, np.sin(az)])
        ).as_matrix()
        A = A @ T
    conv = str(rng.choice(["caesar62-teamB", "subset33-teamC"]))
    mk, minfo = other_convention_markers(P, rng, convention=conv)
    Xf = _tf(A, X)
    Nf = None if normals is None else normals @ A[:3, :3].T / UNITS[units]
    desc = _describe(kind_drawn, body, pose, out, units, up, len(Xf), F)
    return RealWorldCase(
        seed=seed, kind=kind_drawn, V=Xf, F=F, normals=Nf, colors=None, units=units, up=up,
        facing_deg=facing, to_file=A, truth=_tf(A, P),
        markers={k: _tf(A, v[None])[0] for k, v in mk.items()}, marker_info=minfo,
        family=kind_drawn, description=desc,
        body_key=f"{seed}{'-touching' if touching else ''}{'-wide' if wide else ''}"
        f"{'-palms' if any(twist) else ''}",
        params={"sex": body.sex, "body": body.params, "posture": pose, "output": out},
    )  # fmt: skip


def _describe(kind, body, pose, out, units, up, n, F) -> str:
    what = KINDS[kind].split(",")[0].split(" (")[0]
    bits = [f"off-model {body.sex}, BMI {body.params['bmi']:.0f}, "
            f"{body.params['stature_m'] * 100:.0f} cm", what]  # fmt: skip
    if "hair" in out:
        bits.append(f"hair {out['hair']['style']}")
    if pose.get("touching"):
        bits.append("arms touching torso")
    else:
        bits.append(f"arms {pose['arm_abduction']:.0f}°")
    bits.append(f"elbows {pose['elbow_flexion']:.0f}°")
    bits.append("fists" if pose["fist"] else "open hands")
    if pose.get("forearm_twist_L") or pose.get("forearm_twist_R"):
        bits.append(
            f"forearms turned {pose['forearm_twist_L']:+.0f}°/{pose['forearm_twist_R']:+.0f}°"
        )
    bits.append(f"feet {pose['feet_gap_m'] * 100:.0f} cm apart")
    if "stance_lean_deg" in pose:
        bits.append(f"leaning {pose['stance_lean_deg']:+.1f}°")
    if "tilt_deg" in out:
        bits.append(f"tilted {out['tilt_deg']:.0f}°")
    if "cut_m" in out:
        bits.append(f"nothing below {out['cut_m'] * 100:.0f} cm")
    if "head_cut_m" in out:
        bits.append(f"nothing above {out['head_cut_m'] * 100:.0f} cm below the crown")
    if "moved" in out:
        m = out["moved"]
        bits.append(
            f"moved between views (crown {max(m['crown_moves_m']) * 1000:.0f} mm, arms "
            f"{m['arm_drift_deg']:.1f}°, breath {m['breath_m'] * 1000:.0f} mm)"
        )
    if "cap_dome_m" in out:
        d = out["cap_dome_m"]
        bits.append(f"capped there ({f'domed {d * 1000:.0f} mm' if d else 'flat'})")
    bits.append(f"{n:,} {'vertices' if F is not None else 'points'}, {units}, up {up}")
    return ", ".join(bits)


def benchmark_cases(n: int = 40) -> list[tuple[int, str]]:
    """``n`` varied (seed, kind) pairs: every kind in turn, the dense kind rarer (slow), and for
    every fourth body both a ``closed_lowres`` and a ``raw`` twin (same body: the
    closed-vs-raw agreement check)."""
    apart = ("dense", "closed_booth", "closed_decimated", "closed_booth_decimated", "closed_filled",
             "closed_booth_filled")  # fmt: skip
    sets = (*apart, *WIDE_KINDS, *PALM_KINDS, *TILTED_KINDS, *FEETLESS_KINDS, *HEADCUT_KINDS,
            *SWAYED_KINDS)  # fmt: skip
    base = [k for k in sorted(KINDS) if k not in sets]
    out: list[tuple[int, str]] = []
    seed = i = 0
    while len(out) < n:
        if seed % 4 == 0:
            out += [(seed, "closed_lowres"), (seed, "raw")]
        elif seed % 16 == 7:
            out.append((seed, "dense"))
        else:
            out.append((seed, base[i % len(base)]))
            i += 1
        seed += 1
    return out[:n]


#: Lowest BMI (kg/m²) of :func:`heavy_cases`' bodies: the heaviest real booth-scan subjects
#: of issue 12 reach ~45.
HEAVY_BMI = 42.0


def heavy_cases(n: int = 20, start: int = 32) -> list[tuple[int, str]]:
    """``n`` (seed, kind) pairs of heavy bodies (the off-model body of the seed,
    :func:`make_case`'s, has a BMI ≥ :data:`HEAVY_BMI`; seeds from ``start`` on, clear of
    :func:`benchmark_cases`' first 40), each as a ``closed_lowres`` and a ``raw`` twin."""
    out: list[tuple[int, str]] = []
    seed = start
    while len(out) < n:
        if off_model_body(np.random.default_rng([seed, 101])).params["bmi"] >= HEAVY_BMI:
            out += [(seed, "closed_lowres"), (seed, "raw")]
        seed += 1
    return out[:n]


def booth_cases(n: int = 40, start: int = 300) -> list[tuple[int, str]]:
    """``n`` ``closed_booth`` cases, seeds ``start`` on (clear of the other sets): issue 12's
    booth-software meshes of real subjects (10-15 k vertices, hair, touching arms, heavy bodies:
    the off-model bodies' own BMI spread, 15-55)."""
    return [(s, "closed_booth") for s in range(start, start + n)]


def wide_cases(n: int = 24, start: int = 500) -> list[tuple[int, str]]:
    """``n`` (seed, kind) pairs of bodies with the arms 60-90° from the body (T-pose capture,
    :data:`WIDE_KINDS`), seeds ``start`` on (clear of the other sets), the three kinds in turn:
    raw scans, closed meshes and point clouds, each in a random frame."""
    kinds = list(WIDE_KINDS)
    return [(start + i, kinds[i % len(kinds)]) for i in range(n)]


def palm_cases(n: int = 20, start: int = 600) -> list[tuple[int, str]]:
    """``n`` (seed, kind) pairs of bodies with both palms turned 45-100° forwards or backwards
    (:data:`PALM_KINDS`), seeds ``start`` on (clear of the other sets), each body as a
    ``closed_palms`` and a ``raw_palms`` twin."""
    out: list[tuple[int, str]] = []
    for seed in range(start, start + (n + 1) // 2):
        out += [(seed, "closed_palms"), (seed, "raw_palms")]
    return out[:n]


def tilted_cases(n: int = 24, start: int = 800) -> list[tuple[int, str]]:
    """``n`` (seed, kind) pairs of bodies in a handheld scanner's frame (:data:`TILTED_KINDS`:
    5-45° off every file axis), seeds ``start`` on (clear of the other sets), raw scans, point
    clouds and closed meshes in turn."""
    kinds = list(TILTED_KINDS)
    return [(start + i, kinds[i % len(kinds)]) for i in range(n)]


def feetless_cases(n: int = 12, start: int = 1000) -> list[tuple[int, str]]:
    """``n`` (seed, kind) pairs of scans that end above the soles (:data:`FEETLESS_KINDS`),
    seeds ``start`` on (clear of the other sets), raw scans, point clouds, closed meshes open at
    the cut and closed meshes capped there in turn."""
    kinds = list(FEETLESS_KINDS)
    return [(start + i, kinds[i % len(kinds)]) for i in range(n)]


def headcut_cases(n: int = 12, start: int = 1100) -> list[tuple[int, str]]:
    """``n`` (seed, kind) pairs of scans that end below the crown (:data:`HEADCUT_KINDS`), seeds
    ``start`` on (clear of the other sets), raw scans, point clouds, closed meshes open at the
    cut and closed meshes capped there in turn."""
    kinds = list(HEADCUT_KINDS)
    return [(start + i, kinds[i % len(kinds)]) for i in range(n)]


def swayed_cases(n: int = 12, start: int = 1200) -> list[tuple[int, str]]:
    """``n`` (seed, kind) pairs of subjects who moved between sequential views
    (:data:`SWAYED_KINDS`), seeds ``start`` on (clear of the other sets), raw scans and point
    clouds in turn, each in a random frame."""
    kinds = list(SWAYED_KINDS)
    return [(start + i, kinds[i % len(kinds)]) for i in range(n)]


def filled_cases(n: int = 16, start: int = 900) -> list[tuple[int, str]]:
    """``n`` (seed, kind) pairs, seeds ``start`` on (clear of the other sets): each body as a
    ``closed_filled`` mesh (booth software's watertight mesh of its own raw scan, the holes
    bridged, :mod:`core.synth.hole_filling`) and a ``raw`` twin."""
    out: list[tuple[int, str]] = []
    for seed in range(start, start + (n + 1) // 2):
        out += [(seed, "closed_filled"), (seed, "raw")]
    return out[:n]


def decimated_cases(n: int = 16, start: int = 700) -> list[tuple[int, str]]:
    """``n`` (seed, kind) pairs, seeds ``start`` on (clear of the other sets): each body as a
    ``closed_decimated`` mesh (quadric edge collapse of a fine closed mesh to 10-20 k vertices)
    and a ``raw`` twin."""
    out: list[tuple[int, str]] = []
    for seed in range(start, start + (n + 1) // 2):
        out += [(seed, "closed_decimated"), (seed, "raw")]
    return out[:n]


__all__ = [
    "ALL_HAIR_STYLES",
    "EXTRA_HAIR_STYLES",
    "FEETLESS_KINDS",
    "FEETLESS_LEAN_RANGE_DEG",
    "HAIR_STYLES",
    "HEADCUT_KINDS",
    "KINDS",
    "PALM_KINDS",
    "SUBSET_33",
    "SWAYED_KINDS",
    "TILTED_KINDS",
    "WIDE_KINDS",
    "RealWorldCase",
    "benchmark_cases",
    "booth_cases",
    "cap_cut",
    "closed_mesh",
    "clutter",
    "decimate",
    "decimated_cases",
    "feetless_cases",
    "file_transform",
    "filled_cases",
    "hair_box",
    "hair_mesh",
    "hair_volume",
    "headcut_cases",
    "heavy_cases",
    "make_case",
    "other_convention_markers",
    "outward_largest_component",
    "palm_cases",
    "raw_scan",
    "swayed_cases",
    "tilted_cases",
    "wide_cases",
    "wind_arms_inward",
    "winding_occupancy",
]
