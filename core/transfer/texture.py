"""Texture baking on the template's one UV layout (Allen et al. 2003, section 4.6).

Every body shares the template's vertices, so one UV layout serves them all: the MakeHuman
base mesh's own (CC0; ``core/assets/uv_layout.npz``, made by ``core/assets/build_uv.py``). A
body's per-vertex colours are *baked* into a texture image on that layout -- each UV triangle
rasterised with its corners' colours interpolated barycentrically, then dilated a few pixels
across the UV islands' borders so filtering never reads the empty background -- and the texture
then moves from one body to any other unchanged.

Vertex identity in a textured GLB: glTF gives a vertex one UV, so the body's 1 137 vertices on
UV seams are written more than once. The GLB's vertex ``k`` is body vertex ``uv_vertex[k]``:
the first 13 380 are the body's vertices in template order (``uv_vertex[k] == k``), the seam
copies follow (:class:`UVLayout`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import cache
from typing import TYPE_CHECKING

import numpy as np

from core.template import load_asset, load_template

if TYPE_CHECKING:
    from core.io.writers import GlbSkin
    from core.scan import FrameInfo, RawMesh, TexturedSurface

TEXTURE_SIZE = 1024  # pixels per side of a baked texture


@dataclass(frozen=True)
class UVLayout:
    """The template's UV layout with seam vertices split (one UV per vertex, as glTF needs).

    Attributes
    ----------
    uv : (K, 2) float32 texture coordinates, glTF convention (origin at the image's top-left).
    vertex : (K,) int32 body vertex of each UV vertex; ``vertex[:13380] == arange(13380)``.
    faces : (26756, 3) int32 the template's triangles over UV vertices
        (``vertex[faces] == template.F``).
    """

    uv: np.ndarray
    vertex: np.ndarray
    faces: np.ndarray


@cache
def load_uv_layout() -> UVLayout:
    """The committed UV layout (cached; arrays read-only)."""
    arrays = load_asset("uv_layout.npz")
    return UVLayout(uv=arrays["uv"], vertex=arrays["uv_vertex"], faces=arrays["uv_faces"])


def _as_unit(colours: np.ndarray, n: int) -> np.ndarray:
    C = np.asarray(colours)
    if C.shape != (n, 3):
        raise ValueError(f"colours must have shape ({n}, 3), got {C.shape}")
    return C / 255.0 if C.dtype.kind in "ui" else np.clip(C.astype(np.float64), 0.0, 1.0)


def _rasterise(P: np.ndarray, F: np.ndarray, C: np.ndarray, size: int):
    """Barycentric fill of triangles ``F`` at pixel positions ``P`` (K, 2) with corner values
    ``C`` (K, c): the (size, size, c) image and the (size, size) coverage mask."""
    img = np.zeros((size * size, C.shape[1]))
    covered = np.zeros(size * size, dtype=bool)
    for s in range(0, len(F), 8192):  # bounded memory
        T = P[F[s : s + 8192]]  # (t, 3, 2), pixel units; pixel (i, j) has centre (j+.5, i+.5)
        lo = np.ceil(T.min(axis=1) - 0.5).astype(np.int64).clip(0, size - 1)
        hi = np.floor(T.max(axis=1) - 0.5).astype(np.int64).clip(-1, size - 1)
        nx, ny = (hi - lo + 1).clip(0).T
        cnt = nx * ny
        tri = np.repeat(np.arange(len(T)), cnt)
        r = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        nxt = np.maximum(nx[tri], 1)
        j = lo[tri, 0] + r % nxt
        i = lo[tri, 1] + r // nxt
        a, b, c = T[tri, 0], T[tri, 1], T[tri, 2]
        p = np.stack([j + 0.5, i + 0.5], axis=1)

        def cross(u, v):
            return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]

        D = cross(b - a, c - a)
        ok = np.abs(D) > 1e-12
        D = np.where(ok, D, 1.0)
        lb = cross(p - a, c - a) / D
        lc = cross(b - a, p - a) / D
        la = 1.0 - lb - lc
        inside = ok & (la >= -1e-9) & (lb >= -1e-9) & (lc >= -1e-9)
        k = F[s : s + 8192][tri[inside]]
        L = np.stack([la, lb, lc], axis=1)[inside]
        pix = i[inside] * size + j[inside]
        img[pix] = np.einsum("pc,pcd->pd", L, C[k])
        covered[pix] = True
    return img.reshape(size, size, -1), covered.reshape(size, size)


def _dilate(img: np.ndarray, covered: np.ndarray, rings: int) -> np.ndarray:
    """Grow the covered region by ``rings`` pixels (each new pixel takes its nearest covered
    pixel's colour, Euclidean), then give the rest of the background the mean covered colour."""
    from scipy.ndimage import distance_transform_edt

    dist, (ii, jj) = distance_transform_edt(~covered, return_indices=True)
    out = img[ii, jj]
    out[dist > rings] = img[covered].mean(axis=0)
    return out


def bake_texture(
    colours: np.ndarray,
    *,
    size: int = TEXTURE_SIZE,
    dilate: int = 8,
    layout: UVLayout | None = None,
) -> np.ndarray:
    """Bake a body's per-vertex colours into a texture on the template UV layout.

    Parameters
    ----------
    colours : (13380, 3) RGB per body vertex, uint8 or floats in [0, 1] (template order).
    size : texture width = height in pixels.
    dilate : pixels grown across the UV islands' borders (seams stay seamless under bilinear
        filtering and a few mipmap levels).
    layout : default the committed :func:`load_uv_layout`.

    Returns
    -------
    (size, size, 3) uint8 RGB image, glTF's orientation (row 0 at v = 0).
    """
    L = load_uv_layout() if layout is None else layout
    if size < 16:
        raise ValueError(f"size must be at least 16 pixels, got {size}")
    C = _as_unit(colours, len(load_template().V))
    P = L.uv.astype(np.float64) * size
    img, covered = _rasterise(P, np.asarray(L.faces, dtype=np.int64), C[L.vertex], size)
    img = _dilate(img, covered, dilate)
    return np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)


def fit_texture(colours: np.ndarray, texture: np.ndarray | None) -> np.ndarray:
    """A coloured fit's texture on the template UV layout: ``texture`` (taken from a textured
    scan at full resolution, ``FitResult.texture``) when there is one, else the per-vertex
    ``colours`` (13380, 3) baked (:func:`bake_texture`). Returns (size, size, 3) uint8."""
    return bake_texture(colours) if texture is None else texture


def texture_colours(image: np.ndarray, *, layout: UVLayout | None = None) -> np.ndarray:
    """Per-vertex colours of a texture on the template UV layout: (13380, 3) float64 in [0, 1],
    the bilinear sample at each vertex's UV (averaged over a seam vertex's copies)."""
    from core.io.images import sample_image

    L = load_uv_layout() if layout is None else layout
    n = len(load_template().V)
    S = sample_image(image, L.uv)
    out = np.zeros((n, S.shape[1]))
    np.add.at(out, L.vertex, S)
    return out / np.bincount(L.vertex, minlength=n)[:, None]


def textured_glb(
    path_or_none,
    V: np.ndarray,
    texture: np.ndarray | bytes,
    *,
    layout: UVLayout | None = None,
    skin: GlbSkin | None = None,
) -> bytes:
    """A body's GLB carrying a texture on the template UV layout (``TEXCOORD_0`` and the
    material's ``baseColorTexture``), seam vertices split as :class:`UVLayout` says.

    Parameters
    ----------
    path_or_none : output file, or None to only return the bytes.
    V : (13380, 3) body vertices in template order, metres.
    texture : (H, W, 3) uint8 image (e.g. :func:`bake_texture`) or PNG bytes.
    skin : the body's skin (per body vertex); seam copies get their vertex's influences.
    """
    from core.geometry import vertex_normals
    from core.io.images import encode_png
    from core.io.writers import write_glb

    L = load_uv_layout() if layout is None else layout
    tpl = load_template()
    V = np.asarray(V, dtype=np.float64)
    if V.shape != tpl.V.shape:
        raise ValueError(f"V must have shape {tpl.V.shape}, got {V.shape}")
    png = bytes(texture) if isinstance(texture, bytes | bytearray) else encode_png(texture)
    N = vertex_normals(V, tpl.F)  # of the body, so seam copies share their normal
    if skin is not None:
        skin = replace(skin, joint_index=skin.joint_index[L.vertex], weights=skin.weights[L.vertex])
    return write_glb(
        path_or_none,
        V[L.vertex],
        L.faces,
        normals=N[L.vertex],
        texcoords=L.uv,
        texture_png=png,
        skin=skin,
    )


def write_textured_obj(path, V: np.ndarray, texture: np.ndarray | bytes) -> None:
    """Write a body as OBJ with the texture on the template UV layout: ``path`` (``.obj``,
    the body's 13 380 vertices in template order, ``vt`` per face corner), the material
    library ``<stem>.mtl`` (``map_Kd <stem>.png``) and the image ``<stem>.png`` beside it.

    Parameters
    ----------
    path : the ``.obj`` file. V : (13380, 3) body vertices in template order, metres.
    texture : (H, W, 3) uint8 image (e.g. :func:`bake_texture`) or PNG bytes.
    """
    from pathlib import Path

    from core.io.images import encode_png
    from core.io.writers import atomic_write, write_obj

    path = Path(path)
    L = load_uv_layout()
    tpl = load_template()
    png = bytes(texture) if isinstance(texture, bytes | bytearray) else encode_png(texture)
    mtl = f"newmtl skin\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nmap_Kd {path.stem}.png\n"
    atomic_write(path.with_suffix(".png"), png)
    atomic_write(path.with_suffix(".mtl"), mtl.encode("utf-8"))
    write_obj(path, V, tpl.F, uv=L.uv, FT=L.faces, mtllib=f"{path.stem}.mtl")


def textured_surface(raw: RawMesh, frame: FrameInfo) -> TexturedSurface | None:
    """The textured surface of a raw scan (read with its texture mapping) in the canonical
    frame, for :func:`transfer_texture`; None when the scan has no texture or no triangles."""
    from core.scan import TexturedSurface

    if raw.texture is None or raw.F is None or not (raw.texture.image >= 0).any():
        return None
    return TexturedSurface(V=frame.to_canonical(raw.V), F=raw.F, texture=raw.texture)


def transfer_texture(
    V: np.ndarray,
    surface: TexturedSurface,
    fallback: np.ndarray,
    *,
    max_distance: float = 0.01,
    max_angle_deg: float = 60.0,
    dilate: int = 8,
    layout: UVLayout | None = None,
) -> tuple[np.ndarray, float]:
    """A body's texture taken from a textured scan at full texture resolution.

    Every texel of the template UV layout is a point on the fitted body (its UV triangle's
    corners interpolated); it takes the scan texture's colour at the closest scan surface point
    within ``max_distance`` whose triangle faces within ``max_angle_deg`` of the body's normal
    (either side: a raw scan's winding is not trusted), sampled at that point's interpolated
    UVs. Texels with no such point (holes, untextured triangles) keep ``fallback``'s colour
    (the per-vertex transfer baked: :func:`bake_texture`); then the islands are dilated.

    Parameters
    ----------
    V : (13380, 3) fitted body, template order, canonical frame (metres).
    surface : the scan's textured surface (:func:`textured_surface`), same frame.
    fallback : (S, S, 3) uint8 texture on the layout; its size is the result's.

    Returns
    -------
    image : (S, S, 3) uint8 texture on the template UV layout.
    share : fraction of the covered texels that took the scan's texture.
    """
    from scipy.spatial import cKDTree

    from core.geometry import closest_point_on_triangles, face_normals, normalize, vertex_normals
    from core.io.images import sample_image
    from core.transfer.colour import barycentric

    L = load_uv_layout() if layout is None else layout
    size = fallback.shape[0]
    tpl = load_template()
    V = np.asarray(V, dtype=np.float64)
    N = vertex_normals(V, tpl.F)
    P = L.uv.astype(np.float64) * size
    img6, covered = _rasterise(P, L.faces.astype(np.int64), np.hstack([V, N])[L.vertex], size)
    X = img6[covered][:, :3]
    n = normalize(img6[covered][:, 3:])
    tex = surface.texture
    tri = np.flatnonzero(tex.image >= 0)
    SV, SF = surface.V, surface.F[tri]  # corners gathered per chunk, never (t, 3, 3) at once
    FN = normalize(face_normals(SV, SF))
    centre = (SV[SF[:, 0]] + SV[SF[:, 1]] + SV[SF[:, 2]]) / 3.0
    radius = max(float(np.linalg.norm(SV[SF[:, c]] - centre, axis=1).max()) for c in range(3))
    reach = max_distance + min(radius, 0.05)
    tree = cKDTree(centre)
    cos_lim = np.cos(np.deg2rad(max_angle_deg))
    out = fallback[covered].astype(np.float64) / 255.0
    matched = np.zeros(len(X), dtype=bool)
    k = min(8, len(tri))
    for s in range(0, len(X), 65536):
        Xc, nc = X[s : s + 65536], n[s : s + 65536]
        d, j = tree.query(Xc, k=k, distance_upper_bound=reach, workers=-1)
        d, j = d.reshape(len(Xc), k), j.reshape(len(Xc), k)
        ok = np.isfinite(d)
        jj = np.where(ok, j, 0)
        A, B, C = (SV[SF[jj, c]] for c in range(3))  # (chunk, k, 3)
        Xr = np.broadcast_to(Xc[:, None], A.shape)
        Q = closest_point_on_triangles(*(a.reshape(-1, 3) for a in (Xr, A, B, C)))
        Q = Q.reshape(A.shape)
        dist = np.linalg.norm(Q - Xc[:, None], axis=2)
        facing = np.abs(np.einsum("ckd,cd->ck", FN[jj], nc)) >= cos_lim
        ok &= facing & (dist <= max_distance)
        best = np.argmin(np.where(ok, dist, np.inf), axis=1)
        rows = np.flatnonzero(ok.any(axis=1))
        if not len(rows):
            continue
        t = jj[rows, best[rows]]
        r = rows, best[rows]
        lam = barycentric(Q[r], A[r], B[r], C[r])  # (q, 3)
        uv = np.einsum("qc,qcd->qd", lam, tex.uv[tri[t]].astype(np.float64))
        img_of = tex.image[tri[t]]
        for i in np.unique(img_of):
            sel = img_of == i
            out[s + rows[sel]] = sample_image(tex.images[int(i)], uv[sel])
        matched[s + rows] = True
    full = np.zeros(fallback.shape)
    full[covered] = out
    full = _dilate(full, covered, dilate)
    image = np.clip(np.round(full * 255.0), 0, 255).astype(np.uint8)
    return image, float(matched.mean()) if len(matched) else 0.0
