"""The viewer page in a real headless Chromium against the real app.

The app (``create_app`` with an inline job runner) is served by uvicorn in a thread on a
free port; Playwright drives Debian's ``/usr/bin/chromium``. Without a browser the test
tries ``apt-get install chromium chromium-driver`` (as root, time-limited) and otherwise
skips with the reason printed.
"""

from __future__ import annotations

import csv
import io
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


def submit(base: str, scenes_dir: Path, *, model: bytes | None = None, **changes: Any) -> str:
    """Plan hall-small (or ``model``, an OBJ) with the hall's candidates unless changed."""
    hall = scenes_dir / "hall-small"
    with (hall / "candidates.csv").open() as handle:
        candidates = [[float(r["x"]), float(r["y"]), float(r["z"])]
                      for r in csv.DictReader(handle)]
    with httpx.Client(base_url=base, timeout=300) as client:
        mesh = client.post("/meshes?filename=hall.obj",
                           content=model or (hall / "hall.obj").read_bytes(),
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
    # a still view is drawn when something changes, not in a loop that keeps a core busy
    def frames() -> int:
        return int(page.evaluate("window.scanplanViewer.frames"))

    settled = frames()
    for _ in range(20):  # the page's layout settles (a late resize draws once more)
        page.wait_for_timeout(250)
        if frames() == settled:
            break
        settled = frames()
    assert settled >= 1
    page.wait_for_timeout(1000)
    assert frames() == settled, "the viewer keeps drawing while nothing changes"
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
    # the drawing and the print set are linked for CAD; a mesh gets no plan.ifc, and is told
    bim = page.locator("#bim-files")
    for name in ("plan.dxf", "plan.pdf"):
        href = bim.locator(f'a:text-is("{name}")').get_attribute("href") or ""
        assert href.endswith(f"/results/{name}"), href
    assert "no plan.ifc: the model was not IFC" in bim.inner_text()
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

    check_route_and_time(page, plan)
    # no verification: the delivered colouring is not offered, a note says how to get it
    assert not page.locator('#colouring input[value="delivered"]').is_visible()
    assert page.locator('#colouring input[value="delivered"]').is_disabled()
    assert "No verification for this plan" in page.locator("#delivered-note").inner_text()
    assert errors == []


def duration(seconds: float | None) -> str:
    """A duration as the viewer writes it."""
    if seconds is None:
        return "unknown"
    s = int(np.floor(seconds + 0.5))
    if s < 60:
        return f"{s} s"
    if s < 3600:
        return f"{s // 60} min {s % 60:02d} s"
    m = int(np.floor(seconds / 60 + 0.5))
    return f"{m // 60} h {m % 60:02d} min"


def check_route_and_time(page: Any, plan: dict[str, Any]) -> None:
    """The route legs and overlap edges are drawn at the stations; the table and the field
    time say what plan.json says."""
    route, edges = plan["route"], plan["registration"]["edges"]
    overlays = page.evaluate("window.scanplanViewer.overlays()")
    # a leg between consecutive stations of each part: none across a step between parts
    steps = len(route.get("steps_between_parts", []))
    assert len(overlays["legs"]) == len(route["legs"]) == len(route["visits"]) - 1 - steps
    assert len(overlays["edges"]) == len(edges) >= 1
    at = {int(k): v for k, v in overlays["stations"].items()}
    for leg, drawn in zip(route["legs"], overlays["legs"], strict=True):
        assert (drawn["from"], drawn["to"]) == (leg["from"], leg["to"])
        assert drawn["points"] == len(leg["path"]) and drawn["visible"]
        # the path runs at walking height: it starts and ends under the two markers
        # (world Y is up; x and z are the floor)
        for end, station in ((drawn["start"], leg["from"]), (drawn["end"], leg["to"])):
            assert abs(end[0] - at[station][0]) < 0.05 and abs(end[2] - at[station][2]) < 0.05
    for edge, drawn in zip(edges, overlays["edges"], strict=True):
        assert (drawn["a"], drawn["b"]) == (edge["a"], edge["b"])
        assert np.allclose(drawn["start"], at[edge["a"]], atol=1e-3)
        assert np.allclose(drawn["end"], at[edge["b"]], atol=1e-3)
    # the toggles hide them
    page.locator('#overlay-toggles input[data-overlay="route"]').uncheck()
    page.locator('#overlay-toggles input[data-overlay="registration"]').uncheck()
    overlays = page.evaluate("window.scanplanViewer.overlays()")
    assert not any(x["visible"] for x in overlays["legs"] + overlays["edges"])
    page.locator('#overlay-toggles input[data-overlay="route"]').check()
    toggles = page.locator("#overlay-toggles").inner_text()
    n_legs = len(route["legs"])
    assert f"walking route: {n_legs} leg{'' if n_legs == 1 else 's'}" in toggles
    assert f"registration overlaps: {len(edges)} edge" in toggles

    rows = page.locator("#stations tbody tr")
    assert rows.count() == len(plan["stations"])
    for i, station in enumerate(plan["stations"]):
        cells = rows.nth(i).locator("td")
        assert cells.nth(0).inner_text() == str(station["id"])
        visit = station["visit"]
        assert cells.nth(1).inner_text() == ("\u2013" if visit is None else str(visit))
        if "scan_s" in station:  # a scanner was given: its setting and scan time per station
            assert cells.nth(7).inner_text() == (station["setting"] or "plan step")
            assert cells.nth(8).inner_text() == duration(station["scan_s"])
        else:
            assert cells.count() == 7
    times = plan["field_time"]
    box = page.locator("#fieldtime")
    assert box.is_visible()
    assert page.locator('#fieldtime dd[data-time="setup"]').inner_text().startswith(
        duration(times["setup_s"]))
    assert page.locator('#fieldtime dd[data-time="walk"]').inner_text().startswith(
        duration(times["walk_s"]))
    total = page.locator('#fieldtime dd[data-time="total"]').inner_text()
    if times["scan_s"] is None:
        assert page.locator('#fieldtime dd[data-time="scan"]').inner_text() == "unknown"
        assert total.startswith("unknown")
        assert "scan time unknown: no scanner was given (parameter scanner" in box.inner_text()
    else:
        assert total == duration(times["total_s"])
        assert page.locator('#fieldtime dd[data-time="scan"]').inner_text() == duration(
            times["scan_s"])
        assert times["scanner"] in page.locator('#fieldtime dd[data-time="scanner"]').inner_text()
    unreachable = route["unreachable"]
    note = page.locator('#fieldtime [data-note="unreachable"]').inner_text()
    if unreachable:
        assert ", ".join(str(u) for u in unreachable) in note
    else:
        assert note == "every station is on the walking route"


def test_viewer_route_of_a_model_with_another_up(
        server: tuple[str, InlineQueue], scenes_dir: Path, browser_context: Any) -> None:
    """plan.json holds model coordinates, the glb's markers sit under a rotated root: the
    route and the edges still run between the markers."""
    base, _ = server
    # the hall turned so that its up is -Y (plan = R @ model, R of up_axis "-Y")
    rotation = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    lines = []
    for line in (scenes_dir / "hall-small" / "hall.obj").read_text().splitlines():
        if line.startswith("v "):
            x, y, z = (rotation.T @ np.array([float(v) for v in line.split()[1:4]])).tolist()
            line = f"v {x:.6f} {y:.6f} {z:.6f}"
        lines.append(line)
    with (scenes_dir / "hall-small" / "candidates.csv").open() as handle:
        candidates = [(rotation.T @ np.array([float(r["x"]), float(r["y"]), float(r["z"])])
                       ).tolist() for r in csv.DictReader(handle)]
    # with the crew's scanner: the stations' settings and scan times, the field time's total
    scanner = {"name": "crew", "measurement_rate_pts_s": 2e6, "overhead_s": 30, "settings": [
        {"name": "10 mm", "point_spacing_m": 0.01, "reference_distance_m": 10},
        {"name": "20 mm", "point_spacing_m": 0.02, "reference_distance_m": 10}]}
    job = submit(base, scenes_dir, model="\n".join(lines).encode(), up_axis="-Y",
                 candidates=candidates, scanner=scanner)
    plan = httpx.get(f"{base}/jobs/{job}/results/plan.json").json()
    assert plan["scene"]["orientation"]["rotation"] == rotation.tolist()
    assert plan["field_time"]["scan_s"] is not None
    page, errors = open_page(browser_context, f"{base}/jobs/{job}/viewer")
    page.wait_for_function("window.scanplanViewer && window.scanplanViewer.ready",
                           timeout=60_000)
    check_route_and_time(page, plan)
    assert errors == []


def test_viewer_colours_what_the_verification_delivered(
        server: tuple[str, InlineQueue], scenes_dir: Path, browser_context: Any,
        tmp_path: Path) -> None:
    base, _ = server
    # a re-scan whose earlier station stands on a machine, not joined to the floor on foot
    job = submit(base, scenes_dir, verify=True, fixed_stations=[[1.4, 1.9, 2.45]])
    verification = httpx.get(f"{base}/jobs/{job}/results/verification.json").json()
    totals = verification["totals"]
    npz = tmp_path / "faces.npz"
    npz.write_bytes(httpx.get(f"{base}/jobs/{job}/results/faces.npz").content)
    with np.load(npz) as faces:
        covered, delivered = faces["covered"], faces["verified_delivered"]
    plan = httpx.get(f"{base}/jobs/{job}/results/plan.json").json()
    # it is walked in a part of its own, after a step the crew makes on site (a ladder)
    steps = plan["route"]["steps_between_parts"]
    assert plan["route"]["unreachable"] == [] and [step["to"] for step in steps] == [1]
    assert plan["stations"][0]["visit"] == len(plan["stations"])
    page, errors = open_page(browser_context, f"{base}/jobs/{job}/viewer")
    page.wait_for_function("window.scanplanViewer && window.scanplanViewer.ready",
                           timeout=60_000)
    page.wait_for_timeout(500)
    check_route_and_time(page, plan)
    parts = page.locator('#fieldtime [data-note="parts"]').inner_text()
    assert "parts; walk on site from station" in parts and parts.endswith(
        "to station 1 (no stair or way in the model)"), parts
    note = page.locator("#delivered-note").inner_text()
    assert f"({totals['promised_not_delivered_faces']} faces)" in note
    radio = page.locator('#colouring input[value="delivered"]')
    assert radio.is_visible() and radio.is_enabled()
    from PIL import Image

    before = tmp_path / "coverage.png"
    page.locator("#canvas").screenshot(path=str(before))
    radio.check()
    page.wait_for_function("window.scanplanViewer.colouring === 'delivered'", timeout=30_000)
    page.wait_for_timeout(300)
    after = tmp_path / "delivered.png"
    page.locator("#canvas").screenshot(path=str(after))
    page.screenshot(path=str(tmp_path / "delivered-page.png"), full_page=True)

    def legend(kind: str) -> int:
        text = page.locator(f'#delivered-legend [data-kind="{kind}"] .count').inner_text()
        return int(text)

    # the legend and the colours the meshes hold agree with verification.json
    drawn = page.evaluate("window.scanplanViewer.faceColours()")
    expected = {
        "promised_not_delivered": totals["promised_not_delivered_faces"],
        "delivered_not_promised": totals["delivered_not_promised_faces"],
        "delivered": int((covered & delivered).sum()),
    }
    assert expected["promised_not_delivered"] > 0 and expected["delivered_not_promised"] > 0
    for kind, count in expected.items():
        assert legend(kind) == drawn[kind] == count, kind
    assert drawn["other"] == 0
    assert sum(v for k, v in drawn.items() if k != "other") == plan["totals"]["faces"]
    # and the canvas shows it: the blue of "delivered, not promised" appears
    old = np.asarray(Image.open(before).convert("RGB")).reshape(-1, 3).astype(int)
    new = np.asarray(Image.open(after).convert("RGB")).reshape(-1, 3).astype(int)

    def blue(p: np.ndarray) -> float:
        return float(((p[:, 2] > p[:, 0] + 60) & (p[:, 2] > p[:, 1] + 20)).mean())

    assert blue(new) > blue(old) + 0.002, (blue(old), blue(new))
    # back to the plan's colours
    page.locator('#colouring input[value="coverage"]').check()
    page.wait_for_function("window.scanplanViewer.colouring === 'coverage'")
    assert page.evaluate("window.scanplanViewer.faceColours()")["other"] > 0
    assert page.locator("#delivered-legend").is_hidden()
    assert errors == []


def test_viewer_colours_a_split_model_by_feature(
        server: tuple[str, InlineQueue], scenes_dir: Path, browser_context: Any) -> None:
    """A model split for the coverage is drawn by feature (coverage.glb's faces of one file
    face and state): the viewer shows every class, and the delivered colouring counts every
    face of faces.npz once, each kind face by face."""
    import trimesh

    base, _ = server
    room = trimesh.creation.box(extents=(8.0, 6.0, 3.0))
    room.apply_translation((4.0, 3.0, 1.5))
    room.invert()
    block = trimesh.creation.box(extents=(1.0, 2.0, 2.5))
    block.apply_translation((4.5, 3.0, 1.25))
    obj = trimesh.util.concatenate([room, block]).export(file_type="obj")
    job = submit(base, scenes_dir, model=obj.encode(), candidates=[[1.5, 1.5, 1.5]],
                 max_edge_m=0.25, verify=True)
    plan = httpx.get(f"{base}/jobs/{job}/results/plan.json").json()
    faces = np.load(io.BytesIO(httpx.get(f"{base}/jobs/{job}/results/faces.npz").content))
    covered, delivered = faces["covered"], faces["verified_delivered"]
    n_faces = plan["totals"]["faces"]
    assert n_faces == len(covered) > 10_000  # split: many faces, few features
    page, errors = open_page(browser_context, f"{base}/jobs/{job}/viewer")
    page.wait_for_function("window.scanplanViewer && window.scanplanViewer.ready",
                           timeout=60_000)
    toggles = page.locator("#class-toggles").inner_text()
    assert f"({int(covered.sum())} faces)" in toggles
    page.locator('#colouring input[value="delivered"]').check()
    page.wait_for_function("window.scanplanViewer.colouring === 'delivered'", timeout=30_000)
    expected = {"delivered": int((covered & delivered).sum()),
                "promised_not_delivered": int((covered & ~delivered).sum())}
    for kind, count in expected.items():
        text = page.locator(f'#delivered-legend [data-kind="{kind}"] .count').inner_text()
        assert int(text) == count, kind
    drawn = page.evaluate("window.scanplanViewer.faceColours()")
    assert drawn["other"] == 0
    assert sum(v for k, v in drawn.items() if k != "other") == n_faces
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
