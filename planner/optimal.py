"""The fewest stations that reach the goal: partial set cover, solved exactly with HiGHS.

Faces qualified by exactly the same candidates are merged into one class whose weight is
their total area (a large reduction). The greedy plan is the first incumbent. Then, for
k = (stations of the incumbent) - 1, - 2, ..., a *maximum coverage* MILP asks for the k
stations that cover the most area::

    maximise    sum_k area_k * y_k
    subject to  y_k <= sum_{c covers k} x_c      for every class k
                sum_c x_c = k,   x in {0, 1},   y in [0, 1]

If its best k stations reach the goal they become the incumbent and k goes down; if
HiGHS proves that no k stations reach it (its bound on the coverage falls short), the
incumbent is optimal. (Asking directly for the fewest stations reaching the goal leaves
HiGHS without a feasible start on the halls; maximum coverage always has one.) When the
time limit (``optimal_time_limit_s``, over all rounds) runs out first, the incumbent is
reported with the best proven lower bound: k + 1 for the largest k proven short, at least
the fewest candidates whose single areas add up to the goal. Programs larger than
MAX_NONZEROS are relaxed by merging faces per voxel (proofs stay valid; plans it finds are
checked on the exact table). ``y`` may stay continuous:
with integer ``x`` an optimal ``y_k`` is min(1, sum x) at no loss.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.optimize import Bounds, LinearConstraint, milp

from planner.coverage import CoverageTable
from planner.selection import GOAL_SLACK_M2, Selection, replay

# Above this many nonzeros HiGHS's presolve alone outlasts any sensible time limit (hall-full:
# 10.5 M); face classes are then merged per voxel into a relaxation (see relaxed_classes).
MAX_NONZEROS = 1_500_000


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


def relaxed_classes(
    table: CoverageTable, centroids: np.ndarray, max_nonzeros: int
) -> tuple[sp.csc_matrix, np.ndarray, bool]:
    """Face classes small enough for HiGHS: exact when they fit, else merged by voxel.

    Merging the faces of a voxel into one class covered by the union of their candidates
    over-estimates what any stations cover: the program becomes a relaxation, still good
    for proofs (no k stations reach the goal) but not for accepting a plan, which is then
    checked on the exact table. ``centroids`` is (F, 3); returns cover (C, K), area (K,)
    and whether the classes are exact.
    """
    cover, area = face_classes(table)
    if cover.nnz <= max_nonzeros:
        return cover, area, True
    achievable = np.flatnonzero(table.achievable)
    pattern = (table.by_face[:, achievable] != 0).astype(np.float64)
    cell_m = 0.25
    while True:
        cell = np.floor(centroids[achievable] / cell_m).astype(np.int64)
        voxel = np.unique(cell, axis=0, return_inverse=True)[1].reshape(-1)
        members = sp.csr_matrix((np.ones(len(voxel)), (np.arange(len(voxel)), voxel)))
        merged = ((pattern @ members) != 0).astype(np.float64).tocsc()
        if merged.nnz <= max_nonzeros or merged.shape[1] <= 1:
            area = np.bincount(voxel, weights=table.face_area_m2[achievable])
            return merged, area, False
        cell_m *= 2


def solve_optimal(table: CoverageTable, goal: float, time_limit_s: float,
                  incumbent: Selection, centroids: np.ndarray) -> OptimalResult:
    """The fewest stations reaching ``goal`` of the achievable area (see module docstring).

    ``incumbent`` is a plan known to reach the goal (greedy's): the answer is never worse.
    ``centroids`` (F, 3) place the faces, for the relaxation of programs too large to solve.
    """
    need = goal * table.max_achievable_area_m2 - GOAL_SLACK_M2
    cover, area, exact = relaxed_classes(table, centroids, MAX_NONZEROS)
    n_cand, n_class = cover.shape
    best = list(incumbent.stations[:incumbent.count_for_goal(goal)])
    lower = _counting_bound(table, need)
    deadline = time.monotonic() + time_limit_s
    status = "greedy plan proven optimal by the area bound"
    # rows: y_k - sum_c cover[c, k] x_c <= 0, then sum_c x_c = k
    link = sp.hstack([-cover.T, sp.identity(n_class, format="csr")], format="csr")
    count_row = sp.csr_matrix(np.concatenate([np.ones(n_cand), np.zeros(n_class)])[None, :])
    cost = np.concatenate([np.zeros(n_cand), -area])
    integrality = np.concatenate([np.ones(n_cand), np.zeros(n_class)])
    k = len(best) - 1
    while k >= lower:
        left_s = deadline - time.monotonic()
        if left_s <= 0:
            status = f"time limit reached while trying {k} stations"
            break
        result = milp(
            cost, integrality=integrality, bounds=Bounds(0, 1),
            constraints=[LinearConstraint(link, -np.inf, 0.0),
                         LinearConstraint(count_row, k, k)],
            options={"time_limit": left_s, "disp": False, "presolve": True},
        )
        if result.x is not None and -float(result.fun) >= need:
            chosen = [int(c) for c in np.flatnonzero(result.x[:n_cand] > 0.5)]
            if exact or replay(table, chosen, "optimal").covered_area_m2[-1] >= need:
                best = chosen
                k = len(best) - 1
                status = f"{len(best)} stations reach the goal"
                continue
            status = (f"the relaxed program ({n_class} voxel classes) allows {k} stations "
                      "that do not reach the goal on the exact table")
            break
        bound = getattr(result, "mip_dual_bound", None)
        if result.status == 0 or (bound is not None and -float(bound) < need):
            lower = k + 1  # no k stations reach the goal: proven
            status = f"proven: no {k} stations reach the goal"
        else:
            status = f"time limit reached while trying {k} stations ({result.message})"
        break
    found = len(best)
    lower = min(lower, found)
    stations = _order_by_gain(table, np.asarray(best))
    return OptimalResult(
        selection=replay(table, stations, "optimal"),
        lower_bound=int(lower),
        gap=float((found - lower) / found) if found else 0.0,
        proven_optimal=lower == found,
        status=status,
        face_classes=int(n_class),
    )


def _counting_bound(table: CoverageTable, need_m2: float) -> int:
    """Fewest stations whose single areas could add up to ``need_m2`` (a union is no larger)."""
    single = np.sort(table.area_per_candidate())[::-1]
    reach = np.cumsum(single)
    return min(int(np.searchsorted(reach, need_m2)) + 1, len(single))


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
