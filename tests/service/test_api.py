"""The HTTP API against ``create_app()``: meshes, jobs, results, errors, auth."""

from __future__ import annotations

import io
import json
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from planner.io.readers import read_scene
from planner.outputs.report import write_outputs
from planner.parameters import PlanSpec
from planner.pipeline import plan
from service.routes.jobs import media_type
from tests.service.conftest import InlineQueue, make_client, submit, upload

PROBLEM = "application/problem+json"


def assert_problem(response: Any, status: int, *words: str) -> dict[str, Any]:
    assert response.status_code == status, response.text
    assert response.headers["content-type"].startswith(PROBLEM)
    body: dict[str, Any] = response.json()
    assert body["status"] == status and body["title"] and body["type"]
    for word in words:
        assert word in body["detail"], body
    return body


def test_upload_is_content_addressed(client: TestClient, hall_bytes: bytes) -> None:
    first = upload(client, hall_bytes)
    assert first.status_code == 201, first.text
    mesh = first.json()
    assert mesh["faces"] == 14724 and mesh["format"] == "obj"
    assert mesh["groups"]["floor"] == 2088 and mesh["filename"] == "hall.obj"
    assert first.headers["location"] == f"/meshes/{mesh['id']}"
    again = client.post("/meshes", files={"file": ("other.obj", hall_bytes)})
    assert again.status_code == 200 and again.json()["id"] == mesh["id"]
    assert client.get(f"/meshes/{mesh['id']}").json()["bytes"] == len(hall_bytes)
    content = client.get(f"/meshes/{mesh['id']}/content")
    assert content.content == hall_bytes and content.headers["etag"] == f'"{mesh["id"]}"'
    assert client.delete(f"/meshes/{mesh['id']}").status_code == 204
    assert_problem(client.get(f"/meshes/{mesh['id']}"), 404, "POST /meshes")


@pytest.fixture(scope="module")
def hall_job(tmp_path_factory: pytest.TempPathFactory, hall_bytes: bytes,
             hall_parameters: dict[str, Any]) -> Iterator[tuple[TestClient, Any]]:
    """One hall-small job run to its end, and the answer to its submission: for the tests
    that only read a finished job (the same plan each would run on its own)."""
    data = tmp_path_factory.mktemp("hall-job")
    with make_client(data, InlineQueue(), api_keys=[]) as client:
        mesh_id = upload(client, hall_bytes).json()["id"]
        yield client, submit(client, mesh_id, hall_parameters)


def test_plan_equals_in_process_plan(hall_job: tuple[TestClient, Any], hall: Path,
                                     hall_parameters: dict[str, Any], tmp_path: Path) -> None:
    client, created = hall_job
    assert created.status_code == 201, created.text
    job_id = created.json()["jobID"]
    assert created.headers["location"] == f"/jobs/{job_id}"
    status = client.get(f"/jobs/{job_id}").json()
    assert status["status"] == "successful" and status["progress"] == 100
    assert "no plan.ifc: the input is OBJ" in status["message"]  # a mesh: said why
    assert set(status["timings_s"]) >= {"reading", "visibility", "selection"}
    assert any(link["href"].endswith("/viewer") for link in status["links"])
    results = client.get(f"/jobs/{job_id}/results").json()
    assert results["plan"]["totals"]["stations"] >= 1
    assert set(results) >= {"plan", "plan.json", "faces.npz", "stations.csv"}

    spec = PlanSpec.from_mapping(hall_parameters)
    scene = read_scene(hall / "hall.obj", max_edge_m=spec.max_edge_m)
    expected = tmp_path / "expected"
    write_outputs(plan(scene, spec), expected)
    for name in ("plan.json", "faces.npz", "stations.csv"):
        served = client.get(results[name]["href"])
        assert served.content == (expected / name).read_bytes(), name
    assert results["plan"] == json.loads((expected / "plan.json").read_text())


