"""The fewest stations that reach the goal: never worse than a heuristic, exact where tractable.

The selection stage (:func:`choose_stations`) runs both greedy heuristics, and for
``optimal`` (or the goals of ``curve_goals``) :func:`solve_optimal`:

1. the best heuristic plan (fewest stations; greedy on a tie) is the first incumbent; from
   here on everything runs on the face classes of what the fixed stations leave
   (:func:`planner.selection.classes.class_table`: faces seen by the same candidates are
   covered together by every plan, so merging them loses nothing);
2. a local search improves it: drop a station made redundant by later ones, replace two
   stations by one, and (partial goals) swap one for another where that covers more, which
   may let a later drop succeed. So even a plan stopped at the time limit is as good as it
   cheaply gets;
3. when the lower bound does not meet it, a neighbourhood search
   (:mod:`planner.selection.neighbourhoods`) asks HiGHS, part of the building at a time,
   for fewer stations or as many covering more: small exact programs, limited by work;
4. HiGHS, in a child process killed at the deadline (:mod:`planner.selection.highs_worker`):

   - goal 100 %: the set cover ``min sum x_c  s.t.  sum_{c covers k} x_c >= 1`` over face
     classes (faces seen by exactly the same candidates merge into one row). Most rows are
     implied by others (a class seen by a superset of another's candidates is covered
     whenever that one is), so rows are generated lazily: start from the classes seen by
     the fewest candidates, solve, add the rows the answer leaves uncovered, repeat. Every
     round solves a relaxation (a proven lower bound); a round whose answer covers every
     class is optimal. Answers that miss a few classes are repaired (greedy completion +
     local search) into plans. Dominated columns and forced candidates are left to HiGHS's
     presolve, which does both on these small programs.
   - partial goals: for k = (stations of the incumbent) - 1 a *maximum coverage* MILP asks
     for the k stations covering the most area (``y_k <= sum_{c covers k} x_c``,
     ``sum x <= k``; continuous ``y`` is exact with integer ``x``). Reaching the goal gives
     a better incumbent and k goes down; a dual bound short of the goal proves that no k
     stations reach it. Programs over MAX_NONZEROS are relaxed by merging faces per voxel
     (proofs stay valid; plans it finds are checked, and repaired, on the exact table).

The lower bound is the best of: the fewest candidates whose single areas add up to the goal,
the Lagrangian dual of the cover LP (:mod:`planner.selection.lower_bound`, which alone may
prove the incumbent and spare HiGHS), HiGHS's dual bounds, k + 1 for the largest k proven
short. ``proven_optimal`` is true when it meets the plan.

Fixed stations (re-scan, ``fixed_stations``) are in every plan: their faces count as
covered, the programs are solved for what is still missing, and they are never dropped.

Registration connectivity (``min_overlap_m2``, a ``graph`` for :func:`solve_optimal`): the
incumbents are the connected greedy plans, every local-search move and repair must keep the
chosen stations connected on the overlap graph, and every program gets the single-commodity
flow of :mod:`planner.selection.connectivity` (a MIP start from the incumbent included).

A hook for other side constraints: ``constraint_hooks`` are called with every program before
it is solved (:class:`ProgramBuilder`; the first variables are the candidates' ``x``). The
heuristic plans do not know such constraints; a hook that needs them must check incumbents
too.
"""

from __future__ import annotations

import heapq
import math
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numba
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from planner.selection.classes import class_table, labels_per_candidate
from planner.selection.connectivity import Connectivity, OverlapGraph, add_flow
from planner.selection.greedy import GOAL_SLACK_M2, Selection, greedy, replay
from planner.selection.highs_worker import Answer, HighsProcess
from planner.selection.lower_bound import pattern_product, station_lower_bound
from planner.selection.neighbourhoods import neighbourhood_search
from planner.selection.program import ProgramBuilder
from planner.visibility.coverage import CoverageTable

# Above this many nonzeros HiGHS's presolve alone outlasts any sensible time limit (hall-full:
# 10.5 M); face classes are then merged per voxel into a relaxation (see relaxed_classes).
MAX_NONZEROS = 1_500_000
# the volume algorithm's work in ``optimal`` per second of the time limit, counted as
# station_lower_bound counts it (the runs of classes and the classes an iteration reads),
# and at most this many iterations. Its bound keeps rising long after the heuristic plans'
# iterations: the 9.7 M-face office at 80 % (808,000 classes; measured when the iterations
# summed every pair), 160 after 28 iterations, 176 after 100, 189 after 285, 192 after 600
# and after 1,200
BOUND_WORK_PER_LIMIT_S = 250_000_000
BOUND_MAX_ITERATIONS = 1500
# set cover rows in the first round, and at most this many added per round
SET_COVER_ROWS_PER_ROUND = 1000
# how much less than a station's unique area a candidate may cover and still be tried in its
# place (m^2: far above the float sums' rounding, so the pruning never drops a real move)
PRUNE_TOLERANCE_M2 = 1e-6
# a swap must cover this much more area to count as an improvement (m^2; stops cycling)
SWAP_MIN_GAIN_M2 = 1e-6


