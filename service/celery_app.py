"""The Celery app (broker, delivery settings) and :func:`submit`, which publishes a fit job.

The API publishes through this module; ``bodyspace worker`` (:mod:`worker.tasks`) registers the
task under :data:`TASK_NAME` on the same app and runs it. Delivery settings make a job survive a
crash: ``acks_late`` (the message is acknowledged after the job ends),
``task_reject_on_worker_lost`` (a killed pool process puts it back), a broker visibility timeout
above the hard time limit, prefetch 1; one Redis list per priority (fair dispatch, see
:func:`submit`).
"""

from __future__ import annotations

import logging
import uuid

from celery import Celery

from service import fit_job
from service.settings import get_settings

log = logging.getLogger("bodyspace.worker")

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
        priority=min(MAX_PRIORITY, fit_job.tenant_rank(fit_id)),
        retry=True,
        retry_policy={"max_retries": 2, "interval_start": 0, "interval_step": 0.5},
    )
