"""Service tests: ``create_app()`` with an inline runner in place of huey (a fake, not a mock).

The planner runs for real; the hall-small scene plans in about a second.
"""

from __future__ import annotations

import csv
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service.config import Settings
from service.main import create_app
from service.worker import WorkerContext, build_context, execute_job
from tests.data_files import HALL_SMALL as HALL


class InlineQueue:
    """Runs a job right away in the calling thread (``hold=True``: keeps it queued)."""

    def __init__(self, hold: bool = False) -> None:
        self.hold = hold
        self.ctx: WorkerContext | None = None
        self.enqueued: list[str] = []

    def enqueue(self, job_id: str) -> None:
        self.enqueued.append(job_id)
        if not self.hold and self.ctx is not None:
            execute_job(self.ctx, job_id)

    def ping(self) -> None:
        return None


@pytest.fixture(scope="session")
def hall() -> Path:
    return HALL


@pytest.fixture(scope="session")
def hall_bytes(hall: Path) -> bytes:
    return (hall / "hall.obj").read_bytes()


@pytest.fixture(scope="session")
def hall_parameters(hall: Path) -> dict[str, Any]:
    """The team's fast hall-small plan: its candidates, the mesh as given."""
    with (hall / "candidates.csv").open() as handle:
        candidates = [[float(r["x"]), float(r["y"]), float(r["z"])]
                      for r in csv.DictReader(handle)]
    return {"max_edge_m": None, "candidates": candidates}


def make_client(tmp_path: Path, queue: InlineQueue, **overrides: Any) -> TestClient:
    settings = Settings(data_dir=tmp_path / "data", workers=1, **overrides)
    queue.ctx = build_context(settings, queue)
    return TestClient(create_app(settings, queue=queue, reaper=False))


@pytest.fixture
def queue() -> InlineQueue:
    return InlineQueue()


@pytest.fixture
def client(tmp_path: Path, queue: InlineQueue) -> Iterator[TestClient]:
    with make_client(tmp_path, queue, api_keys=[]) as c:
        yield c


def upload(client: TestClient, data: bytes, **headers: str) -> Any:
    return client.post("/meshes?filename=hall.obj", content=data,
                       headers={"content-type": "application/octet-stream", **headers})


def submit(client: TestClient, mesh_id: str, parameters: dict[str, Any],
           **headers: str) -> Any:
    return client.post("/processes/scan-plan/execution",
                       json={"inputs": {"mesh": mesh_id, "parameters": parameters}},
                       headers=headers)
