"""Derive the measurement landmarks that replace CAESAR landmarks misplaced on the template.

The canonical landmark table (core/assets/landmarks.json) names template vertices for marker
files and registration; two of its points sit on the template well below the bony landmark the
ANSUR II tape or anthropometer finds, which biases every height measured from them:

* ``Iliocristale`` (top of the iliac crest, mid-axillary line): on the template it lies ~20 mm
  *below* the navel (Omphalion); in ANSUR II it is 5-15 mm *above* it (held-in means).
* ``Femoral_lateral_epicondyle``: on the template ~20 mm *below* mid-patella; in ANSUR II
  3-17 mm *above* it.

For each, this script measures the offset (ANSUR held-in mean of the landmark height minus its
reference height, minus the same on the shape model's mean bodies at the ANSUR mean stature and
weight), averages it over the sexes and moves, per side, the canonical vertex up the skin by that
offset (scaled to the template's stature: on the horizontal section at the new height, same
azimuth), stored as a triangle and barycentric weights. The result is
:data:`core.measure.landmarks.MEASUREMENT_LANDMARKS`; the canonical table is left alone (marker
files are named against it).

Run: ``python -m bench.measure_landmarks [MODEL]`` (the uncalibrated model of the training
pipeline by default is what the offsets were derived on; any model gives similar numbers).
"""

from __future__ import annotations

import sys

import numpy as np

#: landmark stem -> the reference measurement its height is compared with, and the pair of
#: ANSUR columns (landmark height, reference height).
PAIRS = {
    "Iliocristale": ("iliocristaleheight", "waistheightomphalion"),
    "Femoral_lateral_epicondyle": ("lateralfemoralepicondyleheight", "kneeheightmidpatella"),
}


def surface_point(
    V: np.ndarray, F: np.ndarray, target: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The closest point of a mesh to ``target``: (3,) triangle vertex indices and (3,)
    barycentric weights."""
    from core.geometry import closest_point_on_triangles

    A, B, C = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    P = closest_point_on_triangles(np.broadcast_to(target, A.shape).copy(), A, B, C)
    t = int(np.argmin(np.linalg.norm(P - target, axis=1)))
    T = np.stack([A[t], B[t], C[t]], 1)  # (3, 3): columns are the corners
    M = np.vstack([T, np.ones(3)])
    w = np.clip(np.linalg.lstsq(M, np.append(P[t], 1.0), rcond=None)[0], 0.0, None)
    w = w / w.sum()
    return F[t].astype(int), w


def on_section(tpl, i0: int, dz: float, side: str) -> np.ndarray:
    """The surface point ``dz`` metres above template vertex ``i0`` along the skin: on the
    horizontal section at that height (of the trunk, or of that side's leg for a knee
    landmark), at the same azimuth about the section's centre as the vertex."""
    from core.measure.body import _topologies
    from core.measure.sections import plane_section

    topos = _topologies()
    knee = tpl.part_mask(f"shin_{side}")[i0] or tpl.part_mask(f"thigh_{side}")[i0]
    topo = topos.parts(f"thigh_{side}", f"shin_{side}") if knee else topos.trunk()
    p0 = tpl.V[i0]
    y = p0[1] + dz
    P = plane_section(tpl.V, topo, np.array([0.0, y, 0.0]), np.array([0.0, 1.0, 0.0])).points
    if knee:  # the loop of this leg only
        P = P[np.sign(P[:, 0]) == np.sign(p0[0])]
    c0 = plane_section(tpl.V, topo, p0, np.array([0.0, 1.0, 0.0])).points
    if knee:
        c0 = c0[np.sign(c0[:, 0]) == np.sign(p0[0])]
    centre, centre0 = P[:, [0, 2]].mean(0), c0[:, [0, 2]].mean(0)
    a0 = np.arctan2(*(p0[[0, 2]] - centre0)[::-1])
    a = np.arctan2(P[:, 2] - centre[1], P[:, 0] - centre[0])
    return P[int(np.argmin(np.abs(np.angle(np.exp(1j * (a - a0))))))]


def derive(model_path: str | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    from core.measure import measure
    from core.shapespace import default_model, load_model
    from core.shapespace.ansur import split
    from core.template import load_template

    model = load_model(model_path) if model_path else default_model()
    tpl = load_template()
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for stem, (col, ref) in PAIRS.items():
        deltas = []
        for sex in ("female", "male"):
            d = split(sex, "train")
            ansur = float(np.mean(d[col] - d[ref]))
            V = model.synthesize(
                sex,
                {
                    "height_m": float(np.mean(d["stature"])),
                    "weight_kg": float(np.mean(d["weightkg"])),
                },
            )
            # the canonical landmark's height (right side, as measured), the reference as measured
            h = float(V[tpl.landmarks[f"{stem}_R"], 1] - V[:, 1].min())
            mod = h - measure(V, names=[ref])[ref]
            deltas.append((ansur - mod) / float(np.mean(d["stature"])))
            print(f"{stem:28s} {sex:6s}: ANSUR {col} - {ref} = {1000 * ansur:6.1f} mm, "
                  f"model (canonical landmark) {1000 * mod:6.1f} mm")  # fmt: skip
        dz = float(np.mean(deltas)) * float(np.ptp(tpl.V[:, 1]))
        for side in ("L", "R"):
            name = f"{stem}_{side}"
            i0 = tpl.landmarks[name]
            target = on_section(tpl, i0, dz, side)
            tri, w = surface_point(tpl.V, tpl.F, target)
            p = w @ tpl.V[tri]
            out[name] = (tri, w)
            print(f"  {name}: vertex {i0} -> surface point {[int(t) for t in tri]} "
                  f"{np.round(w, 4).tolist()} ({1000 * dz:.1f} mm up asked, "
                  f"{1000 * (p[1] - tpl.V[i0, 1]):.1f} mm up, "
                  f"{1000 * np.linalg.norm(p - target):.1f} mm from the asked point)")  # fmt: skip
    return out


if __name__ == "__main__":
    res = derive(sys.argv[1] if len(sys.argv) > 1 else None)
    print("MEASUREMENT_LANDMARKS = {")
    for k, (tri, w) in res.items():
        print(f"    {k!r}: (({', '.join(str(int(t)) for t in tri)}), "
              f"({', '.join(f'{x:.4f}' for x in w)})),")  # fmt: skip
    print("}")
