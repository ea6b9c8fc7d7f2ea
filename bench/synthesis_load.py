"""Load test of ``POST /v1/models/{model}/synthesize`` on loopback (issue 5's performance target).

    .venv/bin/python -m bench.synthesis_load                     # embedded, 1 API process
    .venv/bin/python -m bench.synthesis_load --runs 3 --duration 20
    .venv/bin/python -m bench.synthesis_load --api-processes 2   # embedded, serve --workers 2
    .venv/bin/python -m bench.synthesis_load --api-processes 2 --mode distributed  # PG + Redis
    .venv/bin/python -m bench.synthesis_load --client python     # force the Python fallback

Starts a real ``bodyspace serve --workers N`` (``--api-processes``, default 1) in embedded mode
(temp data folder: SQLite, blob folder, the fit runner in one of the processes; key from
``BODYSPACE_API_KEY``) or, with ``--mode distributed``, against the local PostgreSQL (a throwaway
database) and Redis (no fit worker), warms it, then
drives ``--connections`` (32) concurrent keep-alive connections for ``--duration`` seconds with
varied requests: a pool of ``--pool`` (4096) distinct bodies drawn within the model's ranges
(sex 50/50, stature uniform over the central 90 % of the sex's range, BMI ~ N(25.5/27, 4)
clipped to 18–40, age on 30 % of them, a seed on 15 %), each checked against the model first so
that none is out of range. Nothing is cached server-side, so every request synthesises a body.

Two phases per run:

- **saturation** (closed loop): every connection sends its next request as soon as the previous
  answer arrived. Gives the throughput (req/s). By Little's law its mean latency is
  connections / throughput (32 / 300 req/s = 107 ms), so it is *not* the latency at a given load.
- **paced** (``--rate``, default 300 req/s): the same 32 connections, but requests leave on a
  fixed schedule of ``rate`` per second (each wrk thread hands out send slots
  ``1 / (rate / threads)`` apart; a connection waits for its slot). Gives the latency at that
  offered load. If the server falls behind, slots are not made up for and the achieved rate
  drops below the offered one: the output says so.

Load generator: ``wrk`` with a generated Lua script (install: ``apt-get install -y wrk`` on
Debian/Ubuntu, ``brew install wrk`` on macOS); it takes ~10 % of one core here. Without ``wrk`` a
Python asyncio + httpx client runs instead, clearly labelled: it shares the same cores with the
server and costs ~1 ms of CPU per request, so its numbers are pessimistic.

Prints the git HEAD, CPU count, load average before/after each phase, the GLB size, a
one-client sequential baseline, then per phase p50/p90/p99/max latency, req/s, errors, MB/s and
the server's CPU time per request, and finally the targets (p50 ≤ 15 ms, p99 ≤ 50 ms at 32
clients, ≥ 300 req/s) against the median of the runs.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import resource
import secrets
import shutil
import statistics
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np

from service.testing import ROOT, Proc, free_port, service_env, wait_ready

KEY = "bench-synthesis-key-" + "0" * 16
PATH = "/v1/models/default/synthesize"
GLB = "model/gltf-binary"
PG_ADMIN = os.environ.get(
    "BODYSPACE_TEST_POSTGRES_URL", "postgresql://postgres@127.0.0.1:5432/postgres"
)
REDIS_URL = os.environ.get("BODYSPACE_TEST_REDIS_URL", "redis://127.0.0.1:6379/15")
TARGET = {"p50_ms": 15.0, "p99_ms": 50.0, "rps": 300.0}


# ---------------------------------------------------------------- request pool


def body_pool(n: int, seed: int = 0) -> tuple[list[dict], dict[str, int]]:
    """``n`` distinct, valid synthesis requests drawn within the default model's training
    ranges (no extrapolation)."""
    from core.shapespace import default_model
    from core.shapespace.errors import OutOfRangeError

    m = default_model()
    rng = np.random.default_rng(seed)
    ranges = {
        s: {k: v["training_range"] for k, v in m.describe()["spaces"][s]["features"].items()}
        for s in ("female", "male")
    }
    out: list[dict] = []
    kinds = {"height+weight": 0, "+age": 0, "+seed": 0, "rejected draws": 0}
    while len(out) < n:
        sex = "female" if rng.random() < 0.5 else "male"
        r = ranges[sex]
        lo, hi = r["height_m"]
        h = lo + (hi - lo) * (0.05 + 0.9 * rng.random())
        bmi = float(np.clip(rng.normal(25.5 if sex == "female" else 27.0, 4.0), 18.0, 40.0))
        w = float(np.clip(bmi * h * h, *r["weight_kg"]))
        body: dict = {"sex": sex, "height_m": round(h, 4), "weight_kg": round(w, 2)}
        if rng.random() < 0.3:
            body["age"] = round(float(rng.uniform(max(18.0, r["age"][0]), r["age"][1])), 1)
        if rng.random() < 0.15:
            body["seed"] = int(rng.integers(0, 2**31))
        feats = {k: v for k, v in body.items() if k not in ("sex", "seed")}
        try:
            m.synthesize(sex, feats, seed=body.get("seed"))
        except OutOfRangeError:
            kinds["rejected draws"] += 1
            continue
        if m.range_warnings(sex, feats):  # extrapolated: not the common request
            kinds["rejected draws"] += 1
            continue
        out.append(body)
        kinds["+seed" if "seed" in body else "+age" if "age" in body else "height+weight"] += 1
    return out, kinds


# ---------------------------------------------------------------- server


@dataclass
class Server:
    url: str
    procs: list[Proc]
    label: str
    cleanup: list = field(default_factory=list)

    def pids(self) -> list[int]:
        """Every process of the servers' process groups (uvicorn, its workers, the pool)."""
        groups = {p.pid for p in self.procs}
        pids = []
        for d in Path("/proc").iterdir():
            if d.name.isdigit():
                try:
                    st = (d / "stat").read_text()
                except OSError:
                    continue
                fields = st.rsplit(")", 1)[1].split()
                if int(fields[2]) in groups:  # pgrp
                    pids.append(int(d.name))
        return pids

    def cpu_s(self) -> float:
        """User + system CPU seconds of all server processes so far."""
        tick = os.sysconf("SC_CLK_TCK")
        total = 0.0
        for pid in self.pids():
            try:
                fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            total += (int(fields[11]) + int(fields[12])) / tick
        return total

    def stop(self) -> None:
        for p in self.procs:
            p.stop()
        for fn in self.cleanup:
            fn()


