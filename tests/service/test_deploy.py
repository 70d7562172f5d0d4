"""Dockerfile and compose.yaml, checked without a Docker engine (hadolint, compose schema)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
# the exact command the e2e tests run (tests/e2e/service_process.py), with Docker's options
IMAGE_CMD = ["scanplan", "serve", "--host", "0.0.0.0", "--data-dir", "/data"]


def _tool(name: str) -> str:
    path = BIN / name if (BIN / name).exists() else shutil.which(name)
    if path is None:
        pytest.skip(f"{name} is not installed (pip install -e '.[dev]')")
    return str(path)


def _instructions() -> list[tuple[str, str]]:
    lines = (ROOT / "Dockerfile").read_text().replace("\\\n", " ").splitlines()
    found = []
    for line in lines:
        if line.strip() and not line.lstrip().startswith("#"):
            keyword, _, rest = line.strip().partition(" ")
            found.append((keyword.upper(), rest.strip()))
    return found


def test_hadolint_passes() -> None:
    result = subprocess.run([_tool("hadolint"), str(ROOT / "Dockerfile")],
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_image_runs_the_tested_command_as_non_root() -> None:
    instructions = _instructions()
    assert ("FROM", "python:3.11-slim") in instructions
    cmd = [json.loads(rest) for key, rest in instructions if key == "CMD"]
    assert cmd == [IMAGE_CMD]
    users = [rest for key, rest in instructions if key == "USER"]
    assert users and users[-1].split(":")[0].isdigit() and not users[-1].startswith("0")
    assert any(key == "VOLUME" and "/data" in rest for key, rest in instructions)
    assert any(key == "HEALTHCHECK" and "/healthz" in rest for key, rest in instructions)


def test_compose_matches_the_compose_schema() -> None:
    result = subprocess.run(
        [_tool("check-jsonschema"), "--builtin-schema", "vendor.compose-spec",
         str(ROOT / "compose.yaml")], capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_compose_has_embedded_service_and_scale_profile() -> None:
    compose: dict[str, Any] = yaml.safe_load((ROOT / "compose.yaml").read_text())
    services = compose["services"]
    assert "profiles" not in services["scanplan"]  # the default: one container
    assert "/data" in services["scanplan"]["volumes"][0]
    for name in ("api", "worker", "redis", "postgres", "minio", "bucket"):
        assert services[name]["profiles"] == ["scale"], name
    assert services["worker"]["command"][:2] == ["scanplan", "worker"]
    assert services["api"]["command"][:2] == ["scanplan", "serve"]
    for name in ("api", "worker"):  # no shared disk: they meet in Redis, PostgreSQL, MinIO
        assert "volumes" not in services[name], name
        env = services[name]["environment"]
        assert env["SCANPLAN_QUEUE_URL"].startswith("redis://")
        assert env["SCANPLAN_DATABASE_URL"].startswith("postgresql")
        assert env["SCANPLAN_STORE_URL"].startswith("s3://")
        assert env["AWS_ENDPOINT_URL"] == "http://minio:9000"
        assert services[name]["depends_on"]["bucket"]["condition"] == \
            "service_completed_successfully"


def test_serve_and_worker_options_are_documented() -> None:
    from planner.__main__ import build_parser

    parser = build_parser()
    serve = parser.parse_args(["serve", "--host", "0.0.0.0", "--port", "1", "--data-dir",
                               "/d", "--workers", "3"])
    assert (serve.host, serve.port, str(serve.data_dir), serve.workers) == \
        ("0.0.0.0", 1, "/d", 3)
    assert parser.parse_args(["worker"]).handler.__name__ == "run_worker"
