"""The job-runner interface and its two implementations.

- :class:`EmbeddedRunner` (no broker configured): a local process pool in the API process.
- :class:`CeleryRunner` (``BODYSPACE_BROKER_URL`` set): publishes to Celery over Redis; fits run in
  ``bodyspace worker`` processes, never in the API process.

Both take fit ids only; the job itself is :func:`service.fit_job.run_fit`.
"""

from __future__ import annotations

import fcntl
import logging
import multiprocessing
import os
import threading
import time
import uuid
from collections import deque
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Protocol

from sqlalchemy import select

from core.threads import share_cpus
from service.settings import Settings

log = logging.getLogger("bodyspace.service")

#: In ``DATA_DIR``: held (``flock``) by the one API process that runs the embedded fits.
RUNNER_LOCK = "runner.lock"
#: Seconds between the leader's looks for fits accepted by other API processes.
POLL_INTERVAL_S = 0.5
#: Seconds between the other processes' attempts to take the runner lock over.
TAKEOVER_INTERVAL_S = 1.0


class JobRunner(Protocol):
    """Runs fit jobs by id."""

    def start(self) -> None:
        """Start; recover unfinished jobs where this runner owns them."""

    def submit(self, fit_id: str) -> None:
        """Enqueue a fit whose row is already committed."""

    def check(self) -> str | None:
        """Raise if jobs cannot be accepted now; a message if they are accepted but would not
        run soon (readiness says ``degraded``), else None."""

    def shutdown(self) -> None:
        """Stop accepting jobs."""


def _pool_init(parent_pid: int) -> None:
    from service.fit_job import warm_up
    from service.runtime import die_with_parent

    # A pool process dies with its API process (SIGKILL, OOM killer): no orphan keeps running
    # (or storing) a fit that the next runner re-runs (issue 15).
    die_with_parent(parent_pid)
    warm_up()


def _tenant_of(fit_id: str, settings: Settings) -> str | None:
    """The tenant of fit ``fit_id`` (None if it is gone)."""
    from service.db import session_scope
    from service.models import Fit

    with session_scope(settings) as s:
        return s.scalar(select(Fit.tenant_id).where(Fit.id == fit_id))


def _run(fit_id: str, task_id: str) -> str:
    from service.fit_job import run_fit

    return run_fit(fit_id, task_id)


