"""Seat contact: the soft tissue a seated body rests on, flattened on a flat seat.

Linear blend skinning (:func:`core.rig.pose_body`) turns the buttocks and thighs rigidly about
the hips, so a posed body keeps the rounded, unloaded underside of a standing body and "sits"
on its lowest point. A seated person's weight compresses the tissue under the ischial
tuberosities (IT) instead. This module models that compression from published measurements,
not from the benchmark it is checked against (``bench.seated``):

- **Unloaded tissue under the IT at 90 deg hip flexion** ``T0 = 73.8 mm`` (mean; SD 9.0 mm,
  11 healthy adults, MRI, thickness of muscle + fat + skin from the IT tip to the skin,
  perpendicular to the seat): Makhsous et al. 2011, *Use of MRI images to measure tissue
  thickness over the ischial tuberosity at different hip flexion*, Clin. Anat. 24(5):638-645,
  doi:10.1002/ca.21119. The body's IT level is taken ``T0`` above the lowest point of its
  posed (unloaded) buttocks -- the body's own seat geometry -- and never above its hip joints.
- **Compression under the sitting load** ``C = 0.45``: the same study found the tissue over the
  IT "decreased by nearly half" from non-weight-bearing to weight-bearing 90 deg hip flexion,
  muscle (the tissue that deformed most) by 46.2 +- 7.9 %; 0.45 reads "nearly half" for the
  whole column (fat and skin deform less than muscle). Loaded thickness ``(1 - C) T0 =
  40.6 mm``, the order of the loaded bulk tissue thickness under the IT of Sonenblum et al.
  2020, *Seated buttocks anatomy and its impact on biomechanical risk*, J. Tissue Viability
  29(2):69-75 (5.6-32.1 mm on 3" foam, mostly fat, largest in able-bodied sitters).

So the seat plane lies ``(1 - C) T0`` below the IT estimate, i.e. ``C T0 = 33.2 mm`` above
the posed body's lowest buttock point, for every body (the literature gives a population mean,
not a per-body thickness: a body-specific bone level would need a pelvis the rig lacks).

Deformation: on the seat region (skin weight not on the lower legs or arms, fading to nothing
between 10 cm behind the knee joints and the knee joints, the seat's front edge) a vertex at
height ``s`` above the plane moves up by ``d(s)``: ``-s`` when ``s <= -a`` (pressed onto the
plane), ``a (1 - (s + a) / (w + a)) ** ((w + a) / a)`` for ``-a < s < w`` (C1 at both ends, slope
>= -1 so heights keep their order: no fold), 0 above ``w = (1 - C) T0`` (the bone level: nothing
at or above the IT moves). ``a = 10 mm`` only rounds the contact's edge (it does not move the
plane). Volume is not conserved (no sideways bulge).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from core.rig import Rig, load_rig

#: Unloaded soft tissue under the IT at 90 deg hip flexion, m (Makhsous et al. 2011).
IT_TISSUE_UNLOADED = 0.0738
#: Fraction of it compressed by the sitting load (Makhsous et al. 2011: "nearly half").
IT_COMPRESSION = 0.45
#: Width (m) of the rounded edge of the contact below the plane (smoothing only).
CONTACT_EDGE = 0.010
#: The seat ends this far (m) behind the knee joints, fading to nothing at them.
SEAT_FRONT = 0.10
#: sin 45 deg: seat contact needs both thighs forward and within 45 deg of horizontal.
SEAT_THIGH = float(np.sin(np.radians(45.0)))
#: Postures that have a seat (seat contact on by default for them).
SEATED_POSTURES = ("seated", "driving")


@dataclass(frozen=True)
class SeatContact:
    """What :func:`seat_contact` did: heights in the posed body's frame, metres.

    plane : seat plane height ``y``.
    it_level : the ischial tuberosity estimate's height (``plane + (1 - C) T0``).
    lift : how far the lowest buttock point moved up (``C T0`` unless capped at the hips).
    hip_to_it : hip joint centres' mean height minus ``it_level`` (> 0: the IT below the hips).
    n_contact : vertices pressed onto the plane.
    """

    plane: float
    it_level: float
    lift: float
    hip_to_it: float
    n_contact: int


def _region_bones(rig: Rig) -> np.ndarray:
    """(J,) bool: bones whose skin is not the seat's (lower legs and feet, arms and hands)."""
    off = np.zeros(rig.n_joints, dtype=bool)
    for b in ("lowerleg01.L", "lowerleg01.R", "clavicle.L", "clavicle.R"):
        off[[rig.index(b), *rig.descendants(b)]] = True
    return off


