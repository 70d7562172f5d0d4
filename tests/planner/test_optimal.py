"""The optimal method: never worse than greedy, better where greedy is fooled, honest bounds."""

from __future__ import annotations

import numpy as np
import pytest

import planner.optimal as optimal
from planner.coverage import CoverageTable, QualifiedPairs
from planner.selection import greedy


def table_of(sets: list[list[int]], n_faces: int) -> CoverageTable:
    candidate = np.array([c for c, faces in enumerate(sets) for _ in faces], np.int32)
    face = np.array([f for faces in sets for f in sorted(faces)], np.int32)
    pairs = QualifiedPairs(candidate, face, np.full(len(face), 50_000, np.float32))
    return CoverageTable.from_pairs(pairs, len(sets), np.ones(n_faces))


# greedy takes A (4 faces) first and then needs B and C; B and C alone cover everything
FOOLS_GREEDY = [[0, 1, 3, 4], [0, 1, 2], [3, 4, 5]]


def test_optimal_beats_greedy_where_greedy_is_fooled() -> None:
    table = table_of(FOOLS_GREEDY, 6)
    by_greedy = greedy(table)
    assert by_greedy.stations == (0, 1, 2)
    result = optimal.solve_optimal(table, 1.0, 10, incumbent=by_greedy,
                                   centroids=np.zeros((6, 3)))
    assert sorted(result.selection.stations) == [1, 2]
    assert result.proven_optimal and result.lower_bound == 2 and result.gap == 0
    assert result.selection.covered_area_m2[-1] == pytest.approx(6.0)


def test_a_relaxed_program_keeps_its_promises(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(7)
    n_faces = 300
    sets = [sorted(rng.choice(n_faces, size=rng.integers(20, 90), replace=False).tolist())
            for _ in range(25)]
    table = table_of(sets, n_faces)
    centroids = rng.uniform(0, 10, size=(n_faces, 3))
    monkeypatch.setattr(optimal, "MAX_NONZEROS", 200)  # force the voxel relaxation
    cover, _, exact = optimal.relaxed_classes(table, centroids, optimal.MAX_NONZEROS)
    assert not exact and cover.nnz <= 200
    by_greedy = greedy(table)
    for goal in (0.6, 0.9):
        result = optimal.solve_optimal(table, goal, 10, incumbent=by_greedy,
                                       centroids=centroids)
        stations = result.selection.stations
        assert len(stations) <= by_greedy.count_for_goal(goal)
        assert result.lower_bound <= len(stations)
        assert result.selection.covered_area_m2[-1] >= goal * table.max_achievable_area_m2 - 1e-9
