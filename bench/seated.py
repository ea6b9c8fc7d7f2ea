"""Seated posture vs ANSUR II sitting height (issue 14).

For each sex and percentile p in (5, 50, 95): the default shape model's most likely body at the
p-th percentile ANSUR II stature and weight, posed ``seated`` (``core.transfer.rig``), by linear
blend skinning alone (``LBS``) and resting on the seat (``contact``: the soft tissue under the
buttocks compressed, ``core.transfer.seat``, what the API and CLI do for ``seated``); its
sitting height is the vertical distance from the seat (the lowest point of the thighs and
buttocks) to the top of the head. It is compared with (a) the p-th percentile of ANSUR II
``sittingheight`` (what the issue asks) and (b) the mean ``sittingheight`` of the ANSUR II
subjects within 1.5 cm of that stature (the expected value for a body of that stature). Reads
the full ANSUR II development files (``../shared/data/ansur2``, millimetres) for the
``sittingheight`` column, which the bundled copy does not carry.

Run: ``python -m bench.seated [--ansur-dir DIR]``. Target: within 3 % of (a).
"""

from __future__ import annotations

import argparse
import csv
import subprocess
from pathlib import Path

import numpy as np

from core.rig import load_rig
from core.shapespace.model import load_model
from core.transfer.rig import body_joints, pose, posture

ANSUR_DIR = Path("/work/shared/data/ansur2")  # the full development files (--ansur-dir)
PERCENTILES = (5, 50, 95)


def seat_vertices(V: np.ndarray) -> np.ndarray:
    """Indices of the thigh and buttock vertices (dominant bone in a leg above the knee or the
    pelvis, rest height above mid-thigh): the seat is their lowest point when seated."""
    rig = load_rig()
    W = rig.skin_weights()
    dom = W.argmax(axis=1)
    bones = {"root", "pelvis.L", "pelvis.R", "upperleg01.L", "upperleg01.R", "upperleg02.L",
             "upperleg02.R"}  # fmt: skip
    ok = np.isin(dom, [rig.index(b) for b in bones])
    J = body_joints(V)
    hip = J[rig.index("upperleg01.L"), 1]
    knee = J[rig.index("lowerleg01.L"), 1]
    return np.flatnonzero(ok & (V[:, 1] > (hip + knee) / 2) & (V[:, 1] < hip + 0.05))


def sitting_height(V: np.ndarray, *, seat_contact: bool = True) -> float:
    """Sitting height (m) of the rest body ``V`` posed ``seated`` (resting on the seat or, with
    ``seat_contact=False``, by linear blend skinning alone)."""
    P = pose(V, posture("seated"), seat_contact=seat_contact)
    return float(P[:, 1].max() - P[seat_vertices(V), 1].min())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ansur-dir", type=Path, default=ANSUR_DIR)
    args = ap.parse_args()
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    print(f"bench.seated  commit {commit}")
    model = load_model()
    print(f"{'sex':6} {'p':>3} {'stature':>8} {'weight':>7} {'LBS SH':>7} {'contact SH':>10} "
          f"{'ANSUR SH p':>10} {'LBS %':>6} {'err %':>6} {'SH|stature':>10} "
          f"{'err %':>6}")  # fmt: skip
    worst = worst_lbs = 0.0
    for sex in ("female", "male"):
        with open(args.ansur_dir / f"ansur2_{sex}_dev.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        st = np.array([float(r["stature"]) for r in rows]) / 1000
        wt = np.array([float(r["weightkg"]) for r in rows]) / 10
        sh = np.array([float(r["sittingheight"]) for r in rows]) / 1000
        for p in PERCENTILES:
            s_p, w_p, sh_p = (float(np.percentile(a, p)) for a in (st, wt, sh))
            near = np.abs(st - s_p) < 0.015
            sh_given = float(sh[near].mean())
            V = model.synthesize(sex, {"height_m": s_p, "weight_kg": w_p})
            h0, h = sitting_height(V, seat_contact=False), sitting_height(V)
            e0, e1, e2 = (100 * (x - 1) for x in (h0 / sh_p, h / sh_p, h / sh_given))
            worst, worst_lbs = max(worst, abs(e1)), max(worst_lbs, abs(e0))
            print(f"{sex:6} {p:3d} {s_p:8.3f} {w_p:7.1f} {h0:7.3f} {h:10.3f} {sh_p:10.3f} "
                  f"{e0:+6.1f} {e1:+6.1f} {sh_given:10.3f} {e2:+6.1f}")  # fmt: skip
    print(
        f"worst |error| vs the ANSUR II percentile: {worst:.1f} % with seat contact, "
        f"{worst_lbs:.1f} % LBS alone (target 3 %)"
    )


if __name__ == "__main__":
    main()
