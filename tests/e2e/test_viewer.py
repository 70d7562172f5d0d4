"""The viewer page in a real headless Chromium against the real app.

The app (``create_app`` with an inline job runner) is served by uvicorn in a thread on a
free port; Playwright drives Debian's ``/usr/bin/chromium``. Without a browser the test
tries ``apt-get install chromium chromium-driver`` (as root, time-limited) and otherwise
skips with the reason printed.
"""

from __future__ import annotations

import csv
import os
import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

pytestmark = pytest.mark.browser

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]


def find_browser() -> str:
    """The Chromium binary, installed on the spot when possible; skip with the reason."""
    if os.path.exists(CHROMIUM):
        return CHROMIUM
    reason = f"no browser at {CHROMIUM}"
    if hasattr(os, "geteuid") and os.geteuid() == 0 and shutil.which("apt-get"):
        env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
        try:
            subprocess.run(["apt-get", "update", "-q"], check=True, timeout=300, env=env,
                           capture_output=True)
            subprocess.run(["apt-get", "install", "-y", "-q", "chromium", "chromium-driver"],
                           check=True, timeout=600, env=env, capture_output=True)
        except (subprocess.SubprocessError, OSError) as err:
            reason += f"; apt-get install chromium chromium-driver failed: {err}"
        if os.path.exists(CHROMIUM):
            return CHROMIUM
    else:
        reason += "; not root, so it cannot be installed here (apt-get install chromium)"
    print(f"SKIP browser test: {reason}")
    pytest.skip(reason)


