"""Random but plausible bodies in template vertex order, from MakeHuman (CC0) shape targets.

Shape follows MakeHuman's macro modifiers: for the chosen sex, ethnic targets
(``{african,asian,caucasian}-{sex}-{young,old}``) weighted by a random ethnic mix and the age
blend, universal targets interpolating min/average/max muscle and weight, a height target solved
for a sampled stature (1.50-1.95 m), body proportions and breast cup/firmness; then a few regional
targets (waist, hips, bust, thighs, arms, neck, ...). Finally a small pose change (arm abduction,
elbow bend, leg spread, head turn, torso lean) through ``core.rig`` when it is available.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.synth.targets import TargetLibrary, load_targets
from core.template import load_template

SEXES = ("female", "male")
RACES = ("african", "asian", "caucasian")
#: Mean and sd of stature (metres) by sex; samples are clipped to ``STATURE_RANGE``.
STATURE = {"female": (1.63, 0.07), "male": (1.76, 0.075)}
STATURE_RANGE = (1.50, 1.95)
#: Regional target families sampled at random (name stem -> maximum |weight|).
REGIONAL = {
    "torso/measure-waist-circ": 0.8,
    "torso/measure-hips-circ": 0.8,
    "torso/measure-bust-circ": 0.6,
    "torso/measure-underbust-circ": 0.6,
    "torso/measure-shoulder-dist": 0.6,
    "torso/measure-napetowaist-dist": 0.5,
    "torso/measure-waisttohip-dist": 0.5,
    "torso/torso-scale-depth": 0.5,
    "torso/torso-scale-horiz": 0.5,
    "torso/torso-vshape": 0.6,
    "torso/torso-muscle-pectoral": 0.6,
    "hip/hip-scale-depth": 0.5,
    "hip/hip-scale-horiz": 0.5,
    "hip/hip-waist": 0.5,
    "buttocks/buttocks-volume": 0.7,
    "stomach/stomach-pregnant": 0.4,
    "stomach/stomach-tone": 0.6,
    "legs/measure-thigh-circ": 0.7,
    "legs/measure-calf-circ": 0.6,
    "legs/measure-knee-circ": 0.5,
    "legs/measure-upperleg-height": 0.5,
    "legs/measure-lowerleg-height": 0.5,
    "legs/upperleg-fat": 0.6,
    "legs/upperleg-muscle": 0.6,
    "legs/lowerleg-fat": 0.6,
    "arms/measure-upperarm-circ": 0.6,
    "arms/measure-upperarm-length": 0.4,
    "arms/measure-lowerarm-length": 0.4,
    "arms/upperarm-fat": 0.6,
    "arms/upperarm-muscle": 0.6,
    "neck/measure-neck-circ": 0.6,
    "neck/measure-neck-height": 0.5,
    "neck/neck-double": 0.5,
    "head/head-scale-horiz": 0.3,
    "head/head-scale-vert": 0.3,
    "head/head-scale-depth": 0.3,
    "head/head-fat": 0.5,
}
_SUFFIX = {"hip/hip-waist": ("down", "up"), "stomach/stomach-pregnant": ("decr", "incr")}


@dataclass
class SynthBody:
    """A synthetic body.

    Attributes
    ----------
    V : (13380, 3) float64 vertices, metres, template order, +Y up, +Z front, floor at y = 0.
    sex : ``"female"`` or ``"male"``.
    params : the sampled parameters (stature_m, age_years, muscle, weight, ethnic mix,
        proportions, cup, firmness, regional target weights, pose angles in degrees).
    """

    V: np.ndarray
    sex: str
    params: dict = field(default_factory=dict)

    @property
    def stature_m(self) -> float:
        """Height of the body's top vertex above the floor, metres."""
        return float(self.V[:, 1].max() - self.V[:, 1].min())


def _tri(v: float, names: tuple[str, str, str]) -> dict[str, float]:
    """MakeHuman 3-way blend of a [0, 1] value: 0 -> names[0], 0.5 -> names[1], 1 -> names[2]."""
    if v < 0.5:
        lo = (0.5 - v) * 2.0
        return {names[0]: lo, names[1]: 1.0 - lo}
    hi = (v - 0.5) * 2.0
    return {names[1]: 1.0 - hi, names[2]: hi}