def start(tmp: Path, api_processes: int, mode: str = "embedded") -> Server:
    """``bodyspace serve --workers N`` in ``mode`` (``embedded`` or ``distributed``)."""
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    env = {"BODYSPACE_DATA_DIR": str(tmp / "data"), "BODYSPACE_API_KEY": KEY}
    args = ["-m", "service.commands", "serve", "--port", str(port), "--log-level", "warning"]
    cleanup = []
    if api_processes > 1:
        args += ["--workers", str(api_processes)]
    procs = f"{api_processes} API process{'es' if api_processes > 1 else ''}"
    if mode == "distributed":
        import psycopg

        name = f"bodyspace_bench_{secrets.token_hex(4)}"
        admin = psycopg.connect(PG_ADMIN, autocommit=True)
        admin.execute(f'CREATE DATABASE "{name}"')

        def drop() -> None:
            admin.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')
            admin.close()

        cleanup.append(drop)
        env |= {
            "BODYSPACE_DATABASE_URL": PG_ADMIN.rsplit("/", 1)[0] + "/" + name,
            "BODYSPACE_BROKER_URL": REDIS_URL,
            "BODYSPACE_QUEUE_NAME": f"bench-{secrets.token_hex(4)}",
        }
        label = f"distributed, {procs} (PostgreSQL + Redis, no fit worker)"
    else:
        label = f"embedded, {procs} (SQLite, fit runner in one)"
    import sys

    proc = Proc([sys.executable, *args], service_env(env), tmp / "server.log")
    try:
        wait_ready(proc, url, path="/readyz", timeout=90, poll=0.2)
    except BaseException:
        for fn in cleanup:
            fn()
        raise
    return Server(url, [proc], label, cleanup)


