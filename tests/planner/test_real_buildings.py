"""The real IFC buildings in ``shared/scenes/buildings`` (see its README), planned as a new
user plans them, and checked as a surveyor checks a plan: every storey with rooms has
stations, every room is accounted for, the route reaches the stations, and what could not
be read is named in ``scene.warnings``.

The plans use a 1 m grid and 0.5 m faces so that each building takes seconds to tens of
seconds on two cores; reading the files with IfcOpenShell is most of it.
"""

from __future__ import annotations

import dataclasses
import functools
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.candidates.rooms import line_name, rooms_lines
from planner.io.readers import read_scene
from planner.outputs.report import plan_document
from planner.parameters import PlanSpec
from planner.pipeline import plan

ifcopenshell = pytest.importorskip("ifcopenshell")

SPEC = PlanSpec(grid_spacing_m=1.0, max_edge_m=0.5)


def buildings_dir(scenes_dir: Path) -> Path:
    folder = scenes_dir / "buildings"
    if not folder.is_dir():
        pytest.skip(f"the shared buildings are not beside the checkout ({folder})")
    return folder


@functools.cache
def planned(path: Path, route_start: tuple[float, float, float] | None = None
            ) -> dict[str, Any]:
    """plan.json of ``path`` planned with ``SPEC`` (from ``route_start`` when given), as the
    command line would write it
    (once a session: several tests check the same plan), and under the test's own key
    ``legs_through_walls`` the route's legs through walls
    (:func:`planner.truth.legs.legs_through_walls`, against the plan's scene; the doors are
    an IFC model's own, or for a plain mesh the mask saved beside it as ``.doors.npy``:
    the IFC's doorways for a plain mesh, its doors and windows to the floor
    (:func:`tests.planner.buildings.plain_mesh_doorways`), in the export's face order); with
    a mask of the IFC's doors alone beside it (``.ifcdoors.npy``), under
    ``legs_through_non_doors`` the legs through anything else (a French window)."""
    from planner.truth.legs import legs_in_plan, legs_through_walls
    from planner.walkgraph import door_faces

    spec = dataclasses.replace(SPEC, route_start=route_start)
    scene = read_scene(path, max_edge_m=spec.max_edge_m, split_faces="as_needed")
    result = plan(scene, spec)
    document: dict[str, Any] = plan_document(result)
    scene = result.scene
    mask = path.with_suffix(".doors.npy")
    door = scene.of_file_faces(np.load(mask)) if mask.exists() else door_faces(scene)
    legs = legs_in_plan(scene, document["route"])
    document["legs_through_walls"] = [leg.to_dict()
                                      for leg in legs_through_walls(scene, door, legs)]
    ifc_doors = path.with_suffix(".ifcdoors.npy")
    if ifc_doors.exists():  # a plain mesh: the legs through anything but an IfcDoor too
        document["legs_through_non_doors"] = [
            leg.to_dict() for leg in legs_through_walls(
                scene, scene.of_file_faces(np.load(ifc_doors)), legs)]
    return document


# Renga: '*' where '$' belongs, millimetres --------------------------------------------------