@dataclass(frozen=True)
class Move:
    """One change of the local search: ``removed`` stations replaced by ``added`` ones."""

    kind: str  # "drop", "two_for_one", "swap" or "neighbourhood"
    removed: tuple[int, ...]
    added: tuple[int, ...]

    def to_dict(self) -> dict[str, object]:
        return {"move": self.kind, "removed": list(self.removed), "added": list(self.added)}


@dataclass(frozen=True)
class OptimalResult:
    """The answer for one goal.

    ``proven_optimal`` is true when no plan with fewer stations exists; ``lower_bound`` is
    the proven minimum number of stations, ``gap`` = (found - bound) / found.
    ``seconds`` (local search, MILP) is timing: never written into the result files.
    """

    goal: float
    selection: Selection
    lower_bound: int
    gap: float
    proven_optimal: bool
    status: str
    face_classes: int
    best_heuristic: str
    heuristic_stations: int
    local_search: tuple[Move, ...]
    local_search_stations: int
    neighbourhoods: int = 0  # programs of the neighbourhood search
    seconds: dict[str, float] = field(default_factory=dict, compare=False)

    def to_dict(self) -> dict[str, object]:
        return {
            "stations": len(self.selection.stations),
            "lower_bound": self.lower_bound,
            "gap": round(self.gap, 6),
            "proven_optimal": self.proven_optimal,
            "status": self.status,
            "face_classes": self.face_classes,
        }


# builder -> None: adds side constraints (see the module docstring)
ConstraintHook = Callable[[ProgramBuilder], None]
# stations (candidate indices) -> whether a plan satisfies a side constraint
Keep = Callable[[Sequence[int]], bool]
# (k,) face indices -> their (k, 3) centroids (the scene's ``centroids_of``)
CentroidsOf = Callable[[NDArray[Any]], NDArray[np.float64]]


def relaxed_classes(
    table: CoverageTable, centroids: np.ndarray, max_nonzeros: int,
    faces: NDArray[np.bool_] | None = None,
) -> tuple[sp.csc_matrix, np.ndarray, bool]:
    """Classes small enough for HiGHS: ``table``'s own faces when they fit, else merged by
    voxel.

    ``table`` is a table of face classes (:func:`planner.selection.classes.class_table`,
    as :func:`solve_optimal` has it; a table of faces works too, with a larger program).
    Merging the classes of a voxel into one covered by the union of their candidates
    over-estimates what any stations cover: the program becomes a relaxation, still good
    for proofs (no k stations reach the goal) but not for accepting a plan, which is then
    checked on the exact table. ``centroids`` is (F, 3); ``faces`` (F,) bool limits the
    classes to those faces; returns cover (C, K), area (K,) and whether the classes are
    exact.
    """
    mask = table.achievable if faces is None else faces & table.achievable
    achievable = np.flatnonzero(mask)
    if table.n_pairs <= max_nonzeros:
        exact = table.pattern(np.float64).tocsc()
        if not mask.all():  # a class table's classes all are (no copy of every entry)
            exact = exact[:, achievable]
        return exact, table.face_area_m2[mask], True
    # each candidate's voxels read off the table's runs (labels_per_candidate): no pattern
    # of the pairs, where a product with a (F, V) membership matrix held float copies of it
    cell_m = 0.25
    voxel_of = np.full(table.n_faces, -1, np.int32)  # (F,) each achievable face's voxel
    while True:
        cell = np.floor(centroids[achievable] / cell_m).astype(np.int64)
        voxel = np.unique(cell, axis=0, return_inverse=True)[1].reshape(-1)
        voxel_of[achievable] = voxel
        n_voxels = int(voxel.max()) + 1 if len(voxel) else 0
        merged = labels_per_candidate(table, voxel_of, n_voxels).astype(np.float64).tocsc()
        if merged.nnz <= max_nonzeros or merged.shape[1] <= 1:
            area = np.bincount(voxel, weights=table.face_area_m2[achievable])
            return merged, area, False
        cell_m *= 2


# --- local search ----------------------------------------------------------------------


