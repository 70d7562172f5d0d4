"""The neighbourhood search: it finds the replacements the local search cannot (three
stations by two), every plan it gives reaches the goal, and the same plan comes twice."""

from __future__ import annotations

import time

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.selection.greedy import GOAL_SLACK_M2, greedy, replay
from planner.selection.highs_worker import HighsProcess
from planner.selection.neighbourhoods import SearchResult, neighbourhood_search
from planner.selection.optimal import local_search
from planner.visibility.coverage import CoverageTable
from tests.property.test_optimal_exact import fewest_by_enumeration, instance, table_of


def search(table: CoverageTable, stations: list[int], goal: float) -> SearchResult:
    need = goal * table.max_achievable_area_m2 - GOAL_SLACK_M2
    # the faces along a line: faces of neighbouring numbers are neighbours
    xyz = np.stack([np.arange(table.n_faces, dtype=np.float64),
                    np.zeros(table.n_faces), np.zeros(table.n_faces)], axis=1)
    with HighsProcess() as highs:
        return neighbourhood_search(
            table, xyz, stations, need, 0,
            lambda program: highs.solve(program, time.monotonic() + 60), full=goal >= 1.0)


def test_three_stations_replaced_by_two() -> None:
    # six faces of 1 m^2; the plan's stations see two each, two other candidates three each
    table = table_of([[0, 1], [2, 3], [4, 5], [0, 1, 2], [3, 4, 5]], [1.0] * 6)
    need = table.max_achievable_area_m2 - GOAL_SLACK_M2
    stuck, moves = local_search(table, [0, 1, 2], need, 0, time.monotonic() + 60,
                                swaps=False)
    assert stuck == [0, 1, 2] and moves == []  # no station is redundant, no two are one
    result = search(table, [0, 1, 2], 1.0)
    assert sorted(result.stations) == [3, 4]
    assert result.moves == [((0, 1, 2), (3, 4))]
    assert not result.stopped


def test_a_partial_goal_trades_a_station_for_area_elsewhere() -> None:
    # goal 4 of 6 m^2: the plan covers faces 0-3 with three stations; one candidate sees
    # four other square metres of faces 2-5
    table = table_of([[0], [1, 2], [3], [2, 3, 4, 5]], [1.0] * 6)
    result = search(table, [0, 1, 2], 4 / 6)
    assert result.stations == [3]
    assert replay(table, result.stations, "optimal").covered_area_m2[-1] >= 4 - 1e-9


@settings(max_examples=10, deadline=None)
@given(instance=instance, goal=st.sampled_from([0.5, 0.8, 1.0]))
def test_every_plan_reaches_the_goal_and_comes_twice(
        instance: tuple[list[list[int]], list[float]], goal: float) -> None:
    table = table_of(*instance)
    heuristic = greedy(table)
    start = list(heuristic.stations[:heuristic.count_for_goal(goal)])
    first, again = search(table, start, goal), search(table, start, goal)
    assert first.stations == again.stations and first.moves == again.moves
    need = goal * table.max_achievable_area_m2 - GOAL_SLACK_M2
    assert replay(table, first.stations, "optimal").covered_area_m2[-1] >= need
    assert fewest_by_enumeration(table, goal, ()) <= len(first.stations) <= len(start)
    # the moves lead from the start to the plan
    plan = set(start)
    for removed, added in first.moves:
        assert set(removed) <= plan and not set(added) & plan
        plan = (plan - set(removed)) | set(added)
    assert plan == set(first.stations)
    assert all(len(a) <= len(r) for r, a in first.moves)
