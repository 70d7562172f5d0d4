"""Storeys of a plain mesh: stair landings and split levels are not storeys; the
independent check that no leg of a route goes through a wall can fail; and an unreachable
station says what is missing.

Hand-made buildings of boxes (``tests/planner/survey_scenes.py``); each builds in well
under a second.
"""

from __future__ import annotations

import numpy as np
import pytest

from planner.candidates.grid import generate_grid, levels_line
from planner.parameters import PlanSpec
from planner.rays import make_ray_caster
from planner.scene import Scene, build_scene, remesh
from planner.survey.route import Places, plan_route
from planner.truth.legs import SWEEP_HEIGHTS_M, legs_through_walls
from planner.walkgraph import KNEE_HEIGHT_M, build_walk_graph
from tests.planner.survey_scenes import Box, boxes_scene

SPEC = PlanSpec(grid_spacing_m=0.5)
STOREY_M = 4.0  # high storeys: a half landing lies 2 m from both floors, more than head room


def _shell(x1: float, y1: float, top_m: float) -> list[Box]:
    """Four walls around [0, x1] x [0, y1] from 0 to ``top_m`` and a roof over them."""
    t = 0.2
    return [((-t, -t, 0.0), (0.0, y1 + t, top_m)), ((x1, -t, 0.0), (x1 + t, y1 + t, top_m)),
            ((0.0, -t, 0.0), (x1, 0.0, top_m)), ((0.0, y1, 0.0), (x1, y1 + t, top_m)),
            ((-t, -t, top_m), (x1 + t, y1 + t, top_m + t))]


def _off_grid(boxes: list[Box]) -> Scene:
    """The boxes moved 0.13 m along x and y: no grid point lies on a wall's face."""
    return boxes_scene([((x0 + 0.13, y0 + 0.13, z0), (x1 + 0.13, y1 + 0.13, z1))
                        for (x0, y0, z0), (x1, y1, z1) in boxes])


def office_with_landings() -> Scene:
    """A 20 x 10 m office of three 4 m storeys (floors at 0, 4 and 8 m) whose stair hall
    [16, 20] x [0, 6] has a 2 x 3 m half landing at +2 and +6 m, half-way up each
    storey; the slabs over the stair hall are open."""
    boxes = _shell(20.0, 10.0, 3 * STOREY_M)
    boxes.append(((0.0, 0.0, -0.3), (20.0, 10.0, 0.0)))  # ground slab
    for k in (1, 2):
        z = k * STOREY_M
        boxes += [((0.0, 0.0, z - 0.3), (16.0, 10.0, z)),  # the slab, less the stair hall
                  ((16.0, 6.0, z - 0.3), (20.0, 10.0, z))]
    for k in (0, 1):
        z = k * STOREY_M + STOREY_M / 2
        boxes.append(((18.0, 0.0, z - 0.2), (20.0, 3.0, z)))  # the landing
    return _off_grid(boxes)


def test_half_landings_between_storeys_are_not_storeys_and_keep_their_candidates() -> None:
    scene = office_with_landings()
    caster = make_ray_caster(scene, np.ones(scene.n_faces, bool))
    candidates = generate_grid(scene, SPEC, caster)
    assert candidates.levels is not None
    storeys = [lv for lv in candidates.levels if "excluded" not in lv]
    assert [lv["floor_z_m"] for lv in storeys] == [0.0, 4.0, 8.0], candidates.levels
    landings = [lv for lv in candidates.levels
                if str(lv.get("excluded", "")).startswith("landing")]
    assert [lv["floor_z_m"] for lv in landings] == [2.0, 6.0]
    # each belongs to the storey below it, which counts its candidates
    assert [lv["storey_floor_z_m"] for lv in landings] == [0.0, 4.0]
    floor_z = candidates.positions[:, 2] - SPEC.scanner_height_m
    storey_names = {label["storey"] for label in candidates.labels}
    assert storey_names == {str(lv["name"]) for lv in storeys}
    for landing in landings:
        on = np.abs(floor_z - float(str(landing["floor_z_m"]))) < 0.01
        assert on.sum() == landing["candidates"] and on.sum() > 0
        owner = [lv for lv in storeys if lv["floor_z_m"] == landing["storey_floor_z_m"]]
        assert {candidates.labels[i]["storey"] for i in np.flatnonzero(on)} == {
            owner[0]["name"]}
    assert sum(int(str(lv["candidates"])) for lv in storeys) == len(candidates)
    line = levels_line(candidates.levels)
    assert line is not None and line.startswith("3 storeys planned") and "2 landing" in line


