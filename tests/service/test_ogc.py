"""OGC API - Processes Part 1 Core, field by field where a client depends on it."""

from __future__ import annotations

from fastapi.testclient import TestClient

from tests.service.conftest import submit, upload

OGC_REL = "http://www.opengis.net/def/rel/ogc/1.0/"


def test_landing_page_is_json_for_clients_and_html_for_browsers(client: TestClient) -> None:
    for request in ({"headers": {"accept": "application/json"}}, {"params": {"f": "json"}},
                    {}):
        answer = client.get("/", **request)  # type: ignore[arg-type]
        assert answer.headers["content-type"] == "application/json", request
        links = {link["rel"]: link for link in answer.json()["links"]}
        for rel in ("self", "service-desc", "service-doc", OGC_REL + "conformance",
                    OGC_REL + "processes", OGC_REL + "job-list"):
            assert rel in links, rel
        assert links["service-desc"]["type"].startswith("application/vnd.oai.openapi+json")
        assert client.get(links["service-desc"]["href"]).json()["openapi"].startswith("3.")
    page = client.get("/", headers={"accept": "text/html,application/xhtml+xml,*/*;q=0.8"})
    assert page.headers["content-type"].startswith("text/html")
    assert client.get("/?f=html").headers["content-type"].startswith("text/html")


def test_conformance_lists_what_is_implemented(client: TestClient) -> None:
    classes = client.get("/conformance").json()["conformsTo"]
    base = "http://www.opengis.net/spec/ogcapi-processes-1/1.0/conf/"
    assert base + "core" in classes and base + "dismiss" in classes
    assert base + "callback" not in classes and base + "html" not in classes


def test_status_and_results_follow_the_standard(client: TestClient, hall_bytes: bytes,
                                                hall_parameters: dict[str, object]) -> None:
    mesh = upload(client, hall_bytes).json()["id"]
    created = client.post("/processes/scan-plan/execution",
                          json={"inputs": {"mesh": mesh, "parameters": hall_parameters},
                                "response": "document"},
                          headers={"Prefer": "respond-async"})
    assert created.status_code == 201
    assert created.headers["Preference-Applied"] == "respond-async"
    status = client.get(created.headers["location"]).json()
    # statusInfo.yaml: required jobID, status, type; progress 0-100; a results link
    assert status["type"] == "process" and status["processID"] == "scan-plan"
    assert status["status"] == "successful" and status["progress"] == 100
    assert any(link["rel"] == OGC_REL + "results" for link in status["links"])
    results = client.get(f"/jobs/{status['jobID']}/results").json()
    # results.yaml: output id -> inline value or link
    description = client.get("/processes/scan-plan").json()
    assert set(results) <= set(description["outputs"])
    assert all("href" in ref for name, ref in results.items() if name != "plan")


def test_unknown_process_is_ogc_no_such_process(client: TestClient) -> None:
    answer = client.get("/processes/other")
    assert answer.status_code == 404
    assert answer.json()["type"].endswith("no-such-process")
    assert submit(client, "0" * 64, {}).json()["detail"].startswith("inputs.mesh")


def test_wrong_method_names_every_allowed_one(client: TestClient) -> None:
    answer = client.request("OPTIONS", "/jobs/abc")
    assert answer.status_code == 405
    assert {m.strip() for m in answer.headers["allow"].split(",")} >= {"GET", "DELETE"}
