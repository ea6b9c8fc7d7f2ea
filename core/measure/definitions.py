"""What each measurement is: ANSUR II column, kind, unit and the definition implemented.

Definitions paraphrase the ANSUR II measurer's handbook (Hotzman et al. 2011, NATICK/TR-11/017;
Gordon et al. 2014, NATICK/TR-15/007) and ISO 7250-1, followed by how this package reproduces
them on a mesh in template vertex order. Bilateral measurements follow ANSUR and are taken on the
subject's **right** side unless ``measure(..., side="left")`` asks otherwise.
"""

from __future__ import annotations

from typing import NamedTuple


class Measurement(NamedTuple):
    """Metadata of one measurement.

    Attributes
    ----------
    kind : ``"height"``, ``"length"``, ``"breadth"``, ``"depth"``, ``"circumference"`` or
        ``"mass"``.
    unit : ``"m"`` or ``"kg"`` (ANSUR's CSV uses mm and tenths of a kg).
    definition : what is measured and how it is computed here.
    ansur : the ANSUR II column it corresponds to.
    """

    kind: str
    unit: str
    definition: str
    ansur: str


def _m(kind: str, definition: str, ansur: str, unit: str = "m") -> Measurement:
    return Measurement(kind, unit, " ".join(definition.split()), ansur)


