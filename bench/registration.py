"""Registration benchmark: bodyspace's fit against trimesh's non-rigid ICP methods.

Run from the repository root::

    python -m bench.registration [--seeds 0-5] [--methods bodyspace,sumner,amberg]
                                 [--json out.json] [--quick] [--timeout 600]

For each seeded simulated scan (``bench.cases.make_case``) every method runs in a fresh
subprocess, which rebuilds the case from its seed (deterministic) before the timer starts, so
wall time and peak memory belong to that one fit. All methods get the same markers and the same
initialisation (the template-landmark → marker similarity of
``core.registration.initialization.align_markers``); see ``bench/README.md``.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

METHODS = ("bodyspace", "sumner", "amberg")
OPTIONAL_METHODS = ("similarity",)  # the shared initialisation alone, as a reference row
DEFAULT_SEEDS = "0-5"
QUICK_SEEDS = "0-1"
MAX_DISTANCE_M = 0.10  # the correspondence distance bound given to every method (bodyspace: 10 cm)
HOLE_RADIUS_M = 0.005
TARGETS = {
    "mean_mm": 3.0,
    "p95_mm": 8.0,
    "scan_to_fit_mean_mm": 1.0,
    "seconds": 5.0,
    "peak_gb": 0.8,
}
TARGETS_LINE = (
    "targets (bodyspace): mean ≤ 3 mm, p95 ≤ 8 mm, scan→fit ≤ 1.0 mm mean, ≤ 5 s, ≤ 0.8 GB per fit"
)
REPO = Path(__file__).resolve().parent.parent


# --------------------------------------------------------------------------------------------
# memory of the current process (Linux /proc; falls back to ru_maxrss elsewhere)


def _status_kb(field: str) -> float | None:
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return float(line.split()[1])
    except OSError:
        return None
    return None


def _rss_mb() -> float:
    kb = _status_kb("VmRSS")
    if kb is None:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return kb / 1024.0


def _reset_peak() -> bool:
    """Reset the kernel's peak-RSS mark (VmHWM, ru_maxrss) to the current RSS (Linux ≥ 4.0)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def _peak_mb() -> float:
    kb = _status_kb("VmHWM")
    if kb is None:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return kb / 1024.0


# --------------------------------------------------------------------------------------------
# the methods (run inside the child)


