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
area reaches ``need``. ``max_u L(u)`` is the LP above, and any ``u`` found by any method
is a valid bound once ``L(u)`` is summed in float64: the search for ``u`` needs no
accuracy, only the last evaluation. (Scaling ``u`` to column sums at most 1 and choosing
the knapsack's multiplier gives the textbook dual ``need lam - sum_k max(0, a_k lam -
u_k)``; ``L`` is never below it.) Two searches, each with a fixed iteration count (no
clock: the same table gives the same bound):

- full cover (every class must be covered, the knapsack term is ``sum_k u_k``: the
  set-cover LP dual): PDHG, the primal-dual hybrid gradient of Chambolle & Pock, as PDLP
  runs it (restarts from the average), on a growing subset of the classes: first those
  seen by the fewest candidates, then those its primal ``x`` leaves uncovered. Classes
  left out have ``u_k = 0``, which keeps every value a bound; most are seen by a superset
  of another class's candidates and never matter. Hall-full at 100 %: the LP's 62.5 (a
  bound of 63, the proven optimum) from about 2 % of the classes.
- partial cover: the volume algorithm of Barahona & Anbil (a subgradient method on the
  averaged primal; one product with the table per iteration), from Caprara, Fischetti &
  Toth's start ``u_k = a_k min_{c covers k} 1 / area_c``, steps aimed at a known plan.

Lossless reductions come first:

- faces seen by exactly the same candidates merge into one class (areas summed);
- a class larger than all a plan may leave uncovered is covered by every plan: ``y_k = 1``
  in the knapsack, and a candidate alone in covering one is in every plan (counted, its
  classes dropped);
- for a full cover the bound is the sum over the connected components of candidates and
  classes of each component's bound, each rounded up (the Lagrangian separates exactly).
  A partial cover trades area between components, so it keeps one bound.

The bound is ``ceil(L - 1e-9 max(1, |L|))`` (the relative 1e-9 absorbs float64 rounding);
the caller takes the larger of it and the area bound
(:func:`planner.selection.optimal._counting_bound`).

Sources:

- M. Held, R. M. Karp, "The traveling-salesman problem and minimum spanning trees: part
  II", Mathematical Programming 1 (1971) 6-25 (Lagrangian bounds by subgradients).
- J. E. Beasley, "A Lagrangian heuristic for set-covering problems", Naval Research
  Logistics 37 (1990) 151-164 (the Lagrangian bound of set covering).
- A. Caprara, M. Fischetti, P. Toth, "A heuristic method for the set covering problem",
  Operations Research 47(5) (1999) 730-743 (the starting multipliers; columns/rows by
  pricing).
- F. Barahona, R. Anbil, "The volume algorithm: producing primal solutions with a
  subgradient method", Mathematical Programming 87 (2000) 385-399.
- A. Chambolle, T. Pock, "A first-order primal-dual algorithm for convex problems with
  applications to imaging", J. Mathematical Imaging and Vision 40 (2011) 120-145.
- D. Applegate et al., "Practical large-scale linear programming using primal-dual hybrid
  gradient", NeurIPS 2021 (PDLP: restarts to the average).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components

from planner.selection.classes import merged_classes
from planner.selection.sums import numpy_sum
from planner.threads import in_block_order
from planner.visibility.coverage import CoverageTable

# iterations (fixed: no clock, the same bound for the same table): of the volume algorithm
# (partial cover: at most ITERATIONS, fewer on large tables so that iterations times the
# work of one, the runs of classes and the classes it reads (ClassRuns.work), stay within
# PARTIAL_WORK, at least MIN_ITERATIONS) and of PDHG per round of rows (full cover)
ITERATIONS = 250
# hall-full (0.8 M runs over 54,000 classes): 207 iterations in 0.6 s on a 2-core machine;
# the 9.7 M-piece office (about 4.5 M runs over 808,000 classes): 113 iterations in 6 s
PARTIAL_WORK = 600_000_000
MIN_ITERATIONS = 20
PDHG_ITERATIONS = 1000
# PDHG restarts from the average this often; power iterations for the step
RESTART_PERIOD = 200
NORM_ITERATIONS = 30
# full cover: classes added per round, rounds at most, and how far below 1 the primal
# estimate may cover a class before it is added
ROWS_PER_ROUND = 1000
ROUNDS = 8
PRIMAL_SLACK = 0.05
# volume algorithm: the first and largest step factor, the weight of the newest minimiser
# in the primal average, and steps without improvement before the factor is cut
START_STEP = 0.1
MAX_STEP = 2.0
AVERAGE = 0.02
RED_STEPS = 5
# tables whose face classes have more (candidate, class) pairs get no Lagrangian bound
# (only the fixed stations): its matrix takes 5 bytes a pair, 9 in a full cover's PDHG
# (the 9.7 M-face office: 808,000 classes, within it)
MAX_PAIRS = 60_000_000
# a goal whose must-cover classes (see station_lower_bound) leave out at most this share of
# the area is bound as a full cover of them (faces of 1e-10 m^2 at 100 % are not a
# partial cover)
SLIVER_SHARE = 1e-6
# relative tolerance taken off a bound before it is rounded up (float64 sums)
ROUND_TOLERANCE = 1e-9
FULL_METHOD = "lagrangian dual of the set-cover LP (PDHG on generated rows)"
PARTIAL_METHOD = "lagrangian dual of the partial-cover LP (volume algorithm)"
REDUCTIONS = "fixed stations and the candidates alone in covering a class"
COVERAGE_METHOD = ("lagrangian dual of the maximum-coverage LP (volume algorithm "
                   "multipliers, scaled)")
