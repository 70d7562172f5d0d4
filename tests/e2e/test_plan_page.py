"""The page to plan, in a real headless Chromium against ``scanplan serve``: drop a model,
set parameters in the generated form, start, watch the progress, open the viewer."""

from __future__ import annotations

import base64
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.data_files import HALL_SMALL as HALL
from tests.e2e.service_process import Service
from tests.e2e.test_viewer import ARGS, find_browser

pytestmark = pytest.mark.browser


DROP = """([name, b64]) => {
  const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
  const transfer = new DataTransfer();
  transfer.items.add(new File([bytes], name, { type: 'application/octet-stream' }));
  const target = document.getElementById('drop');
  for (const type of ['dragenter', 'dragover', 'drop']) {
    target.dispatchEvent(new DragEvent(type, { dataTransfer: transfer, bubbles: true,
                                               cancelable: true }));
  }
}"""


@pytest.fixture
def service(tmp_path: Path) -> Iterator[Service]:
    running = Service(tmp_path / "data", workers=1).start()
    yield running
    running.stop()
    running.kill_leftovers()


@pytest.fixture
def page(tmp_path: Path) -> Iterator[Any]:
    executable = find_browser()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        context = p.chromium.launch_persistent_context(
            str(tmp_path / "profile"), executable_path=executable, headless=True, args=ARGS)
        try:
            yield context.new_page()
        finally:
            context.close()


def test_drop_a_model_set_parameters_start_and_watch(service: Service, page: Any) -> None:
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(service.url + "/")
    coverage = page.locator("#parameters input[name=coverage_goal]")
    coverage.wait_for(timeout=30_000)
    # the form is the process description: defaults and ranges as the validator's
    assert coverage.input_value() == "0.8"
    assert page.locator("#parameters input[name=min_incidence_deg]").get_attribute(
        "max") == "90"
    assert page.locator("#parameters select[name=method] option").all_inner_texts() == [
        "greedy", "weighted_greedy", "optimal"]

    page.evaluate(DROP, ["hall.obj",
                         base64.b64encode((HALL / "hall.obj").read_bytes()).decode()])
    assert "hall.obj" in page.locator("#drop-text").inner_text()

    coverage.fill("0")  # refused by the service: its problem is shown, naming the parameter
    page.locator("#start").click()
    page.locator("#plan-state .problem").wait_for(timeout=30_000)
    assert "coverage_goal" in page.locator("#plan-state").inner_text()

    coverage.fill("0.7")
    page.locator("#parameters input[name=max_edge_m]").fill("")  # null: the mesh as given
    page.locator("#start").click()
    page.wait_for_selector("#plan-state[data-status=successful]", timeout=120_000)
    assert "100 %" in page.locator("#plan-state").inner_text()
    viewer = page.locator("#plan-state a")
    page.goto(service.url + "/" + viewer.get_attribute("href"))
    page.wait_for_function("window.scanplanViewer && window.scanplanViewer.ready",
                           timeout=60_000)
    with service.client() as client:
        jobs = client.get("/jobs").json()["jobs"]
    assert [job["status"] for job in jobs] == ["successful"]
    parameters = client_parameters(service, jobs[0]["jobID"])
    assert parameters == {"coverage_goal": 0.7, "max_edge_m": None}
    assert errors == []


def client_parameters(service: Service, job_id: str) -> dict[str, Any]:
    """What the page sent: only the parameters that differ from the defaults."""
    import json
    import sqlite3

    with sqlite3.connect(service.data_dir / "jobs.db") as db:
        row = db.execute("SELECT parameters FROM jobs WHERE id = ?", (job_id,)).fetchone()
    return dict(json.loads(row[0]))