def test_rooms_a_few_steps_up_are_a_split_level_of_their_storey() -> None:
    """A 10 x 14 m house: the east 4 m of its ground floor 0.6 m up, its upper floor (3 m)
    likewise 0.6 m up in the east: two storeys, not four (as the Renga house's plain
    mesh: rooms at -0.45 and 0 m, at +2.85 and +3.45 m)."""
    boxes = _shell(10.0, 8.0, 6.0)
    boxes += [((0.0, 0.0, -0.3), (10.0, 8.0, 0.0)), ((6.0, 0.0, 0.0), (10.0, 8.0, 0.6)),
              ((0.0, 0.0, 2.7), (10.0, 8.0, 3.0)), ((6.0, 0.0, 3.0), (10.0, 8.0, 3.6))]
    scene = _off_grid(boxes)
    caster = make_ray_caster(scene, np.ones(scene.n_faces, bool))
    candidates = generate_grid(scene, SPEC, caster)
    assert candidates.levels is not None
    storeys = [lv for lv in candidates.levels if "excluded" not in lv]
    assert [lv["floor_z_m"] for lv in storeys] == [0.0, 3.0], candidates.levels
    assert [lv["with_levels_m"] for lv in storeys] == [[0.6], [3.6]]
    split = [lv for lv in candidates.levels if str(lv.get("excluded", "")).startswith("split")]
    assert [(lv["floor_z_m"], lv["storey_floor_z_m"]) for lv in split] == [(0.6, 0.0),
                                                                          (3.6, 3.0)]
    floor_z = candidates.positions[:, 2] - SPEC.scanner_height_m
    assert {round(float(z), 2) for z in floor_z} == {0.0, 0.6, 3.0, 3.6}
    assert len({label["storey"] for label in candidates.labels}) == 2


def test_a_slope_from_the_basement_up_to_the_ground_floor_joins_neither_storey() -> None:
    """A 10 x 14 m house, its basement floor at 0 and its ground floor at 3 m, on a site
    whose terrain slopes (12 degrees, walkable, askew to the grid) from the basement's
    level up to the ground floor's beside it, as Lantern Hollow's: the slope fills every
    height between the two floors, yet they stay two storeys (a level floor tells a
    storey's height, a slope does not), and the slope is no storey of its own."""
    boxes = _shell(10.0, 14.0, 6.0)
    boxes += [((-0.2, -0.2, -0.3), (10.2, 14.2, 0.0)), ((0.0, 0.0, 2.7), (10.0, 14.0, 3.0))]
    house = _off_grid(boxes)
    # the terrain's slope, one sheet as a site model's: from the basement's wall up to +3 m,
    # along the house's east wall, rising 0.2 m a metre north and 0.05 m a metre east
    x0, x1, y1 = 10.33, 14.33, 14.13
    slope = np.array([[x0, 0.13, 0.0], [x1, 0.13, 0.2], [x1, y1, 3.0], [x0, y1, 2.8]])
    scene = remesh(build_scene(np.concatenate([house.vertices, slope]), np.concatenate(
        [house.faces, np.array([[0, 1, 2], [0, 2, 3]]) + len(house.vertices)])), 0.5)
    caster = make_ray_caster(scene, np.ones(scene.n_faces, bool))
    candidates = generate_grid(scene, SPEC, caster)
    assert candidates.levels is not None
    storeys = [lv for lv in candidates.levels if "excluded" not in lv]
    assert [lv["floor_z_m"] for lv in storeys] == [0.0, 3.0], candidates.levels
    sloped = [lv for lv in candidates.levels if str(lv.get("excluded", "")).startswith(
        "sloped")]
    assert sloped and all(0.1 < float(str(lv["floor_z_m"])) < 2.9 for lv in sloped), \
        candidates.levels