# the maximum-coverage bound's work (see coverage_upper_bound): 2.5 times a plan's bound's
COVERAGE_WORK = 1_500_000_000
TOO_LARGE = f"fixed stations only (the face classes have more than {MAX_PAIRS} pairs)"


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
    method: str = PARTIAL_METHOD

    def to_dict(self) -> dict[str, Any]:
        return {"bound": self.method, "stations": self.stations,
                "lp_value": round(self.lp_value, 6), "iterations": self.iterations,
                "forced_stations": self.forced, "face_classes": self.classes,
                "components": self.components}


@numba.njit(nogil=True, cache=True)
def _class_minimum(indptr: NDArray[np.int32], indices: NDArray[np.int32],
                   price: NDArray[np.float64], cheapest: NDArray[np.float64]
                   ) -> None:  # compiled
    """``cheapest[k]``: the least ``price`` of the candidates (CSR rows) covering class k."""
    for c in range(len(indptr) - 1):
        for j in range(indptr[c], indptr[c + 1]):
            k = indices[j]
            if price[c] < cheapest[k]:
                cheapest[k] = price[c]


# a product with fewer pairs than this runs in the calling thread (a thread pool's start
# costs more than the sum)
THREADED_PAIRS = 1 << 20


def pattern_product(rows: sp.csr_matrix, values: NDArray[Any]) -> NDArray[Any]:
    """(C,) ``rows @ values`` for the 0/1 matrix ``rows`` (C, K) and ``values`` (K,), float32
    or float64: each row's sum in the values' precision, in index order, so the same bits
    as scipy's product of a matrix of ones of that dtype. The rows are summed in ranges of
    about equal pairs on a few threads; the pattern alone is read (4 bytes a pair instead
    of scipy's 8 or 12): hall-full's 10.5 M class pairs in some 5.5 instead of 9.4 ms."""
    n = rows.shape[0]
    sums = np.zeros(n, values.dtype)
    indptr, indices = rows.indptr, rows.indices
    parts = 1 if rows.nnz < THREADED_PAIRS else (os.cpu_count() or 1)
    cuts = np.searchsorted(indptr, np.linspace(0, rows.nnz, parts + 1)[1:-1]).tolist()
    bounds = list(zip([0, *cuts], [*cuts, n], strict=True))

    def add(part: tuple[int, int]) -> None:
        _row_sums(indptr, indices, values, sums, part[0], part[1])

    list(in_block_order(add, bounds))
    return sums


@dataclass(frozen=True)
class ClassRuns:
    """The rows of a 0/1 matrix (C, K) as runs of consecutive columns (ascending, in the
    order a row holds them), for products with many vectors: a row's sum over a run is the
    difference of two prefix sums, so a product reads each run once instead of each pair.

    Classes are numbered in the order of their first face, and a candidate sees the pieces
    of a surface together, so its classes mostly come in runs: hall-full's 10.5 M class
    pairs are 0.8 M runs. The sums differ from the pairs' sums in the last bits (float64
    prefix sums instead of sums in row order): a search may use them, a bound is summed
    again pair by pair (:func:`pattern_product`).

    ``run_ptr`` (C + 1,) int64: row c's runs are ``run_ptr[c]`` to ``run_ptr[c + 1] - 1``;
    ``first`` and ``end`` (R,) int32: each run's first column and one past its last;
    ``n_columns``: K.
    """

    run_ptr: NDArray[np.int64]
    first: NDArray[np.int32]
    end: NDArray[np.int32]
    n_columns: int

    @classmethod
    def of(cls, rows: sp.csr_matrix) -> ClassRuns:
        """The runs of ``rows`` (C, K) CSR (a row's columns in any order: a run ends where
        the next column is not one more)."""
        counts = np.zeros(rows.shape[0], np.int64)
        _count_runs(rows.indptr, rows.indices, counts)
        run_ptr = np.zeros(rows.shape[0] + 1, np.int64)
        np.cumsum(counts, out=run_ptr[1:])
        first = np.empty(int(run_ptr[-1]), np.int32)
        end = np.empty(int(run_ptr[-1]), np.int32)
        _fill_runs(rows.indptr, rows.indices, run_ptr, first, end)
        return cls(run_ptr, first, end, rows.shape[1])

    def work(self) -> int:
        """What one product reads: the runs, and the K prefix sums."""
        return len(self.first) + self.n_columns

    def counts(self, chosen: NDArray[np.bool_]) -> NDArray[np.float64]:
        """(K,) how many of the ``chosen`` (C,) rows hold each column (whole numbers,
        exact), from a difference array over the runs."""
        return _run_counts(self.run_ptr, self.first, self.end, chosen, self.n_columns)

    def sums(self, values: NDArray[np.float64]) -> NDArray[np.float64]:
        """(C,) each row's sum of ``values`` (K,) float64."""
        return _runs_sums(self.run_ptr, self.first, self.end, values)

    def pair_sums(self, values: NDArray[np.float64]) -> NDArray[np.float64]:
        """(C,) each row's sum of ``values`` (K,) float64 class by class, in the row's
        order: the bits of :func:`pattern_product` of the matrix the runs were made of,
        which is not needed for it."""
        sums = np.zeros(len(self.run_ptr) - 1)
        _run_pair_sums(self.run_ptr, self.first, self.end, values, sums)
        return sums


