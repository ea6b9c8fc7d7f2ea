"""Training bodies for the shape space: ANSUR II subjects rebuilt from MakeHuman targets, then
scanned and registered by our own pipeline.

Stages (each resumable; run from the repository root):

``solve``  For every ANSUR II dev-split subject of a sex (``core.shapespace.ansur``), find
           MakeHuman parameters -- macro sliders (muscle, weight, proportions, cup) *and* signed
           regional ``measure-*`` / fat / scale targets -- such that the body's measurements
           (``core.measure.measure`` when available) match the subject's stature, weight and main
           circumferences, heights and breadths. Age and ethnic mix come from the subject
           (``Age``, ``DODRace``); stature is met exactly (height modifier + a residual uniform
           scale). Fast: a surrogate (ridge regression of every measurement on piecewise-linear
           features of the parameters, fitted on ~1000 random bodies per sex) is inverted per
           subject by bounded least squares, then a few chord (fixed-slope Newton) corrections use
           the true measurements of the current bodies.
``fit``    Each solved body -> ``core.synth.simulate_scan`` (random scanner, noise, holes, frame)
           -> ``core.io`` frame detection and preparation -> ``core.registration.fit``; every fit
           is written as ``FITS_DIR/<sex>_<subjectid>.npz`` (``vertices`` (13380, 3) metres,
           template order) next to ``FITS_DIR/features.csv``. Existing files are skipped.

    .venv/bin/python -m bench.training solve --sex male --part train --n 120 --out build/bodies
    .venv/bin/python -m bench.training fit build/bodies --out build/fits --jobs 2
    .venv/bin/python -m bench.training report build/bodies     # held-out solve accuracy
"""

from __future__ import annotations

import argparse
import csv
import re
import sys
import time
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from core.shapespace.ansur import split
from core.synth.bodies import _regional_names, macro_weights
from core.synth.targets import load_targets
from core.template import load_template

# ----------------------------------------------------------------------------- measurements


def _measure_fn():
    """``core.measure.measure`` if it exists, else the stand-in below."""
    try:
        from functools import partial

        from core.measure import MEASUREMENTS, measure
    except ImportError:
        return _standin_measure, "stand-in"
    names = [k for k in SOLVE_MEASURES if k in MEASUREMENTS]
    return partial(measure, names=names), "core.measure"


#: Measurements the solver matches (those the measure function provides are used).
SOLVE_MEASURES = (
    "stature", "weightkg", "chestcircumference", "waistcircumference", "buttockcircumference",
    "thighcircumference", "calfcircumference", "bicepscircumferenceflexed", "neckcircumference",
    "acromialheight", "cervicaleheight", "crotchheight", "waistheightomphalion",
    "biacromialbreadth", "hipbreadth", "kneeheightmidpatella", "forearmcircumferenceflexed",
    "lowerthighcircumference", "chestdepth", "waistdepth", "waistbreadth", "buttockdepth",
)  # fmt: skip

_STANDIN_DENSITY = 1010.0
_Y = np.array([0.0, 1.0, 0.0])


@cache
def _part_edges(parts: tuple[str, ...]) -> np.ndarray:
    t = load_template()
    m = np.zeros(t.n_vertices, bool)
    for p in parts:
        m |= t.part_mask(p)
    F = t.F[m[t.F].all(1)]
    E = np.vstack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    return np.unique(np.sort(E, 1), axis=0)


def _section_perimeter(
    V: np.ndarray, parts: tuple[str, ...], p: np.ndarray, n: np.ndarray
) -> float:
    """Convex-hull perimeter (m) of the section of ``parts`` by the plane (point p, normal n)."""
    from scipy.spatial import ConvexHull

    E = _part_edges(parts)
    n = n / np.linalg.norm(n)
    d = (V - p) @ n
    a, b = d[E[:, 0]], d[E[:, 1]]
    c = (a * b) < 0
    if c.sum() < 3:
        return 0.0
    t = a[c] / (a[c] - b[c])
    P = V[E[c, 0]] + t[:, None] * (V[E[c, 1]] - V[E[c, 0]])
    u = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    try:
        return float(ConvexHull(np.stack([(P - p) @ u, (P - p) @ w], 1)).area)
    except Exception:  # degenerate section
        return 0.0


def _standin_measure(V: np.ndarray) -> dict[str, float]:
    """Simple stand-in measurements (metres; ``weightkg`` = volume x 1010 kg/m^3)."""
    t = load_template()
    L = t.landmarks

    def lm(k: str) -> np.ndarray:
        return V[L[k]]

    floor = V[:, 1].min()
    a, b, c = V[t.F[:, 0]], V[t.F[:, 1]], V[t.F[:, 2]]
    vol = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
    torso = ("torso", "pelvis")
    out = {
        "stature": V[:, 1].max() - floor,
        "weightkg": vol * _STANDIN_DENSITY,
        "acromialheight": 0.5 * (lm("Acromion_L")[1] + lm("Acromion_R")[1]) - floor,
        "cervicaleheight": lm("Cervicale")[1] - floor,
        "crotchheight": lm("Crotch")[1] - floor,
        "waistheightomphalion": lm("Omphalion")[1] - floor,
        "biacromialbreadth": abs(lm("Acromion_L")[0] - lm("Acromion_R")[0]),
        "chestcircumference": _section_perimeter(
            V, torso, 0.5 * (lm("Thelion_L") + lm("Thelion_R")), _Y
        ),
        "waistcircumference": _section_perimeter(V, torso, lm("Omphalion"), _Y),
        "buttockcircumference": _section_perimeter(
            V, (*torso, "thigh_L", "thigh_R"), 0.5 * (lm("Buttock_L") + lm("Buttock_R")), _Y
        ),
        "thighcircumference": _section_perimeter(
            V, ("thigh_L", "pelvis"), lm("Crotch") + np.array([0.1, -0.03, 0.0]), _Y
        ),
        "neckcircumference": _section_perimeter(
            V, ("neck", "head", "torso"), lm("Cervicale") + np.array([0.0, 0.03, 0.0]), _Y
        ),
    }
    k, an = lm("Patella_L"), lm("Lateral_malleolus_L")
    out["calfcircumference"] = max(
        _section_perimeter(V, ("shin_L",), k + f * (an - k), _Y) for f in (0.2, 0.27, 0.34, 0.41)
    )
    ac, r = lm("Acromion_L"), lm("Radiale_L")
    out["bicepscircumferenceflexed"] = _section_perimeter(
        V, ("upper_arm_L",), 0.5 * (ac + r), r - ac
    )
    tr = 0.5 * (lm("Trochanterion_L") + lm("Trochanterion_R"))
    idx = np.unique(_part_edges((*torso, "thigh_L", "thigh_R")))
    sl = idx[np.abs(V[idx, 1] - tr[1]) < 0.01]
    out["hipbreadth"] = float(np.ptp(V[sl, 0]))
    return {k: float(v) for k, v in out.items()}


