"""The job table: the source of truth for every job's state.

Every state change is a conditional UPDATE, so that the API, several workers and the reaper
can race without a lock: a worker claims ``accepted -> running`` with its token, keeps the
claim alive with heartbeats, and only the holder of the current token may finish the job.
"""

from __future__ import annotations

import json
import threading
import time
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from sqlalchemy import Engine, Row, delete, func, insert, select, text, update
from sqlalchemy.exc import IntegrityError

from service.database import jobs

ACCEPTED, RUNNING, SUCCESSFUL, FAILED, DISMISSED = (
    "accepted", "running", "successful", "failed", "dismissed")
STATUSES = (ACCEPTED, RUNNING, SUCCESSFUL, FAILED, DISMISSED)
ACTIVE = (ACCEPTED, RUNNING)
FINISHED = (SUCCESSFUL, FAILED, DISMISSED)


@dataclass(frozen=True)
class JobRecord:
    """One row of the job table, JSON columns decoded."""

    id: str
    owner: str
    mesh_id: str
    parameters: dict[str, Any]
    status: str
    progress: int
    message: str
    created: float
    started: float | None
    finished: float | None
    updated: float
    heartbeat: float | None
    attempts: int
    worker_token: str | None
    worker: str | None
    idempotency_key: str | None
    request_hash: str | None
    problem: dict[str, Any] | None
    timings: dict[str, float] | None
    outputs: dict[str, dict[str, Any]] | None
    attempt_log: list[dict[str, Any]] | None = None  # see attempt_entry

    @classmethod
    def from_row(cls, row: Row[Any]) -> JobRecord:
        data = dict(row._mapping)
        for name in ("parameters", "problem", "timings", "outputs", "attempt_log"):
            data[name] = None if data[name] is None else json.loads(data[name])
        return cls(**data)


# built once: a submission's one write; insert(...).values(**row) per call spent more time
# building and keying the statement than SQLite spent on the row
_INSERT_JOB = insert(jobs)


class OverCapError(Exception):
    """A new job refused: its owner already has ``active`` jobs accepted or running."""

    def __init__(self, active: int) -> None:
        super().__init__(f"{active} jobs accepted or running")
        self.active = active


def _active_count_of(owner: str) -> Any:
    """SELECT the number of ``owner``'s jobs accepted or running."""
    return select(func.count()).select_from(jobs).where(
        jobs.c.owner == owner, jobs.c.status.in_(ACTIVE))


def _json(value: Any) -> str | None:
    return None if value is None else json.dumps(value, sort_keys=True)


def attempt_entry(job: JobRecord, outcome: str, **figures: Any) -> dict[str, Any]:
    """One ended attempt of ``job`` (a running record) as the job's ``attempt_log`` keeps it.

    ``outcome``: successful, failed, out of memory, killed (ended by a signal from outside,
    queued again or failed after the last try) or worker lost; ``figures``: ``stage``,
    ``signal``, ``peak_rss_mib``, ... of :class:`service.plan_process.ChildEnd`. Times are
    epoch seconds.
    """
    return {"attempt": job.attempts, "worker": job.worker, "started": job.started,
            "finished": time.time(), "outcome": outcome, **figures}


def _stage_of(message: str) -> str | None:
    """The stage a running job's progress message names ("visibility: 40 % ...")."""
    stage, colon, _ = message.partition(":")
    return stage if colon and " " not in stage else None


