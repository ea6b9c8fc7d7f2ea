"""The bundled ANSUR II subset (``core/assets/ansur2/``) and its held-in/held-out split.

ANSUR II (U.S. Army 2012 anthropometric survey, public domain; Gordon et al. 2014,
NATICK/TR-15/007) development split, 53 of its columns (see ``core/assets/PROVENANCE.md``).
Rows are returned in **SI units**: lengths in metres, ``weightkg`` in kilograms, ``Age`` in years.

Split: a subject is *held out* when ``(subjectid * 2654435761) mod 2**32 < 0.2 * 2**32``
(Knuth's multiplicative hash: ~20 % of subjects, stable, independent of file order). Everything
trained (the MakeHuman solve's corrections, the shape models, the regression baselines) uses only
the held-in rows; benchmarks report on the held-out rows.
"""

from __future__ import annotations

import csv
from functools import cache
from pathlib import Path

import numpy as np

ANSUR_DIR = Path(__file__).resolve().parent.parent / "assets" / "ansur2"
SEXES = ("female", "male")
#: Columns that are not lengths in millimetres.
_NON_MM = {"subjectid", "weightkg", "Age", "DODRace", "Gender"}
HOLDOUT_FRACTION = 0.2


def is_held_out(subjectid: int | np.ndarray) -> np.ndarray:
    """Whether a subject belongs to the held-out split (bool, or bool array)."""
    h = (np.asarray(subjectid, dtype=np.uint64) * np.uint64(2654435761)) % np.uint64(2**32)
    return h < np.uint64(int(HOLDOUT_FRACTION * 2**32))


@cache
def load_ansur(sex: str) -> dict[str, np.ndarray]:
    """All bundled rows of one sex as column arrays in SI units.

    Parameters
    ----------
    sex : ``"female"`` or ``"male"``.

    Returns
    -------
    dict column -> (n,) float64 array (``subjectid`` and ``DODRace`` as int64); lengths in
    metres, ``weightkg`` kilograms, ``Age`` years; plus ``held_out`` (n,) bool.
    """
    if sex not in SEXES:
        raise ValueError(f"sex must be 'female' or 'male', got {sex!r}")
    with open(ANSUR_DIR / f"ansur2_{sex}_dev.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    out: dict[str, np.ndarray] = {}
    for c in rows[0]:
        if c == "Gender":
            continue
        a = np.array([float(r[c]) for r in rows])
        if c in ("subjectid", "DODRace"):
            out[c] = a.astype(np.int64)
        elif c == "weightkg":
            out[c] = a / 10.0
        elif c == "Age":
            out[c] = a
        else:
            out[c] = a / 1000.0
    out["held_out"] = is_held_out(out["subjectid"])
    return out


def split(sex: str, part: str) -> dict[str, np.ndarray]:
    """Rows of one sex in the ``"train"`` (held-in) or ``"test"`` (held-out) part."""
    if part not in ("train", "test"):
        raise ValueError(f"part must be 'train' or 'test', got {part!r}")
    d = load_ansur(sex)
    m = d["held_out"] if part == "test" else ~d["held_out"]
    return {k: v[m] for k, v in d.items()}


def stature_weight(d: dict[str, np.ndarray], i: int) -> dict[str, float]:
    """Row ``i``'s ``{"height_m", "weight_kg"}`` features (metres, kg)."""
    return {"height_m": float(d["stature"][i]), "weight_kg": float(d["weightkg"][i])}


def rows_in_range(fmap, d: dict[str, np.ndarray], rows: np.ndarray | None = None) -> np.ndarray:
    """Indices (of ``rows``, default all) whose stature and weight lie inside a feature map's
    training range (``fmap.in_training_range``: no extrapolation warning)."""
    ok = []
    for i in np.arange(len(d["stature"])) if rows is None else rows:
        if fmap.in_training_range(stature_weight(d, int(i))):
            ok.append(int(i))
    return np.array(ok, dtype=int)


def measurement_columns() -> list[str]:
    """Names of the bundled ANSUR length columns (metres after loading)."""
    d = load_ansur("female")
    return [c for c in d if c not in _NON_MM and c != "held_out"]
