"""Closed meshes hole-filled from a raw scan, as booth-scanner software writes them (test material).

:func:`core.synth.scanner_outputs.closed_mesh` closes the *true* body surface: armpits, crotch,
the crown, the soles and under the chin are there as the body has them. Real booth software
cannot do that: its scanner never saw those places, and its watertight mesh bridges them with a
smooth surface of its own making (Poisson-like reconstruction, volumetric fusion). This module
does the same from a simulated raw scan's points and outward normals (:func:`filled_mesh`):

1. on a grid of ``voxel_m``, the signed distance to the scanned surface is known near the points
   (within 1.5 voxels: the mean of the plane distances to the 4 nearest points whose normals
   agree with the nearest one's, clipped to ±1.5 voxels);
2. everywhere else it is unknown and filled by a harmonic (membrane) interpolation: Jacobi
   sweeps with the known values and the grid's border (outside) fixed, started from an
   inside/outside guess (the known band closed by a ball of :data:`SEAL_RADIUS_M`, the outside
   flood-filled from the border). Holes get a smooth, flattish cap that meets the scanned
   surface around them; where an arm hangs a few centimetres from the flank the fill can
   bridge them with a web, as real reconstructions do;
3. the zero level set by marching cubes (scikit-image, BSD-3) after a Gaussian of 0.5 voxel, the
   largest component, outward winding, then quadric edge collapse to the vertex count asked for
   (:func:`core.synth.scanner_outputs.decimate`, fast-simplification, MIT).

The fingers (4 mm pitch, 1 mm noise, gaps of a few millimetres) fuse into mittens by themselves.
Nothing here looks at the body the scan came from: what the scanner missed is made up, as booth
software makes it up.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

#: Known band: voxels whose centre lies within this many voxels of a scan point.
BAND_VOXELS = 1.5
#: Radius (metres) of the ball that closes the known band for the inside/outside start of the
#: fill (only the start: the harmonic fill's result does not depend on it, its speed does).
SEAL_RADIUS_M = 0.05
#: Jacobi sweeps of the harmonic fill at each of the two resolutions.
SWEEPS = (400, 120)


def _signed_band(
    X: np.ndarray, N: np.ndarray, origin: np.ndarray, h: float, shape: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance (metres, + outside) near the points and the mask where it is known."""
    tree = cKDTree(X)
    idx = np.floor((X - origin) / h).astype(np.int64)
    near = np.zeros(shape, dtype=bool)
    near[tuple(np.clip(idx, 0, np.array(shape) - 1).T)] = True
    reach = int(np.ceil(BAND_VOXELS)) + 1
    near = ndimage.binary_dilation(near, iterations=reach)
    ii = np.nonzero(near)
    C = origin + h * (np.stack(ii, axis=1) + 0.5)
    d, j = tree.query(C, k=4)
    ok = d[:, 0] <= BAND_VOXELS * h
    d, j, C = d[ok], j[ok], C[ok]
    ii = tuple(a[ok] for a in ii)
    n0 = N[j[:, 0]]
    plane = np.einsum("ikc,ikc->ik", C[:, None, :] - X[j], N[j])
    agree = np.einsum("ikc,ic->ik", N[j], n0) > 0.5  # the same side of a thin part
    s = (plane * agree).sum(axis=1) / agree.sum(axis=1)
    f = np.zeros(shape, dtype=np.float32)
    known = np.zeros(shape, dtype=bool)
    f[ii] = np.clip(s, -BAND_VOXELS * h, BAND_VOXELS * h)
    known[ii] = True
    return f, known


def _harmonic_fill(f: np.ndarray, known: np.ndarray, h: float, sweeps: int) -> np.ndarray:
    """Jacobi sweeps of the 6-neighbour mean over the unknown voxels (the border stays +)."""
    kernel = np.zeros((3, 3, 3), dtype=np.float32)
    kernel[1, 1, [0, 2]] = kernel[1, [0, 2], 1] = kernel[[0, 2], 1, 1] = 1.0 / 6.0
    out = ~known
    out[0, :, :] = out[-1, :, :] = out[:, 0, :] = out[:, -1, :] = False
    out[:, :, 0] = out[:, :, -1] = False
    for _ in range(sweeps):
        g = ndimage.convolve(f, kernel, mode="nearest")
        f[out] = g[out]
    return f


def filled_mesh(
    X: np.ndarray, N: np.ndarray, voxel_m: float, n_vertices: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """A watertight mesh of a raw scan with its holes filled (see the module's docstring).

    Parameters
    ----------
    X : (n, 3) scan points, metres. N : (n, 3) their outward unit normals.
    voxel_m : grid (metres), e.g. 0.006–0.008.
    n_vertices : decimate to this many vertices (None: the marching-cubes mesh as it is).

    Returns
    -------
    V (m, 3) float64 metres, F (k, 3) int64 outward-wound triangles.
    """
    from skimage.measure import marching_cubes  # dev dependency (BSD-3)

    from core.synth.scanner_outputs import decimate, outward_largest_component

    X = np.asarray(X, dtype=np.float64)
    N = np.asarray(N, dtype=np.float64)
    N = N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)
    h = float(voxel_m)
    pad = 6
    lo, hi = X.min(axis=0) - pad * h, X.max(axis=0) + pad * h
    shape = tuple(int(s) for s in np.ceil((hi - lo) / h).astype(int))
    f, known = _signed_band(X, N, lo, h, shape)
    # the start: outside unless sealed in by the band closed with a ball
    r = max(1, round(SEAL_RADIUS_M / (2 * h)))  # closed on a 2h grid: cheap
    coarse = known[::2, ::2, ::2]
    ball = ndimage.generate_binary_structure(3, 1)
    sealed = ndimage.binary_closing(coarse, structure=ball, iterations=r, border_value=0)
    inside = ndimage.binary_fill_holes(sealed) & ~sealed
    inside = ndimage.binary_dilation(inside, iterations=1)
    inside = np.repeat(np.repeat(np.repeat(inside, 2, 0), 2, 1), 2, 2)[: shape[0], : shape[1],
                                                                        : shape[2]]  # fmt: skip
    start = np.where(inside, -BAND_VOXELS * h, BAND_VOXELS * h).astype(np.float32)
    f = np.where(known, f, start).astype(np.float32)
    # two resolutions: the far field on a 2h grid, then the full grid
    fc = _harmonic_fill(f[::2, ::2, ::2].copy(), known[::2, ::2, ::2], 2 * h, SWEEPS[0])
    up = np.repeat(np.repeat(np.repeat(fc, 2, 0), 2, 1), 2, 2)[: shape[0], : shape[1], : shape[2]]
    f = np.where(known, f, up).astype(np.float32)
    f = _harmonic_fill(f, known, h, SWEEPS[1])
    f = ndimage.gaussian_filter(f, 0.5)
    f = np.pad(f, 1, constant_values=BAND_VOXELS * h)
    V, F, _, _ = marching_cubes(f, level=0.0, spacing=(h, h, h))
    V = V + lo - h + 0.5 * h
    V, F = outward_largest_component(V, F)
    if n_vertices is not None and len(V) > n_vertices:
        V, F = decimate(V, F, n_vertices)
    return V, F


__all__ = ["filled_mesh"]
