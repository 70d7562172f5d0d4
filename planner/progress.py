"""What a plan tells while it runs: progress per stage (which may cancel it) and its figures.

:data:`ProgressCallback` is called with (stage, fraction 0..1) between blocks of work;
returning True cancels the plan with :class:`~planner.errors.CancelledError`. :class:`Stats`
collects seconds per stage and counts for benchmarks and the job record; they are never
part of the plan's bytes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from planner.errors import CancelledError
from planner.memory import release_freed_memory

# progress(stage, fraction 0..1) -> True to cancel
ProgressCallback = Callable[[str, float], bool | None]


@dataclass
class Stats:
    """What the run did, for benchmarks and the job record (never in the result bytes)."""

    seconds: dict[str, float] = field(default_factory=dict)
    cpu_seconds: dict[str, float] = field(default_factory=dict)  # process CPU, all threads
    pairs_tested: int = 0
    rays_cast: int = 0
    qualified_pairs: int = 0
    overlap_rows: int = 0  # candidates whose overlap row the connected greedy computed


def notify(progress: ProgressCallback | None, stage: str, fraction: float) -> None:
    """Tell ``progress`` how far ``stage`` is; raise :class:`CancelledError` if it cancels."""
    if progress is not None and progress(stage, min(max(fraction, 0.0), 1.0)):
        raise CancelledError(f"the plan was cancelled during {stage}")


def new_stage(progress: ProgressCallback | None, stage: str) -> None:
    """Start ``stage``: release what the last one freed, then tell ``progress``."""
    release_freed_memory()
    notify(progress, stage, 0.0)
