"""Helpers for tests and benchmarks with real parts: servers and workers as subprocesses.

Nothing here is mocked: :class:`Proc` starts ``bodyspace serve`` / ``bodyspace worker`` in their
own process groups (so a test can ``kill -9`` one), :func:`sim_files` writes a simulated scan and
markers with their truth.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def service_env(extra: Mapping[str, str]) -> dict[str, str]:
    """The current environment without ``BODYSPACE_*`` variables, plus ``extra``."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("BODYSPACE_")}
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    env.update(extra)
    return env


class Proc:
    """A subprocess in its own process group, with its output in a log file."""

    def __init__(self, args: list[str], env: Mapping[str, str], log: Path) -> None:
        self.log = log
        self._fh = open(log, "ab")  # noqa: SIM115 (closed in stop)
        self.p = subprocess.Popen(
            args, env=dict(env), cwd=ROOT, stdout=self._fh, stderr=subprocess.STDOUT,
            start_new_session=True,
        )  # fmt: skip

    @property
    def pid(self) -> int:
        return self.p.pid

    def alive(self) -> bool:
        return self.p.poll() is None

    def kill9(self) -> None:
        """SIGKILL the whole process group (the worker and its pool processes)."""
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.p.pid, signal.SIGKILL)
        self.p.wait(timeout=10)

    def stop(self, timeout: float = 10.0) -> None:
        if self.alive():
            try:
                os.killpg(self.p.pid, signal.SIGTERM)
                self.p.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.kill9()
            except ProcessLookupError:
                pass
        # leftover pool processes of the group
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(self.p.pid, signal.SIGKILL)
        self._fh.close()

    def output(self) -> str:
        return self.log.read_text(errors="replace")


def wait_ready(
    proc: Proc, url: str, *, path: str = "/healthz", timeout: float = 60.0, poll: float = 0.1
) -> None:
    """Wait until ``url + path`` answers 200; stop ``proc`` and raise RuntimeError (with its
    output) when it exits first or ``timeout`` seconds pass."""
    import httpx

    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if not proc.alive():
            raise RuntimeError(f"server exited:\n{proc.output()}")
        try:
            if httpx.get(url + path, timeout=2).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(poll)
    proc.stop()
    raise RuntimeError(f"server did not start in {timeout} s:\n{proc.output()}")


def start_server(env: Mapping[str, str], port: int, log: Path, timeout: float = 60.0) -> Proc:
    """``bodyspace serve`` on ``port``; waits until ``/healthz`` answers."""
    args = [sys.executable, "-m", "service.commands", "serve", "--port", str(port)]
    proc = Proc([*args, "--log-level", "warning"], env, log)
    wait_ready(proc, f"http://127.0.0.1:{port}", timeout=timeout)
    return proc


def start_worker(env: Mapping[str, str], log: Path, name: str, concurrency: int = 1) -> Proc:
    """``bodyspace worker`` (Celery, prefork pool)."""
    args = [sys.executable, "-m", "worker.cli", "worker", "--hostname", f"{name}@%h"]
    return Proc([*args, "--concurrency", str(concurrency)], env, log)


@dataclass
class SimFiles:
    scan: Path
    markers: Path
    truth: np.ndarray  # (13380, 3) metres, canonical frame (the frame fits are returned in)
    n_vertices: int


def sim_files(folder: Path, seed: int = 0, **config: Any) -> SimFiles:
    """A small simulated scan (binary PLY) + markers (CSV) of a random body, and its truth."""
    from core.io import detect_frame, write_markers_csv, write_ply
    from core.synth import ScanConfig, random_body, simulate_scan
    from core.template import load_template

    rng = np.random.default_rng(seed)
    tpl = load_template()
    body = random_body(rng, pose=False)
    sim = simulate_scan(
        body.V, tpl.F, rng, config=ScanConfig.small(**config), landmarks=tpl.landmarks
    )
    folder.mkdir(parents=True, exist_ok=True)
    scan, markers = folder / f"scan{seed}.ply", folder / f"markers{seed}.csv"
    write_ply(scan, sim.V_scan, sim.F_scan, normals=sim.normals, confidence=sim.confidence)
    write_markers_csv(markers, sim.markers)
    frame = detect_frame(sim.V_scan, markers=sim.markers)
    return SimFiles(scan, markers, frame.to_canonical(sim.V_truth), len(sim.V_scan))


