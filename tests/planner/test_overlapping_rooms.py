"""IfcSpaces that overlap: every room accounted for with what stands on its floor.

A tool may write a room more than once (one IfcSpace per area scheme: gross, lettable and
usable floor area, as Revit's area plans and the Dutch NEN 2580 BVO/VVO/GO do), a hall
and a section of it, or a copy left behind. A generated hall of 12 x 6 m has five
IfcSpaces, all on its one floor (a 0.5 m grid):

- 1 "Hall": x 0.2 to 8.0;
- 2 "Stage": x 6.0 to 10.0, partly on the hall (its 2 m beside x 7);
- 3 "Hall" again, the same outline as 1;
- 4 "Hall west": x 0.2 to 4.0, inside the hall;
- 5 "Duct": x 10.0 to 10.3, the stage's neighbour: its only grid points lie on the wall
  line it shares with the stage.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.candidates.rooms import rooms_lines, space_overlaps
from planner.io.readers import read_scene
from planner.outputs.report import plan_document
from planner.parameters import PlanSpec
from planner.pipeline import plan
from tests.planner.ifc_parts import body_and_building, placed, room_shell

ifcopenshell = pytest.importorskip("ifcopenshell")

Y0, Y1 = 0.2, 5.8
SPACES = [("1", "Hall", 0.2, 8.0), ("2", "Stage", 6.0, 10.0), ("3", "Hall", 0.2, 8.0),
          ("4", "Hall west", 0.2, 4.0), ("5", "Duct", 10.0, 10.3)]


def _overlapping_hall(path: Path) -> None:
    """The hall of the module docstring: floor, ceiling, four walls and five IfcSpaces."""
    from ifcopenshell.api import aggregate, geometry, project, root, unit

    model = project.create_file(version="IFC4")
    ifc_project = root.create_entity(model, ifc_class="IfcProject", name="overlapping")
    unit.assign_unit(model, units=[unit.add_si_unit(model, unit_type="LENGTHUNIT")])
    body, building = body_and_building(model, ifc_project)
    storey = root.create_entity(model, ifc_class="IfcBuildingStorey", name="Level 1")
    aggregate.assign_object(model, relating_object=building, products=[storey])
    room_shell(model, body, storey, 12.0, 6.0, 0.0, 3.0)
    for name, long_name, x0, x1 in SPACES:
        space = placed(model, "IfcSpace", name, geometry.add_slab_representation(
            model, body, depth=3.0, polyline=[(x0, Y0), (x1, Y0), (x1, Y1), (x0, Y1)]),
            (0, 0, 0.0))
        space.LongName = long_name
        aggregate.assign_object(model, relating_object=storey, products=[space])
    model.write(str(path))


@pytest.fixture(scope="module")
def hall(tmp_path_factory: pytest.TempPathFactory) -> Any:
    path = tmp_path_factory.mktemp("overlapping") / "hall.ifc"
    _overlapping_hall(path)
    return read_scene(path, max_edge_m=None)


@pytest.fixture(scope="module")
def planned(hall: Any) -> tuple[Any, dict[str, Any]]:
    result = plan(hall, PlanSpec(max_edge_m=None, clearance_m=0.1))
    return result, plan_document(result)


def _by_name(document: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {room["room_name"]: room for room in document["candidates"]["rooms"]}


def _grid(x0: float, x1: float) -> set[tuple[float, float]]:
    """The 0.5 m grid points on a room's floor, boundary included."""
    xs = [x for x in np.arange(0.0, 12.01, 0.5) if x0 - 1e-9 <= x <= x1 + 1e-9]
    ys = [y for y in np.arange(0.0, 6.01, 0.5) if Y0 - 1e-9 <= y <= Y1 + 1e-9]
    return {(round(float(x), 3), round(float(y), 3)) for x in xs for y in ys}


def test_each_overlap_names_the_earlier_room_and_the_floor_they_share(
        planned: tuple[Any, dict[str, Any]]) -> None:
    result, document = planned
    rooms = _by_name(document)
    ids = {space["name"]: space["global_id"] for space in result.scene.metadata["spaces"]}
    assert "overlaps" not in rooms["1"] and "overlaps" not in rooms["5"]  # the duct touches
    (stage,) = rooms["2"]["overlaps"]
    assert stage == {"room": "Hall", "room_name": "1", "room_global_id": ids["1"],
                     "shared_m2": 11.2, "share": 0.5, "relation": "partial"}
    copy = rooms["3"]["overlaps"]
    assert [(o["room_name"], o["relation"], o["share"]) for o in copy] == [
        ("1", "same", 1.0), ("2", "partial", pytest.approx(11.2 / 43.68, abs=1e-3))]
    assert [(o["room_name"], o["relation"], o["shared_m2"]) for o in rooms["4"]["overlaps"]] \
        == [("1", "inside", 21.28), ("3", "inside", 21.28)]


