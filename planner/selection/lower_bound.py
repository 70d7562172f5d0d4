"""A proven lower bound on the number of stations: the Lagrangian dual of the cover LP.

The stations that reach a goal solve a (partial) set cover with areas. With ``x_c`` a
candidate's station and ``y_k`` how much of face class ``k`` (area ``a_k``) counts as
covered::

    min sum_c x_c  s.t.  sum_k a_k y_k >= need,  y_k <= sum_{c covers k} x_c,
                         0 <= y_k <= 1,  0 <= x_c <= 1.

Relaxing ``y_k <= sum x_c`` with multipliers ``u_k >= 0`` (Lagrangian relaxation) gives,
for *every* ``u >= 0``, a lower bound on every plan::

    L(u) = sum_c min(0, 1 - sum_{k in c} u_k) + min{u . y : a . y >= need, 0 <= y <= 1}

The second term is a fractional knapsack: classes by ``u_k / a_k`` ascending until their
area reaches ``need``. For a full cover (every class must be covered) it is ``sum_k u_k``,
and ``max_u L(u)`` is the set cover LP (its dual: ``sum_k u_k`` with column sums at most
1). ``L`` is concave and piecewise linear; its maximum (the LP optimum with ``x <= 1``) is
approached by the subgradient method of Held & Karp as tuned for set covering by Caprara,
Fischetti & Toth (CFT): Polyak steps ``u <- max(0, u + step (UB - L(u)) / |g|^2 g)``
towards a known plan's size ``UB``, with ``g_k = y_k - sum_{c: reduced cost < 0} [c
covers k]`` (components at ``u_k = 0`` pointing down set to 0) and the step factor halved
or raised by 1.5 every :data:`STEP_PERIOD` iterations as ``L`` moves more than 1 % or
less than 0.1 %. The iteration count is fixed, so the same input gives the same bound.

Lossless reductions come first:

- faces seen by exactly the same candidates merge into one class (areas summed);
- a class larger than the area a plan may leave uncovered must be covered: a candidate
  alone in covering one is in every plan (counted, its classes dropped);
- for a full cover the bound is the sum over the connected components of candidates and
  classes of each component's bound, each rounded up (the Lagrangian separates exactly).
  A partial cover trades area between components, so it keeps one bound.

The bound is ``ceil(L - 1e-9 |L|)`` (float64 sums; the relative 1e-9 absorbs their
rounding), never below the area bound of :func:`planner.selection.optimal._counting_bound`
(the caller takes the larger).

Sources:

- M. Held, R. M. Karp, "The traveling-salesman problem and minimum spanning trees: part
  II", Mathematical Programming 1 (1971) 6-25 (subgradient optimisation of Lagrangians).
- A. Caprara, M. Fischetti, P. Toth, "A heuristic method for the set covering problem",
  Operations Research 47(5) (1999) 730-743 (the multipliers' start, step and its control).
- J. E. Beasley, "A Lagrangian heuristic for set-covering problems", Naval Research
  Logistics 37 (1990) 151-164 (the Lagrangian lower bound of set covering).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components

from planner.visibility.coverage import CoverageTable

# subgradient iterations (fixed: no clock, the same bound for the same table)
ITERATIONS = 250
# the step factor is adapted every this many iterations (CFT)
STEP_PERIOD = 20
# the first step factor (Held & Karp: 2)
START_STEP = 2.0
# relative tolerance taken off a bound before it is rounded up (float64 sums)
ROUND_TOLERANCE = 1e-9
METHOD = "lagrangian dual of the set-cover LP (subgradient, Caprara-Fischetti-Toth steps)"


@dataclass(frozen=True)
class StationBound:
    """No plan reaches the goal with fewer than ``stations`` stations (fixed ones included).

    ``lp_value`` is the best Lagrangian value (fixed and forced stations included), a lower
    bound on the cover LP's optimum and so on every plan; ``forced`` counts the candidates
    alone in covering a class that must be covered; ``components`` is how many independent
    parts a full cover split into (1 for a partial cover).
    """

    stations: int
    lp_value: float
    iterations: int
    forced: int
    classes: int
    components: int
    method: str = METHOD

    def to_dict(self) -> dict[str, Any]:
        return {"bound": self.method, "stations": self.stations,
                "lp_value": round(self.lp_value, 6), "iterations": self.iterations,
                "forced_stations": self.forced, "face_classes": self.classes,
                "components": self.components}


def _round_up(value: float) -> int:
    """The smallest whole number of stations at least ``value``, float error forgiven."""
    return max(0, math.ceil(value - ROUND_TOLERANCE * max(1.0, abs(value))))


def merged_classes(table: CoverageTable, faces: NDArray[np.bool_]
                   ) -> tuple[sp.csc_matrix, NDArray[np.float64]]:
    """Faces with identical candidate sets merged into classes, without a loop per face.

    Each face's candidate set is hashed twice (sums of random 64-bit words, wrapping), faces
    are grouped by (count, hashes), and every face is checked entry by entry against its
    group's first face: a face that differs (a hash collision) keeps a class of its own, so
    the merge is exact. ``faces`` (F,) bool: the faces to merge (those of no candidate are
    left out).

    Returns
    -------
    cover : (C, K) CSC float64 0/1, which candidate covers which class
    area_m2 : (K,) float64, the area of each class
    """
    chosen = np.flatnonzero(faces & table.achievable)
    sub = table.by_face[:, chosen]  # (C, F') CSC
    indptr, indices = sub.indptr.astype(np.int64), sub.indices
    count = np.diff(indptr)
    n = len(chosen)
    if n == 0:
        return sp.csc_matrix((table.n_candidates, 0)), np.zeros(0)
    rng = np.random.default_rng(20240601)
    words = rng.integers(0, np.iinfo(np.uint64).max, size=(2, table.n_candidates),
                         dtype=np.uint64, endpoint=True)
    starts = indptr[:-1]
    first_hash = np.add.reduceat(words[0][indices], starts)  # every face has a candidate
    second_hash = np.add.reduceat(words[1][indices], starts)
    order = np.lexsort((np.arange(n), second_hash, first_hash, count))  # (F',)
    new = np.ones(n, bool)
    new[1:] = ((count[order][1:] != count[order][:-1])
               | (first_hash[order][1:] != first_hash[order][:-1])
               | (second_hash[order][1:] != second_hash[order][:-1]))
    group = np.cumsum(new) - 1  # group of order[i]
    leader = order[new][group]  # (F',) the first face of the group of order[i]
    representative = np.empty(n, np.int64)
    representative[order] = leader
    # check entry by entry (the same count within a group, so positions line up)
    face_of_entry = np.repeat(np.arange(n), count)
    position = np.arange(len(indices)) - indptr[face_of_entry]
    same = indices == indices[indptr[representative[face_of_entry]] + position]
    collided = np.unique(face_of_entry[~same])
    representative[collided] = collided
    leaders, class_of = np.unique(representative, return_inverse=True)
    area = np.bincount(class_of.reshape(-1), weights=table.face_area_m2[chosen], minlength=len(leaders))
    cover = sp.csc_matrix((np.ones(int(indptr[leaders + 1].sum() - indptr[leaders].sum())),
                           *_columns(indptr, indices, leaders)),
                          shape=(table.n_candidates, len(leaders)))
    return cover, area


def _columns(indptr: NDArray[np.int64], indices: NDArray[np.int32],
             columns: NDArray[np.int64]) -> tuple[NDArray[np.int32], NDArray[np.int64]]:
    """The (indices, indptr) of the CSC columns ``columns`` of a matrix, in that order."""
    count = indptr[columns + 1] - indptr[columns]
    new_ptr = np.zeros(len(columns) + 1, np.int64)
    np.cumsum(count, out=new_ptr[1:])
    take = np.repeat(indptr[columns] - new_ptr[:-1], count) + np.arange(int(new_ptr[-1]))
    return indices[take], new_ptr


def station_lower_bound(table: CoverageTable, need_m2: float, upper_stations: int,
                        fixed: tuple[int, ...] = (), iterations: int = ITERATIONS
                        ) -> StationBound:
    """The fewest stations any plan needs to cover ``need_m2`` (fixed stations included).

    ``need_m2``: the area to cover, fixed stations' faces included (goal * max achievable
    - slack); ``upper_stations``: the stations of a known plan (the subgradient steps aim
    at it; the bound stops early once it meets it). ``fixed`` stations are in every plan:
    their faces count as covered.
    """
    n_fixed = len(fixed)
    covered = np.zeros(table.n_faces, bool)
    for s in fixed:
        covered[table.faces_of(s)] = True
    rest = table.achievable & ~covered
    need = need_m2 - float(table.face_area_m2[covered].sum())
    if need <= 0:
        return StationBound(n_fixed, float(n_fixed), 0, 0, 0, 0)
    cover, area = merged_classes(table, rest)
    classes = cover.shape[1]
    keep = area > 0
    cover, area = cover[:, keep], area[keep]
    # classes a plan may not leave out: larger than all it may leave uncovered
    allowance = float(area.sum()) - need
    must = area > allowance
    size = np.diff(cover.indptr)
    alone = must & (size == 1)
    forced = np.unique(cover.indices[cover.indptr[:-1][alone]])
    if len(forced):
        hit = np.zeros(table.n_candidates, bool)
        hit[forced] = True
        taken = np.asarray((cover.T @ hit.astype(np.float64)) > 0).reshape(-1)
        need -= float(area[taken].sum())
        cover, area, must = cover[:, ~taken], area[~taken], must[~taken]
    base = n_fixed + len(forced)
    if need <= 0 or cover.shape[1] == 0:
        return StationBound(base, float(base), 0, len(forced), classes, 0)
    full = float(area[~must].sum()) <= allowance  # covering the must classes is enough
    if full:
        cover, area = cover[:, must], area[must]
    solver = _Subgradient(cover, area, need, full)
    target = max(1.0, float(upper_stations - base))
    done = solver.run(target, iterations)
    value = solver.best_value()
    stations = base + solver.best_stations()
    return StationBound(stations=stations, lp_value=base + value, iterations=done,
                        forced=len(forced), classes=classes,
                        components=solver.n_components)


class _Subgradient:
    """The Lagrangian of one cover problem and its best multipliers so far.

    ``cover`` (C, K) 0/1 over classes of area ``area`` (K,); ``full``: every class must be
    covered (the knapsack term is ``sum u``, and components bound separately).
    """

    def __init__(self, cover: sp.csc_matrix, area: NDArray[np.float64], need: float,
                 full: bool) -> None:
        self.rows = cover.tocsr()  # (C, K)
        self.rows.data = np.ones(self.rows.nnz)
        self.area = area
        self.need = need
        self.full = full
        n_cand, n_class = self.rows.shape
        if full:
            graph = sp.bmat([[None, self.rows], [self.rows.T, None]], format="csr")
            self.n_components, label = connected_components(graph, directed=False)
            self.cand_comp, self.class_comp = label[:n_cand], label[n_cand:]
        else:
            self.n_components = 1
            self.cand_comp = np.zeros(n_cand, np.int64)
            self.class_comp = np.zeros(n_class, np.int64)
        # start (CFT): each class at its cheapest candidate's price per area
        cand_area = self.rows @ area  # (C,)
        per_area = np.zeros(n_cand)
        np.divide(1.0, cand_area, out=per_area, where=cand_area > 0)
        csc = cover.tocsc()
        cheapest = np.minimum.reduceat(per_area[csc.indices], csc.indptr[:-1])
        self.u = area * cheapest  # (K,)
        self.best = np.full(self.n_components, -np.inf)
        self.best_u = self.u.copy()

    def evaluate(self, u: NDArray[np.float64]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
        """Per component L(u), the knapsack's y (K,) and the candidates of negative cost."""
        reduced = 1.0 - self.rows @ u  # (C,)
        negative = reduced < 0
        per_comp = np.bincount(self.cand_comp, weights=np.minimum(reduced, 0.0),
                               minlength=self.n_components)
        if self.full:
            y = np.ones(len(u))
            per_comp += np.bincount(self.class_comp, weights=u, minlength=self.n_components)
        else:
            y = self._knapsack(u)
            per_comp[0] += float(u @ y)
        return per_comp, y, negative

    def _knapsack(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """(K,) y in [0, 1] of least u . y with area . y >= need (cheapest per area first)."""
        order = np.lexsort((np.arange(len(u)), u / self.area))
        reach = np.cumsum(self.area[order])
        last = min(int(np.searchsorted(reach, self.need)), len(order) - 1)
        y = np.zeros(len(u))
        y[order[:last]] = 1.0
        before = float(reach[last - 1]) if last > 0 else 0.0
        y[order[last]] = min(1.0, max(0.0, (self.need - before) / self.area[order[last]]))
        return y

    def run(self, target: float, iterations: int) -> int:
        """Subgradient steps towards ``target`` (a plan's stations); returns those made."""
        step = START_STEP
        recent: list[float] = []
        u = self.u
        for it in range(iterations):
            per_comp, y, negative = self.evaluate(u)
            value = float(per_comp.sum())
            better = per_comp > self.best
            if better.any():
                self.best = np.maximum(self.best, per_comp)
                moved = better[self.class_comp]
                self.best_u[moved] = u[moved]
            if self.best_stations() >= target:
                return it + 1
            chosen = np.flatnonzero(negative)
            covered = np.bincount(self.rows[chosen].indices, minlength=len(u)).astype(np.float64)
            g = y - covered
            g[(u <= 0) & (g < 0)] = 0.0
            norm = float(g @ g)
            if norm == 0:
                return it + 1  # u is optimal
            gap = max(target - value, 1e-3 * max(1.0, abs(value)))
            u = np.maximum(0.0, u + step * gap / norm * g)
            recent.append(value)
            if len(recent) == STEP_PERIOD:
                high, low = max(recent), min(recent)
                spread = (high - low) / max(abs(high), 1e-12)
                if spread > 0.01:
                    step /= 2
                elif spread < 0.001:
                    step *= 1.5
                recent = []
        return iterations

    def best_value(self) -> float:
        return float(self.best.sum())

    def best_stations(self) -> int:
        """The bound: each component's best rounded up (one component for partial)."""
        tolerance = ROUND_TOLERANCE * np.maximum(1.0, np.abs(self.best))
        return int(np.maximum(0.0, np.ceil(self.best - tolerance)).sum())
