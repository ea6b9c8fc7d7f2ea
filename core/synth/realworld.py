"""Bodies and postures outside the body prior's family (seeded test material, numpy/scipy only).

The fitter's prior is the MakeHuman target space in MakeHuman's A-pose. Real people are not: this
module makes bodies that no combination of MakeHuman targets reproduces and poses them the way
real scanning protocols do, always in **template vertex order**, so the truth of every vertex is
known. Used by :mod:`core.synth.scanner_outputs` (what scanner software delivers) and
``bench/realworld.py``.

How a body is made (:func:`off_model_body`), decisions and magnitudes:

1. **Stature and weight** from a held-out ANSUR II row of the chosen sex (``core/assets/ansur2``);
   in 40 % of bodies the row's weight is replaced by a BMI drawn uniformly on [15, 55] (civilian
   extremes ANSUR's soldiers do not reach). Target volume = weight / 1000 kg m⁻³ (whole-body
   envelope density incl. lung air, ~1.0).
2. **A MakeHuman start** (:func:`core.synth.bodies.shape_body`) at that stature, its weight
   modifier set from the BMI (15 → 0, 25 → 0.5, 40 → 1): the start is *in* the prior's space.
3. **Smooth random fields no MakeHuman target makes** (all on the rest pose, weights smoothed over
   the template graph so there are no creases):

   - regional fat along the vertex normal, each amplitude uniform in the range given, metres:
     belly (front abdomen below the navel, -0.01..0.06, with a downward sag of half the amplitude
     squared-weighted = overhang), buttocks (-0.01..0.04, sagging), flanks/"love handles"
     (0..0.03), thighs (inner-thigh weighted, -0.01..0.03), upper arms (back weighted, -0.005..
     0.02), breasts (women 0..0.03, men 0..0.015, sagging), back of neck (0..0.015);
   - a global layer along the normal (head, hands and feet at 15 %) solved by bisection so the
     body's volume matches the target volume (clipped to [-12, +60] mm);
   - shoulder breadth: each arm with its shoulder (rig skin weights of ``clavicle``'s subtree)
     moved ±0..3 cm sideways;
   - bone lengths through the rig: upper arm, forearm, thigh and shank each lengthened or
     shortened by up to ±7 % (the bone's own skin weights stretch, the subtree below moves).
4. Floor reset to y = 0 (truth: lowest vertex).

Postures (:func:`posture`, via :func:`core.rig.pose_body`, LBS with the MakeHuman rig): arms 5–60°
from the body (the template's rest A-pose is measured from its joints, ~41°), elbows flexed 0–30° in
all (the rest pose is more flexed: the elbow is straightened), hands open (fingers spread 0–10°) or
fisted (fingers curled 55–80° per joint, thumb 30°), optionally arms touching the torso (abduction
lowered until a forearm or hand meets the torso, hips or thighs within 2 mm: a closed mesh then has
a handle), feet 0–40 cm apart (gap between the medial malleoli), slight lean (spine ±5° forward, ±3°
sideways), neck flexion 0–20°, forward head (neck flexed 0–15° and the head counter-rotated by as
much), head yaw ±15° and roll ±5°. The wide-arms protocols (T-pose and near it: animation and
photogrammetry capture) draw the arms 60–90° from the body instead (:data:`WIDE_ARM_RANGE`); the
turned-palms protocols turn both forearms 45–100° about their own axes, palms forwards or backwards
(:data:`PALM_TWIST_RANGE`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cache

import numpy as np
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

from core.rig import (
    axis_angle,
    bone_transforms,
    finger_rotations,
    joint_positions,
    load_rig,
    pose_body,
)
from core.shapespace.ansur import split
from core.synth.bodies import SEXES, shape_body
from core.template import load_template

#: Envelope density used to turn weight into volume, kg / m³.
DENSITY = 1000.0
#: Regional fat amplitude ranges (metres, along the outward normal).
FAT_RANGES = {
    "belly": (-0.01, 0.06),
    "buttocks": (-0.01, 0.04),
    "flanks": (0.0, 0.03),
    "thighs": (-0.01, 0.03),
    "upper_arms": (-0.005, 0.02),
    "breasts_female": (0.0, 0.03),
    "breasts_male": (0.0, 0.015),
    "nape": (0.0, 0.015),
}
GLOBAL_LAYER_RANGE = (-0.012, 0.06)
SHOULDER_SHIFT = 0.03
BONE_SCALE = 0.07
BMI_RANGE = (15.0, 55.0)


@dataclass
class RealBody:
    """A body outside the prior's family, in template vertex order.

    Attributes
    ----------
    V : (13380, 3) float64 vertices, metres, +Y up, +Z front, floor y = 0 (rest or posed).
    sex : ``"female"`` or ``"male"``.
    params : what was drawn: stature_m, weight_kg, bmi, the volumes, field amplitudes (m),
        shoulder shift (m), bone scales, posture angles (degrees).
    """

    V: np.ndarray
    sex: str
    params: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------- helpers


@cache
def _adjacency() -> sp.csr_matrix:
    """Row-normalised vertex adjacency of the template (for smoothing weights)."""
    tpl = load_template()
    E = tpl.edges
    n = tpl.n_vertices
    A = sp.coo_matrix((np.ones(2 * len(E)), (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])),
                      shape=(n, n)).tocsr()  # fmt: skip
    d = np.asarray(A.sum(axis=1)).ravel()
    return sp.diags(1.0 / d) @ A


def smooth_weights(w: np.ndarray, iterations: int = 20) -> np.ndarray:
    """Smooth a per-vertex field (13380,) or (13380, k) by repeated neighbour averaging."""
    A = _adjacency()
    out = np.asarray(w, dtype=np.float64)
    for _ in range(iterations):
        out = 0.5 * out + 0.5 * (A @ out)
    return out


def mesh_volume(V: np.ndarray, F: np.ndarray) -> float:
    """Signed volume (m³ for metres) enclosed by triangles ``F`` (positive for outward winding)."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def _gauss(V: np.ndarray, c: np.ndarray, s: np.ndarray | float) -> np.ndarray:
    return np.exp(-0.5 * (((V - c) / s) ** 2).sum(axis=1))