# ---------------------------------------------------------------- load generators


@dataclass
class Result:
    phase: str
    generator: str
    duration_s: float
    requests: int
    errors: int
    error_detail: str
    bytes: int
    p50: float
    p90: float
    p99: float
    max: float
    mean: float
    offered_rps: float | None
    server_cpu_s: float = 0.0
    client_cpu_s: float = 0.0
    load_before: tuple[float, float, float] = (0.0, 0.0, 0.0)
    load_after: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def rps(self) -> float:
        return self.requests / self.duration_s


LUA = r"""
-- generated by bench/synthesis_load.py
local bodies = { BODIES }
local headers = { HEADERS }
local path = "PATH"
local interval_ms = INTERVAL_MS   -- per thread; 0 = closed loop
local threads = {}
local counter = 0
local i = 0
local next_slot = 0

function setup(thread)
  counter = counter + 1
  thread:set("tid", counter)
  table.insert(threads, thread)
end

function init(args)
  math.randomseed(1000 + tid)
  i = math.random(#bodies)
end

function request()
  i = i % #bodies + 1
  return wrk.format("POST", path, headers, bodies[i])
end
DELAY
function done(summary, latency, requests)
  local e = summary.errors
  io.write(string.format(
    "BENCH_RESULT {\"duration_us\":%d,\"requests\":%d,\"bytes\":%d,\"connect\":%d,\"read\":%d," ..
    "\"write\":%d,\"status\":%d,\"timeout\":%d,\"p50\":%d,\"p90\":%d,\"p99\":%d,\"max\":%d," ..
    "\"mean\":%f}\n",
    summary.duration, summary.requests, summary.bytes, e.connect, e.read, e.write, e.status,
    e.timeout, latency:percentile(50), latency:percentile(90), latency:percentile(99),
    latency.max, latency.mean))
end
"""

LUA_DELAY = r"""
local ffi = require("ffi")
ffi.cdef[[
typedef struct { long tv_sec; long tv_nsec; } bench_timespec;
int clock_gettime(int clk_id, bench_timespec *tp);
]]
local ts = ffi.new("bench_timespec")
local function now_ms()
  ffi.C.clock_gettime(1, ts)  -- CLOCK_MONOTONIC
  return tonumber(ts.tv_sec) * 1000 + tonumber(ts.tv_nsec) / 1e6
end

function delay()
  local t = now_ms()
  if next_slot < t then next_slot = t end  -- behind schedule: send now, do not catch up
  local wait = next_slot - t
  next_slot = next_slot + interval_ms
  return math.floor(wait + 0.5)
end
"""


def _lua_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def lua_script(bodies: list[dict], accept: str, rate: float | None, threads: int) -> str:
    headers = {
        "Authorization": f"Bearer {KEY}",
        "Content-Type": "application/json",
        "Accept": accept,
    }
    interval = 0.0 if not rate else 1000.0 * threads / rate
    return (
        LUA.replace("BODIES", ",\n".join(_lua_str(json.dumps(b)) for b in bodies))
        .replace(
            "HEADERS", ", ".join(f"[{_lua_str(k)}] = {_lua_str(v)}" for k, v in headers.items())
        )
        .replace("PATH", PATH)
        .replace("INTERVAL_MS", repr(interval))
        .replace("DELAY", LUA_DELAY if rate else "")
    )


