"""The OpenAPI document against the real server: schemathesis (bounded examples) finds no 5xx and
no schema/behaviour mismatch.

Checks: ``not_a_server_error``, ``status_code_conformance`` (every answered status documented),
``content_type_conformance``, ``response_schema_conformance``, ``response_headers_conformance``,
``negative_data_rejection`` (requests the schema forbids are refused) and ``unsupported_method``
(405 with ``Allow``). ``positive_data_acceptance`` is not in the list: uploads whose content
is not a scan, opaque cursors and combinations the schema cannot express are refused by design
(see README, "Reliability and security"). ~1,000 requests, ~40 s.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from service.testing import free_port, service_env, start_server

CHECKS = (
    "not_a_server_error,status_code_conformance,content_type_conformance,"
    "response_schema_conformance,response_headers_conformance,negative_data_rejection,"
    "unsupported_method"
)


def test_schemathesis_finds_no_5xx_and_no_mismatch(tmp_path: Path):
    data = tmp_path / "data"
    port = free_port()
    env = service_env({"BODYSPACE_DATA_DIR": str(data), "BODYSPACE_API_KEY": "st-key"})
    proc = start_server(env, port, tmp_path / "server.log")
    try:
        st = Path(sys.executable).with_name("schemathesis")
        out = subprocess.run(
            [str(st), "run", f"http://127.0.0.1:{port}/openapi.json",
             "-H", "Authorization: Bearer st-key", "--checks", CHECKS,
             "--phases", "examples,coverage,fuzzing", "--max-examples", "3", "--seed", "1",
             "--request-timeout", "30", "--no-color"],
            cwd=tmp_path, capture_output=True, text=True, timeout=600,
        )  # fmt: skip
    finally:
        proc.stop()
    summary = out.stdout[-3000:]
    print(summary)  # the SUMMARY block (operations, phases, test cases) in the test log
    assert out.returncode == 0, out.stdout[-20000:] + out.stderr[-2000:]
    assert " passed" in summary and "failures" not in summary.split("SUMMARY")[-1].lower()