class JobStore:
    """Reads and conditional writes of the job table."""

    def __init__(self, engine: Engine) -> None:
        self.engine = engine
        # one writer at a time in this process: threads wait on this lock instead of
        # SQLite's busy handler, which sleeps up to 100 ms per retry under contention
        self._write_lock = threading.Lock()

    def ping(self) -> None:
        """Raise when the database is unreachable."""
        with self.engine.connect() as conn:
            conn.execute(text("SELECT 1"))

    def create(self, owner: str, mesh_id: str, parameters: dict[str, Any], *,
               idempotency_key: str | None = None, request_hash: str | None = None,
               active_cap: int = 0) -> tuple[JobRecord, bool]:
        """Insert an accepted job; with a known Idempotency-Key, return that job instead.

        ``active_cap``: the most jobs ``owner`` may have accepted or running (0: no cap).
        The count is taken in the insert's own transaction, and a count over the cap rolls
        the insert back and raises :class:`OverCapError`: nothing is stored. Submissions
        racing for the last place are serialised by the database's write lock (SQLite holds
        it from the insert to the commit; on PostgreSQL a transaction-scoped advisory lock
        per owner does it), so exactly the places left are taken, by the first to insert.

        Returns the job and whether it was created now.
        """
        now = time.time()
        job_id = uuid.uuid4().hex
        values: dict[str, Any] = {
            "id": job_id, "owner": owner, "mesh_id": mesh_id,
            "parameters": _json(parameters), "status": ACCEPTED, "progress": 0,
            "message": "queued", "created": now, "updated": now, "attempts": 0,
            "idempotency_key": idempotency_key, "request_hash": request_hash,
        }
        try:
            with self._write_lock, self.engine.begin() as conn:
                if active_cap and conn.dialect.name == "postgresql":
                    conn.execute(text("SELECT pg_advisory_xact_lock(hashtext(:owner))"),
                                 {"owner": owner})
                conn.execute(_INSERT_JOB, values)
                if active_cap:
                    active = conn.execute(_active_count_of(owner)).scalar_one()
                    if active > active_cap:
                        raise OverCapError(active - 1)  # leaving the block rolls back
        except IntegrityError:
            existing = self.by_idempotency_key(owner, idempotency_key)
            if existing is None:
                raise
            return existing, False
        # the row as inserted (no read back: a submission costs one write)
        return JobRecord(
            id=job_id, owner=owner, mesh_id=mesh_id, parameters=parameters, status=ACCEPTED,
            progress=0, message="queued", created=now, started=None, finished=None,
            updated=now, heartbeat=None, attempts=0, worker_token=None, worker=None,
            idempotency_key=idempotency_key, request_hash=request_hash, problem=None,
            timings=None, outputs=None, attempt_log=None), True

    def by_idempotency_key(self, owner: str, key: str | None) -> JobRecord | None:
        """The job created with ``key`` by ``owner``, if any."""
        if key is None:
            return None
        query = select(jobs).where(jobs.c.owner == owner, jobs.c.idempotency_key == key)
        with self.engine.connect() as conn:
            row = conn.execute(query).first()
        return None if row is None else JobRecord.from_row(row)

    def get(self, job_id: str, owner: str | None = None) -> JobRecord | None:
        """The job, or None when it does not exist or ``owner`` does not own it."""
        query = select(jobs).where(jobs.c.id == job_id)
        if owner is not None:
            query = query.where(jobs.c.owner == owner)
        with self.engine.connect() as conn:
            row = conn.execute(query).first()
        return None if row is None else JobRecord.from_row(row)

    def page(self, owner: str | None, statuses: Sequence[str], *, limit: int,
             offset: int) -> tuple[list[JobRecord], int]:
        """A page of jobs, newest first, and the number of jobs matching."""
        where = []
        if owner is not None:
            where.append(jobs.c.owner == owner)
        if statuses:
            where.append(jobs.c.status.in_(list(statuses)))
        query = (select(jobs).where(*where).order_by(jobs.c.created.desc(), jobs.c.id)
                 .limit(limit).offset(offset))
        count = select(func.count()).select_from(jobs).where(*where)
        with self.engine.connect() as conn:
            rows = conn.execute(query).all()
            total = int(conn.execute(count).scalar_one())
        return [JobRecord.from_row(r) for r in rows], total

    def ids_with_status(self, status: str) -> list[str]:
        """Ids of every job in ``status``, oldest first."""
        query = select(jobs.c.id).where(jobs.c.status == status).order_by(jobs.c.created)
        with self.engine.connect() as conn:
            return [r[0] for r in conn.execute(query)]

    def active_jobs_using(self, mesh_id: str) -> int:
        """How many unfinished jobs (any owner) plan on ``mesh_id``."""
        query = select(func.count()).select_from(jobs).where(
            jobs.c.mesh_id == mesh_id, jobs.c.status.in_(ACTIVE))
        with self.engine.connect() as conn:
            return int(conn.execute(query).scalar_one())

    def active_count(self, owner: str) -> int:
        """How many jobs of ``owner`` are accepted or running."""
        with self.engine.connect() as conn:
            return int(conn.execute(_active_count_of(owner)).scalar_one())

    def _update(self, job_id: str, where: Sequence[Any], *,
                attempt: dict[str, Any] | None = None, **values: Any) -> bool:
        """The conditional UPDATE; ``attempt``: an entry appended to the attempt log."""
        values.setdefault("updated", time.time())
        statement = update(jobs).where(jobs.c.id == job_id, *where)
        with self._write_lock, self.engine.begin() as conn:
            if attempt is not None:  # read and extended in the same transaction
                logged = conn.execute(
                    select(jobs.c.attempt_log).where(jobs.c.id == job_id)).scalar()
                values["attempt_log"] = _json([*json.loads(logged or "[]"), attempt])
            return bool(conn.execute(statement.values(**values)).rowcount == 1)

    def claim(self, job_id: str, token: str, worker: str) -> bool:
        """``accepted -> running`` for the worker holding ``token``; False if not accepted."""
        now = time.time()
        return self._update(
            job_id, [jobs.c.status == ACCEPTED], status=RUNNING, worker_token=token,
            worker=worker, started=now, heartbeat=now, progress=0, message="starting",
            attempts=jobs.c.attempts + 1,
        )

    def heartbeat(self, job_id: str, token: str, *, progress: int | None = None,
                  message: str | None = None) -> bool:
        """Refresh the claim (and progress); False when the job was dismissed or taken."""
        values: dict[str, Any] = {"heartbeat": time.time()}
        if progress is not None:
            values["progress"] = progress
        if message is not None:
            values["message"] = message
        return self._update(job_id, [jobs.c.status == RUNNING, jobs.c.worker_token == token],
                            **values)

    def holds_claim(self, job_id: str, token: str) -> bool:
        """Whether ``token`` still runs ``job_id`` (a read: cheap enough to ask often)."""
        query = select(jobs.c.id).where(jobs.c.id == job_id, jobs.c.status == RUNNING,
                                        jobs.c.worker_token == token)
        with self.engine.connect() as conn:
            return conn.execute(query).first() is not None

    def finish(self, job_id: str, token: str, status: str, *, message: str,
               problem: dict[str, Any] | None = None, timings: dict[str, float] | None = None,
               outputs: dict[str, dict[str, Any]] | None = None,
               attempt: dict[str, Any] | None = None) -> bool:
        """``running -> successful|failed`` by the claim holder (``attempt``: its log entry)."""
        values: dict[str, Any] = {
            "status": status, "message": message, "finished": time.time(),
            "problem": _json(problem), "timings": _json(timings), "outputs": _json(outputs),
            "worker_token": None,
        }
        if status == SUCCESSFUL:
            values["progress"] = 100
        return self._update(job_id, [jobs.c.status == RUNNING, jobs.c.worker_token == token],
                            attempt=attempt, **values)

    def retry(self, job_id: str, token: str, *, message: str, attempt: dict[str, Any]) -> bool:
        """``running -> accepted`` by the claim holder whose attempt was killed from outside:
        the attempt counts (unlike :meth:`release`) and is logged; the caller enqueues."""
        return self._update(
            job_id, [jobs.c.status == RUNNING, jobs.c.worker_token == token],
            status=ACCEPTED, worker_token=None, progress=0, message=message, attempt=attempt)

    def release(self, job_id: str, token: str) -> bool:
        """``running -> accepted`` when a worker is stopped: the run does not count."""
        return self._update(
            job_id, [jobs.c.status == RUNNING, jobs.c.worker_token == token],
            status=ACCEPTED, worker_token=None, progress=0, message="queued again (worker stopped)",
            attempts=jobs.c.attempts - 1,
        )

    def dismiss(self, job_id: str) -> bool:
        """``accepted|running -> dismissed``; a running worker sees it and stops."""
        return self._update(
            job_id, [jobs.c.status.in_(ACTIVE)], status=DISMISSED, finished=time.time(),
            message="dismissed", worker_token=None,
        )

    def delete(self, job_id: str) -> bool:
        """Remove a finished job's row."""
        statement = delete(jobs).where(jobs.c.id == job_id, jobs.c.status.in_(FINISHED))
        with self.engine.begin() as conn:
            return bool(conn.execute(statement).rowcount == 1)

    def stale_running(self, heartbeat_before: float) -> list[JobRecord]:
        """Running jobs whose last heartbeat is older than ``heartbeat_before``."""
        query = select(jobs).where(jobs.c.status == RUNNING,
                                   jobs.c.heartbeat < heartbeat_before)
        with self.engine.connect() as conn:
            return [JobRecord.from_row(r) for r in conn.execute(query)]

    def requeue_lost(self, job: JobRecord) -> bool:
        """A stale claim back to accepted, unless its worker woke up meanwhile."""
        return self._update(
            job.id, [jobs.c.status == RUNNING, jobs.c.worker_token == job.worker_token,
                     jobs.c.heartbeat == job.heartbeat],
            status=ACCEPTED, worker_token=None, progress=0,
            message=f"queued again: the worker was lost (attempt {job.attempts})",
            attempt=attempt_entry(job, "worker lost", stage=_stage_of(job.message)),
        )

    def fail_lost(self, job: JobRecord, problem: dict[str, Any]) -> bool:
        """A stale claim after its last attempt: failed, "worker lost"."""
        return self._update(
            job.id, [jobs.c.status == RUNNING, jobs.c.worker_token == job.worker_token,
                     jobs.c.heartbeat == job.heartbeat],
            status=FAILED, worker_token=None, finished=time.time(),
            message=problem["detail"], problem=_json(problem),
            attempt=attempt_entry(job, "worker lost", stage=_stage_of(job.message)),
        )
