"""Running jobs: claim, plan with heartbeats, write outputs atomically, finish; the reaper.

A worker process runs :func:`execute_job` for each id huey hands it. The job table is the
truth: the claim is a conditional UPDATE, a heartbeat thread keeps it fresh, the progress
callback writes progress and learns of a DELETE (the UPDATE matches no row any more), and
only the claim holder may finish the job. The :class:`Reaper` re-enqueues jobs whose
worker died and fails them as "worker lost" after their last attempt.
"""

from __future__ import annotations

import gc
import hashlib
import json
import logging
import multiprocessing
import os
import shutil
import socket
import threading
import time
import uuid
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from planner.errors import CancelledError, PlannerError, SceneError
from planner.io.readers import read_scene
from planner.outputs.report import write_outputs
from planner.parameters import PlanSpec
from planner.pipeline import plan
from service.config import Settings
from service.database import make_engine
from service.job_store import FAILED, SUCCESSFUL, JobRecord, JobStore, attempt_entry
from service.mesh_store import MeshStore
from service.plan_process import (
    ChildFailedError,
    ChildLimits,
    PlanProcessError,
    Progress,
    StoppedError,
    run_in_child,
)
from service.problems import OutOfMemoryError, PlanKilledError, WorkerLostError, problem_for
from service.queue import HueyQueue, JobQueue, make_huey
from service.store import open_store, result_key, results_prefix

log = logging.getLogger("scanplan.worker")

# share of the progress bar per stage, in percent: (start, end)
STAGE_PERCENT: dict[str, tuple[int, int]] = {
    "reading": (0, 5), "candidates": (5, 15), "visibility": (15, 85),
    "selection": (85, 95), "report": (95, 98), "writing": (98, 100),
}


@dataclass
class WorkerContext:
    """What a job run needs; built once per process."""

    settings: Settings
    jobs: JobStore
    meshes: MeshStore
    queue: JobQueue

    @property
    def results_root(self) -> Path:
        return self.settings.data_dir / "jobs"


def build_context(settings: Settings, queue: JobQueue) -> WorkerContext:
    """Open the database and stores for ``settings`` (call it in the process that uses it)."""
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    engine = make_engine(settings.job_db_url)
    meshes = MeshStore(settings.data_dir / "meshes", engine, settings.max_upload_bytes,
                       open_store(settings))
    return WorkerContext(settings, JobStore(engine), meshes, queue)


@dataclass
class ProgressReporter:
    """The planner's progress callback: writes progress, returns True once cancelled."""

    ctx: WorkerContext
    job_id: str
    token: str
    cancelled: threading.Event = field(default_factory=threading.Event)
    _last_stage: str = ""
    _last_write: float = 0.0

    def __call__(self, stage: str, fraction: float) -> bool:
        if self.cancelled.is_set():
            return True
        now = time.monotonic()
        if stage == self._last_stage and now - self._last_write < \
                self.ctx.settings.progress_interval_s:
            return False
        start, end = STAGE_PERCENT.get(stage, (0, 100))
        percent = int(start + (end - start) * fraction)
        message = f"{stage}: {fraction * 100:.0f} % of this stage"
        if not self.ctx.jobs.heartbeat(self.job_id, self.token, progress=percent,
                                       message=message):
            self.cancelled.set()  # dismissed, or the reaper gave the job to another worker
            return True
        self._last_stage, self._last_write = stage, now
        return False


