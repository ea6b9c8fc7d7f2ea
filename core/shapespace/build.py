"""Build a shape model from a folder of registered bodies and a table of subject features.

``build_model(fits_dir, features_csv, out)``: every ``*.npz`` (array ``vertices``, as written by
the training pipeline or any ``np.savez``) or ``*.ply`` / ``*.obj`` (a mesh in template order)
in ``fits_dir`` is one body; its file stem is its ``id`` in the feature table. The table is a CSV
with a header: ``id``, ``sex`` (``female``/``male``) and numeric feature columns -- ``height_m``,
``weight_kg``, ``age`` and any measurement (metres, e.g. ANSUR II names). A lab can build its own
space from its own scans: fit them (``bodyspace fit``), list who is who, build.
"""

from __future__ import annotations

import csv
import datetime as _dt
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from core.shapespace.errors import ModelFormatError
from core.shapespace.features import fit_feature_map
from core.shapespace.model import SPACES, ShapeModel, Space, body_volume
from core.shapespace.pca import fit_pca, to_model_frame
from core.template import load_template

#: Features used when present in the table (in this order); ``None`` in ``build_model`` means these.
DEFAULT_FEATURES = (
    "height_m", "weight_kg", "age", "chestcircumference", "waistcircumference",
    "buttockcircumference",
)  # fmt: skip
MESH_SUFFIXES = (".npz", ".ply", ".obj")


def read_body(path: str | Path) -> np.ndarray:
    """One body in template order: (13380, 3) float64 vertices, metres, from ``*.npz`` (array
    ``vertices``), ``*.ply`` or ``*.obj`` (millimetres are detected by the height and converted).

    Raises
    ------
    ModelFormatError
        unreadable, not a body in template order, or an ``.npz`` without ``vertices``.
    """
    f = Path(path)
    n = load_template().n_vertices
    try:
        if f.suffix.lower() == ".npz":
            with np.load(f, allow_pickle=False) as z:
                if "vertices" not in z.files:
                    raise ModelFormatError(f"{f.name} has no 'vertices' array", path=str(f))
                V = np.asarray(z["vertices"], dtype=np.float64)
        else:
            from core.io import read_mesh

            V = np.asarray(read_mesh(f).V, dtype=np.float64)
    except ModelFormatError:
        raise
    except Exception as e:
        raise ModelFormatError(f"cannot read body {f.name}: {e}", path=str(f)) from None
    if V.shape != (n, 3):
        raise ModelFormatError(
            f"{f.name}: a body must have {n} vertices in template order, got {V.shape}",
            path=str(f),
        )
    if 1000.0 < np.ptp(V[:, 1]) < 2500.0:  # millimetres
        V = V / 1000.0
    return V


def read_bodies(fits_dir: str | Path) -> dict[str, np.ndarray]:
    """All bodies in a folder (:func:`read_body`): id (file stem) -> (13380, 3) vertices, metres;
    ``.npz`` files without ``vertices`` are skipped."""
    fits_dir = Path(fits_dir)
    if not fits_dir.is_dir():
        raise ModelFormatError(f"{fits_dir} is not a folder of fitted bodies", path=str(fits_dir))
    out: dict[str, np.ndarray] = {}
    for f in sorted(fits_dir.iterdir()):
        if f.suffix.lower() not in MESH_SUFFIXES or f.name.endswith(".tmp.npz"):
            continue
        if f.suffix.lower() == ".npz":
            try:
                with np.load(f, allow_pickle=False) as z:
                    body = "vertices" in z.files
            except Exception:
                body = True  # read_body says what is wrong
            if not body:
                continue
        out[f.stem] = read_body(f)
    if not out:
        raise ModelFormatError(f"no bodies (*.npz with 'vertices', *.ply, *.obj) in {fits_dir}")
    return out


def read_features(features_csv: str | Path) -> dict[str, dict[str, float | str]]:
    """The feature table: id -> {"sex": ..., feature: float (nan when empty)}."""
    path = Path(features_csv)
    try:
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
    except OSError as e:
        raise ModelFormatError(f"cannot read feature table {path}: {e}", path=str(path)) from None
    if not rows or "id" not in rows[0] or "sex" not in rows[0]:
        raise ModelFormatError(f"{path}: the feature table needs a header with 'id' and 'sex'")
    out: dict[str, dict[str, float | str]] = {}
    for i, r in enumerate(rows, start=2):
        sex = (r.get("sex") or "").strip().lower()
        if sex not in ("female", "male"):
            raise ModelFormatError(f"{path} line {i}: sex must be 'female' or 'male', got {sex!r}")
        rec: dict[str, float | str] = {"sex": sex}
        for k, v in r.items():
            if k in ("id", "sex") or k is None:
                continue
            try:
                rec[k] = float(v) if v not in ("", None) else float("nan")
            except ValueError:
                raise ModelFormatError(f"{path} line {i}: {k}={v!r} is not a number") from None
        out[r["id"]] = rec
    return out


