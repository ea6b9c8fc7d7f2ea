"""ISO 7250-1 / ANSUR II measurements of a body in template vertex order.

Landmarks come from the template's CAESAR landmark table, limb axes from ``core.rig`` joints
re-placed on the body, and body parts from the template segmentation, so the same code measures
the template, synthetic bodies, scaled bodies and fitted scans. See
:data:`core.measure.definitions.MEASUREMENTS` for each definition.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from functools import cache

import numpy as np

from core.measure.definitions import MEASUREMENTS
from core.measure.landmarks import landmark_point
from core.measure.sections import (
    MeshTopology,
    Section,
    convex_perimeter,
    mesh_volume,
    plane_section,
)
from core.rig import joint_positions, load_rig
from core.template import Template, load_template

#: Default body density, kg/m^3 (to be calibrated by the shape-space work).
DEFAULT_DENSITY = 1010.0
SIDES = ("right", "left")
UP = np.array([0.0, 1.0, 0.0])
_ARM_PARTS = ("upper_arm_L", "upper_arm_R", "forearm_L", "forearm_R", "hand_L", "hand_R")


class _Topologies:
    """Template topology and the per-region sub-topologies used by the sections (cached)."""

    def __init__(self, tpl: Template) -> None:
        self.tpl = tpl
        self.full = MeshTopology(tpl.F)
        self._sub: dict[tuple[str, ...], MeshTopology] = {}

    def parts(self, *names: str, exclude_ears: bool = False) -> MeshTopology:
        key = (*sorted(names), "-ears" if exclude_ears else "")
        if key not in self._sub:
            m = np.zeros(self.tpl.n_vertices, dtype=bool)
            for n in names:
                m |= self.tpl.part_mask(n)
            if exclude_ears:
                m &= ~self.tpl.mask("ears")
            self._sub[key] = self.full.restrict(m)
        return self._sub[key]

    def trunk(self) -> MeshTopology:
        return self.parts(*(p for p in self.tpl.part_names if p not in _ARM_PARTS))


@cache
def _topologies() -> _Topologies:
    return _Topologies(load_template())


@cache
def _trunk_vertices() -> np.ndarray:
    tpl = load_template()
    m = np.ones(tpl.n_vertices, dtype=bool)
    for p in _ARM_PARTS:
        m &= ~tpl.part_mask(p)
    return np.flatnonzero(m)


def _unit(x: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(x))
    if not np.isfinite(n) or n == 0.0:
        raise ValueError("degenerate body: a measurement axis has zero length")
    return x / n


def _horizontal(x: np.ndarray) -> np.ndarray:
    return _unit(np.array([x[0], 0.0, x[2]]))


class _Body:
    """One body being measured: landmarks, joints, axes and cached sections."""

    def __init__(self, V: np.ndarray, side: str, density: float) -> None:
        self.tpl = load_template()
        self.topo = _topologies()
        self.V = V
        self.density = density
        self.s = "R" if side == "right" else "L"
        self.sign = -1.0 if side == "right" else 1.0  # +X is the subject's left
        self.floor = float(V[:, 1].min())
        self._joints: np.ndarray | None = None
        self._cache: dict[str, object] = {}
        # body axes: left-right from pelvis and shoulders, front = lateral x up
        self.lat = _horizontal(
            (self.lm("ASIS_L") - self.lm("ASIS_R"))
            + (self.lm("Acromion_L") - self.lm("Acromion_R"))
        )
        self.front = np.cross(self.lat, UP)

    # ------------------------------------------------------------------ helpers
    def lm(self, name: str) -> np.ndarray:
        return landmark_point(self.V, name, self.tpl.landmarks)

    def side_lm(self, stem: str) -> np.ndarray:
        return self.lm(f"{stem}_{self.s}")

    def both_lm(self, stem: str) -> np.ndarray:
        return 0.5 * (self.lm(f"{stem}_L") + self.lm(f"{stem}_R"))

    def height(self, p: np.ndarray) -> float:
        return float(p[1] - self.floor)

    def joint(self, bone: str) -> np.ndarray:
        if self._joints is None:
            self._joints = joint_positions(self.V)
        return self._joints[load_rig().index(bone)]

    def side_joint(self, bone: str) -> np.ndarray:
        return self.joint(f"{bone}.{self.s}")

    def horizontal_section(self, y: float, topo: MeshTopology) -> Section:
        return plane_section(self.V, topo, np.array([0.0, y, 0.0]), UP)

    def trunk_section(self, key: str, y: float) -> np.ndarray:
        """(k, 3) points of the arm-less horizontal section at height ``y`` (absolute)."""
        if key not in self._cache:
            self._cache[key] = self.horizontal_section(y, self.topo.trunk()).points
        return self._cache[key]  # type: ignore[return-value]

    def extent(self, P: np.ndarray, axis: np.ndarray) -> float:
        if len(P) == 0:
            return 0.0
        t = P @ axis
        return float(t.max() - t.min())

    def perimeter(self, s: Section, P: np.ndarray) -> float:
        return convex_perimeter(s.to_2d(P)) if len(P) else 0.0

    def limb_circumference(
        self, a: np.ndarray, b: np.ndarray, t: float, topo: MeshTopology, *, horizontal: bool
    ) -> float:
        """Perimeter of the limb loop at fraction ``t`` from joint ``a`` to joint ``b``.

        The plane is horizontal or perpendicular to ``b - a``; the loop kept is the one around
        the axis point."""
        p = a + t * (b - a)
        n = UP if horizontal else b - a
        s = plane_section(self.V, topo, p, n)
        return self.perimeter(s, s.piece(p))

    def search(
        self, f: Callable[[float], float], lo: float, hi: float, *, best: str = "max"
    ) -> float:
        """Extreme value of ``f`` on [lo, hi]: a 6-point grid, then 2 points around the best."""
        sgn = 1.0 if best == "max" else -1.0
        ts = np.linspace(lo, hi, 6)
        vals = np.array([f(t) for t in ts])
        i = int(np.argmax(sgn * vals))
        step = ts[1] - ts[0]
        ts2 = np.clip(ts[i] + step * np.array([-0.4, 0.4]), lo, hi)
        vals2 = np.array([f(t) for t in ts2])
        allv = np.concatenate([vals, vals2])
        return float(allv[np.argmax(sgn * allv)])


# ---------------------------------------------------------------------- measurement functions
def _stature(b: _Body) -> float:
    head = b.tpl.part_mask("head")
    return float(b.V[head, 1].max() - b.floor)


def _lm_height(stem: str, *, sided: bool = False, both: bool = False) -> Callable[[_Body], float]:
    def f(b: _Body) -> float:
        if sided:
            return b.height(b.side_lm(stem))
        if both:
            return b.height(b.both_lm(stem))
        return b.height(b.lm(stem))

    return f


def _chest_y(b: _Body) -> float:
    return float(b.both_lm("Thelion")[1])


def _waist_y(b: _Body) -> float:
    return float(b.lm("Omphalion")[1])


def _buttock_y(b: _Body) -> float:
    return float(b.side_lm("Buttock")[1])


def _trunk_circ(key: str, level: Callable[[_Body], float]) -> Callable[[_Body], float]:
    def f(b: _Body) -> float:
        P = b.trunk_section(key, level(b))
        return convex_perimeter(P[:, [0, 2]]) if len(P) else 0.0

    return f


def _trunk_extent(key: str, level: Callable[[_Body], float], axis: str) -> Callable[[_Body], float]:
    def f(b: _Body) -> float:
        return b.extent(b.trunk_section(key, level(b)), b.lat if axis == "lat" else b.front)

    return f


def _neck(b: _Body) -> float:
    a, h = b.joint("neck01"), b.joint("head")
    axis = _unit(h - a)
    s0 = float((b.lm("Cervicale") - a) @ axis)
    s1 = float((b.lm("Menton") - a) @ axis)
    topo = b.topo.parts("neck", "head", "torso")

    def f(t: float) -> float:
        p = a + (s0 + t * (s1 - s0)) * axis
        s = plane_section(b.V, topo, p, axis)
        return b.perimeter(s, s.piece(p))

    return b.search(f, 0.0, 1.0, best="min")


def _thigh(b: _Body) -> float:
    topo = b.topo.parts(f"thigh_{b.s}", "pelvis")
    hip, knee = b.side_joint("upperleg01"), b.side_joint("lowerleg01")
    crotch = b.lm("Crotch")
    y0 = crotch[1] - 0.01 * _stature(b)
    y1 = crotch[1] - 0.25 * (crotch[1] - knee[1])

    def f(y: float) -> float:
        s = b.horizontal_section(y, topo)
        p = hip + (y - hip[1]) / (knee[1] - hip[1]) * (knee - hip)
        P = s.piece(p)
        P = P[b.sign * ((P - crotch) @ b.lat) >= 0.0]  # this leg's side of the midline
        return b.perimeter(s, P)

    return b.search(f, y1, y0)


def _lower_thigh(b: _Body) -> float:
    pat, crotch = b.side_lm("Patella"), b.lm("Crotch")
    y = pat[1] + 0.12 * (crotch[1] - pat[1])
    hip, knee = b.side_joint("upperleg01"), b.side_joint("lowerleg01")
    t = (y - knee[1]) / (hip[1] - knee[1])
    return b.limb_circumference(knee, hip, t, b.topo.parts(f"thigh_{b.s}"), horizontal=True)


def _calf(b: _Body) -> float:
    knee = b.side_joint("lowerleg01")
    mall = b.side_lm("Lateral_malleolus")
    ankle = knee + (mall[1] - knee[1]) / (b.side_joint("foot")[1] - knee[1]) * (
        b.side_joint("foot") - knee
    )
    topo = b.topo.parts(f"shin_{b.s}")
    return b.search(
        lambda t: b.limb_circumference(knee, ankle, t, topo, horizontal=True), 0.10, 0.60
    )


def _ankle(b: _Body) -> float:
    knee, foot = b.side_joint("lowerleg01"), b.side_joint("foot")
    y_m = max(b.side_lm("Lateral_malleolus")[1], b.side_lm("Medial_malleolus")[1])
    topo = b.topo.parts(f"shin_{b.s}", f"foot_{b.s}")

    def f(t: float) -> float:
        y = y_m + t * (knee[1] - y_m)
        p = foot + (y - foot[1]) / (knee[1] - foot[1]) * (knee - foot)
        s = b.horizontal_section(y, topo)
        return b.perimeter(s, s.piece(p))

    return b.search(f, 0.08, 0.35, best="min")


def _biceps(b: _Body) -> float:
    sh, el = b.side_joint("upperarm01"), b.side_joint("lowerarm01")
    topo = b.topo.parts(f"upper_arm_{b.s}")
    return b.search(lambda t: b.limb_circumference(sh, el, t, topo, horizontal=False), 0.35, 0.75)


def _forearm(b: _Body) -> float:
    el, wr = b.side_joint("lowerarm01"), b.side_joint("wrist")
    topo = b.topo.parts(f"forearm_{b.s}", f"upper_arm_{b.s}")
    return b.search(lambda t: b.limb_circumference(el, wr, t, topo, horizontal=False), 0.10, 0.50)


def _wrist(b: _Body) -> float:
    el, wr = b.side_joint("lowerarm01"), b.side_joint("wrist")
    p = 0.5 * (b.side_lm("Radial_styloid") + b.side_lm("Ulnar_styloid"))
    s = plane_section(b.V, b.topo.parts(f"forearm_{b.s}", f"hand_{b.s}"), p, wr - el)
    return b.perimeter(s, s.piece(p))


def _head_lat(b: _Body) -> np.ndarray:
    return _unit(b.lm("Tragion_L") - b.lm("Tragion_R"))


def _head(b: _Body) -> float:
    g, o = b.lm("Glabella"), b.lm("Opisthocranion")
    n = _unit(np.cross(g - o, _head_lat(b)))
    p = 0.5 * (g + o)
    s = plane_section(b.V, b.topo.parts("head", exclude_ears=True), p, n)
    return b.perimeter(s, s.points)  # every piece: leaving out the ears splits the loop


def _head_breadth(b: _Body) -> float:
    tpl = b.tpl
    m = tpl.part_mask("head") & ~tpl.mask("ears")
    return b.extent(b.V[m], _head_lat(b))


def _hip_breadth(b: _Body) -> float:
    P = b.V[_trunk_vertices()]
    y0, y1 = b.lm("Crotch")[1], b.both_lm("Iliocristale")[1]
    P = P[(P[:, 1] >= y0) & (P[:, 1] <= y1)]
    return b.extent(P, b.lat)


def _dist(p: str, q: str, *, sided: bool = True, horizontal: bool = False):
    def f(b: _Body) -> float:
        a = b.side_lm(p) if sided else b.lm(p)
        c = b.side_lm(q) if sided else b.lm(q)
        d = a - c
        if horizontal:
            d = d * np.array([1.0, 0.0, 1.0])
        return float(np.linalg.norm(d))

    return f


def _foot_length(b: _Body) -> float:
    axis = _horizontal(b.side_lm("Toe_tip") - b.side_lm("Calcaneus_posterior"))
    return b.extent(b.V[b.tpl.part_mask(f"foot_{b.s}")], axis)


def _weight(b: _Body) -> float:
    return mesh_volume(b.V, b.tpl.F) * b.density


_FUNCS: dict[str, Callable[[_Body], float]] = {
    "stature": _stature,
    "cervicaleheight": _lm_height("Cervicale"),
    "suprasternaleheight": _lm_height("Suprasternale"),
    "acromialheight": _lm_height("Acromion", sided=True),
    "chestheight": _lm_height("Thelion", both=True),
    "waistheightomphalion": _lm_height("Omphalion"),
    "iliocristaleheight": _lm_height("Iliocristale", sided=True),
    "trochanterionheight": _lm_height("Trochanterion", sided=True),
    "buttockheight": _lm_height("Buttock", sided=True),
    "crotchheight": _lm_height("Crotch"),
    "kneeheightmidpatella": _lm_height("Patella", sided=True),
    "lateralfemoralepicondyleheight": _lm_height("Femoral_lateral_epicondyle", sided=True),
    "lateralmalleolusheight": _lm_height("Lateral_malleolus", sided=True),
    "chestcircumference": _trunk_circ("chest", _chest_y),
    "waistcircumference": _trunk_circ("waist", _waist_y),
    "buttockcircumference": _trunk_circ("buttock", _buttock_y),
    "neckcircumference": _neck,
    "thighcircumference": _thigh,
    "lowerthighcircumference": _lower_thigh,
    "calfcircumference": _calf,
    "anklecircumference": _ankle,
    "bicepscircumferenceflexed": _biceps,
    "forearmcircumferenceflexed": _forearm,
    "wristcircumference": _wrist,
    "headcircumference": _head,
    "biacromialbreadth": _dist("Acromion_L", "Acromion_R", sided=False, horizontal=True),
    "chestbreadth": _trunk_extent("chest", _chest_y, "lat"),
    "chestdepth": _trunk_extent("chest", _chest_y, "front"),
    "waistbreadth": _trunk_extent("waist", _waist_y, "lat"),
    "waistdepth": _trunk_extent("waist", _waist_y, "front"),
    "buttockdepth": _trunk_extent("buttock", _buttock_y, "front"),
    "hipbreadth": _hip_breadth,
    "headbreadth": _head_breadth,
    "headlength": _dist("Glabella", "Opisthocranion", sided=False),
    "bimalleolarbreadth": _dist("Lateral_malleolus", "Medial_malleolus"),
    "acromionradialelength": _dist("Acromion", "Radiale"),
    "radialestylionlength": _dist("Radiale", "Radial_styloid"),
    "footlength": _foot_length,
    "weightkg": _weight,
}
if set(_FUNCS) != set(MEASUREMENTS):  # pragma: no cover - a module invariant
    raise RuntimeError("core.measure: implementations and MEASUREMENTS disagree")


def measure(
    V: np.ndarray,
    *,
    names: Iterable[str] | None = None,
    side: str = "right",
    density: float = DEFAULT_DENSITY,
) -> dict[str, float]:
    """ISO 7250-1 / ANSUR II measurements of a body in template vertex order.

    Parameters
    ----------
    V : (13380, 3) float vertices, metres, template order, +Y up (the floor is the body's
        lowest vertex; the body need not stand at y = 0).
    names : the measurements wanted (keys of :data:`MEASUREMENTS`, ANSUR II column names);
        default all of them.
    side : ``"right"`` (ANSUR's convention for bilateral measurements) or ``"left"``.
    density : body density in kg/m^3 for ``weightkg`` (default 1010).

    Returns
    -------
    name -> value: metres for lengths, heights, breadths, depths and circumferences (ANSUR's
    CSV holds millimetres), kilograms for ``weightkg`` (ANSUR: tenths of a kg).

    Raises
    ------
    ValueError
        On a wrong shape, non-finite vertices, an unknown name, side or a non-positive density.
    """
    tpl = load_template()
    V = np.asarray(V, dtype=np.float64)
    if V.shape != tpl.V.shape:
        raise ValueError(
            f"V must be {tpl.V.shape} vertices in template order (metres), got shape {V.shape}"
        )
    if not np.all(np.isfinite(V)):
        raise ValueError("V contains non-finite coordinates")
    if side not in SIDES:
        raise ValueError(f"side must be 'right' or 'left', got {side!r}")
    if not (np.isfinite(density) and density > 0):
        raise ValueError(f"density must be a positive number of kg/m^3, got {density!r}")
    wanted = list(MEASUREMENTS) if names is None else list(names)
    unknown = [n for n in wanted if n not in MEASUREMENTS]
    if unknown:
        raise ValueError(
            f"unknown measurement(s) {', '.join(map(repr, unknown))}; "
            f"valid: {', '.join(MEASUREMENTS)}"
        )
    body = _Body(V, side, float(density))
    return {n: _FUNCS[n](body) for n in wanted}
