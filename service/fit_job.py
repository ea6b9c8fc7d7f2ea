"""The fit job: claim the row, load the inputs, run ``core``'s fit, store the result atomically.

:func:`run_fit` takes a fit id only and is idempotent: a job that already finished, or that another
live execution holds, is skipped. Both job runners call it (the embedded process pool and the
Celery task in :mod:`worker.tasks`). The row is claimed with one conditional ``UPDATE``; a running
job keeps a heartbeat so that a job whose worker died can be recovered (:func:`recover`).
"""

from __future__ import annotations

import json
import logging
import os
import socket
import threading
import time
from collections.abc import Callable
from datetime import timedelta
from typing import Any

import numpy as np
from sqlalchemy import and_, or_, select, update
from sqlalchemy.exc import InterfaceError, OperationalError

from core.errors import BodyspaceError
from core.serialize import json_ready
from service.blobs import BlobStore, make_store, sha256_file
from service.db import session_scope
from service.errors import describe, job_error
from service.models import Blob, Fit, Scan, utcnow
from service.settings import Settings, get_settings

log = logging.getLogger("bodyspace.worker")

RESULT_FORMATS = {
    "glb": "model/gltf-binary",
    "ply": "application/octet-stream",
    "obj": "text/plain; charset=utf-8",
    "json": "application/json",
}
TEXTURE_FORMAT = ("png", "image/png")  # fits of coloured scans only: the baked texture


class TransientError(Exception):
    """A fault worth retrying (database or storage unreachable); never raised for bad input."""


#: Faults retried by the task: the database or a network store is unreachable (not bad input).
TRANSIENT = (OperationalError, InterfaceError, ConnectionError, TimeoutError, TransientError)


def worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def result_key(tenant_id: str, fit_id: str, fmt: str) -> str:
    name = "report.json" if fmt == "json" else f"result.{fmt}"
    return f"{tenant_id}/fits/{fit_id}/{name}"


def share_fit_threads(processes: int | None) -> None:
    """Before a pool of ``processes`` fitting processes starts (default one per CPU): each
    one's fit threads, the CPUs shared out (``core.threads.share_cpus``; a wrong
    ``BODYSPACE_FIT_THREADS`` raises here, at the start)."""
    from core.threads import available_cpus, share_cpus

    share_cpus(processes or available_cpus())


def warm_up() -> None:
    """Build the template operators once per process so the first fit is not slower."""
    from core.registration.fit import template_operators
    from core.registration.shape_prior import load_shape_basis
    from core.rig import load_rig

    template_operators()
    load_shape_basis()
    load_rig()


def _claim(fit_id: str, task_id: str, settings: Settings) -> bool:
    now = utcnow()
    stale = now - timedelta(seconds=settings.stale_after_s)
    with session_scope(settings) as s:
        res = s.execute(
            update(Fit)
            .where(
                Fit.id == fit_id,
                or_(
                    Fit.state == "queued",
                    and_(
                        Fit.state == "running",
                        or_(Fit.heartbeat_at < stale, Fit.task_id == task_id),
                    ),
                ),
            )
            .values(
                state="running",
                task_id=task_id,
                worker=worker_name(),
                heartbeat_at=now,
                started_at=now,
                attempts=Fit.attempts + 1,
                progress={"phase": "loading", "percent": 0.0},
            )
        )
        return res.rowcount == 1


def _finish(fit_id: str, task_id: str, settings: Settings, **values: Any) -> bool:
    """Set the final state if this execution still holds the job."""
    with session_scope(settings) as s:
        res = s.execute(
            update(Fit)
            .where(Fit.id == fit_id, Fit.task_id == task_id, Fit.state == "running")
            .values(finished_at=utcnow(), heartbeat_at=utcnow(), **values)
        )
        return res.rowcount == 1


class _Heartbeat:
    """Keeps ``heartbeat_at`` fresh while a job runs; notices when the job is lost."""

    def __init__(self, fit_id: str, task_id: str, settings: Settings) -> None:
        self.fit_id, self.task_id, self.settings = fit_id, task_id, settings
        self.lost = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name="heartbeat")
        self._pending: dict[str, Any] | None = None
        self._lock = threading.Lock()

    def __enter__(self) -> _Heartbeat:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)

    def beat(self, progress: dict[str, Any] | None = None) -> None:
        """One heartbeat (with progress, if given), written now."""
        try:
            with session_scope(self.settings) as s:
                values: dict[str, Any] = {"heartbeat_at": utcnow()}
                if progress is not None:
                    values["progress"] = progress
                res = s.execute(
                    update(Fit)
                    .where(
                        Fit.id == self.fit_id, Fit.task_id == self.task_id, Fit.state == "running"
                    )
                    .values(**values)
                )
                if res.rowcount == 0:
                    self.lost.set()
        except TRANSIENT as e:  # a missed beat is not fatal
            log.warning("heartbeat of %s failed: %s", self.fit_id, e)

    def _run(self) -> None:
        while not self._stop.wait(self.settings.heartbeat_interval_s):
            self.beat()