def _part_weight(names: tuple[str, ...], iterations: int = 15) -> np.ndarray:
    tpl = load_template()
    m = np.isin(tpl.part, [tpl.part_names.index(n) for n in names]).astype(np.float64)
    return smooth_weights(m, iterations)


@cache
def _subtree_weights() -> dict[str, np.ndarray]:
    """Per bone name: (13380,) summed skin weight of the bone's subtree (bone included)."""
    rig = load_rig()
    W = rig.skin_weights()
    return {n: W[:, rig.descendants(n)].sum(axis=1) for n in rig.names}


def _fat_fields(V: np.ndarray, sex: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per region: unit-amplitude displacement (13380, 3) = weight x (normal + sag) and weight."""
    tpl = load_template()
    lm = {k: V[i] for k, i in tpl.landmarks.items()}
    N = tpl.vertex_normals(V)
    down = np.array([0.0, -1.0, 0.0])
    trunk = _part_weight(("torso", "pelvis"))
    thighs = _part_weight(("thigh_L", "thigh_R"))
    arms = _part_weight(("upper_arm_L", "upper_arm_R"))
    neck = _part_weight(("neck", "torso"), 5)
    front = 1.0 / (1.0 + np.exp(-(V[:, 2] - np.median(V[:, 2])) / 0.02))
    back = 1.0 - front
    y_navel, y_crotch = lm["Omphalion"][1], lm["Crotch"][1]
    out: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def put(name: str, w: np.ndarray, sag: float = 0.0) -> None:
        w = smooth_weights(w, 10)
        out[name] = (w[:, None] * N + sag * (w**2)[:, None] * down, w)

    belly_c = np.array([0.0, 0.6 * y_navel + 0.4 * y_crotch, lm["Omphalion"][2]])
    put("belly", trunk * front * _gauss(V, belly_c, np.array([0.13, 0.10, 0.5])), 0.5)
    bt = 0.5 * (lm["Buttock_L"] + lm["Buttock_R"])
    put("buttocks", trunk * back * _gauss(V, bt, np.array([0.16, 0.09, 0.5])), 0.4)
    fl = np.zeros(len(V))
    for s in ("L", "R"):
        fl += _gauss(V, lm[f"Iliocristale_{s}"] + [0.0, 0.03, 0.0], np.array([0.06, 0.07, 0.10]))
    put("flanks", trunk * fl)
    mid_thigh = 0.5 * (y_crotch + lm["Patella_L"][1])
    inner = np.exp(-0.5 * (np.abs(V[:, 0]) / 0.08) ** 2)
    put("thighs", thighs * _gauss(V[:, [1]], np.array([mid_thigh + 0.08]), 0.12) * (0.5 + inner))
    put("upper_arms", arms * (0.4 + back))
    br = np.zeros(len(V))
    for s in ("L", "R"):
        br += _gauss(V, lm[f"Thelion_{s}"], np.array([0.065, 0.06, 0.08]))
    put("breasts_" + sex, trunk * front * br, 0.3)
    put("nape", neck * back * _gauss(V, lm["Cervicale"], np.array([0.08, 0.05, 0.08])))
    return out


def _lengthen_bone(V: np.ndarray, head: str, child: str, scale: float) -> np.ndarray:
    """Change a limb bone's length (head joint of ``head`` to head joint of ``child``) by
    ``scale``: the subtree below ``child`` moves along the bone, the bone's own skin stretches."""
    rig = load_rig()
    J = joint_positions(V, rig=rig)
    a, b = J[rig.index(head)], J[rig.index(child)]
    L = float(np.linalg.norm(b - a))
    u = (b - a) / L
    sub = _subtree_weights()
    below = sub[child]
    own = sub[head] - below
    t = np.clip((V - a) @ u / L, 0.0, 1.0)
    return V + (scale - 1.0) * L * (below + own * t)[:, None] * u


# ----------------------------------------------------------------------------- bodies


def _draw_size(rng: np.random.Generator, sex: str) -> tuple[float, float]:
    """(stature m, weight kg): a held-out ANSUR II row; in 40 % a BMI from ``BMI_RANGE``."""
    d = split(sex, "test")
    i = int(rng.integers(len(d["stature"])))
    h, w = float(d["stature"][i]), float(d["weightkg"][i])
    if rng.random() < 0.4:
        w = float(rng.uniform(*BMI_RANGE)) * h * h
    return h, w


def off_model_body(
    rng: np.random.Generator, *, sex: str | None = None, bmi: float | None = None
) -> RealBody:
    """A rest-pose body outside the MakeHuman target space (see the module docstring).

    Parameters
    ----------
    rng : the only source of randomness.
    sex : ``"female"``, ``"male"`` or None (random).
    bmi : force this BMI (kg/m²) instead of drawing one.

    Returns
    -------
    RealBody, V (13380, 3) metres, rest (A-)pose, floor y = 0.
    """
    if sex is None:
        sex = SEXES[int(rng.integers(2))]
    if sex not in SEXES:
        raise ValueError(f"sex must be 'female' or 'male', got {sex!r}")
    tpl = load_template()
    F = np.asarray(tpl.F, dtype=np.int64)
    stature, weight = _draw_size(rng, sex)
    if bmi is not None:
        if not BMI_RANGE[0] - 5 <= bmi <= BMI_RANGE[1] + 5:
            raise ValueError(f"bmi must be within {BMI_RANGE} (±5), got {bmi}")
        weight = bmi * stature**2
    bmi_v = weight / stature**2
    mh_weight = float(np.interp(bmi_v, [15.0, 25.0, 40.0], [0.0, 0.5, 1.0]))
    V, _ = shape_body(
        sex,
        stature_m=stature,
        weight=mh_weight,
        muscle=float(np.clip(rng.normal(0.5, 0.15), 0.1, 0.9)),
        age=float(rng.uniform(0.5, 0.8)),
        proportions=float(rng.uniform(0.3, 0.8)),
        cup=float(rng.uniform(0.3, 0.9) if sex == "female" else 0.5),
    )
    # bone lengths and shoulders (before fat: fat follows the normals of the final skeleton)
    scales = {}
    for head, child in (
        ("upperarm01", "lowerarm01"),
        ("lowerarm01", "wrist"),
        ("upperleg01", "lowerleg01"),
        ("lowerleg01", "foot"),
    ):
        s = float(1.0 + rng.uniform(-BONE_SCALE, BONE_SCALE))  # both sides alike
        scales[head] = s
        for side in (".L", ".R"):
            V = _lengthen_bone(V, head + side, child + side, s)
    sub = _subtree_weights()
    shift = float(rng.uniform(-SHOULDER_SHIFT, SHOULDER_SHIFT))
    for side, sgn in ((".L", 1.0), (".R", -1.0)):
        V = V + np.outer(shift * sgn * sub["clavicle" + side], [1.0, 0.0, 0.0])
    # regional fat
    fields = _fat_fields(V, sex)
    amps = {}
    D = np.zeros_like(V)
    for name, (disp, _) in fields.items():
        a = float(rng.uniform(*FAT_RANGES[name]))
        amps[name.split("_")[0] if name.startswith("breasts") else name] = a
        D += a * disp
    V = V + D
    # global layer to reach the target volume
    N = tpl.vertex_normals(V)
    g = 1.0 - 0.85 * _part_weight(("head", "hand_L", "hand_R", "foot_L", "foot_R"), 10)
    target = weight / DENSITY
    lo, hi = GLOBAL_LAYER_RANGE
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if mesh_volume(V + mid * g[:, None] * N, F) < target:
            lo = mid
        else:
            hi = mid
    layer = 0.5 * (lo + hi)
    V = V + layer * g[:, None] * N
    V[:, 1] -= V[:, 1].min()
    vol = mesh_volume(V, F)
    h = float(V[:, 1].max())
    params = {
        "stature_target_m": stature,
        "stature_m": h,
        "weight_target_kg": weight,
        "weight_kg": vol * DENSITY,
        "bmi": vol * DENSITY / h**2,
        "volume_l": vol * 1000.0,
        "fat_m": amps,
        "global_layer_m": layer,
        "shoulder_shift_m": shift,
        "bone_scale": scales,
    }
    return RealBody(V=V, sex=sex, params=params)


# ----------------------------------------------------------------------------- postures


POSTURE_RANGES = {
    "arm_abduction": (5.0, 60.0),  # degrees between upper arm and the body's vertical
    "elbow_flexion": (0.0, 30.0),  # total (the rest pose has ~25-45°)
    "feet_gap_m": (0.0, 0.40),  # medial malleoli apart
    "lean_fwd": (-5.0, 5.0),
    "lean_side": (-3.0, 3.0),
    "neck_flexion": (0.0, 20.0),
    "forward_head": (0.0, 15.0),
    "head_yaw": (-15.0, 15.0),
    "head_roll": (-5.0, 5.0),
}
#: Arm abduction (degrees) of the wide-arms protocols: T-pose and near-T-pose captures of
#: animation and photogrammetry rigs and some handheld-scan protocols (``arm_range=`` of
#: :func:`posture`; :func:`core.synth.scanner_outputs.make_case`'s ``*_wide`` kinds).
WIDE_ARM_RANGE = (60.0, 90.0)
#: Forearm twists (degrees, each side, either sign: palms turned forwards or backwards from the
#: rest pose's, towards the thighs) of the turned-palms protocols (``core.synth.scanner_outputs``
#: ``PALM_KINDS``): anatomical position (palms forward) and protocols that ask for the palms back.
PALM_TWIST_RANGE = (45.0, 100.0)
_X, _Y, _Z = np.eye(3)


def rest_arm_abduction(V: np.ndarray) -> float:
    """Angle (degrees) between the left upper arm (shoulder to elbow joint) and -Y."""
    rig = load_rig()
    J = joint_positions(V, rig=rig)
    d = J[rig.index("lowerarm01.L")] - J[rig.index("upperarm01.L")]
    return float(np.degrees(np.arctan2(d[0], -d[1])))


def posture(
    V: np.ndarray,
    rng: np.random.Generator,
    *,
    touching: bool = False,
    fist: bool | None = None,
    arm_range: tuple[float, float] | None = None,
    forearm_twist: tuple[float, float] = (0.0, 0.0),
) -> tuple[np.ndarray, dict]:
    """Pose a rest-pose body the way a real scanning protocol would (see the module docstring).

    Parameters
    ----------
    V : (13380, 3) rest-pose body, metres, template order.
    rng : the only source of randomness.
    touching : lower the arms until the upper arms meet the torso (fused in a closed mesh).
    fist : force fisted (True) or open (False) hands; None draws (30 % fisted).
    arm_range : (low, high) degrees to draw the arm abduction from instead of
        ``POSTURE_RANGES["arm_abduction"]`` (e.g. :data:`WIDE_ARM_RANGE`); the draws of every
        other angle are the same.
    forearm_twist : (left, right) degrees each forearm (and its hand) is turned about its own
        axis from the rest pose's palms towards the thighs (thumbs forward), the right mirrored:
        + turns the palms backwards (thumbs inwards), − forwards (thumbs out, the anatomical
        position); see :data:`PALM_TWIST_RANGE`. Not drawn from ``rng``.

    Returns
    -------
    (13380, 3) posed body (floor y = 0) and the angles used (degrees; ``feet_gap_m`` metres).
    """
    rig = load_rig()
    tpl = load_template()
    J = joint_positions(V, rig=rig)
    tails = joint_positions(V, rig=rig, ends="tail")
    ang = {k: float(rng.uniform(*r)) for k, r in POSTURE_RANGES.items() if k != "arm_abduction"}
    abd = rng.uniform(*(arm_range or POSTURE_RANGES["arm_abduction"]))
    ang["arm_abduction"] = float(abd)
    ang["arm_abduction_asym"] = float(rng.uniform(-5.0, 5.0))
    ang["elbow_flexion_asym"] = float(rng.uniform(-5.0, 5.0))
    fist = bool(rng.random() < 0.3) if fist is None else fist
    ang["fist"] = fist
    curl = float(rng.uniform(55.0, 80.0) if fist else rng.uniform(0.0, 10.0))
    ang["finger_curl" if fist else "finger_spread"] = curl
    rest = rest_arm_abduction(V)
    u = J[rig.index("lowerarm01.L")] - J[rig.index("upperarm01.L")]
    d = J[rig.index("wrist.L")] - J[rig.index("lowerarm01.L")]
    rest_flex = float(np.degrees(np.arccos(u @ d / np.linalg.norm(u) / np.linalg.norm(d))))
    rest_gap = abs(
        V[tpl.landmarks["Medial_malleolus_L"], 0] - V[tpl.landmarks["Medial_malleolus_R"], 0]
    )
    leg = np.linalg.norm(J[rig.index("foot.L")] - J[rig.index("upperleg01.L")])
    sin_spread = np.clip((ang["feet_gap_m"] - rest_gap) / 2 / leg, -0.3, 0.5)
    spread = float(np.degrees(np.arcsin(sin_spread)))

    def rotations(abd_l: float, abd_r: float) -> dict[str, np.ndarray]:
        rot: dict[str, np.ndarray] = {}
        for side, s, a in ((".L", 1.0, abd_l), (".R", -1.0, abd_r)):
            rot["upperarm01" + side] = axis_angle(_Z, s * np.radians(a - rest))
            u = J[rig.index("lowerarm01" + side)] - J[rig.index("upperarm01" + side)]
            d = J[rig.index("wrist" + side)] - J[rig.index("lowerarm01" + side)]
            flex = max(ang["elbow_flexion"] + s * ang["elbow_flexion_asym"], 0.0)
            tw = forearm_twist[0] if side == ".L" else -forearm_twist[1]
            rot["lowerarm01" + side] = axis_angle(
                np.cross(u, d), np.radians(flex - rest_flex)
            ) @ axis_angle(d / np.linalg.norm(d), np.radians(tw))
            rot["upperleg01" + side] = axis_angle(_Z, s * np.radians(spread))
            rot["foot" + side] = axis_angle(_Z, -s * np.radians(spread))  # sole back on the floor
            rot.update(finger_rotations(J, tails, side, fist, curl, rig=rig))
        rot["spine03"] = axis_angle(_X, np.radians(ang["lean_fwd"])) @ axis_angle(
            _Z, np.radians(ang["lean_side"])
        )
        rot["neck01"] = axis_angle(_X, np.radians(ang["neck_flexion"] + ang["forward_head"]))
        rot["head"] = (
            axis_angle(_Y, np.radians(ang["head_yaw"]))
            @ axis_angle(_Z, np.radians(ang["head_roll"]))
            @ axis_angle(_X, -np.radians(ang["forward_head"]))
        )
        return rot

    a_l = abd + ang["arm_abduction_asym"]
    a_r = abd - ang["arm_abduction_asym"]
    if touching:
        from scipy.spatial import cKDTree

        trunk = np.zeros(len(V), dtype=bool)
        for part in ("torso", "pelvis", "thigh_L", "thigh_R"):
            trunk |= tpl.part_mask(part)
        torso = cKDTree(V[trunk])
        arms = np.zeros(len(V), dtype=bool)  # forearms and hands: the touch closes a loop
        for part in ("forearm_L", "forearm_R", "hand_L", "hand_R"):
            arms |= tpl.part_mask(part)
        a = 25.0
        for a in np.arange(25.0, -10.0, -1.0):
            P = pose_body(V, rotations(a, a), rig=rig, joints=J)
            if torso.query(P[arms])[0].min() < 0.002:
                break
        a_l = a_r = float(a)
        ang["arm_abduction"] = a_l
        ang["arm_abduction_asym"] = 0.0
        ang["touching"] = True
    P = pose_body(V, rotations(a_l, a_r), rig=rig, joints=J)
    P[:, 1] -= P[:, 1].min()
    ang["forearm_twist_L"], ang["forearm_twist_R"] = (float(t) for t in forearm_twist)
    ang["rest_arm_abduction"] = rest
    ang["rest_elbow_flexion"] = rest_flex
    ang["leg_spread"] = spread
    return P, ang


def stand_leaned(P: np.ndarray, lean_deg: float) -> np.ndarray:
    """The posed body ``P`` (13380, 3; +Y up, +Z front, floor y = 0) leaned as a whole about the
    floor point under its centre, ``lean_deg`` degrees forwards (+) or backwards (−): people
    stand with their weight ahead of the ankles, the shins tilted a few degrees."""
    pivot = np.array([P[:, 0].mean(), P[:, 1].min(), P[:, 2].mean()])
    R = Rotation.from_rotvec(np.radians(lean_deg) * _X).as_matrix()
    out = (P - pivot) @ R.T + pivot
    out[:, 1] -= out[:, 1].min()
    return out


#: A subject scanned view after view (a handheld scanner's sweeps, a turntable, booth heads
#: that fire in turn) moves between the views (:func:`moved_views`). Per case: the RMS sway of
#: the crown (metres; the body turns about the floor between its feet, as an inverted
#: pendulum), the RMS drift of each arm about the shoulder (degrees, out from the body and
#: forwards) and the breathing amplitude of the chest and belly (metres along the normals).
SWAY_RANGE_M = (0.003, 0.012)
ARM_DRIFT_RANGE_DEG = (0.5, 2.0)
BREATH_RANGE_M = (0.001, 0.004)


def moved_views(
    P: np.ndarray, rng: np.random.Generator, n_views: int
) -> tuple[list[tuple[np.ndarray, np.ndarray, np.ndarray]], dict]:
    """The posed body ``P`` as each of ``n_views`` sequential views saw it.

    Each view's body is ``P`` with both arms turned about their shoulders, the chest and belly
    moved along their normals (breathing), then the whole body turned about the floor point
    under its centre (sway). Every motion is drawn per view and its mean over the views taken
    out, so ``P`` is where the subject stood on average: the truth of the scan.

    Returns
    -------
    ([(V_k (13380, 3) metres, R_k (3, 3), t_k (3,))] per view, where the sway alone maps a
    point x to ``R_k @ x + t_k`` (for what moves rigidly with the body: hair), and the draws:
    ``sway_m``, ``arm_drift_deg``, ``breath_m`` (per case) and ``crown_moves_m`` (per view).
    """
    rig = load_rig()
    tpl = load_template()
    J = joint_positions(P, rig=rig)
    height = float(P[:, 1].max() - P[:, 1].min())
    sway = float(rng.uniform(*SWAY_RANGE_M))
    drift = float(rng.uniform(*ARM_DRIFT_RANGE_DEG))
    breath = float(rng.uniform(*BREATH_RANGE_M))

    def centred(x: np.ndarray) -> np.ndarray:
        return x - x.mean(axis=0)

    # sway: horizontal rotation vectors (radians) whose crown displacement has RMS ``sway``
    tilt = centred(rng.normal(0.0, sway / height / np.sqrt(2.0), (n_views, 2)))
    arms = centred(rng.normal(0.0, np.radians(drift), (n_views, 4)))  # L out, L fwd, R out, R fwd
    breaths = centred(rng.uniform(-breath, breath, (n_views, 1)))[:, 0]
    N = tpl.vertex_normals(P)
    front = 1.0 / (1.0 + np.exp(-(P[:, 2] - np.median(P[:, 2])) / 0.02))
    chest = _part_weight(("torso", "pelvis"), 10) * front
    pivot = np.array([P[:, 0].mean(), P[:, 1].min(), P[:, 2].mean()])
    top = int(np.argmax(P[:, 1]))
    views, moves = [], []
    for k in range(n_views):
        rot = {
            "upperarm01.L": axis_angle(_Z, arms[k, 0]) @ axis_angle(_X, -arms[k, 1]),
            "upperarm01.R": axis_angle(_Z, -arms[k, 2]) @ axis_angle(_X, -arms[k, 3]),
        }
        Vk = pose_body(P, rot, rig=rig, joints=J) + breaths[k] * chest[:, None] * N
        R = Rotation.from_rotvec([tilt[k, 0], 0.0, tilt[k, 1]]).as_matrix()
        t = pivot - R @ pivot
        Vk = Vk @ R.T + t
        views.append((Vk, R, t))
        moves.append(float(np.linalg.norm(Vk[top] - P[top])))
    info = {"sway_m": sway, "arm_drift_deg": drift, "breath_m": breath, "crown_moves_m": moves}
    return views, info


def joint_world(V: np.ndarray, rotations: dict[str, np.ndarray]) -> np.ndarray:
    """(J, 3) posed joint positions of a rest body ``V`` under ``rotations`` (metres)."""
    rig = load_rig()
    J = joint_positions(V, rig=rig)
    R, t = bone_transforms(rotations, J, rig=rig)
    return np.einsum("jab,jb->ja", R, J) + t


__all__ = [
    "ARM_DRIFT_RANGE_DEG",
    "BREATH_RANGE_M",
    "PALM_TWIST_RANGE",
    "POSTURE_RANGES",
    "SWAY_RANGE_M",
    "WIDE_ARM_RANGE",
    "RealBody",
    "mesh_volume",
    "moved_views",
    "off_model_body",
    "posture",
    "rest_arm_abduction",
    "smooth_weights",
    "stand_leaned",
]
