"""Build the bundled example scan (``core/assets/examples/``) from the scan simulator.

The example is a seeded random body (``core.synth.random_body``) scanned by the multi-view
simulator (``core.synth.simulate_scan``): 6 scanner columns, 7 mm pitch, 1 mm range noise,
written in **millimetres, +Z up** so that ``bodyspace demo`` shows units and up-axis detection.

Files written (deterministic for a given seed and code version):

- ``example_scan.ply`` — binary PLY, triangles, per-vertex ``confidence``.
- ``example_markers.csv`` — ``name,x,y,z`` landmark positions (with placement noise), in the
  scan's units and axes.
- ``example_truth.npz`` — ``vertices`` (13380, 3) float32: the scanned body in template vertex
  order, in the scan file's frame (millimetres, +Z up); plus ``units`` and ``up``.

Remake with ``.venv/bin/python -m core.assets.build_example``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from core.io import write_markers_csv, write_ply
from core.synth import ScanConfig, random_body, simulate_scan
from core.template import load_template

EXAMPLES_DIR = Path(__file__).resolve().parent / "examples"
SEED = 2003
CONFIG = {"n_views": 6, "pitch_m": 0.007, "noise_m": 0.001, "units": "mm", "up": "+z"}


def build(out_dir: Path = EXAMPLES_DIR, seed: int = SEED) -> dict[str, Path]:
    """Simulate the example scan and write its three files into ``out_dir``.

    Returns
    -------
    dict
        ``scan``, ``markers``, ``truth`` -> written path.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    tpl = load_template()
    body = random_body(rng, pose=True)
    cfg = ScanConfig(**CONFIG)
    sim = simulate_scan(body.V, tpl.F, rng, config=cfg, landmarks=tpl.landmarks)
    paths = {
        "scan": out_dir / "example_scan.ply",
        "markers": out_dir / "example_markers.csv",
        "truth": out_dir / "example_truth.npz",
    }
    write_ply(paths["scan"], sim.V_scan, sim.F_scan, confidence=sim.confidence)
    write_markers_csv(paths["markers"], {k: np.round(v, 2) for k, v in sim.markers.items()})
    np.savez_compressed(
        paths["truth"],
        vertices=sim.V_truth.astype(np.float32),
        units=np.array(cfg.units),
        up=np.array(cfg.up),
        seed=np.array(seed),
        sex=np.array(body.sex),
        stature_m=np.array(body.stature_m),
    )
    return paths


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out-dir", type=Path, default=EXAMPLES_DIR)
    ap.add_argument("--seed", type=int, default=SEED)
    args = ap.parse_args(argv)
    for name, p in build(args.out_dir, args.seed).items():
        print(f"{name:8s} {p}  ({p.stat().st_size / 1e6:.2f} MB)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
