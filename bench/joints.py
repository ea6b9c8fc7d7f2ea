"""Joint placement on a body: the rig's vertex-group regression vs the joint's surface markers
(a least-squares similarity per joint), issue 14.

Three numbers per method, on 100 bodies of the default shape model at the (stature, weight) of
ANSUR II subjects inside the 1st-99th percentile box (50 per sex, as tests/core/test_transfer_rig):
- outside: skeleton joints (the 103 inside the template; not the 59 face-expression bones,
  which MakeHuman puts on skin vertices, nor the root, on the skin of the back) with
  generalised winding number < 0.5, and for reference the face bones that stay inside;
- noise: RMS joint displacement (mm) when every vertex gets 2 mm Gaussian noise (a scanner's);
- pose: a body posed ``seated``/``driving``/``reach`` by LBS on the method's joints, then the
  joints re-placed on the posed body: RMS / max distance (mm) to the posed joints (forward
  kinematics), i.e. how well the method follows a body that is not in the template's pose.

Run: ``python -m bench.joints [--bodies 100]``.
"""

from __future__ import annotations

import argparse
import importlib
import subprocess
from collections import Counter

import numpy as np

from core.geometry import winding_number
from core.rig import bone_transforms, load_rig
from core.shapespace.model import load_model
from core.template import load_template
from core.transfer.rig import JOINT_METHODS, body_joints, pose, posture

cases = importlib.import_module("tests.core.test_transfer_rig")  # one definition of the cases


def _subjects(n_per_sex: int):
    rng = np.random.default_rng(0)
    for sex in ("female", "male"):
        for h, w in cases._subjects(sex, n_per_sex, rng):
            yield sex, h, w


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bodies", type=int, default=100)
    args = ap.parse_args()
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    print(f"bench.joints  commit {commit}  bodies {args.bodies}")
    tpl, rig, model = load_template(), load_rig(), load_model()
    inside = cases.skeleton_joints()
    rng = np.random.default_rng(1)
    stats = {m: {"outside": [], "noise": [], "pose": []} for m in JOINT_METHODS}
    for k, (sex, h, w) in enumerate(_subjects(args.bodies // 2)):
        V = model.synthesize(sex, {"height_m": h, "weight_kg": w})
        noisy = V + rng.normal(scale=0.002, size=V.shape)
        for m in JOINT_METHODS:
            J = body_joints(V, method=m)
            wn = winding_number(V, tpl.F, J[inside], chunk=16)
            stats[m]["outside"] += [rig.names[j] for j in np.flatnonzero(inside)[wn < 0.5]]
            stats[m]["noise"].append(np.linalg.norm(body_joints(noisy, method=m) - J, axis=1))
            if k % 10 == 0:
                for name in ("seated", "driving", "reach"):
                    rot = posture(name)
                    P = pose(V, rot, method=m, floor=False)
                    R, t = bone_transforms(rot, J)
                    truth = np.einsum("jab,jb->ja", R, J) + t
                    stats[m]["pose"].append(
                        np.linalg.norm(body_joints(P, method=m) - truth, axis=1)
                    )
    for m, s in stats.items():
        noise = np.concatenate(s["noise"]) * 1000
        pz = np.concatenate(s["pose"]) * 1000
        out = Counter(s["outside"])
        print(
            f"{m:10} outside {len(s['outside']):4d} joint-bodies {dict(out.most_common(6))}\n"
            f"{'':10} noise 2 mm -> joint RMS {np.sqrt((noise**2).mean()):.2f} mm, "
            f"p99 {np.percentile(noise, 99):.2f}\n"
            f"{'':10} posed bodies: RMS {np.sqrt((pz**2).mean()):.1f} mm, "
            f"p95 {np.percentile(pz, 95):.1f}, max {pz.max():.1f}"
        )


if __name__ == "__main__":
    main()