def test_a_hall_on_a_slab_drawn_with_its_underside_is_planned_on_its_floor() -> None:
    """A 12 x 8 m hall of one storey on a solid slab 0.2 m thick (its underside is the
    lowest surface, with the slab's own top 0.2 m over it), but for a 2 x 2 m grating in
    its middle drawn as one face: the candidates cover the hall's floor, not the grating
    alone (Amersfoort's sports hall as a plain mesh was planned on 1 candidate)."""
    boxes = _shell(12.0, 8.0, 4.0)
    boxes += [((0.0, 0.0, -0.2), (5.0, 8.0, 0.0)), ((7.0, 0.0, -0.2), (12.0, 8.0, 0.0)),
              ((5.0, 0.0, -0.2), (7.0, 3.0, 0.0)), ((5.0, 5.0, -0.2), (7.0, 8.0, 0.0))]
    solid = _off_grid(boxes)
    grating = np.array([[5.0, 3.0, 0.0], [7.0, 3.0, 0.0], [7.0, 5.0, 0.0], [5.0, 5.0, 0.0]])
    grating[:, :2] += 0.13
    scene = remesh(build_scene(np.concatenate([solid.vertices, grating]),
                               np.concatenate([solid.faces, len(solid.vertices)
                                               + np.array([[0, 1, 2], [0, 2, 3]])])), 0.5)
    caster = make_ray_caster(scene, np.ones(scene.n_faces, bool))
    candidates = generate_grid(scene, SPEC, caster)
    floor_z = candidates.positions[:, 2] - SPEC.scanner_height_m
    assert np.allclose(floor_z, 0.0, atol=1e-6)
    inside = candidates.positions[:, :2] - 0.13
    on_grating = ((inside >= [5.0, 3.0]) & (inside <= [7.0, 5.0])).all(axis=1)
    assert len(candidates) >= 200 and (~on_grating).sum() >= 180, len(candidates)


# no leg through a wall: the check itself --------------------------------------------------


def _wall_scene() -> Scene:
    """A 6 x 4 m room cut in two by a wall at x = 3 with a 0.9 m doorway at y in [0.2,
    1.1] whose 2.1 m high opening holds a door leaf, and a low passage at y in [2.5, 3.5]
    1.5 m high (free at knee height, a wall at head height)."""
    boxes: list[Box] = _shell(6.0, 4.0, 2.6)
    boxes += [((0.0, 0.0, -0.2), (6.0, 4.0, 0.0)),
              ((2.9, 0.0, 0.0), (3.1, 0.2, 2.6)), ((2.9, 1.1, 0.0), (3.1, 2.5, 2.6)),
              ((2.9, 0.2, 2.1), (3.1, 1.1, 2.6)),  # lintel
              ((2.9, 2.5, 1.5), (3.1, 3.5, 2.6)),  # over a low passage
              ((2.9, 3.5, 0.0), (3.1, 4.0, 2.6)),
              ((2.98, 0.2, 0.0), (3.02, 1.1, 2.1))]  # the door leaf, last
    return boxes_scene(boxes, max_edge_m=10.0)


def _leg(points: list[tuple[float, float, float]], start: int = 1, end: int = 2
         ) -> dict[str, object]:
    return {"from": start, "to": end, "path": [[x, y, z + KNEE_HEIGHT_M] for x, y, z in points]}


@pytest.fixture(scope="module")
def wall_scene() -> tuple[Scene, np.ndarray]:
    scene = _wall_scene()
    door = np.zeros(scene.n_faces, bool)
    door[-12:] = True  # the leaf's 12 triangles (a box's 6 sides, max_edge_m keeps them whole)
    return scene, door


def test_a_leg_through_the_door_is_free_and_one_through_the_wall_is_found(
        wall_scene: tuple[Scene, np.ndarray]) -> None:
    scene, door = wall_scene
    through_door = _leg([(1.0, 0.65, 0.0), (5.0, 0.65, 0.0)])
    through_wall = _leg([(1.0, 2.0, 0.0), (1.5, 2.0, 0.0), (5.0, 2.0, 0.0)], 2, 3)
    # free at the knee, through the wall over the low passage: what a knee-high walk
    # graph alone would let through
    through_low_passage = _leg([(1.0, 3.0, 0.0), (5.0, 3.0, 0.0)], 3, 4)
    blocked = legs_through_walls(scene, door, [through_door, through_wall,
                                               through_low_passage])
    assert [(b.index, b.start, b.end) for b in blocked] == [(1, 2, 3), (2, 3, 4)]
    assert blocked[0].height_m == KNEE_HEIGHT_M
    assert blocked[0].at_m[0] == pytest.approx(2.9, abs=1e-3)
    assert blocked[1].height_m == max(SWEEP_HEIGHTS_M)
    # the door's leaf blocks when it is not a door
    shut = legs_through_walls(scene, np.zeros(scene.n_faces, bool), [through_door])
    assert [b.index for b in shut] == [0]
    # a leg along the room, clear of everything, and a leg of one point: free
    assert legs_through_walls(scene, door, [_leg([(0.5, 3.0, 0.0), (2.5, 3.0, 0.0)]),
                                            _leg([(1.0, 1.0, 0.0)])]) == []


