"""The feature map (Allen, Curless, Popović 2003, §5): features <-> PCA weights.

Features are what a person can tell or a tape can measure: ``height_m``, ``weight_kg``, ``age``
and any ANSUR II measurement name (metres). Internally each feature is *encoded* -- weight as
its cube root (``weight_kg ** (1/3)``, linear in size like the other lengths), all others as
they are -- and the encoded features ``f`` and the PCA weights ``w`` of the training bodies are
modelled jointly as a Gaussian. Its regression ``w = [f, 1] @ M`` is the paper's least-squares
map; for a *partial* feature vector the most likely body given the known features is the
conditional mean of the same Gaussian (which equals the map when every feature is given).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.shapespace.errors import OutOfRangeError

#: Encoded as a cube root (the paper's weight^(1/3)).
CUBE_ROOT = frozenset({"weight_kg"})
#: Units of the user-facing features (everything else: metres).
UNITS = {"height_m": "m", "weight_kg": "kg", "age": "years", "male": "0/1"}
#: The range is the training bodies' [min, max] widened to mean ± this many SDs when wider.
RANGE_SD = 3.5
#: A feature combination farther than this Mahalanobis distance from the training bodies
#: (given the features supplied) is out of range.
MAX_MAHALANOBIS = 5.0


def encode(name: str, value: float | np.ndarray) -> np.ndarray:
    """Encoded value of feature ``name`` (cube root for weight)."""
    v = np.asarray(value, dtype=np.float64)
    return np.cbrt(v) if name in CUBE_ROOT else v


def decode(name: str, value: float | np.ndarray) -> np.ndarray:
    """Inverse of :func:`encode`."""
    v = np.asarray(value, dtype=np.float64)
    return v**3 if name in CUBE_ROOT else v


@dataclass
class FeatureMap:
    """Linear map between encoded features and PCA weights, with their joint Gaussian.

    Attributes
    ----------
    names : the f feature names (user-facing, e.g. ``("height_m", "weight_kg", "age")``).
    M : (f + 1, k) least-squares map: ``w = [encode(features), 1] @ M``.
    mean : (f + k,) mean of the joint vector ``[encoded features, PCA weights]``.
    cov : (f + k, f + k) its covariance (PCA block diagonal with the PCA variances).
    ranges : name -> (low, high) supported range of each feature, user units.
    residual_sd : (k,) SD of each PCA weight not explained by the features (metres).
    """

    names: tuple[str, ...]
    M: np.ndarray
    mean: np.ndarray
    cov: np.ndarray
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)
    residual_sd: np.ndarray | None = None

    @property
    def f(self) -> int:
        return len(self.names)

    @property
    def k(self) -> int:
        return self.M.shape[1]

    # ------------------------------------------------------------------ checks

    def _encode_dict(
        self, features: dict[str, float], *, check: bool = True
    ) -> tuple[list[int], np.ndarray]:
        idx, vals = [], []
        for name, value in features.items():
            if name not in self.names:
                raise OutOfRangeError(
                    f"unknown feature {name!r}; this model accepts {', '.join(self.names)}",
                    feature=name,
                    accepted=list(self.names),
                )
            v = float(value)
            if not np.isfinite(v):
                raise OutOfRangeError(f"feature {name} must be a finite number, got {value!r}",
                                      feature=name, value=value)  # fmt: skip
            if check:
                self.check_value(name, v)
            idx.append(self.names.index(name))
            vals.append(float(encode(name, v)))
        return idx, np.array(vals)

    def check_value(self, name: str, value: float) -> None:
        """Raise :class:`OutOfRangeError` when ``value`` is outside feature ``name``'s range."""
        lo, hi = self.ranges.get(name, (-np.inf, np.inf))
        if not lo <= value <= hi:
            unit = UNITS.get(name, "m")
            raise OutOfRangeError(
                f"{name}={value:g} {unit} is outside the supported range "
                f"{lo:.3g}–{hi:.3g} {unit} of this model",
                feature=name,
                value=value,
                supported=[lo, hi],
            )

    def mahalanobis(self, features: dict[str, float]) -> float:
        """Mahalanobis distance of (some) encoded features from the training bodies'."""
        idx, f = self._encode_dict(features, check=False)
        if not idx:
            return 0.0
        S = self.cov[np.ix_(idx, idx)]
        d = f - self.mean[idx]
        return float(np.sqrt(d @ np.linalg.solve(S, d)))

    # ------------------------------------------------------------------ map

    def weights(self, features: dict[str, float], *, check: bool = True) -> np.ndarray:
        """Most likely PCA weights given some or all features.

        Parameters
        ----------
        features : name -> value in user units (``height_m`` m, ``weight_kg`` kg, ``age``
            years, measurements m). Missing features are marginalised (conditional Gaussian).
        check : raise :class:`OutOfRangeError` for values outside the supported ranges or an
            implausible combination.

        Returns
        -------
        (k,) PCA weights, metres.
        """
        idx, f = self._encode_dict(features, check=check)
        if not idx:
            return self.mean[self.f :].copy()
        if check and len(idx) > 1:
            d = self.mahalanobis(features)
            if d > MAX_MAHALANOBIS:
                raise OutOfRangeError(
                    "this combination of "
                    + ", ".join(f"{k}={float(v):g}" for k, v in features.items())
                    + f" is unlike any body in the training data (Mahalanobis distance {d:.1f}"
                    f" > {MAX_MAHALANOBIS:g})",
                    mahalanobis=d,
                )
        if len(idx) == self.f:
            order = np.argsort(idx)
            return np.append(f[order], 1.0) @ self.M
        w_idx = np.arange(self.f, self.f + self.k)
        S_gg = self.cov[np.ix_(idx, idx)]
        S_wg = self.cov[np.ix_(w_idx, idx)]
        return self.mean[w_idx] + S_wg @ np.linalg.solve(S_gg, f - self.mean[idx])

    def features(self, weights: np.ndarray) -> dict[str, float]:
        """Most likely features of a body with PCA weights ``weights`` (conditional mean).

        Parameters
        ----------
        weights : (k,) PCA weights, metres.

        Returns
        -------
        name -> value in user units.
        """
        w = np.asarray(weights, dtype=np.float64).ravel()
        if w.size != self.k:
            raise ValueError(f"expected {self.k} PCA weights, got {w.size}")
        fi = np.arange(self.f)
        wi = np.arange(self.f, self.f + self.k)
        S_ww = self.cov[np.ix_(wi, wi)]
        S_fw = self.cov[np.ix_(fi, wi)]
        f = self.mean[fi] + S_fw @ np.linalg.solve(S_ww, w - self.mean[wi])
        return {n: float(decode(n, v)) for n, v in zip(self.names, f, strict=True)}

    def with_slopes(self, B: np.ndarray) -> FeatureMap:
        """The feature map of training bodies whose PCA weights were ``w + B (f - mean f)``.

        A linear change of variables of the joint Gaussian (``cov -> T cov T^T`` with
        ``T = [[I, 0], [B, I]]``): the means, the residuals and the ranges stay; the map's
        slopes gain ``B`` and the conditional means follow.

        Parameters
        ----------
        B : (k, f) PCA weights (metres) per unit of each encoded feature.

        Returns
        -------
        A new FeatureMap (this one is unchanged).
        """
        B = np.asarray(B, dtype=np.float64)
        if B.shape != (self.k, self.f):
            raise ValueError(f"slopes must be ({self.k}, {self.f}), got {B.shape}")
        T = np.eye(self.f + self.k)
        T[self.f :, : self.f] = B
        M = self.M.copy()
        M[: self.f] += B.T
        M[self.f] -= self.mean[: self.f] @ B.T
        return FeatureMap(
            names=self.names, M=M, mean=self.mean.copy(), cov=T @ self.cov @ T.T,
            ranges=dict(self.ranges),
            residual_sd=None if self.residual_sd is None else self.residual_sd.copy(),
        )  # fmt: skip

    def delta_weights(self, names: list[str], delta_encoded: np.ndarray) -> np.ndarray:
        """(k,) change of PCA weights for a change of encoded features (others held fixed):
        ``Δw = Δf @ M[rows of names]`` (the paper's editing step)."""
        rows = [self.names.index(n) for n in names]
        return np.asarray(delta_encoded, dtype=np.float64) @ self.M[rows]


