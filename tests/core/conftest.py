"""Shared fixtures of the core tests."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest


@pytest.fixture
def realworld_case(tmp_path) -> Callable[[int, str], tuple[Any, Any, Any]]:
    """``load(seed, kind)`` -> (case of ``core.synth.scanner_outputs.make_case``, its scan as the
    CLI loads it, its truth in the scan's canonical frame); the file is written to ``tmp_path``.
    """

    def load(seed: int, kind: str) -> tuple[Any, Any, Any]:
        from core.io import load_scan
        from core.synth.scanner_outputs import make_case

        case = make_case(seed, kind)
        scan, _ = load_scan(case.write(tmp_path / f"{kind}-{seed}.ply"))
        return case, scan, scan.frame.to_canonical(case.truth)

    return load