class _CoverState:
    """How many chosen stations see each face, and the moves that keep the goal.

    Areas compared here are float sums in another order than :func:`replay`'s; a plan is
    accepted only after replay confirms it (see :func:`local_search`).
    """

    def __init__(self, table: CoverageTable, stations: list[int], n_fixed: int,
                 need_m2: float, keep: Keep | None = None,
                 by_face: sp.csc_matrix | None = None) -> None:
        self.table = table
        self.keep = keep
        self.area = table.face_area_m2
        # (C, F) by face, made here, not kept by the table: it goes with the search (only
        # its indices are read: bool, 1 byte a pair of data); ``by_face``: the caller's
        self.pattern = table.pattern(np.bool_).tocsc() if by_face is None else by_face
        self.stations = list(stations)
        self.n_fixed = n_fixed
        self.need_m2 = need_m2
        self.count = np.zeros(table.n_faces, np.int32)
        for s in self.stations:
            self.count[table.faces_of(s)] += 1
        self._covered_m2: float | None = None  # summed again after each move

    @property
    def covered_m2(self) -> float:
        if self._covered_m2 is None:
            self._covered_m2 = float(self.area[self.count > 0].sum())
        return self._covered_m2

    def _gain(self, faces: NDArray[np.int64]) -> NDArray[np.float64]:
        """(C,) float64: area of ``faces`` each candidate qualifies for (summed face by face
        in the order of ``faces``, as the product of the pattern's columns would; a
        compiled pass over those columns: the office's local search made 50,000 of these
        sums, 21.6 of its 37.5 s by slicing and multiplying)."""
        pattern = self.pattern
        return _column_sums(pattern.indptr, pattern.indices,
                            np.asarray(faces, np.int64), self.area, self.table.n_candidates)

    def _apply(self, removed: tuple[int, ...], added: tuple[int, ...]) -> None:
        self._covered_m2 = None
        for s in removed:
            self.count[self.table.faces_of(s)] -= 1
            self.stations.remove(s)
        for s in added:
            self.count[self.table.faces_of(s)] += 1
            self.stations.append(s)

    def _keeps(self, removed: tuple[int, ...], added: tuple[int, ...]) -> bool:
        """Whether the plan after the move passes ``keep`` (always without one)."""
        if self.keep is None:
            return True
        return self.keep([s for s in self.stations if s not in removed] + list(added))

    def unique_faces(self, station: int) -> NDArray[np.int64]:
        faces = self.table.faces_of(station)
        return np.asarray(faces[self.count[faces] == 1], np.int64)

    def drop_pass(self) -> list[Move]:
        """Drop, earliest first, every station the others make redundant."""
        moves = []
        for s in list(self.stations[self.n_fixed:]):
            lost = float(self.area[self.unique_faces(s)].sum())
            if self.covered_m2 - lost >= self.need_m2 and self._keeps((s,), ()):
                self._apply((s,), ())
                moves.append(Move("drop", (s,), ()))
        return moves

    def two_for_one(self) -> Move | None:
        """The first pair (least area only it covers) that one candidate can replace."""
        free = self.stations[self.n_fixed:]
        if len(free) < 2:
            return None
        covered = self.covered_m2
        unique = {s: self.unique_faces(s) for s in free}
        unique_gain = {s: self._gain(unique[s]) for s in free}
        unique_area = {s: float(self.area[unique[s]].sum()) for s in free}
        shared = self._shared_by_two(free)
        for lost, (a, b) in self._hopeful_pairs(free, unique_gain, unique_area, shared,
                                                covered - self.need_m2):
            gain = unique_gain[a] + unique_gain[b]
            if (a, b) in shared:
                gain = gain + self._gain(shared[(a, b)])
            gain[[a, b]] = -np.inf  # keeping one of them is a drop, found by drop_pass
            best = int(np.argmax(gain))  # lowest index among equals
            if covered - lost + gain[best] < self.need_m2:
                continue
            if not self._keeps((a, b), (best,)):
                # the replacements reaching the goal, most gain first (lowest index)
                enough = np.flatnonzero(covered - lost + gain >= self.need_m2)
                kept = [int(c) for c in enough[np.lexsort((enough, -gain[enough]))]
                        if self._keeps((a, b), (int(c),))]
                if not kept:
                    continue
                best = kept[0]
            move = Move("two_for_one", (a, b), (best,))
            self._apply(move.removed, move.added)
            return move
        return None

    def _hopeful_pairs(self, free: list[int], unique_gain: dict[int, NDArray[np.float64]],
                       unique_area: dict[int, float],
                       shared: dict[tuple[int, int], NDArray[np.int64]], slack_m2: float
                       ) -> list[tuple[float, tuple[int, int]]]:
        """(lost area, (a, b)) of the pairs of free stations one candidate may replace,
        least lost area first (then the lower stations).

        A candidate replacing a and b must win back all but ``slack_m2`` (the area covered
        beyond the need) of what only they cover, so at least as much of a's unique area and
        of b's alone: pairs without such a candidate in common cannot succeed and are left
        out (a plan of 2,500 stations has 3 M pairs, a handful of them hopeful).
        """
        near = [unique_gain[s] >= unique_area[s] - slack_m2 - PRUNE_TOLERANCE_M2 for s in free]
        able = sp.csr_matrix(np.stack(near).astype(np.float32))  # (S, C)
        common = sp.triu(able @ able.T, k=1).tocoo()  # (S, S) pairs with such a candidate
        pairs = []
        for i, j in zip(common.row.tolist(), common.col.tolist(), strict=True):
            a, b = free[i], free[j]
            key = (min(a, b), max(a, b))
            lost = unique_area[a] + unique_area[b]
            if key in shared:
                lost += float(self.area[shared[key]].sum())
            pairs.append((lost, key))
        pairs.sort()
        return pairs

    def _shared_by_two(self, free: list[int]) -> dict[tuple[int, int], NDArray[np.int64]]:
        """Faces seen by exactly two chosen stations, both free: (a, b) -> faces."""
        two = np.flatnonzero(self.count == 2)
        if len(two) == 0:
            return {}
        chosen = np.zeros(self.table.n_candidates, np.bool_)
        chosen[self.stations] = True
        low, high = _two_holders(self.pattern.indptr, self.pattern.indices, two, chosen)
        free_set = set(free)
        result: dict[tuple[int, int], NDArray[np.int64]] = {}
        order = np.lexsort((high, low))
        keys = np.stack([low[order], high[order]], axis=1)
        splits = np.flatnonzero(np.any(np.diff(keys, axis=0) != 0, axis=1)) + 1
        for group in np.split(order, splits):
            a, b = int(low[group[0]]), int(high[group[0]])
            if a in free_set and b in free_set:
                result[(a, b)] = two[group]
        return result

    def best_swap(self) -> Move | None:
        """The swap of one free station that covers the most additional area, if any."""
        free = self.stations[self.n_fixed:]
        if not free:
            return None
        covered = self.covered_m2
        fresh = self._gain(np.flatnonzero((self.count == 0) & self.table.achievable))
        best: tuple[float, int, int] | None = None
        chosen = np.zeros(self.table.n_candidates, bool)
        chosen[self.stations] = True
        for a in free:
            faces = self.unique_faces(a)
            after = covered - float(self.area[faces].sum()) + fresh + self._gain(faces)
            after[chosen] = -np.inf
            c = int(np.argmax(after))
            if after[c] > covered + SWAP_MIN_GAIN_M2 and (best is None or after[c] > best[0]):
                best = (float(after[c]), a, c)
        if best is None or not self._keeps((best[1],), (best[2],)):
            return None
        move = Move("swap", (best[1],), (best[2],))
        self._apply(move.removed, move.added)
        return move

    def complete(self) -> list[Move]:
        """Add greedily (most new area, lowest index) until the goal is met."""
        moves = []
        while self.covered_m2 < self.need_m2:
            gain = self._gain(np.flatnonzero((self.count == 0) & self.table.achievable))
            c = int(np.argmax(gain))
            if gain[c] <= 0:
                break
            self._apply((), (c,))
            moves.append(Move("add", (), (c,)))
        return moves


