"""Callbacks: a real HTTP receiver on 127.0.0.1 gets signed status documents.

The service runs as in the other service tests (the app's lifespan starts the callback
dispatcher); the plan runs for real. No traffic leaves the loopback interface: the
refused addresses are refused before any connection, and the one test that needs a DNS
name answers it with a resolver that returns loopback or private addresses.
"""

from __future__ import annotations

import hashlib
import hmac
import itertools
import json
import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from datetime import datetime
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from service.callbacks import SIGNATURE_HEADER, CallbackDispatcher, CallbackStore, Delivery
from service.config import Settings
from service.database import make_engine
from service.worker import execute_job
from tests.service.conftest import InlineQueue, make_client, submit, upload

SECRET = "receiver-and-service-share-this"
CALLBACK_SETTINGS: dict[str, Any] = {
    "callback_secret": SECRET, "callback_allow": ["127.0.0.0/8"],
    "callback_poll_interval_s": 0.05, "callback_progress_interval_s": 0.3,
    "callback_retry_base_s": 0.1, "callback_timeout_s": 5.0,
    "worker_nice": 0,  # the plan need not yield to the API here
}


@dataclass
class Received:
    path: str
    headers: dict[str, str]
    body: bytes

    def json(self) -> Any:
        return json.loads(self.body)


