"""The template body: MakeHuman base mesh (CC0), in metres, +Y up, +Z front, +X left, floor y=0.

Loaded once from ``core/assets/template.npz`` (made by ``core/assets/build.py``; see
``core/assets/PROVENANCE.md``) and cached.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import cache, cached_property
from pathlib import Path

import numpy as np

ASSET_DIR = Path(__file__).resolve().parent / "assets"

MASK_NAMES = ("ears", "fingers", "toes", "eyes_mouth", "bad_scan")


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

    def _extra(self, key: str) -> np.ndarray:
        try:
            return self.extras[key]
        except KeyError:
            raise KeyError(
                f"template asset has no {key!r}; rebuild it with `python -m core.assets.build`"
            ) from None

    # ------------------------------------------------------------------ symmetry, parts, masks

    @property
    def mirror(self) -> np.ndarray:
        """(13380,) int32: index of each vertex's left/right mirror vertex (itself on the midline).

        ``V[mirror] * [-1, 1, 1]`` reproduces ``V`` (the template is exactly symmetric in x).
        """
        return self._extra("mirror")

    @property
    def part(self) -> np.ndarray:
        """(13380,) int8 body-part label of each vertex, an index into :attr:`part_names`."""
        return self._extra("part")

    @cached_property
    def part_names(self) -> tuple[str, ...]:
        """Names of the coarse body parts (``_L`` = subject's left = +X)."""
        return tuple(str(n) for n in self._extra("part_names"))

    def part_mask(self, name: str) -> np.ndarray:
        """(13380,) bool: vertices of the body part ``name`` (one of :attr:`part_names`)."""
        if name not in self.part_names:
            raise ValueError(f"unknown body part {name!r}; valid: {', '.join(self.part_names)}")
        return self.part == self.part_names.index(name)

    def mask(self, name: str) -> np.ndarray:
        """(13380,) bool region mask: one of ``ears``, ``fingers``, ``toes``, ``eyes_mouth``,
        ``bad_scan`` (their union: regions that scanners capture badly)."""
        if name not in MASK_NAMES:
            raise ValueError(f"unknown mask {name!r}; valid: {', '.join(MASK_NAMES)}")
        return self._extra(f"mask_{name}")

    @property
    def bad_scan_mask(self) -> np.ndarray:
        """(13380,) bool: ears, fingers, toes, eye sockets and mouth (poorly scanned regions)."""
        return self._extra("mask_bad_scan")

    # ------------------------------------------------------------------ topology and geometry

    @cached_property
    def edges(self) -> np.ndarray:
        """(E, 2) int64 unique undirected edges of the triangle mesh, ``i < j``, sorted."""
        F = np.asarray(self.F, dtype=np.int64)
        E = np.vstack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
        E = np.unique(np.sort(E, axis=1), axis=0)
        E.setflags(write=False)
        return E

    def vertex_normals(self, V: np.ndarray | None = None) -> np.ndarray:
        """Area-weighted unit vertex normals of the template or of any body in template order.

        Parameters
        ----------
        V : (13380, 3) float vertices in metres; default the template's own.

        Returns
        -------
        (13380, 3) float64 unit normals (outward for the template's winding).
        """
        V = self.V if V is None else np.asarray(V, dtype=np.float64)
        if V.shape != self.V.shape:
            raise ValueError(f"V must have shape {self.V.shape}, got {V.shape}")
        from core.geometry import vertex_normals

        return vertex_normals(V, self.F)

    # ------------------------------------------------------------------ rig

    @cached_property
    def joint_names(self) -> tuple[str, ...]:
        """Bone names of the MakeHuman standard rig, parents before children."""
        return tuple(str(n) for n in self._extra("joint_names"))


def load_asset(name: str) -> dict[str, np.ndarray]:
    """The arrays of ``core/assets/<name>`` (an ``.npz``), read-only."""
    with np.load(ASSET_DIR / name) as z:
        arrays = {k: z[k] for k in z.files}
    for a in arrays.values():
        a.setflags(write=False)
    return arrays


@cache
def load_template() -> Template:
    """Load the committed template asset (cached; arrays are read-only)."""
    arrays = load_asset("template.npz")
    lm = json.loads((ASSET_DIR / "landmarks.json").read_text())
    V = arrays.pop("vertices")
    F = arrays.pop("faces")
    return Template(V=V, F=F, landmarks={k: int(v) for k, v in lm.items()}, extras=arrays)
