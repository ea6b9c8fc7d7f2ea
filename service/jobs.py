"""The job-runner interface and its two implementations.

- :class:`EmbeddedRunner` (no broker configured): a local process pool in the API process.
- :class:`CeleryRunner` (``BODYSPACE_BROKER_URL`` set): publishes to Celery over Redis; fits run in
  ``bodyspace worker`` processes, never in the API process.

Both take fit ids only; the job itself is :func:`worker.jobs.run_fit`.
"""

from __future__ import annotations

import logging
import multiprocessing
import threading
import uuid
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Protocol

from service.settings import Settings

log = logging.getLogger("bodyspace.service")


class JobRunner(Protocol):
    """Runs fit jobs by id."""

    def start(self) -> None:
        """Start; recover unfinished jobs where this runner owns them."""

    def submit(self, fit_id: str) -> None:
        """Enqueue a fit whose row is already committed."""

    def check(self) -> None:
        """Raise if jobs cannot be run now (readiness)."""

    def shutdown(self) -> None:
        """Stop accepting jobs."""


def _pool_init() -> None:
    from worker.jobs import warm_up

    warm_up()


def _run(fit_id: str, task_id: str) -> str:
    from worker.jobs import run_fit

    return run_fit(fit_id, task_id)


class EmbeddedRunner:
    """A local pool of spawned processes; a crashed pool is rebuilt and its jobs resubmitted."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self._lock = threading.Lock()
        self._pool: ProcessPoolExecutor | None = None
        self._pending: dict[str, Future] = {}
        self._generation = 0
        self._stop = threading.Event()

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(
            max_workers=max(1, self.settings.workers),
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_pool_init,
        )

    def start(self) -> None:
        from worker.jobs import recover

        with self._lock:
            self._pool = self._new_pool()
        # Nothing else runs this database's jobs: everything unfinished is ours to run again.
        recover(self.submit, self.settings, on_start=True, requeue_running=True)
        threading.Thread(target=self._sweep, daemon=True, name="recovery-sweep").start()

    def _sweep(self) -> None:
        """Re-run jobs whose process died or that a transient fault left behind."""
        from worker.jobs import recover

        while not self._stop.wait(self.settings.sweep_interval_s):
            try:
                recover(self.submit, self.settings)
            except Exception as e:  # keep sweeping
                log.warning("recovery sweep failed: %s", e)

    def submit(self, fit_id: str) -> None:
        with self._lock:
            if self._pool is None:
                raise RuntimeError("the embedded job runner is not started")
            fut = self._pool.submit(_run, fit_id, f"emb.{uuid.uuid4().hex[:12]}")
            self._pending[fit_id] = fut
            gen = self._generation
        fut.add_done_callback(lambda f, i=fit_id, g=gen: self._done(i, f, g))

    def _done(self, fit_id: str, fut: Future, generation: int) -> None:
        exc = fut.exception() if not fut.cancelled() else None
        with self._lock:
            self._pending.pop(fit_id, None)
            rebuild = isinstance(exc, BrokenProcessPool) and generation == self._generation
            if rebuild:
                self._generation += 1
        if rebuild:
            log.error("the process pool broke while running %s: rebuilding it", fit_id)
            self._rebuild()
        elif exc is not None:  # transient fault: the job stays in the DB for a later recovery
            log.error("fit %s: %s", fit_id, exc)

    def _rebuild(self) -> None:
        from worker.jobs import recover

        with self._lock:
            if self._pool is not None:
                self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = self._new_pool()
        recover(self.submit, self.settings, on_start=True, requeue_running=True)

    def check(self) -> None:
        if self._pool is None:
            raise RuntimeError("the embedded job runner is not started")

    def shutdown(self) -> None:
        self._stop.set()
        with self._lock:
            pool, self._pool = self._pool, None
        if pool is not None:
            procs = list((getattr(pool, "_processes", None) or {}).values())
            pool.shutdown(wait=False, cancel_futures=True)
            for p in procs:  # a running fit is recovered on the next start
                p.terminate()


class CeleryRunner:
    """Publishes jobs to Celery over Redis (the broker named by ``BODYSPACE_BROKER_URL``)."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings

    def start(self) -> None:
        """Workers recover jobs on their start and periodically; the API only publishes."""

    def submit(self, fit_id: str) -> None:
        from worker.tasks import submit

        submit(fit_id)

    def check(self) -> None:
        import redis

        client = redis.Redis.from_url(
            self.settings.broker_url, socket_connect_timeout=2, socket_timeout=2
        )
        try:
            client.ping()
        finally:
            client.close()

    def shutdown(self) -> None:
        pass


def make_runner(settings: Settings) -> JobRunner:
    """The runner for the configured mode."""
    return CeleryRunner(settings) if settings.distributed else EmbeddedRunner(settings)
