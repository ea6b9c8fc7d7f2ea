"""Anthropometric calibration of a shape space's mean body.

The training bodies of a space are rebuilt from anthropometric survey rows (MakeHuman solve,
learned correction, simulated scan, registration). Every stage leaves small *systematic* errors
against the real subjects -- the regularised correction is shrunk toward MakeHuman's average
anatomy, the registration rounds concave regions -- and a linear shape space passes them on to
every body it makes. This step removes the population-level part: one displacement field per
space, ``delta = U @ c`` in a smooth deformation basis ``U``, chosen so that bodies synthesised
from the training subjects' features measure, on average, like those subjects::

    c = argmin  || mean_i (y_i - m(S(f_i) + delta)) / sigma ||^2 + mu || c / sd ||^2

(Gauss-Newton with the Jacobian of the measurements at the mean body; ``y_i`` the subject's
measured values, ``m`` :func:`core.measure.measure`, ``S(f_i)`` the body synthesised from the
subject's features, ``sigma`` the residual SD of each measurement after a linear regression on
stature and weight, ``sd`` the basis coefficients' prior SD). Adding the same field to every
training body only moves the mean: components, variances and the feature map are unchanged.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from core.shapespace.model import ShapeModel, body_volume


@dataclass
class Calibration:
    """Result of :func:`calibrate_mean`.

    Attributes
    ----------
    delta : (13380, 3) displacement added to the space's mean body, metres (model frame).
    coefficients : (q,) basis coefficients of ``delta``.
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
        # no exact-height rescaling: the mean shift must keep stature by itself
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
    *,
    mu: float = 0.1,
    iterations: int = 3,
    measure_fn: Callable[[np.ndarray], dict[str, float]] | None = None,
    log: Callable[[str], None] | None = None,
) -> Calibration:
    """Fit and apply (in place) a mean-body displacement of space ``sex``.

    Parameters
    ----------
    model : the model; ``model.space(sex).pca.mean`` is updated in place.
    sex : the space (``"female"`` / ``"male"``).
    features : per training row, the features the model synthesises from (e.g.
        ``{"height_m", "weight_kg"}``).
    targets : (rows, len(names)) the rows' measured values (metres; kg for ``weightkg``).
    names : measurement names (:data:`core.measure.MEASUREMENTS` keys).
    sigma : (len(names),) scale of each measurement's error (metres / kg), > 0.
    basis : (3 * 13380, q) displacement basis per unit coefficient, metres (model frame).
    prior_sd : (q,) prior SD of each coefficient.
    mu : weight of the prior (larger keeps the mean closer to the training bodies').
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
    n3 = space.pca.mean.size
    if targets.shape != (len(features), len(names)):
        raise ValueError(f"targets must be ({len(features)}, {len(names)}), got {targets.shape}")
    if sigma.shape != (len(names),) or not np.all(sigma > 0):
        raise ValueError("sigma must hold one positive scale per measurement")
    if U.ndim != 2 or U.shape[0] != n3 or sd.shape != (U.shape[1],) or not np.all(sd > 0):
        raise ValueError(f"basis must be ({n3}, q) with q positive prior SDs")
    if not (np.isfinite(targets).all() and len(features) > 0):
        raise ValueError("targets must be finite and rows non-empty")
    mfn = measure_fn or (lambda V: measure(V, names=[n for n in names if n != "weightkg"]))

    mean0 = space.pca.mean.copy()
    c = np.zeros(U.shape[1])
    M = _measure_rows(model, sex, features, names, mfn)
    bias0, rmse0 = (M - targets).mean(0), np.sqrt(((M - targets) ** 2).mean(0))
    fbar = {k: float(np.mean([f[k] for f in features])) for k in features[0]}

    def jacobian(c_: np.ndarray) -> np.ndarray:
        """Measurements' Jacobian w.r.t. the coefficients at the body of the mean features."""
        base = mean0 + U @ c_
        space.pca.mean = base
        m0 = _measure_rows(model, sex, [fbar], names, mfn)[0]
        J_ = np.empty((len(names), U.shape[1]))
        eps = 0.5 * float(np.median(sd))
        for j in range(U.shape[1]):
            space.pca.mean = base + eps * U[:, j]
            J_[:, j] = (_measure_rows(model, sex, [fbar], names, mfn)[0] - m0) / eps
        space.pca.mean = base
        return J_ / sigma[:, None]

    P = np.diag(mu / sd**2)

    def objective(M_: np.ndarray, c_: np.ndarray) -> float:
        r_ = ((M_ - targets) / sigma).mean(0)
        return float(r_ @ r_ + c_ @ P @ c_)

    f_now = objective(M, c)
    for it in range(iterations):
        r = ((targets - M) / sigma).mean(0)
        Js = jacobian(c)
        dc = np.linalg.solve(Js.T @ Js + P, Js.T @ r - P @ c)
        for _ in range(4):  # backtrack when the linearisation overshoots
            space.pca.mean = mean0 + U @ (c + dc)
            M_try = _measure_rows(model, sex, features, names, mfn)
            f_try = objective(M_try, c + dc)
            if f_try < f_now:
                break
            dc *= 0.5
        else:
            space.pca.mean = mean0 + U @ c
            break
        c, M, f_now = c + dc, M_try, f_try
        if log:
            b = np.abs((M - targets).mean(0) / sigma)
            log(f"  {sex} calibration step {it + 1}: objective {f_now:.4f}, "
                f"mean |bias|/sigma {b.mean():.3f} max {b.max():.3f}")  # fmt: skip
    return Calibration(
        delta=(U @ c).reshape(-1, 3),
        coefficients=c,
        names=list(names),
        bias_before=bias0,
        bias_after=(M - targets).mean(0),
        rmse_before=rmse0,
        rmse_after=np.sqrt(((M - targets) ** 2).mean(0)),
        n_rows=len(features),
    )
