"""A real ``scanplan serve`` (or ``scanplan worker``) in a subprocess, for e2e tests."""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import httpx

SCANPLAN = str(Path(sys.executable).with_name("scanplan"))
# fast failure detection, so that the kill and restart tests take seconds
FAST = {"SCANPLAN_HEARTBEAT_INTERVAL_S": "0.5", "SCANPLAN_STALE_AFTER_S": "3",
        "SCANPLAN_REAPER_INTERVAL_S": "0.5", "SCANPLAN_WORKER_HEALTH_INTERVAL_S": "1",
        "SCANPLAN_PLAN_THREADS": "1", "SCANPLAN_API_KEYS": ""}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Service:
    """``scanplan serve --port P --data-dir D --workers N`` with its log in ``D.log``."""

    def __init__(self, data_dir: Path, workers: int, env: dict[str, str] | None = None,
                 port: int | None = None) -> None:
        self.data_dir = data_dir
        self.workers = workers
        self.port = port or free_port()
        self.env = {**os.environ, **FAST, **(env or {})}
        self.log = data_dir.with_suffix(".log")
        self.process: subprocess.Popen[bytes] | None = None
        self.url = f"http://127.0.0.1:{self.port}"
        self.sid = 0

    def start(self) -> Service:
        with self.log.open("ab") as log:
            self.process = subprocess.Popen(
                [SCANPLAN, "serve", "--port", str(self.port), "--data-dir",
                 str(self.data_dir), "--workers", str(self.workers)],
                stdout=log, stderr=subprocess.STDOUT, env=self.env, start_new_session=True)
        self.sid = self.process.pid
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                if httpx.get(f"{self.url}/readyz", timeout=2).status_code == 200:
                    return self
            except httpx.HTTPError:
                pass
            assert self.process.poll() is None, self.log.read_text()
            time.sleep(0.2)
        raise AssertionError(f"the service did not become ready:\n{self.log.read_text()}")

    def stop(self) -> None:
        """SIGTERM, as Docker and systemd stop it."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(30)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait()
        self.process = None

    def session_pids(self) -> list[int]:
        """Every live process of the service's session (its own process group leader)."""
        return session_pids(self.sid) if self.sid else []

    def wait_for_workers(self, timeout_s: float = 60.0) -> None:
        """Until the API, the consumer and its ``workers`` processes all run: the consumer
        forks its workers once it has warmed up, a second or more after ``/readyz``."""
        deadline = time.monotonic() + timeout_s
        while len(self.session_pids()) < 2 + self.workers:
            assert time.monotonic() < deadline, "the consumer never started its workers"
            time.sleep(0.1)

    def kill_leftovers(self) -> None:
        """Last-resort cleanup so a failing test never leaves workers behind."""
        for pid in self.session_pids():
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)

    def client(self) -> httpx.Client:
        return httpx.Client(base_url=self.url, timeout=30)

    def worker_pid(self, job_id: str) -> int | None:
        """The pid of the worker process running ``job_id`` (from the job table)."""
        with sqlite3.connect(self.data_dir / "jobs.db") as db:
            row = db.execute("SELECT worker, status FROM jobs WHERE id = ?",
                             (job_id,)).fetchone()
        if row is None or row[0] is None or row[1] != "running":
            return None
        return int(str(row[0]).rsplit(":", 1)[1])


def _live_processes() -> Iterator[tuple[int, int, int]]:
    """(pid, parent pid, session id) of every live (non-zombie) process, from /proc."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if fields[0] != "Z":
            yield int(entry.name), int(fields[1]), int(fields[3])


def session_pids(sid: int) -> list[int]:
    """Live (non-zombie) processes whose session id is ``sid``."""
    return sorted(pid for pid, _, session in _live_processes() if session == sid)


def live_pids(pids: Iterable[int]) -> list[int]:
    """Those of ``pids`` that are live (non-zombie) processes."""
    wanted = set(pids)
    return sorted(pid for pid, _, _ in _live_processes() if pid in wanted)


def child_pids(pid: int) -> list[int]:
    """Live (non-zombie) children of ``pid`` (a worker's planning process)."""
    return sorted(child for child, parent, _ in _live_processes() if parent == pid)


def wait_for(client: httpx.Client, job_id: str, statuses: tuple[str, ...],
             timeout_s: float = 120) -> dict[str, Any]:
    """Poll the job until its status is one of ``statuses``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        status: dict[str, Any] = client.get(f"/jobs/{job_id}").json()
        if status["status"] in statuses:
            return status
        time.sleep(0.2)
    raise AssertionError(f"job {job_id} never reached {statuses}: {status}")
