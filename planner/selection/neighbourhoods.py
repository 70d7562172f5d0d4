"""Large neighbourhood search: a few stations at a time replaced by HiGHS's best answer.

A whole building is too large a program for HiGHS (the 9.7 M-face office's face classes
give tens of millions of nonzeros), but a part of a plan is small. A *neighbourhood* is one
station and the stations looking at the same part of the building (the area centroids of
what they cover nearest its). With every other station kept,
HiGHS chooses from a *pool* (the neighbourhood's stations and the candidates covering the
most of what only the neighbourhood covers, or of what no station covers yet) the fewest
stations that keep the goal, and among those the ones covering the most area. An answer
with fewer stations, or as many covering more, replaces the neighbourhood. Every station of
the plan is a seed once a pass; passes repeat while they improve the plan.

Every step follows from the plan and the table alone: the neighbourhoods, the pools, the
programs, and HiGHS's work, limited by its branch-and-bound nodes (:data:`NODE_LIMIT`), not
by seconds. The same table and plan give the same moves on any machine, unless the wall
deadline (a safety) stops the search first, which the result says.

Sources: P. Shaw, "Using constraint programming and local search methods to solve vehicle
routing problems", CP 1998, LNCS 1520, 417-431 (large neighbourhood search); D. Pisinger,
S. Ropke, "Large neighborhood search", Handbook of Metaheuristics (2010) 399-419.

Array letters: C candidates, K face classes, P candidates of a pool, J classes of a pool.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from planner.selection.highs_worker import Answer, Program
from planner.selection.lower_bound import pattern_product
from planner.selection.program import ProgramBuilder
from planner.visibility.coverage import CoverageTable

# stations in a neighbourhood, candidates in its pool (its stations included), passes over
# the plan at most, branch-and-bound nodes HiGHS may spend on one neighbourhood
NEIGHBOURHOOD_STATIONS = 8
POOL_CANDIDATES = 20
PASSES = 3
NODE_LIMIT = 500
# an answer with as many stations must cover this much more area (m^2; stops cycling)
MIN_GAIN_M2 = 1e-6

# a program -> HiGHS's answer, or None when the deadline came first
Solve = Callable[[Program], "Answer | None"]
# stations (candidate indices) -> whether a plan satisfies a side constraint
Keep = Callable[[Sequence[int]], bool]


@dataclass
class SearchResult:
    """The plan after the search (its first ``n_fixed`` stations unchanged), each accepted
    replacement as (removed, added) candidates, the programs solved and whether the
    deadline stopped the search before its passes ended."""

    stations: list[int]
    moves: list[tuple[tuple[int, ...], tuple[int, ...]]] = field(default_factory=list)
    programs: int = 0
    stopped: bool = False


def neighbourhood_search(table: CoverageTable, class_xyz: NDArray[np.float64],
                         stations: Sequence[int], need_m2: float, n_fixed: int, solve: Solve,
                         *, full: bool, keep: Keep | None = None, floor: int = 0
                         ) -> SearchResult:
    """Improve a plan reaching ``need_m2`` of ``table`` (face classes, see the module doc).

    ``class_xyz`` (K, 3) places each class (a face of it): neighbourhoods are the stations
    that look at the same part of the building.
    ``full``: the goal is every class (each lost class must be covered again, set-cover
    rows); otherwise an area. ``keep``: a side constraint every accepted plan passes
    (registration connectivity). ``solve`` runs HiGHS with the deadline. The search ends
    early when the plan has ``floor`` stations (a lower bound: it cannot get better).
    """
    search = _Search(table, list(stations), n_fixed, need_m2, full, keep, class_xyz)
    result = SearchResult(stations=search.stations)  # the search's list, changed in place
    for _ in range(PASSES):
        improved = False
        for seed in list(search.stations[n_fixed:]):
            if len(search.stations) <= floor:
                break
            if seed not in search.stations:
                continue  # replaced earlier in this pass
            program, pool, before = search.program(seed)
            if program is None:
                continue
            answer = solve(program)
            result.programs += 1
            if answer is None:
                result.stopped = True
                return result
            if answer.x is None:
                continue
            chosen = pool[answer.x[:len(pool)] > 0.5]
            move = search.replace(before, [int(c) for c in chosen])
            if move is not None:
                result.moves.append(move)
                improved = True
        if not improved:
            break
    return result


class _Search:
    """The plan, how many of its stations cover each class, and its neighbourhoods."""

    def __init__(self, table: CoverageTable, stations: list[int], n_fixed: int,
                 need_m2: float, full: bool, keep: Keep | None,
                 class_xyz: NDArray[np.float64]) -> None:
        # (C, K) bool: its products read the pattern alone (pattern_product: the sums of a
        # float matrix of ones, without scipy's float64 copy of the data, 168 MB a product
        # on the 9.7 M-face office's 21 M class pairs)
        self.pattern = table.pattern(np.bool_)
        self.area = table.face_area_m2
        # (C, 3) the area centroid of what each candidate covers: where it looks
        seen = pattern_product(self.pattern, self.area)
        self.view_xyz = np.stack(
            [pattern_product(self.pattern, self.area * class_xyz[:, axis])
             for axis in range(3)], axis=1) / np.maximum(seen, 1e-12)[:, None]
        self.stations = stations
        self.n_fixed = n_fixed
        self.need_m2 = need_m2
        self.full = full
        self.keep = keep
        self.count = self._counts(stations)
        self.covered_m2 = float(self.area[self.count > 0].sum())

    def _counts(self, stations: Sequence[int]) -> NDArray[np.int32]:
        """(K,) how many of ``stations`` cover each class."""
        rows = self.pattern[np.asarray(stations, np.int64)]
        return np.bincount(rows.indices, minlength=self.pattern.shape[1]).astype(np.int32)

    def neighbourhood(self, seed: int) -> list[int]:
        """``seed`` and the free stations whose views are nearest its view (the area
        centroids of what they cover; lowest index on ties), NEIGHBOURHOOD_STATIONS in
        all at most."""
        others = np.asarray([s for s in self.stations[self.n_fixed:] if s != seed], np.int64)
        distance = np.square(self.view_xyz[others] - self.view_xyz[seed]).sum(axis=1)
        order = np.lexsort((others, distance))
        return [seed, *(int(others[i]) for i in order[:NEIGHBOURHOOD_STATIONS - 1])]

    def program(self, seed: int) -> tuple[Program | None, NDArray[np.int64], list[int]]:
        """The program of ``seed``'s neighbourhood, its pool (P,) and the neighbourhood."""
        before = self.neighbourhood(seed)
        inside = self._counts(before)
        only = (inside > 0) & (inside == self.count)  # (K,) covered by the neighbourhood alone
        open_ = only | (self.count == 0) if not self.full else only
        need = self.need_m2 - (self.covered_m2 - float(self.area[only].sum()))
        score = pattern_product(self.pattern, np.where(open_, self.area, 0.0))
        score[before] = np.inf  # the neighbourhood is always in its pool
        ranked = np.lexsort((np.arange(len(score)), -score))
        pool = np.sort(ranked[:POOL_CANDIDATES][score[ranked[:POOL_CANDIDATES]] > 0])
        sub = self.pattern[pool][:, np.flatnonzero(open_)].tocsc()  # (P, J)
        reach = np.diff(sub.indptr) > 0
        sub, area, lost = sub[:, reach], self.area[open_][reach], only[open_][reach]
        if sub.shape[1] == 0:
            return None, pool, before
        # classes the pool sees alike merge (their areas summed)
        dense = np.packbits(sub.T.toarray() > 0, axis=1)  # (J, ceil(P / 8))
        keys, merged = np.unique(dense, axis=0, return_inverse=True)
        merged = merged.reshape(-1)
        cover = sp.csr_matrix(np.unpackbits(keys, axis=1, count=len(pool)).T.astype(np.float64))
        class_area = np.bincount(merged, weights=area, minlength=len(keys)).astype(np.float64)
        builder = ProgramBuilder(len(pool))
        builder.set_cost(0, np.ones(len(pool)))
        start = np.isin(pool, before).astype(np.float64)
        if self.full:
            must = np.bincount(merged, weights=lost, minlength=len(keys)) > 0
            builder.add_rows(cover[:, must].T, 1.0, np.inf)
            builder.start = start
        else:
            # a little for each m^2 of y prefers, among the fewest stations, the most area
            # (all of it together is worth half a station)
            prefer = 0.5 / max(float(class_area.sum()), 1e-12)
            builder.add_partial_cover(cover, class_area, need,
                                      y_cost=np.asarray(-prefer * class_area, np.float64),
                                      x_start=start)
        return dataclasses.replace(builder.build(), node_limit=NODE_LIMIT), pool, before

    def replace(self, before: list[int], after: list[int]
                ) -> tuple[tuple[int, ...], tuple[int, ...]] | None:
        """Put ``after`` in the place of ``before`` if that is better and keeps the goal."""
        removed = tuple(sorted(set(before) - set(after)))
        added = tuple(sorted(set(after) - set(before)))
        if not removed and not added:
            return None
        count = self.count - self._counts(removed) + self._counts(added)
        covered = float(self.area[count > 0].sum())
        if covered < self.need_m2:
            return None
        if len(added) >= len(removed) and (
                len(added) > len(removed) or covered <= self.covered_m2 + MIN_GAIN_M2):
            return None
        plan = [s for s in self.stations if s not in removed] + list(added)
        if self.keep is not None and not self.keep(plan):
            return None
        self.stations[:] = plan
        self.count = count
        self.covered_m2 = covered
        return removed, added