def test_a_leg_up_a_stair_is_swept_over_the_floor_it_climbs(
        wall_scene: tuple[Scene, np.ndarray]) -> None:
    """The sweep follows the leg's own floor: a leg whose points climb 1.2 m passes under
    the lintel only if it is swept from its floor, not from a fixed height."""
    scene, door = wall_scene
    # from the floor at x = 1 up onto a (not modelled) 1 m podium at x = 5: through the
    # doorway the floor is at 0.5 m, the head at 0.5 + 1.75 m, above the 2.1 m lintel
    climbing = _leg([(1.0, 0.65, 0.0), (5.0, 0.65, 1.0)])
    blocked = legs_through_walls(scene, door, [climbing])
    assert len(blocked) == 1 and blocked[0].height_m == max(SWEEP_HEIGHTS_M)
    assert blocked[0].at_m[2] > 2.1


# a station off the route's part, or off any floor, says what is missing ----------------


def _route(boxes: list[Box], stations: list[tuple[float, float, float]],
           places: Places | None = None) -> tuple[tuple[int, ...], tuple[str, ...]]:
    scene = _off_grid(boxes)
    caster = make_ray_caster(scene, np.ones(scene.n_faces, bool))
    moved = np.asarray(stations) + np.array([0.13, 0.13, 0.0])
    route = plan_route(build_walk_graph(scene, caster), caster, moved, None, places)
    # a station in a part the walk does not join to the route's is still walked, in a
    # part of its own after a step the crew makes on site; the step gives the reason
    apart = tuple(step.end for step in route.steps)
    assert set(apart) <= set(route.visits) and not set(apart) & set(route.unreachable)
    return (route.unreachable + apart,
            route.unreachable_reasons + tuple(step.reason for step in route.steps))


def _two_storeys(stair: bool) -> list[Box]:
    """A 8 x 5 m house of two 3 m storeys; its upper slab open over [6, 8] x [0, 2]."""
    boxes = _shell(8.0, 5.0, 6.0)
    boxes += [((0.0, 0.0, -0.3), (8.0, 5.0, 0.0)), ((0.0, 0.0, 2.7), (6.0, 5.0, 3.0)),
              ((6.0, 2.0, 2.7), (8.0, 5.0, 3.0))]
    if stair:  # 15 steps of 0.2 m up along x under the opening
        boxes += [((6.0 - 3.0 + 0.2 * i, 0.0, 0.0), (8.0, 1.0, 0.2 * (i + 1)))
                  for i in range(15)]
    return boxes


def test_a_storey_no_stair_reaches_names_both_storeys() -> None:
    places = Places(storeys=(("Ground", 0.0), ("Upper", 3.0)),
                    station_rooms=("Hall", "Bedroom"))
    unreachable, reasons = _route(_two_storeys(stair=False),
                                  [(2.0, 2.5, 1.5), (2.0, 2.5, 4.5)], places)
    assert unreachable == (2,)
    assert reasons[0].startswith("in room 'Bedroom', storey 'Upper'"), reasons
    assert "no stair, ramp or steps join storey 'Upper' (floor at +3.00 m) to storey " \
        "'Ground' (floor at +0.00 m)" in reasons[0], reasons


def test_a_room_behind_a_door_drawn_as_a_wall_says_so_and_names_the_door() -> None:
    """Two rooms; the wall between them has a doorway closed by a leaf the walk does not
    open (a door of a plain mesh that was not recognised)."""
    boxes = _shell(8.0, 4.0, 2.6)
    boxes += [((0.0, 0.0, -0.2), (8.0, 4.0, 0.0)),
              ((3.9, 0.0, 0.0), (4.1, 1.5, 2.6)), ((3.9, 2.4, 0.0), (4.1, 4.0, 2.6)),
              ((3.9, 1.5, 2.1), (4.1, 2.4, 2.6)), ((3.98, 1.5, 0.0), (4.02, 2.4, 2.1))]
    stations = [(2.0, 2.0, 1.5), (6.0, 2.0, 1.5)]
    unreachable, reasons = _route(boxes, stations)
    assert unreachable == (2,) or unreachable == (1,)
    assert "a wall stands between them" in reasons[0] and "no doorway" in reasons[0], reasons
    door = Places(doors=(("Door 7 (IfcDoor)", (4.11, 1.63, 0.0), (4.15, 2.53, 2.1)),))
    _, reasons = _route(boxes, stations, door)
    assert "through door 'Door 7 (IfcDoor)'" in reasons[0], reasons
    # the model sets the door 0.6 m up, at another level's height (Renga's door from its
    # stair landing): the door is named with its sill's height over the floors on both
    # sides, which meet at the same height
    raised = Places(doors=(("Door 7 (IfcDoor)", (4.11, 1.63, 0.6), (4.15, 2.53, 2.7)),))
    _, reasons = _route(boxes, stations, raised)
    assert "through door 'Door 7 (IfcDoor)'" in reasons[0], reasons
    assert "sets that door's sill at +0.60 m, 0.60 m above this floor (+0.00 m) and 0.60 m " \
        "above the route's floor on its other side (+0.00 m)" in reasons[0], reasons
    assert "no step is missing" in reasons[0], reasons