# ----------------------------------------------------------------------------- body model

MACRO = ("muscle", "weight", "proportions", "cup")
#: Signed regional target families (negative = decr/down) and their bounds.
REGIONAL = (
    "torso/measure-bust-circ", "torso/measure-underbust-circ", "torso/measure-waist-circ",
    "torso/measure-hips-circ", "stomach/stomach-pregnant", "buttocks/buttocks-volume",
    "legs/measure-thigh-circ", "legs/upperleg-fat", "legs/measure-calf-circ", "legs/lowerleg-fat",
    "arms/measure-upperarm-circ", "arms/upperarm-fat", "arms/lowerarm-fat",
    "neck/measure-neck-circ", "torso/measure-shoulder-dist", "torso/torso-scale-depth",
    "hip/hip-scale-horiz", "legs/measure-upperleg-height", "legs/measure-lowerleg-height",
    "torso/measure-napetowaist-dist", "neck/measure-neck-height", "torso/measure-waisttohip-dist",
)  # fmt: skip
REGIONAL_BOUNDS = (-1.0, 1.3)
#: DODRace (1 White, 2 Black, 3 Hispanic, 4 Asian, 5 Native American, 6 Pacific Islander)
#: -> MakeHuman ethnic mix (african, asian, caucasian).
RACE_MIX = {
    1: (0.0, 0.0, 1.0), 2: (1.0, 0.0, 0.0), 3: (0.15, 0.15, 0.7), 4: (0.0, 1.0, 0.0),
    5: (0.0, 0.5, 0.5), 6: (0.3, 0.5, 0.2),
}  # fmt: skip


def age_modifier(age_years: float) -> float:
    """MakeHuman age modifier on [0.5, 1] (0.5 = 25 years, 1 = 90 years)."""
    return 0.5 + max(age_years - 25.0, 0.0) / 65.0 * 0.5


class BodyModel:
    """MakeHuman body of one sex as a dense linear basis: ``V = V0 + c(params) @ B``.

    Free parameters (solved): :data:`MACRO` on [0, 1] (``cup`` female only) and the signed
    :data:`REGIONAL` families. Fixed per subject: stature (m), age (years), ethnic mix.
    """

    def __init__(self, sex: str) -> None:
        self.sex = sex
        lib = load_targets()
        self.lib = lib
        self.V0 = np.array(load_template().V, dtype=np.float64)
        self.macro = tuple(m for m in MACRO if not (m == "cup" and sex == "male"))
        self.names = list(self.macro) + list(REGIONAL)
        lo = [0.0] * len(self.macro) + [REGIONAL_BOUNDS[0]] * len(REGIONAL)
        hi = [1.0] * len(self.macro) + [REGIONAL_BOUNDS[1]] * len(REGIONAL)
        self.bounds = (np.array(lo), np.array(hi))
        self.x0 = np.array([0.5] * len(self.macro) + [0.0] * len(REGIONAL))
        self._reg = [_regional_names(s, lib) for s in REGIONAL]
        sx = re.compile(rf"(^|[/-]){sex}-")
        tn = [n for n in lib.names if sx.search(n) or n.startswith(("arms/", "legs/", "torso/",
              "hip/", "buttocks/", "stomach/", "neck/", "breast/breast-"))]  # fmt: skip
        self.tindex = {n: i for i, n in enumerate(tn)}
        B = np.zeros((len(tn), self.V0.size), dtype=np.float32)
        for i, n in enumerate(tn):
            idx, d = lib.sparse(n)
            B[i].reshape(-1, 3)[idx] = d
        self.B = B
        # stature needs only the extreme vertices: the 400 highest and 400 lowest of the template
        ys = np.argsort(self.V0[:, 1])
        self._ext = np.concatenate([ys[:400], ys[-400:]])
        self.By = np.ascontiguousarray(B.reshape(len(tn), -1, 3)[:, self._ext, 1])

    def coefs(self, x: np.ndarray, h: float, age: float, mix: tuple[float, ...]) -> np.ndarray:
        """Target coefficient vector for free parameters ``x``, height modifier ``h``."""
        kw = dict(zip(self.macro, x[: len(self.macro)].tolist(), strict=True))
        races = dict(zip(("african", "asian", "caucasian"), mix, strict=True))
        w = macro_weights(
            self.sex, age=age_modifier(age), height=h, races=races, lib=self.lib, **kw
        )
        c = np.zeros(len(self.tindex))
        for n, v in w.items():
            c[self.tindex[n]] += v
        for (neg, pos), v in zip(self._reg, x[len(self.macro) :], strict=True):
            for n in pos if v > 0 else neg:
                c[self.tindex[n]] += abs(v)
        return c

    def body(self, x: np.ndarray, stature: float, age: float, mix: tuple[float, ...]) -> np.ndarray:
        """(13380, 3) metres, floor y = 0, stature exactly ``stature`` (height modifier solved
        by bisection, then a residual uniform scale)."""
        c_mid, c_lo, c_hi = (self.coefs(x, h, age, mix).astype(np.float32) for h in (0.5, 0.0, 1.0))

        def c_at(h: float) -> np.ndarray:
            return (
                c_mid + (2 * h - 1) * (c_hi - c_mid)
                if h >= 0.5
                else c_mid + (1 - 2 * h) * (c_lo - c_mid)
            )

        y0 = self.V0[self._ext, 1]
        lo, hi = 0.0, 1.0
        for _ in range(18):
            h = 0.5 * (lo + hi)
            y = y0 + c_at(h) @ self.By
            if y.max() - y.min() < stature:
                lo = h
            else:
                hi = h
        V = self.V0 + (c_at(h) @ self.B).reshape(-1, 3).astype(np.float64)
        V *= stature / (V[:, 1].max() - V[:, 1].min())
        V[:, 1] -= V[:, 1].min()
        return V


