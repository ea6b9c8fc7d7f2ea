"""The OpenAPI document against the real server: schemathesis (bounded examples) finds no 5xx and
no schema/behaviour mismatch.

Checks (``schemathesis.toml`` next to this file): ``not_a_server_error``,
``status_code_conformance`` (every answered status documented), ``content_type_conformance``,
``response_schema_conformance``, ``response_headers_conformance``, ``negative_data_rejection``
(requests the schema forbids are refused), ``unsupported_method`` (405 with ``Allow``) and
``positive_data_acceptance`` (requests the schema allows are accepted) on every operation but
the 9 whose refusals the schema cannot express (opaque cursors, upload contents, ranges that
depend on the sex, on each other or on the body edited, a posed body's state; the file says
which). ~1,200 requests, ~40 s.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from service.testing import free_port, service_env, start_server

CONFIG = Path(__file__).with_name("schemathesis.toml")


def test_schemathesis_finds_no_5xx_and_no_mismatch(tmp_path: Path):
    data = tmp_path / "data"
    port = free_port()
    env = service_env({"BODYSPACE_DATA_DIR": str(data), "BODYSPACE_API_KEY": "st-key"})
    proc = start_server(env, port, tmp_path / "server.log")
    try:
        st = Path(sys.executable).with_name("schemathesis")
        out = subprocess.run(
            [str(st), "--config-file", str(CONFIG), "run", f"http://127.0.0.1:{port}/openapi.json",
             "-H", "Authorization: Bearer st-key",
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
