"""The queue: huey carries job ids from the API to the workers, nothing else.

Embedded default: ``SqliteHuey`` in the data directory. Scale-out: ``RedisHuey`` at
``SCANPLAN_QUEUE_URL``. The queue may lose or repeat an id (a worker killed mid-task, a
re-enqueue on restart); the job table's conditional claim makes a repeat a no-op and the
reaper re-enqueues what was lost.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from huey import Huey, RedisHuey, SqliteHuey

from service.config import Settings

TASK_NAME = "scanplan.run_job"


class JobQueue(Protocol):
    """What the API and the reaper need from a queue."""

    def enqueue(self, job_id: str) -> None:
        """Ask some worker to run ``job_id``."""

    def ping(self) -> None:
        """Raise when the queue is unreachable."""


def make_huey(settings: Settings) -> Huey:
    """The huey instance the settings describe (no task registered yet)."""
    if settings.queue_url:
        return RedisHuey("scanplan", url=settings.queue_url, results=False)
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    # fsync=False: the job table is the truth and the reaper re-enqueues accepted jobs, so
    # the queue need not wait for the disk on every submission
    return SqliteHuey("scanplan", filename=str(settings.data_dir / "queue.db"), results=False,
                      fsync=False)


class HueyQueue:
    """A :class:`JobQueue` over huey with the one task, ``scanplan.run_job(job_id)``."""

    def __init__(self, huey: Huey, run: Callable[[str], None] | None = None) -> None:
        self.huey = huey
        body = run or _never_here  # the API only enqueues: its body is never called there

        def run_job(job_id: str) -> None:
            body(job_id)

        # huey names a task after its function's module: the same here in every process
        self._task: Any = huey.task(name=TASK_NAME)(run_job)

    def enqueue(self, job_id: str) -> None:
        self._task(job_id)

    def ping(self) -> None:
        storage: Any = self.huey.storage
        if hasattr(storage, "conn") and hasattr(storage.conn, "ping"):
            storage.conn.ping()  # Redis
        else:
            self.huey.pending_count()  # SQLite: a query on the queue table


def _never_here(job_id: str) -> None:
    raise RuntimeError(f"job {job_id} reached a process that only enqueues")
