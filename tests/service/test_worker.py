"""The job table's state machine and the reaper, on a real SQLite file."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from service.config import Settings
from service.job_store import JobStore
from service.worker import Reaper, build_context
from tests.e2e.service_process import live_pids
from tests.service.conftest import InlineQueue


def _store(tmp_path: Path, **overrides: object) -> tuple[JobStore, InlineQueue, Settings]:
    settings = Settings(data_dir=tmp_path, workers=1, **overrides)  # type: ignore[arg-type]
    queue = InlineQueue(hold=True)
    return build_context(settings, queue).jobs, queue, settings


def test_claim_is_exclusive_and_finish_needs_the_claim(tmp_path: Path) -> None:
    jobs, _, _ = _store(tmp_path)
    job, created = jobs.create("me", "m" * 64, {})
    assert created
    assert jobs.claim(job.id, "a", "host:1")
    assert not jobs.claim(job.id, "b", "host:2")
    assert not jobs.finish(job.id, "b", "successful", message="done")
    assert jobs.heartbeat(job.id, "a", progress=50, message="visibility")
    assert jobs.dismiss(job.id)
    assert not jobs.heartbeat(job.id, "a"), "a dismissed job must stop its worker"


def test_reaper_requeues_then_fails_as_worker_lost(tmp_path: Path) -> None:
    jobs, queue, settings = _store(tmp_path, stale_after_s=0.01, max_attempts=2)
    reaper = Reaper(jobs, queue, settings)
    job, _ = jobs.create("me", "m" * 64, {})
    for attempt in (1, 2):
        assert jobs.claim(job.id, f"t{attempt}", "host:1")
        time.sleep(0.05)  # no heartbeat: the worker "died"
        assert reaper.run_once() == 1
    final = jobs.get(job.id)
    assert final is not None
    assert queue.enqueued == [job.id]
    assert final.status == "failed" and "worker lost" in final.message
    assert final.problem is not None and final.problem["type"].endswith("worker-lost")
    assert final.attempt_log is not None
    assert [(a["attempt"], a["outcome"]) for a in final.attempt_log] == [
        (1, "worker lost"), (2, "worker lost")]


def test_release_returns_the_job_without_using_an_attempt(tmp_path: Path) -> None:
    jobs, queue, settings = _store(tmp_path)
    job, _ = jobs.create("me", "m" * 64, {})
    assert jobs.claim(job.id, "t", "host:1")
    assert jobs.release(job.id, "t")
    again = jobs.get(job.id)
    assert again is not None and again.status == "accepted" and again.attempts == 0
    assert Reaper(jobs, queue, settings).requeue_accepted() == 1


def test_a_job_table_of_an_older_version_gains_the_attempt_log(tmp_path: Path) -> None:
    import sqlite3

    from service.database import jobs as table

    old_columns = [c for c in table.columns if c.name != "attempt_log"]
    with sqlite3.connect(tmp_path / "jobs.db") as db:  # the table as the last version made it
        db.execute(f"CREATE TABLE jobs ({', '.join(c.name for c in old_columns)})")
        db.execute("INSERT INTO jobs (id, owner, mesh_id, parameters, status, progress, "
                   "message, created, updated, attempts) VALUES ('old', 'me', 'm', '{}', "
                   "'successful', 100, 'done', 1, 1, 1)")
    jobs, _, _ = _store(tmp_path)
    old = jobs.get("old")
    assert old is not None and old.status == "successful" and old.attempt_log is None
    job, _ = jobs.create("me", "m" * 64, {})
    assert jobs.claim(job.id, "t", "host:1")
    assert jobs.finish(job.id, "t", "successful", message="done",
                       attempt={"attempt": 1, "outcome": "successful"})
    assert (jobs.get(job.id) or old).attempt_log == [{"attempt": 1, "outcome": "successful"}]


def test_a_failed_warm_up_leaves_the_consumer_to_start_its_workers(
        monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    """The warm-up before huey forks is a head start only: if it fails (another numba, a
    module that cannot be imported), the consumer logs it and goes on, and each job loads
    what it needs itself."""
    import gc

    import planner.__main__
    from service.worker import _warm_up

    def broken() -> tuple[int, int]:
        raise RuntimeError("numba's cache is not what the warm-up knows")

    monkeypatch.setattr(planner.__main__, "warm_up", broken)
    frozen = gc.get_freeze_count()
    with caplog.at_level("ERROR", logger="scanplan.worker"):
        _warm_up()  # returns: run_consumer goes on to fork the workers
    assert "warm-up failed" in caplog.text
    assert "numba's cache is not what the warm-up knows" in caplog.text
    assert gc.get_freeze_count() == frozen  # nothing frozen for a warm-up that did not happen


def _consumer_signalled_as_its_workers_start(data_dir: Path, pid_file: Path) -> None:
    """The consumer of a fresh service, sent SIGTERM by itself right after huey has forked
    its last worker and before huey's own start sets its signal handlers: the moment a
    ``scanplan serve`` killed as its workers start reaches the consumer (PDEATHSIG)."""
    import os
    import signal

    from huey.consumer import ProcessEnvironment

    from service.worker import run_consumer

    create_process = ProcessEnvironment.create_process

    def create(self: ProcessEnvironment, runnable: object, name: str) -> object:
        process = create_process(self, runnable, name)
        start = process.start

        def started() -> None:
            start()
            with pid_file.open("a") as handle:
                handle.write(f"{process.pid}\n")
            if name == "Worker-2":
                os.kill(os.getpid(), signal.SIGTERM)

        process.start = started
        return process

    ProcessEnvironment.create_process = create
    run_consumer(Settings(data_dir=data_dir, workers=2, warm_up=False), with_reaper=False)


def test_a_consumer_stopped_as_its_workers_start_stops_them(tmp_path: Path) -> None:
    """No worker outlives its consumer, even when the consumer is told to stop while huey
    is still starting them."""
    import multiprocessing
    import os

    pid_file = tmp_path / "pids"
    consumer = multiprocessing.get_context("fork").Process(
        target=_consumer_signalled_as_its_workers_start, args=(tmp_path / "data", pid_file))
    consumer.start()
    consumer.join(30)
    assert consumer.exitcode is not None, "the consumer did not stop"
    started = [int(line) for line in pid_file.read_text().split()]
    assert len(started) == 3  # the scheduler and the two workers
    deadline = time.monotonic() + 20
    alive = started
    while alive and time.monotonic() < deadline:
        time.sleep(0.2)
        alive = live_pids(started)
    for pid in alive:
        os.kill(pid, 9)  # not left behind by a failing test
    assert alive == [], "worker processes outlived their consumer"