def fit_feature_map(
    names: list[str] | tuple[str, ...],
    F: np.ndarray,
    W: np.ndarray,
    pca_variances: np.ndarray,
    *,
    ridge: float = 1e-9,
) -> FeatureMap:
    """Learn the feature map from training bodies.

    Parameters
    ----------
    names : f feature names.
    F : (N, f) raw features in user units (weight in kg; encoded here).
    W : (N, k) PCA weights of the same bodies, metres.
    pca_variances : (k,) PCA variances (the weights' covariance block is diagonal).
    ridge : relative Tikhonov regularisation of the encoded-feature covariance.

    Returns
    -------
    FeatureMap.
    """
    names = tuple(names)
    F = np.asarray(F, dtype=np.float64)
    W = np.asarray(W, dtype=np.float64)
    N, f = F.shape
    if len(W) != N:
        raise ValueError(f"{N} feature rows but {len(W)} bodies")
    if f + 2 > N:
        raise ValueError(f"need at least {f + 2} bodies for {f} features, got {N}")
    if not np.isfinite(F).all():
        raise ValueError("features must be finite (fill or drop rows with missing values)")
    E = np.stack([encode(n, F[:, j]) for j, n in enumerate(names)], axis=1)
    Z = np.concatenate([E, W], axis=1)
    mean = Z.mean(0)
    C = np.cov(Z, rowvar=False).reshape(f + W.shape[1], f + W.shape[1])
    C[f:, f:] = np.diag(np.diag(C[f:, f:]))  # PCA weights are uncorrelated by construction
    C[:f, :f] += ridge * np.diag(np.diag(C[:f, :f])) + 1e-12 * np.eye(f)
    # least-squares map [E 1] -> W (identical to the conditional mean given all features)
    A = np.concatenate([E, np.ones((N, 1))], axis=1)
    M = np.linalg.lstsq(A, W, rcond=None)[0]
    res = W - A @ M
    ranges = {}
    for j, n in enumerate(names):
        x = F[:, j]
        lo, hi = float(x.min()), float(x.max())
        m, s = float(x.mean()), float(x.std())
        ranges[n] = (min(lo, m - RANGE_SD * s), max(hi, m + RANGE_SD * s))
        if n == "male":  # the sex indicator of a joint space
            ranges[n] = (0.0, 1.0)
        else:  # sizes, weights and ages are positive
            ranges[n] = (max(ranges[n][0], 0.0), ranges[n][1])
    return FeatureMap(
        names=names, M=M, mean=mean, cov=C, ranges=ranges,
        residual_sd=np.sqrt((res**2).sum(0) / max(N - f - 1, 1)),
    )  # fmt: skip