# ----------------------------------------------------------------------------- surrogate


def _features(x: np.ndarray, z: np.ndarray, n_macro: int) -> np.ndarray:
    """Piecewise-linear (+ quadratic) features of free params ``x`` (N, p) and fixed ``z`` (N, q)
    (z = [stature - 1.7, age / 50, african, asian])."""
    xm, xr = x[:, :n_macro] - 0.5, x[:, n_macro:]
    u = np.concatenate(
        [np.maximum(xm, 0), np.minimum(xm, 0), np.maximum(xr, 0), np.minimum(xr, 0)], 1
    )
    s = z[:, :1]
    return np.concatenate([np.ones((len(x), 1)), u, u**2, s * u, z, s**2], 1)


@dataclass
class Surrogate:
    """Ridge regression of each measurement on :func:`_features`."""

    names: list[str]
    coef: np.ndarray  # (n_features, n_measures)
    n_macro: int

    def predict(self, x: np.ndarray, z: np.ndarray) -> np.ndarray:
        return _features(np.atleast_2d(x), np.atleast_2d(z), self.n_macro) @ self.coef


def _z(stature: float, age: float, mix: tuple[float, ...]) -> np.ndarray:
    return np.array([stature - 1.7, age / 50.0, mix[0], mix[1]])


def build_surrogate(model: BodyModel, n: int, rng: np.random.Generator, measure) -> Surrogate:
    """Measure ``n`` random bodies and fit the surrogate."""
    lo, hi = model.bounds
    X = rng.uniform(lo, hi, size=(n, len(lo)))
    X[:, len(model.macro) :] *= rng.uniform(0.0, 1.0, size=(n, 1))  # include near-neutral bodies
    st = rng.uniform(1.45, 2.0, n)
    age = rng.uniform(17, 60, n)
    mixes = [RACE_MIX[int(r)] for r in rng.integers(1, 7, n)]
    Z = np.stack([_z(st[i], age[i], mixes[i]) for i in range(n)])
    rows = []
    for i in range(n):
        rows.append(measure(model.body(X[i], st[i], age[i], mixes[i])))
    names = [k for k in SOLVE_MEASURES if k in rows[0]]
    M = np.array([[r[k] for k in names] for r in rows])
    Phi = _features(X, Z, len(model.macro))
    lam = 1e-4 * np.eye(Phi.shape[1])
    lam[0, 0] = 0.0
    coef = np.linalg.solve(Phi.T @ Phi + lam * len(Phi), Phi.T @ M)
    res = M - Phi @ coef
    print(f"  surrogate ({n} bodies): RMS residual per measure (mm / kg):", flush=True)
    rms = np.sqrt((res**2).mean(0))
    print("   " + ", ".join(f"{k}={1000 * r if k != 'weightkg' else r:.1f}"
                           for k, r in zip(names, rms, strict=True)))  # fmt: skip
    return Surrogate(names, coef, len(model.macro))


# ----------------------------------------------------------------------------- solve


def measure_scales(sex: str, names: list[str]) -> np.ndarray:
    """Per-measurement weights: residual SD of the training rows after a linear regression on
    stature and weight (the variation the solve must reproduce). Stature and weight get 1/5 of
    their population SD so that they are met tightly."""
    d = split(sex, "train")
    A = np.stack([np.ones_like(d["stature"]), d["stature"], d["weightkg"]], 1)
    out = []
    for k in names:
        y = d[k]
        if k in ("stature", "weightkg"):
            out.append(0.2 * y.std())
            continue
        r = y - A @ np.linalg.lstsq(A, y, rcond=None)[0]
        out.append(r.std())
    return np.array(out)


