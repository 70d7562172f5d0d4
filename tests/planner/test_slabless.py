"""An architect's model without its structural slabs (:mod:`tests.planner.slabless_office`):
the rooms are the floor, the walls stop a hand's breadth under each storey, the stair ends
a riser under the floor above. Planned with default parameters, as a BIM platform sends
it, and checked as a surveyor checks the plan: every station on the route, each on its
room's floor, no leg through a wall, and no walk along a wall's top."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.io.readers import read_scene
from planner.outputs.report import plan_document
from planner.parameters import PlanSpec
from planner.pipeline import plan
from planner.truth.legs import legs_in_plan, legs_through_walls
from planner.walkgraph import KNEE_HEIGHT_M, door_faces
from tests.planner.buildings import RISER_M, STOREY_M
from tests.planner.slabless_office import slabless_office_ifc

WALL_GAP_M = 0.1  # the walls stop this far under the next storey


@pytest.fixture(scope="module")
def planned(tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, dict[str, Any]]:
    path = slabless_office_ifc(tmp_path_factory.mktemp("slabless") / "office.ifc",
                               floors=2, rooms_per_side=3, wall_gap_m=WALL_GAP_M)
    spec = PlanSpec()
    scene = read_scene(path, max_edge_m=spec.max_edge_m, split_faces="as_needed")
    result = plan(scene, spec)
    return result, plan_document(result)


def test_every_station_is_on_the_route_through_the_doors(planned: tuple[Any, dict[str, Any]]
                                                         ) -> None:
    result, document = planned
    route = document["route"]
    stations = document["stations"]
    assert {s["label"]["storey"] for s in stations} == {"Level 0", "Level 1"}
    assert route["unreachable"] == [], route["unreachable_reasons"]
    assert "steps_between_parts" not in route, route["steps_between_parts"]
    assert sorted(route["visits"]) == list(range(1, len(stations) + 1))
    scene = result.scene
    legs = legs_in_plan(scene, route)
    assert legs_through_walls(scene, door_faces(scene), legs) == []


def test_each_station_stands_on_its_rooms_floor(planned: tuple[Any, dict[str, Any]]) -> None:
    result, document = planned
    floor_of = {s["global_id"]: s["floor_z_m"] for s in result.scene.metadata["spaces"]}
    height = PlanSpec().scanner_height_m
    for station in document["stations"]:
        room = station["label"]["room_global_id"]
        assert station["position"][2] - height == pytest.approx(floor_of[room], abs=0.01)
    assert document["candidates"]["floor_from_space"]  # every room stands on its space


def test_the_walk_is_on_floors_and_treads_never_on_a_walls_top(
        planned: tuple[Any, dict[str, Any]]) -> None:
    """Every point of the route's paths lies over a storey's floor or a stair's tread
    (a riser's multiple above a storey): none at the walls' tops, a hand's breadth under
    the floor above."""
    _, document = planned
    points = np.array([p for leg in document["route"]["legs"] for p in leg["path"]])
    floor_z = points[:, 2] - KNEE_HEIGHT_M
    risers = (floor_z % STOREY_M) / RISER_M
    assert np.allclose(risers, np.round(risers), atol=0.05), sorted(set(floor_z.round(2)))
    wall_tops = np.abs(floor_z - (STOREY_M - WALL_GAP_M)) < 0.02
    assert not wall_tops.any()
    # the crew climbs: the walk reaches the upper storey's floor from the stair's last tread
    assert floor_z.max() == pytest.approx(STOREY_M, abs=0.01)
    assert (np.abs(floor_z - (STOREY_M - RISER_M)) < 0.01).any()


def test_a_model_without_slabs_or_rooms_is_told_what_is_missing(scenes_dir: Path,
                                                                tmp_path: Path) -> None:
    """IfcOpenHouse without its slabs: no rooms and no floor. The error says so, and what
    to send; not to lower the clearance or the grid spacing."""
    import ifcopenshell

    from planner.errors import NoCandidatesError

    model = ifcopenshell.open(str(scenes_dir / "IfcOpenHouse_IFC4.ifc"))
    for slab in model.by_type("IfcSlab"):
        model.remove(slab)
    model.write(str(tmp_path / "bare.ifc"))
    spec = PlanSpec()
    scene = read_scene(tmp_path / "bare.ifc", max_edge_m=spec.max_edge_m)
    with pytest.raises(NoCandidatesError) as raised:
        plan(scene, spec)
    assert "most of the building's points have no floor under them. A model without its " \
        "floor slabs" in str(raised.value)
    assert "lower clearance_m" not in str(raised.value)
