"""A corpus of hostile inputs against ``scanplan serve``: each gets a 4xx problem or a failed
job, and the service answers its health check after every one."""

from __future__ import annotations

import json
from typing import Any

import httpx
import pytest

from planner.version import __version__
from tests.data_files import HALL_SMALL as HALL
from tests.e2e.service_process import Service, wait_for

FINISHED = ("successful", "failed", "dismissed")
PNG = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x01\x00\x00\x00\x01\x08\x00\x00\x00"


@pytest.fixture(scope="module")
def service(tmp_path_factory: pytest.TempPathFactory) -> Any:
    running = Service(tmp_path_factory.mktemp("hostile") / "data", workers=1,
                      env={"SCANPLAN_JOB_MEMORY_LIMIT_MB": "3072"}).start()
    yield running
    running.stop()
    running.kill_leftovers()


@pytest.fixture(scope="module")
def mesh(service: Service) -> str:
    answer = httpx.post(f"{service.url}/meshes?filename=hall.obj",
                        content=(HALL / "hall.obj").read_bytes(),
                        headers={"content-type": "application/octet-stream"})
    return str(answer.json()["id"])


def _healthy(service: Service) -> None:
    answer = httpx.get(f"{service.url}/healthz", timeout=5).json()
    assert answer == {"status": "ok", "version": __version__}


def _problem(answer: httpx.Response, *statuses: int) -> dict[str, Any]:
    assert answer.status_code in statuses, (answer.status_code, answer.text[:300])
    assert answer.headers["content-type"] == "application/problem+json"
    document: dict[str, Any] = answer.json()
    assert document["status"] == answer.status_code and document["detail"]
    return document


def _execute(service: Service, body: bytes | dict[str, Any]) -> httpx.Response:
    content = body if isinstance(body, bytes) else json.dumps(body).encode()
    return httpx.post(f"{service.url}/processes/scan-plan/execution", content=content,
                      headers={"content-type": "application/json"}, timeout=60)


PARAMETERS_REFUSED = [
    ({"max_edge_m": 1e-9}, "max_edge_m"),  # tiny spacing: ~1e20 faces
    ({"grid_spacing_m": 1e-9}, "grid_spacing_m"),
    ({"grid_spacing_m": 5e-324}, "grid_spacing_m"),  # the smallest float: inf points
    ({"max_edge_m": None, "unit_scale": 1e300}, "unit_scale"),  # light-years wide: the unit
    ({"coverage_goal": 0}, "coverage_goal"),
    ({"dof_min_m": 60}, "dof_min_m"),  # beyond dof_max_m
    ({"candidates": []}, "candidates"),
    ({"method": "../../etc/passwd"}, "method"),
]


@pytest.mark.parametrize(("parameters", "parameter"), PARAMETERS_REFUSED)
def test_bad_parameters_are_refused_before_queueing(
        service: Service, mesh: str, parameters: dict[str, Any], parameter: str) -> None:
    document = _problem(_execute(service, {"inputs": {"mesh": mesh,
                                                      "parameters": parameters}}), 422)
    assert document.get("parameter") == parameter, document
    _healthy(service)


def test_malformed_bodies_are_refused(service: Service, mesh: str) -> None:
    nan = b'{"inputs": {"mesh": "' + mesh.encode() + b'", "parameters": {"coverage_goal": NaN}}}'
    _problem(_execute(service, nan), 422)
    _problem(_execute(service, b"[" * 100_000 + b"]" * 100_000), 400, 422)
    _problem(_execute(service, b'{"inputs": ' + b'{"a": ' * 20_000 + b"1" + b"}" * 20_001),
             400, 422)
    _problem(_execute(service, b"\xff\xfe not json"), 400, 422)
    million = b'{"inputs": {"mesh": "%s", "parameters": {"candidates": [' % mesh.encode() \
        + b",".join([b"[1.0, 1.0, 1.5]"] * 1_000_000) + b"]}}}"
    _problem(_execute(service, million), 413)
    _healthy(service)


def test_hostile_uploads_are_refused_or_stored_safely(service: Service) -> None:
    hall = (HALL / "hall.obj").read_bytes()
    url = f"{service.url}/meshes"
    octet = {"content-type": "application/octet-stream"}
    _problem(httpx.post(url, content=hall[: len(hall) // 3], headers=octet), 422)  # truncated
    _problem(httpx.post(f"{url}?filename=hall.obj", content=PNG, headers=octet), 415)
    _problem(httpx.post(url, content=b"glTF\x02\x00\x00\x00" + b"\x00" * 40, headers=octet),
             415, 422)  # a GLB header with nothing behind it
    _problem(httpx.post(url, content=b"ply\nformat binary_little_endian 1.0\nelement vertex "
                        b"99999999\nproperty float x\nend_header\n\x00\x00", headers=octet),
             415, 422)  # a PLY that promises 1e8 vertices
    _problem(httpx.post(url, files={"file": ("x.obj", b"")},), 422)
    _problem(httpx.post(url, content=b"--x\r\nNone--x--\r\n",
                        headers={"content-type": "multipart/form-data; boundary=x"}), 400)
    for name in ("../../../../etc/passwd", "/etc/passwd", "..\\..\\win.ini", "a/b/../c.obj"):
        stored = httpx.post(url, params={"filename": name}, content=hall, headers=octet)
        assert stored.status_code in (200, 201), stored.text
        assert "/" not in (stored.json()["filename"] or "") and ".." not in stored.json()[
            "filename"]
    _problem(httpx.get(f"{url}/..%2F..%2Fjobs.db"), 404)
    _healthy(service)


def test_jobs_that_pass_the_guards_end_as_successful_or_failed(
        service: Service, mesh: str) -> None:
    """Absurd numbers are refused naming the parameter; the largest the schema allows run
    and end; the worker stays for the next."""
    for name, parameters in (("dof_max_m", {"dof_max_m": 1e300}),
                             ("grid_spacing_m", {"grid_spacing_m": 1e300}),
                             ("candidates", {"candidates": [[1e300, -1e300, 1e300]]}),
                             ("min_density_pts_m2", {"min_density_pts_m2": 1e300})):
        answer = _execute(service, {"inputs": {"mesh": mesh, "parameters": parameters}})
        assert _problem(answer, 422)["parameter"].startswith(name), answer.text
    jobs = []
    for parameters in ({"max_edge_m": None, "dof_max_m": 10_000.0},
                       {"max_edge_m": None, "grid_spacing_m": 10_000.0},
                       {"max_edge_m": None, "candidates": [[1e12, -1e12, 1e12]]},
                       {"max_edge_m": 10_000.0, "min_density_pts_m2": 1e9}):
        answer = _execute(service, {"inputs": {"mesh": mesh, "parameters": parameters}})
        assert answer.status_code == 201, answer.text
        jobs.append(answer.json()["jobID"])
    with service.client() as client:
        for job_id in jobs:
            status = wait_for(client, job_id, FINISHED, timeout_s=120)
            assert status["status"] in ("successful", "failed"), status
            if status["status"] == "failed":
                assert 400 <= status["problem"]["status"] < 600 and status["problem"]["detail"]
            _healthy(service)
