"""Guarded jobs: refused before queueing, cancelled in every stage, failed when out of memory.

The worker code runs for real (:func:`execute_job`, its child process, SQLite); only the
queue is the inline one of conftest, held so that the test decides when a job runs.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.e2e.service_process import child_pids
from tests.service.conftest import InlineQueue, make_client, submit, upload


@pytest.fixture
def held(tmp_path: Path) -> Any:
    queue = InlineQueue(hold=True)
    with make_client(tmp_path, queue, api_keys=[], cancel_poll_interval_s=0.1,
                     progress_interval_s=0.1, job_memory_limit_mb=4096) as client:
        yield client, queue


@pytest.mark.parametrize(("parameters", "refused"), [
    ({"max_edge_m": 0.001}, "max_edge_m"),        # ~3e8 faces after remeshing
    ({"max_edge_m": None, "grid_spacing_m": 0.001}, "grid_spacing_m"),  # ~2e7 grid points
    ({"max_edge_m": 0.01, "grid_spacing_m": 0.02}, "grid_spacing_m"),  # ~1.5e11 pairs
])
def test_oversized_plans_are_refused_before_queueing(
        tmp_path: Path, hall_bytes: bytes, parameters: dict[str, Any], refused: str) -> None:
    queue = InlineQueue(hold=True)
    with make_client(tmp_path, queue, api_keys=[], max_candidate_face_pairs=1e10) as client:
        mesh = upload(client, hall_bytes).json()["id"]
        answer = submit(client, mesh, parameters)
        assert answer.status_code == 422, answer.text
        assert answer.headers["content-type"] == "application/problem+json"
        problem = answer.json()
        assert problem["parameter"] == refused
        assert problem["type"].endswith("job-too-large")
        assert "about" in problem["detail"] and "SCANPLAN_" in problem["detail"]
        assert queue.enqueued == [] and client.get("/jobs").json()["numberMatched"] == 0


def test_explicit_candidates_are_capped(tmp_path: Path, hall_bytes: bytes) -> None:
    queue = InlineQueue(hold=True)
    with make_client(tmp_path, queue, api_keys=[], max_candidates=10) as client:
        mesh = upload(client, hall_bytes).json()["id"]
        answer = submit(client, mesh, {"candidates": [[1.0, 1.0, 1.5]] * 11})
        assert answer.status_code == 422 and answer.json()["parameter"] == "candidates"
        assert submit(client, mesh, {"candidates": [[1.0, 1.0, 1.5]] * 10}).status_code == 201


# (stage the job is stopped in, parameters that keep it there for seconds); the reading
# stage is held by the model, FZK-Haus's IFC (its geometry takes 1 - 3 s to read), as
# reading splits no face (the plan splits what it needs after the candidates)
STAGES = [
    ("reading", {}),
    ("candidates", {"max_edge_m": None, "grid_spacing_m": 0.01}),  # 200 k grid points
    ("visibility", {"max_edge_m": 0.05, "grid_spacing_m": 0.25}),
    ("selection", {"max_edge_m": 0.1, "grid_spacing_m": 0.25, "method": "optimal",
                   "coverage_goal": 1.0, "optimal_time_limit_s": 600}),
]


@pytest.mark.parametrize(("stage", "parameters"), STAGES, ids=[s for s, _ in STAGES])
def test_delete_frees_the_worker_within_2_s_in_every_stage(
        held: Any, hall_bytes: bytes, scenes_dir: Path, stage: str,
        parameters: dict[str, Any]) -> None:
    client, queue = held
    if stage == "reading":
        answer = client.post("/meshes", files={"file": (
            "AC20-FZK-Haus.ifc", (scenes_dir / "AC20-FZK-Haus.ifc").read_bytes())})
    else:
        answer = upload(client, hall_bytes)
    mesh = answer.json()["id"]
    job_id = submit(client, mesh, parameters).json()["jobID"]
    # children this test process had before (another test's helpers, such as the resource
    # tracker a Dask LocalCluster's processes leave behind) are not the job's
    before = set(child_pids(_pid()))
    worker = threading.Thread(target=_run, args=(queue, job_id))
    worker.start()
    try:
        deadline = time.monotonic() + 60
        while not client.get(f"/jobs/{job_id}").json()["message"].startswith(stage):
            assert worker.is_alive(), client.get(f"/jobs/{job_id}").json()
            assert time.monotonic() < deadline, f"the job never reached {stage}"
            time.sleep(0.02)
        children = [c for c in child_pids(_pid()) if c not in before]
        assert len(children) == 1, "the plan should run in one child process"
        assert _address_space_limit_mb(children[0]) == 4096, "the child runs unlimited"
        assert client.delete(f"/jobs/{job_id}").json()["status"] == "dismissed"
        worker.join(2.0)
        assert not worker.is_alive(), f"the worker was still busy 2 s after DELETE in {stage}"
        assert [c for c in child_pids(_pid()) if c not in before] == [], \
            "the planning process outlived the DELETE"
    finally:
        worker.join()
    assert client.get(f"/jobs/{job_id}").status_code == 404  # dismissed: gone
    assert queue.ctx.jobs.get(job_id).status == "dismissed"
    assert not list((queue.ctx.results_root).glob(f"*{job_id}*")), "files left behind"


def test_a_job_past_the_memory_limit_fails_and_the_worker_goes_on(
        tmp_path: Path, hall_bytes: bytes, hall_parameters: dict[str, Any]) -> None:
    # The child inherits this process's address space and may map 1.5 GiB more: enough for
    # hall-small's plan (imports, Embree's and the pools' threads, the table), not for the
    # grid of a 0.2 mm spacing (500 M points, arrays of 4 GB at once). The grid and pair
    # guards are raised so that the job reaches the planner and fails on memory there.
    limit_mb = _address_space_mb() + 1536
    queue = InlineQueue()
    with make_client(tmp_path, queue, api_keys=[], job_memory_limit_mb=limit_mb,
                     max_grid_points=10**12, max_candidate_face_pairs=1e16) as client:
        mesh = upload(client, hall_bytes).json()["id"]
        job_id = submit(client, mesh, {"max_edge_m": None, "grid_spacing_m": 0.0002}).json()[
            "jobID"]
        status = client.get(f"/jobs/{job_id}").json()
        assert status["status"] == "failed", status
        assert status["message"].startswith("out of memory"), status["message"]
        assert status["problem"]["type"].endswith("out-of-memory")
        detail = status["problem"]["detail"]
        assert "SCANPLAN_JOB_MEMORY_LIMIT_MB" in detail
        assert f"limit of {limit_mb:,} MiB" in detail and "MiB resident" in detail, detail
        # out of memory is not retried: a re-run would end the same
        [attempt] = status["attempt_log"]
        assert status["attempts"] == 1 and attempt["outcome"] == "out of memory"
        assert attempt["memory_limit_mib"] == limit_mb and attempt["peak_rss_mib"] > 0
        assert queue.enqueued == [job_id]
        results = client.get(f"/jobs/{job_id}/results")
        assert results.status_code == 422
        assert results.headers["content-type"] == "application/problem+json"
        # the same worker plans the next job
        after = submit(client, mesh, hall_parameters).json()["jobID"]
        assert client.get(f"/jobs/{after}").json()["status"] == "successful"


def _run(queue: InlineQueue, job_id: str) -> None:
    from service.worker import execute_job

    assert queue.ctx is not None
    execute_job(queue.ctx, job_id)


def _pid() -> int:
    import os

    return os.getpid()


def _address_space_limit_mb(pid: int) -> int | None:
    """The RLIMIT_AS of ``pid`` in MiB (None: unlimited), from /proc/<pid>/limits."""
    for line in Path(f"/proc/{pid}/limits").read_text().splitlines():
        if line.startswith("Max address space"):
            soft = line.split()[3]
            return None if soft == "unlimited" else int(soft) // 2**20
    raise AssertionError("no address space line in /proc/<pid>/limits")


def _address_space_mb() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmSize:"):
            return int(line.split()[1]) // 1024
    raise AssertionError("no VmSize in /proc/self/status")


def test_planning_errors_still_fail_the_job_with_their_problem(
        client: TestClient, hall_bytes: bytes) -> None:
    mesh = upload(client, hall_bytes).json()["id"]
    job_id = submit(client, mesh, {"max_edge_m": None,
                                   "candidates": [[100.0, 100.0, 100.0]]}).json()["jobID"]
    status = client.get(f"/jobs/{job_id}").json()
    assert status["status"] == "failed"
    assert status["problem"]["status"] == 422
    assert status["problem"]["instance"] == f"/jobs/{job_id}"