def _load_inputs(
    fit: Fit, scan: Scan, store: BlobStore, settings: Settings, *, use_markers: bool = True
):
    """The prepared scan and the markers (canonical frame); without markers (``use_markers``
    False: markerless) the frame is detected from the scan alone."""
    from core.io import detect_frame, prepare_scan, read_mesh

    with store.local_copy(scan.blob_key) as path:
        raw = read_mesh(
            path, scan.format, max_vertices=settings.max_vertices, max_faces=settings.max_faces,
            name=scan.filename, sidecar_files=False,
        )  # fmt: skip
    markers_file = fit.markers if fit.markers is not None else scan.markers
    if not use_markers:
        markers_file = None
    markers = {k: np.asarray(v, dtype=np.float64) for k, v in (markers_file or {}).items()}
    frame = detect_frame(raw.surface()[0], units=scan.units, up=scan.up, markers=markers or None)
    prepared = prepare_scan(raw, frame)
    from core.transfer.texture import textured_surface

    prepared.textured = textured_surface(raw, frame)  # a textured scan, as read
    prepared.notes.insert(0, frame.describe(scan.units, scan.up))
    canon = {k: frame.to_canonical(v[None, :])[0] for k, v in markers.items()}
    return prepared, canon


def _fit_options(options: dict[str, Any], mode: str = "full") -> dict[str, Any]:
    """Keyword options of the core function of ``mode`` from a job's stored options."""
    from core.registration.schedule import preset

    if mode in ("markers_only", "measurements"):  # schedules and distances concern scans
        return {}
    out: dict[str, Any] = dict(preset(options.get("schedule") or "default"))
    if options.get("shape_prior") is not None:
        out["shape_prior"] = bool(options["shape_prior"])
    if options.get("max_distance_m") is not None:
        out["max_distance"] = float(options["max_distance_m"])
    if mode == "markerless":
        out.pop("shape_prior", None)  # always on (the service rejects it off)
        out["refine"] = bool(options.get("refine", True))
    return out


def _markers_only_inputs(fit: Fit) -> tuple[dict[str, np.ndarray], str]:
    """A scan-less markers-only job's markers in the canonical frame, and a note on the frame."""
    from core.io import detect_frame

    markers = {k: np.asarray(v, dtype=np.float64) for k, v in (fit.markers or {}).items()}
    opts = fit.options or {}
    units, up = opts.get("units", "m"), opts.get("up", "+y")
    frame = detect_frame(np.array(list(markers.values())), units=units, up=up)
    canon = {k: frame.to_canonical(v[None, :])[0] for k, v in markers.items()}
    return canon, f"markers in units {frame.units}, up axis {frame.up} (no scan)"


def _run_core(
    row: Fit,
    scan: Scan | None,
    store: BlobStore,
    settings: Settings,
    callback: Callable[[Any], bool],
):
    """Load the job's inputs and call the core function of its mode; returns a FitResult."""
    from core.matching.marker_checks import fit_checking_markers
    from core.matching.markerless import fit_markerless
    from core.matching.markers_only import fit_markers_only

    mode = row.mode or "full"
    opts = _fit_options(row.options or {}, mode)
    if mode == "measurements":
        from core.matching.from_measurements import body_from_measurements

        o = row.options or {}
        calibrate = o.get("calibrate", True)
        return body_from_measurements(o["sex"], o["measurements"], calibrate=calibrate)
    if mode == "markers_only":
        if scan is None:
            markers, note = _markers_only_inputs(row)
            units, up = (row.options or {}).get("units"), (row.options or {}).get("up")
        else:  # markers in the scan file's frame: the scan only tells the frame
            scan_obj, markers = _load_inputs(row, scan, store, settings)
            note = scan_obj.notes[0] + "; the scan's surface is not used"
            units = scan_obj.frame.units if scan_obj.frame else None
            up = scan_obj.frame.up if scan_obj.frame else None
        result = fit_markers_only(markers)
        result.report.notes.insert(0, note)
        result.report.units, result.report.up = units, up
        return result
    from core.transfer.colour import colour_fit

    scan_obj, markers = _load_inputs(row, scan, store, settings, use_markers=mode == "full")
    if mode == "markerless":
        result = fit_markerless(scan_obj, callback=callback, **opts)
    else:
        result = fit_checking_markers(scan_obj, markers, callback=callback, **opts)
    colour_fit(result, scan_obj)  # a coloured scan gives a coloured body
    return result


