"""The most likely body from a handful of tape measurements (issue 6; Allen et al. 2003, §5).

Given a sex and any subset of the ANSUR II measurements :func:`core.measure.measure` computes
(names of :data:`core.measure.MEASUREMENTS`; metres, ``weightkg`` in kilograms), find the body
of the shape space that is most likely and has those measurements.

Method
------
1. **Check** the input (:func:`check_measurements`): known names, finite positive numbers.
   Stature and weight take the shape model's accepted limits (stature 1.0–2.5 m, weight
   10–500 kg, BMI 10–80: :mod:`core.shapespace.features`), the same as synthesis, so every
   ANSUR II subject and civilian extremes (1.40–2.05 m, BMI 15–55) pass, and values beyond the
   model's training range get a warning in the report. Every other value must lie inside a
   plausible range for the sex (the bundled ANSUR II held-in rows' [min, max] widened to mean ±
   :data:`RANGE_SD` SD; when stature and weight are both given, instead of that, only the joint
   check below, which then follows them) and the set must be jointly plausible: the Mahalanobis
   distance of the other values from those rows, *given* stature and weight when they are
   given (conditional Gaussian), outside the chi-square tail of probability :data:`TAIL` is
   refused. Both allow a :data:`SLACK` for the difference between ANSUR's tape and
   ``core.measure``'s definitions, so the measurements of any likely model body pass: the
   checks catch wrong units, typos and impossible bodies, not unusual ones.
2. **Conditional Gaussian**: the measurements the model's feature map knows (``stature`` ->
   ``height_m``, ``weightkg`` -> ``weight_kg`` and the map's own measurements, e.g. chest, waist
   and buttock circumferences in the default model) give the most likely PCA weights as in
   :meth:`core.shapespace.ShapeModel.synthesize` (the map's range checks apply).
3. **Refinement** of those PCA weights ``w`` by Levenberg–Marquardt (damped Gauss–Newton) on

   ``E(w) = Σ_i ((m_i(w) + b_i - t_i) / σ_i)² + Σ_j (w_j / sd_j)²``

   where ``m_i(w)`` is measurement *i* of the reconstructed body (``core.measure.measure``;
   ``weightkg`` = volume × the model's calibrated density), ``b_i`` the model's
   :func:`calibration` offset (how much an ANSUR-style tape reads more than ``core.measure`` on
   the model's bodies; 0 with ``calibrate=False``), ``t_i`` the given value, ``σ_i`` its
   tolerance (:data:`TOLERANCE`, :data:`TOLERANCE_BY_NAME`) and the second sum the paper's
   Gaussian prior ``E_p`` on the weights. Beyond the bulk of the training range the bodies
   are made left-right symmetric as in synthesis (:meth:`ShapeModel.correction`: without it
   one foot of a BMI 55 body was up to 17 mm off the floor). The Jacobian is taken by forward
   differences (steps of :data:`FD_STEP_SD` SD along each component) and recomputed after each
   accepted step. So any measurement ``core.measure`` computes can be used, not only the
   feature map's; the report gives each given one's residual and the body's other
   measurements.

Measured (``python -m bench.measurements``): see ``bench/README.md``.
"""

from __future__ import annotations

import difflib
import math
import time
import weakref
from dataclasses import asdict, dataclass, field
from functools import cache
from typing import Any

import numpy as np

from core.errors import MeasurementError
from core.measure import MEASUREMENTS, measure
from core.shapespace import OutOfRangeError, ShapeModel, default_model
from core.shapespace.features import BMI_LIMITS, LIMITS
from core.shapespace.model import MAX_SD
from core.template import load_template

