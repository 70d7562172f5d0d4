"""The real thing: ``scanplan serve`` with worker processes, killed, cancelled, restarted."""

from __future__ import annotations

import csv
import os
import signal
import time
from pathlib import Path
from typing import Any

import httpx
import pytest

from planner.io.readers import read_scene
from planner.outputs.report import write_outputs
from planner.parameters import PlanSpec
from planner.pipeline import plan
from planner.version import __version__
from tests.data_files import scenes_layout
from tests.e2e.service_process import Service, child_pids, wait_for

FINISHED = ("successful", "failed", "dismissed")


def _scene(name: str) -> Path:
    return scenes_layout() / name


def _parameters(folder: Path) -> dict[str, Any]:
    with (folder / "candidates.csv").open() as handle:
        candidates = [[float(r["x"]), float(r["y"]), float(r["z"])]
                      for r in csv.DictReader(handle)]
    return {"max_edge_m": None, "candidates": candidates}


def _submit(client: httpx.Client, folder: Path, **extra: Any) -> str:
    mesh = client.post("/meshes?filename=hall.obj", content=(folder / "hall.obj").read_bytes(),
                       headers={"content-type": "application/octet-stream"})
    assert mesh.status_code in (200, 201), mesh.text
    body = {"inputs": {"mesh": mesh.json()["id"], "parameters": {**_parameters(folder),
                                                                 **extra}}}
    job = client.post("/processes/scan-plan/execution", json=body)
    assert job.status_code == 201, job.text
    assert job.headers["location"] == f"/jobs/{job.json()['jobID']}"
    return str(job.json()["jobID"])


@pytest.fixture
def service(tmp_path: Path) -> Any:
    """A service of the test's own: for the tests that kill its workers."""
    running = Service(tmp_path / "data", workers=2).start()
    yield running
    running.stop()
    running.kill_leftovers()


@pytest.fixture(scope="module")
def shared_service(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """One service for the tests that leave it as they found it: each waits for its own
    job to end, none kills a process of the service."""
    running = Service(tmp_path_factory.mktemp("shared") / "data", workers=2).start()
    yield running
    running.stop()
    running.kill_leftovers()


@pytest.mark.parametrize("stop_signal", [signal.SIGTERM, signal.SIGKILL])
def test_stopping_serve_stops_its_worker_processes(tmp_path: Path, stop_signal: int) -> None:
    service = Service(tmp_path / "data", workers=2).start()
    try:
        service.wait_for_workers()
        assert service.process is not None
        service.process.send_signal(stop_signal)
        service.process.wait(30)
        deadline = time.monotonic() + 20
        while service.session_pids() and time.monotonic() < deadline:
            time.sleep(0.2)
        assert service.session_pids() == [], "worker processes outlived scanplan serve"
    finally:
        service.kill_leftovers()


@pytest.mark.parametrize("stop_signal", [signal.SIGTERM, signal.SIGKILL])
def test_stopping_serve_stops_busy_workers_too(tmp_path: Path, stop_signal: int) -> None:
    """A worker in a stage that never polls (candidates on a 1 cm grid) stops with serve."""
    small = _scene("hall-small")
    service = Service(tmp_path / "data", workers=2).start()
    try:
        with service.client() as client:
            job_id = _submit(client, small, candidates=None, grid_spacing_m=0.01)
            deadline = time.monotonic() + 60
            while not client.get(f"/jobs/{job_id}").json()["message"].startswith(
                    "candidates"):
                assert time.monotonic() < deadline, "the job never reached its candidates"
                time.sleep(0.05)
        assert service.process is not None
        service.process.send_signal(stop_signal)
        service.process.wait(30)
        deadline = time.monotonic() + 20  # the consumer's grace period is 15 s
        while service.session_pids() and time.monotonic() < deadline:
            time.sleep(0.2)
        assert service.session_pids() == [], "a busy worker outlived scanplan serve"
    finally:
        service.kill_leftovers()


def test_plan_through_workers_equals_in_process(shared_service: Service,
                                                tmp_path: Path) -> None:
    hall = _scene("hall-small")
    with shared_service.client() as client:
        job_id = _submit(client, hall)
        status = wait_for(client, job_id, FINISHED)
        assert status["status"] == "successful", status
        results = client.get(f"/jobs/{job_id}/results").json()
        served = {name: client.get(ref["href"]).content
                  for name, ref in results.items() if name != "plan"}
    spec = PlanSpec.from_mapping(_parameters(hall))
    expected = tmp_path / "in-process"
    write_outputs(plan(read_scene(hall / "hall.obj", max_edge_m=None), spec), expected)
    assert served["plan.json"] == (expected / "plan.json").read_bytes()
    assert served["faces.npz"] == (expected / "faces.npz").read_bytes()


def _wait_running(service: Service, client: httpx.Client, job_id: str) -> int:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        pid = service.worker_pid(job_id)
        if pid is not None and client.get(f"/jobs/{job_id}").json()["progress"] >= 5:
            return pid
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} never ran")