def test_a_room_inside_or_over_another_counts_what_stands_on_its_floor(
        planned: tuple[Any, dict[str, Any]]) -> None:
    """A copy and a section of the hall are not empty rooms: each counts the grid points,
    candidates and stations on its floor, which the hall, listed first, holds too; the
    storey's line counts each candidate and station once."""
    result, document = planned
    rooms = _by_name(document)
    positions = result.candidates.positions
    for name, _, x0, x1 in SPACES[:4]:
        room = rooms[name]
        assert "reason" not in room, room
        assert room["grid_points"] == len(_grid(x0, x1)), name
        standing = (positions[:, 0] >= x0 - 1e-6) & (positions[:, 0] <= x1 + 1e-6)
        assert room["candidates"] == int(standing.sum()), name
        assert room["grid_points"] == room["candidates"] + sum(
            room.get("left_out", {}).values())
        in_room = [s for s in document["stations"] if x0 - 1e-6 <= s["position"][0] <= x1 + 1e-6]
        assert room["stations"] == len(in_room), name
    # the copy shares all of its floor with the hall, the section too; the stage its west
    assert rooms["3"]["shared"] == {key: rooms["3"][key]
                                    for key in ("grid_points", "candidates", "stations")}
    assert rooms["3"]["candidates"] == rooms["1"]["candidates"]
    assert rooms["4"]["shared"]["grid_points"] == rooms["4"]["grid_points"]
    assert rooms["2"]["shared"]["grid_points"] == len(_grid(6.0, 8.0))
    # the candidates keep the first room's label, and each is counted once per storey
    assert {label["room_name"] for label in result.candidates.labels} == {"1", "2"}
    own = [r["candidates"] - r.get("shared", {}).get("candidates", 0)
           for r in rooms.values()]
    assert sum(own) == len(positions) == document["candidates"]["count"]
    own_stations = [r["stations"] - r.get("shared", {}).get("stations", 0)
                    for r in rooms.values()]
    assert sum(own_stations) == len(document["stations"])
    (line,) = rooms_lines(document["candidates"]["rooms"])
    stations = len(document["stations"])
    with_station = sum(1 for r in rooms.values() if r["stations"])
    assert with_station >= 2  # the hall's station stands in its copy too
    assert line == (
        f"Level 1 (+0.00 m): 4 of 5 rooms with candidates, {len(positions)} candidates, "
        f"{stations} station{'s' if stations > 1 else ''} in {with_station} rooms; "
        "3 rooms overlap "
        "rooms listed before them (the candidates and stations they share counted once); "
        "none in Duct (no grid point)")


def test_at_two_heights_the_shared_points_add_up_too(
        hall: Any, planned: tuple[Any, dict[str, Any]]) -> None:
    """Candidates at two instrument heights: each room counts both, its shared ones too,
    and the storey still counts each candidate and station once."""
    document = plan_document(plan(hall, PlanSpec(max_edge_m=None, clearance_m=0.1,
                                                 scanner_heights_m=(1.2, 1.5))))
    once = _by_name(planned[1])
    rooms = _by_name(document)
    for name in once:
        assert rooms[name]["grid_points"] == 2 * once[name]["grid_points"], name
        if "shared" in once[name]:
            assert rooms[name]["shared"]["grid_points"] == \
                2 * once[name]["shared"]["grid_points"], name
    assert sum(r["candidates"] - r.get("shared", {}).get("candidates", 0)
               for r in rooms.values()) == document["candidates"]["count"]
    assert sum(r["stations"] - r.get("shared", {}).get("stations", 0)
               for r in rooms.values()) == len(document["stations"])


def test_a_neighbour_whose_points_lie_on_the_shared_wall_line_says_so(
        planned: tuple[Any, dict[str, Any]]) -> None:
    result, document = planned
    duct = _by_name(document)["5"]
    stage = next(s for s in result.scene.metadata["spaces"] if s["name"] == "2")
    assert duct["grid_points"] == duct["candidates"] == duct["stations"] == 0
    assert duct["reason"] == (
        f"no grid point: its {len(_grid(10.0, 10.0))} grid point(s) lie on the wall line it "
        f"shares with Stage 2 ({stage['global_id']}), listed before it, which holds them")


def test_slivers_and_stacked_rooms_are_no_overlap() -> None:
    """Neighbours whose outlines overlap by a wall line drawn twice (2 cm) or that stand
    on different storeys do not overlap; an outline drawn 2 cm further out is the same
    floor."""
    def space(gid: str, x0: float, x1: float, z: float = 0.0) -> dict[str, Any]:
        return {"global_id": gid, "name": gid, "long_name": "", "floor_z_m": z,
                "polygon": [[x0, 0.0], [x1, 0.0], [x1, 4.0], [x0, 4.0]], "holes": []}

    overlaps = space_overlaps([
        space("a", 0.0, 4.0), space("b", 3.98, 8.0), space("c", 0.0, 4.0, z=3.0),
        space("d", -0.02, 4.02), space("e", 1.0, 2.0, z=0.2)])
    assert set(overlaps) == {"d", "e"}
    assert [(o["room_global_id"], o["relation"]) for o in overlaps["d"]] == [("a", "same")]
    assert [(o["room_global_id"], o["relation"]) for o in overlaps["e"]] == [
        ("a", "inside"), ("d", "inside")]
