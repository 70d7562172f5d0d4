"""Fair tenants: each API key's jobs queued or running are capped (a real SQLite job table)."""

from __future__ import annotations

import threading
import uuid
from pathlib import Path

import pytest
from sqlalchemy.exc import OperationalError

from service.config import Settings
from service.database import make_engine
from service.job_store import JobStore
from service.problems import TooManyJobsError
from service.tenants import create_admitted
from tests.service.conftest import InlineQueue, make_client, submit, upload

ALICE, BOB = {"Authorization": "Bearer alice-key"}, {"Authorization": "Bearer bob-key"}


def test_a_key_past_its_cap_gets_429_and_other_keys_go_on(
        tmp_path: Path, hall_bytes: bytes) -> None:
    queue = InlineQueue(hold=True)  # nothing runs: every job stays queued
    with make_client(tmp_path, queue, api_keys=["alice-key", "bob-key"],
                     max_active_jobs_per_key=2, busy_retry_after_s=45) as client:
        alice_mesh = upload(client, hall_bytes, **ALICE).json()["id"]
        bob_mesh = upload(client, hall_bytes, **BOB).json()["id"]
        first, second = (submit(client, alice_mesh, {}, **ALICE).json()["jobID"]
                         for _ in range(2))
        refused = submit(client, alice_mesh, {}, **ALICE)
        assert refused.status_code == 429, refused.text
        assert refused.headers["retry-after"] == "45"
        assert refused.headers["content-type"] == "application/problem+json"
        problem = refused.json()
        assert problem["type"].endswith("too-many-jobs") and problem["status"] == 429
        assert "2 jobs queued or running" in problem["detail"]
        assert "SCANPLAN_MAX_ACTIVE_JOBS_PER_KEY" in problem["detail"]
        # the refusal stored nothing and queued nothing
        assert client.get("/jobs", headers=ALICE).json()["numberMatched"] == 2
        assert queue.enqueued == [first, second]
        # another key is not held up by alice's batch
        assert submit(client, bob_mesh, {}, **BOB).status_code == 201
        # refused with an Idempotency-Key too, until one of her jobs is gone
        body: dict[str, object] = {"max_edge_m": None}
        assert submit(client, alice_mesh, body, **ALICE, **{"Idempotency-Key": "k"}
                      ).status_code == 429
        client.delete(f"/jobs/{first}", headers=ALICE)
        again = submit(client, alice_mesh, body, **ALICE, **{"Idempotency-Key": "k"})
        assert again.status_code == 201
        # she is at her cap again; a replay of an accepted job is no new job: not refused
        replayed = submit(client, alice_mesh, body, **ALICE, **{"Idempotency-Key": "k"})
        assert replayed.status_code == 200
        assert replayed.json()["jobID"] == again.json()["jobID"]


def _reachable_postgres() -> str | None:
    """The test PostgreSQL server's URL when one answers (CI runs one), else None."""
    url = "postgresql+psycopg://postgres@127.0.0.1:5432/test"
    try:
        with make_engine(url).connect():
            return url
    except OperationalError:
        return None


@pytest.mark.parametrize("database", ["sqlite", "postgresql"])
def test_the_cap_holds_when_submissions_race(tmp_path: Path, database: str) -> None:
    url = f"sqlite:///{tmp_path / 'jobs.db'}" if database == "sqlite" else _reachable_postgres()
    if url is None:
        pytest.skip("no PostgreSQL server answers on 127.0.0.1:5432")
    settings = Settings(data_dir=tmp_path, workers=1, max_active_jobs_per_key=3)
    # three stores on their own engines: three API processes sharing one job table
    stores = [JobStore(make_engine(url)) for _ in range(3)]
    owner = f"alice-{uuid.uuid4().hex}"  # a PostgreSQL table outlives the test
    admitted, refused = [], []
    start = threading.Barrier(12)

    def submit_one(jobs: JobStore) -> None:
        start.wait()
        try:
            job, _ = create_admitted(jobs, settings, owner, "m" * 64, {})
            admitted.append(job.id)
        except TooManyJobsError:
            refused.append("refused")

    threads = [threading.Thread(target=submit_one, args=(stores[n % 3],)) for n in range(12)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    # the three places are taken, no more, and a refusal leaves no row behind
    assert len(admitted) == 3 and len(refused) == 9
    assert stores[0].active_count(owner) == 3