def test_a_room_behind_an_opening_set_above_both_floors_gives_its_sill() -> None:
    """Two rooms at the same height; the only opening in the wall between them, 0.9 m
    wide and 2.1 m high with its leaf, starts 0.6 m above both floors, wall under it (a
    door set at another level's height). A plain mesh names no door: the opening is
    found in the wall, with its sill."""
    boxes = _shell(8.0, 4.0, 3.0)
    boxes += [((0.0, 0.0, -0.2), (8.0, 4.0, 0.0)),
              ((3.9, 0.0, 0.0), (4.1, 1.5, 3.0)), ((3.9, 2.4, 0.0), (4.1, 4.0, 3.0)),
              ((3.9, 1.5, 0.0), (4.1, 2.4, 0.6)), ((3.9, 1.5, 2.7), (4.1, 2.4, 3.0)),
              ((3.98, 1.5, 0.6), (4.02, 2.4, 2.7))]
    unreachable, reasons = _route(boxes, [(2.0, 2.0, 1.5), (6.0, 2.0, 1.5)])
    assert unreachable == (2,) or unreachable == (1,)
    assert "the opening of door height in it" in reasons[0], reasons
    assert "has its sill at +0.60 m, 0.60 m above this floor (+0.00 m) and 0.60 m above " \
        "the route's floor on its other side (+0.00 m), with wall under it" in reasons[0]
    assert "no step is missing" in reasons[0], reasons
    # the same wall with a window 1 m up and 1.2 m high: not of door height, a wall
    boxes[-3:] = [((3.9, 1.5, 0.0), (4.1, 2.4, 1.0)), ((3.9, 1.5, 2.2), (4.1, 2.4, 3.0)),
                  ((3.98, 1.5, 1.0), (4.02, 2.4, 2.2))]
    _, reasons = _route(boxes, [(2.0, 2.0, 1.5), (6.0, 2.0, 1.5)])
    assert "a wall stands between them" in reasons[0] and "no doorway" in reasons[0], reasons


def test_a_door_beside_the_wall_that_closes_a_room_is_not_named() -> None:
    """A shallow closet whose doorway opens to the west room, and behind its back wall,
    0.3 m from the door, a room with no way in (Lantern Hollow: a closet's sliding door
    beside the partition that closes the room behind). The wall is named, not the door,
    whose opening is free."""
    boxes = _shell(8.0, 4.0, 2.6)
    boxes += [((0.0, 0.0, -0.2), (8.0, 4.0, 0.0)),
              # the closet's front wall, with a doorway at y in [0.2, 1.1]
              ((3.9, 0.0, 0.0), (4.1, 0.2, 2.6)), ((3.9, 1.1, 0.0), (4.1, 4.0, 2.6)),
              ((3.9, 0.2, 2.1), (4.1, 1.1, 2.6)),
              # its back wall, solid
              ((4.4, 0.0, 0.0), (4.6, 4.0, 2.6))]
    door = Places(doors=(("Closet door (IfcDoor)", (4.11, 0.33, 0.0), (4.15, 1.23, 2.1)),))
    unreachable, reasons = _route(boxes, [(2.0, 2.0, 1.5), (6.0, 2.0, 1.5)], door)
    assert unreachable == (2,)
    assert "Closet door" not in reasons[0], reasons
    assert "a wall stands between them" in reasons[0] and "no doorway" in reasons[0], reasons


