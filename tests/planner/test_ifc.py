"""IFC input through the real IfcOpenShell: reading, rooms, per-storey plans, BIM outputs.

The shared FZK-Haus is read once a session (tests.planner.ifc_models) and remeshed coarsely
(0.5 m) with a 1 m grid so that the module stays well under a minute on two cores.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh
from shapely import Polygon, intersects_xy

from planner.candidates.grid import DROP_REASONS
from planner.candidates.rooms import inside_elements, room_candidates
from planner.candidates.winding import winding_numbers
from planner.errors import NoCandidatesError, ParameterError, SceneError
from planner.io.ifc import geometry_library, read_ifc
from planner.io.readers import read_scene
from planner.limits import FaceLimits
from planner.outputs import bim
from planner.outputs.report import plan_document, write_outputs
from planner.parameters import PlanSpec
from planner.pipeline import PlanResult, plan
from planner.scene import Element, Scene, build_scene, remesh
from tests.planner.ifc_models import read_ifc_once
from tests.planner.ifc_parts import body_and_building, placed, room_shell

ifcopenshell = pytest.importorskip("ifcopenshell")

FZK = "AC20-FZK-Haus"
HOUSE = "IfcOpenHouse_IFC4"
ROOMS = {"Flur", "Buero", "Bad", "Schlafzimmer", "Wohnen", "Küche", "Galerie"}
EDGE_M = 0.5
GRID_M = 1.0


@pytest.fixture(scope="module")
def fzk_raw(scenes_dir: Path) -> Scene:
    return read_ifc_once(scenes_dir / f"{FZK}.ifc")


@pytest.fixture(scope="module")
def fzk(fzk_raw: Scene) -> Scene:
    return remesh(fzk_raw, EDGE_M)


@pytest.fixture(scope="module")
def reference(scenes_dir: Path) -> dict[str, Any]:
    data: dict[str, Any] = json.loads((scenes_dir / f"{FZK}.elements.json").read_text("utf-8"))
    return data


def _spec(**changes: Any) -> PlanSpec:
    return PlanSpec(max_edge_m=EDGE_M, grid_spacing_m=GRID_M, **changes)


def _caster(scene: Scene, spec: PlanSpec) -> object:
    from planner.rays.embree import EmbreeOcclusion

    return EmbreeOcclusion(scene, FaceLimits.from_spec(spec, scene).occludes)


# reading ---------------------------------------------------------------------------------


def test_fzk_elements_and_classes_match_the_reference_conversion(
    fzk_raw: Scene, reference: dict[str, Any]
) -> None:
    ours = Counter(fzk_raw.elements[e].ifc_class for e in fzk_raw.face_element)
    theirs: Counter[str] = Counter()
    for element in reference["elements"]:
        theirs[element["ifc_class"]] += element["face_count"]
    assert set(ours) == set(reference["classes"])
    for ifc_class, count in theirs.items():
        assert ours[ifc_class] == pytest.approx(count, rel=0.05), ifc_class
    assert {e.global_id for e in fzk_raw.elements} == {
        e["global_id"] for e in reference["elements"]}
    # sorted by (class, GlobalId), every face labelled, groups are classes (+ glazing)
    keys = [(e.ifc_class, e.global_id) for e in fzk_raw.elements]
    assert keys == sorted(keys)
    assert (fzk_raw.face_element >= 0).all()
    assert np.all(np.diff(fzk_raw.face_element) >= 0)
    assert {g.split("/")[0] for g in fzk_raw.groups} == set(reference["classes"])
    for f in (0, fzk_raw.n_faces // 2, fzk_raw.n_faces - 1):
        element = fzk_raw.elements[fzk_raw.face_element[f]]
        assert fzk_raw.groups[fzk_raw.face_group[f]].split("/")[0] == element.ifc_class
    assert fzk_raw.areas.sum() == pytest.approx(2051.13, rel=1e-3)


def test_fzk_metadata_has_storeys_rooms_and_defaults(fzk_raw: Scene) -> None:
    meta = fzk_raw.metadata
    assert meta["format"] == "ifc"
    assert meta["schema"] == "IFC4"
    assert meta["length_unit_scale"] == pytest.approx(1.0)
    assert [(s["name"], s["elevation_m"]) for s in meta["storeys"]] == [
        ("Erdgeschoss", 0.0), ("Dachgeschoss", 2.7)]
    spaces = meta["spaces"]
    assert {s["long_name"] for s in spaces} == ROOMS
    galerie = next(s for s in spaces if s["long_name"] == "Galerie")
    assert galerie["storey"] == "Dachgeschoss"
    assert galerie["floor_z_m"] == pytest.approx(2.7, abs=0.05)
    for space in spaces:
        polygon = Polygon(space["polygon"], space["holes"])
        assert polygon.is_valid and polygon.area == pytest.approx(space["area_m2"])
        assert 5 < space["area_m2"] < 150
    assert {e.storey for e in fzk_raw.elements if e.ifc_class == "IfcWindow"} == {
        "Erdgeschoss", "Dachgeschoss"}
    defaults = meta["default_group_requirements"]
    assert defaults["IfcWindow/glass"] == {"target": False, "occludes": False}
    assert defaults["IfcSite"] == {"target": False, "occludes": True}
    assert "IfcWallStandardCase" not in defaults


def test_glass_panes_neither_occlude_nor_count_by_default_and_can_be_overridden(
    fzk_raw: Scene,
) -> None:
    glass = fzk_raw.face_group == fzk_raw.groups.index("IfcWindow/glass")
    frames = fzk_raw.face_group == fzk_raw.groups.index("IfcWindow")
    site = fzk_raw.face_group == fzk_raw.groups.index("IfcSite")
    assert glass.any() and frames.any()
    limits = FaceLimits.from_spec(PlanSpec(), fzk_raw)
    assert not limits.target[glass].any() and not limits.occludes[glass].any()
    assert limits.target[frames].all() and limits.occludes[frames].all()
    assert not limits.target[site].any() and limits.occludes[site].all()
    # a user's entry for the panes, or for one window by GlobalId, wins over the default
    panes = FaceLimits.from_spec(
        PlanSpec.from_mapping({"group_requirements": {"IfcWindow/glass": {}}}), fzk_raw)
    assert panes.target[glass].all() and panes.occludes[glass].all()
    window = fzk_raw.elements[int(fzk_raw.face_element[np.flatnonzero(glass)[0]])]
    one = FaceLimits.from_spec(
        PlanSpec.from_mapping({"group_requirements": {window.global_id: {}}}), fzk_raw)
    own = fzk_raw.face_element == fzk_raw.elements.index(window)
    assert one.target[own & glass].all() and not one.target[glass & ~own].any()


def test_ifc_in_millimetres_gives_the_reference_mesh_in_metres(scenes_dir: Path) -> None:
    scene = read_ifc(scenes_dir / f"{HOUSE}.ifc")
    mesh: Any = trimesh.load(str(scenes_dir / f"{HOUSE}.ply"), process=False)
    assert scene.metadata["length_unit_scale"] == pytest.approx(0.001)
    np.testing.assert_allclose(scene.bounds, mesh.bounds, atol=1e-3)
    assert scene.areas.sum() == pytest.approx(mesh.area, rel=1e-3)
    assert scene.n_faces == pytest.approx(len(mesh.faces), rel=0.02)
    assert scene.metadata["spaces"] == []
    assert scene.metadata["default_group_requirements"]["IfcPlate/glass"] == {
        "target": False, "occludes": False}


def test_the_reader_uses_the_hybrid_kernel_and_it_gives_opencascades_elements(
        scenes_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # IfcOpenShell's has_geometry_library knows single libraries only: asked for the
    # hybrid's own name it says no, and every read fell back to OpenCASCADE alone
    assert geometry_library() == "hybrid-cgal-simple-opencascade"
    hybrid = read_ifc(scenes_dir / f"{HOUSE}.ifc")
    monkeypatch.setattr("planner.io.ifc.geometry_library", lambda: "opencascade")
    alone = read_ifc(scenes_dir / f"{HOUSE}.ifc")
    assert hybrid.elements == alone.elements
    assert hybrid.n_faces == alone.n_faces
    for e in range(len(hybrid.elements)):  # the same surfaces, element by element
        mine, theirs = hybrid.face_element == e, alone.face_element == e
        assert hybrid.areas[mine].sum() == pytest.approx(alone.areas[theirs].sum(), rel=1e-6)
        np.testing.assert_allclose(hybrid.triangles[mine].reshape(-1, 3).min(axis=0),
                                   alone.triangles[theirs].reshape(-1, 3).min(axis=0),
                                   atol=1e-6)


def test_read_scene_sniffs_ifc_and_remeshes_long_cad_triangles(scenes_dir: Path) -> None:
    scene = read_scene(scenes_dir / f"{HOUSE}.ifc", max_edge_m=1.0)
    edges = scene.triangles - np.roll(scene.triangles, 1, axis=1)
    assert np.linalg.norm(edges, axis=2).max() <= 1.0 + 1e-9
    assert scene.n_faces > 1098
    assert scene.metadata["format"] == "ifc"
    assert len(scene.elements) == 35


def test_the_files_triangles_and_elements_survive_remeshing(scenes_dir: Path) -> None:
    raw = read_ifc(scenes_dir / f"{HOUSE}.ifc")
    pieces = remesh(raw, 0.5)
    assert pieces.n_faces > raw.n_faces
    np.testing.assert_array_equal(pieces.file_triangles, raw.triangles)
    np.testing.assert_array_equal(pieces.on_file_faces(pieces.face_element), raw.face_element)
    # inside an element on the file's triangles is inside it on the pieces
    low, high = pieces.bounds
    points = np.random.default_rng(0).uniform(low, high, size=(200, 3))
    inside = np.zeros(len(points), bool)
    for e in range(len(pieces.elements)):
        own = pieces.face_element == e
        inside |= winding_numbers(pieces.triangles[own], points) > 0.5
    assert inside.any()
    np.testing.assert_array_equal(inside_elements(pieces, points), inside)


def test_unit_scale_is_refused_for_ifc_which_converts_its_own_unit(scenes_dir: Path) -> None:
    with pytest.raises(ParameterError, match="unit_scale") as info:
        read_scene(scenes_dir / f"{HOUSE}.ifc", unit_scale=0.001)
    assert info.value.parameter == "unit_scale"


# errors ----------------------------------------------------------------------------------


def test_garbage_after_an_iso_header_is_a_scene_error(tmp_path: Path) -> None:
    path = tmp_path / "broken.ifc"
    path.write_bytes(b"ISO-10303-21;\nHEADER;\nthis is not a STEP file at all\n")
    with pytest.raises(SceneError, match="could not be read as IFC"):
        read_scene(path)


def test_unsupported_schema_is_named(tmp_path: Path) -> None:
    path = tmp_path / "old.ifc"
    path.write_text(
        "ISO-10303-21;\nHEADER;\nFILE_DESCRIPTION((''),'2;1');\n"
        "FILE_NAME('','',(''),(''),'','','');\nFILE_SCHEMA(('IFC2X2_FINAL'));\nENDSEC;\n"
        "DATA;\n#1=IFCPERSON($,$,'',$,$,$,$,$);\nENDSEC;\nEND-ISO-10303-21;\n")
    with pytest.raises(SceneError, match=r"IFC2X2_FINAL.*IFC2X3, IFC4, IFC4X3"):
        read_scene(path)


@pytest.mark.parametrize("schema", ["IFC2X3", "IFC4"])
def test_ifc_without_geometry_is_a_scene_error(tmp_path: Path, schema: str) -> None:
    model = ifcopenshell.file(schema=schema)
    model.createIfcProject(ifcopenshell.guid.new(), Name="empty")
    path = tmp_path / "empty.ifc"
    model.write(str(path))
    with pytest.raises(SceneError, match="no geometry"):
        read_scene(path)


# rooms -----------------------------------------------------------------------------------


def test_room_candidates_stand_in_their_rooms_in_a_stable_order(fzk: Scene) -> None:
    spec = _spec()
    caster = _caster(fzk, spec)
    first = room_candidates(fzk, spec, caster)
    again = room_candidates(fzk, spec, caster)
    assert first.source == "rooms"
    np.testing.assert_array_equal(first.positions, again.positions)
    assert first.labels == again.labels
    assert set(first.dropped) == set(DROP_REASONS)
    assert first.considered == len(first) + sum(first.dropped.values())
    spaces = {s["global_id"]: s for s in fzk.metadata["spaces"]}
    for position, label in zip(first.positions, first.labels, strict=True):
        space = spaces[label["room_global_id"]]
        room = Polygon(space["polygon"], space["holes"])
        assert intersects_xy(room, position[0], position[1])
        assert position[2] == pytest.approx(space["floor_z_m"] + spec.scanner_height_m)
        assert label["storey"] == space["storey"]
        assert np.allclose(position[:2] / GRID_M, np.round(position[:2] / GRID_M))
    assert {label["room"] for label in first.labels} == ROOMS


def test_rooms_and_storeys_restrict_by_name_long_name_or_global_id(fzk: Scene) -> None:
    spaces = fzk.metadata["spaces"]
    kitchen = next(s for s in spaces if s["long_name"] == "Küche")
    for key in ("Küche", kitchen["name"], kitchen["global_id"]):
        spec = _spec(rooms=(key,))
        found = room_candidates(fzk, spec, _caster(fzk, spec))
        assert {label["room"] for label in found.labels} == {"Küche"}
    storey_id = fzk.metadata["storeys"][1]["global_id"]
    spec = _spec(storeys=(storey_id,))
    found = room_candidates(fzk, spec, _caster(fzk, spec))
    assert {label["room"] for label in found.labels} == {"Galerie"}


def test_unknown_rooms_and_empty_restrictions_say_how_to_fix_them(fzk: Scene) -> None:
    spec = _spec(rooms=("Keller",))
    with pytest.raises(ParameterError, match=r"known rooms are .*Küche") as info:
        room_candidates(fzk, spec, _caster(fzk, spec))
    assert info.value.parameter == "rooms"
    spec = _spec(storeys=("Keller",))
    with pytest.raises(ParameterError, match="known storeys are 'Erdgeschoss', 'Dachgeschoss'"):
        room_candidates(fzk, spec, _caster(fzk, spec))
    spec = _spec(storeys=("Dachgeschoss",), rooms=("Küche",))
    with pytest.raises(NoCandidatesError, match="change storeys or rooms"):
        room_candidates(fzk, spec, _caster(fzk, spec))


# plans and BIM outputs -------------------------------------------------------------------


@pytest.fixture(scope="module", params=["Erdgeschoss", "Dachgeschoss"])
def storey_plan(request: pytest.FixtureRequest, fzk: Scene) -> PlanResult:
    return plan(fzk, _spec(storeys=(request.param,)))


def test_a_plan_per_storey_uses_only_its_rooms_and_names_stations_by_room(
    storey_plan: PlanResult, tmp_path: Path,
) -> None:
    storey = storey_plan.spec.storeys[0]  # type: ignore[index]
    rooms = {s["long_name"] for s in storey_plan.scene.metadata["spaces"]
             if s["storey"] == storey}
    assert storey_plan.candidates.source == "rooms"
    assert {label["storey"] for label in storey_plan.candidates.labels} == {storey}
    document = plan_document(storey_plan)
    assert document["stations"]
    for station in document["stations"]:
        assert station["label"]["storey"] == storey
        assert station["label"]["room"] in rooms
    written = {p.name: p for p in write_outputs(storey_plan, tmp_path)}
    assert {"elements.csv", "elements.json", "plan.json"} <= set(written)
    elements = json.loads(written["elements.json"].read_text("utf-8"))
    rows = elements["elements"]
    assert len(rows) == len(storey_plan.scene.elements)
    assert sum(r["covered_area_m2"] for r in rows) == pytest.approx(
        document["totals"]["covered_area_m2"], rel=1e-6)
    for row in rows:
        assert row["covered_area_m2"] <= row["coverable_area_m2"] + 1e-6
        assert row["coverable_area_m2"] <= row["target_area_m2"] + 1e-6
        if row["target"]:
            assert 0 <= row["fraction"] <= 1
        else:
            assert row["fraction"] is None
        if row["uncoverable_reason"] is not None:
            assert row["coverable_area_m2"] == 0
            assert row["uncoverable_reason"] in bim.REASONS
    assert elements["uncoverable"]
    site = next(r for r in rows if r["ifc_class"] == "IfcSite")
    assert not site["target"] and site["uncoverable_reason"] is None
    by_storey = {s["storey"]: s for s in elements["storeys"]}
    assert by_storey[storey]["stations"] == list(range(1, len(document["stations"]) + 1))
    assert {r["room"] for r in elements["rooms"]} == rooms
    table = list(csv.DictReader(io.StringIO(written["elements.csv"].read_text("utf-8"))))
    assert [r["global_id"] for r in table] == [r["global_id"] for r in rows]
    assert list(table[0]) == list(bim.COLUMNS)
    assert written["elements.csv"].read_bytes() == bim.elements_csv(storey_plan)


# an unseen building, both schemas, millimetres --------------------------------------------


def _one_room_building(schema: str, path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A 6 x 4 m room in millimetres on a storey at 3 m: floor, ceiling, four walls, a space."""
    import ifcopenshell.api.owner.settings
    from ifcopenshell.api import aggregate, geometry, owner, project, root, unit

    model = project.create_file(version=schema)  # type: ignore[arg-type]
    if schema == "IFC2X3":  # every rooted entity needs an owner history there
        user = owner.add_person_and_organisation(
            model, person=owner.add_person(model), organisation=owner.add_organisation(model))
        application = owner.add_application(model)
        monkeypatch.setattr(ifcopenshell.api.owner.settings, "get_user", lambda _: user)
        monkeypatch.setattr(ifcopenshell.api.owner.settings, "get_application",
                            lambda _: application)
    ifc_project = root.create_entity(model, ifc_class="IfcProject", name="synthetic")
    unit.assign_unit(model, units=[
        unit.add_si_unit(model, unit_type="LENGTHUNIT", prefix="MILLI")])
    body, building = body_and_building(model, ifc_project)
    storey = root.create_entity(model, ifc_class="IfcBuildingStorey", name="Level 1")
    storey.Elevation = 3000.0
    aggregate.assign_object(model, relating_object=building, products=[storey])

    room_shell(model, body, storey, 6.0, 4.0, 3.0, 2.7)
    space = placed(model, "IfcSpace", "101", geometry.add_slab_representation(
        model, body, depth=2.7, polyline=[(0.2, 0.2), (5.8, 0.2), (5.8, 3.8), (0.2, 3.8)]),
        (0, 0, 3.0))
    space.LongName = "Office"
    aggregate.assign_object(model, relating_object=storey, products=[space])
    model.write(str(path))


