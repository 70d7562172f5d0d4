"""The coverage curve: stations needed for every goal from 5 % to 100 % (paper Fig. 6c).

Greedy orders do not depend on the goal, so one full run per method gives every point:
the stations needed for a goal are the shortest prefix that reaches it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from planner.selection import Selection

if TYPE_CHECKING:
    from planner.optimal import OptimalResult

GOALS: tuple[float, ...] = tuple(round(0.05 * i, 2) for i in range(1, 21))


def coverage_curve(selections: dict[str, Selection],
                   optimal: OptimalResult | None = None) -> dict[str, Any]:
    """``{"goals": [...], "<method>": [stations per goal], "optimal": {...}}``."""
    curve: dict[str, Any] = {"goals": list(GOALS)}
    for method, selection in sorted(selections.items()):
        curve[method] = [selection.count_for_goal(goal) for goal in GOALS]
    if optimal is not None:
        curve["optimal"] = {
            "stations": len(optimal.selection.stations),
            "lower_bound": optimal.lower_bound,
        }
    return curve
