"""Greedy and weighted greedy choice of stations (after Jia & Lichti, as the paper uses them).

Greedy: take the candidate whose still-uncovered qualified faces have the largest total
area; those faces become covered; repeat. Weighted greedy: the same with each face's area
divided by k_f, the number of candidates that qualify for it, so rarely seen faces count
more; covered area (and so the stopping rule) stays unweighted.

Ties go to the lowest candidate index. Face weights are rounded to whole units of 1e-9 m^2
(GAIN_QUANTUM_M2) and summed exactly, so a tie never depends on summation order, and the
gains can be ranked lazily (a candidate's gain is summed again only when it comes to the
top, see :class:`GainOrder`).
"""

from __future__ import annotations

import heapq
from collections.abc import Generator, Iterable
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import NDArray

from planner.selection.sums import numpy_sum
from planner.visibility.coverage import CoverageTable, QualifiedPairs, StationRows

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
    fixed: int = 0  # the first ``fixed`` stations were given (re-scan), not chosen

    def count_for_goal(self, goal: float) -> int:
        """Stations needed to reach ``goal`` of the achievable area (its first prefix).

        Fixed stations always count, even when fewer of them already reach the goal.
        """
        needed = goal * self.max_achievable_area_m2 - GOAL_SLACK_M2
        for i, covered in enumerate(self.covered_area_m2):
            if covered >= needed:
                return max(i + 1, self.fixed)
        return len(self.stations)

    def truncated(self, goal: float) -> Selection:
        """The first stations that reach ``goal``."""
        n = self.count_for_goal(goal)
        return Selection(self.method, self.stations[:n], self.new_area_m2[:n],
                         self.covered_area_m2[:n], self.max_achievable_area_m2, self.fixed)