def landmark_barycentric(F: np.ndarray, vertex_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """trimesh's barycentric landmark format for landmarks sitting on vertices.

    Returns ``(tids (k,) int, barys (k, 3) float)``: for each vertex a triangle containing it and
    the one-hot barycentric coordinates that select that vertex.
    """
    F = np.asarray(F, dtype=np.int64)
    vertex_ids = np.asarray(vertex_ids, dtype=np.int64)
    tids = np.empty(len(vertex_ids), dtype=np.int64)
    barys = np.zeros((len(vertex_ids), 3))
    for i, v in enumerate(vertex_ids):
        f, c = np.argwhere(np.equal(F, v))[0]
        tids[i] = f
        barys[i, c] = 1.0
    return tids, barys


def _shared_init(case: Any, tpl: Any) -> tuple[Any, list[str]]:
    from core.registration.initialization import align_markers

    tl = {k: tpl.V[i] for k, i in tpl.landmarks.items()}
    align = align_markers(tl, case.markers)
    return align, align.used


def _run_trimesh(method: str, case: Any, tpl: Any) -> tuple[np.ndarray, dict[str, Any]]:
    import trimesh

    align, used = _shared_init(case, tpl)
    F = np.asarray(tpl.F, dtype=np.int64)
    source = trimesh.Trimesh(align.similarity.apply(tpl.V), F, process=False)
    if case.scan.F is not None and len(case.scan.F):
        target: Any = trimesh.Trimesh(case.scan.V, case.scan.F, process=False)
    else:
        target = trimesh.PointCloud(case.scan.V)
    vid = np.array([tpl.landmarks[k] for k in used], dtype=np.int64)
    landmarks = landmark_barycentric(F, vid)
    positions = np.array([case.markers[k] for k in used], dtype=np.float64)
    # trimesh divides source and target by source.scale (bounding-box diagonal) before matching,
    # so its distance_threshold is in those normalised units: convert bodyspace's 10 cm.
    threshold = MAX_DISTANCE_M / float(source.scale)
    func = {
        "sumner": trimesh.registration.nricp_sumner,
        "amberg": trimesh.registration.nricp_amberg,
    }
    X = func[method](
        source,
        target,
        source_landmarks=landmarks,
        target_positions=positions,
        distance_threshold=threshold,
    )
    info = {
        "passed": {
            "source_mesh": "template after the align_markers similarity (Trimesh, process=False)",
            "target_geometry": "scan V/F as Trimesh(process=False)",
            "source_landmarks": f"(tids, one-hot barycentrics) at {len(used)} landmark vertices",
            "target_positions": f"the {len(used)} markers align_markers used",
            "distance_threshold": threshold,
            "distance_threshold_m": MAX_DISTANCE_M,
            "source_scale_m": float(source.scale),
            "steps": "default",
            "other": "defaults",
        },
        "markers_used": len(used),
    }
    return np.asarray(X, dtype=np.float64), info


def _run_bodyspace(case: Any, tpl: Any) -> tuple[np.ndarray, dict[str, Any]]:
    from core.registration.fit import fit

    res = fit(case.scan, case.markers)
    rep = res.report
    info = {
        "passed": {"scan": "case.scan", "markers": "case.markers", "options": "defaults"},
        "markers_used": len(rep.markers_used),
        "report_seconds": rep.seconds,
        "report_scan_to_fit_mean_mm": rep.scan_to_fit_mean_m * 1000.0,
        "no_data_fraction": rep.no_data_fraction,
        "no_data_vertices": int(np.sum(np.asarray(res.data_weight) <= 0)),
        "warnings": list(rep.warnings),
    }
    return np.asarray(res.vertices, dtype=np.float64), info


def _run_similarity(case: Any, tpl: Any) -> tuple[np.ndarray, dict[str, Any]]:
    align, used = _shared_init(case, tpl)
    return align.similarity.apply(tpl.V), {"passed": {}, "markers_used": len(used)}


def run_method(method: str, case: Any, tpl: Any) -> tuple[np.ndarray, dict[str, Any]]:
    """Fit ``case`` with ``method``; returns fitted vertices (13380, 3) metres and notes."""
    if method == "bodyspace":
        return _run_bodyspace(case, tpl)
    if method in ("sumner", "amberg"):
        return _run_trimesh(method, case, tpl)
    if method == "similarity":
        return _run_similarity(case, tpl)
    raise ValueError(f"unknown method {method!r}; choose from {METHODS + OPTIONAL_METHODS}")


def case_meta(case: Any, tpl: Any) -> dict[str, Any]:
    """Case description plus the (method-independent) hole count."""
    from bench.metrics import hole_mask

    meta = dict(case.meta)
    meta["markers"] = len(case.markers)
    meta["hole_vertices"] = int(hole_mask(case.truth, case.scan.V, HOLE_RADIUS_M).sum())
    return meta


def evaluate(X: np.ndarray, case: Any, tpl: Any) -> dict[str, Any]:
    """All accuracy metrics (millimetres) of fitted vertices X against the case's truth."""
    from bench.metrics import (
        correspondence_error,
        hole_mask,
        landmark_error,
        surface_distance_stats,
    )
    from core.geometry import MeshDistance

    holes = hole_mask(case.truth, case.scan.V, HOLE_RADIUS_M)
    lm = np.array(sorted(tpl.landmarks.values()), dtype=np.int64)
    d = MeshDistance(X, np.asarray(tpl.F, dtype=np.int64)).distances(case.scan.V)
    return {
        "corr": correspondence_error(X, case.truth),
        "holes": correspondence_error(X, case.truth, holes),
        "landmark_mean": landmark_error(X, case.truth, lm),
        "scan_to_fit": surface_distance_stats(d),
    }


def fit_code_hash() -> str:
    """Short hash of the registration code on disk (it may be edited while the bench runs)."""
    import hashlib

    h = hashlib.sha1()
    files = [*sorted((REPO / "core" / "registration").glob("*.py")), REPO / "core" / "geometry.py"]
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:10]


def _git_head() -> str:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True
        )
        return out.stdout.strip() or "?"
    except OSError:
        return "?"


