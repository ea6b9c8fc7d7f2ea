"""Principal component analysis of registered bodies (Allen, Curless, Popović 2003, §4).

Each body in template order is a vector of 13380·3 coordinates (metres). The space is the mean
plus the top ``k`` principal directions of the centred training bodies (SVD), ``k`` the fewest
components explaining a stated share of the variance. A body's PCA *weights* are its coordinates
along the (orthonormal) components; random bodies are drawn from the Gaussian they define.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.geometry import umeyama
from core.template import load_template


@dataclass
class PCA:
    """A linear shape space.

    Attributes
    ----------
    mean : (3n,) float64 mean body, metres (template order, x, y, z interleaved).
    components : (k, 3n) float32 orthonormal principal directions (rows).
    variances : (k,) float64 variance of each weight over the training bodies, m².
    total_variance : float, summed variance of the training bodies (all directions), m².
    """

    mean: np.ndarray
    components: np.ndarray
    variances: np.ndarray
    total_variance: float

    @property
    def k(self) -> int:
        """Number of components."""
        return len(self.variances)

    @property
    def n_vertices(self) -> int:
        return self.mean.size // 3

    @property
    def explained(self) -> np.ndarray:
        """(k,) share of the total variance explained by each component."""
        return self.variances / self.total_variance

    @property
    def sd(self) -> np.ndarray:
        """(k,) standard deviation of each weight, metres."""
        return np.sqrt(self.variances)

    def _components64(self) -> np.ndarray:
        """``components`` as float64, converted once per components array (synthesis runs per
        request; converting (k, 3n) float32 each time cost ~0.15 ms)."""
        cached = self.__dict__.get("_c64")
        if cached is None or cached[0] is not self.components:
            cached = (self.components, self.components.astype(np.float64))
            self.__dict__["_c64"] = cached
        return cached[1]

    def _check_body(self, V: np.ndarray) -> np.ndarray:
        V = np.asarray(V, dtype=np.float64)
        if V.shape != (self.n_vertices, 3):
            raise ValueError(f"body must have shape ({self.n_vertices}, 3), got {V.shape}")
        if not np.isfinite(V).all():
            raise ValueError("body has non-finite vertices")
        return V

    def project(self, V: np.ndarray) -> np.ndarray:
        """PCA weights of a body already in the model's frame.

        Parameters
        ----------
        V : (n, 3) vertices, metres, template order.

        Returns
        -------
        (k,) float64 weights, metres (coordinates along the orthonormal components).
        """
        V = self._check_body(V)
        return self._components64() @ (V.ravel() - self.mean)

    def reconstruct(self, weights: np.ndarray) -> np.ndarray:
        """Body from PCA weights.

        Parameters
        ----------
        weights : (k,) weights (metres); fewer than ``k`` are padded with zeros.

        Returns
        -------
        (n, 3) float64 vertices, metres, template order.
        """
        w = np.asarray(weights, dtype=np.float64).ravel()
        if w.size > self.k:
            raise ValueError(f"at most {self.k} PCA weights, got {w.size}")
        if not np.isfinite(w).all():
            raise ValueError("PCA weights must be finite")
        x = self.mean + w @ self._components64()[: w.size]
        return x.reshape(-1, 3)

    def residual(self, V: np.ndarray) -> np.ndarray:
        """(n, 3) part of body ``V`` the space does not explain: ``V - reconstruct(project(V))``."""
        V = self._check_body(V)
        return V - self.reconstruct(self.project(V))

    def sample(self, rng: np.random.Generator, *, scale: float = 1.0) -> np.ndarray:
        """(k,) random weights from the model's Gaussian (``scale`` multiplies every SD)."""
        return rng.normal(size=self.k) * self.sd * scale


def fit_pca(
    X: np.ndarray,
    *,
    variance: float = 0.98,
    max_components: int | None = None,
) -> PCA:
    """PCA of bodies by SVD of the centred data.

    Parameters
    ----------
    X : (N, 3n) bodies as rows (or (N, n, 3)), metres, in one common frame.
    variance : keep the fewest components whose explained variance reaches this share, (0, 1].
    max_components : optional upper bound on ``k``.

    Returns
    -------
    PCA with ``k <= N - 1`` components.
    """
    X = np.asarray(X, dtype=np.float64)
    X = X.reshape(len(X), -1)
    if len(X) < 2:
        raise ValueError(f"PCA needs at least 2 bodies, got {len(X)}")
    if not 0.0 < variance <= 1.0:
        raise ValueError(f"variance must be in (0, 1], got {variance}")
    mean = X.mean(axis=0)
    Xc = X - mean
    # the N x N Gram matrix is cheaper than an SVD of N x 3n for N << 3n
    G = Xc @ Xc.T
    ev, U = np.linalg.eigh(G)
    order = np.argsort(ev)[::-1]
    ev, U = np.clip(ev[order], 0.0, None), U[:, order]
    total = float(ev.sum())
    keep = ev > 1e-12 * max(ev[0], 1e-300)
    ev, U = ev[keep], U[:, keep]
    share = np.cumsum(ev) / max(total, 1e-300)
    k = int(np.searchsorted(share, variance - 1e-12) + 1)
    k = min(k, len(ev))
    if max_components is not None:
        k = max(1, min(k, int(max_components)))
    comps = (U[:, :k].T @ Xc) / np.sqrt(ev[:k])[:, None]
    # re-orthonormalise (rounding) and fix signs: the largest |entry| of each row positive
    Q, _ = np.linalg.qr(comps.T)
    comps = Q.T * np.sign(np.sum(Q.T * comps, axis=1))[:, None]
    s = np.sign(comps[np.arange(k), np.abs(comps).argmax(axis=1)])
    comps *= s[:, None]
    n = len(X)
    return PCA(
        mean=mean,
        components=comps.astype(np.float32),
        variances=ev[:k] / (n - 1),
        total_variance=total / (n - 1),
    )


# ----------------------------------------------------------------------------- alignment


def rigid_align(V: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation taking body ``V`` onto ``ref`` in the least-squares sense.

    Parameters
    ----------
    V, ref : (n, 3) vertices in template order, metres.

    Returns
    -------
    R : (3, 3) rotation, t : (3,) translation (metres): ``V @ R.T + t`` ≈ ``ref``.
    """
    sim = umeyama(np.asarray(V, dtype=np.float64), np.asarray(ref, dtype=np.float64), scale=1.0)
    return sim.R, sim.t


def to_model_frame(
    V: np.ndarray, ref: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Put a body into the shape models' frame: rotated onto ``ref`` (default the template),
    standing on the floor (lowest vertex at y = 0), horizontally centred as ``ref``.

    Parameters
    ----------
    V : (n, 3) vertices, metres, any rigid placement (e.g. a fit in its scan's frame).
    ref : (n, 3) reference body; default the template.

    Returns
    -------
    V_model : (n, 3) the body in the model frame.
    R, t : (3, 3), (3,) with ``V_model = V @ R.T + t`` (invert with :func:`from_model_frame`).
    """
    ref = load_template().V if ref is None else np.asarray(ref, dtype=np.float64)
    R, t = rigid_align(V, ref)
    W = np.asarray(V, dtype=np.float64) @ R.T
    c = ref.mean(0)
    t = np.array([c[0] - W[:, 0].mean(), -W[:, 1].min(), c[2] - W[:, 2].mean()])
    return W + t, R, t


def from_model_frame(V_model: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Inverse of :func:`to_model_frame`: ``(V_model - t) @ R``."""
    return (np.asarray(V_model, dtype=np.float64) - t) @ R
