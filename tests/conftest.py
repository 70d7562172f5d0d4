"""Shared fixtures: the test models (tests/data_files.py), an S3-compatible server."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from planner.examples import DataMissingError
from planner.kernels import pin_numba_target
from tests.data_files import scenes_layout
from tests.s3_server import S3Server

# the kernels compiled in the tests' processes for the target ``scanplan`` compiles them
# for, so the two share numba's cache instead of compiling every kernel twice
pin_numba_target()


@pytest.fixture(scope="session")
def scenes_dir() -> Path:
    """Every test model in the scenes folder's layout; missing ones fail the test (never
    skip it) with what to set."""
    try:
        return scenes_layout()
    except DataMissingError as exc:
        missing = str(exc)
    pytest.fail(missing, pytrace=False)


@pytest.fixture(scope="session")
def s3_server() -> Iterator[S3Server]:
    """A real S3-compatible server (moto's) on 127.0.0.1 for the whole session."""
    server = S3Server()
    yield server
    server.stop()


# Files run first: under pytest-xdist (``--dist loadfile``, as ``make test`` runs) a file goes
# to one worker whole, in the order collected, and the wheel's test (about two minutes: it
# installs the package and compiles its kernels) came last and ran alone at the end.
FIRST_FILES = ("tests/test_wheel.py",)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: item.nodeid.split("::")[0] not in FIRST_FILES)  # stable
