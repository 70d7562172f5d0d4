"""The fewest stations that reach the goal: partial set cover as a MILP, solved by HiGHS.

Variables: ``x_c`` in {0, 1} per candidate (chosen), ``y_k`` in [0, 1] per face class (the
class is covered). Faces qualified by exactly the same candidates are merged into one class
whose weight is their total area, which shrinks the program a lot. Then::

    minimise    sum_c x_c
    subject to  y_k <= sum_{c covers k} x_c          for every class k
                sum_k area_k * y_k >= goal * max achievable area

``y`` may stay continuous: with integer ``x`` an optimal ``y_k`` is 0 or 1 whenever it
matters. The solver stops at ``optimal_time_limit_s``; the result reports the best plan
found, the proven lower bound on the station count and the gap between them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.optimize import Bounds, LinearConstraint, milp

from planner.coverage import CoverageTable
from planner.errors import PlannerError
from planner.selection import GOAL_SLACK_M2, Selection, replay


@dataclass(frozen=True)
class OptimalResult:
    """The MILP's answer.

    ``proven_optimal`` is true when the solver closed the gap within the time limit;
    ``lower_bound`` is the proven minimum number of stations, ``gap`` = (found - bound) /
    found.
    """

    selection: Selection
    lower_bound: int
    gap: float
    proven_optimal: bool
    status: str
    face_classes: int

    def to_dict(self) -> dict[str, object]:
        return {
            "stations": len(self.selection.stations),
            "lower_bound": self.lower_bound,
            "gap": round(self.gap, 6),
            "proven_optimal": self.proven_optimal,
            "status": self.status,
            "face_classes": self.face_classes,
        }


def face_classes(table: CoverageTable) -> tuple[sp.csc_matrix, np.ndarray]:
    """Merge faces with identical candidate sets.

    Returns
    -------
    cover : (C, K) CSC bool, which candidate covers which class
    area_m2 : (K,) float64, the area of each class
    """
    csc = table.by_face
    achievable = np.flatnonzero(np.diff(csc.indptr) > 0)
    keys: dict[bytes, int] = {}
    class_of = np.empty(len(achievable), np.int64)
    for i, f in enumerate(achievable):
        rows = csc.indices[csc.indptr[f]:csc.indptr[f + 1]]
        class_of[i] = keys.setdefault(rows.tobytes(), len(keys))
    area = np.bincount(class_of, weights=table.face_area_m2[achievable], minlength=len(keys))
    first = np.unique(class_of, return_index=True)[1]
    columns = achievable[first]
    cover = (csc[:, columns] != 0).astype(np.float64).tocsc()
    return cover, area


def solve_optimal(table: CoverageTable, goal: float, time_limit_s: float,
                  upper_bound: int | None = None) -> OptimalResult:
    """The fewest stations reaching ``goal`` of the achievable area (see module docstring)."""
    cover, area = face_classes(table)
    n_cand, n_class = cover.shape
    # rows: y_k - sum_c cover[c, k] x_c <= 0
    link = sp.hstack([-cover.T, sp.identity(n_class, format="csr")], format="csr")
    need = goal * float(area.sum()) - GOAL_SLACK_M2
    area_row = sp.csr_matrix(np.concatenate([np.zeros(n_cand), area])[None, :])
    constraints = [
        LinearConstraint(link, -np.inf, 0.0),
        LinearConstraint(area_row, need, np.inf),
    ]
    if upper_bound is not None:
        count_row = sp.csr_matrix(
            np.concatenate([np.ones(n_cand), np.zeros(n_class)])[None, :])
        constraints.append(LinearConstraint(count_row, 0, upper_bound))
    cost = np.concatenate([np.ones(n_cand), np.zeros(n_class)])
    integrality = np.concatenate([np.ones(n_cand), np.zeros(n_class)])
    result = milp(
        cost, constraints=constraints, integrality=integrality, bounds=Bounds(0, 1),
        options={"time_limit": float(time_limit_s), "disp": False, "presolve": True},
    )
    if result.x is None:
        raise PlannerError(
            f"the optimal solver found no plan within optimal_time_limit_s={time_limit_s} "
            f"({result.message}); raise the time limit or use method 'greedy'"
        )
    chosen = np.flatnonzero(result.x[:n_cand] > 0.5)
    stations = _order_by_gain(table, chosen)
    found = len(stations)
    bound_value = getattr(result, "mip_dual_bound", None)
    bound = found if bound_value is None or not math.isfinite(bound_value) \
        else min(found, math.ceil(bound_value - 1e-6))
    gap = 0.0 if found == 0 else (found - bound) / found
    return OptimalResult(
        selection=replay(table, stations, "optimal"),
        lower_bound=int(bound),
        gap=float(gap),
        proven_optimal=bound == found,
        status=str(result.message),
        face_classes=int(n_class),
    )


def _order_by_gain(table: CoverageTable, chosen: np.ndarray) -> list[int]:
    """The chosen stations in greedy order among themselves (most new area first)."""
    remaining = [int(c) for c in chosen]
    uncovered = np.ones(table.n_faces, bool)
    order: list[int] = []
    while remaining:
        gains = []
        for c in remaining:
            faces = table.faces_of(c)
            gains.append(float(table.face_area_m2[faces[uncovered[faces]]].sum()))
        best = remaining[int(np.argmax(gains))]
        order.append(best)
        remaining.remove(best)
        uncovered[table.faces_of(best)] = False
    return order