def macro_weights(
    sex: str,
    *,
    age: float = 0.5,
    muscle: float = 0.5,
    weight: float = 0.5,
    height: float = 0.5,
    proportions: float = 0.5,
    cup: float = 0.5,
    firmness: float = 0.5,
    races: dict[str, float] | None = None,
    lib: TargetLibrary | None = None,
) -> dict[str, float]:
    """MakeHuman macro-modifier target weights.

    Parameters are MakeHuman modifier values on [0, 1] (0.5 = neutral); ``age`` on [0.5, 1]
    (0.5 = 25 years, 1 = 90 years). Returns target name -> weight, only for targets present in
    the library.
    """
    if sex not in SEXES:
        raise ValueError(f"sex must be 'female' or 'male', got {sex!r}")
    lib = load_targets() if lib is None else lib
    races = races or {r: 1.0 / 3.0 for r in RACES}
    a_old = float(np.clip((age - 0.5) * 2.0, 0.0, 1.0))
    ages = {"young": 1.0 - a_old, "old": a_old}
    mus = _tri(muscle, ("minmuscle", "averagemuscle", "maxmuscle"))
    wts = _tri(weight, ("minweight", "averageweight", "maxweight"))
    hts = {"minheight": max(0.0, (0.5 - height) * 2.0), "maxheight": max(0.0, (height - 0.5) * 2.0)}
    prs = {
        "uncommonproportions": max(0.0, (0.5 - proportions) * 2.0),
        "idealproportions": max(0.0, (proportions - 0.5) * 2.0),
    }
    cups = _tri(cup, ("mincup", "averagecup", "maxcup"))
    firms = _tri(firmness, ("minfirmness", "averagefirmness", "maxfirmness"))
    w: dict[str, float] = {}

    def put(name: str, x: float) -> None:
        if x != 0.0 and name in lib:
            w[name] = w.get(name, 0.0) + x

    for age_n, aw in ages.items():
        if aw == 0.0:
            continue
        for r, rw in races.items():
            put(f"macrodetails/{r}-{sex}-{age_n}", aw * rw)
        for m, mw in mus.items():
            for wt, ww in wts.items():
                base = aw * mw * ww
                put(f"macrodetails/universal-{sex}-{age_n}-{m}-{wt}", base)
                for h, hw in hts.items():
                    put(f"macrodetails/height/{sex}-{age_n}-{m}-{wt}-{h}", base * hw)
    # proportions and breasts exist for "young" only: apply them at full age weight
    for m, mw in mus.items():
        for wt, ww in wts.items():
            for p, pw in prs.items():
                put(f"macrodetails/proportions/{sex}-young-{m}-{wt}-{p}", mw * ww * pw)
            for c, cw in cups.items():
                for f, fw in firms.items():
                    put(f"breast/{sex}-young-{m}-{wt}-{c}-{f}", mw * ww * cw * fw)
    return w


def _regional_names(stem: str, lib: TargetLibrary) -> tuple[list[str], list[str]]:
    """Target names for the negative and positive directions of a family (both sides if l/r)."""
    neg, pos = _SUFFIX.get(stem, ("decr", "incr"))
    folder, base = stem.split("/")
    out: tuple[list[str], list[str]] = ([], [])
    for k, sfx in enumerate((neg, pos)):
        for pre in ("", "l-", "r-"):
            n = f"{folder}/{pre}{base}-{sfx}"
            if n in lib:
                out[k].append(n)
    return out


def _stature(V: np.ndarray) -> float:
    return float(V[:, 1].max() - V[:, 1].min())


def shape_body(
    sex: str,
    *,
    stature_m: float | None = None,
    regional: dict[str, float] | None = None,
    **macro: float,
) -> tuple[np.ndarray, dict]:
    """Build an unposed body from MakeHuman parameters.

    Parameters
    ----------
    sex : ``"female"`` or ``"male"``.
    stature_m : wanted stature in metres; the height modifier is solved for it (then a small
        uniform scale about the floor corrects any remainder). None keeps ``macro["height"]``.
    regional : stem (see ``REGIONAL``) -> weight on [-1, 1] (negative = decr/down).
    **macro : ``macro_weights`` keywords (age, muscle, weight, height, proportions, cup, ...).

    Returns
    -------
    V : (13380, 3) float64 metres, floor at y = 0.
    info : {"height": solved height modifier, "scale": residual uniform scale}.
    """
    lib = load_targets()
    V0 = np.array(load_template().V, dtype=np.float64)
    reg = np.zeros_like(V0)
    for stem, x in (regional or {}).items():
        names = _regional_names(stem, lib)[int(x > 0)]
        if names:
            reg += lib.combine({n: abs(x) for n in names})

    def at(h: float) -> np.ndarray:
        return V0 + reg + lib.combine(macro_weights(sex, lib=lib, **{**macro, "height": h}))

    # the body is linear in the height modifier on each side of 0.5
    V_mid, V_lo, V_hi = at(0.5), at(0.0), at(1.0)

    def body(h: float) -> np.ndarray:
        return (
            V_mid + (2 * h - 1) * (V_hi - V_mid)
            if h >= 0.5
            else V_mid + (1 - 2 * h) * (V_lo - V_mid)
        )

    h = float(macro.get("height", 0.5))
    scale = 1.0
    if stature_m is None:
        V = body(h)
    else:
        lo, hi = 0.0, 1.0
        for _ in range(22):  # stature is monotone in the height modifier
            h = 0.5 * (lo + hi)
            if _stature(body(h)) < stature_m:
                lo = h
            else:
                hi = h
        V = body(h)
        scale = stature_m / _stature(V)
        V = V * scale
    V[:, 1] -= V[:, 1].min()
    return V, {"height": h, "scale": scale}


