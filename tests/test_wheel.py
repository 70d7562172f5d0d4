"""The package as a user installs it: a wheel built from the checkout, installed into a
fresh virtual environment, its kernels compiled (``scanplan compile-kernels``, as the README
tells a pip user), run from a folder outside the checkout.

The fresh environment gets the project environment's third-party packages through a
``.pth`` line (so the test needs no download of numpy and the rest), never the checkout:
``.pth`` files in a directory that line adds are not read, so the project's own editable
install stays out, and the test checks that ``planner`` and ``service`` load from the
fresh environment.
"""

from __future__ import annotations

import json
import os
import pickle
import platform
import subprocess
import sys
import sysconfig
import time
from pathlib import Path

import httpx

from planner.kernels import X86_64_V3, host_cpu_flags, target_for
from planner.version import __version__
from tests.e2e.service_process import FAST, free_port

ROOT = Path(__file__).resolve().parents[1]


def _run(command: list[str], cwd: Path, timeout: int = 300,
         extra: dict[str, str] | None = None) -> str:
    environ = {k: v for k, v in os.environ.items()
               if k not in ("PYTHONPATH", "VIRTUAL_ENV") and not k.startswith("NUMBA_")}
    done = subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=timeout,
                          check=False, env={**environ, **(extra or {})})
    assert done.returncode == 0, f"{command}: {done.stdout[-2000:]}{done.stderr[-4000:]}"
    return done.stdout


def _cache_keys(folder: Path) -> set[tuple[str, str]]:
    """The (CPU name, features) of every kernel in numba's cache under ``folder``: the
    second and third words of each index key's codegen tuple (numba/core/caching.py: an
    index file holds numba's version, then the pickled source stamp and overloads)."""
    keys = set()
    for index in folder.rglob("*.nbi"):
        with index.open("rb") as data:
            pickle.load(data)  # numba's version
            _, overloads = pickle.loads(data.read())
        keys |= {tuple(key[1][1:]) for key in overloads}
    return keys


def test_the_wheel_plans_and_serves_outside_the_checkout(tmp_path: Path,
                                                          scenes_dir: Path) -> None:
    dist, venv, work = tmp_path / "dist", tmp_path / "venv", tmp_path / "work"
    work.mkdir()
    _run([sys.executable, "-m", "build", "--wheel", "--outdir", str(dist), str(ROOT)],
         cwd=tmp_path, timeout=600)
    [wheel] = dist.glob("scanplan-*.whl")
    assert wheel.name.startswith(f"scanplan-{__version__}-")
    _run([sys.executable, "-m", "venv", str(venv)], cwd=tmp_path)
    python = venv / "bin" / "python"
    site = Path(_run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()"
                      "['purelib'])"], cwd=work).strip())
    (site / "project_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    _run([str(python), "-m", "pip", "install", "--no-deps", "--no-index", "--quiet",
          str(wheel)], cwd=work)
    where = json.loads(_run([str(python), "-c", "import json, planner, service; print("
                             "json.dumps([planner.__file__, service.__file__]))"], cwd=work))
    assert all(Path(path).is_relative_to(venv) for path in where), where
    scanplan = str(venv / "bin" / "scanplan")
    assert _run([scanplan, "--version"], cwd=work).strip() == f"scanplan {__version__}"

    # the kernels compiled once, into the installed package's own __pycache__ folders, for
    # x86-64-v3 where the CPU runs it: the cache's keys name the level, not this machine
    compiled = _run([scanplan, "compile-kernels"], cwd=work, timeout=900)
    target = X86_64_V3 if target_for(platform.machine(), host_cpu_flags()) else "this CPU"
    assert f"kernels for {target} into numba's cache (__pycache__" in compiled
    if target == X86_64_V3:
        assert _cache_keys(Path(where[0]).parent) == {(X86_64_V3, "")}
    # then a model no example resembles (a plain mesh, split as needed) compiles nothing:
    # numba logs each kernel it loads from its cache and each it compiles and saves there
    log = _run([scanplan, "plan", str(scenes_dir / "AC20-FZK-Haus.obj"), "--out", "fzk",
                "--quiet"], cwd=work, extra={"NUMBA_DEBUG_CACHE": "1"})
    assert "[cache] data loaded from" in log
    assert [line for line in log.splitlines() if "[cache] data saved" in line] == []

    # the command line: an example the package brings, planned with the command it prints
    printed = _run([scanplan, "examples", "hall-small", "--to", "models"], cwd=work)
    command = printed.splitlines()[-1].split()
    (work / "params.json").write_text(json.dumps({"max_edge_m": None}))
    _run([scanplan, *command[1:], "--params", "params.json", "--quiet"], cwd=work)
    out = work / "hall-small-plan"
    plan = json.loads((out / "plan.json").read_text())
    assert plan["scanplan_version"] == __version__ and plan["goal_reached"]
    assert {"preview.png", "plan.pdf", "coverage.glb", "stations.csv"} <= \
        {p.name for p in out.iterdir()}

    # the service: the API, the upload page, the viewer's files and a job's viewer
    port = free_port()
    server = subprocess.Popen(
        [scanplan, "serve", "--port", str(port), "--data-dir", str(work / "data"),
         "--workers", "1"], cwd=work, env={**os.environ, **FAST},
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    base = f"http://127.0.0.1:{port}"
    try:
        with httpx.Client(base_url=base, timeout=10) as client:
            deadline = time.monotonic() + 60
            while True:
                try:
                    if client.get("/readyz").status_code == 200:
                        break
                except httpx.HTTPError:
                    pass
                assert server.poll() is None and time.monotonic() < deadline, "not ready"
                time.sleep(0.3)
            assert client.get("/healthz").json() == {"status": "ok", "version": __version__}
            page = client.get("/", headers={"Accept": "text/html"})
            assert page.status_code == 200 and "<html" in page.text.lower()
            assert client.get("/static/viewer.js").status_code == 200
            uploaded = client.post("/meshes", params={"filename": "hall.obj"},
                                   content=(work / "models" / "hall.obj").read_bytes(),
                                   headers={"Content-Type": "application/octet-stream"})
            assert uploaded.status_code == 201, uploaded.text
            job = client.post("/processes/scan-plan/execution", json={"inputs": {
                "mesh": uploaded.json()["id"],
                "parameters": {"max_edge_m": None, "grid_spacing_m": 1.0}}})
            assert job.status_code == 201, job.text
            job_id = job.json()["jobID"]
            deadline = time.monotonic() + 240
            while (status := client.get(f"/jobs/{job_id}").json())["status"] not in (
                    "successful", "failed"):
                assert time.monotonic() < deadline, status
                time.sleep(0.5)
            assert status["status"] == "successful", status
            viewer = client.get(f"/jobs/{job_id}/viewer")
            assert viewer.status_code == 200 and "viewer.js" in viewer.text
    finally:
        server.terminate()
        server.wait(30)
