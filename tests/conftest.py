"""Shared fixtures: where the team's test scenes live."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
SCENES = SHARED / "scenes"


@pytest.fixture(scope="session")
def scenes_dir() -> Path:
    if not SCENES.is_dir():
        pytest.skip(f"the shared scenes are not beside the checkout ({SCENES})")
    return SCENES