def seat_region(rig: Rig | None = None) -> np.ndarray:
    """(n,) float in [0, 1]: how much of each vertex's skin (the GLB's 4 influences) is on the
    trunk, pelvis and thighs -- 1 on the buttocks and thighs, 0 on calves, feet and arms."""
    rig = rig or load_rig()
    idx, w4 = rig.skin_top4()
    rho = 1.0 - (w4.astype(np.float64) * _region_bones(rig)[idx]).sum(axis=1)
    rho[rho < 1e-6] = 0.0  # float32 weights sum to 1 within ~1e-7
    rho[rho > 1.0 - 1e-6] = 1.0
    return rho


def seat_weights(P: np.ndarray, joints: np.ndarray, *, rig: Rig | None = None) -> np.ndarray:
    """(n,) float in [0, 1]: how fully each vertex of the posed body ``P`` (n, 3) rests on the
    seat -- :func:`seat_region`, faded out (smoothstep) from ``SEAT_FRONT`` behind the posed knee
    joints (``joints`` (J, 3)) to the knees: the seat's front edge."""
    rig = rig or load_rig()
    knee_z = joints[[rig.index("lowerleg01.L"), rig.index("lowerleg01.R")], 2].mean()
    x = np.clip((knee_z - P[:, 2]) / SEAT_FRONT, 0.0, 1.0)
    return seat_region(rig) * x * x * (3.0 - 2.0 * x)


def contact_lift(s: np.ndarray, *, a: float, w: float) -> np.ndarray:
    """Upward displacement ``d(s)`` (m) of a seat-region point ``s`` m above the plane (see the
    module docstring): ``s + d(s) = 0`` for ``s <= -a``, 0 for ``s >= w``, C1, ``d' >= -1``."""
    s = np.asarray(s, dtype=np.float64)
    L = w + a
    u = np.clip((s + a) / L, 0.0, 1.0)
    return np.where(s <= -a, -s, a * (1.0 - u) ** (L / a))


def seat_contact(
    P: np.ndarray,
    joints: np.ndarray,
    *,
    rig: Rig | None = None,
    tissue: float = IT_TISSUE_UNLOADED,
    compression: float = IT_COMPRESSION,
) -> tuple[np.ndarray, SeatContact]:
    """Rest a posed body on a flat, horizontal seat: flatten the tissue under its buttocks.

    Parameters
    ----------
    P : (13380, 3) posed body (e.g. :func:`core.transfer.rig.pose` with ``floor=False``),
        template order, metres, +Y up.
    joints : (J, 3) the posed joint (head) positions, metres.
    tissue, compression : unloaded tissue under the IT (m) and the fraction the sitting load
        compresses (defaults: the literature values of the module docstring).

    Returns
    -------
    (13380, 3) float64 vertices (only ``y`` changes, only on the seat region below the IT
    level), and a :class:`SeatContact`.

    Raises
    ------
    ValueError
        when the posture has no seat: a thigh (hip -> knee joint) not forward or more than
        45 deg from horizontal.
    """
    rig = rig or load_rig()
    P = np.asarray(P, dtype=np.float64)
    if P.shape != (rig.n_vertices, 3):
        raise ValueError(f"P must be ({rig.n_vertices}, 3) in template order, got {P.shape}")
    if not 0.0 < tissue < 0.5 or not 0.0 <= compression < 1.0:
        raise ValueError(f"tissue {tissue} m / compression {compression} out of range")
    rho = seat_weights(P, joints, rig=rig)
    seat = rho == 1.0
    hips = joints[[rig.index("upperleg01.L"), rig.index("upperleg01.R")]]
    thighs = joints[[rig.index("lowerleg01.L"), rig.index("lowerleg01.R")]] - hips
    hip = float(hips[:, 1].mean())
    sitting = np.all(
        (thighs[:, 2] > 0) & (np.abs(thighs[:, 1]) <= SEAT_THIGH * np.linalg.norm(thighs, axis=1))
    )
    if not sitting or not seat.any() or (low := float(P[seat, 1].min())) >= hip:
        raise ValueError(
            "no seat to rest on: seat contact needs both thighs forward and within 45 deg of "
            "horizontal (a seated posture); use seat_contact false"
        )
    t0 = min(tissue, hip - low)  # the bone is not above the hip joints
    loaded = (1.0 - compression) * t0
    plane = low + compression * t0
    s = P[:, 1] - plane
    d = contact_lift(s, a=CONTACT_EDGE, w=loaded)
    out = P.copy()
    out[:, 1] += rho * d
    info = SeatContact(
        plane=plane,
        it_level=plane + loaded,
        lift=compression * t0,
        hip_to_it=hip - (plane + loaded),
        n_contact=int((seat & (s <= -CONTACT_EDGE)).sum()),  # exactly on the plane
    )
    return out, info