class EmbeddedRunner:
    """A local pool of spawned processes; a crashed pool is rebuilt and its jobs resubmitted.

    Several API processes may share one data folder (``bodyspace serve --workers N``): exactly
    one of them -- the one holding an exclusive ``flock`` on ``DATA_DIR/runner.lock`` -- runs
    the pool (the *leader*); the others only serve. A fit accepted by any process is a committed
    ``queued`` row first: the leader hands it to its pool directly (its own requests) or within
    :data:`POLL_INTERVAL_S` (the others'). The kernel drops the lock when its process dies,
    however it dies; another process takes it over within :data:`TAKEOVER_INTERVAL_S` and
    re-runs every unfinished job (nothing else can be running them: the lock says so).
    """

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self._lock = threading.Lock()
        self._pool: ProcessPoolExecutor | None = None
        self._pending: dict[str, Future] = {}  # in the pool (at most settings.workers)
        # Fair dispatch: fits wait here per tenant; a free pool slot goes to the tenant with the
        # fewest fits in the pool, ties to the one served longest ago (one tenant's burst
        # delays another's fit by at most the fits already in the pool).
        self._waiting: dict[str, deque[str]] = {}
        self._waiting_ids: set[str] = set()
        self._tenant_of: dict[str, str] = {}  # fit id -> tenant, for fits in the pool
        self._in_pool: dict[str, int] = {}  # tenant -> fits in the pool
        self._served: dict[str, int] = {}  # tenant -> serial of its last dispatch
        self._serial = 0
        self._polled: set[str] = set()
        self._generation = 0
        self._stop = threading.Event()
        self._lock_fd: int | None = None
        self._started = False
        # Every pool.submit (which starts pool processes on demand) runs in this one thread,
        # alive as long as the runner: the parent-death signal of a pool process fires when
        # the thread that started it exits (a request thread would kill it when idle).
        self._spawner = ThreadPoolExecutor(1, thread_name_prefix="pool-spawner")

    @property
    def is_leader(self) -> bool:
        """True in the process that runs fits (holds the runner lock)."""
        return self._lock_fd is not None

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(
            max_workers=max(1, self.settings.workers),
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_pool_init,
            initargs=(os.getpid(),),
        )

    def _try_lead(self) -> bool:
        """Take the runner lock if no other live process holds it."""
        path = self.settings.data_dir / RUNNER_LOCK
        path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return False
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._lock_fd = fd
        return True

    def start(self) -> None:
        share_cpus(self.settings.workers)  # each pool process's fit threads (inherited)
        self._started = True
        if self._try_lead():
            self._lead()
        else:
            log.info("fits run in another API process of this data folder (runner lock held)")
        threading.Thread(target=self._loop, daemon=True, name="embedded-runner").start()

    def _lead(self) -> None:
        from service.fit_job import recover

        with self._lock:
            self._pool = self._new_pool()
        log.info("this API process runs the fits of %s", self.settings.data_dir)
        # Only the lock holder runs this database's jobs: everything unfinished is ours to run.
        recover(self.submit, self.settings, on_start=True, requeue_running=True)

    def _loop(self) -> None:
        """Leader: pick up fits accepted by other processes, and sweep now and then. Others:
        take over when the leader's process is gone."""
        from service.fit_job import recover

        next_sweep = time.monotonic() + self.settings.sweep_interval_s
        while not self._stop.is_set():
            if not self.is_leader:
                if self._stop.wait(TAKEOVER_INTERVAL_S):
                    return
                try:
                    if self._try_lead():
                        self._lead()
                        next_sweep = time.monotonic() + self.settings.sweep_interval_s
                except Exception as e:  # keep trying
                    log.warning("taking over the fit runner failed: %s", e)
                continue
            if self._stop.wait(POLL_INTERVAL_S):
                return
            try:
                self._poll_queued()
                if time.monotonic() >= next_sweep:
                    next_sweep = time.monotonic() + self.settings.sweep_interval_s
                    recover(self.submit, self.settings)  # re-run jobs whose process died
            except Exception as e:  # keep polling
                log.warning("job poll failed: %s", e)

    def _poll_queued(self) -> None:
        """Submit queued fits not yet handed to the pool (accepted by another API process).
        Each is submitted once by the poll; retries are the sweep's (``recover``)."""
        from service.db import session_scope
        from service.models import Fit

        with session_scope(self.settings) as s:
            queued = set(s.scalars(select(Fit.id).where(Fit.state == "queued")))
        with self._lock:
            new = queued - self._polled - set(self._pending) - self._waiting_ids
            self._polled = (self._polled & queued) | new
        for fit_id in sorted(new):
            self.submit(fit_id)

    def submit(self, fit_id: str) -> None:
        with self._lock:
            if not self.is_leader:
                if not self._started:
                    raise RuntimeError("the embedded job runner is not started")
                return  # the row is committed as queued: the leader's poll picks it up
            if self._pool is None:
                raise RuntimeError("the embedded job runner is not started")
            if fit_id in self._pending or fit_id in self._waiting_ids:
                return  # already in the pool or waiting for it
        tenant = _tenant_of(fit_id, self.settings)
        if tenant is None:
            return  # deleted meanwhile
        with self._lock:
            if fit_id in self._pending or fit_id in self._waiting_ids:
                return
            self._waiting.setdefault(tenant, deque()).append(fit_id)
            self._waiting_ids.add(fit_id)
        self._dispatch()

    def _dispatch(self) -> None:
        """Fill the free pool slots, fairly across tenants."""
        started: list[tuple[str, Future, int]] = []
        with self._lock:
            slots = max(1, self.settings.workers)
            while self._pool is not None and self._waiting and len(self._pending) < slots:
                tenant = min(
                    self._waiting,
                    key=lambda t: (self._in_pool.get(t, 0), self._served.get(t, -1)),
                )
                queue = self._waiting[tenant]
                fit_id = queue.popleft()
                if not queue:
                    del self._waiting[tenant]
                self._waiting_ids.discard(fit_id)
                self._serial += 1
                self._served[tenant] = self._serial
                self._in_pool[tenant] = self._in_pool.get(tenant, 0) + 1
                self._tenant_of[fit_id] = tenant
                task_id = f"emb.{uuid.uuid4().hex[:12]}"
                fut = self._spawner.submit(self._pool.submit, _run, fit_id, task_id).result()
                self._pending[fit_id] = fut
                started.append((fit_id, fut, self._generation))
        for fit_id, fut, gen in started:  # outside the lock: a done future calls back at once
            fut.add_done_callback(lambda f, i=fit_id, g=gen: self._done(i, f, g))

    def _done(self, fit_id: str, fut: Future, generation: int) -> None:
        exc = fut.exception() if not fut.cancelled() else None
        with self._lock:
            if self._pending.get(fit_id) is fut:
                del self._pending[fit_id]
                tenant = self._tenant_of.pop(fit_id, None)
                if tenant is not None:
                    self._in_pool[tenant] -= 1
                    if not self._in_pool[tenant]:
                        del self._in_pool[tenant]
            rebuild = isinstance(exc, BrokenProcessPool) and generation == self._generation
            if rebuild:
                self._generation += 1
        if rebuild:
            log.error("the process pool broke while running %s: rebuilding it", fit_id)
            self._rebuild()
            return
        if exc is not None:  # transient fault: the job stays in the DB for a later recovery
            log.error("fit %s: %s", fit_id, exc)
        self._dispatch()

    def _rebuild(self) -> None:
        from service.fit_job import recover

        with self._lock:
            if self._pool is not None:
                self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = self._new_pool()
            self._forget()
        recover(self.submit, self.settings, on_start=True, requeue_running=True)

    def _forget(self) -> None:
        """Drop the dispatch state (caller holds the lock; recovery resubmits from the DB)."""
        self._pending.clear()
        self._waiting.clear()
        self._waiting_ids.clear()
        self._tenant_of.clear()
        self._in_pool.clear()

    def check(self) -> str | None:
        if not self._started or (self.is_leader and self._pool is None):
            raise RuntimeError("the embedded job runner is not started")
        return None

    def shutdown(self) -> None:
        self._stop.set()
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            procs = list((getattr(pool, "_processes", None) or {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            for p in procs:  # a running fit is recovered on the next start
                p.terminate()
            for p in procs:  # gone before the lock is released: no two runs of one job
                p.join(timeout=10)
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None
        self._spawner.shutdown(wait=False)


def worker_beat_prefix(settings: Settings) -> str:
    """Redis key prefix of the beats of the workers consuming ``settings.queue_name``."""
    return f"bodyspace:workers:{settings.queue_name}:"


class CeleryRunner:
    """Publishes jobs to Celery over Redis (the broker named by ``BODYSPACE_BROKER_URL``).

    Readiness (:meth:`check`): the broker answers and the last enqueue did not fail (within
    :data:`ENQUEUE_FAILURE_S`), else not ready; no worker beat under
    :func:`worker_beat_prefix` (each ``bodyspace worker`` refreshes its key every
    ``worker_beat_interval_s``, expiring after ``worker_beat_ttl_s``) -> degraded.
    """

    #: Seconds a failed enqueue keeps readiness failing (unless an enqueue succeeds since).
    ENQUEUE_FAILURE_S = 10.0

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self._failed: tuple[float, str] | None = None

    def start(self) -> None:
        """Workers recover jobs on their start and periodically; the API only publishes."""

    def submit(self, fit_id: str) -> None:
        from service.celery_app import submit

        try:
            submit(fit_id)
        except Exception as e:
            self._failed = (time.monotonic(), f"{type(e).__name__}: {e}"[:200])
            raise
        self._failed = None

    def check(self) -> str | None:
        import redis

        client = redis.Redis.from_url(
            self.settings.broker_url, socket_connect_timeout=2, socket_timeout=2
        )
        try:
            client.ping()
            failed = self._failed
            if failed is not None and time.monotonic() - failed[0] < self.ENQUEUE_FAILURE_S:
                raise RuntimeError(f"enqueueing a job failed: {failed[1]}")
            n = sum(1 for _ in client.scan_iter(match=worker_beat_prefix(self.settings) + "*"))
        finally:
            client.close()
        if n == 0:
            return f"no worker consumes the queue {self.settings.queue_name!r}: fits wait"
        return None

    def shutdown(self) -> None:
        pass


def make_runner(settings: Settings) -> JobRunner:
    """The runner for the configured mode."""
    return CeleryRunner(settings) if settings.distributed else EmbeddedRunner(settings)
