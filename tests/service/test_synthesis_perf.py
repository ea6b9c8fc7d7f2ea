"""Synthesis serving costs that a functional test would not see (issue 5's performance target;
the load test itself is ``bench/synthesis_load.py``)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from service.runtime import tune_malloc

SYN = "/v1/models/default/synthesize"


def _minor_faults(pid: int) -> int:
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[7])


def test_tune_malloc_sets_thresholds_on_linux():
    assert tune_malloc() is sys.platform.startswith("linux")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc and glibc malloc")
def test_glb_requests_do_not_page_fault(server, client):
    """Without fixed malloc thresholds each GLB request mmap()ed its ~2 MB of arrays afresh:
    ~580 page faults and ~1.7 ms of CPU per request (half of it)."""
    pid = server["proc"].pid
    bodies = [{"sex": "female", "height_m": 1.55 + 0.005 * i, "weight_kg": 60} for i in range(60)]
    for b in bodies[:10]:  # warm: model, encoder, key cache
        assert client.post(SYN, json=b).status_code == 200
    before = _minor_faults(pid)
    for b in bodies[10:]:
        r = client.post(SYN, json=b)
        assert r.status_code == 200 and len(r.content) > 400_000
    per_request = (_minor_faults(pid) - before) / 50
    assert per_request < 50, f"{per_request:.0f} page faults per request"