def run_fit(fit_id: str, task_id: str, settings: Settings | None = None) -> str:
    """Run fit ``fit_id`` as execution ``task_id``; returns the final state or ``"skipped"``.

    Domain errors and bugs end the job as ``failed`` (with the message); transient faults
    (database/storage unreachable) are raised for the caller to retry.
    """
    from core.io import write_glb, write_obj, write_ply
    from core.io.images import encode_png
    from core.registration.fit import FitCancelled
    from core.transfer.texture import TEXTURE_SIZE, fit_texture, textured_glb

    settings = settings or get_settings()
    if not _claim(fit_id, task_id, settings):
        log.info("fit %s: not claimable (finished, deleted or held elsewhere): skipped", fit_id)
        return "skipped"
    with session_scope(settings) as s:
        row = s.get(Fit, fit_id)
        scan = None if row is None or row.scan_id is None else s.get(Scan, row.scan_id)
        if row is None or (row.scan_id is not None and scan is None):  # deleted meanwhile
            return "skipped"
        s.expunge_all()
    if row.attempts > settings.max_attempts:
        _finish(
            fit_id,
            task_id,
            settings,
            state="failed",
            error=job_error(
                "too_many_attempts",
                f"the job was started {row.attempts - 1} times without finishing "
                "(its worker was lost each time); not retried again",
            ),
        )
        return "failed"
    store = make_store(settings)
    t0 = time.monotonic()
    limit = settings.job_time_limit_s
    timed_out = False
    with _Heartbeat(fit_id, task_id, settings) as hb:
        try:
            stages = _fit_options(row.options or {}, row.mode or "full").get("schedule")
            stages = stages.stages if stages is not None else ()
            last = 0.0

            def on_progress(p) -> bool:
                nonlocal last, timed_out
                if time.monotonic() - t0 > limit:
                    timed_out = True
                    return False
                now = time.monotonic()
                if now - last >= settings.progress_interval_s:
                    last = now
                    done = p.stage + min(1.0, (p.iteration + 1) / stages[p.stage].max_iterations)
                    hb.beat(
                        json_ready(
                            {
                                "phase": "fitting",
                                "stage": p.stage,
                                "n_stages": p.n_stages,
                                "iteration": p.iteration,
                                "resolution": p.resolution,
                                "energy": p.energy,
                                "max_step_m": p.max_step_m,
                                "elapsed_s": round(p.elapsed_s, 3),
                                "percent": round(100.0 * done / p.n_stages, 1),
                            }
                        )
                    )
                return not hb.lost.is_set()

            result = _run_core(row, scan, store, settings, on_progress)
            V, F = result.vertices, result.faces
            report = json_ready(result.report.to_dict())
            formats = dict(RESULT_FORMATS)
            colors = getattr(result, "colors", None)  # FitResult of a coloured scan only
            if colors is not None:
                formats[TEXTURE_FORMAT[0]] = TEXTURE_FORMAT[1]
            keys = {f: result_key(row.tenant_id, fit_id, f) for f in formats}
            files = {f: store.temp_file(f".{f}") for f in formats}
            if colors is None:
                write_glb(files["glb"], V, F)
            else:  # the colours baked on the template UV layout: a textured GLB and its PNG
                png = encode_png(fit_texture(colors, result.texture))
                textured_glb(files["glb"], V, png)
                files["png"].write_bytes(png)
                report["texture"] = {"format": "png", "size_px": TEXTURE_SIZE, "uv": "template"}
            write_ply(files["ply"], V, F, colors=colors)
            write_obj(files["obj"], V, F)
            files["json"].write_text(json.dumps(report, indent=1), encoding="utf-8")
            blobs = [
                Blob(
                    key=keys[fmt],
                    tenant_id=row.tenant_id,
                    fit_id=fit_id,
                    kind=f"result.{fmt}",
                    content_type=formats[fmt],
                    size_bytes=files[fmt].stat().st_size,
                    sha256=sha256_file(files[fmt]),
                )
                for fmt in formats
            ]
            try:
                for fmt, tmp in files.items():
                    store.commit_file(tmp, keys[fmt])
            finally:  # consumed by commit_file, unless it failed
                for tmp in files.values():
                    tmp.unlink(missing_ok=True)
        except FitCancelled:
            if timed_out:
                msg = f"the fit exceeded the time limit of {limit:g} s"
                err = job_error("time_limit_exceeded", msg)
                _finish(fit_id, task_id, settings, state="failed", error=err)
                return "failed"
            log.info("fit %s: lost its claim (deleted or taken over): abandoned", fit_id)
            return "skipped"
        except TRANSIENT:
            raise
        except BodyspaceError as e:
            _finish(fit_id, task_id, settings, state="failed", error=describe(e))
            return "failed"
        except Exception as e:
            if type(e).__name__ == "SoftTimeLimitExceeded":
                msg = f"the fit exceeded the time limit of {limit:g} s"
                err = job_error("time_limit_exceeded", msg)
            else:
                log.exception("fit %s raised", fit_id)
                err = describe(e)
            _finish(fit_id, task_id, settings, state="failed", error=err)
            return "failed"

    # One transaction: blob rows + final state, only if this execution still holds the job.
    with session_scope(settings) as s:
        res = s.execute(
            update(Fit)
            .where(Fit.id == fit_id, Fit.task_id == task_id, Fit.state == "running")
            .values(
                state="succeeded",
                finished_at=utcnow(),
                report=report,
                fit_seconds=float(report.get("seconds") or 0.0),
                progress={"phase": "done", "percent": 100.0},
                error=None,
            )
        )
        if res.rowcount != 1:
            if s.get(Fit, fit_id) is None:  # deleted meanwhile: leave nothing behind
                store.delete_prefix(f"{row.tenant_id}/fits/{fit_id}")
            return "skipped"
        for blob in blobs:
            s.merge(blob)
    log.info("fit %s succeeded in %.1f s", fit_id, time.monotonic() - t0)
    return "succeeded"