def test_the_renga_house_is_read_despite_its_stars_and_both_storeys_with_rooms_are_planned(
        scenes_dir: Path) -> None:
    path = buildings_dir(scenes_dir) / "Renga-House.ifc"
    scene = read_scene(path)
    spaces = scene.metadata["spaces"]
    assert len(spaces) == 13  # all 13 IfcSpace, by IfcOpenShell's own tessellation
    # every element with a body is read: the '*' that Renga writes no longer breaks them
    classes = Counter(e.ifc_class for e in scene.elements)
    assert classes["IfcSlab"] == 13 and classes["IfcDoor"] == 19
    assert classes["IfcStairFlight"] == 5 and classes["IfcWindow"] == 23
    # in metres: the ground storey's rooms at -0.45 and 0 m, the upper ones at +2.85/+3.45
    assert {round(s["floor_z_m"], 2) for s in spaces} == {-0.45, 0.0, 2.85, 3.45}
    warnings = scene.metadata["warnings"]
    assert any("'*'" in w and "ISO 10303-21" in w for w in warnings), warnings
    assert scene.metadata["unread_elements"] == 0

    document = planned(path)
    assert "'*'" in " ".join(document["scene"]["warnings"])  # the user is told
    storeys_with_rooms = {s["storey"] for s in spaces}
    assert len(storeys_with_rooms) == 2
    by_storey = Counter(s["label"]["storey"] for s in document["stations"])
    assert set(by_storey) == storeys_with_rooms, by_storey
    assert all(by_storey[s] >= 4 for s in storeys_with_rooms), by_storey
    # the route reaches every station but those in the two rooms at +2.85 m: their only
    # door (1ZgLHazLj3duEKSEptf0x7) is in the wall to the stair's landing, also at +2.85 m,
    # but the model places it and its opening 0.6 m up, at +3.45 m (the other upper rooms'
    # floor), with wall under it (a model defect the route must report, not hide)
    route = document["route"]
    behind_drop = {s["global_id"] for s in spaces if abs(s["floor_z_m"] - 2.85) < 1e-6}
    assert route["unreachable"] == [], route["unreachable_reasons"]
    assert sorted(route["visits"]) == list(range(1, len(document["stations"]) + 1))
    steps = route.get("steps_between_parts", [])
    apart_rooms = {document["stations"][step["to"] - 1]["label"]["room_global_id"]
                   for step in steps}
    assert apart_rooms <= behind_drop, steps
    for step in steps:  # the door and its sill named
        assert "sets that door's sill at +3.45 m, 0.60 m above this floor (+2.85 m) and 0.60 " \
            "m above the route's floor on its other side (+2.85 m)" in step["note"], step


def _break_bodies(model: Any, text: str, keep: str) -> str:
    """``text`` (``model`` written) with the body of every product that is not a ``keep``
    made of a lone point, which IfcOpenShell cannot make a solid of: an exporter that lost
    the element's geometry."""
    import re

    wrong: set[int] = set()
    for product in model.by_type("IfcProduct"):
        if product.Representation is None or product.is_a(keep):
            continue
        for representation in product.Representation.Representations:
            if representation.RepresentationIdentifier == "Body":
                wrong.add(representation.id())
    point = model.by_type("IfcCartesianPoint")[0].id()

    def broken(match: re.Match[str]) -> str:
        if int(match.group(1)) not in wrong:
            return match.group(0)
        return f"#{match.group(1)}={match.group(2)}(#{point}));"

    return re.sub(r"(?m)^#(\d+)=(IFCSHAPEREPRESENTATION\(.*,)\([^()]*\)\);$", broken, text)


def test_elements_whose_geometry_fails_are_named_and_the_file_is_blamed(
        scenes_dir: Path, tmp_path: Path) -> None:
    """The Renga house with a point for the body of every element and room but the walls:
    the elements are named in the warnings with IfcOpenShell's cause,
    and the plan, which finds no floor under the walls alone, says that the file, not the
    parameters, is to blame."""
    from planner.errors import NoCandidatesError

    source = buildings_dir(scenes_dir) / "Renga-House.ifc"
    model = ifcopenshell.open(str(source))
    path = tmp_path / "broken.ifc"
    model.write(str(path))
    path.write_text(_break_bodies(model, path.read_text("utf-8"), "IfcWallStandardCase"),
                    "utf-8")
    scene = read_scene(path, max_edge_m=SPEC.max_edge_m, split_faces="as_needed")
    assert {e.ifc_class for e in scene.elements} == {"IfcWallStandardCase"}
    unread = [w for w in scene.metadata["warnings"] if "could not triangulate" in w]
    assert len(unread) == 1 and unread[0].startswith("broken.ifc: ")
    assert "IfcSlab 13" in unread[0] and "IfcDoor 19" in unread[0]
    assert "IfcSpace 13" in unread[0]
    assert scene.metadata["unread_elements"] >= 13 + 19 + 13
    with pytest.raises(NoCandidatesError, match="the model file is the likely cause, not "
                       "the parameters: the geometry of"):
        plan(scene, SPEC)