def run_wrk(
    url: str, script: Path, connections: int, threads: int, duration: float, phase: str,
    rate: float | None,
) -> Result:  # fmt: skip
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    cmd = [
        "wrk", "-t", str(threads), "-c", str(connections), "-d", f"{duration:g}s",
        "--timeout", "10s", "-s", str(script), url + PATH,
    ]  # fmt: skip
    out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    line = next(x for x in out.splitlines() if x.startswith("BENCH_RESULT "))
    d = json.loads(line.split(" ", 1)[1])
    errs = {k: d[k] for k in ("connect", "read", "write", "status", "timeout") if d[k]}
    return Result(
        phase=phase, generator=f"wrk -t{threads} -c{connections}",
        duration_s=d["duration_us"] / 1e6, requests=d["requests"], errors=sum(errs.values()),
        error_detail=", ".join(f"{k} {v}" for k, v in errs.items()) or "-", bytes=d["bytes"],
        p50=d["p50"] / 1e3, p90=d["p90"] / 1e3, p99=d["p99"] / 1e3, max=d["max"] / 1e3,
        mean=d["mean"] / 1e3, offered_rps=rate,
        client_cpu_s=(after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
    )  # fmt: skip


async def _python_load(
    url: str, bodies: list[dict], accept: str, connections: int, duration: float,
    rate: float | None,
) -> tuple[list[float], int, int, float, dict[str, int]]:  # fmt: skip
    headers = {"Authorization": f"Bearer {KEY}", "Accept": accept}
    lat: list[float] = []
    errors: dict[str, int] = {}
    nbytes = 0
    state = {"i": 0, "slot": time.perf_counter()}
    interval = 0.0 if not rate else 1.0 / rate
    limits = httpx.Limits(max_connections=connections, max_keepalive_connections=connections)
    async with httpx.AsyncClient(base_url=url, headers=headers, limits=limits, timeout=10) as c:
        t0 = time.perf_counter()
        t_end = t0 + duration

        async def one() -> None:
            nonlocal nbytes
            while True:
                if interval:
                    now = time.perf_counter()
                    state["slot"] = max(state["slot"], now)
                    wait = state["slot"] - now
                    state["slot"] += interval
                    if wait > 0:
                        await asyncio.sleep(wait)
                if time.perf_counter() >= t_end:
                    return
                body = bodies[state["i"] % len(bodies)]
                state["i"] += 1
                t = time.perf_counter()
                try:
                    r = await c.post(PATH, json=body)
                    lat.append(time.perf_counter() - t)
                    nbytes += len(r.content)
                    if r.status_code >= 400:
                        errors["status"] = errors.get("status", 0) + 1
                except httpx.HTTPError as e:
                    errors[type(e).__name__] = errors.get(type(e).__name__, 0) + 1

        await asyncio.gather(*(one() for _ in range(connections)))
        elapsed = time.perf_counter() - t0
    return lat, nbytes, sum(errors.values()), elapsed, errors


def run_python(
    url: str, bodies: list[dict], accept: str, connections: int, duration: float, phase: str,
    rate: float | None,
) -> Result:  # fmt: skip
    r0 = resource.getrusage(resource.RUSAGE_SELF)
    lat, nbytes, nerr, elapsed, errors = asyncio.run(
        _python_load(url, bodies, accept, connections, duration, rate)
    )
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    a = np.asarray(lat) * 1e3 if lat else np.array([float("nan")])
    return Result(
        phase=phase, generator=f"PYTHON FALLBACK (asyncio+httpx, {connections} conns)",
        duration_s=elapsed, requests=len(lat), errors=nerr,
        error_detail=", ".join(f"{k} {v}" for k, v in errors.items()) or "-", bytes=nbytes,
        p50=float(np.percentile(a, 50)), p90=float(np.percentile(a, 90)),
        p99=float(np.percentile(a, 99)), max=float(a.max()), mean=float(a.mean()),
        offered_rps=rate,
        client_cpu_s=(r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime),
    )  # fmt: skip


# ---------------------------------------------------------------- main


def _git_head() -> str:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
        )
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
            capture_output=True, text=True,
        ).stdout.strip()  # fmt: skip
        return out.stdout.strip() + (" (+ uncommitted changes)" if dirty else "")
    except OSError:
        return "?"


def _load() -> tuple[float, float, float]:
    return os.getloadavg()


def _fmt_load(t: tuple[float, float, float]) -> str:
    return " ".join(f"{x:.2f}" for x in t)


