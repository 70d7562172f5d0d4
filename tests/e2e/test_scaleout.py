"""Scale-out: API and a separate ``scanplan worker`` over Redis (queue), PostgreSQL (job
table) and an S3-compatible store (meshes, results), each process with a data dir of its own.

Needs Redis on 127.0.0.1:6379 and PostgreSQL on 127.0.0.1:5432 (database ``test``, trust
auth); skipped with the reason otherwise. The S3 server is moto's, started by the test
(``tests/s3_server.py``). Each run uses a database, a Redis db and a bucket of its own,
dropped afterwards.
"""

from __future__ import annotations

import contextlib
import getpass
import os
import signal
import socket
import subprocess
import uuid
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.e2e.service_process import FAST, SCANPLAN, Service, wait_for
from tests.e2e.test_service_e2e import _parameters, _scene, _submit
from tests.s3_server import S3Server

pytestmark = pytest.mark.scaleout


def _open(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(1)
        return s.connect_ex(("127.0.0.1", port)) == 0


def _admin_url() -> str | None:
    import sqlalchemy

    for user in ("postgres", getpass.getuser(), "root"):
        url = f"postgresql+psycopg://{user}@127.0.0.1:5432/test"
        try:
            engine = sqlalchemy.create_engine(url, isolation_level="AUTOCOMMIT")
            with engine.connect() as conn:
                conn.execute(sqlalchemy.text("SELECT 1"))
            engine.dispose()
            return url
        except Exception:
            continue
    return None


@pytest.fixture
def backends() -> Iterator[dict[str, str]]:
    if not _open(6379):
        pytest.skip("scale-out: no Redis on 127.0.0.1:6379")
    if not _open(5432):
        pytest.skip("scale-out: no PostgreSQL on 127.0.0.1:5432")
    admin = _admin_url()
    if admin is None:
        pytest.skip("scale-out: cannot log in to PostgreSQL database 'test' (trust auth)")
    import redis
    import sqlalchemy

    name = f"scanplan_{uuid.uuid4().hex[:12]}"
    engine = sqlalchemy.create_engine(admin, isolation_level="AUTOCOMMIT")
    with engine.connect() as conn:
        conn.execute(sqlalchemy.text(f'CREATE DATABASE "{name}"'))
    queue_db = 13
    redis.Redis(host="127.0.0.1", port=6379, db=queue_db).delete("huey.redis.scanplan")
    try:
        yield {"SCANPLAN_DATABASE_URL": admin.rsplit("/", 1)[0] + f"/{name}",
               "SCANPLAN_QUEUE_URL": f"redis://127.0.0.1:6379/{queue_db}"}
    finally:
        with engine.connect() as conn:
            conn.execute(sqlalchemy.text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
        engine.dispose()


def _outputs(client: httpx.Client, job_id: str) -> dict[str, tuple[bytes, str]]:
    """Every output file of a successful job: name -> (bytes, media type)."""
    results = client.get(f"/jobs/{job_id}/results").json()
    files = {}
    for name, ref in results.items():
        if name != "plan":
            served = client.get(ref["href"])
            assert served.status_code == 200, (name, served.text)
            files[name] = (served.content, served.headers["content-type"])
    return files


def test_api_and_separate_workers_share_no_disk(backends: dict[str, str], tmp_path: Path,
                                                s3_server: S3Server) -> None:
    """The API and a worker, each with its own data dir, meet only in Redis, PostgreSQL and
    the bucket; jobs of two keys succeed with the embedded mode's bytes."""
    hall = _scene("hall-small")
    few = {"candidates": _parameters(hall)["candidates"][:10]}  # fast: 2 stations of 10
    bucket = s3_server.new_bucket()
    scale = {**backends, **s3_server.env(), "SCANPLAN_STORE_URL": f"s3://{bucket}/scanplan",
             "SCANPLAN_API_KEYS": "key-a,key-b"}
    api_dir, worker_dir = tmp_path / "api", tmp_path / "worker"
    api = Service(api_dir, workers=0, env=scale).start()  # API only
    embedded = Service(tmp_path / "embedded", workers=1).start()  # local files, SQLite
    env = {**os.environ, **FAST, **scale}
    with (tmp_path / "worker.log").open("wb") as log:
        worker = subprocess.Popen([SCANPLAN, "worker", "--data-dir", str(worker_dir),
                                   "--workers", "2"], stdout=log, stderr=subprocess.STDOUT,
                                  env=env, start_new_session=True)
    clients = contextlib.ExitStack()
    try:
        jobs = {}
        for key in ("key-a", "key-b"):
            client = clients.enter_context(api.client())
            client.headers["Authorization"] = f"Bearer {key}"
            assert client.get("/readyz").json()["checks"]["store"] == "ok"
            jobs[key] = (client, _submit(client, hall, **few))
        with embedded.client() as local:
            expected = _outputs(local, _finished(local, _submit(local, hall, **few)))
        for client, job_id in jobs.values():
            _finished(client, job_id, tmp_path / "worker.log")
            assert _outputs(client, job_id) == expected
            mesh_id = client.get(f"/jobs/{job_id}").json()["mesh"]
            content = client.get(f"/meshes/{mesh_id}/content")
            assert content.content == (hall / "hall.obj").read_bytes()
        keys = s3_server.keys(bucket)
        for _, job_id in jobs.values():
            assert {f"scanplan/jobs/{job_id}/{name}" for name in expected} <= set(keys)
        assert not (api_dir / "jobs.db").exists(), "the job table must be in PostgreSQL"
        assert not (api_dir / "meshes").exists() and not (api_dir / "jobs").exists()
        assert not (worker_dir / "meshes").exists()
        assert list((worker_dir / "jobs").iterdir()) == [], "the worker's scratch is left"
    finally:
        clients.close()
        os.killpg(worker.pid, signal.SIGTERM)
        worker.wait(30)
        api.stop()
        embedded.stop()


def _finished(client: httpx.Client, job_id: str, log: Path | None = None) -> str:
    status = wait_for(client, job_id, ("successful", "failed"), 120)
    assert status["status"] == "successful", (status, log.read_text() if log else "")
    return job_id


def test_api_and_separate_workers(backends: dict[str, str], tmp_path: Path) -> None:
    hall = _scene("hall-small")
    data = tmp_path / "shared"
    api = Service(data, workers=0, env=backends).start()  # API only
    env = {**os.environ, **FAST, **backends}
    with (tmp_path / "worker.log").open("wb") as log:
        worker = subprocess.Popen([SCANPLAN, "worker", "--data-dir", str(data), "--workers",
                                   "1"], stdout=log, stderr=subprocess.STDOUT, env=env,
                                  start_new_session=True)
    try:
        with api.client() as client:
            assert client.get("/readyz").json()["status"] == "ready"
            job_ids = [_submit(client, hall) for _ in range(2)]
            for job_id in job_ids:
                status = wait_for(client, job_id, ("successful", "failed"), 120)
                assert status["status"] == "successful", (
                    status, (tmp_path / "worker.log").read_text())
        assert not (data / "jobs.db").exists(), "the job table must be in PostgreSQL"
    finally:
        os.killpg(worker.pid, signal.SIGTERM)
        worker.wait(30)
        api.stop()
