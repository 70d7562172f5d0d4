"""A client generated from openapi/openapi.json by openapi-python-client plans end to end
against ``scanplan serve``, without hand edits: the OpenAPI document is the contract."""

from __future__ import annotations

import importlib
import io
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.data_files import HALL_SMALL as HALL
from tests.e2e.service_process import Service

ROOT = Path(__file__).resolve().parents[2]
GENERATOR = str(Path(sys.executable).with_name("openapi-python-client"))


@pytest.fixture
def client_package(tmp_path: Path) -> Iterator[str]:
    subprocess.run([GENERATOR, "generate", "--path", str(ROOT / "openapi" / "openapi.json"),
                    "--meta", "none", "--output-path", str(tmp_path / "scanplan_client")],
                   check=True, capture_output=True, timeout=120, cwd=tmp_path)
    sys.path.insert(0, str(tmp_path))
    try:
        yield "scanplan_client"
    finally:
        sys.path.remove(str(tmp_path))
        for name in [m for m in sys.modules if m.startswith("scanplan_client")]:
            del sys.modules[name]


def test_generated_client_runs_a_plan(tmp_path: Path, client_package: str) -> None:
    def load(name: str) -> Any:
        return importlib.import_module(f"{client_package}.{name}")

    service = Service(tmp_path / "data", workers=1).start()
    try:
        client = load("client").Client(base_url=service.url)
        models, types = load("models"), load("types")
        mesh = load("api.meshes.upload_mesh").sync(
            client=client, filename="hall.obj",
            body=types.File(payload=io.BytesIO((HALL / "hall.obj").read_bytes()),
                            file_name="hall.obj", mime_type="application/octet-stream"))
        assert len(mesh.id) == 64 and mesh.faces > 0
        request = models.ExecuteRequest(inputs=models.ExecuteInputs(
            mesh=mesh.id, parameters=models.PlanParameters(max_edge_m=None)))
        job = load("api.processes.execute").sync(client=client, process_id="scan-plan",
                                                 body=request)
        deadline = time.monotonic() + 120
        status = job
        while str(status.status) not in ("successful", "failed", "dismissed"):
            assert time.monotonic() < deadline, status
            time.sleep(0.3)
            status = load("api.jobs.get_job").sync(client=client, job_id=job.job_id)
        assert str(status.status) == "successful", status
        results = load("api.jobs.get_results").sync(client=client, job_id=job.job_id)
        assert results["plan"]["totals"]["stations"] >= 1
        assert results["stations.csv"]["href"].endswith("/results/stations.csv")
        refused = load("api.processes.execute").sync_detailed(
            client=client, process_id="scan-plan", body=models.ExecuteRequest(
                inputs=models.ExecuteInputs(mesh=mesh.id, parameters=models.PlanParameters(
                    dof_min_m=60.0))))
        assert refused.status_code == 422  # between fields: the service says, as documented
    finally:
        service.stop()
        service.kill_leftovers()
