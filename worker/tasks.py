"""The Celery app and its one task. ``bodyspace worker`` runs :func:`main`.

The task is thin: it takes a fit id, calls :func:`worker.jobs.run_fit` and retries only transient
faults. Delivery settings make a job survive a crash: ``acks_late`` (the message is acknowledged
after the job ends), ``task_reject_on_worker_lost`` (a killed pool process puts it back), a broker
visibility timeout above the hard time limit, prefetch 1. On start, and then periodically, the
worker re-enqueues jobs the database says are queued or whose running worker stopped beating
(:func:`worker.jobs.recover`): the database, not the broker, is the source of truth.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import threading
import uuid

from celery import Celery, signals

from service.settings import get_settings
from worker import jobs

TASK_NAME = "bodyspace.fits.run"
#: Lowest message priority (Redis transport: 0 is consumed first).
MAX_PRIORITY = 9
log = logging.getLogger("bodyspace.worker")


def make_celery() -> Celery:
    s = get_settings()
    app = Celery("bodyspace", broker=s.broker_url or "redis://127.0.0.1:6379/0")
    app.conf.update(
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        task_acks_on_failure_or_timeout=True,
        worker_prefetch_multiplier=1,
        task_ignore_result=True,
        task_default_queue=s.queue_name,
        task_time_limit=int(s.job_time_limit_s + 60),
        task_soft_time_limit=int(s.job_time_limit_s + 30),
        broker_transport_options={
            "visibility_timeout": s.visibility_timeout_s,
            # fairness: one list per priority, consumed 0 first (see submit)
            "queue_order_strategy": "priority",
            "priority_steps": list(range(MAX_PRIORITY + 1)),
        },
        broker_connection_retry_on_startup=True,
        task_serializer="json",
        accept_content=["json"],
        worker_hijack_root_logger=False,
        worker_send_task_events=False,
    )
    return app


app = make_celery()


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


def submit(fit_id: str) -> None:
    """Enqueue fit ``fit_id`` (a fresh task id each time).

    Its priority is its rank among its tenant's active fits (0 for the oldest, capped at
    :data:`MAX_PRIORITY`): workers take every tenant's first fit before anyone's second, so a
    burst of one tenant delays another tenant's fit by about one fit per worker."""
    app.send_task(
        TASK_NAME,
        args=[fit_id],
        task_id=f"{fit_id}.{uuid.uuid4().hex[:12]}",
        queue=get_settings().queue_name,
        priority=min(MAX_PRIORITY, jobs.tenant_rank(fit_id)),
        retry=True,
        retry_policy={"max_retries": 2, "interval_start": 0, "interval_step": 0.5},
    )


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
    argv = ["worker", f"--loglevel={loglevel}", "-Q", get_settings().queue_name]
    argv += ["--without-mingle", "--without-gossip"]  # workers share nothing but the queue
    if concurrency:
        argv.append(f"--concurrency={concurrency}")
    if hostname:
        argv.append(f"--hostname={hostname}")
    app.worker_main(argv)