@dataclass
class Receiver:
    """A webhook receiver: records every POST; ``answers[path]`` lists the statuses to
    answer in turn (then 204)."""

    server: ThreadingHTTPServer
    received: list[Received] = field(default_factory=list)
    answers: dict[str, list[int]] = field(default_factory=dict)

    @property
    def base(self) -> str:
        host, port = self.server.server_address[:2]
        return f"http://{host!s}:{port}"

    def at(self, path: str) -> list[Received]:
        return [r for r in self.received if r.path == path]

    def wait_for(self, ready: Callable[[], bool], timeout_s: float = 30.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not ready():
            if time.monotonic() > deadline:
                raise AssertionError(f"no such callback; received: {self.received}")
            time.sleep(0.02)


@pytest.fixture
def receiver() -> Iterator[Receiver]:
    state: dict[str, Receiver] = {}

    class Handler(BaseHTTPRequestHandler):
        def do_POST(self) -> None:
            body = self.rfile.read(int(self.headers["content-length"]))
            rec = state["r"]
            rec.received.append(Received(self.path, dict(self.headers.items()), body))
            statuses = rec.answers.get(self.path, [])
            code = statuses.pop(0) if statuses else 204
            self.send_response(code)
            if code in (301, 302, 307, 308):
                self.send_header("Location", "/elsewhere")
            self.send_header("Content-Length", "0")
            self.end_headers()

        def log_message(self, *_args: object) -> None:
            return None

    server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
    state["r"] = rec = Receiver(server)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield rec
    server.shutdown()
    server.server_close()


def signed_by_secret(received: Received) -> bool:
    """What a receiver checks: the header is the HMAC-SHA256 of the raw body."""
    expected = "sha256=" + hmac.new(SECRET.encode(), received.body, hashlib.sha256).hexdigest()
    return hmac.compare_digest(received.headers[SIGNATURE_HEADER], expected)


def _execute(client: TestClient, mesh: str, parameters: dict[str, Any],
             subscriber: dict[str, str]) -> Any:
    return client.post("/processes/scan-plan/execution",
                       json={"inputs": {"mesh": mesh, "parameters": parameters},
                             "subscriber": subscriber})


def test_success_and_progress_are_posted_signed(tmp_path: Path, receiver: Receiver,
                                                hall_bytes: bytes,
                                                hall_parameters: dict[str, Any]) -> None:
    queue = InlineQueue(hold=True)  # the test runs the job, the dispatcher watches it
    with make_client(tmp_path, queue, **CALLBACK_SETTINGS) as client:
        assert client.get("/conformance").json()["conformsTo"][-1].endswith("/conf/callback")
        mesh = upload(client, hall_bytes).json()["id"]
        created = _execute(client, mesh, hall_parameters, {
            "successUri": receiver.base + "/done?batch=7",
            "inProgressUri": receiver.base + "/progress", "failedUri": receiver.base + "/fail"})
        assert created.status_code == 201, created.text
        job_id = created.json()["jobID"]
        assert queue.ctx is not None
        execute_job(queue.ctx, job_id)
        receiver.wait_for(lambda: bool(receiver.at("/done?batch=7")))

        [done] = receiver.at("/done?batch=7")
        assert signed_by_secret(done)
        assert done.headers["X-Scanplan-Event"] == "success"
        assert done.headers["X-Scanplan-Job"] == job_id
        status = done.json()
        assert status["jobID"] == job_id and status["status"] == "successful"
        links = {link["title"]: link["href"] for link in status["links"]}
        # absolute links, as the submitter reached the API, to the results and every file
        assert links["results"] == f"http://testserver/jobs/{job_id}/results"
        assert links["plan.json"] == f"http://testserver/jobs/{job_id}/results/plan.json"
        plan = client.get(links["plan.json"].removeprefix("http://testserver"))
        assert plan.status_code == 200 and plan.json()["stations"]

        progress = receiver.at("/progress")
        assert progress, "the stage changes of a running job reach inProgressUri"
        assert all(signed_by_secret(p) and p.headers["X-Scanplan-Event"] == "inProgress"
                   for p in progress)
        assert all(p.json()["status"] == "running" for p in progress)
        assert not receiver.at("/fail")

        record = client.get(f"/jobs/{job_id}/callbacks").json()
        assert record["subscriber"]["successUri"] == receiver.base + "/done?batch=7"
        success = [d for d in record["deliveries"] if d["event"] == "success"]
        assert [(d["state"], d["attempts"], d["last_status_code"]) for d in success] == [
            ("delivered", 1, 204)]
        assert success[0]["history"][0]["address"] == "127.0.0.1"
        # at most one inProgress callback per interval (the records' own timestamps)
        times = sorted(datetime.fromisoformat(d["created"]).timestamp()
                       for d in record["deliveries"] if d["event"] == "inProgress")
        assert all(b - a >= 0.3 - 1e-3 for a, b in itertools.pairwise(times))


def test_failure_is_posted_with_its_problem_and_retried(
        tmp_path: Path, receiver: Receiver, hall_bytes: bytes) -> None:
    queue = InlineQueue()
    receiver.answers["/failed"] = [503]  # the receiver is down for the first attempt
    with make_client(tmp_path, queue, **CALLBACK_SETTINGS) as client:
        mesh = upload(client, hall_bytes).json()["id"]
        # a scanner far outside the hall sees nothing: the job fails in the worker
        created = _execute(client, mesh, {"max_edge_m": None,
                                          "candidates": [[500.0, 500.0, 500.0]]},
                           {"successUri": receiver.base + "/ok",
                            "failedUri": receiver.base + "/failed"})
        assert created.status_code == 201, created.text
        job_id = created.json()["jobID"]
        assert client.get(f"/jobs/{job_id}").json()["status"] == "failed"
        receiver.wait_for(lambda: len(receiver.at("/failed")) == 2)

        first, second = receiver.at("/failed")
        assert first.body == second.body, "a retry sends the same document"
        assert first.headers["X-Scanplan-Delivery"] == second.headers["X-Scanplan-Delivery"]
        assert signed_by_secret(second)
        status = second.json()
        assert status["status"] == "failed"
        assert status["problem"]["status"] == 422 and status["problem"]["detail"]
        assert not receiver.at("/ok")

        receiver.wait_for(lambda: client.get(f"/jobs/{job_id}/callbacks").json()
                          ["deliveries"][0]["state"] == "delivered")
        [delivery] = client.get(f"/jobs/{job_id}/callbacks").json()["deliveries"]
        assert delivery["attempts"] == 2 and delivery["last_status_code"] == 204
        assert [a["status_code"] for a in delivery["history"]] == [503, 204]
        assert delivery["history"][0]["error"].startswith("HTTP 503")

        # deleting the finished job drops its callback records with it
        assert client.delete(f"/jobs/{job_id}").status_code == 200
        store: CallbackStore = client.app.state.services.callbacks  # type: ignore[attr-defined]
        store.purge_deleted()
        assert store.deliveries_of(job_id) == [] and store.subscription(job_id) is None


REFUSED = ["http://10.0.0.1/hook", "http://localhost/hook", "http://127.0.0.1:9/hook",
           "http://[::1]/hook", "http://169.254.169.254/latest/meta-data/",
           "http://[::ffff:192.168.0.1]/", "http://0.0.0.0/", "ftp://example.com/hook",
           "http://user:pw@127.0.0.1/", "not a uri", "http:///no-host"]


def test_a_private_or_odd_uri_is_refused_at_submission(tmp_path: Path,
                                                       hall_bytes: bytes) -> None:
    queue = InlineQueue(hold=True)
    settings = {**CALLBACK_SETTINGS, "callback_allow": []}
    with make_client(tmp_path, queue, **settings) as client:
        mesh = upload(client, hall_bytes).json()["id"]
        for uri in REFUSED:
            # a public address literal: checked without DNS, and nothing is ever sent to it
            refused = _execute(client, mesh, {}, {"successUri": "https://9.9.9.9/",
                                                  "failedUri": uri})
            assert refused.status_code == 422, uri
            assert refused.headers["content-type"] == "application/problem+json"
            problem = refused.json()
            assert problem["type"] == "urn:scanplan:problem:callback-refused", uri
            assert problem["parameter"] == "subscriber.failedUri", uri
            assert uri in problem["detail"]
        assert client.get("/jobs").json()["numberMatched"] == 0 and not queue.enqueued


def test_without_a_secret_no_callback_is_accepted(tmp_path: Path, hall_bytes: bytes) -> None:
    queue = InlineQueue(hold=True)
    with make_client(tmp_path, queue) as client:
        mesh = upload(client, hall_bytes).json()["id"]
        refused = _execute(client, mesh, {}, {"successUri": "https://9.9.9.9/"})
        assert refused.status_code == 422 and refused.json()["parameter"] == "subscriber"
        assert "SCANPLAN_CALLBACK_SECRET" in refused.json()["detail"]
        assert not client.get("/conformance").json()["conformsTo"][-1].endswith("callback")
        assert submit(client, mesh, {}).status_code == 201, "no subscriber: as before"


def _dispatcher(tmp_path: Path, **overrides: Any) -> CallbackDispatcher:
    settings = Settings(data_dir=tmp_path, **{**CALLBACK_SETTINGS, **overrides})
    store = CallbackStore(make_engine(f"sqlite:///{tmp_path / 'jobs.db'}"))
    return CallbackDispatcher(store, settings, render=lambda job, base: {})


def _delivery(uri: str) -> Delivery:
    return Delivery(id="d" * 32, job_id="j" * 32, event="success", uri=uri,
                    body=b'{"status":"successful"}', attempts=0, history=[])


def test_delivery_checks_the_address_again_and_connects_to_it(
        tmp_path: Path, receiver: Receiver, monkeypatch: pytest.MonkeyPatch) -> None:
    port = receiver.server.server_address[1]
    answers = {"hook.example": "127.0.0.1"}
    real = socket.getaddrinfo

    def resolver(host: Any, *args: Any, **kwargs: Any) -> Any:
        if host in answers:  # a DNS name whose answer the test controls
            return [(socket.AF_INET, socket.SOCK_STREAM, 6, "", (answers[host], port))]
        return real(host, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", resolver)
    dispatcher = _dispatcher(tmp_path)
    try:
        attempt = dispatcher.post(_delivery(f"http://hook.example:{port}/pinned"))
        assert attempt["status_code"] == 204 and attempt["address"] == "127.0.0.1"
        [pinned] = receiver.at("/pinned")
        assert pinned.headers["Host"] == f"hook.example:{port}", "the URI's host, not the IP"

        answers["hook.example"] = "10.1.2.3"  # the name now points into the network
        attempt = dispatcher.post(_delivery(f"http://hook.example:{port}/rebound"))
        assert attempt["status_code"] is None and "10.1.2.3 is a private address" in \
            attempt["error"]
        assert not receiver.at("/rebound")
    finally:
        dispatcher.stop()


def test_redirects_are_not_followed(tmp_path: Path, receiver: Receiver) -> None:
    receiver.answers["/moved"] = [302]
    dispatcher = _dispatcher(tmp_path)
    try:
        attempt = dispatcher.post(_delivery(receiver.base + "/moved"))
    finally:
        dispatcher.stop()
    assert attempt["status_code"] == 302 and "not followed" in attempt["error"]
    assert not receiver.at("/elsewhere")
