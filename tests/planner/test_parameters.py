"""Parameter validation: every message names the parameter and the fix."""

from __future__ import annotations

import pytest

from planner.errors import ParameterError
from planner.parameters import GroupRequirement, PlanSpec


def test_defaults_are_the_papers_table_2() -> None:
    spec = PlanSpec()
    assert (spec.dof_min_m, spec.dof_max_m) == (1.5, 50.0)
    assert spec.angular_step_rad == pytest.approx(0.001)
    assert (spec.elevation_min_deg, spec.elevation_max_deg) == (-60.0, 90.0)
    assert (spec.min_incidence_deg, spec.min_density_pts_m2, spec.coverage_goal) == (
        15.0, 45_000.0, 0.8)
    assert spec.method == "greedy"
    assert spec.max_edge_m == 0.2


@pytest.mark.parametrize(
    ("values", "parameter"),
    [
        ({"dof_min_m": -1}, "dof_min_m"),
        ({"dof_min_m": 60}, "dof_min_m"),
        ({"coverage_goal": 0}, "coverage_goal"),
        ({"coverage_goal": 1.2}, "coverage_goal"),
        ({"method": "random"}, "method"),
        ({"min_density_pts_m2": "lots"}, "min_density_pts_m2"),
        ({"max_edge_m": 0}, "max_edge_m"),
        ({"elevation_min_deg": 10, "elevation_max_deg": 5}, "elevation_min_deg"),
        ({"candidates": [[1, 2]]}, "candidates"),
        ({"candidates": []}, "candidates"),
        ({"grid_spacing_m": float("nan")}, "grid_spacing_m"),
        ({"colour": "red"}, "colour"),
        ({"group_requirements": {"pipes": {"density": 1}}}, "group_requirements.pipes.density"),
        ({"group_requirements": {"glass": {"occludes": "no"}}},
         "group_requirements.glass.occludes"),
    ],
)
def test_bad_values_name_the_parameter(values: dict, parameter: str) -> None:
    with pytest.raises(ParameterError) as info:
        PlanSpec.from_mapping(values)
    assert info.value.parameter == parameter
    assert str(info.value).startswith(f"{parameter}: ")


def test_round_trip_through_plain_data() -> None:
    spec = PlanSpec.from_mapping({
        "method": "weighted_greedy",
        "max_edge_m": None,
        "candidates": [[0, 0, 1.5], [1, 0, 1.5]],
        "group_requirements": {"glass": {"occludes": False, "target": False}},
    })
    assert spec.group_requirements["glass"] == GroupRequirement(occludes=False, target=False)
    again = PlanSpec.from_mapping(spec.to_dict())
    assert again == spec
