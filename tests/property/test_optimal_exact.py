"""Property: on small random coverage tables the optimal method finds the true minimum,
as enumerating every subset of stations finds it, and proves it."""

from __future__ import annotations

import itertools

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.sparse.csgraph import breadth_first_order

from planner.selection.connectivity import OverlapGraph
from planner.selection.greedy import GAIN_QUANTUM_M2, GOAL_SLACK_M2, greedy, replay
from planner.selection.optimal import solve_optimal
from planner.visibility.coverage import CoverageTable, QualifiedPairs


def table_of(sets: list[list[int]], areas: list[float]) -> CoverageTable:
    candidate = np.array([c for c, faces in enumerate(sets) for _ in faces], np.int32)
    face = np.array([f for faces in sets for f in sorted(faces)], np.int32)
    pairs = QualifiedPairs(candidate, face, np.full(len(face), 50_000, np.float32))
    return CoverageTable.from_pairs(pairs, len(sets), np.asarray(areas, np.float64))


def fewest_by_enumeration(table: CoverageTable, goal: float, fixed: tuple[int, ...]) -> int:
    need = goal * table.max_achievable_area_m2 - GOAL_SLACK_M2
    free = [c for c in range(table.n_candidates) if c not in fixed]
    for size in range(len(free) + 1):
        for subset in itertools.combinations(free, size):
            faces = np.zeros(table.n_faces, bool)
            for c in (*fixed, *subset):
                faces[table.faces_of(c)] = True
            if table.face_area_m2[faces].sum() >= need:
                return len(fixed) + size
    raise AssertionError("every candidate together reaches every goal")


# small sets over many faces: the area bound is loose and the MILP has to work
instance = st.integers(min_value=6, max_value=14).flatmap(lambda n_faces: st.tuples(
    st.lists(st.lists(st.integers(0, n_faces - 1), min_size=1, max_size=max(2, n_faces // 3),
                      unique=True),
             min_size=4, max_size=9),
    st.lists(st.sampled_from([0.5, 1.0, 2.0, 3.0]), min_size=n_faces, max_size=n_faces),
))


@settings(max_examples=12, deadline=None)
@given(instance=instance, goal=st.sampled_from([0.5, 0.8, 0.95, 1.0]),
       n_fixed=st.integers(0, 1))
def test_optimal_equals_enumeration(instance: tuple[list[list[int]], list[float]],
                                    goal: float, n_fixed: int) -> None:
    sets, areas = instance
    table = table_of(sets, areas)
    fixed = tuple(range(n_fixed))
    heuristics = [greedy(table, fixed=fixed), greedy(table, weighted=True, fixed=fixed)]
    result = solve_optimal(table, goal, 20, heuristics, lambda faces: np.zeros((len(faces), 3)),
                           fixed=fixed)
    fewest = fewest_by_enumeration(table, goal, fixed)
    assert len(result.selection.stations) == fewest
    assert result.proven_optimal and result.lower_bound == fewest
    assert result.selection.stations[:n_fixed] == fixed


def fewest_connected_by_enumeration(table: CoverageTable, goal: float,
                                    graph: OverlapGraph) -> int:
    need = goal * table.max_achievable_area_m2 - GOAL_SLACK_M2
    for size in range(1, table.n_candidates + 1):
        for subset in itertools.combinations(range(table.n_candidates), size):
            faces = np.zeros(table.n_faces, bool)
            for c in subset:
                faces[table.faces_of(c)] = True
            if table.face_area_m2[faces].sum() >= need and graph.connected(subset):
                return size
    raise AssertionError("every candidate together is connected and reaches every goal")


# a connected overlap graph: a random spanning tree (parent of c among 0..c-1) plus extra edges
@settings(max_examples=12, deadline=None)
@given(instance=instance, goal=st.sampled_from([0.5, 0.8, 0.95, 1.0]), data=st.data())
def test_connected_optimal_equals_enumeration(instance: tuple[list[list[int]], list[float]],
                                              goal: float, data: st.DataObject) -> None:
    sets, areas = instance
    table = table_of(sets, areas)
    n = table.n_candidates
    tree = [(data.draw(st.integers(0, c - 1)), c) for c in range(1, n)]
    pairs = list(itertools.combinations(range(n), 2))
    extra = data.draw(st.lists(st.sampled_from(pairs), max_size=n))
    graph = OverlapGraph(n, np.array(sorted(set(tree) | set(extra)), np.int64).reshape(-1, 2))
    # breadth-first from candidate 0: every prefix of the order is connected
    order = [int(c) for c in breadth_first_order(graph.adjacency, 0, directed=False,
                                                 return_predecessors=False)]
    incumbent = replay(table, order, "greedy")
    result = solve_optimal(table, goal, 20, [incumbent], lambda faces: np.zeros((len(faces), 3)),
                           graph=graph)
    fewest = fewest_connected_by_enumeration(table, goal, graph)
    assert graph.connected(result.selection.stations)
    assert len(result.selection.stations) == fewest
    assert result.proven_optimal and result.lower_bound == fewest


@settings(max_examples=40, deadline=None)
@given(instance=instance, n_fixed=st.integers(0, 2), weighted=st.booleans())
def test_greedy_takes_the_largest_gain_each_time(instance: tuple[list[list[int]], list[float]],
                                                 n_fixed: int, weighted: bool) -> None:
    # the rule users read in the method: the given stations first, then every time the
    # candidate that adds the most still-uncovered area (weighted: area over how many
    # candidates see the face; each face's in whole units of GAIN_QUANTUM_M2, so ties are
    # exact), ties to the lowest index, until nothing more is added; each station's added
    # area and the running total as they are summed
    sets, areas = instance
    # ties on purpose: a copy of the first candidate's set
    table = table_of([*sets, sets[0]], areas)
    fixed = tuple(range(n_fixed))
    plan = greedy(table, weighted=weighted, fixed=fixed)
    area = table.face_area_m2
    seen_by = np.zeros(table.n_faces)
    for c in range(table.n_candidates):
        seen_by[table.faces_of(c)] += 1
    weight = np.divide(area, seen_by, out=np.zeros_like(area), where=seen_by > 0) \
        if weighted else area
    units = np.round(weight / GAIN_QUANTUM_M2)
    uncovered = np.ones(table.n_faces, bool)
    expected: list[int] = list(fixed)
    for c in fixed:
        uncovered[table.faces_of(c)] = False
    while True:
        gains = [float(units[f][uncovered[f]].sum())
                 for f in (table.faces_of(c) for c in range(table.n_candidates))]
        best = int(np.argmax(gains))  # the first of the largest
        if gains[best] <= 0:
            break
        expected.append(best)
        uncovered[table.faces_of(best)] = False
    assert list(plan.stations) == expected
    total = 0.0
    covered = np.zeros(table.n_faces, bool)
    for station, added, running in zip(plan.stations, plan.new_area_m2, plan.covered_area_m2,
                                       strict=True):
        faces = table.faces_of(station)
        fresh = faces[~covered[faces]]
        covered[fresh] = True
        total += float(area[fresh].sum())
        assert added == float(area[fresh].sum())
        assert running == total
