"""Plain containers for meshes and scans passed between readers, registration and writers."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from core.geometry import kept_faces


@dataclass
class ScanTexture:
    """A scan's texture mapping, per triangle corner (as read; finer than its vertex colours).

    Attributes
    ----------
    uv : (m, 3, 2) float32 texture coordinates of each triangle's corners (glTF convention:
        origin at the image's top-left), aligned with the mesh's ``F``.
    image : (m,) int16 index into ``images`` per triangle, -1 where a triangle has none.
    images : decoded (H, W, 3) uint8 RGB images.
    """

    uv: np.ndarray
    image: np.ndarray
    images: list[np.ndarray]


@dataclass
class RawMesh:
    """A mesh or point cloud as read from a file, in the file's own units and axes.

    Attributes
    ----------
    V : (n, 3) float64 vertex positions.
    F : (m, 3) int64 triangles, or None for a point cloud.
    normals : (n, 3) float64 unit vertex normals, or None when the file has none.
    confidence : (n,) float64 per-vertex confidence in [0, 1], or None when the file has none.
    colors : (n, 3) uint8 RGB, or None.
    texture : the texture mapping of a textured OBJ or GLB (aligned with ``F``), or None.
    """

    V: np.ndarray
    F: np.ndarray | None = None
    normals: np.ndarray | None = None
    confidence: np.ndarray | None = None
    colors: np.ndarray | None = None
    texture: ScanTexture | None = None

    def surface(self) -> tuple[np.ndarray, np.ndarray | None]:
        """(V (k, 3), F (m, 3) renumbered): the vertices a triangle uses, the points of a cloud.

        A mesh's vertices that no triangle uses are no part of its surface (an exporter's
        leftovers, a camera's or a marker's position): the frame and the body checks leave
        them out, as :func:`core.io.prepare.prepare_scan` does."""
        if self.F is None or not len(self.F):
            return self.V, self.F
        used = np.zeros(len(self.V), bool)
        used[np.asarray(self.F).ravel()] = True
        if used.all():
            return self.V, self.F
        return self.V[used], (np.cumsum(used) - 1)[self.F]


@dataclass
class FrameInfo:
    """How a file's coordinates were mapped to bodyspace's frame (metres, +Y up).

    ``x_canonical = scale * R @ x_file``; ``R`` (3, 3) is a proper rotation: the signed axis
    permutation of ``up`` (``core.io.frame.rotation_for_up``), then, for a body standing
    ``tilt_deg`` off that axis (a handheld scanner's arbitrary frame), the rotation that levels
    it (``core.io.frame.detect_frame``).
    """

    units: str  # "m", "cm", "mm" or "in" (core.io.frame.UNITS)
    up: str  # e.g. "+y", "+z"
    scale: float
    R: np.ndarray
    detected: bool  # True when units/up were auto-detected rather than given
    tilt_deg: float = 0.0  # degrees the body's axis stood off ``up`` (0: not levelled)

    def describe(self, units_option: str, up_option: str) -> str:
        """The report's note on this frame, given the units and up options (``"auto"``:
        detected), e.g. ``units mm (detected), up axis +z (given)``."""
        how_u = "detected" if units_option == "auto" else "given"
        how_up = "detected" if up_option == "auto" else "given"
        out = f"units {self.units} ({how_u}), up axis {self.up} ({how_up})"
        if self.tilt_deg:
            out += (
                f"; the body stood {self.tilt_deg:.1f}° off that axis: the scan was levelled "
                "(turned to stand upright, and the fit with it)"
            )
        return out

    def to_canonical(self, X: np.ndarray) -> np.ndarray:
        """Map (k, 3) file coordinates to canonical metres, +Y up."""
        return _times3(X, self.scale * self.R.T)

    def to_file(self, X: np.ndarray) -> np.ndarray:
        """Map (k, 3) canonical coordinates back to the file's units and axes."""
        return _times3(X, self.R / self.scale)


def _times3(X: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``X @ M`` for (k, 3) X and a (3, 3) M as three scaled columns: BLAS matmul of this
    shape costs ~10x more CPU (0.6 s for 2.2 M points, threads included)."""
    X = np.asarray(X, dtype=np.float64)
    out = X[..., 0:1] * M[0]
    out += X[..., 1:2] * M[1]
    out += X[..., 2:3] * M[2]
    return out


@dataclass
class Scan:
    """A scan ready for registration: metres, +Y up (right-handed).

    Attributes
    ----------
    V : (n, 3) float64 points, metres.
    F : (m, 3) int64 triangles or None (point cloud).
    normals : (n, 3) float64 unit normals (always present; estimated if the file had none).
    confidence : (n,) float64 in [0, 1] (estimated if the file had none).
    boundary : (n,) bool, True for points on a hole boundary.
    frame : how the file's coordinates were mapped here.
    notes : human-readable notes for the report (e.g. "confidence estimated").
    colors : (n, 3) uint8 RGB per point, or None (the file had no colours).
    removed : points of the file left out as not the body (``core.io.clean``), by kind:
        ``{"floor_points": n, "stray_points": m}``; empty when the scan was not prepared.
    textured : the scan's textured surface as read, for a textured OBJ/GLB (else None).
    """

    V: np.ndarray
    F: np.ndarray | None
    normals: np.ndarray
    confidence: np.ndarray
    boundary: np.ndarray
    frame: FrameInfo | None = None
    notes: list[str] = field(default_factory=list)
    colors: np.ndarray | None = None
    removed: dict[str, int] = field(default_factory=dict)
    textured: TexturedSurface | None = None


@dataclass
class TexturedSurface:
    """A textured scan's surface as read (before cleaning), in the canonical frame: what
    :func:`core.transfer.texture.transfer_texture` samples at full texture resolution. Set by
    the scan loaders beside the prepared scan (``Scan.textured``), not by preparation.

    Attributes
    ----------
    V : (n, 3) float64 vertices, metres, +Y up. F : (m, 3) int64 triangles.
    texture : their corners' texture mapping.
    """

    V: np.ndarray
    F: np.ndarray
    texture: ScanTexture


def scan_without(scan: Scan, drop: np.ndarray, what: str, *, rim: bool = False) -> Scan:
    """The scan without the points ``drop`` ((n,) bool) and their triangles; ``removed[what]``
    counts them (the fit's report then says its figures are over the kept points). ``rim``:
    the kept points of a triangle that lost a corner become hole boundary (no data weight, as a
    scanner's hole rim)."""
    keep = ~drop
    boundary = scan.boundary.copy()
    if rim and scan.F is not None:
        cut = drop[scan.F].any(axis=1)
        edge = np.zeros(len(keep), bool)
        edge[scan.F[cut].ravel()] = True
        edge &= keep
        boundary |= edge
    removed = dict(scan.removed)
    removed[what] = removed.get(what, 0) + int(drop.sum())
    return replace(
        scan, V=scan.V[keep], F=None if scan.F is None else kept_faces(scan.F, keep),
        normals=scan.normals[keep], confidence=scan.confidence[keep], boundary=boundary[keep],
        removed=removed, colors=None if scan.colors is None else scan.colors[keep],
    )  # fmt: skip