# every room accounted for ---------------------------------------------------------------------


@pytest.mark.parametrize("name", ["Renga-House", "AC90R1-niedriha-V2-2x3"])
def test_every_ifcspace_is_listed_with_its_storey_area_candidates_and_why_it_has_none(
        name: str, scenes_dir: Path) -> None:
    path = buildings_dir(scenes_dir) / f"{name}.ifc"
    model = ifcopenshell.open(str(path))
    document = planned(path)
    rooms = document["candidates"]["rooms"]
    # every IfcSpace of the file, once, whatever happened to it
    assert sorted(r["room_global_id"] for r in rooms) == sorted(
        s.GlobalId for s in model.by_type("IfcSpace"))
    storeys = {s["storey"] for s in rooms}
    assert "" not in storeys
    for room in rooms:
        assert room["area_m2"] > 0 and room["grid_points"] >= room["candidates"] >= 0
        assert room["grid_points"] == room["candidates"] + sum(
            room.get("left_out", {}).values())
        # a room without candidates says why, one with candidates does not need to
        assert ("reason" in room) == (room["candidates"] == 0), room
        assert room["stations"] <= room["candidates"]
    in_rooms = [s for s in document["stations"] if s["label"].get("room_global_id")]
    # each station once: a room overlapping an earlier one shares some (none here)
    assert sum(r["stations"] - r.get("shared", {}).get("stations", 0) for r in rooms) \
        == len(in_rooms) == len(document["stations"])
    assert not any("overlaps" in r for r in rooms)
    # one line per storey with rooms, naming the rooms without a candidate
    lines = rooms_lines(rooms)
    assert [line.split(" (")[0] for line in lines] == list(dict.fromkeys(
        r["storey"] for r in rooms))
    for room in rooms:
        if room["candidates"] == 0:
            name = line_name(room, [r for r in rooms if r["storey"] == room["storey"]])
            assert any(f"{name} (" in line and line.startswith(room["storey"])
                       for line in lines), (room, lines)


def test_the_attic_too_low_for_a_tripod_says_so(scenes_dir: Path) -> None:
    """NiedriHa's attic (67 m² under a roof that rises to 1.7 m above its floor) gets no
    station: plan.json and the storey's line say that it lacks head room for the
    scanner."""
    document = planned(buildings_dir(scenes_dir) / "AC90R1-niedriha-V2-2x3.ifc")
    rooms = document["candidates"]["rooms"]
    attic = [r for r in rooms if r["storey"] == "Dachgeschoss"]
    assert len(attic) == 1 and attic[0]["candidates"] == 0
    assert attic[0]["reason"].startswith("head room: ")
    assert attic[0]["area_m2"] == pytest.approx(67.4, abs=0.1)
    line = [x for x in rooms_lines(rooms) if x.startswith("Dachgeschoss")]
    assert line == ["Dachgeschoss (+5.70 m): 0 of 1 room with candidates, 0 candidates, "
                    "0 stations; none in Dachboden (head room)"]
    # the three storeys below are planned, each with stations
    by_storey = Counter(s["label"]["storey"] for s in document["stations"])
    assert set(by_storey) == {"Keller", "Erdgeschoss", "Obergeschoss"}


# the building, not the site --------------------------------------------------------------------


