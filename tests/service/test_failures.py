"""Failures that say what happened: out of memory versus a plan killed from outside.

The planning process is a real forked child (:mod:`service.plan_process`); the job table is
a real SQLite file; the queue is the inline one of conftest, held so that the test decides
when a job runs and can kill its child meanwhile.
"""

from __future__ import annotations

import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from service.plan_process import ChildLimits, PlanProcessError, Progress, run_in_child
from service.worker import execute_job
from tests.e2e.service_process import child_pids
from tests.service.conftest import InlineQueue, make_client, submit, upload


def _address_space_mb() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmSize:"):
            return int(line.split()[1]) // 1024
    raise AssertionError("no VmSize in /proc/self/status")


def _run(work: Any, limit_mb: int | None) -> Any:
    return run_in_child(work, limits=ChildLimits(
        memory_bytes=None if limit_mb is None else limit_mb * 2**20),
        on_progress=lambda stage, fraction: False, should_stop=lambda: False,
        poll_interval_s=0.02, describe_error=lambda exc: {"detail": str(exc)})


def _killed_in(stage: str, grab_mb: int) -> Any:
    def work(progress: Progress) -> None:
        progress(stage, 0.0)
        held = bytearray(grab_mb * 2**20)  # address space, zero pages
        time.sleep(0.3)  # the worker reads the peak meanwhile
        os.kill(os.getpid(), signal.SIGKILL)
        del held
    return work


def test_a_kill_far_below_the_limit_is_from_outside() -> None:
    limit_mb = _address_space_mb() + 4096
    with pytest.raises(PlanProcessError) as caught:
        _run(_killed_in("visibility", grab_mb=16), limit_mb)
    end = caught.value.end
    assert (end.killed, end.out_of_memory, end.signal, end.stage) == (
        True, False, "SIGKILL", "visibility")
    assert end.peak_rss_mib is not None and 0 < end.peak_rss_mib < limit_mb
    assert end.memory_limit_mib == limit_mb
    message = str(caught.value)
    assert "SIGKILL" in message and "visibility" in message and "from outside" in message
    assert "out of memory" not in message


def test_a_death_with_the_peak_near_the_limit_is_out_of_memory() -> None:
    """What the host's OOM killer or an allocator refused by RLIMIT_AS leaves behind."""
    limit_mb = _address_space_mb() + 512
    with pytest.raises(PlanProcessError) as caught:
        _run(_killed_in("candidates", grab_mb=480), limit_mb)
    end = caught.value.end
    assert end.out_of_memory and not end.killed and end.signal == "SIGKILL"
    assert end.peak_address_space_mib is not None
    assert end.peak_address_space_mib >= 0.9 * limit_mb
    message = str(caught.value)
    assert message.startswith("out of memory") and f"{limit_mb:,} MiB" in message
    assert "peak" in message and "candidates" in message


@pytest.fixture
def held(tmp_path: Path, hall_bytes: bytes, hall_parameters: dict[str, Any]) -> Any:
    def start(max_attempts: int) -> tuple[Any, InlineQueue, str]:
        queue = InlineQueue(hold=True)
        client = make_client(tmp_path / str(max_attempts), queue, api_keys=[],
                             max_attempts=max_attempts, job_memory_limit_mb=0,
                             cancel_poll_interval_s=0.05)
        client.__enter__()
        mesh = upload(client, hall_bytes).json()["id"]
        return client, queue, submit(client, mesh, hall_parameters).json()["jobID"]
    return start


def _run_and_kill_its_child(queue: InlineQueue) -> None:
    """Run the next queued job in a thread and SIGKILL its planning process once it runs."""
    assert queue.ctx is not None
    job_id = queue.enqueued[-1]
    worker = threading.Thread(target=execute_job, args=(queue.ctx, job_id))
    before = set(child_pids(os.getpid()))
    worker.start()
    deadline = time.monotonic() + 60
    while not (child := set(child_pids(os.getpid())) - before):
        assert worker.is_alive() and time.monotonic() < deadline, "no planning process"
        time.sleep(0.005)
    os.kill(child.pop(), signal.SIGKILL)
    worker.join(60)
    assert not worker.is_alive()