SEXES = ("female", "male")
#: ANSUR name -> feature-map name, where they differ.
FEATURE_NAMES = {"stature": "height_m", "weightkg": "weight_kg"}
#: Tolerance σ by measurement kind (metres; kg for mass): a miss of σ costs as much as one SD
#: of one PCA weight. It covers the tape's own error and what the shape space cannot represent.
#: Chosen on 30 held-in ANSUR II subjects per sex with σ × 0.5, 1 and 2 of these: × 0.5 matches
#: the given circumferences closer (RMS 8–12 mm instead of 14–19) but predicts the measurements
#: not given worse (median RMSE over the regression's 1.03–1.23 instead of 1.02–1.12), × 2
#: matches worse without predicting better.
TOLERANCE = {
    "height": 0.010,
    "length": 0.010,
    "breadth": 0.010,
    "depth": 0.010,
    "circumference": 0.016,
    "mass": 1.0,
}
#: Tolerances of single measurements, overriding their kind's: stature (stadiometer) and weight
#: (scale) are known more precisely than tape values, and the space reaches them easily. On the
#: same held-in subjects this brings their residuals from ~2 mm / 0.1-0.7 kg to < 1 mm / 0.1 kg
#: without changing how well the others are predicted (median ratios within ± 0.01).
TOLERANCE_BY_NAME: dict[str, float] = {"stature": 0.003, "weightkg": 0.3}
#: How far a value may lie from the ANSUR II rows beyond their own spread, by kind: the
#: definitions ``core.measure`` implements on model bodies differ from the ANSUR tape by up to
#: a few centimetres (``bench.shapespace``'s bias column), and such values must pass.
SLACK = {
    "height": 0.02,
    "length": 0.02,
    "breadth": 0.02,
    "depth": 0.02,
    "circumference": 0.03,
    "mass": 2.0,
}
#: A given value outside the ANSUR rows' [min, max] widened to mean ± this many SDs (of the
#: rows' spread and :data:`SLACK` combined) is refused.
RANGE_SD = 6.0
#: A set of values whose Mahalanobis distance from the ANSUR rows lies in the chi-square tail of
#: this probability is refused as implausible.
TAIL = 1e-6
#: Forward-difference step along each PCA component, in SDs of that component.
FD_STEP_SD = 0.1
#: A matched measurement further than this many tolerances from its target is warned about.
WARN_TOLERANCES = 3.0
_ALIASES = {
    "height_m": "stature",
    "height": "stature",
    "weight_kg": "weightkg",
    "weight": "weightkg",
}


@dataclass
class MeasurementsReport:
    """What :func:`body_from_measurements` did (JSON-ready with :meth:`to_dict`).

    Attributes
    ----------
    sex : the space used.
    given : name -> the given value (metres; ``weightkg`` kg).
    matched : name -> ``{"given", "measured", "residual", "tolerance", "unit"}``: each given
        measurement of the resulting body (``residual`` = measured - given).
    feature_map : the given measurements that went through the conditional Gaussian.
    refined : whether the Gauss–Newton refinement ran.
    iterations : accepted refinement steps.
    energy_start, energy : ``E(w)`` (see the module) at the conditional-Gaussian start and at
        the end; ``data_energy`` / ``prior_energy`` its two sums at the end.
    pca_weights : (k,) PCA weights of the body, metres.
    prior_sd : Mahalanobis norm of the weights (√ prior energy; about √k for a typical body).
    measurements : every ``core.measure`` measurement of the body (the given ones and the most
        likely values of the others).
    seconds : wall time.
    """

    sex: str
    given: dict[str, float]
    calibrated: bool = True
    matched: dict[str, dict[str, Any]] = field(default_factory=dict)
    feature_map: list[str] = field(default_factory=list)
    refined: bool = False
    iterations: int = 0
    energy_start: float = float("nan")
    energy: float = float("nan")
    data_energy: float = float("nan")
    prior_energy: float = float("nan")
    pca_weights: list[float] = field(default_factory=list)
    prior_sd: float = float("nan")
    measurements: dict[str, float] = field(default_factory=dict)
    offsets: dict[str, float] = field(default_factory=dict)
    predicted: dict[str, float] = field(default_factory=dict)
    seconds: float = 0.0
    mode: str = "measurements"
    units: str = "m"
    up: str = "+y"
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """Plain dictionary (NaN stays NaN; ``core.serialize.json_ready`` makes it JSON)."""
        return asdict(self)


@dataclass
class MeasurementsResult:
    """The body: ``vertices`` (13380, 3) metres, +Y up, floor y = 0, template order; ``faces``
    the template triangles; ``pca`` (k,) its weights; ``report`` a :class:`MeasurementsReport`."""

    vertices: np.ndarray
    faces: np.ndarray
    pca: np.ndarray
    report: MeasurementsReport


# ----------------------------------------------------------------------------- checks


