"""The object store: the data directory and a real S3-compatible server answer alike.

Each contract test runs on both stores; the service tests plan hall-small through an S3
bucket (moto's server on 127.0.0.1) and compare every byte with the embedded mode's.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi import FastAPI, Request, Response
from fastapi.testclient import TestClient
from pydantic import ValidationError

from service.config import Settings
from service.store import LocalStore, ObjectStore, open_store
from tests.s3_server import S3Server
from tests.service.conftest import InlineQueue, make_client, submit, upload

ETAG = '"0123abcd"'


@pytest.fixture
def s3_env(s3_server: S3Server, monkeypatch: pytest.MonkeyPatch) -> str:
    """The standard AWS_* variables pointing at the test server; returns a new bucket."""
    for name, value in s3_server.env().items():
        monkeypatch.setenv(name, value)
    return s3_server.new_bucket()


@pytest.fixture(params=["local", "s3"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> ObjectStore:
    if request.param == "local":
        return LocalStore(tmp_path / "store")
    bucket = request.getfixturevalue("s3_env")
    return open_store(Settings(data_dir=tmp_path, store_url=f"s3://{bucket}/some/prefix"))


def _file(folder: Path, name: str, data: bytes) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_bytes(data)
    return path


def _published(tmp_path: Path, store: ObjectStore, prefix: str,
               files: dict[str, bytes]) -> None:
    folder = tmp_path / f"out-{len(os.listdir(tmp_path))}"
    for name, data in files.items():
        _file(folder, name, data)
    store.publish_folder(folder, prefix)


def test_put_fetch_read_and_missing_keys(store: ObjectStore, tmp_path: Path) -> None:
    store.put_file("meshes/abc/mesh.obj", _file(tmp_path / "up", "mesh.obj", b"v 0 0 0\n"))
    fetched = store.fetch("meshes/abc/mesh.obj", tmp_path / "scratch")
    assert fetched.read_bytes() == b"v 0 0 0\n" and fetched.name == "mesh.obj"
    assert store.read_bytes("meshes/abc/mesh.obj") == b"v 0 0 0\n"
    with pytest.raises(FileNotFoundError):
        store.fetch("meshes/nope/mesh.obj", tmp_path / "scratch2")
    with pytest.raises(FileNotFoundError):
        store.read_bytes("jobs/nope/plan.json")
    store.ping()


def test_delete_prefix_deletes_that_job_only(store: ObjectStore, tmp_path: Path) -> None:
    _published(tmp_path, store, "jobs/ab/", {"plan.json": b"{}"})
    _published(tmp_path, store, "jobs/abc/", {"plan.json": b"[]"})
    store.delete_prefix("jobs/ab/")
    with pytest.raises(FileNotFoundError):
        store.read_bytes("jobs/ab/plan.json")
    assert store.read_bytes("jobs/abc/plan.json") == b"[]"


def test_publish_replaces_an_earlier_attempt(store: ObjectStore, tmp_path: Path) -> None:
    _published(tmp_path, store, "jobs/j1/", {"plan.json": b"old", "a.csv": b"1"})
    _published(tmp_path, store, "jobs/j1/", {"plan.json": b"new", "a.csv": b"2"})
    assert store.read_bytes("jobs/j1/plan.json") == b"new"
    assert store.read_bytes("jobs/j1/a.csv") == b"2"


def test_a_failed_upload_leaves_the_stored_results_intact(
        s3_server: S3Server, s3_env: str, tmp_path: Path) -> None:
    store = open_store(Settings(data_dir=tmp_path, store_url=f"s3://{s3_env}/p"))
    _published(tmp_path, store, "jobs/j1/", {"a.csv": b"first", "b.csv": b"first"})
    broken = tmp_path / "broken"
    _file(broken, "a.csv", b"second")
    (broken / "b.csv").symlink_to(tmp_path / "gone")  # the upload fails on the second file
    with pytest.raises(FileNotFoundError):
        store.publish_folder(broken, "jobs/j1/")
    assert store.read_bytes("jobs/j1/a.csv") == b"first"
    assert store.read_bytes("jobs/j1/b.csv") == b"first"
    assert s3_server.keys(s3_env) == ["p/jobs/j1/a.csv", "p/jobs/j1/b.csv"]  # no temp keys


def _serving_app(store: ObjectStore) -> TestClient:
    app = FastAPI()

    @app.get("/files/{name}")
    def get_file(name: str, request: Request) -> Response:
        answer = store.response(f"jobs/j1/{name}", media_type="text/csv; charset=utf-8",
                                etag=ETAG, filename=name, disposition="inline",
                                request_headers=dict(request.headers))
        return answer if answer is not None else Response(status_code=404)

    return TestClient(app)


DATA = bytes(range(256)) * 40  # 10,240 bytes


@pytest.mark.parametrize(("headers", "status", "body", "content_range"), [
    ({}, 200, DATA, None),
    ({"range": "bytes=10-19"}, 206, DATA[10:20], "bytes 10-19/10240"),
    ({"range": "bytes=10240-"}, 416, b"", "bytes */10240"),
    ({"range": "bytes=-5"}, 206, DATA[-5:], "bytes 10235-10239/10240"),
    ({"range": "bytes=10-19", "if-range": ETAG}, 206, DATA[10:20], "bytes 10-19/10240"),
    ({"range": "bytes=10-19", "if-range": '"other"'}, 200, DATA, None),
], ids=["whole", "range", "past-the-end", "suffix", "if-range-same", "if-range-changed"])
def test_both_stores_serve_the_same_answers(store: ObjectStore, tmp_path: Path,
                                            headers: dict[str, str], status: int, body: bytes,
                                            content_range: str | None) -> None:
    _published(tmp_path, store, "jobs/j1/", {"stations.csv": DATA})
    with _serving_app(store) as client:
        answer = client.get("/files/stations.csv", headers=headers)
        assert answer.status_code == status
        assert answer.headers.get("content-range") == content_range
        if status != 416:
            assert answer.content == body
            assert answer.headers["content-length"] == str(len(body))
            assert answer.headers["etag"] == ETAG
            assert answer.headers["content-type"] == "text/csv; charset=utf-8"
            assert answer.headers["content-disposition"] == 'inline; filename="stations.csv"'
            assert answer.headers["accept-ranges"] == "bytes"
        assert client.get("/files/absent.csv").status_code == 404


def test_the_store_url_is_checked_at_startup(tmp_path: Path) -> None:
    with pytest.raises(ValidationError, match="s3://bucket/prefix"):
        Settings(data_dir=tmp_path, store_url="https://bucket.example.com/prefix")
    assert isinstance(open_store(Settings(data_dir=tmp_path)), LocalStore)



def test_the_settings_load_without_the_store() -> None:
    """Imports go one way: the store reads the settings, the settings never the store."""
    code = ("import sys; from service.config import Settings; "
            "Settings(store_url='s3://bucket/prefix'); "
            "sys.exit('service.store' in sys.modules)")
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0

# ---- the service on an S3 store ---------------------------------------------------------

@pytest.fixture
def s3_client(tmp_path: Path, s3_env: str) -> Iterator[tuple[TestClient, str]]:
    with make_client(tmp_path / "s3", InlineQueue(), api_keys=[],
                     store_url=f"s3://{s3_env}/scanplan") as client:
        yield client, s3_env


def _plan(client: TestClient, hall_bytes: bytes, parameters: dict[str, Any]) -> str:
    mesh_id = upload(client, hall_bytes).json()["id"]
    status = submit(client, mesh_id, parameters).json()
    job = client.get(f"/jobs/{status['jobID']}").json()
    assert job["status"] == "successful", job
    return str(job["jobID"])


def test_a_plan_through_s3_has_the_embedded_modes_bytes(
        s3_client: tuple[TestClient, str], s3_server: S3Server, tmp_path: Path,
        hall_bytes: bytes, hall_parameters: dict[str, Any]) -> None:
    client, bucket = s3_client
    job_id = _plan(client, hall_bytes, hall_parameters)
    with make_client(tmp_path / "local", InlineQueue(), api_keys=[]) as local:
        local_id = _plan(local, hall_bytes, hall_parameters)
        expected = local.get(f"/jobs/{local_id}/results").json()
        results = client.get(f"/jobs/{job_id}/results").json()
        assert results["plan"] == expected["plan"]
        names = sorted(name for name in expected if name != "plan")
        assert sorted(name for name in results if name != "plan") == names
        for name in names:
            served = client.get(results[name]["href"])
            embedded = local.get(expected[name]["href"])
            assert served.status_code == 200, name
            assert served.content == embedded.content, name
            assert served.headers["content-type"] == embedded.headers["content-type"], name
            assert served.headers["etag"] == embedded.headers["etag"], name

    mesh_id = client.get(f"/jobs/{job_id}").json()["mesh"]
    content = client.get(f"/meshes/{mesh_id}/content")
    assert content.content == hall_bytes
    assert content.headers["content-disposition"] == 'attachment; filename="hall.obj"'
    # every file is in the bucket; the data directory holds only the (empty) scratch
    keys = s3_server.keys(bucket)
    assert f"scanplan/meshes/{mesh_id}/mesh.obj" in keys
    assert {f"scanplan/jobs/{job_id}/{name}" for name in names} <= set(keys)
    assert not any(".tmp-" in key for key in keys)
    data = tmp_path / "s3" / "data"
    assert not (data / "meshes").exists()
    assert list((data / "jobs").iterdir()) == []
    # deleting the job deletes its objects; deleting the mesh deletes its object
    assert client.delete(f"/jobs/{job_id}").status_code == 200
    assert client.delete(f"/jobs/{job_id}").status_code == 404
    assert s3_server.keys(bucket, f"scanplan/jobs/{job_id}/") == []
    assert client.delete(f"/meshes/{mesh_id}").status_code == 204
    assert s3_server.keys(bucket) == []


def test_a_corrupted_mesh_object_fails_the_job_with_the_reason(
        s3_client: tuple[TestClient, str], s3_server: S3Server, hall_bytes: bytes,
        hall_parameters: dict[str, Any]) -> None:
    client, bucket = s3_client
    mesh_id = upload(client, hall_bytes).json()["id"]
    s3_server.client().put_object(Bucket=bucket, Key=f"scanplan/meshes/{mesh_id}/mesh.obj",
                                  Body=hall_bytes[:-10])
    job = client.get(f"/jobs/{submit(client, mesh_id, hall_parameters).json()['jobID']}")
    assert job.json()["status"] == "failed"
    assert "do not match its sha256" in job.json()["message"]


def test_readyz_names_a_missing_bucket(tmp_path: Path, s3_env: str) -> None:
    with make_client(tmp_path, InlineQueue(), api_keys=[],
                     store_url="s3://no-such-bucket-here/x") as client:
        ready = client.get("/readyz")
        assert ready.status_code == 503
        assert "store" in ready.json()["detail"]