def test_output_headers_etag_and_range(hall_job: tuple[TestClient, Any]) -> None:
    client, created = hall_job
    job_id = created.json()["jobID"]
    base = f"/jobs/{job_id}/results"
    assert client.get(f"{base}/plan.json").headers["content-type"] == "application/json"
    assert client.get(f"{base}/faces.npz").headers["content-type"] == \
        "application/octet-stream"
    full = client.get(f"{base}/stations.csv")
    assert full.headers["content-type"].startswith("text/csv")
    assert full.text.splitlines()[0].startswith("id,x,y,z,order")
    part = client.get(f"{base}/stations.csv", headers={"range": "bytes=0-9"})
    assert part.status_code == 206 and part.content == full.content[:10]
    etag = full.headers["etag"]
    assert client.get(f"{base}/stations.csv",
                      headers={"if-none-match": etag}).status_code == 304
    assert_problem(client.get(f"{base}/nope.txt"), 404, "plan.json")


def test_cad_outputs_are_served_with_their_media_types(
        hall_job: tuple[TestClient, Any]) -> None:
    """plan.dxf and plan.pdf are job results like the others; plan.ifc and plan.bcf, when a
    job wrote them, are served as STEP and as bytes."""
    client, created = hall_job
    job_id = created.json()["jobID"]
    results = client.get(f"/jobs/{job_id}/results").json()
    for name, media, magic in (("plan.dxf", "image/vnd.dxf", b"  0\nSECTION"),
                               ("plan.pdf", "application/pdf", b"%PDF-")):
        assert results[name]["type"] == media
        served = client.get(results[name]["href"])
        assert served.status_code == 200, name
        assert served.headers["content-type"] == media
        assert served.content.startswith(magic) and len(served.content) == results[name]["bytes"]
    assert media_type("plan.ifc") == "application/x-step"
    assert media_type("plan.bcf") == "application/octet-stream"


