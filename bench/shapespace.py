"""Shape-space benchmark: realism on held-out ANSUR II subjects, editing, fitted-vs-mesh models.

    .venv/bin/python -m bench.shapespace                          # the committed default model
    .venv/bin/python -m bench.shapespace --model M.npz --fits build/fits --mesh-bodies build/bodies

Realism: for every held-out ANSUR II subject (``core.shapespace.ansur``) inside the model's range,
a body is synthesised from (sex, stature, weight) alone, measured with ``core.measure.measure``
and compared with the subject's real measurements: RMSE per measurement (mm; kg for weight) next
to the best linear regression of that measurement on stature and weight fitted to the held-in
rows (the peer: what (stature, weight) can predict at best, linearly), and the stature error.

Editing: +10 kg on fitted bodies (registered simulated scans): change of the reported weight
(volume x calibrated density) and the largest displacement of face (head) and hand vertices, with
the default edit (face and hands kept) and the plain paper edit.

Models: a model built from the fitted bodies vs one built directly from the meshes they were
scanned from (per-vertex RMS between the means and between the first components, explained
variance).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from core.measure import MEASUREMENTS, measure
from core.shapespace import (
    ShapeModel,
    body_height,
    build_model,
    load_model,
    read_bodies,
)
from core.shapespace.ansur import rows_in_range, split
from core.shapespace.model import DEFAULT_MODEL
from core.template import load_template

SEXES = ("female", "male")
#: The measurements issue 5 names (stature; cervicale, acromial, waist, crotch and knee heights;
#: chest ... head circumferences; biacromial and hip breadths; arm length = acromion-radiale +
#: radiale-stylion; foot length; mass is the input). Marked ``*`` in the table and counted apart.
REQUIRED = frozenset({
    "stature", "cervicaleheight", "acromialheight", "waistheightomphalion", "crotchheight",
    "kneeheightmidpatella", "chestcircumference", "waistcircumference", "buttockcircumference",
    "neckcircumference", "thighcircumference", "calfcircumference", "bicepscircumferenceflexed",
    "forearmcircumferenceflexed", "wristcircumference", "headcircumference", "biacromialbreadth",
    "hipbreadth", "acromionradialelength", "radialestylionlength", "footlength",
})  # fmt: skip


def realism(model: ShapeModel, *, n: int | None = None) -> dict:
    """Per-measurement RMSE of bodies synthesised from (stature, weight) on held-out rows."""
    out: dict = {}
    for sex in SEXES:
        if sex not in model.spaces:
            continue
        te, tr = split(sex, "test"), split(sex, "train")
        names = [k for k in MEASUREMENTS if k in te]
        rng = te["held_out"].size
        idx = np.arange(rng) if n is None else np.arange(rng)[:n]
        idx = rows_in_range(model.space(sex).features, te, idx)
        t0 = time.perf_counter()
        rows, heights, raw_heights = [], [], []
        for i in idx:
            f = {"height_m": float(te["stature"][i]), "weight_kg": float(te["weightkg"][i])}
            V = model.synthesize(sex, f)
            heights.append(body_height(V))
            raw_heights.append(body_height(model.synthesize(sex, f, exact_height=False)))
            r = measure(V, names=names)
            r["weightkg"] = model.weight_kg(V, sex)  # volume x the model's calibrated density
            rows.append(r)
        dt = (time.perf_counter() - t0) / max(len(idx), 1)
        A = np.stack([np.ones_like(tr["stature"]), tr["stature"], tr["weightkg"]], 1)
        At = np.stack([np.ones(len(idx)), te["stature"][idx], te["weightkg"][idx]], 1)
        tab = {}
        for k in names:
            u = 1.0 if k == "weightkg" else 1000.0
            truth = te[k][idx]
            pred = np.array([r[k] for r in rows])
            cf = np.linalg.lstsq(A, tr[k], rcond=None)[0]
            e_m = (pred - truth) * u
            e_r = (At @ cf - truth) * u
            tab[k] = {
                "model_rmse": float(np.sqrt(np.mean(e_m**2))),
                "model_bias": float(e_m.mean()),
                # weight is an input: its regression on itself is exact, no peer
                "regression_rmse": float("nan")
                if k == "weightkg"
                else float(np.sqrt(np.mean(e_r**2))),
            }
        st_err = (np.array(heights) - te["stature"][idx]) * 1000
        st_raw = (np.array(raw_heights) - te["stature"][idx]) * 1000
        out[sex] = {
            "subjects": len(idx),
            "held_out_rows": int(rng),
            "stature_error_mm_max": float(np.abs(st_err).max()),
            "stature_error_mm_max_before_exact_scaling": float(np.abs(st_raw).max()),
            "stature_error_mm_rms_before_exact_scaling": float(np.sqrt(np.mean(st_raw**2))),
            "seconds_per_body_incl_measure": dt,
            "table": tab,
        }
        print(f"\nrealism, {sex}: {len(idx)} held-out subjects in range (of {rng}); bodies from "
              f"(stature, weight); stature |error| max {np.abs(st_err).max():.2f} mm "
              f"(before the exact height scaling: max {np.abs(st_raw).max():.1f}, RMS "
              f"{np.sqrt(np.mean(st_raw**2)):.1f} mm)")  # fmt: skip
        print(
            f"  {'measurement':32s} {'model RMSE':>10s} {'bias':>7s} {'regr RMSE':>10s} "
            f"{'ratio':>6s}"
        )
        for k, r in tab.items():
            if k == "weightkg":
                print(f"  {'weightkg (input; kg)':32s} {r['model_rmse']:10.2f} "
                      f"{r['model_bias']:7.2f}"
                      f" {'-':>10s} {'-':>6s}")  # fmt: skip
                continue
            ratio = r["model_rmse"] / max(r["regression_rmse"], 1e-9)
            flag = "" if ratio <= 1.1 else "  > 1.1"
            star = "*" if k in REQUIRED else " "
            print(f" {star}{k:32s} {r['model_rmse']:10.1f} {r['model_bias']:7.1f} "
                  f"{r['regression_rmse']:10.1f} {ratio:6.2f}{flag}")  # fmt: skip
        ratios = {k: r["model_rmse"] / r["regression_rmse"] for k, r in tab.items()
                  if k != "weightkg"}  # fmt: skip
        req = [x for k, x in ratios.items() if k in REQUIRED]
        print(f"  within 1.1x: {sum(x <= 1.1 for x in ratios.values())}/{len(ratios)}; "
              f"median ratio {np.median(list(ratios.values())):.2f}; issue 5's list (*): "
              f"{sum(x <= 1.1 for x in req)}/{len(req)}, max ratio {max(req):.2f}")  # fmt: skip
        out[sex]["within_1_1"] = sum(x <= 1.1 for x in ratios.values())
        out[sex]["required_within_1_1"] = sum(x <= 1.1 for x in req)
        out[sex]["required_count"] = len(req)
    return out


def editing(model: ShapeModel, fits: Path, *, n: int = 20, delta_kg: float = 10.0) -> dict:
    """+``delta_kg`` on fitted bodies: weight change and face/hand displacement."""
    tpl = load_template()
    face = tpl.part_mask("head")
    hands = tpl.part_mask("hand_L") | tpl.part_mask("hand_R")
    bodies = read_bodies(fits)
    out: dict = {}
    for sex in SEXES:
        ids = [i for i in bodies if i.startswith(sex + "_")][:n]
        if not ids or sex not in model.spaces:
            continue
        res: dict = {"kept": [], "paper": []}
        skipped = 0
        for i in ids:
            V = bodies[i]
            w0 = model.weight_kg(V, sex)
            if not model.space(sex).features.in_training_range({"weight_kg": w0 + delta_kg}):
                skipped += 1
                continue
            for key, keep in (("kept", None), ("paper", ())):
                t0 = time.perf_counter()
                E = model.edit(
                    sex, V, {"weight_kg": delta_kg}, **({} if keep is None else {"keep": keep})
                )
                dt = time.perf_counter() - t0
                d = np.linalg.norm(E - V, axis=1) * 1000
                res[key].append((model.weight_kg(E, sex) - w0, d[face].max(), d[hands].max(),
                                 d.max(), dt))  # fmt: skip
        out[sex] = {}
        print(
            f"\nediting, {sex}: +{delta_kg:g} kg on {len(ids) - skipped} fitted bodies "
            f"({skipped} skipped: the result would be out of the model's weight range)"
        )
        for key, label in (("kept", "default (face/hands kept)"), ("paper", "paper (no keep)")):
            a = np.array(res[key])
            out[sex][key] = {
                "delta_kg_min": float(a[:, 0].min()), "delta_kg_max": float(a[:, 0].max()),
                "face_max_mm": float(a[:, 1].max()), "hands_max_mm": float(a[:, 2].max()),
                "body_max_mm_median": float(np.median(a[:, 3])),
                "ms_median": 1000 * float(np.median(a[:, 4])),
            }  # fmt: skip
            o = out[sex][key]
            print(f"  {label:28s} Δweight {o['delta_kg_min']:.2f}–{o['delta_kg_max']:.2f} kg, "
                  f"face max {o['face_max_mm']:.2f} mm, hands max {o['hands_max_mm']:.2f} mm, "
                  f"largest move (median body) {o['body_max_mm_median']:.0f} mm, "
                  f"{o['ms_median']:.0f} ms")  # fmt: skip
    return out


def compare(a: ShapeModel, b: ShapeModel, labels: tuple[str, str] = ("fitted", "mesh")) -> dict:
    """How two models differ: means, leading components, explained variance."""
    out: dict = {}
    print(f"\nmodels: {labels[0]} vs {labels[1]}")
    for sex in SEXES:
        if sex not in a.spaces or sex not in b.spaces:
            continue
        pa, pb = a.space(sex).pca, b.space(sex).pca
        dm = np.linalg.norm((pa.mean - pb.mean).reshape(-1, 3), axis=1)
        comps = []
        for j in range(min(5, pa.k, pb.k)):
            ca, cb = pa.components[j].astype(float), pb.components[j].astype(float)
            s = np.sign(ca @ cb)
            # unit-SD displacement fields of component j in each model, per-vertex RMS difference
            da = (ca * pa.sd[j]).reshape(-1, 3)
            db = (s * cb * pb.sd[j]).reshape(-1, 3)
            comps.append({
                "cosine": float(abs(ca @ cb)),
                "sd_mm": [1000 * float(p.sd[j]) / np.sqrt(len(da)) for p in (pa, pb)],
                "rms_diff_mm": 1000 * float(np.sqrt(np.mean(np.sum((da - db) ** 2, 1)))),
            })  # fmt: skip
        out[sex] = {
            "mean_rms_mm": 1000 * float(np.sqrt(np.mean(dm**2))),
            "mean_max_mm": 1000 * float(dm.max()),
            "k": [pa.k, pb.k],
            "explained_first5": [float(pa.explained[:5].sum()), float(pb.explained[:5].sum())],
            "total_variance_m2": [pa.total_variance, pb.total_variance],
            "components": comps,
        }
        o = out[sex]
        print(f"  {sex}: means differ by RMS {o['mean_rms_mm']:.2f} mm "
              f"(max {o['mean_max_mm']:.1f});"
              f" components for the variance share: {o['k'][0]} vs {o['k'][1]}; first 5 explain "
              f"{100 * o['explained_first5'][0]:.1f} % vs {100 * o['explained_first5'][1]:.1f} %;"
              f" total variance ratio {pa.total_variance / pb.total_variance:.3f}")  # fmt: skip
        for j, c in enumerate(comps):
            print(f"    PC{j + 1}: |cos| {c['cosine']:.3f}, per-vertex RMS of 1-SD field "
                  f"{c['sd_mm'][0]:.1f} vs {c['sd_mm'][1]:.1f} mm, RMS difference "
                  f"{c['rms_diff_mm']:.1f} mm")  # fmt: skip
    return out


def synthesis_speed(model: ShapeModel, n: int = 200) -> float:
    """Median milliseconds per body synthesised from (sex, height, weight)."""
    ts = []
    for i in range(n):
        t0 = time.perf_counter()
        model.synthesize("female" if i % 2 else "male", {"height_m": 1.7, "weight_kg": 70.0})
        ts.append(time.perf_counter() - t0)
    ms = 1000 * float(np.median(ts))
    print(f"\nsynthesis: {ms:.2f} ms per body (median of {n}, core only)")
    return ms


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench.shapespace", description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, default=DEFAULT_MODEL)
    ap.add_argument("--fits", type=Path, help="folder of fitted bodies (editing benchmark)")
    ap.add_argument("--mesh-bodies", type=Path,
                    help="folder of the unscanned solved bodies + features.csv: build a mesh "
                    "model and compare it with --model")  # fmt: skip
    ap.add_argument("--mesh-features", type=Path)
    ap.add_argument("--n", type=int, default=None, help="at most this many held-out rows per sex")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    model = load_model(args.model)
    print(f"model {args.model}: " + json.dumps(model.metadata.get("bodies", {})))
    res: dict = {"realism": realism(model, n=args.n)}
    if args.fits:
        res["editing"] = editing(model, args.fits)
    if args.mesh_bodies:
        feats = args.mesh_features or (args.fits / "features.csv" if args.fits else None)
        mesh = build_model(
            args.mesh_bodies, feats, variance=model.metadata.get("variance_share", 0.98)
        )
        res["compare"] = compare(model, mesh)
        print("\nrealism of the mesh-built model:")
        res["realism_mesh"] = realism(mesh, n=args.n)
    res["synthesis_ms"] = synthesis_speed(model)
    if args.json:
        args.json.write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