def wait_state(
    client: Any, fit_id: str, states: tuple[str, ...] = ("succeeded", "failed"), timeout=120.0
) -> dict[str, Any]:
    """Poll ``GET /v1/fits/{id}`` until its state is one of ``states``."""
    t_end = time.monotonic() + timeout
    body: dict[str, Any] = {}
    while time.monotonic() < t_end:
        r = client.get(f"/v1/fits/{fit_id}")
        r.raise_for_status()
        body = r.json()
        if body["state"] in states:
            return body
        time.sleep(0.1)
    raise TimeoutError(f"fit {fit_id} still {body.get('state')} after {timeout} s: {body}")


def glb_vertices(data: bytes) -> np.ndarray:
    """POSITION of the first primitive of a GLB written by ``core.io.write_glb``."""
    import json
    import struct

    jlen = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20 : 20 + jlen])
    bin_off = 20 + jlen + 8
    acc = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
    view = doc["bufferViews"][acc["bufferView"]]
    start = bin_off + view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    return np.frombuffer(data, np.float32, acc["count"] * 3, start).reshape(-1, 3)


def glb_parts(data: bytes) -> tuple[dict[str, Any], Any]:
    """The JSON chunk of a GLB and ``accessor(i) -> ndarray`` reading accessor ``i`` (float32,
    uint8/16/32; VEC3/VEC4/MAT4/SCALAR), for tests of any GLB the project writes."""
    import json
    import struct

    jlen = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20 : 20 + jlen])
    bin_off = 20 + jlen + 8
    dtypes = {5126: np.float32, 5125: np.uint32, 5123: np.uint16, 5121: np.uint8}
    widths = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}

    def accessor(i: int) -> np.ndarray:
        acc = doc["accessors"][i]
        view = doc["bufferViews"][acc["bufferView"]]
        start = bin_off + view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        k = widths[acc["type"]]
        a = np.frombuffer(data, dtypes[acc["componentType"]], acc["count"] * k, start)
        return a.reshape(acc["count"], k) if k > 1 else a

    return doc, accessor


GLTF_DIR = ROOT / "tests" / "service" / "gltf"


def ensure_gltf_validator() -> Path:
    """Path of ``validate.js`` (Khronos glTF validator); runs ``npm ci`` there if needed."""
    if not (GLTF_DIR / "node_modules" / "gltf-validator").is_dir():
        subprocess.run(
            ["npm", "ci", "--no-audit", "--no-fund", "--prefix", str(GLTF_DIR)], check=True
        )
    return GLTF_DIR / "validate.js"


def validate_glb(path: Path) -> dict[str, Any]:
    """The validator's summary of one file: ``errors``, ``warnings``, ``messages``."""
    import json

    validator = ensure_gltf_validator()
    out = subprocess.run(["node", str(validator), str(path)], capture_output=True, text=True)
    if out.returncode not in (0, 1):
        raise RuntimeError(f"gltf validator failed: {out.stderr}")
    return json.loads(out.stdout.splitlines()[0])


def upload_scan(client: Any, sim: SimFiles, **fields: str) -> Any:
    """``POST /v1/scans`` with the simulated scan and markers."""
    files = {
        "scan": ("scan.ply", sim.scan.read_bytes(), "application/octet-stream"),
        "markers": ("markers.csv", sim.markers.read_bytes(), "text/csv"),
    }
    return client.post("/v1/scans", files=files, data=fields)
