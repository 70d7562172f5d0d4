"""Shared fixtures: where the team's test scenes live, an S3-compatible server."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.s3_server import S3Server

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
SCENES = SHARED / "scenes"


@pytest.fixture(scope="session")
def scenes_dir() -> Path:
    if not SCENES.is_dir():
        pytest.skip(f"the shared scenes are not beside the checkout ({SCENES})")
    return SCENES


@pytest.fixture(scope="session")
def s3_server() -> Iterator[S3Server]:
    """A real S3-compatible server (moto's) on 127.0.0.1 for the whole session."""
    server = S3Server()
    yield server
    server.stop()
