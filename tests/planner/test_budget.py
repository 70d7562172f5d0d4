"""A budget of stations (``max_stations``): the most coverage in that many stations, with a
bound no plan of that many stations can beat, checked against every pair on hall-small."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from planner.candidates.grid import read_candidates_csv
from planner.errors import ParameterError
from planner.io.readers import read_scene
from planner.outputs.report import plan_document
from planner.parameters import PlanSpec
from planner.pipeline import PlanResult, plan
from tests.data_files import HALL_SMALL


def _hall(**params: object) -> PlanResult:
    folder = HALL_SMALL
    scene = read_scene(folder / "hall.obj", max_edge_m=None)
    candidates = read_candidates_csv(folder / "candidates.csv").tolist()
    return plan(scene, PlanSpec.from_mapping({"candidates": candidates, "max_edge_m": None,
                                              **params}))


@pytest.fixture(scope="module")
def unlimited() -> PlanResult:
    return _hall(coverage_goal=1.0)


@pytest.mark.parametrize("method", ["greedy", "weighted_greedy"])
def test_a_budget_of_two_is_the_greedy_prefix_below_the_best_pair(
        unlimited: PlanResult, method: str) -> None:
    result = _hall(max_stations=2, coverage_goal=1.0, method=method)
    order = unlimited.selections[method]
    assert result.chosen.stations == order.stations[:2]
    document = plan_document(result)
    assert document["totals"]["stations"] == 2 and not document["goal_reached"]
    budget = document["selection"]["budget"]
    assert budget["max_stations"] == 2 and budget["stations"] == 2
    assert budget["covered_area_m2"] == pytest.approx(order.covered_area_m2[1], abs=1e-3)
    assert budget["next_station_gain_m2"] == pytest.approx(order.new_area_m2[2], abs=1e-3)
    assert 1 <= budget["goal_needs_at_least"] <= order.count_for_goal(1.0)
    # every pair of candidates: what the best two stations cover (area of A + B - both)
    table = result.table
    cover = table.by_candidate.astype(bool).astype(np.float64)  # (C, F)
    shared = (cover @ sp.diags(table.face_area_m2) @ cover.T).toarray()  # (C, C)
    single = np.diag(shared)
    best_pair = float((single[:, None] + single[None, :] - shared).max())
    assert budget["covered_area_m2"] <= best_pair + 1e-6
    assert best_pair <= budget["upper_bound_area_m2"] + 1e-6
    if method == "greedy":  # greedy's guarantee: at least 1 - 1/e of the best pair
        assert budget["covered_area_m2"] >= (1 - 1 / np.e) * best_pair - 1e-6


def test_a_budget_above_what_the_goal_needs_adds_coverage(unlimited: PlanResult) -> None:
    at_goal = _hall()  # 80 %: two stations
    more = _hall(max_stations=4)
    assert len(at_goal.chosen.stations) < 4 == len(more.chosen.stations)
    assert more.chosen.stations == unlimited.selections["greedy"].stations[:4]
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
