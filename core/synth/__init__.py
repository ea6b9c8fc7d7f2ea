"""Synthetic ground truth: plausible random bodies and simulated raw whole-body range scans.

- :func:`random_body` — a seeded body in template vertex order (MakeHuman targets + small pose).
- :func:`simulate_scan` — a seeded multi-view range scan of any template-order body.
- :func:`load_targets` — the committed MakeHuman shape-target library.

Outside the prior's family (import the modules directly; ``closed_mesh`` needs scikit-image):
:mod:`core.synth.realworld` (off-model bodies, scanning-protocol postures) and
:mod:`core.synth.scanner_outputs` (closed meshes, hair, inward-wound arms, clutter, clouds, other
marker conventions; ``make_case(seed, kind)``, ``benchmark_cases(n)``).
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
