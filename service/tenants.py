"""Fair tenants: a cap on the jobs each API key has queued or running.

The queue serves jobs in the order they came, so a platform that submits a batch of 500
plans would hold every other key's work behind its own for hours. Each key (each owner; the
one anonymous owner when no keys are configured) may have at most
``SCANPLAN_MAX_ACTIVE_JOBS_PER_KEY`` jobs accepted or running; a submission past that
answers 429 with ``Retry-After`` (``SCANPLAN_BUSY_RETRY_AFTER_S``) and a problem document,
and stores nothing. An Idempotency-Key replay of a job already accepted is not a new job
and is never refused.

The count is taken inside the new row's insert transaction (:meth:`JobStore.create`), so
submissions racing for the last places take exactly those places, from any number of API
processes, and a refused one leaves no row behind.
"""

from __future__ import annotations

from typing import Any

from service.config import Settings
from service.job_store import JobRecord, JobStore, OverCapError
from service.problems import TooManyJobsError


def create_admitted(jobs: JobStore, settings: Settings, owner: str, mesh_id: str,
                    parameters: dict[str, Any], **keys: str | None) -> tuple[JobRecord, bool]:
    """:meth:`JobStore.create` under the owner's cap; raise :class:`TooManyJobsError` past it.

    ``keys``: ``idempotency_key`` and ``request_hash``. Returns the job and whether it was
    created now (False: the Idempotency-Key's earlier job).
    """
    cap = settings.max_active_jobs_per_key
    try:
        return jobs.create(owner, mesh_id, parameters, active_cap=cap, **keys)
    except OverCapError as exc:
        raise TooManyJobsError(
            f"this API key has {exc.active} jobs queued or running, the most one key may "
            f"have ({cap}, SCANPLAN_MAX_ACTIVE_JOBS_PER_KEY); submit again once some have "
            f"finished (Retry-After: {settings.busy_retry_after_s} s), or DELETE jobs you "
            "no longer need", retry_after_s=settings.busy_retry_after_s) from exc