def test_a_house_on_its_site_gets_candidates_in_and_around_the_house_and_a_printable_set(
        scenes_dir: Path) -> None:
    """Lantern Hollow (Revit, feet, no IfcSpace): a 26 x 33 m house on a 114 x 203 m
    terrain. The candidates stand in the house and within the plan's reach of its walls,
    both storeys are planned, and the print set is a few sheets, not the terrain's."""
    from planner.limits import FaceLimits
    from planner.outputs.printset import sheets

    path = buildings_dir(scenes_dir) / "Lantern_Hollow.ifc"
    scene = read_scene(path, max_edge_m=SPEC.max_edge_m, split_faces="as_needed")
    result = plan(scene, SPEC)
    site = np.array([e.ifc_class == "IfcSite" for e in scene.elements] + [False])
    building = ~site[scene.face_element]
    corners = scene.triangles[building].reshape(-1, 3)
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    assert (hi - lo)[:2].max() < 40 < (scene.bounds[1] - scene.bounds[0])[:2].min()
    reach = FaceLimits.from_spec(SPEC, scene).reach_m
    xy = result.candidates.positions[:, :2]
    margin = reach + SPEC.grid_spacing_m
    assert ((xy >= lo[:2] - margin) & (xy <= hi[:2] + margin)).all()
    assert len(result.candidates) < 1000  # 14,373 at 0.5 m over the whole terrain before
    floors = result.candidates.positions[:, 2] - SPEC.scanner_height_m
    document = plan_document(result)
    stations = np.array([s["position"] for s in document["stations"]])
    # the basement (-2.49 m) and the ground floor (0 m) each have candidates and stations
    for storey_z in (-2.49, 0.0):
        assert (np.abs(floors - storey_z) < 0.2).sum() >= 20, storey_z
        assert (np.abs(stations[:, 2] - SPEC.scanner_height_m - storey_z) < 0.2).any()
    # a sheet or a few per storey: the house at 1:100 or 1:200, not the terrain
    printed = sheets(result)
    assert 2 <= len(printed) <= 8, len(printed)


# rooms are floors ------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["AC20-FZK-Haus", "buildings/AC90R1-Jasmin-Sun-105-2x3"])
def test_an_architectural_model_without_its_slabs_gets_every_storey_and_a_route_to_all(
        name: str, scenes_dir: Path, tmp_path: Path) -> None:
    """The discipline model a BIM platform sends: the architectural model, its slabs in the
    structural one (here: deleted). The rooms' bottoms are the floors: every storey with
    rooms gets stations, as with the slabs, and the route reaches every station."""
    source = scenes_dir / f"{name}.ifc"
    if not source.exists():
        pytest.skip(f"{source} is not beside the checkout")
    model = ifcopenshell.open(str(source))
    for slab in model.by_type("IfcSlab"):
        model.remove(slab)
    path = tmp_path / "without-slabs.ifc"
    model.write(str(path))
    document = planned(path)
    full = planned(source)
    assert not any(e == "IfcSlab" for e in document["scene"]["groups"])
    storeys = {s["label"]["storey"] for s in document["stations"]}
    assert storeys == {s["label"]["storey"] for s in full["stations"]}
    assert document["route"]["unreachable"] == [], document["route"]["unreachable_reasons"]
    assert "steps_between_parts" not in document["route"], document["route"]["steps_between_parts"]
    assert sorted(document["route"]["visits"]) == list(range(1, len(document["stations"]) + 1))
    # every room but those over nothing stands on its space (the model has no slab)
    assert document["candidates"]["floor_from_space"]
    assert full["candidates"]["floor_from_space"] == []
    # a walk of the building's size, not a few metres between stations on floor fragments
    assert document["route"]["length_m"] > 0.6 * full["route"]["length_m"]


def test_a_plain_mesh_without_its_slabs_says_what_is_missing(scenes_dir: Path,
                                                            tmp_path: Path) -> None:
    """The same architectural model without its slabs, exported as a plain mesh: no rooms
    to stand on, and the floor left (stair treads, a terrace) is a fraction of the
    footprint. The plan says so and what to send; a plain mesh with its slabs does not."""
    from tests.planner.buildings import export_plain_mesh

    model = ifcopenshell.open(str(buildings_dir(scenes_dir) / "AC90R1-Jasmin-Sun-105-2x3.ifc"))
    for slab in model.by_type("IfcSlab"):
        model.remove(slab)
    model.write(str(tmp_path / "bare.ifc"))
    document = planned(export_plain_mesh(tmp_path / "bare.ifc", tmp_path / "bare.obj"))
    note = document["candidates"]["floor_note"]
    assert note.startswith("the model has ") and "a model without its floor slabs" in note
    assert "Send it as IFC with its rooms (IfcSpace)" in note