def random_body(
    rng: np.random.Generator, *, sex: str | None = None, pose: bool = True
) -> SynthBody:
    """A random plausible adult body (seeded).

    Parameters
    ----------
    rng : numpy random generator (the only source of randomness).
    sex : ``"female"``, ``"male"`` or None (random).
    pose : apply a small random pose change (needs ``core.rig``; skipped if unavailable).

    Returns
    -------
    SynthBody with V (13380, 3) metres in template order, floor at y = 0.
    """
    if sex is None:
        sex = SEXES[int(rng.integers(2))]
    if sex not in SEXES:
        raise ValueError(f"sex must be 'female' or 'male', got {sex!r}")
    mu, sd = STATURE[sex]
    stature = float(np.clip(rng.normal(mu, sd), *STATURE_RANGE))
    age_years = float(rng.uniform(20.0, 65.0))
    mix = rng.dirichlet(np.full(3, 0.7))
    macro = {
        "age": 0.5 + max(age_years - 25.0, 0.0) / 65.0 * 0.5,
        "muscle": float(np.clip(rng.normal(0.5, 0.2), 0.0, 1.0)),
        "weight": float(np.clip(rng.normal(0.5, 0.22), 0.0, 1.0)),
        "proportions": float(rng.uniform(0.3, 0.9)),
        "cup": float(rng.uniform(0.25, 0.95) if sex == "female" else rng.uniform(0.4, 0.6)),
        "firmness": float(rng.uniform(0.2, 0.8)),
    }
    stems = sorted(REGIONAL)
    chosen = rng.choice(len(stems), size=int(rng.integers(3, 7)), replace=False)
    regional = {
        stems[i]: float(rng.uniform(-1.0, 1.0) * REGIONAL[stems[i]]) for i in sorted(chosen)
    }
    V, info = shape_body(
        sex,
        stature_m=stature,
        regional=regional,
        races=dict(zip(RACES, mix.tolist(), strict=True)),
        **macro,
    )
    params: dict = {
        "stature_m": stature,
        "age_years": age_years,
        "races": dict(zip(RACES, mix.tolist(), strict=True)),
        **macro,
        **info,
        "regional": regional,
    }
    if pose:
        V, angles = _random_pose(V, rng)
        params["pose_deg"] = angles
    return SynthBody(V=V, sex=sex, params=params)


#: Pose ranges, degrees: (low, high) of a uniform draw.
POSE_RANGES = {
    "arm_abduction": (-12.0, 12.0),  # + raises the arm sideways (per side)
    "elbow_flexion": (0.0, 20.0),  # forearm towards the front (per side)
    "leg_spread": (-2.0, 5.0),  # + moves the foot outwards (per side)
    "head_turn": (-15.0, 15.0),  # about the vertical, + towards the subject's left
    "head_tilt": (-6.0, 6.0),  # nod, + chin down
    "torso_lean_fwd": (-3.0, 4.0),
    "torso_lean_side": (-3.0, 3.0),
}


def _random_pose(V: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, dict]:
    """Small random pose change by linear blend skinning (``core.rig``); floor reset to y = 0.

    Returns the posed (13380, 3) vertices and the angles used (degrees).
    """
    try:
        from core.rig import axis_angle, joint_positions, load_rig, pose_body
    except ImportError:  # the rig is optional
        return V, {}
    rig = load_rig()
    J = joint_positions(V, rig=rig)
    tails = joint_positions(V, rig=rig, ends="tail")
    ang = {
        f"{k}{sfx}": float(rng.uniform(*r))
        for k, r in POSE_RANGES.items()
        for sfx in (
            (".L", ".R") if k in ("arm_abduction", "elbow_flexion", "leg_spread") else ("",)
        )
    }
    rad = {k: np.radians(v) for k, v in ang.items()}
    z, y, x = np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0])
    rot: dict[str, np.ndarray] = {}
    for side, s in ((".L", 1.0), (".R", -1.0)):
        rot["upperarm01" + side] = axis_angle(z, s * rad["arm_abduction" + side])
        rot["upperleg01" + side] = axis_angle(z, s * rad["leg_spread" + side])
        j = rig.index("lowerarm01" + side)
        d = tails[rig.index("lowerarm02" + side)] - J[j]  # forearm direction at rest
        rot["lowerarm01" + side] = axis_angle(np.cross(d, z), rad["elbow_flexion" + side])
    rot["head"] = axis_angle(y, rad["head_turn"]) @ axis_angle(x, rad["head_tilt"])
    rot["spine03"] = axis_angle(x, rad["torso_lean_fwd"]) @ axis_angle(z, rad["torso_lean_side"])
    P = pose_body(V, rot, rig=rig, joints=J)
    P[:, 1] -= P[:, 1].min()
    return P, ang