def gain_units(table: CoverageTable, *, weighted: bool = False
               ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(F,) face weights in units of GAIN_QUANTUM_M2 and the (C,) gain of every candidate.

    Weighted greedy divides each face's area by the number of candidates that qualify for
    it. Units are whole numbers held in float64 below 2**53, so sums and differences of them
    are exact.
    """
    area = table.face_area_m2
    # one (F,) array, divided and rounded in place: the same values as
    # np.round(area / k / GAIN_QUANTUM_M2) without two more (F,) temporaries
    if weighted:
        k = table.candidates_per_face
        units = np.divide(area, k, out=np.zeros_like(area), where=k > 0)
        units /= GAIN_QUANTUM_M2
    else:
        units = area / GAIN_QUANTUM_M2
    np.round(units, out=units)
    if units.sum() >= 2.0**53:
        raise ValueError("the model's area is too large for exact gains; split the model")
    gains = table.sum_per_candidate(units)
    return units, gains


class GainOrder:
    """Candidates ranked by gain (largest first, ties: lowest index), kept lazily.

    Gains only fall as faces get covered, so a gain computed earlier is an upper bound: a
    heap holds those bounds, and a candidate's exact gain is computed again only when it
    comes to the top. Once its exact gain still ranks first, it is the next in the exact
    order (every other bound, and so every other gain, ranks after it). The ranking is the
    one that sorting every candidate's exact gain would give, without a by-face copy of the
    table to update all gains after every station.
    """

    def __init__(self, table: CoverageTable, units: NDArray[np.float64],
                 gains: NDArray[np.float64], uncovered: NDArray[np.bool_]) -> None:
        """``units`` (F,) and ``gains`` (C,) from :func:`gain_units`; ``uncovered`` (F,) is
        read at every ranking (the caller marks faces covered in it)."""
        self.table = table
        self.units = units
        self.uncovered = uncovered
        positive = np.flatnonzero(gains > 0)
        self._heap = list(zip((-gains[positive]).tolist(), positive.tolist(), strict=True))
        heapq.heapify(self._heap)

    def gain(self, candidate: int) -> float:
        """The exact gain of ``candidate`` now (a sum of whole units, so in any order)."""
        table = self.table
        return float(_uncovered_units(table.run_start, table.run_length,
                                      int(table.run_ptr[candidate]),
                                      int(table.run_ptr[candidate + 1]),
                                      self.units, self.uncovered))

    def ranked(self) -> Generator[int, None, None]:
        """The candidates with a positive gain, best first, for the faces uncovered now.

        Close the iterator (or run it out) before covering more faces.
        """
        ranked: list[tuple[float, int]] = []
        try:
            while self._heap:
                _, candidate = heapq.heappop(self._heap)
                gain = self.gain(candidate)
                if gain <= 0:
                    continue  # gains never rise again
                key = (-gain, candidate)
                if self._heap and self._heap[0] < key:
                    heapq.heappush(self._heap, key)  # another may rank higher now
                    continue
                ranked.append(key)
                yield candidate
        finally:
            for key in ranked:
                heapq.heappush(self._heap, key)


@numba.njit(nogil=True, cache=True)
def _uncovered_units(  # compiled: the lazy ranking sums gains again thousands of times
    run_start: NDArray[np.int32], run_length: NDArray[np.int32], first_run: int,
    last_run: int, units: NDArray[np.float64], uncovered: NDArray[np.bool_],
) -> float:
    """The sum of (F,) ``units`` over the ``uncovered`` faces of runs ``first_run ..
    last_run - 1`` of a :class:`CoverageTable`, read in place (no (P,) faces array)."""
    total = 0.0
    for run in range(first_run, last_run):
        for face in range(run_start[run], run_start[run] + run_length[run]):
            if uncovered[face]:
                total += units[face]
    return total


def greedy(table: CoverageTable, *, weighted: bool = False,
           fixed: tuple[int, ...] = ()) -> Selection:
    """Order the candidates greedily until every achievable face is covered.

    ``fixed`` candidates (stations already scanned) come first, in their order, whatever
    they add; greedy then chooses only what is still missing.

    Gains are kept as exact integers (face weights in units of GAIN_QUANTUM_M2, held in
    float64 below 2**53) and ranked lazily (as :class:`GainOrder` ranks them), so ties are
    real ties and go to the lowest index. The order is made in one compiled call
    (:func:`_greedy_order`) that never takes the interpreter's lock, so greedy and weighted
    greedy run side by side on two cores (one Python loop each, they had taken turns).
    """
    units, gains = gain_units(table, weighted=weighted)
    # the areas of a station's newly covered faces, in face order: at most its row's faces
    fresh = np.empty(int(np.diff(table.pair_ptr).max(initial=0)))
    stations, new_area, covered = _greedy_order(
        table.run_ptr, table.run_start, table.run_length, units, gains, table.face_area_m2,
        np.asarray(fixed, np.int64), fresh)
    return Selection(
        method="weighted_greedy" if weighted else "greedy",
        stations=tuple(stations.tolist()),
        new_area_m2=tuple(new_area.tolist()),
        covered_area_m2=tuple(covered.tolist()),
        max_achievable_area_m2=table.max_achievable_area_m2,
        fixed=len(fixed),
    )


@numba.njit(nogil=True, cache=True)
def _greedy_order(run_ptr: NDArray[np.int64], run_start: NDArray[np.int32],
                  run_length: NDArray[np.int32], units: NDArray[np.float64],
                  gains: NDArray[np.float64], area: NDArray[np.float64],
                  fixed: NDArray[np.int64], fresh: NDArray[np.float64]
                  ) -> tuple[NDArray[np.int64], NDArray[np.float64],
                             NDArray[np.float64]]:  # compiled
    """:func:`greedy`'s order over a :class:`CoverageTable`'s runs: the (S,) stations, the
    area each adds and the running total (each added area summed as numpy sums
    ``area[fresh]``, the total one station at a time).

    A heap of (-gain, candidate) holds each candidate's last gain, an upper bound of its
    gain now; the top's gain is summed again, and it is the next station once it still
    ranks first (:class:`GainOrder`'s lazy ranking). ``fixed`` come first. ``fresh``:
    scratch as long as the longest row, for the areas of a station's newly covered faces.
    """
    n_faces = len(units)
    uncovered = np.ones(n_faces, np.bool_)
    heap_key = np.empty(len(gains))  # -gain
    heap_id = np.empty(len(gains), np.int64)
    size = 0
    for c in range(len(gains)):
        if gains[c] > 0:
            heap_key[size], heap_id[size] = -gains[c], c
            size += 1
    for i in range(size // 2 - 1, -1, -1):
        _sift_down(heap_key, heap_id, size, i)
    stations = np.empty(len(gains) + len(fixed), np.int64)
    new_area = np.empty(len(gains) + len(fixed))
    covered = np.empty(len(gains) + len(fixed))
    total = 0.0
    n = 0
    while True:
        if n < len(fixed):
            candidate = fixed[n]
        else:
            candidate = -1
            while size > 0:
                top = heap_id[0]
                size -= 1
                heap_key[0], heap_id[0] = heap_key[size], heap_id[size]
                _sift_down(heap_key, heap_id, size, 0)
                gain = _uncovered_units(run_start, run_length, run_ptr[top],
                                        run_ptr[top + 1], units, uncovered)
                if gain <= 0:
                    continue  # gains never rise again
                key = -gain
                if size > 0 and _before(heap_key[0], heap_id[0], key, top):
                    # another may rank higher now
                    heap_key[size], heap_id[size] = key, top
                    _sift_up(heap_key, heap_id, size)
                    size += 1
                    continue
                candidate = top
                break
            if candidate < 0:
                break
        n_fresh = 0
        for run in range(run_ptr[candidate], run_ptr[candidate + 1]):
            for face in range(run_start[run], run_start[run] + run_length[run]):
                if uncovered[face]:
                    uncovered[face] = False
                    fresh[n_fresh] = area[face]
                    n_fresh += 1
        added = numpy_sum(fresh[:n_fresh])
        total += added
        stations[n], new_area[n], covered[n] = candidate, added, total
        n += 1
    return stations[:n].copy(), new_area[:n].copy(), covered[:n].copy()


@numba.njit(nogil=True, cache=True)
def _before(key_a: float, id_a: int, key_b: float, id_b: int) -> bool:  # compiled
    """(key_a, id_a) < (key_b, id_b), as tuples compare."""
    return key_a < key_b or (key_a == key_b and id_a < id_b)


@numba.njit(nogil=True, cache=True)
def _sift_down(key: NDArray[np.float64], ids: NDArray[np.int64], size: int,
               i: int) -> None:  # compiled
    """Restore the heap order of the first ``size`` entries below entry ``i``."""
    while True:
        least = i
        for child in (2 * i + 1, 2 * i + 2):
            if child < size and _before(key[child], ids[child], key[least], ids[least]):
                least = child
        if least == i:
            return
        key[i], key[least] = key[least], key[i]
        ids[i], ids[least] = ids[least], ids[i]
        i = least


@numba.njit(nogil=True, cache=True)
def _sift_up(key: NDArray[np.float64], ids: NDArray[np.int64], i: int) -> None:  # compiled
    """Restore the heap order above entry ``i`` (just added)."""
    while i > 0:
        parent = (i - 1) // 2
        if not _before(key[i], ids[i], key[parent], ids[parent]):
            return
        key[i], key[parent] = key[parent], key[i]
        ids[i], ids[parent] = ids[parent], ids[i]
        i = parent


def replay(table: CoverageTable, stations: list[int] | tuple[int, ...],
           method: str, fixed: int = 0) -> Selection:
    """The covered area of a given station order (for an optimal set, say).

    ``fixed``: how many of the first stations were given rather than chosen.
    """
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
                     table.max_achievable_area_m2, fixed)


def coverage_state(
    table: CoverageTable | StationRows, stations: tuple[int, ...],
    densities: Iterable[QualifiedPairs],
    min_density_pts_m2: NDArray[np.float64] | None = None,
) -> dict[str, NDArray[np.generic]]:
    """Per-face results of a plan.

    ``densities`` are the qualified pairs of the chosen stations alone, numbered by their
    place in ``stations`` (the table keeps no densities), in blocks of whole stations in
    that order; each block is let go once read. They must be the table's rows of those
    stations.

    Returns
    -------
    covered : (F,) bool
    best_lpd_pts_m2 : (F,) float32, best LPD over the chosen stations, 0 if none
    n_stations : (F,) int32, chosen stations that qualify
    first_station : (F,) int32, index into ``stations`` of the first that qualifies, -1 if none
    n_candidates : (F,) int32, all candidates that qualify
    density_margin : (S,) float64, only with the (F,) ``min_density_pts_m2``: per station,
        the least ratio of density to requirement over the faces it is credited with (those
        no earlier station covers); inf when none of them needs a density
    """
    n = table.n_faces
    best = np.zeros(n, np.float32)  # the LPDs are float32: their maximum is one of them
    count = np.zeros(n, np.int32)
    first = np.full(n, -1, np.int32)
    margin = np.full(len(stations), np.inf)

    def add(order: int, faces: NDArray[np.int32], lpd_pts_m2: NDArray[np.float32]) -> None:
        if not np.array_equal(faces, table.faces_of(stations[order])):
            raise RuntimeError(f"station {order}: the densities computed again are not of "
                               "the faces in the coverage table")
        np.maximum.at(best, faces, lpd_pts_m2)
        count[faces] += 1
        credited = first[faces] < 0
        first[faces[credited]] = order
        if min_density_pts_m2 is not None:
            required = min_density_pts_m2[faces[credited]]
            needs = required > 0
            if needs.any():
                margin[order] = float(np.min(
                    lpd_pts_m2[credited][needs].astype(np.float64) / required[needs]))

    done = 0  # stations read so far
    for block in densities:
        if not len(block.candidate):
            continue
        if block.candidate[0] < done:
            raise RuntimeError("the densities do not come in blocks of whole stations")
        last = int(block.candidate[-1]) + 1
        bounds = np.searchsorted(block.candidate, np.arange(done, last + 1))
        for order in range(done, last):
            rows = slice(bounds[order - done], bounds[order - done + 1])
            add(order, block.face[rows], block.lpd_pts_m2[rows])
        done = last
    for order in range(done, len(stations)):  # stations that qualify for no face
        add(order, np.zeros(0, np.int32), np.zeros(0, np.float32))
    state: dict[str, NDArray[np.generic]] = {
        "covered": count > 0,
        "best_lpd_pts_m2": best,
        "n_stations": count,
        "first_station": first,
        "n_candidates": table.candidates_per_face,
    }
    if min_density_pts_m2 is not None:
        state["density_margin"] = margin
    return state