# the corpus: every station reached, no leg through a wall, every room accounted for -------

# the IFC models planned above (once a session, by ``planned``): no new plan here
CORPUS_IFC = ["buildings/Renga-House", "buildings/AC90R1-niedriha-V2-2x3",
              "buildings/AC90R1-Jasmin-Sun-105-2x3", "AC20-FZK-Haus"]


@pytest.mark.parametrize("name", CORPUS_IFC)
def test_the_corpus_as_ifc_reaches_every_station_without_a_leg_through_a_wall(
        name: str, scenes_dir: Path) -> None:
    path = scenes_dir / f"{name}.ifc"
    if not path.exists():
        pytest.skip(f"{path} is not beside the checkout")
    document = planned(path)
    route = document["route"]
    assert document["legs_through_walls"] == []
    assert "door_checks" not in route  # IFC: IfcDoor alone opens, never a window
    # every IfcSpace accounted for, each without candidates with its reason
    model = ifcopenshell.open(str(path))
    rooms = document["candidates"]["rooms"]
    assert sorted(r["room_global_id"] for r in rooms) == sorted(
        s.GlobalId for s in model.by_type("IfcSpace"))
    assert all("reason" in r for r in rooms if r["candidates"] == 0)
    if name != "buildings/Renga-House":
        assert route["unreachable"] == [], route["unreachable_reasons"]
        assert "steps_between_parts" not in route, route["steps_between_parts"]
        return
    # the Renga house's two rooms at +2.85 m: no way in at knee height (their door from
    # the landing, at +2.85 m too, has its sill at +3.45 m: a defect of the model); their
    # stations say what cuts them off, naming that door and its sill
    # walked after a step the crew makes on site: the model's door is no way in
    assert route["unreachable"] == [], route["unreachable_reasons"]
    steps = route.get("steps_between_parts", [])
    assert steps, "the rooms behind the raised door are walked as a part of their own"
    for reason in (step["note"] for step in steps):
        assert "cut off from the route (26.7 m² of floor at +2.85 m)" in reason, reason
        assert "sets that door's sill at +3.45 m, 0.60 m above this floor" in reason, reason
        assert "no step is missing" in reason, reason


@pytest.fixture(scope="module")
def niedriha_plain(scenes_dir: Path, tmp_path_factory: pytest.TempPathFactory
                   ) -> dict[str, Any]:
    """The ArchiCAD house as a plain OBJ (no classes, no groups), planned once."""
    return _plain(buildings_dir(scenes_dir) / "AC90R1-niedriha-V2-2x3.ifc",
                  tmp_path_factory.mktemp("plain") / "niedriha.obj")


def _plain(ifc: Path, obj: Path, route_start: tuple[float, float, float] | None = None
           ) -> dict[str, Any]:
    """``ifc`` exported to the plain OBJ ``obj`` and planned (:func:`planned`)."""
    from planner.walkgraph import door_faces
    from tests.planner.buildings import export_plain_mesh, plain_mesh_doorways
    from tests.planner.ifc_models import read_ifc_once

    reference = read_ifc_once(ifc)
    export_plain_mesh(ifc, obj, reference)
    # the ground truth for the legs' check: the IFC's doors and windows to the floor, in
    # the export's face order; and its doors alone
    np.save(obj.with_suffix(".doors.npy"),
            reference.on_file_faces(plain_mesh_doorways(reference)))
    np.save(obj.with_suffix(".ifcdoors.npy"), reference.on_file_faces(door_faces(reference)))
    return planned(obj, route_start)


