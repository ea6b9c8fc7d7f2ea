"""Simulated raw whole-body range scans of a known body (seeded, numpy/scipy only).

The model is a multi-head whole-body scanner of the laser-stripe / structured-light kind
(Cyberware WB4, Vitus, TC2 style): ``n_views`` vertical columns stand on a circle around the
subject; each column sweeps its whole height and yields one range image whose rows are heights
(orthographic vertically, rays horizontal) and whose columns are horizontal angles (perspective
from the column). Per view the body's depth is rasterised with a vectorised z-buffer (exact
points on the true triangles), pixels seen at a grazing angle beyond ``max_angle_deg`` are
dropped, range noise is added along each ray, and the image is triangulated over neighbouring
pixels, breaking at depth jumps. Views are merged by concatenation (overlaps stay duplicated, as in
raw merged scans). Holes then appear where no head looks (soles, armpits, crotch, the crown of the
head, between fingers); the floor contact band is cut explicitly, the crown gets a "hair" dropout
and a few random blobs are removed.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np
from scipy.ndimage import distance_transform_edt, maximum_filter
from scipy.spatial import cKDTree

from core.geometry import vertex_normals
from core.template import load_template

# file-from-canonical axis maps: canonical is +Y up, +Z front, +X left.
_UP = {
    "+y": np.eye(3),
    # +Z up, right-handed: x -> x, y(up) -> z, z(front) -> -y.
    "+z": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),
}
_UNITS = {"m": 1.0, "mm": 1000.0}


@dataclass(frozen=True)
class ScanConfig:
    """Scanner settings. Lengths in metres (canonical frame), angles in degrees.

    Attributes
    ----------
    n_views : number of scanner columns, evenly spaced on a circle around the subject.
    pitch_m : pixel pitch at ``distance_m`` (horizontal and vertical sampling step).
    distance_m : horizontal distance of each column from the subject's vertical axis.
    noise_m : sigma of gaussian range noise along each ray.
    max_angle_deg : pixels whose surface normal is further than this from the ray are dropped.
    triangulation_deg : angle between each head's horizontal light stripe and its two cameras
        (one above, one below); a point is measured only where the stripe and at least one camera
        see it, which carves the natural holes in concavities (armpits, crotch, under the chin).
        0 disables the check.
    depth_jump : triangulation breaks where depths within a pixel triangle differ by more than
        ``depth_jump * pitch_m + 4 * noise_m``.
    edge_px : confidence ramps from 0 to 1 over this many pixels from a range-image edge.
    n_dropouts : (lo, hi) inclusive range for the number of random blobs removed.
    dropout_diameter_m : (lo, hi) blob diameter range.
    crown_cap_m : (lo, hi) height range of the "hair" cap removed from the top of the head.
    floor_cut_m : scan points lower than this above the floor are removed (floor contact).
    marker_sigma_m : sigma of gaussian marker placement noise, per axis.
    units : output units, ``"m"`` or ``"mm"``.
    up : output up axis, ``"+y"`` (canonical) or ``"+z"``.
    random_frame : apply a random rotation about the vertical axis (any angle) and a random
        translation (up to ``max_translation_m`` per axis) to the output frame.
    max_translation_m : bound of the random translation.
    azimuth_jitter_deg : random offset of the first column's azimuth.
    """

    n_views: int = 6
    pitch_m: float = 0.004
    distance_m: float = 1.0
    noise_m: float = 0.001
    max_angle_deg: float = 78.0
    depth_jump: float = 5.0
    triangulation_deg: float = 25.0
    edge_px: float = 4.0
    n_dropouts: tuple[int, int] = (2, 6)
    dropout_diameter_m: tuple[float, float] = (0.01, 0.04)
    crown_cap_m: tuple[float, float] = (0.01, 0.04)
    floor_cut_m: float = 0.01
    marker_sigma_m: float = 0.003
    units: str = "m"
    up: str = "+y"
    random_frame: bool = False
    max_translation_m: float = 0.5
    azimuth_jitter_deg: float = 15.0

    @classmethod
    def small(cls, **kw: object) -> ScanConfig:
        """A coarse, fast configuration for unit tests (4 views, 8 mm pitch)."""
        base = {"n_views": 4, "pitch_m": 0.008, "edge_px": 2.0}
        base.update(kw)
        return cls(**base)  # type: ignore[arg-type]

    def __post_init__(self) -> None:
        if self.units not in _UNITS:
            raise ValueError(f"units must be one of {sorted(_UNITS)}, got {self.units!r}")
        if self.up not in _UP:
            raise ValueError(f"up must be one of {sorted(_UP)}, got {self.up!r}")
        if self.n_views < 1:
            raise ValueError(f"n_views must be >= 1, got {self.n_views}")
        if not 0.0005 <= self.pitch_m <= 0.05:
            raise ValueError(f"pitch_m must be in [0.0005, 0.05] metres, got {self.pitch_m}")


@dataclass
class SimScan:
    """A simulated raw scan and its truth, all in the scan's own frame and units.

    Attributes
    ----------
    V_scan : (n, 3) float64 scan vertices.
    F_scan : (m, 3) int64 triangles (per-view range-image meshes, concatenated).
    confidence : (n,) float64 in [0, 1]: cos(view angle) x distance-to-image-edge ramp.
    normals : (n, 3) float64 unit normals of the scan mesh.
    markers : name -> (3,) float64 landmark position with placement noise.
    V_truth : (13380, 3) float64 the scanned body, template order, same frame and units.
    meta : units, up, ``to_file`` (4, 4) matrix mapping canonical metres to this frame,
        ``view`` (n,) int view index per vertex, config, timings.
    colors : (n, 3) float64 RGB in [0, 1] per scan vertex, when the body was painted.
    """

    V_scan: np.ndarray
    F_scan: np.ndarray
    confidence: np.ndarray
    normals: np.ndarray
    markers: dict[str, np.ndarray]
    V_truth: np.ndarray
    meta: dict = field(default_factory=dict)
    colors: np.ndarray | None = None


def _rasterize(
    uv: np.ndarray, depth: np.ndarray, F: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Z-buffer triangles ``F`` projected to pixel coordinates ``uv`` (pixel centres = integers).

    Returns
    -------
    px, py : (k,) int64 pixel column and row of each covered pixel (nearest surface wins).
    tri : (k,) int64 index into ``F`` of the visible triangle.
    bary : (k, 3) float64 barycentric coordinates of the pixel centre in that triangle.
    d : (k,) float64 interpolated depth.
    """
    a, b, c = uv[F[:, 0]], uv[F[:, 1]], uv[F[:, 2]]
    lo = np.ceil(np.minimum(np.minimum(a, b), c)).astype(np.int64)
    hi = np.floor(np.maximum(np.maximum(a, b), c)).astype(np.int64)
    wh = hi - lo + 1
    den = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    ok = (wh[:, 0] > 0) & (wh[:, 1] > 0) & (np.abs(den) > 1e-12)
    ti = np.flatnonzero(ok)
    w, h = wh[ti, 0], wh[ti, 1]
    cnt = w * h
    rep = np.repeat(np.arange(len(ti)), cnt)
    local = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    t = ti[rep]
    px = lo[t, 0] + local % w[rep]
    py = lo[t, 1] + local // w[rep]
    ax, ay = a[t, 0], a[t, 1]
    e0x, e0y = b[t, 0] - ax, b[t, 1] - ay
    e1x, e1y = c[t, 0] - ax, c[t, 1] - ay
    qx, qy = px - ax, py - ay
    dn = den[t]
    l1 = (qx * e1y - e1x * qy) / dn
    l2 = (e0x * qy - qx * e0y) / dn
    l0 = 1.0 - l1 - l2
    eps = -1e-9
    inside = (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
    px, py, t = px[inside], py[inside], t[inside]
    bary = np.stack([l0[inside], l1[inside], l2[inside]], axis=1)
    d = np.einsum("kj,kj->k", bary, depth[F[t]])
    key = (py - py.min(initial=0)) * (px.max(initial=0) - px.min(initial=0) + 1) + (
        px - px.min(initial=0)
    )
    order = np.lexsort((d, key))
    first = np.ones(len(order), dtype=bool)
    first[1:] = key[order][1:] != key[order][:-1]
    sel = order[first]
    return px[sel], py[sel], t[sel], bary[sel], d[sel]


def _visible(
    uv: np.ndarray,
    depth: np.ndarray,
    F: np.ndarray,
    u: np.ndarray,
    v: np.ndarray,
    d: np.ndarray,
    tol: float = 0.003,
) -> np.ndarray:
    """Whether surface points at pixel coords ``(u, v)`` and depth ``d`` are unoccluded.

    The mesh (``uv`` (n, 2) pixel coords, ``depth`` (n,)) is z-buffered; a point is visible when
    it is no deeper than the farthest surface in its 3x3 pixel neighbourhood plus ``tol``.
    """
    px, py, _, _, zd = _rasterize(uv, depth, F)
    x0, y0 = px.min() - 2, py.min() - 2
    img = np.full((py.max() - y0 + 3, px.max() - x0 + 3), np.inf)
    img[py - y0, px - x0] = zd
    far = maximum_filter(img, size=3, mode="nearest")
    iu = np.clip(np.rint(u).astype(np.int64) - x0, 0, img.shape[1] - 1)
    iv = np.clip(np.rint(v).astype(np.int64) - y0, 0, img.shape[0] - 1)
    return d <= far[iv, iu] + tol


def _scan_view(
    V: np.ndarray,
    F: np.ndarray,
    N: np.ndarray,
    phi: float,
    cfg: ScanConfig,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One column's range image, triangulated.

    ``V`` is horizontally centred on the scanner axis. Returns points (k, 3), triangles (t, 3)
    local to this view, confidence (k,) and unit ray directions (k, 3).
    """
    D, pitch = cfg.distance_m, cfg.pitch_m
    c = D * np.array([np.sin(phi), 0.0, np.cos(phi)])  # column position (horizontal)
    f = -c / D  # looks at the axis
    lat_ax = np.cross(np.array([0.0, 1.0, 0.0]), f)
    rel = V - c
    fwd, lat = rel @ f, rel @ lat_ax
    rng_h = np.hypot(fwd, lat)  # horizontal range
    uv = np.stack([D * np.arctan2(lat, fwd) / pitch, V[:, 1] / pitch], axis=1)
    # back-face culling: keep triangles facing the column
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    cen = V[F].mean(axis=1) - c
    cen[:, 1] = 0.0
    Ff = F[np.einsum("ij,ij->i", fn, cen) < 0]
    px, py, tri, bary, _ = _rasterize(uv, rng_h, Ff)
    tv = Ff[tri]
    P = np.einsum("kj,kjd->kd", bary, V[tv])  # exact points on the true surface
    Nn = np.einsum("kj,kjd->kd", bary, N[tv])
    Nn /= np.linalg.norm(Nn, axis=1, keepdims=True)
    ray = P - c
    ray[:, 1] = 0.0
    ray /= np.linalg.norm(ray, axis=1, keepdims=True)
    cos = -np.einsum("ij,ij->i", Nn, ray)
    cos_max = np.cos(np.radians(cfg.max_angle_deg))
    keep = cos > cos_max
    if cfg.triangulation_deg > 0:  # the stripe must also be seen by a camera above or below
        t = np.tan(np.radians(cfg.triangulation_deg))
        r_pt = np.hypot((P - c) @ f, (P - c) @ lat_ax)
        u_pt = D * np.arctan2((P - c) @ lat_ax, (P - c) @ f) / pitch
        seen = np.zeros(len(P), dtype=bool)
        for sgn in (1.0, -1.0):  # camera above (looking down), camera below (looking up)
            down = np.array([0.0, sgn * t, 0.0])
            cam = ray - down  # (unnormalised) camera ray directions through the points
            ok = -np.einsum("ij,ij->i", Nn, cam) > cos_max * np.linalg.norm(cam, axis=1)
            Fc = F[np.einsum("ij,ij->i", fn, cen / np.linalg.norm(cen, axis=1)[:, None] - down) < 0]
            v_cam = (V[:, 1] + sgn * t * rng_h) / pitch
            v_pt = (P[:, 1] + sgn * t * r_pt) / pitch
            seen |= ok & _visible(np.stack([uv[:, 0], v_cam], 1), rng_h, Fc, u_pt, v_pt, r_pt)
        keep &= seen
    px, py, P, ray, cos = px[keep], py[keep], P[keep], ray[keep], cos[keep]
    src = (tv[keep], bary[keep])  # where each point is on the body (for colours)
    if len(P) == 0:
        return (
            np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0), np.zeros((0, 3)),
            (np.zeros((0, 3), np.int64), np.zeros((0, 3))),
        )  # fmt: skip
    P = P + rng.normal(0.0, cfg.noise_m, size=(len(P), 1)) * ray
    depth = np.einsum("ij,ij->i", P - c, ray)
    # range image
    x0, y0 = px.min(), py.min()
    W, H = px.max() - x0 + 1, py.max() - y0 + 1
    img = -np.ones((H + 1, W + 1), dtype=np.int64)  # padded by one row/col for the quads
    img[py - y0, px - x0] = np.arange(len(P))
    valid = np.pad(img[:H, :W] >= 0, 1)  # padded so image borders count as edges
    dist = distance_transform_edt(valid)[1:-1, 1:-1][py - y0, px - x0]
    conf = np.clip(cos, 0.0, 1.0) * np.clip(dist / cfg.edge_px, 0.0, 1.0)
    # triangulate: quad (a b / c d) -> (a c b), (b c d)
    A, B = img[:-1, :-1].ravel(), img[:-1, 1:].ravel()
    C, Dd = img[1:, :-1].ravel(), img[1:, 1:].ravel()
    T = np.concatenate([np.stack([A, C, B], 1), np.stack([B, C, Dd], 1)])
    T = T[(T >= 0).all(axis=1)]
    dz = depth[T]
    T = T[dz.max(axis=1) - dz.min(axis=1) < cfg.depth_jump * pitch + 4 * cfg.noise_m]
    if len(T):  # orient triangles towards the sensor
        tn = np.cross(P[T[:, 1]] - P[T[:, 0]], P[T[:, 2]] - P[T[:, 0]])
        if np.einsum("ij,ij->i", tn, ray[T[:, 0]]).sum() > 0:
            T = T[:, [0, 2, 1]]
    return P, T, conf, ray, src


def _compact(keep: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop faces touching removed vertices, then unreferenced vertices.

    Returns the kept vertex indices (k,) and the reindexed faces (t, 3).
    """
    F = F[keep[F].all(axis=1)]
    used = np.zeros(len(keep), dtype=bool)
    used[F.ravel()] = True
    idx = np.flatnonzero(used)
    remap = -np.ones(len(keep), dtype=np.int64)
    remap[idx] = np.arange(len(idx))
    return idx, remap[F]


def simulate_scan(
    V: np.ndarray,
    F: np.ndarray,
    rng: np.random.Generator,
    *,
    config: ScanConfig = ScanConfig(),
    landmarks: dict[str, int] | None = None,
    colors: np.ndarray | None = None,
    color_noise: float = 0.02,
    view_bodies: list[np.ndarray] | None = None,
) -> SimScan:
    """Simulate a raw multi-view whole-body range scan of a template-order body.

    Parameters
    ----------
    V : (13380, 3) float64 body vertices, metres, +Y up, +Z front, floor at y = 0.
    F : (m, 3) int triangles (the template's).
    rng : numpy random generator (the only source of randomness: same seed, same scan).
    config : scanner settings; ``ScanConfig.small()`` for fast tests.
    landmarks : name -> vertex index for the markers (default: the template's landmarks).
    colors : (13380, 3) float RGB in [0, 1] painted on the body: each scan point gets the
        barycentric colour of the surface point it samples plus Gaussian noise
        (``color_noise``, drawn after everything else: the geometry is the uncoloured scan's).
    view_bodies : ``config.n_views`` arrays shaped like ``V`` (same triangles ``F``): the body
        as each view saw it (a subject who moved between sequential views,
        :func:`core.synth.realworld.moved_views`); ``V`` stays the truth. Colours are not
        supported with it.

    Returns
    -------
    SimScan in ``config.units`` and ``config.up`` (and a random rigid frame if
    ``config.random_frame``), with the truth body in the same frame.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3:
        raise ValueError(f"V must have shape (n, 3), got {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or F.max(initial=0) >= len(V):
        raise ValueError(f"F must be (m, 3) indices into V, got shape {F.shape}")
    cfg = config
    if view_bodies is not None:
        if len(view_bodies) != cfg.n_views or any(np.shape(b) != V.shape for b in view_bodies):
            raise ValueError(f"view_bodies must be {cfg.n_views} arrays of shape {V.shape}")
        if colors is not None:
            raise ValueError("colors are not supported with view_bodies")
    t0 = time.perf_counter()
    centre = np.array([V[:, 0].mean(), 0.0, V[:, 2].mean()])
    Vc = V - centre
    N = vertex_normals(Vc, F)
    outward = 1.0 if _signed_volume(Vc, F) >= 0 else -1.0  # normals point outwards
    N = outward * N
    phi0 = np.radians(rng.uniform(-cfg.azimuth_jitter_deg, cfg.azimuth_jitter_deg))
    Ps, Ts, Cs, Rs, views, srcs = [], [], [], [], [], []
    n0 = 0
    for k in range(cfg.n_views):
        Vk, Nk = Vc, N
        if view_bodies is not None:  # the body where it stood when this view was taken
            Vk = np.asarray(view_bodies[k], dtype=np.float64) - centre
            Nk = outward * vertex_normals(Vk, F)
        P, T, conf, ray, src = _scan_view(Vk, F, Nk, phi0 + 2 * np.pi * k / cfg.n_views, cfg, rng)
        srcs.append(src)
        Ps.append(P)
        Ts.append(T + n0)
        Cs.append(conf)
        Rs.append(ray)
        views.append(np.full(len(P), k))
        n0 += len(P)
    P, T, conf, ray = np.concatenate(Ps), np.concatenate(Ts), np.concatenate(Cs), np.concatenate(Rs)
    view = np.concatenate(views)
    t_raster = time.perf_counter() - t0
    # explicit removals: floor contact, crown ("hair"), random blobs
    keep = P[:, 1] > V[:, 1].min() + cfg.floor_cut_m
    top = int(np.argmax(V[:, 1]))
    cap = rng.uniform(*cfg.crown_cap_m)
    near_top = np.hypot(P[:, 0] - Vc[top, 0], P[:, 2] - Vc[top, 2]) < 0.15
    keep &= ~(near_top & (P[:, 1] > Vc[top, 1] - cap))
    n_drop = int(rng.integers(cfg.n_dropouts[0], cfg.n_dropouts[1] + 1))
    blobs = []
    if n_drop and len(P):
        tree = cKDTree(P)
        for i in rng.choice(len(P), size=n_drop, replace=False):
            r = 0.5 * rng.uniform(*cfg.dropout_diameter_m)
            keep[tree.query_ball_point(P[i], r)] = False
            blobs.append((P[i] + centre, r))
    idx, T = _compact(keep, T)
    P, conf, ray, view = P[idx], conf[idx], ray[idx], view[idx]
    src_tv = np.concatenate([s_[0] for s_ in srcs])[idx]
    src_bary = np.concatenate([s_[1] for s_ in srcs])[idx]
    Ns = vertex_normals(P, T)
    bad = np.linalg.norm(Ns, axis=1) == 0
    Ns[bad] = -ray[bad]
    P = P + centre
    # markers
    lm = load_template().landmarks if landmarks is None else landmarks
    names = list(lm)
    M = V[[lm[n] for n in names]] + rng.normal(0.0, cfg.marker_sigma_m, size=(len(names), 3))
    # output frame
    A = np.eye(4)
    if cfg.random_frame:
        th = rng.uniform(0.0, 2 * np.pi)
        c_, s_ = np.cos(th), np.sin(th)
        A[:3, :3] = np.array([[c_, 0.0, s_], [0.0, 1.0, 0.0], [-s_, 0.0, c_]])
        A[:3, 3] = rng.uniform(-cfg.max_translation_m, cfg.max_translation_m, size=3)
    S = np.eye(4)
    S[:3, :3] = _UNITS[cfg.units] * _UP[cfg.up]
    A = S @ A

    def tf(X: np.ndarray) -> np.ndarray:
        return X @ A[:3, :3].T + A[:3, 3]

    Rn = A[:3, :3] / _UNITS[cfg.units]
    meta = {
        "units": cfg.units,
        "up": cfg.up,
        "to_file": A,
        "view": view,
        "n_views": cfg.n_views,
        "dropouts": [(tf(c[None])[0], r * _UNITS[cfg.units]) for c, r in blobs],
        "crown_cap_m": cap,
        "config": asdict(cfg),
        "seconds": {"raster": t_raster, "total": time.perf_counter() - t0},
    }
    point_colors = None
    if colors is not None:
        Cv = np.asarray(colors, dtype=np.float64)
        if Cv.shape != V.shape:
            raise ValueError(f"colors must have shape {V.shape}, got {Cv.shape}")
        point_colors = np.einsum("kj,kjc->kc", src_bary, Cv[src_tv])
        point_colors = np.clip(
            point_colors + rng.normal(0.0, color_noise, point_colors.shape), 0, 1
        )
    return SimScan(
        V_scan=tf(P),
        F_scan=T,
        confidence=conf,
        normals=Ns @ Rn.T,
        markers={n: tf(M[i][None])[0] for i, n in enumerate(names)},
        V_truth=tf(V),
        meta=meta,
        colors=point_colors,
    )


def _signed_volume(V: np.ndarray, F: np.ndarray) -> float:
    """Signed volume enclosed by the triangles (positive when they face outwards)."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


__all__ = ["ScanConfig", "SimScan", "simulate_scan", "vertex_normals"]