def test_sigkilled_worker_job_still_finishes(service: Service) -> None:
    hall = _scene("hall-full")  # seconds of planning after the kill: it lands mid-run
    with service.client() as client:
        job_id = _submit(client, hall)
        os.kill(_wait_running(service, client, job_id), signal.SIGKILL)
        status = wait_for(client, job_id, FINISHED, timeout_s=150)
    assert status["status"] == "successful" or "worker lost" in status["message"], status
    assert status["attempts"] >= 2, "the job should have run again after the kill"


def test_sigkilled_planning_process_is_run_again_not_called_out_of_memory(
        service: Service) -> None:
    """What an operator, a container runtime or the host's OOM killer does to the plan."""
    hall = _scene("hall-full")  # seconds of planning after the kill: it lands mid-run
    with service.client() as client:
        job_id = _submit(client, hall)
        worker = _wait_running(service, client, job_id)
        [child] = child_pids(worker)
        os.kill(child, signal.SIGKILL)
        status = wait_for(client, job_id, FINISHED, timeout_s=300)
    assert status["status"] == "successful", status
    assert status["attempts"] == 2, status
    killed, succeeded = status["attempt_log"]
    assert killed["outcome"] == "killed" and killed["signal"] == "SIGKILL", killed
    assert killed["stage"] in ("reading", "candidates", "visibility", "selection"), killed
    assert killed["peak_rss_mib"] < 0.9 * killed["memory_limit_mib"], killed
    assert succeeded["outcome"] == "successful"


def test_delete_cancels_a_running_job(shared_service: Service) -> None:
    service = shared_service
    hall = _scene("hall-full")
    with service.client() as client:
        job_id = _submit(client, hall)
        pid = _wait_running(service, client, job_id)
        assert client.delete(f"/jobs/{job_id}").json()["status"] == "dismissed"
        deadline = time.monotonic() + 15
        while f"job {job_id}: stopped (dismissed" not in service.log.read_text():
            assert time.monotonic() < deadline, "the worker did not stop within 15 s"
            time.sleep(0.2)
        os.kill(pid, 0)  # the worker process itself lives on for the next job
        assert client.get(f"/jobs/{job_id}").status_code == 404  # dismissed: gone
        assert not (service.data_dir / "jobs" / job_id).exists()


def test_restart_loses_no_job(tmp_path: Path) -> None:
    hall, small = _scene("hall-full"), _scene("hall-small")
    first = Service(tmp_path / "data", workers=1).start()
    with first.client() as client:
        # every other candidate of hall-full: seconds of planning left when serve stops,
        # half of the run again after the restart
        running = _submit(client, hall, candidates=_parameters(hall)["candidates"][::2])
        # queued, they wait all the same: 10 candidates plan as well as all of them
        few = _parameters(small)["candidates"][:10]
        queued = [_submit(client, small, candidates=few) for _ in range(3)]
        _wait_running(first, client, running)
        started = client.get(f"/jobs/{running}").json()["started"]
    first.stop()  # one job mid-run, three queued
    second = Service(tmp_path / "data", workers=2, port=first.port).start()
    try:
        with second.client() as client:
            for job_id in [running, *queued]:
                assert wait_for(client, job_id, FINISHED, 150)["status"] == "successful"
            # the job was stopped mid-run and started again, not finished before the stop
            assert client.get(f"/jobs/{running}").json()["started"] > started
    finally:
        second.stop()
        first.kill_leftovers()
        second.kill_leftovers()


def test_bad_input_keeps_the_service_serving(shared_service: Service) -> None:
    with shared_service.client() as client:
        for body, status in ((b"", 422), (b"\x00garbage" * 100, 415)):
            answer = client.post("/meshes", content=body,
                                 headers={"content-type": "application/octet-stream"})
            assert answer.status_code == status
            assert answer.headers["content-type"] == "application/problem+json"
        assert client.get("/jobs/nope").status_code == 404
        assert client.get("/healthz").json() == {"status": "ok", "version": __version__}