def tenant_rank(fit_id: str, settings: Settings | None = None) -> int:
    """How many of its tenant's queued or running fits were created before fit ``fit_id``."""
    from sqlalchemy import func

    settings = settings or get_settings()
    with session_scope(settings) as s:
        row = s.get(Fit, fit_id)
        if row is None:
            return 0
        return int(
            s.scalar(
                select(func.count())
                .select_from(Fit)
                .where(
                    Fit.tenant_id == row.tenant_id,
                    Fit.state.in_(("queued", "running")),
                    Fit.id != fit_id,
                    or_(
                        Fit.created_at < row.created_at,
                        and_(Fit.created_at == row.created_at, Fit.id < fit_id),
                    ),
                )
            )
            or 0
        )


def recover(
    submit: Callable[[str], None],
    settings: Settings | None = None,
    *,
    on_start: bool = False,
    requeue_running: bool = False,
) -> list[str]:
    """Re-enqueue jobs that no queue holds any more; returns their ids.

    - queued jobs: all of them ``on_start`` (the broker may have lost its queue), else those
      enqueued longer than ``requeue_after_s`` ago;
    - running jobs whose heartbeat is older than ``stale_after_s`` (their worker died), or all
      running jobs when ``requeue_running`` (embedded start: nothing else can be running them).

    Jobs are set back to ``queued`` first; a duplicate message is harmless (claims are exclusive).
    """
    settings = settings or get_settings()
    now = utcnow()
    stale = now - timedelta(seconds=settings.stale_after_s)
    old = now - timedelta(seconds=settings.requeue_after_s)
    with session_scope(settings) as s:
        running = Fit.state == "running"
        if not requeue_running:
            running = and_(running, or_(Fit.heartbeat_at < stale, Fit.heartbeat_at.is_(None)))
        queued = Fit.state == "queued"
        if not on_start:
            queued = and_(queued, or_(Fit.enqueued_at < old, Fit.enqueued_at.is_(None)))
        ids = list(s.scalars(select(Fit.id).where(or_(running, queued)).with_for_update()))
        if ids:
            s.execute(
                update(Fit)
                .where(Fit.id.in_(ids), Fit.state.in_(("queued", "running")))
                .values(state="queued", enqueued_at=now)
            )
    for fit_id in ids:
        try:
            submit(fit_id)
        except Exception as e:  # stays queued in the DB: the next sweep tries again
            log.warning("re-enqueue of %s failed: %s", fit_id, e)
    if ids:
        log.info("recovered %d job(s): %s", len(ids), ", ".join(ids))
    return ids