@pytest.mark.parametrize("schema", ["IFC2X3", "IFC4"])
def test_an_unseen_building_in_millimetres_plans_from_its_room(
    schema: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
) -> None:
    path = tmp_path / "building.ifc"
    _one_room_building(schema, path, monkeypatch)
    scene = read_scene(path, max_edge_m=0.5)
    assert scene.metadata["schema"] == schema
    assert scene.metadata["length_unit_scale"] == pytest.approx(0.001)
    np.testing.assert_allclose(scene.bounds, [[0, 0, 2.8], [6, 4, 5.9]], atol=1e-6)
    assert scene.metadata["storeys"][0]["elevation_m"] == pytest.approx(3.0)
    (space,) = scene.metadata["spaces"]
    assert (space["long_name"], space["storey"]) == ("Office", "Level 1")
    assert space["floor_z_m"] == pytest.approx(3.0)
    assert space["area_m2"] == pytest.approx(5.6 * 3.6)
    assert {e.storey for e in scene.elements} == {"Level 1"}
    result = plan(scene, PlanSpec(max_edge_m=0.5))
    assert result.candidates.source == "rooms"
    inner = (result.candidates.positions[:, :2] > 0.2) & (
        result.candidates.positions[:, :2] < [5.8, 3.8])
    assert inner.all()
    np.testing.assert_allclose(result.candidates.positions[:, 2], 4.5)
    rows = bim.element_rows(result)
    assert {r["name"] for r in rows} == {"Floor", "Ceiling", "South", "East", "North", "West"}
    assert all(0 < r["fraction"] < 1 for r in rows)  # the outer faces are the walls' backs
    assert {s["label"]["room"] for s in plan_document(result)["stations"]} == {"Office"}


