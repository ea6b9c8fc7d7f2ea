"""Shape models: PCA spaces per sex (and a joint one) with their feature maps (paper §4–5).

A :class:`ShapeModel` holds one :class:`Space` per key ``"female"``, ``"male"`` and optionally
``"joint"`` (both sexes, with the feature ``male`` = 0/1). Every body goes in and comes out in
template vertex order, metres, +Y up, +Z front, standing on the floor (y = 0).

- :meth:`ShapeModel.synthesize` — a body from a full or partial feature vector, from PCA weights
  or from a seed (random draw from the Gaussian).
- :meth:`ShapeModel.project` / :meth:`ShapeModel.reconstruct` — body <-> PCA weights.
- :meth:`ShapeModel.edit` — change a body's features (e.g. ``{"weight_kg": 10}``) keeping its
  individual residual, face and hands.
- :meth:`ShapeModel.weight_kg` — volume x the density calibrated on the training bodies.
- :meth:`ShapeModel.save` / :func:`load_model` — one compact ``.npz``.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from core.shapespace.errors import ModelFormatError, OutOfRangeError
from core.shapespace.features import CUBE_ROOT, FeatureMap, encode
from core.shapespace.pca import PCA, from_model_frame, to_model_frame
from core.template import ASSET_DIR, load_template

if TYPE_CHECKING:
    from core.registration.shape_prior import ShapeBasis

SPACES = ("female", "male", "joint")
FORMAT_VERSION = 1
DEFAULT_MODEL = ASSET_DIR / "shape_model.npz"
#: Largest |PCA weight| accepted, in SDs of that component.
MAX_SD = 4.0
#: Parts kept in place by :meth:`ShapeModel.edit` (``keep=``), and the blend width (metres).
KEEP_DEFAULT = ("head", "hand_L", "hand_R")
KEEP_BLEND_M = 0.08
#: Extrapolation corrections of :meth:`ShapeModel.synthesize` fade in (smoothstep) between
#: these Mahalanobis distances of the given features from the training bodies' mean: none
#: below the first (the bulk of the training data: those bodies are the plain feature map's),
#: in full beyond the second.
CORRECT_FROM, CORRECT_FULL = 2.5, 3.5
#: The weight correction leaves a body whose weight is within this fraction of the requested
#: one as it is (the plain map's weight RMSE inside the training range is ~0.5 %).
WEIGHT_BAND = 0.015


def body_volume(V: np.ndarray) -> float:
    """Enclosed volume (m³) of a closed body in template order (template triangles)."""
    F = load_template().F
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _gate(d: float) -> float:
    """Strength in [0, 1] of the extrapolation corrections at Mahalanobis distance ``d``."""
    x = min(max((d - CORRECT_FROM) / (CORRECT_FULL - CORRECT_FROM), 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


def body_height(V: np.ndarray) -> float:
    """Stature (m): top vertex above the lowest."""
    return float(V[:, 1].max() - V[:, 1].min())


@dataclass
class Space:
    """One PCA shape space and its feature map.

    Attributes
    ----------
    pca : the PCA (mean, components, variances).
    features : the feature map (names, map, joint Gaussian, ranges).
    density : kg/m³ calibrated on the training bodies (their weights / their volumes).
    n_bodies : number of training bodies.
    """

    pca: PCA
    features: FeatureMap
    density: float
    n_bodies: int


@cache
def _mirror() -> np.ndarray:
    """(13380,) index of each template vertex's mirror vertex."""
    return load_template().mirror