class InlineQueue:
    """Runs a job right away in the calling thread; ``hold``: leaves it queued."""

    def __init__(self) -> None:
        self.ctx: Any = None
        self.hold = False

    def enqueue(self, job_id: str) -> None:
        if not self.hold and self.ctx is not None:
            from service.worker import execute_job

            execute_job(self.ctx, job_id)

    def ping(self) -> None:
        return None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, scenes_dir: Path
           ) -> Iterator[tuple[str, InlineQueue]]:
    import uvicorn

    from service.config import Settings
    from service.main import create_app
    from service.worker import build_context

    settings = Settings(data_dir=tmp_path_factory.mktemp("data"), workers=1, api_keys=[])
    queue = InlineQueue()
    queue.ctx = build_context(settings, queue)
    app = create_app(settings, queue=queue, reaper=False)
    port = free_port()
    config = uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning")
    uv = uvicorn.Server(config)
    thread = threading.Thread(target=uv.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not uv.started:
        assert time.monotonic() < deadline, "uvicorn did not start"
        time.sleep(0.05)
    try:
        yield f"http://127.0.0.1:{port}", queue
    finally:
        uv.should_exit = True
        thread.join(10)


def submit(base: str, scenes_dir: Path, **changes: Any) -> str:
    hall = scenes_dir / "hall-small"
    with (hall / "candidates.csv").open() as handle:
        candidates = [[float(r["x"]), float(r["y"]), float(r["z"])]
                      for r in csv.DictReader(handle)]
    with httpx.Client(base_url=base, timeout=120) as client:
        mesh = client.post("/meshes?filename=hall.obj", content=(hall / "hall.obj").read_bytes(),
                           headers={"content-type": "application/octet-stream"})
        assert mesh.status_code in (200, 201), mesh.text
        parameters = {"max_edge_m": None, "candidates": candidates, **changes}
        job = client.post("/processes/scan-plan/execution",
                          json={"inputs": {"mesh": mesh.json()["id"],
                                           "parameters": parameters}})
        assert job.status_code == 201, job.text
        return str(job.json()["jobID"])


@pytest.fixture(scope="module")
def browser_context(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    executable = find_browser()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        context = p.chromium.launch_persistent_context(
            str(tmp_path_factory.mktemp("chromium-profile")), executable_path=executable,
            headless=True, args=ARGS, viewport={"width": 1280, "height": 800})
        try:
            yield context
        finally:
            context.close()


def open_page(context: Any, url: str) -> tuple[Any, list[str]]:
    page = context.new_page()
    errors: list[str] = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(url)
    return page, errors


def test_viewer_of_a_finished_job(server: tuple[str, InlineQueue], scenes_dir: Path,
                                  browser_context: Any, tmp_path: Path) -> None:
    base, _ = server
    job = submit(base, scenes_dir)
    page, errors = open_page(browser_context, f"{base}/jobs/{job}/viewer")
    page.wait_for_function("window.scanplanViewer && window.scanplanViewer.ready",
                           timeout=60_000)
    page.wait_for_timeout(500)  # a few frames
    shot = tmp_path / "viewer.png"
    page.locator("#canvas").screenshot(path=str(shot))
    from PIL import Image

    page.screenshot(path=str(tmp_path / "viewer-page.png"))
    pixels = np.asarray(Image.open(shot).convert("RGB")).reshape(-1, 3).astype(int)
    background = np.array([0xF4, 0xF5, 0xF7])
    drawn = np.any(np.abs(pixels - background) > 12, axis=1).mean()
    assert drawn > 0.05, f"only {drawn:.1%} of the canvas differs from the background"
    greenish = ((pixels[:, 1] > pixels[:, 0] + 30) & (pixels[:, 1] > pixels[:, 2] + 20)).mean()
    assert greenish > 0.01, "no covered (green) faces on the canvas"

    assert page.locator("#status-badge").inner_text() == "successful"
    assert "stations" in page.locator("#totals").inner_text()
    assert page.locator("#class-toggles input").count() == 4
    stations = page.evaluate("window.scanplanViewer.stations()")
    assert len(stations) >= 1
    plan = httpx.get(f"{base}/jobs/{job}/results/plan.json").json()
    for station in stations:
        page.mouse.click(station["x"], station["y"])
        box = page.locator("#station")
        box.wait_for(state="visible")
        text = box.inner_text()
        expected = plan["stations"][station["order"] - 1]
        assert f"Station {station['order']}" in text
        assert f"new area {expected['new_area_m2']:.2f} m²" in text
        x, y, z = expected["position"]
        assert f"x {x:.2f} m, y {y:.2f} m, z {z:.2f} m" in text
    # a class toggle hides its faces
    page.locator('#class-toggles input[data-class="covered"]').uncheck()
    page.wait_for_timeout(300)
    page.locator("#canvas").screenshot(path=str(shot))
    pixels = np.asarray(Image.open(shot).convert("RGB")).reshape(-1, 3).astype(int)
    assert ((pixels[:, 1] > pixels[:, 0] + 30) & (pixels[:, 1] > pixels[:, 2] + 20)
            ).mean() < greenish / 2
    assert errors == []


def test_viewer_shows_a_failure_readably(server: tuple[str, InlineQueue], scenes_dir: Path,
                                         browser_context: Any) -> None:
    base, _ = server
    # a single candidate far outside the hall: nothing qualifies, the plan fails
    job = submit(base, scenes_dir, candidates=[[500.0, 500.0, 1.5]])
    status = httpx.get(f"{base}/jobs/{job}").json()
    assert status["status"] == "failed"
    page, errors = open_page(browser_context, f"{base}/jobs/{job}/viewer")
    problem = page.locator("#problem")
    problem.wait_for(state="visible", timeout=30_000)
    text = problem.inner_text()
    assert "The plan failed" in text
    detail = (status.get("problem") or {}).get("detail") or status["message"]
    assert detail[:40] in text
    assert page.locator("#status-badge").inner_text() == "failed"
    assert errors == []


def test_viewer_and_list_while_a_job_waits(server: tuple[str, InlineQueue], scenes_dir: Path,
                                           browser_context: Any) -> None:
    base, queue = server
    queue.hold = True
    try:
        job = submit(base, scenes_dir)
    finally:
        queue.hold = False
    page, errors = open_page(browser_context, f"{base}/jobs/{job}/viewer")
    page.wait_for_function("window.scanplanViewer.status === 'accepted'", timeout=30_000)
    assert page.locator("#progress").is_visible()
    # the job runs now; the page notices by polling and loads the results
    from service.worker import execute_job

    execute_job(queue.ctx, job)
    page.wait_for_function("window.scanplanViewer.ready", timeout=60_000)
    assert page.locator("#status-badge").inner_text() == "successful"

    listing, list_errors = open_page(browser_context, f"{base}/")
    listing.wait_for_selector(f'a[href="jobs/{job}/viewer"]', timeout=30_000)
    assert "successful" in listing.locator("#jobs").inner_text()
    assert errors == [] and list_errors == []
