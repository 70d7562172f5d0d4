"""Real models as they arrive: up axes, scans, units, and the candidate stage's spatial queries.

hall-small is planned with ``max_edge_m`` 0.5 to stay fast; every file written here is
generated with trimesh in ``tmp_path`` from the shared OBJ.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from planner.candidates.grid import generate_grid, inside_closed_groups, on_the_building
from planner.candidates.scratch import kept_or_none, stage_scratch
from planner.candidates.winding import (
    _Cells,
    _direct,
    coordinate_ranks,
    winding_cells,
    winding_numbers,
)
from planner.errors import ParameterError
from planner.io.readers import read_scene
from planner.outputs.report import plan_document, write_outputs
from planner.parameters import PlanSpec
from planner.pipeline import plan
from planner.rays import make_ray_caster
from planner.scene import Scene, build_scene, remesh
from tests.planner.scenes import scene_of

EDGE_M = 0.5
# model_gltf = Y_UP @ model_zup: the usual Z-up to Y-up turn (x stays, z becomes y)
Y_UP = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])


def _hall(scenes_dir: Path) -> trimesh.Trimesh:
    mesh = trimesh.load(scenes_dir / "hall-small" / "hall.obj", process=False,
                        maintain_order=True, force="mesh")
    assert isinstance(mesh, trimesh.Trimesh)
    return mesh


def _stations(path: Path, up_axis: str | None) -> tuple[np.ndarray, float, dict[str, object]]:
    scene = read_scene(path, max_edge_m=EDGE_M, up_axis=up_axis)
    document = plan_document(plan(scene, PlanSpec(max_edge_m=EDGE_M, up_axis=up_axis)))
    positions = np.array([s["position"] for s in document["stations"]])
    return positions, document["totals"]["covered_area_m2"], document["scene"]


@pytest.fixture(scope="module")
def zup_plan(scenes_dir: Path) -> tuple[np.ndarray, float, dict[str, object]]:
    return _stations(scenes_dir / "hall-small" / "hall.obj", None)


def test_y_up_glb_plans_like_the_z_up_obj_in_its_own_coordinates(
        scenes_dir: Path, tmp_path: Path, zup_plan: tuple[np.ndarray, float, dict[str, object]]
) -> None:
    mesh = _hall(scenes_dir)
    path = tmp_path / "hall.glb"
    trimesh.Trimesh(mesh.vertices @ Y_UP.T, mesh.faces, process=False).export(path)
    stations, covered, scene = _stations(path, None)  # glTF's own +Y, no parameter needed
    expected, expected_covered, _ = zup_plan
    np.testing.assert_allclose(stations, expected @ Y_UP.T, atol=1e-6)
    assert covered == pytest.approx(expected_covered, rel=1e-9)
    assert scene["orientation"]["up_axis"] == "+Y"  # type: ignore[index]
    # every station stands on the model's floor: its y (glTF up) is the scanner height
    np.testing.assert_allclose(stations[:, 1], 1.5, atol=1e-6)


def test_auto_levels_a_rotated_ply_and_gives_the_same_stations(
        scenes_dir: Path, tmp_path: Path, zup_plan: tuple[np.ndarray, float, dict[str, object]]
) -> None:
    mesh = _hall(scenes_dir)
    # tilted and turned by 40 degrees about an arbitrary axis: auto keeps the heading
    # nearest the model's own, which is exact below 45 degrees
    axis = np.array([0.3, -0.5, 0.8])
    turn = Rotation.from_rotvec(np.radians(40.0) * axis / np.linalg.norm(axis)).as_matrix()
    path = tmp_path / "hall.ply"
    trimesh.Trimesh(mesh.vertices @ turn.T, mesh.faces, process=False).export(path)
    stations, covered, scene = _stations(path, "auto")
    expected, expected_covered, _ = zup_plan
    # PLY stores float32 coordinates: micrometres of rounding
    np.testing.assert_allclose(stations, expected @ turn.T, atol=1e-4)
    assert covered == pytest.approx(expected_covered, rel=0.005)
    orientation = scene["orientation"]
    assert isinstance(orientation, dict)
    np.testing.assert_allclose(orientation["up_in_model"], turn[:, 2], atol=1e-5)
    assert 0 < orientation["confidence"] <= 1


@pytest.mark.parametrize("name", ["hall-small/hall.obj", "AC20-FZK-Haus.obj",
                                  "IfcOpenHouse_IFC4.obj"])
def test_auto_leaves_a_z_up_model_alone(scenes_dir: Path, name: str) -> None:
    # FZK-Haus has railings and window bars a little off its walls, IfcOpenHouse a sloped
    # site larger than its floors and roofs with outward normals: up and heading are
    # refined down to the plumb walls themselves
    scene = read_scene(scenes_dir / name, max_edge_m=None, up_axis="auto")
    assert scene.metadata["orientation"]["rotation"] is None
    original = read_scene(scenes_dir / name, max_edge_m=None)
    assert np.array_equal(scene.vertices, original.vertices)


def test_outputs_and_glb_root_are_in_model_coordinates(
        scenes_dir: Path, tmp_path: Path) -> None:
    mesh = _hall(scenes_dir)
    path = tmp_path / "hall.glb"
    trimesh.Trimesh(mesh.vertices @ Y_UP.T, mesh.faces, process=False).export(path)
    scene = read_scene(path, max_edge_m=EDGE_M)
    # glb_compression none: trimesh has no meshopt decoder
    result = plan(scene, PlanSpec(max_edge_m=EDGE_M, glb_compression="none"))
    out = write_outputs(result, tmp_path / "out")
    assert out
    rows = (tmp_path / "out" / "stations.csv").read_text().splitlines()[1:]
    plan_json = json.loads((tmp_path / "out" / "plan.json").read_text())
    csv_xyz = np.array([[float(v) for v in row.split(",")[1:4]] for row in rows])
    np.testing.assert_allclose(csv_xyz, [s["position"] for s in plan_json["stations"]])
    # the glb's root undoes the levelling: loaded back, the model lies where the input did
    loaded = trimesh.load(tmp_path / "out" / "coverage.glb", force="mesh")
    assert isinstance(loaded, trimesh.Trimesh)
    given = np.asarray(mesh.vertices) @ Y_UP.T
    np.testing.assert_allclose(loaded.bounds, [given.min(axis=0), given.max(axis=0)],
                               atol=1e-5)


def test_the_copy_room_scan_plans_with_auto(scenes_dir: Path) -> None:
    scene = read_scene(scenes_dir / "copyroom_scan_c2000.ply", up_axis="auto")
    result = plan(scene, PlanSpec(up_axis="auto"))
    assert len(result.chosen.stations) >= 1
    # candidates stand scanner_height_m above the scan's floor: the lowest large surface
    floor_z = result.candidates.positions[:, 2] - 1.5
    lowest = float(scene.bounds[0, 2])
    assert np.all(np.abs(floor_z - lowest) < 0.3)


@pytest.mark.parametrize(("name", "value"), [
    ("up_axis", "up"), ("up_axis", "Z"), ("up_axis", "+z"), ("floor_levels", "every"),
])
def test_an_unknown_choice_names_the_parameter(name: str, value: str) -> None:
    with pytest.raises(ParameterError, match=f"^{name}: "):
        PlanSpec.from_mapping({name: value})


def test_an_ifc_model_is_z_up(scenes_dir: Path) -> None:
    with pytest.raises(ParameterError, match="up_axis"):
        read_scene(scenes_dir / "AC20-FZK-Haus.ifc", up_axis="+Y")


def test_auto_says_when_it_cannot_tell(tmp_path: Path) -> None:
    path = tmp_path / "cube.obj"
    trimesh.creation.box(extents=(3.0, 3.0, 3.0)).export(path)  # no side is special
    with pytest.raises(ParameterError, match="up_axis: auto cannot tell"):
        read_scene(path, up_axis="auto")


def test_a_model_in_millimetres_gets_a_unit_warning(scenes_dir: Path, tmp_path: Path) -> None:
    mesh = _hall(scenes_dir)
    path = tmp_path / "hall_mm.obj"
    trimesh.Trimesh(mesh.vertices * 1000.0, mesh.faces, process=False).export(path)
    scene = read_scene(path, max_edge_m=None)
    assert any("unit_scale 0.001" in w for w in scene.metadata["warnings"])
    assert scene.summary()["warnings"] == scene.metadata["warnings"]  # the upload shows it
    fine = read_scene(path, max_edge_m=None, unit_scale=0.001)
    assert "warnings" not in fine.metadata


def test_winding_numbers_through_cells_equal_the_direct_sum(scenes_dir: Path) -> None:
    scene = read_scene(scenes_dir / "hall-full" / "hall.obj", max_edge_m=None)
    one_group = build_scene(scene.vertices, scene.faces)  # a scan has a single group
    rng = np.random.default_rng(7)
    lo, hi = one_group.bounds
    points = lo + rng.random((200, 3)) * (hi - lo)
    direct = _direct(one_group.triangles, points)
    cells = _Cells.build(one_group.triangles)
    assert len(cells.caps) < one_group.n_faces  # far cells cost their boundary only
    np.testing.assert_allclose(cells.winding(points), direct, atol=1e-9)
    assert ((direct > 0.5) | (direct < -0.5)).any()  # the sample hits inside and outside


def test_winding_cells_from_the_meshs_vertex_ranks_are_the_cells_of_the_corners(
        scenes_dir: Path) -> None:
    """The cells built with the corners ordered through the mesh's vertices (a vertex
    repeated at the same coordinates, as files have them, shares its rank) are the same
    arrays as those built from the corners alone, so every winding number is the same."""
    scene = read_scene(scenes_dir / "hall-full" / "hall.obj", max_edge_m=None)
    # every face with its own three vertices (a triangle soup), the first corners shared
    soup = scene.vertices[scene.faces].reshape(-1, 3)
    faces = np.arange(len(soup)).reshape(-1, 3)
    faces[: len(faces) // 2] = scene.faces[: len(faces) // 2]
    vertices = np.concatenate([scene.vertices, soup])
    faces[len(faces) // 2:] += len(scene.vertices)
    triangles = vertices[faces]
    alone = _Cells.build(triangles)
    ranked = winding_cells(triangles, coordinate_ranks(vertices)[faces])
    for name in ("triangles", "face_start", "caps", "cap_start", "lo", "hi"):
        assert np.array_equal(getattr(alone, name), getattr(ranked, name)), name
    rng = np.random.default_rng(3)
    lo, hi = scene.bounds
    points = lo + rng.random((50, 3)) * (hi - lo)
    assert np.array_equal(alone.winding(points), ranked.winding(points))


def test_the_candidate_stage_makes_what_it_derives_from_the_scene_once(
        scenes_dir: Path) -> None:
    """Within ``stage_scratch`` a closed group's winding cells, built for many points, answer
    the later calls (a few points too), and the building's upright samples are made once;
    every answer is the one made without them, and nothing is kept after the block."""
    scene = read_scene(scenes_dir / "hall-full" / "hall.obj", max_edge_m=None)
    # one group, turned inside out: the hall's air is inside it, its props are not
    one_group = build_scene(scene.vertices, np.ascontiguousarray(scene.faces[:, ::-1]))
    rng = np.random.default_rng(11)
    lo, hi = one_group.bounds
    points = lo + rng.random((400, 3)) * (hi - lo)
    few = points[:8]  # few enough to be summed directly
    np.testing.assert_allclose(winding_numbers(one_group.triangles, few),
                               _direct(one_group.triangles, few), atol=0, rtol=0)
    alone = inside_closed_groups(one_group, points), inside_closed_groups(one_group, few)
    spec = PlanSpec.from_mapping({})
    caster = make_ray_caster(one_group, np.ones(one_group.n_faces, bool))
    floors = np.full(len(points), lo[2])
    on_alone = on_the_building(one_group, spec, points, floors, caster)
    with stage_scratch(one_group):
        many = inside_closed_groups(one_group, points)
        assert kept_or_none(one_group, ("winding cells", 0)) is not None
        through_cells = inside_closed_groups(one_group, few)
        on_first = on_the_building(one_group, spec, points, floors, caster)
        on_again = on_the_building(one_group, spec, points, floors, caster)
    assert kept_or_none(one_group, ("winding cells", 0)) is None
    np.testing.assert_array_equal(many, alone[0])
    np.testing.assert_array_equal(through_cells, alone[1])
    assert alone[0].any() and not alone[0].all()
    np.testing.assert_array_equal(on_first, on_alone)
    np.testing.assert_array_equal(on_again, on_alone)


@pytest.mark.parametrize(("name", "considered", "kept", "dropped"), [
    # the grids generated before the candidate stage used spatial queries (commit 5e99982)
    ("hall-small", 99, 35, {"no_floor": 19, "blocked_above_floor": 6, "inside_geometry": 2,
                            "too_close": 37}),
    ("hall-full", 437, 228, {"no_floor": 41, "blocked_above_floor": 62, "inside_geometry": 5,
                             "too_close": 101}),
])
def test_generated_grids_are_unchanged(scenes_dir: Path, name: str, considered: int,
                                       kept: int, dropped: dict[str, int]) -> None:
    scene = read_scene(scenes_dir / name / "hall.obj")
    candidates = generate_grid(scene, PlanSpec(),
                               make_ray_caster(scene, np.ones(scene.n_faces, bool)))
    assert (candidates.considered, len(candidates)) == (considered, kept)
    assert {k: v for k, v in candidates.dropped.items() if v} == dropped


def _two_storeys() -> Scene:
    """A 10 x 6 m house, storeys of 3 m on 0.2 m slabs, a stair in a hole of the upper slab."""
    boxes: list[tuple[tuple[float, float, float], tuple[float, float, float]]] = [
        ((0, 0, -0.2), (10, 6, 0)),  # ground slab
        ((0, 1.5, 3.0), (10, 6, 3.2)),  # upper slab, stair hole along y < 1.5 ...
        ((0, 0, 3.0), (6, 1.5, 3.2)),  # ... for x > 6
        ((0, 0, 6.2), (10, 6, 6.4)),  # roof
        ((-0.2, -0.2, -0.2), (0, 6.2, 6.4)), ((10, -0.2, -0.2), (10.2, 6.2, 6.4)),
        ((0, -0.2, -0.2), (10, 0, 6.4)), ((0, 6, -0.2), (10, 6.2, 6.4)),
    ]
    rise = 3.2 / 11
    boxes += [((6 + 0.36 * k, 0, 0), (6 + 0.36 * (k + 1), 1.5, rise * (k + 1)))
              for k in range(11)]
    parts = []
    for lo, hi in boxes:
        box = trimesh.creation.box(bounds=[lo, hi])
        parts.append((np.asarray(box.vertices), np.asarray(box.faces)))
    return scene_of(*parts)


def _two_storeys_on_a_ramp() -> Scene:
    """A 14 x 6 m house, storeys of 3 m on 0.2 m slabs, joined by a ramp (a wedge rising
    3.2 m over 7 m, 24.6 degrees: walkable, and steeper than 1:20) in a hole of the upper
    slab along y < 1.5 for x > 6."""
    boxes: list[tuple[tuple[float, float, float], tuple[float, float, float]]] = [
        ((0, 0, -0.2), (14, 6, 0)), ((0, 1.5, 3.0), (14, 6, 3.2)),
        ((0, 0, 3.0), (6, 1.5, 3.2)), ((13, 0, 3.0), (14, 1.5, 3.2)),
        ((0, 0, 6.2), (14, 6, 6.4)),
        ((-0.2, -0.2, -0.2), (0, 6.2, 6.4)), ((14, -0.2, -0.2), (14.2, 6.2, 6.4)),
        ((0, -0.2, -0.2), (14, 0, 6.4)), ((0, 6, -0.2), (14, 6.2, 6.4)),
    ]
    parts = []
    for lo, hi in boxes:
        box = trimesh.creation.box(bounds=[lo, hi])
        parts.append((np.asarray(box.vertices), np.asarray(box.faces)))
    wedge = trimesh.convex.convex_hull(np.array(
        [[6, 0, 0], [13, 0, 0], [13, 0, 3.2], [6, 1.5, 0], [13, 1.5, 0], [13, 1.5, 3.2]],
        float))
    parts.append((np.asarray(wedge.vertices), np.asarray(wedge.faces)))
    return scene_of(*parts)


@pytest.mark.parametrize("floor_levels", ["walkable", "all"])
def test_a_ramp_between_two_storeys_joins_neither_to_the_other(floor_levels: str) -> None:
    """With "all" or "walkable" the floors are grouped into levels as the storeys are: a
    ramp fills every height between the two floors, so heights alone made one level of
    the house; level surfaces only give the two floors as two levels, the ramp apart."""
    scene = remesh(_two_storeys_on_a_ramp(), 1.0)
    spec = PlanSpec.from_mapping({"floor_levels": floor_levels, "grid_spacing_m": 0.25,
                                  "max_edge_m": 1.0})
    candidates = generate_grid(scene, spec, make_ray_caster(scene, np.ones(scene.n_faces,
                                                                            bool)))
    levels = candidates.levels
    assert levels is not None
    floors = [float(str(level["floor_z_m"])) for level in levels]
    assert 0.0 in floors and 3.2 in floors, levels
    # each floor's candidates lie on that floor, none on the ramp between
    by_name = {str(level["name"]): float(str(level["floor_z_m"])) for level in levels}
    floor_z = candidates.positions[:, 2] - spec.scanner_height_m
    for z, label in zip(floor_z, candidates.labels, strict=True):
        if by_name[label["storey"]] in (0.0, 3.2):
            assert abs(z - by_name[label["storey"]]) < 0.01


@pytest.mark.parametrize("floor_levels", ["storeys", "walkable", "all"])
def test_a_two_storey_mesh_gets_candidates_and_stations_on_both_storeys(
        floor_levels: str) -> None:
    """By default ("storeys") the upper storey counts because it has floor and head room
    and is no furniture; with "walkable" because the stair reaches it."""
    scene = _two_storeys()
    spec = PlanSpec.from_mapping({"floor_levels": floor_levels, "grid_spacing_m": 1.0,
                                  "max_edge_m": 1.0})
    result = plan(remesh(scene, 1.0), spec)
    levels = result.candidates.summary()["levels"]
    assert isinstance(levels, list)
    levels = [level for level in levels if "excluded" not in level]  # stair treads
    assert [level["floor_z_m"] for level in levels] == [0.0, 3.2]
    assert all(level["candidates"] > 0 for level in levels)
    floors = result.candidates.positions[result.chosen.stations, 2] - 1.5
    assert set(np.round(floors, 3)) == {0.0, 3.2}
    # the labels name the level, as IFC storeys do, so preview.png draws a panel per level
    assert {label["storey"] for label in result.candidates.labels} == {
        level["name"] for level in levels}