@numba.njit(nogil=True, cache=True)
def _rows_holding(indptr: NDArray[np.int32], indices: NDArray[np.int32],
                  flagged: NDArray[np.bool_]) -> NDArray[np.int64]:  # compiled
    """The rows (ascending) of the 0/1 CSR matrix that hold a ``flagged`` (K,) column, in
    one pass (a (pairs,) gather of the flags took 10 MB and 50 ms on hall-full)."""
    rows = np.empty(len(indptr) - 1, np.int64)
    n = 0
    for c in range(len(indptr) - 1):
        for j in range(indptr[c], indptr[c + 1]):
            if flagged[indices[j]]:
                rows[n] = c
                n += 1
                break
    return rows[:n].copy()


@numba.njit(nogil=True, cache=True)
def _count_runs(indptr: NDArray[np.int32], indices: NDArray[np.int32],
                counts: NDArray[np.int64]) -> None:  # compiled
    """``counts[c]``: how many runs of consecutive columns row c holds, in its order."""
    for c in range(len(counts)):
        n = 0
        for j in range(indptr[c], indptr[c + 1]):
            if j == indptr[c] or indices[j] != indices[j - 1] + 1:
                n += 1
        counts[c] = n


@numba.njit(nogil=True, cache=True)
def _fill_runs(indptr: NDArray[np.int32], indices: NDArray[np.int32],
               run_ptr: NDArray[np.int64], first: NDArray[np.int32],
               end: NDArray[np.int32]) -> None:  # compiled
    """Each row's runs, in its order, at ``run_ptr[c]`` on."""
    for c in range(len(run_ptr) - 1):
        r = run_ptr[c] - 1
        for j in range(indptr[c], indptr[c + 1]):
            if j == indptr[c] or indices[j] != indices[j - 1] + 1:
                r += 1
                first[r] = indices[j]
            end[r] = indices[j] + 1


@numba.njit(nogil=True, cache=True)
def _run_steps(run_ptr: NDArray[np.int64], first: NDArray[np.int32], end: NDArray[np.int32],
               chosen: NDArray[np.bool_], steps: NDArray[np.float64]) -> None:  # compiled
    """``steps``: +1 where each run of a ``chosen`` row starts, -1 one past its end."""
    for c in range(len(chosen)):
        if chosen[c]:
            for r in range(run_ptr[c], run_ptr[c + 1]):
                steps[first[r]] += 1.0
                steps[end[r]] -= 1.0


@numba.njit(nogil=True, cache=True)
def _run_counts(run_ptr: NDArray[np.int64], first: NDArray[np.int32], end: NDArray[np.int32],
                chosen: NDArray[np.bool_], n_columns: int) -> NDArray[np.float64]:  # compiled
    """(K,) how many of the ``chosen`` (C,) rows hold each of the ``n_columns`` columns:
    the running sum of the difference array of the rows' runs."""
    steps = np.zeros(n_columns + 1)
    _run_steps(run_ptr, first, end, chosen, steps)
    return np.cumsum(steps[:-1])


@numba.njit(nogil=True, cache=True)
def _runs_sums(run_ptr: NDArray[np.int64], first: NDArray[np.int32], end: NDArray[np.int32],
               values: NDArray[np.float64]) -> NDArray[np.float64]:  # compiled
    """(C,) each row's sum of ``values`` (K,) over its runs, from the values' prefix sums."""
    prefix = np.zeros(len(values) + 1)
    prefix[1:] = np.cumsum(values)
    sums = np.empty(len(run_ptr) - 1)
    _run_sums(run_ptr, first, end, prefix, sums)
    return sums


@numba.njit(nogil=True, cache=True)
def _run_pair_sums(run_ptr: NDArray[np.int64], first: NDArray[np.int32],
                   end: NDArray[np.int32], values: NDArray[np.float64],
                   sums: NDArray[np.float64]) -> None:  # compiled
    """``sums[c]``: row c's ``values`` added one class at a time, run after run."""
    for c in range(len(sums)):
        total = 0.0
        for r in range(run_ptr[c], run_ptr[c + 1]):
            for k in range(first[r], end[r]):
                total += values[k]
        sums[c] = total


@numba.njit(nogil=True, cache=True)
def _run_sums(run_ptr: NDArray[np.int64], first: NDArray[np.int32], end: NDArray[np.int32],
              prefix: NDArray[np.float64], sums: NDArray[np.float64]) -> None:  # compiled
    """``sums[c]``: the sum over row c's runs of ``prefix[end] - prefix[first]``."""
    for c in range(len(sums)):
        total = 0.0
        for r in range(run_ptr[c], run_ptr[c + 1]):
            total += prefix[end[r]] - prefix[first[r]]
        sums[c] = total


def class_sizes(rows: sp.csr_matrix) -> NDArray[np.int64]:
    """(K,) how many rows of the 0/1 matrix ``rows`` (C, K) hold each column, counted in
    place (``np.bincount`` of the indices made an int64 copy of them: 168 MB on the
    office's 21 M class pairs)."""
    sizes = np.zeros(rows.shape[1], np.int64)
    _count_covers(rows.indptr, rows.indices, np.ones(rows.shape[0], np.bool_), sizes)
    return sizes


@numba.njit(nogil=True, cache=True)
def _row_sums(indptr: NDArray[np.int32], indices: NDArray[np.int32], values: NDArray[Any],
              sums: NDArray[Any], first: int, last: int) -> None:  # compiled
    """``sums[c]`` for rows ``first`` to ``last - 1``: the sum of ``values`` over row c's
    classes, in order, in the type of ``sums`` (zero on entry)."""
    for c in range(first, last):
        total = sums[c]
        for j in range(indptr[c], indptr[c + 1]):
            total += values[indices[j]]
        sums[c] = total