def test_the_archicad_house_as_a_plain_mesh_gets_its_storeys_not_its_landings(
        niedriha_plain: dict[str, Any]) -> None:
    """NiedriHa as a plain mesh: its three storeys with floor room (basement, ground,
    upper floor), the basement's half level and the stair's steps not called storeys, and
    every station reached through the doors the mesh rule finds."""
    document = niedriha_plain
    assert "floor_note" not in document["candidates"]  # its slabs are floor enough
    levels = document["candidates"]["levels"]
    storeys = [lv for lv in levels if "excluded" not in lv]
    assert [lv["floor_z_m"] for lv in storeys] == [-2.85, 0.0, 2.85], levels
    assert {s["label"]["storey"] for s in document["stations"]} == {
        lv["name"] for lv in storeys}
    route = document["route"]
    assert route["unreachable"] == [], route["unreachable_reasons"]
    assert "steps_between_parts" not in route, route["steps_between_parts"]


def test_the_archicad_house_as_a_plain_mesh_has_no_leg_through_a_wall(
        niedriha_plain: dict[str, Any]) -> None:
    """Its stair's stringers are as thin as a door leaf and one stands under the next
    flight's, in its plane; the door rule does not take them for a door (they are not one
    piece from knee to head height), so no leg passes through them."""
    assert niedriha_plain["legs_through_walls"] == []


def _plain_mesh_levels(ifc: Path, obj: Path) -> list[dict[str, Any]]:
    """``candidates.levels`` of the IFC model ``ifc`` exported as the plain mesh ``obj``:
    the candidates alone (the grid and its storeys), no plan."""
    from planner.candidates.grid import generate_grid
    from planner.limits import FaceLimits
    from planner.rays import make_ray_caster
    from tests.planner.buildings import export_plain_mesh
    from tests.planner.ifc_models import read_ifc_once

    mesh = export_plain_mesh(ifc, obj, read_ifc_once(ifc))
    scene = read_scene(mesh, max_edge_m=SPEC.max_edge_m, split_faces="as_needed")
    caster = make_ray_caster(scene, FaceLimits.from_spec(SPEC, scene).occludes,
                             file_faces=True)
    levels = generate_grid(scene, SPEC, caster).levels
    assert levels is not None
    return list(levels)


def test_the_renga_house_as_a_plain_mesh_has_two_storeys_with_split_levels(
        scenes_dir: Path, tmp_path: Path) -> None:
    """Renga's rooms lie at -0.45 and 0 m (Level 1) and at +2.85 and +3.45 m (Level 2):
    a plain mesh of it has two storeys, each with a split level, not four."""
    levels = _plain_mesh_levels(buildings_dir(scenes_dir) / "Renga-House.ifc",
                                tmp_path / "renga.obj")
    storeys = [lv for lv in levels if "excluded" not in lv]
    assert [lv["floor_z_m"] for lv in storeys] == [0.0, 3.45], levels
    # on this 1 m grid a few stair treads and roof patches add up to 4 m² near +3.45 m
    split = [list(map(float, str(lv["with_levels_m"]).strip("[]").split(", ")))
             for lv in storeys]
    assert -0.45 in split[0] and 2.85 in split[1], storeys


def test_the_renga_house_as_a_plain_mesh_gives_the_raised_doors_sill(
        scenes_dir: Path, tmp_path: Path) -> None:
    """The plain mesh names no door, but the reason of a station in the lower wing's upper
    rooms (+2.85 m) finds the opening over the wall to the stair's landing (+2.85 m too)
    and its sill, 0.60 m above both floors: no step is missing, the door is set too high."""
    from planner.limits import FaceLimits
    from planner.rays import make_ray_caster
    from planner.survey.fieldwork import _walk_caster
    from planner.survey.route import plan_route
    from planner.walkgraph import build_walk_graph
    from tests.planner.buildings import export_plain_mesh
    from tests.planner.ifc_models import read_ifc_once

    ifc = buildings_dir(scenes_dir) / "Renga-House.ifc"
    scene = read_scene(export_plain_mesh(ifc, tmp_path / "renga.obj", read_ifc_once(ifc)))
    limits = FaceLimits.from_spec(SPEC, scene)
    walk, _ = _walk_caster(scene, limits, make_ray_caster(scene, limits.occludes), False)
    # in the +3.45 m room over the entrance, and in the lower wing's room at +2.85 m
    stations = np.array([[3.0, -4.5, 4.95], [8.0, -1.0, 4.35]])
    route = plan_route(build_walk_graph(scene, walk), walk, stations, None)
    assert route.unreachable == () and [step.end for step in route.steps] == [2]
    (reason,) = (step.reason for step in route.steps)
    assert "the opening of door height in it" in reason, reason
    assert "has its sill at +3.45 m, 0.60 m above this floor (+2.85 m) and 0.60 m above the " \
        "route's floor on its other side (+2.85 m), with wall under it" in reason, reason