H = "Vertical distance from the floor (the body's lowest vertex) to"
MEASUREMENTS: dict[str, Measurement] = {
    # ---------------------------------------------------------------- heights
    "stature": _m("height", f"{H} the top of the head (highest head vertex).", "stature"),
    "cervicaleheight": _m("height", f"{H} the Cervicale landmark (C7).", "cervicaleheight"),
    "suprasternaleheight": _m(
        "height", f"{H} the Suprasternale landmark (jugular notch).", "suprasternaleheight"
    ),
    "acromialheight": _m("height", f"{H} the Acromion landmark.", "acromialheight"),
    "chestheight": _m(
        "height", f"{H} the chest at nipple (Thelion) level, mean of both sides.", "chestheight"
    ),
    "waistheightomphalion": _m(
        "height", f"{H} the Omphalion landmark (centre of the navel).", "waistheightomphalion"
    ),
    "iliocristaleheight": _m(
        "height",
        f"{H} the Iliocristale landmark (top of the iliac crest; the measurement landmark of "
        "core.measure.landmarks, 31 mm above the template's CAESAR vertex).",
        "iliocristaleheight",
    ),
    "trochanterionheight": _m(
        "height", f"{H} the Trochanterion landmark (greater trochanter).", "trochanterionheight"
    ),
    "buttockheight": _m(
        "height",
        f"{H} the Buttock landmark (maximum posterior protrusion of the buttock).",
        "buttockheight",
    ),
    "crotchheight": _m("height", f"{H} the Crotch landmark.", "crotchheight"),
    "kneeheightmidpatella": _m(
        "height", f"{H} the Patella landmark (midpoint of the kneecap).", "kneeheightmidpatella"
    ),
    "lateralfemoralepicondyleheight": _m(
        "height",
        f"{H} the lateral femoral epicondyle landmark (the measurement landmark of "
        "core.measure.landmarks, 31 mm above the template's CAESAR vertex).",
        "lateralfemoralepicondyleheight",
    ),
    "lateralmalleolusheight": _m(
        "height", f"{H} the lateral malleolus landmark.", "lateralmalleolusheight"
    ),
    # ---------------------------------------------------------------- circumferences
    "chestcircumference": _m(
        "circumference",
        """Horizontal circumference of the trunk at the level of the nipples (mean height of
        Thelion L/R; ANSUR: bustpoint/nipple level): convex-hull perimeter of the horizontal
        section of the body without arms and hands (template parts).""",
        "chestcircumference",
    ),
    "waistcircumference": _m(
        "circumference",
        """Horizontal circumference of the trunk at the level of the Omphalion (ANSUR's
        waist, omphalion): convex-hull perimeter of the horizontal section without arms and
        hands.""",
        "waistcircumference",
    ),
    "buttockcircumference": _m(
        "circumference",
        """Horizontal circumference of the trunk at the level of the maximum posterior
        protrusion of the buttock (Buttock landmark): convex-hull perimeter of the horizontal
        section without arms and hands (both legs together, as the tape goes).""",
        "buttockcircumference",
    ),
    "neckcircumference": _m(
        "circumference",
        """Circumference of the neck just below the laryngeal prominence, perpendicular to the
        long axis of the neck. The template has no larynx landmark, so: the smallest
        convex-hull perimeter of the neck loop in planes normal to the rig's neck axis (neck01
        -> head joint), between the plane through Cervicale (C7, the back of the neck's base)
        and the one through Menton (below the chin): the tape sits at the narrowest part of
        the neck, just under the larynx.""",
        "neckcircumference",
    ),
    "thighcircumference": _m(
        "circumference",
        """Maximum horizontal circumference of the thigh just below the gluteal furrow: the
        largest convex-hull perimeter of horizontal sections of that leg (thigh + pelvis
        parts) from 1 % of stature below the Crotch down to a quarter of the way to the knee;
        where the thighs touch, the section is cut at the mid-sagittal plane.""",
        "thighcircumference",
    ),
    "lowerthighcircumference": _m(
        "circumference",
        """Horizontal circumference of the thigh just above the kneecap: section at the
        Patella landmark height plus 12 % of the Patella-Crotch height.""",
        "lowerthighcircumference",
    ),
    "calfcircumference": _m(
        "circumference",
        """Maximum horizontal circumference of the calf: the largest convex-hull perimeter of
        horizontal sections of the shin between 10 % and 60 % of the way from the knee joint
        down to the lateral malleolus.""",
        "calfcircumference",
    ),
    "anklecircumference": _m(
        "circumference",
        """Minimum horizontal circumference of the ankle just above the malleoli: smallest
        convex-hull perimeter of horizontal sections of the lower leg between 8 % and 35 %
        of the way from the higher malleolus up to the knee joint.""",
        "anklecircumference",
    ),
    "bicepscircumferenceflexed": _m(
        "circumference",
        """Maximum circumference of the upper arm perpendicular to its axis (rig shoulder ->
        elbow joints), searched over 35-75 % of the way from shoulder to elbow. ANSUR
        measures the biceps FLEXED (fist clenched, elbow at 90 degrees); bodies here are
        relaxed, so this reads lower than ANSUR (relaxed arm circumference).""",
        "bicepscircumferenceflexed",
    ),
    "forearmcircumferenceflexed": _m(
        "circumference",
        """Maximum circumference of the forearm perpendicular to its axis (rig elbow -> wrist
        joints), searched over 10-50 % of the way from elbow to wrist. ANSUR measures it with
        the elbow flexed and fist clenched; here relaxed.""",
        "forearmcircumferenceflexed",
    ),
    "wristcircumference": _m(
        "circumference",
        """Circumference of the wrist at the styloid processes, perpendicular to the forearm
        axis: plane through the midpoint of the radial and ulnar styloid landmarks, normal to
        the rig's elbow -> wrist axis.""",
        "wristcircumference",
    ),
    "headcircumference": _m(
        "circumference",
        """Maximum circumference of the head just above the brow ridges: the plane through
        Glabella and Opisthocranion containing the head's left-right axis (Tragion R -> L);
        convex-hull perimeter of the head loop, ears excluded.""",
        "headcircumference",
    ),
    # ---------------------------------------------------------------- breadths and depths
    "biacromialbreadth": _m(
        "breadth",
        "Horizontal distance between the Acromion L and R landmarks.",
        "biacromialbreadth",
    ),
    "chestbreadth": _m(
        "breadth",
        """Horizontal breadth of the trunk at nipple level: extent of the chest section
        (arms excluded) along the body's left-right axis. This is the skin surface's breadth,
        which the latissimus behind the arms sets; ANSUR II's beam caliper reads the rib cage
        under the arms and is narrower: on bodies of the default shape model this reads
        ~25 mm (women) / ~58 mm (men) more than ANSUR's column (bench.shapespace), while the
        chest circumference and depth agree with ANSUR's.""",
        "chestbreadth",
    ),
    "chestdepth": _m(
        "depth",
        "Horizontal depth of the trunk at nipple level: extent of the chest section front-back.",
        "chestdepth",
    ),
    "waistbreadth": _m(
        "breadth",
        "Horizontal breadth of the trunk at Omphalion level (waist section, left-right extent).",
        "waistbreadth",
    ),
    "waistdepth": _m(
        "depth",
        "Horizontal depth of the trunk at Omphalion level (waist section, front-back extent).",
        "waistdepth",
    ),
    "buttockdepth": _m(
        "depth",
        "Horizontal depth of the trunk at the buttock level (buttock section, front-back extent).",
        "buttockdepth",
    ),
    "hipbreadth": _m(
        "breadth",
        """Maximum horizontal breadth of the hips: left-right extent of the trunk and thigh
        vertices (arms excluded) between the Crotch and Iliocristale heights, which contains
        the trochanter level.""",
        "hipbreadth",
    ),
    "headbreadth": _m(
        "breadth",
        "Maximum breadth of the head (ears excluded) along the head's left-right axis.",
        "headbreadth",
    ),
    "headlength": _m("length", "Straight distance from Glabella to Opisthocranion.", "headlength"),
    "bimalleolarbreadth": _m(
        "breadth",
        "Distance between the lateral and medial malleolus landmarks of one ankle.",
        "bimalleolarbreadth",
    ),
    # ---------------------------------------------------------------- lengths
    "acromionradialelength": _m(
        "length",
        """Straight distance from the Acromion to the Radiale landmark (upper arm length).""",
        "acromionradialelength",
    ),
    "radialestylionlength": _m(
        "length",
        """Straight distance from the Radiale to the radial styloid landmark (stylion;
        forearm length). Arm length = acromionradialelength + radialestylionlength.""",
        "radialestylionlength",
    ),
    "footlength": _m(
        "length",
        """Maximum length of the foot parallel to its long axis: extent of the foot's
        vertices along the horizontal direction from the heel (Calcaneus posterior) to the
        toe tip.""",
        "footlength",
    ),
    # ---------------------------------------------------------------- mass
    "weightkg": _m(
        "mass",
        """Body mass = enclosed mesh volume (divergence theorem over the closed template
        mesh) x density (default 1010 kg/m^3; to be calibrated on training data). ANSUR
        stores tenths of a kg; this is kg.""",
        "weightkg",
        unit="kg",
    ),
}