def station_lower_bound(table: CoverageTable, need_m2: float, upper_stations: int,
                        fixed: tuple[int, ...] = (), iterations: int | None = None,
                        work: int = PARTIAL_WORK,
                        max_iterations: int = ITERATIONS) -> StationBound:
    """The fewest stations any plan needs to cover ``need_m2`` (fixed stations included).

    ``need_m2``: the area to cover, fixed stations' faces included (goal * max achievable
    - slack); ``upper_stations``: the stations of a known plan (the steps aim at it; the
    search stops early once the bound meets it). ``fixed`` stations are in every plan:
    their faces count as covered. ``iterations``: of the volume algorithm (partial cover,
    default: as many as ``work`` allows (:func:`_volume_iterations`), at least MIN_ITERATIONS
    and at most ``max_iterations``) or of PDHG per round of rows (full cover, default
    PDHG_ITERATIONS).
    """
    n_fixed = len(fixed)
    covered = table.covered_by(fixed)
    rest = table.achievable & ~covered
    need = need_m2 - float(table.face_area_m2[covered].sum())
    if need <= 0:
        return StationBound(n_fixed, float(n_fixed), 0, 0, 0, 0, REDUCTIONS)
    cover, area = merged_classes(table, rest)
    classes = cover.shape[1]
    if cover.nnz > MAX_PAIRS:
        return StationBound(n_fixed, float(n_fixed), 0, 0, classes, 0, TOO_LARGE)
    if not (area > 0).all():
        cover, area = cover[:, area > 0], area[area > 0]
    # classes a plan may not leave out: larger than all it may leave uncovered
    allowance = float(area.sum()) - need
    must = area > allowance
    size = class_sizes(cover)  # (K,) candidates a class
    # the candidates alone in covering a must class
    forced = _rows_holding(cover.indptr, cover.indices, must & (size == 1))
    if len(forced):
        hit = np.zeros(table.n_candidates, bool)
        hit[forced] = True
        counts = np.zeros(cover.shape[1])
        _count_covers(cover.indptr, cover.indices, hit, counts)
        taken = counts > 0
        need -= float(area[taken].sum())
        cover, area, must = cover[:, ~taken], area[~taken], must[~taken]
    base = n_fixed + len(forced)
    if need <= 0 or cover.shape[1] == 0:
        return StationBound(base, float(base), 0, len(forced), classes, 0, REDUCTIONS)
    # every plan covers the must classes, so the set cover of them alone is a relaxation:
    # exact when covering them is enough, and taken too when the others are slivers
    full = float(area[~must].sum()) <= max(allowance, SLIVER_SHARE * float(area.sum()))
    if full and not must.all():
        cover, area, must = cover[:, must], area[must], must[must]
    problem = _Lagrangian(cover, area, need, must, full)
    del cover  # the problem keeps its runs (a partial cover) or the matrix (a full one)
    if iterations is None:
        iterations = PDHG_ITERATIONS if full else _volume_iterations(
            problem.work(), work, max_iterations)
    target = max(1.0, float(upper_stations - base))
    done = problem.solve(target, iterations)
    return StationBound(stations=base + problem.best_stations(),
                        lp_value=base + float(problem.best.sum()), iterations=done,
                        forced=len(forced), classes=classes, components=problem.n_components,
                        method=FULL_METHOD if full else PARTIAL_METHOD)


