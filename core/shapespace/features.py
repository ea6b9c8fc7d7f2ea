"""The feature map (Allen, Curless, Popović 2003, §5): features <-> PCA weights.

Features are what a person can tell or a tape can measure: ``height_m``, ``weight_kg``, ``age``
and any ANSUR II measurement name (metres). Internally each feature is *encoded* -- weight as
its cube root (``weight_kg ** (1/3)``, linear in size like the other lengths), all others as
they are -- and the encoded features ``f`` and the PCA weights ``w`` of the training bodies are
modelled jointly as a Gaussian. Its regression ``w = [f, 1] @ M`` is the paper's least-squares
map; for a *partial* feature vector the most likely body given the known features is the
conditional mean of the same Gaussian (which equals the map when every feature is given).

Ranges. Each feature has a **training range** (:attr:`FeatureMap.ranges`: the training bodies'
[min, max] widened to mean ± :data:`RANGE_SD` SD; for ``age`` the adult ages of the training
subjects) and, wider, the **accepted limits** (:meth:`FeatureMap.limits`): what is physically
meaningful for an adult -- stature 1.0–2.5 m, weight 10–500 kg, BMI 10–80 (given or most likely
stature), age 17–90 years, measurements the training range widened by half its width. Values
inside the limits but outside the training range, or a combination farther than
:data:`MAX_MAHALANOBIS` from the training bodies, are *extrapolated*: accepted, with a warning
(:meth:`FeatureMap.range_warnings`). Only values outside the limits (and non-finite ones) raise
:class:`OutOfRangeError`. Why these limits: every ANSUR II subject (stature 1.41–1.99 m, 36–140 kg,
BMI 15–44) and civilian extremes (stature 1.40–2.05 m, BMI 15–55) lie inside; a stature under
1 m or over 2.5 m, or a BMI under 10 or over 80, is not an adult body (the tallest and the most
underweight people on record are at the edge of these). Ages: 17 is the youngest ANSUR II subject
(the model has no children's proportions), 90 the oldest age adult anthropometric surveys tabulate;
the age effect is extrapolated linearly beyond the training subjects' 58 years (with a warning).
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
#: (given the features supplied) is beyond the training range (a warning, not an error).
MAX_MAHALANOBIS = 5.0
#: Accepted limits (user units) of these features, whatever the training data: see the module.
LIMITS = {"height_m": (1.0, 2.5), "weight_kg": (10.0, 500.0), "age": (17.0, 90.0)}
#: Accepted body-mass index (kg/m²) with the given (else the most likely) stature.
BMI_LIMITS = (10.0, 80.0)
#: Measurement features are accepted up to this fraction of their training range's width beyond it.
MEASUREMENT_MARGIN = 0.5
#: Training range of ``age``: the training subjects' ages (ANSUR II: 17–58), not mean ± SD.
AGE_TRAINING = (17.0, 58.0)


def _fmt(name: str, value: float) -> str:
    return f"{value:.3g} {UNITS.get(name, 'm')}"


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

    def training_range(self, name: str) -> tuple[float, float]:
        """(low, high) of feature ``name`` covered by the training bodies (user units)."""
        lo, hi = self.ranges.get(name, (-np.inf, np.inf))
        if name == "age":
            return max(lo, AGE_TRAINING[0]), min(hi, AGE_TRAINING[1])
        return lo, hi

    def limits(self, name: str) -> tuple[float, float]:
        """(low, high) accepted for feature ``name`` (user units): :data:`LIMITS`, else the
        training range widened by :data:`MEASUREMENT_MARGIN` of its width (``male``: 0–1)."""
        if name in LIMITS:
            return LIMITS[name]
        lo, hi = self.ranges.get(name, (-np.inf, np.inf))
        if name == "male":
            return lo, hi
        pad = MEASUREMENT_MARGIN * (hi - lo)
        return max(lo - pad, 0.0), hi + pad

    def check_value(self, name: str, value: float) -> None:
        """Raise :class:`OutOfRangeError` when ``value`` is outside feature ``name``'s accepted
        limits (:meth:`limits`); the message gives them and the training range."""
        lo, hi = self.limits(name)
        if not lo <= value <= hi:
            unit = UNITS.get(name, "m")
            tlo, thi = self.training_range(name)
            raise OutOfRangeError(
                f"{name}={value:g} {unit} is outside the supported range "
                f"{lo:.3g}–{hi:.3g} {unit} of this model (its training range is "
                f"{tlo:.3g}–{thi:.3g} {unit}; values between are extrapolated, with a warning)",
                feature=name,
                value=value,
                supported=[lo, hi],
                training_range=[tlo, thi],
            )

    def check_bmi(self, features: dict[str, float]) -> None:
        """Raise :class:`OutOfRangeError` when the body-mass index of ``weight_kg`` with the
        given ``height_m`` (else the most likely stature for the other features) is outside
        :data:`BMI_LIMITS`."""
        if "weight_kg" not in features or "height_m" not in self.names:
            return
        given = "height_m" in features
        h = float(features["height_m"]) if given else self.conditional(features)["height_m"]
        w = float(features["weight_kg"])
        bmi = w / (h * h)
        lo, hi = BMI_LIMITS
        if not lo <= bmi <= hi:
            at = f"height_m={h:.3g} m" if given else f"the most likely stature {h:.3g} m"
            raise OutOfRangeError(
                f"weight_kg={w:g} kg at {at} is a body-mass index of {bmi:.1f} kg/m², outside "
                f"the supported range {lo:g}–{hi:g} kg/m² (weight {lo * h * h:.1f}–"
                f"{hi * h * h:.1f} kg at that stature)",
                feature="weight_kg", value=w, bmi=bmi, supported=[lo * h * h, hi * h * h],
            )  # fmt: skip

    def range_warnings(self, features: dict[str, float]) -> list[str]:
        """Warnings for values (already within the limits) that the model extrapolates: a
        feature outside its training range, or a combination farther than
        :data:`MAX_MAHALANOBIS` from the training bodies. Empty inside the training range."""
        out = []
        for name, value in features.items():
            if name not in self.names:
                continue
            lo, hi = self.training_range(name)
            v = float(value)
            if not lo <= v <= hi:
                out.append(
                    f"{name}={_fmt(name, v)} is beyond the model's training range "
                    f"{lo:.3g}–{hi:.3g} {UNITS.get(name, 'm')}: the body is extrapolated"
                )
        if len(features) > 1:
            d = self.mahalanobis(features)
            if d > MAX_MAHALANOBIS:
                out.append(
                    "this combination of "
                    + ", ".join(f"{k}={float(v):g}" for k, v in features.items())
                    + " is unlike the model's training bodies (Mahalanobis distance "
                    f"{d:.1f} > {MAX_MAHALANOBIS:g}): the body is extrapolated"
                )
        return out

    def in_training_range(self, features: dict[str, float]) -> bool:
        """Whether :meth:`range_warnings` has nothing to say about ``features``."""
        return not self.range_warnings(features)

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
        check : raise :class:`OutOfRangeError` for values outside the accepted limits
            (:meth:`limits`, :meth:`check_bmi`); values the model extrapolates pass (see
            :meth:`range_warnings`).

        Returns
        -------
        (k,) PCA weights, metres.
        """
        idx, f = self._encode_dict(features, check=check)
        if not idx:
            return self.mean[self.f :].copy()
        if check:
            self.check_bmi(features)
        if len(idx) == self.f:
            order = np.argsort(idx)
            return np.append(f[order], 1.0) @ self.M
        w_idx = np.arange(self.f, self.f + self.k)
        S_gg = self.cov[np.ix_(idx, idx)]
        S_wg = self.cov[np.ix_(w_idx, idx)]
        return self.mean[w_idx] + S_wg @ np.linalg.solve(S_gg, f - self.mean[idx])

    def conditional(self, features: dict[str, float]) -> dict[str, float]:
        """Most likely value of every feature given some of them (conditional mean of the
        encoded features; user units). Unchecked."""
        idx, f = self._encode_dict(features, check=False)
        mu = self.mean[: self.f].copy()
        if idx:
            S = self.cov[: self.f, : self.f]
            mu = mu + S[:, idx] @ np.linalg.solve(S[np.ix_(idx, idx)], f - mu[idx])
            mu[idx] = f
        return {n: float(decode(n, v)) for n, v in zip(self.names, mu, strict=True)}

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