def solve_subject(
    model: BodyModel,
    sur: Surrogate,
    target: np.ndarray,
    sigma: np.ndarray,
    stature: float,
    age: float,
    mix: tuple[float, ...],
    measure,
    *,
    iterations: int = 3,
    prior: float = 0.15,
) -> tuple[np.ndarray, np.ndarray, dict[str, float]]:
    """Parameters, body and measurements for one subject (bounded LS on the surrogate with a
    measured-minus-predicted offset, refreshed ``iterations`` times)."""
    z = _z(stature, age, mix)
    lo, hi = model.bounds
    x = model.x0.copy()
    offset = np.zeros_like(target)
    best = None
    for _ in range(iterations + 1):

        def resid(xx: np.ndarray, off: np.ndarray = offset) -> np.ndarray:
            r = (sur.predict(xx, z)[0] + off - target) / sigma
            return np.concatenate([r, prior * (xx - model.x0)])

        x = least_squares(resid, x, bounds=(lo, hi), method="trf", x_scale=1.0, max_nfev=60).x
        V = model.body(x, stature, age, mix)
        m = measure(V)
        mv = np.array([m[k] for k in sur.names])
        err = float(np.sum(((mv - target) / sigma) ** 2))
        if best is None or err < best[0]:
            best = (err, x.copy(), V, m)
        offset = mv - sur.predict(x, z)[0]
    return best[1], best[2], best[3]


def solve(
    sex: str, part: str, n: int | None, out: Path, *, seed: int = 0, n_surrogate: int = 600
) -> None:
    """Solve subjects of ``sex`` in split ``part`` (the first ``n`` in hash order) into ``out``."""
    measure, mname = _measure_fn()
    out.mkdir(parents=True, exist_ok=True)
    model = BodyModel(sex)
    sur_path = out / f"surrogate_{sex}.npz"
    if sur_path.exists():
        z = np.load(sur_path)
        sur = Surrogate([str(s) for s in z["names"]], z["coef"], int(z["n_macro"]))
    else:
        t0 = time.time()
        sur = build_surrogate(model, n_surrogate, np.random.default_rng(seed), measure)
        np.savez(sur_path, names=np.array(sur.names), coef=sur.coef, n_macro=sur.n_macro)
        print(f"  surrogate built in {time.time() - t0:.0f} s ({mname} measurements)", flush=True)
    d = split(sex, part)
    order = np.argsort((d["subjectid"] * 40503) % 65536, kind="stable")  # fixed shuffle
    if n is not None:
        order = order[:n]
    sigma = measure_scales(sex, sur.names)
    t0 = time.time()
    for j, i in enumerate(order):
        sid = int(d["subjectid"][i])
        f = out / f"{sex}_{sid}.npz"
        if f.exists():
            continue
        target = np.array([d[k][i] for k in sur.names])
        mix = RACE_MIX[int(d["DODRace"][i])]
        x, V, m = solve_subject(
            model, sur, target, sigma, float(d["stature"][i]), float(d["Age"][i]), mix, measure
        )
        np.savez_compressed(
            f, vertices=V.astype(np.float32), params=x, param_names=np.array(model.names),
            sex=sex, subjectid=sid, part=part,
            measured=np.array([m.get(k, np.nan) for k in sur.names]),
            target=target, measure_names=np.array(sur.names), measure_source=mname,
        )  # fmt: skip
        if j % 20 == 0:
            print(f"  {sex} {part} {j + 1}/{len(order)}  {time.time() - t0:.0f} s", flush=True)


# ----------------------------------------------------------------------------- refine


#: Measurements the correction weights 3x less (see :func:`refine`).
SECONDARY = (
    "lateralfemoralepicondyleheight", "lateralmalleolusheight", "iliocristaleheight",
    "buttockheight", "suprasternaleheight", "chestheight", "trochanterionheight", "chestbreadth",
)  # fmt: skip
#: Shoulder drop (both clavicles rotated down about the front axis) is a basis field of the
#: correction: MakeHuman's acromion sits ~50 mm too high relative to cervicale for ANSUR.
SHOULDER_DROP_DEG = 4.0


def correction_basis(Vref: np.ndarray, k: int = 80) -> tuple[np.ndarray, np.ndarray]:
    """Displacement basis of the learned correction: the top ``k`` principal directions of all
    426 MakeHuman targets (``core.registration.shape_prior``) plus a shoulder-drop field.

    Only the left-right symmetric part of each direction is kept (directions with less than
    10 % of their norm symmetric are dropped): 11 of the top 80 MakeHuman directions are
    one-sided (``l-``/``r-`` targets), and with measurements taken on the right side the
    correction used them to lengthen one arm and, through the floor's kink, to lift one foot
    (up to 52 mm in a refined body; 23 mm in the mean of the model built from them).

    Returns U (3n, q) (per unit coefficient, metres; q <= k + 1) and the prior SD of each
    coefficient.
    """
    from core.registration.shape_prior import load_shape_basis
    from core.rig import axis_angle, pose_body
    from core.shapespace.calibrate import symmetric_part
    from core.template import load_template

    B = load_shape_basis(k)
    th = np.radians(SHOULDER_DROP_DEG)
    z = np.array([0.0, 0.0, 1.0])
    P = pose_body(Vref, {"clavicle.L": axis_angle(z, -th), "clavicle.R": axis_angle(z, th)})
    d = (P - Vref).ravel()
    U = np.concatenate([B.U.reshape(-1, B.k), (d / np.linalg.norm(d))[:, None]], axis=1)
    sd = np.append(B.sigma, np.linalg.norm(d) * 3.0)  # up to ~12 degrees
    mirror = load_template().mirror
    U = np.stack([symmetric_part(U[:, j], mirror) for j in range(U.shape[1])], 1)
    norms = np.linalg.norm(U, axis=0)
    keep = norms > 0.1
    return U[:, keep] / norms[keep], sd[keep] * norms[keep]


REFINE_VERSION = "/v3"  # v3: symmetric correction basis


def _unrefined(f: Path) -> np.ndarray:
    with np.load(f) as z:
        return (z["vertices_mh"] if "vertices_mh" in z else z["vertices"]).astype(np.float64)


