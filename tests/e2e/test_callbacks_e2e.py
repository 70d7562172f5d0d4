"""Callbacks from a real ``scanplan serve``: the plan runs in a huey worker process, the
callbacks leave the API process for a receiver on 127.0.0.1."""

from __future__ import annotations

from pathlib import Path

import httpx

from tests.e2e.service_process import Service, wait_for
from tests.e2e.test_service_e2e import _parameters, _scene
from tests.service.test_callbacks import SECRET, Receiver, receiver, signed_by_secret

__all__ = ["receiver"]  # the fixture, used by name


def test_serve_posts_signed_callbacks_to_a_receiver(tmp_path: Path, receiver: Receiver) -> None:
    hall = _scene("hall-small")
    service = Service(tmp_path / "data", workers=1, env={
        "SCANPLAN_CALLBACK_SECRET": SECRET, "SCANPLAN_CALLBACK_ALLOW": "127.0.0.0/8",
        "SCANPLAN_CALLBACK_POLL_INTERVAL_S": "0.1",
        "SCANPLAN_CALLBACK_PROGRESS_INTERVAL_S": "0.5"}).start()
    try:
        with service.client() as client:
            mesh = client.post("/meshes?filename=hall.obj",
                               content=(hall / "hall.obj").read_bytes(),
                               headers={"content-type": "application/octet-stream"}).json()
            job = client.post("/processes/scan-plan/execution", json={
                "inputs": {"mesh": mesh["id"], "parameters": _parameters(hall)},
                "subscriber": {"successUri": receiver.base + "/done",
                               "inProgressUri": receiver.base + "/progress"}})
            assert job.status_code == 201, job.text
            job_id = job.json()["jobID"]
            assert wait_for(client, job_id, ("successful", "failed"))["status"] == "successful"
            receiver.wait_for(lambda: bool(receiver.at("/done")))
            [done] = receiver.at("/done")
            assert signed_by_secret(done) and done.json()["status"] == "successful"
            assert all(signed_by_secret(p) for p in receiver.at("/progress"))
            assert {p.json()["status"] for p in receiver.at("/progress")} <= {"running"}
            links = {link["title"]: link["href"] for link in done.json()["links"]}
            assert links["plan.json"].startswith(service.url)
            served = httpx.get(links["plan.json"], timeout=30)
            assert served.status_code == 200 and served.json()["stations"]
    finally:
        service.stop()
        service.kill_leftovers()