@cache
def _ansur_stats(sex: str) -> tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray]:
    """Names, mean, covariance (+ :data:`SLACK`² on the diagonal) and [min, max] of the
    measurements on the ANSUR II held-in rows of ``sex``."""
    from core.shapespace.ansur import split

    rows = split(sex, "train")
    names = tuple(n for n in MEASUREMENTS if n in rows)
    X = np.stack([rows[n] for n in names], axis=1).astype(np.float64)
    slack = np.array([SLACK[MEASUREMENTS[n].kind] for n in names])
    C = np.cov(X, rowvar=False) + np.diag(slack**2)
    return names, X.mean(0), C, np.stack([X.min(0), X.max(0)], 1)


def plausible_range(sex: str, name: str) -> tuple[float, float]:
    """[low, high] accepted for measurement ``name`` of ``sex`` (metres; ``weightkg`` kg):
    the shape model's accepted limits for ``stature`` and ``weightkg``, else ANSUR II ±
    :data:`RANGE_SD` SD."""
    if name in FEATURE_NAMES:
        return LIMITS[FEATURE_NAMES[name]]
    names, mu, C, mm = _ansur_stats(sex)
    if name not in names:
        return (0.0, math.inf)
    i = names.index(name)
    sd = float(np.sqrt(C[i, i]))
    lo = max(0.0, min(float(mm[i, 0]), float(mu[i]) - RANGE_SD * sd))
    return lo, max(float(mm[i, 1]), float(mu[i]) + RANGE_SD * sd)


def _unit(name: str) -> str:
    return MEASUREMENTS[name].unit


def _fmt(name: str, v: float) -> str:
    return f"{v:.1f} kg" if _unit(name) == "kg" else f"{v:.3f} m"


