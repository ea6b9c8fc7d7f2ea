"""Units and up-axis of a scan: detection and mapping to bodyspace's frame.

Canonical frame: metres, right-handed, +Y up, +Z the subject's front, +X the subject's left.
``x_canonical = scale * R @ x_file``, ``R`` a proper rotation (det +1): a signed axis
permutation, levelled where the body stands tilted (below). Only the up axis is mapped; the
facing direction about the vertical is left to the registration's rigid alignment, and no
translation is applied.

Auto-detection rules
--------------------
- **Up**: with head and foot markers, the signed file axis closest to the foot -> head
  direction. Otherwise the axis of largest extent, if it is at least 1.15x the other two (with
  two extents closer than that, as a body with its arms spread wide has, the one of the two
  that is not the body's left-right mirror axis, when the points tell; failing both, the axis
  nearest the body's long axis, as for a body turned 30-55° off every file axis); its sign is
  taken as **positive** (a file's up axis is assumed to point up, as every scanner we know
  writes it). Pass ``up="-y"`` etc. for upside-down files; a markerless fit that finds
  the body head-down turns the scan over (:func:`turn_over`).
- **Level**: a body whose long axis (the principal axis of its points nearest the up axis)
  stands more than :data:`LEVEL_MIN_DEG` off the up axis (a handheld scanner's or an
  uncalibrated rig's frame) is turned upright: ``R`` is then the axis permutation followed by
  that levelling rotation, and ``FrameInfo.tilt_deg`` says by how much (the report's note too).
- **Units**: the body's height (robust extent along the up axis): 1.0-2.3 -> m, 39.4-90.6 ->
  inches (``in``: 1.0-2.3 m; US apparel and anthropometry scanners write them), 100-230 -> cm,
  1000-2300 -> mm; anything else is a :class:`UnitsError` naming the ``units=`` option. The
  ranges do not overlap, so an adult's height tells them apart.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from core.errors import UnitsError
from core.scan import FrameInfo, RawMesh, Scan

#: Canonical metres per file unit of each units name a scan (or markers) may be stored in.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
#: The units options of the readers, the CLI and the API: detection, or one of :data:`UNITS`.
UNITS_OPTIONS = ("auto", *UNITS)
UPS = ("+x", "-x", "+y", "-y", "+z", "-z")
#: Standing adults' heights (1.0-2.3 m) in each of :data:`UNITS`: detection reads the units off
#: the height (:func:`detect_frame`).
HEIGHT_RANGES = {
    "m": (1.0, 2.3), "cm": (100.0, 230.0), "mm": (1000.0, 2300.0), "in": (39.37, 90.56),
}  # fmt: skip
DOMINANCE = 1.15
#: A body whose long axis stands more than this (degrees) off the up axis is levelled
#: (:func:`_level`), when the axis of its band :data:`LEVEL_BAND` does too. Upright bodies read
#: 0.1-4.5° over the whole body (the 70 upright cases of ``core.synth.scanner_outputs``' varied,
#: wide, booth and palms sets: posture, hair, belly and buttocks tilt the principal axis;
#: closed_booth-311, a bun and a forward head, 4.50, its band 0.54) and at most 2.95 by the lower
#: of the two, so they are left as they are; the markerless fit tolerates about 5° (raw-4: 5.0
#: mm correspondence at 5°, 9.5 at 6.5°, 29 at 8°, failed).
LEVEL_MIN_DEG = 4.5
#: Share of the body's height (from its lowest point) of the band whose axis must read the tilt
#: too: without the feet and the head (and its hair).
LEVEL_BAND = (0.05, 0.80)
#: Tilts beyond this (degrees) are not levelled (the nearest file axis is at most 54.7° off).
LEVEL_MAX_DEG = 55.0
#: Fewer points than this (a marker set's) tell no tilt.
LEVEL_MIN_POINTS = 1000
#: Cells of the grid along the body's largest extent over which the principal axes are taken.
LEVEL_GRID = 100
#: The long axis's variance must be at least this many times the next axis's.
LEVEL_SEPARATION = 1.5

HEAD_MARKERS = (
    "Vertex",
    "Sellion",
    "Menton",
    "Cervicale",
    "Glabella",
    "Opisthocranion",
    "Pronasale",
    "Supramenton",
    "Tragion_L",
    "Tragion_R",
    "Infraorbitale_L",
    "Infraorbitale_R",
)
FOOT_MARKERS = (
    "Calcaneus_posterior_L",
    "Calcaneus_posterior_R",
    "Toe_tip_L",
    "Toe_tip_R",
    "Lateral_malleolus_L",
    "Lateral_malleolus_R",
    "Medial_malleolus_L",
    "Medial_malleolus_R",
    "MTP_I_L",
    "MTP_I_R",
    "MTP_V_L",
    "MTP_V_R",
)

_OPTIONS = (
    'pass units="m", "cm", "mm" or "in" and up="+x", "-x", "+y", "-y", "+z" or "-z" '
    "to say how the file is stored"
)


def rotation_for_up(up: str) -> np.ndarray:
    """The proper rotation (3, 3) mapping the file's ``up`` axis to canonical +Y.

    ``+y`` is the identity; ``+z`` is the usual Z-up -> Y-up map ``(x, y, z) -> (x, z, -y)``.
    """
    up = up.lower()
    R = {
        "+y": [[1, 0, 0], [0, 1, 0], [0, 0, 1]],
        "-y": [[1, 0, 0], [0, -1, 0], [0, 0, -1]],  # 180 deg about X
        "+z": [[1, 0, 0], [0, 0, 1], [0, -1, 0]],  # -90 deg about X
        "-z": [[1, 0, 0], [0, 0, -1], [0, 1, 0]],  # +90 deg about X
        "+x": [[0, -1, 0], [1, 0, 0], [0, 0, 1]],  # +90 deg about Z
        "-x": [[0, 1, 0], [-1, 0, 0], [0, 0, 1]],  # -90 deg about Z
    }.get(up)
    if R is None:
        raise UnitsError(f"unknown up axis {up!r}; use one of {', '.join(UPS)} or 'auto'", up=up)
    return np.array(R, dtype=np.float64)


def _robust_extent(V: np.ndarray) -> np.ndarray:
    """Per-axis extent (3,) ignoring the 0.1 % most extreme points at each end."""
    if len(V) >= 1000:
        lo, hi = np.quantile(V, [0.001, 0.999], axis=0)
    else:
        lo, hi = V.min(axis=0), V.max(axis=0)
    return hi - lo


def _up_from_markers(markers: Mapping[str, np.ndarray]) -> str | None:
    head = [np.asarray(markers[k], float) for k in HEAD_MARKERS if k in markers]
    foot = [np.asarray(markers[k], float) for k in FOOT_MARKERS if k in markers]
    if not head or not foot:
        return None
    d = np.mean(head, axis=0) - np.mean(foot, axis=0)
    L = float(np.linalg.norm(d))
    if not np.isfinite(L) or L == 0:
        return None
    a = int(np.argmax(np.abs(d)))
    if abs(d[a]) / L < 0.7:
        raise UnitsError(
            "the foot-to-head direction of the markers is not close to any file axis "
            f"(direction {np.round(d / L, 2).tolist()}); the body is tilted: {_OPTIONS}",
            direction=(d / L).tolist(),
        )
    return ("+" if d[a] > 0 else "-") + "xyz"[a]


def _mirror_gap(V: np.ndarray, axis: int, about: int, n: int = 4000) -> float:
    """Median distance (file units) from the points ``V`` (q, 3), mirrored across a plane
    through their mean, to the nearest unmirrored point (an even subsample of ≤ ``n``
    points); the plane's normal is file axis ``axis`` turned about axis ``about`` by
    :data:`MIRROR_TURNS_DEG`, the least gap of those.

    A standing body is nearly mirror-symmetric left to right, never head to foot: mirrored
    across its left-right axis it lands on itself (the posture's asymmetry apart), mirrored
    across its vertical the head lands among the feet."""
    from scipy.spatial import cKDTree

    P = V[np.linspace(0, len(V) - 1, min(n, len(V))).astype(np.int64)]
    c = P.mean(axis=0)
    tree = cKDTree(P)
    third = 3 - axis - about
    best = np.inf
    for deg in MIRROR_TURNS_DEG:
        nrm = np.zeros(3)
        nrm[axis], nrm[third] = np.cos(np.radians(deg)), np.sin(np.radians(deg))
        M = P - 2.0 * np.outer((P - c) @ nrm, nrm)
        best = min(best, float(np.median(tree.query(M, k=1)[0])))
    return best


#: Turns (degrees) of the mirror plane's normal tried by :func:`_mirror_gap`: a body may face any
#: way about its up axis (a file's facing is not the scanner's), and the two largest extents are
#: the up axis and the axis within 45° of its arm span. With ±20° only, a T-pose raw scan turned
#: ~30° off a file axis read a gap ratio of 1.57 (below :data:`MIRROR_RATIO`: refused); with
#: ±40° the 65 scans of bodies with their arms 60-90° out whose two largest extents were within
#: :data:`DOMINANCE` (raw, cloud and closed_hair cases of ``core.synth.scanner_outputs`` with the
#: arms drawn 60-90°, 30 seeds each) read 2.32-3.54, every one right.
MIRROR_TURNS_DEG = (-40.0, -30.0, -20.0, -10.0, 0.0, 10.0, 20.0, 30.0, 40.0)

#: With two extents within :data:`DOMINANCE` of each other (arms spread as wide as the body is
#: tall), the one whose mirror gap (:func:`_mirror_gap`) is at least this many times the other's
#: is up.
MIRROR_RATIO = 1.6


def _up_from_extent(ext: np.ndarray, V: np.ndarray | None = None) -> str:
    """The largest extent's axis, + sign; where the two largest are within :data:`DOMINANCE`
    of each other (a body with its arms spread as wide as it is tall), the one of the two that
    is not the body's mirror axis (:func:`_mirror_gap`), if the points ``V`` (q, 3) tell."""
    order = np.argsort(ext)[::-1]
    a, b = int(order[0]), int(order[1])
    if ext[b] > 0 and ext[a] >= DOMINANCE * ext[b]:
        return "+" + "xyz"[a]
    if ext[b] > 0 and V is not None and len(V) >= 100:
        ga, gb = _mirror_gap(V, a, about=b), _mirror_gap(V, b, about=a)
        if ga >= MIRROR_RATIO * gb:
            return "+" + "xyz"[a]
        if gb >= MIRROR_RATIO * ga:
            return "+" + "xyz"[b]
    raise UnitsError(
        "cannot tell which axis is up: the scan's extents "
        f"(x {ext[0]:.4g}, y {ext[1]:.4g}, z {ext[2]:.4g}) have no clearly largest axis "
        f"(need >= {DOMINANCE}x the others) and neither of the two largest is clearly the "
        f"body's left-right mirror axis; give markers with head and foot landmarks, or "
        f"{_OPTIONS}",
        extents=ext.tolist(),
    )


def _principal_axes(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(variances (3,) ascending, axes (3, 3) as columns) of the points P (n, 3) taken one per
    occupied cell of a grid 1/:data:`LEVEL_GRID` of their largest extent: the body's shape, not
    where the scanner sampled it densely (overlaps, a handheld scanner's lingering)."""
    ext = _robust_extent(P).max()
    cell = ext / LEVEL_GRID if ext > 0 else 1.0
    lo = np.quantile(P, 0.001, axis=0) - ext  # far strays held at the box's edge: no overflow
    ijk = np.floor((np.clip(P, lo, lo + 3 * ext) - lo) / cell).astype(np.int64)
    span = ijk.max(axis=0) + 1
    key = np.unique((ijk[:, 0] * span[1] + ijk[:, 1]) * span[2] + ijk[:, 2])  # one per cell
    G = np.stack([key // (span[1] * span[2]), key // span[2] % span[1], key % span[2]], 1) * cell
    return np.linalg.eigh(np.cov(G.T))


def _up_from_principal_axis(V: np.ndarray) -> str | None:
    """The file axis nearest the body's long axis, + sign, when no extent is clearly the largest
    (a body turned 30-55° off every file axis) but the long axis is clearly the longest
    (:data:`LEVEL_SEPARATION`); None otherwise."""
    if len(V) < LEVEL_MIN_POINTS:
        return None
    w, E = _principal_axes(V)
    if w[2] < LEVEL_SEPARATION * w[1]:
        return None
    return "+" + "xyz"[int(np.argmax(np.abs(E[:, 2])))]


def _level(V: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, float]:
    """(L (3, 3), tilt in degrees): the rotation of the canonical frame that turns the body's
    long axis to +Y, for points V (n, 3, file frame) mapped by the axis permutation A (3, 3),
    and that axis's angle from +Y. L is the identity (tilt still measured) where the tilt is
    under :data:`LEVEL_MIN_DEG` or over :data:`LEVEL_MAX_DEG`, the axis is not clearly the
    longest (:data:`LEVEL_SEPARATION`), or the axis of the body's :data:`LEVEL_BAND` reads
    under :data:`LEVEL_MIN_DEG`; with under :data:`LEVEL_MIN_POINTS` points, tilt 0."""
    from scipy.spatial.transform import Rotation

    eye = np.eye(3)
    if len(V) < LEVEL_MIN_POINTS:
        return eye, 0.0
    P = V @ A.T
    w, E = _principal_axes(P)
    i = int(np.argmax(np.abs(E[1])))
    axis = E[:, i] * np.sign(E[1, i])
    tilt = float(np.degrees(np.arccos(np.clip(axis[1], -1.0, 1.0))))
    others = np.delete(w, i)
    if not LEVEL_MIN_DEG <= tilt <= LEVEL_MAX_DEG or w[i] < LEVEL_SEPARATION * others.max():
        return eye, tilt
    # the same without the head and feet (a bun, a forward head, the feet's length tip the
    # whole body's axis): levelled only when this too reads the tilt
    band = axis
    for _ in range(2):
        h = P @ band
        lo, hi = np.quantile(h, [0.001, 0.999])
        t = (h - lo) / (hi - lo)
        _, Eb = _principal_axes(P[(t > LEVEL_BAND[0]) & (t < LEVEL_BAND[1])])
        j = int(np.argmax(np.abs(Eb.T @ band)))
        band = Eb[:, j] * np.sign(Eb[:, j] @ band)
    if np.degrees(np.arccos(np.clip(band[1], -1.0, 1.0))) < LEVEL_MIN_DEG:
        return eye, tilt
    L = Rotation.align_vectors([[0.0, 1.0, 0.0]], [axis])[0].as_matrix()
    return L, tilt


def _units_from_height(h: float, up: str) -> str:
    for u, (lo, hi) in HEIGHT_RANGES.items():
        if lo <= h <= hi:
            return u
    raise UnitsError(
        f"cannot tell the units: the body is {h:.4g} units tall along {up}, which is not a "
        "standing adult in metres (1.0-2.3), inches (39.4-90.6), centimetres (100-230) or "
        "millimetres (1000-2300); "
        f"{_OPTIONS}",
        height=h,
        up=up,
    )


def detect_frame(
    V: np.ndarray,
    *,
    units: str = "auto",
    up: str = "auto",
    markers: Mapping[str, np.ndarray] | None = None,
) -> FrameInfo:
    """Work out how to map a scan's coordinates to metres, +Y up.

    Parameters
    ----------
    V : (n, 3) vertex positions in the file's units and axes.
    units : {"auto", "m", "cm", "mm", "in"}
    up : {"auto", "+x", "-x", "+y", "-y", "+z", "-z"}
    markers : name -> (3,) positions in the file's frame; head and foot landmarks decide the
        up axis when ``up="auto"``.

    Returns
    -------
    FrameInfo
        ``scale`` (canonical metres per file unit), ``R`` (3, 3) proper rotation, ``detected``
        True when units or up were auto-detected.

    Raises
    ------
    UnitsError
        Unknown options, an ambiguous up axis, or a height that fits no unit.
    """
    units = str(units).lower()
    up = str(up).lower()
    if units not in UNITS_OPTIONS:
        raise UnitsError(
            f"unknown units {units!r}; use 'auto', 'm', 'cm', 'mm' or 'in' (inches)", units=units
        )
    if up not in ("auto", *UPS):
        raise UnitsError(f"unknown up axis {up!r}; use 'auto' or one of {', '.join(UPS)}", up=up)
    V = np.asarray(V, dtype=np.float64)
    if V.ndim != 2 or V.shape[1] != 3 or len(V) == 0:
        raise UnitsError(f"V must be a non-empty (n, 3) array, got shape {V.shape}")
    finite = np.isfinite(V).all(axis=1)
    if not finite.all():
        V = V[finite]
    ext = _robust_extent(V)
    if up == "auto":
        up_found = _up_from_markers(markers) if markers else None
        if up_found is None:
            try:
                up_found = _up_from_extent(ext, V)
            except UnitsError:  # a body turned far off every file axis: its long axis tells
                up_found = _up_from_principal_axis(V)
                if up_found is None:
                    raise
    else:
        up_found = up
    A = rotation_for_up(up_found)
    L, tilt = _level(V, A)
    levelled = not np.array_equal(L, np.eye(3))
    R = L @ A
    h = float(_robust_extent(V @ R.T)[1]) if levelled else float(ext["xyz".index(up_found[1])])
    units_found = _units_from_height(h, up_found) if units == "auto" else units
    return FrameInfo(
        units=units_found,
        up=up_found,
        scale=UNITS[units_found],
        R=R,
        detected=(units == "auto" or up == "auto"),
        tilt_deg=tilt if levelled else 0.0,
    )


def apply_frame(raw: RawMesh, frame: FrameInfo) -> RawMesh:
    """Map a raw mesh to the canonical frame (positions scaled and rotated, normals rotated).

    Returns a new :class:`RawMesh`; faces, confidence and colours are carried over (the
    rotation is proper, so triangle winding keeps its meaning).
    """
    normals = None if raw.normals is None else np.asarray(raw.normals, float) @ frame.R.T
    return RawMesh(
        V=frame.to_canonical(raw.V),
        F=raw.F,
        normals=normals,
        confidence=raw.confidence,
        colors=raw.colors,
    )


def turn_over(scan: Scan) -> np.ndarray:
    """Turn a scan whose up axis was read with the wrong sign head up, in place.

    Without markers the up axis's sign is assumed positive (see the module notes); a body found
    standing head-down along it (by the markerless search) is turned over: points, normals and
    the textured surface are rotated by ``M`` (3, 3), a proper rotation taking canonical -Y to +Y,
    and the frame becomes that of the opposite up axis (``rotation_for_up``), so ``to_file``
    still maps the canonical frame back to the file's (a scan without a frame: 180° about Z).
    Returns ``M``.
    """
    old = scan.frame
    up = "" if old is None else ("-" if old.up.startswith("+") else "+") + old.up[1]
    # the turn of the canonical frame between the two up axes; a levelled frame stays levelled
    M = np.diag([-1.0, -1.0, 1.0])
    if old is not None:
        M = rotation_for_up(up) @ rotation_for_up(old.up).T
    R = None if old is None else M @ old.R
    scan.V = scan.V @ M.T
    scan.normals = scan.normals @ M.T
    if scan.textured is not None:
        scan.textured.V = scan.textured.V @ M.T
    if old is None or R is None:
        scan.notes.append("the body stood head-down: turned over")
        return M
    scan.frame = FrameInfo(
        units=old.units, up=up, scale=old.scale, R=R, detected=old.detected, tilt_deg=old.tilt_deg
    )
    scan.notes.append(
        f"up axis {old.up} held the body head-down: turned over, up axis {up} (the sign of an "
        "up axis found from the scan's extents is a guess)"
    )
    return M
