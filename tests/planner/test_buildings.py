"""Real buildings: every storey gets candidates, the route goes through doors, up stairs
and around the outside, and no leg crosses a wall.

The generated office (``tests/planner/buildings.py``) and the shared IFC houses, as IFC
and as plain meshes exported from them. Legs are checked against the model's faces other
than doors with a float64 segment test written here (not Embree), at knee height.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

from planner.candidates.grid import CandidateSet, generate_grid, levels_line
from planner.io.readers import read_scene
from planner.limits import FaceLimits
from planner.parameters import PlanSpec
from planner.rays import RayCaster, make_ray_caster
from planner.scene import Scene, build_scene
from planner.survey.route import Route, plan_route
from planner.walkgraph import build_walk_graph, door_faces
from tests.planner import buildings
from tests.planner.buildings import (
    CORRIDOR_Y_M,
    ROOM_X_M,
    ROOM_Y_M,
    STOREY_M,
    export_plain_mesh,
    office_building,
    office_parts,
    units,
)
from tests.planner.ifc_models import read_ifc_once
from tests.planner.survey_scenes import boxes_scene, room_shell

FLOORS, ROOMS = 2, 2


# a float64 reference for "the leg crosses no wall" -------------------------------------------


def segments_hit(a: NDArray[np.float64], b: NDArray[np.float64],
                 triangles: NDArray[np.float64]) -> NDArray[np.bool_]:
    """(K,) bool: segment (K, 3) a -> (K, 3) b crosses one of the (T, 3, 3) triangles
    (Möller-Trumbore in float64). Only a crossing through a face's inside counts: a
    segment that grazes a wall's corner edge exactly (the walk grid is aligned with the
    walls of a generated model) or lies in a face's plane is decided by rounding, in
    Embree's float32 as here."""
    hit = np.zeros(len(a), bool)
    v0 = triangles[:, 0]
    e1, e2 = triangles[:, 1] - v0, triangles[:, 2] - v0
    t_lo, t_hi = triangles.min(axis=1), triangles.max(axis=1)
    eps = 1e-6
    for first in range(0, len(a), 32):  # 32 segments against the triangles near them
        sa, sb = a[first:first + 32], b[first:first + 32]
        near = ((t_hi >= np.minimum(sa, sb).min(axis=0))
                & (t_lo <= np.maximum(sa, sb).max(axis=0))).all(axis=1)
        v, f1, f2 = v0[near], e1[near], e2[near]
        d = (sb - sa)[:, None, :]  # (k, 1, 3)
        p = np.cross(d, f2[None])  # (k, t, 3)
        det = np.einsum("tc,ktc->kt", f1, p)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        offset = sa[:, None, :] - v[None]  # (k, t, 3)
        u = np.einsum("ktc,ktc->kt", offset, p) * inv
        q = np.cross(offset, f1[None])
        w = np.einsum("ktc,kc->kt", q, sb - sa) * inv
        t = np.einsum("tc,ktc->kt", f2, q) * inv
        hit[first:first + 32] = (ok & (u > eps) & (w > eps) & (u + w < 1 - eps)
                                 & (t > eps) & (t < 1 - eps)).any(axis=1)
    return hit


def assert_legs_in_free_space(route: Route, triangles: NDArray[np.float64]) -> None:
    """Every leg's segments (points at knee height) cross none of ``triangles``."""
    starts, ends = [], []
    for leg in route.legs:
        path = np.asarray(leg.path)
        starts.append(path[:-1])
        ends.append(path[1:])
    a, b = np.concatenate(starts), np.concatenate(ends)
    moving = np.linalg.norm(b - a, axis=1) > 1e-9
    a, b = a[moving], b[moving]
    crossing = segments_hit(a, b, triangles)
    assert not crossing.any(), f"{crossing.sum()} leg segments cross a wall, e.g. " \
        f"{a[crossing][0].round(3).tolist()} -> {b[crossing][0].round(3).tolist()}"


def walk(scene: Scene, caster: RayCaster, stations: NDArray[np.float64]) -> Route:
    """The route over ``stations`` as the survey walks it (doors open)."""
    walk_caster = make_ray_caster(scene, ~door_faces(scene, caster))
    return plan_route(build_walk_graph(scene, walk_caster), walk_caster, stations, None)


# the generated office ------------------------------------------------------------------------