def child_main(method: str, seed: int, out: str) -> None:
    """One method × case in this (fresh) process; writes a JSON record to ``out``."""
    import trimesh  # noqa: F401  (imports are part of the baseline, not the fit)

    from bench.cases import make_case
    from core.registration.fit import fit  # noqa: F401
    from core.template import load_template

    code = fit_code_hash()
    tpl = load_template()
    case = make_case(seed)
    meta = case_meta(case, tpl)
    gc.collect()
    baseline = _rss_mb()
    exact = _reset_peak()
    r0 = resource.getrusage(resource.RUSAGE_SELF)
    t0 = time.perf_counter()
    X, info = run_method(method, case, tpl)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    peak = _peak_mb()
    rec: dict[str, Any] = {
        "method": method,
        "seed": seed,
        "ok": True,
        "meta": meta,
        "seconds": wall,
        "seconds_kind": "cold: first fit call in a fresh process",
        "cpu_seconds": (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime),
        "baseline_mb": baseline,
        "peak_mb": peak,
        "peak_increase_mb": peak - baseline,
        "peak_exact": exact,
        "fit_code": code,
        "info": info,
    }
    if method == "bodyspace":  # warm: template operators already cached in this process
        t1 = time.perf_counter()
        run_method(method, case, tpl)
        rec["seconds_warm"] = time.perf_counter() - t1
    rec["metrics"] = evaluate(X, case, tpl)
    with open(out, "w") as f:
        json.dump(rec, f)


# --------------------------------------------------------------------------------------------
# the driver


def parse_seeds(text: str) -> list[int]:
    """``"0-5"`` → [0..5]; ``"0,2,7"`` → [0, 2, 7]; ranges and lists combine."""
    seeds: list[int] = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        if "-" in part:
            a, b = part.split("-", 1)
            seeds.extend(range(int(a), int(b) + 1))
        else:
            seeds.append(int(part))
    if not seeds:
        raise ValueError(f"no seeds in {text!r}")
    return seeds


def run_child(method: str, seed: int, timeout: float) -> dict[str, Any]:
    """Run one method × case in a fresh subprocess; failures come back as records."""
    fd, out = tempfile.mkstemp(prefix=f"bench-{method}-{seed}-", suffix=".json")
    os.close(fd)
    cmd = [sys.executable, "-m", "bench.registration", "--child", method, str(seed), out]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(
            cmd, cwd=REPO, capture_output=True, text=True, timeout=timeout, check=False
        )
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
            return _failed(method, seed, f"exit {proc.returncode}: {' | '.join(tail)}")
        with open(out) as f:
            rec = json.load(f)
        rec["process_seconds"] = time.perf_counter() - t0
        return rec
    except subprocess.TimeoutExpired:
        return _failed(method, seed, f"timeout: > {timeout:.0f} s (process killed)")
    except (OSError, ValueError) as e:
        return _failed(method, seed, f"{type(e).__name__}: {e}")
    finally:
        Path(out).unlink(missing_ok=True)


def _failed(method: str, seed: int, reason: str) -> dict[str, Any]:
    return {"method": method, "seed": seed, "ok": False, "reason": reason}


COLS = [
    # header, width, getter
    ("mean", 6, lambda r: r["metrics"]["corr"]["mean"]),
    ("p95", 6, lambda r: r["metrics"]["corr"]["p95"]),
    ("max", 6, lambda r: r["metrics"]["corr"]["max"]),
    ("h.mean", 6, lambda r: r["metrics"]["holes"]["mean"]),
    ("h.p95", 6, lambda r: r["metrics"]["holes"]["p95"]),
    ("h.max", 6, lambda r: r["metrics"]["holes"]["max"]),
    ("lmk", 6, lambda r: r["metrics"]["landmark_mean"]),
    ("s2f", 6, lambda r: r["metrics"]["scan_to_fit"]["mean"]),
    ("s2f95", 6, lambda r: r["metrics"]["scan_to_fit"]["p95"]),
    ("time s", 7, lambda r: r["seconds"]),
    ("cpu s", 7, lambda r: r.get("cpu_seconds", float("nan"))),
    ("peak MB", 8, lambda r: r["peak_mb"]),
    ("+MB", 7, lambda r: r["peak_increase_mb"]),
]
NAME_W = 11
SUMMARY_W = 19


def _fmt(v: float, w: int) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-".rjust(w)
    if abs(v) >= 1000:
        return f"{v:{w}.0f}"
    return f"{v:{w}.2f}" if abs(v) < 100 else f"{v:{w}.1f}"


