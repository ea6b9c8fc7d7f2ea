"""Seeded registration cases: a random body, its simulated raw scan, markers and the truth.

Each case varies what real scanners vary: body (sex, stature, weight, regional shape, slight pose),
views, pixel pitch, noise, dropouts, units (m/mm), up axis (+Y/+Z) and the scanner frame.
The truth is the scanned body in template vertex order, in the same canonical frame as the
prepared scan (metres, +Y up).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.io import detect_frame, prepare_scan
from core.scan import RawMesh, Scan
from core.synth import ScanConfig, random_body, simulate_scan
from core.template import load_template


@dataclass
class Case:
    """One registration case (canonical frame: metres, +Y up)."""

    seed: int
    scan: Scan
    markers: dict[str, np.ndarray]
    truth: np.ndarray  # (13380, 3) metres
    raw: RawMesh  # the scan as a file would hold it (file units/axes)
    raw_markers: dict[str, np.ndarray]
    meta: dict = field(default_factory=dict)


def scan_config(
    rng: np.random.Generator, *, small: bool = False, vary_frame: bool = True
) -> ScanConfig:
    """A random but plausible scanner configuration."""
    kw: dict = {
        "n_views": int(rng.choice([4, 6, 8])),
        "pitch_m": float(rng.uniform(0.003, 0.005)),
        "noise_m": float(rng.uniform(0.0005, 0.0015)),
    }
    if vary_frame:
        kw["units"] = str(rng.choice(["m", "mm"]))
        kw["up"] = str(rng.choice(["+y", "+z"]))
        kw["random_frame"] = True
    if small:
        return ScanConfig.small(**{k: v for k, v in kw.items() if k not in ("n_views", "pitch_m")})
    return ScanConfig(**kw)


def make_case(
    seed: int, *, small: bool = False, vary_frame: bool = True, pose: bool = True
) -> Case:
    """Build case ``seed`` (deterministic)."""
    rng = np.random.default_rng(seed)
    tpl = load_template()
    body = random_body(rng, pose=pose)
    cfg = scan_config(rng, small=small, vary_frame=vary_frame)
    sim = simulate_scan(body.V, tpl.F, rng, config=cfg, landmarks=tpl.landmarks)
    raw = RawMesh(V=sim.V_scan, F=sim.F_scan, normals=sim.normals, confidence=sim.confidence)
    frame = detect_frame(raw.V, markers=sim.markers)
    scan = prepare_scan(raw, frame)
    markers = {k: frame.to_canonical(v[None])[0] for k, v in sim.markers.items()}
    truth = frame.to_canonical(sim.V_truth)
    meta = {
        "sex": body.sex,
        "stature_m": float(body.stature_m),
        "units": cfg.units,
        "up": cfg.up,
        "n_views": cfg.n_views,
        "pitch_mm": cfg.pitch_m * 1000,
        "noise_mm": cfg.noise_m * 1000,
        "scan_vertices": len(scan.V),
    }
    return Case(seed, scan, markers, truth, raw, dict(sim.markers), meta)