@pytest.fixture(scope="module")
def office() -> Scene:
    mesh = office_building(FLOORS, ROOMS)
    return build_scene(np.asarray(mesh.vertices), np.asarray(mesh.faces))


@pytest.fixture(scope="module")
def office_caster(office: Scene) -> RayCaster:
    return make_ray_caster(office, np.ones(office.n_faces, bool))


def leaf_faces(scene: Scene) -> NDArray[np.bool_]:
    """(F,) bool: the faces of the office's door leaves, from how it was generated (boxes,
    then leaves, 12 triangles a box when not split)."""
    boxes, leaves, _ = office_parts(FLOORS, ROOMS)
    result = np.zeros(scene.n_faces, bool)
    result[12 * len(boxes):12 * (len(boxes) + len(leaves))] = True
    return result


def test_the_closed_door_leaves_of_a_plain_mesh_are_found_and_nothing_else(
        office: Scene, office_caster: RayCaster) -> None:
    found = door_faces(office, office_caster)
    assert found.sum() > 0
    np.testing.assert_array_equal(found, leaf_faces(office))


def test_every_storey_of_the_office_gets_candidates_and_desks_are_listed_not_planned(
        office: Scene, office_caster: RayCaster) -> None:
    spec = PlanSpec(grid_spacing_m=0.5)
    candidates = generate_grid(office, spec, office_caster)
    assert candidates.levels is not None
    storeys = [lv for lv in candidates.levels if "excluded" not in lv]
    assert [lv["floor_z_m"] for lv in storeys] == [0.0, STOREY_M]
    floor_z = candidates.positions[:, 2] - spec.scanner_height_m
    for unit in units(ROOMS):
        for k in range(FLOORS):
            for room in range(ROOMS):  # every room, behind its closed door, on every storey
                x0 = room * ROOM_X_M
                in_room = ((np.abs(floor_z - k * STOREY_M) < 0.01)
                           & (candidates.positions[:, 0] > x0)
                           & (candidates.positions[:, 0] < x0 + ROOM_X_M)
                           & (candidates.positions[:, 1] > unit.origin_y_m)
                           & (candidates.positions[:, 1] < unit.origin_y_m + ROOM_Y_M))
                assert in_room.sum() >= 4, (unit, k, room)
    desks = [lv for lv in candidates.levels if str(lv.get("excluded")).startswith("raised")
             and abs(float(str(lv["floor_z_m"])) % STOREY_M - buildings.DESK_M[2]) < 0.01]
    assert desks, candidates.levels
    line = levels_line(candidates.levels)
    assert line is not None and line.startswith("2 storeys planned (+0.00 m: ")


def office_stations() -> NDArray[np.float64]:
    """A station in every room, corridor and stair hall of both units on every storey, at
    scanner height, clear of the desks."""
    points = []
    for unit in units(ROOMS):
        oy = unit.origin_y_m
        for k in range(FLOORS):
            z = k * STOREY_M + 1.5
            for room in range(ROOMS):
                x = room * ROOM_X_M + 1.0
                points += [(x, oy + 1.0, z), (x, oy + 2 * ROOM_Y_M + CORRIDOR_Y_M - 1.0, z)]
            points.append((1.0, oy + ROOM_Y_M + CORRIDOR_Y_M / 2, z))  # corridor
            points.append((unit.length_x_m - 0.6, oy + 6.0, z))  # stair hall
    return np.asarray(points)


def test_the_route_reaches_every_room_of_both_units_through_doors_stairs_and_outside(
        office: Scene, office_caster: RayCaster) -> None:
    stations = office_stations()
    route = walk(office, office_caster, stations)
    assert route.unreachable == () and route.steps == ()
    assert sorted(route.visits) == list(range(1, len(stations) + 1))
    path = np.concatenate([np.asarray(leg.path) for leg in route.legs])
    unit_a, unit_b = units(ROOMS)
    yard = (path[:, 1] > unit_a.origin_y_m + 2 * ROOM_Y_M + CORRIDOR_Y_M + 0.3) \
        & (path[:, 1] < unit_b.origin_y_m - 0.3)
    assert yard.any(), "the units are joined only outside: some leg crosses the yard"
    climbing = (path[:, 2] > 0.5 + 0.3) & (path[:, 2] < STOREY_M + 0.5 - 0.3)
    for unit in (unit_a, unit_b):  # steps in unit A, a sloped stair in unit B
        in_unit = (path[:, 1] > unit.origin_y_m) & (path[:, 1] < unit.origin_y_m + 12)
        assert (climbing & in_unit).any(), unit
    assert_legs_in_free_space(route, office.triangles[~leaf_faces(office)])