def single_client(url: str, bodies: list[dict], accept: str, n: int) -> tuple[float, float, int]:
    """Sequential requests on one keep-alive connection: p50, p99 (ms), response size."""
    headers = {"Authorization": f"Bearer {KEY}", "Accept": accept}
    lat, size = [], 0
    with httpx.Client(base_url=url, headers=headers, timeout=30) as c:
        for b in bodies[:n]:
            t = time.perf_counter()
            r = c.post(PATH, json=b)
            lat.append(time.perf_counter() - t)
            if r.status_code != 200:
                raise RuntimeError(f"warm-up request {b} -> {r.status_code} {r.text[:300]}")
            size = len(r.content)
    a = np.asarray(lat) * 1e3
    return float(np.percentile(a, 50)), float(np.percentile(a, 99)), size


def _row(r: Result) -> str:
    offered = f"{r.offered_rps:g}" if r.offered_rps else "max"
    return (
        f"{r.phase:<11} {offered:>7} {r.rps:8.1f} {r.p50:7.2f} {r.p90:7.2f} {r.p99:7.2f} "
        f"{r.max:8.2f} {r.requests:8d} {r.errors:6d} {r.bytes / r.duration_s / 1e6:7.1f} "
        f"{1e3 * r.server_cpu_s / max(r.requests, 1):7.2f} "
        f"{100 * r.client_cpu_s / r.duration_s:6.0f}%"
        f"   {_fmt_load(r.load_before)} -> {_fmt_load(r.load_after)}"
    )