# Jasmin: in the garden, outside the west French window of its ground floor (model metres)
JASMIN_GARDEN = (1.58, 8.6, 1.0)


def test_the_archicad_house_with_french_windows_as_a_plain_mesh_has_no_leg_through_a_wall(
        scenes_dir: Path, tmp_path_factory: pytest.TempPathFactory) -> None:
    """Jasmin's ground floor has French windows (IfcWindow from the floor to door height).
    A plain mesh cannot tell them from glazed doors, so its door rule opens them and the
    legs' check lets a leg through them; through anything else (a window with a parapet, a
    wall) no leg passes, and every station is reached. The crew, starting in the garden by
    a French window, walks in through it: that leg, and every leg through a French window,
    carries a check naming the leg, its stations and where, so that the crew checks that
    the window opens; the job's message says so."""
    from planner.survey.route import door_checks_line

    document = _plain(buildings_dir(scenes_dir) / "AC90R1-Jasmin-Sun-105-2x3.ifc",
                      tmp_path_factory.mktemp("plain") / "jasmin.obj",
                      JASMIN_GARDEN)
    assert document["legs_through_walls"] == []
    route = document["route"]
    assert route["unreachable"] == [], route["unreachable_reasons"]
    assert "steps_between_parts" not in route, route["steps_between_parts"]
    storeys = [lv for lv in document["candidates"]["levels"] if "excluded" not in lv]
    assert [lv["floor_z_m"] for lv in storeys] == [-2.9, 0.0, 2.9], storeys
    through_windows = document["legs_through_non_doors"]
    assert through_windows and through_windows[0]["leg"] == 0, through_windows
    checks = route["door_checks"]
    for leg in through_windows:
        named = [c for c in checks if c["leg"] == leg["leg"] + 1
                 and np.hypot(*np.subtract(c["at"][:2], leg["at"][:2])) < 0.3]
        assert len(named) == 1, (leg, checks)
        check = named[0]
        assert (check["from"], check["to"]) == (leg["from"], leg["to"])
        assert f"leg {check['leg']} of the route, from " in check["warning"]
        assert "French window" in check["warning"]
    assert checks[0]["from"] is None and "from the route's start" in checks[0]["warning"]
    line = door_checks_line(route)
    assert line is not None and "may be a fixed window" in line


def test_a_house_on_a_sloping_site_as_a_plain_mesh_keeps_its_basement_and_ground_floor(
        scenes_dir: Path, tmp_path: Path) -> None:
    """Lantern Hollow as a plain mesh: its terrain slopes from the basement's door (-2.5 m)
    up to the ground floor (0 m), a walkable slope at every height between them. The
    storeys are the level floors, the slope joins neither to the other: two storeys, at
    the basement's and the ground floor's heights, not one between them."""
    levels = _plain_mesh_levels(buildings_dir(scenes_dir) / "Lantern_Hollow.ifc",
                                tmp_path / "lantern.obj")
    storeys = [lv for lv in levels if "excluded" not in lv]
    heights = [float(str(lv["floor_z_m"])) for lv in storeys]
    assert len(heights) == 2 and abs(heights[0] + 2.49) < 0.05 and abs(heights[1]) < 0.1, \
        levels
    assert all(int(str(lv["candidates"])) >= 50 for lv in storeys), storeys