def test_a_platform_reached_only_by_a_ladder_is_a_storey_and_its_station_says_why() -> None:
    """A 6 x 3 m hall, 5 m high, with a 3 x 3 m platform at 2.2 m and no stair to it."""
    boxes = room_shell(0.0, 6.0, 0.0, 3.0, height_m=5.0)
    boxes.append(((3.0, 0.0, 2.0), (6.0, 3.0, 2.2)))
    scene = boxes_scene(boxes)
    caster = make_ray_caster(scene, np.ones(scene.n_faces, bool))
    candidates = generate_grid(scene, PlanSpec(grid_spacing_m=0.5), caster)
    heights = {round(float(z), 2) for z in candidates.positions[:, 2]}
    assert heights == {1.5, 3.7}  # the hall floor and the platform
    route = walk(scene, caster, np.array([[1.0, 1.5, 1.5], [2.5, 1.5, 1.5], [4.5, 1.5, 3.7]]))
    # the platform's station is walked after a step the crew makes on site (the ladder)
    assert route.unreachable == () and route.visits[-1] == 3
    (step,) = route.steps
    assert step.end == 3 and "ladder" in step.reason
    assert route.to_dict()["steps_between_parts"][0]["note"].endswith(step.reason)


# the shared IFC houses, as IFC and as plain meshes ------------------------------------------

HOUSES = {"AC20-FZK-Haus": 2, "IfcOpenHouse_IFC4": 1}  # storeys with floor to plan


@pytest.fixture(scope="module")
def plain_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("plain")


def ifc_reading(path: Path) -> Scene:
    """The IFC model as IfcOpenShell reads it (once a session: seconds for FZK)."""
    return read_ifc_once(path)


def house_candidates(scene: Scene, spec: PlanSpec, caster: RayCaster) -> CandidateSet:
    if scene.metadata.get("spaces"):
        from planner.candidates.rooms import room_candidates

        return room_candidates(scene, spec, caster)
    return generate_grid(scene, spec, caster)


@pytest.mark.parametrize("form", ["ifc", "obj", "ply"])
@pytest.mark.parametrize("house", sorted(HOUSES))
def test_the_houses_get_every_storey_and_a_route_to_every_station(
        house: str, form: str, scenes_dir: Path, plain_dir: Path) -> None:
    pytest.importorskip("ifcopenshell")
    ifc = scenes_dir / f"{house}.ifc"
    path = ifc if form == "ifc" else plain_dir / f"{house}.{form}"
    if not path.exists():
        export_plain_mesh(ifc, path, ifc_reading(ifc))
    spec = PlanSpec(grid_spacing_m=1.0, max_edge_m=0.5)
    if form == "ifc":  # read_scene's IFC path: IfcOpenShell's reading, split as needed
        scene = dataclasses.replace(ifc_reading(ifc), split_max_edge_m=spec.max_edge_m)
    else:
        scene = read_scene(path, max_edge_m=spec.max_edge_m, split_faces="as_needed")
    if form != "ifc":
        assert not scene.elements and scene.groups == ("",)  # no classes, no groups
    caster = make_ray_caster(scene, FaceLimits.from_spec(spec, scene).occludes,
                             file_faces=True)
    candidates = house_candidates(scene, spec, caster)
    floor_z = np.round(candidates.positions[:, 2] - spec.scanner_height_m, 1)
    storeys = np.unique(floor_z[floor_z > -0.5])
    assert len(storeys) == HOUSES[house], storeys
    # a station on each storey's candidates, spread: every one must be walked to
    stations = np.concatenate([candidates.positions[floor_z == z][::3] for z in storeys])
    route = walk(scene, caster, stations)
    assert route.unreachable == (), list(zip(route.unreachable, route.unreachable_reasons,
                                             strict=True))
    assert route.steps == (), route.steps
    # doors, independently of the mesh's door rule: the IFC model's door faces
    reference = ifc_reading(ifc)
    door = np.array([e.ifc_class == "IfcDoor" for e in reference.elements] + [False])
    walls = np.asarray(reference.vertices)[np.asarray(reference.faces)[
        ~door[reference.face_element]]]
    assert_legs_in_free_space(route, walls)