def _volume_iterations(per_iteration: int, work: int, max_iterations: int) -> int:
    """Iterations of the volume algorithm whose one iteration reads ``per_iteration`` runs
    and classes (:meth:`ClassRuns.work`): as many as ``work`` allows, at least
    MIN_ITERATIONS and at most ``max_iterations`` (fixed work, no clock: the same table
    gives the same bound)."""
    return min(max_iterations, max(MIN_ITERATIONS, work // max(1, per_iteration)))


@dataclass(frozen=True)
class CoverageBound:
    """No ``stations`` stations (fixed ones included) cover more than ``area_m2``.

    ``iterations`` of the volume algorithm in all, over ``classes`` face classes.
    """

    stations: int
    area_m2: float
    iterations: int
    classes: int
    method: str = COVERAGE_METHOD

    def to_dict(self) -> dict[str, Any]:
        return {"bound": self.method, "stations": self.stations,
                "area_m2": round(self.area_m2, 3), "iterations": self.iterations,
                "face_classes": self.classes}


def coverage_upper_bound(table: CoverageTable, stations: int, reached_m2: float,
                         fixed: tuple[int, ...] = (),
                         work: int = COVERAGE_WORK) -> CoverageBound:
    """The most area any ``stations`` stations (``fixed`` ones included) could cover: the
    Lagrangian dual of the maximum-coverage LP.

    For every ``u >= 0`` over the classes (area ``a``) and ``t >= 0``, no ``k`` candidates
    cover more than ``sum_k max(0, a_k - t u_k) + t * (the k largest sums of u over a
    candidate's classes)``: a plan's covered classes count ``a_k = (a_k - t u_k) + t u_k``,
    the first part at most its positive part, the second at most ``t u_k`` times the plan's
    candidates covering the class. The multipliers come from the volume algorithm on the
    fewest-stations problem (:func:`station_lower_bound`'s), whose optimal multipliers,
    scaled, are the maximum-coverage LP's; ``t`` is then chosen exactly (the bound is
    convex and piecewise linear in ``t``, least at one of the ratios ``a_k / u_k``).
    The fewest-stations problem is solved for ``reached_m2``, what a known plan of
    ``stations`` covers (fixed stations included), with ``work`` (runs and classes read
    in all; fixed work, no clock: the same table gives the same bound). One such run gives a
    tighter bound than several at other areas for the same work (the Amersfoort sports
    hall, 30 stations: 1,449 m² against 1,491 for three runs bisecting the area).
    """
    n_fixed = len(fixed)
    covered = table.covered_by(fixed)
    fixed_m2 = float(table.face_area_m2[covered].sum())
    free = stations - n_fixed
    rest = table.achievable & ~covered
    if free <= 0 or not rest.any():  # the fixed stations' area is all there is
        return CoverageBound(stations, fixed_m2, 0, 0)
    cover, area = merged_classes(table, rest)
    del rest, covered
    classes = cover.shape[1]
    if not (area > 0).all():
        cover, area = cover[:, area > 0], area[area > 0]
    total = float(area.sum())
    if cover.nnz > MAX_PAIRS or free >= cover.shape[0]:
        return CoverageBound(stations, fixed_m2 + total, 0, classes)
    # the multipliers of the fewest stations covering what the known plan covers: their
    # knapsack's threshold is the plan's, near the maximum coverage LP's optimum
    need = min(max(reached_m2 - fixed_m2, ROUND_TOLERANCE * total), total)
    problem = _Lagrangian(cover, area, need, area > total - need, full=False)
    del cover  # the problem keeps its runs
    iterations = _volume_iterations(problem.work(), work, ITERATIONS)
    # aimed one station above the plan's: the search never stops early, the plan reaching
    # ``need`` with ``free`` stations
    done = problem.solve(free + 1.0, iterations)
    best = _max_coverage(problem.row_sums(problem.best_u), area, problem.best_u, free)
    return CoverageBound(stations, fixed_m2 + best, done, classes)


def _max_coverage(sums: NDArray[np.float64], area: NDArray[np.float64],
                  u: NDArray[np.float64], k: int) -> float:
    """``min over t >= 0`` of the bound of :func:`coverage_upper_bound` for multipliers
    ``u`` (K,) and ``k`` candidates whose sums of ``u`` over their classes are ``sums``
    (C,), rounded up to stay a bound."""
    top = float(np.sort(-np.partition(-sums, k - 1)[:k]).sum()) if k < len(sums) \
        else float(sums.sum())
    positive = u > 0
    constant = float(area[~positive].sum())  # classes of u = 0 count whole at every t
    ratio = area[positive] / u[positive]
    order = np.argsort(ratio, kind="stable")
    ratio, u_pos, a_pos = ratio[order], u[positive][order], area[positive][order]
    # at t = ratio[i], the classes after i in this order still count a_k - t u_k
    u_after = np.append(np.cumsum(u_pos[::-1])[::-1][1:], 0.0)
    a_after = np.append(np.cumsum(a_pos[::-1])[::-1][1:], 0.0)
    at_ratios = a_after - ratio * u_after + ratio * top
    value = min(float(area.sum()), constant + float(at_ratios.min(initial=np.inf)))
    return value + ROUND_TOLERANCE * max(1.0, float(area.sum()))


class _Lagrangian:
    """The Lagrangian of one cover problem, maximised by PDHG (full cover) or the volume
    algorithm (partial cover).

    ``cover`` (C, K) 0/1 over classes of area ``area`` (K,), ``need`` the area to cover,
    ``must`` (K,) bool the classes every plan covers (``y = 1`` in the knapsack); ``full``:
    every class must be covered (the knapsack term is ``sum u``, components bound
    separately, and rows are generated: see :meth:`solve`).

    ``best`` (components,) holds each component's best value and ``best_u`` (K,) the
    multipliers that gave it (the components' parts of different iterations: the
    Lagrangian separates, so together they give the sum).

    A partial cover keeps ``cover`` as its runs of classes only (:class:`ClassRuns`, which
    give every product the volume algorithm needs): the matrix, 5 bytes a class pair (105
    MB on the 9.7 M-piece office), is let go once they are made, when the caller holds no
    other reference to it.
    """

    def __init__(self, cover: sp.csr_matrix, area: NDArray[np.float64], need: float,
                 must: NDArray[np.bool_], full: bool) -> None:
        self.rows: sp.csr_matrix | None = cover.tocsr()  # (C, K); PDHG's only
        self.shape: tuple[int, int] = cover.shape
        if full:  # PDHG's products are scipy's, in float64; a partial cover reads the
            # pattern only (pattern_product, its runs), so its matrix keeps the merge's bool
            # data
            self.rows.data = np.ones(self.rows.nnz, np.float64)
        self.area = area
        self.need = need
        self.must = must
        self.full = full
        # the knapsack's classes other than the must ones, and the area left for them
        # (every class when none is a must one: read without gathers, ``_free`` empty)
        self._every_free = not must.any()
        self._free = np.empty(0, np.int64) if self._every_free else np.flatnonzero(~must)
        self._free_area = area if self._every_free else area[self._free]
        self._rest = need - float(area[must].sum())
        n_cand, n_class = self.shape
        rows = self.rows
        if full:
            graph = sp.bmat([[None, rows], [rows.T, None]], format="csr")
            self.n_components, label = connected_components(graph, directed=False)
            self.cand_comp = label[:n_cand]
            self.class_comp = label[n_cand:]
        else:
            self.n_components = 1
            self.cand_comp = np.zeros(n_cand, np.int64)
            self.class_comp = np.zeros(n_class, np.int64)
        self.best = np.full(self.n_components, -np.inf)
        # the volume algorithm's products, over each row's runs of consecutive classes
        self._runs = None if full else ClassRuns.of(rows)
        # the start (CFT): each class at its cheapest candidate's price per area
        cand_area = pattern_product(rows, area)  # (C,)
        price = np.zeros(n_cand)
        np.divide(1.0, cand_area, out=price, where=cand_area > 0)
        cheapest = np.full(n_class, np.inf)
        _class_minimum(rows.indptr, rows.indices, price, cheapest)
        self.best_u = area * cheapest
        if not full:
            self.rows = None

    def solve(self, target: float, iterations: int) -> int:
        """Search multipliers aiming at ``target`` (a plan's stations); the iterations made.

        A partial cover: ``iterations`` of the volume algorithm on every class. A full
        cover: PDHG on a growing subset of the classes (the others at ``u = 0``, which
        keeps every value a bound): first the ROWS_PER_ROUND seen by the fewest
        candidates, then after each round of ``iterations`` those PDHG's primal ``x``
        covers less than 1 - PRIMAL_SLACK (at most ROWS_PER_ROUND, fewest candidates
        first), for at most ROUNDS rounds. Most classes are seen by supersets of another's
        candidates and never matter.
        """
        n_class = self.shape[1]
        if not self.full:
            return self._volume(target, iterations)
        assert self.rows is not None
        size = class_sizes(self.rows)
        by_size = np.lexsort((np.arange(n_class), size))
        active = np.zeros(n_class, bool)
        active[by_size[:ROWS_PER_ROUND]] = True
        done = 0
        self._primal = np.zeros(self.shape[0])
        self._dual = self.best_u.copy()
        for _ in range(ROUNDS):
            done += self._pdhg(np.flatnonzero(active), target, iterations)
            if self.best_stations() >= target:
                break
            seen = self.rows.T @ self._primal  # (K,) how much the estimate covers
            missed = np.flatnonzero(~active & (seen < 1.0 - PRIMAL_SLACK))
            if len(missed) == 0:
                break
            active[missed[np.lexsort((missed, size[missed]))][:ROWS_PER_ROUND]] = True
        return done

    def _pdhg(self, columns: NDArray[np.int64], target: float, iterations: int) -> int:
        """Primal-dual hybrid gradient (full cover) on ``columns``; iterations made.

        Chambolle & Pock's method on the LP ``min 1.x  s.t.  M x >= 1, 0 <= x <= 1`` with
        ``M`` (K', C) the active classes' rows, as PDLP runs it: steps ``0.95 / |M|``
        (the norm by power iteration), restarted from the average of the iterates every
        :data:`RESTART_PERIOD` iterations when the average is better. Every dual iterate
        ``u`` is a Lagrangian multiplier; the primal ``x`` picks the next rows.
        """
        assert self.rows is not None
        by_class = self.rows[:, columns].T.tocsr()  # (K', C)
        by_cand = by_class.T.tocsr()  # (C, K')
        comp = self.class_comp[columns]
        v = np.ones(by_class.shape[1])
        for _ in range(NORM_ITERATIONS):
            v = by_cand @ (by_class @ v)
            v /= math.sqrt(_dot(v, v))
        w = by_cand @ (by_class @ v)
        step = 0.95 / math.sqrt(math.sqrt(_dot(w, w)))
        x, u = self._primal, self._dual[columns]
        x_sum, u_sum = np.zeros_like(x), np.zeros_like(u)
        for it in range(iterations):
            reduced = 1.0 - by_cand @ u  # (C,)
            self._record_reduced(columns, comp, u, reduced)
            if self.best_stations() >= target:
                self._primal, self._dual[columns] = x, u
                return it
            x_new = np.clip(x - step * reduced, 0.0, 1.0)
            u = np.maximum(0.0, u + step * (1.0 - by_class @ (2.0 * x_new - x)))
            x = x_new
            x_sum += x
            u_sum += u
            if (it + 1) % RESTART_PERIOD == 0:
                u_avg = u_sum / RESTART_PERIOD
                reduced_avg = 1.0 - by_cand @ u_avg
                if self._record_reduced(columns, comp, u_avg, reduced_avg) >= \
                        _full_value(u, 1.0 - by_cand @ u):
                    x, u = x_sum / RESTART_PERIOD, u_avg
                x_sum[:] = 0.0
                u_sum[:] = 0.0
        self._primal, self._dual[columns] = x, u
        return iterations

    def _record_reduced(self, columns: NDArray[np.int64], comp: NDArray[np.int64],
                        u: NDArray[np.float64], reduced: NDArray[np.float64]) -> float:
        """Record a full cover's L(u) per component (reduced costs given); the total."""
        value = np.bincount(self.cand_comp, weights=np.minimum(reduced, 0.0),
                            minlength=self.n_components).astype(np.float64)
        value += np.bincount(comp, weights=u, minlength=self.n_components)
        self._record(columns, value, u)
        return float(value.sum())

    def _volume(self, target: float, iterations: int) -> int:
        """Volume algorithm (partial cover) from ``best_u``; the iterations made.

        Barahona & Anbil: steps from the best multipliers along the subgradient of the
        averaged primal (running convex combinations of the Lagrangian's minimisers ``y``
        and of how many chosen candidates cover each class, which approach an optimal LP
        solution), the step factor raised after improving steps and cut after
        :data:`RED_STEPS` steps without. The reduced costs of the search are sums over
        runs of classes (:class:`ClassRuns`); the best multipliers are evaluated again by
        summing every class of every row, in float64.

        The search is one compiled call (:func:`_volume_search`) that never takes the
        interpreter's lock: a thread beside it (the command line's imports of the
        renderers) does not make it wait at every step, as a search of some twenty
        compiled steps an iteration did (hall-full's bound: 0.56 s alone, 0.9 s beside the
        imports, 18 s beside a busy Python thread: benchmarks/selection_beside_threads.py).
        """
        runs = self._runs
        assert runs is not None
        self.best_u, self.best[0], done = _volume_search(
            runs.run_ptr, runs.first, runs.end, self.area, self.must, self._free,
            self._free_area, self._rest, self._every_free, self.best_u.copy(),
            float(self.best[0]), target, iterations)
        # the bound: the best multipliers, summed again in float64
        reduced = 1.0 - self.row_sums(self.best_u)
        self.best[0] = float(np.minimum(reduced, 0.0).sum()) + _dot(
            self.best_u, self._knapsack(self.best_u))
        return done

    def row_sums(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """(C,) each candidate's sum of ``u`` (K,) over its classes, class by class in
        float64 (:func:`pattern_product`'s bits)."""
        if self._runs is not None:
            return self._runs.pair_sums(u)
        assert self.rows is not None
        return pattern_product(self.rows, u)

    def _knapsack(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        """(K,) y in [0, 1] of least ``u . y`` with ``area . y >= need`` and ``y = 1`` on the
        must classes: the others cheapest per area first, ties to the lowest index."""
        return _knapsack_y(u, self.area, self.must, self._free, self._free_area, self._rest,
                           self._every_free)

    def work(self) -> int:
        """What one iteration of the volume algorithm reads (:meth:`ClassRuns.work`)."""
        assert self._runs is not None
        return self._runs.work()

    def _record(self, columns: NDArray[np.int64], value: NDArray[np.float64],
                u: NDArray[np.float64]) -> None:
        """Keep each component's best value and its multipliers."""
        better = value > self.best
        if better.any():
            self.best = np.maximum(self.best, value)
            moved = better[self.class_comp[columns]]
            self.best_u[:] = np.where(better[self.class_comp], 0.0, self.best_u)
            self.best_u[columns[moved]] = u[moved]

    def best_stations(self) -> int:
        """The bound: each component's best rounded up (one component for partial)."""
        tolerance = ROUND_TOLERANCE * np.maximum(1.0, np.abs(self.best))
        return int(np.maximum(0.0, np.ceil(self.best - tolerance)).sum())


def _full_value(u: NDArray[np.float64], reduced: NDArray[np.float64]) -> float:
    """L(u) of a full cover from the multipliers (K',) and reduced costs ``1 - M^T u`` (C,)."""
    return float(np.minimum(reduced, 0.0).sum() + u.sum())


def _dot(a: NDArray[np.float64], b: NDArray[np.float64]) -> float:
    """``a . b`` without BLAS (whose threads stall on a busy machine for vectors this size)."""
    return float(np.multiply(a, b).sum())


@numba.njit(nogil=True, cache=True)
def _volume_search(run_ptr: NDArray[np.int64], first: NDArray[np.int32], end: NDArray[np.int32],
                   area: NDArray[np.float64], must: NDArray[np.bool_], free: NDArray[np.int64],
                   free_area: NDArray[np.float64], rest: float, every_free: bool,
                   u_start: NDArray[np.float64], recorded: float, target: float,
                   iterations: int) -> tuple[NDArray[np.float64], float, int]:  # compiled
    """The volume algorithm's search of :meth:`_Lagrangian._volume` from ``u_start`` (K,):
    the best multipliers it evaluated (``u_start`` when none beat ``recorded``), their
    value, and the iterations made. The problem is given as :class:`ClassRuns` arrays and
    :func:`_knapsack_y`'s; every sum is summed as numpy sums it, so the search takes the
    same steps as numpy's operations would."""
    n_class = len(area)
    u_best = u_start
    l_best, y, x = _partial_value(run_ptr, first, end, u_best, area, must, free, free_area,
                                  rest, every_free)
    best_value, best_u = recorded, u_start
    if l_best > best_value:
        best_value, best_u = l_best, u_best
    y_bar = y.copy()
    seen_bar = _run_counts(run_ptr, first, end, x, n_class)
    g_bar = np.empty_like(y_bar)
    factor = START_STEP
    red = 0
    done = iterations
    for it in range(iterations):
        if _rounded_up(best_value) >= target:
            done = it
            break
        _subgradient(y_bar, seen_bar, u_best, g_bar)
        norm = numpy_sum(g_bar * g_bar)
        if norm <= 0:
            done = it
            break
        gap = max(target - l_best, 1e-3 * max(1.0, abs(l_best)))
        u = np.empty_like(u_best)
        _step(u_best, factor * gap / norm, g_bar, u)
        value, y, x = _partial_value(run_ptr, first, end, u, area, must, free, free_area,
                                     rest, every_free)
        if value > best_value:
            best_value, best_u = value, u
        seen = _run_counts(run_ptr, first, end, x, n_class)
        _average(y, y_bar, AVERAGE)
        _average(seen, seen_bar, AVERAGE)
        if value > l_best:
            if numpy_sum((y - seen) * g_bar) >= 0:  # green: the step could be longer
                factor = min(MAX_STEP, factor * 1.1)
            l_best, u_best = value, u
            red = 0
        else:
            red += 1
            if red >= RED_STEPS:
                factor *= 0.66
                red = 0
    return best_u, best_value, done


@numba.njit(nogil=True, cache=True)
def _partial_value(run_ptr: NDArray[np.int64], first: NDArray[np.int32],
                   end: NDArray[np.int32], u: NDArray[np.float64], area: NDArray[np.float64],
                   must: NDArray[np.bool_], free: NDArray[np.int64],
                   free_area: NDArray[np.float64], rest: float, every_free: bool
                   ) -> tuple[float, NDArray[np.float64], NDArray[np.bool_]]:  # compiled
    """L(u) of a partial cover (the rows' sums over their runs), the knapsack's y (K,) and
    x (C,): the candidates of negative reduced cost (the Lagrangian's minimisers)."""
    reduced = 1.0 - _runs_sums(run_ptr, first, end, u)  # (C,)
    y = _knapsack_y(u, area, must, free, free_area, rest, every_free)
    value = numpy_sum(np.minimum(reduced, 0.0)) + numpy_sum(u * y)
    return value, y, reduced < 0


@numba.njit(nogil=True, cache=True)
def _knapsack_y(u: NDArray[np.float64], area: NDArray[np.float64], must: NDArray[np.bool_],
                free: NDArray[np.int64], free_area: NDArray[np.float64], rest: float,
                every_free: bool) -> NDArray[np.float64]:  # compiled
    """(K,) y in [0, 1] of least ``u . y`` with ``area . y >= need`` and ``y = 1`` on the
    ``must`` classes: the ``free`` others (all of them when ``every_free``, read without
    gathers), of ``free_area``, cheapest per area first until they cover ``rest``."""
    if rest <= 0 or len(free_area) == 0:
        return must.astype(np.float64)
    if every_free:
        return _cheapest_first(u / area, area, rest)
    y = must.astype(np.float64)
    y[free] = _cheapest_first(u[free] / free_area, free_area, rest)
    return y


@numba.njit(nogil=True, cache=True)
def _rounded_up(value: float) -> float:
    """:meth:`_Lagrangian.best_stations` of one component of Lagrangian ``value``."""
    return max(0.0, float(np.ceil(value - ROUND_TOLERANCE * max(1.0, abs(value)))))


# The volume algorithm's steps over the (K,) classes, each one compiled pass (numpy took a
# temporary a step: 6 ms an iteration on the office's 808,000 classes), the same values
# element for element.


@numba.njit(nogil=True, cache=True)
def _subgradient(y_bar: NDArray[np.float64], seen_bar: NDArray[np.float64],
                 u: NDArray[np.float64], g: NDArray[np.float64]) -> None:  # compiled
    """``g = y_bar - seen_bar``, 0 where it is negative at a multiplier ``u`` of 0."""
    for k in range(len(g)):
        value = y_bar[k] - seen_bar[k]
        g[k] = 0.0 if u[k] <= 0 and value < 0 else value


@numba.njit(nogil=True, cache=True)
def _step(u: NDArray[np.float64], step: float, g: NDArray[np.float64],
          out: NDArray[np.float64]) -> None:  # compiled
    """``out = max(0, u + step g)``."""
    for k in range(len(u)):
        value = u[k] + step * g[k]
        out[k] = value if value > 0.0 else 0.0


@numba.njit(nogil=True, cache=True)
def _average(new: NDArray[np.float64], running: NDArray[np.float64], weight: float
             ) -> None:  # compiled
    """``running = weight new + (1 - weight) running``, in place."""
    keep = 1.0 - weight
    for k in range(len(new)):
        running[k] = weight * new[k] + keep * running[k]


@numba.njit(nogil=True, cache=True)
def _count_covers(indptr: NDArray[np.int32], indices: NDArray[np.int32],
                  chosen: NDArray[np.bool_], counts: NDArray[Any]) -> None:  # compiled
    """``counts[k]`` += how many of the ``chosen`` (C,) rows hold class k (float64 or
    integer counts)."""
    for c in range(len(chosen)):
        if chosen[c]:
            for j in range(indptr[c], indptr[c + 1]):
                counts[indices[j]] += 1


# a band of the knapsack's ratios is cut into this many buckets, until it holds at most
# BAND_SORTED classes, which are sorted
BUCKETS = 1024
BAND_SORTED = 4096


@numba.njit(nogil=True, cache=True)
def _cheapest_first(ratio: NDArray[np.float64], area: NDArray[np.float64], rest: float
                    ) -> NDArray[np.float64]:  # compiled
    """(n,) y: 1 for the items of least ``ratio`` while their ``area`` stays under ``rest``,
    the fraction of the next that reaches it, 0 after; ties to the lowest index.

    A full sort of 808,000 ratios took 78 ms an iteration of the volume algorithm; only the
    items around the threshold need an order. The band that holds it is cut into
    :data:`BUCKETS` buckets by value (monotone: an item of less ratio never lands in a later
    bucket), the buckets before the threshold's are taken whole, and so on in that bucket
    until it is small or all one value; then it is sorted (stable: by index on ties).
    """
    n = len(ratio)
    y = np.zeros(n)
    band = np.arange(n)
    base = 0.0  # the area taken before the band
    while len(band) > BAND_SORTED:
        lo, hi = ratio[band[0]], ratio[band[0]]
        for i in band:
            lo = min(lo, ratio[i])
            hi = max(hi, ratio[i])
        if not hi > lo:
            break
        scale = BUCKETS / (hi - lo)
        bucket = np.empty(len(band), np.int64)
        filled = np.zeros(BUCKETS)
        for j in range(len(band)):
            b = min(BUCKETS - 1, int((ratio[band[j]] - lo) * scale))
            bucket[j] = b
            filled[b] += area[band[j]]
        crossing = BUCKETS  # none: the band does not reach ``rest``, all of it is taken
        taken = base
        for b in range(BUCKETS):
            if taken + filled[b] >= rest:
                crossing = b
                break
            taken += filled[b]
        kept = 0
        for j in range(len(band)):
            if bucket[j] < crossing:
                y[band[j]] = 1.0
            elif bucket[j] == crossing:
                band[kept] = band[j]
                kept += 1
        band = band[:kept].copy()
        base = taken
    order = band[np.argsort(ratio[band], kind="mergesort")]
    running = base
    for i in order:
        if running + area[i] >= rest:
            y[i] = min(1.0, max(0.0, (rest - running) / area[i]))
            break
        y[i] = 1.0
        running += area[i]
    return y