@cache
def _keep_weights(parts: tuple[str, ...], blend_m: float) -> np.ndarray:
    """(13380,) in [0, 1]: 0 on ``parts``, rising smoothly to 1 at ``blend_m`` (edge-path
    distance on the template) away from them."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import dijkstra

    tpl = load_template()
    n = tpl.n_vertices
    seed = np.zeros(n, dtype=bool)
    for p in parts:
        seed |= tpl.part_mask(p)
    if not seed.any():
        return np.ones(n)
    E = tpl.edges
    L = np.linalg.norm(tpl.V[E[:, 0]] - tpl.V[E[:, 1]], axis=1)
    # a virtual source joined to every seed vertex at distance 0
    rows = np.concatenate([E[:, 0], E[:, 1], np.full(seed.sum(), n)])
    cols = np.concatenate([E[:, 1], E[:, 0], np.flatnonzero(seed)])
    vals = np.concatenate([L, L, np.full(seed.sum(), 1e-12)])
    G = coo_matrix((vals, (rows, cols)), shape=(n + 1, n + 1)).tocsr()
    d = dijkstra(G, indices=n, limit=blend_m * 1.01)[:n]
    t = np.clip(np.nan_to_num(d, posinf=blend_m) / blend_m, 0.0, 1.0)
    w = t * t * (3 - 2 * t)
    w[seed] = 0.0
    return w


def _follow_parts(parts: tuple[str, ...], D: np.ndarray) -> np.ndarray:
    """(13380, 3): each kept part's mean displacement under ``D``, spread over the part and its
    blend zone (weighted by nearness where zones meet), zero elsewhere."""
    tpl = load_template()
    num = np.zeros_like(D)
    den = np.zeros((len(D), 1))
    for p in parts:
        a = 1.0 - _keep_weights((p,), KEEP_BLEND_M)[:, None]
        mask = tpl.part_mask(p)
        if mask.any():
            num += a * D[mask].mean(axis=0)
            den += a
    return np.divide(num, den, out=np.zeros_like(D), where=den > 0)


@dataclass
class ShapeModel:
    """Shape spaces per sex (and joint), their feature maps, metadata and provenance."""

    spaces: dict[str, Space]
    metadata: dict[str, Any] = field(default_factory=dict)
    provenance: str = ""

    # ------------------------------------------------------------------ access

    def space(self, sex: str) -> Space:
        """The space of ``sex`` (``"female"``, ``"male"`` or ``"joint"``)."""
        if sex not in self.spaces:
            raise OutOfRangeError(
                f"sex must be one of {', '.join(self.spaces)}, got {sex!r}",
                feature="sex", value=sex, supported=list(self.spaces),
            )  # fmt: skip
        return self.spaces[sex]

    def shape_basis(self, sex: str = "joint", k: int | None = None) -> ShapeBasis:
        """The space of ``sex`` as the body prior's shape space (first ``k`` components; default
        all): ``core.registration.shape_prior.ShapeBasis`` for the markers-only, markerless and
        full fits."""
        from core.registration.shape_prior import ShapeBasis

        return ShapeBasis.from_pca(self.space(sex).pca, k)

    def describe(self) -> dict[str, Any]:
        """JSON-ready summary: per space the accepted features, their accepted ``range`` (beyond
        it: refused), ``training_range`` (beyond it: extrapolated, with a warning) and units,
        the number of components and of training bodies, and the model's metadata/provenance."""
        out: dict[str, Any] = {
            "spaces": {},
            "metadata": self.metadata,
            "provenance": self.provenance,
        }
        for key, s in self.spaces.items():
            out["spaces"][key] = {
                "features": {
                    n: {
                        "range": list(s.features.limits(n)),
                        "training_range": list(s.features.training_range(n)),
                        "unit": {"weight_kg": "kg", "age": "years", "male": "0/1"}.get(n, "m"),
                    }
                    for n in s.features.names
                },
                "components": s.pca.k,
                "explained_variance": float(s.pca.explained.sum()),
                "training_bodies": s.n_bodies,
                "density_kg_m3": s.density,
            }
        return out

    # ------------------------------------------------------------------ bodies

    def weight_kg(self, V: np.ndarray, sex: str = "joint") -> float:
        """Reported weight (kg) of a body: volume x the density calibrated for ``sex``."""
        s = self.spaces.get(sex) or next(iter(self.spaces.values()))
        return body_volume(np.asarray(V, dtype=np.float64)) * s.density

    def project(self, sex: str, V: np.ndarray, *, align: bool = True) -> np.ndarray:
        """PCA weights (k,) (metres) of a body in template order (any rigid placement when
        ``align``; it is first brought into the model frame)."""
        s = self.space(sex)
        V = _check_body(V)
        if align:
            V = to_model_frame(V, s.pca.mean.reshape(-1, 3))[0]
        return s.pca.project(V)

    def reconstruct(
        self, sex: str, weights: np.ndarray, *, check: bool = True, symmetrize: float = 0.0
    ) -> np.ndarray:
        """(13380, 3) body from PCA weights (metres), standing on the floor; ``symmetrize``
        in [0, 1] moves it that far towards its left-right symmetric part (the extrapolation
        correction, :meth:`correction`)."""
        s = self.space(sex)
        w = np.asarray(weights, dtype=np.float64).ravel()
        if check and w.size <= s.pca.k:
            z = np.abs(w) / s.pca.sd[: w.size]
            if np.any(z > MAX_SD):
                i = int(np.argmax(z))
                raise OutOfRangeError(
                    f"PCA weight {i} = {w[i]:g} is {z[i]:.1f} SD from the mean; this model "
                    f"supports at most {MAX_SD:g} SD (|w[{i}]| <= {MAX_SD * s.pca.sd[i]:.3g})",
                    feature=f"pca[{i}]", value=float(w[i]),
                    supported=[-MAX_SD * float(s.pca.sd[i]), MAX_SD * float(s.pca.sd[i])],
                )  # fmt: skip
        V = s.pca.reconstruct(w)
        if symmetrize > 0.0:
            V += symmetrize * (0.5 * (V[_mirror()] * np.array([-1.0, 1.0, 1.0]) - V))
        V[:, 1] -= V[:, 1].min()
        return V

    def correction(self, sex: str, features: dict[str, float] | None) -> float:
        """Strength in [0, 1] of the extrapolation corrections for ``features`` (smoothstep of
        their Mahalanobis distance from :data:`CORRECT_FROM` to :data:`CORRECT_FULL`)."""
        return _gate(self.space(sex).features.mahalanobis(features)) if features else 0.0

    def synthesize(
        self,
        sex: str,
        features: dict[str, float] | None = None,
        *,
        pca: np.ndarray | None = None,
        seed: int | None = None,
        exact_height: bool = True,
    ) -> np.ndarray:
        """A body of ``sex`` from features, from PCA weights or at random.

        Parameters
        ----------
        sex : ``"female"``, ``"male"`` or ``"joint"`` (then ``male`` may be a feature).
        features : name -> value (``height_m`` m, ``weight_kg`` kg, ``age`` years, ANSUR
            measurements m); missing ones take their most likely values given the rest.
        pca : (j,) PCA weights (metres), j <= k; instead of ``features``.
        seed : random body from the Gaussian, seeded; combined with ``features`` it draws
            the individual variation around the most likely body (conditional Gaussian
            residual spread).
        exact_height : with a ``height_m`` feature, scale the body about the floor so that its
            stature is exactly the requested one (a correction of a few millimetres).

        Extrapolation. Features within the accepted limits but beyond the training range are
        synthesised (:meth:`range_warnings` says so). Where the given features lie farther
        than :data:`CORRECT_FROM` (Mahalanobis) from the training bodies, two corrections fade
        in (in full at :data:`CORRECT_FULL`; below, bodies are the plain feature map's, so the
        bulk of the training range is unchanged): the body is made left-right symmetric (the
        map's weight/height slopes carry small asymmetric components which, extrapolated to
        BMI 55, lift one foot 10–13 mm off the floor) and, when its weight (volume x density)
        misses the requested one by more than :data:`WEIGHT_BAND`, it is moved further along
        the map's weight direction until it misses by that much (the plain map misses by up
        to 5–7 % at BMI 15 and 55). The PCA weights themselves are not damped:
        measured on stature 1.40–2.05 m x BMI 15–55, the plainly extrapolated bodies (|z| up
        to 9.8 SD) are smooth, plausible obese or thin bodies (rendered and checked: at most
        0.52 % of the faces flip against the mean body's normals, 99.8 % of the edges within
        0.27–2.5x their mean-body length, no NaN; ``tests/core/test_extrapolation.py``);
        clamping their Mahalanobis norm would only move the shape change into the weight
        correction, the same direction.

        Returns
        -------
        (13380, 3) float64 vertices, metres, floor at y = 0.
        """
        s = self.space(sex)
        if pca is not None:
            if features or seed is not None:
                raise ValueError("give either pca weights, or features and/or a seed")
            return self.reconstruct(sex, pca)
        features = dict(features or {})
        w = s.features.weights(features)
        if seed is not None:
            rng = np.random.default_rng(seed)
            sd = s.features.residual_sd if features else s.pca.sd
            w = w + rng.normal(size=s.pca.k) * sd
        t = self.correction(sex, features)
        height = float(features["height_m"]) if exact_height and "height_m" in features else None
        V = self._finish(sex, w, t, height)
        if t > 0.0 and "weight_kg" in features:
            V = self._match_weight(sex, w, t, height, float(features["weight_kg"]), V)
        return V

    def _finish(self, sex: str, w: np.ndarray, t: float, height: float | None) -> np.ndarray:
        """Body of weights ``w``: symmetrised by ``t`` (extrapolation), scaled about the floor
        to ``height`` (when given), standing on the floor."""
        V = self.reconstruct(sex, w, check=False, symmetrize=t)
        if height is not None:
            V *= height / body_height(V)
            V[:, 1] -= V[:, 1].min()
        return V

    def _match_weight(
        self, sex: str, w: np.ndarray, t: float, height: float | None, target: float,
        V: np.ndarray,
    ) -> np.ndarray:  # fmt: skip
        """Move ``w`` along the feature map's weight direction (secant on the step) until the
        finished body's weight misses ``target`` by at most :data:`WEIGHT_BAND` where the
        corrections are in full (by the plain map's miss where they are off, blended by ``t``
        between): bodies within the band are left as they are."""
        s = self.space(sex)
        dw = s.features.delta_weights(["weight_kg"], np.array([1.0]))

        def err(a: float, X: np.ndarray | None = None) -> tuple[float, np.ndarray]:
            X = self._finish(sex, w + a * dw, t, height) if X is None else X
            return body_volume(X) * s.density - goal, X

        plain = body_volume(V) * s.density
        band = WEIGHT_BAND * target
        kept = min(max(plain - target, -band), band)
        goal = target + kept + (1.0 - t) * (plain - target - kept)
        if goal == plain:
            return V
        a0, (f0, X0) = 0.0, err(0.0, V)
        a1 = float(np.cbrt(goal) - np.cbrt(plain))
        f1, X1 = err(a1)
        for _ in range(8):
            if abs(f1) < 1e-4 * goal or f1 == f0:
                break
            a0, a1, f0 = a1, a1 - f1 * (a1 - a0) / (f1 - f0), f1
            f1, X1 = err(a1)
        return X1 if abs(f1) <= abs(f0) else X0

    def range_warnings(self, sex: str, features: dict[str, float] | None) -> list[str]:
        """Warnings where a body of ``features`` is extrapolated beyond the training range
        (:meth:`core.shapespace.FeatureMap.range_warnings`); empty inside it."""
        return self.space(sex).features.range_warnings(dict(features or {}))

    def features_of(self, sex: str, V: np.ndarray) -> dict[str, float]:
        """A body's features: measured height and weight (volume x density), the rest the most
        likely given its PCA weights."""
        s = self.space(sex)
        V = _check_body(V)
        f = s.features.features(self.project(sex, V))
        if "height_m" in f:
            f["height_m"] = body_height(V)
        if "weight_kg" in f:
            f["weight_kg"] = body_volume(V) * s.density
        return f

    def edit(
        self,
        sex: str,
        V: np.ndarray,
        delta: dict[str, float],
        *,
        keep: tuple[str, ...] = KEEP_DEFAULT,
        exact: bool = True,
    ) -> np.ndarray:
        """Change a body's features, keeping what makes it individual (paper §5).

        The body's PCA weights move by ``Δf @ M`` (``Δf`` the change of the encoded features,
        e.g. of weight^(1/3) for ``weight_kg``), its residual (the part of ``V`` outside the
        space) is kept, and the displacement fades to zero on the ``keep`` parts (face/head and
        hands by default) so that they do not move. A ``height_m`` change moves them rigidly
        instead (each by the mean displacement the height change gives it): their shape is kept
        while they follow the taller or shorter body — a head held in place would cancel the
        change of stature.

        Parameters
        ----------
        sex : the space to edit in.
        V : (13380, 3) body, metres, template order, any rigid placement (returned in the same).
        delta : feature -> change in user units, e.g. ``{"weight_kg": 10}`` or
            ``{"height_m": 0.05}``.
        keep : template parts left in place (``core.template.Template.part_names``), or only
            translated for a ``height_m`` change; () for the plain paper edit.
        exact : for a ``weight_kg`` (or ``height_m``) change, scale the edit so that the
            reported weight (stature) changes by exactly the requested amount.

        Returns
        -------
        (13380, 3) float64 edited body, same frame as ``V``.
        """
        s = self.space(sex)
        V = _check_body(V)
        if not delta:
            return V.copy()
        Vm, R, t = to_model_frame(V, s.pca.mean.reshape(-1, 3))
        now = {"height_m": body_height(Vm), "weight_kg": body_volume(Vm) * s.density}
        names, d_enc = [], []
        after: dict[str, float] = {}
        for name, dv in delta.items():
            if name not in s.features.names:
                raise OutOfRangeError(
                    f"unknown feature {name!r}; this model edits {', '.join(s.features.names)}",
                    feature=name, accepted=list(s.features.names),
                )  # fmt: skip
            dv = float(dv)
            if not np.isfinite(dv):
                raise OutOfRangeError(f"delta of {name} must be finite", feature=name, value=dv)
            if name in now:
                new = now[name] + dv
                s.features.check_value(name, new)
                after[name] = new
                d_enc.append(float(encode(name, new) - encode(name, now[name])))
            elif name in CUBE_ROOT:
                raise OutOfRangeError(f"cannot edit {name} of this body", feature=name)
            else:
                d_enc.append(dv)
            names.append(name)
        if "weight_kg" in after:
            s.features.check_bmi({"height_m": after.get("height_m", now["height_m"]), **after})
        C = s.pca.components.astype(np.float64)
        D = (s.features.delta_weights(names, np.array(d_enc)) @ C).reshape(-1, 3)
        if keep:
            w = _keep_weights(tuple(keep), KEEP_BLEND_M)[:, None]
            follow = 0.0
            if "height_m" in names:
                i = names.index("height_m")
                Dh = s.features.delta_weights(["height_m"], np.array(d_enc[i : i + 1])) @ C
                follow = _follow_parts(tuple(keep), Dh.reshape(-1, 3))
            D = D * w + (1.0 - w) * follow
        scale = 1.0
        target = None
        if exact and "weight_kg" in delta:
            target = ("weight_kg", now["weight_kg"] + float(delta["weight_kg"]))
        elif exact and "height_m" in delta:
            target = ("height_m", now["height_m"] + float(delta["height_m"]))
        if target is not None:

            def value(a: float) -> float:
                X = Vm + a * D
                return body_volume(X) * s.density if target[0] == "weight_kg" else body_height(X)

            a0, f0 = 0.0, now[target[0]] - target[1]
            a1, f1 = 1.0, value(1.0) - target[1]
            for _ in range(20):  # secant on the edit's scale
                if abs(f1) < 1e-6 * max(1.0, abs(target[1])) or f1 == f0:
                    break
                a0, a1, f0 = a1, a1 - f1 * (a1 - a0) / (f1 - f0), f1
                f1 = value(a1) - target[1]
            scale = a1
        out = Vm + scale * D
        return from_model_frame(out, R, t)

    # ------------------------------------------------------------------ persistence

    def save(self, path: str | Path) -> None:
        """Write the model as one compressed ``.npz`` (components float32)."""
        arrays: dict[str, np.ndarray] = {}
        meta = {"format_version": FORMAT_VERSION, "metadata": self.metadata, "spaces": {}}
        for key, s in self.spaces.items():
            p = f"{key}/"
            arrays[p + "mean"] = s.pca.mean.astype(np.float32)
            arrays[p + "components"] = s.pca.components.astype(np.float32)
            arrays[p + "variances"] = s.pca.variances
            arrays[p + "fmap_M"] = s.features.M
            arrays[p + "fmap_mean"] = s.features.mean
            arrays[p + "fmap_cov"] = s.features.cov
            arrays[p + "fmap_residual_sd"] = (
                s.features.residual_sd if s.features.residual_sd is not None else np.zeros(s.pca.k)
            )
            meta["spaces"][key] = {
                "total_variance": s.pca.total_variance,
                "feature_names": list(s.features.names),
                "ranges": {n: list(r) for n, r in s.features.ranges.items()},
                "density": s.density,
                "n_bodies": s.n_bodies,
            }
        arrays["meta_json"] = np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)
        arrays["provenance"] = np.frombuffer(self.provenance.encode(), dtype=np.uint8)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        buf = io.BytesIO()
        np.savez_compressed(buf, **arrays)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_bytes(buf.getvalue())
        tmp.replace(path)


