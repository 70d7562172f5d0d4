"""The halls of shared/scenes against the independent brute-force results (expected.json)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from planner.candidates.grid import read_candidates_csv
from planner.io.readers import read_scene
from planner.parameters import PlanSpec
from planner.pipeline import PlanResult, plan
from planner.selection.curve import GOALS


def run_hall(scenes_dir: Path, name: str, *, exact_rays: bool = True
             ) -> tuple[PlanResult, dict]:
    folder = scenes_dir / name
    scene = read_scene(folder / "hall.obj", max_edge_m=None)
    candidates = read_candidates_csv(folder / "candidates.csv")
    spec = PlanSpec(candidates=tuple(map(tuple, candidates.tolist())), max_edge_m=None,
                    exact_rays=exact_rays)
    expected = json.loads((folder / "expected.json").read_text())
    return plan(scene, spec), expected


# with exact rays every ray is decided as the brute-force reference decides it: the whole
# curve is the reference's
@pytest.fixture(scope="module", params=["hall-small", "hall-full"])
def hall(request: pytest.FixtureRequest, scenes_dir: Path) -> tuple[PlanResult, dict]:
    return run_hall(scenes_dir, request.param)


@pytest.fixture(scope="module", params=["hall-small", "hall-full"])
def hall_at_defaults(request: pytest.FixtureRequest, scenes_dir: Path
                     ) -> tuple[PlanResult, dict]:
    return run_hall(scenes_dir, request.param, exact_rays=False)


@pytest.mark.parametrize("method", ["greedy", "weighted_greedy"])
def test_defaults_keep_the_paper_s_stations(hall_at_defaults: tuple[PlanResult, dict],
                                             method: str) -> None:
    """One cast a ray (the default) keeps the reference's stations at the paper's goal,
    80 %, and its curve below 100 %. At 100 % the last faces are often seen by one grazing
    ray: there the curve may differ by a station (hall-small: 37 and 32 against the
    reference's 36 and 31)."""
    result, expected = hall_at_defaults
    assert list(result.selections[method].truncated(0.8).stations) == \
        expected["goal_0.8"][method]["stations"]
    curve = [result.selections[method].count_for_goal(goal) for goal in GOALS]
    reference = expected["coverage_curve"][method]
    assert curve[:-1] == reference[:-1]
    assert abs(curve[-1] - reference[-1]) <= 1
    assert result.table.n_pairs == pytest.approx(expected["qualified_pairs"], rel=1e-4)


def test_totals_match(hall: tuple[PlanResult, dict]) -> None:
    result, expected = hall
    assert result.scene.n_faces == expected["faces"]
    assert len(result.candidates) == expected["candidates"]
    assert result.scene.areas.sum() == pytest.approx(expected["total_area_m2"], abs=1e-3)
    assert result.table.max_achievable_area_m2 == pytest.approx(
        expected["max_achievable_area_m2"], rel=1e-3)
    assert result.table.n_pairs == pytest.approx(expected["qualified_pairs"], rel=1e-4)


@pytest.mark.parametrize("method", ["greedy", "weighted_greedy"])
def test_stations_in_order_at_80_percent(hall: tuple[PlanResult, dict], method: str) -> None:
    result, expected = hall
    plan_at_goal = result.selections[method].truncated(0.8)
    assert list(plan_at_goal.stations) == expected["goal_0.8"][method]["stations"]
    np.testing.assert_allclose(plan_at_goal.covered_area_m2,
                               expected["goal_0.8"][method]["covered_area_m2"], atol=2e-3)


@pytest.mark.parametrize("method", ["greedy", "weighted_greedy"])
def test_coverage_curve(hall: tuple[PlanResult, dict], method: str) -> None:
    result, expected = hall
    assert list(GOALS) == expected["coverage_curve"]["goals"]
    curve = [result.selections[method].count_for_goal(goal) for goal in GOALS]
    assert curve == expected["coverage_curve"][method]


def test_plan_is_the_greedy_prefix(hall: tuple[PlanResult, dict]) -> None:
    result, expected = hall
    assert list(result.chosen.stations) == expected["goal_0.8"]["greedy"]["stations"]
    faces = result.faces
    covered_area = result.scene.areas[faces["covered"]].sum()
    assert covered_area == pytest.approx(result.chosen.covered_area_m2[-1], rel=1e-9)
    assert (faces["n_stations"][faces["covered"]] >= 1).all()
    assert (faces["first_station"][~faces["covered"]] == -1).all()
    assert (faces["best_lpd_pts_m2"][faces["covered"]] >= 45_000 * (1 - 1e-6)).all()