def test_a_killed_plan_runs_again_and_succeeds(held: Any) -> None:
    client, queue, job_id = held(max_attempts=2)
    _run_and_kill_its_child(queue)
    status = client.get(f"/jobs/{job_id}").json()
    assert status["status"] == "accepted", status
    assert "queued again" in status["message"] and "SIGKILL" in status["message"]
    assert queue.enqueued == [job_id, job_id], "the job must go back to the queue"
    [killed] = status["attempt_log"]
    assert killed["outcome"] == "killed" and killed["signal"] == "SIGKILL"
    assert killed["attempt"] == 1 and killed["peak_rss_mib"] > 0 and killed["finished"]
    assert queue.ctx is not None
    execute_job(queue.ctx, job_id)  # the next worker takes it
    status = client.get(f"/jobs/{job_id}").json()
    assert status["status"] == "successful" and status["attempts"] == 2, status
    assert [a["outcome"] for a in status["attempt_log"]] == ["killed", "successful"]
    assert status["attempt_log"][1]["peak_rss_mib"] > 0  # for sizing the memory limit
    client.__exit__(None, None, None)


def test_a_plan_killed_on_its_last_attempt_fails_naming_signal_stage_and_tries(
        held: Any) -> None:
    client, queue, job_id = held(max_attempts=1)
    _run_and_kill_its_child(queue)
    status = client.get(f"/jobs/{job_id}").json()
    assert status["status"] == "failed", status
    problem = status["problem"]
    assert problem["type"].endswith("plan-killed")
    assert "SIGKILL" in problem["detail"] and "attempt 1 of 1" in problem["detail"]
    assert "stage" in problem["detail"] and "out of memory" not in problem["detail"]
    assert queue.enqueued == [job_id], "no retry after the last attempt"
    assert [a["outcome"] for a in status["attempt_log"]] == ["killed"]
    # its results: the same problem, with a 4xx status (the request is sound, the job's
    # state keeps the results from it), never a server error
    results = client.get(f"/jobs/{job_id}/results")
    assert results.status_code == 409, results.text
    assert results.headers["content-type"].startswith("application/problem+json")
    answer = results.json()
    assert answer["status"] == 409 and answer["type"] == problem["type"]
    assert answer["detail"] == problem["detail"]
    client.__exit__(None, None, None)


def _job_endpoints_answer_no_5xx(client: Any, job_id: str) -> dict[str, int]:
    """Every ``/jobs/{id}`` request a client makes; the status of each (none may be 5xx)."""
    answers = {path: client.get(path).status_code for path in (
        "/jobs", f"/jobs/{job_id}", f"/jobs/{job_id}/results",
        f"/jobs/{job_id}/results/plan.json", f"/jobs/{job_id}/callbacks")}
    assert all(code < 500 for code in answers.values()), answers
    return answers


def test_the_results_of_a_job_failed_by_the_service_are_its_problem_not_a_5xx(
        held: Any) -> None:
    """A job whose plan failed for the service's own reason (here its planning process was
    killed on its last attempt; an unexpected error stores a 500 problem the same way):
    ``GET /jobs/{id}/results`` answered 500 with the stored problem. It answers 409 with that
    problem's type and detail, and no job endpoint answers 5xx in any state of the job."""
    client, queue, job_id = held(max_attempts=1)
    assert _job_endpoints_answer_no_5xx(client, job_id)[f"/jobs/{job_id}/results"] == 404
    _run_and_kill_its_child(queue)
    assert client.get(f"/jobs/{job_id}").json()["status"] == "failed"
    results = client.get(f"/jobs/{job_id}/results")
    assert results.status_code == 409, results.text
    assert results.headers["content-type"].startswith("application/problem+json")
    problem = results.json()
    assert problem["status"] == 409 and problem["job_status"] == 500
    assert problem["type"].endswith("plan-killed") and "SIGKILL" in problem["detail"]
    _job_endpoints_answer_no_5xx(client, job_id)
    assert client.delete(f"/jobs/{job_id}").status_code == 200
    assert _job_endpoints_answer_no_5xx(client, job_id)[f"/jobs/{job_id}"] == 404
    assert client.delete(f"/jobs/{job_id}").status_code == 404
    client.__exit__(None, None, None)


def test_a_job_deleted_while_its_plan_process_runs_answers_no_5xx(held: Any) -> None:
    client, queue, job_id = held(max_attempts=1)
    assert queue.ctx is not None
    worker = threading.Thread(target=execute_job, args=(queue.ctx, job_id))
    before = set(child_pids(os.getpid()))
    worker.start()
    deadline = time.monotonic() + 60
    while not set(child_pids(os.getpid())) - before:
        assert worker.is_alive() and time.monotonic() < deadline, "no planning process"
        time.sleep(0.005)
    _job_endpoints_answer_no_5xx(client, job_id)  # running
    assert client.delete(f"/jobs/{job_id}").json()["status"] == "dismissed"
    _job_endpoints_answer_no_5xx(client, job_id)  # dismissed, its process still running
    worker.join(60)
    assert not worker.is_alive()
    assert _job_endpoints_answer_no_5xx(client, job_id)[f"/jobs/{job_id}/results"] == 404
    client.__exit__(None, None, None)