# why an element cannot be covered ----------------------------------------------------------


def _panel(centre: tuple[float, float, float], normal_axis: int, size: float
           ) -> tuple[np.ndarray, np.ndarray]:
    """Two triangles, a square of ``size`` facing along ``normal_axis`` around ``centre``."""
    u, v = [a for a in range(3) if a != normal_axis]
    corners = np.zeros((4, 3))
    for i, (du, dv) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
        corners[i] = centre
        corners[i, u] += du * size / 2
        corners[i, v] += dv * size / 2
    return corners, np.array([[0, 1, 2], [0, 2, 3]])


def test_each_uncoverable_element_gets_the_reason_that_blocks_it() -> None:
    # scanner at (0, 0, 1.5); density 10 000 pts/m2 reaches 10 m head-on
    panels = {
        "seen": ((3.0, 0.0, 1.5), 0, 2.0),  # 3 m ahead, head-on
        "occluded": ((5.0, 0.0, 1.5), 0, 1.0),  # right behind "seen"
        "too_far": ((20.0, 0.0, 1.5), 0, 1.0),
        "too_close": ((-1.0, 0.0, 1.5), 0, 0.5),
        "outside_field_of_view": ((0.0, 0.0, 0.0), 2, 0.4),  # the floor under the tripod
        "too_grazing": ((2.5, 3.0, 1.6), 2, 1.0),  # level with the scanner, 4 m away
    }
    vertices, faces, owner = [], [], []
    for e, (centre, axis, size) in enumerate(panels.values()):
        corners, tris = _panel(centre, axis, size)
        faces.append(tris + 4 * e)
        vertices.append(corners)
        owner += [e, e]
    elements = tuple(Element(f"id-{name}", "IfcWall", name, "Level 1") for name in panels)
    scene = build_scene(np.concatenate(vertices), np.concatenate(faces),
                        face_element=np.array(owner), elements=elements)
    spec = PlanSpec(candidates=((0.0, 0.0, 1.5),), max_edge_m=None,
                    min_density_pts_m2=10_000.0)
    result = plan(scene, spec)
    rows = {row["name"]: row for row in bim.element_rows(result)}
    assert rows["seen"]["fraction"] == pytest.approx(1.0)
    assert rows["seen"]["uncoverable_reason"] is None
    for name in list(panels)[1:]:
        assert rows[name]["coverable_area_m2"] == 0
        assert rows[name]["uncoverable_reason"] == name, rows[name]


