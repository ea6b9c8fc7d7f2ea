"""Body-prior initialisation: personalise and pose the template before the per-vertex affine fit.

The affine-per-vertex energy says nothing about *where along the surface* a vertex belongs in
smooth regions (thighs, back, shins): that comes from the markers and the template. A template
that already has the subject's proportions and posture gives much better correspondences. We fit

    X(c, ω, S) = S( LBS( V0 + U c ; ω ) )

to the markers and the scan (point-to-plane) by damped Gauss–Newton with correspondence updates:
``U c`` a linear shape basis (principal directions of the CC0 MakeHuman shape targets: sex, age,
muscle, weight, height, proportions, regional targets) with a Gaussian prior on ``c``; ``ω`` small
rotations of the major bones of the standard rig (linear blend skinning, joints re-placed on the
shaped body); ``S`` a similarity. The affine fit then starts from that body.

The shape space enters through one interface, :class:`ShapeBasis` (mean body, orthonormal basis,
prior variances): the MakeHuman basis (:func:`load_shape_basis`, centred on the caller's template)
or a learned PCA shape space of registered bodies (paper §4; :meth:`ShapeBasis.from_pca`,
:meth:`core.shapespace.model.ShapeModel.shape_basis`). The full fit (``PriorOptions.basis``),
the markers-only fit (``fit_markers_only(basis=...)``) and the markerless search all hand it to
:func:`fit_body_prior`.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from core.geometry import row_norms
from core.registration.correspondence import ScanIndex, other_foot_matches
from core.registration.foot_end import FootLength, correct_foot_lengths, toe_allowance
from core.registration.hand_length import HandLength, correct_hand_lengths
from core.registration.initialization import Similarity, umeyama
from core.registration.operators import vertex_normals
from core.rig import Rig, bone_transforms, finger_rotations, joint_positions, load_rig
from core.template import load_template

if TYPE_CHECKING:
    from core.shapespace.pca import PCA

# Bones whose rotation the prior estimates (the rest follow their parents).
POSE_BONES = (
    "spine03", "spine01", "neck01", "head",
    "clavicle.L", "clavicle.R", "upperarm01.L", "upperarm01.R", "lowerarm01.L", "lowerarm01.R",
    "wrist.L", "wrist.R", "upperleg01.L", "upperleg01.R", "lowerleg01.L", "lowerleg01.R",
    "foot.L", "foot.R",
)  # fmt: skip


@dataclass(frozen=True)
class ShapeBasis:
    """A linear shape space as the body prior uses it: rest body ``mean + U c``, ``c ~ N(0, σ²)``.

    U : (n, 3, k) float64 basis displacements, metres per unit coefficient (orthonormal).
    sigma : (k,) float64 prior standard deviation of each coefficient (metres).
    mean : (n, 3) float64 body the basis is centred on, metres, template order and rest pose;
        ``None``: the template the caller fits (the MakeHuman basis is a set of displacements of
        the template).
    """

    U: np.ndarray
    sigma: np.ndarray
    mean: np.ndarray | None = None

    @property
    def k(self) -> int:
        return self.U.shape[2]

    @property
    def variances(self) -> np.ndarray:
        """(k,) prior variance of each coefficient, m²."""
        return self.sigma**2

    @classmethod
    def from_pca(cls, pca: PCA, k: int | None = None) -> ShapeBasis:
        """The first ``k`` (default all) components of a learned PCA shape space
        (``core.shapespace.pca.PCA``: mean, orthonormal components, variances of the weights)."""
        k = pca.k if k is None else min(int(k), pca.k)
        n = pca.n_vertices
        U = np.asarray(pca.components[:k], dtype=np.float64).T.reshape(n, 3, k)
        mean = np.asarray(pca.mean, dtype=np.float64).reshape(n, 3)
        return cls(U=U, sigma=np.sqrt(np.asarray(pca.variances[:k], dtype=np.float64)), mean=mean)


BASIS_ASSET = Path(__file__).resolve().parents[1] / "assets" / "shape_basis.npz"


def compute_shape_basis(k: int = 60) -> ShapeBasis:
    """The top-``k`` principal directions of the committed MakeHuman target library."""
    from core.synth.targets import N_VERTICES, load_targets

    lib = load_targets()
    names = lib.names
    rows, cols, vals = [], [], []
    for j, name in enumerate(names):
        idx, d = lib.sparse(name)
        rows.append((3 * idx[:, None] + np.arange(3)).ravel())
        cols.append(np.full(d.size, j))
        vals.append(d.ravel())
    D = np.zeros((N_VERTICES * 3, len(names)), dtype=np.float32)
    D[np.concatenate(rows), np.concatenate(cols)] = np.concatenate(vals)
    # principal directions via the small Gram matrix: D = U S Vᵀ, DᵀD = V S² Vᵀ
    G = (D.T @ D).astype(np.float64)
    ev, Vr = np.linalg.eigh(G)
    order = np.argsort(ev)[::-1]
    k = min(k, int(np.sum(ev > 1e-12 * ev.max())))
    S = np.sqrt(ev[order[:k]])
    U = (D @ Vr[:, order[:k]].astype(np.float32)).astype(np.float64) / S
    U, _ = np.linalg.qr(U)  # re-orthonormalise (float32 products above)
    # Targets are used at weights of order 1 (and combined); σ = singular value / sqrt(count).
    sigma = S.astype(np.float64) / np.sqrt(len(names)) * 2.0
    return ShapeBasis(U=U.reshape(N_VERTICES, 3, k), sigma=sigma)


def write_shape_basis(path: Path = BASIS_ASSET, k: int = 60) -> None:
    """Store the basis compactly (float16 directions; re-orthonormalised on load)."""
    b = compute_shape_basis(k)
    np.savez_compressed(path, U=b.U.astype(np.float16), sigma=b.sigma)


@cache
def load_shape_basis(k: int = 60) -> ShapeBasis:
    """The shape basis (cached): from ``core/assets/shape_basis.npz`` when it holds ≥ k
    directions, else computed from the target library (~1 s)."""
    if BASIS_ASSET.exists():
        with np.load(BASIS_ASSET) as z:
            U16, sigma = z["U"], z["sigma"]
        if U16.shape[2] >= k:
            n = U16.shape[0]
            U, _ = np.linalg.qr(U16[:, :, :k].astype(np.float64).reshape(n * 3, k))
            # keep each direction's sign (QR may flip it)
            ref = U16[:, :, :k].reshape(n * 3, k).astype(np.float64)
            U *= np.sign(np.sum(U * ref, axis=0))
            return ShapeBasis(U=U.reshape(n, 3, k), sigma=sigma[:k].astype(np.float64))
    return compute_shape_basis(k)


#: Prior on the *total* rotation of the distal arm bones, ``(bone, bend, twist)`` weights per
#: radian² in units of one data row (m²): scanning postures keep the wrists straight and the elbows
#: near the rest pose's flexion; without it the hands of arms close to the body followed thigh
#: data (wrists bent 95-175°, hands 5-28 cm off: ``core.synth.scanner_outputs`` closed_hair-1,
#: cloud-6, closed_lowres-16, closed_touching-5/17). Twist (pronation) is left nearly free.
BONE_PRIOR: tuple[tuple[str, float, float], ...] = (
    ("wrist.L", 0.1, 0.01), ("wrist.R", 0.1, 0.01),
    ("lowerarm01.L", 0.03, 0.003), ("lowerarm01.R", 0.03, 0.003),
)  # fmt: skip
#: The markerless fit's prior on the head's and neck's total rotation (same units as
#: :data:`BONE_PRIOR`, added to it): scanning postures keep the head facing forward, and a nearly
#: round skull's data barely turn it, so without markers the fit left heads flexed or turned
#: 40-69° on their data (``core.synth.scanner_outputs`` raw-19, closed_plate-27, raw_clutter-10:
#: 64-107 mm off the truth). 0.03 turned them back only to 28-53° (raw-19 still 73 mm off); 0.1
#: on the head bone alone left raw-19 at 47° (74 mm); 0.1 on head and neck01: 17-24°, 13-29 mm.
HEAD_PRIOR: tuple[tuple[str, float, float], ...] = (("neck01", 0.1, 0.1), ("head", 0.1, 0.1))
#: The markerless fit's prior on the clavicles' total rotation (same units, added to
#: :data:`BONE_PRIOR`) in its soft-marker round only: the data barely split a shoulder's turn
#: between clavicle and upper arm, and the first shape-space fit turned clavicles 15-33° with
#: the upper arms turned back against them (``core.synth.scanner_outputs`` closed_plate-15: its
#: Acromion 83 mm off the truth's). In every shape-space fit it cost the T-poses (a real T-pose
#: raises the clavicles too: ``bench.realworld --wide`` 9.52 -> 9.89 mm); in the round only the
#: landmarks gained everywhere (``bench/README.md``, stops 30-32).
CLAVICLE_PRIOR: tuple[tuple[str, float, float], ...] = (
    ("clavicle.L", 0.1, 0.1), ("clavicle.R", 0.1, 0.1),
)  # fmt: skip
#: The markerless fit's prior on the thighs' twist about their own axis (same units, added to
#: :data:`BONE_PRIOR`): a nearly cylindrical leg's data barely turn it, and the fits of the closed
#: and the raw delivery of one body twisted the legs 5-18° from the truth, differently.
#: Measured (``bench.realworld``, 40 cases): correspondence 10.81 -> 10.56 mm, closed-vs-raw twins
#: 6.5 -> 6.3 mm mean, no verdict changed; held-in ``bench.matching`` 3.44 -> 3.48 mm. 0.3 on
#: thighs and shins turned raw-4's legs round (correspondence 6.8 -> 24.9 mm).
LEG_TWIST_PRIOR: tuple[tuple[str, float, float], ...] = (
    ("upperleg01.L", 0.0, 0.1), ("upperleg01.R", 0.0, 0.1),
)  # fmt: skip
#: The markerless fit's prior on the feet's total rotation (same units, added to
#: :data:`BONE_PRIOR`): standing people point their feet forward and flat, but where two feet
#: stand close a coarse closed mesh fuses them and their data barely tell one foot's direction:
#: closed_lowres-4 of ``core.synth.scanner_outputs`` meshed on a 17 mm grid (8 k vertices, feet
#: 2 cm apart) turned its left foot 77-100° (135 mm off the truth's); with 0.05 12 mm.
FOOT_PRIOR: tuple[tuple[str, float, float], ...] = (
    ("foot.L", 0.05, 0.05), ("foot.R", 0.05, 0.05),
)  # fmt: skip


#: Limb chains ``(root, middle, end)`` (rig bones whose heads are the shoulder, elbow and wrist
#: joints) whose middle joint :func:`fit_body_prior` keeps near its template share of the way
#: from root to end (``limb_prior``).
LIMB_CHAINS: tuple[tuple[str, str, str], ...] = (
    ("upperarm01.L", "lowerarm01.L", "wrist.L"), ("upperarm01.R", "lowerarm01.R", "wrist.R"),
)  # fmt: skip
#: Chains ``(root, middle, end)`` whose middle joint the trunk prior (``fit_body_prior(
#: trunk_prior=)``) keeps near its template share of the way: the spine's joints between the
#: pelvis (``root``) and the neck.
TRUNK_CHAINS: tuple[tuple[str, str, str], ...] = tuple(
    ("root", f"spine0{i}", "neck01") for i in (4, 3, 2, 1)
)
#: Weight of the trunk prior (per m², as :data:`LIMB_PRIOR`) in the markerless fit's
#: soft-marker round. A heavy body's data barely tell where on the belly its skin lies, and the
#: shape space's fat slid the waist's skin down the belly (``core.synth.scanner_outputs``
#: closed_lowres-69, BMI 49: navel 80 mm and iliac crests 92 mm off the truth's, the waist's
#: spine joint 52 mm low; 42 and 61 mm with it). ``bench.realworld`` (correspondence;
#: landmarks mm): heavy 20 16.78 -> 16.58; 19.25 -> 18.97 (navel 49 -> 34), booth 40 14.26 ->
#: 14.04; 13.67 -> 13.44, varied 40 9.07 -> 8.89; 9.96 -> 9.77, wide 24 9.46 -> 9.25; 11.06 ->
#: 10.68. In every shape-space fit too: heavy 17.01 (landmarks 18.21), the limbs worse.
TRUNK_PRIOR = 100.0
#: Curl (degrees per finger joint) of a fisted hand in the body prior (``fit_body_prior(fists=)``):
#: the middle of the 55-80° of ``core.synth.realworld``'s fists.
FIST_CURL_DEG = 70.0
#: Weight of the limb-proportion prior (``fit_body_prior(limb_prior=)``) of the markerless fit,
#: per m² of the elbow's offset along the shoulder→wrist axis from its template share, in units
#: of one data row (100-10 000 give the same arms on raw-16/28 and closed_lowres-24; markers
#: place the elbows of a marker fit, whose default is 0).
LIMB_PRIOR = 100.0
#: Plausible rest lengths of the arm's bones per stature (joint to joint: ``upperarm01`` →
#: ``lowerarm01`` → ``wrist``; stature: the rest body's height), ``{bone: (low, high)}``. ANSUR
#: II (dev split) reads forearm (radiale–stylion) / stature 0.129–0.176 in all 4 082 soldiers
#: (mean 0.150, SD 0.0065, ±4 %) and upper arm (acromion–radiale, from the acromion above the
#: joint) 0.171–0.214; the off-model bodies of ``core.synth.realworld`` (bones ±7 %), joint to
#: joint, 0.138–0.169 and 0.126–0.162. The upper arm's band holds all of them with a margin.
#: The forearm's runs from the shape space's mean joint-to-joint forearm (0.135 of the stature)
#: − 2.6 ANSUR SDs of the ratio to :data:`ARM_BONE_CENTRES`' (0.145) + 3: where the data cannot
#: tell the forearm's length (an arm fused to the flank in a closed mesh) the fit stops at
#: 0.165, not at 0.18 (closed_booth-339: rest forearm 0.18 of the stature, truth 0.137). It was
#: 0.118-0.152 (stop 31), which held a real-sized forearm short (below, ARM_BONE_CENTRES).
ARM_BONE_RATIOS: dict[str, tuple[float, float]] = {
    "upperarm01": (0.125, 0.185), "lowerarm01": (0.118, 0.165),
}  # fmt: skip
#: Plausible rest lengths of the thigh per stature (joint to joint: ``upperleg01`` →
#: ``lowerleg01``, the knee). ANSUR II (dev split) reads thigh (trochanterion height − lateral
#: femoral epicondyle height) / stature 0.233 (SD 0.012, both sexes; 0.184–0.286); the band is
#: that ± 2.6 SDs shifted by the template's joint-to-joint thigh over its landmark thigh (0.253
#: vs 0.245). Off-model heavy bodies fitted without it had thighs of 0.19–0.20 (truths
#: 0.23–0.24: ``bench.realworld`` closed_booth-305 / -339, their hips 30–58 mm low and knees
#: 35–44 mm high — the skin of the shape space's fat slid along the thigh).
LEG_BONE_RATIOS: dict[str, tuple[float, float]] = {"upperleg01": (0.210, 0.272)}
#: Every bone the bone length prior holds in a band (``fit_body_prior(bone_length_prior=)``).
BONE_LENGTH_RATIOS: dict[str, tuple[float, float]] = {**ARM_BONE_RATIOS, **LEG_BONE_RATIOS}
#: The joint at each such bone's far end (its length: head to that joint).
BONE_CHILD_JOINTS = {"upperarm01": "lowerarm01", "lowerarm01": "wrist", "upperleg01": "lowerleg01"}
#: A weight (per m², in units of one data row, as :data:`LIMB_PRIOR`) for the bone length prior
#: (``fit_body_prior(bone_length_prior=)``; the markerless fit's soft-marker round uses it): a
#: bone's rest length beyond its :data:`BONE_LENGTH_RATIOS` band of the stature, and the left
#: and right bones' difference (the limbs of one body are alike within ~2 %). In the round only
#: (``bench.realworld``, correspondence mean mm from 6c1256d): the arms' bands, booth 40 15.57
#: -> 14.73 (closed_booth-339 37.8 -> 21.8, -304 18.0 -> 7.5, -314 15.2 -> 20.3), heavy 20
#: 17.70 -> 17.20, varied 40 8.95 -> 8.98; with :data:`ARM_BONE_CENTRES` for resting hands,
#: booth 14.14, heavy 17.00, varied 9.13; with the thigh's band, booth 14.30 (landmarks 14.72
#: -> 14.58), heavy 16.77 (landmarks 20.50 -> 19.92, closed_lowres-89 suspect -> good), varied
#: 9.10 (landmarks 10.57 -> 10.46). Earlier, the wide forearm band (0.115–0.170) in every
#: markerless stage (on 6a498d7): booth 19.95 -> 19.45, varied 10.46 -> 10.38, heavy 22.54 ->
#: 22.75, and at 10 000 per m² the heavy set broke (22.54 -> 32.80): the prior acts on the
#: global shape coefficients, which also shape legs and trunk.
BONE_LENGTH_PRIOR = 100.0
#: Rest length per stature an arm's bones are pulled to where the data cannot tell it
#: (``fit_body_prior(bone_length_centred=)``: a band of no width): a real adult's forearm in the
#: rig's joint-to-joint terms. Not the shape space's mean (0.1354 ± 0.0088 over 300 random
#: bodies; the template's 0.1359): the template's span is 0.958 of its stature, ANSUR II's
#: soldiers' 1.022 ± 0.029 (women) / 1.033 ± 0.027 (men), and the off-model bodies of
#: ``core.synth.realworld``, whose span is ANSUR's (1.027 ± 0.037), have forearms of 0.143 ±
#: 0.007; the template's arm chain scaled to ANSUR's span gives 0.148. The markerless fit's
#: soft-marker round centres the forearm of an arm whose hand rests on the body (fused to the
#: thigh in a closed mesh). ``bench.realworld`` (correspondence; landmarks mm), 0.135 -> 0.145
#: with the forearm band to 0.165: booth 40 14.04 -> 13.88; 13.44 -> 13.50 (closed_booth-311
#: 17.0 -> 13.2, -317 17.2 -> 12.7, -322 16.2 -> 13.6, -323 13.4 -> 9.5; -315 17.8 -> 21.1),
#: varied 40 8.89 -> 8.73; 9.77 -> 9.61 (cloud-6 16.8 -> 11.2, its truth's forearm 0.161),
#: wide 24 9.25 -> 9.17; 10.68 -> 10.63, heavy 20 16.58 -> 16.70; 18.97 -> 18.78.
ARM_BONE_CENTRES: dict[str, float] = {"lowerarm01": 0.145}
#: Rest length per stature each thigh is pulled towards (``fit_body_prior(
#: leg_length_centre=)``): the middle of :data:`LEG_BONE_RATIOS`' band (ANSUR II's mean thigh
#: in the rig's joint-to-joint terms). Without markers the shape space fits a leg's surface
#: 0.3-1.7 mm closer by sliding the upper thigh's skin 4-8 cm down the thigh (the crotch,
#: trochanter and hip joint with it), a shape further from the mean (Mahalanobis 14-15 vs
#: 10-11) than the body's best correspondence-aware shape in the space: off-model thighs came
#: out 0.206-0.214 of the stature (truths 0.230-0.237; ``core.synth.scanner_outputs``
#: closed_booth-310/331/337, raw-4), even from a clean rest-pose mesh of the truth (0.214 vs
#: 0.232).
LEG_BONE_CENTRES: dict[str, float] = {"upperleg01": 0.241}
#: The markerless soft-marker round's weight (per m², in units of one data row, a tenth of
#: :data:`BONE_LENGTH_PRIOR`) of the thighs' pull to :data:`LEG_BONE_CENTRES`
#: (``bench.realworld``, landmarks / correspondence mean mm): booth 40 14.47 -> 13.67 / 14.25
#: -> 14.26 (Trochanterion 39.8 -> 31, verdicts good 17 -> 19), varied 40 10.34 -> 9.96 / 9.10
#: -> 9.07, wide 24 11.59 -> 11.06 / 9.60 -> 9.46, heavy 20 19.75 -> 19.25 / 16.75 -> 16.78.
#: At 100 the knees came down instead (Patella 15 mm low): booth 13.80 / 14.35.
LEG_CENTRE_PRIOR = 10.0


def arm_pose(abduction_deg: float, sides: str = "LR") -> dict[str, np.ndarray]:
    """Local rotations of the upper arms of ``sides`` (``"L"``, ``"R"`` or both) that put them
    ``abduction_deg`` from the body's side (the template's own abduction,
    :func:`template_arm_abduction`, is undone): a start for :func:`fit_body_prior`."""
    from core.rig import axis_angle

    z = np.array([0.0, 0.0, 1.0])
    d = np.radians(abduction_deg - template_arm_abduction())
    return {f"upperarm01.{x}": axis_angle(z, d if x == "L" else -d) for x in sides}


@cache
def template_arm_abduction() -> float:
    """Degrees between the template's left upper arm (shoulder → elbow joint) and −Y."""
    rig = load_rig()
    J = joint_positions(load_template().V, rig=rig)
    d = J[rig.index("lowerarm01.L")] - J[rig.index("upperarm01.L")]
    return float(np.degrees(np.arctan2(d[0], -d[1])))