def _header(first: str = "method", name_w: int = NAME_W) -> str:
    groups = (
        f"{'':{name_w}} {'correspondence error (mm)':^20} {'in holes (mm)':^20} "
        f"{'mm':>6} {'scan→fit mm':^13}"
    )
    cols = f"{first:{name_w}} " + " ".join(h.rjust(w) for h, w, _ in COLS)
    return groups.rstrip() + "\n" + cols + "\n" + "-" * len(cols)


def _row(name: str, rec: dict[str, Any]) -> str:
    if not rec.get("ok"):
        return f"{name:{NAME_W}} FAILED: {rec.get('reason', '?')}"
    return f"{name:{NAME_W}} " + " ".join(_fmt(g(rec), w) for _, w, g in COLS)


def describe_case(seed: int, meta: dict[str, Any]) -> str:
    """One line describing a case."""
    return (
        f"case seed {seed}: {meta['sex']}, stature {meta['stature_m']:.3f} m, "
        f"units {meta['units']}, up {meta['up']}, {meta['n_views']} views, "
        f"pitch {meta['pitch_mm']:.2f} mm, noise {meta['noise_mm']:.2f} mm, "
        f"{meta['scan_vertices']} scan vertices, "
        f"{meta['markers']} markers, {meta['hole_vertices']} template vertices in holes (>5 mm)"
    )


def summarize(results: dict[int, dict[str, dict]], methods: list[str]) -> dict[str, Any]:
    """Per method: mean over successful cases and the worst case of every column."""
    out: dict[str, Any] = {}
    for m in methods:
        recs = [results[s][m] for s in results if m in results[s]]
        ok = [r for r in recs if r.get("ok")]
        entry: dict[str, Any] = {"cases": len(recs), "ok": len(ok), "mean": {}, "worst": {}}
        for h, _, g in COLS:
            vals = np.array([g(r) for r in ok], dtype=np.float64)
            vals = vals[np.isfinite(vals)]
            entry["mean"][h] = float(vals.mean()) if vals.size else float("nan")
            entry["worst"][h] = float(vals.max()) if vals.size else float("nan")
        if m == "bodyspace":
            warm = [r["seconds_warm"] for r in ok if "seconds_warm" in r]
            entry["mean"]["seconds_warm"] = float(np.mean(warm)) if warm else float("nan")
        out[m] = entry
    return out


