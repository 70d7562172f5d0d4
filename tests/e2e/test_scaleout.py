"""Scale-out: API and a separate ``scanplan worker`` over Redis (queue) and PostgreSQL.

Needs Redis on 127.0.0.1:6379 and PostgreSQL on 127.0.0.1:5432 (database ``test``, trust
auth); skipped with the reason otherwise. Each run uses a database and a Redis db of its
own, dropped afterwards.
"""

from __future__ import annotations

import getpass
import os
import signal
import socket
import subprocess
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.e2e.service_process import FAST, SCANPLAN, Service, wait_for
from tests.e2e.test_service_e2e import _scene, _submit

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
