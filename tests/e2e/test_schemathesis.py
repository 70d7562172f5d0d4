"""Schemathesis (its CLI, all checks, stateful phase included) against ``scanplan serve``.

A real service with a worker process; the run is bounded by a fixed seed and example count
(about a minute on 2 cores). 0 failures is the contract: every status a route returns is
documented with its media type, every schema-valid request is accepted or refused with a
documented problem, no 5xx.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from planner.version import __version__
from tests.e2e.service_process import Service

ROOT = Path(__file__).resolve().parents[2]
ST = str(Path(sys.executable).with_name("st"))


def test_schemathesis_finds_no_contract_failure(tmp_path: Path) -> None:
    service = Service(tmp_path / "data", workers=1,
                      env={"SCANPLAN_MAX_FACES": "200000"}).start()
    try:
        env = {**os.environ, "SCHEMATHESIS_HOOKS": "tests.e2e.schemathesis_hooks",
               "PYTHONPATH": str(ROOT)}
        run = subprocess.run(
            [ST, "--config-file", str(ROOT / "tests" / "e2e" / "schemathesis.toml"), "run",
             f"{service.url}/openapi.json", "--checks", "all", "--max-examples", "8",
             "--seed", "1", "--workers", "1", "--request-timeout", "30",
             "--phases", "examples,coverage,fuzzing,stateful", "--no-color"],
            capture_output=True, text=True, env=env, cwd=tmp_path, timeout=400)
        report = run.stdout[-6000:]
        assert run.returncode == 0, report
        assert "✅ Stateful" in report, report  # upload -> execute -> status -> results
        with service.client() as client:
            assert client.get("/healthz").json() == {"status": "ok", "version": __version__}
    finally:
        service.stop()
        service.kill_leftovers()
