"""CI: a distributed fit end to end with a plain install (``pip install .``, no extras).

Usage: ``python .ci/plain_install_smoke.py VENV`` where ``VENV`` holds a fresh ``pip install .``.
Needs Redis (``BODYSPACE_TEST_REDIS_URL``) and PostgreSQL (``BODYSPACE_TEST_POSTGRES_URL``, an
admin connection: a throwaway database is created and dropped). Starts that venv's ``bodyspace
serve`` and ``bodyspace worker`` from a folder outside the source tree (so only the installed
package is imported), creates a key with ``bodyspace keys create``, uploads the bundled example
scan and markers, posts a fit (fast schedule), polls until it succeeds and fetches the GLB;
also runs docker-compose.yml's worker healthcheck command against the worker.
Standard library only (the plain venv has no httpx, and this script runs with any python3).
"""

from __future__ import annotations

import json
import os
import re
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "core" / "assets" / "examples"
REDIS = os.environ.get("BODYSPACE_TEST_REDIS_URL", "redis://127.0.0.1:6379/15")
PG_ADMIN = os.environ.get(
    "BODYSPACE_TEST_POSTGRES_URL", "postgresql://postgres@127.0.0.1:5432/postgres"
)
TIMEOUT_S = 150


def log(msg: str) -> None:
    print(f"[plain-install] {msg}", flush=True)


def psql(sql: str) -> None:
    subprocess.run(["psql", PG_ADMIN, "-q", "-v", "ON_ERROR_STOP=1", "-c", sql], check=True)


def request(method: str, url: str, key: str, body: bytes | None = None, ctype: str = "") -> tuple:
    req = urllib.request.Request(url, data=body, method=method)
    req.add_header("Authorization", f"Bearer {key}")
    if ctype:
        req.add_header("Content-Type", ctype)
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.read()


def multipart(fields: dict[str, tuple[str, bytes]]) -> tuple[bytes, str]:
    boundary = uuid.uuid4().hex
    out = b""
    for name, (filename, data) in fields.items():
        out += (
            (
                f'--{boundary}\r\nContent-Disposition: form-data; name="{name}"; '
                f'filename="{filename}"\r\nContent-Type: application/octet-stream\r\n\r\n'
            ).encode()
            + data
            + b"\r\n"
        )
    return out + f"--{boundary}--\r\n".encode(), f"multipart/form-data; boundary={boundary}"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main(venv: Path) -> int:
    bodyspace = str(venv / "bin" / "bodyspace")
    db = f"bodyspace_ci_{secrets.token_hex(4)}"
    work = Path(tempfile.mkdtemp(prefix="bodyspace-plain-"))
    port = free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("BODYSPACE_", "PYTHON"))}
    env.update(
        BODYSPACE_DATABASE_URL=PG_ADMIN.rsplit("/", 1)[0] + "/" + db,
        BODYSPACE_BROKER_URL=REDIS,
        BODYSPACE_DATA_DIR=str(work / "data"),
        BODYSPACE_QUEUE_NAME=f"bodyspace-ci-{secrets.token_hex(4)}",
    )
    psql(f'CREATE DATABASE "{db}"')
    procs: list[subprocess.Popen] = []
    t0 = time.monotonic()
    try:
        out = subprocess.run(
            [bodyspace, "keys", "create", "--tenant", "ci"],
            env=env, cwd=work, capture_output=True, text=True, check=True,
        )  # fmt: skip
        key = re.search(r"(bsk_\S+)", out.stdout).group(1)
        for name, args in (
            ("api", ["serve", "--port", str(port), "--log-level", "warning"]),
            ("worker", ["worker", "--concurrency", "1", "--hostname", "ci@%h"]),
        ):
            fh = open(work / f"{name}.log", "wb")  # noqa: SIM115 (lives as long as the process)
            procs.append(
                subprocess.Popen(
                    [bodyspace, *args],
                    env=env,
                    cwd=work,
                    stdout=fh,
                    stderr=subprocess.STDOUT,
                    start_new_session=True,
                )
            )
        base = f"http://127.0.0.1:{port}"
        while True:  # ready = database reachable and a worker consumes the queue
            if any(p.poll() is not None for p in procs):
                raise RuntimeError("a process exited during start-up")
            try:
                status, body = request("GET", base + "/readyz", key)
                if status == 200 and json.loads(body).get("status") == "ok":
                    break
            except OSError:
                pass
            if time.monotonic() - t0 > 60:
                raise RuntimeError(f"not ready after 60 s: {status} {body[:300]!r}")
            time.sleep(0.3)
        log(f"serve + worker ready in {time.monotonic() - t0:.1f} s")
        # docker-compose.yml's worker healthcheck, against this worker (node ci@HOST)
        ping = [str(venv / "bin" / "celery"), "-A", "worker.tasks", "inspect", "ping"]
        ping += ["-d", f"ci@{socket.gethostname()}", "--timeout", "10"]
        hc = subprocess.run(ping, env=env, cwd=work, capture_output=True, text=True)
        assert hc.returncode == 0 and "pong" in hc.stdout, (hc.returncode, hc.stdout, hc.stderr)
        log("worker healthcheck (celery inspect ping): pong")
        body, ctype = multipart(
            {
                "scan": ("example_scan.ply", (EXAMPLES / "example_scan.ply").read_bytes()),
                "markers": ("example_markers.csv", (EXAMPLES / "example_markers.csv").read_bytes()),
            }
        )
        status, resp = request("POST", base + "/v1/scans", key, body, ctype)
        assert status == 201, (status, resp[:500])
        scan_id = json.loads(resp)["id"]
        fit = json.dumps({"scan_id": scan_id, "options": {"schedule": "fast"}}).encode()
        status, resp = request("POST", base + "/v1/fits", key, fit, "application/json")
        assert status == 202, (status, resp[:500])
        fit_id = json.loads(resp)["id"]
        while True:
            status, resp = request("GET", f"{base}/v1/fits/{fit_id}", key)
            state = json.loads(resp)["state"]
            if state in ("succeeded", "failed"):
                break
            if time.monotonic() - t0 > TIMEOUT_S:
                raise RuntimeError(f"fit still {state} after {TIMEOUT_S} s")
            time.sleep(0.5)
        assert state == "succeeded", resp[:1000]
        status, glb = request("GET", f"{base}/v1/fits/{fit_id}/result?format=glb", key)
        assert status == 200 and glb[:4] == b"glTF", (status, glb[:100])
        log(f"fit {fit_id} succeeded on the worker; GLB {len(glb)} bytes; "
            f"{time.monotonic() - t0:.1f} s in all")  # fmt: skip
        return 0
    except BaseException:
        for f in sorted(work.glob("*.log")):
            log(f"--- {f.name}\n{f.read_text(errors='replace')[-4000:]}")
        raise
    finally:
        for p in procs:
            try:
                os.killpg(p.pid, signal.SIGTERM)
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()
            except ProcessLookupError:
                pass
        psql(f'DROP DATABASE IF EXISTS "{db}" WITH (FORCE)')
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))
