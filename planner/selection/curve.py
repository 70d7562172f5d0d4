"""The coverage curve: stations needed for every goal from 5 % to 100 % (paper Fig. 6c).

Greedy orders do not depend on the goal, so one full run per method gives every point:
the stations needed for a goal are the shortest prefix that reaches it. ``optimal`` is a
MILP per goal, so its row holds only the goals it was solved for (``curve_goals``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from planner.selection.greedy import Selection

if TYPE_CHECKING:
    from planner.selection.optimal import OptimalResult

GOALS: tuple[float, ...] = tuple(round(0.05 * i, 2) for i in range(1, 21))


def coverage_curve(selections: dict[str, Selection],
                   optimal: OptimalResult | Sequence[OptimalResult] | None = None
                   ) -> dict[str, Any]:
    """``{"goals": [...], "<method>": [stations per goal], "optimal": {...}}``.

    ``optimal``: the results per goal (or one result); its row is ``{"goals", "stations",
    "lower_bound", "proven_optimal"}``, each a list in ascending goal order.
    """
    curve: dict[str, Any] = {"goals": list(GOALS)}
    for method, selection in sorted(selections.items()):
        curve[method] = [selection.count_for_goal(goal) for goal in GOALS]
    if optimal is None:
        return curve
    rows = sorted([optimal] if not isinstance(optimal, Sequence) else optimal,
                  key=lambda r: r.goal)
    if rows:
        curve["optimal"] = {
            "goals": [r.goal for r in rows],
            "stations": [len(r.selection.stations) for r in rows],
            "lower_bound": [r.lower_bound for r in rows],
            "proven_optimal": [r.proven_optimal for r in rows],
        }
    return curve
