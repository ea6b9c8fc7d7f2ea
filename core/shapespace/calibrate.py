"""Anthropometric calibration of a shape space: its mean body and its feature map's slopes.

The training bodies of a space are rebuilt from anthropometric survey rows (MakeHuman solve,
learned correction, simulated scan, registration). Every stage leaves small *systematic* errors
against the real subjects -- the regularised correction is shrunk toward MakeHuman's average
anatomy, the registration rounds concave regions, a template landmark sits a centimetre off the
survey's palpated one -- and a linear shape space passes them on to every body it makes. This
step removes the population-level part, fitted on survey rows:

* the **mean**: one displacement field ``delta = U @ c`` in a smooth deformation basis ``U``
  (e.g. MakeHuman target directions plus :func:`laplacian_basis`) added to the space's mean;
* the **slopes** (optional): a change ``B`` (k x f) of how the PCA weights follow the encoded
  features named in ``slope_features`` (height, weight^(1/3)), i.e. the feature map becomes that
  of training bodies ``w + B (f - mean f)`` (:meth:`FeatureMap.with_slopes`),

chosen so that bodies synthesised from the rows' features measure like those subjects::

    min  mean_i || (y_i - m(S(f_i))) / sigma ||^2 + mu || c / sd ||^2 + mu || beta / slope_sd ||^2

(Gauss-Newton, Levenberg-Marquardt damped, with the measurements' Jacobians at the body of the
mean features; ``y_i`` the
subject's measured values, ``m`` :func:`core.measure.measure`, ``S(f_i)`` the body synthesised
from the row's features, ``sigma`` the residual SD of each measurement after a linear regression
on stature and weight, ``sd`` the basis coefficients' prior SD, ``beta`` the slopes in SD units:
change of each PCA weight, in its SD, per SD of the feature). Without slopes only the mean moves
(components, variances and the feature map are unchanged) and the objective is the squared mean
bias plus a constant.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from core.shapespace.features import encode
from core.shapespace.model import ShapeModel, body_volume


@dataclass
class Calibration:
    """Result of :func:`calibrate_space` / :func:`calibrate_mean`.

    Attributes
    ----------
    delta : (13380, 3) displacement added to the space's mean body, metres (model frame).
    coefficients : (q,) basis coefficients of ``delta``.
    slopes : (k, f) change ``B`` of the feature map (PCA weights, metres, per unit of each
        encoded feature; zero columns for features not calibrated), or None.
    slope_features : the features whose slopes were calibrated.
    names : the measurements calibrated.
    bias_before, bias_after : (len(names),) mean of measured - subject over the rows, before
        and after (metres; kg for ``weightkg``).
    rmse_before, rmse_after : (len(names),) RMS of measured - subject over the rows.
    n_rows : rows used.
    """

    delta: np.ndarray
    coefficients: np.ndarray
    names: list[str]
    bias_before: np.ndarray
    bias_after: np.ndarray
    rmse_before: np.ndarray
    rmse_after: np.ndarray
    n_rows: int
    slopes: np.ndarray | None = None
    slope_features: tuple[str, ...] = ()


def laplacian_basis(
    F: np.ndarray, mirror: np.ndarray, n_eigen: int = 120, *, cutoff: int = 30, sd0: float = 0.25
) -> tuple[np.ndarray, np.ndarray]:
    """Smooth, left-right symmetric displacement fields of a mesh, coarse to fine.

    The lowest ``n_eigen`` eigenvectors ``phi`` of the mesh's graph Laplacian, each times the
    x, y and z unit vectors, made mirror-symmetric (``x`` fields of antisymmetric ``phi``,
    ``y``/``z`` fields of symmetric ones) and orthonormalised. Their prior SD falls with
    frequency: ``sd0 / (1 + lambda / lambda_cutoff)``.

    Parameters
    ----------
    F : (m, 3) triangles of an n-vertex mesh (connected).
    mirror : (n,) index of each vertex's mirror vertex (x -> -x).
    n_eigen : eigenvectors used (the constant one included).
    cutoff : index of the eigenvalue where the prior SD has halved.
    sd0 : prior SD of the smoothest fields (unit-norm fields: RMS ``sd0 / sqrt(n)`` m/vertex).

    Returns
    -------
    U (3n, q) orthonormal fields (x, y, z interleaved per vertex) and their prior SDs (q,).
    """
    import scipy.sparse as sp
    from scipy.sparse.linalg import eigsh

    F = np.asarray(F)
    n = len(mirror)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    A = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n)).tocsr()
    A = ((A + A.T) > 0).astype(np.float64)
    L = sp.diags(np.asarray(A.sum(1)).ravel()) - A
    lam, phi = eigsh(L.tocsc(), k=n_eigen, sigma=-1e-3, which="LM")
    order = np.argsort(lam)
    lam, phi = np.maximum(lam[order], 0.0), phi[:, order]
    cols, sds = [], []
    lam_c = max(float(lam[min(cutoff, n_eigen - 1)]), 1e-12)
    for j in range(n_eigen):
        p = phi[:, j]
        for axis in range(3):
            f = np.zeros((n, 3))
            f[:, axis] = p
            g = f[mirror] * np.array([-1.0, 1.0, 1.0])
            f = 0.5 * (f + g)  # the mirror-symmetric part
            nf = float(np.linalg.norm(f))
            if nf > 1e-6:
                cols.append(f.ravel() / nf)
                sds.append(sd0 / (1.0 + lam[j] / lam_c))
    Q, R = np.linalg.qr(np.stack(cols, 1))
    keep = np.abs(np.diag(R)) > 1e-3  # drop fields already spanned (degenerate eigenpairs)
    return Q[:, keep], np.array(sds)[keep]


def symmetric_part(X: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    """Left-right symmetric part of a body or displacement field.

    Parameters
    ----------
    X : (n, 3) (or (3n,)) vertices or displacements in template order, x = left-right.
    mirror : (n,) index of each vertex's mirror vertex.

    Returns
    -------
    ``(X + mirror(X)) / 2`` in the shape of ``X``, where
    ``mirror(X)[i] = X[mirror[i]] * (-1, 1, 1)``.
    """
    X = np.asarray(X, dtype=np.float64)
    Y = X.reshape(-1, 3)
    return (0.5 * (Y + Y[mirror] * np.array([-1.0, 1.0, 1.0]))).reshape(X.shape)


def _measure_rows(
    model: ShapeModel,
    sex: str,
    features: Sequence[dict[str, float]],
    names: list[str],
    measure_fn: Callable[[np.ndarray], dict[str, float]],
) -> np.ndarray:
    """(rows, len(names)) measurements of the bodies synthesised from each feature dict."""
    out = np.empty((len(features), len(names)))
    density = model.space(sex).density
    for i, f in enumerate(features):
        # no exact-height rescaling: the calibration must keep stature by itself
        V = model.synthesize(sex, f, exact_height=False)
        m = measure_fn(V)
        for j, n in enumerate(names):
            out[i, j] = body_volume(V) * density if n == "weightkg" else m[n]
    return out


def calibrate_mean(
    model: ShapeModel,
    sex: str,
    features: Sequence[dict[str, float]],
    targets: np.ndarray,
    names: list[str],
    sigma: np.ndarray,
    basis: np.ndarray,
    prior_sd: np.ndarray,
    **kwargs,
) -> Calibration:
    """:func:`calibrate_space` of the mean body only (no slopes)."""
    return calibrate_space(
        model, sex, features, targets, names, sigma, basis, prior_sd, slope_features=(), **kwargs
    )


def calibrate_space(
    model: ShapeModel,
    sex: str,
    features: Sequence[dict[str, float]],
    targets: np.ndarray,
    names: list[str],
    sigma: np.ndarray,
    basis: np.ndarray,
    prior_sd: np.ndarray,
    *,
    slope_features: Sequence[str] = ("height_m", "weight_kg"),
    slope_sd: float = 0.3,
    mu: float = 0.1,
    iterations: int = 3,
    measure_fn: Callable[[np.ndarray], dict[str, float]] | None = None,
    log: Callable[[str], None] | None = None,
) -> Calibration:
    """Fit and apply (in place) a mean-body displacement and feature-map slopes of ``sex``.

    Parameters
    ----------
    model : the model; ``model.space(sex)``'s PCA mean and feature map are updated in place.
    sex : the space (``"female"`` / ``"male"``).
    features : per training row, the features the model synthesises from (e.g.
        ``{"height_m", "weight_kg"}``); every row must give each of ``slope_features``.
    targets : (rows, len(names)) the rows' measured values (metres; kg for ``weightkg``).
    names : measurement names (:data:`core.measure.MEASUREMENTS` keys).
    sigma : (len(names),) scale of each measurement's error (metres / kg), > 0.
    basis : (3 * 13380, q) displacement basis per unit coefficient, metres (model frame).
    prior_sd : (q,) prior SD of each coefficient.
    slope_features : feature-map features whose slopes are calibrated (none: mean only).
    slope_sd : prior SD of a slope in SD units (PCA weight SDs per feature SD).
    mu : weight of the priors (larger keeps the space closer to the training bodies').
    iterations : Gauss-Newton steps (each re-measures every row).
    measure_fn : ``V -> {name: value}``; default :func:`core.measure.measure` over ``names``.

    Returns
    -------
    :class:`Calibration`.
    """
    from core.measure import measure

    targets = np.asarray(targets, dtype=np.float64)
    sigma = np.asarray(sigma, dtype=np.float64)
    U = np.asarray(basis, dtype=np.float64)
    sd = np.asarray(prior_sd, dtype=np.float64)
    space = model.space(sex)
    fmap0 = space.features
    n3 = space.pca.mean.size
    if targets.shape != (len(features), len(names)):
        raise ValueError(f"targets must be ({len(features)}, {len(names)}), got {targets.shape}")
    if sigma.shape != (len(names),) or not np.all(sigma > 0):
        raise ValueError("sigma must hold one positive scale per measurement")
    if U.ndim != 2 or U.shape[0] != n3 or sd.shape != (U.shape[1],) or not np.all(sd > 0):
        raise ValueError(f"basis must be ({n3}, q) with q positive prior SDs")
    if not (np.isfinite(targets).all() and len(features) > 0):
        raise ValueError("targets must be finite and rows non-empty")
    slope_features = tuple(slope_features)
    for n in slope_features:
        if n not in fmap0.names:
            raise ValueError(f"slope feature {n!r} is not a feature of this space")
        if any(n not in f for f in features):
            raise ValueError(f"every row must give slope feature {n!r}")
    mfn = measure_fn or (lambda V: measure(V, names=[n for n in names if n != "weightkg"]))

    k, nf = fmap0.k, fmap0.f
    q, ns = U.shape[1], len(slope_features)
    cols = [fmap0.names.index(n) for n in slope_features]
    # encoded deviations of the slope features per row, and their SDs (for the prior's units)
    G = np.array([[float(encode(n, f[n])) for n in slope_features] for f in features])
    G = G - fmap0.mean[cols] if ns else np.zeros((len(features), 0))
    g_sd = np.sqrt(np.diag(fmap0.cov)[cols]) if ns else np.zeros(0)
    w_sd = np.sqrt(np.diag(fmap0.cov)[nf:])
    mean0 = space.pca.mean.copy()

    def apply(theta: np.ndarray) -> None:
        c_, beta = theta[:q], theta[q:].reshape(k, ns)
        space.pca.mean = mean0 + U @ c_
        if ns:
            B = np.zeros((k, nf))
            B[:, cols] = beta * w_sd[:, None] / g_sd[None, :]
            space.features = fmap0.with_slopes(B)

    def measure_all() -> np.ndarray:
        return _measure_rows(model, sex, features, names, mfn)

    theta = np.zeros(q + k * ns)
    prior = np.concatenate([1.0 / sd**2, np.full(k * ns, 1.0 / slope_sd**2)]) * mu
    M = measure_all()
    bias0, rmse0 = (M - targets).mean(0), np.sqrt(((M - targets) ** 2).mean(0))
    fbar = {n: float(np.mean([f[n] for f in features])) for n in features[0]}

    def jacobians(theta_: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Measurements' Jacobians (sigma units) at the body of the mean features: w.r.t.
        the basis coefficients and w.r.t. the PCA weights (metres)."""
        apply(theta_)
        base = space.pca.mean.copy()
        m0 = _measure_rows(model, sex, [fbar], names, mfn)[0]
        JU = np.empty((len(names), q))
        eps = 0.5 * float(np.median(sd))
        for j in range(q):
            space.pca.mean = base + eps * U[:, j]
            JU[:, j] = (_measure_rows(model, sex, [fbar], names, mfn)[0] - m0) / eps
        JW = np.empty((len(names), k if ns else 0))
        for j in range(JW.shape[1]):
            e = 0.25 * float(space.pca.sd[j])
            space.pca.mean = base + e * space.pca.components[j]
            JW[:, j] = (_measure_rows(model, sex, [fbar], names, mfn)[0] - m0) / e
        space.pca.mean = base
        return JU / sigma[:, None], JW / sigma[:, None]

    def objective(M_: np.ndarray, theta_: np.ndarray) -> float:
        r_ = (M_ - targets) / sigma
        return float((r_**2).sum(1).mean() + theta_ @ (prior * theta_))

    f_now = objective(M, theta)
    for it in range(iterations):
        JU, JW = jacobians(theta)
        R = (targets - M) / sigma  # (rows, measurements)
        # row i: r_i ~ JU dc + sum_{j,m} JW[:, j] * (w_sd_j / g_sd_m) G[i, m] dbeta[j, m]
        H = np.zeros((q + k * ns, q + k * ns))
        b = np.zeros(q + k * ns)
        H[:q, :q] = JU.T @ JU
        b[:q] = JU.T @ R.mean(0)
        if ns:
            Gs = G / g_sd[None, :]  # rows' feature deviations in SD units
            JWs = JW * w_sd[None, :]  # per SD of each PCA weight
            # design of the slopes for row i: kron(JWs, Gs[i]) (measurements, k * ns)
            S2 = Gs.T @ Gs / len(G)  # (ns, ns) second moments
            S1 = Gs.mean(0)  # (ns,)
            H[q:, q:] = np.kron(JWs.T @ JWs, S2)
            H[:q, q:] = np.kron(JU.T @ JWs, S1[None, :])
            H[q:, :q] = H[:q, q:].T
            b[q:] = np.einsum("ir,rj,im->jm", R, JWs, Gs).reshape(-1) / len(G)
        A = H + np.diag(prior)
        for lam in (0.0, 0.1, 1.0, 10.0):  # Levenberg-Marquardt: damp when a step overshoots
            dtheta = np.linalg.solve(A + lam * np.diag(np.diag(A)), b - prior * theta)
            apply(theta + dtheta)
            M_try = measure_all()
            f_try = objective(M_try, theta + dtheta)
            if f_try < f_now:
                break
        else:
            apply(theta)
            break
        theta, M, f_now = theta + dtheta, M_try, f_try
        if log:
            bb = np.abs((M - targets).mean(0) / sigma)
            log(f"  {sex} calibration step {it + 1}: objective {f_now:.4f}, "
                f"mean |bias|/sigma {bb.mean():.3f} max {bb.max():.3f}")  # fmt: skip
    apply(theta)
    slopes = None
    if ns:
        slopes = np.zeros((k, nf))
        slopes[:, cols] = theta[q:].reshape(k, ns) * w_sd[:, None] / g_sd[None, :]
    return Calibration(
        delta=(U @ theta[:q]).reshape(-1, 3),
        coefficients=theta[:q],
        names=list(names),
        bias_before=bias0,
        bias_after=(M - targets).mean(0),
        rmse_before=rmse0,
        rmse_after=np.sqrt(((M - targets) ** 2).mean(0)),
        n_rows=len(features),
        slopes=slopes,
        slope_features=slope_features,
    )