def refine(bodies: Path, sex: str, *, mu: float = 0.3, iterations: int = 3, k: int = 80) -> None:
    """Learned correction of solved bodies: small displacements in :func:`correction_basis`
    that bring the measurements the MakeHuman sliders cannot reach (waist, buttock, shoulder
    slope, ...) to the subject's. Linearised once per sex (finite-difference Jacobian of the
    measurements at the mean solved body), then ``iterations`` chord steps per body, each a
    Tikhonov-regularised least-squares solve (``mu`` x the coefficients' prior), stature kept
    exact. Rewrites ``vertices`` (the unrefined body stays as ``vertices_mh``)."""
    from core.measure import MEASUREMENTS, measure

    files = sorted(bodies.glob(f"{sex}_*.npz"))
    if not files:
        return
    # every measurement core.measure provides that ANSUR has, targets from the subject's row
    rows = {p: split(sex, p) for p in ("train", "test")}
    names = [k for k in MEASUREMENTS if k in rows["train"]]
    sigma = measure_scales(sex, names)
    sigma[names.index("weightkg")] *= 0.5
    # landmark-defined heights whose ANSUR definitions disagree with the template's landmark
    # placement (they pull in opposite directions: e.g. epicondyle vs mid-patella) count less
    for n in SECONDARY:
        if n in names:
            sigma[names.index(n)] *= 3.0
    jpath = bodies / f"refine_{sex}{REFINE_VERSION.replace('/', '_')}.npz"
    if jpath.exists():
        with np.load(jpath) as z:
            U, sd, J = z["U"], z["sd"], z["J"]
    else:
        t0 = time.time()
        Vref = np.mean([_unrefined(f) for f in files[:100]], 0)
        U, sd = correction_basis(Vref, k)
        m0 = np.array([measure(Vref, names=names)[n] for n in names])
        eps = 0.002
        J = np.zeros((len(names), U.shape[1]))
        for j in range(U.shape[1]):
            step = eps * sd[j] / np.median(sd)
            Vj = Vref + step * U[:, j].reshape(-1, 3)
            J[:, j] = (np.array([measure(Vj, names=names)[n] for n in names]) - m0) / step
        np.savez(jpath, U=U.astype(np.float32), sd=sd, J=J, names=np.array(names))
        print(f"  {sex}: correction Jacobian in {time.time() - t0:.0f} s", flush=True)
    U = U.astype(np.float64)
    Js = J / sigma[:, None]
    P = np.linalg.solve(Js.T @ Js + mu * np.diag(1.0 / sd**2), Js.T)
    t0 = time.time()
    for c, f in enumerate(files):
        z = dict(np.load(f))
        if str(z.get("refined_names", "")) == ",".join(names) + REFINE_VERSION:
            continue
        V = z.get("vertices_mh", z["vertices"]).astype(np.float64)
        d = rows[str(z["part"])]
        i = int(np.flatnonzero(d["subjectid"] == int(z["subjectid"]))[0])
        T = np.array([d[n][i] for n in names])
        st = float(T[names.index("stature")])
        mm = measure(V, names=names)
        m = np.array([mm[n] for n in names])
        z["vertices_mh"], z["measured_mh"], z["target"] = V.astype(np.float32), m.copy(), T
        z["measure_names"] = np.array(names)
        V1 = V.copy()
        for _ in range(iterations):
            V1 = V1 + (U @ (P @ ((T - m) / sigma))).reshape(-1, 3)
            V1 *= st / np.ptp(V1[:, 1])
            V1[:, 1] -= V1[:, 1].min()
            mm = measure(V1, names=names)
            m = np.array([mm[n] for n in names])
        z["refined_names"] = ",".join(names) + REFINE_VERSION
        z["vertices"] = V1.astype(np.float32)
        z["measured"] = m
        tmp = f.with_suffix(".tmp.npz")
        np.savez_compressed(tmp, **z)
        tmp.replace(f)
        if c % 50 == 0:
            print(f"  {sex} refine {c + 1}/{len(files)}  {time.time() - t0:.0f} s", flush=True)


# ----------------------------------------------------------------------------- calibrate

#: Features the calibration synthesises each training row from (what users give most).
CALIBRATION_FEATURES = ("height_m", "weight_kg")
#: Measurements the calibration leaves out: ANSUR's chest breadth (beam caliper at nipple level,
#: arms at the sides) is narrower than the template's trunk section at that level, whose
#: lateral extent is set by the latissimus "wings" behind the arms (+25 mm in women, +50 mm in
#: men; the front half of the section alone is still +40 mm in men): matching it would pull
#: the chest and the arms inward (33 mm at the hands when it was weighted in).
CALIBRATION_EXCLUDED = ("chestbreadth",)


