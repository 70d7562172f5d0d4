"""scanplan's version: the one in pyproject.toml, as the installed package's metadata says."""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("scanplan")
except PackageNotFoundError:  # pragma: no cover - the sources run without being installed
    __version__ = "0+unknown"
