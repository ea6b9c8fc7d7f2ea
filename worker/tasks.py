"""Celery wiring of ``bodyspace worker`` (:func:`main`): the one task, signals, nothing else.

The app and :func:`submit` live in :mod:`service.celery_app`, the job in :mod:`service.fit_job`
(claim, heartbeat, run, recover); this package only connects them to Celery. The task is thin:
it takes a fit id, calls :func:`service.fit_job.run_fit` and retries only transient faults. On
start, and then periodically, the worker re-enqueues jobs the database says are queued or whose
running worker stopped beating (:func:`service.fit_job.recover`): the database, not the broker,
is the source of truth. A beat key in Redis tells ``/readyz`` that a worker consumes the queue.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import threading

from celery import signals

from service import fit_job as jobs
from service.celery_app import TASK_NAME, app, submit
from service.settings import get_settings

log = logging.getLogger("bodyspace.worker")


@app.task(
    name=TASK_NAME,
    bind=True,
    autoretry_for=jobs.TRANSIENT,
    retry_backoff=True,
    retry_backoff_max=60,
    max_retries=5,
)
def run_fit(self, fit_id: str) -> str:
    """Run one fit job (idempotent; ids only)."""
    return jobs.run_fit(fit_id, self.request.id)


@signals.worker_process_init.connect
def _child_init(**_: object) -> None:
    from service.runtime import die_with_parent

    # A pool process whose worker died exits (its job is recovered from the database once its
    # heartbeat is stale). Watchdog only: billiard may start pool processes from a thread that
    # does not live as long as the worker, which would fire a parent-death signal early.
    die_with_parent(os.getppid(), pdeathsig=False, poll_s=1.0)
    # in the background: process start-up must stay short (worker_proc_alive_timeout)
    threading.Thread(target=jobs.warm_up, daemon=True, name="warm-up").start()


_sweeper_stop = threading.Event()


@signals.worker_init.connect
def _on_init(**_: object) -> None:
    from service.db import migrate

    migrate()


def _beat_key(node: str) -> str:
    from service.jobs import worker_beat_prefix

    return worker_beat_prefix(get_settings()) + node


def _beat(node: str) -> None:
    """Tell the API that this worker consumes the queue (``/readyz``): a Redis key with a TTL,
    refreshed until shutdown, deleted then."""
    import redis

    s = get_settings()
    client = redis.Redis.from_url(s.broker_url, socket_connect_timeout=2, socket_timeout=2)
    key, ttl = _beat_key(node), max(1, round(s.worker_beat_ttl_s))
    while True:
        try:
            client.set(key, f"{os.getpid()}", ex=ttl)
        except Exception as e:  # the broker is down: the key expires, readiness says so
            log.warning("worker beat failed: %s", e)
        if _sweeper_stop.wait(s.worker_beat_interval_s):
            break
    with contextlib.suppress(Exception):
        client.delete(key)
    client.close()


_beat_thread: threading.Thread | None = None


@signals.worker_ready.connect
def _on_ready(sender: object = None, **_: object) -> None:
    global _beat_thread
    node = getattr(sender, "hostname", None) or f"{socket.gethostname()}.{os.getpid()}"
    _beat_thread = threading.Thread(target=_beat, args=(node,), daemon=True, name="worker-beat")
    _beat_thread.start()
    jobs.recover(submit, on_start=True)

    def sweep() -> None:
        s = get_settings()
        while not _sweeper_stop.wait(s.sweep_interval_s):
            try:
                jobs.recover(submit)
            except Exception as e:  # keep sweeping
                log.warning("recovery sweep failed: %s", e)

    threading.Thread(target=sweep, daemon=True, name="recovery-sweep").start()


@signals.worker_shutdown.connect
def _on_shutdown(**_: object) -> None:
    _sweeper_stop.set()
    if _beat_thread is not None:  # its key deleted: readiness sees the worker gone at once
        _beat_thread.join(timeout=5)


def main(
    concurrency: int | None = None, loglevel: str = "INFO", hostname: str | None = None
) -> None:
    """Start a Celery worker for the configured broker (``bodyspace worker``)."""
    # each pool process's fits run their trials on the CPUs shared out (one each by default)
    jobs.share_fit_threads(concurrency)
    argv = ["worker", f"--loglevel={loglevel}", "-Q", get_settings().queue_name]
    argv += ["--without-mingle", "--without-gossip"]  # workers share nothing but the queue
    if concurrency:
        argv.append(f"--concurrency={concurrency}")
    if hostname:
        argv.append(f"--hostname={hostname}")
    app.worker_main(argv)
