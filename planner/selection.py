"""Greedy and weighted greedy choice of stations (after Jia & Lichti, as the paper uses them).

Greedy: take the candidate whose still-uncovered qualified faces have the largest total
area; those faces become covered; repeat. Weighted greedy: the same with each face's area
divided by k_f, the number of candidates that qualify for it, so rarely seen faces count
more; covered area (and so the stopping rule) stays unweighted.

Ties go to the lowest candidate index. Gains are compared after rounding to 1e-9 m^2
(GAIN_QUANTUM_M2): sums of the same faces in another order may differ in the last bit,
and a tie must not depend on that.

The selection is lazy (a priority queue of stale upper bounds, re-evaluated when they reach
the top): gains never grow as faces get covered, so it returns exactly the stations of the
eager loop, in far fewer evaluations.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from planner.coverage import CoverageTable

GAIN_QUANTUM_M2 = 1e-9
# covered >= goal * max achievable, with this much slack for summation order (m^2)
GOAL_SLACK_M2 = 1e-9


@dataclass(frozen=True)
class Selection:
    """Stations in the order chosen, until every achievable face is covered.

    Attributes
    ----------
    stations : (S,) candidate indices
    new_area_m2 : (S,) area each station adds
    covered_area_m2 : (S,) cumulative covered area
    """

    method: str
    stations: tuple[int, ...]
    new_area_m2: tuple[float, ...]
    covered_area_m2: tuple[float, ...]
    max_achievable_area_m2: float

    def count_for_goal(self, goal: float) -> int:
        """Stations needed to reach ``goal`` of the achievable area (its first prefix)."""
        needed = goal * self.max_achievable_area_m2 - GOAL_SLACK_M2
        for i, covered in enumerate(self.covered_area_m2):
            if covered >= needed:
                return i + 1
        return len(self.stations)

    def truncated(self, goal: float) -> Selection:
        """The first stations that reach ``goal``."""
        n = self.count_for_goal(goal)
        return Selection(self.method, self.stations[:n], self.new_area_m2[:n],
                         self.covered_area_m2[:n], self.max_achievable_area_m2)


def greedy(table: CoverageTable, *, weighted: bool = False,
           should_stop: Callable[[], bool] | None = None) -> Selection:
    """Order the candidates greedily until every achievable face is covered."""
    area = table.face_area_m2
    if weighted:
        k = table.candidates_per_face
        weight = np.divide(area, k, out=np.zeros_like(area), where=k > 0)
    else:
        weight = area
    uncovered = np.ones(table.n_faces, bool)

    def gain(candidate: int) -> int:
        faces = table.faces_of(candidate)
        value = float(weight[faces][uncovered[faces]].sum())
        return round(value / GAIN_QUANTUM_M2)

    heap = [(-gain(c), c, 0) for c in range(table.n_candidates)]
    heapq.heapify(heap)
    stations: list[int] = []
    new_area: list[float] = []
    covered: list[float] = []
    total = 0.0
    round_no = 0
    while heap:
        neg_gain, candidate, stamp = heapq.heappop(heap)
        if neg_gain == 0:
            break
        if stamp != round_no:
            heapq.heappush(heap, (-gain(candidate), candidate, round_no))
            continue
        faces = table.faces_of(candidate)
        fresh = faces[uncovered[faces]]
        added = float(area[fresh].sum())
        uncovered[fresh] = False
        total += added
        stations.append(candidate)
        new_area.append(added)
        covered.append(total)
        round_no += 1
        if should_stop is not None and should_stop():
            break
    return Selection(
        method="weighted_greedy" if weighted else "greedy",
        stations=tuple(stations),
        new_area_m2=tuple(new_area),
        covered_area_m2=tuple(covered),
        max_achievable_area_m2=table.max_achievable_area_m2,
    )


def replay(table: CoverageTable, stations: list[int] | tuple[int, ...],
           method: str) -> Selection:
    """The covered area of a given station order (for an optimal set, say)."""
    uncovered = np.ones(table.n_faces, bool)
    new_area: list[float] = []
    covered: list[float] = []
    total = 0.0
    for candidate in stations:
        faces = table.faces_of(candidate)
        fresh = faces[uncovered[faces]]
        added = float(table.face_area_m2[fresh].sum())
        uncovered[fresh] = False
        total += added
        new_area.append(added)
        covered.append(total)
    return Selection(method, tuple(int(s) for s in stations), tuple(new_area), tuple(covered),
                     table.max_achievable_area_m2)


def coverage_state(table: CoverageTable, stations: tuple[int, ...]) -> dict[str, NDArray[np.generic]]:
    """Per-face results of a plan.

    Returns
    -------
    covered : (F,) bool
    best_lpd_pts_m2 : (F,) float32, best LPD over the chosen stations, 0 if none
    n_stations : (F,) int32, chosen stations that qualify
    first_station : (F,) int32, index into ``stations`` of the first that qualifies, -1 if none
    n_candidates : (F,) int32, all candidates that qualify
    """
    n = table.n_faces
    best = np.zeros(n, np.float64)
    count = np.zeros(n, np.int32)
    first = np.full(n, -1, np.int32)
    for order, candidate in enumerate(stations):
        start, stop = table.by_candidate.indptr[candidate], table.by_candidate.indptr[candidate + 1]
        faces = table.by_candidate.indices[start:stop]
        lpd = table.by_candidate.data[start:stop]
        np.maximum.at(best, faces, lpd)
        count[faces] += 1
        unset = faces[first[faces] < 0]
        first[unset] = order
    return {
        "covered": count > 0,
        "best_lpd_pts_m2": best.astype(np.float32),
        "n_stations": count,
        "first_station": first,
        "n_candidates": table.candidates_per_face.astype(np.int32),
    }