class Heartbeat:
    """A thread that refreshes the claim while the plan computes between callbacks."""

    def __init__(self, reporter: ProgressReporter, interval_s: float) -> None:
        self.reporter = reporter
        self.interval_s = interval_s
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="heartbeat", daemon=True)

    def __enter__(self) -> Heartbeat:
        self._thread.start()
        return self

    def __exit__(self, *_exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def _run(self) -> None:
        r = self.reporter
        while not self._stop.wait(self.interval_s):
            try:
                if not r.ctx.jobs.heartbeat(r.job_id, r.token):
                    r.cancelled.set()
                    return
            except Exception:  # a database hiccup: the next beat tries again
                log.exception("heartbeat of job %s failed", r.job_id)


def execute_job(ctx: WorkerContext, job_id: str) -> None:
    """Run one job to its end state; a no-op when another worker claimed it already."""
    token = uuid.uuid4().hex
    if not ctx.jobs.claim(job_id, token, f"{socket.gethostname()}:{os.getpid()}"):
        log.info("job %s is not accepted any more; skipping", job_id)
        return
    job = ctx.jobs.get(job_id)
    assert job is not None
    reporter = ProgressReporter(ctx, job_id, token)
    measured: dict[str, float] = {}  # the planning process's peak memory, once it is gone
    log.info("job %s: running (attempt %d)", job_id, job.attempts)
    instance = f"/jobs/{job_id}"
    try:
        with Heartbeat(reporter, ctx.settings.heartbeat_interval_s):
            outputs, timings = _run_plan(ctx, job, reporter, measured)
    except (CancelledError, StoppedError):
        log.info("job %s: stopped (dismissed or reassigned)", job_id)
    except ChildFailedError as exc:
        log.info("job %s: failed: %s", job_id, exc)
        ctx.jobs.finish(job_id, token, FAILED, message=str(exc),
                        problem={**exc.problem, "instance": instance},
                        attempt=attempt_entry(job, FAILED, **measured))
    except PlanProcessError as exc:
        log.warning("job %s: %s", job_id, exc)
        _child_ended(ctx, job, token, exc)
    except PlannerError as exc:
        log.info("job %s: failed: %s", job_id, exc)
        ctx.jobs.finish(job_id, token, FAILED, message=str(exc),
                        problem=problem_for(exc, instance=instance),
                        attempt=attempt_entry(job, FAILED, **measured))
    except KeyboardInterrupt:  # huey stops the worker: hand the job back, it is not lost
        if ctx.jobs.release(job_id, token):
            ctx.queue.enqueue(job_id)
        raise
    except Exception as exc:
        log.exception("job %s: unexpected error", job_id)
        ctx.jobs.finish(job_id, token, FAILED, message="internal error",
                        problem=problem_for(exc, instance=instance),
                        attempt=attempt_entry(job, FAILED, **measured))
    else:
        if ctx.jobs.finish(job_id, token, SUCCESSFUL, message=_done_message(ctx, job_id),
                           timings=timings, outputs=outputs,
                           attempt=attempt_entry(job, SUCCESSFUL, **measured)):
            log.info("job %s: successful", job_id)
        else:  # dismissed while the files were moved into place
            ctx.meshes.store.delete_prefix(results_prefix(job_id))


def _child_ended(ctx: WorkerContext, job: JobRecord, token: str,
                 exc: PlanProcessError) -> None:
    """The planning process ended without a result: out of memory fails the job; ended by a
    signal from outside, the job is queued again like a lost worker's, until its last try."""
    end = exc.end
    outcome = "out of memory" if end.out_of_memory else "killed" if end.killed else FAILED
    figures = {k: v for k, v in asdict(end).items() if k != "out_of_memory" and v is not None}
    attempt = attempt_entry(job, outcome, **figures)
    tries = f"attempt {job.attempts} of {ctx.settings.max_attempts}"
    if end.killed and job.attempts < ctx.settings.max_attempts:
        if ctx.jobs.retry(job.id, token, attempt=attempt, message=(
                f"queued again: the planning process was ended by {end.signal} in stage "
                f"{end.stage or 'starting'} ({tries})")):
            ctx.queue.enqueue(job.id)
            log.warning("job %s: queued again after %s", job.id, tries)
        return
    error: Exception = exc
    if end.out_of_memory:
        error = OutOfMemoryError(str(exc))
    elif end.killed:
        error = PlanKilledError(f"{exc}; that was {tries} (SCANPLAN_MAX_ATTEMPTS, the job's "
                                "attempt_log lists each); submit the job again")
    ctx.jobs.finish(job.id, token, FAILED, message=str(error), attempt=attempt,
                    problem=problem_for(error, instance=f"/jobs/{job.id}"))


def _done_message(ctx: WorkerContext, job_id: str) -> str:
    """"done", then the storeys planned and what was left out when there is more than one
    level (:func:`planner.candidates.grid.levels_line`), for an IFC model one clause per
    storey with its rooms (:func:`planner.candidates.rooms.rooms_lines`), why there is no
    plan.ifc for an input that is not IFC, the parts of the walk the model does not join
    (:func:`planner.survey.route.parts_line`), and for a plain mesh the glazed openings on
    the route that the crew must check (:func:`planner.survey.route.door_checks_line`), each
    in a clause of its own."""
    from planner.candidates.grid import levels_line
    from planner.candidates.rooms import rooms_lines
    from planner.outputs.ifc_plan import reason_without_ifc
    from planner.survey.route import door_checks_line, parts_line

    try:
        plan_doc = json.loads(ctx.meshes.store.read_bytes(result_key(job_id, "plan.json")))
        no_ifc = reason_without_ifc(str(plan_doc["scene"].get("format", "")))
        clauses = [levels_line(plan_doc["candidates"].get("levels")),
                   plan_doc["candidates"].get("floor_note"),
                   *rooms_lines(plan_doc["candidates"].get("rooms")),
                   None if no_ifc is None else f"no plan.ifc: {no_ifc}",
                   parts_line(plan_doc.get("route")),
                   door_checks_line(plan_doc.get("route"))]
    except (OSError, ValueError, KeyError):
        clauses = []
    return "; ".join(["done", *(clause for clause in clauses if clause)])


def _run_plan(ctx: WorkerContext, job: JobRecord, reporter: ProgressReporter,
              measured: dict[str, float]) -> tuple[dict[str, dict[str, Any]], dict[str, float]]:
    """Plan ``job`` in a child process (see :mod:`service.plan_process`), then move the
    outputs it wrote into place (upload them, with an object store); ``measured`` receives
    the child's peak memory."""
    spec = PlanSpec.from_mapping(job.parameters)
    ctx.results_root.mkdir(parents=True, exist_ok=True)
    temporary = ctx.results_root / f".tmp-{job.id}-{reporter.token}"
    downloads = ctx.results_root / f".mesh-{job.id}-{reporter.token}"  # from an object store
    mesh_path = ctx.meshes.fetch(job.mesh_id, downloads)
    if mesh_path is None:
        raise SceneError(f"mesh {job.mesh_id} is no longer stored; upload it again")
    threads = ctx.settings.threads_per_job
    dask_scheduler = ctx.settings.dask_scheduler  # None: the plan runs in this worker

    def work(progress: Progress) -> tuple[dict[str, dict[str, Any]], dict[str, float]]:
        timings: dict[str, float] = {}
        progress("reading", 0.0)
        started = time.perf_counter()
        scene = read_scene(mesh_path, max_edge_m=spec.max_edge_m, unit_scale=spec.unit_scale,
                           up_axis=spec.up_axis, split_faces="as_needed")
        timings["reading"] = time.perf_counter() - started
        result = plan(scene, spec, progress=progress, threads=threads,
                      dask_scheduler=dask_scheduler)
        timings.update(result.stats.seconds)
        progress("writing", 0.0)
        started = time.perf_counter()
        outputs = _write_outputs(result, temporary)
        timings["writing"] = time.perf_counter() - started
        if spec.verify:  # a simulated scan of the stations (planner.truth): the plan's truth
            from planner.truth.verification import read_plan_dir, verify_plan_dir

            progress("verification", 0.0)
            started = time.perf_counter()
            verify_plan_dir(temporary, result.scene, read_plan_dir(temporary), progress=progress,
                            threads=threads)
            outputs = _describe(sorted(temporary.iterdir()))
            timings["verification"] = time.perf_counter() - started
        return outputs, {name: round(seconds, 4) for name, seconds in timings.items()}

    def should_stop() -> bool:
        return reporter.cancelled.is_set() or not ctx.jobs.holds_claim(job.id, reporter.token)

    try:
        outputs, timings = run_in_child(
            work, measured=measured, limits=ChildLimits(
                memory_bytes=ctx.settings.job_memory_limit_bytes,
                nice=ctx.settings.worker_nice),
            on_progress=reporter, should_stop=should_stop,
            poll_interval_s=ctx.settings.cancel_poll_interval_s,
            describe_error=lambda exc: problem_for(exc))
        if reporter("writing", 1.0):
            raise CancelledError("the plan was cancelled before its outputs were in place")
        ctx.meshes.store.publish_folder(temporary, results_prefix(job.id))
    finally:
        shutil.rmtree(temporary, ignore_errors=True)
        shutil.rmtree(downloads, ignore_errors=True)
    return outputs, timings


def _write_outputs(result: Any, folder: Path) -> dict[str, dict[str, Any]]:
    """Write every output into ``folder``; name -> bytes and sha256."""
    return _describe(write_outputs(result, folder))


def _describe(paths: list[Path]) -> dict[str, dict[str, Any]]:
    """File name -> its size and sha256, as the results document lists them."""
    return {path.name: {"bytes": path.stat().st_size,
                        "sha256": hashlib.sha256(path.read_bytes()).hexdigest()}
            for path in paths}


def worker_lost_problem(job: JobRecord) -> dict[str, Any]:
    """The problem of a job whose worker died on its last attempt."""
    exc = WorkerLostError(
        f"worker lost: the worker running this job stopped responding on attempt "
        f"{job.attempts} of {job.attempts}; submit the job again, and check the workers' "
        "memory if it keeps happening")
    return problem_for(exc, instance=f"/jobs/{job.id}")


class Reaper:
    """Re-enqueues running jobs whose heartbeat went stale; fails them after the last try."""

    def __init__(self, jobs: JobStore, queue: JobQueue, settings: Settings) -> None:
        self.jobs = jobs
        self.queue = queue
        self.settings = settings
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def run_once(self) -> int:
        """One pass; returns how many jobs it touched."""
        touched = 0
        for job in self.jobs.stale_running(time.time() - self.settings.stale_after_s):
            if job.attempts >= self.settings.max_attempts:
                if self.jobs.fail_lost(job, worker_lost_problem(job)):
                    log.warning("job %s: worker lost on its last attempt; failed", job.id)
                    touched += 1
            elif self.jobs.requeue_lost(job):
                self.queue.enqueue(job.id)
                log.warning("job %s: worker lost; queued again", job.id)
                touched += 1
        return touched

    def requeue_accepted(self) -> int:
        """Enqueue every accepted job once more (a repeat is a no-op; a lost id is found)."""
        ids = self.jobs.ids_with_status("accepted")
        for job_id in ids:
            self.queue.enqueue(job_id)
        return len(ids)

    def start(self) -> None:
        """Run :meth:`run_once` every ``reaper_interval_s`` in a daemon thread."""
        self._thread = threading.Thread(target=self._loop, name="reaper", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()

    def _loop(self) -> None:
        while not self._stop.wait(self.settings.reaper_interval_s):
            try:
                self.run_once()
            except Exception:  # the database may be briefly away: try again next time
                log.exception("reaper pass failed")


class _LazyContext:
    """One :class:`WorkerContext` per process, built on first use (after huey forks)."""

    def __init__(self, settings: Settings, queue: HueyQueue) -> None:
        self.settings = settings
        self.queue = queue
        self._pid = -1
        self._context: WorkerContext | None = None

    def get(self) -> WorkerContext:
        if self._context is None or self._pid != os.getpid():
            self._context = build_context(self.settings, self.queue)
            self._pid = os.getpid()
        return self._context


def make_worker_queue(settings: Settings) -> HueyQueue:
    """The huey queue with the task body that runs jobs in this process."""
    contexts: dict[str, _LazyContext] = {}

    def run_job(job_id: str) -> None:
        execute_job(contexts["lazy"].get(), job_id)

    queue = HueyQueue(make_huey(settings), run_job)
    contexts["lazy"] = _LazyContext(settings, queue)
    return queue


def _configure_logging(settings: Settings) -> None:
    logging.basicConfig(level=settings.log_level.upper(),
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")


def run_reaper(settings: Settings) -> None:
    """The reaper alone, forever (a process of its own beside a consumer)."""
    _configure_logging(settings)
    queue = HueyQueue(make_huey(settings))
    reaper = Reaper(build_context(settings, queue).jobs, queue, settings)
    reaper.start()
    threading.Event().wait()


def _warm_up() -> None:
    """The planner's modules and compiled kernels loaded here, before huey forks: every
    worker process, and every job's process forked from it, then has them (hall-small's
    job took 1.0 s from submission to its results instead of 1.75 s, 2 cores). The objects
    are then frozen out of the garbage collector (:func:`gc.freeze`), whose passes would
    otherwise write to their pages in every fork and copy them."""
    from planner.__main__ import warm_up

    started = time.perf_counter()
    try:
        modules, kernels = warm_up()
    except Exception:  # only a head start: the jobs load what they need themselves
        log.exception("warm-up failed; each job loads the planner's modules and kernels")
        return
    gc.freeze()
    log.info("warmed up in %.1f s: %d planner modules, %d compiled kernels loaded",
             time.perf_counter() - started, modules, kernels)


def run_consumer(settings: Settings, *, with_reaper: bool) -> None:
    """Consume jobs with ``settings.workers`` processes until SIGINT/SIGTERM (blocking).

    huey forks its worker processes (and forks again to replace a dead one), so the
    consumer process itself keeps no threads and no database connections; the reaper,
    when wanted, runs in a process of its own.
    """
    _configure_logging(settings)
    if with_reaper:
        reaper = multiprocessing.get_context("fork").Process(
            target=run_reaper, args=(settings,), name="reaper", daemon=True)
        reaper.start()
    if settings.warm_up:
        _warm_up()
    queue = make_worker_queue(settings)
    consumer = queue.huey.create_consumer(
        workers=max(1, settings.workers), worker_type="process", periodic=False,
        check_worker_health=True, health_check_interval=settings.worker_health_interval_s,
        initial_delay=0.05, max_delay=0.5, backoff=1.5,
    )
    log.info("consuming jobs with %d worker processes", max(1, settings.workers))
    # huey sets its signal handlers only after it has forked its workers (Consumer.start):
    # a SIGTERM in between (serve killed as the workers start, which the consumer hears
    # through PR_SET_PDEATHSIG) ended the consumer and left its workers running. Set
    # first, they record the signal, and the consumer's first loop stops the workers.
    consumer._set_signal_handlers()
    consumer.run()
