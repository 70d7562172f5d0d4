"""Timestamps on the wire: RFC 3339 UTC with milliseconds."""

from __future__ import annotations

from datetime import UTC, datetime


def iso(epoch_s: float | None) -> str | None:
    """``2024-05-01T12:00:00.000Z`` for epoch seconds; None stays None."""
    if epoch_s is None:
        return None
    return datetime.fromtimestamp(epoch_s, UTC).isoformat(timespec="milliseconds").replace(
        "+00:00", "Z")