def _check_body(V: np.ndarray) -> np.ndarray:
    V = np.asarray(V, dtype=np.float64)
    n = load_template().n_vertices
    if V.shape != (n, 3):
        raise ValueError(f"body must have shape ({n}, 3) in template order, got {V.shape}")
    if not np.isfinite(V).all():
        raise ValueError("body has non-finite vertices")
    return V


def load_model(path: str | Path = DEFAULT_MODEL) -> ShapeModel:
    """Read a model written by :meth:`ShapeModel.save`."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            a = {k: z[k] for k in z.files}
        meta = json.loads(a["meta_json"].tobytes().decode())
    except (OSError, ValueError, KeyError) as e:
        raise ModelFormatError(f"cannot read shape model {path}: {e}", path=str(path)) from None
    if meta.get("format_version") != FORMAT_VERSION:
        raise ModelFormatError(
            f"shape model {path} has format {meta.get('format_version')}, expected {FORMAT_VERSION}"
        )
    spaces = {}
    for key, m in meta["spaces"].items():
        p = f"{key}/"
        var = a[p + "variances"].astype(np.float64)
        pca = PCA(a[p + "mean"].astype(np.float64), a[p + "components"], var, m["total_variance"])
        fmap = FeatureMap(
            names=tuple(m["feature_names"]), M=a[p + "fmap_M"], mean=a[p + "fmap_mean"],
            cov=a[p + "fmap_cov"], ranges={n: tuple(r) for n, r in m["ranges"].items()},
            residual_sd=a[p + "fmap_residual_sd"],
        )  # fmt: skip
        spaces[key] = Space(pca, fmap, float(m["density"]), int(m["n_bodies"]))
    return ShapeModel(spaces, meta.get("metadata", {}), a["provenance"].tobytes().decode())


@cache
def default_model() -> ShapeModel:
    """The committed default model ``core/assets/shape_model.npz`` (cached)."""
    return load_model(DEFAULT_MODEL)
