"""FZK-Haus uploaded through the API as it is: a plan per storey from its rooms, in BIM terms."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.service.conftest import submit

GROUND_FLOOR_ROOMS = {"Flur", "Buero", "Bad", "Schlafzimmer", "Wohnen", "Küche"}


@pytest.fixture(scope="module")
def fzk_bytes(scenes_dir: Path) -> bytes:
    return (scenes_dir / "AC20-FZK-Haus.ifc").read_bytes()


def test_ifc_upload_and_a_ground_floor_plan(client: TestClient, fzk_bytes: bytes) -> None:
    uploaded = client.post("/meshes", files={"file": ("AC20-FZK-Haus.ifc", fzk_bytes)})
    assert uploaded.status_code == 201, uploaded.text
    mesh = uploaded.json()
    assert mesh["format"] == "ifc"
    assert {"IfcWallStandardCase", "IfcSlab", "IfcWindow"} <= set(mesh["groups"])

    parameters: dict[str, Any] = {"storeys": ["Erdgeschoss"], "max_edge_m": 0.5,
                                  "grid_spacing_m": 1.0}
    created = submit(client, mesh["id"], parameters)
    assert created.status_code == 201, created.text
    job = client.get(f"/jobs/{created.json()['jobID']}").json()
    assert job["status"] == "successful", job
    results = client.get(f"/jobs/{job['jobID']}/results").json()
    plan = results["plan"]
    assert plan["candidates"]["source"] == "rooms"
    labels = [station["label"] for station in plan["stations"]]
    assert labels and all(label["storey"] == "Erdgeschoss" for label in labels)
    assert {label["room"] for label in labels} <= GROUND_FLOOR_ROOMS

    elements = client.get(results["elements.csv"]["href"])
    assert elements.status_code == 200
    rows = list(csv.DictReader(io.StringIO(elements.text)))
    walls = [row for row in rows if row["ifc_class"] == "IfcWallStandardCase"]
    assert walls and all(len(row["global_id"]) == 22 for row in walls)
    assert any(float(row["covered_area_m2"]) > 0 for row in walls)


def test_a_broken_ifc_is_a_422_naming_the_problem(client: TestClient, tmp_path: Path) -> None:
    body = b"ISO-10303-21;\nHEADER;\nthis is not STEP at all\n"
    answer = client.post("/meshes?filename=broken.ifc", content=body,
                         headers={"content-type": "application/octet-stream"})
    assert answer.status_code == 422
    assert answer.headers["content-type"].startswith("application/problem+json")
    assert "broken.ifc" in answer.json()["detail"] or "IFC" in answer.json()["detail"]
