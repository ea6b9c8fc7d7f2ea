"""Measurement landmarks that replace misplaced CAESAR landmarks of the template.

The canonical landmark table (``core/assets/landmarks.json``, one template vertex per CAESAR
landmark) is what marker files are named against and what registration uses; it stays as it
is. Two of its points sit well below the bony landmark an ANSUR II measurer palpates, which
biased every height measured from them by ~30 mm:

* ``Iliocristale`` (top of the iliac crest, mid-axillary line): ~20 mm *below* the navel on the
  template, 5-15 mm *above* it in ANSUR II (held-in means, women / men);
* ``Femoral_lateral_epicondyle``: ~20 mm *below* mid-patella on the template, 3-17 mm
  *above* it in ANSUR II.

Measurements use these surface points instead: each is the canonical vertex moved 31.2 mm up
the skin (on the template; the mean of the sexes' offsets), stored as a triangle of template
vertices and barycentric weights so that it follows any body in template order. Derived by
``python -m bench.measure_landmarks`` (see there); numbers in bench/results.
"""

from __future__ import annotations

import numpy as np

#: name -> ((3 template vertex indices), (3 barycentric weights)).
MEASUREMENT_LANDMARKS: dict[str, tuple[tuple[int, int, int], tuple[float, float, float]]] = {
    "Iliocristale_L": ((10703, 10704, 10717), (0.0500, 0.0000, 0.9500)),
    "Iliocristale_R": ((4047, 4061, 4062), (0.0500, 0.0000, 0.9500)),
    "Femoral_lateral_epicondyle_L": ((11248, 11245, 11226), (0.0000, 0.0955, 0.9045)),
    "Femoral_lateral_epicondyle_R": ((4630, 4608, 4627), (0.0000, 0.9045, 0.0955)),
}


def landmark_point(V: np.ndarray, name: str, canonical: dict[str, int]) -> np.ndarray:
    """(3,) position of landmark ``name`` on body ``V`` (13380, 3) for measuring: the
    measurement landmark when there is one, else the canonical vertex."""
    if name in MEASUREMENT_LANDMARKS:
        tri, w = MEASUREMENT_LANDMARKS[name]
        return np.asarray(w) @ V[list(tri)]
    return V[canonical[name]]