def targets_check(summary: dict[str, Any]) -> str:
    """Whether bodyspace's worst case meets each target."""
    if "bodyspace" not in summary or not summary["bodyspace"]["ok"]:
        return "bodyspace: no successful fits"
    w = summary["bodyspace"]["worst"]
    checks = [
        ("mean", w["mean"], TARGETS["mean_mm"], "mm"),
        ("p95", w["p95"], TARGETS["p95_mm"], "mm"),
        ("scan→fit", w["s2f"], TARGETS["scan_to_fit_mean_mm"], "mm"),
        ("time", w["time s"], TARGETS["seconds"], "s"),
        ("peak", w["peak MB"] / 1024.0, TARGETS["peak_gb"], "GB"),
    ]
    parts = [
        f"{n} {v:.2f} {u} {'ok' if v <= t else 'MISS'}" for n, v, t, u in checks if np.isfinite(v)
    ]
    return "bodyspace worst case vs targets: " + ", ".join(parts)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.registration", description=__doc__)
    p.add_argument("--seeds", default=None, help=f"e.g. 0-5 or 0,3,7 (default {DEFAULT_SEEDS})")
    p.add_argument(
        "--methods",
        default=",".join(METHODS),
        help="comma list: " + ", ".join(METHODS + OPTIONAL_METHODS),
    )
    p.add_argument("--json", default=None, help="write all numbers to this JSON file")
    p.add_argument("--quick", action="store_true", help=f"smoke run: seeds {QUICK_SEEDS}")
    p.add_argument("--timeout", type=float, default=600.0, help="seconds per fit process (600)")
    p.add_argument("--child", nargs=3, metavar=("METHOD", "SEED", "OUT"), help=argparse.SUPPRESS)
    a = p.parse_args(argv)

    if a.child:
        child_main(a.child[0], int(a.child[1]), a.child[2])
        return 0

    seeds = parse_seeds(a.seeds or (QUICK_SEEDS if a.quick else DEFAULT_SEEDS))
    methods = [m.strip() for m in a.methods.split(",") if m.strip()]
    bad = [m for m in methods if m not in METHODS + OPTIONAL_METHODS]
    if bad:
        p.error(f"unknown method(s) {bad}; choose from {', '.join(METHODS + OPTIONAL_METHODS)}")

    print(f"registration benchmark: seeds {seeds}, methods {methods}", flush=True)
    print(
        "errors in mm against the truth (template order); 'holes' = template vertices with no "
        "scan point within 5 mm of their true position; lmk = mean over the 62 landmark vertices;"
        " s2f = exact scan→fit distance; time = wall time of the first (cold) fit call in a fresh "
        "process, cpu = its user+sys CPU time (all threads); peak MB = process peak RSS during "
        "the fit, +MB = over the baseline after imports and case loading",
        flush=True,
    )
    t_all = time.perf_counter()
    load0 = os.getloadavg()
    head = _git_head()
    print(
        f"{os.cpu_count()} CPUs; load average at start {load0[0]:.2f}; git HEAD {head}, "
        f"registration code {fit_code_hash()}",
        flush=True,
    )
    results: dict[int, dict[str, dict]] = {}
    metas: dict[int, dict[str, Any]] = {}
    for seed in seeds:
        results[seed] = {}
        for m in methods:
            rec = run_child(m, seed, a.timeout)
            results[seed][m] = rec
            if rec.get("ok") and seed not in metas:
                metas[seed] = rec["meta"]
                print("\n" + describe_case(seed, rec["meta"]), flush=True)
            state = f"{rec['seconds']:.1f} s" if rec.get("ok") else "FAILED"
            print(f"  ran {m} on seed {seed}: {state}", flush=True)
        if seed not in metas:
            print(f"\ncase seed {seed}: every method failed", flush=True)
        print(_header(), flush=True)
        for m in methods:
            print(_row(m, results[seed][m]), flush=True)
        bs = results[seed].get("bodyspace")
        if bs and bs.get("ok"):
            print(
                f"  bodyspace warm fit (operators cached): {bs['seconds_warm']:.2f} s; "
                f"its data_weight==0 vertices: {bs['info']['no_data_vertices']}",
                flush=True,
            )

    summary = summarize(results, methods)
    total = time.perf_counter() - t_all
    load1 = os.getloadavg()
    print(f"\nSUMMARY over {len(seeds)} cases (seeds {seeds}); total run {total / 60:.1f} min")
    print(_header("method / over cases", SUMMARY_W))
    for m in methods:
        s = summary[m]
        tag = f" ({s['ok']}/{s['cases']} ok)" if s["ok"] < s["cases"] else ""
        for kind in ("mean", "worst"):
            vals = s[kind]
            line = f"{(m + ' ' + kind):{SUMMARY_W}} " + " ".join(
                _fmt(vals[h], w) for h, w, _ in COLS
            )
            print(line + (tag if kind == "mean" else ""))
    if "bodyspace" in summary and summary["bodyspace"]["ok"]:
        print(
            f"bodyspace warm fit time, mean: {summary['bodyspace']['mean']['seconds_warm']:.2f} s"
        )
    print(
        f"load average (1 min) at start {load0[0]:.2f}, at end {load1[0]:.2f} on {os.cpu_count()} "
        "CPUs (a load near or above the CPU count: other work shared the machine, wall times "
        "are inflated)"
    )
    codes = sorted(
        {r["fit_code"] for rs in results.values() for r in rs.values() if "fit_code" in r}
    )
    if len(codes) > 1:
        print(f"NOTE: the registration code changed during the run (versions {', '.join(codes)})")
    print(TARGETS_LINE)
    print(targets_check(summary))

    if a.json:
        doc = {
            "seeds": seeds,
            "methods": methods,
            "targets": TARGETS,
            "hole_radius_m": HOLE_RADIUS_M,
            "units": "millimetres for errors, seconds, MB",
            "total_seconds": total,
            "cpus": os.cpu_count(),
            "git_head": head,
            "fit_code_versions": codes,
            "load_average_start_end": [load0[0], load1[0]],
            "cases": [{"seed": s, "meta": metas.get(s), "results": results[s]} for s in seeds],
            "summary": summary,
        }
        Path(a.json).write_text(json.dumps(doc, indent=1, allow_nan=True))
        print(f"wrote {a.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
