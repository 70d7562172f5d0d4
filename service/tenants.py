"""Fair tenants: a cap on the jobs each API key has queued or running.

The queue serves jobs in the order they came, so a platform that submits a batch of 500
plans would hold every other key's work behind its own for hours. Each key (each owner; the
one anonymous owner when no keys are configured) may have at most
``SCANPLAN_MAX_ACTIVE_JOBS_PER_KEY`` jobs accepted or running; a submission past that
answers 429 with ``Retry-After`` (``SCANPLAN_BUSY_RETRY_AFTER_S``) and a problem document,
and stores nothing. An Idempotency-Key replay of a job already accepted is not a new job
and is never refused.

The count is taken after the new row is inserted, and the row is withdrawn when the count
is over the cap: of two submissions racing for the last place, the one that counts last
sees both, so the cap holds without a lock across API processes (at worst both are refused
and the client retries).
"""

from __future__ import annotations

from service.config import Settings
from service.job_store import JobRecord, JobStore
from service.problems import TooManyJobsError


def admit(jobs: JobStore, job: JobRecord, settings: Settings) -> None:
    """Keep the just-created ``job``, or withdraw it and raise :class:`TooManyJobsError`."""
    cap = settings.max_active_jobs_per_key
    if cap == 0:
        return
    active = jobs.active_count(job.owner)
    if active <= cap:
        return
    jobs.withdraw(job.id)
    raise TooManyJobsError(
        f"this API key has {active - 1} jobs queued or running, the most one key may have "
        f"({cap}, SCANPLAN_MAX_ACTIVE_JOBS_PER_KEY); submit again once some have finished "
        f"(Retry-After: {settings.busy_retry_after_s} s), or DELETE jobs you no longer need",
        retry_after_s=settings.busy_retry_after_s)