def align_bodies(bodies: Sequence[np.ndarray], iterations: int = 2) -> np.ndarray:
    """Generalised Procrustes (rigid, no scale): bodies (N, n, 3) rotated onto their mean,
    standing on the floor and horizontally centred (see ``to_model_frame``)."""
    X = np.stack([to_model_frame(V)[0] for V in bodies])
    for _ in range(iterations):
        ref = X.mean(0)
        X = np.stack([to_model_frame(V, ref)[0] for V in X])
    return X


def _space(
    X: np.ndarray, F: np.ndarray, names: list[str], weights_kg: np.ndarray, variance: float
) -> Space:
    pca = fit_pca(X, variance=variance)
    W = (X.reshape(len(X), -1) - pca.mean) @ pca.components.T.astype(np.float64)
    fmap = fit_feature_map(names, F, W, pca.variances)
    vol = np.array([body_volume(V) for V in X])
    ok = np.isfinite(weights_kg)
    density = float(weights_kg[ok] @ vol[ok] / (vol[ok] @ vol[ok])) if ok.any() else 1010.0
    return Space(pca=pca, features=fmap, density=density, n_bodies=len(X))


def build_model(
    fits_dir: str | Path,
    features_csv: str | Path,
    out: str | Path | None = None,
    *,
    features: Sequence[str] | None = None,
    variance: float = 0.98,
    spaces: Sequence[str] = SPACES,
    provenance: str = "",
    metadata: dict | None = None,
) -> ShapeModel:
    """Build (and optionally save) a shape model.

    Parameters
    ----------
    fits_dir : folder of bodies in template order (``*.npz`` with ``vertices``, ``*.ply``,
        ``*.obj``; metres or millimetres, any rigid placement).
    features_csv : table with ``id``, ``sex`` and feature columns (see module docstring).
    out : where to write the model ``.npz`` (None: do not write).
    features : feature columns to map (default: those of :data:`DEFAULT_FEATURES` the table
        has for every body). ``weight_kg`` is encoded as its cube root.
    variance : share of the variance the kept components explain (per space).
    spaces : which of ``"female"``, ``"male"``, ``"joint"`` to build (a sex with fewer than
        ``len(features) + 3`` bodies is skipped).
    provenance, metadata : stored with the model.

    Returns
    -------
    ShapeModel.
    """
    bodies = read_bodies(fits_dir)
    table = read_features(features_csv)
    ids = [i for i in bodies if i in table]
    missing = [i for i in bodies if i not in table]
    if not ids:
        raise ModelFormatError(
            f"none of the {len(bodies)} bodies in {fits_dir} has a row in {features_csv} "
            f"(ids are file stems, e.g. {next(iter(bodies))!r})"
        )
    if features is None:
        features = [
            n for n in DEFAULT_FEATURES
            if all(np.isfinite(float(table[i].get(n, np.nan))) for i in ids)  # type: ignore[arg-type]
        ]  # fmt: skip
    features = list(features)
    for n in features:
        bad = [i for i in ids if not np.isfinite(float(table[i].get(n, np.nan)))]  # type: ignore[arg-type]
        if bad:
            raise ModelFormatError(f"feature {n!r} is missing for {len(bad)} bodies, e.g. {bad[0]}")
    X = align_bodies([bodies[i] for i in ids])
    sex = np.array([table[i]["sex"] for i in ids])
    F = np.array([[float(table[i][n]) for n in features] for i in ids])  # type: ignore[arg-type]
    wkg = np.array([float(table[i].get("weight_kg", np.nan)) for i in ids])  # type: ignore[arg-type]
    built: dict[str, Space] = {}
    skipped = {}
    for key in spaces:
        if key == "joint":
            m = np.ones(len(ids), dtype=bool)
            names = [*features, "male"]
            Fk = np.concatenate([F, (sex == "male")[:, None].astype(float)], axis=1)
            if len(set(sex)) < 2:
                skipped[key] = "needs both sexes"
                continue
        else:
            m = sex == key
            names, Fk = features, F
        if m.sum() < len(names) + 3:
            skipped[key] = f"{int(m.sum())} bodies"
            continue
        built[key] = _space(X[m], Fk[m], list(names), wkg[m], variance)
    if not built:
        raise ModelFormatError(f"too few bodies to build any space: {skipped}")
    meta = {
        "created": _dt.date.today().isoformat(),
        "fits_dir": Path(fits_dir).name,
        "variance_share": variance,
        "features": features,
        "bodies": {k: s.n_bodies for k, s in built.items()},
        "components": {k: s.pca.k for k, s in built.items()},
        "bodies_without_features": len(missing),
        "skipped_spaces": skipped,
        **(metadata or {}),
    }
    model = ShapeModel(built, meta, provenance)
    if out is not None:
        model.save(out)
    return model
