"""The MakeHuman (CC0) shape-target library committed as ``core/assets/targets.npz``.

Made by ``core/assets/build_targets.py``. A target is a sparse displacement field over template
vertices, in metres, on our axes (+Y up, +Z front, +X the subject's left).
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np

ASSET = Path(__file__).resolve().parent.parent / "assets" / "targets.npz"
N_VERTICES = 13380


class TargetLibrary:
    """Named sparse displacement targets over the template's 13380 vertices."""

    def __init__(
        self,
        names: np.ndarray,
        offsets: np.ndarray,
        indices: np.ndarray,
        deltas: np.ndarray,
        scale: float,
    ) -> None:
        self._pos = {str(n): i for i, n in enumerate(names)}
        self._off = offsets
        self._idx = indices.astype(np.int64)
        self._d = deltas
        self._scale = float(scale)

    @property
    def names(self) -> list[str]:
        """All target names, e.g. ``"torso/measure-waist-circ-incr"``."""
        return list(self._pos)

    def __contains__(self, name: str) -> bool:
        return name in self._pos

    def sparse(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Return ``(idx (k,) int64, delta (k, 3) float64 metres)`` of target ``name``."""
        if name not in self._pos:
            raise KeyError(f"unknown target {name!r}")
        t = self._pos[name]
        a, b = self._off[t], self._off[t + 1]
        return self._idx[a:b], self._d[a:b].astype(np.float64) * self._scale

    def dense(self, name: str) -> np.ndarray:
        """Return target ``name`` as a dense (13380, 3) float64 displacement in metres."""
        out = np.zeros((N_VERTICES, 3))
        idx, d = self.sparse(name)
        out[idx] = d
        return out

    def combine(self, weights: dict[str, float]) -> np.ndarray:
        """Weighted sum of targets: (13380, 3) float64 metres. Zero weights are skipped."""
        out = np.zeros((N_VERTICES, 3))
        for name, w in weights.items():
            if w == 0.0:
                continue
            idx, d = self.sparse(name)
            out[idx] += w * d
        return out


@cache
def load_targets(path: Path = ASSET) -> TargetLibrary:
    """Load the committed target library (cached)."""
    with np.load(path) as z:
        return TargetLibrary(z["names"], z["offsets"], z["indices"], z["deltas"], float(z["scale"]))
