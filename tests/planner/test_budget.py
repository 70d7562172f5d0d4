"""A budget of stations (``max_stations``): the most coverage in that many stations, with a
bound no plan of that many stations can beat, checked against every pair on hall-small and
against every plan of small tables."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
import scipy.sparse as sp

from planner.candidates.grid import read_candidates_csv
from planner.errors import ParameterError
from planner.io.readers import read_scene
from planner.outputs.drawing import _budget_words, _stations_title
from planner.outputs.report import plan_document
from planner.parameters import PlanSpec
from planner.pipeline import PlanResult, plan
from planner.selection.budget import longest_prefix_in_time
from planner.selection.greedy import Selection
from planner.selection.lower_bound import coverage_upper_bound
from planner.visibility.coverage import CoverageTable
from tests.data_files import HALL_SMALL


def _hall(**params: object) -> PlanResult:
    folder = HALL_SMALL
    scene = read_scene(folder / "hall.obj", max_edge_m=None)
    candidates = read_candidates_csv(folder / "candidates.csv").tolist()
    return plan(scene, PlanSpec.from_mapping({"candidates": candidates, "max_edge_m": None,
                                              **params}), keep_table=True)


@pytest.fixture(scope="module")
def unlimited() -> PlanResult:
    return _hall(coverage_goal=1.0)


@pytest.mark.parametrize("method", ["greedy", "weighted_greedy"])
def test_a_budget_of_two_covers_at_least_the_greedy_prefix_and_at_most_the_best_pair(
        unlimited: PlanResult, method: str) -> None:
    result = _hall(max_stations=2, coverage_goal=1.0, method=method)
    order = unlimited.selections[method]
    document = plan_document(result)
    assert document["totals"]["stations"] == 2 and not document["goal_reached"]
    budget = document["selection"]["budget"]
    assert budget["max_stations"] == 2 and budget["stations"] == 2
    assert budget["covered_area_m2"] >= order.covered_area_m2[1] - 1e-3
    swapped = {c for swap in budget["swaps"] for c in swap["added"]}
    assert set(result.chosen.stations) == (set(order.stations[:2]) - {
        c for swap in budget["swaps"] for c in swap["removed"]} | swapped)
    assert 1 <= budget["goal_needs_at_least"] <= order.count_for_goal(1.0)
    # every pair of candidates: what the best two stations cover (area of A + B - both)
    table = result.table
    cover = table.by_candidate.astype(bool).astype(np.float64)  # (C, F)
    shared = (cover @ sp.diags(table.face_area_m2) @ cover.T).toarray()  # (C, C)
    single = np.diag(shared)
    best_pair = float((single[:, None] + single[None, :] - shared).max())
    assert budget["covered_area_m2"] <= best_pair + 1e-6
    assert best_pair <= budget["upper_bound_area_m2"] + 1e-6
    # one station more: the most any candidate adds to the plan's faces
    uncovered = ~table.covered_by(result.chosen.stations)
    assert budget["next_station_gain_m2"] == pytest.approx(
        float((cover @ (table.face_area_m2 * uncovered)).max()), abs=1e-3)
    # the LP's bound is one to act on: within 10 % of the best pair (95.5 against 90.2 m²),
    # where submodularity alone allows 109 m²
    bounds = budget["bounds"]
    assert budget["upper_bound_area_m2"] == min(bounds["submodular_area_m2"],
                                                 bounds["lagrangian"]["area_m2"])
    assert bounds["lagrangian"]["area_m2"] < bounds["submodular_area_m2"]
    assert budget["upper_bound_area_m2"] <= 1.1 * best_pair
    # greedy's guarantee: at least 1 - 1/e of the best pair
    assert budget["covered_area_m2"] >= (1 - 1 / np.e) * best_pair - 1e-6
    if method == "greedy":  # a swap covers more than greedy's first two (89.92, 89.85 m²)
        assert budget["swaps"]
        assert budget["covered_area_m2"] > order.covered_area_m2[1] + 0.05


@pytest.mark.parametrize("seed", range(12))
def test_no_plan_of_k_stations_covers_more_than_the_lagrangian_bound(seed: int) -> None:
    """Every plan of k of 10 candidates on random tables (classes of random areas), with and
    without a fixed station: none covers more than the bound for k stations."""
    rng = np.random.default_rng(seed)
    pattern = rng.random((10, 40)) < 0.25  # (C, K)
    area = rng.random(40) + 0.05
    table = CoverageTable.from_csr(sp.csr_matrix(pattern), area)

    def best(k: int, fixed: tuple[int, ...]) -> float:
        free = [c for c in range(10) if c not in fixed]
        return max(float(area[pattern[[*fixed, *plan]].any(axis=0)].sum())
                   for plan in itertools.combinations(free, k - len(fixed)))

    for k in (1, 2, 3, 4):
        for fixed in ((), (0,)):
            most = best(k, fixed)
            # from a plan below the best, as a greedy order would give
            bound = coverage_upper_bound(table, k, 0.9 * most, fixed=fixed)
            assert most <= bound.area_m2 <= float(area.sum()) + 1e-6
            assert bound.stations == k


def test_the_lagrangian_bound_is_exact_where_the_lp_is() -> None:
    """Candidates that share no class: the best k are the k largest, and the LP knows it."""
    area = np.arange(1.0, 13.0)
    pattern = np.zeros((6, 12), bool)
    for c in range(6):
        pattern[c, 2 * c:2 * c + 2] = True
    table = CoverageTable.from_csr(sp.csr_matrix(pattern), area)
    sums = np.sort(pattern.astype(float) @ area)[::-1]
    for k in (1, 2, 3):
        bound = coverage_upper_bound(table, k, float(sums[:k].sum()))
        assert bound.area_m2 == pytest.approx(float(sums[:k].sum()), rel=1e-6)


def test_a_budget_above_what_the_goal_needs_adds_coverage(unlimited: PlanResult) -> None:
    at_goal = _hall()  # 80 %: two stations
    more = _hall(max_stations=4)
    # the preview's station table says the most any plan of four stations could cover
    budget = plan_document(more)["selection"]["budget"]
    assert _stations_title(more) == \
        f"4 stations; any 4 cover at most {100 * budget['upper_bound_fraction']:.1f} %"
    assert len(at_goal.chosen.stations) < 4 == len(more.chosen.stations)
    assert more.chosen.covered_area_m2[-1] >= \
        unlimited.selections["greedy"].covered_area_m2[3] - 1e-9
    assert plan_document(more)["goal_reached"]
    assert more.chosen.covered_area_m2[-1] > at_goal.chosen.covered_area_m2[-1]


@pytest.mark.parametrize(("params", "says"), [
    ({"max_stations": 0}, "max_stations"),
    ({"max_stations": 3, "method": "optimal"}, "optimal"),
    ({"max_stations": 2.5}, "whole number"),
    ({"max_stations": 1, "fixed_stations": [[0, 0, 1.5], [1, 0, 1.5]]}, "fixed_stations"),
])
def test_a_budget_that_cannot_be_planned_names_the_parameter(params: dict[str, object],
                                                             says: str) -> None:
    with pytest.raises(ParameterError, match="max_stations") as error:
        PlanSpec.from_mapping(params)
    assert says in str(error.value)


# --- a budget of hours (max_field_time_h) ----------------------------------------------

# measurement rate and overhead: a scan at the paper's step takes 38.2 s, a station with
# the default 60 s setup 98.2 s
CREW_SCANNER = {"name": "crew scanner", "measurement_rate_pts_s": 2e6, "overhead_s": 30.0}


def test_a_budget_of_hours_is_the_longest_greedy_start_whose_walk_fits(
        unlimited: PlanResult) -> None:
    """Hours for seven setups and scans but only 5 s of walking: the walk decides."""
    one_station_s = 60.0 + 38.2247
    max_s = 7 * one_station_s + 5.0
    result = _hall(scanner=CREW_SCANNER, max_field_time_h=max_s / 3600, coverage_goal=1.0)
    document = plan_document(result)
    budget = document["selection"]["budget"]
    spent = budget["field_time"]
    n = document["totals"]["stations"]
    # what the crew is told: the plan's field time fits, one station more would not
    assert spent["within"] and spent["at_most_stations"] == 7
    assert spent["station_setup_and_scan_s"] == pytest.approx(one_station_s, abs=0.05)
    assert document["field_time"]["total_s"] <= max_s
    assert spent["plan_field_time_h"] * 3600 == pytest.approx(
        document["field_time"]["total_s"], abs=0.4)  # every station at the plan's step
    assert 1 <= n < 7  # the walk of seven stations does not fit in 5 s
    assert spent["one_station_more_field_time_h"] * 3600 > max_s
    order = unlimited.selections["greedy"]
    assert budget["covered_area_m2"] >= order.covered_area_m2[n - 1] - 1e-3
    assert budget["upper_bound_area_m2"] >= budget["covered_area_m2"]
    assert _stations_title(result) == (
        f"{n} stations; in {spent['max_field_time_h']:g} h at most "
        f"{100 * budget['upper_bound_fraction']:.1f} %")
    # a longer day never covers less
    longer = plan_document(_hall(scanner=CREW_SCANNER, max_field_time_h=0.5,
                                 coverage_goal=1.0))
    assert longer["selection"]["budget"]["covered_area_m2"] >= budget["covered_area_m2"]
    assert longer["totals"]["stations"] > n
    assert longer["field_time"]["total_s"] <= 0.5 * 3600


def test_no_plan_in_the_hours_covers_more_than_the_bound_every_pair_checked() -> None:
    """Hours for two setups and scans: the bound is over any two stations, walk or not."""
    max_s = 2 * (60.0 + 38.2247) + 60.0
    result = _hall(scanner=CREW_SCANNER, max_field_time_h=max_s / 3600)
    budget = plan_document(result)["selection"]["budget"]
    assert budget["field_time"]["at_most_stations"] == budget["max_stations"] == 2
    table = result.table
    cover = table.by_candidate.astype(bool).astype(np.float64)  # (C, F)
    shared = (cover @ sp.diags(table.face_area_m2) @ cover.T).toarray()  # (C, C)
    single = np.diag(shared)
    best_pair = float((single[:, None] + single[None, :] - shared).max())
    assert budget["covered_area_m2"] <= best_pair + 1e-6 <= budget["upper_bound_area_m2"] + 2e-6


@pytest.mark.parametrize(("params", "says"), [
    ({"max_field_time_h": 2}, "needs a scanner"),
    ({"max_field_time_h": 2, "scanner": {"name": "no rate"}}, "measurement_rate_pts_s"),
    ({"max_field_time_h": 2, "scanner": CREW_SCANNER, "method": "optimal"}, "optimal"),
    ({"max_field_time_h": 0.01, "scanner": CREW_SCANNER}, "less than one station's setup"),
    ({"max_field_time_h": 0}, "in (0, 10000]"),
    ({"max_field_time_h": "8 h"}, "expected a number"),
])
def test_a_budget_of_hours_that_cannot_be_planned_names_the_parameter(
        params: dict[str, object], says: str) -> None:
    with pytest.raises(ParameterError, match="max_field_time_h") as error:
        PlanSpec.from_mapping(params)
    assert says in str(error.value)


def test_hours_that_hold_no_walk_from_the_start_say_so(unlimited: PlanResult) -> None:
    positions = unlimited.candidates.positions
    first = positions[unlimited.selections["greedy"].stations[0]]
    far = positions[int(np.argmax(np.linalg.norm(positions - first, axis=1)))]
    with pytest.raises(ParameterError, match=r"max_field_time_h.*route_start"):
        _hall(scanner=CREW_SCANNER, max_field_time_h=(60.0 + 38.2247 + 1.0) / 3600,
              route_start=far.tolist())


def test_the_previews_subtitle_names_the_budget() -> None:
    assert _budget_words(PlanSpec()) == ""
    assert _budget_words(PlanSpec(max_stations=20)) == "budget 20 stations, "
    assert _budget_words(PlanSpec(scanner=CREW_SCANNER, max_field_time_h=2.5)) == \
        "budget 2.5 h, "


@pytest.mark.parametrize("seed", range(20))
def test_the_longest_start_in_time_is_the_longest_that_fits(seed: int) -> None:
    """Orders of up to 40 stations whose walk grows with them (a route over more stations
    is no shorter): the search finds the longest start within the hours, as trying every
    start would, and says what the next would take."""
    rng = np.random.default_rng(seed)
    n, fixed = int(rng.integers(1, 40)), int(rng.integers(0, 3))
    fixed = min(fixed, n)
    order = Selection("greedy", tuple(range(n)), (1.0,) * n, tuple(range(1, n + 1)),
                      float(n), fixed)
    per_s = float(rng.uniform(60, 300))
    walk_s = np.concatenate(([0.0], np.cumsum(rng.uniform(0, 200, n))))  # (n + 1,)
    max_s = float(rng.uniform(per_s, per_s * n * 1.5))
    cap = int(rng.integers(1, n + 3))
    asked: list[int] = []

    def seconds_of(stations: list[int]) -> float:
        asked.append(len(stations))
        return per_s * len(stations) + float(walk_s[len(stations)])

    count, count_s, next_s = longest_prefix_in_time(order, max(cap, fixed), max_s,
                                                    seconds_of, per_s)
    top = min(max(cap, fixed), n)
    fitting = [k for k in range(fixed, top + 1) if per_s * k + walk_s[k] <= max_s]
    assert count == (max(fitting) if fitting else fixed)
    assert count_s == per_s * count + walk_s[count]
    if count < n:
        assert next_s == per_s * (count + 1) + walk_s[count + 1]
        assert count == top or next_s > max_s
    else:
        assert next_s is None
    assert asked[0] == top  # the largest start first: the walk network is made for it