HEADER = (
    f"{'phase':<11} {'offered':>7} {'req/s':>8} {'p50 ms':>7} {'p90 ms':>7} {'p99 ms':>7} "
    f"{'max ms':>8} {'requests':>8} {'errors':>6} {'MB/s':>7} {'srv CPU':>7} {'client':>7}"
    "   load avg before -> after"
)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--connections", type=int, default=32)
    ap.add_argument("--duration", type=float, default=15.0, help="seconds per phase")
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--rate", type=float, default=TARGET["rps"], help="paced phase req/s (0: skip)")
    ap.add_argument("--threads", type=int, default=1, help="wrk threads")
    ap.add_argument("--api-processes", type=int, default=1, help="bodyspace serve --workers N")
    ap.add_argument("--mode", choices=("embedded", "distributed"), default="embedded")
    ap.add_argument("--accept", choices=("glb", "json"), default="glb")
    ap.add_argument("--client", choices=("auto", "wrk", "python"), default="auto")
    ap.add_argument("--pool", type=int, default=4096, help="distinct request bodies")
    ap.add_argument("--skip-saturation", action="store_true")
    args = ap.parse_args(argv)

    accept = GLB if args.accept == "glb" else "application/json"
    wrk = shutil.which("wrk")
    if args.client == "wrk" and not wrk:
        raise SystemExit("wrk not found: apt-get install -y wrk (Debian/Ubuntu), brew install wrk")
    use_wrk = bool(wrk) and args.client != "python"
    if use_wrk:
        ver = subprocess.run(["wrk", "-v"], capture_output=True, text=True).stdout.split("\n")[0]
        generator = f"wrk ({ver.strip()}), {args.threads} thread(s), Lua script"
    else:
        generator = (
            "PYTHON FALLBACK: asyncio + httpx in the bench process (wrk not found or --client "
            "python; install wrk: apt-get install -y wrk). It competes with the server for the "
            "same cores: latencies and req/s are pessimistic."
        )

    print("bench.synthesis_load — POST /v1/models/default/synthesize on loopback")
    print(f"git HEAD {_git_head()}; {time.strftime('%Y-%m-%d %H:%M:%S %Z')}")
    print(f"CPUs: {os.cpu_count()}; load average (1/5/15 min) at start: {_fmt_load(_load())}")
    print(f"load generator: {generator}")
    t = time.perf_counter()
    bodies, kinds = body_pool(args.pool)
    mix = ", ".join(f"{k} {v}" for k, v in kinds.items())
    print(
        f"request pool: {len(bodies)} distinct bodies ({mix}), "
        f"built in {time.perf_counter() - t:.1f} s; Accept: {accept}"
    )

    with tempfile.TemporaryDirectory(prefix="bodyspace-synth-load-") as d:
        tmp = Path(d)
        srv = start(tmp, args.api_processes, args.mode)
        try:
            print(f"server: bodyspace serve, {srv.label}, {srv.url}")
            # warm-up: every process loads the model, encoder, key cache (2 s of load)
            p50, p99, size = single_client(srv.url, bodies, accept, 50)
            if use_wrk:
                warm = tmp / "warm.lua"
                warm.write_text(lua_script(bodies, accept, None, args.threads))
                run_wrk(srv.url, warm, args.connections, args.threads, 2, "warm-up", None)
            else:
                run_python(srv.url, bodies, accept, args.connections, 2, "warm-up", None)
            p50, p99, size = single_client(srv.url, bodies[100:], accept, 300)
            kind = "GLB" if accept == GLB else "JSON"
            print(f"{kind} size: {size:,} bytes ({size / 1e3:.0f} kB)")
            print(
                f"one client, sequential (300 requests, keep-alive, httpx): p50 {p50:.2f} ms, "
                f"p99 {p99:.2f} ms"
            )
            print(
                f"\n{args.connections} connections, {args.duration:g} s per phase; latency is "
                "send -> last byte; 'srv CPU' = server CPU ms per request (all server processes);"
                " 'client' = load generator CPU (% of one core)"
            )
            print(HEADER)
            results: list[Result] = []
            phases = [] if args.skip_saturation else [("saturation", None)]
            if args.rate:
                phases.append(("paced", args.rate))
            for run in range(args.runs):
                for phase, rate in phases:
                    time.sleep(3)  # let the previous phase's sockets and CPU settle
                    lb = _load()
                    c0 = srv.cpu_s()
                    if use_wrk:
                        script = tmp / f"{phase}.lua"
                        script.write_text(lua_script(bodies, accept, rate, args.threads))
                        r = run_wrk(
                            srv.url, script, args.connections, args.threads, args.duration,
                            phase, rate,
                        )  # fmt: skip
                    else:
                        r = run_python(
                            srv.url, bodies, accept, args.connections, args.duration, phase, rate
                        )
                    r.server_cpu_s = srv.cpu_s() - c0
                    r.load_before, r.load_after = lb, _load()
                    results.append(r)
                    print(_row(r) + f"   [run {run + 1}]", flush=True)
                    if r.errors:
                        print(f"    errors: {r.error_detail}")
        finally:
            srv.stop()

    print()
    sat = [r for r in results if r.phase == "saturation"]
    paced = [r for r in results if r.phase == "paced"]
    ok = True
    if sat:
        rps = statistics.median(r.rps for r in sat)
        good = rps >= TARGET["rps"]
        ok &= good
        print(
            f"throughput (saturation, median of {len(sat)}): {rps:.0f} req/s "
            f"-> target >= {TARGET['rps']:g} req/s: {'MET' if good else 'NOT MET'}"
        )
        lat = statistics.median(r.p50 for r in sat)
        print(
            f"  (closed loop: p50 {lat:.1f} ms ~ {args.connections} / {rps:.0f} req/s by Little's "
            f"law; a 15 ms p50 with {args.connections} back-to-back clients would need "
            f">= {args.connections / 0.015:.0f} req/s)"
        )
    if paced:
        p50 = statistics.median(r.p50 for r in paced)
        p99 = statistics.median(r.p99 for r in paced)
        rps = statistics.median(r.rps for r in paced)
        behind = rps < 0.97 * args.rate
        good = p50 <= TARGET["p50_ms"] and p99 <= TARGET["p99_ms"] and not behind
        ok &= good
        print(
            f"latency at {args.rate:g} req/s offered over {args.connections} connections (median "
            f"of {len(paced)}): p50 {p50:.1f} ms, p99 {p99:.1f} ms, achieved {rps:.0f} req/s "
            f"-> target p50 <= {TARGET['p50_ms']:g} ms, p99 <= {TARGET['p99_ms']:g} ms: "
            f"{'MET' if good else 'NOT MET'}"
            + (" (server fell behind the schedule)" if behind else "")
        )
    errors = sum(r.errors for r in results)
    print(f"errors: {errors} in {sum(r.requests for r in results)} requests")
    print(f"load average at end: {_fmt_load(_load())}; CPUs: {os.cpu_count()}")
    print("targets " + ("MET" if ok and not errors else "NOT MET"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