def _numpy_face_reasons(result: PlanResult, faces: np.ndarray) -> np.ndarray:
    """The reasons of the module docstring in plain numpy, every (candidate, face) pair."""
    lim, positions = result.limits, result.candidates.positions
    offsets = result.scene.centroids[faces][None, :, :] - positions[:, None, :]  # (C, n, 3)
    distance = np.linalg.norm(offsets, axis=2)
    safe = np.maximum(distance, 1e-12)
    elevation = np.degrees(np.arcsin(np.clip(offsets[:, :, 2] / safe, -1.0, 1.0)))
    sin_incidence = np.abs(np.einsum("cnk,nk->cn", offsets, result.scene.normals[faces])) / safe
    incidence = np.degrees(np.arcsin(np.clip(sin_incidence, 0.0, 1.0)))
    density = lim.min_density_pts_m2[faces][None, :]
    head_on = 1.0 / np.maximum(lim.angular_step_rad * distance, 1e-12) ** 2
    fails = np.stack([
        distance < lim.dof_min_m,
        (distance > lim.dof_max_m) | (head_on < density),
        (elevation < lim.elevation_min_deg) | (elevation > lim.elevation_max_deg),
        (incidence < lim.min_incidence_deg[faces][None, :])
        | ((sin_incidence * head_on < density) & (head_on >= density)),
    ])
    count = fails.sum(axis=0)
    tally = (fails & (count == count.min(axis=0))[None]).sum(axis=1)
    return np.where(count.min(axis=0) == 0, 0, 1 + np.argmax(tally, axis=0))