def calibrate(
    model_path: Path,
    out: Path,
    *,
    rows: int = 300,
    mu: float = 0.01,
    iterations: int = 8,
    k: int = 80,
    laplacian: int = 200,
    slopes: bool = True,
    seed: int = 0,
) -> dict:
    """Anthropometric calibration of the model's per-sex mean bodies
    (:func:`core.shapespace.calibrate.calibrate_mean`) on ``rows`` random held-in ANSUR rows per
    sex, in the basis of the learned correction (:func:`correction_basis`) plus ``laplacian``
    smooth symmetric fields (:func:`core.shapespace.calibrate.laplacian_basis`; 0: none), with
    the feature map's height and weight slopes when ``slopes``, every measurement
    ``core.measure`` shares with ANSUR weighted by its regression residual SD
    (:func:`measure_scales`). The joint space's mean moves by the sexes' weighted mean shift.
    Writes the calibrated model to ``out`` and returns a per-sex report."""
    from core.measure import MEASUREMENTS
    from core.shapespace import load_model
    from core.shapespace.ansur import rows_in_range, stature_weight
    from core.shapespace.calibrate import calibrate_space, laplacian_basis, symmetric_part
    from core.template import load_template

    model = load_model(model_path)
    rng = np.random.default_rng(seed)
    report: dict = {}
    shifts = {}
    tpl = load_template()
    # the fitted bodies' mean is not left-right symmetric (lower legs and feet up to 24 mm,
    # forearms and hands 12 mm: one foot stood 23 mm above the floor in every synthesised
    # woman); a population's mean body is: keep its symmetric part first
    asym = {}
    for sex, sp in model.spaces.items():
        sym = symmetric_part(sp.pca.mean, tpl.mirror)
        asym[sex] = float(np.abs(sym - sp.pca.mean).max())
        sp.pca.mean = sym
        print(f"  {sex}: mean body made symmetric (moved at most {1000 * asym[sex]:.1f} mm)")
    for sex in ("female", "male"):
        if sex not in model.spaces:
            continue
        d = split(sex, "train")
        names = [n for n in MEASUREMENTS if n in d and n not in CALIBRATION_EXCLUDED]
        ok = rows_in_range(model.space(sex).features, d)
        idx = np.sort(rng.choice(ok, size=min(rows, len(ok)), replace=False))
        feats = [stature_weight(d, int(i)) for i in idx]
        T = np.stack([d[n][idx] for n in names], 1)
        sigma = measure_scales(sex, names)
        # stature is an input: a body must keep it (a stature error turns into an offset of
        # every height, or, after the exact-height scaling, into a scale error)
        sigma[names.index("stature")] = 0.003
        U, sd = correction_basis(model.space(sex).pca.mean.reshape(-1, 3), k)
        if laplacian:
            UL, sdL = laplacian_basis(tpl.F, tpl.mirror, laplacian)
            U, sd = np.concatenate([U, UL], 1), np.concatenate([sd, sdL])
        t0 = time.time()
        cal = calibrate_space(
            model, sex, feats, T, names, sigma, U, sd, mu=mu, iterations=iterations,
            slope_features=CALIBRATION_FEATURES if slopes else (),
            log=lambda s: print(s, flush=True),
        )  # fmt: skip
        shifts[sex] = (cal.delta, model.space(sex).n_bodies)
        report[sex] = {
            n: {"bias_before": float(cal.bias_before[j]), "bias_after": float(cal.bias_after[j]),
                "rmse_before": float(cal.rmse_before[j]), "rmse_after": float(cal.rmse_after[j]),
                "sigma": float(sigma[j])}
            for j, n in enumerate(names)
        }  # fmt: skip
        rel = cal.delta - cal.delta.mean(0)  # the shape change (reconstruction re-floors bodies)
        print(f"  {sex}: {cal.n_rows} rows, {time.time() - t0:.0f} s, displacement after "
              f"removing its mean: RMS {1000 * np.sqrt((rel**2).sum(1).mean()):.1f} mm, "
              f"max {1000 * np.linalg.norm(rel, axis=1).max():.1f} mm")  # fmt: skip
        u = lambda n: 1.0 if n == "weightkg" else 1000.0  # noqa: E731
        for j, n in enumerate(names):
            b0, b1 = u(n) * cal.bias_before[j], u(n) * cal.bias_after[j]
            print(f"    {n:32s} bias {b0:7.1f} -> {b1:7.1f}"
                  f"   rmse {u(n) * cal.rmse_before[j]:6.1f} -> {u(n) * cal.rmse_after[j]:6.1f}"
                  f"   sigma {u(n) * sigma[j]:5.1f}")  # fmt: skip
    if "joint" in model.spaces and shifts:
        tot = sum(n for _, n in shifts.values())
        dj = sum(dl * n for dl, n in shifts.values()) / tot
        model.spaces["joint"].pca.mean = model.spaces["joint"].pca.mean + dj.ravel()
    model.metadata = dict(model.metadata)
    model.metadata["calibration"] = {
        "method": "core.shapespace.calibrate.calibrate_space", "rows_per_sex": rows, "mu": mu,
        "iterations": iterations, "slopes": list(CALIBRATION_FEATURES) if slopes else [],
        "basis": f"{k} MakeHuman target PCs + shoulder drop + {laplacian} Laplacian "
        "eigenvectors (symmetric x/y/z fields)",
        "features": list(CALIBRATION_FEATURES), "seed": seed,
        "excluded": list(CALIBRATION_EXCLUDED), "stature_sigma_m": 0.003,
        "symmetrised_mean_max_move_m": asym,
    }  # fmt: skip
    note = (
        f" Calibrated (bench.training calibrate, mu={mu:g}, {rows} held-in rows per sex): each "
        "sex's mean body made left-right symmetric and moved by one smooth displacement field "
        "(MakeHuman target PCs + Laplacian fields), and its feature map's height and weight "
        "slopes adjusted, so that bodies synthesised from the rows' stature and weight measure "
        "like the subjects (core.shapespace.calibrate)."
    )
    if "Calibrated (bench.training calibrate" not in model.provenance:
        model.provenance = model.provenance.rstrip() + note
    model.save(out)
    return report


# ----------------------------------------------------------------------------- fit


FEATURE_COLUMNS = ("stature", "weightkg", "Age")