@pytest.mark.parametrize(("body", "status", "word"), [
    (b"", 422, "empty"),
    (b"\x00\x01\x02\x03binary" * 50, 415, "not a model format"),
    (b"v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n", 422, "non-finite"),
    (b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", 422, "no triangles"),
], ids=["empty", "binary", "nan-vertex", "truncated"])
def test_bad_uploads(client: TestClient, body: bytes, status: int, word: str) -> None:
    assert_problem(upload(client, body), status, word)
    assert client.get("/healthz").status_code == 200


def test_truncated_hall_is_refused(client: TestClient, hall_bytes: bytes) -> None:
    assert_problem(upload(client, hall_bytes[: len(hall_bytes) // 3]), 422)


def test_oversized_upload(tmp_path: Path, hall_bytes: bytes) -> None:
    with make_client(tmp_path, InlineQueue(), max_upload_bytes=1000) as client:
        assert_problem(upload(client, hall_bytes), 413, "1000 bytes")

        def chunked() -> Any:  # no Content-Length: the cap is enforced while streaming
            for start in range(0, len(hall_bytes), 500):
                yield hall_bytes[start:start + 500]

        streamed = client.post("/meshes", content=chunked())
        assert_problem(streamed, 413)
        staging = tmp_path / "data" / "tmp"
        assert not any(staging.rglob("upload*")), "an oversized body was kept"


@pytest.mark.parametrize(("parameters", "parameter", "word"), [
    ({"dof_min_m": -1}, "dof_min_m", "negative"),
    ({"dof_min_m": "abc"}, "dof_min_m", "valid number"),
    ({"dof_min_m": "1.5"}, "dof_min_m", "valid number"),
    ({"coverage_goal": 2}, "coverage_goal", "(0, 1]"),
    ({"method": "best"}, "method", "greedy"),
    ({"no_such": 1}, "no_such", "Extra inputs"),
    ({"candidates": [[0, 0]]}, "candidates.0", "3"),
    ({"scanner": 42}, "scanner", "preset id or an object"),
    ({"scanner": "leica-x"}, "scanner", "not a known preset"),
    ({"scanner": {"name": "x", "measurement_rate_pts_s": 0}}, "scanner.measurement_rate_pts_s",
     "must be in [1, 1e+09]"),
    ({"scanner": {"name": "x", "overhead_s": -3}}, "scanner.overhead_s", "in [0, 86400]"),
    ({"scanner": {"name": "x", "settings": [{"name": "a", "point_spacing_m": 0.01}]}},
     "scanner.settings.0.reference_distance_m", "required"),
    ({"scanner": {"name": "x", "settings": [
        {"name": "a", "point_spacing_m": 0.01, "reference_distance_m": 10, "duration_s": 0}]}},
     "scanner.settings.0.duration_s", "in (0, 86400]"),
    ({"scanner": {"name": "x", "min_range_m": 4, "max_range_m": 2}}, "scanner.min_range_m",
     "less than scanner.max_range_m"),
    ({"max_field_time_h": 4, "scanner": "leica-rtc360"}, "max_field_time_h",
     "scan time, which is unknown"),
    ({"max_field_time_h": -1}, "max_field_time_h", "in (0, 10000]"),
])
def test_bad_parameters(client: TestClient, hall_bytes: bytes, parameters: dict[str, Any],
                        parameter: str, word: str) -> None:
    mesh_id = upload(client, hall_bytes).json()["id"]
    body = assert_problem(submit(client, mesh_id, parameters), 422, word)
    assert body["parameter"] == parameter


def test_unknown_ids(client: TestClient) -> None:
    assert_problem(client.get("/jobs/0123"), 404, "no job")
    assert_problem(client.get("/jobs/0123/results"), 404)
    assert_problem(client.delete("/jobs/0123"), 404)
    assert_problem(client.get("/meshes/abc"), 404)
    assert_problem(submit(client, "f" * 64, {}), 404, "POST /meshes")
    assert_problem(client.get("/processes/other"), 404, "scan-plan")
    assert_problem(client.get("/no/such/route"), 404)
    not_json = client.post("/processes/scan-plan/execution", content=b"{oops",
                           headers={"content-type": "application/json"})
    assert_problem(not_json, 422)


def test_failed_job_carries_its_problem(client: TestClient, hall_bytes: bytes) -> None:
    mesh_id = upload(client, hall_bytes).json()["id"]
    job_id = submit(client, mesh_id, {"max_edge_m": None,
                                      "candidates": [[100.0, 100.0, 100.0]]}).json()["jobID"]
    status = client.get(f"/jobs/{job_id}").json()
    assert status["status"] == "failed"
    assert status["problem"]["type"].endswith("nothing-visible")
    assert_problem(client.get(f"/jobs/{job_id}/results"), 422, "candidates")


def test_idempotency_key(client: TestClient, hall_bytes: bytes,
                         hall_parameters: dict[str, Any]) -> None:
    mesh_id = upload(client, hall_bytes).json()["id"]
    first = submit(client, mesh_id, hall_parameters, **{"Idempotency-Key": "k1"})
    again = submit(client, mesh_id, hall_parameters, **{"Idempotency-Key": "k1"})
    assert (first.status_code, again.status_code) == (201, 200)
    assert first.json()["jobID"] == again.json()["jobID"]
    other = submit(client, mesh_id, {"max_edge_m": None}, **{"Idempotency-Key": "k1"})
    assert_problem(other, 422, "another body")


def test_dismiss_queued_job_and_mesh_in_use(tmp_path: Path, hall_bytes: bytes) -> None:
    with make_client(tmp_path, InlineQueue(hold=True), api_keys=[]) as client:
        mesh_id = upload(client, hall_bytes).json()["id"]
        job_id = submit(client, mesh_id, {}).json()["jobID"]
        assert client.get(f"/jobs/{job_id}").json()["status"] == "accepted"
        assert_problem(client.delete(f"/meshes/{mesh_id}"), 409, "unfinished")
        assert client.delete(f"/jobs/{job_id}").json()["status"] == "dismissed"
        # OGC dismiss: the job is gone for every /jobs request, and from the list
        for path in (f"/jobs/{job_id}", f"/jobs/{job_id}/results",
                     f"/jobs/{job_id}/results/plan.json"):
            assert_problem(client.get(path), 404, "dismissed")
        assert_problem(client.delete(f"/jobs/{job_id}"), 404, "dismissed")
        assert client.get("/jobs").json()["numberMatched"] == 0
        assert client.get("/jobs?status=dismissed").json()["jobs"] == []
        assert client.delete(f"/meshes/{mesh_id}").status_code == 204


def test_delete_of_a_finished_job_removes_it_and_its_files(
        client: TestClient, hall_bytes: bytes, hall_parameters: dict[str, Any]) -> None:
    mesh_id = upload(client, hall_bytes).json()["id"]
    job_id = submit(client, mesh_id, hall_parameters).json()["jobID"]
    assert client.get(f"/jobs/{job_id}").json()["status"] == "successful"
    answer = client.delete(f"/jobs/{job_id}")
    assert answer.status_code == 200 and answer.json()["status"] == "dismissed"
    assert_problem(client.get(f"/jobs/{job_id}"), 404)
    assert_problem(client.get(f"/jobs/{job_id}/results/plan.json"), 404)
    assert_problem(client.delete(f"/jobs/{job_id}"), 404)


def test_callbacks_of_a_dismissed_job_are_gone(tmp_path: Path, hall_bytes: bytes) -> None:
    """POST an execution, DELETE the job, GET its callbacks: 404 like its status."""
    with make_client(tmp_path, InlineQueue(hold=True), api_keys=[]) as client:
        mesh_id = upload(client, hall_bytes).json()["id"]
        job_id = submit(client, mesh_id, {}).json()["jobID"]
        assert client.get(f"/jobs/{job_id}/callbacks").json() == {
            "subscriber": None, "deliveries": []}
        assert client.delete(f"/jobs/{job_id}").json()["status"] == "dismissed"
        assert_problem(client.get(f"/jobs/{job_id}"), 404, "dismissed")
        assert_problem(client.get(f"/jobs/{job_id}/callbacks"), 404, "dismissed")


def _job_operations(client: TestClient) -> list[tuple[str, str]]:
    """Every (method, path template) the OpenAPI document lists under /jobs/{job_id}."""
    paths = client.get("/openapi.json").json()["paths"]
    return sorted((method, path) for path, operations in paths.items()
                  if path.startswith("/jobs/{job_id}") for method in operations)


@pytest.mark.parametrize("finished", [False, True], ids=["queued", "finished"])
def test_every_job_route_answers_404_once_the_job_is_dismissed(
        tmp_path: Path, hall_bytes: bytes, hall_parameters: dict[str, Any],
        finished: bool) -> None:
    """Dismissed (queued) or deleted (finished): every documented /jobs/{id} operation,
    present and future, answers 404 with a problem document."""
    with make_client(tmp_path, InlineQueue(hold=not finished), api_keys=[]) as client:
        mesh_id = upload(client, hall_bytes).json()["id"]
        job_id = submit(client, mesh_id, hall_parameters).json()["jobID"]
        assert client.get(f"/jobs/{job_id}").json()["status"] == (
            "successful" if finished else "accepted")
        assert client.delete(f"/jobs/{job_id}").status_code == 200
        operations = _job_operations(client)
        assert ("get", "/jobs/{job_id}/callbacks") in operations
        for method, template in operations:
            path = template.replace("{job_id}", job_id).replace("{output}", "plan.json")
            assert_problem(client.request(method, path), 404)


class LinkWalker:
    """A stateful client: it only follows the OpenAPI links of the app's own document,
    resolving their runtime expressions ($response.body#/..., $request.path.<name>)
    against the response they leave from."""

    def __init__(self, client: TestClient) -> None:
        self.client = client
        document = client.get("/openapi.json").json()
        self.document = document
        self.operations = {operation["operationId"]: (method, path)
                           for path, methods in document["paths"].items()
                           for method, operation in methods.items()}
        self.links = {operation["operationId"]: {
            int(code): answer.get("links", {})
            for code, answer in operation["responses"].items() if code.isdigit()}
            for methods in document["paths"].values() for operation in methods.values()}
        self.followed: set[str] = set()

    def names(self, source: str, status: int) -> list[str]:
        return sorted(self.links[source].get(status, {}))

    def follow(self, source: str, answer: Any, name: str) -> tuple[str, Any]:
        """Follow link ``name`` of operation ``source`` from its response ``answer``."""
        link = self.links[source][answer.status_code][name]
        method, template = self.operations[link["operationId"]]
        path_parameters = self._path_parameters(source, answer)

        def resolve(value: Any) -> Any:
            if isinstance(value, dict):
                return {key: resolve(item) for key, item in value.items()}
            if not isinstance(value, str) or not value.startswith("$"):
                return value
            if value.startswith("$request.path."):
                return path_parameters[value.removeprefix("$request.path.")]
            assert value.startswith("$response.body#/"), value
            found = answer.json()
            for key in value.removeprefix("$response.body#/").split("/"):
                found = found[key]
            return found

        path = template
        for parameter, expression in link["parameters"].items():
            assert "{" + parameter + "}" in path, (name, parameter, template)
            path = path.replace("{" + parameter + "}", str(resolve(expression)))
        assert "{" not in path, (name, path)
        body = resolve(link["requestBody"]) if "requestBody" in link else None
        self.followed.add(link["operationId"])
        return link["operationId"], self.client.request(method, path, json=body)

    def _path_parameters(self, source: str, answer: Any) -> dict[str, str]:
        template = self.operations[source][1].split("/")
        sent = answer.request.url.path.split("/")
        return {part[1:-1]: value for part, value in zip(template, sent, strict=True)
                if part.startswith("{")}


def test_a_client_following_links_reaches_every_mesh_and_job_operation(
        client: TestClient, hall_bytes: bytes, hall_parameters: dict[str, Any]) -> None:
    """From an upload, the document's links alone lead to the mesh, its bytes, a job, its
    status, results, every output it has, its callbacks, and both deletions."""
    walker = LinkWalker(client)
    uploaded = upload(client, hall_bytes)
    assert uploaded.status_code == 201
    assert walker.names("upload_mesh", 201) == walker.names("upload_mesh", 200) == [
        "delete_mesh", "execute", "get_mesh", "get_mesh_content"]
    _, mesh = walker.follow("upload_mesh", uploaded, "get_mesh")
    assert mesh.status_code == 200 and mesh.json()["faces"] == 14724
    _, content = walker.follow("get_mesh", mesh, "get_mesh_content")
    assert content.content == hall_bytes
    # the execute link names the mesh; the plan's own parameters are the client's
    link = walker.links["upload_mesh"][201]["execute"]
    link["requestBody"]["inputs"]["parameters"] = hall_parameters
    _, created = walker.follow("upload_mesh", uploaded, "execute")
    assert created.status_code == 201, created.text
    job_id = created.json()["jobID"]
    _, status = walker.follow("execute", created, "get_job")
    assert status.status_code == 200 and status.json()["status"] == "successful"
    _, callbacks = walker.follow("execute", created, "get_callbacks")
    assert callbacks.json() == {"subscriber": None, "deliveries": []}
    _, results = walker.follow("get_job", status, "get_results")
    assert results.status_code == 200
    outputs = set(results.json()) - {"plan"}
    assert outputs >= {"plan.json", "faces.npz", "stations.csv", "coverage.glb"}
    # each file comes with a media type the document lists for it
    documented = walker.document["paths"]["/jobs/{job_id}/results/{output}"]["get"][
        "responses"]["200"]["content"]
    for source, answer in (("get_job", status), ("get_results", results)):
        linked = [name for name in walker.names(source, 200) if name.startswith("get_output")]
        served = set()
        for name in linked:
            _, output = walker.follow(source, answer, name)
            output_name = output.request.url.path.rsplit("/", 1)[-1]
            if output.status_code == 200:
                assert output.content == client.get(results.json()[output_name]["href"]).content
                media = output.headers["content-type"].split(";")[0]
                assert media in documented, (output_name, media)
                served.add(output_name)
            else:  # a file only other plans have (plan.ifc of an IFC model, ...)
                assert_problem(output, 404, output_name)
        assert served == outputs, source  # a link to every output the job has
    _, mesh_of_job = walker.follow("get_job", status, "get_mesh")
    assert mesh_of_job.json()["id"] == mesh.json()["id"]
    _, dismissed = walker.follow("get_job", status, "delete_job")
    assert dismissed.json()["status"] == "dismissed"
    assert_problem(client.get(f"/jobs/{job_id}"), 404)
    _, deleted = walker.follow("get_mesh", mesh, "delete_mesh")
    assert deleted.status_code == 204
    assert walker.followed == {"get_mesh", "get_mesh_content", "execute", "get_job",
                               "get_callbacks", "get_results", "get_output", "delete_job",
                               "delete_mesh"}


def test_job_list_filters_and_pages(tmp_path: Path, hall_bytes: bytes) -> None:
    with make_client(tmp_path, InlineQueue(hold=True), api_keys=[]) as client:
        mesh_id = upload(client, hall_bytes).json()["id"]
        ids = [submit(client, mesh_id, {}).json()["jobID"] for _ in range(3)]
        ids.append(submit(client, mesh_id, {}).json()["jobID"])
        client.delete(f"/jobs/{ids[0]}")  # dismissed: no longer listed
        page = client.get("/jobs?limit=2").json()
        assert page["numberMatched"] == 3 and len(page["jobs"]) == 2
        assert any(link["rel"] == "next" for link in page["links"])
        accepted = client.get("/jobs?status=accepted").json()
        assert {j["jobID"] for j in accepted["jobs"]} == set(ids[1:])
        assert_problem(client.get("/jobs?status=bogus"), 422, "bogus")


def test_api_keys(tmp_path: Path, hall_bytes: bytes) -> None:
    import hashlib

    hashed = "sha256:" + hashlib.sha256(b"bob-key").hexdigest()
    with make_client(tmp_path, InlineQueue(hold=True), api_keys=["alice-key", hashed]) as c:
        alice = {"authorization": "Bearer alice-key"}
        bob = {"authorization": "Bearer bob-key"}
        assert_problem(upload(c, hall_bytes), 401)
        assert_problem(upload(c, hall_bytes, authorization="Bearer wrong"), 401)
        mesh_id = upload(c, hall_bytes, **alice).json()["id"]
        job_id = submit(c, mesh_id, {}, **alice).json()["jobID"]
        assert c.get(f"/jobs/{job_id}", headers=alice).status_code == 200
        assert_problem(c.get(f"/jobs/{job_id}", headers=bob), 404)
        assert_problem(c.get(f"/meshes/{mesh_id}", headers=bob), 404)
        assert c.get("/jobs", headers=bob).json()["numberMatched"] == 0
        assert upload(c, hall_bytes, **bob).status_code == 201  # new to bob
        assert c.get("/healthz").status_code == 200


def test_processes_describe_real_defaults(client: TestClient) -> None:
    assert client.get("/processes").json()["processes"][0]["id"] == "scan-plan"
    schema = client.get("/processes/scan-plan").json()["inputs"]["parameters"]["schema"]
    defaults = PlanSpec()
    for name, prop in schema["properties"].items():
        value = getattr(defaults, name)
        assert prop["default"] == (dict(value) if name == "group_requirements" else value)


def test_process_lists_the_scanner_presets(client: TestClient) -> None:
    scanners = client.get("/processes/scan-plan").json()["scanners"]
    rtc360 = next(s for s in scanners if s["id"] == "leica-rtc360")
    assert rtc360["defaults"]["dof_max_m"] == 130.0
    assert all(s["sources"] or not s["defaults"] for s in scanners)  # no default unsourced
    # the parameter's schema describes the instrument object, with its ranges
    schema = client.get("/processes/scan-plan").json()["inputs"]["parameters"]["schema"]
    profile = schema["$defs"]["ScannerProfileModel"]["properties"]
    assert {"name", "measurement_rate_pts_s", "settings", "overhead_s"} <= set(profile)
    rate = next(s for s in profile["measurement_rate_pts_s"]["anyOf"] if s["type"] == "number")
    assert rate["minimum"] == 1


def test_a_scanner_object_is_accepted(client: TestClient, hall_bytes: bytes) -> None:
    mesh_id = upload(client, hall_bytes).json()["id"]
    scanner = {"name": "crew", "measurement_rate_pts_s": 2e6, "overhead_s": 30, "settings": [
        {"name": "fine", "point_spacing_m": 0.01, "reference_distance_m": 10}]}
    response = submit(client, mesh_id, {"scanner": scanner})
    assert response.status_code == 201, response.text


def test_readyz(client: TestClient) -> None:
    ready = client.get("/readyz")
    assert ready.status_code == 200 and ready.json()["status"] == "ready"


def test_a_model_in_millimetres_is_flagged_before_any_work(client: TestClient) -> None:
    """A 30 m box written in millimetres: the upload and the submission name unit_scale."""
    import trimesh

    box = trimesh.creation.box(extents=(30_000.0, 20_000.0, 5_000.0))
    mesh = upload(client, box.export(file_type="ply")).json()
    assert any("unit_scale" in w and "0.001" in w for w in mesh["warnings"]), mesh
    # as it is, the grid alone would be billions of points: the refusal names unit_scale
    refused = assert_problem(submit(client, mesh["id"], {"max_edge_m": None}), 422,
                             "unit_scale", "0.001")
    assert refused.get("parameter") == "unit_scale", refused
    queued = submit(client, mesh["id"], {"max_edge_m": None, "candidates": [[1e4, 1e4, 1e3]]})
    assert queued.status_code == 201
    assert any("unit_scale" in w for w in queued.json()["warnings"])
    fixed = submit(client, mesh["id"], {"max_edge_m": None, "unit_scale": 0.001})
    assert fixed.status_code == 201
    assert fixed.json()["warnings"] is None


def test_verify_job_option_serves_the_simulated_scan(
        client: TestClient, hall: Path, hall_bytes: bytes, hall_parameters: dict[str, Any],
        tmp_path: Path) -> None:
    """verify: true adds verification.json, the same as `scanplan verify` on that plan."""
    import numpy as np

    from planner.truth.verification import read_plan_dir, verify_plan_dir

    mesh_id = upload(client, hall_bytes).json()["id"]
    created = submit(client, mesh_id, {**hall_parameters, "verify": True})
    assert created.status_code == 201, created.text
    job_id = created.json()["jobID"]
    status = client.get(f"/jobs/{job_id}").json()
    assert status["status"] == "successful", status
    assert "verification" in status["timings_s"]
    results = client.get(f"/jobs/{job_id}/results").json()
    served = client.get(results["verification.json"]["href"]).json()
    # the plan's promise is what it covers; the scan says how much of it arrived
    covered_m2 = results["plan"]["totals"]["covered_area_m2"]
    assert abs(served["totals"]["promised_area_m2"] - covered_m2) < 1e-3 * covered_m2

    spec = PlanSpec.from_mapping(hall_parameters)
    scene = read_scene(hall / "hall.obj", max_edge_m=spec.max_edge_m)
    plan_dir = tmp_path / "plan"
    write_outputs(plan(scene, spec), plan_dir)
    verify_plan_dir(plan_dir, scene, read_plan_dir(plan_dir))
    expected = json.loads((plan_dir / "verification.json").read_text())
    assert served["totals"] == expected["totals"]
    faces = np.load(io.BytesIO(client.get(results["faces.npz"]["href"]).content))
    assert "verified_lpd_pts_m2" in faces.files


def test_a_query_parameter_given_twice_is_refused_unless_it_is_a_list(
        client: TestClient) -> None:
    # FastAPI would keep the last value silently; the schema says one value
    answer = client.post("/meshes?filename=a.obj&filename=b.obj", content=b"v 0 0 0",
                         headers={"content-type": "application/octet-stream"})
    assert_problem(answer, 422, "filename", "more than once")
    assert_problem(client.get("/jobs?limit=2&limit=3"), 422, "limit")
    assert client.get("/jobs?status=accepted&status=running").status_code == 200
    assert_problem(client.get("/jobs?offset=2703897329755260715008&limit=353"), 422, "offset")


def test_the_version_is_the_package_s_everywhere(client: TestClient) -> None:
    version = metadata.version("scanplan")
    assert client.get("/healthz").json() == {"status": "ok", "version": version}
    assert client.get("/openapi.json").json()["info"]["version"] == version
    committed = json.loads((Path(__file__).resolve().parents[2] / "openapi" /
                            "openapi.json").read_text())
    assert committed["info"]["version"] == version


def test_a_budget_of_hours_through_the_api(client: TestClient, hall_bytes: bytes,
                                           hall_parameters: dict[str, Any]) -> None:
    """A crew's morning: the plan's field time fits the hours, one station more would not."""
    mesh_id = upload(client, hall_bytes).json()["id"]
    scanner = {"name": "crew scanner", "measurement_rate_pts_s": 2e6, "overhead_s": 30.0}
    created = submit(client, mesh_id, {**hall_parameters, "scanner": scanner,
                                       "max_field_time_h": 0.25})
    assert created.status_code == 201, created.text
    job_id = created.json()["jobID"]
    assert client.get(f"/jobs/{job_id}").json()["status"] == "successful"
    document = client.get(f"/jobs/{job_id}/results").json()["plan"]
    spent = document["selection"]["budget"]["field_time"]
    assert spent["within"] and spent["max_field_time_h"] == 0.25
    assert document["field_time"]["total_s"] <= 0.25 * 3600
    assert spent["one_station_more_field_time_h"] > 0.25
    assert document["totals"]["stations"] == len(document["stations"]) <= \
        spent["at_most_stations"]
