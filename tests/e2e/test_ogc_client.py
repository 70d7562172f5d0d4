"""OWSLib, the standard Python OGC client, runs a plan end to end against ``scanplan serve``.

OWSLib 0.35's ``Processes`` lists, describes and executes; it has no job methods, so the
polling and the results go through its generic ``_request`` (the same HTTP client).
"""

from __future__ import annotations

import csv
import time
from pathlib import Path
from typing import Any

import httpx
import pytest
from owslib.ogcapi.processes import Processes

from tests.data_files import HALL_SMALL as HALL
from tests.e2e.service_process import Service

CORE = "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/core"


@pytest.fixture
def service(tmp_path: Path) -> Any:
    running = Service(tmp_path / "data", workers=1).start()
    yield running
    running.stop()
    running.kill_leftovers()


def test_owslib_lists_describes_executes_polls_and_fetches_results(service: Service) -> None:
    client = Processes(service.url + "/")
    rels = {link["rel"] for link in client.links}
    assert {"self", "service-desc", "service-doc"} <= rels
    assert client.api()["info"]["title"] == "scanplan"
    assert CORE in client.conformance()["conformsTo"]
    assert [p["id"] for p in client.processes()] == ["scan-plan"]
    description = client.process("scan-plan")
    assert {"mesh", "parameters"} <= set(description["inputs"])
    assert "plan.json" in description["outputs"]

    mesh = httpx.post(f"{service.url}/meshes?filename=hall.obj",
                      content=(HALL / "hall.obj").read_bytes(),
                      headers={"content-type": "application/octet-stream"}).json()["id"]
    with (HALL / "candidates.csv").open() as handle:
        candidates = [[float(r["x"]), float(r["y"]), float(r["z"])]
                      for r in csv.DictReader(handle)]
    status = client.execute("scan-plan", inputs={
        "mesh": mesh, "parameters": {"max_edge_m": None, "candidates": candidates}},
        async_=True)
    assert status["status"] in ("accepted", "running", "successful")
    assert client.response_headers["Location"] == f"/jobs/{status['jobID']}"
    assert client.response_headers["Preference-Applied"] == "respond-async"

    deadline = time.monotonic() + 120
    while status["status"] in ("accepted", "running"):
        assert time.monotonic() < deadline, status
        time.sleep(0.2)
        status = client._request(path=f"jobs/{status['jobID']}")
    assert status["status"] == "successful", status
    results = client._request(path=f"jobs/{status['jobID']}/results")
    assert results["plan"]["totals"]["stations"] >= 1
    stations = client._request(path=results["stations.csv"]["href"].lstrip("/"),
                               as_dict=False)
    assert stations.decode().startswith("id,x,y,z")
