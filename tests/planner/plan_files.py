"""The files a plan writes, read back: for tests that compare two plans byte for byte."""

from __future__ import annotations

from pathlib import Path

from planner.outputs.report import write_outputs
from planner.pipeline import PlanResult


def files_of(result: PlanResult, out: Path) -> dict[str, bytes]:
    """Every file ``write_outputs`` writes for ``result`` into ``out``: name -> bytes."""
    return {path.name: path.read_bytes() for path in write_outputs(result, out)}


def assert_same_files(ours: dict[str, bytes], theirs: dict[str, bytes]) -> None:
    """Two plans' files (:func:`files_of`): the same names, the data files among them, and
    the same bytes in each (the names of the files that differ in the failure)."""
    assert sorted(ours) == sorted(theirs)
    assert "plan.json" in ours and "faces.npz" in ours
    assert [name for name in ours if ours[name] != theirs[name]] == []