@dataclass(frozen=True)
class PriorOptions:
    """Tuning of :func:`fit_body_prior` (its keyword arguments of the same names and defaults).

    ``PriorOptions.of(d)`` accepts a dict too (unknown names: ``TypeError`` naming them).
    """

    iterations: int = 12
    shape_prior_weight: float = 1.0
    pose_prior_weight: float = 1e-3
    marker_weight: float = 4.0
    marker_scale: float = 0.03
    marker_scale_start: float = 0.3
    subsample: int = 3
    template_row_weight: float = 1.0
    k_schedule: tuple[int, ...] | None = None
    bidirectional: bool = False
    freeze_pose: int = 0
    scan_sample: int = 4000
    scan_oversample: int = 1
    initial_pose: dict[str, np.ndarray] | None = None
    initial_coefficients: np.ndarray | None = None
    max_angle_deg: float = 60.0
    point_weight: float = 0.0
    basis: ShapeBasis | None = None
    bone_prior: tuple[tuple[str, float, float], ...] = BONE_PRIOR
    limb_prior: float = 0.0
    trunk_prior: float = 0.0
    bone_length_prior: float = 0.0
    bone_length_centred: str = ""
    leg_length_centre: float = 0.0
    fists: str = ""
    floor_y: float | None = None
    hand_length: bool = False
    foot_length: bool = False
    sole_data: bool = True
    upright: bool = False

    @classmethod
    def of(cls, value: PriorOptions | dict | None) -> PriorOptions:
        if value is None:
            return cls()
        if isinstance(value, cls):
            return value
        unknown = sorted(set(value) - set(cls.__dataclass_fields__))
        if unknown:
            raise TypeError(f"unknown body-prior options: {', '.join(unknown)}")
        d = dict(value)
        if d.get("k_schedule") is not None:
            d["k_schedule"] = tuple(d["k_schedule"])
        if d.get("bone_prior") is not None:
            d["bone_prior"] = tuple((str(b), float(x), float(y)) for b, x, y in d["bone_prior"])
        return cls(**d)

    def kwargs(self) -> dict:
        """The options as keyword arguments of :func:`fit_body_prior`."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass
class PriorFit:
    """Result of :func:`fit_body_prior`: the posed, personalised template in the scan frame.

    X : (n, 3) metres, scan frame. rest : (n, 3) the shaped body in the template frame, unposed.
    """

    X: np.ndarray
    rest: np.ndarray
    coefficients: np.ndarray
    pose: dict[str, np.ndarray]
    similarity: Similarity
    iterations: int
    rms_marker_m: float
    rms_data_m: float
    marker_residuals_m: np.ndarray  # (km,) per marker, after the fit
    data_cost_m: float  # rms template→scan distance, unmatched counted as 5 cm (NaN: unmeasured)
    coverage: float  # share of (sampled, data-eligible) vertices matched within 1.5 cm (or NaN)
    marker_weights: np.ndarray  # (km,) final robust weight of each marker, fraction of full
    hand_lengths: list[HandLength] = field(default_factory=list)  # hands set to their length
    foot_lengths: list[FootLength] = field(default_factory=list)  # feet set to their length
    #: mean vertex displacement of the last iteration (metres, scan frame): how far from
    #: converged the fit stopped
    last_step_m: float = float("nan")


def marker_weights(
    residuals: np.ndarray,
    iteration: int,
    iterations: int,
    scale_start: float,
    scale_end: float,
    floor: np.ndarray,
) -> np.ndarray:
    """Annealed Cauchy weights in [0, 1] of markers with ``residuals`` (km,) metres.

    ``w = max(floor, 1 / (1 + (r / s)²))`` with ``s`` going geometrically from ``scale_start``
    (iteration 0) to ``scale_end`` (iteration ``iterations // 2`` and later).
    """
    half = max(1, iterations // 2)
    t = min(1.0, iteration / half)
    s = scale_start * (scale_end / scale_start) ** t
    return np.maximum(floor, 1.0 / (1.0 + (np.asarray(residuals) / s) ** 2))


def _scan_to_template(
    index: ScanIndex,
    X: np.ndarray,
    N: np.ndarray,
    cand: np.ndarray,
    max_distance: float,
    n_sample: int,
    min_cos: float = 0.5,
    explained: np.ndarray | None = None,
    oversample: int = 1,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pairs (template vertex, scan point, weight, scan normal) from a fixed scan sample: each
    scan point with its closest compatible vertex of ``cand``. ``n_sample``: the direction's
    weight in unit rows; ``oversample`` times as many points are paired (spread over the scan's
    surface by area, :meth:`ScanIndex.spread_sample`), each weighing its share (at most 1).

    ``explained``: vertices that take no data (the template's regions that scan badly: fingers,
    toes, ears) but explain the scan points closest to them: such a point makes no pair, where
    it would otherwise pull the nearest data vertex over it (a closed mesh's mitten pulled the
    palm, and with it the hand, 5-31 mm down the forearm's axis).
    """
    pts = index.points
    sel = index.spread_sample(oversample * n_sample)
    share = min(1.0, n_sample / len(sel))
    n_data = len(cand)
    allc = cand if explained is None else np.r_[cand, explained]
    tree = cKDTree(X[allc])
    Nc, Ns = N[allc], index.normals[sel]
    # the nearest vertex settles most points (where it is compatible the 4-nearest rule picks it
    # first; where it is out of range so are the rest): the 4-nearest query runs on the others
    d1, j1 = tree.query(pts[sel], k=1, distance_upper_bound=max_distance)
    valid1 = np.isfinite(d1)
    hit = np.where(valid1, j1, 0)
    has = valid1 & (np.einsum("sc,sc->s", Nc[hit], Ns) > min_cos)
    redo = np.flatnonzero(valid1 & ~has)
    if len(redo):
        d, j = tree.query(pts[sel[redo]], k=min(4, len(allc)), distance_upper_bound=max_distance)
        d, j = d.reshape(len(redo), -1), j.reshape(len(redo), -1)
        valid = np.isfinite(d)
        jj = np.where(valid, j, 0)
        ok = valid & (np.einsum("skc,sc->sk", Nc[jj], Ns[redo]) > min_cos)
        hit[redo] = jj[np.arange(len(redo)), np.argmax(ok, axis=1)]
        has[redo] = ok.any(axis=1)
    has &= hit < n_data
    v = allc[hit][has]
    p = sel[has]
    w = index.point_weight[p] * ~index.boundary[p] * share
    return v, pts[p], w, index.normals[p]


#: Weight of a floor row (:func:`floor_pairs`) relative to one point-to-plane data row.
FLOOR_WEIGHT = 10.0


def floor_pairs(
    X: np.ndarray, cand: np.ndarray, floor_y: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pairs (vertex, target, normal) holding the body ``X`` (n, 3, metres, +Y up) above the
    plane y = ``floor_y``: each vertex of ``cand`` below it, with its projection onto the plane
    and the plane's normal +Y (point-to-plane rows: free to slide along the floor)."""
    v = cand[X[cand, 1] < floor_y]
    P = X[v].copy()
    P[:, 1] = floor_y
    return v, P, np.tile([0.0, 1.0, 0.0], (len(v), 1))


class _Articulation:
    """LBS of a shaped body with per-bone local rotations, and its Jacobians."""

    def __init__(
        self, rig: Rig, bones: tuple[str, ...], fixed: dict[str, np.ndarray] | None = None
    ) -> None:
        self.rig = rig
        self.fixed = dict(fixed or {})  # bone -> local rotation held fixed (fingers of a fist)
        self.bones = [rig.index(b) for b in bones]
        self.names = bones
        J = rig.n_joints
        self.desc = np.zeros((len(bones), J), dtype=bool)
        for a, name in enumerate(bones):
            self.desc[a, rig.descendants(name)] = True
        self.r = rig.skin_rows.astype(np.int64)
        self.c = rig.skin_cols.astype(np.int64)
        self.w = rig.skin_vals.astype(np.float64)
        # (4J, 4B): joint j's sums -> pose bone a's (j below or at a), for W and y's 3 coordinates
        self.desc4 = np.kron(np.eye(4), self.desc.T.astype(np.float64))
        self.skin = sp.csr_matrix((self.w, (self.r, self.c)), shape=(rig.n_vertices, J))

    def pose(self, rest: np.ndarray, local: np.ndarray) -> tuple[np.ndarray, dict]:
        """Posed vertices (n, 3) and the quantities the Jacobian needs."""
        rig = self.rig
        joints = joint_positions(rest, rig=rig)
        rot = {**self.fixed, **{rig.names[j]: local[a] for a, j in enumerate(self.bones)}}
        # proper by construction (the prior's updates, core.rig.finger_rotations): not re-checked
        R, t = bone_transforms(rot, joints, rig=rig, validate=False)
        n = len(rest)
        # LBS Σ_b w_ib (R_b x_i + t_b) = (Σ_b w_ib R_b) x_i + Σ_b w_ib t_b: one sparse product
        Rt = self.skin @ np.hstack([R.reshape(-1, 9), t])  # (n, 12)
        Rb = Rt[:, :9].reshape(n, 3, 3)
        X = np.einsum("nab,nb->na", Rb, rest) + Rt[:, 9:]
        posed_joints = np.einsum("jab,jb->ja", R, joints) + t
        return X, {"rest": rest, "R": R, "t": t, "Rb": Rb, "pj": posed_joints, "n": n}

    def blended_rotations(self, aux: dict, rows: np.ndarray) -> np.ndarray:
        """Skin-weighted bone rotations Σ_b w_ib R_b at vertices ``rows``: (len(rows), 3, 3)."""
        return aux["Rb"][rows]

    def pose_jacobian(
        self, aux: dict, rows: np.ndarray, out: np.ndarray | None = None
    ) -> np.ndarray:
        """d X[rows] / d ω (world-frame rotation increments): (len(rows), 3, 3·B), written
        into ``out`` (a view of that shape, e.g. a slice of a larger Jacobian) when given."""
        n, nr, B, J = aux["n"], len(rows), len(self.bones), self.rig.n_joints
        pos = np.full(n, -1)
        pos[rows] = np.arange(nr)
        e = np.flatnonzero(pos[self.r] >= 0)
        # per row and pose bone a: W_a = Σ w_e and y_a = Σ w_e·moved_e over the row's skin
        # entries whose joint a carries: sums per (row, joint), then joints -> pose bones
        w, c = self.w[e], self.c[e]
        mv = np.einsum("eab,eb->ea", aux["R"][c], aux["rest"][self.r[e]]) + aux["t"][c]
        S = sp.csr_matrix(
            (np.r_[w, w * mv[:, 0], w * mv[:, 1], w * mv[:, 2]],
             (np.tile(pos[self.r[e]], 4), np.r_[c, c + J, c + 2 * J, c + 3 * J])),
            shape=(nr, 4 * J),
        )  # fmt: skip
        Y = S @ self.desc4  # (nr, 4B): W, y_x, y_y, y_z
        Wa, pj = Y[:, :B], aux["pj"][self.bones]
        vx, vy, vz = (Y[:, (k + 1) * B : (k + 2) * B] - Wa * pj[:, k] for k in range(3))
        if out is None:
            out = np.zeros((nr, 3, 3 * B))
        else:
            out[...] = 0.0
        # -[v]_× per bone, bone a in columns 3a..3a+2
        out[:, 0, 1::3], out[:, 0, 2::3] = vz, -vy
        out[:, 1, 0::3], out[:, 1, 2::3] = -vz, vx
        out[:, 2, 0::3], out[:, 2, 1::3] = vy, -vx
        return out


@cache
def _articulation() -> _Articulation:
    """The body prior's articulation of the standard rig (:data:`POSE_BONES`), built once."""
    return _Articulation(load_rig(), POSE_BONES)


def _fisted_articulation(V0: np.ndarray, fists: str) -> _Articulation:
    """The body prior's articulation with the fingers of ``fists`` (sides "L", "R") curled
    into a fist (:data:`FIST_CURL_DEG`, held fixed) on the body V0 (n, 3); the cached one
    when there are none."""
    art = _articulation()
    if not fists:
        return art
    art = copy.copy(art)
    J0 = joint_positions(V0, rig=art.rig)
    tails = joint_positions(V0, rig=art.rig, ends="tail")
    art.fixed = {  # a new dict: the cached articulation keeps its open hands
        name: R
        for x in fists
        for name, R in finger_rotations(
            J0, tails, f".{x}", True, FIST_CURL_DEG, rig=art.rig
        ).items()
    }
    return art


def fisted_rest(V0: np.ndarray, fists: str) -> np.ndarray:
    """(n, 3): the body V0 (n, 3, metres) in its rest pose with the hands of ``fists``
    (sides "L", "R") curled into the body prior's fist."""
    art = _fisted_articulation(V0, fists)
    return art.pose(V0, np.broadcast_to(np.eye(3), (len(POSE_BONES), 3, 3)).copy())[0]


def _bone_metrics(
    art: _Articulation, V0: np.ndarray, weights: tuple[tuple[str, float, float], ...]
) -> list[tuple[int, np.ndarray]]:
    """(bone slot, (3, 3) metric) per ``(bone, bend, twist)`` of ``weights``: ``bend`` weighs the
    part of the bone's total rotation vector (radians) across the bone's axis (joint → centroid of
    the vertices it and its descendants carry, at rest), ``twist`` the part along it."""
    if not weights:
        return []
    joints = joint_positions(V0, rig=art.rig)
    out = []
    for name, bend, twist in weights:
        if bend <= 0 and twist <= 0:
            continue
        a = art.names.index(name)
        j = art.bones[a]
        carried = np.flatnonzero(art.desc[a, art.c] & (art.w > 0.5))
        d = V0[np.unique(art.r[carried])].mean(axis=0) - joints[j]
        d /= np.linalg.norm(d)
        P = np.outer(d, d)
        out.append((a, bend * (np.eye(3) - P) + twist * P))
    return out


def _limb_rows(
    V0: np.ndarray, U: np.ndarray, rig: Rig, chains: tuple[tuple[str, str, str], ...] = LIMB_CHAINS
) -> tuple[np.ndarray, np.ndarray]:
    """Rows (m, k) and offsets (m,) of the limb-proportion prior: for each of ``chains``
    (:data:`LIMB_CHAINS`, :data:`TRUNK_CHAINS`), the middle joint's offset (metres) along the
    rest root→end axis from the point at the template's share of the way, ``G @ c + g0`` for
    shape coefficients ``c`` (joints are linear in the vertices: ``core.rig.joint_positions``)."""
    idx, w = rig.head_reg_idx, rig.head_reg_w

    def joint(name: str) -> tuple[np.ndarray, np.ndarray]:
        j = rig.index(name)
        return w[j] @ V0[idx[j]], np.einsum("q,qck->ck", w[j], U[idx[j]])

    G, g0 = [], []
    for a, b, e in chains:
        (pa, Ga), (pb, Gb), (pe, Ge) = joint(a), joint(b), joint(e)
        axis = pe - pa
        share = float((pb - pa) @ axis / (axis @ axis))
        u = axis / np.linalg.norm(axis)
        G.append(u @ (Gb - (1.0 - share) * Ga - share * Ge))
        g0.append(float(u @ (pb - (1.0 - share) * pa - share * pe)))
    return np.array(G), np.array(g0)


def _bone_length_terms(V0: np.ndarray, U: np.ndarray, rig: Rig) -> dict[str, Any]:
    """What :func:`_bone_length_rows` needs: per joint at either end of a bone of
    :data:`BONE_LENGTH_RATIOS` (:data:`BONE_CHILD_JOINTS`; each side) its rest position as
    ``p0 (3,) + G (3, k) @ c``; the stature as ``s0 + gs (k,) @ c`` (the rest body's highest
    vertex over its lowest)."""
    idx, w = rig.head_reg_idx, rig.head_reg_w
    joints = {}
    for side in "LR":
        for name in dict.fromkeys([*BONE_CHILD_JOINTS, *BONE_CHILD_JOINTS.values()]):
            j = rig.index(f"{name}.{side}")
            joints[f"{name}.{side}"] = (w[j] @ V0[idx[j]], np.einsum("q,qck->ck", w[j], U[idx[j]]))
    top, bottom = int(np.argmax(V0[:, 1])), int(np.argmin(V0[:, 1]))
    return {
        "joints": joints,
        "s0": float(V0[top, 1] - V0[bottom, 1]),
        "gs": U[top, 1] - U[bottom, 1],
    }


def _rest_bone_length(
    terms: dict[str, Any], c: np.ndarray, bone: str, side: str
) -> tuple[float, np.ndarray]:
    """A bone's rest length (metres, head to :data:`BONE_CHILD_JOINTS`' joint) at shape ``c``
    (k,) and its gradient (k,)."""
    (pa, Ga), (pb, Gb) = (
        terms["joints"][f"{bone}.{side}"],
        terms["joints"][f"{BONE_CHILD_JOINTS[bone]}.{side}"],
    )
    d = (pb + Gb @ c) - (pa + Ga @ c)
    length = float(np.linalg.norm(d))
    return length, (d / max(length, 1e-9)) @ (Gb - Ga)


def _leg_centre_rows(terms: dict[str, Any], c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residual rows (metres) of the thighs' pull to :data:`LEG_BONE_CENTRES` at shape ``c``
    (k,), linearised: Jacobian (m, k) and residuals (m,), a row per side and bone."""
    stature = terms["s0"] + terms["gs"] @ c
    J_all, r_all = [], []
    for bone, centre in LEG_BONE_CENTRES.items():
        for side in "LR":
            length, dL = _rest_bone_length(terms, c, bone, side)
            J_all.append(dL - centre * terms["gs"])
            r_all.append(length - centre * stature)
    return np.array(J_all), np.array(r_all)


def _bone_length_rows(
    terms: dict[str, Any], c: np.ndarray, centred: str = ""
) -> tuple[np.ndarray, np.ndarray]:
    """Residual rows (metres) of the bone length prior at shape ``c`` (k,), linearised:
    Jacobian (m, k) and residuals (m,). Per side and bone of :data:`BONE_LENGTH_RATIOS`, a row
    where the bone's rest length leaves its band of the stature (to the band's edge; for the
    ``centred`` sides' bones of :data:`ARM_BONE_CENTRES`, a row to that centre); per bone, the
    left minus the right length."""
    J_all, r_all = [], []
    stature = terms["s0"] + terms["gs"] @ c
    lengths: dict[tuple[str, str], tuple[float, np.ndarray]] = {}
    for side in "LR":
        for bone, (lo, hi) in BONE_LENGTH_RATIOS.items():
            if side in centred and bone in ARM_BONE_CENTRES:
                lo = hi = ARM_BONE_CENTRES[bone]
            length, dL = _rest_bone_length(terms, c, bone, side)
            lengths[(bone, side)] = (length, dL)
            for edge, outside in ((lo, length < lo * stature), (hi, length > hi * stature)):
                if outside:
                    J_all.append(dL - edge * terms["gs"])
                    r_all.append(length - edge * stature)
    for bone in BONE_LENGTH_RATIOS:
        (lL, dLL), (lR, dLR) = lengths[(bone, "L")], lengths[(bone, "R")]
        J_all.append(dLL - dLR)
        r_all.append(lL - lR)
    return np.array(J_all), np.array(r_all)


#: height (metres) above the template's soles below which its feet's downward faces take no
#: data without ``fit_body_prior(sole_data=)`` (:func:`sole_undersides`): booth software cuts
#: the soles flat 3-8 mm up (or fuses them with a floor plate), a raw scan's floor contact band
#: is cut or in shadow. The markerless fit's soft-marker round leaves them out
#: (``core.matching.markerless``): there the cut plane's rows lifted a closed mesh's feet.
SOLE_UNDERSIDE_M = 0.01


def sole_undersides(n: int) -> np.ndarray:
    """(n,) bool: the template's foot vertices less than :data:`SOLE_UNDERSIDE_M` above its soles
    whose normals point down (more than 60° from the horizontal); all False for another mesh."""
    tpl = load_template()
    if n != tpl.n_vertices:
        return np.zeros(n, bool)
    feet = tpl.part_mask("foot_L") | tpl.part_mask("foot_R")
    V = np.asarray(tpl.V, np.float64)
    N = vertex_normals(V, np.asarray(tpl.F, np.int64))
    return feet & (V[:, 1] < V[feet, 1].min() + SOLE_UNDERSIDE_M) & (N[:, 1] < -0.5)


def feet_sides(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(n,) int8 toe sides and foot sides of the template (1 left, 2 right, 0 elsewhere;
    :func:`core.registration.correspondence.other_foot_matches`); zeros for another mesh."""
    tpl = load_template()
    if n != tpl.n_vertices:
        return np.zeros(n, np.int8), np.zeros(n, np.int8)
    toes = np.asarray(tpl.mask("toes"), bool)
    foot = np.zeros(n, np.int8)
    for k, x in ((1, "L"), (2, "R")):
        foot[tpl.part_mask(f"foot_{x}")] = k
    return np.where(toes, foot, 0).astype(np.int8), foot


def fit_body_prior(
    index: ScanIndex | None,
    V0: np.ndarray,
    F: np.ndarray,
    marker_vid: np.ndarray,
    marker_pos: np.ndarray,
    sim: Similarity,
    *,
    data_mask: np.ndarray | None = None,
    basis: ShapeBasis | None = None,
    iterations: int = 12,
    max_distance: float = 0.10,
    shape_prior_weight: float = 1.0,
    pose_prior_weight: float = 1e-3,
    marker_weight: float = 4.0,
    marker_scale: float = 0.03,
    marker_scale_start: float = 0.3,
    marker_floor: np.ndarray | None = None,
    vertex_weight: np.ndarray | None = None,
    subsample: int = 3,
    template_row_weight: float = 1.0,
    k_schedule: tuple[int, ...] | None = None,
    bidirectional: bool = False,
    freeze_pose: int = 0,
    scan_sample: int = 4000,
    scan_oversample: int = 1,
    initial_pose: dict[str, np.ndarray] | None = None,
    initial_coefficients: np.ndarray | None = None,
    max_angle_deg: float = 60.0,
    point_weight: float = 0.0,
    bone_prior: tuple[tuple[str, float, float], ...] = BONE_PRIOR,
    limb_prior: float = 0.0,
    trunk_prior: float = 0.0,
    bone_length_prior: float = 0.0,
    bone_length_centred: str = "",
    leg_length_centre: float = 0.0,
    fists: str = "",
    floor_y: float | None = None,
    hand_length: bool = False,
    foot_length: bool = False,
    sole_data: bool = True,
    upright: bool = False,
    measure: bool = True,
) -> PriorFit:
    """Fit shape coefficients, bone rotations and a similarity to markers and scan.

    Parameters
    ----------
    index : the scan (metres, canonical frame), or None to fit the markers alone.
    V0 : (n, 3) template, metres; F : (m, 3) its triangles. A ``basis`` with a ``mean`` (a learned
        shape space) replaces V0 by that mean (same vertex order and triangles).
    marker_vid : (km,) template vertices of the markers; marker_pos : (km, 3) metres.
    sim : initial similarity (template → scan), e.g. from the markers.
    shape_prior_weight : weight of ‖c/σ‖² relative to the data (in units of one data row, mm²).
    pose_prior_weight : weight of ‖ω‖² (radians²) relative to one data row in m².
    marker_weight : weight of a marker coordinate relative to one point-to-plane data row.
    marker_scale, marker_scale_start : metres; robust (Cauchy) marker weights
        ``w = marker_weight / (1 + (r / s)²)`` with a scale ``s`` that anneals geometrically from
        ``marker_scale_start`` to ``marker_scale`` over the first half of the iterations (then
        holds): early on every marker pulls (the pose can still reach it), later a misplaced or
        misnamed marker cannot bend the body.
    marker_floor : (km,) minimum weight of each marker as a fraction of ``marker_weight``
        (``core.registration.markers``: markers consistent with their neighbours keep half their
        weight whatever the current fit says); default 0.
    vertex_weight : (n,) multiplier of each template vertex's data rows (default 1): a retry
        raises a lost body part's weight so its data pulls it back.
    subsample, template_row_weight : every ``subsample``-th template vertex makes a
        template → scan data row (one per vertex, matched to its closest compatible scan point)
        of this weight (e.g. ``subsample`` 2 at 2/3: denser, the term as heavy as every third
        vertex's at full weight, :data:`core.matching.markerless.FIRST_FIT_SUBSAMPLE`).
    k_schedule : number of active shape components per iteration (the paper's k' schedule:
        few first, more later); the last entry holds for the remaining iterations.
    bidirectional : also pair ``scan_sample`` scan points with their closest compatible body
        vertex (without markers, one-way pairs let the body shrink or slide off the scan).
    scan_oversample : pair this many times ``scan_sample`` scan points (spread by area), each
        weighing its share: the direction keeps the weight of ``scan_sample`` rows, and which
        points the spread picks averages out (e.g. :data:`core.matching.markerless.
        FIRST_FIT_SCAN_OVERSAMPLE`).
    freeze_pose : iterations before the bone rotations may move (coarse alignment first).
    initial_pose : bone name (of :data:`POSE_BONES`) -> (3, 3) local rotation to start from
        (a markerless search's arm-pose hypothesis); others start at the identity.
    initial_coefficients : (k,) shape coefficients to start from (default 0).
    basis : the shape space (:class:`ShapeBasis`; default the MakeHuman basis,
        :func:`load_shape_basis`).
    max_angle_deg : template and scan normals further apart are not paired; above 90° the
        sign of the scan's normals is not trusted (180°: any normal, for a coarse search on
        scans whose orientation may be wrong).
    point_weight : weight of point-to-point data rows (all three coordinates) next to the
        point-to-plane ones (0: point-to-plane only). Without markers, point-to-plane pairs let
        the body slide along the scan's walls (legs grow below soles a raw scan lacks).
    bone_prior : ``(bone, bend, twist)`` weights of a prior on those bones' total rotation
        (:data:`BONE_PRIOR`: wrists and elbows); ``()`` leaves every bone free (the pose
        prior then only damps each iteration's step).
    limb_prior : weight (per m², in units of one data row) of the elbows' offset along the
        shoulder→wrist axis of the rest body from their template share of the way
        (:data:`LIMB_CHAINS`; the markerless fit's :data:`LIMB_PRIOR`); 0 (default) leaves it
        to the shape prior and the markers. Point-to-plane data barely tell
        where along a nearly straight arm the elbow is: without it the shape space slid the
        elbows of heavy bodies 10-16 cm down the arm (rest forearm / upper arm 0.29-0.66,
        truths 0.87-0.96; ``core.synth.scanner_outputs`` raw-16/28, closed_lowres-16/24), arm
        centroids 51-84 mm off the truth's.
    trunk_prior : weight (per m², as ``limb_prior``) of the spine's joints' offsets along the
        root→neck axis of the rest body from their template shares (:data:`TRUNK_CHAINS`); 0
        (default): none.
    bone_length_prior : weight (per m², in units of one data row) of the arms' and thighs'
        rest bone lengths beyond their :data:`BONE_LENGTH_RATIOS` bands of the stature and of
        the left and right bones' difference (e.g. :data:`BONE_LENGTH_PRIOR`); 0 (default):
        none. An arm hanging against a heavy body's side or fused to it in a closed mesh has
        data all along the flank: without it the shape space stretched the forearms of
        ``bench.realworld --booth`` closed_booth-339 (BMI 40, arms touching) to 0.18/0.20 of
        the stature (the truth's 0.137), left and right apart, hands 104/124 mm low.
    bone_length_centred : sides (``"L"``, ``"R"``) whose bones of :data:`ARM_BONE_CENTRES` the
        bone length prior pulls to that centre instead of holding in their band: arms whose data
        cannot tell their length (a hand fused to the thigh). Needs ``bone_length_prior`` > 0.
    leg_length_centre : weight (per m², in units of one data row) of each thigh's rest length
        off :data:`LEG_BONE_CENTRES` (e.g. :data:`LEG_CENTRE_PRIOR`); 0 (default): none. The
        data barely tell where along the thigh its skin lies (:data:`LEG_BONE_CENTRES`).
    fists : sides (``"L"``, ``"R"``) whose fingers are curled into a fist
        (:data:`FIST_CURL_DEG`, :func:`core.rig.finger_rotations`), held fixed.
    floor_y : height (metres, scan frame, +Y up) below which no body vertex may go: vertices
        under it are paired with their projection onto that plane (point-to-plane rows of
        weight :data:`FLOOR_WEIGHT`, :func:`floor_pairs`). None (default): no floor. Scans
        without soles (a raw scan's floor contact band cut) left the feet free to grow
        downwards along the instep.
    hand_length : with a scan, set each hand's length after the fit: to the scanned hand's end
        where it is clear of the body, into ANSUR II's band of the stature where it is not
        (:func:`core.registration.hand_length.correct_hand_lengths`; the fingers take no data,
        so the coefficients alone gave the length: 4-19 % long on closed booth meshes).
    foot_length : with a scan, set each foot's length after the fit: its toe tip just past the
        scanned foot's end (:func:`core.registration.foot_end.correct_foot_lengths`; on coarse
        scans the toes take no data).
    sole_data : False: the soles' downward faces (:func:`sole_undersides`) take no data.
    upright : keep the body standing as ``sim`` stands it (upright, or head-down where its
        rotation turns the template's up below the horizon): the similarity only turns about the
        scan's +Y; lean and sway are the spine's, hips' and feet's (the markerless fits,
        :data:`core.matching.markerless.UPRIGHT`).
    measure : with a scan, measure the result's ``data_cost_m`` and ``coverage`` (one more
        correspondence query; the markerless search scores its starts by them), else NaN.
    """
    if index is None and len(marker_vid) < 3:
        raise ValueError("fit_body_prior needs a scan or at least 3 markers")
    basis = basis or load_shape_basis()
    if basis.mean is not None:
        if basis.mean.shape != np.shape(V0):
            raise ValueError(f"shape space mean {basis.mean.shape} != V0 {np.shape(V0)}")
        V0 = basis.mean
    U, sigma = basis.U, basis.sigma
    n, k = len(V0), basis.k
    U2 = U.reshape(3 * n, k)  # (3n, k) view: U @ c as one matrix-vector product

    def shaped(c: np.ndarray) -> np.ndarray:
        return V0 + (U2 @ c).reshape(n, 3)

    art = _fisted_articulation(V0, fists)
    B = len(POSE_BONES)
    mask = np.ones(n, bool) if data_mask is None else np.asarray(data_mask, bool)
    if not sole_data:
        mask = mask & ~sole_undersides(n)
    toe_side, foot_side = feet_sides(n)
    toe_guard = bool((mask & (toe_side > 0)).any())
    sub = np.zeros(n, bool)
    sub[::subsample] = True
    floor = np.zeros(len(marker_vid)) if marker_floor is None else np.asarray(marker_floor, float)
    if floor.shape != (len(marker_vid),):
        raise ValueError(f"marker_floor must have shape ({len(marker_vid)},), got {floor.shape}")
    mw = np.full(len(marker_vid), marker_weight)
    c = np.zeros(k) if initial_coefficients is None else np.array(initial_coefficients, float)
    local = np.broadcast_to(np.eye(3), (B, 3, 3)).copy()
    for name, Rb in (initial_pose or {}).items():
        local[POSE_BONES.index(name)] = Rb
    rows = np.zeros(0, dtype=np.int64)
    P = np.zeros((0, 3))
    w = np.zeros(0)
    damping = 1e-3
    rms_d = float("nan")
    Xp, aux = art.pose(shaped(c), local)
    Xp_before = Xp
    bone_M = _bone_metrics(art, V0, bone_prior)
    # upright: the template's up held along the scan's (or against it, head-down)
    stand = None if not upright else (np.eye(3) if sim.R[1, 1] >= 0 else np.diag([-1.0, -1.0, 1.0]))
    bone_slots = [a for a, _ in bone_M]
    G_limb, g_limb = _limb_rows(V0, U, art.rig) if limb_prior > 0 else (np.zeros((0, k)), [])
    G_trunk, g_trunk = (
        _limb_rows(V0, U, art.rig, TRUNK_CHAINS) if trunk_prior > 0 else (np.zeros((0, k)), [])
    )
    bone_terms = (
        _bone_length_terms(V0, U, art.rig)
        if bone_length_prior > 0 or leg_length_centre > 0
        else None
    )
    for it in range(iterations):
        X = sim.apply(Xp)
        # correspondences in the scan frame; residuals in the posed template frame
        md = max_distance if it < 2 else max_distance * 0.5
        if index is not None:
            N = vertex_normals(X, F)
            cand = np.flatnonzero(mask & sub)
            corr = index.closest_compatible(
                X[cand], N[cand], max_distance=md, max_angle_deg=max_angle_deg, project=False
            )
            ok = corr.weights > 0
            if toe_guard:  # a toe's data on the other foot is no toe's
                ok[ok] = ~other_foot_matches(X, cand[ok], corr.targets[ok], toe_side, foot_side)
            rows = cand[ok]
            P = corr.targets[ok]
            w = corr.weights[ok] * template_row_weight
            Np = index.normals[corr.point_ids[ok]] @ sim.R  # scan normals in the posed frame
            if bidirectional:  # scan → template pairs too: the body must cover the scan
                min_cos = np.cos(np.radians(max_angle_deg))
                explained = np.flatnonzero(~mask & sub)  # bad-scan regions explain their data
                s_rows, s_P, s_w, s_N = _scan_to_template(
                    index,
                    X,
                    N,
                    cand,
                    md,
                    scan_sample,
                    min_cos,
                    explained=explained,
                    oversample=scan_oversample,
                )
                rows = np.r_[rows, s_rows]
                P = np.vstack([P, s_P])
                w = np.r_[w, s_w]
                Np = np.vstack([Np, s_N @ sim.R])
            if vertex_weight is not None:
                w = w * vertex_weight[rows]
            if floor_y is not None:  # the body stands on the floor, not in it
                f_rows, f_P, f_N = floor_pairs(X, np.flatnonzero(sub), floor_y)
                rows = np.r_[rows, f_rows]
                P = np.vstack([P, f_P])
                w = np.r_[w, np.full(len(f_rows), FLOOR_WEIGHT)]
                Np = np.vstack([Np, f_N @ sim.R])
        else:
            Np = np.zeros((0, 3))
        Q = ((P - sim.t) @ sim.R) / sim.s
        Qm = ((marker_pos - sim.t) @ sim.R) / sim.s
        uniq, inv = np.unique(np.r_[rows, marker_vid], return_inverse=True)
        Rb = art.blended_rotations(aux, uniq)
        nu, K = len(uniq), k + 3 * B
        # (u, 3, k + 3B), each row's is J_u[inv]: shape then pose columns, filled in place
        J_u = np.empty((nu, 3, K))
        np.matmul(Rb, U[uniq], out=J_u[:, :, :k])
        art.pose_jacobian(aux, uniq, out=J_u[:, :, k:])
        nd = len(rows)
        inv_d, inv_m = inv[:nd], inv[nd:]
        sw = np.sqrt(w)
        # data rows n_r·J_u(r) as one sparse (nd, 3u) × (3u, K) product: no (nd, 3, K) copy
        cols_d = (3 * inv_d[:, None] + np.arange(3)).ravel()
        S_d = sp.csr_matrix(
            ((Np * sw[:, None]).ravel(), cols_d, np.arange(0, 3 * nd + 1, 3)), shape=(nd, 3 * nu)
        )
        A_d = S_d @ J_u.reshape(3 * nu, K)
        b_d = np.einsum("rc,rc->r", Np, Q - Xp[rows]) * sw
        H = A_d.T @ A_d
        g = A_d.T @ b_d
        if point_weight > 0 and nd:  # point-to-point rows: no sliding along the surface
            # Σ_r pw_r² J_r^T J_r summed per vertex first (rows sharing a vertex share J)
            pw2 = w * point_weight
            W_u = np.bincount(inv_d, pw2, minlength=nu)
            r_u = np.stack(
                [np.bincount(inv_d, pw2 * (Q - Xp[rows])[:, c], minlength=nu) for c in range(3)], 1
            )
            Js = (J_u * np.sqrt(W_u)[:, None, None]).reshape(3 * nu, K)
            H += Js.T @ Js
            g += np.einsum("uck,uc->k", J_u, r_u)
        # robust marker weights, annealed: a misplaced or misnamed marker loses its pull
        res_m = np.linalg.norm(Qm - Xp[marker_vid], axis=1) * sim.s
        mw = marker_weight * marker_weights(
            res_m, it, iterations, marker_scale_start, marker_scale, floor
        )
        A_m = J_u[inv_m] * np.sqrt(mw)[:, None, None]
        A_m = A_m.reshape(-1, K)
        b_m = ((Qm - Xp[marker_vid]) * np.sqrt(mw)[:, None]).ravel()
        rms_d = float(np.sqrt(np.mean(b_d**2 / np.maximum(w, 1e-9)))) if nd else float("nan")
        # normal equations with priors (data rows are in metres: scale priors to mm² units)
        H += A_m.T @ A_m
        g += A_m.T @ b_m
        pose_w = pose_prior_weight if it >= freeze_pose else 1e6
        prior = np.r_[shape_prior_weight * 1e-6 / sigma**2, np.full(3 * B, pose_w)]
        if k_schedule:
            k_active = k_schedule[min(it, len(k_schedule) - 1)]
            prior[k_active:k] = 1e12  # inactive components stay where they are
        wvec = np.r_[c, np.zeros(3 * B)]
        H += np.diag(prior)
        g -= prior * wvec
        # the bones' rotation vectors, all at once
        rv = Rotation.from_matrix(local[bone_slots]).as_rotvec() if bone_M else np.zeros((0, 3))
        for i, (a, M) in enumerate(bone_M):  # total rotation of the distal arm bones off rest
            j = art.bones[a]
            Rp = aux["R"][art.rig.parents[j]]
            r = rv[i]
            sl = slice(k + 3 * a, k + 3 * a + 3)
            H[sl, sl] += Rp @ M @ Rp.T
            g[sl] -= Rp @ (M @ r)
        if len(G_limb):  # elbows where the shape puts them along the arm, not slid
            H[:k, :k] += limb_prior * G_limb.T @ G_limb
            g[:k] -= limb_prior * G_limb.T @ (G_limb @ c + g_limb)
        if len(G_trunk):  # the spine's joints where the shape puts them, the torso's skin not slid
            H[:k, :k] += trunk_prior * G_trunk.T @ G_trunk
            g[:k] -= trunk_prior * G_trunk.T @ (G_trunk @ c + g_trunk)
        if bone_terms is not None and bone_length_prior > 0:  # limbs of a human's length,
            J_a, r_a = _bone_length_rows(bone_terms, c, bone_length_centred)  # left as right
            H[:k, :k] += bone_length_prior * J_a.T @ J_a
            g[:k] -= bone_length_prior * J_a.T @ r_a
        if bone_terms is not None and leg_length_centre > 0:  # thighs' skin not slid
            J_t, r_t = _leg_centre_rows(bone_terms, c)
            H[:k, :k] += leg_length_centre * J_t.T @ J_t
            g[:k] -= leg_length_centre * J_t.T @ r_t
        H += damping * np.diag(np.diag(H))
        delta = np.linalg.solve(H, g)
        c = c + delta[:k]
        dR = Rotation.from_rotvec(delta[k:].reshape(B, 3)).as_matrix()
        for a in range(B):
            p = art.rig.parents[art.bones[a]]
            Rp = aux["R"][p] if p >= 0 else np.eye(3)
            local[a] = Rp.T @ dR[a] @ Rp @ local[a]
        # similarity from markers and data pairs on the updated body
        rest = shaped(c)
        Xp_before = Xp
        Xp, aux = art.pose(rest, local)
        src = np.vstack([Xp[marker_vid], Xp[rows]])
        dst = np.vstack([marker_pos, P])
        # without markers, closest-point pairs bias the scale down: hold it (shape modes carry size)
        sim = umeyama(src, dst, np.r_[mw, w], scale=None if len(marker_vid) >= 3 else sim.s,
                      upright=stand)  # fmt: skip
    rest = shaped(c)
    X = sim.apply(Xp)
    # the last iteration's mean vertex step (scan frame; NaN without iterations)
    last_step = float(row_norms(Xp - Xp_before).mean() * sim.s) if iterations else float("nan")
    res_m = np.linalg.norm(X[marker_vid] - marker_pos, axis=1)
    final_w = marker_weights(res_m, iterations, iterations, marker_scale_start, marker_scale, floor)
    rms_m = float(np.sqrt(np.mean(res_m**2))) if len(res_m) else float("nan")
    cost = float("nan")
    coverage = float("nan")
    if index is not None and measure:  # how well the body explains the scan (unmatched: 5 cm)
        cand = np.flatnonzero(mask & sub)
        corr = index.closest_compatible(
            X[cand],
            vertex_normals(X, F)[cand],
            max_distance=0.05,
            max_angle_deg=60.0,
            project=False,
        )
        d = np.where(corr.weights > 0, corr.distances, np.inf)
        cost = float(np.sqrt(np.mean(np.minimum(d, 0.05) ** 2)))
        coverage = float(np.mean(d < 0.015))
    hands: list[HandLength] = []
    if index is not None and hand_length:
        top = load_template().landmarks["Vertex"]
        stature = (rest[top, 1] - rest[:, 1].min()) * sim.s
        X, hands = correct_hand_lengths(index, X, stature, fists=fists)
    feet: list[FootLength] = []
    if index is not None and foot_length:
        X, feet = correct_foot_lengths(index, X, toe_allowance(index))
    return PriorFit(
        X=X, rest=rest, coefficients=c,
        pose={name: local[a].copy() for a, name in enumerate(POSE_BONES)},
        similarity=sim, iterations=iterations, rms_marker_m=rms_m, rms_data_m=rms_d,
        marker_residuals_m=res_m, data_cost_m=cost, coverage=coverage, marker_weights=final_w,
        hand_lengths=hands, foot_lengths=feet, last_step_m=last_step,
    )  # fmt: skip