def _fit_one(args: tuple[str, str, bool]) -> str:
    """Scan and register one solved body; writes ``<out>/<stem>.npz``. Returns a log line."""
    from bench.cases import scan_config
    from core.io import detect_frame, prepare_scan
    from core.registration.fit import fit
    from core.scan import RawMesh
    from core.synth import simulate_scan
    from core.synth.bodies import _random_pose

    src, dst, pose = Path(args[0]), Path(args[1]), args[2]
    if dst.exists():
        return f"{dst.stem}: exists"
    z = np.load(src)
    sid = int(z["subjectid"])
    rng = np.random.default_rng(1_000_003 + sid)
    tpl = load_template()
    V = z["vertices"].astype(np.float64)
    if pose:
        V, _ = _random_pose(V, rng)
    t0 = time.perf_counter()
    cfg = scan_config(rng)
    sim = simulate_scan(V, tpl.F, rng, config=cfg, landmarks=tpl.landmarks)
    raw = RawMesh(V=sim.V_scan, F=sim.F_scan, normals=sim.normals, confidence=sim.confidence)
    frame = detect_frame(raw.V, markers=sim.markers)
    scan = prepare_scan(raw, frame)
    markers = {k: frame.to_canonical(v[None])[0] for k, v in sim.markers.items()}
    truth = frame.to_canonical(sim.V_truth)
    t1 = time.perf_counter()
    res = fit(scan, markers)
    t2 = time.perf_counter()
    err = np.linalg.norm(res.vertices - truth, axis=1)
    tmp = dst.with_suffix(".tmp.npz")
    np.savez_compressed(
        tmp, vertices=res.vertices.astype(np.float32), truth=truth.astype(np.float32),
        sex=str(z["sex"]), subjectid=sid, pose=pose, scan_seconds=t1 - t0, fit_seconds=t2 - t1,
        truth_mean_m=float(err.mean()), truth_p95_m=float(np.percentile(err, 95)),
        scan_to_fit_mean_m=res.report.scan_to_fit_mean_m,
    )  # fmt: skip
    tmp.replace(dst)
    return (
        f"{dst.stem}: scan {t1 - t0:.1f} s, fit {t2 - t1:.1f} s, vs truth mean "
        f"{1000 * err.mean():.1f} mm p95 {1000 * np.percentile(err, 95):.1f} mm"
    )


def write_features(bodies: Path, out_csv: Path, part: str = "train") -> int:
    """``features.csv`` for every solved body of ``part``: ``id, sex, height_m, weight_kg, age``
    and the subject's ANSUR measurements (metres), the subject's own (tape-measure) values."""
    cols = None
    rows = []
    for f in sorted(bodies.glob("*_*.npz")):
        sex, _, sid = f.stem.partition("_")
        if sex not in ("female", "male") or not sid.isdigit():
            continue
        d = split(sex, part)
        hit = np.flatnonzero(d["subjectid"] == int(sid))
        if not len(hit):
            continue
        i = int(hit[0])
        meas = [k for k in d if k not in ("subjectid", "DODRace", "held_out", *FEATURE_COLUMNS)]
        if cols is None:
            cols = ["id", "sex", "height_m", "weight_kg", "age", *meas]
        rows.append([f.stem, sex, d["stature"][i], d["weightkg"][i], d["Age"][i],
                     *(d[k][i] for k in meas)])  # fmt: skip
    out_csv.parent.mkdir(parents=True, exist_ok=True)
    with open(out_csv, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols or ["id", "sex", "height_m", "weight_kg", "age"])
        for r in rows:
            w.writerow([r[0], r[1], *(f"{v:.4f}" for v in r[2:])])
    return len(rows)


