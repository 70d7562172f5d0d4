"""The Lagrangian lower bound on the stations: never above a real plan (the halls' proven
optima, every subset of small tables), close to the cover LP (HiGHS), far above the area
bound, the same bound every time, and in plan.json beside every heuristic plan."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.optimize import linprog

from planner.outputs.report import plan_document
from planner.pipeline import PlanResult
from planner.selection.classes import class_table, merged_classes
from planner.selection.greedy import GOAL_SLACK_M2, greedy
from planner.selection.lower_bound import (
    BAND_SORTED,
    THREADED_PAIRS,
    ClassRuns,
    _cheapest_first,
    pattern_product,
    station_lower_bound,
)
from planner.selection.optimal import _counting_bound
from planner.selection.sums import numpy_sum
from planner.visibility.coverage import CoverageTable
from tests.planner.test_optimal import hall_plan
from tests.property.test_optimal_exact import fewest_by_enumeration, instance, table_of

# the optima test_optimal proves at goal 100 %
PROVEN_OPTIMUM = {"hall-small": 30, "hall-full": 63}


def need_of(table: CoverageTable, goal: float) -> float:
    return goal * table.max_achievable_area_m2 - GOAL_SLACK_M2


def area_bound(table: CoverageTable, goal: float) -> int:
    return _counting_bound(table, need_of(table, goal), table.achievable)


def cover_lp(table: CoverageTable, goal: float) -> float:
    """The cover LP's optimum (0 <= x, y <= 1) by HiGHS, over the face classes.

    A class larger than all a plan may leave uncovered is covered by every plan: its
    ``y`` is 1 (the bound knows that too).
    """
    classes = class_table(table, table.achievable).table
    cover, area = classes.pattern(np.float64).tocsc(), classes.face_area_m2
    must = area > area.sum() - need_of(table, goal)
    n_cand, n_class = cover.shape
    if goal >= 1.0:
        answer = linprog(np.ones(n_cand), A_ub=-cover.T.tocsr(), b_ub=-np.ones(n_class),
                         bounds=(0, 1), method="highs")
    else:
        # y_k - sum_c x_c <= 0, -area . y <= -need
        rows = sp.vstack([sp.hstack([-cover.T, sp.identity(n_class)]),
                          sp.hstack([sp.csr_matrix((1, n_cand)),
                                     -sp.csr_matrix(area[None, :])])]).tocsr()
        answer = linprog(np.concatenate([np.ones(n_cand), np.zeros(n_class)]), A_ub=rows,
                         b_ub=np.concatenate([np.zeros(n_class), [-need_of(table, goal)]]),
                         bounds=[(0, 1)] * n_cand + [(1 if m else 0, 1) for m in must],
                         method="highs")
    assert answer.status == 0
    return float(answer.fun)


@pytest.fixture(scope="module")
def halls(scenes_dir: Path) -> dict[str, PlanResult]:
    return {name: hall_plan(scenes_dir, name, coverage_goal=1.0) for name in PROVEN_OPTIMUM}


@pytest.mark.parametrize("name", sorted(PROVEN_OPTIMUM))
def test_the_bound_at_100_percent_stays_below_the_proven_optimum(
        halls: dict[str, PlanResult], name: str) -> None:
    result = halls[name]
    table = result.table
    plan = min(s.count_for_goal(1.0) for s in result.selections.values())
    bound = station_lower_bound(table, need_of(table, 1.0), plan)
    assert area_bound(table, 1.0) <= bound.stations <= PROVEN_OPTIMUM[name]
    assert bound.lp_value <= PROVEN_OPTIMUM[name]
    # the proven optimum and the weighted greedy plan would pass as the plan to aim at
    aimed = station_lower_bound(table, need_of(table, 1.0), PROVEN_OPTIMUM[name])
    assert aimed.stations <= PROVEN_OPTIMUM[name]


def test_hall_full_bound_is_far_above_the_area_bound(halls: dict[str, PlanResult]) -> None:
    table = halls["hall-full"].table
    bound = station_lower_bound(table, need_of(table, 1.0), 72)  # weighted greedy's plan
    # the area bound proves 6 of the 63 stations; the cover LP is 62.5 (HiGHS on the
    # classes the set cover needs), so its dual proves 63
    assert area_bound(table, 1.0) == 6
    assert bound.lp_value <= 62.5 + 1e-6
    assert PROVEN_OPTIMUM["hall-full"] - 1 <= bound.stations <= PROVEN_OPTIMUM["hall-full"]
    assert bound.forced > 0 and bound.components > 1


@pytest.mark.parametrize("goal", [0.8, 0.9, 0.95])
@pytest.mark.parametrize("name", sorted(PROVEN_OPTIMUM))
def test_partial_goals_stay_below_every_plan(halls: dict[str, PlanResult], name: str,
                                             goal: float, scenes_dir: Path) -> None:
    result = halls[name]
    table = result.table
    plans = [s.count_for_goal(goal) for s in result.selections.values()]
    if goal == 0.8:  # the independent reference implementation's plans
        expected = json.loads((scenes_dir / name / "expected.json").read_text())["goal_0.8"]
        plans += [len(row["stations"]) for row in expected.values()]
    bound = station_lower_bound(table, need_of(table, goal), min(plans))
    assert bound.stations <= min(plans)
    if goal == 0.95:  # hall-small: 4 (the LP is 3.88), hall-full: 8; the area bound 2 and 5
        assert bound.stations > area_bound(table, goal)


def test_the_same_table_gives_the_same_bound(halls: dict[str, PlanResult]) -> None:
    table = halls["hall-small"].table
    for goal in (1.0, 0.8):
        first = station_lower_bound(table, need_of(table, goal), 31)
        again = station_lower_bound(table, need_of(table, goal), 31)
        assert first == again and first.to_dict() == again.to_dict()
        assert first.lp_value.hex() == again.lp_value.hex()


def test_hall_small_reaches_the_cover_lp(halls: dict[str, PlanResult]) -> None:
    table = halls["hall-small"].table
    lp = cover_lp(table, 1.0)
    bound = station_lower_bound(table, need_of(table, 1.0), 31)
    assert 0.9 * lp <= bound.lp_value <= lp + 1e-6
    assert bound.stations <= PROVEN_OPTIMUM["hall-small"]


def test_the_merged_classes_are_the_face_classes(halls: dict[str, PlanResult]) -> None:
    table = halls["hall-small"].table
    # the classes by hand: each achievable face's set of candidates, areas summed
    by_face = table.by_candidate.tocsc()
    expected: dict[bytes, float] = {}
    for f in np.flatnonzero(table.achievable):
        key = by_face.indices[by_face.indptr[f]:by_face.indptr[f + 1]].tobytes()
        expected[key] = expected.get(key, 0.0) + float(table.face_area_m2[f])
    # the same classes (sets of candidates) with the same areas, in any order
    def classes(matrix: sp.csc_matrix, areas: np.ndarray) -> list[tuple[bytes, float]]:
        return sorted((matrix.indices[matrix.indptr[k]:matrix.indptr[k + 1]].tobytes(),
                       round(float(areas[k]), 9)) for k in range(matrix.shape[1]))
    want = sorted((key, round(area, 9)) for key, area in expected.items())
    cover, area = merged_classes(table, np.ones(table.n_faces, bool))
    assert classes(cover.tocsc(), area) == want
    # and as the optimal method's table of classes, in the order of their first face
    table_of_classes = class_table(table, table.achievable)
    by_class = table_of_classes.table.pattern(np.float64).tocsc()
    assert classes(by_class, table_of_classes.table.face_area_m2) == want
    first = table_of_classes.first_face
    assert (np.diff(first) > 0).all()
    assert all(by_face.indices[by_face.indptr[f]:by_face.indptr[f + 1]].tolist() ==
               by_class.indices[by_class.indptr[k]:by_class.indptr[k + 1]].tolist()
               for k, f in enumerate(first))


# small tables: enumeration gives the true minimum and HiGHS the LP
def random_tables(count: int) -> list[tuple[list[list[int]], list[float]]]:
    rng = np.random.default_rng(7)
    tables = []
    for _ in range(count):
        n_faces = int(rng.integers(8, 15))
        n_cand = int(rng.integers(5, 10))
        sets = [sorted(rng.choice(n_faces, int(rng.integers(1, n_faces // 2)),
                                  replace=False).tolist()) for _ in range(n_cand)]
        areas = rng.choice([0.5, 1.0, 2.0, 3.0], n_faces).tolist()
        tables.append((sets, areas))
    return tables


@pytest.mark.parametrize(("index", "instance"), list(enumerate(random_tables(12))))
def test_small_tables_bound_below_the_minimum_and_near_the_lp(
        index: int, instance: tuple[list[list[int]], list[float]]) -> None:
    table = table_of(*instance)
    for goal in (0.5, 0.8, 1.0):
        for fixed in ((), (index % table.n_candidates,)):
            fewest = fewest_by_enumeration(table, goal, fixed)
            plan = greedy(table, fixed=fixed).count_for_goal(goal)
            bound = station_lower_bound(table, need_of(table, goal), plan, fixed)
            assert len(fixed) <= bound.stations <= fewest
        lp = cover_lp(table, goal)
        bound = station_lower_bound(table, need_of(table, goal), table.n_candidates)
        assert 0.9 * lp - 1e-9 <= bound.lp_value <= lp + 1e-6


@settings(max_examples=40, deadline=None)
@given(instance=instance, goal=st.sampled_from([0.5, 0.8, 0.95, 1.0]),
       n_fixed=st.integers(0, 1), aim=st.integers(0, 3))
def test_random_tables_bound_below_the_minimum(instance: tuple[list[list[int]], list[float]],
                                              goal: float, n_fixed: int, aim: int) -> None:
    table = table_of(*instance)
    fixed = tuple(range(n_fixed))
    fewest = fewest_by_enumeration(table, goal, fixed)
    # the plan the steps aim at may be the minimum or any larger one
    bound = station_lower_bound(table, need_of(table, goal), fewest + aim, fixed)
    assert n_fixed <= bound.stations <= fewest


def corridor_sets() -> list[list[int]]:
    """80 stations along a corridor of 3000 faces, each seeing 60 % of a window of them."""
    rng = np.random.default_rng(11)
    n_faces = 3000
    sets = []
    for _ in range(80):
        centre, width = int(rng.integers(0, n_faces)), int(rng.integers(100, 600))
        faces = np.arange(centre - width, centre + width) % n_faces
        sets.append(sorted(set(faces[rng.random(len(faces)) < 0.6].tolist())))
    return sets


def corridor_table() -> CoverageTable:
    """:func:`corridor_sets` with face areas of 0.01 to 0.2 m^2."""
    areas = np.random.default_rng(12).uniform(0.01, 0.2, 3000)
    return table_of(corridor_sets(), areas.tolist())


@pytest.mark.parametrize("goal", [0.8, 0.9, 0.95, 1.0])
def test_a_corridor_reaches_the_cover_lp(goal: float) -> None:
    table = corridor_table()
    every_face = greedy(table)  # a plan for every goal: the steps aim at it
    bound = station_lower_bound(table, need_of(table, goal), len(every_face.stations))
    lp = cover_lp(table, goal)
    assert 0.9 * lp <= bound.lp_value <= lp + 1e-6
    assert area_bound(table, goal) <= bound.stations <= every_face.count_for_goal(goal)


def test_greedy_plans_report_the_bound(halls: dict[str, PlanResult]) -> None:
    selection = plan_document(halls["hall-small"])["selection"]
    assert selection["method"] == "greedy" and selection["stations"] == 36
    bound = selection["bound"]
    assert bound["area_bound"] == 2
    assert bound["lagrangian"]["stations"] == selection["lower_bound"]
    assert bound["area_bound"] < selection["lower_bound"] <= PROVEN_OPTIMUM["hall-small"]
    assert "lagrangian" in selection["status"] and not selection["proven_optimal"]


def test_slivers_leave_a_full_cover_full() -> None:
    table = corridor_table()
    bound = station_lower_bound(table, need_of(table, 1.0), 23)
    # 100 faces of 1e-10 m^2 more (together above the goal's slack), sliver j seen by
    # stations j and j + 1: a plan may leave out a few of them, not all
    sets = [[*faces, *(3000 + j for j in range(100) if c in (j % 80, (j + 1) % 80))]
            for c, faces in enumerate(corridor_sets())]
    slivers = table_of(sets, [*table.face_area_m2.tolist(), *[1e-10] * 100])
    with_slivers = station_lower_bound(slivers, need_of(slivers, 1.0), 23)
    assert with_slivers.method == bound.method
    assert with_slivers.stations == bound.stations


def test_a_table_too_large_keeps_the_fixed_stations(monkeypatch: pytest.MonkeyPatch) -> None:
    import planner.selection.lower_bound as lower_bound

    table = corridor_table()
    monkeypatch.setattr(lower_bound, "MAX_PAIRS", 0)  # any class over the fixed stations
    bound = station_lower_bound(table, need_of(table, 1.0), 23, fixed=(0, 1))
    assert bound.stations == 2 and "pairs" in bound.method


def knapsack_by_sort(ratio: np.ndarray, area: np.ndarray, rest: float) -> np.ndarray:
    """The fractional knapsack by one stable sort of every ratio (ties to the lowest index)."""
    order = np.argsort(ratio, kind="stable")
    reach = np.cumsum(area[order])
    last = min(int(np.searchsorted(reach, rest)), len(order) - 1)
    y = np.zeros(len(ratio))
    y[order[:last]] = 1.0
    before = float(reach[last - 1]) if last > 0 else 0.0
    y[order[last]] = min(1.0, max(0.0, (rest - before) / float(area[order[last]])))
    return y


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 3 * BAND_SORTED), seed=st.integers(0, 2**32 - 1),
       values=st.sampled_from(["spread", "few", "equal", "heavy tail"]),
       share=st.floats(0.0, 1.2))
def test_knapsack_by_buckets_is_the_knapsack_of_a_full_sort(
        n: int, seed: int, values: str, share: float) -> None:
    # the volume algorithm's knapsack takes the cheapest classes per area until the goal's
    # area: by buckets around the threshold instead of sorting all, the same y (to float
    # rounding), ties included, and all of them when the area does not reach it
    rng = np.random.default_rng(seed)
    ratio = {"spread": rng.random(n), "few": rng.integers(0, 4, n).astype(np.float64),
             "equal": np.full(n, 0.5), "heavy tail": rng.lognormal(0.0, 6.0, n)}[values]
    area = rng.random(n) + 1e-3
    rest = share * float(area.sum())
    if rest <= 0:
        return
    assert np.allclose(_cheapest_first(ratio, area, rest), knapsack_by_sort(ratio, area, rest),
                       rtol=0, atol=1e-9)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("pairs", [1_000, 3 * THREADED_PAIRS])
def test_the_bounds_products_are_scipys_to_the_bit(dtype: type, pairs: int) -> None:
    # the volume algorithm's reduced costs read the class matrix's pattern only, in row
    # ranges on several threads (above THREADED_PAIRS): every sum must be the one scipy
    # gives, bit for bit, so that the bound's iterations and value do not change
    rng = np.random.default_rng(pairs)
    n_rows, n_cols = 257, 50_000
    rows = sp.random(n_rows, n_cols, density=pairs / (n_rows * n_cols), format="csr",
                     random_state=rng, dtype=dtype)
    rows.data[:] = 1.0
    values = (rng.random(n_cols) * rng.lognormal(0.0, 4.0, n_cols)).astype(dtype)
    product = pattern_product(rows, values)
    assert product.dtype == dtype
    assert np.array_equal(product, rows @ values)


def test_runs_of_classes_sum_what_their_pairs_sum(halls: dict[str, PlanResult]) -> None:
    # the volume algorithm's reduced costs are sums over each row's runs of consecutive
    # classes (prefix sums): the same sums as every pair's, to float64 rounding, on rows
    # that hold their classes in any order, with empty rows and a class alone at the end
    rows = sp.csr_matrix((np.ones(9, bool), np.array([3, 4, 5, 9, 10, 2, 11, 0, 1]),
                          np.array([0, 6, 6, 7, 9])), shape=(4, 12))
    runs = ClassRuns.of(rows)
    assert runs.run_ptr.tolist() == [0, 3, 3, 4, 5]  # [3, 6), [9, 11), [2, 3); none; ...
    assert list(zip(runs.first.tolist(), runs.end.tolist(), strict=True)) == [
        (3, 6), (9, 11), (2, 3), (11, 12), (0, 2)]
    values = np.random.default_rng(5).lognormal(0.0, 3.0, 12)
    assert np.allclose(runs.sums(values), rows.astype(np.float64) @ values, rtol=1e-12,
                       atol=0)
    # and how many chosen rows hold each column, exactly
    chosen = np.array([True, False, True, True])
    assert runs.counts(chosen).tolist() == (
        chosen.astype(np.float64) @ rows.astype(np.float64)).tolist()
    # hall-full's class matrix: 10.5 M pairs in far fewer runs, the same sums
    table = halls["hall-full"].table
    cover, _ = merged_classes(table, table.achievable)
    runs = ClassRuns.of(cover)
    assert len(runs.first) * 5 < cover.nnz
    values = np.random.default_rng(6).random(cover.shape[1])
    assert np.allclose(runs.sums(values), pattern_product(cover, values), rtol=1e-9,
                       atol=1e-9)
    # and the final bound's sums, class by class over the runs: the pairs' bits
    assert np.array_equal(runs.pair_sums(values), pattern_product(cover, values))
    chosen = np.random.default_rng(7).random(cover.shape[0]) < 0.3
    assert np.array_equal(runs.counts(chosen),
                          chosen.astype(np.float64) @ cover.astype(np.float64))


def test_the_compiled_search_sums_as_numpy_sums() -> None:
    # the volume algorithm runs compiled, and decides its steps on sums: summed in numpy's
    # pairwise order they are numpy's bits, so the bound beside a plan stays what numpy's
    # operations gave (every length's tree: under 8, one block of 8 running sums, halves)
    rng = np.random.default_rng(11)
    for n in [*range(300), 1000, 4097, 8193, 100_003]:
        values = rng.standard_normal(n) * rng.lognormal(0.0, 4.0, n)
        assert numpy_sum(values) == values.sum(), n