def check_measurements(
    sex: str, measurements: dict[str, Any], *, model: ShapeModel | None = None
) -> dict[str, float]:
    """Validate tape measurements (fast: no body is made); returns them as ``{name: float}``.

    Parameters
    ----------
    sex : ``"female"`` or ``"male"``.
    measurements : ANSUR II name (keys of :data:`core.measure.MEASUREMENTS`) -> value in
        metres (``weightkg``: kilograms). At least one.
    model : also apply this shape model's feature-map checks (ranges of its features and
        their combination) to the measurements it knows.

    Raises
    ------
    MeasurementError (a ``ValueError``)
        Unknown sex or names (the message lists the valid names), values that are not finite
        positive numbers, lengths that look like millimetres or centimetres.
    OutOfRangeError (a ``ValueError``)
        A value outside the plausible range for the sex, or an implausible combination.
    """
    if sex not in SEXES:
        raise MeasurementError(f"sex must be 'female' or 'male', got {sex!r}", field="sex")
    if not isinstance(measurements, dict) or not measurements:
        raise MeasurementError(
            "give at least one measurement: {ANSUR name: value}, lengths in metres, weightkg in "
            f"kg; valid names: {', '.join(MEASUREMENTS)}",
            valid=list(MEASUREMENTS),
        )
    unknown = [n for n in measurements if n not in MEASUREMENTS]
    if unknown:
        hints = []
        for n in unknown:
            close = [_ALIASES[n]] if n in _ALIASES else difflib.get_close_matches(
                str(n).lower(), list(MEASUREMENTS), n=1
            )  # fmt: skip
            hints.append(f"{n!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
        raise MeasurementError(
            f"unknown measurement name(s): {', '.join(hints)}; valid names (ANSUR II): "
            f"{', '.join(MEASUREMENTS)}",
            unknown=[str(n) for n in unknown],
            valid=list(MEASUREMENTS),
        )
    out: dict[str, float] = {}
    for n, v in measurements.items():
        if isinstance(v, bool) or not isinstance(v, int | float | np.integer | np.floating):
            raise MeasurementError(f"{n} must be a number, got {v!r}", field=n)
        x = float(v)
        if not math.isfinite(x) or x <= 0.0:
            raise MeasurementError(f"{n} must be a finite positive number, got {v!r}", field=n)
        lo, hi = plausible_range(sex, n)
        if _unit(n) == "m":
            for unit, f in (("millimetres", 1000.0), ("centimetres", 100.0)):
                if x > hi and lo <= x / f <= hi:
                    raise MeasurementError(
                        f"{n}={x:g} looks like {unit}: lengths are in metres "
                        f"({x / f:g} m?)",
                        field=n, value=x,
                    )  # fmt: skip
        joint = n not in FEATURE_NAMES and all(k in measurements for k in FEATURE_NAMES)
        if not lo <= x <= hi and not joint:
            why = (
                "the shape model's accepted limits" if n in FEATURE_NAMES
                else f"ANSUR II ± {RANGE_SD:g} SD"
            )  # fmt: skip
            raise OutOfRangeError(
                f"{n}={_fmt(n, x)} is outside the plausible range {_fmt(n, lo)}–{_fmt(n, hi)} "
                f"for {sex} bodies ({why})",
                feature=n, value=x, supported=[lo, hi],
            )  # fmt: skip
        out[n] = x
    _check_combination(sex, out)
    if model is not None:
        model.space(sex).features.weights(_feature_values(model, sex, out)[0])
    return out


def _feature_values(
    model: ShapeModel, sex: str, values: dict[str, float]
) -> tuple[dict[str, float], list[str]]:
    """The given values the feature map of ``sex`` knows, by feature name; their ANSUR names."""
    fm = model.space(sex).features
    feats, used = {}, []
    for n, v in values.items():
        f = FEATURE_NAMES.get(n, n)
        if f in fm.names:
            feats[f] = v
            used.append(n)
    return feats, used


def _check_combination(sex: str, values: dict[str, float]) -> None:
    """BMI of stature and weight within :data:`BMI_LIMITS`; the other values jointly
    plausible given them (see the module)."""
    from scipy.stats import chi2

    if "stature" in values and "weightkg" in values:
        h, w = values["stature"], values["weightkg"]
        lo, hi = BMI_LIMITS
        if not lo <= w / h**2 <= hi:
            raise OutOfRangeError(
                f"weightkg={w:g} kg at stature={h:g} m is a body-mass index of {w / h**2:.1f} "
                f"kg/m², outside the supported range {lo:g}–{hi:g} kg/m² (weight {lo * h * h:.1f}–"
                f"{hi * h * h:.1f} kg at that stature)",
                feature="weightkg", value=w, supported=[lo * h * h, hi * h * h],
            )  # fmt: skip
    known = [n for n in FEATURE_NAMES if n in values]
    rest = [n for n in values if n not in FEATURE_NAMES]
    if not rest or len(values) < 2:
        return
    names, mu, C, _ = _ansur_stats(sex)
    ir, ik = [names.index(n) for n in rest], [names.index(n) for n in known]
    x = np.array([values[n] for n in rest]) - mu[ir]
    S = C[np.ix_(ir, ir)]
    if ik:  # conditional Gaussian of the others given stature and/or weight
        G = C[np.ix_(ir, ik)] @ np.linalg.inv(C[np.ix_(ik, ik)])
        x = x - G @ (np.array([values[n] for n in known]) - mu[ik])
        S = S - G @ C[np.ix_(ik, ir)]
    P = np.linalg.inv(S)
    d2 = float(x @ P @ x)
    limit = float(chi2.isf(TAIL, len(ir)))
    if d2 <= limit:
        return
    # the value least like the others: largest standardised conditional residual
    g = P @ x
    z = g / np.sqrt(np.diag(P))
    i = int(np.argmax(np.abs(z)))
    n = rest[i]
    expect = values[n] - g[i] / P[i, i]
    sd = 1.0 / np.sqrt(P[i, i])
    raise OutOfRangeError(
        f"these measurements are unlike any {sex} body in ANSUR II (Mahalanobis distance "
        f"{np.sqrt(d2):.1f} > {np.sqrt(limit):.1f}); the least consistent is "
        f"{n}={_fmt(n, values[n])}, expected about {_fmt(n, expect)} ± {_fmt(n, sd)} "
        "given the others",
        feature=n, value=values[n], mahalanobis=float(np.sqrt(d2)),
    )  # fmt: skip


# ----------------------------------------------------------------------------- calibration


_CALIBRATION: dict[tuple[int, str], tuple[weakref.ref, dict[str, float]]] = {}


def calibration(model: ShapeModel, sex: str) -> dict[str, float]:
    """Offsets ``tape - core.measure`` per measurement for bodies of ``model`` (metres; kg).

    ``core.measure``'s definitions on the model's bodies read some measurements systematically
    differently from ANSUR II's tape (e.g. the buttock circumference 3 cm short, the
    Iliocristale 2.5 cm low). The offset of each is the mean of the ANSUR II held-in rows of
    ``sex`` minus the measurement of the model's body for their mean stature and weight
    (cached per model and sex).
    """
    key = (id(model), sex)
    hit = _CALIBRATION.get(key)
    if hit is not None and hit[0]() is model:
        return hit[1]
    names, mu, _, _ = _ansur_stats(sex)
    i_st, i_w = names.index("stature"), names.index("weightkg")
    V = model.synthesize(sex, {"height_m": float(mu[i_st]), "weight_kg": float(mu[i_w])})
    m = measure(V, names=names, density=model.space(sex).density)
    offsets = {n: float(mu[i] - m[n]) for i, n in enumerate(names)}
    _CALIBRATION[key] = (weakref.ref(model), offsets)
    return offsets


# ----------------------------------------------------------------------------- fitting


def _tolerances(names: list[str]) -> np.ndarray:
    """(n,) σ of each named measurement (:data:`TOLERANCE_BY_NAME`, else of its kind)."""
    return np.array([TOLERANCE_BY_NAME.get(n, TOLERANCE[MEASUREMENTS[n].kind]) for n in names])


def body_from_measurements(
    sex: str,
    measurements: dict[str, Any],
    *,
    model: ShapeModel | None = None,
    refine: bool = True,
    calibrate: bool = True,
    tolerance_scale: float = 1.0,
    max_iterations: int = 10,
) -> MeasurementsResult:
    """The most likely body of ``sex`` with the given tape measurements.

    Parameters
    ----------
    sex : ``"female"`` or ``"male"``.
    measurements : ANSUR II name -> value (metres; ``weightkg`` kilograms); any subset of
        :data:`core.measure.MEASUREMENTS`.
    model : the shape model (default: the committed default model).
    refine : run the Gauss–Newton refinement on the measured values (else the conditional
        Gaussian alone, which uses only the feature map's measurements).
    calibrate : the values are ANSUR-style tape measurements: the body's ``core.measure``
        values plus the model's :func:`calibration` offsets are matched to them. ``False``:
        the values follow ``core.measure``'s definitions (e.g. measured on a bodyspace body)
        and are matched as they are.
    tolerance_scale : multiplies every tape tolerance σ (:data:`TOLERANCE`); smaller matches
        the given values more tightly at the expense of likelihood.
    max_iterations : accepted refinement steps at most.

    Returns
    -------
    MeasurementsResult (body in template order, metres, +Y up, floor at y = 0).

    Raises
    ------
    MeasurementError, OutOfRangeError
        See :func:`check_measurements`; the feature map's range checks apply as well.
    """
    t0 = time.perf_counter()
    model = model or default_model()
    given = check_measurements(sex, measurements)
    if not (math.isfinite(tolerance_scale) and tolerance_scale > 0):
        raise ValueError(f"tolerance_scale must be a positive number, got {tolerance_scale!r}")
    space = model.space(sex)
    fm, sd, density = space.features, space.pca.sd, space.density
    names = list(given)
    offsets = calibration(model, sex) if calibrate else {}
    off = np.array([offsets.get(n, 0.0) for n in names])
    target = np.array([given[n] for n in names])
    sigma = _tolerances(names) * tolerance_scale
    report = MeasurementsReport(sex=sex, given=dict(given), calibrated=calibrate)

    # conditional Gaussian on the measurements the feature map knows (tape values, as trained)
    feats, report.feature_map = _feature_values(model, sex, given)
    w = fm.weights(feats) if feats else fm.mean[fm.f :].copy()
    report.warnings.extend(model.range_warnings(sex, feats))
    report.notes.append(
        "conditional Gaussian of the feature map on "
        + (", ".join(report.feature_map) if feats else "nothing (the mean body)")
    )

    # beyond the training bulk, bodies are symmetrised as in synthesis (else one foot lifts)
    sym = model.correction(sex, feats)

    # whitened weights z = w / sd: the prior E_p is |z|^2
    def measured(z: np.ndarray) -> np.ndarray:
        V = model.reconstruct(sex, z * sd, check=False, symmetrize=sym)
        m = measure(V, names=names, density=density)
        return np.array([m[n] for n in names])

    # the body's core.measure values should read the tape values minus the offsets
    z = w / sd
    m = measured(z)
    ed, ep = _energy(z, m, target - off, sigma)
    report.energy_start = ed + ep
    if refine:
        z, m, ed, ep, report.iterations = _levenberg_marquardt(
            measured, z, m, target - off, sigma, max_iterations=max_iterations
        )
        report.refined = True
        report.notes.append(
            f"Gauss–Newton on the measured values with the Gaussian prior: "
            f"{report.iterations} steps, E {report.energy_start:.3g} -> {ed + ep:.3g}"
        )
    report.energy, report.data_energy, report.prior_energy = ed + ep, ed, ep
    w = z * sd
    V = model.reconstruct(sex, w, check=False, symmetrize=sym)
    report.pca_weights = [float(x) for x in w]
    report.prior_sd = float(np.sqrt(ep))
    for n, t, mi, o, s in zip(names, target, m, off, sigma, strict=True):
        report.matched[n] = {
            "given": float(t), "measured": float(mi), "offset": float(o),
            "residual": float(mi + o - t), "tolerance": float(s), "unit": _unit(n),
        }  # fmt: skip
        if abs(mi + o - t) > WARN_TOLERANCES * s:
            report.warnings.append(
                f"{n}: the most likely body has {_fmt(n, mi + o)}, not {_fmt(n, t)} "
                "(the shape space has no likely body with all the given values)"
            )
    big = np.flatnonzero(np.abs(z) > MAX_SD)
    if big.size:
        report.warnings.append(
            f"PCA weight(s) {', '.join(map(str, big))} beyond {MAX_SD:g} SD: an unusual body "
            "for this model"
        )
    all_m = measure(V, density=density)
    report.measurements = {k: float(v) for k, v in all_m.items()}
    report.offsets = {k: float(offsets.get(k, 0.0)) for k in all_m}
    report.predicted = {k: float(v + offsets.get(k, 0.0)) for k, v in all_m.items()}
    report.seconds = time.perf_counter() - t0
    return MeasurementsResult(
        vertices=V, faces=np.asarray(load_template().F, np.int64), pca=w, report=report
    )


def _energy(
    z: np.ndarray, m: np.ndarray, target: np.ndarray, sigma: np.ndarray
) -> tuple[float, float]:
    """(data, prior) energies: ``|(m - target) / σ|²`` and ``|z|²``."""
    r = (m - target) / sigma
    return float(r @ r), float(z @ z)


def _levenberg_marquardt(
    measured,
    z: np.ndarray,
    m: np.ndarray,
    target: np.ndarray,
    sigma: np.ndarray,
    *,
    max_iterations: int,
) -> tuple[np.ndarray, np.ndarray, float, float, int]:
    """Minimise ``|(m(z) - t) / σ|² + |z|²`` over whitened PCA weights ``z``."""
    k = z.size
    ed, ep = _energy(z, m, target, sigma)
    lam = 1e-3
    steps = 0
    while steps < max_iterations:
        r = (m - target) / sigma
        J = np.empty((len(target), k))
        for j in range(k):
            dz = np.zeros(k)
            dz[j] = FD_STEP_SD
            J[:, j] = (measured(z + dz) - m) / (sigma * FD_STEP_SD)
        H = J.T @ J + np.eye(k)
        g = J.T @ r + z
        accepted = False
        for _ in range(8):
            step = -np.linalg.solve(H + lam * np.diag(np.diag(H)), g)
            zn = z + step
            try:
                mn = measured(zn)
            except ValueError:  # a degenerate body far out: damp more
                lam *= 10.0
                continue
            edn, epn = _energy(zn, mn, target, sigma)
            if edn + epn < ed + ep:
                gain = (ed + ep) - (edn + epn)
                z, m, ed, ep = zn, mn, edn, epn
                lam = max(lam / 3.0, 1e-6)
                accepted = True
                break
            lam *= 10.0
        if not accepted:
            break
        steps += 1
        if gain < 1e-3 * (1.0 + ed + ep) or np.abs(step).max() < 1e-3:
            break
    return z, m, ed, ep, steps