def fit_all(bodies: Path, out: Path, *, jobs: int = 1, pose: bool = False, limit: int | None = None,
            part: str = "train") -> None:  # fmt: skip
    """Scan and register every solved body of ``part`` (resumable); balanced across sexes."""
    out.mkdir(parents=True, exist_ok=True)
    by_sex = {}
    for sex in ("female", "male"):
        fs = []
        for f in sorted(bodies.glob(f"{sex}_*.npz")):
            with np.load(f) as z:
                if str(z["part"]) == part:
                    fs.append(f)
        by_sex[sex] = fs[:limit] if limit else fs
    todo = [f for pair in zip(by_sex["female"], by_sex["male"], strict=False) for f in pair]
    n_max = max(len(v) for v in by_sex.values())
    todo += [f for v in by_sex.values() for f in v[len(todo) // 2 : n_max]]
    work = [(str(f), str(out / f.name), pose) for f in todo if not (out / f.name).exists()]
    print(f"{len(todo)} bodies, {len(work)} to fit ({jobs} processes)", flush=True)
    n = write_features(bodies, out / "features.csv", part)
    print(f"features.csv: {n} rows", flush=True)
    t0 = time.time()
    if jobs <= 1:
        it = map(_fit_one, work)
    else:
        import multiprocessing as mp

        pool = mp.get_context("spawn").Pool(jobs)
        it = pool.imap_unordered(_fit_one, work)
    for k, line in enumerate(it):
        print(f"[{k + 1}/{len(work)} {time.time() - t0:.0f} s] {line}", flush=True)


PROVENANCE = (
    "bodyspace default shape model: ANSUR II (public domain) held-in subjects rebuilt from CC0 "
    "MakeHuman targets (bench.training solve + refine), scanned by core.synth.simulate_scan, "
    "registered by core.registration.fit, PCA per sex and joint (core.shapespace.build_model). "
    "See core/assets/PROVENANCE.md."
)


def build(fits: Path, out: Path, *, variance: float = 0.99) -> None:
    """Build the model from ``fits`` (and its ``features.csv``) and print a summary."""
    from core.shapespace import build_model

    t0 = time.time()
    with open(fits / "features.csv") as fh:
        n_rows = sum(1 for _ in fh) - 1
    m = build_model(
        fits, fits / "features.csv", out, variance=variance, provenance=PROVENANCE,
        metadata={"pipeline": "ANSUR II -> MakeHuman solve + correction -> simulate_scan -> fit",
                  "feature_rows": n_rows},
    )  # fmt: skip
    print(f"built {out} in {time.time() - t0:.0f} s: " + ", ".join(
        f"{k}: {s.n_bodies} bodies, {s.pca.k} components ({100 * s.pca.explained.sum():.1f} %)"
        for k, s in m.spaces.items()))  # fmt: skip


# ----------------------------------------------------------------------------- CLI


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench.training", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("solve")
    s.add_argument("--sex", choices=("female", "male"), required=True)
    s.add_argument("--part", choices=("train", "test"), default="train")
    s.add_argument("--n", type=int, default=None)
    s.add_argument("--out", type=Path, required=True)
    r = sub.add_parser("report")
    r.add_argument("bodies", type=Path)
    r.add_argument("--part", choices=("train", "test"), default="test")
    rf = sub.add_parser("refine")
    rf.add_argument("bodies", type=Path)
    rf.add_argument("--sex", choices=("female", "male"), required=True)
    fa = sub.add_parser("fit")
    fa.add_argument("bodies", type=Path)
    fa.add_argument("--out", type=Path, required=True)
    fa.add_argument("--jobs", type=int, default=1)
    fa.add_argument("--limit", type=int, default=None, help="at most this many bodies per sex")
    fa.add_argument("--pose", action="store_true", help="slight random pose before scanning")
    ca = sub.add_parser("calibrate", help="anthropometric calibration of a model's mean bodies")
    ca.add_argument("model", type=Path)
    ca.add_argument("--out", type=Path, required=True)
    ca.add_argument("--rows", type=int, default=300)
    ca.add_argument("--mu", type=float, default=0.01)
    ca.add_argument("--iterations", type=int, default=8)
    ca.add_argument(
        "--laplacian",
        type=int,
        default=200,
        help="smooth symmetric Laplacian fields added to the basis (0: none)",
    )
    ca.add_argument(
        "--no-slopes",
        action="store_true",
        help="calibrate the mean only (not the height/weight slopes)",
    )
    bm = sub.add_parser("build", help="build a shape model from a fits folder")
    bm.add_argument("fits", type=Path)
    bm.add_argument("--out", type=Path, required=True)
    bm.add_argument("--variance", type=float, default=0.99)
    args = ap.parse_args(argv)
    if args.cmd == "build":
        build(args.fits, args.out, variance=args.variance)
    if args.cmd == "calibrate":
        calibrate(
            args.model,
            args.out,
            rows=args.rows,
            mu=args.mu,
            iterations=args.iterations,
            laplacian=args.laplacian,
            slopes=not args.no_slopes,
        )
    if args.cmd == "refine":
        refine(args.bodies, args.sex)
    if args.cmd == "fit":
        fit_all(args.bodies, args.out, jobs=args.jobs, pose=args.pose, limit=args.limit)
    if args.cmd == "solve":
        solve(args.sex, args.part, args.n, args.out)
    elif args.cmd == "report":
        report(args.bodies, args.part)
    return 0


# ----------------------------------------------------------------------------- report


def report(bodies: Path, part: str = "test") -> dict[str, dict[str, float]]:
    """Solve accuracy on solved subjects of ``part`` vs a linear regression on stature and weight
    fitted to the training rows: per-measurement RMSE (mm; kg for weight) and bias, for the
    MakeHuman solve alone and after the learned correction (:func:`refine`)."""
    out: dict[str, dict[str, float]] = {}
    for sex in ("female", "male"):
        recs = [np.load(f) for f in sorted(bodies.glob(f"{sex}_*.npz"))]
        recs = [r for r in recs if str(r["part"]) == part]
        if not recs:
            continue
        names = [str(s) for s in recs[0]["measure_names"]]
        M = np.array([r["measured"] for r in recs])
        M0 = np.array([r["measured_mh"] if "measured_mh" in r else r["measured"] for r in recs])
        T = np.array([r["target"] for r in recs])
        ids = np.array([int(r["subjectid"]) for r in recs])
        tr, te = split(sex, "train"), split(sex, part)
        pos = {int(s): i for i, s in enumerate(te["subjectid"])}
        rows = np.array([pos[i] for i in ids])
        A = np.stack([np.ones_like(tr["stature"]), tr["stature"], tr["weightkg"]], 1)
        At = np.stack([np.ones(len(rows)), te["stature"][rows], te["weightkg"][rows]], 1)
        print(f"\n{sex}: {len(recs)} solved {part} subjects; RMSE (bias) vs the subject, mm / kg")
        print(
            f"  {'measurement':28s} {'sliders only':>15s} {'+ correction':>15s} {'regression':>11s}"
        )
        for j, k in enumerate(names):
            u = 1.0 if k == "weightkg" else 1000.0
            e0, e = (M0[:, j] - T[:, j]) * u, (M[:, j] - T[:, j]) * u
            cf = np.linalg.lstsq(A, tr[k], rcond=None)[0]
            er = (At @ cf - T[:, j]) * u
            r0, r1, r2 = (float(np.sqrt(np.mean(x**2))) for x in (e0, e, er))
            out[f"{sex}/{k}"] = {
                "sliders_rmse": r0, "sliders_bias": float(e0.mean()), "solve_rmse": r1,
                "bias": float(e.mean()), "regression_rmse": r2,
            }  # fmt: skip
            rs = "-" if k in ("stature", "weightkg") else f"{r2:11.1f}"
            print(f"  {k:28s} {r0:7.1f} ({e0.mean():5.1f}) {r1:7.1f} ({e.mean():5.1f}) {rs:>11s}")
    return out


if __name__ == "__main__":
    sys.exit(main())
