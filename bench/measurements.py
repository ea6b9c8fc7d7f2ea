"""Bodies from tape measurements on held-out ANSUR II subjects (issue 6).

    .venv/bin/python -m bench.measurements                 # 100 held-out subjects per sex
    .venv/bin/python -m bench.measurements --n 0 --json out.json   # every held-out subject

For every held-out subject (``core.shapespace.ansur.split(sex, "test")``) and each tape set
(:data:`TAPE_SETS`), the most likely body is made from the subject's real values of the set's
measurements (``core.matching.from_measurements.body_from_measurements``, default model) and
measured with ``core.measure.measure`` plus the model's calibration offsets (the body's most
likely ANSUR tape values, ``report.predicted``). Printed per set and sex:

- for each measurement **not given**: RMSE (mm; kg for weight) of the body's value against the
  subject's real one, its mean error (bias), the RMSE of the conditional Gaussian alone (the
  feature map, before the Gauss–Newton refinement) and that of the peer — the best linear
  regression of the measurement on the given ones, fitted to the held-in rows
  (``split(sex, "train")``) — with the ratio body / regression;
- for the **given** measurements: the residual of the body (measured - given), RMSE and max,
  and the RMSE of the conditional Gaussian's body;
- the time per body (check, conditional Gaussian, refinement, and measuring all 39).

``core.measure``'s definitions read some measurements on the model's bodies systematically
differently from ANSUR's tape (``bench.shapespace``'s bias column); the offsets
(``from_measurements.calibration``: ANSUR held-in mean minus the measurement of the model's body
of their mean stature and weight) take the mean of that out, the bias column shows what is left.
Subjects outside the model's range (the feature map's check) are skipped and counted.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from bench.registration import _git_head
from core.errors import BodyspaceError
from core.matching.from_measurements import body_from_measurements
from core.measure import MEASUREMENTS
from core.shapespace import default_model
from core.shapespace.ansur import split

SEXES = ("female", "male")
SW = ("stature", "weightkg")
CIRC3 = (*SW, "chestcircumference", "waistcircumference", "buttockcircumference")
#: Tape sets: what a user might know — stature and weight; plus the three main circumferences;
#: a tailor's set (plus neck, thigh, calf, wrist, inseam, shoulder breadth, arm lengths).
TAPE_SETS: dict[str, tuple[str, ...]] = {
    "stature+weight": SW,
    "+chest/waist/buttock": CIRC3,
    "tailor (13)": (
        *CIRC3, "neckcircumference", "thighcircumference", "calfcircumference",
        "wristcircumference", "crotchheight", "biacromialbreadth", "acromionradialelength",
        "radialestylionlength",
    ),
}  # fmt: skip


def _unit(name: str) -> float:
    return 1.0 if name == "weightkg" else 1000.0


def run_set(sex: str, given: tuple[str, ...], n: int | None) -> dict:
    """Bodies from the ``given`` measurements of held-out rows of ``sex``; errors and timing."""
    te, tr = split(sex, "test"), split(sex, "train")
    names = [k for k in MEASUREMENTS if k in te]
    rows = np.arange(len(te["stature"]))
    if n:
        rows = rows[:n]
    model = default_model()
    got, cond, used, times, skipped = [], [], [], [], []
    for i in rows:
        vals = {k: float(te[k][i]) for k in given}
        t0 = time.perf_counter()
        try:
            res = body_from_measurements(sex, vals, model=model)
        except BodyspaceError as e:
            skipped.append(f"{int(te['subjectid'][i])}: {e}")
            continue
        times.append(time.perf_counter() - t0)
        got.append(res.report.predicted)
        c = body_from_measurements(sex, vals, model=model, refine=False)
        cond.append(c.report.predicted)
        used.append(i)
    idx = np.array(used, dtype=int)
    A = np.stack([np.ones_like(tr["stature"])] + [tr[k] for k in given], 1)
    At = np.stack([np.ones(len(idx))] + [te[k][idx] for k in given], 1)
    table: dict[str, dict] = {}
    for k in names:
        u = _unit(k)
        truth = te[k][idx]
        body = np.array([g[k] for g in got])
        e = (body - truth) * u
        ec = (np.array([c[k] for c in cond]) - truth) * u
        row = {"rmse": float(np.sqrt(np.mean(e**2))), "bias": float(e.mean())}
        row["cond_rmse"] = float(np.sqrt(np.mean(ec**2)))
        if k in given:
            row["max_abs"] = float(np.abs(e).max())
        else:
            cf = np.linalg.lstsq(A, tr[k], rcond=None)[0]
            er = (At @ cf - truth) * u
            row["regression_rmse"] = float(np.sqrt(np.mean(er**2)))
            row["ratio"] = row["rmse"] / max(row["regression_rmse"], 1e-12)
        table[k] = row
    return {
        "given": list(given),
        "subjects": len(idx),
        "skipped": skipped,
        "seconds_per_body_mean": float(np.mean(times)) if times else float("nan"),
        "seconds_per_body_p95": float(np.percentile(times, 95)) if times else float("nan"),
        "table": table,
    }


def print_set(sex: str, label: str, r: dict) -> None:
    given = r["given"]
    t, t95 = r["seconds_per_body_mean"], r["seconds_per_body_p95"]
    print(f"\n{sex}, given {label} ({', '.join(given)}): {r['subjects']} held-out subjects "
          f"({len(r['skipped'])} out of the model's range); "
          f"{t:.2f} s per body (p95 {t95:.2f})")  # fmt: skip
    tab = r["table"]
    print(f"  not given (mm; kg)               {'body':>7s} {'bias':>7s} {'cond.G':>7s} "
          f"{'regr.':>7s} {'ratio':>6s}")  # fmt: skip
    ratios = []
    for k, t in tab.items():
        if k in given:
            continue
        ratios.append(t["ratio"])
        flag = "" if t["ratio"] <= 1.1 else "  > 1.1"
        print(f"  {k:32s} {t['rmse']:7.1f} {t['bias']:7.1f} {t['cond_rmse']:7.1f} "
              f"{t['regression_rmse']:7.1f} {t['ratio']:6.2f}{flag}")  # fmt: skip
    print(f"  -> within 1.1x of the regression: {sum(x <= 1.1 for x in ratios)}/{len(ratios)}, "
          f"median ratio {np.median(ratios):.2f}")  # fmt: skip
    res = ", ".join(
        f"{k} {tab[k]['rmse']:.1f}/{tab[k]['max_abs']:.1f} ({tab[k]['cond_rmse']:.1f})"
        for k in given
    )
    print(f"  given, residual RMSE/max (cond.G RMSE) (mm; kg): {res}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench.measurements", description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=100,
                    help="held-out subjects per sex (first n rows; 0 = all)")  # fmt: skip
    ap.add_argument("--sets", default=",".join(TAPE_SETS),
                    help=f"comma-separated tape sets of {list(TAPE_SETS)}")  # fmt: skip
    ap.add_argument("--sex", choices=SEXES, action="append", help="default both")
    ap.add_argument("--json", type=Path, help="write every number here")
    args = ap.parse_args(argv)
    sets = [s.strip() for s in args.sets.split(",") if s.strip()]
    bad = [s for s in sets if s not in TAPE_SETS]
    if bad:
        ap.error(f"unknown tape set(s) {bad}; choose from {list(TAPE_SETS)}")
    m = default_model()
    bodies = json.dumps(m.metadata.get("bodies", {}))
    created = m.metadata.get("created", "?")
    print(f"bench.measurements — git {_git_head()}, load {os.getloadavg()[0]:.1f}; model: "
          f"default ({created}, {bodies}); n = {args.n or 'all'} per sex")  # fmt: skip
    out: dict = {}
    t0 = time.perf_counter()
    for sex in args.sex or SEXES:
        out[sex] = {}
        for label in sets:
            r = run_set(sex, TAPE_SETS[label], args.n or None)
            out[sex][label] = r
            print_set(sex, label, r)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s, load {os.getloadavg()[0]:.1f}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