def test_compiled_reasons_equal_every_pair_tested_in_numpy(storey_plan: PlanResult) -> None:
    # candidates lifted 0.7 m and thinned, so that every reason occurs on the storey's faces
    faces = np.flatnonzero(storey_plan.limits.target)[::7]
    for subset in (slice(0, 3), slice(None, None, 5)):
        candidates = dataclasses.replace(
            storey_plan.candidates, labels=(),
            positions=storey_plan.candidates.positions[subset] + np.array([0.0, 0.0, 0.7]))
        result = dataclasses.replace(storey_plan, candidates=candidates)
        codes = bim.face_reasons(result, faces)
        np.testing.assert_array_equal(codes, _numpy_face_reasons(result, faces))
        assert len(np.unique(codes)) >= 3


def test_a_mesh_without_elements_writes_no_element_tables(tmp_path: Path) -> None:
    room = trimesh.creation.box(extents=(4.0, 4.0, 3.0))
    room.apply_translation((0.0, 0.0, 1.5))
    scene = remesh(build_scene(room.vertices, room.faces), 0.5)
    result = plan(scene, PlanSpec(candidates=((0.0, 0.0, 1.5),), max_edge_m=0.5,
                                  min_density_pts_m2=1000.0))
    names = {p.name for p in write_outputs(result, tmp_path)}
    assert "plan.json" in names
    assert not names & {"elements.csv", "elements.json"}
    assert bim.elements_json(result) is None


def test_rooms_without_slabs_stand_on_their_spaces(scenes_dir: Path, tmp_path: Path,
                                                   fzk: Scene) -> None:
    # a BIM platform often sends the architectural model alone: the slabs are elsewhere
    model = ifcopenshell.open(str(scenes_dir / f"{FZK}.ifc"))
    for slab in model.by_type("IfcSlab"):
        model.remove(slab)
    path = tmp_path / "fzk-without-slabs.ifc"
    model.write(str(path))
    spec = _spec()
    bare = remesh(read_ifc(path), EDGE_M)
    assert "IfcSlab" not in bare.groups
    candidates = room_candidates(bare, spec, _caster(bare, spec))
    rooms = {label["room_global_id"] for label in candidates.labels}
    assert rooms == {space["global_id"] for space in bare.metadata["spaces"]}
    assert candidates.floor_from_space
    assert set(candidates.floor_from_space) <= {label["room"] for label in candidates.labels}
    # with its slabs, every room finds its floor and none needs its space
    full = room_candidates(fzk, spec, _caster(fzk, spec))
    assert full.floor_from_space == ()