def test_a_floor_a_step_too_high_above_the_rest_gives_the_step() -> None:
    """A 6 x 4 m room whose east half is a 0.6 m podium with no step up to it."""
    boxes = _shell(6.0, 4.0, 3.0)
    boxes += [((0.0, 0.0, -0.2), (6.0, 4.0, 0.0)), ((3.0, 0.0, 0.0), (6.0, 4.0, 0.6))]
    unreachable, reasons = _route(boxes, [(1.0, 2.0, 1.5), (1.5, 1.0, 1.5),
                                          (5.0, 2.0, 2.1)])
    assert unreachable == (3,)
    assert "with a step of 0.60 m (down to +0.00 m)" in reasons[0], reasons
    assert "no stair or steps are modelled there" in reasons[0]


def test_a_station_under_a_low_ceiling_gives_the_head_room() -> None:
    """A room whose west 2 m have a 1.4 m high ceiling (a duct box over the floor)."""
    boxes = _shell(6.0, 4.0, 3.0)
    boxes += [((0.0, 0.0, -0.2), (6.0, 4.0, 0.0)), ((0.0, 0.0, 1.4), (2.0, 4.0, 3.0))]
    unreachable, reasons = _route(boxes, [(4.0, 2.0, 1.5), (5.0, 1.0, 1.5),
                                          (1.0, 2.0, 1.2)])
    assert unreachable == (3,)
    assert reasons[0].startswith("no floor a person can walk on under it: only 1.40 m is "
                                 "free over its floor"), reasons


@pytest.mark.parametrize("reach", [1, 2])
def test_the_walk_links_every_two_samples_of_neighbouring_columns_a_step_apart(reach: int
                                                                                ) -> None:
    """The walk graph's links: every two floor samples whose columns are neighbours (or two
    columns apart along the same directions) and whose heights differ by at most a step,
    each pair once, as a search of every pair finds them; several surfaces in a column
    (a floor, a stair's flight, the slab above) link only to those a step away."""
    from planner.walkgraph import STEP_M, _neighbour_pairs

    rng = np.random.default_rng(5)
    n = 3_000
    ix, iy = rng.integers(-20, 20, n), rng.integers(-10, 30, n)
    z = rng.choice([0.0, 0.15, 0.3, 2.9], n) + rng.normal(0.0, 0.02, n)
    xyz = np.stack([ix * 0.25, iy * 0.25, z], axis=1)
    a, b = _neighbour_pairs(xyz, ix, iy, reach)
    found = set(zip(a.tolist(), b.tolist(), strict=True))
    assert len(found) == len(a)  # each pair once
    dx, dy = ix[None, :] - ix[:, None], iy[None, :] - iy[:, None]
    offsets = {(reach, 0), (0, reach), (reach, reach), (reach, -reach)}
    linked = np.zeros((n, n), bool)
    for ox, oy in offsets:
        linked |= (dx == ox) & (dy == oy)
    linked &= np.abs(z[None, :] - z[:, None]) <= STEP_M
    assert found == set(zip(*np.nonzero(linked), strict=True))
    assert len(found) > 1_000
    # direction by direction, each one's pairs by their first sample
    assert (np.diff(a) < 0).sum() <= 3


def test_a_room_whose_door_leads_to_no_floor_names_the_door_and_the_drop() -> None:
    """An architect's model without its slab: the east room's floor lies 0.6 m under the
    west room's and under the door between them (no step modelled). The east room is cut
    off, and its reason names the door, where it is, its sill and its height over the
    room's floor."""
    boxes = _shell(8.0, 4.0, 2.6)
    boxes += [((0.0, 0.0, -0.2), (4.0, 4.0, 0.0)), ((4.0, 0.0, -0.8), (8.0, 4.0, -0.6)),
              ((3.9, 0.0, -0.6), (4.1, 1.5, 2.6)), ((3.9, 2.4, -0.6), (4.1, 4.0, 2.6)),
              ((3.9, 1.5, 2.1), (4.1, 2.4, 2.6)), ((3.9, 1.5, -0.6), (4.1, 2.4, 0.0))]
    door = Places(doors=(("Door 9 (IfcDoor)", (4.03, 1.63, 0.0), (4.23, 2.53, 2.1)),))
    unreachable, reasons = _route(boxes, [(2.0, 2.0, 1.5), (6.0, 2.0, 0.9)], door)
    assert unreachable == (2,)
    assert "its door 'Door 9 (IfcDoor)' at (4.13, 2.08), sill at +0.00 m, stands 0.60 m over " \
        "this part's floor (-0.60 m) at (4.48, 2.08), and no step or stair is modelled up to " \
        "its sill" in reasons[0], reasons
    # without the door in the model, no door is named
    _, reasons = _route(boxes, [(2.0, 2.0, 1.5), (6.0, 2.0, 0.9)])
    assert "its door" not in reasons[0], reasons
