"""Synthetic ground truth: plausible random bodies and simulated raw whole-body range scans.

- :func:`random_body` — a seeded body in template vertex order (MakeHuman targets + small pose).
- :func:`simulate_scan` — a seeded multi-view range scan of any template-order body.
- :func:`load_targets` — the committed MakeHuman shape-target library.
"""

from core.synth.bodies import SynthBody, random_body
from core.synth.scanner import ScanConfig, SimScan, simulate_scan
from core.synth.targets import TargetLibrary, load_targets

__all__ = [
    "ScanConfig",
    "SimScan",
    "SynthBody",
    "TargetLibrary",
    "load_targets",
    "random_body",
    "simulate_scan",
]