@numba.njit(nogil=True, cache=True)
def _column_sums(indptr: NDArray[np.int32], indices: NDArray[np.int32],
                 faces: NDArray[np.int64], area: NDArray[np.float64], n_rows: int
                 ) -> NDArray[np.float64]:  # compiled
    """(n_rows,) ``area[f]`` added to every row of column f of a CSC pattern, for each f
    of ``faces`` in turn."""
    sums = np.zeros(n_rows)
    for f in faces:
        value = area[f]
        for j in range(indptr[f], indptr[f + 1]):
            sums[indices[j]] += value
    return sums


@numba.njit(nogil=True, cache=True)
def _two_holders(indptr: NDArray[np.int32], indices: NDArray[np.int32],
                 faces: NDArray[np.int64], chosen: NDArray[np.bool_]
                 ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:  # compiled
    """(F2,) each of ``faces``' two ``chosen`` rows in a CSC pattern: the lower and the
    higher (every face held by exactly two chosen rows)."""
    low = np.empty(len(faces), np.int64)
    high = np.empty(len(faces), np.int64)
    for i in range(len(faces)):
        f = faces[i]
        first = -1
        for j in range(indptr[f], indptr[f + 1]):
            c = indices[j]
            if chosen[c]:
                if first < 0:
                    first = c
                else:
                    low[i], high[i] = min(first, c), max(first, c)
    return low, high


def local_search(table: CoverageTable, stations: Sequence[int], need_m2: float,
                 n_fixed: int, deadline: float, *, swaps: bool, keep: Keep | None = None,
                 by_face: sp.csc_matrix | None = None) -> tuple[list[int], list[Move]]:
    """Improve a plan that reaches ``need_m2``: drops, two-for-one, then (``swaps``) swaps.

    The first ``n_fixed`` stations stay; every move keeps ``keep`` true (a side constraint
    such as registration connectivity). Returns the stations (fixed first) and the moves;
    the plan is the input again when replay does not confirm the goal (float order).
    ``by_face``: the table's (C, F) pattern by face, when the caller holds it already.
    """
    state = _CoverState(table, list(stations), n_fixed, need_m2, keep, by_face)
    moves = state.drop_pass()
    swaps_left = 2 * len(stations) if swaps else 0
    while time.monotonic() < deadline:
        move = state.two_for_one()
        if move is None and swaps_left > 0:
            move = state.best_swap()
            swaps_left -= 1
        if move is None:
            break
        moves.append(move)
        moves += state.drop_pass()
    if not moves:
        return list(stations), []
    if replay(table, state.stations, "optimal").covered_area_m2[-1] < need_m2:
        return list(stations), []
    return state.stations, moves


def most_coverage(table: CoverageTable, stations: Sequence[int], n_fixed: int
                  ) -> tuple[list[int], list[Move]]:
    """As many stations covering more: swaps of one free station for the candidate that
    adds the most in its place, while a swap adds more than SWAP_MIN_GAIN_M2, at most two a
    free station (no clock: the same plan on any machine). Runs on the face classes.

    Returns the stations (the first ``n_fixed`` first, the others in greedy order among
    themselves) and the swaps; the input when no swap helps.
    """
    classes = class_table(table, table.achievable)
    state = _CoverState(classes.table, list(stations), n_fixed, need_m2=0.0)
    moves: list[Move] = []
    for _ in range(2 * (len(stations) - n_fixed)):
        move = state.best_swap()
        if move is None:
            break
        moves.append(move)
    if not moves:
        return list(stations), []
    fixed = list(stations[:n_fixed])
    kept = state.stations[n_fixed:]  # the swaps touch free stations only
    return fixed + _order_by_gain(table, kept, table.covered_by(fixed)), moves


def _repair(table: CoverageTable, stations: list[int], need_m2: float, n_fixed: int,
            deadline: float, keep: Keep | None = None,
            by_face: sp.csc_matrix | None = None) -> list[int]:
    """A plan from stations that may miss the goal: greedy completion, then local search.

    Empty when it misses the goal or (greedy completion knows no side constraint) fails
    ``keep``. ``by_face``: as for :func:`local_search`.
    """
    state = _CoverState(table, stations, n_fixed, need_m2, by_face=by_face)
    state.complete()
    if state.covered_m2 < need_m2 or (keep is not None and not keep(state.stations)):
        return []
    return local_search(table, state.stations, need_m2, n_fixed, deadline, swaps=False,
                        keep=keep, by_face=state.pattern)[0]


# --- the solver ------------------------------------------------------------------------


def solve_optimal(
    table: CoverageTable, goal: float, time_limit_s: float,
    incumbents: Sequence[Selection], centroids_of: CentroidsOf, *,
    fixed: tuple[int, ...] = (), deadline: float | None = None,
    constraint_hooks: Sequence[ConstraintHook] = (), tick: Callable[[], None] | None = None,
    graph: OverlapGraph | None = None,
) -> OptimalResult:
    """The fewest stations reaching ``goal`` of the achievable area (see module docstring).

    ``incumbents`` are heuristic plans (greedy, weighted greedy; their first stations are
    ``fixed``): the answer is never worse than the best of them. ``centroids_of`` gives the
    (k, 3) centroids of (k,) faces: they place the faces for the relaxation of programs
    too large to solve. Stops by ``time_limit_s``
    (or the earlier ``deadline``, ``time.monotonic()`` seconds). ``tick`` is called about
    twice a second while HiGHS works and may raise to cancel.

    ``graph`` (registration overlap, :mod:`planner.selection.connectivity`): every plan must be
    connected on it. The incumbents must then be connected plans (connected greedy), the
    local search keeps connectivity and the MILPs carry the flow rows; a graph too big for
    them leaves the local search's plan.
    """
    start = time.monotonic()
    stop = start + time_limit_s if deadline is None else min(deadline, start + time_limit_s)
    need = goal * table.max_achievable_area_m2 - GOAL_SLACK_M2
    counts = [s.count_for_goal(goal) for s in incumbents]
    pick = int(np.argmin(counts))  # the first of equals: greedy before weighted greedy
    heuristic = list(incumbents[pick].stations[:counts[pick]])
    n_fixed = len(fixed)
    keep = None if graph is None else graph.connected
    # the search runs on the face classes of what the fixed stations leave (lossless: every
    # plan covers the same area of them, summed in another order; GOAL_SLACK_M2 absorbs it)
    fixed_faces = table.covered_by(fixed)
    rest = table.achievable & ~fixed_faces
    need_rest = need - float(table.face_area_m2[fixed_faces].sum())
    classes = class_table(table, rest)
    del rest, fixed_faces
    search = classes.table
    best, moves = local_search(search, heuristic, need_rest, n_fixed, stop,
                               swaps=goal < 1.0, keep=keep)
    seconds = {"local_search": time.monotonic() - start}
    after_search = len(best)
    # the local search stops by the clock: a plan it left early may differ between runs
    late = time.monotonic() >= stop

    lower = n_fixed + _counting_bound(search, need_rest, search.achievable)
    status = "the plan meets the area bound (fewest candidates whose areas add up to the goal)"
    n_classes = 0
    neighbourhoods = 0
    dual_method = "area bound"
    if len(best) > lower and need_rest > 0:
        t_bound = time.monotonic()
        # the bound's work grows with the time asked for, counted in what its iterations
        # read, not in seconds
        dual = station_lower_bound(
            search, need_rest, len(best) - n_fixed,
            work=int(BOUND_WORK_PER_LIMIT_S * time_limit_s),
            max_iterations=BOUND_MAX_ITERATIONS)
        seconds["lower_bound"] = time.monotonic() - t_bound
        if n_fixed + dual.stations > lower:
            lower = n_fixed + dual.stations
            dual_method = dual.method
            status = f"the plan meets the {dual.method}"
    t_milp = time.monotonic()
    reached = graph is None or bool(
        best and replay(search, best, "optimal").covered_area_m2[-1] >= need_rest)
    if not reached:
        status = "the connected greedy plan does not reach the goal"
    elif graph is not None and graph.too_big:
        status = (f"{len(graph.edges)} overlap edges are too many for the flow MILP: the "
                  "connected greedy plan after local search")
    elif len(best) > lower and need_rest > 0:
        with HighsProcess(tick) as highs:
            highs.start()
            stopped = False
            if not constraint_hooks:  # the neighbourhoods' programs know no hook's rows
                searched = neighbourhood_search(
                    search, centroids_of(classes.first_face), best, need_rest, n_fixed,
                    lambda program: highs.solve(program, stop), full=goal >= 1.0, keep=keep,
                    floor=lower)
                best, stopped = searched.stations, searched.stopped
                neighbourhoods = searched.programs
                moves += [Move("neighbourhood", removed, added)
                          for removed, added in searched.moves]
                seconds["neighbourhoods"] = time.monotonic() - t_milp
                if stopped:
                    status = (f"time limit reached in the neighbourhood search "
                              f"({neighbourhoods} programs)")
                elif len(best) <= lower:
                    status = f"the neighbourhood search's plan meets the {dual_method}"
            if len(best) > lower and not stopped:
                solver = _set_cover if goal >= 1.0 else _partial_cover
                best, lower, status, n_classes = solver(
                    _Problem(search, centroids_of(classes.first_face), need_rest, fixed,
                             constraint_hooks, stop, highs, graph), best, lower)
    seconds["milp"] = time.monotonic() - t_milp - seconds.get("neighbourhoods", 0.0)
    # the classes hold only what the fixed stations leave
    stations = list(fixed) + _order_by_gain(search, [s for s in best if s not in fixed],
                                            np.zeros(classes.n_classes, bool))
    del search, classes
    selection = replay(table, stations, "optimal", n_fixed)
    if stations and selection.covered_area_m2[-1] < need:
        # the class sums met the goal by less than their order's rounding (never seen)
        fallback = replay(table, heuristic, "optimal", n_fixed)
        if fallback.covered_area_m2[-1] >= need:
            selection, moves = fallback, []
    found = len(selection.stations)
    lower = min(lower, found)
    if late:
        status = f"time limit reached in the local search; {status}"
    return OptimalResult(
        goal=goal,
        selection=selection,
        lower_bound=int(lower),
        gap=float((found - lower) / found) if found else 0.0,
        proven_optimal=lower == found and reached,
        status=status,
        face_classes=int(n_classes),
        best_heuristic=incumbents[pick].method,
        heuristic_stations=len(heuristic),
        local_search=tuple(moves),
        local_search_stations=after_search,
        neighbourhoods=neighbourhoods,
        seconds=seconds,
    )


@dataclass(frozen=True)
class _Problem:
    """What is still missing after the fixed stations, and how to solve it."""

    table: CoverageTable  # the classes of what the fixed stations leave
    centroids: np.ndarray  # (K, 3) a face of each class
    need_m2: float  # area of ``table`` to cover
    fixed: tuple[int, ...]
    hooks: Sequence[ConstraintHook]
    deadline: float
    highs: HighsProcess
    graph: OverlapGraph | None = None  # registration connectivity: the flow rows

    def builder(self) -> ProgramBuilder:
        return ProgramBuilder(self.table.n_candidates)

    @property
    def keep(self) -> Keep | None:
        return None if self.graph is None else self.graph.connected

    def solve(self, builder: ProgramBuilder, capacity: int) -> Answer | None:
        """HiGHS's answer; ``capacity``: the most stations of a plan of interest."""
        if self.graph is not None:
            add_flow(builder, self.graph, capacity)
        for hook in self.hooks:
            hook(builder)
        return self.highs.solve(builder.build(), self.deadline)

    def plan_of(self, x: NDArray[np.float64]) -> list[int]:
        chosen = [int(c) for c in np.flatnonzero(x[:self.table.n_candidates] > 0.5)]
        return list(self.fixed) + [c for c in chosen if c not in self.fixed]


def _set_cover(problem: _Problem, best: list[int], lower: int
               ) -> tuple[list[int], int, str, int]:
    """Goal 100 %: set cover with lazily generated rows (see the module docstring)."""
    # (K, C) bool: the table holds classes (5 bytes a pair; a round's rows are made float)
    rows = problem.table.pattern(np.bool_).T.tocsr()
    n_class = rows.shape[0]
    size = np.diff(rows.indptr)
    by_size = np.lexsort((np.arange(n_class), size))  # fewest candidates first
    active = np.zeros(n_class, bool)
    active[by_size[:SET_COVER_ROWS_PER_ROUND]] = True
    n_fixed = len(problem.fixed)
    status = "time limit reached before HiGHS answered"
    while True:
        builder = problem.builder()
        builder.set_cost(0, np.ones(problem.table.n_candidates))
        builder.add_rows(rows[np.flatnonzero(active)].astype(np.float64), 1.0, np.inf)
        builder.start = np.zeros(problem.table.n_candidates)
        builder.start[[c for c in best if c not in problem.fixed]] = 1.0
        answer = problem.solve(builder, len(best))
        if answer is None:
            status = f"time limit reached solving the set cover on {active.sum()} rows"
            break
        if answer.dual_bound is not None:
            lower = max(lower, n_fixed + math.ceil(answer.dual_bound - 1e-6))
        if answer.x is None:
            status = f"HiGHS: {answer.message}"
            break
        x = answer.x[:problem.table.n_candidates] > 0.5
        missed = np.flatnonzero(pattern_product(rows, x.astype(np.float64)) < 0.5)
        plan = problem.plan_of(answer.x)
        if len(missed) == 0:
            if len(plan) < len(best):
                best = plan
            status = (f"set cover solved on {active.sum()} of {n_class} face classes"
                      if answer.status == 0 else
                      f"time limit reached in the set cover ({answer.message})")
            break
        repaired = _repair(problem.table, plan, problem.need_m2, n_fixed, problem.deadline,
                           problem.keep, by_face=rows.T)  # rows by class: the pattern by face
        if repaired and len(repaired) < len(best):
            best = repaired
        if len(best) <= lower:
            status = (f"a repaired set cover on {active.sum()} of {n_class} face classes "
                      "meets the lower bound")
            break
        if answer.status != 0:
            status = f"time limit reached in the set cover ({answer.message})"
            break
        add = missed[np.lexsort((missed, size[missed]))][:SET_COVER_ROWS_PER_ROUND]
        active[add] = True
    return best, lower, status, n_class


def _partial_cover(problem: _Problem, best: list[int], lower: int
                   ) -> tuple[list[int], int, str, int]:
    """Partial goals: the fewest stations covering ``need_m2``, from the incumbent.

    ``min sum x  s.t.  y_k <= sum_{c covers k} x_c,  sum_k area_k y_k >= need`` with
    ``y`` in [0, 1] continuous (exact with integer ``x``: a covered class may take y = 1).
    HiGHS starts from the incumbent (a MIP start), so the answer is never worse, and its
    dual bound is a lower bound whenever it stops.
    """
    table = problem.table
    cover, area, exact = relaxed_classes(table, problem.centroids, MAX_NONZEROS)
    n_cand, n_class = cover.shape
    n_fixed = len(problem.fixed)
    builder = problem.builder()
    builder.set_cost(0, np.ones(n_cand))
    x0 = np.zeros(n_cand)
    x0[[c for c in best if c not in problem.fixed]] = 1.0
    builder.add_partial_cover(cover, area, problem.need_m2, x_start=x0)
    del cover  # the builder holds the program's rows; the pattern is not needed again
    answer = problem.solve(builder, len(best))
    if answer is None:
        return best, lower, f"time limit reached before HiGHS answered ({n_class} face classes)", \
            n_class
    if answer.dual_bound is not None:
        lower = max(lower, n_fixed + math.ceil(answer.dual_bound - 1e-6))
    status = f"HiGHS: {answer.message}"
    if answer.x is not None:
        plan = problem.plan_of(answer.x)
        if replay(table, plan, "optimal").covered_area_m2[-1] < problem.need_m2:
            plan = _repair(table, plan, problem.need_m2, n_fixed, problem.deadline,
                           problem.keep)
            if not exact:
                status += " (relaxed answer, repaired on the exact table)"
        if plan and len(plan) < len(best):
            best = plan
    if not exact:
        status += f"; relaxed per voxel to {n_class} classes"
    return best, lower, status, n_class


def _counting_bound(table: CoverageTable, need_m2: float, faces: NDArray[np.bool_]) -> int:
    """Fewest stations whose single areas on ``faces`` could add up to ``need_m2``."""
    if need_m2 <= 0:
        return 0
    single = np.sort(table.sum_per_candidate(table.face_area_m2 * faces))[::-1]
    reach = np.cumsum(single)
    return min(int(np.searchsorted(reach, need_m2)) + 1, len(single))


def _order_by_gain(table: CoverageTable, chosen: Sequence[int],
                   already: NDArray[np.bool_]) -> list[int]:
    """The chosen stations in greedy order among themselves (most new area first, the
    earlier in ``chosen`` among equals).

    ``already`` (F,) bool: faces covered before them (by fixed stations). A station's new
    area only shrinks as others come first, so the gains are evaluated lazily: a heap of
    the last known gains, and the top is taken once its gain, made again, still tops it
    (2,500 stations in seconds, where evaluating every gain for every place took a minute).
    """
    uncovered = ~already

    def gain(c: int) -> float:
        faces = table.faces_of(c)
        return float(table.face_area_m2[faces[uncovered[faces]]].sum())

    heap = [(-gain(int(c)), place, int(c)) for place, c in enumerate(chosen)]
    heapq.heapify(heap)
    order: list[int] = []
    while heap:
        _, place, c = heapq.heappop(heap)
        fresh = (-gain(c), place, c)
        if heap and fresh > heap[0]:
            heapq.heappush(heap, fresh)  # another may be better now
            continue
        order.append(c)
        uncovered[table.faces_of(c)] = False
    return order


# --- the selection stage ---------------------------------------------------------------

# how far a greedy method's selection stage is once its heuristic plans are made: the
# lower bound beside the plan is the rest (hall-full: 0.1 s of heuristics, 0.5 s of bound;
# the 9.7 M-piece office: 2 s and 6 s)
HEURISTICS_SHARE = 0.3


@dataclass(frozen=True)
class SelectionOutcome:
    """What the selection stage decided, for :class:`planner.pipeline.PlanResult`.

    ``curve`` holds one :class:`OptimalResult` per goal of ``curve_goals`` (ascending);
    ``report`` is the ``selection`` object of plan.json (no timings); ``seconds`` the
    time per step, for the job record only.
    """

    selections: dict[str, Selection]
    chosen: Selection
    optimal: OptimalResult | None
    curve: tuple[OptimalResult, ...]
    report: dict[str, Any]
    seconds: dict[str, float]


def choose_stations(table: CoverageTable, *, method: str, goal: float, time_limit_s: float,
                    centroids_of: CentroidsOf, fixed: tuple[int, ...] = (),
                    curve_goals: tuple[float, ...] | None = None,
                    constraint_hooks: Sequence[ConstraintHook] = (),
                    progress: Callable[[float], None] | None = None,
                    connectivity: Connectivity | None = None) -> SelectionOutcome:
    """Both heuristics, then ``optimal`` for the plan's goal and for ``curve_goals``.

    ``curve_goals`` None means the plan's goal when ``method`` is optimal, no goal
    otherwise. The MILPs share ``time_limit_s``, counted from the start of this stage: the
    plan's goal first, each goal getting an equal share of what is left. ``progress`` is
    called once the heuristic plans are made (with :data:`HEURISTICS_SHARE` for a greedy
    method, whose lower bound is the rest of the stage) and with the share of the time
    limit used (0..1) about twice a second while HiGHS works; it may raise to cancel the
    plan.

    ``connectivity`` (``min_overlap_m2``, no fixed stations): ``optimal`` starts from its
    connected greedy plans and keeps every plan connected on its overlap graph
    (:mod:`planner.selection.connectivity`); the report then says how (``connectivity``) and
    its heuristics are the connected ones.
    """
    start = time.monotonic()
    deadline = start + time_limit_s
    with ThreadPoolExecutor(max_workers=2) as pool:
        weighted = pool.submit(greedy, table, weighted=True, fixed=fixed)
        selections = {"greedy": greedy(table, fixed=fixed),
                      "weighted_greedy": weighted.result()}
    seconds = {"heuristics": time.monotonic() - start}
    if progress is not None:
        progress(HEURISTICS_SHARE if method != "optimal" else
                 min(1.0, seconds["heuristics"] / time_limit_s) if time_limit_s > 0 else 1.0)
    goals = sorted(set(curve_goals if curve_goals is not None
                       else ((goal,) if method == "optimal" else ())))
    todo = ([goal] if method == "optimal" else []) + [g for g in goals if g != goal or
                                                        method != "optimal"]
    heuristics = selections if connectivity is None else {
        "greedy": connectivity.greedy, "weighted_greedy": connectivity.weighted_greedy}
    solved: dict[float, OptimalResult] = {}
    for i, g in enumerate(todo):
        share = (deadline - time.monotonic()) / (len(todo) - i)
        solved[g] = solve_optimal(
            table, g, max(share, 0.0), [heuristics["greedy"], heuristics["weighted_greedy"]],
            centroids_of, fixed=fixed, deadline=deadline, constraint_hooks=constraint_hooks,
            tick=None if progress is None else lambda: progress(
                min(1.0, (time.monotonic() - start) / time_limit_s)),
            graph=None if connectivity is None else connectivity.graph)
        for step, s in solved[g].seconds.items():
            seconds[step] = seconds.get(step, 0.0) + s
    optimal = solved.get(goal) if method == "optimal" else None
    chosen = optimal.selection if optimal is not None else selections[method].truncated(goal)
    t_report = time.monotonic()
    report = _selection_report(table, heuristics, chosen, goal, optimal, fixed)
    if optimal is None:  # the heuristic plan's lower bound
        seconds["lower_bound"] = time.monotonic() - t_report
    if connectivity is not None and optimal is not None:
        report["connectivity"] = connectivity.report()
    return SelectionOutcome(selections=selections, chosen=chosen, optimal=optimal,
                            curve=tuple(solved[g] for g in goals), report=report,
                            seconds=seconds)


def _selection_report(table: CoverageTable, selections: Mapping[str, Selection],
                      chosen: Selection, goal: float, optimal: OptimalResult | None,
                      fixed: tuple[int, ...]) -> dict[str, Any]:
    """plan.json's ``selection``: why this plan (the heuristics, local search, bound)."""
    counts = {name: s.count_for_goal(goal) for name, s in sorted(selections.items())}
    best = min(("greedy", "weighted_greedy"), key=lambda name: counts[name])
    bound: dict[str, Any] | None = None
    if optimal is not None:
        lower, status = optimal.lower_bound, optimal.status
        search: dict[str, Any] | None = {
            "stations_before": optimal.heuristic_stations,
            "stations_after": optimal.local_search_stations,
            "neighbourhood_programs": optimal.neighbourhoods,
            "moves": [m.to_dict() for m in optimal.local_search],
        }
    else:
        need = goal * table.max_achievable_area_m2 - GOAL_SLACK_M2
        fixed_faces = table.covered_by(fixed)
        need_rest = need - float(table.face_area_m2[fixed_faces].sum())
        area_bound = len(fixed) + _counting_bound(table, need_rest,
                                                  table.achievable & ~fixed_faces)
        bound = {"area_bound": area_bound, "lagrangian": None}
        status = ("heuristic plan; the lower bound is the area bound (fewest candidates "
                  "whose areas add up to the goal)")
        lower = min(len(chosen.stations), area_bound)
        if area_bound < len(chosen.stations):  # else the plan meets it already
            dual = station_lower_bound(table, need, len(chosen.stations), fixed)
            bound["lagrangian"] = dual.to_dict()
            if dual.stations > area_bound:
                lower = min(len(chosen.stations), dual.stations)
                status = "heuristic plan; the lower bound is the " + dual.method
        search = None
    n = len(chosen.stations)
    return {
        "method": chosen.method,
        "heuristics": counts,
        "best_heuristic": best,
        "fixed_stations": len(fixed),
        "local_search": search,
        "stations": n,
        "lower_bound": int(lower),
        "gap": round(float((n - lower) / n) if n else 0.0, 6),
        "proven_optimal": lower == n,
        "status": status,
        **({} if bound is None else {"bound": bound}),
        # a MILP stopped by the wall-clock limit: how far HiGHS got depends on the machine
        # and its load, so its stations (and every file drawn from them) may differ between
        # runs; the heuristics, the local search and the bounds never do
        **({} if optimal is None else
           {"stopped_at_time_limit": "time limit" in status.lower()}),
    }
