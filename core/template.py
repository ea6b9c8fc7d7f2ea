"""The template body: MakeHuman base mesh (CC0), in metres, +Y up, +Z front, +X left, floor y=0.

Loaded once from ``core/assets/template.npz`` (made by ``core/assets/build.py``) and cached.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numpy as np

ASSET_DIR = Path(__file__).resolve().parent / "assets"


@dataclass(frozen=True)
class Template:
    """The template body in template vertex order.

    Attributes
    ----------
    V : (13380, 3) float64 vertices, metres.
    F : (26756, 3) int32 triangles.
    landmarks : name -> vertex index (62 CAESAR landmarks).
    extras : any further arrays stored in the asset (mirror map, segmentation, masks, rig).
    """

    V: np.ndarray
    F: np.ndarray
    landmarks: dict[str, int]
    extras: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n_vertices(self) -> int:
        return len(self.V)


@cache
def load_template() -> Template:
    """Load the committed template asset (cached; arrays are read-only)."""
    with np.load(ASSET_DIR / "template.npz") as z:
        arrays = {k: z[k] for k in z.files}
    for a in arrays.values():
        a.setflags(write=False)
    lm = json.loads((ASSET_DIR / "landmarks.json").read_text())
    V = arrays.pop("vertices")
    F = arrays.pop("faces")
    return Template(V=V, F=F, landmarks={k: int(v) for k, v in lm.items()}, extras=arrays)
